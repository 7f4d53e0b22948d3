//! The WGSL render-time shading (shaders/shared/shading.wgsl) against its f64 Rust twins
//! (twill_precompute::shading) on a real Vulkan adapter, on draft bakes of the default fabric
//! with its own materials and with the narrowest lobes the model allows on the warp
//! (β_R = β_TT = γ_TT = 0.5°), over grids that include the hard cases: λ from 1e-4 to 1e5, ξ and
//! ωo along ±t, grazing directions, fully occluded and fully visible segments. NaN or Inf
//! fails.
//!
//! Tolerance: |gpu − cpu| ≤ 2e-3 · scale + 1e-6, where scale is the largest |cpu| value of that
//! function over the grid's same segment. It covers f32 transcendental and table arithmetic;
//! the GPU's f16 copy of the IIRTF, which alone accounts for the multiple-scattering
//! differences (up to 3.4e-4 of scale measured, under 5e-6 against a CPU fed the same
//! f16-rounded matrix); and the far tails of the 0.5° lobes (up to 7.9e-4 measured), where
//! exp(−λ(θi + θo)²) with λ = 1/(2β²) ≈ 6566 multiplies f32 angle rounding by 2λ|θi + θo|. The
//! SSDF sign step is compared only where |d| > 1e-3 rad, since the sign of a near-zero f32 sum
//! is not the f64 one.
//!
//! Fiber lobes (`BakeSettings::fiber_lobes`), on a draft bake of the silk satin with them (its
//! cells keep lobes nearly everywhere): the WGSL `lobe_quadrature` against its twin over κ,
//! axes, grazing views and offset distributions, each case relative to its own value
//! ([`QUADRATURE_BOUND`]); the whole per-light term (`shade_fiber_lobes`) against
//! `shading::multiple::lobe_scattering` over the grid of the other functions
//! ([`LOBES_BOUND`], and the shared tolerance); whole one-sample GPU frames against the CPU
//! method shading the same primary hits, per pixel ([`FRAME_PIXEL_TOLERANCE`]); and the plan
//! compiles the lobes in only for a bake that has them.

use std::collections::HashMap;

use glam::{DVec3, Vec3};
use twill_precompute::bake::Cancel;
use twill_precompute::bake::iirtf::{
    CellTransfer, LOBE_AZIMUTH_TERMS, LOBE_FOURIER_TERMS, LOBE_PACKED_FLOATS,
};
use twill_precompute::bake::pattern::PatternMap;
use twill_precompute::bake::pipeline::{BakeInputs, Baked, bake};
use twill_precompute::bake::settings::{BakeSettings, Quality};
use twill_precompute::bcsdf::{FiberParams, MaterialDesc};
use twill_precompute::pathtrace::{Component, Light};
use twill_precompute::scene::{Scene, SceneFile, camera_from};
use twill_precompute::shading::gamma::{LobeAngles, lobe_quadrature};
use twill_precompute::shading::multiple::FiberLobe;
use twill_precompute::shading::{self, SegmentShading};
use twill_precompute::{Rgb, sh};
use twill_renderer::fabric_data::FabricArrays;
use twill_renderer::fabric_data::FabricData;
use twill_renderer::frame::plan_frame;
use twill_renderer::gpu::Gpu;
use twill_renderer::headless::{frame_settings, renderer_on_mesh};
use twill_renderer::passes::shade::ShadeVariant;
use twill_renderer::plan::Components;
use twill_renderer::shaders;

/// The default scene's draft bake (no fiber lobes; local visibility from the kept binary
/// images), shared by the tests of this binary.
fn default_bake() -> &'static Baked {
    static BAKE: std::sync::OnceLock<Baked> = std::sync::OnceLock::new();
    BAKE.get_or_init(|| draft_bake(&SceneFile::default_scene(), true))
}

/// A draft bake of `file`, with or without the binary visibility images
/// (`BakeSettings::visibility_bits`; without them, local visibility is the PCA SSDF's sign).
fn draft_bake(file: &SceneFile, visibility_bits: bool) -> Baked {
    let scene = file.build().expect("scene");
    let inputs = BakeInputs {
        exemplar: &scene.exemplar,
        materials: &scene.material_descs,
        // The SH transfer alone: the fiber lobes have their own bake (`lobe_bake`). Three
        // visibility points per segment, so every function reads images past the first. A
        // transfer of its own for each segment an eye sees (few paths: parity, not accuracy),
        // so that the multiple-scattering cases take both the segments' and the cells'.
        settings: BakeSettings {
            fiber_lobes: false,
            visibility_points: 3,
            visibility_bits,
            segment_transfer_paths: 16,
            ..Quality::Draft.settings()
        },
    };
    bake(&inputs, None, &Cancel::new(), &|_, _| {}).expect("draft bake").baked
}

/// The lobe widths of the narrowest material the model allows (0.5°, `BETA_RANGE_DEG` and
/// `GAMMA_RANGE_DEG`): the sharpest Gn, longitudinal and azimuthal lobes shading meets.
const NARROW_DEG: f64 = 0.5;

/// The narrowest fiber material.
fn narrow_material() -> MaterialDesc {
    MaterialDesc::Fiber(FiberParams {
        c_r: Rgb::new(0.04, 0.06, 0.08),
        beta_r_deg: NARROW_DEG,
        c_tt: Rgb::new(0.9, 0.6, 0.3),
        beta_tt_deg: NARROW_DEG,
        gamma_tt_deg: NARROW_DEG,
    })
}

/// The default scene with the narrowest fiber material on the warp yarns.
fn narrow_scene() -> SceneFile {
    let mut file = SceneFile::default_scene();
    file.materials.warp = Some(narrow_material());
    file
}

/// Direction codes shared by both sides: 0..32 are spherical Fibonacci points computed in f32
/// the same way in WGSL and Rust; 1000 = +t, 1001 = −t (each side's own unit tangent, exactly),
/// 1002 = near the fabric normal tilted
/// 1e-3 toward t, 1003 = +x, 1004 = +z, 1005 = grazing the fabric plane.
const FIB: u32 = 32;

fn direction_of(code: u32, t: DVec3) -> DVec3 {
    // ±t is the tangent itself, as in the WGSL (`return t;`), not t rounded through f32: that
    // lies up to 3.4e-8 off the f64 tangent, where S cos θi (∝ |ω⊥|/Gn(±π/2)) is already 3e-4.
    match code {
        1000 => return t,
        1001 => return -t,
        _ => {}
    }
    let tf = t.as_vec3();
    let d = match code {
        1002 => (Vec3::Z + 1e-3 * tf).normalize(),
        1003 => Vec3::X,
        1004 => Vec3::Z,
        1005 => Vec3::new(0.0, 1.0, 1e-3).normalize(),
        k => {
            let z = 1.0 - (2 * k + 1) as f32 / FIB as f32;
            let r = ((1.0 - z) * (1.0 + z)).max(0.0).sqrt();
            let phi = 2.0 * std::f32::consts::PI * (k as f32 * 0.618_034).fract();
            Vec3::new(r * phi.cos(), r * phi.sin(), z)
        }
    };
    d.as_dvec3().normalize()
}

/// WGSL decoding the test inputs: x = segment, y = λ, z = ωo code, w = ξ code.
const DECODE: &str = "
fn direction_of(code: u32, t: vec3<f32>) -> vec3<f32> {
    switch code {
        case 1000u: { return t; }
        case 1001u: { return -t; }
        case 1002u: { return normalize(vec3<f32>(0.0, 0.0, 1.0) + 1e-3 * t); }
        case 1003u: { return vec3<f32>(1.0, 0.0, 0.0); }
        case 1004u: { return vec3<f32>(0.0, 0.0, 1.0); }
        case 1005u: { return normalize(vec3<f32>(0.0, 1.0, 1e-3)); }
        default: {
            let z = 1.0 - f32(2u * code + 1u) / 32.0;
            let r = sqrt(max((1.0 - z) * (1.0 + z), 0.0));
            let phi = 2.0 * PI * fract(f32(code) * 0.618034);
            return normalize(vec3<f32>(r * cos(phi), r * sin(phi), z));
        }
    }
}
fn case_t(input: vec4<f32>) -> vec3<f32> {
    return normalize(segments[u32(input.x)].direction);
}
fn case_axis(input: vec4<f32>) -> vec3<f32> {
    return direction_of(u32(input.w), case_t(input));
}
fn case_wo(input: vec4<f32>) -> vec3<f32> {
    return direction_of(u32(input.z), case_t(input));
}
fn gamma_case(input: vec4<f32>) -> vec4<f32> {
    let s = segments[u32(input.x)];
    let space = omega_o_space(normalize(s.direction), case_wo(input));
    return vec4<f32>(sg_bcsdf_gamma(fiber_constants(s.material), space, case_axis(input), input.y), 0.0);
}
fn multiple_case(input: vec4<f32>) -> vec4<f32> {
    var c: array<vec3<f32>, 49>;
    for (var j = 0u; j < 49u; j++) { c[j] = vec3<f32>(0.0); }
    hemisphere_light_sh_accumulate(fabric.sh_order, case_axis(input), input.y, vec3<f32>(1.0), &c);
    return vec4<f32>(shade_multiple(0u, u32(input.x), case_point(input), case_wo(input), &c), 0.0);
}
// The visibility image a case shades with: one of its segment's points, picked from the id
// (twin: case_image in Rust).
fn case_image(input: vec4<f32>) -> u32 {
    let segment = u32(input.x);
    return segment * fabric.visibility_points + segment % fabric.visibility_points;
}
// A point of the cell lattice picked from the segment id (twin: case_point in Rust).
fn case_point(input: vec4<f32>) -> vec3<f32> {
    let ex = exemplars[0];
    let u = fract(vec3<f32>(input.x * 0.618034, input.x * 0.414214, input.x * 0.732051));
    return ex.cell_origin + u * vec3<f32>(cell_lattice(ex)) * ex.cell_size;
}
";

/// Twin of the WGSL `case_point`: a point of the cell lattice picked from the segment id, so
/// the interpolation of transfer between cells is compared too.
fn case_point(baked: &Baked, segment: u32) -> DVec3 {
    let grid = &baked.transfer.cells;
    // f32 like the shader: the fraction of a product of thousands loses digits the same way.
    let x = segment as f32;
    let fract = |a: f32| -> f64 { f64::from(a - a.floor()) };
    let u = DVec3::new(fract(x * 0.618_034), fract(x * 0.414_214), fract(x * 0.732_051));
    let lattice = DVec3::from(grid.lattice_dims().map(f64::from));
    grid.origin_cm() + u * lattice * grid.cell_size_cm()
}

/// Twin of the WGSL `case_image`: one of the segment's visibility points, picked from its id,
/// so every point's image is compared.
fn case_image(baked: &Baked, segment: u32) -> usize {
    let points = baked.visibility.points;
    segment as usize * points + segment as usize % points
}

#[derive(Clone)]
struct Case {
    segment: u32,
    lambda: f64,
    wo_code: u32,
    axis_code: u32,
}

impl Case {
    fn input(&self) -> [f32; 4] {
        [self.segment as f32, self.lambda as f32, self.wo_code as f32, self.axis_code as f32]
    }
    fn wo(&self, t: DVec3) -> DVec3 {
        direction_of(self.wo_code, t)
    }
    fn axis(&self, t: DVec3) -> DVec3 {
        direction_of(self.axis_code, t)
    }
}

/// The segments the grid uses: 12 spread over the bake.
fn grid_segments(baked: &Baked) -> Vec<u32> {
    let count = baked.volume.segments.len() as u32;
    (0..12).map(|i| (i * 1733 + 5) % count).collect()
}

/// Segments spread over the bake, directions over the sphere plus the hard ones.
fn cases(baked: &Baked, lambdas: &[f64]) -> Vec<Case> {
    let segments = grid_segments(baked);
    let specials = [1000, 1001, 1002, 1003, 1004, 1005];
    let wos: Vec<u32> = (0..FIB).step_by(3).chain(specials).collect();
    let mut out = Vec::new();
    for (k, &segment) in segments.iter().enumerate() {
        for (i, &wo_code) in wos.iter().enumerate() {
            for (j, &lambda) in lambdas.iter().enumerate() {
                let r = (i * 7 + j * 3 + k) as u32;
                let axis_code =
                    if r.is_multiple_of(5) { specials[(r as usize / 5) % specials.len()] } else { r % FIB };
                out.push(Case { segment, lambda, wo_code, axis_code });
            }
        }
    }
    out
}

/// Whether local visibility toward `dir` is clearly decided, so f32 and f64 agree on it: the
/// kept binary images' visible fraction is continuous in the direction (always), the PCA
/// SSDF's hard step only where the SSDF is at least 1e-3 from zero.
fn visibility_clearly_decided(baked: &Baked, image: usize, dir: DVec3) -> bool {
    let vis = &baked.visibility;
    vis.bits.is_some() || shading::ssdf_lookup(&vis.ssdf, image, dir).abs() > 1e-3
}

fn compare(name: &str, cases: &[Case], gpu: &[[f32; 4]], cpu: &[Option<Rgb>]) -> Vec<String> {
    let mut failures = Vec::new();
    let mut worst = 0.0_f64;
    // The tolerance's scale: the largest |cpu| value over the grid's cases of the same segment.
    let mut scales: HashMap<u32, f64> = HashMap::new();
    for (case, c) in cases.iter().zip(cpu) {
        let largest = c.map_or(0.0, |c| c.abs().max_element());
        let scale = scales.entry(case.segment).or_insert(0.0);
        *scale = scale.max(largest);
    }
    let mut compared = 0;
    for ((case, g), c) in cases.iter().zip(gpu).zip(cpu) {
        assert!(
            g.iter().all(|v| v.is_finite()),
            "{name}: non-finite GPU value {g:?} for segment {} λ {}",
            case.segment,
            case.lambda
        );
        let Some(c) = c else { continue };
        compared += 1;
        let scale = scales[&case.segment];
        for ch in 0..3 {
            let err = (f64::from(g[ch]) - c[ch]).abs();
            let allowed = 2e-3 * scale.max(c[ch].abs()) + 1e-6;
            worst = worst.max(err / (scale + 1e-30));
            if err > allowed {
                failures.push(format!(
                    "{name}: segment {} λ {} wo code {} axis code {}: GPU {} vs CPU {} (channel {ch}, allowed {allowed:.3e})",
                    case.segment, case.lambda, case.wo_code, case.axis_code, g[ch], c[ch]
                ));
            }
        }
    }
    let largest = scales.values().copied().fold(0.0, f64::max);
    eprintln!(
        "{name}: {compared} cases, worst error {worst:.2e} of its segment's largest value (largest over the grid {largest:.3e})"
    );
    assert!(compared > cases.len() / 2, "{name}: only {compared} of {} cases compared", cases.len());
    eprintln!("{name}: {} of {compared} cases outside the tolerance", failures.len());
    failures
}

/// Evaluates a WGSL expression over inputs on the GPU with a bake bound.
type GpuEvaluation<'a> = dyn Fn(&str, &[[f32; 4]]) -> Vec<[f32; 4]> + 'a;

/// `visibility_image` (WGSL) against `Baked::visibility_image` at points along the grid's
/// segments: fractions of the way from one end to the other away from the pieces' borders,
/// the caps beyond both ends, and (periodic exemplars) the same points a period away in x and
/// y. Positions are rounded to f32 first, as the shader gets them.
fn compare_visibility_images(label: &str, baked: &Baked, run: &GpuEvaluation<'_>) -> Vec<String> {
    let points = baked.visibility.points;
    let shifts: Vec<DVec3> = match baked.volume.volume.period() {
        Some(period) => vec![DVec3::ZERO, DVec3::new(period.x, 0.0, 0.0), DVec3::new(0.0, -period.y, 0.0)],
        None => vec![DVec3::ZERO],
    };
    let mut inputs = Vec::new();
    for segment in grid_segments(baked) {
        let [x, y, z, half] = baked.volume.segments.axis[segment as usize];
        let t = Vec3::from(baked.volume.segments.direction[segment as usize]).as_dvec3().normalize();
        let mid = DVec3::new(f64::from(x), f64::from(y), f64::from(z));
        for j in 0..points {
            for inside in [-0.3, 0.0, 0.3] {
                let u = (j as f64 + 0.5 + inside) / points as f64;
                for &shift in &shifts {
                    let p = mid + t * (2.0 * u - 1.0) * f64::from(half) + shift;
                    inputs.push([segment as f32, p.x as f32, p.y as f32, p.z as f32]);
                }
            }
        }
        for beyond in [-1.2, 1.2] {
            let p = mid + t * beyond * f64::from(half);
            inputs.push([segment as f32, p.x as f32, p.y as f32, p.z as f32]);
        }
    }
    let gpu = run("vec4<f32>(f32(visibility_image(0u, u32(input.x), input.yzw)), 0.0, 0.0, 0.0)", &inputs);
    let mut failures = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for (input, g) in inputs.iter().zip(&gpu) {
        let segment = input[0] as u32;
        let t = Vec3::from(baked.volume.segments.direction[segment as usize]).as_dvec3().normalize();
        let p = Vec3::new(input[1], input[2], input[3]).as_dvec3();
        let cpu = baked.visibility_image(segment as usize, t, Some(p));
        seen.insert(cpu % points);
        // Image indices are small integers, exact in f32.
        if (g[0] - cpu as f32).abs() > 0.25 {
            failures.push(format!(
                "{label}, visibility image: segment {segment} at {p}: GPU {} vs CPU {cpu}",
                g[0]
            ));
        }
    }
    eprintln!(
        "{label}, visibility image: {} points, {points} per segment, {} failures",
        inputs.len(),
        failures.len()
    );
    assert_eq!(seen.len(), points, "{label}: every visibility point must be compared");
    failures
}

#[test]
fn shading_functions_match_their_rust_twins() {
    let Some(gpu) = Gpu::for_test("shading_functions_match_their_rust_twins") else { return };
    let mut failures = Vec::new();
    failures.extend(compare_bake(&gpu, "default", default_bake()));
    // The narrow material's bake also takes local visibility from the PCA SSDF alone.
    let narrow = draft_bake(&narrow_scene(), false);
    let narrow_segments = grid_segments(&narrow)
        .into_iter()
        .filter(|&k| {
            narrow.materials[narrow.volume.segments.material[k as usize] as usize] == narrow_material()
        })
        .count();
    eprintln!("narrow: {narrow_segments} of the grid's segments have β_R = β_TT = γ_TT = {NARROW_DEG}°");
    assert!(narrow_segments > 0, "the grid must include segments of the narrowest material");
    failures.extend(compare_bake(&gpu, "narrow", &narrow));
    for f in failures.iter().take(20) {
        eprintln!("{f}");
    }
    assert!(failures.is_empty(), "{} GPU/CPU shading mismatches (first 20 printed above)", failures.len());
}

/// Every shading function of one bake over the grid; returns the mismatches, labelled.
fn compare_bake(gpu: &Gpu, label: &str, baked: &Baked) -> Vec<String> {
    let mut failures = Vec::new();
    let fabric =
        FabricData::upload(&gpu.device, &gpu.queue, &[baked], &PatternMap::uniform(0)).expect("upload");
    let library = format!("{}\n{DECODE}", shaders::shared_library());
    let run = |expression: &str, cases: &[Case]| {
        let inputs: Vec<[f32; 4]> = cases.iter().map(Case::input).collect();
        gpu.evaluate_with_fabric(&library, expression, &inputs, Some(&fabric)).expect("GPU evaluation")
    };
    let seg =
        |c: &Case| SegmentShading::of(baked, c.segment).expect("fiber segment").expect("non-zero segment");

    // Γ over λ = 1e-4 .. 1e5.
    let gamma_cases = cases(baked, &[1e-4, 1.0, 100.0, 300.0, 1e3, 1e4, 1e5]);
    let gpu_gamma = run("gamma_case(input)", &gamma_cases);
    let cpu_gamma: Vec<Option<Rgb>> = gamma_cases
        .iter()
        .map(|c| {
            let s = seg(c);
            let (lambda32, axis) = (f64::from(c.lambda as f32), c.axis(s.tangent));
            Some(shading::gamma(&s.fiber, &baked.gn, s.tangent, axis, lambda32, c.wo(s.tangent)))
        })
        .collect();
    failures.extend(compare(&format!("{label}, gamma"), &gamma_cases, &gpu_gamma, &cpu_gamma));

    // The visibility image of points along segments, beyond their ends and a period away.
    failures.extend(compare_visibility_images(label, baked, &|exp, inputs| {
        gpu.evaluate_with_fabric(&library, exp, inputs, Some(&fabric)).expect("GPU evaluation")
    }));

    // Directional single scattering (unit irradiance): compared where local visibility is
    // clearly decided.
    let dir_cases = cases(baked, &[0.0]);
    let gpu_dir = run(
        "vec4<f32>(shade_single_directional(0u, u32(input.x), case_image(input), case_wo(input), case_axis(input)), 0.0)",
        &dir_cases,
    );
    let cpu_dir: Vec<Option<Rgb>> = dir_cases
        .iter()
        .map(|c| {
            let s = seg(c);
            let wd = c.axis(s.tangent);
            visibility_clearly_decided(baked, case_image(baked, c.segment), wd).then(|| {
                shading::single_scattering_directional(
                    &s.fiber,
                    &baked.gn,
                    &baked.visibility,
                    case_image(baked, c.segment),
                    s.tangent,
                    c.wo(s.tangent),
                    wd,
                    Rgb::ONE,
                    1.0,
                )
            })
        })
        .collect();
    failures.extend(compare(&format!("{label}, single, directional"), &dir_cases, &gpu_dir, &cpu_dir));
    let occluded = cpu_dir.iter().flatten().filter(|c| c.max_element() == 0.0).count();
    let visible = cpu_dir.iter().flatten().filter(|c| c.max_element() > 0.0).count();
    eprintln!("{label}, single, directional: {occluded} occluded and {visible} visible cases");
    assert!(occluded > 0 && visible > 0, "the grid must include occluded and visible cases");

    // SG single scattering: sum-of-SGs (λ ≤ 100: at the SGs' centroids for broad lights, at
    // their Fibonacci axes for sharp ones, both between, `sos_centroid_share`), blend (150),
    // erf-SSDF or the kept bits (≥ 200).
    let sg_cases = cases(baked, &[1e-4, 2.0, 8.0, 16.0, 40.0, 100.0, 150.0, 300.0, 1e5]);
    let gpu_sg = run(
        "vec4<f32>(select(0.0, 1.0, input.y < 200.0) * shade_single_sg_sum_of_sg(0u, u32(input.x), case_image(input), case_wo(input), case_axis(input), input.y) * (1.0 - clamp((input.y - 100.0) / 100.0, 0.0, 1.0)) + select(0.0, 1.0, input.y > 100.0) * shade_single_sg_ssdf_erf(0u, u32(input.x), case_image(input), case_wo(input), case_axis(input), input.y) * clamp((input.y - 100.0) / 100.0, 0.0, 1.0), 0.0)",
        &sg_cases,
    );
    let cpu_sg: Vec<Option<Rgb>> = sg_cases
        .iter()
        .map(|c| {
            let s = seg(c);
            Some(shading::single_scattering_sg(
                &s.fiber,
                &baked.gn,
                &baked.visibility,
                case_image(baked, c.segment),
                s.tangent,
                c.wo(s.tangent),
                c.axis(s.tangent),
                f64::from(c.lambda as f32),
                Rgb::ONE,
                1.0,
            ))
        })
        .collect();
    failures.extend(compare(&format!("{label}, single, SG"), &sg_cases, &gpu_sg, &cpu_sg));

    // Multiple scattering of a unit directional light (λ < 0 marks directional) and SG lights.
    let ms_cases = cases(baked, &[-1.0, 2e-4, 8.0, 1e5]);
    let gpu_ms = run("multiple_case(input)", &ms_cases);
    let order = baked.transfer.iirtf.sh_order;
    let cpu_ms: Vec<Option<Rgb>> = ms_cases
        .iter()
        .map(|c| {
            let s = seg(c);
            let axis = c.axis(s.tangent);
            let light = if c.lambda < 0.0 {
                Light::directional(axis, Rgb::ONE).expect("light")
            } else {
                Light::sg(axis, f64::from(c.lambda as f32), Rgb::ONE).expect("light")
            };
            let c_light = shading::hemisphere_light_sh(&light, order, &baked.cg);
            assert_eq!(c_light.len(), sh::sh_count(order));
            let point = case_point(baked, c.segment);
            Some(
                shading::multiple_scattering(baked, c.segment, Some(point), c.wo(s.tangent), &c_light)
                    .expect("multiple"),
            )
        })
        .collect();
    failures.extend(compare(&format!("{label}, multiple"), &ms_cases, &gpu_ms, &cpu_ms));
    failures
}

// ---------------------------------------------------------------------------------------------
// Fiber lobes (`BakeSettings::fiber_lobes`): the WGSL quadrature against `lobe_quadrature`, the
// whole per-light term against `lobe_scattering`, and whole GPU frames against the CPU method
// at the same primary hits.

/// Side of the fiber-lobe frames, in pixels.
const LOBE_FRAME_SIZE: usize = 24;

/// A flat swatch of fabric preset `preset` (2 cm, no ground) seen by an orthographic camera
/// 0.3 cm high from 30° off the normal (well inside the swatch), under `lights` (TOML), at
/// LOBE_FRAME_SIZE x LOBE_FRAME_SIZE and one sample per pixel.
fn swatch_scene(preset: &str, lights: &[String]) -> Scene {
    let t = 30.0_f64.to_radians();
    let text = format!(
        "[fabric]\npreset = \"{preset}\"\n[swatch]\nsize_cm = [2.0, 2.0]\nground = false\n\
         [camera]\nprojection = \"orthographic\"\neye = [0.0, {:?}, {:?}]\ntarget = [0.0, 0.0, 0.0]\n\
         up = [0.0, 0.0, 1.0]\nheight_cm = 0.3\n{}[render]\nwidth = {LOBE_FRAME_SIZE}\nheight = {LOBE_FRAME_SIZE}\nspp = 1\n",
        -t.sin(),
        t.cos(),
        lights.concat()
    );
    SceneFile::parse(&text, std::path::Path::new("fiber_lobes.toml"))
        .unwrap_or_else(|e| panic!("{e}\n{text}"))
        .build()
        .unwrap_or_else(|e| panic!("{e}\n{text}"))
}

/// The silk satin swatch (`swatch_scene`): its cells keep their light as fiber lobes nearly
/// everywhere.
fn silk_scene(lights: &[String]) -> Scene {
    swatch_scene("silk_satin", lights)
}

/// Unit vector `theta_deg` from +z, toward +x rotated by `phi_deg` about z.
fn from_zenith(theta_deg: f64, phi_deg: f64) -> [f64; 3] {
    let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
}

fn directional_toml(direction: [f64; 3], irradiance: f64) -> String {
    format!(
        "[[lights]]\ntype = \"directional\"\ndirection = {direction:?}\nirradiance = [{irradiance:?}, {:?}, {:?}]\n",
        0.9 * irradiance,
        0.8 * irradiance
    )
}

fn sg_toml(axis: [f64; 3], sharpness: f64, intensity: f64) -> String {
    format!(
        "[[lights]]\ntype = \"sg\"\naxis = {axis:?}\nsharpness = {sharpness:?}\nintensity = [{:?}, {:?}, {intensity:?}]\n",
        0.8 * intensity,
        0.9 * intensity
    )
}

/// A directional light 40° from the zenith.
fn sun_toml() -> String {
    directional_toml(from_zenith(40.0, 120.0), 3.0)
}

/// The silk satin's draft bake with fiber lobes, shared by the tests of this binary.
fn lobe_bake() -> &'static Baked {
    static BAKE: std::sync::OnceLock<Baked> = std::sync::OnceLock::new();
    BAKE.get_or_init(|| {
        let scene = silk_scene(&[sun_toml()]);
        // Two visibility points per segment, as the interactive preset: the whole-frame
        // parity then also checks which image each pixel's hit takes.
        // Segment transfers too: the segments under cells that keep lobes take the lobes, the
        // others their own transfer, on both sides.
        let settings = BakeSettings {
            fiber_lobes: true,
            visibility_points: 2,
            segment_transfer_paths: 16,
            ..Quality::Draft.settings()
        };
        let inputs = BakeInputs { exemplar: &scene.exemplar, materials: &scene.material_descs, settings };
        let started = std::time::Instant::now();
        let mut baked =
            bake(&inputs, None, &Cancel::new(), &|_, _| {}).expect("draft bake with fiber lobes").baked;
        eprintln!("silk satin draft bake with fiber lobes: {:.1} s", started.elapsed().as_secs_f64());
        let given = give_reflected_segment_cells(&mut baked);
        eprintln!("{given} segments under lobe cells given a reflected-light transfer of their own");
        assert!(given > 100, "{given} segments under lobe cells given a transfer");
        baked
    })
}

/// Gives every other segment whose lattice cell keeps fiber lobes (and that has a segment cell)
/// a transfer of its own, a copy of a cell's matrix without lobes: what a bake whose reflected
/// light fits matrices holds there (`iirtf::MatrixLight::Reflected`; the silk's does not, so
/// its bake leaves them empty). Both twins then shade those segments with that matrix beside
/// the lattice cells' forward lobes alone (`multiple.rs` `LobesTaken::ForwardOnly`, WGSL
/// `fiber_lobes_at`), the others with both lobes. Returns how many it gave.
fn give_reflected_segment_cells(baked: &mut Baked) -> usize {
    let grid = baked.transfer.cells.clone();
    let cells = &mut baked.transfer.iirtf.cells;
    let donor = cells.iter().find(|c| c.paths > 0 && !c.has_lobes() && !c.matrix.is_empty()).cloned();
    let donor = donor.expect("a cell with a matrix");
    let mut given = 0;
    for k in (0..grid.segment_count() as u32).step_by(2) {
        let Some(own) = grid.segment_cell(k) else { continue };
        if cells[grid.cell_of_segment(k) as usize].keeps_lobe_light() && cells[own as usize].paths == 0 {
            cells[own as usize] = donor.clone();
            given += 1;
        }
    }
    given
}

/// Asserts that some of `baked`'s cells keep fiber lobes (a cell whose light is broad folds it
/// into its matrix), and that most of those carry light; returns how many cells have them.
fn assert_has_lobes(baked: &Baked) -> usize {
    let cells = &baked.transfer.iirtf.cells;
    let with = cells.iter().filter(|c| c.has_lobes()).count();
    let nonempty = cells.iter().filter(|c| !c.is_empty()).count();
    eprintln!("fiber lobes: {with} of {} cells ({nonempty} hold segments)", cells.len());
    assert!(with > 0, "a fiber-lobe bake of the silk satin must keep lobes in some cells");
    let lit = |c: &CellTransfer| c.forward[0].iter().chain(&c.reflected[0]).sum::<f32>() > 0.0;
    let strong = cells.iter().filter(|c| c.has_lobes() && lit(c)).count();
    assert!(strong * 2 > with, "most cells' lobes must carry light ({strong} of {with} do)");
    with
}

/// Floats of a quadrature case's offsets: the azimuthal means (`LobeAngles::azimuth`'s
/// layout, before smoothing), then the longitudinal ones.
const CASE_SHAPE_LEN: usize = 2 * LOBE_AZIMUTH_TERMS + 2 * LOBE_FOURIER_TERMS;

/// Turn, in radians, of the von Mises azimuth [`quadrature_cases`] add (so that the series'
/// odd terms count).
const AZIMUTH_TURN: f64 = 0.3;

/// A case's offsets ([`CASE_SHAPE_LEN`]): no azimuthal terms, then the Fourier terms `[c_1, s_1, …]` (`LobeAngles::fourier`) of a
/// wrapped normal offset of mean `mean_deg` and deviation `sigma_deg`:
/// `c_k + i s_k = exp(−k²σ²/2 + ikμ)`.
fn wrapped_normal(mean_deg: f64, sigma_deg: f64) -> Vec<f32> {
    let (mu, sigma) = (mean_deg.to_radians(), sigma_deg.to_radians());
    std::iter::repeat_n(0.0, 2 * LOBE_AZIMUTH_TERMS)
        .chain((1..=LOBE_FOURIER_TERMS).flat_map(|k| {
            let k = k as f64;
            let a = (-0.5 * k * k * sigma * sigma).exp();
            [(a * (k * mu).cos()) as f32, (a * (k * mu).sin()) as f32]
        }))
        .collect()
}

/// The offset distributions the quadrature is compared over, named: none (uniform), a sharp
/// one (σ 1.5°, so sharp that the cut series rings below zero and the clamp acts), a broad one (σ 15°),
/// a two-sided one, and the silk bake's own brightest cell's forward and reflected shapes (the
/// means of its nodes around one light, as `FiberLobe::angles` takes them; red, and the
/// reflected light's green, which one reflection fills more).
fn lobe_offsets(baked: &Baked) -> Vec<(String, Vec<f32>)> {
    let two_sided: Vec<f32> =
        wrapped_normal(8.0, 3.0).iter().zip(wrapped_normal(-8.0, 3.0)).map(|(a, b)| 0.5 * (a + b)).collect();
    let mut out = vec![
        ("uniform".to_owned(), vec![0.0; CASE_SHAPE_LEN]),
        ("sharp, +4° σ 1.5°".to_owned(), wrapped_normal(4.0, 1.5)),
        ("broad, −12° σ 15°".to_owned(), wrapped_normal(-12.0, 15.0)),
        ("two-sided, ±8° σ 3°".to_owned(), two_sided),
    ];
    let strength = |c: &CellTransfer| c.forward[0].iter().sum::<f32>();
    let brightest = baked
        .transfer
        .iirtf
        .cells
        .iter()
        .filter(|c| c.has_lobes())
        .max_by(|a, b| strength(a).total_cmp(&strength(b)))
        .expect("a cell with lobes");
    for (name, lobe, shape, channel) in [
        ("the silk's forward shape (red)", &brightest.forward, &brightest.forward_shape, 0),
        ("the silk's reflected shape (red)", &brightest.reflected, &brightest.reflected_shape, 0),
        ("the silk's reflected shape (green)", &brightest.reflected, &brightest.reflected_shape, 1),
    ] {
        assert!(lobe[0].iter().sum::<f32>() > 0.0, "{name}: no light");
        // The azimuthal means at a light 30° above the horizon and the longitudinal ones at a
        // light 12° off the fiber's normal plane, as FiberLobe::angles takes them.
        let cell_lobe = FiberLobe {
            strength: lobe.iter().map(|c| Vec3::from(*c).as_dvec3()).collect(),
            shape: shape.iter().map(|v| f64::from(*v)).collect(),
        };
        #[allow(clippy::cast_possible_truncation)]
        let azimuth = cell_lobe.azimuth_means(channel, 0.5).into_iter().map(|v| v as f32);
        #[allow(clippy::cast_possible_truncation)]
        let longitudinal = cell_lobe.longitudinal_means(channel, 0.2).into_iter().map(|v| v as f32);
        out.push((name.to_owned(), azimuth.chain(longitudinal).collect()));
    }
    out
}

/// Offset-code stride of the quadrature cases: the case's axis code is `axis + OFFSET_CODE ×
/// offset index`.
const OFFSET_CODE: u32 = 4096;

/// More direction codes for the quadrature cases, beyond [`direction_of`]'s: 1006 / 1007 =
/// ±t tilted 1e-3 toward +z (an axis nearly along the fiber), 1008 / 1009 = ±85° from the
/// fiber's normal plane (grazing θo), 2000 + k = Fibonacci point k mirrored across t (an axis
/// on the far side of the fiber from the view). f32 as the
/// WGSL twin (`lobe_case_direction`).
fn lobe_case_direction(code: u32, t: DVec3) -> DVec3 {
    let tf = t.as_vec3();
    let up = Vec3::Z;
    let d = match code {
        1006 => (tf + 1e-3 * up).normalize(),
        1007 => (-tf + 1e-3 * up).normalize(),
        1008 | 1009 => {
            let across = (up - up.dot(tf) * tf).normalize();
            let sign = if code == 1008 { 1.0 } else { -1.0 };
            (sign * 0.996_194_7 * tf + 0.087_155_74 * across).normalize()
        }
        c if c >= 2000 => {
            let a = direction_of(c - 2000, t).as_vec3();
            (2.0 * a.dot(tf) * tf - a).normalize()
        }
        c => return direction_of(c, t),
    };
    d.as_dvec3().normalize()
}

/// WGSL for the quadrature cases: x = segment, y = κ, z = ωo code, w = axis code + OFFSET_CODE
/// × offset (the offsets written out as WGSL arrays).
fn quadrature_decode(offsets: &[(String, Vec<f32>)]) -> String {
    let n = CASE_SHAPE_LEN;
    let arrays: Vec<String> = offsets
        .iter()
        .map(|(_, terms)| {
            let values: Vec<String> = terms.iter().map(|v| format!("{v:?}")).collect();
            format!("array<f32, {n}>({})", values.join(", "))
        })
        .collect();
    format!(
        "
fn lobe_case_offset(index: u32, kappa: f32, angles: ptr<function, LobeAngles>) {{
    var offsets = array<array<f32, {n}>, {count}>({arrays});
    let ratios = bessel_i_ratios(kappa);
    for (var k = 0u; k < LOBE_AZIMUTH_TERMS; k++) {{
        let turn = f32(k + 1u) * {turn:?};
        (*angles).azimuth[2u * k] = 0.5 * (offsets[index][2u * k] + ratios[k] * cos(turn));
        (*angles).azimuth[2u * k + 1u] = 0.5 * (offsets[index][2u * k + 1u] + ratios[k] * sin(turn));
    }}
    for (var i = 0u; i < 2u * LOBE_FOURIER_TERMS; i++) {{
        (*angles).fourier[i] = offsets[index][2u * LOBE_AZIMUTH_TERMS + i];
    }}
}}
fn lobe_case_direction(code: u32, t: vec3<f32>) -> vec3<f32> {{
    let up = vec3<f32>(0.0, 0.0, 1.0);
    switch code {{
        case 1006u: {{ return normalize(t + 1e-3 * up); }}
        case 1007u: {{ return normalize(-t + 1e-3 * up); }}
        case 1008u, 1009u: {{
            let across = normalize(up - dot(up, t) * t);
            let sign = select(-1.0, 1.0, code == 1008u);
            return normalize(sign * 0.9961947 * t + 0.08715574 * across);
        }}
        default: {{
            if (code >= 2000u) {{
                let a = direction_of(code - 2000u, t);
                return normalize(2.0 * dot(a, t) * t - a);
            }}
            return direction_of(code, t);
        }}
    }}
}}
fn quadrature_case(input: vec4<f32>) -> vec4<f32> {{
    var angles: LobeAngles;
    let code = u32(input.w);
    lobe_case_offset(code / {OFFSET_CODE}u, input.y, &angles);
    let s = segments[u32(input.x)];
    let t = case_t(input);
    let space = omega_o_space(t, lobe_case_direction(u32(input.z), t));
    let axis = lobe_case_direction(code % {OFFSET_CODE}u, t);
    let f = fiber_constants(s.material);
    return vec4<f32>(lobe_quadrature(f, bessel_i_ratios(f.kappa), space, axis, &angles), 0.0);
}}
",
        count = offsets.len(),
        arrays = arrays.join(",\n        "),
        turn = AZIMUTH_TURN as f32
    )
}

/// The quadrature cases: the grid's segments, κ 0, 0.5, 5 and 50 (a von Mises azimuth turned
/// [`AZIMUTH_TURN`] from the axis, mixed half and half with the offset's own azimuth: a
/// density, as the bake's means describe one), view directions over the sphere with ±t and ±85° (grazing
/// θo), axes over the sphere, mirrored across t, nearly along ±t, along ±t (with κ = 0) and
/// near the normal, every offset distribution.
fn quadrature_cases(baked: &Baked, offsets: usize) -> Vec<Case> {
    let wos: Vec<u32> = (0..FIB).step_by(4).chain([1000, 1001, 1004, 1005, 1008, 1009]).collect();
    let axes: Vec<u32> =
        (0..FIB).step_by(3).chain([1000, 1001, 1002, 1006, 1007, 2001, 2010, 2017, 2029]).collect();
    let mut out = Vec::new();
    for (k, &segment) in grid_segments(baked).iter().enumerate() {
        for (i, &wo_code) in wos.iter().enumerate() {
            for (j, kappa) in [0.0, 0.5, 5.0, 50.0].into_iter().enumerate() {
                for offset in 0..offsets {
                    let axis = match axes[(i * 7 + j * 3 + k + offset * 5) % axes.len()] {
                        // An axis along ±t has no azimuth φ', yet S_TT's azimuthal factor
                        // depends on it wherever κ > 0: each side takes its rounding's φ' (f64
                        // and f32 differ), so only κ = 0 compares there; 1e-3 off t otherwise.
                        // The silk's own shapes (offsets 4 and 5) carry azimuthal terms too.
                        along @ (1000 | 1001) if kappa > 0.0 || offset >= 4 => along + 6,
                        axis => axis,
                    };
                    let axis_code = axis + OFFSET_CODE * offset as u32;
                    out.push(Case { segment, lambda: kappa, wo_code, axis_code });
                }
            }
        }
    }
    out
}

/// How far GPU values are from CPU ones, each relative to its own case: the largest
/// `|gpu − cpu|` over `max(max |cpu|, floor.0 × the largest |cpu| of the case's segment,
/// floor.1 × the largest |cpu| of all cases)` (the floors keep values near zero from dividing
/// by nothing), and the cases above `bound`, labelled. Asserts every GPU value is finite and
/// that some cases carry light.
fn relative_parity(
    name: &str,
    cases: &[Case],
    gpu: &[[f32; 4]],
    cpu: &[Rgb],
    floor: (f64, f64),
    bound: f64,
) -> Vec<String> {
    let mut scales: HashMap<u32, f64> = HashMap::new();
    for (case, c) in cases.iter().zip(cpu) {
        assert!(c.is_finite(), "{name}: non-finite CPU value {c} for segment {}", case.segment);
        let scale = scales.entry(case.segment).or_insert(0.0);
        *scale = scale.max(c.abs().max_element());
    }
    let largest = scales.values().fold(0.0_f64, |m, &v| m.max(v));
    let (mut worst, mut worst_case) = (0.0_f64, String::new());
    let mut failures = Vec::new();
    for ((case, g), c) in cases.iter().zip(gpu).zip(cpu) {
        assert!(
            g.iter().all(|v| v.is_finite()),
            "{name}: non-finite GPU value {g:?} for segment {}",
            case.segment
        );
        let g = Vec3::new(g[0], g[1], g[2]).as_dvec3();
        let denominator = c.abs().max_element().max(floor.0 * scales[&case.segment]).max(floor.1 * largest);
        if denominator == 0.0 {
            assert_eq!(g, DVec3::ZERO, "{name}: GPU light where the CPU has none");
            continue;
        }
        let err = (g - *c).abs().max_element() / denominator;
        let label = format!(
            "segment {} κ/λ {} wo code {} axis code {}: GPU {g} vs CPU {c}",
            case.segment, case.lambda, case.wo_code, case.axis_code
        );
        if err > worst {
            (worst, worst_case) = (err, label.clone());
        }
        if err > bound {
            failures.push(format!("{name}: {label} (relative error {err:.2e})"));
        }
    }
    let lit = cpu.iter().filter(|c| c.max_element() > 0.0).count();
    eprintln!(
        "{name}: {} cases ({lit} lit), worst relative error {worst:.2e} (bound {bound:.1e}) at {worst_case}",
        cases.len()
    );
    assert!(lit * 2 > cases.len(), "{name}: only {lit} of {} cases carry light", cases.len());
    failures
}

/// Worst relative error the WGSL `lobe_quadrature` may make against its f64 twin, per case.
/// Measured 2026-11-27 on lavapipe (the Gauss–Legendre rule, the azimuthal series against the
/// WGSL Bessel ratios): 3.5e-4 (the cotton's fibers, the silk's forward shape), 2.4e-4 on the
/// silk's, 0.3e-4 to 3.5e-4 per offset distribution. Adding the von Mises to the offsets'
/// azimuth instead of mixing it in (a series that is no density, rising above 1 in its mean
/// cosine and clamped at zero) had reached 4.4e-3 where the sum cancels.
/// That is the f64 function's own conditioning, not the shader's arithmetic: moving t, ωo or ξ
/// by 1e-7 (f32 rounding) moves the f64 values by up to 9.5e-4 (an axis 1e-3 off t with κ 50;
/// grazing views through the 1° R lobe's Gn). With 24 longitudinal terms (2026-11-27, tenth
/// session): 1.73e-3 on the silk's forward shape viewed along the fiber (ωo = −t), 0.3e-4 to
/// 4.6e-4 on every other distribution. There the window lies in the tail of that sharp series,
/// a remainder of 24 terms of order one, which f32 sums less closely than 12.
const QUADRATURE_BOUND: f64 = 2.5e-3;

/// The WGSL `lobe_quadrature` (shared/shading.wgsl) against `shading::gamma::lobe_quadrature`
/// on the silk satin's fibers (β_R 1°, β_TT 10°, γ_TT 20°: narrow) and the default cotton's
/// (β_TT 27°, γ_TT 38°: broad), over [`quadrature_cases`] and [`lobe_offsets`]: κ from 0 to
/// 50, axes mirrored across t, nearly along it and along it, grazing θo (±85°, and ±90°), the
/// offsets of a sharp (ringing, clamped), a broad and a two-sided distribution and of the
/// silk's own lobes. Each case within QUADRATURE_BOUND of its own value (floored at 1e-4 of its
/// segment's largest); NaN or Inf fails.
#[test]
fn lobe_quadrature_matches_its_rust_twin() {
    let Some(gpu) = Gpu::for_test("lobe_quadrature_matches_its_rust_twin") else { return };
    let silk = lobe_bake();
    let offsets = lobe_offsets(silk);
    for (name, terms) in &offsets {
        let f = &terms[2 * LOBE_AZIMUTH_TERMS..];
        eprintln!(
            "offset {name}: a_1 {:.3}, b_1 {:.3}, c_1 {:.3}, s_1 {:.3}, c_12 {:.3}",
            terms[0], terms[1], f[0], f[1], f[22]
        );
    }
    let library = format!("{}\n{DECODE}\n{}", shaders::shared_library(), quadrature_decode(&offsets));
    let mut failures = Vec::new();
    for (label, baked) in [("silk satin", silk), ("default cotton", default_bake())] {
        let fabric =
            FabricData::upload(&gpu.device, &gpu.queue, &[baked], &PatternMap::uniform(0)).expect("upload");
        let cases = quadrature_cases(baked, offsets.len());
        let inputs: Vec<[f32; 4]> = cases.iter().map(Case::input).collect();
        let gpu_values = gpu
            .evaluate_with_fabric(&library, "quadrature_case(input)", &inputs, Some(&fabric))
            .expect("GPU evaluation");
        // Each case's f64 value and its condition: the largest relative change 1e-7 moves of
        // t, ωo or ξ (f32 rounding) make.
        let (cpu_values, conditions): (Vec<Rgb>, Vec<f64>) = cases
            .iter()
            .map(|c| {
                let s =
                    SegmentShading::of(baked, c.segment).expect("fiber segment").expect("non-zero segment");
                let offset = &offsets[(c.axis_code / OFFSET_CODE) as usize].1;
                let offset: Vec<f64> = offset.iter().map(|v| f64::from(*v)).collect();
                let (azimuth, fourier) = offset.split_at(2 * LOBE_AZIMUTH_TERMS);
                let mut ratios = [0.0; LOBE_AZIMUTH_TERMS];
                twill_precompute::special::bessel_i_ratios(f64::from(c.lambda as f32), &mut ratios);
                let turn = f64::from(AZIMUTH_TURN as f32);
                let azimuth = azimuth
                    .chunks_exact(2)
                    .zip(ratios)
                    .enumerate()
                    .flat_map(|(k, (pair, rho))| {
                        let (sk, ck) = ((k + 1) as f64 * turn).sin_cos();
                        [0.5 * (pair[0] + rho * ck), 0.5 * (pair[1] + rho * sk)]
                    })
                    .collect();
                let angles = LobeAngles { fourier: fourier.to_vec(), azimuth };
                let wo = lobe_case_direction(c.wo_code, s.tangent);
                let axis = lobe_case_direction(c.axis_code % OFFSET_CODE, s.tangent);
                let at = |t: DVec3, wo: DVec3, axis: DVec3| {
                    lobe_quadrature(&s.fiber, &baked.gn, t, axis, &angles, wo)
                };
                let value = at(s.tangent, wo, axis);
                let mut condition = 0.0_f64;
                for d in [DVec3::X, DVec3::Y, DVec3::Z, -DVec3::X, -DVec3::Y, -DVec3::Z].map(|d| 1e-7 * d) {
                    let moved = (d + s.tangent).normalize();
                    for other in [
                        at(moved, wo, axis),
                        at(s.tangent, (wo + d).normalize(), axis),
                        at(s.tangent, wo, (axis + d).normalize()),
                    ] {
                        condition = condition
                            .max((other - value).abs().max_element() / value.abs().max_element().max(1e-300));
                    }
                }
                (value, condition)
            })
            .unzip();
        let worst_condition = conditions.iter().copied().fold(0.0, f64::max);
        eprintln!(
            "lobe quadrature, {label}: 1e-7 moves of t, ωo or ξ change the f64 values by up to {worst_condition:.2e} \
             of themselves"
        );
        // Per offset distribution, each over all the other parameters.
        for (k, (offset, _)) in offsets.iter().enumerate() {
            let picked: Vec<usize> =
                (0..cases.len()).filter(|&i| cases[i].axis_code / OFFSET_CODE == k as u32).collect();
            let subset: Vec<Case> = picked.iter().map(|&i| cases[i].clone()).collect();
            let gpu_subset: Vec<[f32; 4]> = picked.iter().map(|&i| gpu_values[i]).collect();
            let cpu_subset: Vec<Rgb> = picked.iter().map(|&i| cpu_values[i]).collect();
            let name = format!("lobe quadrature, {label}, {offset}");
            failures.extend(relative_parity(
                &name,
                &subset,
                &gpu_subset,
                &cpu_subset,
                (1e-4, 0.0),
                QUADRATURE_BOUND,
            ));
        }
    }
    for f in failures.iter().take(20) {
        eprintln!("{f}");
    }
    assert!(failures.is_empty(), "{} GPU/CPU quadrature mismatches (first 20 printed above)", failures.len());
}

/// WGSL for the fiber-lobe cases: a unit-colour light along the case's axis, directional for
/// λ < 0, else an SG of sharpness λ; the lobes' light at `case_point` toward the case's ωo.
const LOBES_DECODE: &str = "
fn lobes_case(input: vec4<f32>) -> vec4<f32> {
    var light: LightGpu;
    light.direction = case_axis(input);
    light.kind = select(LIGHT_SG, LIGHT_DIRECTIONAL, input.y < 0.0);
    light.color = vec3<f32>(1.0);
    light.sharpness = max(input.y, 0.0);
    return vec4<f32>(shade_fiber_lobes(0u, u32(input.x), case_point(input), case_wo(input), light, light.direction), 0.0);
}
";

/// Worst relative error of the whole fiber-lobe term per light and case. Measured 2026-11-26 on
/// lavapipe: 2.3e-4, and 8.5e-6 of the segment's largest value; then 2.45e-3 once the light's
/// SH at order 6 pass through the upper-hemisphere fit (`twill_precompute::upper_fit`), whose
/// inverse's entries (up to 1.6e3) carry f32 rounding of the light's SH into the strengths.
const LOBES_BOUND: f64 = 3e-3;

/// Below this fraction of the grid's largest lobe value a case is judged against it rather
/// than against itself: such values are near-cancellations of a lobe strength's SH sum, whose
/// f32 rounding scales with its terms (carried through the upper-hemisphere fit's inverse), not
/// with the sum. With the colour-free transfer walk's bake (2026-11-27) one silk segment whose
/// every case is below 4e-7 of the grid's largest value had a case at 3.9e-3 of itself (1.2e-7
/// against the grid's 0.34). With the voxel-grid ray caster's bake (2026-11-27: the same paths,
/// hits rounded differently) a case at 3.4e-6 of the grid's largest value measured 4.46e-3 of
/// itself (1.07e-6 against the grid's 0.313; an error of 1.5e-8 of the grid's largest), so the
/// floor is 1e-5. The bound that would follow the cause is one relative to the magnitude of the
/// SH sum's terms, which the CPU twin does not report. With the draft's lobes from λ 3
/// (`iirtf::FORWARD_LOBE_FLOOR`, 2026-11-28: fewer of the silk's order-2 cells keep lobes) a
/// case at 4.9e-5 of the grid's largest value measured 6.5e-3 of itself (1.17e-5 against the
/// grid's 0.259, in a segment whose largest lobe value is 2e-3 of the grid's): an error of
/// 8.2e-8, less than one f32 epsilon (1.19e-7) of terms of order one. The floor is 2e-4, so
/// that the bound allows about that much absolutely (3e-3 × 2e-4 × 0.259 = 1.6e-7). Since the
/// lobes' strengths are signed (2026-12-07: `FiberLobe::strength_for`, no clamp at zero) a case
/// can sit at any point of a cancellation, the sign change included, where before a negative
/// strength gave an exact zero on both sides: two silk cases measured −1.818e-4 against
/// −1.772e-4 and 5.016e-4 against 5.067e-4 (errors of 4.6e-6 and 5.1e-6, 9e-6 of the grid's
/// largest value 0.558, f32 rounding carried through the upper-hemisphere fit's inverse), so
/// the floor is 4e-3 (3e-3 × 4e-3 × 0.558 = 6.7e-6 allowed absolutely).
const LOBES_GRID_FLOOR: f64 = 4e-3;

/// The fiber-lobe term (`shade_fiber_lobes`, shared/shading.wgsl) against its twin
/// `shading::multiple::lobe_scattering` on the silk satin's lobe bake, over the grid of the other
/// functions (12 segments, 17 view directions including ±t and grazing, light axes over the
/// sphere and the hard ones, including a light grazing the fabric plane), for directional
/// lights and SG lights of λ 2, 30, 300 and 2000, at points of the cell lattice (lobes
/// interpolated between cells). Each case within LOBES_BOUND of its own value (floored at 1e-4
/// of its segment's largest and LOBES_GRID_FLOOR of the grid's), and within the other
/// functions' tolerance (2e-3 of the segment's largest value + 1e-6); NaN or Inf fails.
#[test]
fn fiber_lobes_match_their_rust_twin() {
    let Some(gpu) = Gpu::for_test("fiber_lobes_match_their_rust_twin") else { return };
    let baked = lobe_bake();
    assert_has_lobes(baked);
    let fabric =
        FabricData::upload(&gpu.device, &gpu.queue, &[baked], &PatternMap::uniform(0)).expect("upload");
    assert!(fabric.arrays.has_lobes());
    let library = format!("{}\n{DECODE}\n{LOBES_DECODE}", shaders::shared_library());
    // Lights exactly along ±t included: the lobe's azimuthal concentration fades as
    // 1 − (ξ·t)² there (FiberLobe::angles), so both twins take κ = 0 where φ' is undefined.
    let lobe_cases = cases(baked, &[-1.0, 2.0, 30.0, 300.0, 2000.0]);
    let inputs: Vec<[f32; 4]> = lobe_cases.iter().map(Case::input).collect();
    let started = std::time::Instant::now();
    let gpu_lobes = gpu
        .evaluate_with_fabric(&library, "lobes_case(input)", &inputs, Some(&fabric))
        .expect("GPU evaluation");
    eprintln!("fiber lobes: {} GPU cases in {:.2} s", inputs.len(), started.elapsed().as_secs_f64());
    let cpu_lobes: Vec<Rgb> = lobe_cases
        .iter()
        .map(|c| {
            let s = SegmentShading::of(baked, c.segment).expect("fiber segment").expect("non-zero segment");
            let axis = c.axis(s.tangent);
            let light = if c.lambda < 0.0 {
                Light::directional(axis, Rgb::ONE).expect("light")
            } else {
                Light::sg(axis, f64::from(c.lambda as f32), Rgb::ONE).expect("light")
            };
            let point = case_point(baked, c.segment);
            shading::multiple::lobe_scattering(
                baked,
                c.segment,
                Some(point),
                c.wo(s.tangent),
                &[(light, 1.0)],
            )
            .expect("lobe scattering")
        })
        .collect();
    let floors = (1e-4, LOBES_GRID_FLOOR);
    let mut failures =
        relative_parity("fiber lobes", &lobe_cases, &gpu_lobes, &cpu_lobes, floors, LOBES_BOUND);
    let cpu_some: Vec<Option<Rgb>> = cpu_lobes.iter().copied().map(Some).collect();
    failures.extend(compare("fiber lobes", &lobe_cases, &gpu_lobes, &cpu_some));
    for f in failures.iter().take(20) {
        eprintln!("{f}");
    }
    assert!(failures.is_empty(), "{} GPU/CPU fiber-lobe mismatches (first 20 printed above)", failures.len());
}

/// `baked` with every cell's fiber lobes removed (its matrices as they are: zero where the cell
/// kept lobes), to measure what the lobes add.
fn without_lobes(baked: &Baked) -> Baked {
    let mut out = baked.clone();
    for cell in &mut out.transfer.iirtf.cells {
        cell.forward.clear();
        cell.reflected.clear();
        cell.forward_shape.clear();
        cell.reflected_shape.clear();
        cell.forward_cosine = [0.0; 3];
    }
    out
}

/// The CPU method's image of `scene` at the GPU's primary hits of a one-sample frame: per
/// pixel the ray through its centre (the GPU's sample 0), the first fiber it enters among the
/// voxels of the bake's volume it crosses (`VoxelVolume::first_fiber_hit`, what the G-buffer
/// pass finds), shaded where the ray enters it by `shading::shade` (`component`; multiple
/// scattering with the fiber lobes, clamped at zero with the rest, transfer and lobes
/// interpolated between cells) with V_glo = V̄_glo = 1 (a flat swatch lit from above).
/// Row-major, y down, as the GPU's frame.
fn cpu_at_voxel_hits(scene: &Scene, baked: &Baked, component: Component) -> Vec<Rgb> {
    let camera = camera_from(&scene.camera, LOBE_FRAME_SIZE, LOBE_FRAME_SIZE).expect("camera");
    let lights: Vec<(Light, f64, f64)> = scene.path_scene.lights.iter().map(|&l| (l, 1.0, 1.0)).collect();
    let volume = &baked.volume.volume;
    let mut out = Vec::with_capacity(LOBE_FRAME_SIZE * LOBE_FRAME_SIZE);
    for y in 0..LOBE_FRAME_SIZE {
        for x in 0..LOBE_FRAME_SIZE {
            let (origin, dir) = camera.ray(x as f64 + 0.5, y as f64 + 0.5);
            let Some((segment, t)) =
                volume.first_fiber_hit(&baked.volume.segments, origin, dir, 0.0, f64::INFINITY)
            else {
                out.push(Rgb::ZERO);
                continue;
            };
            // Wrapped into the exemplar as `shading::render`'s voxel hits are.
            let p = volume.wrap(origin + t * dir);
            out.push(shading::shade(baked, segment, Some(p), -dir, &lights, component).expect("shade"));
        }
    }
    out
}

/// The mean of an image over pixels and channels.
fn image_mean(image: &[Rgb]) -> f64 {
    image.iter().copied().sum::<Rgb>().element_sum() / (3 * image.len()) as f64
}

/// How a GPU frame compares with the CPU image of the same hits.
struct FrameParity {
    /// Pixels whose difference exceeds the per-pixel tolerance.
    outliers: usize,
    /// The largest difference among the other pixels, over the CPU image's mean.
    worst_inlier: f64,
    /// GPU minus CPU image mean (over pixels and channels) over the CPU's, over the pixels
    /// inside the tolerance: an outlier (a ray that grazes a fiber's edge, where the f32 march
    /// and the f64 one enter different fibers) moves the whole mean by its own difference over
    /// the pixel count, and the outliers are bounded by count.
    mean: f64,
}

/// Compares a GPU frame with the CPU image of the same pixels (differences relative to the
/// CPU image's mean); asserts every value of both is finite and every GPU value non-negative.
fn frame_parity(label: &str, gpu: &[[f32; 3]], cpu: &[Rgb]) -> FrameParity {
    assert_eq!(gpu.len(), cpu.len(), "{label}: image sizes");
    let cpu_mean = image_mean(cpu);
    let (mut gpu_sum, mut cpu_sum) = (0.0, 0.0);
    let (mut outliers, mut worst_inlier) = (0, 0.0_f64);
    for (i, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        assert!(g.iter().all(|v| v.is_finite() && *v >= 0.0), "{label}: GPU pixel {i} is {g:?}");
        assert!(c.is_finite(), "{label}: CPU pixel {i} is {c}");
        let g = Vec3::from(*g).as_dvec3();
        let err = (g - *c).abs().max_element() / cpu_mean;
        if err > FRAME_PIXEL_TOLERANCE {
            outliers += 1;
        } else {
            worst_inlier = worst_inlier.max(err);
            gpu_sum += g.element_sum();
            cpu_sum += c.element_sum();
        }
    }
    FrameParity { outliers, worst_inlier, mean: (gpu_sum - cpu_sum) / cpu_sum.max(f64::MIN_POSITIVE) }
}

/// Per-pixel tolerance of the fiber-lobe frames, relative to the CPU image's mean: f32 against
/// f64 arithmetic and the GPU's f16 IIRTF (measured 2026-11-26 on lavapipe: at most 1.9e-3 of
/// the mean, in the sharp SG's frame; 2.5e-4 to 5.8e-4 in the others).
const FRAME_PIXEL_TOLERANCE: f64 = 1e-2;
/// Pixels allowed outside it (measured: 2 of 576 in every frame, since eye rays stop at the
/// fibers' capsules): where a ray grazes a fiber's edge the f32 march and the f64 one may
/// enter different fibers, and an SSDF near zero can take either sign.
const FRAME_OUTLIER_FRACTION: f64 = 0.02;
/// GPU minus CPU image mean over the CPU's, over the pixels inside the tolerance (measured:
/// at most 1.2e-5 before eye rays stopped at the capsules, when the mean also took the
/// outliers).
const FRAME_MEAN_TOLERANCE: f64 = 1e-3;
/// The least share of the CPU image the fiber lobes must carry in every frame, 30 times
/// [`FRAME_MEAN_TOLERANCE`], so that a GPU without the term (or with it off by a few percent)
/// fails the comparison (measured: 0.85 to 0.99 of the multiple scattering, where the silk's
/// cells keep nearly all their light as lobes, and 0.40 of the whole image).
const MIN_LOBE_SHARE: f64 = 30.0 * FRAME_MEAN_TOLERANCE;

/// Whole one-sample GPU frames of the silk satin's fiber-lobe bake against the CPU method at
/// the same primary hits ([`cpu_at_voxel_hits`]), through both multiple-scattering paths (the
/// cells' once-per-frame transfer and the per-pixel one), under a directional light at 40°, one
/// grazing the fabric (85° from the normal), a soft SG (λ 3) and a sharp SG (λ 300), each alone
/// (multiple scattering with the lobes: the term the lobes add to), and all four together (the
/// whole image, single scattering included, clamped with the rest). Per pixel GPU and CPU
/// agree within FRAME_PIXEL_TOLERANCE of the image mean but for FRAME_OUTLIER_FRACTION of the
/// pixels, the image means within FRAME_MEAN_TOLERANCE; no value is NaN, infinite or (on the
/// GPU) negative. The lobes carry at least MIN_LOBE_SHARE of every CPU image (against the same
/// bake without them), so the comparison covers them.
#[test]
fn fiber_lobe_frames_match_the_cpu_method() {
    let Some(gpu) = Gpu::for_test("fiber_lobe_frames_match_the_cpu_method") else { return };
    let baked = lobe_bake();
    assert_has_lobes(baked);
    let without = without_lobes(baked);
    let sun = sun_toml();
    let grazing = directional_toml(from_zenith(85.0, 30.0), 3.0);
    let soft = sg_toml(from_zenith(20.0, 200.0), 3.0, 1.0);
    let sharp = sg_toml(from_zenith(50.0, 300.0), 300.0, 3.0);
    let frames = [
        ("directional 40°", vec![sun.clone()], Component::Multiple),
        ("grazing directional 85°", vec![grazing.clone()], Component::Multiple),
        ("soft SG λ 3", vec![soft.clone()], Component::Multiple),
        ("sharp SG λ 300", vec![sharp.clone()], Component::Multiple),
        ("all four", vec![sun, grazing, soft, sharp], Component::All),
    ];
    let probe = silk_scene(&[sun_toml()]);
    let mut renderer = renderer_on_mesh(
        &gpu,
        &[baked],
        &PatternMap::uniform(0),
        &probe.mesh,
        probe.swatch.size_cm,
        &probe.base_dir,
    )
    .expect("the scene uploads");
    let mut failures = Vec::new();
    for (name, lights, component) in &frames {
        let scene = silk_scene(lights);
        let cpu = cpu_at_voxel_hits(&scene, baked, *component);
        let cpu_mean = image_mean(&cpu);
        let share = (cpu_mean - image_mean(&cpu_at_voxel_hits(&scene, &without, *component))) / cpu_mean;
        if share < MIN_LOBE_SHARE {
            failures.push(format!("{name}: the fiber lobes carry {share:.3} of the CPU image"));
        }
        let components =
            if *component == Component::All { Components::All } else { Components::MultipleOnly };
        for frame_transfer in [true, false] {
            let label = format!("{name}, {}", if frame_transfer { "cells' A c_in" } else { "per pixel" });
            let mut settings = frame_settings(&scene, components);
            (settings.width, settings.height, settings.spp) =
                (LOBE_FRAME_SIZE as u32, LOBE_FRAME_SIZE as u32, 1);
            settings.frame_transfer = frame_transfer;
            let started = std::time::Instant::now();
            let frame = renderer
                .render(&scene.camera, &scene.path_scene.lights, &settings)
                .expect("the frame renders");
            let seconds = started.elapsed().as_secs_f64();
            assert!(
                frame.plan.fiber_lobes && frame.plan.cell_transfer == frame_transfer,
                "{label}: {}",
                frame.plan
            );
            let parity = frame_parity(&label, &frame.radiance, &cpu);
            eprintln!(
                "{label}: CPU mean {cpu_mean:.5} (fiber lobes {share:.3} of it), GPU − CPU mean {:+.2e} of it; \
                 {} pixel(s) outside the tolerance, the largest difference of the others {:.2e} of the mean \
                 ({seconds:.2} s)",
                parity.mean, parity.outliers, parity.worst_inlier
            );
            let allowed = (FRAME_OUTLIER_FRACTION * cpu.len() as f64) as usize;
            if parity.outliers > allowed {
                failures.push(format!(
                    "{label}: {} pixels outside the tolerance (allowed {allowed})",
                    parity.outliers
                ));
            }
            if parity.mean.abs() > FRAME_MEAN_TOLERANCE {
                failures.push(format!("{label}: GPU − CPU image mean {:+.3e} of the mean", parity.mean));
            }
        }
    }
    for f in &failures {
        eprintln!("{f}");
    }
    assert!(failures.is_empty(), "{} fiber-lobe frame mismatches (printed above)", failures.len());
}

/// The frame plan compiles the fiber lobes into the shading pass only for a bake that has them:
/// a draft bake with `fiber_lobes: false` packs no lobes and plans `ENABLE_FIBER_LOBES` off, on
/// a flat swatch (cells' transfer) and a curved shell (per pixel) alike; the silk's lobe bake
/// packs `LOBE_PACKED_FLOATS` per cell that keeps lobes and plans it on. Both pack a slot,
/// a matrix for the cells with segments only, and lobes for the cells that keep them. CPU only (packing and planning need no
/// device).
#[test]
fn the_plan_enables_fiber_lobes_only_for_a_bake_that_has_them() {
    let plain = default_bake();
    assert!(!plain.settings.fiber_lobes);
    assert!(!plain.transfer.iirtf.cells.iter().any(CellTransfer::has_lobes));
    let scene = silk_scene(&[sun_toml(), sg_toml(from_zenith(20.0, 200.0), 3.0, 1.0)]);
    let settings = frame_settings(&scene, Components::All);
    for (label, baked, expected) in
        [("fiber_lobes: false", plain, false), ("fiber_lobes: true", lobe_bake(), true)]
    {
        let arrays = FabricArrays::pack(&[baked], &PatternMap::uniform(0)).expect("pack");
        assert_eq!(arrays.has_lobes(), expected, "{label}");
        // Sparse cells: a slot for every cell that holds segments, numbered in cell order, and
        // a matrix per slot only.
        let held: Vec<bool> = baked.transfer.iirtf.cells.iter().map(|c| c.paths > 0).collect();
        let slots: Vec<u32> = arrays.cell_slots.iter().copied().filter(|&s| s != 0).collect();
        assert_eq!(arrays.cell_slots.len(), held.len(), "{label}");
        assert!(arrays.cell_slots.iter().zip(&held).all(|(&s, &h)| (s != 0) == h), "{label}");
        assert_eq!(slots, (1..=slots.len() as u32).collect::<Vec<_>>(), "{label}: slots in cell order");
        assert_eq!(arrays.slot_count, slots.len(), "{label}");
        assert!(slots.len() < held.len(), "{label}: some cells are empty");
        let n = arrays.header.sh_count as usize;
        assert_eq!(arrays.iirtf.len(), (arrays.slot_count * 3 * n * n).div_ceil(2), "{label}");
        // Without lobes the buffer is empty (bound as one zeroed vec4); with them the lobe
        // table (a u32 per lattice slot: the segment cells' slots come after them and have no
        // lobes) and LOBE_PACKED_FLOATS per lobe slot, one for each cell that keeps lobes,
        // numbered in slot order, each holding that cell's packed lobes.
        let lattice = baked.transfer.cells.lattice_cell_count();
        assert_eq!(arrays.lattice_slot_count, held[..lattice].iter().filter(|&&h| h).count(), "{label}");
        assert!(arrays.slot_count > arrays.lattice_slot_count, "{label}: segment cells have slots");
        let lobed: Vec<&CellTransfer> = baked.transfer.iirtf.cells.iter().filter(|c| c.has_lobes()).collect();
        let table = 4 * arrays.header.lobe_table_vec4s as usize;
        assert_eq!(table, if expected { arrays.lattice_slot_count.div_ceil(4) * 4 } else { 0 }, "{label}");
        let expected_len = if expected { table + lobed.len() * LOBE_PACKED_FLOATS } else { 0 };
        assert_eq!(arrays.holds_lobes(), expected, "{label}");
        assert_eq!(arrays.lobes.len(), expected_len, "{label}");
        assert_eq!(arrays.lobe_cells, lobed.len(), "{label}");
        if expected {
            assert!(!lobed.is_empty() && lobed.len() < arrays.lattice_slot_count, "{label}: {}", lobed.len());
            let table_slots: Vec<u32> =
                arrays.lobes[..arrays.lattice_slot_count].iter().map(|v| v.to_bits()).collect();
            assert_eq!(table_slots, arrays.lobe_slots, "{label}");
            let numbered: Vec<u32> = arrays.lobe_slots.iter().copied().filter(|&l| l != 0).collect();
            assert_eq!(
                numbered,
                (1..=lobed.len() as u32).collect::<Vec<_>>(),
                "{label}: lobe slots in slot order"
            );
            let mut packed = vec![0.0; LOBE_PACKED_FLOATS];
            for (cell, values) in lobed.iter().zip(arrays.lobe_values().chunks_exact(LOBE_PACKED_FLOATS)) {
                cell.pack_lobes(&mut packed);
                assert_eq!(values, &packed[..], "{label}");
            }
            // A recolouring that changes which cells keep lobes: the slots from the middle on
            // swap, the first half keep theirs and their lobes, the new ones start as zeros.
            let mut relaid = arrays.clone();
            let half = arrays.lattice_slot_count / 2;
            let wanted: Vec<bool> = arrays.lobe_slots[half..].iter().map(|&l| l == 0).collect();
            relaid.relayout_lobes(half, &wanted).expect("relayout");
            let keeps: Vec<bool> = relaid.lobe_slots.iter().map(|&l| l != 0).collect();
            let expected_keeps: Vec<bool> =
                arrays.lobe_slots[..half].iter().map(|&l| l != 0).chain(wanted.iter().copied()).collect();
            assert_eq!(keeps, expected_keeps, "{label}");
            let numbered: Vec<u32> = relaid.lobe_slots.iter().copied().filter(|&l| l != 0).collect();
            assert_eq!(numbered, (1..=numbered.len() as u32).collect::<Vec<_>>(), "{label}");
            let table_slots: Vec<u32> =
                relaid.lobes[..relaid.lattice_slot_count].iter().map(|v| v.to_bits()).collect();
            assert_eq!(table_slots, relaid.lobe_slots, "{label}");
            let chunk = |a: &FabricArrays, lobe_slot: u32| {
                let at = (lobe_slot as usize - 1) * LOBE_PACKED_FLOATS;
                a.lobe_values()[at..at + LOBE_PACKED_FLOATS].to_vec()
            };
            for slot in 0..arrays.lattice_slot_count {
                let (old, new) = (arrays.lobe_slots[slot], relaid.lobe_slots[slot]);
                if slot < half && old != 0 {
                    assert_eq!(
                        chunk(&relaid, new),
                        chunk(&arrays, old),
                        "{label}: slot {slot} kept its lobes"
                    );
                } else if new != 0 {
                    assert!(
                        chunk(&relaid, new).iter().all(|&v| v == 0.0),
                        "{label}: slot {slot} starts empty"
                    );
                }
            }
            assert_eq!(relaid.lobe_values().len(), numbered.len() * LOBE_PACKED_FLOATS, "{label}");
        }
        // The C_G table at the lights' order: the lobes' with them.
        let cg_order = arrays.header.cg_order as usize;
        assert_eq!(cg_order, baked.settings.light_sh_order(), "{label}");
        let fits: usize =
            (0..=cg_order).map(twill_precompute::upper_fit::UpperHemisphereFit::packed_len).sum();
        assert_eq!(
            arrays.cg_table.len(),
            arrays.header.cg_points as usize * (cg_order + 1) + fits,
            "{label}"
        );
        for (flat, uniform) in [(Some(glam::Vec3::Z), true), (None, false)] {
            let plan = plan_frame(&scene.path_scene.lights, &settings, flat, uniform, arrays.has_lobes());
            let variant = plan.passes().iter().find_map(ShadeVariant::of).expect("a shading pass");
            assert_eq!(variant.fiber_lobes, expected, "{label}: {plan}");
            assert_eq!(plan.fiber_lobes, expected, "{label}: {plan}");
        }
    }
}
