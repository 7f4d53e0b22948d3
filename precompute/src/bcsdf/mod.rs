//! Fiber scattering: the R + TT fiber model (BCSDF), a Lambertian fiber surface, and the
//! [`Material`] interface the path tracer uses at a fiber hit.
//!
//! How it works: [`FiberScattering`] (in `fiber`) evaluates, samples and gives the pdf of the
//! two-lobe model of Khungurn et al. 2015 (see `docs/MATH.md` / the design math notes), using a
//! tabulated longitudinal normalizer (`gn_table`) and exact truncated-Gaussian and von Mises
//! samplers (`sampling`). [`Lambertian`] is the check material. [`Material`] wraps both behind
//! one interface taking the fiber tangent t and the surface normal n at the hit.
//!
//! Conventions: all directions are unit vectors pointing away from the scattering point, ωi
//! toward the light and ωo toward the viewer. The fiber model is not reciprocal, so a camera
//! path tracer must pass the light-side direction as ωi even though it samples ωi from ωo.

mod fiber;
mod gn_table;
mod lambert;
mod sampling;
#[cfg(test)]
mod tests;

pub use fiber::{
    BETA_RANGE_DEG, COLOUR_FREE_C_R, ColourFreeEvent, FiberFrame, FiberScattering, GAMMA_RANGE_DEG, Lobe,
};
pub use gn_table::{GN_TABLE_INTERVALS, GnTable as LobeGnTable};
pub use lambert::Lambertian;

use glam::DVec3;

use crate::Rgb;
use crate::params::ParamError;

/// Parameters of the two-lobe R + TT fiber scattering model (Khungurn et al. 2015, as
/// reconstructed in `docs/MATH.md`), as a user writes them: angles in degrees.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FiberParams {
    /// Reflectance at normal incidence of the R lobe (Schlick F0), per channel in [0, 1].
    pub c_r: Rgb,
    /// Longitudinal width of the R lobe, degrees.
    pub beta_r_deg: f64,
    /// Transmission colour of the TT lobe, per channel in [0, 1].
    pub c_tt: Rgb,
    /// Longitudinal width of the TT lobe, degrees.
    pub beta_tt_deg: f64,
    /// Azimuthal width of the TT lobe, degrees.
    pub gamma_tt_deg: f64,
}

/// A fiber material as a scene file names it.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "model", rename_all = "lowercase", deny_unknown_fields)]
pub enum MaterialDesc {
    /// The R + TT fiber scattering model.
    Fiber(FiberParams),
    /// A Lambertian fiber surface shaded with the exact cylinder hit normal (for checking light
    /// transport against independent renderers).
    Lambert { albedo: Rgb },
}

/// A fiber material ready for rendering.
#[derive(Debug, Clone)]
pub enum Material {
    Fiber(FiberScattering),
    Lambert(Lambertian),
}

impl Material {
    /// Validates a scene-file description and precomputes what it needs.
    pub fn from_desc(desc: &MaterialDesc) -> Result<Self, ParamError> {
        Ok(match desc {
            MaterialDesc::Fiber(p) => Self::Fiber(FiberScattering::new(p)?),
            MaterialDesc::Lambert { albedo } => Self::Lambert(Lambertian::new(*albedo)?),
        })
    }

    /// Scattering function times the cosine factor of ωi: `S(ωi, ωo) cos θi` with
    /// `cos θi = |ωi × t|` for the fiber, `albedo/π · max(0, ωi·n)` for Lambert (zero if ωo is
    /// below n). `t` is the unit fiber tangent, `n` the unit surface normal at the hit. ωi must be
    /// the light-side direction (the fiber model is not reciprocal).
    #[must_use]
    pub fn eval_cos(&self, t: DVec3, n: DVec3, wi: DVec3, wo: DVec3) -> Rgb {
        match self {
            Self::Fiber(f) => {
                let s = wi.dot(t).clamp(-1.0, 1.0);
                f.eval(t, wi, wo) * (1.0 - s * s).sqrt()
            }
            Self::Lambert(l) => l.eval_cos(n, wi, wo),
        }
    }

    /// Samples ωi given ωo; returns it with its solid-angle pdf (> 0).
    #[must_use]
    pub fn sample(&self, t: DVec3, n: DVec3, wo: DVec3, u: [f64; 3]) -> Option<(DVec3, f64)> {
        let wi = match self {
            Self::Fiber(f) => f.sample(t, wo, u)?,
            Self::Lambert(l) => l.sample(n, wo, [u[1], u[2]])?,
        };
        let pdf = self.pdf(t, n, wo, wi);
        (pdf > 0.0 && pdf.is_finite()).then_some((wi, pdf))
    }

    /// Solid-angle density with which [`Self::sample`] returns ωi given ωo.
    #[must_use]
    pub fn pdf(&self, t: DVec3, n: DVec3, wo: DVec3, wi: DVec3) -> f64 {
        match self {
            Self::Fiber(f) => f.pdf(t, wo, wi),
            Self::Lambert(l) => l.pdf(n, wo, wi),
        }
    }

    /// A scattering event sampled and weighed without the material's colours (see
    /// [`FiberScattering::sample_colour_free`]); a Lambertian surface samples its cosine lobe,
    /// weight 1, colour factor its albedo (reported as [`Lobe::Tt`]).
    #[must_use]
    pub fn sample_colour_free(&self, t: DVec3, n: DVec3, wo: DVec3, u: [f64; 3]) -> Option<ColourFreeEvent> {
        match self {
            Self::Fiber(f) => f.sample_colour_free(t, wo, u),
            Self::Lambert(l) => {
                let dir = l.sample(n, wo, [u[1], u[2]])?;
                let pdf = l.pdf(n, wo, dir);
                let value = dir.dot(n).max(0.0) * std::f64::consts::FRAC_1_PI;
                (pdf > 0.0).then(|| ColourFreeEvent {
                    dir,
                    lobe: Lobe::Tt,
                    weight: value / pdf,
                    schlick: 0.0,
                })
            }
        }
    }

    /// `eval_cos` split into the part that does not depend on the paintable colour and the
    /// part per unit of it: `(fixed, per_colour)` with `eval_cos = fixed + colour · per_colour`,
    /// the colour being `C_TT` for the fiber (its R lobe and the `1 − F_R` of TT stay in) and
    /// the albedo for Lambert (whose fixed part is zero). See [`FiberScattering::eval_cos_parts`].
    #[must_use]
    pub fn eval_cos_parts(&self, t: DVec3, n: DVec3, wi: DVec3, wo: DVec3) -> (Rgb, Rgb) {
        match self {
            Self::Fiber(f) => f.eval_cos_parts(t, wi, wo),
            Self::Lambert(_) => (Rgb::ZERO, Rgb::splat(Lambertian::eval_cos_white(n, wi, wo))),
        }
    }

    /// The TT lobe's part of [`Self::eval_cos`] (`C_TT` times the fiber's transmitted part;
    /// zero for a Lambertian surface, which transmits nothing).
    #[must_use]
    pub fn eval_cos_tt(&self, t: DVec3, wi: DVec3, wo: DVec3) -> Rgb {
        match self {
            Self::Fiber(f) => f.c_tt() * f.eval_cos_parts(t, wi, wo).1,
            Self::Lambert(_) => Rgb::ZERO,
        }
    }

    /// Solid-angle density of [`Self::sample_colour_free`] (for multiple importance sampling
    /// in a walk that must not read the colours).
    #[must_use]
    pub fn pdf_colour_free(&self, t: DVec3, n: DVec3, wo: DVec3, wi: DVec3) -> f64 {
        match self {
            Self::Fiber(f) => f.pdf_colour_free(t, wo, wi),
            Self::Lambert(l) => l.pdf(n, wo, wi),
        }
    }

    /// The paintable colour: `C_TT` of a fiber, the albedo of a Lambertian surface.
    #[must_use]
    pub fn paint_colour(&self) -> Rgb {
        match self {
            Self::Fiber(f) => f.c_tt(),
            Self::Lambert(l) => l.albedo,
        }
    }

    /// The same material with its paintable colour replaced ([`Self::paint_colour`]); checked
    /// to lie in [0, 1] per channel.
    pub fn with_paint_colour(&self, colour: Rgb) -> Result<Self, ParamError> {
        Ok(match self {
            Self::Fiber(f) => Self::Fiber(f.with_c_tt(colour)?),
            Self::Lambert(_) => Self::Lambert(Lambertian::new(colour)?),
        })
    }

    /// The colour variables a recolouring works in: `(τ, C_R)` with `τ = (1 − C_R) C_TT` the
    /// factor of a TT event (a Lambertian surface: its albedo, and C_R = 0).
    #[must_use]
    pub fn colour_variables(&self) -> (Rgb, Rgb) {
        match self {
            Self::Fiber(f) => f.colour_variables(),
            Self::Lambert(l) => (l.albedo, Rgb::ZERO),
        }
    }

    /// Whether light can pass through the surface (fiber: yes; Lambert: no).
    #[must_use]
    pub fn is_transmissive(&self) -> bool {
        matches!(self, Self::Fiber(_))
    }

    /// A typical albedo, for Russian roulette: the fiber's furnace value at normal incidence
    /// `C_R + (1 - C_R) C_TT` (it rises toward 1 at grazing angles), Lambert's albedo.
    #[must_use]
    pub fn albedo_hint(&self) -> Rgb {
        match self {
            Self::Fiber(f) => f.albedo_hint(),
            Self::Lambert(l) => l.albedo,
        }
    }
}
