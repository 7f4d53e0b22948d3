//! The method's error budget on a flat swatch: which approximation costs how much accuracy.
//!
//! How it works: every rung renders the scene's camera view over the same primary fiber hits
//! ([`render_primary_hits`] with one seed) and replaces one more exact quantity by the method's
//! approximation of it, single and multiple scattering separately. Each rung is compared with
//! the path tracer's image of the same component (`pathtrace::render`, `Component::Single` or
//! `Component::Multiple`): relative error of the image mean, per-pixel RMSE relative to the
//! reference mean, and the rung's wall time. A rung's own cost is its error minus the error of
//! the rung before it.
//!
//! Single scattering, from exact to the method (lights sampled `light_samples` times per hit
//! for SG lights, exactly for directional ones, with the exact fiber scattering function):
//! 1. shadow rays from the hit point: exactly what the path tracer does (checks the
//!    decomposition and the light and scattering conventions);
//! 2. shadow rays from the segment midpoint, on the fiber axis (the paper's V_k);
//! 3. shadow rays from the segment midpoint raised to the centroid of the fiber's upper half
//!    (`bake::svf::visibility_origin`, twill's V_k at one visibility point);
//!    3′. (when the bake has more than one visibility point per segment) from the point whose
//!    piece of the segment the hit lies on, raised the same way (twill's V_k);
//! 4. the binary visibility image of the bake's resolution (nearest pixel) at that point;
//!    4′. the sign of the PCA-compressed SSDF (bilinear) of that image: the paper's local
//!    visibility, still with the exact scattering function (what PCA alone costs; with
//!    `BakeSettings::visibility_bits` the method reads rung 4's bits instead);
//! 5. the method: local visibility as the bake keeps it (the binary image's bits bilinear
//!    between pixel centres, or the PCA SSDF's hard and erf steps), sum of SGs, closed-form Γ;
//! 6. the method on the GPU's primary hits: the first fiber entered among the voxels of the
//!    bake's volume along the ray ([`PrimaryHits::Voxels`]), what the GPU's eye rays see.
//!
//! Multiple scattering (indirect light through the exact fiber scattering function, one path
//! per sample, then the method):
//! 1. path-traced indirect light at the hit point (equals the reference: checks that single +
//!    multiple is all the light);
//!    1′. the same incident light projected on the bake's SH (order n) and scattered through
//!    the method's `C_S` table: what the SH truncation alone costs, at the exact point and
//!    with exact light transport (no clamp);
//! 2. path-traced indirect light at the segment midpoint (what the IIRTF integrates);
//!    2e. (a bake with exposed starts) the same at a point of the segment an eye sees, drawn as
//!    the bake draws its paths' starts: what the segment's transfer averages, every eye's side
//!    of the fiber instead of this view's;
//!    2′. the IIRTF of the hit's segment alone (the bake's sampler, SH order, paths and starts,
//!    matrices only), shaded as rung 3: the transfer without the cells' averaging;
//! 3. the per-cell IIRTF, constant over each cell (the paper), at the bake's cell size, SH order
//!    and paths per cell, its paths from segment midpoints (the paper) or exposed starts
//!    (`BakeSettings::exposed_starts`); the lattice's cells alone;
//!    3i. (a bake with segment transfers) the lattice's cells interpolated at the hit point:
//!    the method without the segments' own transfers;
//! 4. the method: the IIRTF interpolated between cells at the hit point, or the segment's own
//!    transfer where the bake has one (`BakeSettings::segment_transfer_paths`,
//!    `multiple::segment_transfer`; under a cell that keeps fiber lobes, its reflected light
//!    beside the cells' forward lobes);
//! 5. the method on the GPU's primary hits (as single-scattering rung 6);
//!
//! and beside them 4′, the method without its clamp at zero (on this ladder the radiance shaded
//! is multiple scattering alone, so the clamp acts on it). Truncated SH and
//! a noisy transfer go negative in places; the clamp of each pixel's mean (the GPU's too) keeps
//! the image an image but lifts its mean, so rung 4 minus rung 4′ is what the clamp adds. 4″
//! is the clamp taken on each sample instead (the renderers' choice until the fifteenth
//! session of 2026-11-27; the same samples, so its mean lies above 4's). With a bake that has
//! fiber lobes, 4f and 4g split 4′ by the form the transfer is held in
//! ([`MultipleHeld`]): the lobes alone and the SH matrices alone, so that a view's error can be
//! laid at the form that carries its light. With
//! [`BudgetSettings::split_transfer`], 4a–4c split 4′ by light transport
//! (`bake::iirtf::TransferPart`): the first neighbour's transmission (light through one fiber,
//! peaked around the light's direction), its reflection (a cone about its axis) and light
//! scattered twice or more, each baked on the same paths; run at two SH orders, a part whose
//! figure swings with the order is one the SH transfer cannot hold. With segment cells the
//! parts are baked on the lattice's cells alone and split rung 3i (unclamped) instead: a
//! segment cell under lobe cells holds the whole bake's reflected light by a rule the parts do
//! not split (baked with a part, the forward chains of silk configuration 0 read 43% of the
//! reference where the whole bake's forward lobe carries 14%).
//!
//! Callers can add rungs measured elsewhere with [`Budget::add_rung`]: `twill accuracy budget`
//! adds the GPU renderer's frame (primary visibility from the voxel volume) after each
//! component's ladder. The GPU rung minus the last
//! CPU rung is what the GPU renderer itself adds beyond its primary hits.

use std::collections::{BTreeSet, HashMap};
use std::fmt::Write as _;
use std::sync::Mutex;
use std::time::Instant;

use glam::DVec3;
use rand::Rng;
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use super::multiple::{multiple_scattering_in_cell, scatter_transferred, transfer_light_sh};
use super::render::{
    ClampAtZero, MethodOptions, MultipleHeld, PrimaryHits, render_flat_with, render_primary_hits,
};
use super::visibility::ssdf_lookup;
use super::{SegmentShading, ShadingError};
use crate::Rgb;
use crate::bake::Cancel;
use crate::bake::iirtf::{
    CellTransfer, IirtfOptions, MatrixLight, TransferPart, TransferSampler, bake_cell, bake_iirtf,
    cell_stream, uniform_sphere,
};
use crate::bake::pipeline::{BakeInputs, Baked, yarn_materials};
use crate::bake::svf::{VisibilityImages, render_exemplar, visibility_origin, visibility_point_fraction};
use crate::image::{Estimate, Film, Image, compare};
use crate::pathtrace::integrator::{below_ground, occluded, radiance_from, russian_roulette, trace};
use crate::pathtrace::{Component, Light, RenderSettings, render};
use crate::raycast::Hit;
use crate::scene::{Scene, camera_from};
use crate::sh::{sh_count, sh_eval};

/// How finely the budget samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BudgetSettings {
    /// Samples per pixel of every rung.
    pub spp: u32,
    /// Samples per pixel of the path-traced references.
    pub reference_spp: u32,
    /// Light samples per hit for SG lights (single-scattering rungs 1–4).
    pub light_samples: u32,
    pub seed: u64,
    /// Add rungs 4a–4c: the transfer split into the first neighbour's transmission, its
    /// reflection and light scattered twice or more (three more IIRTF bakes).
    pub split_transfer: bool,
}

impl Default for BudgetSettings {
    fn default() -> Self {
        Self { spp: 16, reference_spp: 64, light_samples: 16, seed: 1, split_transfer: false }
    }
}

/// One rung of the ladder.
#[derive(Debug, Clone, PartialEq)]
pub struct Rung {
    pub component: Component,
    pub name: String,
    /// (mean − reference mean) / reference mean.
    pub relative_error_of_mean: f64,
    /// Standard error of that figure from both images' noise.
    pub relative_error_std: f64,
    /// (mean − reference mean) / reference mean per colour channel: a yarn dark in one channel
    /// shows its error there, hidden in the sum by the bright channels.
    pub relative_error_rgb: Rgb,
    /// Per-pixel RMSE over the reference's mean.
    pub relative_pixel_rmse: f64,
    /// What the two images' noise alone would give for that figure.
    pub relative_noise_rmse: f64,
    pub seconds: f64,
}

/// The whole ladder, with the references' own cost.
#[derive(Debug, Clone)]
pub struct Budget {
    pub rungs: Vec<Rung>,
    pub width: usize,
    pub height: usize,
    pub settings: BudgetSettings,
    /// Wall time of the two references.
    pub reference_seconds: f64,
    single_reference: Film,
    multiple_reference: Film,
}

impl Budget {
    /// Adds a rung measured outside this module (the GPU renderer's image of `component`, with
    /// no variance of its own), compared like every other rung.
    pub fn add_rung(&mut self, component: Component, name: String, image: &Image, seconds: f64) {
        let reference =
            if component == Component::Single { &self.single_reference } else { &self.multiple_reference };
        let rung = measure(component, name, Estimate { mean: image, variance: None }, reference, seconds);
        self.insert_after_component(rung);
    }

    /// Adds a rung of another scene's view, compared with that scene's own path-traced
    /// `reference` of `component` (`twill accuracy budget` on a mesh: the GPU renderer on the
    /// curved cloth against the path tracer on the same cloth).
    pub fn add_rung_against(
        &mut self,
        component: Component,
        name: String,
        image: &Image,
        reference: &Film,
        seconds: f64,
    ) {
        let rung = measure(component, name, Estimate { mean: image, variance: None }, reference, seconds);
        self.insert_after_component(rung);
    }

    fn insert_after_component(&mut self, rung: Rung) {
        let component = rung.component;
        let at =
            self.rungs.iter().rposition(|r| r.component == component).map_or(self.rungs.len(), |i| i + 1);
        self.rungs.insert(at, rung);
    }

    /// A Markdown table of the ladder.
    #[must_use]
    pub fn markdown(&self) -> String {
        let mut out = format!(
            "{}x{} px, rungs {} spp, references {} spp (path traced in {:.1} s), seed {}\n\n\
             | component | rung | mean error | ± noise | R / G / B | per-pixel RMSE | noise alone | time |\n\
             |---|---|---|---|---|---|---|---|\n",
            self.width,
            self.height,
            self.settings.spp,
            self.settings.reference_spp,
            self.reference_seconds,
            self.settings.seed
        );
        for r in &self.rungs {
            let _ = writeln!(
                out,
                "| {:?} | {} | {:+.1}% | {:.1}% | {:+.0}/{:+.0}/{:+.0}% | {:.1}% | {:.1}% | {:.2} s |",
                r.component,
                r.name,
                100.0 * r.relative_error_of_mean,
                100.0 * r.relative_error_std,
                100.0 * r.relative_error_rgb.x,
                100.0 * r.relative_error_rgb.y,
                100.0 * r.relative_error_rgb.z,
                100.0 * r.relative_pixel_rmse,
                100.0 * r.relative_noise_rmse,
                r.seconds
            );
        }
        out
    }

    /// The rung named `name` of `component`.
    #[must_use]
    pub fn rung(&self, component: Component, name: &str) -> Option<&Rung> {
        self.rungs.iter().find(|r| r.component == component && r.name.starts_with(name))
    }
}

/// Where a rung's shadow rays start.
#[derive(Debug, Clone, Copy)]
enum ShadowOrigin {
    HitPoint,
    Midpoint,
    /// The segment's midpoint raised to the centroid of the fiber's upper half
    /// (`bake::svf::visibility_origin`).
    RaisedMidpoint,
    /// The bake's visibility point whose piece holds the hit, raised the same way.
    RaisedHitsPoint,
}

/// Runs the ladder on `scene` (a flat swatch) with `baked`, a bake of its fabric; see the
/// module docs. `progress` gets each finished rung's name.
pub fn error_budget(
    scene: &Scene,
    baked: &Baked,
    settings: &BudgetSettings,
    progress: &dyn Fn(&str),
) -> Result<Budget, ShadingError> {
    let (width, height) = (scene.render.width, scene.render.height);
    let started = Instant::now();
    let camera = camera_from(&scene.camera, width, height)?;
    let reference_of = |component| {
        let render_settings = RenderSettings {
            spp: settings.reference_spp,
            max_depth: scene.render.max_depth,
            component,
            seed: settings.seed ^ 0x00AB_CDEF,
        };
        render(&scene.path_scene, &camera, &render_settings, &|_| {})
    };
    let single_reference = reference_of(Component::Single);
    let multiple_reference = reference_of(Component::Multiple);
    let reference_seconds = started.elapsed().as_secs_f64();
    progress("references");

    let mut rungs = Vec::new();
    let mut push = |component: Component, name: String, film: &Film, seconds: f64| {
        let reference = if component == Component::Single { &single_reference } else { &multiple_reference };
        let (mean, variance) = (film.mean(), film.variance_of_mean());
        progress(&name);
        rungs.push(measure(
            component,
            name,
            Estimate { mean: &mean, variance: Some(&variance) },
            reference,
            seconds,
        ));
    };

    // Single scattering.
    let points = baked.settings.visibility_points;
    let mut origins = vec![
        ("1 shadow rays from the hit point (exact)".to_string(), ShadowOrigin::HitPoint),
        ("2 shadow rays from the segment midpoint (paper)".to_string(), ShadowOrigin::Midpoint),
        (
            "3 shadow rays from the segment midpoint raised (twill's origin)".to_string(),
            ShadowOrigin::RaisedMidpoint,
        ),
    ];
    if points > 1 {
        let name = format!("3' shadow rays from the nearest of {points} points along the segment, raised");
        origins.push((name, ShadowOrigin::RaisedHitsPoint));
    }
    for (name, origin) in origins {
        let t = Instant::now();
        let film = single_by_light_sampling(scene, settings, |hit, dir| {
            shadow_ray_visible(scene, baked, hit, dir, origin)
        })?;
        push(Component::Single, name, &film, t.elapsed().as_secs_f64());
    }
    let n = baked.settings.svf_resolution;
    let t = Instant::now();
    let images: VisibilityImages = render_exemplar(&scene.exemplar, n, points, &Cancel::new(), &|_| {})
        .map_err(|e| ShadingError::Budget(e.to_string()))?;
    let film = single_by_light_sampling(scene, settings, |hit, dir| {
        images.lookup(visibility_image_of(baked, hit), dir)
    })?;
    push(Component::Single, format!("4 visibility image {n}x{n}"), &film, t.elapsed().as_secs_f64());
    let t = Instant::now();
    let film = single_by_light_sampling(scene, settings, |hit, dir| {
        ssdf_lookup(&baked.visibility.ssdf, visibility_image_of(baked, hit), dir) > 0.0
    })?;
    push(
        Component::Single,
        format!(
            "4' the PCA SSDF's sign (K = {}): the paper's local visibility",
            baked.settings.pca_components
        ),
        &film,
        t.elapsed().as_secs_f64(),
    );
    let t = Instant::now();
    let film = render_flat_with(
        scene,
        baked,
        Component::Single,
        settings.spp,
        settings.seed,
        MethodOptions::default(),
    )?;
    push(
        Component::Single,
        format!(
            "5 the method: {} (K = {}), sum of {} SGs, closed-form Γ",
            if baked.visibility.bits.is_some() { "binary images bilinear" } else { "PCA SSDF" },
            baked.settings.pca_components,
            baked.settings.sos_count
        ),
        &film,
        t.elapsed().as_secs_f64(),
    );
    let voxel_hits = PrimaryHits::Voxels;
    let voxels = "the GPU's primary hits (fibers of the voxels walked)";
    let t = Instant::now();
    let options = MethodOptions { primary: voxel_hits, ..MethodOptions::default() };
    let film = render_flat_with(scene, baked, Component::Single, settings.spp, settings.seed, options)?;
    push(Component::Single, format!("6 the method on {voxels}"), &film, t.elapsed().as_secs_f64());

    // Multiple scattering.
    let fibers = &scene.path_scene.fibers;
    let segments = fibers.segments();
    let midpoint =
        |hit: &Hit| segments[hit.segment as usize].midpoint().as_dvec3() + fibers.tile_offset(hit.tile);
    let order = baked.transfer.iirtf.sh_order;
    for (name, at_hit) in [
        ("1 path-traced indirect light at the hit point (exact)", true),
        ("2 path-traced indirect light at the segment midpoint", false),
    ] {
        let t = Instant::now();
        let film = render_primary_hits(scene, settings.spp, settings.seed, |hit, wo, rng| {
            let origin = if at_hit { fibers.world_position_f64(hit) } else { midpoint(hit) };
            Ok(indirect_light(scene, hit, origin, wo, rng))
        })?;
        push(Component::Multiple, name.to_string(), &film, t.elapsed().as_secs_f64());
        if at_hit {
            let t = Instant::now();
            let film = render_primary_hits(scene, settings.spp, settings.seed, |hit, wo, rng| {
                incident_sh_scattered(scene, baked, hit, fibers.world_position_f64(hit), wo, rng)
            })?;
            push(
                Component::Multiple,
                format!(
                    "1' rung 1's incident indirect light in SH of order {order}, scattered through C_S (no clamp)"
                ),
                &film,
                t.elapsed().as_secs_f64(),
            );
        } else {
            if baked.settings.exposed_starts {
                let t = Instant::now();
                let film = at_exposed_starts(scene, baked, settings)?;
                push(
                    Component::Multiple,
                    "2e path-traced indirect light at an exposed start of the hit's segment (what its transfer averages)"
                        .into(),
                    &film,
                    t.elapsed().as_secs_f64(),
                );
            }
            let t = Instant::now();
            let film = per_segment_transfer(scene, baked, settings)?;
            push(
                Component::Multiple,
                format!(
                    "2' the IIRTF of the hit's segment alone ({} paths, {}, matrices only, no clamp)",
                    baked.settings.iirtf_paths_per_cell,
                    if baked.settings.exposed_starts { "exposed starts" } else { "from its midpoint" }
                ),
                &film,
                t.elapsed().as_secs_f64(),
            );
        }
    }
    if settings.split_transfer {
        for (part, name) in [
            (
                TransferPart::ForwardChains,
                "2a rung 2's forward chains alone (light transmitted by every fiber)",
            ),
            (TransferPart::AfterReflection, "2b rung 2's light reflected at least once (2a + 2b = 2)"),
        ] {
            let t = Instant::now();
            let film = render_primary_hits(scene, settings.spp, settings.seed, |hit, wo, rng| {
                Ok(indirect_light_part(scene, hit, midpoint(hit), wo, part, rng))
            })?;
            push(Component::Multiple, name.to_string(), &film, t.elapsed().as_secs_f64());
        }
    }
    let grid = &baked.transfer.cells;
    let cell = grid.cell_size_cm();
    let starts = if baked.settings.exposed_starts { "exposed starts" } else { "from midpoints" };
    let cells = format!(
        "{:.2}x{:.2}x{:.2} ℓ cells, SH order {}, {} paths {starts}",
        cell.x / baked.mean_free_path.mean_cm,
        cell.y / baked.mean_free_path.mean_cm,
        cell.z / baked.mean_free_path.mean_cm,
        baked.transfer.iirtf.sh_order,
        baked.settings.iirtf_paths_per_cell
    );
    // Rungs 3 and 3i are the lattice's cells alone; the method (4) shades a segment with its own
    // transfer where the bake has one (`BakeSettings::segment_transfer_paths`,
    // multiple::segment_transfer).
    let segment_cells = baked.transfer.cells.has_segment_cells();
    let lattice =
        segment_cells.then(|| Baked { transfer: baked.transfer.without_segment_cells(), ..baked.clone() });
    let lattice = lattice.as_ref().unwrap_or(baked);
    let method = if segment_cells {
        format!(
            "4 the method: each segment's own transfer ({} paths; under lobe cells its reflected light, beside their forward lobes) where it has one, else IIRTF interpolated between cells",
            baked.settings.segment_transfer_paths
        )
    } else {
        "4 the method: IIRTF interpolated between cells".into()
    };
    let per_cell = MethodOptions { interpolate_transfer: false, ..MethodOptions::default() };
    let unclamped = MethodOptions { clamp: ClampAtZero::Never, ..MethodOptions::default() };
    let mut method_rungs = vec![(format!("3 IIRTF per cell: {cells}"), lattice, per_cell)];
    if segment_cells {
        let name = "3i IIRTF interpolated between cells (rung 4 without the segments' own transfers)";
        method_rungs.push((name.into(), lattice, MethodOptions::default()));
    }
    method_rungs.extend([
        (method, baked, MethodOptions::default()),
        (
            "4' the method without its clamp at zero (rung 4 minus this: the clamp's bias)".into(),
            baked,
            unclamped,
        ),
        (
            "4'' the method with its clamp on each sample, not on each pixel's mean".into(),
            baked,
            MethodOptions { clamp: ClampAtZero::EachSample, ..MethodOptions::default() },
        ),
    ]);
    if baked.settings.fiber_lobes {
        method_rungs.extend([
            (
                "4f rung 4′ with the fiber lobes alone".into(),
                baked,
                MethodOptions { held: MultipleHeld::LobesOnly, ..unclamped },
            ),
            (
                "4g rung 4′ with the SH matrices alone (4f + 4g = 4′)".into(),
                baked,
                MethodOptions { held: MultipleHeld::MatricesOnly, ..unclamped },
            ),
        ]);
    }
    for (name, baked, options) in method_rungs {
        let t = Instant::now();
        let film = render_flat_with(scene, baked, Component::Multiple, settings.spp, settings.seed, options)?;
        push(Component::Multiple, name, &film, t.elapsed().as_secs_f64());
    }
    if settings.split_transfer {
        // A part is baked on the lattice's cells alone: a segment cell under lobe cells holds
        // the whole bake's reflected light by a rule the parts do not split, so with segment
        // cells the parts sum to rung 3i taken without its clamp, not to 4′.
        let whole = if segment_cells { "rung 3i without its clamp" } else { "rung 4′" };
        for (part, name) in [
            (
                TransferPart::FirstTransmission,
                format!("4a {whole} with the first neighbour's transmission alone"),
            ),
            (
                TransferPart::FirstReflection,
                format!("4b {whole} with the first neighbour's reflection alone"),
            ),
            (
                TransferPart::Later,
                format!("4c {whole} with light scattered twice or more (4a + 4b + 4c = it)"),
            ),
            (TransferPart::ForwardChains, format!("4d {whole} with the forward chains alone (against 2a)")),
            (
                TransferPart::AfterReflection,
                format!("4e {whole} with light reflected at least once (against 2b)"),
            ),
        ] {
            let t = Instant::now();
            let part_baked = with_transfer_part(scene, lattice, part)?;
            let film = render_flat_with(
                scene,
                &part_baked,
                Component::Multiple,
                settings.spp,
                settings.seed,
                unclamped,
            )?;
            push(Component::Multiple, name, &film, t.elapsed().as_secs_f64());
        }
    }
    let t = Instant::now();
    let options = MethodOptions { primary: voxel_hits, ..MethodOptions::default() };
    let film = render_flat_with(scene, baked, Component::Multiple, settings.spp, settings.seed, options)?;
    push(Component::Multiple, format!("5 the method on {voxels}"), &film, t.elapsed().as_secs_f64());
    Ok(Budget {
        rungs,
        width,
        height,
        settings: *settings,
        reference_seconds,
        single_reference,
        multiple_reference,
    })
}

/// Rung 2′: the method's transfer with each cell replaced by the hit's own segment. Every
/// segment a primary hit lands on gets the IIRTF of a cell that holds it alone, baked with the
/// bake's sampler, SH order, paths per cell and starts (its matrix only: no fiber lobes), and
/// the hit is shaded with it as rung 3 shades with its cell's. Against rung 3 it shows what
/// averaging the transfer over a cell costs, against rung 2 what the transfer itself costs
/// (the light's SH and the paths' noise) where the cells do not average.
fn per_segment_transfer(
    scene: &Scene,
    baked: &Baked,
    settings: &BudgetSettings,
) -> Result<Film, ShadingError> {
    let hit_segments = Mutex::new(BTreeSet::new());
    render_primary_hits(scene, settings.spp, settings.seed, |hit, _, _| {
        hit_segments
            .lock()
            .map_err(|_| ShadingError::Budget("a worker panicked".into()))?
            .insert(hit.segment);
        Ok(Rgb::ZERO)
    })?;
    let segments: Vec<u32> = hit_segments
        .into_inner()
        .map_err(|_| ShadingError::Budget("a worker panicked".into()))?
        .into_iter()
        .collect();
    let sampler = transfer_sampler(scene, baked)?;
    let order = baked.transfer.iirtf.sh_order;
    let paths = baked.settings.iirtf_paths_per_cell;
    let transfers: HashMap<u32, CellTransfer> = segments
        .par_iter()
        .filter_map(|&k| {
            bake_cell(
                &sampler,
                &[k],
                order,
                paths,
                false,
                MatrixLight::All,
                cell_stream(settings.seed, k),
                &|_| true,
            )
            .map(|transfer| (k, transfer))
        })
        .collect();
    let c_light = transfer_light_sh(baked, scene.path_scene.lights.iter().map(|light| (light, 1.0)));
    render_primary_hits(scene, settings.spp, settings.seed, |hit, wo, _| {
        let Some(seg) = SegmentShading::of(baked, hit.segment)? else {
            return Ok(Rgb::ZERO);
        };
        let cs = seg.cs_table(baked)?;
        let Some(transfer) = transfers.get(&hit.segment) else {
            return Ok(Rgb::ZERO);
        };
        Ok(multiple_scattering_in_cell(cs, transfer, seg.tangent, wo, &c_light))
    })
}

/// Rung 2e: rung 2's path-traced indirect light, taken not at the hit's segment midpoint but at
/// a point of that segment an eye sees, drawn as the bake draws its paths' starts
/// (`TransferSampler::exposed_start`: an eye direction uniform over the upper hemisphere, a
/// point of the fiber's side facing it that nothing hides), and scattered toward `wo` by the
/// hit's fiber. Its mean is the light the segment's transfer averages; against rung 1 it shows
/// what averaging over every eye's side of the fiber (instead of this view's) costs, against
/// rung 2′ what the transfer's SH and paths cost at those points. A segment no eye sees (all
/// tries fail) counts its midpoint, as the bake does.
fn at_exposed_starts(scene: &Scene, baked: &Baked, settings: &BudgetSettings) -> Result<Film, ShadingError> {
    let sampler = transfer_sampler(scene, baked)?;
    let fibers = &scene.path_scene.fibers;
    let segments = fibers.segments();
    render_primary_hits(scene, settings.spp, settings.seed, |hit, wo, rng| {
        // The sampler's points lie in its own central copy of the fabric: moved to the hit's.
        let local = segments[hit.segment as usize].midpoint().as_dvec3();
        let central = sampler.midpoint(hit.segment) - local;
        let start = sampler
            .exposed_start(&[hit.segment], 0, rng)
            .map_or_else(|| sampler.midpoint(hit.segment), |(_, point)| point);
        Ok(indirect_light(scene, hit, start - central + fibers.tile_offset(hit.tile), wo, rng))
    })
}

/// The bake's transfer sampler for `scene`: its materials, light domain and starts.
fn transfer_sampler(scene: &Scene, baked: &Baked) -> Result<TransferSampler, ShadingError> {
    let inputs =
        BakeInputs { exemplar: &scene.exemplar, materials: &scene.material_descs, settings: baked.settings };
    let (_, yarn_materials) = yarn_materials(&inputs)?;
    Ok(TransferSampler::new(&scene.exemplar, &yarn_materials, baked.transfer.iirtf.light_domain)
        .map_err(|e| ShadingError::Budget(format!("the transfer's sampler: {e}")))?
        .with_exposed_starts(baked.settings.exposed_starts)
        .with_light_samples(baked.settings.iirtf_light_samples))
}

/// `baked` with its IIRTF baked again holding only `part` of the transfer (same cells,
/// settings and paths: the parts of one bake sum to it).
fn with_transfer_part(scene: &Scene, baked: &Baked, part: TransferPart) -> Result<Baked, ShadingError> {
    let inputs =
        BakeInputs { exemplar: &scene.exemplar, materials: &scene.material_descs, settings: baked.settings };
    let (_, yarn_materials) = yarn_materials(&inputs)?;
    let options =
        IirtfOptions { light_domain: baked.transfer.iirtf.light_domain, part, colour_aware_walk: false };
    let iirtf = bake_iirtf(
        &scene.exemplar,
        &yarn_materials,
        &baked.transfer.cells,
        &baked.settings,
        &options,
        &Cancel::new(),
        &|_| {},
    )
    .map_err(|e| ShadingError::Budget(format!("baking the transfer's part {part:?}: {e}")))?;
    let mut out = baked.clone();
    out.transfer.iirtf = iirtf;
    Ok(out)
}

/// One rung's figures: `test` against the path-traced `reference`.
fn measure(component: Component, name: String, test: Estimate<'_>, reference: &Film, seconds: f64) -> Rung {
    let (r_mean, r_variance) = (reference.mean(), reference.variance_of_mean());
    let c = compare(test, Estimate { mean: &r_mean, variance: Some(&r_variance) });
    let level = (r_mean.mean().element_sum() / 3.0).max(f64::MIN_POSITIVE);
    let (test_rgb, reference_rgb) = (test.mean.mean(), r_mean.mean());
    let relative_error_rgb = Rgb::from_array(std::array::from_fn(|c| {
        if reference_rgb[c] > 0.0 { test_rgb[c] / reference_rgb[c] - 1.0 } else { test_rgb[c].abs() }
    }));
    Rung {
        component,
        name,
        relative_error_of_mean: c.relative_error_of_mean,
        relative_error_std: c.relative_error_of_mean_std,
        relative_error_rgb,
        relative_pixel_rmse: c.rmse / level,
        relative_noise_rmse: c.expected_noise_rmse / level,
        seconds,
    }
}

/// Single scattering at every primary hit by sampling the scene's lights (directional lights
/// exactly, SG lights with `light_samples` samples), the exact fiber scattering function and
/// `visible(hit, to_light)` as local visibility.
fn single_by_light_sampling(
    scene: &Scene,
    settings: &BudgetSettings,
    visible: impl Fn(&Hit, DVec3) -> bool + Sync,
) -> Result<Film, ShadingError> {
    render_primary_hits(scene, settings.spp, settings.seed, |hit, wo, rng| {
        let material = &scene.path_scene.yarn_materials[hit.yarn as usize];
        let (t, n) = (hit.tangent.as_dvec3(), hit.normal.as_dvec3());
        let mut total = Rgb::ZERO;
        for light in &scene.path_scene.lights {
            let samples =
                if matches!(light, Light::Directional { .. }) { 1 } else { settings.light_samples.max(1) };
            let mut sum = Rgb::ZERO;
            for _ in 0..samples {
                let s = light.sample([rng.random(), rng.random()]);
                let f = material.eval_cos(t, n, s.to_light, wo);
                if f != Rgb::ZERO && visible(hit, s.to_light) {
                    sum += f * s.weight;
                }
            }
            total += sum / f64::from(samples);
        }
        Ok(total)
    })
}

/// The visibility image (`segment points + point`) of `hit`: the point whose piece of the
/// segment holds the hit, as the method's shading finds it ([`Baked::visibility_image`]).
fn visibility_image_of(baked: &Baked, hit: &Hit) -> usize {
    baked.visibility_image(hit.segment as usize, hit.tangent.as_dvec3(), Some(hit.local_position.as_dvec3()))
}

/// Whether `dir` is unoccluded from `origin`'s choice of point for `hit` (the hit's own fiber
/// never occludes, as in the path tracer and the bake).
fn shadow_ray_visible(scene: &Scene, baked: &Baked, hit: &Hit, dir: DVec3, origin: ShadowOrigin) -> bool {
    let fibers = &scene.path_scene.fibers;
    let segment = &fibers.segments()[hit.segment as usize];
    let midpoint = segment.midpoint().as_dvec3() + fibers.tile_offset(hit.tile);
    let start = match origin {
        ShadowOrigin::HitPoint => fibers.world_position_f64(hit),
        ShadowOrigin::Midpoint => midpoint,
        ShadowOrigin::RaisedMidpoint => {
            visibility_origin(midpoint, segment.tangent().as_dvec3(), f64::from(segment.radius))
        }
        ShadowOrigin::RaisedHitsPoint => {
            let points = baked.visibility.points;
            let (a, b) = (segment.a.as_dvec3(), segment.b.as_dvec3());
            let along = visibility_point_fraction(visibility_image_of(baked, hit) % points, points);
            let point = a + (b - a) * along + fibers.tile_offset(hit.tile);
            visibility_origin(point, segment.tangent().as_dvec3(), f64::from(segment.radius))
        }
    };
    !below_ground(&scene.path_scene, start, dir)
        && !fibers.any_hit_f64(start, dir, f64::INFINITY, Some(hit.fiber))
}

/// One sample of `part` (`TransferPart::ForwardChains` or `AfterReflection`) of the indirect
/// light at `origin` scattered toward `wo` by `hit`'s fiber: a direction from the fiber's
/// scattering function, then a walk that lights every fiber event it reaches from the scene's
/// lights (next-event estimation alone, no light hit by a continuation counted: unbiased for
/// every light, exact for directional ones) and carries, beside its throughput, the TT
/// lobe's share of it from the first fiber it meets on (the IIRTF's definition of the parts;
/// the shaded fiber's own scattering is not part of the transfer).
fn indirect_light_part(
    scene: &Scene,
    hit: &Hit,
    origin: DVec3,
    wo: DVec3,
    part: TransferPart,
    rng: &mut Pcg64Mcg,
) -> Rgb {
    let path_scene = &scene.path_scene;
    let material = path_scene.material(hit);
    let (t, n) = (hit.tangent.as_dvec3(), hit.normal.as_dvec3());
    let Some((wi, pdf)) = material.sample(t, n, wo, [rng.random(), rng.random(), rng.random()]) else {
        return Rgb::ZERO;
    };
    let mut throughput = material.eval_cos(t, n, wi, wo) / pdf;
    let mut forward = throughput;
    let mut dir = wi;
    let mut next = trace(path_scene, origin, wi, Some(hit.fiber));
    let mut total = Rgb::ZERO;
    for event in 1..=scene.render.max_depth {
        let Some(h) = next else { break };
        let (position, t, n) = (h.position.as_dvec3(), h.tangent.as_dvec3(), h.normal.as_dvec3());
        let material = path_scene.material(&h);
        let wo = -dir;
        for light in &path_scene.lights {
            let sample = light.sample([rng.random(), rng.random()]);
            let to_light = sample.to_light;
            let f = material.eval_cos(t, n, to_light, wo);
            if f != Rgb::ZERO && !occluded(path_scene, position, to_light, h.fiber) {
                let f_tt = material.eval_cos_tt(t, to_light, wo);
                total += part.share(throughput * f, forward * f_tt) * sample.weight;
            }
        }
        let Some((wi, pdf)) = material.sample(t, n, wo, [rng.random(), rng.random(), rng.random()]) else {
            break;
        };
        let f = material.eval_cos(t, n, wi, wo);
        if f == Rgb::ZERO {
            break;
        }
        throughput *= f / pdf;
        forward *= material.eval_cos_tt(t, wi, wo) / pdf;
        let before = throughput.max_element();
        if !russian_roulette(event, &mut throughput, rng) {
            break;
        }
        forward *= throughput.max_element() / before;
        dir = wi;
        next = trace(path_scene, position, wi, Some(h.fiber));
    }
    total
}

/// One sample of rung 1′: the indirect light arriving at `origin` (one path of the path
/// tracer, as rung 1), projected on the bake's SH basis (order n) and scattered toward `wo` by
/// the method's `C_S` table of `hit`'s segment (`multiple::scatter_transferred`). Its mean is
/// exactly what the method would shade at the hit point from a transfer without error, so
/// rung 1 minus rung 1′ is what truncating the incident light and the fiber's scattering to
/// order n costs. The direction is drawn from an even mix of the uniform sphere (every SH
/// coefficient needs the whole sphere) and the fiber's scattering function (where the light
/// that counts comes from), and weighted by the mix's density.
fn incident_sh_scattered(
    scene: &Scene,
    baked: &Baked,
    hit: &Hit,
    origin: DVec3,
    wo: DVec3,
    rng: &mut Pcg64Mcg,
) -> Result<Rgb, ShadingError> {
    let Some(seg) = SegmentShading::of(baked, hit.segment)? else {
        return Ok(Rgb::ZERO);
    };
    let cs = seg.cs_table(baked)?;
    let material = &scene.path_scene.yarn_materials[hit.yarn as usize];
    let (t, n) = (hit.tangent.as_dvec3(), hit.normal.as_dvec3());
    let wi = if rng.random::<f64>() < 0.5 {
        uniform_sphere(rng.random(), rng.random())
    } else {
        match material.sample(t, n, wo, [rng.random(), rng.random(), rng.random()]) {
            Some((wi, _)) => wi,
            None => return Ok(Rgb::ZERO),
        }
    };
    let pdf = 0.5 / (4.0 * std::f64::consts::PI) + 0.5 * material.pdf(t, n, wo, wi);
    let settings =
        RenderSettings { spp: 1, max_depth: scene.render.max_depth, component: Component::All, seed: 0 };
    let incident = radiance_from(&scene.path_scene, origin, wi, Some(hit.fiber), &settings, rng) / pdf;
    if incident == Rgb::ZERO {
        return Ok(Rgb::ZERO);
    }
    let order = cs.sh_order();
    let mut basis = vec![0.0; sh_count(order)];
    sh_eval(order, wi, &mut basis);
    let projected: Vec<Rgb> = basis.iter().map(|y| incident * *y).collect();
    Ok(scatter_transferred(cs, &projected, seg.tangent, wo))
}

/// One sample of the indirect light at `origin` scattered toward `wo` by `hit`'s fiber: a
/// direction from the fiber's scattering function, then one path of the path tracer from
/// `origin` (which counts only light that touched a fiber).
fn indirect_light(scene: &Scene, hit: &Hit, origin: DVec3, wo: DVec3, rng: &mut Pcg64Mcg) -> Rgb {
    let material = &scene.path_scene.yarn_materials[hit.yarn as usize];
    let (t, n) = (hit.tangent.as_dvec3(), hit.normal.as_dvec3());
    let Some((wi, pdf)) = material.sample(t, n, wo, [rng.random(), rng.random(), rng.random()]) else {
        return Rgb::ZERO;
    };
    let settings =
        RenderSettings { spp: 1, max_depth: scene.render.max_depth, component: Component::All, seed: 0 };
    material.eval_cos(t, n, wi, wo) / pdf
        * radiance_from(&scene.path_scene, origin, wi, Some(hit.fiber), &settings, rng)
}
