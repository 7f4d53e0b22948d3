//! Real spherical harmonics: evaluation, projection by quadrature, rotation.
//!
//! How it works:
//! - Basis: orthonormal real SH **without** the Condon–Shortley phase, indexed `j = l(l+1) + m`
//!   (so band 1 is `sqrt(3/4pi) (y, z, x)` for `m = -1, 0, 1`):
//!   `Y_l0 = N_l0 P_l^0(z)`, `Y_lm = sqrt(2) N_lm P_l^m(z) cos(m phi)` and
//!   `Y_l,-m = sqrt(2) N_lm P_l^m(z) sin(m phi)` for `m > 0`, with `P_l^m >= 0` near the poles.
//!   An order-`L` expansion holds bands `0..=L`, [`sh_count`]`(L) = (L+1)^2` coefficients.
//! - [`sh_eval`] runs the standard recurrences for the *normalized* associated Legendre
//!   functions (no factorials, so no overflow at any order), with the `sin^m theta` factor
//!   folded into `Re/Im (x + i y)^m`, which needs no `atan2` and is smooth at the poles.
//! - [`sh_project`] integrates with Gauss–Legendre nodes in `cos theta` (computed here by
//!   Newton iteration on `P_n`) times a uniform rule in `phi`; it is exact for band-limited
//!   integrands up to the degree stated on the function.
//! - [`ShRotation`] builds each band's `(2l+1) x (2l+1)` matrix from the 3x3 rotation with the
//!   Ivanic–Ruedenberg recurrences (J. Phys. Chem. 1996, with the 1998 errata; the `V` term for
//!   `m < 0` as corrected there). Convention: applying the rotation built from `R` to the
//!   coefficients of `f` gives the coefficients of `g(w) = f(R^T w)`, i.e. the function is
//!   carried along by `R` (a lobe around `a` moves to `R a`).

use glam::{DMat3, DVec3};

use crate::quadrature::gauss_legendre;
use std::f64::consts::PI;

/// Number of coefficients of an order-`order` expansion: `(order + 1)^2`.
#[must_use]
pub const fn sh_count(order: usize) -> usize {
    (order + 1) * (order + 1)
}

/// Index of coefficient `(l, m)`, `-l <= m <= l`: `l (l + 1) + m`.
#[must_use]
pub const fn sh_index(l: usize, m: isize) -> usize {
    ((l * (l + 1)) as isize + m) as usize
}

/// Evaluates all real SH of bands `0..=order` at the unit vector `dir` into
/// `out[..sh_count(order)]`.
///
/// # Panics
/// If `out` is shorter than `sh_count(order)`.
pub fn sh_eval(order: usize, dir: DVec3, out: &mut [f64]) {
    assert!(out.len() >= sh_count(order), "sh_eval: need {} outputs, got {}", sh_count(order), out.len());
    debug_assert!((dir.length_squared() - 1.0).abs() < 1e-6, "sh_eval: dir {dir} is not unit length");
    let (x, y, z) = (dir.x, dir.y, dir.z);
    // q_mm = N_mm P_m^m / sin^m theta, starting from Y_00 = 1/sqrt(4 pi).
    let mut q_mm = 0.5 / PI.sqrt();
    // (cos_m, sin_m) = Re, Im of (x + i y)^m = sin^m theta (cos m phi, sin m phi).
    let (mut cos_m, mut sin_m) = (1.0, 0.0);
    for m in 0..=order {
        if m > 0 {
            let mf = m as f64;
            q_mm *= ((2.0 * mf + 1.0) / (2.0 * mf)).sqrt();
            (cos_m, sin_m) = (x * cos_m - y * sin_m, x * sin_m + y * cos_m);
        }
        let mut store = |l: usize, q: f64| {
            let center = l * (l + 1);
            if m == 0 {
                out[center] = q;
            } else {
                out[center + m] = std::f64::consts::SQRT_2 * q * cos_m;
                out[center - m] = std::f64::consts::SQRT_2 * q * sin_m;
            }
        };
        store(m, q_mm);
        if m == order {
            break;
        }
        let mut q_prev = q_mm;
        let mut q = (2.0 * m as f64 + 3.0).sqrt() * z * q_mm;
        store(m + 1, q);
        let mf2 = (m * m) as f64;
        for l in m + 2..=order {
            let lf = l as f64;
            let a = ((4.0 * lf * lf - 1.0) / (lf * lf - mf2)).sqrt();
            let b = (((lf - 1.0) * (lf - 1.0) - mf2) / (4.0 * (lf - 1.0) * (lf - 1.0) - 1.0)).sqrt();
            let q_next = a * (z * q - b * q_prev);
            q_prev = q;
            q = q_next;
            store(l, q);
        }
    }
}

/// `sum_j coeffs[j] Y_j(dir)` over the `sh_count(order)` leading coefficients.
///
/// # Panics
/// If `coeffs` is shorter than `sh_count(order)`.
#[must_use]
pub fn sh_eval_sum(order: usize, coeffs: &[f64], dir: DVec3) -> f64 {
    let n = sh_count(order);
    assert!(coeffs.len() >= n, "sh_eval_sum: need {n} coefficients, got {}", coeffs.len());
    let mut basis = vec![0.0; n];
    sh_eval(order, dir, &mut basis);
    basis.iter().zip(coeffs).map(|(y, c)| y * c).sum()
}

/// Projects `f` onto the real SH of bands `0..=order` with a product rule: `quadrature_n`
/// Gauss–Legendre nodes in `cos theta` times `2 quadrature_n` uniform nodes in `phi`.
/// Exact when `f` is band-limited to band `B` and `B + order <= 2 quadrature_n - 1`; for smooth
/// `f` the error falls off with the decay of `f`'s spectrum above that band.
///
/// # Panics
/// If `quadrature_n` is 0.
#[must_use]
pub fn sh_project(order: usize, quadrature_n: usize, f: impl Fn(DVec3) -> f64) -> Vec<f64> {
    let n = sh_count(order);
    let (nodes, weights) = gauss_legendre(quadrature_n);
    let n_phi = 2 * quadrature_n;
    let phi_weight = 2.0 * PI / n_phi as f64;
    let mut coeffs = vec![0.0; n];
    let mut basis = vec![0.0; n];
    for (&z, &w) in nodes.iter().zip(&weights) {
        let s = (1.0 - z * z).max(0.0).sqrt();
        for j in 0..n_phi {
            let phi = 2.0 * PI * (j as f64 + 0.5) / n_phi as f64;
            let dir = DVec3::new(s * phi.cos(), s * phi.sin(), z);
            sh_eval(order, dir, &mut basis);
            let weighted = f(dir) * w * phi_weight;
            for (c, y) in coeffs.iter_mut().zip(&basis) {
                *c += weighted * y;
            }
        }
    }
    coeffs
}

/// Rotation of real SH coefficients, one `(2l+1) x (2l+1)` matrix per band.
///
/// Built from a rotation matrix `R`; [`ShRotation::apply`] maps the coefficients of `f` to
/// those of `g(w) = f(R^T w)`. Rotations compose like matrices: the rotation of `R1 R2` is the
/// product of the band matrices of `R1` and `R2`.
#[derive(Debug, Clone, PartialEq)]
pub struct ShRotation {
    order: usize,
    /// `bands[l]` is row-major, entry `(m, n)` at `(m + l) (2l + 1) + (n + l)`.
    bands: Vec<Vec<f64>>,
}

impl ShRotation {
    /// Builds the band matrices `0..=order` for the rotation `rotation` (must be orthonormal
    /// with determinant +1).
    ///
    /// # Panics
    /// If `rotation` is not a rotation (to 1e-6).
    #[must_use]
    pub fn new(order: usize, rotation: &DMat3) -> Self {
        let should_be_identity = *rotation * rotation.transpose();
        assert!(
            should_be_identity.abs_diff_eq(DMat3::IDENTITY, 1e-6)
                && (rotation.determinant() - 1.0).abs() < 1e-6,
            "ShRotation::new: {rotation} is not a rotation matrix"
        );
        let mut bands = vec![vec![1.0]];
        if order >= 1 {
            // Band 1 acts on (y, z, x): the rotation matrix itself, rows and columns permuted.
            let axis_of = |m: isize| [1_usize, 2, 0][(m + 1) as usize];
            let mut band1 = vec![0.0; 9];
            for m in -1..=1_isize {
                for n in -1..=1_isize {
                    band1[((m + 1) * 3 + n + 1) as usize] = rotation.col(axis_of(n))[axis_of(m)];
                }
            }
            bands.push(band1);
        }
        for l in 2..=order {
            let band = ivanic_band(l, &bands[1], &bands[l - 1]);
            bands.push(band);
        }
        Self { order, bands }
    }

    /// The highest band held.
    #[must_use]
    pub fn order(&self) -> usize {
        self.order
    }

    /// Band `l`'s matrix, row-major, `(2l+1)^2` entries; entry `(m, n)` (each in `-l..=l`) at
    /// `(m + l)(2l + 1) + (n + l)`.
    #[must_use]
    pub fn band(&self, l: usize) -> &[f64] {
        &self.bands[l]
    }

    /// Entry `(m, n)` of band `l`'s matrix.
    #[must_use]
    pub fn entry(&self, l: usize, m: isize, n: isize) -> f64 {
        centered(&self.bands[l], l, m, n)
    }

    /// `coeffs_out = rotation(coeffs_in)` over the `sh_count(order)` leading coefficients.
    ///
    /// # Panics
    /// If either slice is shorter than `sh_count(self.order())`.
    pub fn apply(&self, coeffs_in: &[f64], coeffs_out: &mut [f64]) {
        let n = sh_count(self.order);
        assert!(coeffs_in.len() >= n && coeffs_out.len() >= n, "ShRotation::apply: need {n} coefficients");
        for (l, band) in self.bands.iter().enumerate() {
            let width = 2 * l + 1;
            let start = l * l;
            let input = &coeffs_in[start..start + width];
            for (row, out) in band.chunks_exact(width).zip(&mut coeffs_out[start..start + width]) {
                *out = row.iter().zip(input).map(|(r, c)| r * c).sum();
            }
        }
    }
}

/// The highest order [`ShEulerRotation`] holds quarter-turn tables for (the GPU's
/// `SH_MAX_ORDER`).
pub const EULER_MAX_ORDER: usize = 6;

/// Rotation of real SH coefficients as three turns about z and two fixed quarter turns about x
/// (`R = Rz(alpha) Ry(beta) Rz(gamma)`, `Ry(beta) = Rx(-pi/2) Rz(beta) Rx(pi/2)`): the CPU
/// twin of the GPU's `sh_rotate_rgb_f32`, and equal to [`ShRotation`] of the same matrix.
///
/// A turn about z mixes only the pairs `(l, m), (l, -m)` (2 multiplies each); the quarter turn
/// about x is one constant band matrix per band, the same for every rotation, so nothing is
/// built per rotation but three turns ([`zyz_turns`]). They come from the rotation's
/// quaternion (Shepperd's branches), where `(alpha + gamma) / 2` is the angle of `(w, z)` and
/// `(alpha - gamma) / 2` that of `(y, -x)`: each half-angle is only ever weighted by the
/// length of the pair it comes from, so the turns are as accurate as the quaternion even at
/// gimbal lock (`beta` near 0 or pi), where the sum or the difference is free.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShEulerRotation {
    order: usize,
    /// `(cos, sin)` of `alpha`, `beta`, `gamma`.
    turns: [(f64, f64); 3],
}

impl ShEulerRotation {
    /// The rotation `rotation` (orthonormal, determinant +1) for bands `0..=order`.
    ///
    /// # Panics
    /// If `order > EULER_MAX_ORDER` or `rotation` is not a rotation (to 1e-6).
    #[must_use]
    pub fn new(order: usize, rotation: &DMat3) -> Self {
        assert!(order <= EULER_MAX_ORDER, "ShEulerRotation::new: order {order} above {EULER_MAX_ORDER}");
        let should_be_identity = *rotation * rotation.transpose();
        assert!(
            should_be_identity.abs_diff_eq(DMat3::IDENTITY, 1e-6)
                && (rotation.determinant() - 1.0).abs() < 1e-6,
            "ShEulerRotation::new: {rotation} is not a rotation matrix"
        );
        Self { order, turns: zyz_turns(rotation) }
    }

    /// `coeffs[..sh_count(order)]` rotated in place.
    ///
    /// # Panics
    /// If `coeffs` is shorter than `sh_count(order)`.
    pub fn apply_in_place(&self, coeffs: &mut [f64]) {
        assert!(
            coeffs.len() >= sh_count(self.order),
            "ShEulerRotation: need {} coefficients",
            sh_count(self.order)
        );
        let [alpha, beta, gamma] = self.turns;
        rotate_z_in_place(self.order, gamma, coeffs);
        quarter_turn_x_in_place(self.order, false, coeffs);
        rotate_z_in_place(self.order, beta, coeffs);
        quarter_turn_x_in_place(self.order, true, coeffs);
        rotate_z_in_place(self.order, alpha, coeffs);
    }
}

/// The ZYZ Euler turns of a rotation, `R = Rz(alpha) Ry(beta) Rz(gamma)` with `beta` in
/// `[0, pi]`, as `(cos, sin)` pairs `[alpha, beta, gamma]`, through the quaternion and without
/// a transcendental function: `(cos, sin)` of `S = (alpha + gamma) / 2` is `(w, z)` normalized,
/// of `D = (alpha - gamma) / 2` is `(y, -x)` normalized, and alpha and gamma are their sum and
/// difference; `cos beta = 1 - 2 (x^2 + y^2)`, `sin beta = 2 |(x, y)| |(z, w)|`. A pair shorter
/// than 1e-15 (its half-angle is then free, or weighs nothing) counts as the angle 0. The GPU's
/// `sh_zyz_turns` is its twin, branch for branch.
#[must_use]
pub fn zyz_turns(rotation: &DMat3) -> [(f64, f64); 3] {
    // Shepperd's branches (DirectXMath's XMQuaternionRotationMatrix): the largest of |x|, |y|,
    // |z|, |w| is found first and divided by, so no branch loses precision.
    let [x, y, z, w] = glam::DQuat::from_mat3(rotation).to_array();
    let unit = |c: f64, s: f64| {
        let length = c.hypot(s);
        if length > 1e-15 { (c / length, s / length) } else { (1.0, 0.0) }
    };
    let (cos_s, sin_s) = unit(w, z);
    let (cos_d, sin_d) = unit(y, -x);
    let alpha = (cos_s * cos_d - sin_s * sin_d, sin_s * cos_d + cos_s * sin_d);
    let gamma = (cos_s * cos_d + sin_s * sin_d, sin_s * cos_d - cos_s * sin_d);
    let beta = (1.0 - 2.0 * (x * x + y * y), 2.0 * x.hypot(y) * z.hypot(w));
    [alpha, beta, gamma]
}

/// Turns the coefficients about z by the angle with `(cos, sin)` = `turn`: for `m > 0`,
/// `(c_lm, c_l-m) <- (c_lm cos m a - c_l-m sin m a, c_lm sin m a + c_l-m cos m a)`, the
/// multiples of the angle by the Chebyshev recurrence.
fn rotate_z_in_place(order: usize, turn: (f64, f64), coeffs: &mut [f64]) {
    let (cos_1, sin_1) = turn;
    let (mut cos_m, mut sin_m) = turn;
    for m in 1..=order {
        for l in m..=order {
            let (plus, minus) = (sh_index(l, m as isize), sh_index(l, -(m as isize)));
            let (p, q) = (coeffs[plus], coeffs[minus]);
            coeffs[plus] = p * cos_m - q * sin_m;
            coeffs[minus] = p * sin_m + q * cos_m;
        }
        (cos_m, sin_m) = (cos_m * cos_1 - sin_m * sin_1, sin_m * cos_1 + cos_m * sin_1);
    }
}

/// The band matrices of the quarter turn about +x, `Rx(pi/2)`, bands `0..=EULER_MAX_ORDER`,
/// with the entries that are zero in exact arithmetic (below 1e-12 after the recurrence) made 0.
fn quarter_turn_x() -> &'static ShRotation {
    static TABLE: std::sync::OnceLock<ShRotation> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut rotation = ShRotation::new(EULER_MAX_ORDER, &DMat3::from_rotation_x(0.5 * PI));
        for band in &mut rotation.bands {
            for entry in band.iter_mut().filter(|entry| entry.abs() < 1e-12) {
                *entry = 0.0;
            }
        }
        rotation
    })
}

/// Applies `Rx(pi/2)` (`inverse`: `Rx(-pi/2)`, the transposed bands) in place.
fn quarter_turn_x_in_place(order: usize, inverse: bool, coeffs: &mut [f64]) {
    let table = quarter_turn_x();
    let mut input = [0.0; 2 * EULER_MAX_ORDER + 1];
    for l in 1..=order {
        let width = 2 * l + 1;
        let start = l * l;
        input[..width].copy_from_slice(&coeffs[start..start + width]);
        let band = table.band(l);
        for (row, out) in coeffs[start..start + width].iter_mut().enumerate() {
            *out = (0..width)
                .map(|k| if inverse { band[k * width + row] } else { band[row * width + k] } * input[k])
                .sum();
        }
    }
}

/// WGSL for the GPU twin of the quarter turns: `sh_quarter_turn_x_rgb(top, coeffs, inverse)`
/// with every nonzero entry of the band matrices written out as a constant, band by band up
/// to `top` (no table reads, no loops). `shaders/shared/sh_quarter_turn.wgsl` is this text;
/// the renderer's tests check that it is current.
#[must_use]
pub fn quarter_turn_x_wgsl() -> String {
    use std::fmt::Write as _;
    let table = quarter_turn_x();
    let mut out = String::from(
        "// GENERATED by twill_precompute::sh::quarter_turn_x_wgsl: do not edit. Regenerate with\n\
         // TWILL_REGENERATE=1 cargo test -p twill-renderer generated_quarter_turn (a test fails while\n\
         // this file and the generator differ).\n\
         //\n\
         // The quarter turn about +x on real SH coefficients (rotation convention of sh.wgsl): band\n\
         // l's (2l + 1) x (2l + 1) matrix of ShRotation::new(6, Rx(pi / 2)), its nonzero entries\n\
         // written out as constants; `inverse` applies the transpose, Rx(-pi / 2). Bands 1..=top\n\
         // of three coefficient vectors (one per component) in place. Twin of\n\
         // quarter_turn_x_in_place in precompute/src/sh.rs.\n",
    );
    for (inverse, name) in [(false, "sh_quarter_turn_x_rgb"), (true, "sh_quarter_turn_x_inverse_rgb")] {
        let _ = writeln!(out, "\nfn {name}(top: u32, c: ptr<function, array<vec3<f32>, 49>>) {{");
        for l in 1..=EULER_MAX_ORDER {
            let width = 2 * l + 1;
            let start = l * l;
            let band = table.band(l);
            let _ = writeln!(out, "    if (top < {l}u) {{\n        return;\n    }}");
            let _ = writeln!(out, "    {{");
            for k in 0..width {
                let _ = writeln!(out, "        let a{k} = (*c)[{}];", start + k);
            }
            for row in 0..width {
                let terms: Vec<String> = (0..width)
                    .filter_map(|k| {
                        let entry = if inverse { band[k * width + row] } else { band[row * width + k] };
                        #[allow(clippy::cast_possible_truncation)]
                        let entry = entry as f32;
                        (entry != 0.0).then(|| format!("{entry:?} * a{k}"))
                    })
                    .collect();
                let sum = if terms.is_empty() { "vec3<f32>(0.0)".to_owned() } else { terms.join(" + ") };
                let _ = writeln!(out, "        (*c)[{}] = {sum};", start + row);
            }
            let _ = writeln!(out, "    }}");
        }
        let _ = writeln!(out, "}}");
    }
    out.replace("+ -", "- ")
}

/// Entry `(m, n)` of a band-`l` matrix stored row-major.
fn centered(band: &[f64], l: usize, m: isize, n: isize) -> f64 {
    let li = l as isize;
    band[((m + li) * (2 * li + 1) + n + li) as usize]
}

/// Band `l >= 2` from band 1 and band `l - 1` (Ivanic–Ruedenberg, Table 1 and 2 with errata).
fn ivanic_band(l: usize, band1: &[f64], prev: &[f64]) -> Vec<f64> {
    let li = l as isize;
    let lf = l as f64;
    // Ivanic's P function: P^l_{i,a,b} for i in {-1, 0, 1}, a in -(l-1)..=(l-1).
    let p = |i: isize, a: isize, b: isize| -> f64 {
        let r1 = |m: isize, n: isize| centered(band1, 1, m, n);
        let rp = |m: isize, n: isize| centered(prev, l - 1, m, n);
        if b == li {
            r1(i, 1) * rp(a, li - 1) - r1(i, -1) * rp(a, -li + 1)
        } else if b == -li {
            r1(i, 1) * rp(a, -li + 1) + r1(i, -1) * rp(a, li - 1)
        } else {
            r1(i, 0) * rp(a, b)
        }
    };
    let width = 2 * l + 1;
    let mut band = vec![0.0; width * width];
    for m in -li..=li {
        let mf = m as f64;
        let am = m.unsigned_abs() as f64;
        let d = if m == 0 { 1.0 } else { 0.0 };
        for n in -li..=li {
            let nf = n as f64;
            let denom = if n.abs() == li { 2.0 * lf * (2.0 * lf - 1.0) } else { (lf + nf) * (lf - nf) };
            let u = ((lf + mf) * (lf - mf) / denom).sqrt();
            let v = 0.5 * ((1.0 + d) * (lf + am - 1.0) * (lf + am) / denom).sqrt() * (1.0 - 2.0 * d);
            let w = -0.5 * ((lf - am - 1.0) * (lf - am) / denom).sqrt() * (1.0 - d);
            let mut value = 0.0;
            if u != 0.0 {
                value += u * p(0, m, n);
            }
            if v != 0.0 {
                let big_v = match m.signum() {
                    0 => p(1, 1, n) + p(-1, -1, n),
                    1 if m == 1 => p(1, 0, n) * std::f64::consts::SQRT_2,
                    1 => p(1, m - 1, n) - p(-1, -m + 1, n),
                    _ if m == -1 => p(-1, 0, n) * std::f64::consts::SQRT_2,
                    _ => p(1, m + 1, n) + p(-1, -m - 1, n),
                };
                value += v * big_v;
            }
            if w != 0.0 {
                let big_w =
                    if m > 0 { p(1, m + 1, n) + p(-1, -m - 1, n) } else { p(1, m - 1, n) - p(-1, -m + 1, n) };
                value += w * big_w;
            }
            band[((m + li) * (2 * li + 1) + n + li) as usize] = value;
        }
    }
    band
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::random_unit;
    use glam::DQuat;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    fn random_rotation(rng: &mut Pcg64) -> DMat3 {
        let axis = random_unit(rng);
        DMat3::from_quat(DQuat::from_axis_angle(axis, rng.random::<f64>() * 2.0 * PI))
    }

    /// Rotations that have broken SH rotation code before: identity, poles, half turns.
    fn hard_rotations(rng: &mut Pcg64) -> Vec<(String, DMat3)> {
        let arbitrary = DVec3::new(0.3, -0.5, 0.81).normalize();
        let mut rotations = vec![
            ("identity".to_owned(), DMat3::IDENTITY),
            ("z by 0.7".to_owned(), DMat3::from_rotation_z(0.7)),
            ("z by -2.9".to_owned(), DMat3::from_rotation_z(-2.9)),
            ("x by pi".to_owned(), DMat3::from_rotation_x(PI)),
            ("y by pi".to_owned(), DMat3::from_rotation_y(PI)),
            ("z by pi".to_owned(), DMat3::from_rotation_z(PI)),
            ("arbitrary axis by pi".to_owned(), DMat3::from_axis_angle(arbitrary, PI)),
            ("x by pi/2".to_owned(), DMat3::from_rotation_x(0.5 * PI)),
            ("tiny about y".to_owned(), DMat3::from_rotation_y(1e-9)),
            ("pole to pole".to_owned(), DMat3::from_axis_angle(DVec3::X, PI - 1e-12)),
        ];
        for i in 0..6 {
            rotations.push((format!("random {i}"), random_rotation(rng)));
        }
        rotations
    }

    fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
    }

    #[test]
    fn low_bands_match_closed_forms_without_condon_shortley_phase() {
        let mut rng = Pcg64::seed_from_u64(11);
        let mut y = vec![0.0; sh_count(2)];
        for _ in 0..50 {
            let d = random_unit(&mut rng);
            sh_eval(2, d, &mut y);
            let c1 = (3.0 / (4.0 * PI)).sqrt();
            let c2 = 0.5 * (15.0 / PI).sqrt();
            let expected = [
                0.5 / PI.sqrt(),
                c1 * d.y,
                c1 * d.z,
                c1 * d.x,
                c2 * d.x * d.y,
                c2 * d.y * d.z,
                0.25 * (5.0 / PI).sqrt() * (3.0 * d.z * d.z - 1.0),
                c2 * d.x * d.z,
                0.5 * c2 * (d.x * d.x - d.y * d.y),
            ];
            assert!(max_abs_diff(&y, &expected) < 1e-15, "{y:?} vs {expected:?}");
        }
    }

    #[test]
    fn basis_is_orthonormal_by_quadrature_up_to_order_15() {
        for order in [8_usize, 15] {
            let n = sh_count(order);
            let (nodes, weights) = gauss_legendre(order + 1);
            let n_phi = 2 * (order + 1);
            let mut gram = vec![0.0; n * n];
            let mut y = vec![0.0; n];
            for (&z, &w) in nodes.iter().zip(&weights) {
                let s = (1.0 - z * z).sqrt();
                for j in 0..n_phi {
                    let phi = 2.0 * PI * j as f64 / n_phi as f64;
                    sh_eval(order, DVec3::new(s * phi.cos(), s * phi.sin(), z), &mut y);
                    let wq = w * 2.0 * PI / n_phi as f64;
                    for a in 0..n {
                        for b in 0..n {
                            gram[a * n + b] += wq * y[a] * y[b];
                        }
                    }
                }
            }
            for a in 0..n {
                for b in 0..n {
                    let expected = if a == b { 1.0 } else { 0.0 };
                    assert!(
                        (gram[a * n + b] - expected).abs() < 1e-12,
                        "order {order}: <{a}, {b}> = {}",
                        gram[a * n + b]
                    );
                }
            }
        }
    }

    #[test]
    fn poles_are_finite_and_only_zonal_terms_survive() {
        let order = 15;
        let mut y = vec![0.0; sh_count(order)];
        for (pole, sign) in [(DVec3::Z, 1.0), (DVec3::NEG_Z, -1.0_f64)] {
            sh_eval(order, pole, &mut y);
            for l in 0..=order {
                for m in -(l as isize)..=l as isize {
                    let v = y[sh_index(l, m)];
                    let expected = if m == 0 {
                        sign.powi(l as i32) * ((2 * l + 1) as f64 / (4.0 * PI)).sqrt()
                    } else {
                        0.0
                    };
                    assert!((v - expected).abs() < 1e-13, "l {l} m {m}: {v}");
                }
            }
        }
    }

    #[test]
    fn band_matrices_are_orthogonal_and_compose() {
        let mut rng = Pcg64::seed_from_u64(5);
        let order = 15;
        let r2 = random_rotation(&mut rng);
        let rot2 = ShRotation::new(order, &r2);
        let mut worst_all: f64 = 0.0;
        for (name, r) in hard_rotations(&mut rng) {
            let rot = ShRotation::new(order, &r);
            let composed = ShRotation::new(order, &(r * r2));
            for l in 0..=order {
                let w = 2 * l + 1;
                let b = rot.band(l);
                let mut worst: f64 = 0.0;
                let mut worst_compose: f64 = 0.0;
                for i in 0..w {
                    for j in 0..w {
                        let dot: f64 = (0..w).map(|k| b[i * w + k] * b[j * w + k]).sum();
                        worst = worst.max((dot - if i == j { 1.0 } else { 0.0 }).abs());
                        let product: f64 = (0..w).map(|k| b[i * w + k] * rot2.band(l)[k * w + j]).sum();
                        worst_compose = worst_compose.max((product - composed.band(l)[i * w + j]).abs());
                    }
                }
                assert!(worst < 1e-12, "{name}, band {l}: orthogonality error {worst:e}");
                assert!(worst_compose < 1e-12, "{name}, band {l}: composition error {worst_compose:e}");
                worst_all = worst_all.max(worst).max(worst_compose);
            }
        }
        eprintln!("band orthogonality / composition worst error up to band {order}: {worst_all:e}");
    }

    #[test]
    fn rotate_then_project_equals_project_then_rotate() {
        let mut rng = Pcg64::seed_from_u64(3);
        let order = 8;
        let n = sh_count(order);
        // A band-limited random function (exact under quadrature) and a smooth non-band-limited
        // one (spectrum decays like 1/l!, negligible beyond the quadrature's reach).
        let random_coeffs: Vec<f64> = (0..n).map(|_| rng.random::<f64>() - 0.5).collect();
        let lobe = DVec3::new(0.2, 0.9, -0.4).normalize();
        let smooth = move |w: DVec3| (1.5 * w.dot(lobe)).exp() + w.x * w.y * w.z;
        let band_limited = |w: DVec3| sh_eval_sum(order, &random_coeffs, w);
        let quadrature_n = 30;
        let mut worst: f64 = 0.0;
        let f_band_limited = sh_project(order, quadrature_n, band_limited);
        assert!(max_abs_diff(&f_band_limited, &random_coeffs) < 1e-13);
        let f_smooth = sh_project(order, quadrature_n, smooth);
        for (name, r) in hard_rotations(&mut rng) {
            let rot = ShRotation::new(order, &r);
            let rt = r.transpose();
            for (which, f, coeffs) in [
                ("band-limited", &band_limited as &dyn Fn(DVec3) -> f64, &f_band_limited),
                ("smooth", &smooth as &dyn Fn(DVec3) -> f64, &f_smooth),
            ] {
                let projected = sh_project(order, quadrature_n, |w| f(rt * w));
                let mut rotated = vec![0.0; n];
                rot.apply(coeffs, &mut rotated);
                let err = max_abs_diff(&rotated, &projected);
                worst = worst.max(err);
                assert!(err < 1e-12, "{name}, {which}: max coefficient error {err:e}");
            }
        }
        eprintln!("rotate vs project: worst coefficient error {worst:e}");
    }

    #[test]
    fn euler_rotation_equals_the_band_matrices_for_every_order_and_hard_rotation() {
        let mut rng = Pcg64::seed_from_u64(23);
        let mut rotations = hard_rotations(&mut rng);
        // Gimbal lock and its neighbourhood: beta at 0 and pi exactly, and 1e-9 and 1e-4 away.
        for (name, tilt) in [("beta 0", 0.0), ("beta 1e-9", 1e-9), ("beta 1e-4", 1e-4)] {
            let spin =
                DMat3::from_rotation_z(1.1) * DMat3::from_rotation_y(tilt) * DMat3::from_rotation_z(-0.4);
            rotations.push((name.to_owned(), spin));
            let flipped =
                DMat3::from_rotation_z(0.3) * DMat3::from_rotation_y(PI - tilt) * DMat3::from_rotation_z(2.0);
            rotations.push((format!("pi - {name}"), flipped));
        }
        for i in 0..200 {
            rotations.push((format!("random {i}"), random_rotation(&mut rng)));
        }
        let mut worst: f64 = 0.0;
        for order in 0..=EULER_MAX_ORDER {
            let n = sh_count(order);
            for (name, r) in &rotations {
                let input: Vec<f64> = (0..n).map(|_| rng.random::<f64>() - 0.5).collect();
                let mut expected = vec![0.0; n];
                ShRotation::new(order, r).apply(&input, &mut expected);
                let mut rotated = input.clone();
                ShEulerRotation::new(order, r).apply_in_place(&mut rotated);
                let err = max_abs_diff(&rotated, &expected);
                worst = worst.max(err);
                assert!(err < 1e-12, "order {order}, {name}: max coefficient error {err:e}");
            }
        }
        eprintln!("Euler vs band matrices: worst coefficient error {worst:e}");
    }

    #[test]
    fn zyz_turns_are_unit_and_rebuild_the_rotation_with_beta_in_0_to_pi() {
        let mut rng = Pcg64::seed_from_u64(29);
        let mut rotations = hard_rotations(&mut rng);
        for i in 0..500 {
            rotations.push((format!("random {i}"), random_rotation(&mut rng)));
        }
        for (name, r) in rotations {
            let turns = zyz_turns(&r);
            for (c, s) in turns {
                assert!((c.hypot(s) - 1.0).abs() < 1e-14, "{name}: ({c}, {s}) is not a unit pair");
            }
            let [alpha, beta, gamma] = turns.map(|(c, s)| s.atan2(c));
            assert!(turns[1].1 >= 0.0, "{name}: beta {beta} outside [0, pi]");
            let rebuilt =
                DMat3::from_rotation_z(alpha) * DMat3::from_rotation_y(beta) * DMat3::from_rotation_z(gamma);
            assert!(rebuilt.abs_diff_eq(r, 1e-13), "{name}: {rebuilt} vs {r}");
        }
    }

    #[test]
    fn quarter_turn_table_is_the_quarter_turn_and_its_transpose_the_inverse() {
        let mut rng = Pcg64::seed_from_u64(31);
        let n = sh_count(EULER_MAX_ORDER);
        let input: Vec<f64> = (0..n).map(|_| rng.random::<f64>() - 0.5).collect();
        let mut expected = vec![0.0; n];
        ShRotation::new(EULER_MAX_ORDER, &DMat3::from_rotation_x(0.5 * PI)).apply(&input, &mut expected);
        let mut turned = input.clone();
        quarter_turn_x_in_place(EULER_MAX_ORDER, false, &mut turned);
        assert!(max_abs_diff(&turned, &expected) < 1e-13);
        quarter_turn_x_in_place(EULER_MAX_ORDER, true, &mut turned);
        assert!(max_abs_diff(&turned, &input) < 1e-13);
        // Parity makes about half of every band zero: what the generated WGSL leaves out.
        let table = quarter_turn_x();
        let nonzero: usize =
            (0..=EULER_MAX_ORDER).map(|l| table.band(l).iter().filter(|e| **e != 0.0).count()).sum();
        let total: usize = (0..=EULER_MAX_ORDER).map(|l| (2 * l + 1) * (2 * l + 1)).sum();
        assert!(nonzero * 2 <= total + 2 * EULER_MAX_ORDER + 2, "{nonzero} of {total} entries nonzero");
    }
}
