//! The fiber model `S(ωi, ωo) cos θi` as the renderer evaluates it: from per-material constants
//! and the baked Gn table (`bake::tables::GnTable`, f32 nodes, cubic Hermite), not from
//! `bcsdf::FiberScattering`'s own f64 table. The formula is exactly the one of
//! `bcsdf::fiber` (see `docs/MATH.md`):
//!
//! ```text
//! S cos θi = cos θi · [ F_R(θi) M_R / (2π) + (1 − F_R(θi)) C_TT M_TT N_TT(φo − φi) ]
//! M_X      = sqrt(λ_X/π) exp(−λ_X (θi + θo)²) / Gn_X(−θi),   λ_X = 1/(2β_X²)
//! N_TT     = exp(−κ (1 + cos(φo − φi))) / (2π i0e(κ)),      κ = γ_TT⁻²
//! F_R(θ)   = C_R + (1 − C_R)(1 − cos θ)^5
//! ```
//!
//! How it works (the order the GPU follows): with `s = ω·t`, `ω⊥ = ω − s t`, the fiber angle
//! is `θ = atan2(s, |ω⊥|)` and `cos θ = |ω⊥|`; `1 + cos(φo − φi)` is `½|ûi + ûo|²` with
//! `û = ω⊥/|ω⊥|`, which has no cancellation at the TT peak (φo − φi = π). A direction within
//! `|ω⊥| ≤ 1e-6` of ±t (`bake::cs_table::AZIMUTH_MIN_PERP`, above f32 rounding) has no usable
//! azimuth; it gets `û = sg::frame_from_z(t).0`, the same axis `bake::cs_table::OmegaOSpace`
//! uses (and `FiberFrame`'s φ = 0). The WGSL computes the same `ω⊥` as `(t × ω) × t`, which
//! does not cancel in f32 near ±t (in f64 `ω − s t` is accurate enough).

use std::f64::consts::PI;

use glam::DVec3;

use crate::Rgb;
use crate::bake::cs_table::AZIMUTH_MIN_PERP;
use crate::bake::iirtf::LOBE_AZIMUTH_TERMS;
use crate::bake::tables::GnTable;
use crate::bcsdf::{BETA_RANGE_DEG, FiberParams, GAMMA_RANGE_DEG};
use crate::params::{ParamError, check_range, check_rgb};
use crate::special::{bessel_i_ratios, i0e};

/// Gn table lobe index of the R lobe.
pub const LOBE_R: usize = 0;
/// Gn table lobe index of the TT lobe.
pub const LOBE_TT: usize = 1;

/// The constants of one fiber material that shading needs, as a GPU uniform would hold them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FiberConstants {
    pub c_r: Rgb,
    pub c_tt: Rgb,
    /// `λ_R = 1/(2β_R²)`, β in radians.
    pub lambda_r: f64,
    /// `λ_TT = 1/(2β_TT²)`.
    pub lambda_tt: f64,
    /// `κ = γ_TT⁻²`.
    pub kappa: f64,
    /// `i0e(κ) = e^{−κ} I0(κ)`.
    pub i0e_kappa: f64,
    /// `I_k(κ)/I_0(κ)` for k = 1..=[`LOBE_AZIMUTH_TERMS`]: the TT lobe's azimuthal Fourier
    /// coefficients, which the fiber lobes' azimuth is convolved with
    /// ([`super::gamma::lobe_tt_azimuth`]).
    pub tt_ratios: [f64; LOBE_AZIMUTH_TERMS],
    /// Material slot: the row of the Gn table (and the index of the C_S table).
    pub material: usize,
}

impl FiberConstants {
    /// Validates `params` (the ranges of `bcsdf::FiberScattering::new`) and derives the
    /// constants; `material` is the slot whose Gn rows belong to these parameters.
    pub fn new(params: &FiberParams, material: usize) -> Result<Self, ParamError> {
        let c_r = check_rgb("c_r", params.c_r, 0.0, 1.0)?;
        let c_tt = check_rgb("c_tt", params.c_tt, 0.0, 1.0)?;
        let (blo, bhi) = BETA_RANGE_DEG;
        let beta_r = check_range("beta_r_deg", params.beta_r_deg, blo, bhi)?.to_radians();
        let beta_tt = check_range("beta_tt_deg", params.beta_tt_deg, blo, bhi)?.to_radians();
        let (glo, ghi) = GAMMA_RANGE_DEG;
        let gamma = check_range("gamma_tt_deg", params.gamma_tt_deg, glo, ghi)?.to_radians();
        let kappa = 1.0 / (gamma * gamma);
        let mut tt_ratios = [0.0; LOBE_AZIMUTH_TERMS];
        bessel_i_ratios(kappa, &mut tt_ratios);
        Ok(Self {
            c_r,
            c_tt,
            lambda_r: 0.5 / (beta_r * beta_r),
            lambda_tt: 0.5 / (beta_tt * beta_tt),
            kappa,
            i0e_kappa: i0e(kappa),
            tt_ratios,
            material,
        })
    }

    /// `F_R(θ) = C_R + (1 − C_R)(1 − cos θ)^5` for `cos θ` (clamped to [0, 1]).
    #[must_use]
    pub fn fresnel(&self, cos_theta: f64) -> Rgb {
        let m = (1.0 - cos_theta.clamp(0.0, 1.0)).powi(5);
        self.c_r + (Rgb::ONE - self.c_r) * m
    }

    /// The longitudinal lobe `M_X(θi, θo) = sqrt(λ_X/π) exp(−λ_X (θi + θo)²) / Gn_X(−θi)`.
    #[must_use]
    pub fn longitudinal(&self, gn: &GnTable, lobe: usize, theta_i: f64, theta_o: f64) -> f64 {
        let lambda = if lobe == LOBE_R { self.lambda_r } else { self.lambda_tt };
        let sum = theta_i + theta_o;
        (lambda / PI).sqrt() * (-lambda * sum * sum).exp() / gn.eval(self.material, lobe, -theta_i)
    }
}

/// A direction in the fiber frame of unit tangent `t`: `θ = atan2(ω·t, |ω⊥|)`, `cos θ = |ω⊥|`,
/// and the unit azimuthal direction `û = ω⊥/|ω⊥|`, or `frame_from_z(t).0` when
/// `|ω⊥| ≤ AZIMUTH_MIN_PERP` (1e-6, the threshold of `OmegaOSpace`: closer to the pole an f32
/// direction's azimuth is rounding noise).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FiberAngles {
    pub theta: f64,
    pub cos_theta: f64,
    pub azimuth: DVec3,
}

impl FiberAngles {
    #[must_use]
    pub fn new(t: DVec3, w: DVec3) -> Self {
        let s = w.dot(t);
        let perp = w - s * t;
        let c = perp.length();
        let azimuth = if c > AZIMUTH_MIN_PERP { perp / c } else { crate::sg::frame_from_z(t).0 };
        Self { theta: s.atan2(c), cos_theta: c, azimuth }
    }
}

/// `S(ωi, ωo) cos θi` for unit tangent `t` and unit directions (ωi toward the light, ωo toward
/// the viewer), with Gn from the baked table; see the module docs.
#[must_use]
pub fn fiber_eval_cos(fiber: &FiberConstants, gn: &GnTable, t: DVec3, wi: DVec3, wo: DVec3) -> Rgb {
    let i = FiberAngles::new(t, wi);
    let o = FiberAngles::new(t, wo);
    let f = fiber.fresnel(i.cos_theta);
    let m_r = fiber.longitudinal(gn, LOBE_R, i.theta, o.theta);
    let m_tt = fiber.longitudinal(gn, LOBE_TT, i.theta, o.theta);
    let one_plus_cos = 0.5 * (i.azimuth + o.azimuth).length_squared();
    let n_tt = (-fiber.kappa * one_plus_cos).exp() / (2.0 * PI * fiber.i0e_kappa);
    (f * (m_r / (2.0 * PI)) + (Rgb::ONE - f) * fiber.c_tt * (m_tt * n_tt)) * i.cos_theta
}
