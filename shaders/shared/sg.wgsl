// Spherical Gaussian helpers for the GPU. Twins of precompute/src/special.rs (expm1_f32,
// ln_1p_f32) and precompute/src/sg.rs (sg_mass_f32, sg_azimuthal_average_f32,
// sg_upper_fraction_f32): keep them in sync; compared on the GPU by renderer/tests/gpu_parity.rs.
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

// ln(1 + x) without cancellation near 0 (WGSL has no log1p): Goldberg's ln(y) x / (y - 1).
fn ln_1p_f32(x: f32) -> f32 {
    let y = 1.0 + x;
    let d = y - 1.0;
    if (d == 0.0) {
        return x;
    }
    return log(y) * (x / d);
}

const UPPER_FRACTION_NODES: u32 = 32u;

// The share of a normalized SG's power above the plane z = 0 (sg.rs sg_upper_fraction): for an
// axis above the plane, the mass within 1 - t <= 1 - |xi_xy| of the axis in closed form
// (F(w) = expm1(-lambda w) / expm1(-2 lambda)), the mass between t = +-|xi_xy| by the midpoint
// rule over UPPER_FRACTION_NODES equal slices, each slice's circle cut by the plane; below the
// plane one minus the mirror's share; 1 or 0 where the plane lies more than 20 widths away.
fn sg_upper_fraction_f32(axis_z: f32, lambda: f32) -> f32 {
    let z = clamp(axis_z, -1.0, 1.0);
    let s = abs(z);
    let c = sqrt(max(1.0 - s * s, 0.0));
    let gap = s * s / (1.0 + c);
    var upper = 1.0;
    if (!(lambda * gap > 20.0)) {
        let total = expm1_f32(-2.0 * lambda);
        var top = 0.5 * gap;
        var bottom = 0.5 * (1.0 + c);
        if (lambda > 0.0) {
            top = expm1_f32(-lambda * gap) / total;
            bottom = expm1_f32(-lambda * (1.0 + c)) / total;
        }
        var between = 0.0;
        for (var i = 0u; i < UPPER_FRACTION_NODES; i++) {
            let u = top + (bottom - top) * (f32(i) + 0.5) / f32(UPPER_FRACTION_NODES);
            var w = clamp(2.0 * u, 0.0, 2.0);
            if (lambda > 0.0) {
                w = clamp(-ln_1p_f32(u * total) / lambda, 0.0, 2.0);
            }
            let t = 1.0 - w;
            let r = sqrt(max(w * (2.0 - w), 0.0));
            between += acos(clamp(-t * s / max(r * c, 1.17549435e-38), -1.0, 1.0)) / PI;
        }
        upper = top + (bottom - top) * between / f32(UPPER_FRACTION_NODES);
    }
    return select(1.0 - upper, upper, z >= 0.0);
}
