//! The GPU renderer end to end on a real Vulkan adapter (lavapipe without a GPU): golden
//! images, the frame plan as executed, the tone-map twin, and the method against the path
//! tracer (paper Fig. 13 style). Without an adapter these tests fail unless
//! `TWILL_ALLOW_NO_GPU=1` (then they print a loud SKIPPED line).

use std::path::Path;
use std::sync::OnceLock;

use twill_precompute::bake::Cancel;
use twill_precompute::bake::pattern::PatternMap;
use twill_precompute::bake::pipeline::{BakeInputs, Baked, bake, bake_set};
use twill_precompute::bake::settings::Quality;
use twill_precompute::image::{Estimate, compare};
use twill_precompute::pathtrace::{self, Component};
use twill_precompute::scene::{GpuSection, Scene, SceneFile};
use twill_renderer::export::{Display, ToneCurve, display_srgb8};
use twill_renderer::frame::{Frame, FrameSettings, MAX_SAMPLE_INDEX, Readback, RenderError, RowBands};
use twill_renderer::gpu::Gpu;
use twill_renderer::headless::{SceneRenderer, frame_settings, shell_for_mesh};
use twill_renderer::plan::Components;
use twill_tests::compare_with_golden;

const FABRIC: &str = "[fabric]\npreset = \"default\"\n";

/// The default fabric's draft bake, shared by every test of this binary.
fn default_bake() -> &'static Baked {
    static BAKE: OnceLock<Baked> = OnceLock::new();
    BAKE.get_or_init(|| {
        let scene = scene(&format!("{FABRIC}{}", camera_above(0.0)), &[SUN]);
        let inputs = BakeInputs {
            exemplar: &scene.exemplar,
            materials: &scene.material_descs,
            settings: Quality::Draft.settings(),
        };
        bake(&inputs, None, &Cancel::new(), &|_, _| {}).expect("draft bake of the default fabric").baked
    })
}

const SUN: &str =
    "[[lights]]\ntype = \"directional\"\ndirection = [-0.5, 0.3, 0.8]\nirradiance = [3.0, 2.9, 2.7]\n";
/// A broad SG light from above and in front, and a sharp one (what PCSS shadows).
const SG_FILL: &str =
    "[[lights]]\ntype = \"sg\"\naxis = [0.3, -0.6, 1.0]\nsharpness = 8.0\nintensity = [1.6, 1.7, 1.8]\n";
const SG_SHARP: &str =
    "[[lights]]\ntype = \"sg\"\naxis = [0.4, 0.2, 0.9]\nsharpness = 300.0\nintensity = [3.0, 3.0, 3.0]\n";

fn camera_above(tilt: f64) -> String {
    format!(
        "[camera]\nprojection = \"perspective\"\neye = [0.0, {:.4}, {:.4}]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nfov_y_deg = 30.0\n",
        -0.9 * tilt.sin(),
        0.9 * tilt.cos()
    )
}

fn scene(head: &str, lights: &[&str]) -> Scene {
    let text = format!("{head}{}", lights.concat());
    SceneFile::parse(&text, Path::new("gpu_render.toml"))
        .expect("scene parses")
        .build()
        .expect("scene builds")
}

fn render(gpu: Gpu, scene: &Scene, size: u32, spp: u32, components: Components) -> (Frame, Gpu) {
    let mut settings = frame_settings(scene, components);
    (settings.width, settings.height, settings.spp) = (size, size, spp);
    settings.gpu.visibility_texture_size = 256;
    settings.gpu.shadow_map_size = 512;
    let mut session = SceneRenderer::with_gpu(gpu, scene, &[default_bake()], &PatternMap::uniform(0))
        .expect("scene uploads");
    let frame = session.render(scene, &settings).expect("frame renders");
    for (i, p) in frame.radiance.iter().enumerate() {
        assert!(p.iter().all(|c| c.is_finite() && *c >= 0.0), "pixel {i} is {p:?}");
    }
    (frame, session.gpu)
}

fn pass_names(frame: &Frame) -> Vec<String> {
    frame.timings.as_ref().expect("lavapipe has timestamp queries").iter().map(|t| t.pass.clone()).collect()
}

#[test]
fn golden_images_and_the_plan_as_executed() {
    let Some(gpu) = Gpu::for_test("golden_images_and_the_plan_as_executed") else { return };
    let oblique = camera_above(0.6);
    let cases: Vec<(&str, Scene)> = vec![
        (
            "swatch_sun_and_sky",
            scene(
                &format!("{FABRIC}[swatch]\nsize_cm = [1.0, 1.0]\nground = true\n{oblique}"),
                &[SUN, SG_FILL],
            ),
        ),
        (
            "swatch_sharp_sg",
            scene(&format!("{FABRIC}[swatch]\nsize_cm = [1.0, 1.0]\nground = true\n{oblique}"), &[SG_SHARP]),
        ),
        (
            "drape_sun_pcf",
            scene(&format!("{FABRIC}[mesh]\nbuiltin = \"drape\"\nsize_cm = [1.0, 1.0]\n{oblique}"), &[SUN]),
        ),
        (
            "cushion_sg_pcss",
            scene(
                &format!("{FABRIC}[mesh]\nbuiltin = \"cushion\"\nsize_cm = [1.0, 1.0]\n{oblique}"),
                &[SG_SHARP, SG_FILL],
            ),
        ),
    ];
    let mut gpu = gpu;
    let mut failures = Vec::new();
    for (name, scene) in &cases {
        let (frame, back) = render(gpu, scene, 64, 2, Components::All);
        gpu = back;
        let passes = pass_names(&frame);
        eprintln!("{name}: passes {passes:?}\n{}", frame.plan);
        let shadowed = passes.iter().any(|p| p.starts_with("shadow"));
        if name.starts_with("swatch") {
            assert!(
                !shadowed && !passes.iter().any(|p| p.contains("visibility")),
                "{name}: a flat swatch lit from above ran {passes:?}"
            );
        } else {
            assert!(
                shadowed && passes.iter().any(|p| p.contains("visibility")),
                "{name}: a curved shell ran no shadow pass: {passes:?}"
            );
        }
        if *name == "drape_sun_pcf" {
            let text = frame.plan.to_string();
            assert!(text.contains("PCF") && !text.contains("PCSS") && !text.contains("SumOfSg"), "{text}");
        }
        let lit = frame.radiance.iter().filter(|p| p.iter().sum::<f32>() > 0.0).count();
        assert!(lit > 64 * 64 / 4, "{name}: only {lit} pixels lit");
        match compare_with_golden(name, frame.width, frame.height, &frame.display) {
            Ok(summary) => eprintln!("{summary}"),
            Err(reason) => failures.push(reason),
        }
    }
    assert!(failures.is_empty(), "golden mismatches:\n{}", failures.join("\n"));
}

#[test]
fn sample_batches_add_up_to_one_frame() {
    // The viewer's progressive rendering and its exports: frames of samples 0..2 and 2..4,
    // weighted by their sample counts, are the frame of samples 0..4 in their signed means
    // (only a pixel's whole mean is clamped at zero, and that is the frame's radiance).
    let Some(gpu) = Gpu::for_test("sample_batches_add_up_to_one_frame") else { return };
    let scene = scene(&format!("{FABRIC}{}", camera_above(0.4)), &[SUN]);
    let mut settings = frame_settings(&scene, Components::All);
    (settings.width, settings.height, settings.spp) = (48, 40, 4);
    let mut session = SceneRenderer::with_gpu(gpu, &scene, &[default_bake()], &PatternMap::uniform(0))
        .expect("scene uploads");
    let whole = session.render(&scene, &settings).expect("frame renders");
    let (camera, lights) = (&scene.camera, &scene.path_scene.lights);
    let half = FrameSettings { spp: 2, ..settings.clone() };
    let first = session.renderer.render_samples(camera, lights, &half, 0).expect("samples 0..2");
    let second = session.renderer.render_samples(camera, lights, &half, 2).expect("samples 2..4");
    let mut largest = 0.0_f32;
    for ((w, a), b) in whole.signed_radiance.iter().zip(&first.signed_radiance).zip(&second.signed_radiance) {
        for c in 0..3 {
            let mean = 0.5 * (a[c] + b[c]);
            assert!((mean - w[c]).abs() <= 1e-4 * w[c].abs().max(1.0), "{w:?} vs {a:?} + {b:?}");
            largest = largest.max(w[c]);
        }
    }
    assert_eq!(whole.radiance, twill_renderer::frame::clamp_at_zero(&whole.signed_radiance));
    assert!(largest > 0.01, "the frame is lit");
    assert!(first.radiance != second.radiance, "the two batches take different samples");
    let err = session.renderer.render_samples(camera, lights, &half, MAX_SAMPLE_INDEX - 1).unwrap_err();
    assert!(err.to_string().contains("sequence ends"), "{err}");
}

#[test]
fn the_progressive_picture_on_the_gpu_is_the_frame_of_all_its_samples() {
    // The viewer's frame: batches of 1, 1, 2 and 4 samples accumulated on the GPU and tone
    // mapped there are the one-shot frame of samples 0..8, to the bit (the same additions in
    // the same order). An export between batches does not disturb the picture; a retone needs
    // no samples; a continuation of another view, a wrong sample count or a rebake is refused.
    let Some(gpu) = Gpu::for_test("the_progressive_picture_on_the_gpu_is_the_frame_of_all_its_samples")
    else {
        return;
    };
    let swatch = scene(&format!("{FABRIC}{}", camera_above(0.4)), &[SUN]);
    let mut settings = frame_settings(&swatch, Components::All);
    (settings.width, settings.height, settings.spp) = (40, 32, 8);
    let mut session = SceneRenderer::with_gpu(gpu, &swatch, &[default_bake()], &PatternMap::uniform(0))
        .expect("scene uploads");
    let whole = session.render(&swatch, &settings).expect("frame renders");
    let (camera, lights) = (&swatch.camera, &swatch.path_scene.lights);
    let renderer = &mut session.renderer;
    let mut first = 0;
    let mut last = None;
    for spp in [1, 1, 2, 4] {
        let batch = FrameSettings { spp, ..settings.clone() };
        let readback = if first == 4 { Readback::Display } else { Readback::Nothing };
        let frame =
            renderer.render_progressive(camera, lights, &batch, first, readback).expect("batch renders");
        assert_eq!(frame.samples, first + spp);
        assert_eq!(frame.display.is_some(), readback == Readback::Display, "read back only when asked");
        first += spp;
        if first == 2 {
            // An export at another size in the middle of the picture.
            let export = FrameSettings { width: 24, height: 16, spp: 2, ..settings.clone() };
            renderer.render_samples(camera, lights, &export, 0).expect("export renders");
        }
        last = Some(frame);
    }
    let last = last.expect("four batches");
    assert_eq!(last.display.as_deref(), Some(&whole.display[..]), "tone mapped on the GPU, as one frame");
    let everything = FrameSettings { spp: 1, ..settings.clone() };
    let more =
        renderer.render_progressive(camera, lights, &everything, 8, Readback::Everything).expect("9th");
    assert_eq!(more.samples, 9);
    assert_eq!(more.radiance.as_ref().map(Vec::len), Some(whole.radiance.len()));

    // A retone: the same samples, a new exposure, as a frame rendered with it.
    let brighter = FrameSettings { exposure: settings.exposure + 1.0, spp: 8, ..settings.clone() };
    let brighter_whole = renderer.render(camera, lights, &brighter).expect("frame renders");
    let restarted =
        renderer.render_progressive(camera, lights, &settings, 0, Readback::Nothing).expect("restart");
    assert_eq!(restarted.samples, 8);
    let retoned = renderer.tone_map_progressive(brighter.exposure, true, Readback::Display).expect("retone");
    assert_eq!(retoned.samples, 8);
    assert_eq!(
        retoned.display.as_deref(),
        Some(&brighter_whole.display[..]),
        "a retone is the frame at that exposure"
    );
    // The picture goes on with the new exposure (the samples do not depend on it).
    let next = FrameSettings { spp: 1, ..brighter.clone() };
    renderer
        .render_progressive(camera, lights, &next, 8, Readback::Nothing)
        .expect("continues after a retone");

    // Refused: a wrong sample count, another view, and anything after a rebake.
    let one = FrameSettings { spp: 1, ..settings.clone() };
    let err = renderer.render_progressive(camera, lights, &one, 5, Readback::Nothing).unwrap_err();
    assert!(err.to_string().contains("start it again from sample 0"), "{err}");
    let moved = scene(&format!("{FABRIC}{}", camera_above(0.3)), &[SUN]);
    let err = renderer.render_progressive(&moved.camera, lights, &one, 9, Readback::Nothing).unwrap_err();
    assert!(err.to_string().contains("0 samples"), "{err}");
    let exemplars = [default_bake()];
    renderer.update_fabric(&exemplars, &PatternMap::uniform(0)).expect("rebake in place");
    assert!(renderer.render_progressive(camera, lights, &one, 9, Readback::Nothing).is_err());
    assert!(renderer.tone_map_progressive(0.0, true, Readback::Nothing).is_err());
}

#[test]
fn a_batch_rendered_in_bands_of_rows_is_the_same_picture_and_stops_between_bands() {
    // The viewer's slow-device batches: every sample's G-buffer and shading band by band of
    // rows, each band its own submission. The picture is the one-submission picture to the bit
    // (each pixel's samples are added in the same order), whatever the band height (12 rounds
    // up to 16; the last band of 36 rows is short). A stop between bands ends the batch with
    // the bands done so far and the picture with it.
    let Some(gpu) =
        Gpu::for_test("a_batch_rendered_in_bands_of_rows_is_the_same_picture_and_stops_between_bands")
    else {
        return;
    };
    let swatch = scene(&format!("{FABRIC}{}", camera_above(0.4)), &[SUN]);
    let mut settings = frame_settings(&swatch, Components::All);
    (settings.width, settings.height, settings.spp) = (40, 36, 3);
    let mut session = SceneRenderer::with_gpu(gpu, &swatch, &[default_bake()], &PatternMap::uniform(0))
        .expect("scene uploads");
    let (camera, lights) = (&swatch.camera, &swatch.path_scene.lights);
    let renderer = &mut session.renderer;
    let whole =
        renderer.render_progressive(camera, lights, &settings, 0, Readback::Everything).expect("whole");
    let never = || false;
    for rows in [8, 12, 40] {
        let bands = RowBands { rows, stop: &never };
        let banded = renderer
            .render_progressive_in_bands(camera, lights, &settings, 0, Readback::Everything, Some(&bands))
            .expect("banded");
        assert_eq!(banded.samples, 3);
        assert_eq!(banded.radiance, whole.radiance, "bands of {rows} rows: the same radiance");
        assert_eq!(banded.display, whole.display, "bands of {rows} rows: the same display");
        assert!(banded.timings.is_none() || rows >= 36, "several submissions carry no pass timings");
    }
    let lit = whole.radiance.as_ref().expect("read back").iter().filter(|p| p[0] > 0.0).count();
    assert!(lit > 40 * 36 / 2, "the frame is lit ({lit} pixels)");

    // Stopped after the 7th of 3 x 5 bands (the 2nd band of the 2nd sample): reported, and the
    // picture is gone, so its continuation is refused; a new picture is whole again.
    let asked = std::cell::Cell::new(0);
    let seventh = || {
        asked.set(asked.get() + 1);
        asked.get() == 7
    };
    let bands = RowBands { rows: 8, stop: &seventh };
    let err = renderer
        .render_progressive_in_bands(camera, lights, &settings, 0, Readback::Everything, Some(&bands))
        .unwrap_err();
    assert!(matches!(err, RenderError::Interrupted { bands_done: 7 }), "{err}");
    assert_eq!(asked.get(), 7, "asked after each band until it said stop");
    let one = FrameSettings { spp: 1, ..settings.clone() };
    let err = renderer.render_progressive(camera, lights, &one, 3, Readback::Nothing).unwrap_err();
    assert!(matches!(err, RenderError::Continuation { .. }), "{err}");
    // A stop asked after the last band of a batch is never asked: the batch is done.
    let asked = std::cell::Cell::new(0);
    let always = || {
        asked.set(asked.get() + 1);
        true
    };
    let bands = RowBands { rows: 64, stop: &always };
    let again = renderer
        .render_progressive_in_bands(camera, lights, &one, 0, Readback::Nothing, Some(&bands))
        .expect("one band, nothing to stop between");
    assert_eq!((again.samples, asked.get()), (1, 0));
    let restarted =
        renderer.render_progressive(camera, lights, &settings, 0, Readback::Everything).expect("restart");
    assert_eq!(restarted.radiance, whole.radiance);
}

#[test]
fn the_cell_transfer_once_per_frame_equals_the_per_pixel_product() {
    // A flat swatch lit from above: every pixel receives the same light SH, so each cell's A c_in
    // is computed once for the frame (the plan's cell-transfer pass) instead of by every pixel.
    // Same image as the per-pixel product (the same f32 operations in the same order), for a
    // directional light and an SG light, and multiple scattering is really there.
    let Some(gpu) = Gpu::for_test("the_cell_transfer_once_per_frame_equals_the_per_pixel_product") else {
        return;
    };
    let sky =
        "[[lights]]\ntype = \"sg\"\naxis = [0.3, -0.6, 1.0]\nsharpness = 8.0\nintensity = [1.6, 1.7, 1.8]\n";
    let scene = scene(&format!("{FABRIC}{}", camera_above(0.4)), &[SUN, sky]);
    let mut settings = frame_settings(&scene, Components::MultipleOnly);
    (settings.width, settings.height, settings.spp) = (40, 32, 2);
    let mut session = SceneRenderer::with_gpu(gpu, &scene, &[default_bake()], &PatternMap::uniform(0))
        .expect("scene uploads");
    let once = session.render(&scene, &settings).expect("frame renders");
    assert!(pass_names(&once).iter().any(|p| p == "cell transfer A c_in"), "{}", once.plan);
    let per_pixel_settings = FrameSettings { frame_transfer: false, ..settings.clone() };
    let per_pixel = session.render(&scene, &per_pixel_settings).expect("frame renders");
    assert!(!per_pixel.plan.cell_transfer, "{}", per_pixel.plan);
    let mut largest = 0.0_f32;
    for (a, b) in once.radiance.iter().zip(&per_pixel.radiance) {
        for c in 0..3 {
            assert!((a[c] - b[c]).abs() <= 1e-5 * b[c].abs().max(1e-3), "{a:?} vs {b:?}");
            largest = largest.max(b[c]);
        }
    }
    assert!(largest > 0.01, "multiple scattering lights the frame ({largest})");
}

#[test]
fn shell_space_visibility_is_reused_until_the_lights_or_the_shell_change() {
    // Shadow maps, X[u,v], V[u,v] and the blur do not depend on the camera or the sample: a
    // second frame of the cushion under the same lights (a progressive batch, a camera move)
    // reuses them and gives the same picture; a light edit or a new shell runs them again.
    let Some(gpu) = Gpu::for_test("shell_space_visibility_is_reused_until_the_lights_or_the_shell_change")
    else {
        return;
    };
    let cushion_head = format!("{FABRIC}[mesh]\nbuiltin = \"cushion\"\nsize_cm = [1.0, 1.0]\n");
    let cushion = scene(&format!("{cushion_head}{}", camera_above(0.5)), &[SUN]);
    let mut settings = frame_settings(&cushion, Components::All);
    (settings.width, settings.height, settings.spp) = (40, 32, 1);
    settings.gpu.visibility_texture_size = 128;
    settings.gpu.shadow_map_size = 256;
    let mut session = SceneRenderer::with_gpu(gpu, &cushion, &[default_bake()], &PatternMap::uniform(0))
        .expect("cushion uploads");
    let shadowed = |frame: &Frame| pass_names(frame).iter().any(|p| p.starts_with("shadow map"));
    let first = session.render(&cushion, &settings).expect("cushion renders");
    assert!(shadowed(&first), "the first frame renders its shadow maps: {:?}", pass_names(&first));
    assert!(first.reused.is_empty(), "{:?}", first.reused);
    let again = session.render(&cushion, &settings).expect("cushion renders");
    assert!(!shadowed(&again), "the same lights reuse them: {:?}", pass_names(&again));
    // The frame says which of its plan's passes it reused, by their plan names.
    let shell_space: Vec<String> = pass_names(&first)
        .into_iter()
        .filter(|p| !again.timings.as_ref().unwrap().iter().any(|t| &t.pass == p))
        .collect();
    assert_eq!(
        again.reused, shell_space,
        "reused passes are the ones the first frame ran and this one did not"
    );
    assert_eq!(again.radiance, first.radiance, "reused visibility, same picture");
    let moved = scene(&format!("{cushion_head}{}", camera_above(0.3)), &[SUN]);
    assert!(!shadowed(&session.render(&moved, &settings).expect("renders")), "a camera move reuses them");
    let relit = scene(
        &format!("{cushion_head}{}", camera_above(0.5)),
        &[SUN.replace("-0.5, 0.3", "-0.4, 0.3").as_str()],
    );
    assert!(shadowed(&session.render(&relit, &settings).expect("renders")), "a light edit reruns them");
    let blurrier =
        FrameSettings { gpu: GpuSection { sigma_glo_cm: 0.1, ..settings.gpu }, ..settings.clone() };
    assert!(shadowed(&session.render(&relit, &blurrier).expect("renders")), "a setting edit reruns them");
    let z = session.renderer.fabric_z_range();
    let drape_head = format!("{FABRIC}[mesh]\nbuiltin = \"drape\"\nsize_cm = [1.0, 1.0]\n");
    let drape = scene(&format!("{drape_head}{}", camera_above(0.5)), &[SUN]);
    let shell = shell_for_mesh(&drape.mesh, drape.swatch.size_cm, &drape.base_dir, z).expect("drape shell");
    session.renderer.set_shell(&shell);
    assert!(shadowed(&session.render(&drape, &blurrier).expect("renders")), "a new shell reruns them");
}

#[test]
fn a_mesh_edit_replaces_only_the_shell() {
    // The viewer's mesh edit: set_shell on a renderer of the swatch gives the same picture as a
    // renderer built on the cushion, without uploading the fabric again.
    let Some(gpu) = Gpu::for_test("a_mesh_edit_replaces_only_the_shell") else { return };
    let flat = scene(&format!("{FABRIC}{}", camera_above(0.5)), &[SUN]);
    let cushion = scene(
        &format!("{FABRIC}[mesh]\nbuiltin = \"cushion\"\nsize_cm = [1.0, 1.0]\n{}", camera_above(0.5)),
        &[SUN],
    );
    let mut settings = frame_settings(&flat, Components::All);
    (settings.width, settings.height, settings.spp) = (40, 32, 1);
    settings.gpu.visibility_texture_size = 128;
    settings.gpu.shadow_map_size = 256;
    let mut session = SceneRenderer::with_gpu(gpu, &flat, &[default_bake()], &PatternMap::uniform(0))
        .expect("scene uploads");
    let before = session.render(&flat, &settings).expect("swatch renders");
    let z = session.renderer.fabric_z_range();
    let shell =
        shell_for_mesh(&cushion.mesh, cushion.swatch.size_cm, &cushion.base_dir, z).expect("cushion shell");
    session.renderer.set_shell(&shell);
    let edited = session.render(&cushion, &settings).expect("cushion renders");
    let mut fresh =
        SceneRenderer::with_gpu(session.gpu, &cushion, &[default_bake()], &PatternMap::uniform(0))
            .expect("cushion uploads");
    let reference = fresh.render(&cushion, &settings).expect("cushion renders");
    assert!(edited.radiance != before.radiance, "the mesh edit changed the picture");
    for (i, (a, b)) in edited.radiance.iter().zip(&reference.radiance).enumerate() {
        for c in 0..3 {
            assert!((a[c] - b[c]).abs() <= 1e-5 * b[c].abs().max(1.0), "pixel {i}: {a:?} vs {b:?}");
        }
    }
    assert_eq!(edited.plan.to_string(), reference.plan.to_string());
}

#[test]
fn the_tone_map_pass_matches_its_cpu_twin() {
    let Some(gpu) = Gpu::for_test("the_tone_map_pass_matches_its_cpu_twin") else { return };
    let scene = scene(&format!("{FABRIC}{}", camera_above(0.3)), &[SUN]);
    let (frame, _) = render(gpu, &scene, 64, 2, Components::All);
    let display = Display { exposure: scene.render.exposure, curve: ToneCurve::Filmic };
    let mut worst = 0;
    for (r, d) in frame.radiance.iter().zip(&frame.display) {
        let cpu = display_srgb8(glam::Vec3::from(*r).as_dvec3(), display);
        for c in 0..3 {
            worst = worst.max(cpu[c].abs_diff(d[c]));
        }
    }
    assert!(worst <= 1, "GPU tone map differs from export::display_srgb8 by {worst} levels");
}

/// The GPU renderer against the path tracer on a flat swatch, single and multiple scattering
/// separately (32x32, 64 spp both; draft bake). Measured 2026-11-24 on lavapipe (the relative
/// error of the image mean, the per-pixel RMSE over the reference mean): single +1.1%, 0.67;
/// multiple +9.9%, 0.71 (before the fidelity fixes: single −4.9%, multiple −19.6%); the
/// multiple's per-pixel RMSE re-measured 0.65 on 2026-12-05 (its mean then +12.6%). Both are
/// held to one-sided bands (`twill_tests::check_band`): the mean within 1% plus three standard
/// errors of the reference's mean, the per-pixel RMSE within 5% of the mean.
#[test]
fn single_and_multiple_scattering_against_the_path_tracer() {
    let Some(gpu) = Gpu::for_test("single_and_multiple_scattering_against_the_path_tracer") else { return };
    let head = format!(
        "{FABRIC}[swatch]\nsize_cm = [2.0, 2.0]\nground = true\n[camera]\nprojection = \"orthographic\"\neye = [0.0, -0.3, 0.6]\ntarget = [0.0, 0.0, 0.0]\nheight_cm = 0.4\n"
    );
    let scene = scene(&head, &[SUN]);
    let size = 32;
    let mut gpu = gpu;
    for (components, component, measured_mean, measured_pixel) in [
        (Components::SingleOnly, Component::Single, 0.011, 0.666),
        (Components::MultipleOnly, Component::Multiple, 0.099, 0.647),
    ] {
        let (frame, back) = render(gpu, &scene, size, 64, components);
        gpu = back;
        let ours = frame.radiance_image();
        let settings = pathtrace::RenderSettings { spp: 64, max_depth: 64, component, seed: 7 };
        let camera = twill_precompute::scene::camera_from(&scene.camera, size as usize, size as usize)
            .expect("camera");
        let film = pathtrace::render(&scene.path_scene, &camera, &settings, &|_| {});
        let (reference, variance) = (film.mean(), film.variance_of_mean());
        let c = compare(
            Estimate { mean: &ours, variance: None },
            Estimate { mean: &reference, variance: Some(&variance) },
        );
        let level = reference.mean().element_sum() / 3.0;
        eprintln!(
            "{components:?}: relative error of the mean {:+.1}% (reference noise {:.1}%), per-pixel RMSE {:.5} = {:.3} of the mean (noise alone {:.5})",
            100.0 * c.relative_error_of_mean,
            100.0 * c.relative_error_of_mean_std,
            c.rmse,
            c.rmse / level,
            c.expected_noise_rmse
        );
        let margin = 0.01 + 3.0 * c.relative_error_of_mean_std;
        let mean = twill_tests::check_band(
            &format!("{components:?}, mean"),
            c.relative_error_of_mean,
            measured_mean,
            margin,
        );
        let pixel = twill_tests::check_band(
            &format!("{components:?}, per pixel"),
            c.rmse / level,
            measured_pixel,
            0.05,
        );
        if let Err(e) = mean.and(pixel) {
            panic!("{e}");
        }
    }
}

/// The paper's Fig. 13 experiment, small: 50 light/view configurations of a flat swatch (views
/// to 70°, lights to 75°, directional and SG lights), 12x12 images, the draft bake. `twill bench
/// accuracy` runs the full-size version for docs/BENCHMARKS.md. One-sided bands around what was
/// measured on lavapipe at this size (`twill_tests::check_band`): relative RMSE of the
/// image-average intensity GPU 10.4%, CPU method 8.5% (2026-12-05, re-measured when the CPU
/// method's band noticed its improvement from 13.8%; the GPU was 11.2% on 2026-11-25 with eye
/// rays to the first occupied voxel, 19.4% and 13.1% with 32 and 128 samples per tetrahedron
/// before; before the fidelity fixes both were 24–32%), each within 3 points; the excess
/// per-pixel RMSE within 10% of its measurement; and the path tracer's own excess per-pixel
/// error falls with spp.
#[test]
fn fig13_average_intensity_over_fifty_configurations() {
    use twill_renderer::accuracy::{ExperimentSettings, run};
    let Some(gpu) = Gpu::for_test("fig13_average_intensity_over_fifty_configurations") else { return };
    let head = format!("{FABRIC}[swatch]\nsize_cm = [2.0, 2.0]\nground = true\n{}", camera_above(0.0));
    let mut scene = scene(&head, &[SUN]);
    let settings = ExperimentSettings {
        configurations: 50,
        size: 12,
        reference_spp: 64,
        method_spp: 4,
        gpu_method: true,
        cpu_method: true,
        ladder_spp: vec![1, 4],
        max_depth: 64,
    };
    let report = run(&mut scene, default_bake(), gpu, &settings, &|_, _| {}).expect("experiment runs");
    eprintln!("{}", report.markdown());
    let rms = report.reference_rms();
    assert!(rms > 0.0 && rms.is_finite(), "reference RMS {rms}");
    for m in report.methods.iter().chain(&report.ladder).chain([&report.reference]) {
        assert!(
            m.average.iter().all(|a| a.is_finite() && a.min_element() >= 0.0),
            "{}: {:?}",
            m.name,
            m.average
        );
        assert!(m.pixel_mse.iter().all(|e| e.is_finite()), "{}", m.name);
    }
    let relative: Vec<f64> = report.methods.iter().map(|m| report.summary(m).average_rmse / rms).collect();
    // (relative RMSE of the average intensity, excess per-pixel RMSE) of the GPU and the CPU.
    let measured = [(0.104, 1.09e-2), (0.085, 1.16e-2)];
    let mut failures = Vec::new();
    for ((m, r), (mean, pixel)) in report.methods.iter().zip(&relative).zip(measured) {
        let excess = report.summary(m).pixel_excess_rmse;
        failures
            .extend(twill_tests::check_band(&format!("{}, average intensity", m.name), *r, mean, 0.03).err());
        failures.extend(
            twill_tests::check_band(&format!("{}, per pixel", m.name), excess, pixel, 0.1 * pixel).err(),
        );
    }
    assert!(failures.is_empty(), "{failures:#?}");
    let (one, four) = (report.summary(&report.ladder[0]), report.summary(&report.ladder[1]));
    assert!(
        four.pixel_excess_rmse < 0.7 * one.pixel_excess_rmse,
        "path tracer per-pixel error at 4 spp {:.3e} vs 1 spp {:.3e}",
        four.pixel_excess_rmse,
        one.pixel_excess_rmse
    );
}

#[test]
fn lambertian_yarns_are_refused_with_a_message_not_rendered_black() {
    let mut baked = default_bake().clone();
    baked.materials[1] = twill_precompute::bcsdf::MaterialDesc::Lambert { albedo: glam::DVec3::splat(0.5) };
    let err = twill_renderer::fabric_data::FabricArrays::pack(&[&baked], &PatternMap::uniform(0))
        .expect_err("a Lambertian slot is refused");
    let message = err.to_string();
    assert!(message.contains("material slot 1") && message.contains("twill reference"), "{message}");
}

#[test]
fn sh_orders_above_what_the_shaders_hold_are_refused_naming_the_limit() {
    let mut baked = default_bake().clone();
    baked.transfer.iirtf.sh_order = twill_renderer::fabric_data::MAX_SH_ORDER + 1;
    let err = twill_renderer::fabric_data::FabricArrays::pack(&[&baked], &PatternMap::uniform(0))
        .expect_err("SH order 7 is refused");
    let message = err.to_string();
    assert!(message.contains("SH order is 7") && message.contains("SH order 6 at most"), "{message}");
}

/// The hard configurations of `twill accuracy` (views to 75°, lights to 80°; the first four are
/// head-on, grazing, backlit, and grazing and backlit under a broad SG), small: 8 configurations
/// of the default fabric, 12x12, draft bake, through the same sweep the report runs. One-sided
/// bands around what was measured 2026-11-24 on lavapipe at this size, per component (single,
/// multiple, all) for the GPU and the CPU method: the image-mean error (Fig. 13 figure, reference
/// noise subtracted) within 3 points, the per-pixel error within 10% of itself, and the grazing
/// and backlit configurations' own image-mean errors within 5 points. Measured (draft, 32
/// SGs, 2026-11-25, GPU eye rays to the first occupied voxel): GPU single / multiple / all
/// 14.9% / 9.2% / 8.7%, CPU method 11.7% / 10.2% / 8.8%; grazing −31.4% (GPU) and −8.3% (CPU),
/// backlit −12.6% and −18.1%. Far from the targets (5%): these bands catch regressions while
/// the fidelity work goes on.
///
/// The GPU's figures moved twice on 2026-11-25. When its orthographic eye rays began at the
/// film plane, as the path tracer's do (before, the GPU also drew fabric behind the film):
/// single 18.1% → 11.8%, all 13.8% → 9.7%, grazing −25.7% → −34.3%. When its eye rays stopped
/// taking 64 samples per tetrahedron and stepped voxel by voxel to the first occupied voxel:
/// single 11.8% → 14.9% (the grazing-and-backlit configuration, view 75° under a broad SG,
/// +29%: the exact first voxel sees the top fibers the samples stepped over, as the budget's
/// voxel-hit rung did, +18.6% against +15.1% on exact hits), multiple 10.1% → 9.2%, grazing
/// −34.3% → −31.4%, backlit −15.9% → −12.6%.
///
/// Re-measured 2026-11-26, since eye rays stop where they enter the fibers' capsules rather
/// than at the first occupied voxel (the voxels had made the fibers wider at oblique views):
/// GPU single / multiple / all 11.2% / 8.9% / 7.9%, grazing −24.5%, backlit −7.0%; CPU method
/// 11.7% / 10.1% / 9.8%, grazing −0.2%, backlit −18.0%. (The CPU method's grazing figure had
/// moved from −8.3% before this session's changes, none of which touches its exact hits on a
/// draft bake; not traced.)
///
/// Re-measured 2026-11-26 (fifth session), since the IIRTF's paths start where an eye sees the
/// cell's fibers (`BakeSettings::exposed_starts`): multiple scattering brighter, GPU multiple /
/// all 8.9% → 7.4% / 7.9% → 7.1%, grazing −24.5% → −18.4%, backlit −7.0% → −1.0%; CPU method
/// 10.1% → 6.0% / 9.8% → 8.7%, backlit −18.0% → −13.7%, and its grazing case −0.2% → +6.3%
/// (over-bright now where it had been near zero; the band follows the measurement).
///
/// Re-measured 2026-11-27 (seventh session), since local visibility reads the kept binary
/// images bilinearly and its rays start at the centroid of the fiber's upper half
/// (`BakeSettings::visibility_bits`, `svf::visibility_origin`): single scattering's darkness at
/// raking light is gone, and with it what had offset other biases here. GPU single / all
/// 11.2% → 14.3% / 7.1% → 8.4% (configuration 3, a broad SG light 80° from the normal behind a
/// 75° view, is +28% in single scattering: the sum-of-SGs path's own excess, which the lit
/// side's darkness had hidden), grazing −18.4% → −13.2%, backlit −1.0% → +7.4% (its multiple
/// scattering's excess now shows); CPU method single 11.7% → 13.5%, grazing +6.3% → +12.5%,
/// backlit −13.7% → −6.5%. Over the 100 configurations of `twill accuracy` at draft the same
/// change took single scattering from 10.6% to 9.6% (docs/BENCHMARKS.md, "Local visibility at
/// raking light"); the bands follow this measurement.
///
/// Re-measured 2026-11-27 (fifteenth session), since the method clamps each pixel's mean at
/// zero instead of each sample (`shading::render::ClampAtZero`): the grazing front-lit case's
/// multiple scattering had been lifted by its negative samples, GPU grazing −13.2% → −22.3%
/// (multiple scattering −32.7%), CPU method +12.5% → +5.9%; GPU single / multiple / all 14.3%
/// → 9.8% / 7.5% → 8.4% / 8.4% → 5.6% (single scattering had moved with the thirteenth
/// session's sum of SGs at their visible directions without reaching the band's edge); CPU
/// method 13.5% → 11.0% / 6.0% → 8.5% / 8.8% → 8.5%, backlit −6.5% → −8.0%.
///
/// Re-measured 2026-11-28 (twenty-second session), since the draft preset's IIRTF cells are 3ℓ
/// across instead of 4ℓ (over the 100 configurations of `twill accuracy` at draft: 11.3% →
/// 9.0% on the GPU, docs/BENCHMARKS.md "The draft preset's cells, switched"). Here GPU multiple
/// / all 8.4% → 7.8% / 5.6% → 6.4%, grazing −22.3% → −18.7%, but the backlit case +4.7% →
/// +9.7% (not traced); CPU method multiple / all 8.5% → 6.5%
/// / 8.5% → 5.2%, grazing +5.9% → +3.4%, backlit −8.0% → −1.8%. The bands follow this
/// measurement; the backlit GPU case is a known cost of the switch.
#[test]
fn hard_configurations_grazing_and_backlit_stay_within_their_measured_bands() {
    use twill_renderer::accuracy::sweep::{Fabric, Method, ReferenceCache, SweepSettings, run};
    let Some(gpu) = Gpu::for_test("hard_configurations_grazing_and_backlit_stay_within_their_measured_bands")
    else {
        return;
    };
    let head = format!("{FABRIC}[swatch]\nsize_cm = [2.0, 2.0]\nground = true\n{}", camera_above(0.0));
    let mut fabrics = vec![Fabric { name: "default".into(), scene: scene(&head, &[SUN]) }];
    let settings = SweepSettings {
        configurations: 8,
        size: 12,
        reference_spp: 64,
        reference_noise: None,
        reference_max_spp: 64,
        method_spp: 4,
        base: Quality::Draft,
        base_bake: Quality::Draft.settings(),
        presets: vec![Quality::Draft],
        knobs: Vec::new(),
        cpu_method: true,
        max_depth: 64,
        example_images: 0,
    };
    let dir = tempfile::tempdir().unwrap();
    let references = ReferenceCache::new(&dir.path().join("references")).unwrap();
    let stages = twill_precompute::bake::file::Cache::new(&dir.path().join("stages")).unwrap();
    let sweep = run(&mut fabrics, gpu, &settings, &references, &stages, &|_| {}).expect("the sweep runs");
    eprintln!("{}", sweep.headline_markdown());
    assert_eq!(sweep.points.len(), 2, "the draft preset on the GPU and the CPU method");
    assert!(sweep.pareto().iter().all(|&on| on), "one point per method: each is its own front");
    // Per method: (single, multiple, all) image-mean error and per-pixel error; then the
    // grazing (1) and backlit (2) configurations' relative error of all light.
    let measured: [([f64; 3], [f64; 3], [f64; 2]); 2] = [
        ([0.098, 0.078, 0.064], [0.941, 0.523, 0.594], [-0.187, 0.097]),
        ([0.110, 0.065, 0.052], [1.041, 0.531, 0.636], [0.034, -0.018]),
    ];
    let mut failures = Vec::new();
    for (point, (mean, pixel, cases)) in sweep.points.iter().zip(measured) {
        let method = if point.method == Method::Gpu { "GPU" } else { "CPU" };
        let result = &point.fabrics[0];
        for (c, name) in ["single", "multiple", "all"].into_iter().enumerate() {
            let e = &result.errors[c];
            eprintln!(
                "{method} {name}: mean {:.4} worst {:+.4} (configuration {}) pixel {:.4} ssim {:.3}",
                e.mean_relative_rmse, e.worst_relative, e.worst_configuration, e.pixel_relative_rmse, e.ssim
            );
            failures.extend(
                twill_tests::check_band(
                    &format!("{method} {name} image mean"),
                    e.mean_relative_rmse,
                    mean[c],
                    0.03,
                )
                .err(),
            );
            failures.extend(
                twill_tests::check_band(
                    &format!("{method} {name} per pixel"),
                    e.pixel_relative_rmse,
                    pixel[c],
                    0.1 * pixel[c],
                )
                .err(),
            );
        }
        for (k, (configuration, what)) in [(1usize, "grazing"), (2, "backlit")].into_iter().enumerate() {
            let relative = result.configuration_errors[configuration][2];
            eprintln!("{method} {what}: {relative:+.4} ({})", sweep.configurations[configuration].describe());
            failures
                .extend(twill_tests::check_band(&format!("{method} {what}"), relative, cases[k], 0.05).err());
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// What a new user sees first: `twill render` against `twill reference` of the built-in default
/// scene (its camera and lights, 128x128, 64 spp, interactive bake), image mean ratio per channel.
/// Before the fidelity fixes the ratio was 0.84. Slow on lavapipe; run with `--ignored --nocapture`.
#[test]
#[ignore = "diagnostic: prints the default scene's image mean against the path tracer (slow)"]
fn default_scene_image_mean_against_the_path_tracer() {
    let Some(gpu) = Gpu::for_test("default_scene_image_mean_against_the_path_tracer") else { return };
    let mut file = SceneFile::default_scene();
    (file.render.width, file.render.height) = (128, 128);
    let scene = file.build().expect("the default scene builds");
    let inputs = scene.bake_inputs(Quality::Interactive.settings());
    let baked = bake(&inputs[0], None, &Cancel::new(), &|_, _| {}).expect("interactive bake").baked;
    let mut settings = frame_settings(&scene, Components::All);
    (settings.width, settings.height, settings.spp) = (128, 128, 64);
    let mut session =
        SceneRenderer::with_gpu(gpu, &scene, &[&baked], &PatternMap::uniform(0)).expect("scene uploads");
    let frame = session.render(&scene, &settings).expect("frame renders");
    let method = frame.radiance_image().mean();
    let camera = twill_precompute::scene::camera_from(&scene.camera, 128, 128).expect("camera");
    let render_settings =
        pathtrace::RenderSettings { spp: 64, max_depth: 64, component: Component::All, seed: 1 };
    let reference = pathtrace::render(&scene.path_scene, &camera, &render_settings, &|_| {}).mean().mean();
    eprintln!(
        "default scene, 128x128: method {method:.5}, reference {reference:.5}, ratio {:.3}",
        method / reference
    );
}

/// Patterned cloth: with a map of alternating block columns of the default twill (exemplar 0)
/// and a plain weave of its yarns (exemplar 1), the middle of every block renders as the
/// single-weave cloth of that block's weave (the same bake under a map of that exemplar alone),
/// and unlike the other weave's. Orthographic view from above over four block columns, so each
/// pixel's block is where its ray meets z = 0 (u = x, blocks start at u = 0); pixels within a
/// quarter block of a block edge are left out (fibers, shadows and multiple scattering cross
/// edges). Measured 2026-11-25 on lavapipe (64x64, 2 spp, draft bake of both weaves, 10 s):
/// the block middles equal their own weave's render exactly (RMS difference 0) and differ from
/// the other weave's by 1.66 and 1.72 times the mean; held to at most 0.1% and at least 50%.
/// The path tracer (`raycast::pattern`, 32 spp, seed 7) draws the same blocks: measured
/// 2026-11-28, its block middles differ from its own single-weave pictures by 0.32 / 0.30 of
/// their mean (paths that cross a block edge; the same seed gives the same random numbers per
/// pixel) and from the other weave's by 1.51 / 1.72 (held to at most 0.3 of the latter), and the
/// GPU's block middles are +6.7% / −6.3% of the path tracer's in mean (the draft method's error
/// on this view; held to one-sided bands of 4 points). Re-measured 2026-11-28 (twenty-second
/// session) with the draft's cells 3ℓ across instead of 4ℓ: +11.0% / −2.6% (the twill's block
/// middles brighter; the bands follow). These are one bake seed's figures: the draft's transfer
/// is noisy enough that on the plain weave alone (from above, this sun) its multiple scattering
/// measured −0.4% at seed 1 and −12%, −19%, −9%, +0.3% with other seeds of its paths, and −11%
/// at ten times the paths (docs/BENCHMARKS.md, "The bake's own noise"): a bake change that moves
/// these bands may be moving the noise, so measure it over seeds before reading it as a bias.
#[test]
fn patterned_cloth_blocks_render_as_their_own_weave() {
    let Some(gpu) = Gpu::for_test("patterned_cloth_blocks_render_as_their_own_weave") else { return };
    let scene_with = |rows: &str, height_cm: f64| {
        scene(
            &format!(
                "{FABRIC}[pattern]\nweaves = [{{ weave = \"plain\" }}]\nrows = [\"{rows}\"]\n\
                 [swatch]\nsize_cm = [2.0, 2.0]\nground = true\n[camera]\nprojection = \"orthographic\"\n\
                 eye = [0.0, 0.0, 0.6]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nheight_cm = {height_cm}\n"
            ),
            &[SUN],
        )
    };
    let probe = scene_with("01", 1.0);
    let twill = &probe.exemplars()[0];
    let twill_precompute::fabric::Tiling::Periodic { period } = twill.tiling else {
        panic!("the twill tiles")
    };
    let block_cm = f64::from(period.x) / f64::from(twill.blocks.nx);
    let height_cm = 4.0 * block_cm;
    let patterned = scene_with("01", height_cm);
    let started = std::time::Instant::now();
    let set = bake_set(
        &patterned.bake_inputs(Quality::Draft.settings()),
        patterned.pattern_map(),
        None,
        &Cancel::new(),
        &|_, _| {},
    )
    .expect("draft bake of both weaves");
    eprintln!("bake of 2 exemplars: {:.1} s, blocks {block_cm:.4} cm", started.elapsed().as_secs_f64());
    let baked: Vec<&Baked> = set.exemplars.iter().map(|o| &o.baked).collect();
    let size = 64_u32;
    let mut settings = frame_settings(&patterned, Components::All);
    (settings.width, settings.height, settings.spp) = (size, size, 2);
    settings.gpu.visibility_texture_size = 256;
    settings.gpu.shadow_map_size = 512;
    let mut gpu = Some(gpu);
    let mut render_map = |rows: &[&str]| {
        let map = PatternMap::from_rows(rows).expect("map");
        let mut session =
            SceneRenderer::with_gpu(gpu.take().expect("device"), &patterned, &baked, &map).expect("uploads");
        let frame = session.render(&patterned, &settings).expect("frame renders");
        gpu = Some(session.gpu);
        assert!(frame.radiance.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));
        frame.radiance
    };
    let mixed = render_map(&["01"]);
    let only = [render_map(&["0"]), render_map(&["1"])];
    let camera = twill_precompute::scene::camera_from(&patterned.camera, size as usize, size as usize)
        .expect("camera");
    // Per weave: squared differences from each single-weave render, and the level.
    let mut sums = [[0.0_f64; 3]; 2];
    let mut counts = [0_usize; 2];
    // The weave of the block a pixel sees the middle of (None within a quarter block of an edge).
    let block_middle = |i: usize| {
        let (px, py) = ((i % size as usize) as f64 + 0.5, (i / size as usize) as f64 + 0.5);
        let (origin, direction) = camera.ray(px, py);
        let x = origin.x - direction.x * origin.z / direction.z;
        let block = (x / block_cm).floor();
        ((x / block_cm - block - 0.5).abs() <= 0.25).then(|| (block as i64).rem_euclid(2) as usize)
    };
    for (i, pixel) in mixed.iter().enumerate() {
        let Some(weave) = block_middle(i) else { continue };
        let luminance = |p: &[f32; 3]| p.iter().map(|&c| f64::from(c)).sum::<f64>() / 3.0;
        let own = luminance(pixel) - luminance(&only[weave][i]);
        let other = luminance(pixel) - luminance(&only[1 - weave][i]);
        sums[weave][0] += own * own;
        sums[weave][1] += other * other;
        sums[weave][2] += luminance(&only[weave][i]);
        counts[weave] += 1;
    }
    for weave in 0..2 {
        let n = counts[weave] as f64;
        assert!(n >= 200.0, "weave {weave}: only {n} pixels in block middles");
        let (own, other, level) =
            ((sums[weave][0] / n).sqrt(), (sums[weave][1] / n).sqrt(), sums[weave][2] / n);
        eprintln!(
            "weave {weave}: {n} pixels, RMS difference from its own weave's render {:.4}, from the other's {:.4} (of the mean {level:.4})",
            own / level,
            other / level
        );
        assert!(
            own <= 1e-3 * level,
            "weave {weave}: block middles differ from their weave's render by {own}"
        );
        assert!(other >= 0.5 * level, "weave {weave}: the other weave renders alike ({other})");
    }

    // The path tracer draws the same blocks (`raycast::pattern`): its block middles are its own
    // single-weave pictures' (the same seed, so the same random numbers per pixel: they differ
    // only where a path crosses a block edge) and unlike the other weave's, and the GPU's
    // picture of each weave's blocks is as bright as the path tracer's.
    let render_settings =
        pathtrace::RenderSettings { spp: 32, max_depth: 64, component: Component::All, seed: 7 };
    let trace = |scene: &Scene| {
        let film = pathtrace::render(&scene.path_scene, &camera, &render_settings, &|_| {});
        let luminance: Vec<f64> = film.mean().pixels.iter().map(|p| p.element_sum() / 3.0).collect();
        assert!(luminance.iter().all(|l| l.is_finite()));
        luminance
    };
    let traced = trace(&patterned);
    let traced_only = [trace(&scene_with("0", height_cm)), trace(&scene_with("1", height_cm))];
    let gpu_luminance: Vec<f64> =
        mixed.iter().map(|p| p.iter().map(|&c| f64::from(c)).sum::<f64>() / 3.0).collect();
    let mut failures = Vec::new();
    for weave in 0..2 {
        let middles: Vec<usize> = (0..mixed.len()).filter(|&i| block_middle(i) == Some(weave)).collect();
        let n = middles.len() as f64;
        let mean = |image: &[f64]| middles.iter().map(|&i| image[i]).sum::<f64>() / n;
        let rms =
            |a: &[f64], b: &[f64]| (middles.iter().map(|&i| (a[i] - b[i]).powi(2)).sum::<f64>() / n).sqrt();
        let level = mean(&traced);
        let (own, other) =
            (rms(&traced, &traced_only[weave]) / level, rms(&traced, &traced_only[1 - weave]) / level);
        let gpu_error = mean(&gpu_luminance) / level - 1.0;
        eprintln!(
            "path tracer, weave {weave}: block middles' mean {level:.5}; RMS difference from its own weave's \
             picture {own:.4}, from the other's {other:.4}; GPU mean {:+.1}% of it",
            100.0 * gpu_error
        );
        if own.is_nan() || own > 0.3 * other {
            failures.push(format!("weave {weave}: the path tracer's blocks are not their own weave's ({own:.3} against {other:.3})"));
        }
        let measured = [0.110, -0.026][weave];
        if let Err(e) = twill_tests::check_band(
            &format!("weave {weave}, GPU against the path tracer"),
            gpu_error,
            measured,
            0.04,
        ) {
            failures.push(e);
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Curved cloth against the path tracer (the fidelity issue, part 1): the path tracer traces
/// the fibers carried onto the mesh through the shell the GPU renders
/// (`headless::trace_on_mesh`), so the GPU's shadow maps (the drape under the sun, PCF) and PCSS
/// (the cushion under a sharp and a broad SG light) have ground truth. 32x32, a view of the
/// whole 1 cm mesh, the GPU at 64 spp on the draft bake, the path tracer at 256 spp (seed 7).
/// Measured 2026-11-28 on lavapipe: the GPU's image mean against the path tracer's +3.2%
/// (drape) and +0.3% (cushion), with the reference's mean good to 1.3% / 0.7% (one standard
/// error); per pixel, the RMS difference 0.490 / 0.286 of the mean against the reference's own
/// noise of 0.412 / 0.237. (Before the visibility pass's receiver-plane bias the top surface
/// shadowed itself on slopes: −1.0% / −4.6%; docs/BENCHMARKS.md has the interactive budget's
/// figures before and after.) The control, the flat swatch the path tracer traced before, is
/// +145% / +5% off in mean and 2.76 / 0.87 per pixel (held to at least twice the GPU's).
/// Held to one-sided bands: the mean within 3 points plus three standard errors of the
/// reference's mean, per pixel within 5 points.
#[test]
fn curved_cloth_against_the_path_tracer() {
    let Some(gpu) = Gpu::for_test("curved_cloth_against_the_path_tracer") else { return };
    let view = "[camera]\nprojection = \"perspective\"\neye = [0.0, -1.1, 1.1]\ntarget = [0.0, 0.0, 0.1]\n\
                up = [0.0, 0.0, 1.0]\nfov_y_deg = 40.0\n";
    let head = |mesh: &str| {
        format!(
            "{FABRIC}[swatch]\nsize_cm = [1.0, 1.0]\nground = true\n[mesh]\nbuiltin = \"{mesh}\"\nsize_cm = [1.0, 1.0]\n{view}"
        )
    };
    // (mesh, lights, measured mean error, measured per-pixel error)
    let cases = [("drape", vec![SUN], 0.032, 0.490), ("cushion", vec![SG_SHARP, SG_FILL], 0.003, 0.286)];
    let size = 32_u32;
    let mut gpu = Some(gpu);
    let mut failures = Vec::new();
    for (mesh, lights, measured_mean, measured_pixel) in cases {
        let mut scene = scene(&head(mesh), &lights);
        let (frame, back) = render(gpu.take().expect("device"), &scene, size, 64, Components::All);
        gpu = Some(back);
        let ours = frame.radiance_image();
        let camera = twill_precompute::scene::camera_from(&scene.camera, size as usize, size as usize)
            .expect("camera");
        let settings =
            pathtrace::RenderSettings { spp: 256, max_depth: 64, component: Component::All, seed: 7 };
        let flat = pathtrace::render(&scene.path_scene, &camera, &settings, &|_| {}).mean();
        assert!(twill_renderer::headless::trace_on_mesh(&mut scene).expect("the fabric maps onto the mesh"));
        let film = pathtrace::render(&scene.path_scene, &camera, &settings, &|_| {});
        let reference = film.mean();
        let luminance = |p: &twill_precompute::Rgb| p.element_sum() / 3.0;
        let mean = |image: &twill_precompute::image::Image| {
            image.pixels.iter().map(luminance).sum::<f64>() / image.pixels.len() as f64
        };
        let (level, n) = (mean(&reference), reference.pixels.len() as f64);
        let pixel_noise =
            (film.variance_of_mean().pixels.iter().map(luminance).sum::<f64>() / n).sqrt() / level;
        let error = mean(&ours) / level - 1.0;
        let per_pixel = |image: &twill_precompute::image::Image| {
            (image
                .pixels
                .iter()
                .zip(&reference.pixels)
                .map(|(a, b)| (luminance(a) - luminance(b)).powi(2))
                .sum::<f64>()
                / n)
                .sqrt()
                / level
        };
        let (pixel, control, control_pixel) = (per_pixel(&ours), mean(&flat) / level - 1.0, per_pixel(&flat));
        eprintln!(
            "{mesh}: reference mean {level:.5} (per-pixel noise {:.3} of it), GPU {:+.1}%, per pixel {:.3}; \
             the flat swatch {:+.1}%, per pixel {control_pixel:.3}",
            pixel_noise,
            100.0 * error,
            pixel,
            100.0 * control
        );
        failures.extend(
            twill_tests::check_band(
                &format!("{mesh}: image mean"),
                error,
                measured_mean,
                0.03 + 3.0 * pixel_noise / n.sqrt(),
            )
            .err(),
        );
        failures.extend(
            twill_tests::check_band(&format!("{mesh}: per pixel"), pixel, measured_pixel, 0.05).err(),
        );
        if control_pixel < 2.0 * pixel {
            failures.push(format!(
                "{mesh}: the flat swatch is as near the curved reference per pixel ({control_pixel:.3}) as the GPU ({pixel:.3})"
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Colour orders reach the GPU renderer: a colourway of the default twill (warp "1 navy, 1 red",
/// weft "2 cream, 2 navy": four palette-coloured yarn kinds, the same 4 x 4 repeat) against the
/// path tracer, which takes each yarn's material from the same orders, per channel. A renderer
/// that gave every warp end one material, or indexed the palette wrongly, would move the red
/// and blue channels apart by tens of percent (the control: an all-navy warp is 42% darker in
/// red in the path tracer, against a band of ~8 points). Measured 2026-11-25 on lavapipe (32x32, 64 spp,
/// draft bake): relative error of the mean R/G/B +5.6% / +9.7% / +2.2%
/// (reference noise 1.3–1.8%; the default twill's multiple scattering is ~10% bright at this view,
/// see `single_and_multiple_scattering_against_the_path_tracer`); held to one-sided bands of 3 points
/// plus three standard errors of the reference's mean.
#[test]
fn colour_orders_reach_the_gpu_renderer_channel_by_channel() {
    let Some(gpu) = Gpu::for_test("colour_orders_reach_the_gpu_renderer_channel_by_channel") else { return };
    let head = format!(
        "{FABRIC}[materials]\nwarp_order = \"1 navy, 1 red\"\nweft_order = \"2 cream, 2 navy\"\n\
         [materials.palette]\nnavy = {{ base = \"warp\", c_tt = [0.05, 0.07, 0.4] }}\ncream = {{ base = \"weft\" }}\n\
         red = {{ base = \"warp\", c_r = [0.05, 0.03, 0.03], c_tt = [0.8, 0.1, 0.08] }}\n\
         [swatch]\nsize_cm = [2.0, 2.0]\nground = true\n[camera]\nprojection = \"orthographic\"\n\
         eye = [0.0, -0.3, 0.6]\ntarget = [0.0, 0.0, 0.0]\nheight_cm = 0.4\n"
    );
    let scene = scene(&head, &[SUN]);
    assert_eq!(scene.material_descs.len(), 3);
    let warp_materials: Vec<u32> = scene.exemplar.yarns.iter().take(4).map(|y| y.material).collect();
    assert_eq!(warp_materials, [1, 2, 1, 2], "navy, red, navy, red (palette: cream 0, navy 1, red 2)");
    let inputs = &scene.bake_inputs(Quality::Draft.settings())[0];
    let baked = bake(inputs, None, &Cancel::new(), &|_, _| {}).expect("draft bake of the colourway").baked;
    let size = 32;
    let mut settings = frame_settings(&scene, Components::All);
    (settings.width, settings.height, settings.spp) = (size, size, 64);
    settings.gpu.visibility_texture_size = 256;
    settings.gpu.shadow_map_size = 512;
    let mut session =
        SceneRenderer::with_gpu(gpu, &scene, &[&baked], &PatternMap::uniform(0)).expect("scene uploads");
    let frame = session.render(&scene, &settings).expect("frame renders");
    assert!(frame.radiance.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));
    let ours = frame.radiance_image().mean();
    let camera =
        twill_precompute::scene::camera_from(&scene.camera, size as usize, size as usize).expect("camera");
    let render_settings =
        pathtrace::RenderSettings { spp: 64, max_depth: 64, component: Component::All, seed: 7 };
    let film = pathtrace::render(&scene.path_scene, &camera, &render_settings, &|_| {});
    let reference = film.mean().mean();
    let variance = film.variance_of_mean().mean();
    let pixels = f64::from(size * size);
    let mut failures = Vec::new();
    for (channel, measured) in [(0, 0.056), (1, 0.097), (2, 0.022)] {
        let error = ours[channel] / reference[channel] - 1.0;
        // The standard error of the reference's image mean, relative.
        let noise = (variance[channel] / pixels).sqrt() / reference[channel];
        eprintln!(
            "channel {channel}: GPU {:.5}, reference {:.5}, error {:+.1}% (noise {:.1}%)",
            ours[channel],
            reference[channel],
            100.0 * error,
            100.0 * noise
        );
        if let Err(e) =
            twill_tests::check_band(&format!("channel {channel}"), error, measured, 0.03 + 3.0 * noise)
        {
            failures.push(e);
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // The control: the same cloth with every warp end navy is far from it in red.
    let all_navy = self::scene(&head.replace("1 navy, 1 red", "1 navy"), &[SUN]);
    let navy_reference =
        pathtrace::render(&all_navy.path_scene, &camera, &render_settings, &|_| {}).mean().mean();
    let red_shift = 1.0 - navy_reference[0] / reference[0];
    eprintln!(
        "all-navy warp: red channel {:.5} ({:.0}% below the colourway's)",
        navy_reference[0],
        100.0 * red_shift
    );
    assert!(red_shift > 0.2, "the red warp ends should carry much of the red: {red_shift:.3}");
}

/// A material rebake reaches the GPU without a new renderer: `Renderer::update_fabric` writes
/// the new bake into the fabric's buffers in place (no new buffers, bind groups, pipelines or
/// shell), only the buffers whose bytes changed, and the frame equals that of a renderer built
/// on the new bake bit for bit. A bake of another geometry is refused (`None`) and changes
/// nothing. Prints both times (lavapipe, 2026-11-25: see docs/BENCHMARKS.md).
#[test]
fn a_material_rebake_is_written_in_place_and_renders_as_a_new_renderer_would() {
    let Some(gpu) =
        Gpu::for_test("a_material_rebake_is_written_in_place_and_renders_as_a_new_renderer_would")
    else {
        return;
    };
    let recoloured = scene(
        &format!(
            "{FABRIC}[materials]\nwarp = {{ model = \"fiber\", c_r = [0.05, 0.03, 0.03], beta_r_deg = 5.0, \
             c_tt = [0.8, 0.1, 0.08], beta_tt_deg = 10.0, gamma_tt_deg = 25.0 }}\n{}",
            camera_above(0.3)
        ),
        &[SUN],
    );
    let inputs = &recoloured.bake_inputs(Quality::Draft.settings())[0];
    let new_bake = bake(inputs, None, &Cancel::new(), &|_, _| {}).expect("draft bake, recoloured").baked;
    let mut settings = frame_settings(&recoloured, Components::All);
    (settings.width, settings.height, settings.spp) = (48, 48, 2);
    let pattern = PatternMap::uniform(0);

    let started = std::time::Instant::now();
    let mut fresh = SceneRenderer::with_gpu(gpu, &recoloured, &[&new_bake], &pattern).expect("uploads");
    let rebuild_seconds = started.elapsed().as_secs_f64();
    let expected = fresh.render(&recoloured, &settings).expect("renders").radiance;
    let rebuild_first_frame = started.elapsed().as_secs_f64();

    let mut session =
        SceneRenderer::with_gpu(fresh.gpu, &recoloured, &[default_bake()], &pattern).expect("uploads");
    let before = session.render(&recoloured, &settings).expect("renders").radiance;
    let started = std::time::Instant::now();
    let written =
        session.renderer.update_fabric(&[&new_bake], &pattern).expect("packs").expect("same layout");
    let in_place_seconds = started.elapsed().as_secs_f64();
    let after = session.render(&recoloured, &settings).expect("renders").radiance;
    let in_place_first_frame = started.elapsed().as_secs_f64();
    eprintln!(
        "in place: {:.1} ms ({:.1} ms to the first frame), buffers written {written:?}; new renderer: {:.1} ms \
         ({:.1} ms to the first frame)",
        1e3 * in_place_seconds,
        1e3 * in_place_first_frame,
        1e3 * rebuild_seconds,
        1e3 * rebuild_first_frame
    );
    assert!(written.contains(&"materials") && written.contains(&"iirtf"), "{written:?}");
    assert!(
        !written.contains(&"voxels") && !written.contains(&"segments"),
        "geometry is unchanged: {written:?}"
    );
    assert_ne!(before, after, "the picture changes with the materials");
    assert_eq!(after, expected, "in place equals a renderer built on the new bake");

    // Another fabric (a silk satin) does not fit the buffers: refused, nothing written.
    let satin = scene(&format!("[fabric]\npreset = \"silk_satin\"\n{}", camera_above(0.3)), &[SUN]);
    let satin_inputs = &satin.bake_inputs(Quality::Draft.settings())[0];
    let satin_bake = bake(satin_inputs, None, &Cancel::new(), &|_, _| {}).expect("draft bake, satin").baked;
    assert_eq!(session.renderer.update_fabric(&[&satin_bake], &pattern).expect("packs"), None);
    let unchanged = session.render(&recoloured, &settings).expect("renders").radiance;
    assert_eq!(unchanged, after);
}

/// A bake with fiber lobes (`fiber_lobes`), recoloured in place from its basis: the live write
/// puts each cell's matrix and lobes on the GPU from one evaluation (`RecolourBasis::write_cell`
/// in `CellTransfer::pack_lobes`' layout; the basis decides per cell whether it keeps lobes at
/// the new colours or folds them into its matrix), and the picture is exactly the one the
/// whole-bake path gives for the same recolouring.
#[test]
fn live_recolouring_writes_fiber_lobes_in_place() {
    use twill_precompute::Rgb;
    use twill_precompute::bake::iirtf::CellTransfer;
    use twill_precompute::bake::pipeline::{bake_material_preview, recolour_basis};
    use twill_precompute::bake::settings::BakeSettings;
    use twill_precompute::bcsdf::{FiberParams, MaterialDesc};
    let Some(gpu) = Gpu::for_test("live_recolouring_writes_fiber_lobes_in_place") else {
        return;
    };
    let scene0 = scene(&format!("{FABRIC}{}", camera_above(0.5)), &[SUN]);
    let settings0 = BakeSettings { fiber_lobes: true, ..Quality::Draft.settings() };
    let inputs0 = scene0.bake_inputs(settings0);
    let before = bake(&inputs0[0], None, &Cancel::new(), &|_, _| {}).expect("bake").baked;
    let lobes = |b: &Baked| b.transfer.iirtf.cells.iter().filter(|c| c.has_lobes()).count();
    let cells = before.transfer.iirtf.cells.iter().filter(|c| !c.is_empty()).count();
    assert!(lobes(&before) > 0 && lobes(&before) < cells, "{} of {cells} cells keep lobes", lobes(&before));
    let basis = recolour_basis(&inputs0[0], None, &Cancel::new(), &|_| {}).expect("basis");
    let recolour = |m: &MaterialDesc, c_tt: Rgb| match *m {
        MaterialDesc::Fiber(p) => MaterialDesc::Fiber(FiberParams { c_tt, ..p }),
        MaterialDesc::Lambert { .. } => panic!("the default fabric is fiber"),
    };
    let mut scene1 = scene(&format!("{FABRIC}{}", camera_above(0.5)), &[SUN]);
    scene1.material_descs = vec![
        recolour(&scene0.material_descs[0], Rgb::new(0.05, 0.08, 0.45)),
        recolour(&scene0.material_descs[1], Rgb::new(0.92, 0.86, 0.7)),
    ];
    let inputs1 = scene1.bake_inputs(settings0);
    let mut settings = frame_settings(&scene1, Components::All);
    (settings.width, settings.height, settings.spp) = (24, 24, 4);
    let pattern = PatternMap::uniform(0);
    let mut session = SceneRenderer::with_gpu(gpu, &scene0, &[&before], &pattern).expect("scene uploads");
    let written = session.renderer.recolour(0, &basis, &scene1.material_descs).expect("recolours");
    assert_eq!(written, ["materials", "cs_table", "iirtf", "lobes"]);
    let live = session.render(&scene1, &settings).expect("frame renders");
    assert!(live.plan.fiber_lobes, "the recoloured cells keep lobes: {}", live.plan);
    let live = live.radiance_image();
    assert!(live.pixels.iter().all(|p| p.is_finite() && p.min_element() >= 0.0));
    let preview = bake_material_preview(&inputs1[0], &before, Some(&basis), None, &Cancel::new(), &|_, _| {})
        .expect("preview")
        .baked;
    assert!(preview.transfer.iirtf.cells.iter().any(CellTransfer::has_lobes));
    session.renderer.update_fabric(&[&preview], &pattern).expect("packs").expect("same layout");
    let packed = session.render(&scene1, &settings).expect("frame renders").radiance_image();
    let largest = packed.pixels.iter().map(|p| p.max_element()).fold(0.0, f64::max);
    assert!(largest > 0.0);
    for (a, b) in live.pixels.iter().zip(&packed.pixels) {
        assert!((*a - *b).abs().max_element() <= 1e-6 * largest, "in place {a:?} vs packed {b:?}");
    }
}

/// Live recolouring of patterned cloth (the colourways issue, part 2): the default twill beside
/// a plain weave in a 2 x 1 block map, both under the colour orders "1 navy, 1 cream" (warp)
/// and "2 cream, 1 red" (weft), so each weave's exemplar spans its own joint repeat (4 x 12
/// and 2 x 6 threads) and has its own cell grid and recolouring basis. The viewer writes a recolouring into
/// every exemplar with the scene's one palette (`RenderWorker`'s `Work::Recolour`); here:
/// - every exemplar written in place equals the material previews of both exemplars uploaded
///   through the whole-bake path, to rounding;
/// - with only the first exemplar written, the picture differs (the second weave's blocks are
///   in view, so a write that missed them would show);
/// - one exemplar's basis written into the other, whose cell grid differs, is refused.
///
/// This test found the viewer refusing every live recolouring of patterned cloth: the GPU
/// counted an exemplar's cells in one block of its lattice, not in all of them (the basis of
/// the twill's exemplar, 12 blocks, has 10,800 cells; the GPU said 900). Measured 2026-11-28 on
/// lavapipe (32x32, 4 spp, draft): the live picture differs from the original colours' by 20.7%
/// (mean absolute difference over the mean) and from the picture with only the first exemplar
/// written by 8.4%; held to at least 10% and 2%.
#[test]
fn live_recolouring_of_patterned_cloth_writes_every_exemplar() {
    use twill_precompute::bake::pipeline::{bake_material_preview, recolour_basis};
    let Some(gpu) = Gpu::for_test("live_recolouring_of_patterned_cloth_writes_every_exemplar") else {
        return;
    };
    let scene_with = |navy: &str, red: &str| {
        scene(
            &format!(
                "{FABRIC}[pattern]\nweaves = [{{ weave = \"plain\" }}]\nrows = [\"01\"]\n\
                 [materials]\nwarp_order = \"1 navy, 1 cream\"\nweft_order = \"2 cream, 1 red\"\n\
                 [materials.palette]\nnavy = {{ base = \"warp\", c_tt = {navy} }}\ncream = {{ base = \"weft\" }}\n\
                 red = {{ base = \"warp\", c_tt = {red} }}\n\
                 [swatch]\nsize_cm = [2.0, 2.0]\nground = true\n[camera]\nprojection = \"orthographic\"\n\
                 eye = [0.0, -0.2, 0.6]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nheight_cm = 0.5\n"
            ),
            &[SUN],
        )
    };
    let scene0 = scene_with("[0.05, 0.07, 0.4]", "[0.8, 0.1, 0.08]");
    let scene1 = scene_with("[0.1, 0.5, 0.12]", "[0.95, 0.8, 0.1]");
    let draft = Quality::Draft.settings();
    let (inputs0, inputs1) = (scene0.bake_inputs(draft), scene1.bake_inputs(draft));
    assert_eq!(inputs0.len(), 2, "two weaves, two exemplars");
    let map = scene0.pattern_map();
    let set =
        bake_set(&inputs0, map.clone(), None, &Cancel::new(), &|_, _| {}).expect("draft bake of both weaves");
    let before: Vec<&Baked> = set.exemplars.iter().map(|o| &o.baked).collect();
    let bases: Vec<_> = inputs0
        .iter()
        .map(|inputs| recolour_basis(inputs, None, &Cancel::new(), &|_| {}).expect("basis"))
        .collect();
    assert_ne!(bases[0].cells.len(), bases[1].cells.len(), "the weaves' cell grids differ");
    for inputs in &inputs1 {
        assert_eq!(inputs.materials, scene1.material_descs.as_slice(), "one palette for every exemplar");
    }
    let size = 32;
    let mut settings = frame_settings(&scene1, Components::All);
    (settings.width, settings.height, settings.spp) = (size, size, 4);
    settings.gpu.visibility_texture_size = 256;
    settings.gpu.shadow_map_size = 512;
    let mut session = SceneRenderer::with_gpu(gpu, &scene0, &before, &map).expect("scene uploads");
    let original = session.render(&scene0, &settings).expect("frame renders").radiance;
    // The first exemplar alone, then the second: what the viewer writes.
    let written = session.renderer.recolour(0, &bases[0], &scene1.material_descs).expect("recolours");
    assert!(written.contains(&"iirtf"), "{written:?}");
    let first_only = session.render(&scene1, &settings).expect("frame renders").radiance;
    session.renderer.recolour(1, &bases[1], &scene1.material_descs).expect("recolours");
    let live = session.render(&scene1, &settings).expect("frame renders").radiance_image();
    assert!(live.pixels.iter().all(|p| p.is_finite() && p.min_element() >= 0.0));
    // Each exemplar's basis fits its own grid only.
    let refused = session.renderer.recolour(0, &bases[1], &scene1.material_descs);
    assert!(
        matches!(&refused, Err(RenderError::Settings(m)) if m.contains("cells")),
        "a basis of another exemplar: {refused:?}"
    );
    // The same recolouring through the whole-bake path.
    let previews: Vec<Baked> = inputs1
        .iter()
        .zip(&before)
        .zip(&bases)
        .map(|((inputs, baked), basis)| {
            bake_material_preview(inputs, baked, Some(basis), None, &Cancel::new(), &|_, _| {})
                .expect("preview")
                .baked
        })
        .collect();
    let previews: Vec<&Baked> = previews.iter().collect();
    session.renderer.update_fabric(&previews, &map).expect("packs").expect("same layout");
    let packed = session.render(&scene1, &settings).expect("frame renders").radiance_image();
    let largest = packed.pixels.iter().map(|p| p.max_element()).fold(0.0, f64::max);
    assert!(largest > 0.0);
    for (a, b) in live.pixels.iter().zip(&packed.pixels) {
        assert!((*a - *b).abs().max_element() <= 1e-6 * largest, "in place {a:?} vs packed {b:?}");
    }
    // Both writes show in the picture.
    let difference = |a: &[[f32; 3]], b: &twill_precompute::image::Image| {
        let sum: f64 = a
            .iter()
            .zip(&b.pixels)
            .map(|(x, y)| (0..3).map(|c| (f64::from(x[c]) - y[c]).abs()).sum::<f64>())
            .sum();
        sum / b.pixels.iter().map(|p| p.x + p.y + p.z).sum::<f64>()
    };
    let (from_original, from_first_only) = (difference(&original, &live), difference(&first_only, &live));
    eprintln!(
        "mean absolute difference from the live picture: the original colours {:.1}%, only the first exemplar recoloured {:.1}%",
        100.0 * from_original,
        100.0 * from_first_only
    );
    assert!(from_original > 0.1, "the new colours change the picture: {from_original}");
    assert!(from_first_only > 0.02, "the second weave's blocks change with its write: {from_first_only}");
}

/// Live recolouring on the GPU (the colourways issue, part 2): the default fabric's draft bake,
/// recoloured to a navy warp and a cream weft from its recolouring basis, written in place
/// (`Renderer::recolour`):
/// - the same picture as the material preview evaluated from the basis and uploaded through the
///   whole-bake path (`bake_material_preview` + `update_fabric`): the in-place splice of the
///   f16 cells, the C_S rows and the materials is exact;
/// - against a full rebake at those colours, 32 x 32, 16 spp. Since the transfer stage walks
///   the basis's own colour-free paths (2026-11-27), the two differ by the basis's
///   approximation alone: image mean R / G / B +0.11% / +0.11% / −0.10%, per-pixel RMS
///   difference 1.09% of the rebake's mean, where two rebakes that differ only in their seed
///   differ by 43.2% (draft: 96 paths per cell, so the transfer itself is noisy). When the bake
///   walked with its colours (another draw of that noise) these were −3.31% / −2.08% / −0.76%
///   and 26.2% (2026-11-26, exposed starts; +4.2% / +1.6% / −1.7% and 34.6% with independent
///   starts a day earlier). One-sided bands of half a point on the means and one on the
///   per-pixel figure, which must also stay within the seed-to-seed difference. Re-measured
///   2026-11-28 (twenty-second session) with the draft's cells 3ℓ across instead of 4ℓ: means
///   +0.38% / +0.40% / +0.17%, per-pixel RMS 2.68% (seed to seed 38.7%): smaller cells hold
///   fewer paths' worth of each mixed class's weights, which the basis takes from the cell's
///   (0, 0) entry. The per-pixel band follows; the means stay within theirs.
#[test]
fn live_recolouring_writes_the_basis_in_place_and_follows_a_rebake() {
    use twill_precompute::Rgb;
    use twill_precompute::bake::pipeline::{bake_material_preview, recolour_basis};
    use twill_precompute::bcsdf::{FiberParams, MaterialDesc};
    let Some(gpu) = Gpu::for_test("live_recolouring_writes_the_basis_in_place_and_follows_a_rebake") else {
        return;
    };
    let scene0 = scene(&format!("{FABRIC}{}", camera_above(0.5)), &[SUN]);
    let draft = Quality::Draft.settings();
    let before = default_bake();
    let basis = recolour_basis(&scene0.bake_inputs(draft)[0], None, &Cancel::new(), &|_| {}).expect("basis");
    let recolour = |m: &MaterialDesc, c_r: Rgb, c_tt: Rgb| match *m {
        MaterialDesc::Fiber(p) => MaterialDesc::Fiber(FiberParams { c_r, c_tt, ..p }),
        MaterialDesc::Lambert { .. } => panic!("the default fabric is fiber"),
    };
    // The GPU renders from the bake inputs' materials (the path-traced scene is not used here).
    let mut scene1 = scene(&format!("{FABRIC}{}", camera_above(0.5)), &[SUN]);
    scene1.material_descs = vec![
        recolour(&scene0.material_descs[0], Rgb::new(0.03, 0.03, 0.05), Rgb::new(0.05, 0.08, 0.45)),
        recolour(&scene0.material_descs[1], Rgb::splat(0.06), Rgb::new(0.92, 0.86, 0.7)),
    ];
    let inputs1 = scene1.bake_inputs(draft);
    let size = 32;
    let mut settings = frame_settings(&scene1, Components::All);
    (settings.width, settings.height, settings.spp) = (size, size, 16);
    settings.gpu.visibility_texture_size = 256;
    settings.gpu.shadow_map_size = 512;
    let pattern = PatternMap::uniform(0);
    let mut session = SceneRenderer::with_gpu(gpu, &scene0, &[before], &pattern).expect("scene uploads");
    let written = session.renderer.recolour(0, &basis, &scene1.material_descs).expect("recolours");
    assert_eq!(written, ["materials", "cs_table", "iirtf", "lobes"], "the draft bake holds fiber lobes");
    let live = session.render(&scene1, &settings).expect("frame renders").radiance_image();
    assert!(live.pixels.iter().all(|p| p.is_finite() && p.min_element() >= 0.0));
    // The same recolouring through the whole-bake path.
    let preview = bake_material_preview(&inputs1[0], before, Some(&basis), None, &Cancel::new(), &|_, _| {})
        .expect("preview")
        .baked;
    session.renderer.update_fabric(&[&preview], &pattern).expect("packs").expect("same layout");
    let packed = session.render(&scene1, &settings).expect("frame renders").radiance_image();
    let largest = packed.pixels.iter().map(|p| p.max_element()).fold(0.0, f64::max);
    for (a, b) in live.pixels.iter().zip(&packed.pixels) {
        assert!((*a - *b).abs().max_element() <= 1e-6 * largest, "in place {a:?} vs packed {b:?}");
    }
    // Against full rebakes at the new colours.
    let rebake = |seed: u64| {
        let inputs = BakeInputs {
            settings: twill_precompute::bake::settings::BakeSettings { seed, ..draft },
            ..inputs1[0]
        };
        bake(&inputs, None, &Cancel::new(), &|_, _| {}).expect("rebake").baked
    };
    // A new seed measures another mean free path, so another cell grid: that one needs a new
    // renderer rather than an in-place write.
    let render_bake = |mut session: SceneRenderer, baked: &Baked| {
        let mut session = match session.renderer.update_fabric(&[baked], &pattern).expect("packs") {
            Some(_) => session,
            None => SceneRenderer::with_gpu(session.gpu, &scene1, &[baked], &pattern).expect("uploads"),
        };
        let image = session.render(&scene1, &settings).expect("frame renders").radiance_image();
        (image, session)
    };
    let (rebaked, session) = render_bake(session, &rebake(draft.seed));
    let (reseeded, _) = render_bake(session, &rebake(draft.seed + 1));
    let rms = |a: &twill_precompute::image::Image, b: &twill_precompute::image::Image| {
        let n = (b.pixels.len() * 3) as f64;
        let sq: f64 = a.pixels.iter().zip(&b.pixels).map(|(x, y)| (*x - *y).length_squared()).sum();
        (sq / n).sqrt() / (b.pixels.iter().map(|p| p.x + p.y + p.z).sum::<f64>() / n)
    };
    let (ours, theirs) = (live.mean(), rebaked.mean());
    let mut failures = Vec::new();
    for (channel, measured) in [(0, 0.0011), (1, 0.0011), (2, -0.0010)] {
        let error = ours[channel] / theirs[channel] - 1.0;
        eprintln!(
            "channel {channel}: live {:.5}, rebake {:.5}, {:+.2}%",
            ours[channel],
            theirs[channel],
            100.0 * error
        );
        if let Err(e) =
            twill_tests::check_band(&format!("image mean, channel {channel}"), error, measured, 0.005)
        {
            failures.push(e);
        }
    }
    let (live_rms, floor) = (rms(&live, &rebaked), rms(&reseeded, &rebaked));
    eprintln!("per-pixel RMS: live {:.2}%, seed to seed {:.2}%", 100.0 * live_rms, 100.0 * floor);
    if let Err(e) = twill_tests::check_band("per-pixel RMS", live_rms, 0.0268, 0.01) {
        failures.push(e);
    }
    if live_rms > floor {
        failures.push(format!("per-pixel RMS {live_rms:.4} above the seed-to-seed difference {floor:.4}"));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A live recolouring of a bake with segment transfers (`BakeSettings::segment_transfer_paths`):
/// the recolouring basis holds the lattice's cells alone, so the live write takes the segment
/// cells' slots away and the frame equals the whole-bake preview's (whose segment cells are
/// empty), uploaded afresh: every segment is shaded with the lattice's cells at the new colours,
/// none with its own transfer at the old ones. The rebake has its segment transfers again.
#[test]
fn live_recolouring_with_segment_transfers_shades_with_the_cells_until_the_rebake() {
    use twill_precompute::Rgb;
    use twill_precompute::bake::pipeline::{bake_material_preview, recolour_basis};
    use twill_precompute::bake::settings::BakeSettings;
    use twill_precompute::bcsdf::{FiberParams, MaterialDesc};
    let Some(gpu) =
        Gpu::for_test("live_recolouring_with_segment_transfers_shades_with_the_cells_until_the_rebake")
    else {
        return;
    };
    let settings0 = BakeSettings { segment_transfer_paths: 16, ..Quality::Draft.settings() };
    let scene0 = scene(&format!("{FABRIC}{}", camera_above(0.5)), &[SUN]);
    let before =
        bake(&scene0.bake_inputs(settings0)[0], None, &Cancel::new(), &|_, _| {}).expect("bake").baked;
    let segment_cells = |b: &Baked| {
        let grid = &b.transfer.cells;
        (grid.lattice_cell_count()..grid.cell_count())
            .filter(|&c| b.transfer.iirtf.cells[c].paths > 0)
            .count()
    };
    assert!(segment_cells(&before) > 1000, "{} segment cells with a transfer", segment_cells(&before));
    let basis =
        recolour_basis(&scene0.bake_inputs(settings0)[0], None, &Cancel::new(), &|_| {}).expect("basis");
    let mut scene1 = scene(&format!("{FABRIC}{}", camera_above(0.5)), &[SUN]);
    scene1.material_descs = scene0
        .material_descs
        .iter()
        .map(|m| match *m {
            MaterialDesc::Fiber(p) => MaterialDesc::Fiber(FiberParams { c_tt: Rgb::new(0.2, 0.5, 0.9), ..p }),
            MaterialDesc::Lambert { .. } => panic!("the default fabric is fiber"),
        })
        .collect();
    let mut settings = frame_settings(&scene1, Components::MultipleOnly);
    (settings.width, settings.height, settings.spp) = (32, 32, 4);
    let pattern = PatternMap::uniform(0);
    let mut session = SceneRenderer::with_gpu(gpu, &scene0, &[&before], &pattern).expect("scene uploads");
    let written = session.renderer.recolour(0, &basis, &scene1.material_descs).expect("recolours");
    assert!(written.contains(&"cell_slots") && written.contains(&"iirtf"), "{written:?}");
    let live = session.render(&scene1, &settings).expect("frame renders").radiance_image();
    let inputs1 = scene1.bake_inputs(settings0);
    let preview = bake_material_preview(&inputs1[0], &before, Some(&basis), None, &Cancel::new(), &|_, _| {})
        .expect("preview")
        .baked;
    assert_eq!(segment_cells(&preview), 0, "the preview's segment cells are empty");
    let mut fresh = SceneRenderer::with_gpu(session.gpu, &scene1, &[&preview], &pattern).expect("uploads");
    let packed = fresh.render(&scene1, &settings).expect("frame renders").radiance_image();
    let largest = packed.pixels.iter().map(|p| p.max_element()).fold(0.0, f64::max);
    assert!(largest > 0.0);
    for (a, b) in live.pixels.iter().zip(&packed.pixels) {
        assert!((*a - *b).abs().max_element() <= 1e-6 * largest, "in place {a:?} vs packed {b:?}");
    }
    // The rebake at the new colours has its segment transfers again.
    let rebaked = bake(&inputs1[0], None, &Cancel::new(), &|_, _| {}).expect("rebake").baked;
    assert!(segment_cells(&rebaked) > 1000, "{} segment cells with a transfer", segment_cells(&rebaked));
}
