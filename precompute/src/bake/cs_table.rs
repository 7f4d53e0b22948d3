//! The BCSDF's SH expansion table C_S[θo, j] (paper section 4.3).
//!
//! Definition: `C_S[θo, j] = ∫ Y_j(ωi) S(ωi, ωo) cos θi dωi` in the **ωo-space** of a fiber:
//! x along the fiber tangent t, y chosen so that ωo lies in the xy plane with a non-negative y
//! component, z = x × y. In that frame `ωo = (sin θo, cos θo, 0)`. A world direction w has
//! ωo-space coordinates `(w·t, w·b, w·c)` with `b = normalize(ωo − (ωo·t) t)` (when
//! `|ωo − (ωo·t) t| ≤` [`AZIMUTH_MIN_PERP`], b is `sg::frame_from_z(t).0`) and `c = t × b`; [`OmegaOSpace`] builds
//! exactly this. Y_j is our real SH ([`crate::sh::sh_eval`]) evaluated on those coordinates, so
//! a renderer holding world-space SH coefficients c_T gets the ωo-space ones with
//! `ShRotation::new(order, &OmegaOSpace::world_to_local)` (that rotation maps the coefficients
//! of f to those of `f(Rᵀ u)`, the same function written in ωo-space coordinates), and the
//! multiple-scattering response is `C_S[θo] · (R_ωo c_T)`.
//!
//! Rows: `theta_count` values of θo equally spaced over [−π/2, π/2], **both endpoints
//! included**: `θo_k = −π/2 + kπ/(theta_count − 1)`. [`CsTable::lookup`] interpolates linearly
//! in θo between neighbouring rows and clamps outside the range.
//!
//! How it works: with ωi = (sin θ, cos θ cos φ, cos θ sin φ) the integral is
//! `∫ dθ cos²θ ∫ dφ Y_j(θ, φ) S(θ, φ)` (one cos θ from dω, one from the BCSDF's cos θi). On a
//! circle of constant θ, Y_j is a trigonometric polynomial of degree ≤ L in φ, so only the
//! Fourier coefficients of S up to degree L enter: Y_j's come exactly from 2L + 2 equally
//! spaced φ nodes, S's from Gauss–Legendre panels in φ graded around φ = π (where the TT lobe
//! peaks, down to 0.25° panels: γ_TT ≥ 0.5°). S is a φ-independent R term plus the TT lobe's
//! longitudinal part times its azimuthal lobe, so the φ integral is done once per row for the
//! azimuthal lobe, not at every θ node (the table costs milliseconds, not seconds). The θ integral uses Gauss–Legendre panels graded
//! around θ = −θo (where both longitudinal lobes peak, down to 0.25° panels: β ≥ 0.5°). The
//! scheme needs only `FiberScattering::eval_angles`, so it works for any lobe widths in the
//! model's valid range. A Lambertian fiber surface has no per-tangent BCSDF (it depends on
//! the hit normal), so it has no table: [`CsTable::for_material`] rejects it.

use std::f64::consts::{FRAC_PI_2, PI};

use glam::{DMat3, DVec3};
use rayon::prelude::*;

use crate::Rgb;
use crate::bcsdf::{FiberScattering, Material};
use crate::quadrature::gauss_legendre_pairs;
use crate::sh::{sh_count, sh_eval};

/// Width of the innermost quadrature panels (radians), half the narrowest lobe allowed.
const FINEST_PANEL: f64 = 0.25 * PI / 180.0;
/// Widest quadrature panel (radians).
const WIDEST_PANEL: f64 = PI / 8.0;
/// Gauss–Legendre nodes per panel.
const NODES_PER_PANEL: usize = 12;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CsTableError {
    #[error("a Lambertian fiber surface has no per-tangent BCSDF, so no C_S table")]
    Lambertian,
    #[error("C_S needs at least 2 θo values, got {0}")]
    TooFewAngles(usize),
    #[error("SH order {0} is above the supported 8")]
    OrderTooHigh(usize),
}

/// The ωo-space of a fiber tangent and a view direction (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OmegaOSpace {
    /// θo = asin(ωo·t) in [−π/2, π/2].
    pub theta_o: f64,
    /// Rows t, b, c: maps world coordinates to ωo-space coordinates.
    pub world_to_local: DMat3,
}

impl OmegaOSpace {
    /// The frame for unit tangent `t` and unit view direction `wo`.
    #[must_use]
    pub fn new(t: DVec3, wo: DVec3) -> Self {
        let along = wo.dot(t).clamp(-1.0, 1.0);
        let perp = wo - along * t;
        let b =
            if perp.length() > AZIMUTH_MIN_PERP { perp.normalize() } else { crate::sg::frame_from_z(t).0 };
        let c = t.cross(b);
        Self { theta_o: along.atan2(perp.length()), world_to_local: DMat3::from_cols(t, b, c).transpose() }
    }

    /// `w` in ωo-space coordinates.
    #[must_use]
    pub fn to_local(&self, w: DVec3) -> DVec3 {
        self.world_to_local * w
    }
}

/// Below this `|ω − (ω·t) t|` a direction ω counts as lying along ±t: its azimuth about the
/// fiber is undefined and the fixed axis `sg::frame_from_z(t).0` is used instead
/// ([`OmegaOSpace`], `shading::bcsdf::FiberAngles`, and their WGSL twins in
/// `shaders/shared/shading.wgsl`, which use the same value). It sits above f32 rounding: a
/// direction meant to lie along t but held in f32 (the baked tangents, the GPU's view
/// directions) is off by up to ~2e-7 (measured on lavapipe for ωo = ±normalize(t) over every
/// segment of the default fabric: |ω⊥| ≤ 2.2e-7), so a smaller threshold would turn rounding
/// noise into an azimuth on the GPU and in any f64 code fed f32 data. 1e-6 rad is 0.2″.
pub const AZIMUTH_MIN_PERP: f64 = 1e-6;

/// C_S for one material: `theta_count` rows of `(L+1)²` RGB coefficients.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CsTable {
    sh_order: usize,
    theta_count: usize,
    /// Row-major: `coeffs[k * sh_count + j]`.
    coeffs: Vec<Rgb>,
}

impl CsTable {
    /// The table of a material; Lambertian materials have none.
    pub fn for_material(
        material: &Material,
        sh_order: usize,
        theta_count: usize,
    ) -> Result<Self, CsTableError> {
        match material {
            Material::Fiber(f) => Self::new(f, sh_order, theta_count),
            Material::Lambert(_) => Err(CsTableError::Lambertian),
        }
    }

    /// Computes every row (rayon over θo).
    pub fn new(fiber: &FiberScattering, sh_order: usize, theta_count: usize) -> Result<Self, CsTableError> {
        if theta_count < 2 {
            return Err(CsTableError::TooFewAngles(theta_count));
        }
        if sh_order > 8 {
            return Err(CsTableError::OrderTooHigh(sh_order));
        }
        let rows: Vec<Vec<Rgb>> = (0..theta_count)
            .into_par_iter()
            .map(|k| cs_coefficients(fiber, sh_order, theta_at(k, theta_count)))
            .collect();
        Ok(Self { sh_order, theta_count, coeffs: rows.concat() })
    }

    /// `self − other`, coefficient by coefficient (tables of one order and row count).
    #[must_use]
    pub(crate) fn minus(&self, other: &Self) -> Self {
        debug_assert_eq!((self.sh_order, self.theta_count), (other.sh_order, other.theta_count));
        let coeffs = self.coeffs.iter().zip(&other.coeffs).map(|(a, b)| *a - *b).collect();
        Self { sh_order: self.sh_order, theta_count: self.theta_count, coeffs }
    }

    /// `self + r b + t c` per channel (tables of one order and row count): a table that is
    /// affine in two colours, from its parts (`bake::recolour::CsParts`).
    #[must_use]
    pub(crate) fn combined(&self, b: &Self, r: Rgb, c: &Self, t: Rgb) -> Self {
        let coeffs = (self.coeffs.iter().zip(&b.coeffs).zip(&c.coeffs))
            .map(|((a, b), c)| *a + r * *b + t * *c)
            .collect();
        Self { sh_order: self.sh_order, theta_count: self.theta_count, coeffs }
    }

    #[must_use]
    pub fn sh_order(&self) -> usize {
        self.sh_order
    }

    #[must_use]
    pub fn theta_count(&self) -> usize {
        self.theta_count
    }

    /// θo of row `k`: `−π/2 + kπ/(theta_count − 1)`.
    #[must_use]
    pub fn theta_o(&self, k: usize) -> f64 {
        theta_at(k, self.theta_count)
    }

    /// Row `k`'s `(L+1)²` coefficients.
    #[must_use]
    pub fn row(&self, k: usize) -> &[Rgb] {
        let n = sh_count(self.sh_order);
        &self.coeffs[k * n..(k + 1) * n]
    }

    /// All rows, row-major (`[k * (L+1)² + j]`).
    #[must_use]
    pub fn coefficients(&self) -> &[Rgb] {
        &self.coeffs
    }

    /// Coefficients at any θo: linear interpolation between the two nearest rows, θo clamped
    /// to [−π/2, π/2].
    #[must_use]
    pub fn lookup(&self, theta_o: f64) -> Vec<Rgb> {
        let last = self.theta_count - 1;
        let x =
            ((theta_o.clamp(-FRAC_PI_2, FRAC_PI_2) + FRAC_PI_2) / PI * last as f64).clamp(0.0, last as f64);
        let k = (x.floor() as usize).min(last - 1);
        let w = x - k as f64;
        self.row(k).iter().zip(self.row(k + 1)).map(|(a, b)| *a * (1.0 - w) + *b * w).collect()
    }
}

fn theta_at(k: usize, count: usize) -> f64 {
    -FRAC_PI_2 + PI * k as f64 / (count - 1) as f64
}

/// Breakpoints graded around `centre` from [`FINEST_PANEL`] (panels double away from it),
/// then split so that no panel is wider than [`WIDEST_PANEL`].
fn graded_breaks(lo: f64, hi: f64, centre: f64) -> Vec<f64> {
    let b = crate::quadrature::graded_breaks(lo, hi, centre, FINEST_PANEL);
    let mut out = vec![b[0]];
    for w in b.windows(2) {
        let pieces = ((w[1] - w[0]) / WIDEST_PANEL).ceil().max(1.0) as usize;
        out.extend((1..=pieces).map(|i| w[0] + (w[1] - w[0]) * i as f64 / pieces as f64));
    }
    out
}

/// Nodes and weights of a panel rule over `breaks`.
fn panel_nodes(breaks: &[f64]) -> Vec<(f64, f64)> {
    let rule = gauss_legendre_pairs(NODES_PER_PANEL);
    let mut out = Vec::with_capacity(rule.len() * breaks.len());
    for w in breaks.windows(2) {
        let (mid, half) = (0.5 * (w[0] + w[1]), 0.5 * (w[1] - w[0]));
        out.extend(rule.iter().map(|&(x, wt)| (mid + half * x, half * wt)));
    }
    out
}

/// One row: `C_S[θo, j]` for `j < (L+1)²`; see the module docs.
#[must_use]
pub fn cs_coefficients(fiber: &FiberScattering, order: usize, theta_o: f64) -> Vec<Rgb> {
    let n = sh_count(order);
    let degree = order; // Fourier degrees 0..=L.
    let theta_nodes = panel_nodes(&graded_breaks(-FRAC_PI_2, FRAC_PI_2, -theta_o));
    let phi_nodes = panel_nodes(&graded_breaks(0.0, 2.0 * PI, PI));
    // cos(mφ), sin(mφ) at the φ quadrature nodes.
    let phi_trig: Vec<Vec<(f64, f64)>> = phi_nodes
        .iter()
        .map(|&(phi, _)| (0..=degree).map(|m| (m as f64 * phi).sin_cos()).collect())
        .collect();
    // Equally spaced nodes for the exact Fourier coefficients of Y_j on a circle.
    let uniform = 2 * order + 2;
    let uniform_phi: Vec<f64> = (0..uniform).map(|i| 2.0 * PI * i as f64 / uniform as f64).collect();
    // S(θ, φ) = U(θ) + T(θ) N_TT(−φ) (`FiberScattering::longitudinal_parts`, θo's azimuth is
    // 0): the Fourier coefficients of N_TT are integrated once, and U's are 2π U at m = 0.
    let mut n_cos = vec![0.0; degree + 1];
    let mut n_sin = vec![0.0; degree + 1];
    for (&(phi, w_phi), trig) in phi_nodes.iter().zip(&phi_trig) {
        let n_tt = fiber.tt_azimuthal(-phi) * w_phi;
        for (m, &(sm, cm)) in trig.iter().enumerate() {
            n_cos[m] += n_tt * cm;
            n_sin[m] += n_tt * sm;
        }
    }
    let phi_weight: f64 = phi_nodes.iter().map(|&(_, w)| w).sum();
    let mut y = vec![0.0; n];
    let mut y_fourier = vec![(0.0, 0.0); n * (degree + 1)];
    let mut out = vec![Rgb::ZERO; n];
    let mut s_cos = vec![Rgb::ZERO; degree + 1];
    let mut s_sin = vec![Rgb::ZERO; degree + 1];
    for &(theta, w_theta) in &theta_nodes {
        let (st, ct) = theta.sin_cos();
        // Fourier coefficients of S(θ, ·): s_m = ∫ S cos mφ dφ, s'_m = ∫ S sin mφ dφ.
        let (uniform_part, tt_part) = fiber.longitudinal_parts(theta, theta_o);
        for m in 0..=degree {
            s_cos[m] = tt_part * n_cos[m];
            s_sin[m] = tt_part * n_sin[m];
        }
        s_cos[0] += uniform_part * phi_weight;
        // Y_j(θ, φ) = a_0 + Σ_m a_m cos mφ + b_m sin mφ, exactly from the uniform nodes.
        y_fourier.fill((0.0, 0.0));
        for &phi in &uniform_phi {
            let (sp, cp) = phi.sin_cos();
            sh_eval(order, DVec3::new(st, ct * cp, ct * sp), &mut y);
            for m in 0..=degree {
                let (sm, cm) = (m as f64 * phi).sin_cos();
                for j in 0..n {
                    let f = &mut y_fourier[j * (degree + 1) + m];
                    f.0 += y[j] * cm;
                    f.1 += y[j] * sm;
                }
            }
        }
        let weight = w_theta * ct * ct;
        for (j, o) in out.iter_mut().enumerate() {
            let mut sum = Rgb::ZERO;
            for m in 0..=degree {
                let (a, b) = y_fourier[j * (degree + 1) + m];
                let scale = if m == 0 { 1.0 } else { 2.0 } / uniform as f64;
                sum += (s_cos[m] * a + s_sin[m] * b) * scale;
            }
            *o += sum * weight;
        }
    }
    out
}

/// `∫ g(θ) dθ` helper for the tests' independent integrals.
#[cfg(test)]
fn integrate_theta(centre: f64, f: impl FnMut(f64) -> f64) -> f64 {
    let rule = gauss_legendre_pairs(NODES_PER_PANEL);
    crate::quadrature::integrate_panels(&rule, &graded_breaks(-FRAC_PI_2, FRAC_PI_2, centre), f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bcsdf::FiberParams;
    use crate::pathtrace::integrator::pixel_rng;
    use rand::Rng;

    fn fiber(beta_r: f64, beta_tt: f64, gamma: f64) -> FiberScattering {
        FiberScattering::new(&FiberParams {
            c_r: Rgb::new(0.04, 0.05, 0.06),
            beta_r_deg: beta_r,
            c_tt: Rgb::new(0.85, 0.6, 0.3),
            beta_tt_deg: beta_tt,
            gamma_tt_deg: gamma,
        })
        .unwrap()
    }

    #[test]
    fn omega_o_space_puts_wo_in_the_xy_plane() {
        let t = DVec3::new(0.3, -0.5, 0.8).normalize();
        let wo = DVec3::new(-0.2, 0.9, 0.4).normalize();
        let space = OmegaOSpace::new(t, wo);
        let local = space.to_local(wo);
        let expect = DVec3::new(space.theta_o.sin(), space.theta_o.cos(), 0.0);
        assert!((local - expect).length() < 1e-12, "{local} {expect}");
        assert!((space.to_local(t) - DVec3::X).length() < 1e-12);
        assert!((space.world_to_local.determinant() - 1.0).abs() < 1e-12);
        let pole = OmegaOSpace::new(t, t);
        assert!((pole.theta_o - FRAC_PI_2).abs() < 1e-9 && pole.world_to_local.is_finite());
        // Within AZIMUTH_MIN_PERP of ±t (f32 rounding of a direction along t) b is the pole's.
        let (u, v) = crate::sg::frame_from_z(t);
        for wo in [t, -t] {
            for tilt in [0.0, 1e-9, 5e-7] {
                let near = OmegaOSpace::new(t, (wo + tilt * v).normalize());
                assert_eq!(near.world_to_local.row(1), u, "tilt {tilt}");
            }
            let outside = OmegaOSpace::new(t, (wo + 2e-6 * v).normalize());
            assert!((outside.world_to_local.row(1) - v).length() < 1e-9);
        }
    }

    /// The separated azimuth integral equals integrating S itself over the same φ nodes at
    /// every θ node (the direct double sum the table used before), to rounding.
    #[test]
    fn separated_azimuth_integral_equals_the_direct_double_sum() {
        for (f, order) in
            [(fiber(1.0, 10.0, 19.8), 4), (fiber(7.2, 27.0, 38.3), 2), (fiber(0.5, 0.5, 0.5), 6)]
        {
            for theta_o in [-1.4, -0.3, 0.0, 0.7, FRAC_PI_2] {
                let fast = cs_coefficients(&f, order, theta_o);
                let n = sh_count(order);
                let mut direct = vec![Rgb::ZERO; n];
                let mut y = vec![0.0; n];
                for &(theta, w_theta) in &panel_nodes(&graded_breaks(-FRAC_PI_2, FRAC_PI_2, -theta_o)) {
                    let (st, ct) = theta.sin_cos();
                    for &(phi, w_phi) in &panel_nodes(&graded_breaks(0.0, 2.0 * PI, PI)) {
                        sh_eval(order, DVec3::new(st, ct * phi.cos(), ct * phi.sin()), &mut y);
                        let s = f.eval_angles(theta, phi, theta_o, 0.0) * (w_theta * w_phi * ct * ct);
                        for (d, yj) in direct.iter_mut().zip(&y) {
                            *d += s * *yj;
                        }
                    }
                }
                let scale = direct[0].max_element().max(1e-12);
                for (j, (a, b)) in fast.iter().zip(&direct).enumerate() {
                    assert!(
                        (*a - *b).abs().max_element() < 1e-9 * scale,
                        "order {order} θo {theta_o} j {j}: {a} vs {b}"
                    );
                }
            }
        }
    }

    #[test]
    fn dc_coefficient_is_the_albedo_over_incident_directions() {
        // Independent: world-space evaluation, θ panels and a dense periodic φ rule.
        let f = fiber(1.0, 27.0, 38.0);
        let t = DVec3::new(0.0, 0.6, 0.8);
        let frame = crate::bcsdf::FiberFrame::new(t);
        let y0 = 0.5 / PI.sqrt();
        for theta_o_deg in [-89.0_f64, -40.0, 0.0, 25.0, 70.0] {
            let theta_o = theta_o_deg.to_radians();
            let wo = frame.direction(theta_o, 0.7);
            let space = OmegaOSpace::new(t, wo);
            let row = cs_coefficients(&f, 3, space.theta_o);
            let phis = 720_u32;
            for (ch, &got) in row[0].to_array().iter().enumerate() {
                let albedo = integrate_theta(-theta_o, |theta| {
                    let mut s = 0.0;
                    for i in 0..phis {
                        let wi = frame.direction(theta, 2.0 * PI * (f64::from(i) + 0.5) / f64::from(phis));
                        s += f.eval(t, wi, wo)[ch];
                    }
                    s * 2.0 * PI / f64::from(phis) * theta.cos() * theta.cos()
                });
                assert!(got.is_finite());
                assert!(
                    (got - y0 * albedo).abs() < 1e-7 * (1.0 + albedo),
                    "θo {theta_o_deg}: {got} vs {}",
                    y0 * albedo
                );
            }
        }
    }

    #[test]
    fn table_matches_monte_carlo_with_the_bcsdf_sampler() {
        let order = 4;
        let n = sh_count(order);
        for f in [fiber(1.0, 27.0, 38.0), fiber(0.5, 5.0, 8.0)] {
            let material = Material::Fiber(f.clone());
            let t = DVec3::new(1.0, 1.0, 0.2).normalize();
            let frame = crate::bcsdf::FiberFrame::new(t);
            for theta_o_deg in [-89.0_f64, -30.0, 0.0, 45.0, 89.0] {
                let wo = frame.direction(theta_o_deg.to_radians(), 1.3);
                let space = OmegaOSpace::new(t, wo);
                let got = cs_coefficients(&f, order, space.theta_o);
                assert!(got.iter().all(|c| c.is_finite()));
                let samples = 40_000_u32;
                let mut sum = vec![Rgb::ZERO; n];
                let mut sum2 = vec![Rgb::ZERO; n];
                let mut y = vec![0.0; n];
                let mut rng = pixel_rng(7, theta_o_deg.to_bits());
                for _ in 0..samples {
                    let u = [rng.random(), rng.random(), rng.random()];
                    let Some((wi, pdf)) = material.sample(t, DVec3::Z, wo, u) else { continue };
                    let weight = material.eval_cos(t, DVec3::Z, wi, wo) / pdf;
                    sh_eval(order, space.to_local(wi), &mut y);
                    for j in 0..n {
                        let x = weight * y[j];
                        sum[j] += x;
                        sum2[j] += x * x;
                    }
                }
                let ns = f64::from(samples);
                for j in 0..n {
                    let mean = sum[j] / ns;
                    let err = ((sum2[j] / ns - mean * mean).max(Rgb::ZERO) / (ns - 1.0)).powf(0.5);
                    let bound = 4.5 * err + Rgb::splat(1e-6);
                    assert!(
                        (got[j] - mean).abs().cmple(bound).all(),
                        "θo {theta_o_deg}, j {j}: table {} vs MC {mean} ± {err}",
                        got[j]
                    );
                }
            }
        }
    }

    #[test]
    fn lookup_interpolates_linearly_and_clamps() {
        let f = fiber(2.0, 20.0, 30.0);
        let table = CsTable::new(&f, 2, 5).unwrap();
        assert!((table.theta_o(0) + FRAC_PI_2).abs() < 1e-15);
        assert!((table.theta_o(4) - FRAC_PI_2).abs() < 1e-15);
        let mid = table.lookup(0.5 * (table.theta_o(1) + table.theta_o(2)));
        for (j, got) in mid.iter().enumerate() {
            let expect = 0.5 * (table.row(1)[j] + table.row(2)[j]);
            assert!((*got - expect).length() < 1e-15);
        }
        assert_eq!(table.lookup(-10.0), table.row(0).to_vec());
        assert_eq!(table.lookup(10.0), table.row(4).to_vec());
        let lambert = Material::Lambert(crate::bcsdf::Lambertian::new(Rgb::ONE).unwrap());
        assert_eq!(CsTable::for_material(&lambert, 2, 5), Err(CsTableError::Lambertian));
    }
}
