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

fn relative_l2(a: &Image, b: &Image) -> f64 {
    let (mut d, mut n) = (0.0, 0.0);
    for (x, y) in a.pixels.iter().zip(&b.pixels) {
        d += (*x - *y).length_squared();
        n += y.length_squared();
    }
    (d / n).sqrt()
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
        let error = relative_l2(&painted, &exact);
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
