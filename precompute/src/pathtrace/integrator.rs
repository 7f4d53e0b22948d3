//! The path-tracing integrator.
//!
//! A path starts at the camera. At each fiber hit (a scattering event, counted from 1) it adds
//! next-event estimation toward every light, then samples the material for the next direction.
//! The fiber model is not reciprocal, so every evaluation passes the light-side direction as
//! ωi and the camera-side direction as ωo (`Material::eval_cos(t, n, ωi, ωo)`). A continuation
//! ray that escapes the fabric picks up SG-light radiance, weighted against next-event
//! estimation by the power heuristic; directional lights are reached by next-event estimation
//! only. Primary rays that miss see a black background; an optional black ground plane under
//! the fabric absorbs whatever reaches it and shadows lights from below.
//!
//! [`Component`] selects which scattering orders count: all, single scattering only (exactly
//! one fiber interaction) or multiple scattering only (two or more). Each pixel gets its own
//! random stream derived from the seed and the pixel index, so images do not depend on thread
//! scheduling.

use std::sync::atomic::{AtomicUsize, Ordering};

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use super::camera::Camera;
use super::light::Light;
use crate::Rgb;
use crate::bcsdf::Material;
use crate::image::{Film, PixelRow};
use crate::paint::PaintedMaterials;
use crate::params::{ParamError, check_count};
use crate::raycast::pattern::PatternedFibers;
use crate::raycast::{FiberScene, Hit};

/// Which scattering orders an image shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Component {
    #[default]
    All,
    /// Light that scattered exactly once on a fiber before reaching the camera.
    Single,
    /// Light that scattered two or more times.
    Multiple,
}

impl Component {
    fn counts(self, event: u32) -> bool {
        match self {
            Self::All => true,
            Self::Single => event == 1,
            Self::Multiple => event >= 2,
        }
    }
}

/// Sampling settings of a render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    pub spp: u32,
    /// Maximum number of scattering events on a path.
    pub max_depth: u32,
    pub component: Component,
    pub seed: u64,
}

impl RenderSettings {
    pub fn validate(&self) -> Result<(), ParamError> {
        check_count("spp", self.spp as usize, 1, 1 << 20)?;
        check_count("max_depth", self.max_depth as usize, 1, 10_000)?;
        Ok(())
    }
}

/// Everything a path needs: fibers, their materials, lights and an optional ground.
pub struct PathScene {
    /// The fabric (of a patterned cloth, exemplar 0's swatch alone, for the tools that trace
    /// one exemplar; paths trace `pattern`).
    pub fibers: FiberScene,
    /// Patterned cloth: every exemplar in its blocks, what paths trace instead of `fibers`.
    pub pattern: Option<PatternedFibers>,
    /// Material of each yarn of the fabric (indexed by `Hit::yarn`; a patterned cloth's yarns
    /// are numbered across its exemplars, see [`PatternedFibers`]).
    pub yarn_materials: Vec<Material>,
    pub lights: Vec<Light>,
    /// Height of a black, absorbing ground plane under the fabric, if any.
    pub ground_z: Option<f64>,
    /// A painted cloth: materials per paint cell, in place of `yarn_materials`.
    pub painted: Option<PaintedMaterials>,
}

impl PathScene {
    /// The material at a fiber hit: its paint cell's when the cloth is painted, else its yarn's.
    #[must_use]
    pub fn material(&self, hit: &Hit) -> &Material {
        match &self.painted {
            Some(p) => &p.materials[p.of_cell[p.cells.cell_of(hit) as usize] as usize],
            None => &self.yarn_materials[hit.yarn as usize],
        }
    }

    /// The first fiber along `origin + t dir`, `t < t_max`, skipping `ignore_fiber`: in the
    /// pattern's blocks for patterned cloth, else in `fibers`.
    #[must_use]
    pub fn closest_hit(
        &self,
        origin: DVec3,
        dir: DVec3,
        t_max: f64,
        ignore_fiber: Option<u32>,
    ) -> Option<Hit> {
        let (o, d, t) = (origin.as_vec3(), dir.as_vec3(), t_max as f32);
        match &self.pattern {
            Some(pattern) => pattern.closest_hit(o, d, t, ignore_fiber),
            None => self.fibers.closest_hit(o, d, t, ignore_fiber),
        }
    }

    /// Whether a fiber blocks `origin + t dir` for any `t` (shadow rays), `ignore_fiber` skipped.
    #[must_use]
    pub fn blocked(&self, origin: DVec3, dir: DVec3, ignore_fiber: Option<u32>) -> bool {
        let (o, d) = (origin.as_vec3(), dir.as_vec3());
        match &self.pattern {
            Some(pattern) => pattern.any_hit(o, d, f32::INFINITY, ignore_fiber),
            None => self.fibers.any_hit(o, d, f32::INFINITY, ignore_fiber),
        }
    }
}

/// Renders `settings.spp` samples per pixel; `progress` is called with the number of rows done.
pub fn render(
    scene: &PathScene,
    camera: &Camera,
    settings: &RenderSettings,
    progress: &(dyn Fn(usize) + Sync),
) -> Film {
    let (width, height) = (camera.width(), camera.height());
    let rows_done = AtomicUsize::new(0);
    let rows: Vec<PixelRow> = (0..height)
        .into_par_iter()
        .map(|y| {
            let mut row = PixelRow::new(width);
            for x in 0..width {
                let mut rng = pixel_rng(settings.seed, (y * width + x) as u64);
                for _ in 0..settings.spp {
                    let (px, py) = (x as f64 + rng.random::<f64>(), y as f64 + rng.random::<f64>());
                    let (origin, dir) = camera.ray(px, py);
                    row.add(x, radiance(scene, origin, dir, settings, &mut rng));
                }
            }
            progress(rows_done.fetch_add(1, Ordering::Relaxed) + 1);
            row
        })
        .collect();
    let mut film = Film::new(width, height);
    for (y, row) in rows.iter().enumerate() {
        film.set_row(y, row);
    }
    film
}

/// A random stream for one pixel, independent of every other pixel's.
#[must_use]
pub fn pixel_rng(seed: u64, pixel: u64) -> Pcg64Mcg {
    // SplitMix64 finalizer decorrelates neighbouring pixel indices.
    let mut z = seed ^ pixel.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    Pcg64Mcg::seed_from_u64(z ^ (z >> 31))
}

/// One path's estimate of the radiance arriving at `origin` from direction `-dir`.
pub fn radiance(
    scene: &PathScene,
    origin: DVec3,
    dir: DVec3,
    settings: &RenderSettings,
    rng: &mut Pcg64Mcg,
) -> Rgb {
    radiance_from(scene, origin, dir, None, settings, rng)
}

/// [`radiance`] for a ray that starts on a fiber: the first ray ignores `origin_fiber` (as the
/// paper's V_k and IIRTF do). Light that reaches `origin` without touching a fiber is not
/// counted (the background is black), so with one directional light of unit irradiance from
/// ω0 this estimates the IIRTF's T(ω0, dir, origin).
pub fn radiance_from(
    scene: &PathScene,
    origin: DVec3,
    dir: DVec3,
    origin_fiber: Option<u32>,
    settings: &RenderSettings,
    rng: &mut Pcg64Mcg,
) -> Rgb {
    let Some(mut hit) = trace(scene, origin, dir, origin_fiber) else {
        return Rgb::ZERO; // black background
    };
    let mut dir = dir;
    let mut throughput = Rgb::ONE;
    let mut total = Rgb::ZERO;
    for event in 1..=settings.max_depth {
        let wo = -dir;
        let position = hit.position.as_dvec3();
        let t = hit.tangent.as_dvec3();
        let n = hit.normal.as_dvec3();
        let material = scene.material(&hit);
        let counts_here = settings.component.counts(event);

        if counts_here {
            for light in &scene.lights {
                let sample = light.sample([rng.random(), rng.random()]);
                let wi = sample.to_light;
                let f = material.eval_cos(t, n, wi, wo);
                if f == Rgb::ZERO || occluded(scene, position, wi, hit.fiber) {
                    continue;
                }
                let mis = sample
                    .pdf
                    .map_or(1.0, |light_pdf| power_heuristic(light_pdf, material.pdf(t, n, wo, wi)));
                total += throughput * f * sample.weight * mis;
            }
        }
        // Nothing further can count once single scattering is done.
        if settings.component == Component::Single && !has_sg_light(scene) {
            break;
        }

        let Some((wi, pdf)) = material.sample(t, n, wo, [rng.random(), rng.random(), rng.random()]) else {
            break;
        };
        if pdf <= 0.0 || !pdf.is_finite() {
            break;
        }
        let f = material.eval_cos(t, n, wi, wo);
        if f == Rgb::ZERO {
            break;
        }
        throughput *= f / pdf;
        dir = wi;

        if let Some(next) = trace(scene, position, wi, Some(hit.fiber)) {
            hit = next;
        } else {
            if counts_here && !below_ground(scene, position, wi) {
                for light in &scene.lights {
                    let light_pdf = light.pdf(wi);
                    if light_pdf > 0.0 {
                        total += throughput * light.radiance(wi) * power_heuristic(pdf, light_pdf);
                    }
                }
            }
            break;
        }
        if settings.component == Component::Single {
            break;
        }
        if !russian_roulette(event, &mut throughput, rng) {
            break;
        }
    }
    total
}

/// Russian roulette after scattering event `event`: from the fourth event on, a path survives
/// with probability `max(throughput)` clamped to [0.05, 1] and its throughput is divided by it.
/// Returns whether the path goes on.
pub(crate) fn russian_roulette(event: u32, throughput: &mut Rgb, rng: &mut Pcg64Mcg) -> bool {
    if event < 3 {
        return true;
    }
    let survive = throughput.max_element().clamp(0.05, 1.0);
    if rng.random::<f64>() >= survive {
        return false;
    }
    *throughput /= survive;
    true
}

fn has_sg_light(scene: &PathScene) -> bool {
    scene.lights.iter().any(|l| matches!(l, Light::Sg { .. }))
}

pub(crate) fn power_heuristic(a: f64, b: f64) -> f64 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 == 0.0 { 0.0 } else { a2 / (a2 + b2) }
}

/// Closest fiber hit that lies above the ground (fibers below it are hidden by it).
pub(crate) fn trace(scene: &PathScene, origin: DVec3, dir: DVec3, ignore_fiber: Option<u32>) -> Option<Hit> {
    let t_max = ground_distance(scene, origin, dir).unwrap_or(f64::INFINITY);
    scene.closest_hit(origin, dir, t_max, ignore_fiber)
}

pub(crate) fn occluded(scene: &PathScene, origin: DVec3, dir: DVec3, fiber: u32) -> bool {
    below_ground(scene, origin, dir) || scene.blocked(origin, dir, Some(fiber))
}

/// Whether a ray from `origin` toward `dir` reaches the scene's ground plane (if any).
pub(crate) fn below_ground(scene: &PathScene, origin: DVec3, dir: DVec3) -> bool {
    ground_distance(scene, origin, dir).is_some()
}

/// Distance along the ray to the ground plane, if the ray reaches it.
fn ground_distance(scene: &PathScene, origin: DVec3, dir: DVec3) -> Option<f64> {
    let z = scene.ground_z?;
    (dir.z < 0.0 && origin.z > z).then(|| (origin.z - z) / -dir.z)
}
