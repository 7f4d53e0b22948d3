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
use super::multiple::{lobe_scattering, multiple_scattering, transfer_light_sh};
use super::single::single_scattering;
use crate::Rgb;
use crate::bake::pipeline::Baked;
use crate::bake::volume::{SegmentTable, VoxelVolume};
use crate::image::{Film, PixelRow};
use crate::pathtrace::integrator::pixel_rng;
use crate::pathtrace::{Component, Light};
use crate::raycast::Hit;
use crate::raycast::clip_slab;
use crate::scene::{Scene, camera_from};

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
    shade_segment(baked, segment, position, position, wo, lights, component, true, MultipleHeld::Both)
}

/// [`shade`], with the clamp of the shaded radiance at zero optional (`clamp_at_zero`), the
/// position that picks the segment's visibility image (`visibility_at`) apart from the one
/// that interpolates the transfer (`position`), and multiple scattering from its SH matrices,
/// its fiber lobes or both (`held`).
#[allow(clippy::too_many_arguments)]
fn shade_segment(
    baked: &Baked,
    segment: u32,
    visibility_at: Option<DVec3>,
    position: Option<DVec3>,
    wo: DVec3,
    lights: &[(Light, f64, f64)],
    component: Component,
    clamp_at_zero: bool,
    held: MultipleHeld,
) -> Result<Rgb, ShadingError> {
    let mut total = Rgb::ZERO;
    if component != Component::Multiple {
        for (light, v_glo, _) in lights {
            total += single_scattering(baked, segment, visibility_at, wo, light, *v_glo)?;
        }
    }
    if component != Component::Single {
        let c_light =
            transfer_light_sh(baked, lights.iter().map(|(light, _, v_blurred)| (light, *v_blurred)));
        // Truncated SH and a noisy transfer can go negative. What is clamped (per channel, as
        // the GPU's shade pass does) is the radiance shaded, single and multiple scattering
        // together, not the multiple-scattering term alone: a clamp lifts the mean wherever it
        // acts (on the silk satin's multiple scattering, which rings below zero over much of
        // the image, by 50–200 points in the error budget; docs/BENCHMARKS.md), and the sum
        // goes below zero less often than the term.
        if held != MultipleHeld::LobesOnly {
            total += multiple_scattering(baked, segment, position, wo, &c_light)?;
        }
        // Only a bake made with fiber lobes has cells that hold them.
        if baked.settings.fiber_lobes && held != MultipleHeld::MatricesOnly {
            let blurred: Vec<(Light, f64)> = lights.iter().map(|(light, _, v)| (*light, *v)).collect();
            total += lobe_scattering(baked, segment, position, wo, &blurred)?;
        }
    }
    Ok(if clamp_at_zero { total.max(Rgb::ZERO) } else { total })
}

/// Choices of [`render_flat_with`] between the method's approximations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MethodOptions {
    /// Interpolate transfer between cells at the hit point (`true`, the default) or use the
    /// hit segment's own cell (the paper's constant per cell).
    pub interpolate_transfer: bool,
    /// Where the shaded radiance (single plus multiple scattering) is clamped at zero.
    pub clamp: ClampAtZero,
    /// Where camera rays meet the fabric.
    pub primary: PrimaryHits,
    /// Which of the transfer's two forms multiple scattering is shaded from.
    pub held: MultipleHeld,
}

impl Default for MethodOptions {
    fn default() -> Self {
        Self {
            interpolate_transfer: true,
            clamp: ClampAtZero::PixelMean,
            primary: PrimaryHits::Exact,
            held: MultipleHeld::Both,
        }
    }
}

/// Which of the two forms a bake holds its transfer in multiple scattering is shaded from:
/// the SH matrices (lattice cells without fiber lobes, segment cells) and the fiber lobes
/// (lattice cells that keep them, `bake::iirtf::forward_lobe_min_sharpness`). The method
/// adds both; either alone (unclamped, `shading::budget`'s rungs 4f and 4g) shows which form
/// the light of a view comes from, and which one its error.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MultipleHeld {
    /// Both forms: the method.
    Both,
    /// The SH matrices alone.
    MatricesOnly,
    /// The fiber lobes alone.
    LobesOnly,
}

/// Where the method's radiance is clamped at zero, per channel. Truncated SH and a noisy
/// transfer ring below zero in places; radiance cannot, so the picture is clamped, and where
/// the clamp acts it lifts the mean.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClampAtZero {
    /// Each pixel's mean over its samples (the default, and the GPU's: its shade pass adds
    /// signed samples to the accumulation, the tone map and the readback clamp the mean).
    /// Ringing that changes sign from sample to sample within a pixel cancels before the
    /// clamp; only a pixel whose mean is negative is lifted.
    PixelMean,
    /// Each sample (until the fifteenth session of 2026-11-27): lifts the mean wherever any
    /// sample rings below zero; on the default cotton under raking light it hid a transfer
    /// 15–30% too dark (docs/BENCHMARKS.md, "The clamp on each pixel's mean").
    EachSample,
    /// Nowhere: unbiased in the mean, but not an image.
    Never,
}

/// Where a camera ray first meets the fabric.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PrimaryHits {
    /// The exact first ray–capsule hit (what the path tracer sees).
    Exact,
    /// The GPU's eye rays (shaders/gbuffer.wgsl) on a flat swatch: the first voxel of the bake's
    /// volume that the ray crosses and that holds a segment; the hit is where the ray enters it.
    Voxels,
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
    let shade_at = |segment: u32, local: DVec3, wo: DVec3| {
        let position = options.interpolate_transfer.then_some(local);
        let each_sample = options.clamp == ClampAtZero::EachSample;
        shade_segment(
            baked,
            segment,
            Some(local),
            position,
            wo,
            &lights,
            component,
            each_sample,
            options.held,
        )
    };
    let mut film = match options.primary {
        PrimaryHits::Exact => render_primary_hits(scene, spp, seed, |hit, wo, _| {
            shade_at(hit.segment, hit.local_position.as_dvec3(), wo)
        }),
        PrimaryHits::Voxels => {
            let volume = &baked.volume.volume;
            let swatch = scene.path_scene.fibers.rectangle();
            render_camera_rays(scene, spp, seed, |origin, dir, t_max, _| {
                match voxel_hit(volume, &baked.volume.segments, swatch, origin, dir, t_max) {
                    Some((segment, local)) => shade_at(segment, local, -dir),
                    None => Ok(Rgb::ZERO),
                }
            })
        }
    }?;
    if options.clamp == ClampAtZero::PixelMean {
        film.clamp_means_at_zero();
    }
    Ok(film)
}

/// The GPU's primary hit on a flat swatch ([`PrimaryHits::Voxels`]): the first fiber the ray
/// crosses among the capsules of the voxels it walks ([`VoxelVolume::first_fiber_hit`]) where
/// it is over the swatch rectangle (the GPU's shell ends there), as (segment, exemplar-local
/// position of the point where the ray enters it).
fn voxel_hit(
    volume: &VoxelVolume,
    segments: &SegmentTable,
    swatch: Option<(glam::Vec2, glam::Vec2)>,
    origin: DVec3,
    dir: DVec3,
    t_max: f64,
) -> Option<(u32, DVec3)> {
    let mut span = (0.0, t_max);
    if let Some((min, max)) = swatch {
        for axis in 0..2 {
            clip_slab(&mut span, origin[axis], dir[axis], f64::from(min[axis]), f64::from(max[axis]));
        }
        if span.0 >= span.1 {
            return None;
        }
    }
    let (segment, t) = volume.first_fiber_hit(segments, origin, dir, span.0, span.1)?;
    Some((segment, volume.wrap(origin + t * dir)))
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
    let fibers = &scene.path_scene.fibers;
    render_camera_rays(scene, spp, seed, |origin, dir, t_max, rng| {
        match fibers.closest_hit(origin.as_vec3(), dir.as_vec3(), t_max as f32, None) {
            Some(hit) => shade(&hit, -dir, rng),
            None => Ok(Rgb::ZERO),
        }
    })
}

/// Renders `scene`'s camera view with `trace(origin, direction, t_max, rng)` per camera ray:
/// `spp` jittered film positions per pixel from `pixel_rng(seed, pixel)`, `t_max` where the ray
/// reaches the ground (if any) first, `rng` a second per-pixel stream for the shading's own
/// random numbers. Rows are rendered in parallel; the image does not depend on the thread count.
fn render_camera_rays(
    scene: &Scene,
    spp: u32,
    seed: u64,
    trace: impl Fn(DVec3, DVec3, f64, &mut Pcg64Mcg) -> Result<Rgb, ShadingError> + Sync,
) -> Result<Film, ShadingError> {
    let (width, height) = (scene.render.width, scene.render.height);
    let camera = camera_from(&scene.camera, width, height)?;
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
                    row.add(x, trace(origin, dir, t_max, &mut shading_rng)?);
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

#[cfg(test)]
mod tests {
    use glam::{DVec3, Vec3};

    use super::voxel_hit;
    use crate::bake::volume::{EMPTY_VOXEL, Occupancy, SegmentTable, VoxelVolume};

    /// A 4 x 4 x 4 grid of 1 cm voxels from the origin, empty but for voxel `(i, j, k)` = 7.
    fn one_voxel(periodic: bool, [i, j, k]: [usize; 3]) -> VoxelVolume {
        let mut ids = vec![EMPTY_VOXEL; 64];
        ids[(k * 4 + j) * 4 + i] = 7;
        VoxelVolume {
            dims: [4, 4, 4],
            origin: Vec3::ZERO,
            voxel_size: Vec3::ONE,
            periodic,
            occupancy: Occupancy::Touches,
            ids,
        }
    }

    /// Segment 7 (of 8): a capsule along x through the centre of voxel `(i, j, k)`, 0.6 cm long
    /// and 0.4 cm in radius; the others far away.
    fn one_capsule([i, j, k]: [usize; 3]) -> SegmentTable {
        let centre = [i as f32 + 0.5, j as f32 + 0.5, k as f32 + 0.5];
        let mut table = SegmentTable {
            direction: vec![[1.0, 0.0, 0.0]; 8],
            material: vec![0; 8],
            axis: vec![[100.0, 100.0, 100.0, 0.3]; 8],
            radius: vec![0.4; 8],
        };
        table.axis[7] = [centre[0], centre[1], centre[2], 0.3];
        table
    }

    #[test]
    fn voxel_hits_stop_where_the_ray_enters_the_fiber_of_the_voxels_it_crosses() {
        let (volume, segments) = (one_voxel(false, [1, 2, 1]), one_capsule([1, 2, 1]));
        // Straight down through x = 1.5, y = 2.5: the capsule's top, z = 1.5 + 0.4.
        let down = |x: f64, y: f64, t_max: f64| {
            voxel_hit(&volume, &segments, None, DVec3::new(x, y, 10.0), -DVec3::Z, t_max)
        };
        let (id, p) = down(1.5, 2.5, f64::INFINITY).unwrap();
        assert_eq!(id, 7);
        // (The radius is stored in f32.)
        assert!((p - DVec3::new(1.5, 2.5, 1.9)).length() < 1e-6, "{p}");
        // Through the voxel beside the capsule, beside the voxel, or cut short by the ground
        // above the capsule: none.
        assert!(down(1.5, 2.95, f64::INFINITY).is_none());
        assert!(down(0.5, 2.5, f64::INFINITY).is_none());
        assert!(down(1.5, 2.5, 8.0).is_none());
        // Level with the slab along the capsule's axis: it enters the near cap at x = 0.8.
        let (_, p) =
            voxel_hit(&volume, &segments, None, DVec3::new(-1.0, 2.5, 1.5), DVec3::X, f64::INFINITY).unwrap();
        assert!((p - DVec3::new(0.8, 2.5, 1.5)).length() < 1e-6, "{p}");
    }

    #[test]
    fn periodic_voxel_hits_wrap_across_the_fabric() {
        let (volume, segments) = (one_voxel(true, [3, 0, 2]), one_capsule([3, 0, 2]));
        // Three periods over and one back: x = 15.5 wraps to 3.5, y = -3.5 to 0.5; the ray
        // enters that copy of the capsule at its top, z = 2.5 + 0.4.
        let origin = DVec3::new(15.5, -3.5, 10.0);
        let (id, p) = voxel_hit(&volume, &segments, None, origin, -DVec3::Z, f64::INFINITY).unwrap();
        assert_eq!(id, 7);
        assert!((p - DVec3::new(3.5, 0.5, 2.9)).length() < 1e-6, "exemplar-local position {p}");
        let not_periodic = one_voxel(false, [3, 0, 2]);
        assert!(voxel_hit(&not_periodic, &segments, None, origin, -DVec3::Z, f64::INFINITY).is_none());
        // A swatch rectangle ends the fabric, as the GPU's shell does: the same ray down misses
        // when the rectangle stops short of it, and hits when the rectangle takes it in.
        let swatch = Some((glam::Vec2::new(10.0, -5.0), glam::Vec2::new(15.0, 0.0)));
        assert!(voxel_hit(&volume, &segments, swatch, origin, -DVec3::Z, f64::INFINITY).is_none());
        let inside = Some((glam::Vec2::new(10.0, -5.0), glam::Vec2::new(16.0, 0.0)));
        assert_eq!(
            voxel_hit(&volume, &segments, inside, origin, -DVec3::Z, f64::INFINITY).map(|h| h.0),
            Some(7)
        );
    }
}
