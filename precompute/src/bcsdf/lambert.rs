//! A Lambertian fiber surface, shaded with the exact cylinder hit normal.
//!
//! How it works: f = albedo/π when both ωi and ωo lie on the side of the surface normal n
//! (zero otherwise); sampling is cosine-weighted about n (Malley's method: a uniform disk point
//! lifted to the hemisphere), with pdf cos θ/π. Directions at the horizon get pdf 0.

use std::f64::consts::{FRAC_1_PI, PI};

use glam::DVec3;

use super::fiber::FiberFrame;
use crate::Rgb;
use crate::params::{ParamError, check_rgb};

/// Lambertian reflection off the fiber surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lambertian {
    pub albedo: Rgb,
}

impl Lambertian {
    /// Validates `albedo` (each channel in [0, 1]).
    pub fn new(albedo: Rgb) -> Result<Self, ParamError> {
        Ok(Self { albedo: check_rgb("albedo", albedo, 0.0, 1.0)? })
    }

    /// f(ωi, ωo) · max(0, ωi·n); zero when ωo is not above the surface.
    #[must_use]
    pub fn eval_cos(&self, n: DVec3, wi: DVec3, wo: DVec3) -> Rgb {
        self.albedo * Self::eval_cos_white(n, wi, wo)
    }

    /// [`Self::eval_cos`] at albedo 1.
    #[must_use]
    pub fn eval_cos_white(n: DVec3, wi: DVec3, wo: DVec3) -> f64 {
        let (ci, co) = (wi.dot(n), wo.dot(n));
        if ci > 0.0 && co > 0.0 { FRAC_1_PI * ci } else { 0.0 }
    }

    /// Cosine-weighted direction about n (`None` when ωo is below the surface or the sample
    /// lands on the horizon).
    #[must_use]
    pub fn sample(&self, n: DVec3, wo: DVec3, u: [f64; 2]) -> Option<DVec3> {
        if wo.dot(n) <= 0.0 {
            return None;
        }
        let frame = FiberFrame::new(n);
        let r = u[0].sqrt();
        let (s, c) = (2.0 * PI * u[1]).sin_cos();
        let z = (1.0 - u[0]).max(0.0).sqrt();
        let dir = (z * n + r * (c * frame.u + s * frame.v)).normalize();
        (dir.dot(n) > 0.0).then_some(dir)
    }

    /// Solid-angle density of [`Self::sample`].
    #[must_use]
    pub fn pdf(&self, n: DVec3, wo: DVec3, wi: DVec3) -> f64 {
        let c = wi.dot(n);
        if wo.dot(n) <= 0.0 || c <= 0.0 { 0.0 } else { c * FRAC_1_PI }
    }
}
