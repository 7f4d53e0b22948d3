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

use std::collections::HashMap;

use glam::{DVec3, Vec3};
use twill_precompute::bake::Cancel;
use twill_precompute::bake::pattern::PatternMap;
use twill_precompute::bake::pipeline::{BakeInputs, Baked, bake};
use twill_precompute::bake::settings::Quality;
use twill_precompute::bcsdf::{FiberParams, MaterialDesc};
use twill_precompute::pathtrace::Light;
use twill_precompute::scene::SceneFile;
use twill_precompute::shading::{self, SegmentShading};
use twill_precompute::{Rgb, sh};
use twill_renderer::fabric_data::FabricData;
use twill_renderer::gpu::Gpu;
use twill_renderer::shaders;

fn draft_bake(file: &SceneFile) -> Baked {
    let scene = file.build().expect("scene");
    let inputs = BakeInputs {
        exemplar: &scene.exemplar,
        materials: &scene.material_descs,
        settings: Quality::Draft.settings(),
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
    light_sh_accumulate(fabric.sh_order, case_axis(input), input.y, vec3<f32>(1.0), &c);
    return vec4<f32>(shade_multiple(0u, u32(input.x), case_point(input), case_wo(input), &c), 0.0);
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

#[test]
fn shading_functions_match_their_rust_twins() {
    let Some(gpu) = Gpu::for_test("shading_functions_match_their_rust_twins") else { return };
    let mut failures = Vec::new();
    failures.extend(compare_bake(&gpu, "default", &draft_bake(&SceneFile::default_scene())));
    let narrow = draft_bake(&narrow_scene());
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

    // Directional single scattering (unit irradiance): compared where the SSDF is clearly signed.
    let dir_cases = cases(baked, &[0.0]);
    let gpu_dir = run(
        "vec4<f32>(shade_single_directional(0u, u32(input.x), case_wo(input), case_axis(input)), 0.0)",
        &dir_cases,
    );
    let cpu_dir: Vec<Option<Rgb>> = dir_cases
        .iter()
        .map(|c| {
            let s = seg(c);
            let wd = c.axis(s.tangent);
            let d = shading::ssdf_lookup(&baked.visibility.ssdf, c.segment as usize, wd);
            (d.abs() > 1e-3).then(|| {
                shading::single_scattering_directional(
                    &s.fiber,
                    &baked.gn,
                    &baked.visibility,
                    c.segment as usize,
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

    // SG single scattering: sum-of-SGs (λ ≤ 100), blend (150), erf-SSDF (≥ 200).
    let sg_cases = cases(baked, &[1e-4, 8.0, 100.0, 150.0, 300.0, 1e5]);
    let gpu_sg = run(
        "vec4<f32>(select(0.0, 1.0, input.y < 200.0) * shade_single_sg_sum_of_sg(0u, u32(input.x), case_wo(input), case_axis(input), input.y) * (1.0 - clamp((input.y - 100.0) / 100.0, 0.0, 1.0)) + select(0.0, 1.0, input.y > 100.0) * shade_single_sg_ssdf_erf(0u, u32(input.x), case_wo(input), case_axis(input), input.y) * clamp((input.y - 100.0) / 100.0, 0.0, 1.0), 0.0)",
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
                c.segment as usize,
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
            let c_light = shading::light_sh(&light, order, &baked.cg);
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
