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
//! Γ by quadrature (`sg_bcsdf_gamma_quadrature`, the forward lobes' Γ) is compared like Γ.
//! Forward lobes (`BakeSettings::forward_lobe`), on a draft bake of the default fabric with
//! them: the WGSL term (`shade_forward`) against `shading::multiple::forward_scattering` over
//! the same grid and tolerance (worst measured under 1e-5 of scale), and whole one-sample GPU
//! frames against the CPU method shading the same primary hits, per pixel (tolerances at
//! [`FRAME_PIXEL_TOLERANCE`]); the plan compiles the lobes in only for a bake that has them.

use std::collections::HashMap;

use glam::{DVec3, Vec3};
use twill_precompute::bake::Cancel;
use twill_precompute::bake::iirtf::CellTransfer;
use twill_precompute::bake::pattern::PatternMap;
use twill_precompute::bake::pipeline::{BakeInputs, Baked, bake};
use twill_precompute::bake::settings::{BakeSettings, Quality};
use twill_precompute::bcsdf::{FiberParams, MaterialDesc};
use twill_precompute::pathtrace::{Component, Light};
use twill_precompute::scene::{Scene, SceneFile, camera_from};
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

/// The default scene's draft bake (no forward lobes), shared by the tests of this binary.
fn default_bake() -> &'static Baked {
    static BAKE: std::sync::OnceLock<Baked> = std::sync::OnceLock::new();
    BAKE.get_or_init(|| draft_bake(&SceneFile::default_scene()))
}

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
    failures.extend(compare_bake(&gpu, "default", default_bake()));
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

    // Γ by quadrature (the forward lobes' Γ) over the same grid.
    let gpu_quadrature = run(
        "vec4<f32>(sg_bcsdf_gamma_quadrature(fiber_constants(segments[u32(input.x)].material), omega_o_space(case_t(input), case_wo(input)), case_axis(input), input.y), 0.0)",
        &gamma_cases,
    );
    let cpu_quadrature: Vec<Option<Rgb>> = gamma_cases
        .iter()
        .map(|c| {
            let s = seg(c);
            let (lambda32, axis) = (f64::from(c.lambda as f32), c.axis(s.tangent));
            Some(shading::gamma::gamma_quadrature(
                &s.fiber,
                &baked.gn,
                s.tangent,
                axis,
                lambda32,
                c.wo(s.tangent),
            ))
        })
        .collect();
    failures.extend(compare(
        &format!("{label}, gamma by quadrature"),
        &gamma_cases,
        &gpu_quadrature,
        &cpu_quadrature,
    ));

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

// ---------------------------------------------------------------------------------------------
// Forward lobes (`BakeSettings::forward_lobe`): the WGSL term against `forward_scattering`, and
// whole GPU frames against the CPU method at the same primary hits.

/// Side of the forward-lobe frames, in pixels.
const FORWARD_SIZE: usize = 24;

/// A flat default-fabric swatch (2 cm, no ground) seen by an orthographic camera 0.3 cm high
/// from 30° off the normal (well inside the swatch), under `lights` (TOML), at
/// FORWARD_SIZE x FORWARD_SIZE and one sample per pixel.
fn forward_scene(lights: &[String]) -> Scene {
    let t = 30.0_f64.to_radians();
    let text = format!(
        "[fabric]\npreset = \"default\"\n[swatch]\nsize_cm = [2.0, 2.0]\nground = false\n\
         [camera]\nprojection = \"orthographic\"\neye = [0.0, {:?}, {:?}]\ntarget = [0.0, 0.0, 0.0]\n\
         up = [0.0, 0.0, 1.0]\nheight_cm = 0.3\n{}[render]\nwidth = {FORWARD_SIZE}\nheight = {FORWARD_SIZE}\nspp = 1\n",
        -t.sin(),
        t.cos(),
        lights.concat()
    );
    SceneFile::parse(&text, std::path::Path::new("forward_lobe.toml"))
        .unwrap_or_else(|e| panic!("{e}\n{text}"))
        .build()
        .unwrap_or_else(|e| panic!("{e}\n{text}"))
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

/// The default fabric's draft bake with forward lobes, shared by the tests of this binary.
fn forward_bake() -> &'static Baked {
    static BAKE: std::sync::OnceLock<Baked> = std::sync::OnceLock::new();
    BAKE.get_or_init(|| {
        let scene = forward_scene(&[sun_toml()]);
        let settings = BakeSettings { fiber_lobes: true, ..Quality::Draft.settings() };
        let inputs = BakeInputs { exemplar: &scene.exemplar, materials: &scene.material_descs, settings };
        let started = std::time::Instant::now();
        let baked =
            bake(&inputs, None, &Cancel::new(), &|_, _| {}).expect("draft bake with forward lobes").baked;
        eprintln!("draft bake with forward lobes: {:.1} s", started.elapsed().as_secs_f64());
        baked
    })
}

/// Asserts that some of `baked`'s cells carry forward lobes (a cell whose forward light is
/// broad keeps it in its matrix), and that most of those lobes hold light; returns how many
/// cells have one.
fn assert_has_lobess(baked: &Baked) -> usize {
    let cells = &baked.transfer.iirtf.cells;
    let with = cells.iter().filter(|c| c.has_lobes()).count();
    let nonempty = cells.iter().filter(|c| !c.is_empty()).count();
    eprintln!("forward lobes: {with} of {} cells ({nonempty} hold segments)", cells.len());
    assert!(with * 20 >= nonempty, "a forward-lobe bake must give at least 5% of its non-empty cells a lobe");
    let strong =
        cells.iter().filter(|c| c.has_lobes() && c.forward[0].iter().sum::<f32>() > 0.0).count();
    assert!(strong * 2 > with, "most forward lobes must carry light ({strong} of {with} do)");
    with
}

/// WGSL for the forward-lobe cases: a unit-colour light along the case's axis, directional for
/// λ < 0, else an SG of sharpness λ; its forward lobe at `case_point` toward the case's ωo.
const FORWARD_DECODE: &str = "
fn forward_case(input: vec4<f32>) -> vec4<f32> {
    var light: LightGpu;
    light.direction = case_axis(input);
    light.kind = select(LIGHT_SG, LIGHT_DIRECTIONAL, input.y < 0.0);
    light.color = vec3<f32>(1.0);
    light.sharpness = max(input.y, 0.0);
    let p = case_point(input);
    return vec4<f32>(shade_forward(0u, u32(input.x), p, case_wo(input), light, light.direction), 0.0);
}
";

/// The forward-lobe term (`shade_forward`, shared/shading.wgsl) against its twin
/// `shading::multiple::forward_scattering` over the grid of the other functions (12 segments,
/// 17 view directions including ±t and grazing, light axes over the sphere and the hard ones
/// including a light grazing the fabric plane), for directional lights and SG lights of λ 2e-4,
/// 3, 300 and 1e5, at points of the cell lattice (lobes interpolated between cells). Same
/// tolerance as the other functions: 2e-3 of the segment's largest value, + 1e-6.
#[test]
fn forward_lobe_matches_its_rust_twin() {
    let Some(gpu) = Gpu::for_test("forward_lobe_matches_its_rust_twin") else { return };
    let baked = forward_bake();
    assert_has_lobess(baked);
    let fabric =
        FabricData::upload(&gpu.device, &gpu.queue, &[baked], &PatternMap::uniform(0)).expect("upload");
    assert!(fabric.arrays.has_lobess());
    let library = format!("{}\n{DECODE}\n{FORWARD_DECODE}", shaders::shared_library());
    let forward_cases = cases(baked, &[-1.0, 2e-4, 3.0, 300.0, 1e5]);
    let inputs: Vec<[f32; 4]> = forward_cases.iter().map(Case::input).collect();
    let gpu_forward = gpu
        .evaluate_with_fabric(&library, "forward_case(input)", &inputs, Some(&fabric))
        .expect("GPU evaluation");
    let cpu_forward: Vec<Option<Rgb>> = forward_cases
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
            Some(
                shading::multiple::forward_scattering(
                    baked,
                    c.segment,
                    Some(point),
                    c.wo(s.tangent),
                    &[(light, 1.0)],
                )
                .expect("forward scattering"),
            )
        })
        .collect();
    let lit = cpu_forward.iter().flatten().filter(|c| c.max_element() > 0.0).count();
    eprintln!("forward lobe: {lit} of {} cases receive forward-scattered light", forward_cases.len());
    assert!(
        lit * 4 > forward_cases.len(),
        "a quarter of the cases at least must receive forward-scattered light"
    );
    let failures = compare("forward lobe", &forward_cases, &gpu_forward, &cpu_forward);
    for f in failures.iter().take(20) {
        eprintln!("{f}");
    }
    assert!(
        failures.is_empty(),
        "{} GPU/CPU forward-lobe mismatches (first 20 printed above)",
        failures.len()
    );
}

/// `baked` with every cell's forward lobe removed (its matrices as they are), to measure what
/// the lobes add.
fn without_forward_lobes(baked: &Baked) -> Baked {
    let mut out = baked.clone();
    for cell in &mut out.transfer.iirtf.cells {
        cell.forward.clear();
        cell.forward_cosine = [0.0; 3];
    }
    out
}

/// The CPU method's image of `scene` at the GPU's primary hits of a one-sample frame: per
/// pixel the ray through its centre (the GPU's sample 0), the first voxel of the bake's volume
/// it crosses that holds a segment (`VoxelVolume::first_occupied`, what the G-buffer pass
/// marches to), shaded where the ray enters it by `shading::shade` (`component`; multiple
/// scattering with the forward lobes, clamped at zero with the rest, transfer and lobes
/// interpolated between cells) with V_glo = V̄_glo = 1 (a flat swatch lit from above).
/// Row-major, y down, as the GPU's frame.
fn cpu_at_voxel_hits(scene: &Scene, baked: &Baked, component: Component) -> Vec<Rgb> {
    let camera = camera_from(&scene.camera, FORWARD_SIZE, FORWARD_SIZE).expect("camera");
    let lights: Vec<(Light, f64, f64)> = scene.path_scene.lights.iter().map(|&l| (l, 1.0, 1.0)).collect();
    let volume = &baked.volume.volume;
    let (grid_origin, size) = (volume.origin.as_dvec3(), volume.voxel_size.as_dvec3());
    let extent = size * DVec3::new(f64::from(volume.dims[0]), f64::from(volume.dims[1]), 1.0);
    let mut out = Vec::with_capacity(FORWARD_SIZE * FORWARD_SIZE);
    for y in 0..FORWARD_SIZE {
        for x in 0..FORWARD_SIZE {
            let (origin, dir) = camera.ray(x as f64 + 0.5, y as f64 + 0.5);
            let Some((segment, t)) = volume.first_occupied(origin, dir, 0.0, f64::INFINITY) else {
                out.push(Rgb::ZERO);
                continue;
            };
            // Wrapped into the exemplar as `shading::render`'s voxel hits are.
            let mut p = origin + t * dir;
            if volume.periodic {
                p.x = grid_origin.x + (p.x - grid_origin.x).rem_euclid(extent.x);
                p.y = grid_origin.y + (p.y - grid_origin.y).rem_euclid(extent.y);
            }
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
    /// GPU minus CPU image mean (over pixels and channels) over the CPU's.
    mean: f64,
}

/// Compares a GPU frame with the CPU image of the same pixels (differences relative to the
/// CPU image's mean); asserts every value of both is finite and every GPU value non-negative.
fn frame_parity(label: &str, gpu: &[[f32; 3]], cpu: &[Rgb]) -> FrameParity {
    assert_eq!(gpu.len(), cpu.len(), "{label}: image sizes");
    let cpu_mean = image_mean(cpu);
    let mut gpu_sum = 0.0;
    let (mut outliers, mut worst_inlier) = (0, 0.0_f64);
    for (i, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        assert!(g.iter().all(|v| v.is_finite() && *v >= 0.0), "{label}: GPU pixel {i} is {g:?}");
        assert!(c.is_finite(), "{label}: CPU pixel {i} is {c}");
        let g = Vec3::from(*g).as_dvec3();
        gpu_sum += g.element_sum();
        let err = (g - *c).abs().max_element() / cpu_mean;
        if err > FRAME_PIXEL_TOLERANCE {
            outliers += 1;
        } else {
            worst_inlier = worst_inlier.max(err);
        }
    }
    FrameParity { outliers, worst_inlier, mean: (gpu_sum / (3 * gpu.len()) as f64 - cpu_mean) / cpu_mean }
}

/// Per-pixel tolerance of the forward-lobe frames, relative to the CPU image's mean: f32
/// against f64 arithmetic and the GPU's f16 IIRTF (measured 2026-11-26 on lavapipe: at most
/// 2.5e-3 of the mean, in the grazing light's frame).
const FRAME_PIXEL_TOLERANCE: f64 = 1e-2;
/// Pixels allowed outside it (measured: none): where the f32 voxel march and the f64 one part
/// at a voxel boundary the two sides shade different segments, and an SSDF near zero can take
/// either sign.
const FRAME_OUTLIER_FRACTION: f64 = 0.02;
/// GPU minus CPU image mean over the CPU's (measured: at most 1.0e-5).
const FRAME_MEAN_TOLERANCE: f64 = 1e-3;
/// The least share of the CPU image the forward lobes must carry in every frame, 30 times
/// [`FRAME_MEAN_TOLERANCE`], so that a GPU without the term (or with it off by a few percent)
/// fails the comparison (measured: 0.08 to 0.22 with the cells whose forward light is broad
/// keeping it in their matrices, `forward_lobe_min_sharpness`).
const MIN_FORWARD_SHARE: f64 = 30.0 * FRAME_MEAN_TOLERANCE;

/// Whole one-sample GPU frames of a forward-lobe bake against the CPU method at the same
/// primary hits ([`cpu_at_voxel_hits`]), through both multiple-scattering paths (the cells'
/// once-per-frame transfer and the per-pixel one), under a directional light at 40°, one
/// grazing the fabric (85° from the normal), a soft SG (λ 3) and a sharp SG (λ 300), each alone
/// (multiple scattering with the lobes: the term the lobes add to), and all four together (the
/// whole image, single scattering included, clamped with the rest). Per pixel GPU and CPU
/// agree within FRAME_PIXEL_TOLERANCE of the image mean but for FRAME_OUTLIER_FRACTION of the
/// pixels, the image means within FRAME_MEAN_TOLERANCE; no value is NaN, infinite or (on the
/// GPU) negative. The lobes carry at least MIN_FORWARD_SHARE of every CPU image (against the
/// same bake without them), so the comparison covers them.
#[test]
fn forward_lobe_frames_match_the_cpu_method() {
    let Some(gpu) = Gpu::for_test("forward_lobe_frames_match_the_cpu_method") else { return };
    let baked = forward_bake();
    assert_has_lobess(baked);
    let without = without_forward_lobes(baked);
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
    let probe = forward_scene(&[sun_toml()]);
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
        let scene = forward_scene(lights);
        let cpu = cpu_at_voxel_hits(&scene, baked, *component);
        let cpu_mean = image_mean(&cpu);
        let share = (cpu_mean - image_mean(&cpu_at_voxel_hits(&scene, &without, *component))) / cpu_mean;
        if share < MIN_FORWARD_SHARE {
            failures.push(format!("{name}: the forward lobes carry {share:.3} of the CPU image"));
        }
        let components =
            if *component == Component::All { Components::All } else { Components::MultipleOnly };
        for frame_transfer in [true, false] {
            let label = format!("{name}, {}", if frame_transfer { "cells' A c_in" } else { "per pixel" });
            let mut settings = frame_settings(&scene, components);
            (settings.width, settings.height, settings.spp) = (FORWARD_SIZE as u32, FORWARD_SIZE as u32, 1);
            settings.frame_transfer = frame_transfer;
            let frame = renderer
                .render(&scene.camera, &scene.path_scene.lights, &settings)
                .expect("the frame renders");
            assert!(
                frame.plan.forward_lobe && frame.plan.cell_transfer == frame_transfer,
                "{label}: {}",
                frame.plan
            );
            let parity = frame_parity(&label, &frame.radiance, &cpu);
            eprintln!(
                "{label}: CPU mean {cpu_mean:.5} (forward lobes {share:.3} of it), GPU − CPU mean {:+.2e} of it; \
                 {} pixel(s) outside the tolerance, the largest difference of the others {:.2e} of the mean",
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
    assert!(failures.is_empty(), "{} forward-lobe frame mismatches (printed above)", failures.len());
}

/// The frame plan compiles the forward lobes into the shading pass only for a bake that has
/// them: a draft bake with `forward_lobe: false` packs no lobes and plans
/// `ENABLE_FORWARD_LOBE` off, on a flat swatch (cells' transfer) and a curved shell (per
/// pixel) alike; the forward-lobe bake plans it on. CPU only (packing and planning need no
/// device).
#[test]
fn the_plan_enables_forward_lobes_only_for_a_bake_that_has_them() {
    let plain = default_bake();
    assert!(!plain.settings.fiber_lobes);
    assert!(!plain.transfer.iirtf.cells.iter().any(CellTransfer::has_lobes));
    let scene = forward_scene(&[sun_toml(), sg_toml(from_zenith(20.0, 200.0), 3.0, 1.0)]);
    let settings = frame_settings(&scene, Components::All);
    for (label, baked, expected) in
        [("forward_lobe: false", plain, false), ("forward_lobe: true", forward_bake(), true)]
    {
        let arrays = FabricArrays::pack(&[baked], &PatternMap::uniform(0)).expect("pack");
        assert_eq!(arrays.has_lobess(), expected, "{label}");
        // Without lobes the buffer is empty (bound as one zeroed vec4); with them n + 1 per cell.
        let n = arrays.header.sh_count as usize;
        let expected_len = if expected { arrays.cell_flags.len() * (n + 1) } else { 0 };
        assert_eq!(arrays.holds_forward_lobes(), expected, "{label}");
        assert_eq!(arrays.forward_lobes.len(), expected_len, "{label}");
        for (flat, uniform) in [(Some(glam::Vec3::Z), true), (None, false)] {
            let plan =
                plan_frame(&scene.path_scene.lights, &settings, flat, uniform, arrays.has_lobess());
            let variant = plan.passes().iter().find_map(ShadeVariant::of).expect("a shading pass");
            assert_eq!(variant.forward_lobe, expected, "{label}: {plan}");
            assert_eq!(plan.forward_lobe, expected, "{label}: {plan}");
        }
    }
}
