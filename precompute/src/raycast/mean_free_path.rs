//! Mean free path of light between fibers, measured by ray casting.
//!
//! Definition: a sample starts at a uniformly random point on the lateral surface of a fiber
//! segment of the scene's central copy (segments chosen with probability proportional to their
//! length, the angle about the axis uniform), leaves in a direction uniform over the outward
//! hemisphere about the surface normal, and flies until it enters another fiber (its own fiber
//! is ignored, in every copy). The free path is that distance. Samples that leave the fabric
//! slab (or the swatch rectangle) without a hit are *escaped*: they are counted in
//! `escaped_fraction` and excluded from the mean. Start points outside a finite swatch's
//! rectangle are redrawn.
//!
//! Each sample draws from its own generator seeded from `(seed, sample index)`, and the sums are
//! combined in a fixed order, so the result depends on the seed only, not on the thread count.

use super::FiberScene;
use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

/// Result of [`mean_free_path`]; lengths in cm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeanFreePath {
    /// Mean distance to the next fiber over samples that hit one (NaN if none did).
    pub mean_cm: f64,
    /// Standard error of `mean_cm`.
    pub std_error_cm: f64,
    /// Fraction of samples that left the fabric without hitting a fiber.
    pub escaped_fraction: f64,
    pub samples: usize,
}

const CHUNK: usize = 1024;

/// Measures the mean free path in `scene` with `samples` rays; see the module docs.
#[must_use]
pub fn mean_free_path(scene: &FiberScene, samples: usize, seed: u64) -> MeanFreePath {
    let segments = scene.segments();
    let mut cdf = Vec::with_capacity(segments.len());
    let mut total = 0.0;
    for s in segments {
        total += f64::from(s.length());
        cdf.push(total);
    }
    if samples == 0 || total <= 0.0 {
        return MeanFreePath {
            mean_cm: f64::NAN,
            std_error_cm: f64::NAN,
            escaped_fraction: f64::NAN,
            samples,
        };
    }
    let offset = scene.tile_offset(scene.central_tile());
    let rect = scene.rectangle();
    let sample = |index: usize| -> Option<f64> {
        let mut rng = Pcg64Mcg::seed_from_u64(
            seed ^ (index as u64).wrapping_add(1).wrapping_mul(0x9E37_79B9_7F4A_7C15),
        );
        for _attempt in 0..64 {
            let u = rng.random::<f64>() * total;
            let k = cdf.partition_point(|&c| c <= u).min(segments.len() - 1);
            let s = &segments[k];
            let (a, b) = (s.a.as_dvec3() + offset, s.b.as_dvec3() + offset);
            let axis = (b - a).normalize_or(DVec3::X);
            let (e1, e2) = axis.any_orthonormal_pair();
            let phi = rng.random::<f64>() * std::f64::consts::TAU;
            let normal = phi.cos() * e1 + phi.sin() * e2;
            let origin = a + rng.random::<f64>() * (b - a) + f64::from(s.radius) * normal;
            if let Some((min, max)) = rect
                && (origin.x < f64::from(min.x)
                    || origin.y < f64::from(min.y)
                    || origin.x > f64::from(max.x)
                    || origin.y > f64::from(max.y))
            {
                continue;
            }
            // Uniform direction on the sphere, flipped into the outward hemisphere.
            let z: f64 = rng.random_range(-1.0..1.0);
            let psi = rng.random::<f64>() * std::f64::consts::TAU;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let mut dir = DVec3::new(r * psi.cos(), r * psi.sin(), z);
            if dir.dot(normal) < 0.0 {
                dir = -dir;
            }
            return scene.closest_hit_f64(origin, dir, f64::INFINITY, Some(s.fiber)).map(|h| f64::from(h.t));
        }
        None
    };
    let chunks: Vec<(usize, f64, f64)> = (0..samples.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut acc = (0usize, 0.0, 0.0);
            for i in c * CHUNK..((c + 1) * CHUNK).min(samples) {
                if let Some(t) = sample(i) {
                    acc.0 += 1;
                    acc.1 += t;
                    acc.2 += t * t;
                }
            }
            acc
        })
        .collect();
    let (hits, sum, sum_sq) =
        chunks.iter().fold((0usize, 0.0, 0.0), |acc, c| (acc.0 + c.0, acc.1 + c.1, acc.2 + c.2));
    let n = hits as f64;
    let mean = sum / n;
    let variance = if hits > 1 { ((sum_sq - n * mean * mean) / (n - 1.0)).max(0.0) } else { f64::NAN };
    MeanFreePath {
        mean_cm: mean,
        std_error_cm: (variance / n).sqrt(),
        escaped_fraction: 1.0 - n / samples as f64,
        samples,
    }
}
