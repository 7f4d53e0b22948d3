//! Special functions: f64 references and f32 "GPU forms".
//!
//! How it works:
//! - [`erf`] and [`erfc`] forward to `libm` (FreeBSD's msun, full f64 accuracy including the
//!   `erfc` tail, which is computed directly and never as `1 - erf`).
//! - [`i0e`] is `e^{-|x|} I0(x)` from the Cephes Chebyshev expansions (the ones SciPy uses):
//!   one on `[0, 8]` in `x/2 - 2`, one on `(8, inf)` in `32/x - 2` divided by `sqrt(x)`.
//!   [`log_i0`] is `|x| + ln i0e(x)`, with a power series below `|x| = 2` where that sum would
//!   cancel.
//! - [`sph_i_scaled`] returns `e^{-x} i_l(x)` (modified spherical Bessel functions of the first
//!   kind). Where the upward recurrence `i_{l+1} = i_{l-1} - (2l+1)/x i_l` is unstable (it
//!   amplifies rounding by about `e^{l^2/x}`), the ratios `r_l = i_{l+1}/i_l` are run downward
//!   from far above `l_max` (Miller's algorithm in ratio form: no overflow, no rescaling) and
//!   multiplied up from the closed form of `e^{-x} i_0`. Where `x >= l_max^2` the upward
//!   recurrence is used from closed forms of `i_0` and `i_1`.
//! - The `*_f32` functions are the CPU twins of WGSL code: only `+ - * /`, `abs`, `floor`,
//!   `exp`, `sqrt` and `select`-style branches, so they translate line by line.

/// Error function, full f64 accuracy (libm).
#[must_use]
pub fn erf(x: f64) -> f64 {
    libm::erf(x)
}

/// Complementary error function `1 - erf(x)`, full f64 *relative* accuracy in the tail (libm);
/// underflows to 0 only beyond `x ~ 26.5`.
#[must_use]
pub fn erfc(x: f64) -> f64 {
    libm::erfc(x)
}

/// Cephes Chebyshev coefficients of `e^{-x} I0(x)` on `[0, 8]` in the variable `x/2 - 2`.
const I0E_A: [f64; 30] = [
    -4.41534164647933937950E-18,
    3.33079451882223809783E-17,
    -2.43127984654795469359E-16,
    1.71539128555513303061E-15,
    -1.16853328779934516808E-14,
    7.67618549860493561688E-14,
    -4.85644678311192946090E-13,
    2.95505266312963983461E-12,
    -1.72682629144155570723E-11,
    9.67580903537323691224E-11,
    -5.18979560163526290666E-10,
    2.65982372468238665035E-9,
    -1.30002500998624804212E-8,
    6.04699502254191894932E-8,
    -2.67079385394061173391E-7,
    1.11738753912010371815E-6,
    -4.41673835845875056359E-6,
    1.64484480707288970893E-5,
    -5.75419501008210370398E-5,
    1.88502885095841655729E-4,
    -5.76375574538582365885E-4,
    1.63947561694133579842E-3,
    -4.32430999505057594430E-3,
    1.05464603945949983183E-2,
    -2.37374148058994688156E-2,
    4.93052842396707084878E-2,
    -9.49010970480476444210E-2,
    1.71620901522208775349E-1,
    -3.04682672343198398683E-1,
    6.76795274409476084995E-1,
];

/// Cephes Chebyshev coefficients of `sqrt(x) e^{-x} I0(x)` on `(8, inf)` in `32/x - 2`.
const I0E_B: [f64; 25] = [
    -7.23318048787475395456E-18,
    -4.83050448594418207126E-18,
    4.46562142029675999901E-17,
    3.46122286769746109310E-17,
    -2.82762398051658348494E-16,
    -3.42548561967721913462E-16,
    1.77256013305652638360E-15,
    3.81168066935262242075E-15,
    -9.55484669882830764870E-15,
    -4.15056934728722208663E-14,
    1.54008621752140982691E-14,
    3.85277838274214270114E-13,
    7.18012445138366623367E-13,
    -1.79417853150680611778E-12,
    -1.32158118404477131188E-11,
    -3.14991652796324136454E-11,
    1.18891471078464383424E-11,
    4.94060238822496958910E-10,
    3.39623202570838634515E-9,
    2.26666899049817806459E-8,
    2.04891858946906374183E-7,
    2.89137052083475648297E-6,
    6.88975834691682398426E-5,
    3.36911647825569408990E-3,
    8.04490411014108831608E-1,
];

/// Clenshaw sum of a Chebyshev series in the Cephes `chbevl` convention (first coefficient is
/// the highest order, the constant term is halved).
fn chebyshev_sum(x: f64, coeffs: &[f64]) -> f64 {
    let mut b0 = coeffs[0];
    let mut b1 = 0.0;
    let mut b2 = 0.0;
    for &c in &coeffs[1..] {
        b2 = b1;
        b1 = b0;
        b0 = x * b1 - b2 + c;
    }
    0.5 * (b0 - b2)
}

/// Above this κ, [`bessel_i_ratios`] takes `I_k(κ)/I_0(κ)` as `exp(−k²/2κ)` (its error there
/// at most 5.6e-4 for k ≤ 12, falling as 1/κ²); at or below it, the continued fraction run
/// [`BESSEL_RATIO_DEPTH`] terms past the last ratio asked for (error below 2e-6 at κ = 200
/// and k ≤ 12, at rounding level below κ = 50).
pub const BESSEL_RATIO_GAUSSIAN_ABOVE: f64 = 200.0;

/// Extra terms of [`bessel_i_ratios`]'s continued fraction.
pub const BESSEL_RATIO_DEPTH: usize = 40;

/// `out[k − 1] = I_k(κ) / I_0(κ)` for k = 1..=`out.len()`, κ ≥ 0: the Fourier coefficients of
/// a von Mises density of concentration κ, `E cos kφ` (0 for κ = 0, toward 1 as κ grows).
/// The ratios `r_k = I_k/I_{k−1} = 1 / (2k/κ + r_{k+1})` are run downward from
/// [`BESSEL_RATIO_DEPTH`] terms above the last (Miller's algorithm in ratio form: no overflow)
/// and multiplied up; above [`BESSEL_RATIO_GAUSSIAN_ABOVE`] the continued fraction would need
/// a depth of order √κ, and `exp(−k²/2κ)` is accurate there instead. WGSL twin
/// `bessel_i_ratios` (shaders/shared/shading.wgsl, beside the fiber lobes that use it).
pub fn bessel_i_ratios(kappa: f64, out: &mut [f64]) {
    if kappa.is_nan() || kappa <= 0.0 {
        out.fill(0.0);
        return;
    }
    if kappa > BESSEL_RATIO_GAUSSIAN_ABOVE {
        for (k, o) in out.iter_mut().enumerate() {
            let k = (k + 1) as f64;
            *o = (-k * k / (2.0 * kappa)).exp();
        }
        return;
    }
    let n = out.len();
    let mut r = 0.0;
    for k in (n + 1..=n + BESSEL_RATIO_DEPTH).rev() {
        r = 1.0 / (2.0 * k as f64 / kappa + r);
    }
    for k in (1..=n).rev() {
        r = 1.0 / (2.0 * k as f64 / kappa + r);
        out[k - 1] = r;
    }
    let mut product = 1.0;
    for o in out.iter_mut() {
        product *= *o;
        *o = product;
    }
}

/// Exponentially scaled modified Bessel function of order 0: `e^{-|x|} I0(x)`.
/// Even in `x`; about 1e-15 relative accuracy (Cephes `i0e`). Never overflows.
#[must_use]
pub fn i0e(x: f64) -> f64 {
    let x = x.abs();
    if x <= 8.0 {
        chebyshev_sum(0.5 * x - 2.0, &I0E_A)
    } else {
        chebyshev_sum(32.0 / x - 2.0, &I0E_B) / x.sqrt()
    }
}

/// `ln I0(x)`, overflow-free for any finite `x`, accurate to relative ~1e-15 also near 0
/// (where `ln I0(x) ~ x^2/4`).
#[must_use]
pub fn log_i0(x: f64) -> f64 {
    let x = x.abs();
    if x < 2.0 {
        // I0(x) - 1 = sum_{k>=1} (x^2/4)^k / (k!)^2, all terms positive; 20 terms reach 1e-30.
        let q = 0.25 * x * x;
        let mut term = 1.0;
        let mut sum = 0.0;
        for k in 1..=20 {
            let kf = f64::from(k);
            term *= q / (kf * kf);
            sum += term;
        }
        sum.ln_1p()
    } else {
        x + i0e(x).ln()
    }
}

/// `e^{-x} i_0(x) = (1 - e^{-2x}) / (2x)`, with the limit 1 at `x = 0`.
fn sph_i0_scaled(x: f64) -> f64 {
    if x == 0.0 { 1.0 } else { -(-2.0 * x).exp_m1() / (2.0 * x) }
}

/// Scaled modified spherical Bessel functions of the first kind: `out[l] = e^{-x} i_l(x)` for
/// `l = 0..=l_max`, for `x >= 0` (including `x = 0`, where `i_0 = 1` and the others are 0).
/// Relative accuracy about `1e-14` for `x` in `[1e-4, 1e5]` and `l_max <= 30`; values below
/// the f64 range underflow to 0 gracefully.
///
/// # Panics
/// If `x` is negative or not finite.
#[must_use]
pub fn sph_i_scaled(l_max: usize, x: f64) -> Vec<f64> {
    assert!(x.is_finite() && x >= 0.0, "sph_i_scaled: x = {x} must be finite and >= 0");
    let mut out = vec![0.0; l_max + 1];
    out[0] = sph_i0_scaled(x);
    if l_max == 0 || x == 0.0 {
        return out;
    }
    let lf = l_max as f64;
    if x >= (lf * lf).max(2.0) {
        sph_i_scaled_upward(x, &mut out);
    } else {
        sph_i_scaled_miller(x, &mut out);
    }
    out
}

/// Upward recurrence from closed forms of `i_0` and `i_1`; rounding grows like `e^{l^2/x}`, so
/// only used for `x >= l_max^2` (growth at most `e`) and `x >= 2` (mild cancellation in `i_1`).
fn sph_i_scaled_upward(x: f64, out: &mut [f64]) {
    // e^{-x} i_1(x) = e^{-x} (cosh x / x - sinh x / x^2).
    let e2 = (-2.0 * x).exp();
    let cosh_scaled = 0.5 * (1.0 + e2);
    let sinh_scaled = -0.5 * (-2.0 * x).exp_m1();
    out[1] = (cosh_scaled - sinh_scaled / x) / x;
    for l in 1..out.len() - 1 {
        out[l + 1] = out[l - 1] - (2 * l + 1) as f64 / x * out[l];
    }
}

/// Miller's downward recurrence in ratio form: `r_{l-1} = x / (2l + 1 + x r_l)`, started with
/// `r_N = 0` far enough above `l_max` that the starting error (about `e^{-(N^2 - l^2)/x}` for
/// large `x`, and far smaller for small `x`) is below f64 rounding.
fn sph_i_scaled_miller(x: f64, out: &mut [f64]) {
    let l_max = out.len() - 1;
    let lf = l_max as f64;
    let start = (lf * lf + 40.0 * x).sqrt().ceil() as usize + 20;
    let mut ratios = vec![0.0; l_max];
    let mut r = 0.0;
    for l in (1..=start).rev() {
        r = x / ((2 * l + 1) as f64 + x * r);
        if l - 1 < l_max {
            ratios[l - 1] = r;
        }
    }
    for l in 1..=l_max {
        out[l] = out[l - 1] * ratios[l - 1];
    }
}

/// Error function in f32: Taylor series for `|x| < 0.5` (relative error ~1e-7, also near 0),
/// Abramowitz–Stegun 7.1.26 above (1.5e-7 formula error; measured absolute error 3e-7 with
/// f32 rounding of its Horner sum); odd in `x`.
/// `1 - erf_f32` has poor *relative* accuracy in the tail: use [`erfc_f32`] where a tail is
/// divided.
#[must_use]
pub fn erf_f32(x: f32) -> f32 {
    let z = x.abs();
    if z < 0.5 {
        // Taylor series 2/sqrt(pi) (x - x^3/3 + x^5/10 - x^7/42 + x^9/216 - x^11/1320): keeps
        // relative accuracy near 0, where 7.1.26 computes 1 - (almost 1).
        let x2 = x * x;
        let s = 1.0 + x2 * (-1.0 / 3.0 + x2 * (0.1 + x2 * (-1.0 / 42.0 + x2 * (1.0 / 216.0 - x2 / 1320.0))));
        return std::f32::consts::FRAC_2_SQRT_PI * x * s;
    }
    let t = 1.0 / (1.0 + 0.3275911 * z);
    let poly =
        t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))));
    let y = 1.0 - poly * (-z * z).exp();
    if x < 0.0 { -y } else { y }
}

/// Complementary error function in f32 with good *relative* accuracy in the tail: Numerical
/// Recipes' Chebyshev fit `erfcc` (fractional error < 1.2e-7 in exact arithmetic). The
/// exponent `-z^2` is split as `-s^2 - (z - s)(z + s)` with `s = floor(256 z)/256`, so `s^2` is
/// exact in f32 and the large part of the exponent is not rounded: measured relative error
/// below 1e-6 up to `x = 9` (f32 `exp` rounding), where erfc is 4e-37; 0 beyond ~9.2.
#[must_use]
pub fn erfc_f32(x: f32) -> f32 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -1.26551223
        + t * (1.00002368
            + t * (0.37409196
                + t * (0.09678418
                    + t * (-0.18628806
                        + t * (0.27886807
                            + t * (-1.13520398 + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277))))))));
    let s = (z * 256.0).floor() / 256.0;
    let small = -(z - s) * (z + s) + poly;
    let ans = t * (-s * s).exp() * small.exp();
    if x < 0.0 { 2.0 - ans } else { ans }
}

/// `e^{-|x|} I0(x)` in f32: Abramowitz–Stegun 9.8.1 (polynomial in `(x/3.75)^2`) times
/// `e^{-|x|}` for `|x| <= 3.75`, 9.8.2 (polynomial in `3.75/x` over `sqrt(x)`) above.
/// Relative error about 2e-7 (measured bound in the tests); never overflows.
#[must_use]
pub fn i0e_f32(x: f32) -> f32 {
    let ax = x.abs();
    if ax <= 3.75 {
        let t = ax / 3.75;
        let t2 = t * t;
        let i0 = 1.0
            + t2 * (3.5156229
                + t2 * (3.0899424 + t2 * (1.2067492 + t2 * (0.2659732 + t2 * (0.0360768 + t2 * 0.0045813)))));
        i0 * (-ax).exp()
    } else {
        let u = 3.75 / ax;
        let poly = 0.39894228
            + u * (0.01328592
                + u * (0.00225319
                    + u * (-0.00157565
                        + u * (0.00916281
                            + u * (-0.02057706 + u * (0.02635537 + u * (-0.01647633 + u * 0.00392377)))))));
        poly / ax.sqrt()
    }
}

/// `e^x - 1` in f32 without cancellation near 0 (WGSL has no `expm1`): Taylor series through
/// `x^8/8!` for `|x| < 0.5` (truncation below 3e-9 relative), `exp(x) - 1` above, where the
/// subtraction loses at most about two bits.
#[must_use]
pub fn expm1_f32(x: f32) -> f32 {
    if x.abs() < 0.5 {
        x * (1.0
            + x * (1.0 / 2.0
                + x * (1.0 / 6.0
                    + x * (1.0 / 24.0
                        + x * (1.0 / 120.0 + x * (1.0 / 720.0 + x * (1.0 / 5040.0 + x / 40320.0)))))))
    } else {
        x.exp() - 1.0
    }
}

/// `ln(1 + x)` in f32 without cancellation near 0 (WGSL has no `log1p`): Goldberg's form
/// `ln(y) x / (y - 1)` with `y = 1 + x` rounded, which cancels the rounding of `y`.
#[must_use]
pub fn ln_1p_f32(x: f32) -> f32 {
    let y = 1.0 + x;
    let d = y - 1.0;
    if d == 0.0 { x } else { y.ln() * (x / d) }
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // exact limits and symmetries are checked bit for bit
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn rel_err(a: f64, b: f64) -> f64 {
        assert!(a.is_finite() && b.is_finite(), "non-finite: {a} vs {b}");
        if b == 0.0 { a.abs() } else { ((a - b) / b).abs() }
    }

    /// Log-spaced grid from `lo` to `hi`, `n` points.
    fn log_grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
        (0..n).map(|i| lo * (hi / lo).powf(i as f64 / (n - 1) as f64)).collect()
    }

    /// `e^{-x} I0(x)` by its power series (all terms positive), valid while `e^{-x}` is normal.
    fn i0e_series(x: f64) -> f64 {
        let q = 0.25 * x * x;
        let mut term = (-x).exp();
        let mut sum = term;
        let mut k = 1.0;
        while term > 1e-18 * sum || k < x {
            term *= q / (k * k);
            sum += term;
            k += 1.0;
        }
        sum
    }

    /// `e^{-x} i_l(x)` by its power series
    /// `x^l/(2l+1)!! sum_k (x^2/2)^k / (k! (2l+3)(2l+5)...(2l+2k+1))`, all terms positive.
    fn sph_i_scaled_series(l: usize, x: f64) -> f64 {
        let mut lead = (-x).exp();
        for k in 0..=l {
            lead *= if k == 0 { 1.0 } else { x } / (2 * k + 1) as f64;
        }
        let q = 0.5 * x * x;
        let (mut term, mut sum, mut k) = (lead, lead, 1.0);
        while term > 1e-18 * sum || k < x {
            term *= q / (k * (2.0 * (l as f64 + k) + 1.0));
            sum += term;
            k += 1.0;
        }
        sum
    }

    /// Exact finite sum for large `x` (the `e^{-2x}` part dropped, valid for `x >= 40`):
    /// `e^{-x} i_l(x) = 1/(2x) sum_{k=0}^{l} (-1)^k (l+k)! / (k! (l-k)!) (2x)^{-k}`.
    fn sph_i_scaled_large(l: usize, x: f64) -> f64 {
        let mut term = 1.0;
        let mut sum = 1.0;
        for k in 1..=l {
            // (l+k)!/(k!(l-k)!) over the previous = (l+k)(l-k+1)/k.
            term *= -(((l + k) * (l - k + 1)) as f64) / (k as f64 * 2.0 * x);
            sum += term;
        }
        sum / (2.0 * x)
    }

    #[test]
    fn erf_and_erfc_match_known_values_and_are_complementary() {
        // Values from mpmath (30 digits, rounded).
        assert!(rel_err(erf(0.5), 0.520_499_877_813_046_5) < 1e-15);
        assert!(rel_err(erfc(5.0), 1.537_459_794_428_034_8e-12) < 1e-14);
        assert!(rel_err(erfc(10.0), 2.088_487_583_762_544_8e-45) < 1e-14);
        assert!(rel_err(erfc(-2.0), 1.995_322_265_018_952_7) < 1e-15);
        for x in log_grid(1e-6, 6.0, 200) {
            assert!((erf(x) + erfc(x) - 1.0).abs() < 2e-16, "x = {x}");
            assert!((erf(-x) + erf(x)).abs() < 1e-300);
        }
    }

    /// `I_k(κ)/I_0(κ)` as the mean of `cos kφ` under `e^{κ(cos φ − 1)}`, by the trapezoid rule
    /// over a period (exponentially accurate for a smooth periodic integrand; 8,192 points
    /// resolve the narrowest density tested, 1/√κ = 0.009 rad wide).
    fn bessel_ratio_by_quadrature(kappa: f64, k: usize) -> f64 {
        let n = 8192;
        let (mut num, mut den) = (0.0, 0.0);
        for i in 0..n {
            let phi = 2.0 * std::f64::consts::PI * f64::from(i) / f64::from(n);
            let w = (kappa * (phi.cos() - 1.0)).exp();
            num += w * (k as f64 * phi).cos();
            den += w;
        }
        num / den
    }

    #[test]
    fn bessel_i_ratios_match_the_von_mises_means() {
        for &kappa in &[1e-6, 0.01, 0.5, 1.0, 8.35, 49.0, 150.0, 200.0, 200.1, 1000.0, 13_131.0] {
            let mut got = [0.0; 12];
            bessel_i_ratios(kappa, &mut got);
            let bound = if kappa > BESSEL_RATIO_GAUSSIAN_ABOVE { 6e-4 } else { 2e-6 };
            for (k, g) in got.iter().enumerate() {
                let want = bessel_ratio_by_quadrature(kappa, k + 1);
                assert!(
                    g.is_finite() && (g - want).abs() <= bound,
                    "κ {kappa} k {}: {g} against {want}",
                    k + 1
                );
            }
        }
        let mut zero = [1.0; 4];
        bessel_i_ratios(0.0, &mut zero);
        assert_eq!(zero, [0.0; 4]);
        bessel_i_ratios(f64::NAN, &mut zero);
        assert_eq!(zero, [0.0; 4]);
    }

    #[test]
    fn i0e_matches_power_series_and_asymptotics() {
        // Known value: scipy.special.i0e(1) = 0.46575960759364043.
        assert!(rel_err(i0e(1.0), 0.465_759_607_593_640_43) < 1e-15);
        assert_eq!(i0e(0.0), 1.0);
        // mpmath, 30 digits, rounded.
        for (x, reference) in [
            (0.1, 0.907_100_925_782_301_09),
            (2.5, 0.270_046_441_612_202_74),
            (7.9, 0.144_369_864_141_041_92),
            (8.1, 0.142_511_809_488_295_28),
            (30.0, 0.073_145_946_482_237_294),
            (100.0, 0.039_944_379_299_096_683),
            (700.0, 0.015_081_295_651_531_358),
        ] {
            assert!(rel_err(i0e(x), reference) < 2e-15, "x = {x}");
        }
        let mut worst: f64 = 0.0;
        for x in log_grid(1e-6, 30.0, 400) {
            let e = rel_err(i0e(x), i0e_series(x));
            worst = worst.max(e);
            assert_eq!(i0e(-x), i0e(x));
        }
        assert!(worst < 3e-15, "i0e worst relative error {worst:e}");
        // Large x: e^{-x} I0(x) ~ 1/sqrt(2 pi x) sum_k ((2k-1)!!)^2 / (k! (8x)^k).
        for x in [50.0, 1e3, 1e4, 1e5, 1e8] {
            let (mut term, mut sum) = (1.0, 1.0);
            for k in 1..12 {
                let kf = f64::from(k);
                term *= (2.0 * kf - 1.0).powi(2) / (8.0 * kf * x);
                sum += term;
            }
            let asym = sum / (2.0 * PI * x).sqrt();
            assert!(rel_err(i0e(x), asym) < 2e-15, "x = {x}: {} vs {asym}", i0e(x));
        }
    }

    #[test]
    fn log_i0_is_accurate_near_zero_and_finite_far_out() {
        for x in log_grid(1e-8, 600.0, 300) {
            if x >= 0.5 {
                // x + ln i0e(x) cancels by at most a factor 8 here.
                let reference = x + i0e_series(x).ln();
                assert!(rel_err(log_i0(x), reference) < 1e-14, "x = {x}");
            } else {
                // ln I0(x) = q - q^2/4 + q^3/9 - ..., q = x^2/4.
                let q = 0.25 * x * x;
                assert!(rel_err(log_i0(x), q * (1.0 - q / 4.0)) < q * q / 8.0 + 1e-15, "x = {x}");
            }
        }
        assert!(rel_err(log_i0(1.0), 0.235_914_358_507_178_65) < 1e-15);
        assert!(rel_err(log_i0(1e6), 1e6 - 0.5 * (2.0 * PI * 1e6).ln() + (1.0 / 8e6_f64).ln_1p()) < 1e-15);
        assert_eq!(log_i0(-3.0), log_i0(3.0));
    }

    #[test]
    fn sph_i_scaled_matches_series_and_large_x_forms() {
        let l_max = 15;
        let mut worst: f64 = 0.0;
        for x in log_grid(1e-4, 40.0, 120) {
            let v = sph_i_scaled(l_max, x);
            for (l, &vl) in v.iter().enumerate() {
                let e = rel_err(vl, sph_i_scaled_series(l, x));
                worst = worst.max(e);
                assert!(e < 1e-13, "l = {l}, x = {x}: {vl:e} vs {:e}", sph_i_scaled_series(l, x));
            }
        }
        for x in log_grid(40.0, 1e5, 80) {
            let v = sph_i_scaled(l_max, x);
            for (l, &vl) in v.iter().enumerate() {
                let e = rel_err(vl, sph_i_scaled_large(l, x));
                worst = worst.max(e);
                assert!(e < 1e-13, "l = {l}, x = {x}");
            }
        }
        eprintln!("sph_i_scaled worst relative error {worst:e}");
        // Asymptotic e^{-l(l+1)/(2x)} / (2x) at x = 1e5 (its own error is ~ l(l+1)/(4 x^2)).
        let x = 1e5;
        for (l, &vl) in sph_i_scaled(l_max, x).iter().enumerate() {
            let asym = (-((l * (l + 1)) as f64) / (2.0 * x)).exp() / (2.0 * x);
            assert!(rel_err(vl, asym) < 1e-8, "l = {l}");
        }
    }

    #[test]
    fn sph_i_scaled_branches_agree_and_limits_are_exact() {
        assert_eq!(sph_i_scaled(4, 0.0), vec![1.0, 0.0, 0.0, 0.0, 0.0]);
        assert_eq!(sph_i_scaled(0, 3.0), vec![sph_i0_scaled(3.0)]);
        // Both algorithms near the switch x = l_max^2 (upward is at its least stable there).
        for l_max in [2_usize, 5, 8, 15] {
            let x = (l_max * l_max) as f64 + 0.5;
            let mut up = vec![0.0; l_max + 1];
            let mut down = vec![0.0; l_max + 1];
            up[0] = sph_i0_scaled(x);
            down[0] = up[0];
            sph_i_scaled_upward(x, &mut up);
            sph_i_scaled_miller(x, &mut down);
            for l in 0..=l_max {
                assert!(rel_err(up[l], down[l]) < 1e-13, "l_max = {l_max}, l = {l}");
            }
        }
        // Tiny and huge arguments stay finite and non-negative.
        for x in [1e-300, 1e-30, 1e8] {
            for v in sph_i_scaled(15, x) {
                assert!(v.is_finite() && v >= 0.0, "x = {x}: {v}");
            }
        }
    }

    #[test]
    fn erf_f32_absolute_error_on_minus_ten_to_ten() {
        let mut worst: f64 = 0.0;
        for i in 0..=20_000 {
            let x = -10.0 + 20.0 * f64::from(i) / 20_000.0;
            let e = (f64::from(erf_f32(x as f32)) - erf(f64::from(x as f32))).abs();
            worst = worst.max(e);
        }
        eprintln!("erf_f32 worst absolute error {worst:e}");
        assert!(worst < 3.5e-7, "erf_f32 worst absolute error {worst:e}");
        let mut worst_rel: f64 = 0.0;
        for x in log_grid(1e-30, 0.6, 300) {
            let x32 = x as f32;
            worst_rel = worst_rel.max(rel_err(f64::from(erf_f32(x32)), erf(f64::from(x32))));
        }
        eprintln!("erf_f32 worst relative error on [1e-30, 0.6]: {worst_rel:e}");
        assert!(worst_rel < 5e-7, "erf_f32 worst relative error near 0 {worst_rel:e}");
    }

    #[test]
    fn erfc_f32_relative_error_up_to_nine() {
        let mut worst: f64 = 0.0;
        for i in 0..=19_000 {
            let x = (-10.0 + 19.0 * f64::from(i) / 19_000.0) as f32;
            let reference = erfc(f64::from(x));
            let got = f64::from(erfc_f32(x));
            assert!(got.is_finite());
            worst = worst.max(rel_err(got, reference));
        }
        eprintln!("erfc_f32 worst relative error on [-10, 9]: {worst:e}");
        assert!(worst < 1e-6, "erfc_f32 worst relative error {worst:e}");
        assert!(erfc_f32(20.0) == 0.0 && erfc_f32(-20.0) == 2.0);
    }

    #[test]
    fn i0e_f32_relative_error_up_to_1e5() {
        let mut worst: f64 = 0.0;
        let grid = (0..=4000).map(|i| 10.0 * f64::from(i) / 4000.0).chain(log_grid(10.0, 1e5, 2000));
        for x in grid {
            let x32 = x as f32;
            let e = rel_err(f64::from(i0e_f32(x32)), i0e(f64::from(x32)));
            worst = worst.max(e);
            assert_eq!(i0e_f32(-x32), i0e_f32(x32));
        }
        eprintln!("i0e_f32 worst relative error on [0, 1e5]: {worst:e}");
        assert!(worst < 7e-7, "i0e_f32 worst relative error {worst:e}");
    }
}
