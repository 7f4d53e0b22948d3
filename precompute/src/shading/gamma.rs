//! Γ(ξ, λ, ωo): the closed-form approximation of paper eq. (2) and Appendix A to
//! `∫ G(ωi; ξ, λ) S(ωi, ωo) cos θi dωi`, with `G(ω; ξ, λ) = exp(λ(ω·ξ − 1))` **unnormalized**
//! (value 1 on its axis) and S our fiber model ([`super::bcsdf`]).
//!
//! Derivation for our S (`docs/MATH.md` has it in full). In the ωo-space of the fiber
//! (`bake::cs_table::OmegaOSpace`: x = t, ωo in the xy plane, so φo = 0) let ξ have fiber angles
//! (θ', φ'), `h = cos θ'`, `ξ_b = h cos φ'`. With dωi = cos θi dθi dφi the φi integral is exact:
//! - R: `∫ G dφi = 2π exp(−λ(1 − cos(θi − θ'))) i0e(λ cos θi h)`; the 2π cancels S_R's 1/(2π).
//! - TT: `∫ G N_TT dφi = exp(−λ(1 − cos(θi − θ'))) i0e(λ_m) e^{λ_m − a − κ} / i0e(κ)` with
//!   `a = λ cos θi h` and `λ_m = |a e^{iφ'} − κ|` (the appendix's λ_m; the von Mises lobe peaks
//!   at φ = π). Overflow- and cancellation-free:
//!   `λ_m = sqrt((a − κ)² + 2κλ cos θi (h − ξ_b))`,
//!   `λ_m − a − κ = −2κλ cos θi (h + ξ_b) / (λ_m + a + κ)`,
//!   where whichever of `h ± ξ_b` would cancel is computed as `ξ_c² / (h ∓ ξ_b)`.
//!
//! What is left is a θi integral of `cos²θi · slow(θi) · exp(−λ_X(θi + θo)²) ·
//! exp(−λ(1 − cos(θi − θ')))`. The paper replaces `1 − cos(θi − θ')` by `(θi − θ')²/2`, so the
//! two Gaussians multiply into `a_X exp(−λ'_X(θi − θ_X)²)` with
//!
//! ```text
//! λ'_X = λ_X + λ/2,   θ_X = (−λ_X θo + (λ/2) θ') / λ'_X,   ln a_X = −(λ_X λ/2 / λ'_X)(θo + θ')²
//! ```
//!
//! (the paper prints `−β_R² θo` in θ_R; with `β_R⁻² = 2λ_R` it must be `β_R⁻²`), evaluates
//! the slowly varying rest at θ_X and integrates the Gaussian over [−π/2, π/2] exactly:
//! `½ sqrt(π/λ'_X) [erf(sqrt(λ'_X)(π/2 − θ_X)) + erf(sqrt(λ'_X)(π/2 + θ_X))]`. Both erf
//! arguments are ≥ 0 (θ_X lies between −θo and θ'), so this sum never cancels. The rest, the
//! appendix's B_R and B_TT in our normalization:
//!
//! ```text
//! B_R  = F_R(θ_R) cos²θ_R sqrt(λ_R/π) / Gn_R(−θ_R) · i0e(λ cos θ_R h)
//! B_TT = (1 − F_R(θ_TT)) C_TT cos²θ_TT sqrt(λ_TT/π) / Gn_TT(−θ_TT) · i0e(λ_m) e^{λ_m − a − κ} / i0e(κ)
//! Γ    = a_R B_R E_R + a_TT B_TT E_TT          (E_X the erf integral above)
//! ```
//!
//! `sqrt(λ_X/π) = 1/(sqrt(2π) β_X)` is the appendix's `1/(sqrt(2π) β_X)`, the appendix's
//! `I0(x)/e^x` are `i0e(x)`, its `𝒢(−θ; β⁻²/2)` is our Gn; the F_R there has a sign typo (we use
//! the Schlick form of `bcsdf`). So the appendix's constants agree with our S: the R lobe's
//! 1/(2π) and N_TT's 1/(2π) both cancel against the exact azimuthal integral's 2π.
//!
//! Every exponential has a non-positive argument and every Bessel function is scaled, so Γ is
//! finite for any λ ≥ 0 (also far outside the λ ≥ 100 the approximation is meant for; the
//! tests measure its accuracy there too).

use std::f64::consts::{FRAC_PI_2, PI};

use glam::DVec3;

use super::bcsdf::{FiberConstants, LOBE_R, LOBE_TT};
use crate::Rgb;
use crate::bake::cs_table::OmegaOSpace;
use crate::bake::tables::GnTable;
use crate::special::{erf, i0e};

/// The light axis ξ seen from ωo-space: θ', `h = cos θ'` and `h ± ξ_b` without cancellation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisInOmegaOSpace {
    /// θo of the view direction.
    pub theta_o: f64,
    /// θ' = atan2(ξ·t, |ξ⊥|).
    pub theta: f64,
    /// h = cos θ' = |ξ⊥| = sqrt(ξ_b² + ξ_c²).
    pub cos_theta: f64,
    /// h + ξ_b = h (1 + cos φ') ≥ 0.
    pub h_plus_b: f64,
    /// h − ξ_b = h (1 − cos φ') ≥ 0.
    pub h_minus_b: f64,
}

impl AxisInOmegaOSpace {
    /// For unit tangent `t`, unit view direction `wo` and unit axis `xi`.
    #[must_use]
    pub fn new(t: DVec3, wo: DVec3, xi: DVec3) -> Self {
        let space = OmegaOSpace::new(t, wo);
        let local = space.to_local(xi);
        let (b, c) = (local.y, local.z);
        let h = b.hypot(c);
        // (h + b)(h − b) = c²: compute the larger factor directly and the smaller from it.
        let (h_plus_b, h_minus_b) = if b >= 0.0 {
            let plus = h + b;
            (plus, if plus > 0.0 { c * c / plus } else { 0.0 })
        } else {
            let minus = h - b;
            (c * c / minus, minus)
        };
        Self { theta_o: space.theta_o, theta: local.x.atan2(h), cos_theta: h, h_plus_b, h_minus_b }
    }
}

/// The Gaussian part of one lobe: its centre θ_X and `a_X · E_X` (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LobeGaussian {
    pub centre: f64,
    pub weight: f64,
}

/// `θ_X` and `a_X E_X` for a lobe of longitudinal sharpness `lambda_lobe` (λ_X) and an SG of
/// sharpness `lambda` at fiber angle `theta_axis` (θ'), seen from `theta_o`.
#[must_use]
pub fn lobe_gaussian(lambda_lobe: f64, lambda: f64, theta_o: f64, theta_axis: f64) -> LobeGaussian {
    let half = 0.5 * lambda;
    let sharpness = lambda_lobe + half;
    let centre = ((-lambda_lobe * theta_o + half * theta_axis) / sharpness).clamp(-FRAC_PI_2, FRAC_PI_2);
    let sum = theta_o + theta_axis;
    let log_a = -(lambda_lobe * half / sharpness) * sum * sum;
    let s = sharpness.sqrt();
    let e = 0.5 * (PI / sharpness).sqrt() * (erf(s * (FRAC_PI_2 - centre)) + erf(s * (FRAC_PI_2 + centre)));
    LobeGaussian { centre, weight: log_a.exp() * e }
}

/// The TT azimuthal factor `i0e(λ_m) e^{λ_m − a − κ} / i0e(κ)` at `cos θi`, for the SG
/// `lambda` whose axis is `axis` (see the module docs).
#[must_use]
pub fn tt_azimuthal(fiber: &FiberConstants, lambda: f64, cos_theta_i: f64, axis: &AxisInOmegaOSpace) -> f64 {
    let kappa = fiber.kappa;
    let a = lambda * cos_theta_i * axis.cos_theta;
    let scale = 2.0 * kappa * lambda * cos_theta_i;
    let lambda_m = ((a - kappa) * (a - kappa) + scale * axis.h_minus_b).sqrt();
    let deficit = -scale * axis.h_plus_b / (lambda_m + a + kappa);
    i0e(lambda_m) * deficit.exp() / fiber.i0e_kappa
}

/// Γ(ξ, λ, ωo) per RGB channel: unit tangent `t`, unit SG axis `xi`, sharpness `lambda ≥ 0`,
/// unit view direction `wo`; Gn from the baked table. See the module docs.
#[must_use]
pub fn gamma(fiber: &FiberConstants, gn: &GnTable, t: DVec3, xi: DVec3, lambda: f64, wo: DVec3) -> Rgb {
    gamma_in_omega_o_space(fiber, gn, &AxisInOmegaOSpace::new(t, wo, xi), lambda)
}

/// [`gamma`] with the axis already expressed in ωo-space.
#[must_use]
pub fn gamma_in_omega_o_space(
    fiber: &FiberConstants,
    gn: &GnTable,
    axis: &AxisInOmegaOSpace,
    lambda: f64,
) -> Rgb {
    let r = lobe_gaussian(fiber.lambda_r, lambda, axis.theta_o, axis.theta);
    let cos_r = r.centre.cos().max(0.0);
    let b_r = cos_r * cos_r * (fiber.lambda_r / PI).sqrt() / gn.eval(fiber.material, LOBE_R, -r.centre)
        * i0e(lambda * cos_r * axis.cos_theta);
    let tt = lobe_gaussian(fiber.lambda_tt, lambda, axis.theta_o, axis.theta);
    let cos_tt = tt.centre.cos().max(0.0);
    let b_tt = cos_tt * cos_tt * (fiber.lambda_tt / PI).sqrt() / gn.eval(fiber.material, LOBE_TT, -tt.centre)
        * tt_azimuthal(fiber, lambda, cos_tt, axis);
    fiber.fresnel(cos_r) * (r.weight * b_r)
        + (Rgb::ONE - fiber.fresnel(cos_tt)) * fiber.c_tt * (tt.weight * b_tt)
}

/// Positive nodes x_k of the 8-point Gauss–Hermite rule (weight `e^{−x²}`), and its weights
/// times `e^{x_k²}`, so that `∫ f dx ≈ Σ_k w_k e^{x_k²} f(±x_k)` for an integrand `f` that
/// is a Gaussian times a slowly varying factor.
const HERMITE_NODES: [f64; 4] =
    [0.381_186_990_207_322, 1.157_193_712_446_78, 1.981_656_756_695_843, 2.930_637_420_257_244];
const HERMITE_SCALED_WEIGHTS: [f64; 4] =
    [0.764_544_128_651_728_8, 0.792_890_048_386_401_2, 0.866_752_606_563_357_3, 1.071_930_144_246_006_3];

/// Γ(ξ, λ, ωo) by quadrature, accurate for broad SGs too (the forward lobe's λ is 0.5–30,
/// where the closed form [`gamma`] is off by up to 70%; `docs/MATH.md`). The φi integral is
/// the same exact one; the θi integral, per lobe X, is an 8-point Gauss–Hermite rule centred
/// on the product of the lobe's Gaussian and the SG's quadratic approximation (the closed
/// form's `θ_X`, `λ'_X`), with the exact integrand at each node: the SG's `1 − cos(θi − θ')`
/// itself and the slowly varying rest (`cos²θi`, Gn, the azimuthal factors, Fresnel) where
/// the closed form reads them at `θ_X` alone. Nodes beyond ±π/2 count zero (the integrand
/// ends there). Every exponential has a non-positive argument, so the result is finite and
/// non-negative for any λ ≥ 0.
#[must_use]
pub fn gamma_quadrature(
    fiber: &FiberConstants,
    gn: &GnTable,
    t: DVec3,
    xi: DVec3,
    lambda: f64,
    wo: DVec3,
) -> Rgb {
    let axis = AxisInOmegaOSpace::new(t, wo, xi);
    let half = 0.5 * lambda;
    let mut out = Rgb::ZERO;
    for (lobe, lambda_lobe) in [(LOBE_R, fiber.lambda_r), (LOBE_TT, fiber.lambda_tt)] {
        let sharpness = lambda_lobe + half;
        let centre = (-lambda_lobe * axis.theta_o + half * axis.theta) / sharpness;
        let step = 1.0 / sharpness.sqrt();
        let norm = (lambda_lobe / PI).sqrt();
        for (x, w) in HERMITE_NODES.iter().zip(HERMITE_SCALED_WEIGHTS) {
            for theta in [centre - x * step, centre + x * step] {
                if theta.abs() >= FRAC_PI_2 {
                    continue;
                }
                let cos = theta.cos();
                let sum = theta + axis.theta_o;
                let s = (0.5 * (theta - axis.theta)).sin();
                let gaussians = (-lambda_lobe * sum * sum - 2.0 * lambda * s * s).exp();
                let common =
                    cos * cos * norm * gaussians / gn.eval(fiber.material, lobe, -theta) * (w * step);
                let f = fiber.fresnel(cos);
                out += if lobe == LOBE_R {
                    f * (common * i0e(lambda * cos * axis.cos_theta))
                } else {
                    (Rgb::ONE - f) * fiber.c_tt * (common * tt_azimuthal(fiber, lambda, cos, &axis))
                };
            }
        }
    }
    out
}
