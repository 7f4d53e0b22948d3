//! Incoherent fiber ray casting throughput, single thread, on the real fabric presets.
//!
//! Scenes: the `default` (~20k segments) and `large` (~100k segments) presets of
//! `fabric::presets`, each clipped to a 2 cm x 2 cm swatch (`Extent::Rectangle`). Rays:
//! - `camera`: from 0.5 cm above the fabric, aimed at random points of the swatch inside the slab;
//! - `scatter`: from random points inside the slab, in uniformly random directions.
//!
//! Each family is cast with `closest_hit` and with `any_hit`. Criterion reports elements/s =
//! rays/s on one core. Run with `cargo bench -p twill-precompute --bench raycast`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;
use twill_precompute::fabric::presets::fabric_preset;
use twill_precompute::raycast::{Extent, FiberScene};

const RAYS: usize = 1 << 15;
const SWATCH_CM: f32 = 2.0;

/// A uniformly random point of the swatch's fabric slab (z between `lo` and `hi`).
fn point_in_slab(rng: &mut Pcg64, lo: f32, hi: f32) -> Vec3 {
    Vec3::new(rng.random::<f32>() * SWATCH_CM, rng.random::<f32>() * SWATCH_CM, rng.random_range(lo..hi))
}

/// Camera-like rays: from above the fabric, aimed into the slab.
fn camera_rays(scene: &FiberScene, seed: u64) -> Vec<(Vec3, Vec3)> {
    let (lo, hi) = scene.slab();
    let mut rng = Pcg64::seed_from_u64(seed);
    (0..RAYS)
        .map(|_| {
            let p = point_in_slab(&mut rng, lo, hi);
            let o = p + Vec3::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5), 0.5 + hi - p.z);
            (o, (p - o).normalize())
        })
        .collect()
}

/// Scattering-like rays: from random points inside the slab, uniformly random directions.
fn scatter_rays(scene: &FiberScene, seed: u64) -> Vec<(Vec3, Vec3)> {
    let (lo, hi) = scene.slab();
    let mut rng = Pcg64::seed_from_u64(seed);
    (0..RAYS)
        .map(|_| {
            let p = point_in_slab(&mut rng, lo, hi);
            let z: f32 = rng.random_range(-1.0..1.0);
            let phi = rng.random::<f32>() * std::f32::consts::TAU;
            let s = (1.0 - z * z).sqrt();
            (p, Vec3::new(s * phi.cos(), s * phi.sin(), z))
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    for name in ["default", "large"] {
        let exemplar = fabric_preset(name).expect("preset").fabric.build(Path::new(".")).expect("fabric");
        let extent = Extent::Rectangle { min: Vec2::ZERO, max: Vec2::splat(SWATCH_CM) };
        let scene = FiberScene::new(&exemplar, extent).expect("scene");
        let camera = camera_rays(&scene, 1);
        let scatter = scatter_rays(&scene, 2);
        let hit_fraction = |set: &[(Vec3, Vec3)]| {
            let hits = set.iter().filter(|(o, d)| scene.closest_hit(*o, *d, f32::INFINITY, None).is_some());
            100.0 * hits.count() as f64 / set.len() as f64
        };
        eprintln!(
            "{name}: {} segments, {} BVH capsules, {:.1} % of camera and {:.1} % of scatter rays hit",
            exemplar.segment_count(),
            scene.primitive_count(),
            hit_fraction(&camera),
            hit_fraction(&scatter),
        );
        let mut group = c.benchmark_group(format!("raycast_{name}"));
        group.throughput(Throughput::Elements(RAYS as u64));
        for (family, set) in [("camera", &camera), ("scatter", &scatter)] {
            group.bench_function(format!("closest_hit_{family}"), |b| {
                b.iter(|| {
                    let mut count = 0u32;
                    for &(o, d) in set {
                        count += u32::from(scene.closest_hit(o, d, f32::INFINITY, None).is_some());
                    }
                    black_box(count)
                });
            });
            group.bench_function(format!("any_hit_{family}"), |b| {
                b.iter(|| {
                    let mut count = 0u32;
                    for &(o, d) in set {
                        count += u32::from(scene.any_hit(o, d, f32::INFINITY, None));
                    }
                    black_box(count)
                });
            });
        }
        group.finish();
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    targets = bench
}
criterion_main!(benches);
