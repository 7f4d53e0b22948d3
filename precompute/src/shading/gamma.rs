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
    /// ξ_b = h cos φ' and ξ_c = h sin φ', φ' measured from ωo's azimuth.
    pub b: f64,
    pub c: f64,
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
        Self { theta_o: space.theta_o, theta: local.x.atan2(h), cos_theta: h, h_plus_b, h_minus_b, b, c }
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

/// The light a fiber lobe brings (`shading::multiple`'s fiber lobes), per unit strength, over
/// the angles of its arrival direction ωi in the shaded fiber's frame, about an axis ξ at
/// (θ', φ'): `L(ωi) dωi = p(θi − θ') v(φi − φ') dθi dφi` with
/// - `p(Δθ) = (1 + 2 Σ_k c_k cos kΔθ + s_k sin kΔθ) / 2π`, the Fourier series of the
///   longitudinal offset, clamped at zero (its terms are means `c_k = E cos kΔθ`, so it
///   integrates to 1 over a period);
/// - `v(Δφ) = (1 + 2 Σ_k a_k cos kΔφ + b_k sin kΔφ) / 2π` likewise for the azimuthal offset,
///   Δφ turning in the positive sense about the tangent.
#[derive(Debug, Clone, PartialEq)]
pub struct LobeAngles {
    /// `[c_1, s_1, c_2, s_2, …]`.
    pub fourier: Vec<f64>,
    /// `[a_1, b_1, a_2, b_2, …]`.
    pub azimuth: Vec<f64>,
}

impl LobeAngles {
    /// The unit lobe whose offsets have the means `longitudinal = [E cos Δθ, E sin Δθ, E cos
    /// 2Δθ, …]` and `azimuth = [E cos Δφ, E sin Δφ, …]`, both series smoothed by Jackson's
    /// factors ([`jackson_factor`]): cut after K terms, the series of a sharp density rings
    /// below zero (an offset 5° wide, cut at 12 terms, loses a third of its mass to the
    /// clamp), while the series smoothed by a non-negative kernel about 180°/(K+1) wide is
    /// itself a density (7° for both series' 24 terms).
    #[must_use]
    pub fn from_means(longitudinal: &[f64], azimuth: &[f64]) -> Self {
        Self { fourier: jackson_smoothed(longitudinal), azimuth: jackson_smoothed(azimuth) }
    }

    /// `p(Δθ)`, the longitudinal density (see the type's docs), clamped at zero.
    #[must_use]
    pub fn longitudinal(&self, delta_theta: f64) -> f64 {
        fourier_density(&self.fourier, delta_theta)
    }

    /// `v(Δφ)`, the azimuthal density (see the type's docs), clamped at zero.
    #[must_use]
    pub fn azimuthal(&self, delta_phi: f64) -> f64 {
        fourier_density(&self.azimuth, delta_phi)
    }
}

/// `(1 + 2 Σ_k c_k cos kx + s_k sin kx) / 2π` for `series = [c_1, s_1, c_2, s_2, …]`, clamped
/// at zero: cos kx and sin kx by the rotation recurrence.
fn fourier_density(series: &[f64], x: f64) -> f64 {
    let (s1, c1) = x.sin_cos();
    let (mut sk, mut ck) = (s1, c1);
    let mut v = 1.0;
    for term in series.chunks_exact(2) {
        v += 2.0 * (term[0] * ck + term[1] * sk);
        (ck, sk) = (ck * c1 - sk * s1, sk * c1 + ck * s1);
    }
    (v / (2.0 * PI)).max(0.0)
}

/// `[c_1, s_1, c_2, s_2, …]` with pair k multiplied by Jackson's factor of term k.
fn jackson_smoothed(means: &[f64]) -> Vec<f64> {
    let terms = means.len() / 2;
    means
        .chunks_exact(2)
        .enumerate()
        .flat_map(|(k, m)| {
            let g = jackson_factor(k + 1, terms);
            [g * m[0], g * m[1]]
        })
        .collect()
}

/// `∫ v(φi − φ') N_TT(φo − φi) dφi` for the lobe's azimuthal series `azimuth` ([`LobeAngles`])
/// and a TT lobe whose von Mises density about π has the Fourier coefficients `tt_ratios`
/// (`I_k(κ_TT)/I_0(κ_TT)`, [`crate::special::bessel_i_ratios`]), at `Φ = φo − φ'` given as its
/// cosine and sine: a convolution, so term by term a product,
/// `(1 + 2 Σ_k (−1)^k ρ_k (a_k cos kΦ + b_k sin kΦ)) / 2π`, clamped at zero.
#[must_use]
pub fn lobe_tt_azimuth(azimuth: &[f64], tt_ratios: &[f64], cos_phi: f64, sin_phi: f64) -> f64 {
    let (mut ck, mut sk) = (cos_phi, sin_phi);
    let mut sign = -1.0;
    let mut v = 1.0;
    for (pair, rho) in azimuth.chunks_exact(2).zip(tt_ratios) {
        v += 2.0 * sign * rho * (pair[0] * ck + pair[1] * sk);
        (ck, sk) = (ck * cos_phi - sk * sin_phi, sk * cos_phi + ck * sin_phi);
        sign = -sign;
    }
    (v / (2.0 * PI)).max(0.0)
}

/// Half-width, in the fiber lobe's standard deviations, of the θi interval
/// [`lobe_quadrature`] integrates over (the Gaussian is e^{−12.5} of its peak there).
pub const LOBE_WINDOW: f64 = 5.0;

/// Nodes on [−1, 1] of [`lobe_quadrature`]'s Gauss–Legendre rule, per panel.
pub const LOBE_NODES: usize = 12;

/// Widest panel, in radians of θi, of [`lobe_quadrature`]'s composite rule: a window wider is
/// cut into equal panels, each with its own [`LOBE_NODES`]-point rule. The longitudinal
/// density's 24 terms vary faster than one 12-point rule resolves over a broad lobe's window
/// (13% off against brute force on the 20°/30° test fiber, whose window spans [−π/2, π/2]);
/// with panels of at most 1.6 rad the rule stays within 1e-3 there, and a lobe narrower than
/// about 9° (the R lobes of silk and cotton) still takes one panel.
pub const LOBE_PANEL_WIDTH: f64 = 1.6;

/// Most panels [`lobe_quadrature`] takes: a guard, since a window is at most π wide (two
/// panels of [`LOBE_PANEL_WIDTH`]).
pub const LOBE_MAX_PANELS: u32 = 8;

static LOBE_LEGENDRE: std::sync::LazyLock<Vec<(f64, f64)>> =
    std::sync::LazyLock::new(|| crate::quadrature::gauss_legendre_pairs(LOBE_NODES));

/// Jackson's damping factor of Fourier term k of a series cut after `terms` terms (Weiße et
/// al. 2006, the kernel polynomial method): `((N − k) cos(πk/N) + sin(πk/N) cot(π/N)) / N`
/// with N = terms + 1. The factors make the cut series a convolution with a non-negative
/// kernel, so a non-negative density stays non-negative and keeps its integral; 1 at k = 0,
/// falling smoothly to 0 past the last term.
#[must_use]
pub fn jackson_factor(k: usize, terms: usize) -> f64 {
    let n = (terms + 1) as f64;
    let k = k as f64;
    let a = PI / n;
    ((n - k) * (a * k).cos() + (a * k).sin() / a.tan()) / n
}

/// Panels of [`lobe_quadrature`]'s composite rule over a window `width` radians wide: the
/// fewest no wider than [`LOBE_PANEL_WIDTH`], at least one and at most [`LOBE_MAX_PANELS`].
#[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
fn lobe_panels(width: f64) -> u32 {
    (width / LOBE_PANEL_WIDTH).ceil().clamp(1.0, f64::from(LOBE_MAX_PANELS)) as u32
}

/// `∫ L(ωi) S(ωi, ωo) cos θi dωi` for the unit lobe `angles` about unit `xi` ([`LobeAngles`]),
/// per RGB channel: unit tangent `t`, unit view direction `wo`. The φi integrals are exact
/// for the series: S_R's azimuth is uniform, so its integral against `v` is `1/2π`; S_TT's
/// von Mises about φ = π convolved with `v` is [`lobe_tt_azimuth`] at `φo − φ'`, with the
/// fiber's own ratios (`FiberConstants::tt_ratios`, computed once per material). The θi
/// integral, per lobe X, is a composite [`LOBE_NODES`]-point Gauss–Legendre rule over the lobe's
/// own Gaussian `exp(−λ_X (θi + θo)²)` within [`LOBE_WINDOW`] standard deviations, clipped to
/// [−π/2, π/2] (a Gauss–Hermite rule lost its nodes past the pole at grazing views: 12% off on
/// the fleece), in equal panels no wider than [`LOBE_PANEL_WIDTH`], with `p`, `cos θi`, Gn and
/// Fresnel exact at each node. Finite and non-negative for any lobe.
#[must_use]
pub fn lobe_quadrature(
    fiber: &FiberConstants,
    gn: &GnTable,
    t: DVec3,
    xi: DVec3,
    angles: &LobeAngles,
    wo: DVec3,
) -> Rgb {
    let axis = AxisInOmegaOSpace::new(t, wo, xi);
    // φo − φ': in ωo-space ξ's azimuth is measured from ωo's, so Φ = −φ'.
    let (cos_phi, sin_phi) =
        if axis.cos_theta > 0.0 { (axis.b / axis.cos_theta, -axis.c / axis.cos_theta) } else { (1.0, 0.0) };
    let tt_azimuth = lobe_tt_azimuth(&angles.azimuth, &fiber.tt_ratios, cos_phi, sin_phi);
    let mut out = Rgb::ZERO;
    for (lobe, lambda_lobe) in [(LOBE_R, fiber.lambda_r), (LOBE_TT, fiber.lambda_tt)] {
        // The lobe's Gaussian exp(−λ_X (θi + θo)²) over ±LOBE_WINDOW standard deviations,
        // clipped to [−π/2, π/2] where the integrand ends.
        let sigma = (0.5 / lambda_lobe).sqrt();
        let lo = (-axis.theta_o - LOBE_WINDOW * sigma).max(-FRAC_PI_2);
        let hi = (-axis.theta_o + LOBE_WINDOW * sigma).min(FRAC_PI_2);
        if hi <= lo {
            continue;
        }
        let panels = lobe_panels(hi - lo);
        let half = 0.5 * (hi - lo) / f64::from(panels);
        let norm = (lambda_lobe / PI).sqrt();
        let mut sum = 0.0_f64;
        let mut fresnel = Rgb::ZERO;
        for panel in 0..panels {
            let mid = lo + f64::from(2 * panel + 1) * half;
            for &(x, w) in LOBE_LEGENDRE.iter() {
                let theta = mid + half * x;
                let cos = theta.cos();
                let offset = theta + axis.theta_o;
                let term = cos
                    * norm
                    * (-lambda_lobe * offset * offset).exp()
                    * angles.longitudinal(theta - axis.theta)
                    / gn.eval(fiber.material, lobe, -theta)
                    * (w * half);
                sum += term;
                fresnel += fiber.fresnel(cos) * term;
            }
        }
        out += if lobe == LOBE_R {
            fresnel / (2.0 * PI)
        } else {
            (Rgb::splat(sum) - fresnel) * fiber.c_tt * tt_azimuth
        };
    }
    out
}
