// Real spherical harmonics for the GPU. Twins of precompute/src/sh.rs (sh_eval,
// ShEulerRotation, zyz_angles): keep them in sync; compared on the GPU with the f64 originals
// (ShRotation's band matrices for rotations) by renderer/tests/gpu_sh_parity.rs. The quarter
// turns are generated from sh.rs; every name here starts with sh_ / SH_.
#import shared/sh_quarter_turn.wgsl
//
// Conventions, as in sh.rs:
// - Orthonormal real SH without the Condon-Shortley phase, coefficient (l, m) at
//   j = l (l + 1) + m; band 1 is sqrt(3/4pi) (y, z, x).
// - Orders 0..=SH_MAX_ORDER; an order-L expansion holds (L + 1)^2 coefficients in the leading
//   entries of an array<f32, SH_MAX_COUNT>. Functions read and write only those entries; a
//   larger `order` is clamped to SH_MAX_ORDER.
// - Rotations: the matrix `r` is the `R` of ShRotation::new(order, &R): rotating the
//   coefficients of f gives those of g(w) = f(R^T w) (a lobe around a moves to R a).
//   WGSL matrices are column-major like glam's: r[c] is column c of R, r[c][k] is R's entry in
//   row k, column c. A Rust DMat3 `m` is passed as mat3x3<f32>(m.x_axis, m.y_axis, m.z_axis)
//   (as f32), i.e. m.to_cols_array() in order. In a uniform or storage buffer a mat3x3<f32>
//   has 16-byte columns (48 bytes): upload glam's Mat3A, or each column padded to a vec4.

const SH_MAX_ORDER: u32 = 6u;
const SH_MAX_COUNT: u32 = 49u;
// Y_00 = 1 / sqrt(4 pi).
const SH_Y00: f32 = 0.28209479177387814;
const SH_SQRT_2: f32 = 1.4142135623730951;
const SH_4PI: f32 = 12.566370614359172;

// (order + 1)^2, the number of coefficients of an order-`order` expansion.
fn sh_count(order: u32) -> u32 {
    return (order + 1u) * (order + 1u);
}

// The `store` closure of sh_eval: writes Y_l0, or Y_l,+-m from q = N_lm P_l^m / sin^m theta.
fn sh_store_f32(out: ptr<function, array<f32, 49>>, l: u32, m: u32, q: f32, cos_m: f32, sin_m: f32) {
    let center = l * (l + 1u);
    if (m == 0u) {
        (*out)[center] = q;
    } else {
        (*out)[center + m] = SH_SQRT_2 * q * cos_m;
        (*out)[center - m] = SH_SQRT_2 * q * sin_m;
    }
}

// All real SH of bands 0..=order at the unit vector `dir` into out[0 .. (order + 1)^2], by the
// recurrences of sh_eval (normalized associated Legendre functions, sin^m theta folded into
// Re/Im (x + i y)^m: no atan2, finite and smooth at the poles).
fn sh_eval_f32(order: u32, dir: vec3<f32>, out: ptr<function, array<f32, 49>>) {
    let top = min(order, SH_MAX_ORDER);
    // q_mm = N_mm P_m^m / sin^m theta, starting from Y_00.
    var q_mm = SH_Y00;
    // (cos_m, sin_m) = Re, Im of (x + i y)^m.
    var cos_m = 1.0;
    var sin_m = 0.0;
    for (var m = 0u; m <= top; m++) {
        if (m > 0u) {
            let mf = f32(m);
            q_mm *= sqrt((2.0 * mf + 1.0) / (2.0 * mf));
            let c = dir.x * cos_m - dir.y * sin_m;
            sin_m = dir.x * sin_m + dir.y * cos_m;
            cos_m = c;
        }
        sh_store_f32(out, m, m, q_mm, cos_m, sin_m);
        if (m == top) {
            break;
        }
        var q_prev = q_mm;
        var q = sqrt(2.0 * f32(m) + 3.0) * dir.z * q_mm;
        sh_store_f32(out, m + 1u, m, q, cos_m, sin_m);
        let mf2 = f32(m * m);
        for (var l = m + 2u; l <= top; l++) {
            let lf = f32(l);
            let a = sqrt((4.0 * lf * lf - 1.0) / (lf * lf - mf2));
            let b = sqrt(((lf - 1.0) * (lf - 1.0) - mf2) / (4.0 * (lf - 1.0) * (lf - 1.0) - 1.0));
            let q_next = a * (dir.z * q - b * q_prev);
            q_prev = q;
            q = q_next;
            sh_store_f32(out, l, m, q, cos_m, sin_m);
        }
    }
}

// The ZYZ Euler turns of the rotation r (r = Rz(alpha) Ry(beta) Rz(gamma), beta in [0, pi])
// as (cos, sin) pairs: columns alpha, beta, gamma of the result. Twin of zyz_turns in sh.rs:
// the quaternion by Shepperd's branches (glam's from_mat3; mCR is r[C][R]); (w, z) normalized
// is the turn by (alpha + gamma) / 2, (y, -x) normalized the turn by (alpha - gamma) / 2 (a
// pair shorter than 1e-15 counts as no turn), alpha and gamma their sum and difference;
// cos beta = 1 - 2 (x^2 + y^2), sin beta = 2 |(x, y)| |(z, w)|. No transcendental function:
// as accurate at gimbal lock as anywhere.
fn sh_zyz_turns(r: mat3x3<f32>) -> mat3x2<f32> {
    var q: vec4<f32>;
    if (r[2][2] <= 0.0) {
        let dif10 = r[1][1] - r[0][0];
        let omm22 = 1.0 - r[2][2];
        if (dif10 <= 0.0) {
            let four_xsq = omm22 - dif10;
            let inv = 0.5 / sqrt(four_xsq);
            q = vec4<f32>(four_xsq * inv, (r[0][1] + r[1][0]) * inv, (r[0][2] + r[2][0]) * inv, (r[1][2] - r[2][1]) * inv);
        } else {
            let four_ysq = omm22 + dif10;
            let inv = 0.5 / sqrt(four_ysq);
            q = vec4<f32>((r[0][1] + r[1][0]) * inv, four_ysq * inv, (r[1][2] + r[2][1]) * inv, (r[2][0] - r[0][2]) * inv);
        }
    } else {
        let sum10 = r[1][1] + r[0][0];
        let opm22 = 1.0 + r[2][2];
        if (sum10 <= 0.0) {
            let four_zsq = opm22 - sum10;
            let inv = 0.5 / sqrt(four_zsq);
            q = vec4<f32>((r[0][2] + r[2][0]) * inv, (r[1][2] + r[2][1]) * inv, four_zsq * inv, (r[0][1] - r[1][0]) * inv);
        } else {
            let four_wsq = opm22 + sum10;
            let inv = 0.5 / sqrt(four_wsq);
            q = vec4<f32>((r[1][2] - r[2][1]) * inv, (r[2][0] - r[0][2]) * inv, (r[0][1] - r[1][0]) * inv, four_wsq * inv);
        }
    }
    let half_sum = sh_unit_turn(q.w, q.z);
    let half_difference = sh_unit_turn(q.y, -q.x);
    let alpha = vec2<f32>(
        half_sum.x * half_difference.x - half_sum.y * half_difference.y,
        half_sum.y * half_difference.x + half_sum.x * half_difference.y,
    );
    let gamma = vec2<f32>(
        half_sum.x * half_difference.x + half_sum.y * half_difference.y,
        half_sum.y * half_difference.x - half_sum.x * half_difference.y,
    );
    let beta = vec2<f32>(1.0 - 2.0 * dot(q.xy, q.xy), 2.0 * length(q.xy) * length(q.zw));
    return mat3x2<f32>(alpha, beta, gamma);
}

// (c, s) normalized, or (1, 0) where it is shorter than 1e-15.
fn sh_unit_turn(c: f32, s: f32) -> vec2<f32> {
    let length = length(vec2<f32>(c, s));
    if (length > 1e-15) {
        return vec2<f32>(c, s) / length;
    }
    return vec2<f32>(1.0, 0.0);
}

// Turns three coefficient vectors in place about z by the angle with (cos, sin) = `turn`:
// (c_lm, c_l-m) <- (c_lm cos m a - c_l-m sin m a, c_lm sin m a + c_l-m cos m a) for m > 0
// (rotate_z_in_place in sh.rs).
fn sh_turn_z_rgb(top: u32, turn: vec2<f32>, c: ptr<function, array<vec3<f32>, 49>>) {
    var turn_m = turn;
    for (var m = 1u; m <= top; m++) {
        for (var l = m; l <= top; l++) {
            let center = l * (l + 1u);
            let p = (*c)[center + m];
            let q = (*c)[center - m];
            (*c)[center + m] = p * turn_m.x - q * turn_m.y;
            (*c)[center - m] = p * turn_m.y + q * turn_m.x;
        }
        turn_m = vec2<f32>(turn_m.x * turn.x - turn_m.y * turn.y, turn_m.y * turn.x + turn_m.x * turn.y);
    }
}

// Rotates three coefficient vectors (one per component, e.g. RGB) in place by the rotation `r`
// (the R of ShRotation::new, column-major: see the top of this file), as ShEulerRotation does:
// turns about z by gamma, the quarter turn about x, beta about z, the quarter turn back, alpha
// about z (R = Rz(alpha) Rx(-pi/2) Rz(beta) Rx(pi/2) Rz(gamma)).
// Cost at order 6: about 1,400 multiply-adds per component, no per-rotation tables.
fn sh_rotate_rgb_f32(order: u32, r: mat3x3<f32>, coeffs: ptr<function, array<vec3<f32>, 49>>) {
    let top = min(order, SH_MAX_ORDER);
    if (top == 0u) {
        return;
    }
    let turns = sh_zyz_turns(r);
    sh_turn_z_rgb(top, turns[2], coeffs);
    sh_quarter_turn_x_rgb(top, coeffs);
    sh_turn_z_rgb(top, turns[1], coeffs);
    sh_quarter_turn_x_inverse_rgb(top, coeffs);
    sh_turn_z_rgb(top, turns[0], coeffs);
}

// Rotates one coefficient vector in place (sh_rotate_rgb_f32 on its first component).
fn sh_rotate_f32(order: u32, r: mat3x3<f32>, coeffs: ptr<function, array<f32, 49>>) {
    let count = sh_count(min(order, SH_MAX_ORDER));
    var wide: array<vec3<f32>, 49>;
    for (var j = 0u; j < count; j++) {
        wide[j] = vec3<f32>((*coeffs)[j], 0.0, 0.0);
    }
    sh_rotate_rgb_f32(order, r, &wide);
    for (var j = 0u; j < count; j++) {
        (*coeffs)[j] = wide[j].x;
    }
}

// Coefficients of the zonal function with band coefficients zonal[l] (the (l, 0) coefficients
// of a function symmetric about +z) turned so that its axis is the unit vector `axis`:
// c_lm = sqrt(4 pi / (2l + 1)) zonal[l] Y_lm(axis), into out[0 .. (order + 1)^2]. Equals
// rotating the zonal coefficients with any R taking +z to `axis`, without building bands.
fn sh_zonal_rotated_f32(
    order: u32,
    axis: vec3<f32>,
    zonal: ptr<function, array<f32, 7>>,
    out: ptr<function, array<f32, 49>>,
) {
    let top = min(order, SH_MAX_ORDER);
    sh_eval_f32(top, axis, out);
    for (var l = 0u; l <= top; l++) {
        let scale = sqrt(SH_4PI / f32(2u * l + 1u)) * (*zonal)[l];
        let center = l * (l + 1u);
        for (var j = center - l; j <= center + l; j++) {
            (*out)[j] *= scale;
        }
    }
}
