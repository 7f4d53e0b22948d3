// Special functions in f32 for the GPU. Line-by-line twins of the Rust functions in
// precompute/src/special.rs (erf_f32, erfc_f32, i0e_f32): keep them in sync; the test
// renderer/tests/gpu_parity.rs compares both over grids that include the hard cases.

const FRAC_2_SQRT_PI: f32 = 1.1283791670955126;

// Error function: Taylor series for |x| < 0.5, Abramowitz-Stegun 7.1.26 above; odd in x.
fn erf_f32(x: f32) -> f32 {
    let z = abs(x);
    if (z < 0.5) {
        let x2 = x * x;
        let s = 1.0 + x2 * (-1.0 / 3.0 + x2 * (0.1 + x2 * (-1.0 / 42.0 + x2 * (1.0 / 216.0 - x2 / 1320.0))));
        return FRAC_2_SQRT_PI * x * s;
    }
    let t = 1.0 / (1.0 + 0.3275911 * z);
    let poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))));
    let y = 1.0 - poly * exp(-z * z);
    return select(y, -y, x < 0.0);
}

// Complementary error function with good relative accuracy in the tail (Numerical Recipes
// erfcc); the exponent -z^2 is split as -s^2 - (z - s)(z + s) with s = floor(256 z) / 256.
fn erfc_f32(x: f32) -> f32 {
    let z = abs(x);
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -1.26551223
        + t * (1.00002368
        + t * (0.37409196
        + t * (0.09678418
        + t * (-0.18628806
        + t * (0.27886807
        + t * (-1.13520398 + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277))))))));
    let s = floor(z * 256.0) / 256.0;
    let small = -(z - s) * (z + s) + poly;
    let ans = t * exp(-s * s) * exp(small);
    return select(ans, 2.0 - ans, x < 0.0);
}

// e^{-|x|} I0(x): Abramowitz-Stegun 9.8.1 times e^{-|x|} for |x| <= 3.75, 9.8.2 above.
fn i0e_f32(x: f32) -> f32 {
    let ax = abs(x);
    if (ax <= 3.75) {
        let t = ax / 3.75;
        let t2 = t * t;
        let i0 = 1.0
            + t2 * (3.5156229
            + t2 * (3.0899424 + t2 * (1.2067492 + t2 * (0.2659732 + t2 * (0.0360768 + t2 * 0.0045813)))));
        return i0 * exp(-ax);
    }
    let u = 3.75 / ax;
    let poly = 0.39894228
        + u * (0.01328592
        + u * (0.00225319
        + u * (-0.00157565
        + u * (0.00916281
        + u * (-0.02057706 + u * (0.02635537 + u * (-0.01647633 + u * 0.00392377)))))));
    return poly / sqrt(ax);
}
