//! Precomputation ("baking"): everything Khungurn et al. 2017 section 4 computes once per
//! fabric, on the CPU with rayon.
//!
//! Stages (each its own module, each a pure function of exactly what it depends on):
//! - [`svf`]: per-segment binary visibility images over the sphere, from the segment midpoint in
//!   a large flat tiled fabric, ignoring the segment's own fiber;
//!   [`ssdf`]: their spherical signed distance functions; [`pca`]: PCA compression of those;
//!   [`sum_of_sg`]: the sum-of-SGs visibility weights.
//! - [`cells`]: IIRTF cells sized from the measured mean free path; [`iirtf`]: the per-cell
//!   SH-to-SH transfer matrices by path tracing; [`cs_table`]: the BCSDF's SH expansion
//!   C_S[θo, j].
//! - [`tables`]: the zonal SH of normalized SGs C_G[λ, l] and the normalizer Gn(μ; λ);
//!   [`volume`]: the exemplar rasterized to voxels holding segment ids; [`pattern`]: block to
//!   exemplar maps for patterned cloth.
//! - [`file`]: the bake file (versioned, content-hashed, checksummed, written atomically).
//!
//! Long stages take a [`Cancel`] token they check often and report progress through a
//! [`Progress`] callback with the fraction of the stage done.

pub mod cells;
pub mod cs_table;
pub mod file;
pub mod iirtf;
pub mod pattern;
pub mod pca;
pub mod pipeline;
pub mod recolour;
pub mod settings;
pub mod shard;
pub mod ssdf;
pub mod sum_of_sg;
pub mod svf;
pub mod tables;
pub mod volume;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// A cancellation flag shared between whoever runs a bake and whoever may stop it.
#[derive(Debug, Clone, Default)]
pub struct Cancel(Arc<AtomicBool>);

impl Cancel {
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Asks every stage holding a clone of this token to stop.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::Relaxed);
    }

    #[must_use]
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }

    /// `Err(Cancelled)` once cancelled: stages call this often and return early with `?`.
    pub fn check(&self) -> Result<(), Cancelled> {
        if self.is_cancelled() { Err(Cancelled) } else { Ok(()) }
    }
}

/// A stage stopped because its [`Cancel`] token was set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("cancelled")]
pub struct Cancelled;

/// Progress of one stage: called with the fraction done, in [0, 1], from any thread.
pub type Progress<'a> = &'a (dyn Fn(f64) + Sync);

/// A progress callback that ignores its reports.
pub fn no_progress(_: f64) {}
