//! Precomputation benchmarks that `twill bake`'s per-stage report does not cover: the PCA of
//! SSDFs at the paper's image size (128 x 128, K = 48), where the randomized range finder runs.
//!
//! Run: `cargo bench -p twill-precompute --bench bake`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use twill_precompute::bake::Cancel;
use twill_precompute::bake::pca::{PcaMethod, compress};

fn pca_at_paper_resolution(c: &mut Criterion) {
    let (segments, dims) = (2000, 128 * 128);
    let mut rng = Pcg64::seed_from_u64(5);
    let data: Vec<f32> = (0..segments * dims).map(|_| rng.random::<f32>()).collect();
    let mut group = c.benchmark_group("pca");
    group.sample_size(10);
    group.throughput(Throughput::Elements(segments as u64));
    group.bench_function("randomized_128x128_k48_2000_segments", |b| {
        b.iter(|| {
            let basis = compress(&data, dims, 48, 1, &Cancel::new()).expect("valid input");
            assert_eq!(basis.stats.method, PcaMethod::RandomizedRangeFinder);
            basis
        });
    });
    group.finish();
}

criterion_group!(benches, pca_at_paper_resolution);
criterion_main!(benches);
