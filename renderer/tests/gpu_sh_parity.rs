//! The WGSL spherical harmonics (`shaders/shared/sh.wgsl`) against their f64 originals in
//! `twill_precompute::sh`, on a real Vulkan adapter (lavapipe on machines without a GPU), for
//! every order 0..=6: evaluation over 2,000+ directions (poles, near-poles, equator, ±x, ±y),
//! rotation over 300+ rotations (identity, half turns about x, y, z and an oblique axis,
//! turns about the pole, random ones), and the rotated zonal helper. NaN or Inf anywhere fails,
//! and so does a write past the `(order + 1)^2` leading entries.
//!
//! Errors are measured as the largest coefficient error divided by the 2-norm of the reference
//! coefficient vector (for evaluation, `|Y| = (order + 1) / sqrt(4 pi)` by the addition
//! theorem). Tolerance [`TOLERANCE`].
//!
//! Without an adapter these tests fail, unless `TWILL_ALLOW_NO_GPU=1` is set, in which case
//! they print a loud SKIPPED line: skipping is never silent.

use glam::{DMat3, DVec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::f64::consts::PI;
use twill_precompute::sh::{ShRotation, sh_count, sh_eval, sh_index};
use twill_renderer::gpu::Gpu;
use twill_renderer::shaders;

/// Largest coefficient error allowed, relative to the reference vector's 2-norm.
const TOLERANCE: f64 = 1e-5;
const MAX_ORDER: usize = 6;
/// What the test wrappers put in the entries past `(order + 1)^2`: they must come back as is.
const SENTINEL: f32 = 1234.5;
/// Four coefficients per invocation: 13 chunks cover the 49 of order 6.
const CHUNKS: usize = 13;

/// Test wrappers appended to `shared/sh.wgsl` (composed). The input's `w` packs integers exactly
/// (`seed * 91 + order * 13 + chunk`, below 2^24); each call returns coefficients
/// `4 chunk .. 4 chunk + 4` (0 past 49).
const WRAPPERS: &str = r"
const SH_TEST_SENTINEL: f32 = 1234.5;

// PCG hash (Jarzynski & Olano 2020), mirrored by test_hash in Rust.
fn sh_test_hash(x: u32) -> u32 {
    let state = x * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Exactly representable values in [-0.5, 0.5), mirrored by test_value in Rust.
fn sh_test_value(seed: u32, j: u32) -> f32 {
    return f32(sh_test_hash(seed * 64u + j) >> 8u) / 16777216.0 - 0.5;
}

fn sh_test_at(a: ptr<function, array<f32, 49>>, j: u32) -> f32 {
    if (j < 49u) {
        return (*a)[j];
    }
    return 0.0;
}

fn sh_test_chunk(a: ptr<function, array<f32, 49>>, chunk: u32) -> vec4<f32> {
    let j = 4u * chunk;
    return vec4<f32>(sh_test_at(a, j), sh_test_at(a, j + 1u), sh_test_at(a, j + 2u), sh_test_at(a, j + 3u));
}

// glam's DMat3::from_axis_angle(w / |w|, |w|), identity for w = 0.
fn sh_test_rotation(w: vec3<f32>) -> mat3x3<f32> {
    let angle = length(w);
    if (angle == 0.0) {
        return mat3x3<f32>(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 0.0, 1.0));
    }
    let axis = w / angle;
    let s = sin(angle);
    let c = cos(angle);
    let sa = axis * s;
    let a2 = axis * axis;
    let omc = 1.0 - c;
    let xyomc = axis.x * axis.y * omc;
    let xzomc = axis.x * axis.z * omc;
    let yzomc = axis.y * axis.z * omc;
    return mat3x3<f32>(
        vec3<f32>(a2.x * omc + c, xyomc + sa.z, xzomc - sa.y),
        vec3<f32>(xyomc - sa.z, a2.y * omc + c, yzomc + sa.x),
        vec3<f32>(xzomc + sa.y, yzomc - sa.x, a2.z * omc + c),
    );
}

fn sh_test_eval(dir: vec3<f32>, packed: u32) -> vec4<f32> {
    var y: array<f32, 49>;
    for (var j = 0u; j < 49u; j++) {
        y[j] = SH_TEST_SENTINEL;
    }
    sh_eval_f32((packed / 13u) % 7u, dir, &y);
    return sh_test_chunk(&y, packed % 13u);
}

fn sh_test_rotate(w: vec3<f32>, packed: u32) -> vec4<f32> {
    let order = (packed / 13u) % 7u;
    let seed = packed / 91u;
    var c: array<f32, 49>;
    for (var j = 0u; j < 49u; j++) {
        c[j] = select(SH_TEST_SENTINEL, sh_test_value(seed, j), j < sh_count(order));
    }
    sh_rotate_f32(order, sh_test_rotation(w), &c);
    return sh_test_chunk(&c, packed % 13u);
}

fn sh_test_zonal(axis: vec3<f32>, packed: u32) -> vec4<f32> {
    let order = (packed / 13u) % 7u;
    let seed = packed / 91u;
    var zonal: array<f32, 7>;
    for (var l = 0u; l < 7u; l++) {
        zonal[l] = sh_test_value(seed, l);
    }
    var c: array<f32, 49>;
    for (var j = 0u; j < 49u; j++) {
        c[j] = SH_TEST_SENTINEL;
    }
    sh_zonal_rotated_f32(order, axis, &zonal, &c);
    return sh_test_chunk(&c, packed % 13u);
}
";

fn library() -> String {
    format!("{}\n{WRAPPERS}", shaders::compose("shared/sh.wgsl").expect("sh.wgsl composes"))
}

/// Twin of `sh_test_hash`.
fn test_hash(x: u32) -> u32 {
    let state = x.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// Twin of `sh_test_value` (exact in f32, so both sides start from the same numbers).
fn test_value(seed: u32, j: u32) -> f64 {
    f64((test_hash(seed.wrapping_mul(64).wrapping_add(j)) >> 8) as f32 / 16_777_216.0 - 0.5)
}

fn f64(x: f32) -> f64 {
    f64::from(x)
}

fn to_f64(v: [f32; 3]) -> DVec3 {
    DVec3::new(f64(v[0]), f64(v[1]), f64(v[2]))
}

/// The rotation the WGSL `sh_test_rotation` builds from the rotation vector `w`, in f64.
fn rotation_of(w: [f32; 3]) -> DMat3 {
    let w = to_f64(w);
    let angle = w.length();
    if angle == 0.0 { DMat3::IDENTITY } else { DMat3::from_axis_angle(w / angle, angle) }
}

/// One invocation per (case, order, chunk), `case` also being the coefficient seed.
fn packed_inputs(cases: &[[f32; 3]]) -> Vec<[f32; 4]> {
    let mut inputs = Vec::new();
    for (case, v) in cases.iter().enumerate() {
        for order in 0..=MAX_ORDER {
            for chunk in 0..sh_count(order).div_ceil(4) {
                let packed = (case * 7 + order) * CHUNKS + chunk;
                assert!(packed < 1 << 24);
                inputs.push([v[0], v[1], v[2], packed as f32]);
            }
        }
    }
    inputs
}

/// The GPU coefficients per (case, order), with the sentinel entries past `sh_count(order)`
/// checked and dropped, and non-finite values failing.
fn unpack(cases: usize, inputs: &[[f32; 4]], out: &[[f32; 4]]) -> Vec<Vec<Vec<f64>>> {
    let mut result = vec![vec![vec![f64::NAN; sh_count(MAX_ORDER)]; MAX_ORDER + 1]; cases];
    for (input, r) in inputs.iter().zip(out) {
        let packed = input[3] as usize;
        let (case, order, chunk) = (packed / (7 * CHUNKS), packed / CHUNKS % 7, packed % CHUNKS);
        assert!(r.iter().all(|v| v.is_finite()), "{input:?}: non-finite GPU result {r:?}");
        for (k, &v) in r.iter().enumerate() {
            let j = 4 * chunk + k;
            if j < sh_count(order) {
                result[case][order][j] = f64(v);
            } else if j < sh_count(MAX_ORDER) {
                assert!(v == SENTINEL, "{input:?}: entry {j} past order {order} was overwritten: {v}");
            }
        }
    }
    for (case, orders) in result.iter_mut().enumerate() {
        for (order, coeffs) in orders.iter_mut().enumerate() {
            coeffs.truncate(sh_count(order));
            assert!(coeffs.iter().all(|c| !c.is_nan()), "case {case}, order {order}: missing outputs");
        }
    }
    result
}

/// Largest coefficient error relative to the reference's 2-norm.
fn relative_error(gpu: &[f64], reference: &[f64]) -> f64 {
    let norm = reference.iter().map(|c| c * c).sum::<f64>().sqrt();
    gpu.iter().zip(reference).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max) / norm
}

/// Tracks the worst error per order, with the case it came from.
struct Worst(Vec<(f64, String)>);

impl Worst {
    fn new() -> Self {
        Self(vec![(0.0, String::new()); MAX_ORDER + 1])
    }

    fn check(&mut self, what: &str, order: usize, case: &str, gpu: &[f64], reference: &[f64]) {
        let e = relative_error(gpu, reference);
        assert!(
            e < TOLERANCE,
            "{what}, order {order}, {case}: relative error {e:.2e}\n  GPU {gpu:?}\n  f64 {reference:?}"
        );
        if e >= self.0[order].0 {
            self.0[order] = (e, case.to_owned());
        }
    }

    fn report(&self, what: &str, cases: usize) {
        eprintln!("{what}: GPU vs f64 over {cases} cases, worst error / |reference| per order:");
        for (order, (e, case)) in self.0.iter().enumerate() {
            eprintln!("  order {order}: {e:.2e} ({case})");
        }
    }
}

/// 2,000 spherical Fibonacci directions plus the hard ones: poles, 1e-7 off them, the
/// equator, ±x, ±y.
fn directions() -> Vec<[f32; 3]> {
    let mut dirs: Vec<DVec3> = vec![
        DVec3::X,
        DVec3::NEG_X,
        DVec3::Y,
        DVec3::NEG_Y,
        DVec3::Z,
        DVec3::NEG_Z,
        DVec3::new(1e-7, 0.0, 1.0),
        DVec3::new(0.0, -1e-7, 1.0),
        DVec3::new(1e-7, 1e-7, -1.0),
        DVec3::new(-1e-7, 0.0, -1.0),
        DVec3::new(1.0, 1.0, 1.0),
        DVec3::new(-1.0, 1.0, -1.0),
        DVec3::new(1.0, 0.0, 1e-7),
    ];
    dirs.extend((0..16).map(|k| {
        let phi = f64::from(k) * PI / 8.0;
        DVec3::new(phi.cos(), phi.sin(), 0.0)
    }));
    dirs.extend(twill_precompute::fibonacci::spherical_fibonacci(2000));
    dirs.iter()
        .map(|d| {
            let d = d.normalize();
            [d.x as f32, d.y as f32, d.z as f32]
        })
        .collect()
}

/// Rotation vectors (axis times angle): identity, half turns about x, y, z and an oblique axis,
/// near half turns, quarter and tiny turns, turns about the pole (z), and random ones.
fn rotations() -> Vec<(String, [f32; 3])> {
    let pi = std::f32::consts::PI;
    let mut named = vec![
        ("identity".to_owned(), [0.0, 0.0, 0.0]),
        ("x by pi".to_owned(), [pi, 0.0, 0.0]),
        ("y by pi".to_owned(), [0.0, pi, 0.0]),
        ("z by pi".to_owned(), [0.0, 0.0, pi]),
        ("x by -pi".to_owned(), [-pi, 0.0, 0.0]),
        ("y by -pi".to_owned(), [0.0, -pi, 0.0]),
        ("z by -pi".to_owned(), [0.0, 0.0, -pi]),
        ("x by pi - 1e-4".to_owned(), [pi - 1e-4, 0.0, 0.0]),
        ("x by pi/2".to_owned(), [0.5 * pi, 0.0, 0.0]),
        ("y by pi/2".to_owned(), [0.0, 0.5 * pi, 0.0]),
        ("y by 1e-6".to_owned(), [0.0, 1e-6, 0.0]),
        ("x by 1e-30".to_owned(), [1e-30, 0.0, 0.0]),
    ];
    let oblique = DVec3::new(0.3, -0.5, 0.81).normalize() * PI;
    named.push(("oblique axis by pi".to_owned(), [oblique.x as f32, oblique.y as f32, oblique.z as f32]));
    for k in 0..24 {
        let angle = -pi + 2.0 * pi * k as f32 / 23.0;
        named.push((format!("z by {angle}"), [0.0, 0.0, angle]));
    }
    let mut rng = Pcg64::seed_from_u64(20_240_611);
    for i in 0..280 {
        let axis = loop {
            let v = DVec3::new(rng.random::<f64>(), rng.random::<f64>(), rng.random::<f64>()) * 2.0 - 1.0;
            if v.length_squared() > 1e-4 && v.length_squared() <= 1.0 {
                break v.normalize();
            }
        };
        let w = axis * rng.random::<f64>() * PI;
        named.push((format!("random {i}"), [w.x as f32, w.y as f32, w.z as f32]));
    }
    named
}

#[test]
fn sh_eval_matches_its_f64_original_for_orders_0_to_6() {
    let Some(gpu) = Gpu::for_test("sh_eval_matches_its_f64_original_for_orders_0_to_6") else { return };
    let dirs = directions();
    assert!(dirs.len() >= 2000);
    let inputs = packed_inputs(&dirs);
    let out =
        gpu.evaluate(&library(), "sh_test_eval(input.xyz, u32(input.w))", &inputs).expect("GPU evaluation");
    let results = unpack(dirs.len(), &inputs, &out);
    let mut worst = Worst::new();
    for (dir, orders) in dirs.iter().zip(&results) {
        for (order, gpu_coeffs) in orders.iter().enumerate() {
            let mut reference = vec![0.0; sh_count(order)];
            sh_eval(order, to_f64(*dir), &mut reference);
            worst.check("sh_eval_f32", order, &format!("dir {dir:?}"), gpu_coeffs, &reference);
        }
    }
    worst.report("sh_eval_f32", dirs.len());
}

#[test]
fn sh_rotate_matches_sh_rotation_for_orders_0_to_6() {
    let Some(gpu) = Gpu::for_test("sh_rotate_matches_sh_rotation_for_orders_0_to_6") else { return };
    let named = rotations();
    assert!(named.len() >= 300);
    let vectors: Vec<[f32; 3]> = named.iter().map(|(_, w)| *w).collect();
    let inputs = packed_inputs(&vectors);
    let out =
        gpu.evaluate(&library(), "sh_test_rotate(input.xyz, u32(input.w))", &inputs).expect("GPU evaluation");
    let results = unpack(vectors.len(), &inputs, &out);
    let mut worst = Worst::new();
    for (case, ((name, w), orders)) in named.iter().zip(&results).enumerate() {
        let r = rotation_of(*w);
        for (order, gpu_coeffs) in orders.iter().enumerate() {
            let n = sh_count(order);
            let input: Vec<f64> = (0..n as u32).map(|j| test_value(case as u32, j)).collect();
            let mut reference = vec![0.0; n];
            ShRotation::new(order, &r).apply(&input, &mut reference);
            worst.check("sh_rotate_f32", order, name, gpu_coeffs, &reference);
        }
    }
    worst.report("sh_rotate_f32", named.len());
}

#[test]
fn sh_zonal_rotated_matches_sh_rotation_of_the_zonal_coefficients() {
    let Some(gpu) = Gpu::for_test("sh_zonal_rotated_matches_sh_rotation_of_the_zonal_coefficients") else {
        return;
    };
    let axes = directions();
    let inputs = packed_inputs(&axes);
    let out =
        gpu.evaluate(&library(), "sh_test_zonal(input.xyz, u32(input.w))", &inputs).expect("GPU evaluation");
    let results = unpack(axes.len(), &inputs, &out);
    let mut worst = Worst::new();
    let mut worst_formula: f64 = 0.0;
    for (case, (axis, orders)) in axes.iter().zip(&results).enumerate() {
        let axis = to_f64(*axis).normalize();
        // Any rotation taking +z to the axis: a right-handed orthonormal frame (Duff et al. 2017)
        // with the axis as its third column, accurate at the poles too.
        let (b1, b2) = axis.any_orthonormal_pair();
        let r = DMat3::from_cols(b1, b2, axis);
        for (order, gpu_coeffs) in orders.iter().enumerate() {
            let n = sh_count(order);
            let mut zonal = vec![0.0; n];
            for l in 0..=order {
                zonal[sh_index(l, 0)] = test_value(case as u32, l as u32);
            }
            let mut reference = vec![0.0; n];
            ShRotation::new(order, &r).apply(&zonal, &mut reference);
            // The identity the helper rests on, in f64: c_lm = sqrt(4 pi / (2l + 1)) z_l Y_lm(axis).
            let mut y = vec![0.0; n];
            sh_eval(order, axis, &mut y);
            for l in 0..=order {
                let scale = (4.0 * PI / (2 * l + 1) as f64).sqrt() * zonal[sh_index(l, 0)];
                for m in -(l as isize)..=l as isize {
                    let j = sh_index(l, m);
                    worst_formula = worst_formula.max((scale * y[j] - reference[j]).abs());
                }
            }
            worst.check("sh_zonal_rotated_f32", order, &format!("axis {axis}"), gpu_coeffs, &reference);
        }
    }
    assert!(worst_formula < 1e-12, "zonal rotation identity off by {worst_formula:e} in f64");
    worst.report("sh_zonal_rotated_f32", axes.len());
}
