//! Shading at render time: CPU twins (f64) of every radiance function the GPU renderer
//! evaluates per pixel, written so that a WGSL port can follow them line by line (Khungurn et
//! al. 2017, sections 5.2 and 5.3 and Appendix A; `docs/MATH.md`, "Shading at render time").
//!
//! How it works: a shaded point is a fiber segment k of a bake (the eye ray's hit), seen from
//! ωo. All directions are unit vectors in **fabric space** (the space the bake used, z up).
//! - [`bcsdf`]: the fiber model `S(ωi, ωo) cos θi` evaluated from a material's constants
//!   ([`FiberConstants`]) and the baked Gn table, as the GPU will (`S` exactly as
//!   `bcsdf::FiberScattering` defines it).
//! - [`gamma`](mod@gamma): Γ(ξ, λ, ωo), the paper's closed-form approximation of
//!   `∫ G(ωi; ξ, λ) S(ωi, ωo) cos θi dωi` for an unnormalized SG, derived for our S.
//! - [`visibility`]: local visibility from the bake: the SSDF lookup (bilinear over pixel
//!   centres), the erf soft step, the sum-of-SGs product with a light, and the blend weights
//!   between the two for SG lights ([`sg_path_weights`]).
//! - [`single`]: single scattering per light (directional: local visibility, the kept bits or
//!   the hard SSDF step; SG: the blend).
//! - [`multiple`]: multiple scattering, `C_S[θo] · (R_ωo · A_cell · c_light)` per channel, with
//!   the lights projected to SH by [`hemisphere_light_sh`] (the light above the horizon, taken
//!   through the transfer's least-squares fit over the upper hemisphere, so the transfer's cut
//!   at the horizon does not ring).
//! - [`render`]: [`shade`] (both components, several lights) and [`render_flat`], the CPU
//!   version of the method for flat swatches, comparable pixel for pixel with the reference
//!   path tracer.
//! - [`budget`]: the method's error budget, a ladder from exact light transport to the
//!   method, one approximation at a time (`twill accuracy budget`).
//!
//! Everything here is a pure function of its arguments; no state is cached between calls.
//! Only fiber (R + TT) materials can be shaded: a Lambertian fiber surface needs the hit normal
//! and has no C_S table, so it is reported as [`ShadingError::LambertMaterial`].

pub mod bcsdf;
pub mod budget;
pub mod gamma;
pub mod multiple;
pub mod render;
pub mod single;
pub mod visibility;

#[cfg(test)]
mod tests;

pub use bcsdf::{FiberConstants, fiber_eval_cos};
pub use gamma::gamma;
pub use multiple::{hemisphere_light_sh, light_sh, multiple_scattering, multiple_scattering_in_cell};
pub use render::{
    ClampAtZero, MethodOptions, MultipleHeld, render_flat, render_flat_with, render_primary_hits, shade,
};
pub use single::{single_scattering, single_scattering_directional, single_scattering_sg};
pub use visibility::{
    bilinear_over_pixel_centres, bits_lookup, erf_soft_visibility, sg_path_weights, ssdf_lookup,
    ssdf_step_visibility, sum_of_sg_path,
};

use glam::DVec3;

use crate::bake::cs_table::CsTable;
use crate::bake::pipeline::Baked;
use crate::bcsdf::MaterialDesc;
use crate::params::ParamError;

/// Why a segment could not be shaded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ShadingError {
    #[error(
        "segment {segment} uses material slot {material}, a Lambertian fiber surface: the render-time \
         method shades fiber (R + TT) materials only (a Lambertian surface needs the hit normal and \
         has no C_S table)"
    )]
    LambertMaterial { segment: u32, material: u32 },
    #[error("segment {segment} is out of range: the bake has {count} segments")]
    NoSuchSegment { segment: u32, count: usize },
    #[error("segment {segment} names material slot {material}, but the bake has {count} materials")]
    NoSuchMaterial { segment: u32, material: u32, count: usize },
    #[error("material slot {material} is a fiber material but the bake holds no C_S table for it")]
    MissingCsTable { material: usize },
    #[error("the light's SH vector has {got} coefficients; the bake's SH order {order} needs {expected}")]
    ShLength { got: usize, expected: usize, order: usize },
    #[error("the scene's fabric has {scene} segments but the bake has {baked}: bake this scene's fabric")]
    SegmentCountMismatch { scene: usize, baked: usize },
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error("error budget: {0}")]
    Budget(String),
}

/// What shading needs to know about one segment of a bake.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentShading {
    /// Unit fiber tangent: the baked f32 direction widened to f64 and normalized.
    pub tangent: DVec3,
    /// The material's constants (they hold the material slot: Gn table row, C_S table index).
    pub fiber: FiberConstants,
}

impl SegmentShading {
    /// The segment's tangent and material constants. `Ok(None)` for a zero-length segment
    /// (its stored direction is zero): such a segment reflects nothing.
    pub fn of(baked: &Baked, segment: u32) -> Result<Option<Self>, ShadingError> {
        let table = &baked.volume.segments;
        let count = table.len();
        let k = segment as usize;
        if k >= count {
            return Err(ShadingError::NoSuchSegment { segment, count });
        }
        let material = table.material[k];
        let desc = baked.materials.get(material as usize).ok_or(ShadingError::NoSuchMaterial {
            segment,
            material,
            count: baked.materials.len(),
        })?;
        let params = match desc {
            MaterialDesc::Fiber(p) => p,
            MaterialDesc::Lambert { .. } => return Err(ShadingError::LambertMaterial { segment, material }),
        };
        let Some(tangent) = glam::Vec3::from(table.direction[k]).as_dvec3().try_normalize() else {
            return Ok(None);
        };
        Ok(Some(Self { tangent, fiber: FiberConstants::new(params, material as usize)? }))
    }

    /// The bake's `C_S` table of the segment's material (multiple scattering's fiber side).
    pub fn cs_table<'a>(&self, baked: &'a Baked) -> Result<&'a CsTable, ShadingError> {
        let material = self.fiber.material;
        match baked.cs_tables.get(material) {
            Some(Some(cs)) => Ok(cs),
            _ => Err(ShadingError::MissingCsTable { material }),
        }
    }
}
