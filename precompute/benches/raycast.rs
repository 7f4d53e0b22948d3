//! Incoherent fiber ray casting throughput, single thread, on the real fabric presets.
//!
//! Scenes: the `default` (~20k segments) and `large` (~100k segments) presets of
//! `fabric::presets`, each clipped to a 2 cm x 2 cm swatch. Rays: the camera and scatter
//! families of `raycast::throughput` (`twill bench raycast` measures the same for any scene).
//!
//! Each family is cast with `closest_hit` and with `any_hit`. Criterion reports elements/s =
//! rays/s on one core. Run with `cargo bench -p twill-precompute --bench raycast`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::Vec3;
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;
use twill_precompute::fabric::presets::fabric_preset;
use twill_precompute::raycast::FiberScene;
use twill_precompute::raycast::throughput::{camera_rays, scatter_rays, swatch_extent};

const RAYS: usize = 1 << 15;
const SWATCH_CM: f32 = 2.0;

fn bench(c: &mut Criterion) {
    for name in ["default", "large"] {
        let exemplar = fabric_preset(name).expect("preset").fabric.build(Path::new(".")).expect("fabric");
        let scene = FiberScene::new(&exemplar, swatch_extent(SWATCH_CM)).expect("scene");
        let camera = camera_rays(&scene, SWATCH_CM, RAYS, 1);
        let scatter = scatter_rays(&scene, SWATCH_CM, RAYS, 2);
        let hit_fraction = |set: &[(Vec3, Vec3)]| {
            let hits = set.iter().filter(|(o, d)| scene.closest_hit(*o, *d, f32::INFINITY, None).is_some());
            100.0 * hits.count() as f64 / set.len() as f64
        };
        eprintln!(
            "{name}: {} segments, {} capsules, {:.1} % of camera and {:.1} % of scatter rays hit",
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
