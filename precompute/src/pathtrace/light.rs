//! Lights: directional lights and normalized spherical Gaussian (SG) lights, both at infinity.
//!
//! A directional light sends irradiance `irradiance` (measured perpendicular to the beam) from
//! the single direction `to_light`. An SG light is an environment light whose radiance is a
//! normalized SG around `axis`: L(ω) = intensity · exp(λ(ω·axis − 1)) / M(λ), with M(λ) the SG's
//! integral over the sphere. Its total radiance integrates to `intensity`, so as λ grows the SG
//! light tends to a directional light of irradiance `intensity`, and as λ → 0 it tends to a
//! uniform environment of radiance `intensity / 4π`. Sampling draws directions from exactly
//! that distribution (`sg::sample_sg_dir`), so the sampling weight is just `intensity`.

use glam::DVec3;

use crate::Rgb;
use crate::params::{ParamError, check_range, check_rgb};
use crate::sg::{sample_sg_dir, sg_pdf};

/// Sharpness range accepted for SG lights (the range the SG math is tested over).
pub const SG_SHARPNESS_RANGE: (f64, f64) = (1e-4, 1e5);

/// A light at infinity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Light {
    Directional { to_light: DVec3, irradiance: Rgb },
    Sg { axis: DVec3, sharpness: f64, intensity: Rgb },
}

/// A direction sampled toward a light, with its radiance divided by the pdf (for SG lights) or
/// the irradiance (for directional lights, whose pdf is a delta).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightSample {
    pub to_light: DVec3,
    /// Radiance / pdf for SG lights; irradiance for directional lights.
    pub weight: Rgb,
    /// Solid-angle pdf, or `None` for a delta light (no MIS).
    pub pdf: Option<f64>,
}

impl Light {
    /// A directional light; `to_light` need not be normalized but must be nonzero.
    pub fn directional(to_light: DVec3, irradiance: Rgb) -> Result<Self, ParamError> {
        Ok(Self::Directional {
            to_light: unit("light.direction", to_light)?,
            irradiance: check_rgb("light.irradiance", irradiance, 0.0, 1e6)?,
        })
    }

    /// A normalized SG light.
    pub fn sg(axis: DVec3, sharpness: f64, intensity: Rgb) -> Result<Self, ParamError> {
        let (lo, hi) = SG_SHARPNESS_RANGE;
        Ok(Self::Sg {
            axis: unit("light.axis", axis)?,
            sharpness: check_range("light.sharpness", sharpness, lo, hi)?,
            intensity: check_rgb("light.intensity", intensity, 0.0, 1e6)?,
        })
    }

    /// Draws a direction toward the light.
    #[must_use]
    pub fn sample(&self, u: [f64; 2]) -> LightSample {
        match *self {
            Self::Directional { to_light, irradiance } => {
                LightSample { to_light, weight: irradiance, pdf: None }
            }
            Self::Sg { axis, sharpness, intensity } => {
                let dir = sample_sg_dir(axis, sharpness, u);
                // radiance / pdf = intensity * (G/M) / (G/M) = intensity.
                LightSample { to_light: dir, weight: intensity, pdf: Some(sg_pdf(axis, sharpness, dir)) }
            }
        }
    }

    /// Radiance arriving from direction `to_light` (zero for delta lights, which no ray hits).
    #[must_use]
    pub fn radiance(&self, to_light: DVec3) -> Rgb {
        match *self {
            Self::Directional { .. } => Rgb::ZERO,
            Self::Sg { axis, sharpness, intensity } => intensity * sg_pdf(axis, sharpness, to_light),
        }
    }

    /// Solid-angle pdf of [`Light::sample`] for `to_light` (zero for delta lights).
    #[must_use]
    pub fn pdf(&self, to_light: DVec3) -> f64 {
        match *self {
            Self::Directional { .. } => 0.0,
            Self::Sg { axis, sharpness, .. } => sg_pdf(axis, sharpness, to_light),
        }
    }
}

fn unit(name: &str, v: DVec3) -> Result<DVec3, ParamError> {
    let n = v.normalize_or_zero();
    if n == DVec3::ZERO || !n.is_finite() {
        return Err(ParamError::new(name, format!("[{}, {}, {}]", v.x, v.y, v.z), "a finite nonzero vector"));
    }
    Ok(n)
}
