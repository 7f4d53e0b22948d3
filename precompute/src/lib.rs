//! twill-precompute: everything twill computes on the CPU.
//!
//! The crate is read bottom-up: [`params`] validates user numbers, [`special`], [`sh`], [`sg`]
//! and [`fibonacci`] are the math the rest stands on, [`bcsdf`] is the fiber scattering model,
//! [`fabric`] builds fiber geometry (weave drafts, procedural yarns, periodic exemplars, fiber
//! files), [`raycast`] intersects rays with a tiled fabric, [`scene`] reads scene files and
//! [`pathtrace`] renders the fiber-level reference images everything else is measured against.
//!
//! Conventions (see also `docs/CONVENTIONS.md`): lengths in centimetres; the flat fabric lies in
//! the xy plane with its top surface facing +z; directions are unit vectors pointing *away* from
//! the scattering point (omega_i toward the light, omega_o toward the viewer); radiance is linear
//! RGB. This crate knows nothing of the GPU.

pub mod atomic_file;
pub mod bake;
pub mod bcsdf;
pub mod fabric;
pub mod fibonacci;
pub mod image;
pub mod paint;
pub mod params;
pub mod pathtrace;
pub mod quadrature;
pub mod raycast;
pub mod scene;
pub mod sg;
pub mod sh;
pub mod shading;
pub mod special;
#[cfg(test)]
mod test_support;
pub mod upper_fit;

/// Linear RGB triple (radiance, albedo or colour), one `f64` per channel.
pub type Rgb = glam::DVec3;
