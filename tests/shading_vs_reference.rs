//! The CPU version of the paper's method (`shading::render_flat`, from a draft bake) against
//! the reference path tracer, on the default scene at 48 × 48, one light at a time:
//! single scattering against `Component::Single`, multiple against `Component::Multiple`.
//!
//! The method approximates (16 × 16 visibility images compressed to 8 PCA components, 16
//! sum-of-SG lobes, IIRTF cells 3 mean free paths across and 0.5 deep with 96 paths each, SH
//! order 2), so the images are not expected to agree within noise. Each comparison prints the
//! relative error of the image mean and the per-pixel RMSE (relative to the reference mean)
//! and holds both to one-sided bands around what was measured (`twill_tests::check_band`: a
//! regression fails, an improvement prints a notice). NaN or Inf anywhere fails. Ignored tests
//! break the differences down (`--ignored --nocapture`; `twill accuracy budget` does it for
//! any scene).

use std::sync::OnceLock;

use twill_precompute::bake::Cancel;
use twill_precompute::bake::pipeline::{BakeInputs, Baked, bake};
use twill_precompute::bake::settings::Quality;
use twill_precompute::image::{Comparison, Estimate, Film, compare};
use twill_precompute::pathtrace::{Component, RenderSettings, render};
use twill_precompute::scene::{LightSection, Scene, SceneFile, camera_from};
use twill_precompute::shading::budget::Budget;
use twill_precompute::shading::{MethodOptions, render_flat, render_flat_with};

const SIZE: usize = 48;
/// Samples per pixel of the reference path tracer and of the CPU method.
const REFERENCE_SPP: u32 = 64;
const METHOD_SPP: u32 = 16;

/// The default scene with only `light`, at `SIZE` × `SIZE`.
fn scene_with(light: LightSection) -> Scene {
    let mut file = SceneFile::default_scene();
    file.lights = vec![light];
    file.render.width = SIZE;
    file.render.height = SIZE;
    file.build().expect("the default scene builds")
}

/// A draft bake of the default scene's fabric (the same for every light), made once.
fn baked() -> &'static Baked {
    static BAKED: OnceLock<Baked> = OnceLock::new();
    BAKED.get_or_init(|| {
        let scene = scene_with(directional());
        let inputs = BakeInputs {
            exemplar: &scene.exemplar,
            materials: &scene.material_descs,
            settings: Quality::Draft.settings(),
        };
        bake(&inputs, None, &Cancel::new(), &|_, _| {}).expect("draft bake").baked
    })
}

/// The default scene's key light: low, from the side.
fn directional() -> LightSection {
    LightSection::Directional { direction: [-0.6, 0.35, 0.5], irradiance: [3.3, 3.15, 2.85] }
}

/// The default scene's fill light, at sharpness `sharpness`.
fn sg(sharpness: f64) -> LightSection {
    LightSection::Sg { axis: [0.3, -0.6, 1.0], sharpness, intensity: [1.6, 1.7, 1.8] }
}

fn reference(scene: &Scene, component: Component) -> Film {
    let camera = camera_from(&scene.camera, SIZE, SIZE).expect("camera");
    let settings =
        RenderSettings { spp: REFERENCE_SPP, max_depth: scene.render.max_depth, component, seed: 11 };
    render(&scene.path_scene, &camera, &settings, &|_| {})
}

/// Renders one component both ways, prints the comparison and returns it.
fn compare_component(label: &str, scene: &Scene, component: Component) -> Comparison {
    let method = render_flat(scene, baked(), component, METHOD_SPP, 5).expect("render_flat");
    let reference = reference(scene, component);
    let (m_mean, m_var) = (method.mean(), method.variance_of_mean());
    let (r_mean, r_var) = (reference.mean(), reference.variance_of_mean());
    assert!(m_mean.is_finite() && m_var.is_finite(), "{label}: the method's image is not finite");
    assert!(r_mean.is_finite() && r_var.is_finite(), "{label}: the reference is not finite");
    let c = compare(
        Estimate { mean: &m_mean, variance: Some(&m_var) },
        Estimate { mean: &r_mean, variance: Some(&r_var) },
    );
    let reference_level = r_mean.mean().element_sum() / 3.0;
    eprintln!(
        "{label:<28} mean: method {:.5} reference {:.5} → relative error {:+.4} (± {:.4} noise); \
         per-pixel RMSE {:.5} = {:.3} of the mean (noise alone {:.5})",
        m_mean.mean().element_sum() / 3.0,
        reference_level,
        c.relative_error_of_mean,
        c.relative_error_of_mean_std,
        c.rmse,
        c.rmse / reference_level,
        c.expected_noise_rmse,
    );
    assert!(reference_level > 0.0, "{label}: the reference is black");
    c
}

/// What one comparison measured (2026-11-24, draft bake: lit-side visibility, 32 SGs, 4ℓ × 0.5ℓ
/// cells of 96 paths, transfer interpolated between cells; with 16 SGs SG λ = 8 single was −11.3%): the relative error of the image mean and
/// the per-pixel RMSE over the reference mean.
struct Measured {
    mean: f64,
    pixel: f64,
}

/// Bands around the measurements: three standard errors of the mean's noise (about 1% here)
/// plus 1%; the per-pixel RMSE 5% of the mean. `twill accuracy budget` breaks the remaining
/// errors down (docs/BENCHMARKS.md, "Fidelity").
const MEAN_MARGIN: f64 = 0.01;
const PIXEL_MARGIN: f64 = 0.05;

fn check(label: &str, light: LightSection, component: Component, measured: &Measured) {
    let scene = scene_with(light);
    let c = compare_component(label, &scene, component);
    let reference_level = reference(&scene, component).mean().mean().element_sum() / 3.0;
    let margin = MEAN_MARGIN + 3.0 * c.relative_error_of_mean_std;
    let mean =
        twill_tests::check_band(&format!("{label}, mean"), c.relative_error_of_mean, measured.mean, margin);
    let pixel = twill_tests::check_band(
        &format!("{label}, per pixel"),
        c.rmse / reference_level,
        measured.pixel,
        PIXEL_MARGIN,
    );
    if let Err(e) = mean.and(pixel) {
        panic!("{e}");
    }
}

// Before this bake (paper visibility from the fiber axis, 4ℓ cubic cells, uniform light
// directions in the IIRTF): single −14..−17%, multiple −26..−30%.
//
// Every band re-measured 2026-11-28 (twenty-second session), since the draft preset's cells are
// 3ℓ across instead of 4ℓ (over the 100 configurations of `twill accuracy` at draft, 11.3% →
// 9.0% on the GPU). Multiple scattering on this front-lit view: directional +3.3% → +3.8% (per
// pixel 0.887 → 0.801), SG λ = 8 −9.5% → −11.4%, SG λ = 300 −12.1% → −14.2%; the per-pixel
// figures 0.629 → 0.645 and 0.715 → 0.735. Single scattering had improved since its bands were
// set, through earlier sessions' visibility changes that left it inside them (directional
// −6.4% → −1.0%, SG λ = 8 −8.9% → −7.4%, SG λ = 300 −11.1% → −10.0%): the bands now follow.

#[test]
fn directional_light_single_scattering() {
    check("directional, single", directional(), Component::Single, &Measured { mean: -0.0101, pixel: 0.936 });
}

#[test]
fn directional_light_multiple_scattering() {
    check(
        "directional, multiple",
        directional(),
        Component::Multiple,
        // Exposed IIRTF path starts (2026-11-26): mean +3.6% → +3.3%, per pixel 0.823 → 0.887
        // (the transfer of the points an eye sees varies more from cell to cell).
        &Measured { mean: 0.0381, pixel: 0.801 },
    );
}

#[test]
fn soft_sg_light_single_scattering() {
    check("SG λ = 8, single", sg(8.0), Component::Single, &Measured { mean: -0.0738, pixel: 0.633 });
}

// Multiple scattering under SG lights moved with the exposed IIRTF path starts (2026-11-26):
// λ = 8 −15.1% → −9.5%, λ = 300 −18.1% → −12.1% (per pixel 0.626 → 0.629, 0.699 → 0.715).
#[test]
fn soft_sg_light_multiple_scattering() {
    check("SG λ = 8, multiple", sg(8.0), Component::Multiple, &Measured { mean: -0.1143, pixel: 0.645 });
}

#[test]
fn sharp_sg_light_single_scattering() {
    check("SG λ = 300, single", sg(300.0), Component::Single, &Measured { mean: -0.1001, pixel: 0.777 });
}

#[test]
fn sharp_sg_light_multiple_scattering() {
    check("SG λ = 300, multiple", sg(300.0), Component::Multiple, &Measured { mean: -0.1420, pixel: 0.735 });
}

// ---------------------------------------------------------------------------------------------
// Diagnostics (ignored): where the differences come from.

use glam::DVec3;
use rand::Rng;
use twill_precompute::Rgb;
use twill_precompute::bake::pca::compress;
use twill_precompute::bake::settings::BakeSettings;
use twill_precompute::bake::ssdf::ssdf_all;
use twill_precompute::bake::svf::render_exemplar;
use twill_precompute::image::Image;
use twill_precompute::pathtrace::integrator::pixel_rng;
use twill_precompute::raycast::Hit;
use twill_precompute::shading::{SegmentShading, fiber_eval_cos, ssdf_lookup, ssdf_step_visibility};

/// Mean image of `shade(hit, ωo)` over the scene's primary hits (black where rays miss).
fn render_with(scene: &Scene, spp: u32, shade: impl Fn(&Hit, DVec3) -> Rgb) -> Image {
    let camera = camera_from(&scene.camera, SIZE, SIZE).expect("camera");
    let mut image = Image::new(SIZE, SIZE);
    for y in 0..SIZE {
        for x in 0..SIZE {
            let mut rng = pixel_rng(5, (y * SIZE + x) as u64);
            let mut sum = Rgb::ZERO;
            for _ in 0..spp {
                let (origin, dir) =
                    camera.ray(x as f64 + rng.random::<f64>(), y as f64 + rng.random::<f64>());
                let hit =
                    scene.path_scene.fibers.closest_hit(origin.as_vec3(), dir.as_vec3(), f32::INFINITY, None);
                sum += hit.map_or(Rgb::ZERO, |h| shade(&h, -dir));
            }
            image.set(x, y, sum / f64::from(spp));
        }
    }
    image
}

fn relative_error_of_mean(test: &Image, reference: &Image) -> f64 {
    test.mean().element_sum() / reference.mean().element_sum() - 1.0
}

/// Whether the directional light reaches a hit, by one of the visibility approximations.
type VisibilityTest<'a> = dyn Fn(&Hit) -> bool + 'a;

#[test]
#[ignore = "diagnostic: prints where the single-scattering error of a directional light comes from"]
fn diagnose_directional_single_scattering_visibility() {
    let scene = scene_with(directional());
    let baked = baked();
    let reference = reference(&scene, Component::Single).mean();
    let to_light = DVec3::new(-0.6, 0.35, 0.5).normalize();
    let irradiance = Rgb::new(3.3, 3.15, 2.85);
    let fibers = &scene.path_scene.fibers;
    let segments = fibers.segments();
    let n = baked.settings.svf_resolution;
    let images = render_exemplar(&scene.exemplar, n, 1, &Cancel::new(), &|_| {}).unwrap();
    let ssdf = ssdf_all(&images, &Cancel::new()).unwrap();
    let exact_ssdf = compress(&ssdf, n * n, n * n, 1, &Cancel::new()).unwrap();
    let variants: Vec<(&str, Box<VisibilityTest>)> = vec![
        (
            "shadow ray from the hit point",
            Box::new(|h: &Hit| {
                !fibers.any_hit_f64(fibers.world_position_f64(h), to_light, f64::INFINITY, Some(h.fiber))
            }),
        ),
        (
            "shadow ray from the segment midpoint",
            Box::new(|h: &Hit| {
                let mid = segments[h.segment as usize].midpoint().as_dvec3() + fibers.tile_offset(h.tile);
                !fibers.any_hit_f64(mid, to_light, f64::INFINITY, Some(h.fiber))
            }),
        ),
        (
            "shadow ray from midpoint + r toward light",
            Box::new(|h: &Hit| {
                let seg = &segments[h.segment as usize];
                let t = seg.tangent().as_dvec3();
                let across = (to_light - t * t.dot(to_light)).normalize_or_zero();
                let mid =
                    seg.midpoint().as_dvec3() + fibers.tile_offset(h.tile) + across * f64::from(seg.radius);
                !fibers.any_hit_f64(mid, to_light, f64::INFINITY, Some(h.fiber))
            }),
        ),
        (
            "shadow ray from axis under hit + r toward light",
            Box::new(|h: &Hit| {
                let seg = &segments[h.segment as usize];
                let t = seg.tangent().as_dvec3();
                let across = (to_light - t * t.dot(to_light)).normalize_or_zero();
                let s = f64::from(h.segment_param.clamp(0.0, 1.0));
                let axis = seg.a.as_dvec3().lerp(seg.b.as_dvec3(), s) + fibers.tile_offset(h.tile);
                !fibers.any_hit_f64(
                    axis + across * f64::from(seg.radius),
                    to_light,
                    f64::INFINITY,
                    Some(h.fiber),
                )
            }),
        ),
        ("visibility image, nearest pixel", Box::new(|h: &Hit| images.lookup(h.segment as usize, to_light))),
        (
            "exact SSDF, bilinear sign",
            Box::new(|h: &Hit| {
                ssdf_step_visibility(ssdf_lookup(&exact_ssdf, h.segment as usize, to_light)) > 0.0
            }),
        ),
        (
            "PCA SSDF (the method)",
            Box::new(|h: &Hit| {
                ssdf_step_visibility(ssdf_lookup(&baked.visibility.ssdf, h.segment as usize, to_light)) > 0.0
            }),
        ),
    ];
    for (name, visible) in &variants {
        let image = render_with(&scene, METHOD_SPP, |hit: &Hit, wo: DVec3| -> Rgb {
            let seg = SegmentShading::of(baked, hit.segment).unwrap().unwrap();
            if !visible(hit) {
                return Rgb::ZERO;
            }
            fiber_eval_cos(&seg.fiber, &baked.gn, seg.tangent, to_light, wo) * irradiance
        });
        eprintln!(
            "directional single, {name:<38}: relative error of the mean {:+.4}",
            relative_error_of_mean(&image, &reference)
        );
    }
}

#[test]
#[ignore = "diagnostic: prints the six comparisons for bakes of higher quality (slow)"]
fn diagnose_bake_quality() {
    let base = scene_with(directional());
    let draft = Quality::Draft.settings();
    let variants = [
        ("draft", draft),
        ("draft, cubic 4ℓ cells", BakeSettings { cell_depth_mfp: 4.0, ..draft }),
        ("draft, 0.5ℓ deep", BakeSettings { cell_depth_mfp: 0.5, ..draft }),
        ("draft, 128 paths", BakeSettings { iirtf_paths_per_cell: 128, ..draft }),
        ("interactive", Quality::Interactive.settings()),
    ];
    for (name, settings) in variants {
        let inputs = BakeInputs { exemplar: &base.exemplar, materials: &base.material_descs, settings };
        let baked = bake(&inputs, None, &Cancel::new(), &|_, _| {}).unwrap().baked;
        for (label, light) in
            [("directional", directional()), ("SG λ = 8", sg(8.0)), ("SG λ = 300", sg(300.0))]
        {
            let scene = scene_with(light);
            for component in [Component::Single, Component::Multiple] {
                let reference = reference(&scene, component).mean();
                for interpolate_transfer in [false, true] {
                    if component == Component::Single && interpolate_transfer {
                        continue;
                    }
                    let options = MethodOptions { interpolate_transfer, ..MethodOptions::default() };
                    let method =
                        render_flat_with(&scene, &baked, component, METHOD_SPP, 5, options).unwrap().mean();
                    eprintln!(
                        "{name:<24} {label:<12} {component:?} {}: relative error of the mean {:+.4}",
                        if interpolate_transfer { "interpolated" } else { "per cell" },
                        relative_error_of_mean(&method, &reference)
                    );
                }
            }
        }
    }
}

#[test]
#[ignore = "diagnostic: multiple-scattering error of draft bakes over seeds and paths per cell (slow)"]
fn diagnose_transfer_noise_and_bias() {
    let scene = scene_with(directional());
    let reference = reference(&scene, Component::Multiple).mean();
    let draft = Quality::Draft.settings();
    let variants = [
        ("draft, 96 paths", BakeSettings { iirtf_paths_per_cell: 96, ..draft }),
        ("draft, 256 paths", BakeSettings { iirtf_paths_per_cell: 256, ..draft }),
        ("draft, 1024 paths", BakeSettings { iirtf_paths_per_cell: 1024, ..draft }),
        ("512 paths, 2ℓ across", BakeSettings { iirtf_paths_per_cell: 512, cell_size_mfp: 2.0, ..draft }),
        ("512 paths, 0.5ℓ deep", BakeSettings { iirtf_paths_per_cell: 512, cell_depth_mfp: 0.5, ..draft }),
        ("512 paths, SH order 4", BakeSettings { iirtf_paths_per_cell: 512, sh_order: 4, ..draft }),
    ];
    let filter = std::env::var("TWILL_DIAGNOSE_VARIANTS").unwrap_or_default();
    for (name, variant) in variants {
        if !filter.is_empty() && !filter.split(',').any(|f| name.contains(f)) {
            continue;
        }
        let mut errors = Vec::new();
        for seed in 1..=4 {
            let settings = BakeSettings { seed, ..variant };
            let inputs = BakeInputs { exemplar: &scene.exemplar, materials: &scene.material_descs, settings };
            let baked = bake(&inputs, None, &Cancel::new(), &|_, _| {}).unwrap().baked;
            let method = render_flat(&scene, &baked, Component::Multiple, METHOD_SPP, 5).unwrap().mean();
            errors.push(relative_error_of_mean(&method, &reference));
        }
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        eprintln!("{name:<24}: relative errors {errors:+.4?}, mean {mean:+.4}");
    }
}

#[test]
#[ignore = "diagnostic: prints where the single-scattering error of SG lights comes from"]
fn diagnose_sg_single_scattering() {
    use twill_precompute::pathtrace::Light;
    use twill_precompute::shading::{erf_soft_visibility, gamma, sum_of_sg_path};
    let baked = baked();
    for lambda in [8.0, 300.0] {
        let scene = scene_with(sg(lambda));
        let reference = reference(&scene, Component::Single).mean();
        let fibers = &scene.path_scene.fibers;
        let segments = fibers.segments();
        let light = scene.path_scene.lights[0];
        let Light::Sg { axis, sharpness, intensity } = light else { unreachable!() };
        let mass = twill_precompute::sg::sg_mass(sharpness);
        let lit_side = |h: &Hit, dir: DVec3| -> DVec3 {
            let seg = &segments[h.segment as usize];
            let t = seg.tangent().as_dvec3();
            let across = (dir - t * t.dot(dir)).normalize_or_zero();
            seg.midpoint().as_dvec3() + fibers.tile_offset(h.tile) + across * f64::from(seg.radius)
        };
        // Monte Carlo over the light: `shadow` says whether a sampled direction is blocked.
        let monte_carlo = |shadow: &dyn Fn(&Hit, DVec3) -> bool| {
            let counter = std::sync::atomic::AtomicU64::new(0);
            render_with(&scene, METHOD_SPP, |hit: &Hit, wo: DVec3| -> Rgb {
                let k = counter.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let mut rng = pixel_rng(91, k);
                let seg = SegmentShading::of(baked, hit.segment).unwrap().unwrap();
                let mut sum = Rgb::ZERO;
                for _ in 0..16 {
                    let s = light.sample([rng.random(), rng.random()]);
                    if !shadow(hit, s.to_light) {
                        sum += fiber_eval_cos(&seg.fiber, &baked.gn, seg.tangent, s.to_light, wo) * s.weight;
                    }
                }
                sum / 16.0
            })
        };
        let report = |name: &str, image: &Image| {
            eprintln!(
                "SG λ = {lambda:<5} single, {name:<44}: relative error of the mean {:+.4}",
                relative_error_of_mean(image, &reference)
            );
        };
        report(
            "MC, shadow rays from the hit point",
            &monte_carlo(&|h, d| {
                fibers.any_hit_f64(fibers.world_position_f64(h), d, f64::INFINITY, Some(h.fiber))
            }),
        );
        report(
            "MC, shadow rays from the lit side",
            &monte_carlo(&|h, d| fibers.any_hit_f64(lit_side(h, d), d, f64::INFINITY, Some(h.fiber))),
        );
        report(
            "MC, shadow rays from the fiber top",
            &monte_carlo(&|h, d| fibers.any_hit_f64(lit_side(h, DVec3::Z), d, f64::INFINITY, Some(h.fiber))),
        );
        report(
            "MC, shadow rays from between lit side and top",
            &monte_carlo(&|h, d| {
                let seg = &segments[h.segment as usize];
                let t = seg.tangent().as_dvec3();
                let across = |w: DVec3| (w - t * t.dot(w)).normalize_or_zero();
                let side = (across(d) + across(DVec3::Z)).normalize_or_zero();
                let origin =
                    seg.midpoint().as_dvec3() + fibers.tile_offset(h.tile) + side * f64::from(seg.radius);
                fibers.any_hit_f64(origin, d, f64::INFINITY, Some(h.fiber))
            }),
        );
        let unshadowed_mc = monte_carlo(&|_, _| false);
        let unshadowed_gamma = render_with(&scene, METHOD_SPP, |hit: &Hit, wo: DVec3| -> Rgb {
            let seg = SegmentShading::of(baked, hit.segment).unwrap().unwrap();
            gamma(&seg.fiber, &baked.gn, seg.tangent, axis, sharpness, wo) * intensity / mass
        });
        eprintln!(
            "SG λ = {lambda:<5} single, Γ against MC without shadows: {:+.4}",
            relative_error_of_mean(&unshadowed_gamma, &unshadowed_mc)
        );
        let vis = &baked.visibility;
        report(
            "erf-SSDF path alone",
            &render_with(&scene, METHOD_SPP, |hit: &Hit, wo: DVec3| -> Rgb {
                let seg = SegmentShading::of(baked, hit.segment).unwrap().unwrap();
                let d = ssdf_lookup(&vis.ssdf, hit.segment as usize, axis);
                gamma(&seg.fiber, &baked.gn, seg.tangent, axis, sharpness, wo)
                    * (erf_soft_visibility(d, sharpness) / mass)
                    * intensity
            }),
        );
        report(
            "sum-of-SG path alone",
            &render_with(&scene, METHOD_SPP, |hit: &Hit, wo: DVec3| -> Rgb {
                let seg = SegmentShading::of(baked, hit.segment).unwrap().unwrap();
                let sos = &vis.sum_of_sg;
                let k = hit.segment as usize;
                sum_of_sg_path(
                    &seg.fiber,
                    &baked.gn,
                    seg.tangent,
                    wo,
                    &sos.axes(k),
                    sos.weights(k),
                    sos.sharpness,
                    axis,
                    sharpness,
                ) * intensity
                    / mass
            }),
        );
    }
}

/// The error budget's ladder (`shading::budget`, `twill accuracy budget`) on the default scene
/// at 32 × 32: its exact rungs must equal the path tracer within noise (this checks the
/// decomposition itself: single + multiple = all light, and the light and fiber-scattering
/// conventions of both), every rung is finite, and the raised visibility origin (the centroid
/// of the fiber's upper half) keeps its measured gain over the paper's fiber-axis origin.
#[test]
fn error_budget_exact_rungs_equal_the_path_tracer() {
    use twill_precompute::shading::budget::{BudgetSettings, error_budget};
    let mut file = SceneFile::default_scene();
    (file.render.width, file.render.height) = (32, 32);
    let scene = file.build().expect("the default scene builds");
    let settings =
        BudgetSettings { spp: 16, reference_spp: 64, light_samples: 8, seed: 3, split_transfer: false };
    let budget = error_budget(&scene, baked(), &settings, &|_| {}).expect("budget");
    eprintln!("{}", budget.markdown());
    assert_eq!(budget.rungs.len(), 19);
    // The cotton keeps a few lobes (measured 2026-12-07: 5.1% of the light, the matrices 90.7%).
    let (lobes, _) = assert_lobes_and_matrices_add_up(&budget);
    assert!(lobes > 0.0, "the cotton's lobes carry no light");
    // The clamp at zero on the same samples: on each sample (4″) lifts the mean at least as
    // much as on each pixel's mean (4, the method), which lifts it at least as much as no
    // clamp (4′).
    let multiple = |prefix: &str| {
        budget.rung(Component::Multiple, prefix).map(|r| r.relative_error_of_mean).expect("a multiple rung")
    };
    let (per_sample, per_pixel, none) = (multiple("4'' "), multiple("4 "), multiple("4' "));
    assert!(
        per_sample >= per_pixel - 1e-12 && per_pixel >= none - 1e-12,
        "clamps on each sample {per_sample:+.5}, each pixel {per_pixel:+.5}, none {none:+.5}"
    );
    for rung in &budget.rungs {
        assert!(
            rung.relative_error_of_mean.is_finite() && rung.relative_pixel_rmse.is_finite(),
            "{}: not finite",
            rung.name
        );
    }
    for component in [Component::Single, Component::Multiple] {
        assert_exact_rung_matches_the_path_tracer(&budget, component);
    }
    // Rung 1′ shades rung 1's incident light through the method's SH machinery (the light's
    // projection, the rotation into the ωo frame, the C_S table) instead of the exact fiber
    // scattering function. On the cotton the truncation to order 2 costs less than the noise
    // (measured −0.8% ± 2.2% against −0.5% ± 1.7%), so a wrong convention anywhere in that
    // machinery shows here as a difference beyond noise.
    assert_multiple_rungs_agree(&budget, "1' ", "1 ", "incident light in SH through C_S");
    // Rung 2e takes rung 2's light at the points the bake starts its paths from (exposed
    // starts, moved from the sampler's copy of the fabric to the hit's). On this view of the
    // cotton they stand for the hits themselves (measured −0.1% ± 1.8% against rung 1's
    // −0.5% ± 1.7%); points put in the wrong place (another tile, another segment) see other
    // light, beyond this band.
    assert_multiple_rungs_agree(&budget, "2e ", "1 ", "indirect light at exposed starts");
    // A rung added from outside (as `twill accuracy budget` adds the GPU's frames) is measured
    // like the others: the method's own image, without its variance, lands on rung 5's error.
    let mut budget = budget;
    let method =
        render_flat(&scene, baked(), Component::Single, settings.spp, settings.seed).expect("method");
    budget.add_rung(Component::Single, "the method again".into(), &method.mean(), 0.0);
    let again = budget.rung(Component::Single, "the method again").expect("added rung");
    let fifth = budget.rung(Component::Single, "5 ").expect("method rung");
    assert!((again.relative_error_of_mean - fifth.relative_error_of_mean).abs() < 1e-12);
    assert_eq!(
        budget.rungs.iter().position(|r| r.name == "the method again"),
        Some(7),
        "after the single rungs"
    );
    // Interpolating transfer between cells (no block edges) must not lose per-pixel accuracy
    // against the paper's constant per cell (measured at 32 x 32: 58.4% vs 64.1% of the mean).
    let per_cell = budget.rung(Component::Multiple, "3 ").expect("per-cell rung");
    let interpolated = budget.rung(Component::Multiple, "4 ").expect("interpolated rung");
    assert!(
        interpolated.relative_pixel_rmse <= per_cell.relative_pixel_rmse,
        "per-pixel RMSE: interpolated {:.3} vs per cell {:.3}",
        interpolated.relative_pixel_rmse,
        per_cell.relative_pixel_rmse
    );
    // Clamping at zero only ever raises a sample: rung 4 is never below its unclamped twin.
    let unclamped = budget.rung(Component::Multiple, "4'").expect("unclamped rung");
    assert!(
        unclamped.relative_error_of_mean <= interpolated.relative_error_of_mean + 1e-12,
        "unclamped {:+.4} vs clamped {:+.4}",
        unclamped.relative_error_of_mean,
        interpolated.relative_error_of_mean
    );
    let midpoint = budget.rung(Component::Single, "2 ").expect("midpoint rung");
    let raised = budget.rung(Component::Single, "3 ").expect("raised-origin rung");
    assert!(
        raised.relative_error_of_mean.abs() + 0.05 < midpoint.relative_error_of_mean.abs(),
        "raised {:+.4} vs midpoint {:+.4}",
        raised.relative_error_of_mean,
        midpoint.relative_error_of_mean
    );
}

/// Rungs 4f and 4g of `budget` shade 4′'s samples from the fiber lobes alone and the SH
/// matrices alone: as shares of the reference (1 + relative error) they add up to 4′'s. Returns
/// the two shares.
fn assert_lobes_and_matrices_add_up(budget: &Budget) -> (f64, f64) {
    let share = |prefix: &str| {
        1.0 + budget.rung(Component::Multiple, prefix).expect("a multiple rung").relative_error_of_mean
    };
    let (lobes, matrices, unclamped) = (share("4f "), share("4g "), share("4' "));
    assert!(
        (lobes + matrices - unclamped).abs() < 1e-9,
        "lobes {lobes:.6} + matrices {matrices:.6} against the method unclamped {unclamped:.6}"
    );
    (lobes, matrices)
}

/// Multiple-scattering rungs `name` and `exact` (name prefixes) of `budget` agree within four
/// standard errors of their difference; `what` names the first in the failure.
fn assert_multiple_rungs_agree(budget: &Budget, name: &str, exact: &str, what: &str) {
    let rung = |prefix: &str| budget.rung(Component::Multiple, prefix).expect("a multiple-scattering rung");
    let (test, exact) = (rung(name), rung(exact));
    let noise = exact.relative_error_std.hypot(test.relative_error_std);
    assert!(
        (test.relative_error_of_mean - exact.relative_error_of_mean).abs() < 4.0 * noise,
        "{what} {:+.4} against exact {:+.4} (noise {noise:.4})",
        test.relative_error_of_mean,
        exact.relative_error_of_mean
    );
}

/// A budget's exact rung of `component` (its first) equals the path tracer within four of its
/// standard errors plus 0.5%: the decomposition and the light and scattering conventions hold.
fn assert_exact_rung_matches_the_path_tracer(budget: &Budget, component: Component) {
    let exact = budget.rungs.iter().find(|r| r.component == component).expect("an exact rung");
    assert!(
        exact.relative_error_of_mean.abs() < 4.0 * exact.relative_error_std + 0.005,
        "{component:?}: the exact rung differs from the path tracer by {:+.4} (noise {:.4})",
        exact.relative_error_of_mean,
        exact.relative_error_std
    );
}

/// A 2 cm flat swatch of the gabardine on its ground, seen orthographically (0.4 cm high, 24 ×
/// 24) from `eye` toward the origin under one SG light of unit intensity, and its interactive
/// bake: the scenes of the budget's regression tests, named `name` in their errors.
fn gabardine_swatch_baked(name: &str, eye: [f64; 3], axis: [f64; 3], sharpness: f64) -> (Scene, Baked) {
    let text = format!(
        "[fabric]\npreset = \"gabardine_twill\"\n[swatch]\nsize_cm = [2.0, 2.0]\nground = true\n\
         [camera]\nprojection = \"orthographic\"\neye = {eye:?}\ntarget = [0.0, 0.0, 0.0]\nup = [0, 0, 1]\n\
         height_cm = 0.4\n[[lights]]\ntype = \"sg\"\naxis = {axis:?}\nsharpness = {sharpness:?}\n\
         intensity = [1.0, 1.0, 1.0]\n[render]\nwidth = 24\nheight = 24\nspp = 16\nmax_depth = 64\nseed = 1\n"
    );
    let scene = SceneFile::parse(&text, std::path::Path::new(name))
        .expect("the scene parses")
        .build()
        .expect("the scene builds");
    let inputs = scene.bake_inputs(Quality::Interactive.settings());
    let baked = bake(&inputs[0], None, &Cancel::new(), &|_, _| {}).expect("interactive bake").baked;
    (scene, baked)
}

/// The gabardine's forward chains (light transmitted fiber after fiber, peaked about the
/// light's direction) ring in SH matrices of order 4, so its cells hold them as fiber lobes
/// (`iirtf::forward_lobe_min_sharpness`, λ 3 at order 4). While they folded below λ 5 (until
/// 2026-11-27), a grazing front-lit view under a sharp SG light (configuration 31 of `twill
/// accuracy`: view 74°, λ 639 at 37°) had multiple scattering without its clamp at zero (the
/// budget's rung 4′) at −54% of the path tracer, −31% after the clamp; at λ 3, −20% and −16%
/// (32 × 32, 16 spp, references of 128 spp; docs/BENCHMARKS.md, "The gabardine's forward
/// chains"). Here at 24 × 24: an interactive bake of the gabardine, some of whose cells must
/// keep lobes (873 of 917; 484 at λ 5), the exact rung equal to the path tracer within noise,
/// and rungs 4 and 4′ held to one-sided bands around what was measured (−2.1% and −2.5% since
/// 2026-12-05, when the segments under lobe cells got transfers of their reflected light;
/// −15.9% and −20.8% before; at λ 5 this test measured −31.5% and −54.8% and failed).
#[test]
fn gabardine_forward_chains_keep_their_lobes_at_a_grazing_front_lit_view() {
    use twill_precompute::shading::budget::{BudgetSettings, error_budget};
    let (scene, baked) = gabardine_swatch_baked(
        "gabardine_grazing.toml",
        [-0.5546, 0.1544, 0.1692],
        [-0.6053, -0.0389, 0.7951],
        638.5,
    );
    let cells = &baked.transfer.iirtf.cells;
    let lobes = cells.iter().filter(|c| c.has_lobes()).count();
    let nonempty = cells.iter().filter(|c| c.paths > 0).count();
    eprintln!("gabardine, interactive: {lobes} of {nonempty} cells keep fiber lobes");
    assert!(lobes > 0, "no cell of the gabardine keeps its forward chains as lobes");
    let settings =
        BudgetSettings { spp: 16, reference_spp: 128, light_samples: 8, seed: 3, split_transfer: false };
    let budget = error_budget(&scene, &baked, &settings, &|_| {}).expect("budget");
    eprintln!("{}", budget.markdown());
    assert_exact_rung_matches_the_path_tracer(&budget, Component::Multiple);
    let multiple = |prefix: &str| budget.rung(Component::Multiple, prefix).expect("a multiple rung");
    // Here, under a sharp light at a grazing front-lit view, the segments' own matrices of
    // their reflected light carry most of the light and the lobes a quarter of it (measured
    // 2026-12-07: 75.1% and 22.0% of the reference).
    let (lobes, matrices) = assert_lobes_and_matrices_add_up(&budget);
    assert!(lobes > 0.1 && matrices > lobes, "lobes {lobes:.4} against matrices {matrices:.4}");
    let failures: Vec<String> = [
        ("rung 4, the method", multiple("4 ").relative_error_of_mean, MEASURED_4, 0.08),
        (
            "rung 4', without the clamp at zero",
            multiple("4' ").relative_error_of_mean,
            MEASURED_4_UNCLAMPED,
            0.08,
        ),
    ]
    .into_iter()
    .filter_map(|(label, value, measured, margin)| {
        eprintln!("gabardine, grazing front-lit, multiple scattering, {label}: {value:+.4}");
        twill_tests::check_band(label, value, measured, margin).err()
    })
    .collect();
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Rungs 4 and 4′ of [`gabardine_forward_chains_keep_their_lobes_at_a_grazing_front_lit_view`],
/// measured 2026-12-05.
const MEASURED_4: f64 = -0.021;
const MEASURED_4_UNCLAMPED: f64 = -0.025;

/// The sum of SGs stands each SG at the centroid of the visible directions it holds
/// (`bake::sum_of_sg`). While each stood at its Fibonacci axis (until 2026-11-27), an SG whose
/// cell straddled the horizon carried its visible mass below it, where a backlit eye near the
/// horizon sees the forward-scattered light come from: under a broad SG light low in the sky
/// (configuration 3 of `twill accuracy`: view 75°, λ 2 at 80° on the opposite side) the
/// method's single scattering (the budget's rung 5) was +18.7% of the path tracer on the
/// gabardine, with the visibility images themselves (rung 4) at +2.1%; at the centroids −1.9%
/// (32 × 32, references of 128 spp; docs/BENCHMARKS.md, "The sum of SGs at its visible
/// directions"). Here at 24 × 24: the exact rung equal to the path tracer within noise, and
/// rung 5 held to a one-sided band around what was measured (−2.2%; the Fibonacci axes
/// measure +18.4% on this scene, `twill accuracy budget` at 24 × 24 with 8 light samples, and
/// would fail).
#[test]
fn a_broad_sg_light_at_the_horizon_keeps_its_sum_of_sgs_on_the_visible_side() {
    use twill_precompute::shading::budget::{BudgetSettings, error_budget};
    let (scene, baked) = gabardine_swatch_baked(
        "gabardine_broad_sg_at_the_horizon.toml",
        [0.0, 0.5796, 0.1553],
        [-0.1710, -0.9698, 0.1736],
        2.0,
    );
    let settings =
        BudgetSettings { spp: 16, reference_spp: 128, light_samples: 8, seed: 3, split_transfer: false };
    let budget = error_budget(&scene, &baked, &settings, &|_| {}).expect("budget");
    eprintln!("{}", budget.markdown());
    assert_exact_rung_matches_the_path_tracer(&budget, Component::Single);
    let rung = budget.rung(Component::Single, "5 ").expect("the method's single-scattering rung");
    let value = rung.relative_error_of_mean;
    eprintln!("gabardine, broad SG light at the horizon, single scattering, rung 5: {value:+.4}");
    twill_tests::check_band("rung 5, the method", value, MEASURED_SINGLE_5, 0.06).unwrap();
}

/// Rung 5 of [`a_broad_sg_light_at_the_horizon_keeps_its_sum_of_sgs_on_the_visible_side`],
/// measured 2026-11-27.
const MEASURED_SINGLE_5: f64 = -0.0225;
