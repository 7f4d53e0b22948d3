//! Albedo painting against its own paths, the path tracer and finite differences.

use std::path::Path;

use super::*;
use crate::scene::{Scene, SceneFile};

/// The default twill, a 0.5 cm swatch seen from above at an angle, a sun and a soft sky.
const SCENE: &str = r#"
[fabric]
preset = "default"
[swatch]
size_cm = [0.5, 0.5]
ground = true
[camera]
projection = "perspective"
eye = [0.0, -0.25, 0.45]
target = [0.0, 0.0, 0.0]
up = [0.0, 0.0, 1.0]
fov_y_deg = 28.0
[[lights]]
type = "directional"
direction = [-0.6, 0.35, 0.5]
irradiance = [3.3, 3.15, 2.85]
[[lights]]
type = "sg"
axis = [0.3, -0.6, 1.0]
sharpness = 8.0
intensity = [1.6, 1.7, 1.8]
[render]
width = 12
height = 12
spp = 16
max_depth = 64
seed = 1
"#;

fn scene(text: &str) -> (Scene, Camera) {
    let file = SceneFile::parse(text, Path::new("paint.toml")).expect("scene parses");
    let scene = file.build().expect("scene builds");
    let camera = file.camera(file.render.width, file.render.height).expect("camera");
    (scene, camera)
}

fn cells(scene: &Scene) -> PaintCells {
    PaintCells::new(&scene.exemplar, &scene.path_scene.fibers).expect("a finite swatch")
}

fn settings(spp: u32, seed: u64) -> PaintSettings {
    PaintSettings { width: 12, height: 12, curve_spp: spp, gradient_spp: spp, max_depth: 64, seed }
}

fn data(scene: &Scene, camera: &Camera, s: &PaintSettings) -> PaintData {
    precompute(&scene.path_scene, cells(scene), camera, s, &|_| {}).expect("precomputes")
}

fn stripes(data: &PaintData) -> Vec<Rgb> {
    let painting = Painting::parse(
        "base = [0.8, 0.75, 0.6]\n[[stroke]]\ncolour = [0.05, 0.1, 0.5]\nwarp = \"1-2, 5\"\n\
         [[stroke]]\ncolour = [0.9, 0.2, 0.1]\nweft = \"3\"\n",
        Path::new("stripes.toml"),
    )
    .unwrap();
    painting.colours(&data.cells, &data.scene_painting(), Path::new("stripes.toml")).unwrap()
}

#[test]
fn homogeneous_paintings_are_their_own_paths_up_to_the_curve_interpolation() {
    let (scene, camera) = scene(SCENE);
    let s = settings(32, 5);
    let data = data(&scene, &camera, &s);
    let cells = cells(&scene);
    for alpha in [0.3, 0.78, 0.9, 0.975] {
        let colours = vec![Rgb::splat(alpha); cells.count()];
        let exact = render_painted_paths(&scene.path_scene, &cells, &camera, &s, &colours).unwrap().mean();
        let painted = data.evaluate(&colours);
        let error = painted.relative_l2(&exact);
        eprintln!("homogeneous α = {alpha}: relative L2 {error:.2e}");
        assert!(painted.is_finite());
        assert!(error < 2e-3, "α = {alpha}: relative L2 {error:.2e} between Theorem 1 and its own paths");
    }
}

#[test]
fn the_walk_never_reads_the_colours_it_differentiates() {
    let (navy, camera) = scene(SCENE);
    let recoloured = SCENE.replace(
        "[swatch]",
        "[materials]\nwarp = { model = \"fiber\", c_r = [0.03, 0.03, 0.05], beta_r_deg = 1.0, \
         c_tt = [0.9, 0.1, 0.5], beta_tt_deg = 27.197, gamma_tt_deg = 38.269 }\n\
         weft = { model = \"fiber\", c_r = [0.04, 0.04, 0.04], beta_r_deg = 1.0, \
         c_tt = [0.02, 0.6, 0.3], beta_tt_deg = 27.197, gamma_tt_deg = 38.269 }\n[swatch]",
    );
    let (other, _) = scene(&recoloured);
    let s = settings(8, 3);
    let (a, b) = (data(&navy, &camera, &s), data(&other, &camera, &s));
    assert_ne!(a.scene_colours, b.scene_colours, "the scenes differ in their colours");
    // Bit for bit (no float printed: the arrays are long).
    assert!(a.curve_values == b.curve_values, "the curves moved with the colours");
    assert!(a.curve_slopes == b.curve_slopes, "the curves' slopes moved with the colours");
    assert!(a.weight_cells == b.weight_cells && a.weights == b.weights, "the weights moved with the colours");
}

#[test]
fn the_colour_free_paths_agree_with_the_path_tracer_on_a_painted_cloth() {
    let (mut scene, camera) = scene(SCENE);
    let cells = cells(&scene);
    let s = settings(8, 3);
    let probe = data(&scene, &camera, &s);
    let colours = stripes(&probe);
    let walked =
        render_painted_paths(&scene.path_scene, &cells, &camera, &settings(256, 11), &colours).unwrap();
    scene.path_scene.painted = Some(PaintedMaterials::new(&scene.path_scene, cells, &colours).unwrap());
    let render = crate::pathtrace::RenderSettings {
        spp: 256,
        max_depth: 64,
        component: crate::pathtrace::Component::All,
        seed: 12,
    };
    let traced = crate::pathtrace::render(&scene.path_scene, &camera, &render, &|_| {});
    let (a, b) = (walked.mean(), traced.mean());
    let (va, vb) = (walked.variance_of_mean(), traced.variance_of_mean());
    let n = a.pixels.len() as f64;
    let diff = a.mean() - b.mean();
    let se = ((va.mean() + vb.mean()) / n).map(f64::sqrt);
    for c in 0..3 {
        assert!(
            diff[c].abs() < 4.0 * se[c],
            "channel {c}: {:.5} vs {:.5} (se {:.5})",
            a.mean()[c],
            b.mean()[c],
            se[c]
        );
    }
}

/// Mean and standard error of the mean of `values`.
fn mean_and_error(values: &[Rgb]) -> (Rgb, Rgb) {
    let n = values.len() as f64;
    let mean = values.iter().fold(Rgb::ZERO, |a, v| a + *v) / n;
    let var = values.iter().fold(Rgb::ZERO, |a, v| a + (*v - mean) * (*v - mean)) / (n - 1.0);
    (mean, (var / n).map(f64::sqrt))
}

#[test]
fn the_weights_match_finite_differences_at_the_expansion_point() {
    // Hašan & Ramamoorthy section 6: W (times the curve's slope) against
    // (I(α0 + h e_T) − I(α0 − h e_T)) / 2h, h = 0.02, for T the cells of one warp end, summed
    // over the image. Both sides from independent paths, four seeds each.
    let (scene, camera) = scene(SCENE);
    let cells = cells(&scene);
    let thread = cells.thread_cells(true, 4, 0..cells.warp.sections).expect("warp end 4 lies in the swatch");
    let pixels: Vec<usize> = (0..144).collect();
    let h = 0.02;
    let (mut from_weights, mut differences) = (Vec::new(), Vec::new());
    for seed in 0..4 {
        let s = settings(64, 100 + seed);
        from_weights.push(data(&scene, &camera, &s).gradient_sum(&pixels, &thread));
        let at = |alpha: f64| {
            let mut colours = vec![Rgb::splat(EXPANSION_ALBEDO); cells.count()];
            for &c in &thread {
                colours[c as usize] = Rgb::splat(alpha);
            }
            let film =
                render_painted_paths(&scene.path_scene, &cells, &camera, &settings(64, 200 + seed), &colours);
            film.unwrap().mean().mean() * pixels.len() as f64
        };
        differences.push((at(EXPANSION_ALBEDO + h) - at(EXPANSION_ALBEDO - h)) / (2.0 * h));
    }
    let (w, w_err) = mean_and_error(&from_weights);
    let (d, d_err) = mean_and_error(&differences);
    eprintln!("weights {w:.4?} ± {w_err:.4?}, finite differences {d:.4?} ± {d_err:.4?}");
    assert!(w.min_element() > 0.0, "the warp end is seen: {w:?}");
    for c in 0..3 {
        let se = w_err[c].hypot(d_err[c]);
        assert!(
            (w[c] - d[c]).abs() < 3.0 * se + 0.01 * d[c].abs(),
            "channel {c}: weights {:.4} ± {:.4}, finite differences {:.4} ± {:.4}",
            w[c],
            w_err[c],
            d[c],
            d_err[c]
        );
    }
}

#[test]
fn theorem_one_stays_near_its_own_paths_on_stripes() {
    // The approximation alone: Theorem 1 against the same paths evaluated exactly at the
    // painting (no path noise between them). Measured 2026-11-26: relative L2 0.019, image mean
    // −0.7 / −0.6 / −0.1% (Theorem 1 alone, without the exact single-cell classes: 0.069 and
    // −2.4 / −2.8 / −0.6%).
    let (scene, camera) = scene(SCENE);
    let s = settings(64, 9);
    let data = data(&scene, &camera, &s);
    let colours = stripes(&data);
    let exact =
        render_painted_paths(&scene.path_scene, &cells(&scene), &camera, &s, &colours).unwrap().mean();
    let painted = data.evaluate(&colours);
    let error = painted.relative_l2(&exact);
    let mean_error = (painted.mean() - exact.mean()) / exact.mean();
    eprintln!("stripes: relative L2 {error:.4}, image mean {mean_error:.4?}");
    assert!(error < 0.025, "relative L2 {error:.4} against its own paths");
    assert!(mean_error.abs().max_element() < 0.01, "image mean off by {mean_error:.4?}");
}

#[test]
fn the_paint_file_round_trips_and_refuses_damage() {
    let (scene, camera) = scene(SCENE);
    let data = data(&scene, &camera, &settings(4, 1));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cloth.twillpaint");
    data.save(&path).unwrap();
    assert_eq!(PaintData::load(&path).unwrap(), data);
    let bytes = std::fs::read(&path).unwrap();
    let mut flipped = bytes.clone();
    let last = flipped.len() - 1;
    flipped[last] ^= 1;
    let named = |e: PaintFileError| {
        let text = e.to_string();
        assert!(text.contains("cloth.twillpaint"), "{text}");
        text
    };
    assert!(named(PaintData::from_bytes(&flipped, &path).unwrap_err()).contains("checksum"));
    assert!(
        named(PaintData::from_bytes(&bytes[..bytes.len() - 9], &path).unwrap_err()).contains("truncated")
    );
    assert!(
        named(PaintData::from_bytes(b"TWILLBAK....", &path).unwrap_err()).contains("not a twill paint file")
    );
    let mut version = bytes.clone();
    version[8] = 99;
    assert!(named(PaintData::from_bytes(&version, &path).unwrap_err()).contains("version 99"));
}

#[test]
fn threads_are_numbered_across_the_swatch_from_its_edges() {
    let (scene, _) = scene(SCENE);
    let cells = cells(&scene);
    // The default twill: 0.035 cm spacing over a 0.5 cm swatch: 14 or 15 threads inside.
    for set in [&cells.warp, &cells.weft] {
        assert!((14..=15).contains(&set.inside), "{} threads inside", set.inside);
        assert!((15..=16).contains(&set.sections), "{} sections", set.sections);
    }
    // A ray straight down at the crossing of warp end j and weft pick i (centres at
    // (k + 0.5) 0.035 cm) hits whichever lies on top there. Warp end 0 is the first whose
    // centre is inside the swatch's edge at -0.25 cm (k = -7); section 0 holds that edge, and
    // sections are centred on the crossings (k = -8 holds it).
    let fibers = &scene.path_scene.fibers;
    let mut seen = [0, 0];
    for j in -7..7 {
        for i in -7..7 {
            let (x, y) = ((f64::from(j) + 0.5) * 0.035, (f64::from(i) + 0.5) * 0.035);
            let down = glam::Vec3::NEG_Z;
            let Some(hit) = fibers.closest_hit(glam::Vec3::new(x as f32, y as f32, 1.0), down, 10.0, None)
            else {
                continue;
            };
            let (warp, thread, section) = cells.thread_of(cells.cell_of(&hit)).expect("woven threads");
            let (across, along) = if warp { (j, i) } else { (i, j) };
            assert_eq!(
                (thread, section),
                (i64::from(across + 7), (along + 8) as u32),
                "warp {warp}, crossing ({j}, {i})"
            );
            seen[usize::from(warp)] += 1;
        }
    }
    assert!(seen[0] > 40 && seen[1] > 40, "hits on weft and warp: {seen:?}");
}

#[test]
fn pixels_pick_the_cell_their_eye_ray_meets_and_a_cancelled_precompute_stops() {
    let (scene, camera) = scene(SCENE);
    let cells = cells(&scene);
    // Pixel centres' eye rays: the swatch fills the image, so most meet a fiber of a woven
    // thread (the rest look through the gaps between yarns at the ground).
    let mut on_cloth = 0;
    for y in 0..camera.height() {
        for x in 0..camera.width() {
            if let Some(cell) = cell_at(&scene.path_scene, &cells, &camera, x as f64 + 0.5, y as f64 + 0.5) {
                assert!(cells.thread_of(cell).is_some(), "pixel ({x}, {y}): a woven thread's cell");
                on_cloth += 1;
            }
        }
    }
    assert!(on_cloth > camera.width() * camera.height() / 2, "{on_cloth} pixel centres on the cloth");
    let far_up = Camera::new(
        glam::DVec3::new(0.0, 0.0, 5.0),
        glam::DVec3::new(0.0, 0.0, 10.0),
        glam::DVec3::Y,
        crate::pathtrace::camera::Projection::Perspective { fov_y_deg: 10.0 },
        8,
        8,
    )
    .unwrap();
    assert_eq!(cell_at(&scene.path_scene, &cells, &far_up, 4.0, 4.0), None, "looking away from the cloth");

    let cancel = AtomicBool::new(true);
    let s = settings(4, 1);
    let outcome = precompute_cancellable(&scene.path_scene, cells, &camera, &s, &|_| {}, &cancel);
    assert!(matches!(outcome, Err(PaintError::Cancelled)), "a set flag cancels");
}

#[test]
fn a_painting_written_from_its_colours_reads_back_exactly() {
    let (scene, _) = scene(SCENE);
    let cells = cells(&scene);
    let scene_colours = scene_colours(&scene.path_scene, &cells);
    let mut colours = scene_colours.clone();
    let (red, navy) = (Rgb::new(0.7, 0.1, 0.05), Rgb::new(0.05, 0.07, 0.3));
    let paint = |colours: &mut Vec<Rgb>, warp: bool, thread: i64, sections: std::ops::Range<u32>, c: Rgb| {
        for cell in cells.thread_cells(warp, thread, sections).expect("a thread of the swatch") {
            colours[cell as usize] = c;
        }
    };
    // Every 97th cell its own shade, then threads over them, and one cell back at the scene's
    // colour.
    for cell in (0..cells.count()).step_by(97) {
        colours[cell] = Rgb::splat(0.2 + 0.6 * (cell as f64 / cells.count() as f64));
    }
    let sections = cells.warp.sections;
    paint(&mut colours, true, 3, 0..sections, red); // a whole warp end
    paint(&mut colours, true, 4, 0..sections, red);
    paint(&mut colours, false, 2, 0..cells.weft.sections, navy); // a whole weft pick
    paint(&mut colours, true, 7, 2..5, navy); // a part of one
    paint(&mut colours, true, -1, 0..sections, red); // a copy beyond the left edge
    let first_red = cells.thread_cells(true, 3, 0..1).unwrap()[0] as usize;
    colours[first_red] = scene_colours[first_red];

    let painting = Painting::from_colours(&cells, &colours, &scene_colours);
    let text = toml::to_string(&painting).expect("a painting writes as TOML");
    let read = Painting::parse(&text, Path::new("saved.toml")).expect("and reads back");
    let again = read.colours(&cells, &scene_colours, Path::new("saved.toml")).unwrap();
    assert!(again == colours, "the painting reads back cell for cell:\n{text}");
    assert!(text.contains("warp = \"4\""), "a whole warp end is written as a thread:\n{text}");
    assert!(text.contains("sections = \"2-4\""), "a part of one with its sections:\n{text}");
}

#[test]
fn bad_strokes_are_refused_naming_the_stroke_the_value_and_the_range() {
    let (scene, _) = scene(SCENE);
    let cells = cells(&scene);
    let scene_colours = scene_colours(&scene.path_scene, &cells);
    let count = cells.count();
    let refused = |text: &str| {
        let path = Path::new("bad.toml");
        match Painting::parse(text, path) {
            Err(e) => e.to_string(),
            Ok(p) => p.colours(&cells, &scene_colours, path).unwrap_err().to_string(),
        }
    };
    let outside = format!("outside 0-{}", count - 1);
    for (text, needles) in [
        (
            format!("[[stroke]]\ncolour = [1, 0, 0]\ncells = \"0-3, {count}\"\n"),
            vec!["bad.toml", "[[stroke]] 1", "cells", outside.as_str()],
        ),
        (
            "[[stroke]]\ncolour = [1, 0, 0]\ncells = \"2\"\nwarp = \"1\"\n".into(),
            vec!["[[stroke]] 1", "by number"],
        ),
        (
            "[[stroke]]\ncolour = [1, 0, 0]\nall = true\ncells = \"2\"\n".into(),
            vec!["`all` paints every cell"],
        ),
        ("[[stroke]]\ncolour = [1.5, 0, 0]\ncells = \"2\"\n".into(), vec!["colour", "[0, 1]"]),
        ("[[stroke]]\ncolour = [1, 0, 0]\n".into(), vec!["`cells`"]),
    ] {
        let message = refused(&text);
        for needle in needles {
            assert!(message.contains(needle), "{needle:?} missing in: {message}");
        }
    }
}
