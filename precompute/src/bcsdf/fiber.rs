//! The two-lobe R + TT fiber scattering function (BCSDF) of Khungurn et al. 2015.
//!
//! How it works: directions are expressed in the fiber frame (x = tangent t): θ ∈ [-π/2, π/2]
//! is the angle from the normal plane (sin θ = ω·t) and φ the azimuth around t, measured from an
//! arbitrary but fixed perpendicular axis (only φ differences enter the model). Directions are
//! unit vectors pointing away from the scattering point: ωi toward the light, ωo toward the
//! viewer. With λ_X = 1/(2β_X²) and `M_X(θi, θo) = sqrt(λ_X/π) exp(-λ_X (θo + θi)²) / Gn(-θi; λ_X)`,
//!
//! ```text
//! S(ωi, ωo) = F_R(θi) M_R / (2π)  +  (1 - F_R(θi)) C_TT M_TT N_TT(φo - φi)
//! F_R(θ) = C_R + (1 - C_R)(1 - cos θ)^5,   N_TT(φ) = exp(κ(cos(φ - π) - 1)) / (2π i0e(κ)), κ = γ_TT⁻²
//! ```
//!
//! so `∫ S cos θo dωo = F_R(θi) + (1 - F_R(θi)) C_TT` for every ωi. S is not reciprocal (F_R
//! and Gn use θi only): a path tracer walking from the camera must still pass the light-side
//! direction as ωi. Gn comes from a table ([`super::gn_table`]).
//!
//! Sampling works from either side, because both lobes depend only on θi + θo and φo - φi:
//! given the fixed direction (θf, φf), pick R or TT by the luminance of F_R(θf) against
//! (1 - F_R(θf)) C_TT, draw θ from N(-θf, β²) truncated to [-π/2, π/2] and φ uniformly (R) or
//! from a von Mises around φf + π (TT). The solid-angle pdf is the lobe mixture of
//! p(θ) p(φ) / cos θ; directions within 1e-9 of the tangent have pdf 0 and are not returned.

use std::f64::consts::{FRAC_PI_2, PI};
use std::sync::Arc;

use glam::DVec3;

use super::FiberParams;
use super::gn_table::GnTable;
use super::sampling::{TruncGauss, VonMises};
use crate::Rgb;
use crate::params::{ParamError, check_range, check_rgb};

/// Valid range of the longitudinal widths β_R, β_TT in degrees. Below 0.5° the lobe is narrower
/// than the Gn table resolves (10 nodes per β); above 60° the "Gaussian" is flat over the
/// whole [-90°, 90°] and wider values add nothing.
pub const BETA_RANGE_DEG: (f64, f64) = (0.5, 60.0);
/// Valid range of the azimuthal width γ_TT in degrees (κ = γ⁻² from 13131 down to 0.101; at
/// 180° the TT lobe is already within 10% of uniform in φ).
pub const GAMMA_RANGE_DEG: (f64, f64) = (0.5, 180.0);

/// Directions with cos θ below this (within ~1e-9 rad of ±t) get pdf 0 and are never sampled.
const MIN_COS_THETA: f64 = 1e-9;

/// Rec. 709 luminance, used to choose a lobe.
fn luminance(c: Rgb) -> f64 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// An orthonormal frame (t, u, v) around the unit fiber tangent t (Duff et al. 2017).
#[derive(Debug, Clone, Copy)]
pub struct FiberFrame {
    pub t: DVec3,
    pub u: DVec3,
    pub v: DVec3,
}

impl FiberFrame {
    #[must_use]
    pub fn new(t: DVec3) -> Self {
        let (u, v) = crate::sg::frame_from_z(t);
        Self { t, u, v }
    }

    /// (θ, φ) of a unit direction: θ = atan2(ω·t, |ω⊥|) (accurate near the poles), φ = atan2.
    #[must_use]
    pub fn angles(&self, w: DVec3) -> (f64, f64) {
        let (x, y) = (w.dot(self.u), w.dot(self.v));
        (w.dot(self.t).atan2(x.hypot(y)), y.atan2(x))
    }

    #[must_use]
    pub fn direction(&self, theta: f64, phi: f64) -> DVec3 {
        let (st, ct) = theta.sin_cos();
        let (sp, cp) = phi.sin_cos();
        (st * self.t + ct * (cp * self.u + sp * self.v)).normalize()
    }
}

/// The Schlick reflectance at normal incidence [`FiberScattering::sample_colour_free`] chooses
/// its lobes with (the presets' C_R lie between 0.03 and 0.09).
pub const COLOUR_FREE_C_R: f64 = 0.05;

/// Which lobe a colour-free event took.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lobe {
    /// The R lobe (colour factor `C_R + (1 − C_R) m`).
    R,
    /// The TT lobe, or a Lambertian surface (colour factor τ).
    Tt,
}

/// A scattering event with its colours left out ([`FiberScattering::sample_colour_free`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColourFreeEvent {
    /// The sampled light-side direction ωi.
    pub dir: DVec3,
    pub lobe: Lobe,
    /// Lobe value × cos θi / (choice probability × lobe pdf), colours left out.
    pub weight: f64,
    /// `m = (1 − cos θi)^5`, the Schlick term of ωi.
    pub schlick: f64,
}

/// The R + TT fiber scattering model with its Gn tables, ready to evaluate and sample.
#[derive(Debug, Clone)]
pub struct FiberScattering {
    c_r: Rgb,
    c_tt: Rgb,
    beta_r: f64,
    beta_tt: f64,
    lam_r: f64,
    lam_tt: f64,
    von_mises: VonMises,
    // Shared: a recoloured copy ([`Self::with_c_tt`]) keeps its tables.
    gn_r: Arc<GnTable>,
    gn_tt: Arc<GnTable>,
}

impl FiberScattering {
    /// Validates the parameters and tabulates Gn for both lobes (a few ms).
    pub fn new(p: &FiberParams) -> Result<Self, ParamError> {
        let c_r = check_rgb("c_r", p.c_r, 0.0, 1.0)?;
        let c_tt = check_rgb("c_tt", p.c_tt, 0.0, 1.0)?;
        let (blo, bhi) = BETA_RANGE_DEG;
        let beta_r = check_range("beta_r_deg", p.beta_r_deg, blo, bhi)?.to_radians();
        let beta_tt = check_range("beta_tt_deg", p.beta_tt_deg, blo, bhi)?.to_radians();
        let (glo, ghi) = GAMMA_RANGE_DEG;
        let gamma = check_range("gamma_tt_deg", p.gamma_tt_deg, glo, ghi)?.to_radians();
        let kappa = 1.0 / (gamma * gamma);
        Ok(Self {
            c_r,
            c_tt,
            beta_r,
            beta_tt,
            lam_r: 0.5 / (beta_r * beta_r),
            lam_tt: 0.5 / (beta_tt * beta_tt),
            von_mises: VonMises::new(kappa),
            gn_r: Arc::new(GnTable::new(beta_r)),
            gn_tt: Arc::new(GnTable::new(beta_tt)),
        })
    }

    /// The Gn normalizer tables of the R and TT lobes (what [`Self::eval`] divides by).
    #[must_use]
    pub fn gn_tables(&self) -> (&GnTable, &GnTable) {
        (&self.gn_r, &self.gn_tt)
    }

    /// The TT colour `C_TT`.
    #[must_use]
    pub fn c_tt(&self) -> Rgb {
        self.c_tt
    }

    /// The same fiber with the TT colour `c_tt` (checked as [`Self::new`] does); the Gn
    /// tables are shared, so this costs a copy of a few numbers.
    pub fn with_c_tt(&self, c_tt: Rgb) -> Result<Self, ParamError> {
        Ok(Self { c_tt: check_rgb("c_tt", c_tt, 0.0, 1.0)?, ..self.clone() })
    }

    /// `S(ωi, ωo) cos θi` split by lobe and with `C_TT` left out: `(R, T)` with the whole
    /// value `R + C_TT T`. R carries `F_R(θi)` and T carries `1 − F_R(θi)`, so only the TT
    /// colour is left to multiply in (what albedo painting differentiates, `crate::paint`).
    #[must_use]
    pub fn eval_cos_parts(&self, tangent: DVec3, wi: DVec3, wo: DVec3) -> (Rgb, Rgb) {
        let frame = FiberFrame::new(tangent);
        let (ti, pi) = frame.angles(wi);
        let (to, po) = frame.angles(wo);
        let theta_i = ti.clamp(-FRAC_PI_2, FRAC_PI_2);
        let sum = theta_i + to.clamp(-FRAC_PI_2, FRAC_PI_2);
        let cos_i = theta_i.cos();
        let f = self.fresnel(cos_i);
        let m_r = self.m_r(theta_i, sum);
        let m_tt = self.m_tt(theta_i, sum);
        let azimuth = self.tt_azimuthal(po - pi);
        (f * (m_r / (2.0 * PI) * cos_i), (Rgb::ONE - f) * (m_tt * azimuth * cos_i))
    }

    /// Schlick-form reflectance `F_R(θ) = C_R + (1 - C_R)(1 - cos θ)^5`.
    #[must_use]
    pub fn fresnel(&self, cos_theta: f64) -> Rgb {
        let m = (1.0 - cos_theta.clamp(0.0, 1.0)).powi(5);
        self.c_r + (Rgb::ONE - self.c_r) * m
    }

    /// The exact furnace value `∫ S(ωi, ωo) cos θo dωo = F_R(θi) + (1 - F_R(θi)) C_TT`.
    #[must_use]
    pub fn albedo(&self, theta_i: f64) -> Rgb {
        let f = self.fresnel(theta_i.cos());
        f + (Rgb::ONE - f) * self.c_tt
    }

    /// `(τ, C_R)` with `τ = (1 − C_R) C_TT`: the colour factors of a TT and an R event
    /// ([`Self::sample_colour_free`]).
    #[must_use]
    pub fn colour_variables(&self) -> (Rgb, Rgb) {
        ((Rgb::ONE - self.c_r) * self.c_tt, self.c_r)
    }

    /// Albedo at normal incidence, `C_R + (1 - C_R) C_TT` (a hint for Russian roulette).
    #[must_use]
    pub fn albedo_hint(&self) -> Rgb {
        self.albedo(0.0)
    }

    /// S in fiber angles (θ from the normal plane, φ around the tangent), no cosine factor.
    #[must_use]
    pub fn eval_angles(&self, theta_i: f64, phi_i: f64, theta_o: f64, phi_o: f64) -> Rgb {
        let (uniform, tt) = self.longitudinal_parts(theta_i, theta_o);
        uniform + tt * self.tt_azimuthal(phi_o - phi_i)
    }

    /// S split by its azimuthal dependence: `S(θi, φi, θo, φo) = U + T · N_TT(φo − φi)` with
    /// U (the R lobe, uniform in azimuth) and T (the TT lobe's longitudinal part) returned here
    /// and N_TT from [`Self::tt_azimuthal`]. Integrals over azimuth use it to integrate N_TT
    /// once instead of S at every longitude (`bake::cs_table`).
    #[must_use]
    pub fn longitudinal_parts(&self, theta_i: f64, theta_o: f64) -> (Rgb, Rgb) {
        let theta_i = theta_i.clamp(-FRAC_PI_2, FRAC_PI_2);
        let theta_o = theta_o.clamp(-FRAC_PI_2, FRAC_PI_2);
        let f = self.fresnel(theta_i.cos());
        let sum = theta_i + theta_o;
        let m_r = self.m_r(theta_i, sum);
        let m_tt = self.m_tt(theta_i, sum);
        (f * (m_r / (2.0 * PI)), (Rgb::ONE - f) * self.c_tt * m_tt)
    }

    /// The R lobe's longitudinal density over its Gn normalizer at θi and `sum` = θi + θo.
    fn m_r(&self, theta_i: f64, sum: f64) -> f64 {
        (self.lam_r / PI).sqrt() * (-self.lam_r * sum * sum).exp() / self.gn_r.eval(-theta_i)
    }

    /// The TT lobe's, as [`Self::m_r`].
    fn m_tt(&self, theta_i: f64, sum: f64) -> f64 {
        (self.lam_tt / PI).sqrt() * (-self.lam_tt * sum * sum).exp() / self.gn_tt.eval(-theta_i)
    }

    /// The TT lobe's azimuthal density at `phi_o − phi_i` (a von Mises lobe about π).
    #[must_use]
    pub fn tt_azimuthal(&self, delta_phi: f64) -> f64 {
        self.von_mises.pdf(delta_phi - PI)
    }

    /// S(ωi, ωo) for unit world-space directions and unit fiber tangent (no cosine factor).
    /// ωi points toward the light, ωo toward the viewer.
    #[must_use]
    pub fn eval(&self, tangent: DVec3, wi: DVec3, wo: DVec3) -> Rgb {
        let frame = FiberFrame::new(tangent);
        let (ti, pi) = frame.angles(wi);
        let (to, po) = frame.angles(wo);
        self.eval_angles(ti, pi, to, po)
    }

    /// Probability of choosing the R lobe when `fixed` has cos θ = `cos_fixed`; `None` when
    /// both lobes are black.
    fn lobe_probability_r(&self, cos_fixed: f64) -> Option<f64> {
        let f = self.fresnel(cos_fixed);
        let w_r = luminance(f);
        let w_tt = luminance((Rgb::ONE - f) * self.c_tt);
        let total = w_r + w_tt;
        (total > 0.0).then(|| w_r / total)
    }

    /// The lobe [`Self::sample`] draws from with these uniforms (`u[0]` chooses it); `None`
    /// when both lobes are black.
    #[must_use]
    pub fn sampled_lobe(&self, tangent: DVec3, fixed: DVec3, u: [f64; 3]) -> Option<Lobe> {
        let (theta_f, _) = FiberFrame::new(tangent).angles(fixed);
        self.choose_lobe(theta_f, u[0]).map(|(lobe, _)| lobe)
    }

    /// The lobe `u0` chooses when the fixed direction is at longitudinal angle `theta_f`, with
    /// the probability of R; `None` when both lobes are black. The one choice of
    /// [`Self::sample`] and [`Self::sampled_lobe`].
    fn choose_lobe(&self, theta_f: f64, u0: f64) -> Option<(Lobe, f64)> {
        let p_r = self.lobe_probability_r(theta_f.cos())?;
        Some((if u0 < p_r { Lobe::R } else { Lobe::Tt }, p_r))
    }

    /// Samples the direction on the other side of S from `fixed` (either ωi or ωo: the
    /// density is the same), from three uniforms in [0, 1). Its density is [`Self::pdf`].
    #[must_use]
    pub fn sample(&self, tangent: DVec3, fixed: DVec3, u: [f64; 3]) -> Option<DVec3> {
        let frame = FiberFrame::new(tangent);
        let (theta_f, phi_f) = frame.angles(fixed);
        let (theta, phi) = match self.choose_lobe(theta_f, u[0])? {
            (Lobe::R, _) => {
                let theta = TruncGauss::new(-theta_f, self.beta_r).sample(u[1]);
                (theta, phi_f + 2.0 * PI * u[2])
            }
            (Lobe::Tt, p_r) => {
                let reuse = ((u[0] - p_r) / (1.0 - p_r)).clamp(0.0, 1.0);
                let theta = TruncGauss::new(-theta_f, self.beta_tt).sample(u[1]);
                (theta, phi_f + PI + self.von_mises.sample(u[2], reuse))
            }
        };
        let dir = frame.direction(theta, phi);
        // Same cut-off as `pdf`, measured the same way.
        (frame.angles(dir).0.cos() > MIN_COS_THETA && dir.is_finite()).then_some(dir)
    }

    /// One lobe of S sampled on its own, chosen without looking at the colours: what a
    /// recolouring reweighs (`bake::recolour`). `wo` is the fixed (viewer-side) direction and
    /// the result is the light-side ωi. R is chosen with probability
    /// `clamp(F_ref(θo), 0.1, 0.9)` (`F_ref` the Schlick form at [`COLOUR_FREE_C_R`]), so the
    /// choice depends on the lobe widths and the geometry only. The event's weight is the
    /// chosen lobe's value times `cos θi` over (choice probability × the lobe's own pdf), with
    /// every colour factor left out: `(1 − m)` stays in the TT weight and the R weight is
    /// multiplied by `C_R + (1 − C_R) m` by the caller, `m = (1 − cos θi)^5`, while TT is
    /// multiplied by `τ = (1 − C_R) C_TT`. Summing the two lobes' estimates is S exactly, so
    /// the estimate is unbiased for every colour.
    #[must_use]
    pub fn sample_colour_free(&self, tangent: DVec3, wo: DVec3, u: [f64; 3]) -> Option<ColourFreeEvent> {
        let frame = FiberFrame::new(tangent);
        let (theta_f, phi_f) = frame.angles(wo);
        let p_r = colour_free_probability_r(theta_f);
        let (lobe, theta, phi, choice) = if u[0] < p_r {
            let theta = TruncGauss::new(-theta_f, self.beta_r).sample(u[1]);
            (Lobe::R, theta, phi_f + 2.0 * PI * u[2], p_r)
        } else {
            let reuse = ((u[0] - p_r) / (1.0 - p_r)).clamp(0.0, 1.0);
            let theta = TruncGauss::new(-theta_f, self.beta_tt).sample(u[1]);
            (Lobe::Tt, theta, phi_f + PI + self.von_mises.sample(u[2], reuse), 1.0 - p_r)
        };
        let dir = frame.direction(theta, phi);
        let (theta_i, phi_i) = frame.angles(dir);
        let cos_i = theta_i.cos();
        if cos_i <= MIN_COS_THETA || !dir.is_finite() {
            return None;
        }
        let schlick = (1.0 - cos_i.clamp(0.0, 1.0)).powi(5);
        let sum = theta_i + theta_f;
        let weight = match lobe {
            Lobe::R => {
                let pdf = TruncGauss::new(-theta_f, self.beta_r).pdf(theta_i) / (2.0 * PI) / cos_i;
                let m_r = self.m_r(theta_i, sum);
                m_r / (2.0 * PI) * cos_i / (choice * pdf)
            }
            Lobe::Tt => {
                let azimuth = self.von_mises.pdf(phi_f - phi_i - PI);
                let pdf = TruncGauss::new(-theta_f, self.beta_tt).pdf(theta_i) * azimuth / cos_i;
                let m_tt = self.m_tt(theta_i, sum);
                (1.0 - schlick) * m_tt * azimuth * cos_i / (choice * pdf)
            }
        };
        (weight.is_finite() && weight > 0.0).then_some(ColourFreeEvent { dir, lobe, weight, schlick })
    }

    /// Solid-angle density with which [`Self::sample_colour_free`] returns `dir` given `wo`
    /// (what multiple importance sampling weighs a colour-free walk with: the weights then do
    /// not depend on the colours either).
    #[must_use]
    pub fn pdf_colour_free(&self, tangent: DVec3, wo: DVec3, dir: DVec3) -> f64 {
        let frame = FiberFrame::new(tangent);
        let (theta_f, _) = frame.angles(wo);
        self.mixture_pdf(&frame, wo, dir, colour_free_probability_r(theta_f))
    }

    /// Density of choosing R with probability `p_r` (else TT) and sampling that lobe about
    /// `fixed`.
    fn mixture_pdf(&self, frame: &FiberFrame, fixed: DVec3, dir: DVec3, p_r: f64) -> f64 {
        let (theta_f, phi_f) = frame.angles(fixed);
        let (theta, phi) = frame.angles(dir);
        let cos_theta = theta.cos();
        if cos_theta <= MIN_COS_THETA {
            return 0.0;
        }
        let pdf_r = TruncGauss::new(-theta_f, self.beta_r).pdf(theta) / (2.0 * PI);
        let pdf_tt =
            TruncGauss::new(-theta_f, self.beta_tt).pdf(theta) * self.von_mises.pdf(phi - phi_f - PI);
        (p_r * pdf_r + (1.0 - p_r) * pdf_tt) / cos_theta
    }

    /// Solid-angle density with which [`Self::sample`] returns `dir` given `fixed`.
    #[must_use]
    pub fn pdf(&self, tangent: DVec3, fixed: DVec3, dir: DVec3) -> f64 {
        let frame = FiberFrame::new(tangent);
        let (theta_f, _) = frame.angles(fixed);
        let Some(p_r) = self.lobe_probability_r(theta_f.cos()) else {
            return 0.0;
        };
        self.mixture_pdf(&frame, fixed, dir, p_r)
    }
}

/// The colour-free walk's probability of R when the fixed direction is at longitudinal angle
/// `theta_f`: `clamp(F_ref(θ), 0.1, 0.9)` with `F_ref` the Schlick form at [`COLOUR_FREE_C_R`].
fn colour_free_probability_r(theta_f: f64) -> f64 {
    let m_fixed = (1.0 - theta_f.cos().clamp(0.0, 1.0)).powi(5);
    (COLOUR_FREE_C_R + (1.0 - COLOUR_FREE_C_R) * m_fixed).clamp(0.1, 0.9)
}
