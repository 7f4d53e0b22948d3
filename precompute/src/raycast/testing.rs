//! Synthetic periodic exemplars for tests and benchmarks (not a fabric model).
//!
//! [`synthetic_weave`] builds a plain weave of straight-axis yarns along x (weft) and y (warp)
//! that undulate over and under each other; each yarn is a bundle of fibers placed on a
//! sunflower pattern in the yarn cross-section and twisted helically with a whole number of
//! turns per period, so every fiber joins its continuation in the next copy. Fibers start at a
//! yarn-dependent offset, so they extend past the period rectangle like real exemplars do.
//! [`random_fiber_cloud`] scatters straight, randomly oriented fibers through a periodic box:
//! a Poisson-like medium whose mean free path is known in closed form.

use crate::fabric::{BlockGrid, Exemplar, Fiber, Tiling, Yarn, YarnRole};
use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::f32::consts::TAU;

/// Parameters of [`synthetic_weave`]; lengths in cm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyntheticWeave {
    /// Square period of the exemplar.
    pub period: f32,
    /// Yarns per period along each axis (even, for a plain weave).
    pub yarns_per_axis: u32,
    pub fibers_per_yarn: u32,
    pub fiber_radius: f32,
    /// Radius of the yarn cross-section the fibers are spread over.
    pub yarn_radius: f32,
    /// Approximate segment length (along the yarn axis).
    pub segment_length: f32,
    /// Whole helix turns of the fibers about the yarn axis per period.
    pub twist_turns: u32,
}

impl SyntheticWeave {
    /// About 5k segments: 0.05 cm tile, 2 + 2 yarns of 64 fibers, ~0.024 cm slab.
    #[must_use]
    pub fn small() -> Self {
        Self {
            period: 0.05,
            yarns_per_axis: 2,
            fibers_per_yarn: 64,
            fiber_radius: 5e-4,
            yarn_radius: 5.5e-3,
            segment_length: 2.5e-3,
            twist_turns: 1,
        }
    }

    /// About 100k segments: 0.2 cm tile, 4 + 4 yarns of 190 fibers, ~0.036 cm slab.
    #[must_use]
    pub fn large() -> Self {
        Self {
            period: 0.2,
            yarns_per_axis: 4,
            fibers_per_yarn: 190,
            fiber_radius: 5e-4,
            yarn_radius: 9e-3,
            segment_length: 3e-3,
            twist_turns: 2,
        }
    }
}

/// A periodic plain-weave exemplar; see the module docs.
#[must_use]
pub fn synthetic_weave(p: &SyntheticWeave) -> Exemplar {
    let n = p.yarns_per_axis;
    let period = p.period;
    let spacing = period / n as f32;
    let amplitude = p.yarn_radius * 1.05;
    let steps = (period / p.segment_length).round().max(2.0) as usize;
    let golden = std::f32::consts::PI * (3.0 - 5.0_f32.sqrt());
    let mut fibers = Vec::new();
    let mut yarns = Vec::new();
    for role in [YarnRole::Weft, YarnRole::Warp] {
        for j in 0..n {
            let yarn = yarns.len() as u32;
            yarns.push(Yarn { role, material: 0 });
            let across = (j as f32 + 0.5) * spacing;
            let start = -0.3 * period * (j as f32 + 1.0) / n as f32;
            let sign = if role == YarnRole::Weft { 1.0 } else { -1.0 };
            for k in 0..p.fibers_per_yarn {
                let rho = p.yarn_radius * ((k as f32 + 0.5) / p.fibers_per_yarn as f32).sqrt();
                let phi0 = k as f32 * golden;
                let points = (0..=steps)
                    .map(|i| {
                        let along = start + period * i as f32 / steps as f32;
                        let phase = std::f32::consts::PI * (n as f32 * along / period + j as f32);
                        let center_z = sign * amplitude * phase.sin();
                        let phi = phi0 + TAU * p.twist_turns as f32 * along / period;
                        let (s, c) = phi.sin_cos();
                        let lateral = across + rho * c;
                        let z = center_z + rho * s;
                        match role {
                            YarnRole::Weft => Vec3::new(along, lateral, z),
                            _ => Vec3::new(lateral, along, z),
                        }
                    })
                    .collect();
                fibers.push(Fiber { points, radius: p.fiber_radius, yarn });
            }
        }
    }
    Exemplar {
        fibers,
        yarns,
        tiling: Tiling::Periodic { period: Vec2::splat(period) },
        blocks: BlockGrid { nx: n, ny: n },
    }
}

/// `count` straight fibers of `length` (each `segments_per_fiber` segments), centres uniform in
/// `[0, period)^2 x [0, thickness)`, directions uniform on the sphere; periodic in xy.
#[must_use]
pub fn random_fiber_cloud(
    period: f32,
    thickness: f32,
    count: usize,
    length: f32,
    radius: f32,
    segments_per_fiber: usize,
    seed: u64,
) -> Exemplar {
    let mut rng = Pcg64::seed_from_u64(seed);
    let fibers = (0..count)
        .map(|_| {
            let c = Vec3::new(
                rng.random::<f32>() * period,
                rng.random::<f32>() * period,
                rng.random::<f32>() * thickness,
            );
            let z: f32 = rng.random_range(-1.0..1.0);
            let phi = rng.random::<f32>() * TAU;
            let s = (1.0 - z * z).sqrt();
            let d = Vec3::new(s * phi.cos(), s * phi.sin(), z);
            let a = c - 0.5 * length * d;
            let points = (0..=segments_per_fiber)
                .map(|i| a + d * (length * i as f32 / segments_per_fiber as f32))
                .collect();
            Fiber { points, radius, yarn: 0 }
        })
        .collect();
    Exemplar {
        fibers,
        yarns: vec![Yarn { role: YarnRole::Other, material: 0 }],
        tiling: Tiling::Periodic { period: Vec2::splat(period) },
        blocks: BlockGrid { nx: 1, ny: 1 },
    }
}
