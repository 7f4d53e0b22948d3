// Real spherical harmonics for the GPU. Twins of precompute/src/sh.rs (sh_eval, ShRotation,
// ivanic_band): keep them in sync; compared on the GPU with the f64 originals by
// renderer/tests/gpu_sh_parity.rs. Self-contained (needs no other module); every name here
// starts with sh_ / SH_.
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
// Band matrices are kept at a fixed row stride 2 SH_MAX_ORDER + 1: entry (m, n) of band l at
// (m + l) SH_BAND_STRIDE + (n + l).
const SH_BAND_STRIDE: i32 = 13;
const SH_BAND_SIZE: u32 = 169u;
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

// Entry (i, j) of the band-1 matrix, i, j in -1..=1 (row-major 3 x 3).
fn sh_band1_at(band1: ptr<function, array<f32, 9>>, i: i32, j: i32) -> f32 {
    return (*band1)[u32((i + 1) * 3 + j + 1)];
}

// Entry (m, n) of the band-l matrix held at stride SH_BAND_STRIDE.
fn sh_band_at(band: ptr<function, array<f32, 169>>, l: i32, m: i32, n: i32) -> f32 {
    return (*band)[u32((m + l) * SH_BAND_STRIDE + n + l)];
}

// Ivanic's P^l_{i,a,b} (the closure `p` of ivanic_band): i in -1..=1, a in -(l-1)..=(l-1),
// b in -l..=l; `prev` holds band l - 1.
fn sh_ivanic_p(
    l: i32,
    i: i32,
    a: i32,
    b: i32,
    band1: ptr<function, array<f32, 9>>,
    prev: ptr<function, array<f32, 169>>,
) -> f32 {
    let lp = l - 1;
    if (b == l) {
        return sh_band1_at(band1, i, 1) * sh_band_at(prev, lp, a, lp)
            - sh_band1_at(band1, i, -1) * sh_band_at(prev, lp, a, -lp);
    } else if (b == -l) {
        return sh_band1_at(band1, i, 1) * sh_band_at(prev, lp, a, -lp)
            + sh_band1_at(band1, i, -1) * sh_band_at(prev, lp, a, lp);
    }
    return sh_band1_at(band1, i, 0) * sh_band_at(prev, lp, a, b);
}

// Band l >= 2 into `band` from band 1 and band l - 1 (Ivanic-Ruedenberg 1996, Tables 1 and 2
// with the 1998 errata): twin of ivanic_band. The guards on u, v, w are ivanic_band's
// `!= 0.0` tests written as the integer conditions they amount to (u = 0 iff |m| = l, w = 0
// iff m = 0 or |m| >= l - 1, v never 0 for l >= 2), so P is only read inside its range.
fn sh_ivanic_band(
    l: i32,
    band1: ptr<function, array<f32, 9>>,
    prev: ptr<function, array<f32, 169>>,
    band: ptr<function, array<f32, 169>>,
) {
    let lf = f32(l);
    for (var m = -l; m <= l; m++) {
        let am = abs(m);
        let d = select(0.0, 1.0, m == 0);
        for (var n = -l; n <= l; n++) {
            let nf = f32(n);
            var denom = (lf + nf) * (lf - nf);
            if (abs(n) == l) {
                denom = 2.0 * lf * (2.0 * lf - 1.0);
            }
            var value = 0.0;
            if (am < l) {
                let u = sqrt(f32((l + m) * (l - m)) / denom);
                value += u * sh_ivanic_p(l, 0, m, n, band1, prev);
            }
            let v = 0.5 * sqrt((1.0 + d) * f32((l + am - 1) * (l + am)) / denom) * (1.0 - 2.0 * d);
            var big_v: f32;
            if (m == 0) {
                big_v = sh_ivanic_p(l, 1, 1, n, band1, prev) + sh_ivanic_p(l, -1, -1, n, band1, prev);
            } else if (m == 1) {
                big_v = sh_ivanic_p(l, 1, 0, n, band1, prev) * SH_SQRT_2;
            } else if (m > 1) {
                big_v = sh_ivanic_p(l, 1, m - 1, n, band1, prev) - sh_ivanic_p(l, -1, -m + 1, n, band1, prev);
            } else if (m == -1) {
                big_v = sh_ivanic_p(l, -1, 0, n, band1, prev) * SH_SQRT_2;
            } else {
                big_v = sh_ivanic_p(l, 1, m + 1, n, band1, prev) + sh_ivanic_p(l, -1, -m - 1, n, band1, prev);
            }
            value += v * big_v;
            if (m != 0 && am < l - 1) {
                let w = -0.5 * sqrt(f32((l - am - 1) * (l - am)) / denom);
                var big_w: f32;
                if (m > 0) {
                    big_w = sh_ivanic_p(l, 1, m + 1, n, band1, prev) + sh_ivanic_p(l, -1, -m - 1, n, band1, prev);
                } else {
                    big_w = sh_ivanic_p(l, 1, m - 1, n, band1, prev) - sh_ivanic_p(l, -1, -m + 1, n, band1, prev);
                }
                value += w * big_w;
            }
            (*band)[u32((m + l) * SH_BAND_STRIDE + n + l)] = value;
        }
    }
}

// coeffs[l^2 .. (l + 1)^2] = band * coeffs[l^2 .. (l + 1)^2] (ShRotation::apply for one band),
// for three functions at once (one per vector component).
fn sh_apply_band(l: i32, band: ptr<function, array<f32, 169>>, coeffs: ptr<function, array<vec3<f32>, 49>>) {
    let width = 2 * l + 1;
    let start = u32(l * l);
    var input: array<vec3<f32>, 13>;
    for (var k = 0; k < width; k++) {
        input[k] = (*coeffs)[start + u32(k)];
    }
    for (var row = 0; row < width; row++) {
        var sum = vec3<f32>(0.0);
        for (var k = 0; k < width; k++) {
            sum += (*band)[u32(row * SH_BAND_STRIDE + k)] * input[k];
        }
        (*coeffs)[start + u32(row)] = sum;
    }
}

// Rotates three coefficient vectors (one per component, e.g. RGB) in place by the rotation `r`
// (the R of ShRotation::new, column-major: see the top of this file), building each band's
// matrix once by the same Ivanic-Ruedenberg recurrence as ShRotation::new. Band 0 is left as it
// is. Cost: about 10^4 flops for the bands and 1.6 KB of private memory per call at order 6
// (for many directions under one rotation, rotate once, not per invocation).
fn sh_rotate_rgb_f32(order: u32, r: mat3x3<f32>, coeffs: ptr<function, array<vec3<f32>, 49>>) {
    let top = i32(min(order, SH_MAX_ORDER));
    if (top == 0) {
        return;
    }
    // Band 1 acts on (y, z, x): R with rows and columns permuted, entry (m, n) = R[a(m)][a(n)]
    // for a(-1, 0, 1) = (y, z, x); r[c][k] is R's row k, column c.
    var band1 = array<f32, 9>(
        r[1][1], r[2][1], r[0][1],
        r[1][2], r[2][2], r[0][2],
        r[1][0], r[2][0], r[0][0],
    );
    var prev: array<f32, 169>;
    var band: array<f32, 169>;
    for (var i = 0; i < 3; i++) {
        for (var j = 0; j < 3; j++) {
            band[u32(i * SH_BAND_STRIDE + j)] = band1[u32(i * 3 + j)];
        }
    }
    sh_apply_band(1, &band, coeffs);
    for (var l = 2; l <= top; l++) {
        prev = band;
        sh_ivanic_band(l, &band1, &prev, &band);
        sh_apply_band(l, &band, coeffs);
    }
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
