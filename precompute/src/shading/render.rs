//! The whole shading of a segment ([`shade`]) and the CPU version of the paper's method for a
//! flat swatch ([`render_flat`]).
//!
//! How it works: [`shade`] adds single scattering of every light (each scaled by its global
//! visibility V_glo) and multiple scattering of the summed light SH (each light scaled by its
//! blurred global visibility V̄_glo), as the [`Component`] asks. [`render_flat`] renders a
//! scene's camera view: each pixel draws `spp` jittered film positions from its own random
//! stream `pathtrace::integrator::pixel_rng(seed, pixel)` (two uniforms per sample, the
//! camera's pixel convention), casts the primary ray against the swatch's fibers (rays that miss
//! see black; a ground plane, if any, is black and hides nothing above it) and shades the hit
//! segment at the hit point (transfer interpolated between cells) with ωo = −ray direction. A flat swatch lit from above has nothing casting
//! macro-scale shadows on it, so V_glo = V̄_glo = 1 for every light. Rows are rendered in
//! parallel; the image does not depend on the thread count.

use glam::DVec3;
use rand::Rng;
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use super::ShadingError;
use super::multiple::{light_sh, multiple_scattering};
use super::single::single_scattering;
use crate::Rgb;
use crate::bake::pipeline::Baked;
use crate::image::{Film, PixelRow};
use crate::pathtrace::integrator::pixel_rng;
use crate::pathtrace::{Component, Light};
use crate::raycast::Hit;
use crate::scene::{Scene, camera_from};
use crate::sh::sh_count;

/// Radiance leaving `segment` of `baked` at `position` (exemplar coordinates; `None`: transfer
/// constant per cell, see [`multiple_scattering`]) toward unit `wo` (fabric space) under
/// `lights`, each given as `(light, V_glo, V̄_glo)`: single scattering, multiple scattering or
/// both.
pub fn shade(
    baked: &Baked,
    segment: u32,
    position: Option<DVec3>,
    wo: DVec3,
    lights: &[(Light, f64, f64)],
    component: Component,
) -> Result<Rgb, ShadingError> {
    shade_segment(baked, segment, position, wo, lights, component, true)
}

/// [`shade`], with the clamp of multiple scattering at zero optional (`clamp_multiple`).
fn shade_segment(
    baked: &Baked,
    segment: u32,
    position: Option<DVec3>,
    wo: DVec3,
    lights: &[(Light, f64, f64)],
    component: Component,
    clamp_multiple: bool,
) -> Result<Rgb, ShadingError> {
    let mut total = Rgb::ZERO;
    if component != Component::Multiple {
        for (light, v_glo, _) in lights {
            total += single_scattering(baked, segment, wo, light, *v_glo)?;
        }
    }
    if component != Component::Single {
        let order = baked.transfer.iirtf.sh_order;
        let mut c_light = vec![Rgb::ZERO; sh_count(order)];
        for (light, _, v_blurred) in lights {
            if *v_blurred != 0.0 {
                for (sum, c) in c_light.iter_mut().zip(light_sh(light, order, &baked.cg)) {
                    *sum += c * *v_blurred;
                }
            }
        }
        // Truncated SH and a noisy transfer can go negative; clamped per channel as the GPU's
        // shade pass does (which biases the mean up where the transfer is noisy).
        let multiple = multiple_scattering(baked, segment, position, wo, &c_light)?;
        total += if clamp_multiple { multiple.max(Rgb::ZERO) } else { multiple };
    }
    Ok(total)
}

/// Choices of [`render_flat_with`] between the method's approximations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MethodOptions {
    /// Interpolate transfer between cells at the hit point (`true`, the default) or use the
    /// hit segment's own cell (the paper's constant per cell).
    pub interpolate_transfer: bool,
    /// Clamp multiple scattering at zero per channel and sample (`true`, the default and the
    /// GPU's choice) or keep negative values (unbiased in the mean, but not an image).
    pub clamp_multiple: bool,
}

impl Default for MethodOptions {
    fn default() -> Self {
        Self { interpolate_transfer: true, clamp_multiple: true }
    }
}

/// Renders `scene` (its camera at its `[render]` size, its lights) with the paper's method from
/// `baked`, which must be a bake of the scene's fabric; see the module docs.
pub fn render_flat(
    scene: &Scene,
    baked: &Baked,
    component: Component,
    spp: u32,
    seed: u64,
) -> Result<Film, ShadingError> {
    render_flat_with(scene, baked, component, spp, seed, MethodOptions::default())
}

/// [`render_flat`] with a choice of approximations ([`MethodOptions`]).
pub fn render_flat_with(
    scene: &Scene,
    baked: &Baked,
    component: Component,
    spp: u32,
    seed: u64,
    options: MethodOptions,
) -> Result<Film, ShadingError> {
    let baked_segments = baked.volume.segments.len();
    if scene.exemplar.segment_count() != baked_segments {
        return Err(ShadingError::SegmentCountMismatch {
            scene: scene.exemplar.segment_count(),
            baked: baked_segments,
        });
    }
    let lights: Vec<(Light, f64, f64)> = scene.path_scene.lights.iter().map(|&l| (l, 1.0, 1.0)).collect();
    render_primary_hits(scene, spp, seed, |hit, wo, _| {
        let position = options.interpolate_transfer.then(|| hit.local_position.as_dvec3());
        shade_segment(baked, hit.segment, position, wo, &lights, component, options.clamp_multiple)
    })
}

/// Renders `scene`'s camera view (flat swatch) with `shade(hit, ωo, rng)` at every primary
/// fiber hit: `spp` jittered film positions per pixel from `pixel_rng(seed, pixel)` (so every
/// caller with the same seed sees the same hits), black where a ray misses or reaches the
/// ground first. `rng` is a second per-pixel stream for the shading's own random numbers.
/// Rows are rendered in parallel; the image does not depend on the thread count.
pub fn render_primary_hits(
    scene: &Scene,
    spp: u32,
    seed: u64,
    shade: impl Fn(&Hit, DVec3, &mut Pcg64Mcg) -> Result<Rgb, ShadingError> + Sync,
) -> Result<Film, ShadingError> {
    let (width, height) = (scene.render.width, scene.render.height);
    let camera = camera_from(&scene.camera, width, height)?;
    let fibers = &scene.path_scene.fibers;
    let ground_z = scene.path_scene.ground_z;
    let rows: Vec<PixelRow> = (0..height)
        .into_par_iter()
        .map(|y| -> Result<PixelRow, ShadingError> {
            let mut row = PixelRow::new(width);
            for x in 0..width {
                let pixel = (y * width + x) as u64;
                let mut rng = pixel_rng(seed, pixel);
                let mut shading_rng = pixel_rng(seed ^ SHADING_STREAM, pixel);
                for _ in 0..spp {
                    let (px, py) = (x as f64 + rng.random::<f64>(), y as f64 + rng.random::<f64>());
                    let (origin, dir) = camera.ray(px, py);
                    // The ground (if any) lies below every fiber: only a ray that reaches it
                    // first is cut short.
                    let t_max = match ground_z {
                        Some(z) if dir.z < 0.0 && origin.z > z => (origin.z - z) / -dir.z,
                        _ => f64::INFINITY,
                    };
                    let value = match fibers.closest_hit(origin.as_vec3(), dir.as_vec3(), t_max as f32, None)
                    {
                        Some(hit) => shade(&hit, -dir, &mut shading_rng)?,
                        None => Rgb::ZERO,
                    };
                    row.add(x, value);
                }
            }
            Ok(row)
        })
        .collect::<Result<_, _>>()?;
    let mut film = Film::new(width, height);
    for (y, row) in rows.iter().enumerate() {
        film.set_row(y, row);
    }
    Ok(film)
}

/// Mixed into the seed of the shading's own random stream per pixel.
const SHADING_STREAM: u64 = 0x5EED_0F5A_DE00_0001;
