//! Spherical Gaussians (SG): evaluation, products, integrals, zonal SH, sampling.
//!
//! How it works: an SG is `G(w) = a exp(lam (w . xi - 1))` with unit axis `xi`, sharpness
//! `lam >= 0` and amplitude `a`; it peaks at `a` on the axis, so nothing overflows for any
//! `lam`. Its integral over the sphere is `a M(lam)` with the mass
//! `M(lam) = 2 pi (1 - e^{-2 lam}) / lam`, evaluated as `-2 pi expm1(-2 lam) / lam` (-> `4 pi`).
//! A product of SGs is an SG: axis sum `p = lam1 xi1 + lam2 xi2`, sharpness `|p|`, amplitude
//! `a1 a2 exp(-(lam1 + lam2 - |p|))` with the loss written `lam1 lam2 |xi1 - xi2|^2 /
//! (lam1 + lam2 + |p|)` so that nearly aligned lobes do not cancel. The zonal SH coefficients
//! of the normalized SG are `z_l = sqrt(4 pi (2l + 1)) e^{-lam} i_l(lam) / M(lam)` (from
//! `Int_{-1}^{1} e^{lam t} P_l(t) dt = 2 i_l(lam)`), computed with the scaled spherical Bessel
//! functions of [`crate::special`]; an SG about any axis then follows from the addition
//! theorem. Sampling inverts the CDF of `cos theta` in the form
//! `1 - cos theta = -ln_1p((1 - u) expm1(-2 lam)) / lam`, exact from `lam = 1e-300` to `1e300`.

use crate::sh::{sh_count, sh_eval};
use crate::special::sph_i_scaled;
use glam::DVec3;
use std::f64::consts::PI;

/// A spherical Gaussian `G(w) = amplitude * exp(sharpness * (w . axis - 1))`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sg {
    /// Unit lobe axis `xi`.
    pub axis: DVec3,
    /// Sharpness `lam >= 0` (0 is a constant).
    pub sharpness: f64,
    /// Value on the axis.
    pub amplitude: f64,
}

impl Sg {
    /// An SG with the given axis (normalized here), sharpness and amplitude.
    ///
    /// # Panics
    /// If the axis is zero or the sharpness negative or not finite.
    #[must_use]
    pub fn new(axis: DVec3, sharpness: f64, amplitude: f64) -> Self {
        assert!(sharpness.is_finite() && sharpness >= 0.0, "Sg::new: sharpness {sharpness} must be >= 0");
        let axis =
            axis.try_normalize().unwrap_or_else(|| panic!("Sg::new: axis {axis} cannot be normalized"));
        Self { axis, sharpness, amplitude }
    }

    /// The normalized SG (integral 1): amplitude `1 / M(sharpness)`.
    #[must_use]
    pub fn normalized(axis: DVec3, sharpness: f64) -> Self {
        Self::new(axis, sharpness, 1.0 / sg_mass(sharpness))
    }

    /// `G(dir)` for a unit `dir`.
    #[must_use]
    pub fn eval(&self, dir: DVec3) -> f64 {
        self.amplitude * (self.sharpness * (dir.dot(self.axis) - 1.0)).exp()
    }
}

/// Integral over the sphere of `exp(lam (w . xi - 1))`: `2 pi (1 - e^{-2 lam}) / lam`,
/// evaluated as `-2 pi expm1(-2 lam) / lam`; `4 pi` at `lam = 0`.
#[must_use]
pub fn sg_mass(lambda: f64) -> f64 {
    if lambda == 0.0 { 4.0 * PI } else { -2.0 * PI * (-2.0 * lambda).exp_m1() / lambda }
}

/// The product of two SGs, itself an SG (see the module doc for the cancellation-free loss).
/// Two opposite lobes of equal sharpness give a constant (sharpness 0, axis of `a`).
#[must_use]
pub fn sg_product(a: &Sg, b: &Sg) -> Sg {
    let p = a.sharpness * a.axis + b.sharpness * b.axis;
    let lam = p.length();
    let lam_sum = a.sharpness + b.sharpness;
    let loss = if lam_sum == 0.0 {
        0.0
    } else {
        a.sharpness * b.sharpness * (a.axis - b.axis).length_squared() / (lam_sum + lam)
    };
    let axis = if lam > 0.0 { p / lam } else { a.axis };
    Sg { axis, sharpness: lam, amplitude: a.amplitude * b.amplitude * (-loss).exp() }
}

/// Integral of an SG over the sphere: `amplitude * M(sharpness)`.
#[must_use]
pub fn sg_integral(sg: &Sg) -> f64 {
    sg.amplitude * sg_mass(sg.sharpness)
}

/// Integral over the sphere of the product of two SGs.
#[must_use]
pub fn sg_inner_product(a: &Sg, b: &Sg) -> f64 {
    sg_integral(&sg_product(a, b))
}

/// Zonal SH coefficients `z_l`, `l = 0..=order`, of the normalized SG of sharpness `lambda`
/// about +z: `z_l = sqrt(4 pi (2l + 1)) e^{-lam} i_l(lam) / M(lam)`. At `lam = 0` (constant
/// `1/(4 pi)`) this is `z_0 = 1/sqrt(4 pi)`, the rest 0; for large `lam`,
/// `z_l ~ sqrt((2l + 1)/(4 pi)) e^{-l(l+1)/(2 lam)}`.
///
/// # Panics
/// If `lambda` is negative or not finite.
#[must_use]
pub fn sg_zonal_sh(order: usize, lambda: f64) -> Vec<f64> {
    let mass = sg_mass(lambda);
    sph_i_scaled(order, lambda)
        .into_iter()
        .enumerate()
        .map(|(l, i_l)| (4.0 * PI * (2 * l + 1) as f64).sqrt() * i_l / mass)
        .collect()
}

/// Full SH coefficients (bands `0..=order`) of any SG, by the addition theorem:
/// `c_lm = amplitude M(lam) z_l sqrt(4 pi / (2l + 1)) Y_lm(axis)`.
#[must_use]
pub fn sg_sh(order: usize, sg: &Sg) -> Vec<f64> {
    let zonal = sg_zonal_sh(order, sg.sharpness);
    let mut coeffs = vec![0.0; sh_count(order)];
    sh_eval(order, sg.axis, &mut coeffs);
    let integral = sg_integral(sg);
    for (l, z) in zonal.iter().enumerate() {
        let scale = integral * z * (4.0 * PI / (2 * l + 1) as f64).sqrt();
        for c in &mut coeffs[l * l..(l + 1) * (l + 1)] {
            *c *= scale;
        }
    }
    coeffs
}

/// Two unit vectors `(x, y)` with `(x, y, z)` a right-handed orthonormal frame, for a unit `z`
/// (Duff et al. 2017, "Building an Orthonormal Basis, Revisited": branchless, continuous except
/// across `z.z = 0` sign changes, accurate near both poles).
#[must_use]
pub fn frame_from_z(z: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0_f64.copysign(z.z);
    let a = -1.0 / (sign + z.z);
    let b = z.x * z.y * a;
    let x = DVec3::new(1.0 + sign * z.x * z.x * a, sign * b, -sign * z.x);
    let y = DVec3::new(b, sign + z.y * z.y * a, -z.y);
    (x, y)
}

/// `1 - cos theta` for the normalized SG sample with uniform `u` in `[0, 1)`, in `[0, 2]`.
fn sample_one_minus_cos(lambda: f64, u: f64) -> f64 {
    let v = 1.0 - u;
    if lambda == 0.0 {
        2.0 * v
    } else {
        // P(1 - cos <= t) = (1 - e^{-lam t}) / (1 - e^{-2 lam}) = v, solved for t.
        (-(v * (-2.0 * lambda).exp_m1()).ln_1p() / lambda).clamp(0.0, 2.0)
    }
}

/// Samples a direction with density [`sg_pdf`] (the normalized SG) from two uniform numbers
/// in `[0, 1)`. Stable for `lambda` from 0 to 1e300.
#[must_use]
pub fn sample_sg_dir(axis: DVec3, lambda: f64, u: [f64; 2]) -> DVec3 {
    let one_minus_cos = sample_one_minus_cos(lambda, u[0]);
    let cos_theta = 1.0 - one_minus_cos;
    let sin_theta = (one_minus_cos * (2.0 - one_minus_cos)).max(0.0).sqrt();
    let phi = 2.0 * PI * u[1];
    let (x, y) = frame_from_z(axis);
    (x * phi.cos() + y * phi.sin()) * sin_theta + axis * cos_theta
}

/// Solid-angle density of [`sample_sg_dir`]: `exp(lam (dir . axis - 1)) / M(lam)`. Its relative
/// accuracy is about `lam * 1e-16`, the rounding of `dir . axis` scaled by the sharpness.
#[must_use]
pub fn sg_pdf(axis: DVec3, lambda: f64, dir: DVec3) -> f64 {
    (lambda * (dir.dot(axis) - 1.0)).exp() / sg_mass(lambda)
}

/// f32 twin of `sg_mass` for the GPU (`shaders/shared/sg.wgsl`): `-2π expm1(-2λ)/λ`, 4π at
/// λ = 0.
#[must_use]
pub fn sg_mass_f32(lambda: f32) -> f32 {
    if lambda <= 0.0 {
        return 4.0 * std::f32::consts::PI;
    }
    -2.0 * std::f32::consts::PI * crate::special::expm1_f32(-2.0 * lambda) / lambda
}

/// The azimuthal average of an SG in the fiber frame, overflow-free:
/// `(1/2π) ∫ exp(λ(ω·ξ − 1)) dφ = exp(−λ(1 − cos(θ − θξ))) · i0e(λ cos θ cos θξ)`, with θ, θξ
/// measured from the normal plane (cos ≥ 0). `1 − cos(Δ)` is computed as `2 sin²(Δ/2)`, so
/// nearly aligned directions keep their accuracy at λ up to 1e5.
#[must_use]
pub fn sg_azimuthal_average(theta: f64, theta_xi: f64, lambda: f64) -> f64 {
    let half = 0.5 * (theta - theta_xi);
    let one_minus_cos = 2.0 * half.sin() * half.sin();
    (-lambda * one_minus_cos).exp()
        * crate::special::i0e(lambda * theta.cos().max(0.0) * theta_xi.cos().max(0.0))
}

/// f32 twin of [`sg_azimuthal_average`] (`shaders/shared/sg.wgsl`).
#[must_use]
pub fn sg_azimuthal_average_f32(theta: f32, theta_xi: f32, lambda: f32) -> f32 {
    let half = 0.5 * (theta - theta_xi);
    let s = half.sin();
    let one_minus_cos = 2.0 * s * s;
    (-lambda * one_minus_cos).exp()
        * crate::special::i0e_f32(lambda * theta.cos().max(0.0) * theta_xi.cos().max(0.0))
}

/// Nodes of the midpoint rule over the SG's mass in [`sg_upper_fraction`].
pub const UPPER_FRACTION_NODES: usize = 32;

/// The share of a normalized SG's power above the plane z = 0 (its axis's z is `axis_z`,
/// sharpness `lambda`): `∫_{z>0} exp(λ(ω·ξ − 1)) dω / M(λ)`.
///
/// How (for `ξ_z ≥ 0`; below, one minus the mirror's share): on the circle of directions at
/// `t = ω·ξ` about the axis the share above the plane is 1 for `t > |ξ_xy|`, 0 for
/// `t < −|ξ_xy|`, and `acos(−t ξ_z / (√(1 − t²) |ξ_xy|)) / π` between. The mass with
/// `t > |ξ_xy|` is closed-form, `F(1 − |ξ_xy|)` with `F(w) = expm1(−λw) / expm1(−2λ)` the
/// share of the mass within `1 − t ≤ w`; the mass between is cut into [`UPPER_FRACTION_NODES`]
/// equal slices, each taken at its middle (`1 − t = −ln_1p(u expm1(−2λ)) / λ`, as
/// [`sample_sg_dir`] draws it). Exact for an axis along z or in the plane. Where the plane lies
/// more than 20 widths from the axis (`λ(1 − |ξ_xy|) > 20`, the mass beyond below 2e-9) the
/// share is 1 or 0 outright.
#[must_use]
pub fn sg_upper_fraction(axis_z: f64, lambda: f64) -> f64 {
    let z = axis_z.clamp(-1.0, 1.0);
    let s = z.abs();
    let c = (1.0 - s * s).max(0.0).sqrt();
    // 1 − c without cancellation: s² / (1 + c).
    let gap = s * s / (1.0 + c);
    let upper = if lambda * gap > 20.0 {
        1.0
    } else {
        let (top, bottom, circles) = circles_cut_by_the_plane(lambda, s, c, gap);
        let between: f64 = circles.map(|(_, _, alpha)| alpha / PI).sum();
        top + (bottom - top) * between / UPPER_FRACTION_NODES as f64
    };
    if z >= 0.0 { upper } else { 1.0 - upper }
}

/// The circles of directions about an SG's axis (sharpness `lambda`, `ξ_z = s ≥ 0`,
/// `|ξ_xy| = c`, `gap = 1 − c` without cancellation) that the plane z = 0 cuts, for
/// [`sg_upper_fraction`] and [`sg_upper_moment`]: `(top, bottom, circles)` with `top` and
/// `bottom` the shares of the mass within `1 − t ≤ gap` and `≤ 1 + c` of the axis, and per each
/// of the [`UPPER_FRACTION_NODES`] equal slices of the mass between, its middle circle's
/// `(t, r, α)`: `t = ω·ξ`, `r = √(1 − t²)` and the half-angle `α` of its arc above the plane.
fn circles_cut_by_the_plane(
    lambda: f64,
    s: f64,
    c: f64,
    gap: f64,
) -> (f64, f64, impl Iterator<Item = (f64, f64, f64)>) {
    // The share of the mass within 1 − t ≤ w of the axis.
    let total = (-2.0 * lambda).exp_m1();
    let mass_within = |w: f64| if lambda > 0.0 { (-lambda * w).exp_m1() / total } else { 0.5 * w };
    let (top, bottom) = (mass_within(gap), mass_within(1.0 + c));
    let circles = (0..UPPER_FRACTION_NODES).map(move |i| {
        let u = top + (bottom - top) * (i as f64 + 0.5) / UPPER_FRACTION_NODES as f64;
        // The inverse of `mass_within`: the sampler's, which takes the share from the far end.
        let w = sample_one_minus_cos(lambda, 1.0 - u);
        let (t, r) = (1.0 - w, (w * (2.0 - w)).max(0.0).sqrt());
        (t, r, (-t * s / (r * c).max(f64::MIN_POSITIVE)).clamp(-1.0, 1.0).acos())
    });
    (top, bottom, circles)
}

/// A normalized SG's power above the plane z = 0, as `(share, first moment)`: the share is
/// [`sg_upper_fraction`]'s, the moment `∫_{z>0} ω exp(λ(ω·ξ − 1)) dω / M(λ)` (a vector; over the
/// share it is the mean direction of the light above the horizon, whose length is the mean
/// resultant length R of that part).
///
/// How: as [`sg_upper_fraction`], by circles of directions at `t = ω·ξ` about the axis. On
/// the circle `ω(φ) = t ξ + r (cos φ u + sin φ v)` (`r = √(1 − t²)`, `u` the unit vector in
/// the plane of ξ and z, perpendicular to ξ and toward +z; so `ω_z = t ξ_z + r cos φ |ξ_xy|`)
/// the arc above the plane is `|φ| < α`, `α = acos(−t ξ_z / (r |ξ_xy|))`, and its mean over the
/// whole circle is `(α t ξ + sin α r u) / π`. The circles wholly above the plane (the mass within
/// `1 − t ≤ 1 − |ξ_xy|`, share `F`) add `F (1 − E[1 − t]) ξ` with the truncated exponential's
/// mean `E[1 − t] = 1/λ − g / expm1(λ g)`; the mass between is cut into
/// [`UPPER_FRACTION_NODES`] equal slices taken at their middles. An axis below the plane
/// takes the whole SG's moment `A(λ) ξ` (`A = coth λ − 1/λ`) less its mirror's part above.
#[must_use]
pub fn sg_upper_moment(axis: DVec3, lambda: f64) -> (f64, DVec3) {
    if axis.z < 0.0 {
        let mirror = DVec3::new(axis.x, axis.y, -axis.z);
        let (share, moment) = sg_upper_moment(mirror, lambda);
        let whole = sg_mean_resultant(lambda) * axis;
        return (1.0 - share, whole - DVec3::new(moment.x, moment.y, -moment.z));
    }
    let s = axis.z.min(1.0);
    let c = (1.0 - s * s).max(0.0).sqrt();
    let gap = s * s / (1.0 + c);
    let cap_mean_t = |g: f64| {
        // 1 − E[1 − t] over 1 − t ∈ [0, g] with density ∝ exp(−λ(1 − t)).
        let x = lambda * g;
        let mean_w = if x < 1e-4 { g * (0.5 - x / 12.0) } else { 1.0 / lambda - g / x.exp_m1() };
        1.0 - mean_w
    };
    if lambda * gap > 20.0 {
        return (1.0, sg_mean_resultant(lambda) * axis);
    }
    let (top, bottom, circles) = circles_cut_by_the_plane(lambda, s, c, gap);
    if c == 0.0 {
        // The axis along z (gap 1): every circle is level, those within 1 − t ≤ 1 wholly above.
        return (top, top * cap_mean_t(gap) * axis);
    }
    // u: in the plane of ξ and z, perpendicular to ξ, toward +z.
    let u = (DVec3::Z - s * axis) / c;
    let (mut share, mut moment) = (0.0, DVec3::ZERO);
    for (t, r, alpha) in circles {
        share += alpha / PI;
        moment += (alpha * t * axis + alpha.sin() * r * u) / PI;
    }
    let slice = (bottom - top) / UPPER_FRACTION_NODES as f64;
    (top + slice * share, top * cap_mean_t(gap) * axis + slice * moment)
}

/// The mean resultant length of a normalized SG of sharpness `lambda` (a von Mises–Fisher
/// density): `A(λ) = coth λ − 1/λ`, by its series below λ = 1e-3.
#[must_use]
pub fn sg_mean_resultant(lambda: f64) -> f64 {
    if lambda < 1e-3 {
        lambda / 3.0 - lambda.powi(3) / 45.0
    } else {
        // coth λ = 1 + 2 / expm1(2λ).
        1.0 + 2.0 / (2.0 * lambda).exp_m1() - 1.0 / lambda
    }
}

/// f32 twin of [`sg_upper_fraction`] (`shaders/shared/sg.wgsl`), with [`ln_1p_f32`] and
/// [`crate::special::expm1_f32`].
///
/// [`ln_1p_f32`]: crate::special::ln_1p_f32
#[must_use]
pub fn sg_upper_fraction_f32(axis_z: f32, lambda: f32) -> f32 {
    use crate::special::{expm1_f32, ln_1p_f32};
    let z = axis_z.clamp(-1.0, 1.0);
    let s = z.abs();
    let c = (1.0 - s * s).max(0.0).sqrt();
    let gap = s * s / (1.0 + c);
    let upper = if lambda * gap > 20.0 {
        1.0
    } else {
        let total = expm1_f32(-2.0 * lambda);
        let share = |w: f32| if lambda > 0.0 { expm1_f32(-lambda * w) / total } else { 0.5 * w };
        let (top, bottom) = (share(gap), share(1.0 + c));
        let mut between = 0.0;
        for i in 0..UPPER_FRACTION_NODES {
            let u = top + (bottom - top) * (i as f32 + 0.5) / UPPER_FRACTION_NODES as f32;
            let w = if lambda > 0.0 {
                (-ln_1p_f32(u * total) / lambda).clamp(0.0, 2.0)
            } else {
                (2.0 * u).clamp(0.0, 2.0)
            };
            let (t, r) = (1.0 - w, (w * (2.0 - w)).max(0.0).sqrt());
            between +=
                (-t * s / (r * c).max(f32::MIN_POSITIVE)).clamp(-1.0, 1.0).acos() / std::f32::consts::PI;
        }
        top + (bottom - top) * between / UPPER_FRACTION_NODES as f32
    };
    if z >= 0.0 { upper } else { 1.0 - upper }
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // exact limits are checked bit for bit
mod tests {
    use super::*;
    use crate::quadrature::gauss_legendre;
    use crate::sh::{ShRotation, sh_index, sh_project};
    use crate::test_support::{gamma_q, random_unit};

    /// The share and first moment of a normalized SG above the plane z = 0 by a product rule
    /// over the upper hemisphere: Gauss–Legendre in z (`nodes`, `weights` on [−1, 1]) by 800
    /// midpoints in azimuth.
    fn upper_hemisphere_rule(axis: DVec3, lambda: f64, nodes: &[f64], weights: &[f64]) -> (f64, DVec3) {
        let (mut share, mut moment) = (0.0, DVec3::ZERO);
        for (x, w) in nodes.iter().zip(weights) {
            let z = 0.5 * (x + 1.0);
            let r = (1.0 - z * z).sqrt();
            for k in 0..800 {
                let phi = 2.0 * PI * (f64::from(k) + 0.5) / 800.0;
                let dir = DVec3::new(r * phi.cos(), r * phi.sin(), z);
                let p = 0.5 * w * (2.0 * PI / 800.0) * sg_pdf(axis, lambda, dir);
                share += p;
                moment += p * dir;
            }
        }
        (share, moment)
    }

    #[test]
    fn upper_moment_matches_a_product_rule_and_its_limits() {
        // The share and first moment above the plane by a product rule over the upper
        // hemisphere (400 x 800 nodes), axes above, in and below the plane, turned in azimuth.
        let (nodes, weights) = gauss_legendre(400);
        for lambda in [1e-4, 0.5, 2.0, 8.0, 50.0, 300.0] {
            for axis_z in [-0.6_f64, -0.1, 0.0, 0.05, 0.2, 0.7, 0.95, 1.0] {
                let r0 = (1.0 - axis_z * axis_z).sqrt();
                let axis = DVec3::new(r0 * 0.6, r0 * 0.8, axis_z);
                let (share, moment) = upper_hemisphere_rule(axis, lambda, &nodes, &weights);
                let (got_share, got_moment) = sg_upper_moment(axis, lambda);
                assert!(
                    (got_share - share).abs() < 2e-3,
                    "λ {lambda} ξz {axis_z}: share {got_share} vs {share}"
                );
                assert!(
                    (got_share - sg_upper_fraction(axis_z, lambda)).abs() < 1e-12,
                    "λ {lambda} ξz {axis_z}"
                );
                assert!(
                    (got_moment - moment).length() < 2e-3,
                    "λ {lambda} ξz {axis_z}: moment {got_moment} vs {moment}"
                );
            }
        }
        // Whole lobes: the von Mises–Fisher mean resultant length along the axis.
        for lambda in [1e-5, 0.3, 3.0, 30.0, 3e3] {
            let a = sg_mean_resultant(lambda);
            let expected = 1.0 / lambda.tanh() - 1.0 / lambda;
            assert!((a - expected).abs() < 1e-9, "λ {lambda}: {a} vs {expected}");
            let (share, moment) = sg_upper_moment(DVec3::new(0.0, 0.6, 0.8), lambda.max(200.0));
            assert!(
                share == 1.0
                    && (moment - sg_mean_resultant(lambda.max(200.0)) * DVec3::new(0.0, 0.6, 0.8)).length()
                        < 1e-15
            );
        }
    }

    #[test]
    fn upper_fraction_matches_quadrature_closed_forms_and_its_f32_twin() {
        use rand::{Rng, SeedableRng};
        // Closed forms: an axis along ±z leaves (1 − e^{−λ}) / (1 − e^{−2λ}) = 1 / (1 + e^{−λ})
        // above; an axis in the plane, half.
        for lambda in [1e-4_f64, 0.5, 3.0, 40.0, 2e3] {
            let up = 1.0 / (1.0 + (-lambda).exp());
            assert!((sg_upper_fraction(1.0, lambda) - up).abs() < 1e-12, "λ {lambda}");
            assert!((sg_upper_fraction(-1.0, lambda) - (1.0 - up)).abs() < 1e-12, "λ {lambda}");
            assert!((sg_upper_fraction(0.0, lambda) - 0.5).abs() < 1e-12, "λ {lambda}");
        }
        // Broad lobes: a product rule over the upper hemisphere (400 × 800 nodes).
        let (nodes, weights) = gauss_legendre(400);
        for lambda in [1e-4, 0.5, 2.0, 8.0, 50.0] {
            for axis_z in [-0.6_f64, -0.1, 0.05, 0.2, 0.7, 0.95] {
                let axis = DVec3::new((1.0 - axis_z * axis_z).sqrt(), 0.0, axis_z);
                let (sum, _) = upper_hemisphere_rule(axis, lambda, &nodes, &weights);
                let got = sg_upper_fraction(axis_z, lambda);
                assert!((got - sum).abs() < 2e-3, "λ {lambda} ξz {axis_z}: {got} vs {sum}");
                let f32_twin = f64::from(sg_upper_fraction_f32(axis_z as f32, lambda as f32));
                assert!((f32_twin - got).abs() < 2e-4, "λ {lambda} ξz {axis_z}: f32 {f32_twin} vs {got}");
            }
        }
        // Sharp lobes near the plane: 400,000 samples of the lobe (noise below 8e-4).
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        for (lambda, axis_z) in [(2e3, 0.01_f64), (2e3, -0.02), (300.0, 0.05), (1e5, 0.002)] {
            let axis = DVec3::new((1.0 - axis_z * axis_z).sqrt(), 0.0, axis_z);
            let n = 400_000;
            let above =
                (0..n).filter(|_| sample_sg_dir(axis, lambda, [rng.random(), rng.random()]).z > 0.0).count();
            let expected = above as f64 / f64::from(n);
            let got = sg_upper_fraction(axis_z, lambda);
            assert!((got - expected).abs() < 4e-3, "λ {lambda} ξz {axis_z}: {got} vs {expected}");
            let f32_twin = f64::from(sg_upper_fraction_f32(axis_z as f32, lambda as f32));
            assert!((f32_twin - got).abs() < 2e-3, "λ {lambda} ξz {axis_z}: f32 {f32_twin} vs {got}");
        }
        // Far from the plane, whole.
        assert_eq!(sg_upper_fraction(0.5, 2e3), 1.0);
        assert_eq!(sg_upper_fraction(-0.5, 2e3), 0.0);
    }

    #[test]
    fn azimuthal_average_matches_quadrature_and_its_f32_twin() {
        for &lambda in &[1e-4, 0.3, 5.0, 80.0, 1e3] {
            for &(theta, theta_xi) in &[
                (0.0_f64, 0.0_f64),
                (0.4, -0.2),
                (1.2, 1.1),
                (-1.5, 0.3),
                (std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_2),
            ] {
                let xi = DVec3::new(f64::cos(theta_xi), 0.0, f64::sin(theta_xi));
                let n = 4096;
                let quadrature = (0..n)
                    .map(|k| {
                        let phi = std::f64::consts::TAU * (f64::from(k) + 0.5) / f64::from(n);
                        let w = DVec3::new(theta.cos() * phi.cos(), theta.cos() * phi.sin(), f64::sin(theta));
                        (lambda * (w.dot(xi) - 1.0)).exp()
                    })
                    .sum::<f64>()
                    / f64::from(n);
                let formula = sg_azimuthal_average(theta, theta_xi, lambda);
                assert!(
                    (formula - quadrature).abs() <= 1e-12 + 1e-10 * quadrature,
                    "{lambda} {theta} {theta_xi}: {formula} vs {quadrature}"
                );
                let twin = f64::from(sg_azimuthal_average_f32(theta as f32, theta_xi as f32, lambda as f32));
                // f32 rounding of θ and θξ (relative 6e-8) is amplified by d ln f / dθ ≲ λ: the
                // twin cannot beat that conditioning, plus a few ulp of its own arithmetic.
                let tolerance = 1e-6 + 2.4e-7 * lambda * (theta.abs() + theta_xi.abs());
                // Below f32's normal range (subnormals) only an absolute comparison makes sense.
                let close = (twin - formula).abs() <= tolerance * formula + f64::from(f32::MIN_POSITIVE);
                assert!(close, "{lambda} {theta} {theta_xi}: {twin} vs {formula}");
            }
        }
        for &lambda in &[0.0f32, 1e-4, 1e-3, 0.1, 0.25, 0.3, 1.0, 1e5] {
            let reference = sg_mass(f64::from(lambda));
            let twin = f64::from(sg_mass_f32(lambda));
            assert!((twin / reference - 1.0).abs() < 1e-6, "mass({lambda}): {twin} vs {reference}");
        }
    }
    use glam::DMat3;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    fn rel_err(a: f64, b: f64) -> f64 {
        assert!(a.is_finite() && b.is_finite(), "non-finite: {a} vs {b}");
        if b == 0.0 { a.abs() } else { ((a - b) / b).abs() }
    }

    /// `Int_0^2 g(s) ds` for integrands concentrated near `s = 0` on the scale `1/lam`: panels
    /// with edges at `2^k / lam`, 24 Gauss–Legendre nodes each.
    fn integrate_near_zero(lambda: f64, g: impl Fn(f64) -> f64) -> f64 {
        let (nodes, weights) = gauss_legendre(24);
        let mut edges = vec![0.0];
        let mut e = 0.25 / lambda.max(1e-300);
        while e < 2.0 {
            edges.push(e);
            e *= 2.0;
        }
        edges.push(2.0);
        let mut sum = 0.0;
        for pair in edges.windows(2) {
            let (lo, hi) = (pair[0], pair[1]);
            let half = 0.5 * (hi - lo);
            for (x, w) in nodes.iter().zip(&weights) {
                sum += w * half * g(lo + half * (x + 1.0));
            }
        }
        sum
    }

    /// Frame with columns `(x, y, axis)`: maps +z to `axis`.
    fn rotation_to(axis: DVec3) -> DMat3 {
        let (x, y) = frame_from_z(axis);
        DMat3::from_cols(x, y, axis)
    }

    #[test]
    fn mass_is_stable_and_has_the_right_limits() {
        assert_eq!(sg_mass(0.0), 4.0 * PI);
        assert!(rel_err(sg_mass(1e-300), 4.0 * PI) < 1e-15);
        assert!(rel_err(sg_mass(1e-8), 4.0 * PI * (1.0 - 1e-8)) < 1e-15);
        assert!(rel_err(sg_mass(1.0), 2.0 * PI * (1.0 - (-2.0_f64).exp())) < 1e-15);
        assert!(rel_err(sg_mass(1e5), 2.0 * PI / 1e5) < 1e-15);
        // Against quadrature of the SG itself.
        for lambda in [1e-4, 0.1, 1.0, 10.0, 1e3, 1e5] {
            let q = 2.0 * PI * integrate_near_zero(lambda, |s| (-lambda * s).exp());
            assert!(rel_err(sg_mass(lambda), q) < 1e-13, "lam = {lambda}");
        }
    }

    #[test]
    fn product_matches_pointwise_product_without_cancellation() {
        let mut rng = Pcg64::seed_from_u64(17);
        for _ in 0..200 {
            let a = Sg::new(
                random_unit(&mut rng),
                10f64.powf(rng.random_range(-3.0..3.0)),
                rng.random_range(0.1..2.0),
            );
            let b = Sg::new(
                random_unit(&mut rng),
                10f64.powf(rng.random_range(-3.0..3.0)),
                rng.random_range(0.1..2.0),
            );
            let ab = sg_product(&a, &b);
            assert!((ab.axis.length() - 1.0).abs() < 1e-14);
            for _ in 0..5 {
                let w = random_unit(&mut rng);
                let direct = a.eval(w) * b.eval(w);
                if direct > 1e-250 {
                    assert!(rel_err(ab.eval(w), direct) < 1e-9, "{a:?} {b:?} at {w}");
                }
            }
        }
        // Nearly aligned sharp lobes: the naive lam1 + lam2 - |p| loses every digit here.
        let xi = DVec3::new(0.0, 0.6, 0.8);
        let tilt = DVec3::new(1e-7, 0.8e-7, -0.6e-7);
        let a = Sg::new(xi, 1e5, 1.0);
        let b = Sg::new(xi + tilt, 1e5, 1.0);
        let loss =
            1e5 * 1e5 * (a.axis - b.axis).length_squared() / (2e5 + (1e5 * (a.axis + b.axis)).length());
        let expected = (-loss).exp();
        assert!(rel_err(sg_product(&a, &b).amplitude, expected) < 1e-15);
        assert!(loss > 1e-10 && loss < 1e-8, "test setup: loss {loss:e}");
        // Opposite lobes of equal sharpness: a constant a1 a2 e^{-2 lam}.
        let c = sg_product(&Sg::new(DVec3::Z, 3.0, 2.0), &Sg::new(DVec3::NEG_Z, 3.0, 0.5));
        assert!(c.sharpness == 0.0 && rel_err(c.amplitude, (-6.0_f64).exp()) < 1e-15);
    }

    #[test]
    fn inner_product_matches_quadrature() {
        let mut rng = Pcg64::seed_from_u64(23);
        let (nodes, weights) = gauss_legendre(200);
        for _ in 0..10 {
            let a = Sg::new(random_unit(&mut rng), rng.random_range(0.01..30.0), rng.random_range(0.1..2.0));
            let b = Sg::new(random_unit(&mut rng), rng.random_range(0.01..30.0), rng.random_range(0.1..2.0));
            // Product rule on the sphere, fine enough for sharpness <= 60 combined.
            let n_phi = 400;
            let mut q = 0.0;
            for (&z, &w) in nodes.iter().zip(&weights) {
                let s = (1.0 - z * z).sqrt();
                for j in 0..n_phi {
                    let phi = 2.0 * PI * (f64::from(j) + 0.5) / f64::from(n_phi);
                    let dir = DVec3::new(s * phi.cos(), s * phi.sin(), z);
                    q += w * 2.0 * PI / f64::from(n_phi) * a.eval(dir) * b.eval(dir);
                }
            }
            assert!(rel_err(sg_inner_product(&a, &b), q) < 1e-10, "{a:?} {b:?}");
        }
    }

    #[test]
    fn zonal_sh_matches_quadrature_limits_and_asymptotics() {
        let order = 8;
        let mut worst: f64 = 0.0;
        for lambda in [1e-4, 0.1, 1.0, 10.0, 100.0, 1e3] {
            let z = sg_zonal_sh(order, lambda);
            for (l, &zl) in z.iter().enumerate() {
                // z_l = 2 pi Int G_n(t) Y_l0(t) dt with t = cos theta = 1 - s.
                let q = 2.0
                    * PI
                    * integrate_near_zero(lambda, |s| {
                        let t = 1.0 - s;
                        let mut y = vec![0.0; sh_count(order)];
                        sh_eval(order, DVec3::new((1.0 - t * t).max(0.0).sqrt(), 0.0, t), &mut y);
                        (-lambda * s).exp() / sg_mass(lambda) * y[sh_index(l, 0)]
                    });
                let err = (zl - q).abs();
                worst = worst.max(err / q.abs().max(1e-3));
                assert!(err < 1e-14 + 1e-12 * q.abs(), "lam = {lambda}, l = {l}: {zl:e} vs {q:e}");
                assert!(zl > 0.0, "lam = {lambda}, l = {l}");
            }
        }
        eprintln!("sg_zonal_sh vs quadrature: worst error {worst:e}");
        let z0 = sg_zonal_sh(order, 0.0);
        assert!(rel_err(z0[0], 0.5 / PI.sqrt()) < 1e-15 && z0[1..].iter().all(|&v| v == 0.0));
        let lambda = 1e5;
        for (l, &zl) in sg_zonal_sh(order, lambda).iter().enumerate() {
            let lf = l as f64;
            let asym = ((2.0 * lf + 1.0) / (4.0 * PI)).sqrt() * (-lf * (lf + 1.0) / (2.0 * lambda)).exp();
            assert!(rel_err(zl, asym) < 1e-8, "l = {l}");
        }
    }

    #[test]
    fn full_sh_from_zonal_and_rotation_equals_projection() {
        let mut rng = Pcg64::seed_from_u64(29);
        let order = 6;
        let n = sh_count(order);
        for lambda in [0.3, 4.0] {
            for axis in [random_unit(&mut rng), DVec3::NEG_Z, DVec3::X] {
                let sg = Sg::new(axis, lambda, 1.7);
                let by_addition = sg_sh(order, &sg);
                let projected = sh_project(order, 48, |w| sg.eval(w));
                // Zonal coefficients about +z, placed in the m = 0 slots, then rotated to the axis.
                let mut zonal_full = vec![0.0; n];
                for (l, z) in sg_zonal_sh(order, lambda).iter().enumerate() {
                    zonal_full[sh_index(l, 0)] = z * sg_integral(&sg);
                }
                let mut rotated = vec![0.0; n];
                ShRotation::new(order, &rotation_to(axis)).apply(&zonal_full, &mut rotated);
                for j in 0..n {
                    assert!(
                        (by_addition[j] - projected[j]).abs() < 1e-12,
                        "lam {lambda}, axis {axis}, j {j}"
                    );
                    assert!((rotated[j] - projected[j]).abs() < 1e-12, "lam {lambda}, axis {axis}, j {j}");
                }
            }
        }
    }

    #[test]
    fn frame_is_right_handed_and_orthonormal_everywhere() {
        let mut rng = Pcg64::seed_from_u64(31);
        let mut dirs = vec![DVec3::Z, DVec3::NEG_Z, DVec3::X, DVec3::new(1e-9, 0.0, -1.0).normalize()];
        dirs.extend((0..1000).map(|_| random_unit(&mut rng)));
        for z in dirs {
            let (x, y) = frame_from_z(z);
            assert!((x.length() - 1.0).abs() < 1e-14 && (y.length() - 1.0).abs() < 1e-14, "{z}");
            assert!(x.dot(y).abs() < 1e-14 && x.dot(z).abs() < 1e-14 && y.dot(z).abs() < 1e-14, "{z}");
            assert!((x.cross(y) - z).length() < 1e-14, "{z}");
        }
    }

    #[test]
    fn pdf_integrates_to_one_and_samples_are_finite() {
        let mut rng = Pcg64::seed_from_u64(37);
        for lambda in [0.0_f64, 1e-4, 1e-3, 1.0, 100.0, 1e4, 1e5] {
            let axis = random_unit(&mut rng);
            let (x, _) = frame_from_z(axis);
            // Integrate over s = 1 - cos theta (the pdf does not depend on phi; one phi suffices).
            let total = 2.0
                * PI
                * integrate_near_zero(lambda.max(1.0), |s| {
                    let sin = (s * (2.0 - s)).sqrt();
                    sg_pdf(axis, lambda, x * sin + axis * (1.0 - s))
                });
            // A unit direction carries ~1e-16 absolute error in w . axis, i.e. lam * 1e-16 in the pdf.
            assert!(rel_err(total, 1.0) < 1e-12 + 1e-15 * lambda, "lam = {lambda}: {total}");
            for u0 in [0.0, 1e-300, 0.5, 1.0 - f64::EPSILON] {
                let d = sample_sg_dir(axis, lambda, [u0, 0.3]);
                assert!(d.is_finite() && (d.length() - 1.0).abs() < 1e-14, "lam {lambda}, u0 {u0}: {d}");
                assert!(sg_pdf(axis, lambda, d).is_finite());
            }
        }
    }

    /// p-value of a chi-square test of `sampled_lambda` samples against the pdf of `lambda`,
    /// in (1 - cos theta, phi) bins around a tilted axis.
    fn chi_square_p_value(lambda: f64, sampled_lambda: f64, seed: u64) -> f64 {
        const N_S: usize = 12;
        const N_PHI: usize = 8;
        const SAMPLES: usize = 200_000;
        let axis = DVec3::new(0.36, -0.48, 0.8);
        let (fx, fy) = frame_from_z(axis);
        let s_max = (6.0 / lambda).min(2.0);
        let bin_of = |d: DVec3| -> usize {
            let s = 1.0 - d.dot(axis);
            if s >= s_max {
                return N_S * N_PHI;
            }
            let phi = d.dot(fy).atan2(d.dot(fx)).rem_euclid(2.0 * PI);
            let i = ((s / s_max * N_S as f64) as usize).min(N_S - 1);
            let j = ((phi / (2.0 * PI) * N_PHI as f64) as usize).min(N_PHI - 1);
            i * N_PHI + j
        };
        // Expected: the pdf integrated over each bin (6 x 6 Gauss-Legendre), the rest in a tail bin.
        let (nodes, weights) = gauss_legendre(6);
        let mut expected = vec![0.0; N_S * N_PHI + 1];
        for i in 0..N_S {
            for j in 0..N_PHI {
                let (s0, s1) = (s_max * i as f64 / N_S as f64, s_max * (i + 1) as f64 / N_S as f64);
                let (p0, p1) = (2.0 * PI * j as f64 / N_PHI as f64, 2.0 * PI * (j + 1) as f64 / N_PHI as f64);
                let mut sum = 0.0;
                for (xa, wa) in nodes.iter().zip(&weights) {
                    let s = s0 + 0.5 * (s1 - s0) * (xa + 1.0);
                    let sin = (s * (2.0 - s)).sqrt();
                    for (xb, wb) in nodes.iter().zip(&weights) {
                        let phi = p0 + 0.5 * (p1 - p0) * (xb + 1.0);
                        let d = (fx * phi.cos() + fy * phi.sin()) * sin + axis * (1.0 - s);
                        sum += wa * wb * 0.25 * (s1 - s0) * (p1 - p0) * sg_pdf(axis, lambda, d);
                    }
                }
                expected[i * N_PHI + j] = sum * SAMPLES as f64;
            }
        }
        let inside: f64 = expected.iter().sum();
        expected[N_S * N_PHI] = (SAMPLES as f64 - inside).max(0.0);
        let mut observed = vec![0.0; N_S * N_PHI + 1];
        let mut rng = Pcg64::seed_from_u64(seed);
        for _ in 0..SAMPLES {
            let d = sample_sg_dir(axis, sampled_lambda, [rng.random(), rng.random()]);
            observed[bin_of(d)] += 1.0;
        }
        // Pool bins expected to hold fewer than 5 samples into one (as mitsuba's chi2 does).
        let (mut chi2, mut dof, mut pooled_e, mut pooled_o) = (0.0, 0_usize, 0.0, 0.0);
        for (e, o) in expected.iter().zip(&observed) {
            if *e < 5.0 {
                pooled_e += e;
                pooled_o += o;
            } else {
                chi2 += (o - e) * (o - e) / e;
                dof += 1;
            }
        }
        if pooled_e > 0.0 {
            chi2 += (pooled_o - pooled_e) * (pooled_o - pooled_e) / pooled_e.max(1e-12);
            dof += 1;
        }
        gamma_q((dof - 1) as f64 / 2.0, chi2 / 2.0)
    }

    #[test]
    fn sampler_passes_chi_square_against_pdf() {
        let lambdas = [1e-3, 1.0, 100.0, 1e4];
        // Sidak correction for the four tests at overall significance 1%.
        let alpha = 1.0 - 0.99_f64.powf(1.0 / lambdas.len() as f64);
        for (k, &lambda) in lambdas.iter().enumerate() {
            let p = chi_square_p_value(lambda, lambda, 1000 + k as u64);
            eprintln!("chi-square lam = {lambda:e}: p = {p:.3}");
            assert!(p > alpha, "lam = {lambda}: p = {p:e} < {alpha:e}");
        }
        // The test can fail: a sampler 5% too sharp is rejected.
        for lambda in [1.0, 100.0, 1e4] {
            let p = chi_square_p_value(lambda, lambda * 1.05, 7);
            eprintln!("chi-square, sampler 5% too sharp, lam = {lambda:e}: p = {p:e}");
            assert!(p < alpha, "wrong sampler not detected at lam = {lambda}: p = {p:e}");
        }
    }
}
