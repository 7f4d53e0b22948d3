// Spherical Gaussian helpers for the GPU. Twins of precompute/src/special.rs (expm1_f32,
// ln_1p_f32), precompute/src/sg.rs (sg_mass_f32, sg_azimuthal_average_f32,
// sg_upper_fraction_f32, sg_upper_moment, sg_mean_resultant) and
// precompute/src/shading/multiple.rs (sg_above_horizon, vmf_sharpness): keep them in sync; compared on the GPU by renderer/tests/gpu_parity.rs.
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

// The circles of directions about an SG's axis (xi_z = s >= 0, |xi_xy| = c, gap = 1 - c) that
// the plane z = 0 cuts (sg.rs circles_cut_by_the_plane): vec3(top, bottom, expm1(-2 lambda)),
// the shares of the mass within 1 - t <= gap and <= 1 + c of the axis.
fn cut_circle_shares(lambda: f32, c: f32, gap: f32) -> vec3<f32> {
    let total = expm1_f32(-2.0 * lambda);
    if (lambda > 0.0) {
        return vec3<f32>(expm1_f32(-lambda * gap) / total, expm1_f32(-lambda * (1.0 + c)) / total, total);
    }
    return vec3<f32>(0.5 * gap, 0.5 * (1.0 + c), total);
}

// The middle circle of slice i of the UPPER_FRACTION_NODES equal slices of the mass between
// `shares` (cut_circle_shares) as vec3(t, r, alpha): t = w.xi, r = sqrt(1 - t^2) and the
// half-angle alpha of its arc above the plane.
fn cut_circle(i: u32, shares: vec3<f32>, lambda: f32, s: f32, c: f32) -> vec3<f32> {
    let u = shares.x + (shares.y - shares.x) * (f32(i) + 0.5) / f32(UPPER_FRACTION_NODES);
    var w = clamp(2.0 * u, 0.0, 2.0);
    if (lambda > 0.0) {
        w = clamp(-ln_1p_f32(u * shares.z) / lambda, 0.0, 2.0);
    }
    let t = 1.0 - w;
    let r = sqrt(max(w * (2.0 - w), 0.0));
    return vec3<f32>(t, r, acos(clamp(-t * s / max(r * c, 1.17549435e-38), -1.0, 1.0)));
}

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
        let shares = cut_circle_shares(lambda, c, gap);
        var between = 0.0;
        for (var i = 0u; i < UPPER_FRACTION_NODES; i++) {
            between += cut_circle(i, shares, lambda, s, c).z / PI;
        }
        upper = shares.x + (shares.y - shares.x) * between / f32(UPPER_FRACTION_NODES);
    }
    return select(1.0 - upper, upper, z >= 0.0);
}

// The mean resultant length of a normalized SG, coth(lambda) - 1/lambda (sg.rs
// sg_mean_resultant), by its series below lambda = 1e-2 (where f32 cancels).
fn sg_mean_resultant_f32(lambda: f32) -> f32 {
    if (lambda < 1e-2) {
        return lambda / 3.0 - lambda * lambda * lambda / 45.0;
    }
    return 1.0 + 2.0 / expm1_f32(2.0 * lambda) - 1.0 / lambda;
}

// A normalized SG's power above the plane z = 0 as vec4(first moment, share) (sg.rs
// sg_upper_moment): by circles of directions about the axis, the arc of each above the plane
// (its mean over the circle (alpha t xi + sin(alpha) r u) / pi), the circles wholly above in
// closed form (the truncated exponential's mean), the rest in UPPER_FRACTION_NODES equal
// slices; an axis below the plane takes the whole SG's moment less its mirror's part above.
fn sg_upper_moment_f32(axis_in: vec3<f32>, lambda: f32) -> vec4<f32> {
    let below = axis_in.z < 0.0;
    let axis = vec3<f32>(axis_in.xy, abs(axis_in.z));
    let s = min(axis.z, 1.0);
    let c = sqrt(max(1.0 - s * s, 0.0));
    let gap = s * s / (1.0 + c);
    var share = 1.0;
    var moment = sg_mean_resultant_f32(lambda) * axis;
    if (!(lambda * gap > 20.0)) {
        let shares = cut_circle_shares(lambda, c, gap);
        let top = shares.x;
        // 1 - E[1 - t] over the circles wholly above the plane.
        let x = lambda * gap;
        var mean_w = gap * (0.5 - x / 12.0);
        if (x >= 1e-2) {
            mean_w = 1.0 / lambda - gap / expm1_f32(x);
        }
        if (c == 0.0) {
            share = top;
            moment = top * (1.0 - mean_w) * axis;
        } else {
            let u = (vec3<f32>(0.0, 0.0, 1.0) - s * axis) / c;
            var arcs = 0.0;
            var sum = vec3<f32>(0.0);
            for (var i = 0u; i < UPPER_FRACTION_NODES; i++) {
                let circle = cut_circle(i, shares, lambda, s, c);
                arcs += circle.z / PI;
                sum += (circle.z * circle.x * axis + sin(circle.z) * circle.y * u) / PI;
            }
            let slice = (shares.y - top) / f32(UPPER_FRACTION_NODES);
            share = top + slice * arcs;
            moment = top * (1.0 - mean_w) * axis + slice * sum;
        }
    }
    if (below) {
        let whole = sg_mean_resultant_f32(lambda) * axis_in;
        return vec4<f32>(whole - vec3<f32>(moment.xy, -moment.z), 1.0 - share);
    }
    return vec4<f32>(moment, share);
}

// A'(lambda) = 1/lambda^2 - 1/sinh^2(lambda) (shading::multiple::sg_mean_resultant_slope), by
// its series below lambda = 0.05.
fn sg_mean_resultant_slope_f32(lambda: f32) -> f32 {
    if (lambda < 0.05) {
        let l2 = lambda * lambda;
        return 1.0 / 3.0 - l2 / 15.0 + 2.0 * l2 * l2 / 189.0;
    }
    let e = expm1_f32(-2.0 * lambda);
    return 1.0 / (lambda * lambda) - 4.0 * exp(-2.0 * lambda) / (e * e);
}

// The von Mises-Fisher sharpness of mean resultant length r (shading::multiple::vmf_sharpness):
// Banerjee et al.'s r (3 - r^2) / (1 - r^2), then below VMF_NEWTON_BELOW three Newton steps on
// A(lambda) = r.
fn vmf_sharpness_f32(r_in: f32) -> f32 {
    let r = clamp(r_in, 1e-9, 1.0 - 1e-7);
    var lambda = r * (3.0 - r * r) / (1.0 - r * r);
    if (lambda < VMF_NEWTON_BELOW) {
        for (var i = 0; i < 3; i++) {
            lambda = max(lambda + (r - sg_mean_resultant_f32(lambda)) / sg_mean_resultant_slope_f32(lambda), 1e-9);
        }
    }
    return lambda;
}

// The SG standing for an SG light's part above the horizon, as vec4(axis, sharpness)
// (shading::multiple::sg_above_horizon): the mean direction of that part, and the von
// Mises-Fisher sharpness of its mean resultant length.
// Below ABOVE_HORIZON_SHARES.x of its power above the horizon a light keeps its own SG, and up
// to ABOVE_HORIZON_SHARES.y it moves to the one above by a smoothstep in the share.
fn sg_above_horizon_f32(axis: vec3<f32>, lambda: f32) -> vec4<f32> {
    let upper = sg_upper_moment_f32(axis, lambda);
    let x = clamp((upper.w - ABOVE_HORIZON_SHARES.x) / (ABOVE_HORIZON_SHARES.y - ABOVE_HORIZON_SHARES.x), 0.0, 1.0);
    let weight = x * x * (3.0 - 2.0 * x);
    let length = length(upper.xyz);
    if (weight == 0.0 || length < 1e-12) {
        return vec4<f32>(axis, lambda);
    }
    let above = upper.xyz / length;
    let above_sharpness = vmf_sharpness_f32(length / upper.w);
    return vec4<f32>(normalize(axis + weight * (above - axis)), lambda + weight * (above_sharpness - lambda));
}
