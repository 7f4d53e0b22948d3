//! Whole-path-tracer tests with known answers.
//!
//! - A Lambertian fiber under a directional light, seen orthographically: the mean radiance of
//!   the image has a closed form (single scattering, exact geometry, no approximation).
//! - A white furnace: Lambertian fibers of albedo 1 in a uniform environment of radiance 1 must
//!   look exactly 1 wherever a ray hits a fiber, however many times light bounces between them.
//! - Single + multiple scattering renders add up to the full render (within their noise).
//!
//! Every comparison is against the estimate's own measured noise (4 standard errors) plus a
//! stated small allowance; NaN or Inf anywhere fails.

use glam::DVec3;
use twill_precompute::Rgb;
use twill_precompute::fabric::presets::fabric_preset;
use twill_precompute::image::{Estimate, compare};
use twill_precompute::pathtrace::integrator::{pixel_rng, radiance};
use twill_precompute::pathtrace::{Camera, Component, Light, Projection, RenderSettings, render};
use twill_precompute::raycast::Extent;
use twill_tests::{lambert_cylinder_mean_radiance, lambert_scene, straight_fiber, tilted_from_z};

fn settings(spp: u32, component: Component) -> RenderSettings {
    RenderSettings { spp, max_depth: 100_000, component, seed: 7 }
}

#[test]
fn lambertian_fiber_under_a_directional_light_matches_the_closed_form() {
    let (radius, film_height, albedo, irradiance) = (0.1, 0.3, 0.8, 2.0);
    let exemplar = straight_fiber(radius as f32, 10.0);
    let camera = Camera::new(
        DVec3::new(0.0, 0.0, 5.0),
        DVec3::ZERO,
        DVec3::Y,
        Projection::Orthographic { height_cm: film_height },
        48,
        48,
    )
    .unwrap();
    for alpha in [0.0, 0.6, 1.2, std::f64::consts::FRAC_PI_2] {
        let light = Light::directional(tilted_from_z(alpha), Rgb::splat(irradiance)).unwrap();
        let scene = lambert_scene(&exemplar, Extent::Unbounded, albedo, vec![light]);
        let film = render(&scene, &camera, &settings(16, Component::All), &|_| {});
        let (mean, variance) = (film.mean(), film.variance_of_mean());
        assert!(mean.is_finite() && variance.is_finite());
        // The fiber covers 2r / H of the film; elsewhere the background is black.
        let expected = 2.0 * radius / film_height * lambert_cylinder_mean_radiance(albedo, irradiance, alpha);
        let measured = mean.mean().x;
        let std_error =
            (variance.pixels.iter().map(|v| v.x).sum::<f64>()).sqrt() / variance.pixels.len() as f64;
        assert!(
            (measured - expected).abs() < 4.0 * std_error + 1e-4 * expected,
            "alpha {alpha}: measured {measured} expected {expected} (std. error {std_error})"
        );
    }
}

#[test]
fn white_furnace_lambertian_fabric_in_a_uniform_environment_is_exactly_one() {
    // Albedo 1 fibers of a real woven exemplar, lit by an SG of tiny sharpness scaled to
    // radiance 1 everywhere (within 2e-4): every path that hits must estimate exactly 1.
    let preset = fabric_preset("cotton_plain").unwrap();
    let exemplar = preset.fabric.build(std::path::Path::new(".")).unwrap();
    let lambda = 1e-4;
    let environment = Light::sg(DVec3::Z, lambda, Rgb::splat(4.0 * std::f64::consts::PI)).unwrap();
    let extent = Extent::Rectangle { min: glam::Vec2::splat(-0.5), max: glam::Vec2::splat(0.5) };
    let scene = lambert_scene(&exemplar, extent, 1.0, vec![environment]);
    let settings = settings(1, Component::All);

    let (mut sum, mut sum_sq, mut n) = (0.0, 0.0, 0usize);
    for i in 0..6000u64 {
        let mut rng = pixel_rng(11, i);
        // Rays from above and from grazing angles, aimed at random points of the swatch centre.
        let u: [f64; 4] = std::array::from_fn(|_| rand::Rng::random(&mut rng));
        let target = DVec3::new(0.2 * (u[0] - 0.5), 0.2 * (u[1] - 0.5), 0.0);
        let dir = -DVec3::new(
            (0.9 * u[2]).sqrt() * (std::f64::consts::TAU * u[3]).cos(),
            (0.9 * u[2]).sqrt() * (std::f64::consts::TAU * u[3]).sin(),
            1.0,
        )
        .normalize();
        let origin = target - 2.0 * dir;
        if scene.fibers.closest_hit_f64(origin, dir, f64::INFINITY, None).is_none() {
            continue;
        }
        let l = radiance(&scene, origin, dir, &settings, &mut rng);
        assert!(l.is_finite(), "non-finite radiance {l}");
        sum += l.x;
        sum_sq += l.x * l.x;
        n += 1;
    }
    assert!(n > 3000, "too few rays hit the fabric: {n}");
    let mean = sum / n as f64;
    let std_error = ((sum_sq / n as f64 - mean * mean) / (n as f64 - 1.0)).sqrt();
    assert!(
        (mean - 1.0).abs() < 4.0 * std_error + 3e-4,
        "furnace: mean {mean} +- {std_error} over {n} paths"
    );
}

#[test]
fn single_plus_multiple_scattering_equals_the_full_render() {
    let preset = fabric_preset("default").unwrap();
    let exemplar = preset.fabric.build(std::path::Path::new(".")).unwrap();
    let lights = vec![
        Light::directional(DVec3::new(-0.5, 0.3, 0.8), Rgb::splat(2.0)).unwrap(),
        Light::sg(DVec3::new(0.2, -0.4, 1.0), 5.0, Rgb::splat(1.0)).unwrap(),
    ];
    let extent = Extent::Rectangle { min: glam::Vec2::splat(-0.3), max: glam::Vec2::splat(0.3) };
    let scene = lambert_scene(&exemplar, extent, 0.7, lights);
    let camera = Camera::new(
        DVec3::new(0.0, -0.3, 0.4),
        DVec3::ZERO,
        DVec3::Z,
        Projection::Perspective { fov_y_deg: 20.0 },
        16,
        16,
    )
    .unwrap();
    let all = render(&scene, &camera, &settings(48, Component::All), &|_| {});
    let single = render(&scene, &camera, &settings(48, Component::Single), &|_| {});
    let multiple = render(&scene, &camera, &settings(48, Component::Multiple), &|_| {});
    let mut sum = single.mean();
    let mut sum_var = single.variance_of_mean();
    for (i, (m, v)) in multiple.mean().pixels.iter().zip(&multiple.variance_of_mean().pixels).enumerate() {
        sum.pixels[i] += *m;
        sum_var.pixels[i] += *v;
    }
    let (all_mean, all_var) = (all.mean(), all.variance_of_mean());
    let c = compare(
        Estimate { mean: &sum, variance: Some(&sum_var) },
        Estimate { mean: &all_mean, variance: Some(&all_var) },
    );
    assert!(multiple.mean().mean().x > 0.05 * single.mean().mean().x, "multiple scattering is visible");
    assert!(c.relative_error_of_mean.abs() < 4.0 * c.relative_error_of_mean_std, "{c:?}");
    assert!(c.mean_z_squared < 1.5, "{c:?}");
}

#[test]
fn fiber_bcsdf_single_scattering_matches_the_model_with_light_side_as_omega_i() {
    use twill_precompute::bcsdf::{FiberParams, FiberScattering, Material};
    // An asymmetric configuration where S(wi, wo) and S(wo, wi) differ, so evaluating the
    // non-reciprocal model with the directions swapped would fail this test.
    let params = FiberParams {
        c_r: Rgb::new(0.05, 0.3, 0.6),
        beta_r_deg: 8.0,
        c_tt: Rgb::new(0.9, 0.5, 0.2),
        beta_tt_deg: 15.0,
        gamma_tt_deg: 30.0,
    };
    let fiber = FiberScattering::new(&params).unwrap();
    let (radius, film_height, irradiance) = (0.05, 0.4, 3.0);
    let exemplar = straight_fiber(radius as f32, 20.0);
    let wo = DVec3::new(0.55, 0.0, 1.0).normalize();
    let wi = DVec3::new(-0.2, 0.45, 0.8).normalize();
    let t = DVec3::X;
    let s = fiber.eval(t, wi, wo);
    let s_swapped = fiber.eval(t, wo, wi);
    assert!(((s - s_swapped) / s).abs().max_element() > 0.1, "the configuration must tell the order apart");

    let mut scene = lambert_scene(
        &exemplar,
        Extent::Unbounded,
        0.5,
        vec![Light::directional(wi, Rgb::splat(irradiance)).unwrap()],
    );
    scene.yarn_materials = vec![Material::Fiber(fiber)];
    let camera = Camera::new(
        5.0 * wo,
        DVec3::ZERO,
        DVec3::Y,
        Projection::Orthographic { height_cm: film_height },
        32,
        32,
    )
    .unwrap();
    let film = render(&scene, &camera, &settings(16, Component::Single), &|_| {});
    let mean = film.mean();
    assert!(mean.is_finite());
    // Every visible point of the fiber reflects E * S(wi, wo) * cos(theta_i); the fiber covers
    // 2r / H of the film whatever the view's tilt along its axis.
    let cos_theta_i = (1.0 - wi.dot(t).powi(2)).sqrt();
    let expected = 2.0 * radius / film_height * irradiance * s * cos_theta_i;
    let measured = mean.mean();
    // Coverage is sampled by jittered pixels: 32 rows x 16 spp give well under 1% error.
    let rel = ((measured - expected) / expected).abs().max_element();
    assert!(rel < 0.01, "measured {measured} expected {expected}");
}
