// Spherical Gaussian helpers for the GPU. Twins of precompute/src/special.rs (expm1_f32) and
// precompute/src/sg.rs (sg_mass_f32, sg_azimuthal_average_f32): keep them in sync; compared
// on the GPU by renderer/tests/gpu_parity.rs.
#import shared/special.wgsl

const PI: f32 = 3.14159265358979;

// e^x - 1 without cancellation near 0 (WGSL has no expm1).
fn expm1_f32(x: f32) -> f32 {
    if (abs(x) < 0.5) {
        return x * (1.0
            + x * (1.0 / 2.0
            + x * (1.0 / 6.0
            + x * (1.0 / 24.0 + x * (1.0 / 120.0 + x * (1.0 / 720.0 + x * (1.0 / 5040.0 + x / 40320.0)))))));
    }
    return exp(x) - 1.0;
}

// Integral of exp(lambda (w.xi - 1)) over the sphere: -2 pi expm1(-2 lambda) / lambda, 4 pi at 0.
fn sg_mass_f32(lambda: f32) -> f32 {
    if (lambda <= 0.0) {
        return 4.0 * PI;
    }
    return -2.0 * PI * expm1_f32(-2.0 * lambda) / lambda;
}

// (1 / 2 pi) Int exp(lambda (w.xi - 1)) dphi in the fiber frame, overflow-free:
// exp(-lambda (1 - cos(theta - theta_xi))) i0e(lambda cos(theta) cos(theta_xi)).
fn sg_azimuthal_average_f32(theta: f32, theta_xi: f32, lambda: f32) -> f32 {
    let half = 0.5 * (theta - theta_xi);
    let s = sin(half);
    let one_minus_cos = 2.0 * s * s;
    return exp(-lambda * one_minus_cos) * i0e_f32(lambda * max(cos(theta), 0.0) * max(cos(theta_xi), 0.0));
}
