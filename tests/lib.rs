//! Shared helpers for twill's workspace-level tests: small scenes whose answers are known.

use glam::{DVec3, Vec3};
use twill_precompute::Rgb;
use twill_precompute::bcsdf::{Lambertian, Material};
use twill_precompute::fabric::fiber_io::exemplar_from_fibers;
use twill_precompute::fabric::{BlockGrid, Exemplar, Fiber, Tiling};
use twill_precompute::pathtrace::{Light, PathScene};
use twill_precompute::raycast::{Extent, FiberScene};

/// One straight fiber along x, centred on the origin, `length` long, used as-is.
#[must_use]
pub fn straight_fiber(radius: f32, length: f32) -> Exemplar {
    let points = (0..=16).map(|i| Vec3::new(length * (i as f32 / 16.0 - 0.5), 0.0, 0.0)).collect();
    exemplar_from_fibers(vec![Fiber { points, radius, yarn: 0 }], Tiling::AsIs, BlockGrid { nx: 1, ny: 1 })
}

/// A path scene of `exemplar` with every yarn Lambertian of `albedo`.
#[must_use]
pub fn lambert_scene(exemplar: &Exemplar, extent: Extent, albedo: f64, lights: Vec<Light>) -> PathScene {
    let material = Material::Lambert(Lambertian::new(Rgb::splat(albedo)).expect("albedo in [0, 1]"));
    PathScene {
        fibers: FiberScene::new(exemplar, extent).expect("valid fabric"),
        yarn_materials: vec![material; exemplar.yarns.len()],
        lights,
        ground_z: None,
    }
}

/// Mean radiance over the projected width of a Lambertian cylinder of albedo `rho`, seen along
/// a direction perpendicular to its axis, under a directional light of irradiance `e` whose
/// direction is perpendicular to the axis at angle `alpha` (0..=pi/2) from the view direction:
/// `rho e (sin a + (pi - a) cos a) / (4 pi)`.
#[must_use]
pub fn lambert_cylinder_mean_radiance(rho: f64, e: f64, alpha: f64) -> f64 {
    rho * e * (alpha.sin() + (std::f64::consts::PI - alpha) * alpha.cos()) / (4.0 * std::f64::consts::PI)
}

/// Unit vector at angle `alpha` from +z toward +y.
#[must_use]
pub fn tilted_from_z(alpha: f64) -> DVec3 {
    DVec3::new(0.0, alpha.sin(), alpha.cos())
}
