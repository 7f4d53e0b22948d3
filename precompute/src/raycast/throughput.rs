//! Ray casting throughput on a fabric: the rays the benchmarks cast, and their timing.
//!
//! How it works: two families of incoherent rays over a square swatch of the fabric clipped
//! from its exemplar (`Extent::Rectangle`): *camera* rays start 0.5 cm above the fabric and aim
//! at uniformly random points of its slab; *scatter* rays start at random points inside the slab
//! in uniformly random directions (what path tracing, visibility and the IIRTF cast). Each family
//! is cast with [`FiberScene::closest_hit`] and [`FiberScene::any_hit`] (`t_max = ∞`, no ignored
//! fiber), on one thread ([`rays_per_second`]): rays per second per core. Fixed seeds, so every
//! run casts the same rays. `benches/raycast.rs` (criterion) and `twill bench raycast` use it.

use std::time::{Duration, Instant};

use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use super::{Extent, FiberScene};

/// Which query a measurement casts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Query {
    ClosestHit,
    AnyHit,
}

/// The rectangle of a `side_cm` swatch at the origin.
#[must_use]
pub fn swatch_extent(side_cm: f32) -> Extent {
    Extent::Rectangle { min: Vec2::ZERO, max: Vec2::splat(side_cm) }
}

/// A uniformly random point of the swatch's fabric slab.
fn point_in_slab(rng: &mut Pcg64, side_cm: f32, lo: f32, hi: f32) -> Vec3 {
    Vec3::new(rng.random::<f32>() * side_cm, rng.random::<f32>() * side_cm, rng.random_range(lo..hi))
}

/// `count` camera-like rays (origin, unit direction): from above the fabric, aimed into the
/// slab of a `side_cm` swatch.
#[must_use]
pub fn camera_rays(scene: &FiberScene, side_cm: f32, count: usize, seed: u64) -> Vec<(Vec3, Vec3)> {
    let (lo, hi) = scene.slab();
    let mut rng = Pcg64::seed_from_u64(seed);
    (0..count)
        .map(|_| {
            let p = point_in_slab(&mut rng, side_cm, lo, hi);
            let o = p + Vec3::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5), 0.5 + hi - p.z);
            (o, (p - o).normalize())
        })
        .collect()
}

/// `count` scattering-like rays: from random points inside the slab, uniformly random directions.
#[must_use]
pub fn scatter_rays(scene: &FiberScene, side_cm: f32, count: usize, seed: u64) -> Vec<(Vec3, Vec3)> {
    let (lo, hi) = scene.slab();
    let mut rng = Pcg64::seed_from_u64(seed);
    (0..count)
        .map(|_| {
            let p = point_in_slab(&mut rng, side_cm, lo, hi);
            let z: f32 = rng.random_range(-1.0..1.0);
            let phi = rng.random::<f32>() * std::f32::consts::TAU;
            let s = (1.0 - z * z).sqrt();
            (p, Vec3::new(s * phi.cos(), s * phi.sin(), z))
        })
        .collect()
}

/// Casts every ray of `rays` once with `query`; returns how many hit.
#[must_use]
pub fn cast(scene: &FiberScene, rays: &[(Vec3, Vec3)], query: Query) -> usize {
    rays.iter()
        .filter(|&&(o, d)| match query {
            Query::ClosestHit => scene.closest_hit(o, d, f32::INFINITY, None).is_some(),
            Query::AnyHit => scene.any_hit(o, d, f32::INFINITY, None),
        })
        .count()
}

/// Rays per second on this thread: `rays` cast with `query` over and over for at least
/// `min_time` (after one untimed pass), the best of the passes (the machine's noise only slows
/// a pass down).
#[must_use]
pub fn rays_per_second(scene: &FiberScene, rays: &[(Vec3, Vec3)], query: Query, min_time: Duration) -> f64 {
    best_rate(rays.len(), min_time, || cast(scene, rays, query))
}

/// Items per second of the fastest of repeated `pass`es over `items` items: one untimed pass,
/// then passes until `min_time` has gone by (at least one).
pub fn best_rate(items: usize, min_time: Duration, mut pass: impl FnMut() -> usize) -> f64 {
    let _ = std::hint::black_box(pass());
    let started = Instant::now();
    let mut best = 0.0_f64;
    while started.elapsed() < min_time || best == 0.0 {
        let timer = Instant::now();
        let _ = std::hint::black_box(pass());
        best = best.max(items as f64 / timer.elapsed().as_secs_f64().max(1e-9));
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raycast::testing::{SyntheticWeave, synthetic_weave};

    #[test]
    fn the_ray_families_are_fixed_by_their_seed_and_start_where_they_should() {
        let exemplar = synthetic_weave(&SyntheticWeave { fibers_per_yarn: 8, ..SyntheticWeave::small() });
        let scene = FiberScene::new(&exemplar, swatch_extent(0.5)).unwrap();
        let (lo, hi) = scene.slab();
        let camera = camera_rays(&scene, 0.5, 200, 1);
        assert_eq!(camera, camera_rays(&scene, 0.5, 200, 1), "same seed, same rays");
        assert_ne!(camera, camera_rays(&scene, 0.5, 200, 2));
        for (o, d) in &camera {
            assert!(o.z > hi && d.z < 0.0, "camera rays come from above, downwards: {o} {d}");
            assert!((d.length() - 1.0).abs() < 1e-5);
        }
        for (o, d) in scatter_rays(&scene, 0.5, 200, 3) {
            assert!((lo..=hi).contains(&o.z) && (0.0..=0.5).contains(&o.x) && (0.0..=0.5).contains(&o.y));
            assert!((d.length() - 1.0).abs() < 1e-5);
        }
        // Every camera ray aims into the slab of a fabric: most hit; an any-hit query agrees.
        let hits = cast(&scene, &camera, Query::ClosestHit);
        assert_eq!(hits, cast(&scene, &camera, Query::AnyHit));
        assert!(rays_per_second(&scene, &camera, Query::AnyHit, Duration::from_millis(20)) > 0.0);
    }
}
