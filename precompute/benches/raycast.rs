//! Incoherent fiber ray casting throughput, single thread.
//!
//! Scenes: the synthetic ~5k- and ~100k-segment periodic weaves of `raycast::testing`, tiled into a
//! 2 cm x 2 cm swatch. Rays: half from 0.5 cm above the fabric aimed at random points of the
//! swatch inside the slab (camera-like), half from random points inside the slab in uniformly
//! random directions (scattering-like). Criterion reports elements/s = rays/s on one core.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::hint::black_box;
use std::time::Duration;
use twill_precompute::raycast::testing::{SyntheticWeave, synthetic_weave};
use twill_precompute::raycast::{Extent, FiberScene};

const RAYS: usize = 1 << 16;
const SWATCH_CM: f32 = 2.0;

fn rays(scene: &FiberScene, seed: u64) -> Vec<(Vec3, Vec3)> {
    let (lo, hi) = scene.slab();
    let mut rng = Pcg64::seed_from_u64(seed);
    (0..RAYS)
        .map(|i| {
            let p = Vec3::new(
                rng.random::<f32>() * SWATCH_CM,
                rng.random::<f32>() * SWATCH_CM,
                rng.random_range(lo..hi),
            );
            if i % 2 == 0 {
                let o =
                    p + Vec3::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5), 0.5 + hi - p.z);
                (o, (p - o).normalize())
            } else {
                let z: f32 = rng.random_range(-1.0..1.0);
                let phi = rng.random::<f32>() * std::f32::consts::TAU;
                let s = (1.0 - z * z).sqrt();
                (p, Vec3::new(s * phi.cos(), s * phi.sin(), z))
            }
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    for (name, params) in [("5k", SyntheticWeave::small()), ("100k", SyntheticWeave::large())] {
        let exemplar = synthetic_weave(&params);
        let n = (SWATCH_CM / params.period).round() as u32;
        let scene = FiberScene::new(&exemplar, Extent::Copies { nx: n, ny: n }).unwrap();
        let rays = rays(&scene, 1);
        let hits =
            rays.iter().filter(|(o, d)| scene.closest_hit(*o, *d, f32::INFINITY, None).is_some()).count();
        eprintln!(
            "{name}: {} segments, {} BVH capsules, {n}x{n} copies, {:.1} % of rays hit",
            exemplar.segment_count(),
            scene.primitive_count(),
            100.0 * hits as f64 / RAYS as f64
        );
        let mut group = c.benchmark_group(format!("raycast_{name}"));
        let (camera, scatter): (Vec<_>, Vec<_>) = rays.iter().enumerate().partition(|(i, _)| i % 2 == 0);
        let camera: Vec<(Vec3, Vec3)> = camera.into_iter().map(|(_, r)| *r).collect();
        let scatter: Vec<(Vec3, Vec3)> = scatter.into_iter().map(|(_, r)| *r).collect();
        for (label, set) in
            [("closest_hit", &rays), ("closest_hit_camera", &camera), ("closest_hit_scatter", &scatter)]
        {
            group.throughput(Throughput::Elements(set.len() as u64));
            group.bench_function(label, |b| {
                b.iter(|| {
                    let mut count = 0u32;
                    for &(o, d) in set {
                        count += u32::from(scene.closest_hit(o, d, f32::INFINITY, None).is_some());
                    }
                    black_box(count)
                });
            });
        }
        group.throughput(Throughput::Elements(RAYS as u64));
        group.bench_function("any_hit", |b| {
            b.iter(|| {
                let mut count = 0u32;
                for &(o, d) in &rays {
                    count += u32::from(scene.any_hit(o, d, f32::INFINITY, None));
                }
                black_box(count)
            });
        });
        group.finish();
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(4));
    targets = bench
}
criterion_main!(benches);
