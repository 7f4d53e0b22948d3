//! The bake pipeline: runs the stages in dependency order, each cached under the hash of
//! exactly what it depends on, so an edit reruns only the stages it invalidates.
//!
//! | stage | depends on |
//! |---|---|
//! | mean free path | geometry, `mfp_samples`, `seed` |
//! | visibility (SVF → SSDF → PCA, sum of SGs, the kept bits) | geometry, `svf_resolution`, `visibility_points`, `pca_components`, `visibility_bits`, `sos_count`, `sos_sharpness`, `seed` |
//! | transfer (cells, IIRTF) | geometry, materials, the mean free path, `cell_size_mfp`, `cell_depth_mfp`, `iirtf_paths_per_cell`, `sh_order`, `seed`, `fiber_lobes`, `exposed_starts`, `segment_transfer_paths`, `segment_pool_mfp` |
//! | C_S tables | materials, `sh_order`, `cs_theta_count` |
//! | Gn tables | materials |
//! | C_G table | `sh_order` |
//! | volume (voxels, segment table) | geometry (which includes each yarn's material slot), `voxels_per_fiber_diameter` |
//!
//! "Geometry" is the hash of the exemplar itself (every fiber point, radius, yarn, the tiling
//! and blocks), so it does not matter how the fabric was described. Lights are no input at all:
//! a light edit reruns nothing. Each key also hashes the stage's code version
//! ([`STAGE_VERSIONS`]): bump it when a stage's output changes meaning.
//!
//! With a [`Cache`], every stage first looks for its key; a missing, corrupt, truncated or
//! stale entry is recomputed (the cache deletes bad files and says why). A stage's result is
//! stored only once complete, through an atomic write, so a cancelled or failed bake leaves no
//! partial file. Stage results are serialized with serde (postcard) into one section each,
//! streamed into the file as it is written ([`BakeWriter::streamed_section`]): a bake never
//! holds an encoded copy of itself.

use std::path::Path;
use std::time::Instant;

use glam::DVec3;
use serde::Serialize;
use serde::de::DeserializeOwned;

use super::cells::{CellError, CellGrid};
use super::cs_table::{CsTable, CsTableError};
use super::file::{Array, ArrayData, BakeFile, BakeFileError, BakeWriter, Cache, ContentHash, Hasher};
use super::iirtf::{CellTransfer, Iirtf, IirtfError, IirtfOptions, bake_iirtf, pool_segment_cells};
use super::pattern::PatternMap;
use super::pca::{PcaBasis, PcaError, compress_images};
use super::recolour::{RecolourBasis, RecolourError, SlotColour, bake_recolour_basis};
use super::settings::{BakeSettings, MAX_VISIBILITY_POINTS};
use super::sum_of_sg::{SumOfSgError, SumOfSgVisibility, fit_weights};
use super::svf::{SvfError, VisibilityImages, render_exemplar, visibility_point_of};
use super::tables::{CG_DEFAULT_POINTS, CgTable, GnTable};
use super::volume::{
    EMPTY_VOXEL, Occupancy, SegmentTable, VolumeError, VoxelVolume, fit_resolution, rasterize,
};
use super::{Cancel, Cancelled};
use crate::bcsdf::{Material, MaterialDesc};
use crate::fabric::{Exemplar, Tiling};
use crate::params::ParamError;
use crate::raycast::{Extent, FiberScene, mean_free_path};
use crate::shading::{bits_lookup, erf_soft_visibility, ssdf_lookup, ssdf_step_visibility};

/// The stages, in the order they run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    MeanFreePath,
    Visibility,
    Transfer,
    CsTables,
    GnTables,
    CgTable,
    Volume,
}

impl Stage {
    pub const ALL: [Stage; 7] = [
        Stage::MeanFreePath,
        Stage::Visibility,
        Stage::Transfer,
        Stage::CsTables,
        Stage::GnTables,
        Stage::CgTable,
        Stage::Volume,
    ];

    /// The stage's name (also its section name in bake files).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::MeanFreePath => "mean_free_path",
            Self::Visibility => "visibility",
            Self::Transfer => "transfer",
            Self::CsTables => "cs_tables",
            Self::GnTables => "gn_tables",
            Self::CgTable => "cg_table",
            Self::Volume => "volume",
        }
    }

    fn version(self) -> u32 {
        STAGE_VERSIONS[self as usize]
    }
}

/// Code version of each stage, in [`Stage::ALL`] order: part of every cache key (visibility
/// 3: images at `visibility_points` points along each segment, 4: the kept bits and rays from
/// the centroid of the fiber's upper half, 5: each sum-of-SGs axis at the centroid of its
/// visible directions; transfer 5: the fiber lobes,
/// `CellTransfer::reflected` and the two shapes, and a kept cell's zero matrix, 6: the shapes'
/// azimuth as a Fourier series with its odd part toward the fabric's top, 7: the colour-free
/// walk weighed at the materials' colours, the recolouring basis's paths, 8: 24 longitudinal
/// Fourier terms, 9: 24 azimuthal ones, 10: segment cells, `bake::cells`, 11: a segment cell
/// under fiber lobes holds its reflected light, `iirtf::MatrixLight`, 12: the lobe shapes'
/// azimuth per light elevation about the fiber (`iirtf::fiber_elevation`), their longitudinal
/// terms per node of ω0·t (`iirtf::LOBE_LONGITUDINAL_BINS`), 13: a lobe shape per colour
/// channel (`iirtf::LOBE_CHANNEL_SHAPE_LEN`), 14: segment cells pooled with their yarn's
/// neighbours (`iirtf::pool_segment_cells`, `BakeSettings::segment_pool_mfp`); volume 3:
/// touching occupancy and the segments' capsules).
pub const STAGE_VERSIONS: [u32; 7] = [1, 5, 14, 1, 1, 1, 3];

/// Version of the serialized layout of [`Baked`] (part of the whole-file key; 4: the fiber
/// lobes' fields of `CellTransfer`; 5: `VisibilityData::points`, `SegmentTable::axis` and
/// `radius`; 6: `VisibilityData::bits`; 7: the lobe shapes' azimuthal Fourier terms; 8: 24 longitudinal
/// terms per lobe shape; 9: 24 azimuthal terms per elevation node; 10: the sum of SGs' packed
/// axes; 11: `CellGrid`'s segment cells, `BakeSettings::segment_transfer_paths`; 12: the lobe
/// shapes' longitudinal terms per node of ω0·t, `iirtf::LOBE_SHAPE_LEN`; 13: a lobe shape per
/// colour channel).
pub const BAKE_LAYOUT_VERSION: u32 = 13;

/// What a bake needs: the fabric, its material slots, the settings.
#[derive(Debug, Clone, Copy)]
pub struct BakeInputs<'a> {
    pub exemplar: &'a Exemplar,
    /// Material slots, indexed by `Yarn::material`.
    pub materials: &'a [MaterialDesc],
    pub settings: BakeSettings,
}

/// Mean free path ℓ as measured by ray casting.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MeanFreePathData {
    pub mean_cm: f64,
    pub std_error_cm: f64,
    pub escaped_fraction: f64,
}

/// Per-segment visibility: PCA-compressed SSDFs and sum-of-SGs weights, one of each per
/// visibility point (`points` per segment; image `k points + j` is point `j` of segment `k`,
/// [`Baked::visibility_image`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VisibilityData {
    /// Visibility images were `resolution x resolution` (see `svf`).
    pub resolution: usize,
    /// Visibility points per segment (`BakeSettings::visibility_points`).
    pub points: usize,
    pub ssdf: PcaBasis,
    /// The binary visibility images themselves, when `BakeSettings::visibility_bits` kept
    /// them: local visibility for directional and sharp SG lights in place of the PCA SSDF
    /// ([`VisibilityData::visibility`], [`VisibilityData::soft_visibility`]).
    pub bits: Option<VisibilityImages>,
    pub sum_of_sg: SumOfSgVisibility,
    /// Mean visible solid angle over the images (steradians), for reports.
    pub mean_visible_solid_angle: f64,
}

impl VisibilityData {
    /// Local visibility of image `image` toward a directional light's unit direction `dir`, in
    /// [0, 1]: with the kept binary images their visible fraction there (bilinear between
    /// pixel centres, `shading::bits_lookup`), else the hard step of the PCA SSDF (the paper).
    /// Twin: `local_visibility` in shaders/shared/shading.wgsl.
    #[must_use]
    pub fn visibility(&self, image: usize, dir: DVec3) -> f64 {
        match &self.bits {
            Some(bits) => bits_lookup(bits, image, dir),
            None => ssdf_step_visibility(ssdf_lookup(&self.ssdf, image, dir)),
        }
    }

    /// Local visibility of image `image` for a sharp SG light of unit axis `axis` and
    /// sharpness `lambda`, in [0, 1]: with the kept binary images their visible fraction
    /// toward the axis (the lobe is no wider than a pixel where this path runs, λ ≥ 100:
    /// 0.1 rad against 0.13 at 24²), else the erf step of the PCA SSDF (the paper). Twin:
    /// `local_soft_visibility` in shaders/shared/shading.wgsl.
    #[must_use]
    pub fn soft_visibility(&self, image: usize, axis: DVec3, lambda: f64) -> f64 {
        match &self.bits {
            Some(bits) => bits_lookup(bits, image, axis),
            None => erf_soft_visibility(ssdf_lookup(&self.ssdf, image, axis), lambda),
        }
    }
}

/// IIRTF cells and their transfer matrices.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TransferData {
    pub cells: CellGrid,
    pub iirtf: Iirtf,
}

impl TransferData {
    /// The transfer without its segment cells (`bake::cells`): the lattice's cells alone, as a
    /// bake with `segment_transfer_paths = 0` holds them (the error budget's rungs 3 and 3i).
    #[must_use]
    pub fn without_segment_cells(&self) -> Self {
        let cells = self.cells.clone().lattice_only();
        let mut iirtf = self.iirtf.clone();
        iirtf.cells.truncate(cells.cell_count());
        Self { cells, iirtf }
    }
}

/// Voxel volume of segment ids and the per-segment table.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VolumeData {
    pub volume: VoxelVolume,
    pub segments: SegmentTable,
}

/// Everything a bake produces.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Baked {
    pub settings: BakeSettings,
    pub materials: Vec<MaterialDesc>,
    pub mean_free_path: MeanFreePathData,
    pub visibility: VisibilityData,
    pub transfer: TransferData,
    /// C_S table per material slot (`None` for Lambertian materials, which have none).
    pub cs_tables: Vec<Option<CsTable>>,
    pub gn: GnTable,
    pub cg: CgTable,
    pub volume: VolumeData,
}

impl Baked {
    /// The visibility image (PCA SSDF and sum-of-SGs row) that shades `segment` (unit tangent
    /// `tangent`) at `position` (exemplar coordinates; `None`: the midpoint's): that of the
    /// visibility point whose piece of the segment holds `position`'s projection on its axis
    /// (`svf::visibility_point_of`), taken in the copy of a periodic exemplar nearest the
    /// segment (the voxel volume spans exactly one period). Twin: `visibility_image` in
    /// shaders/shared/shading.wgsl.
    #[must_use]
    pub fn visibility_image(&self, segment: usize, tangent: DVec3, position: Option<DVec3>) -> usize {
        let points = self.visibility.points.max(1);
        let point = match (position, self.volume.segments.axis.get(segment)) {
            (Some(p), Some(&[x, y, z, half_length])) if points > 1 => {
                let mut offset = p - DVec3::new(f64::from(x), f64::from(y), f64::from(z));
                if let Some(period) = self.volume.volume.period() {
                    offset.x -= period.x * (offset.x / period.x).round();
                    offset.y -= period.y * (offset.y / period.y).round();
                }
                visibility_point_of(offset.dot(tangent), f64::from(half_length), points)
            }
            _ => points / 2,
        };
        segment * points + point
    }

    /// The point the transfer is interpolated at for `segment` shaded at `position` (exemplar
    /// coordinates): `position`'s projection on the segment's axis, clamped to its ends, in
    /// the copy of a periodic exemplar that holds `position`. Cells are filled with the
    /// segments whose midpoints they hold, so a fiber's transfer belongs to its axis: taken at
    /// the surface hit itself (up to a fiber radius above the axis, a third of a cell's depth
    /// on the gabardine), the interpolation leaned toward the cells above, whose fibers are
    /// more exposed (backlit gabardine +13 points of multiple scattering; docs/BENCHMARKS.md).
    /// Twin: `transfer_point` in shaders/shared/shading.wgsl.
    #[must_use]
    pub fn transfer_point(&self, segment: usize, position: DVec3) -> DVec3 {
        let (Some(&[x, y, z, half_length]), Some(&[tx, ty, tz])) =
            (self.volume.segments.axis.get(segment), self.volume.segments.direction.get(segment))
        else {
            return position;
        };
        let mut offset = position - DVec3::new(f64::from(x), f64::from(y), f64::from(z));
        if let Some(period) = self.volume.volume.period() {
            offset.x -= period.x * (offset.x / period.x).round();
            offset.y -= period.y * (offset.y / period.y).round();
        }
        let tangent = DVec3::new(f64::from(tx), f64::from(ty), f64::from(tz));
        let half = f64::from(half_length);
        let along = offset.dot(tangent).clamp(-half, half);
        let point = position - offset + along * tangent;
        if point.is_finite() { point } else { position }
    }

    /// Checks that the sections agree with each other (a file can be intact and still hold
    /// sections from different bakes): one segment count everywhere, array sizes that match
    /// their counts, voxel ids and material slots in range, one SH order. Returns what
    /// disagrees.
    pub fn check_sections_agree(&self) -> Result<(), String> {
        let segments = self.volume.segments.len();
        let expect = |what: &str, got: usize, expected: usize| {
            if got == expected { Ok(()) } else { Err(format!("{what} is {got}, expected {expected}")) }
        };
        expect("segment directions", self.volume.segments.direction.len(), segments)?;
        let points = self.visibility.points;
        if !(1..=MAX_VISIBILITY_POINTS).contains(&points) {
            return Err(format!(
                "visibility points per segment is {points}, expected 1 to {MAX_VISIBILITY_POINTS}"
            ));
        }
        expect("segment axes", self.volume.segments.axis.len(), segments)?;
        expect("segment radii", self.volume.segments.radius.len(), segments)?;
        let images = segments * points;
        let ssdf = &self.visibility.ssdf;
        expect("visibility (PCA SSDF) images", ssdf.segment_count, images)?;
        expect("PCA mean values", ssdf.mean().len(), ssdf.dims)?;
        expect("PCA component values", ssdf.components().len(), ssdf.component_count * ssdf.dims)?;
        expect("PCA coefficients", ssdf.all_coefficients().len(), images * ssdf.component_count)?;
        if let Some(bits) = &self.visibility.bits {
            expect("binary visibility images", bits.segment_count(), images)?;
            expect("binary visibility image resolution", bits.resolution, self.visibility.resolution)?;
            if !bits.is_well_formed() {
                return Err("the binary visibility images' bits do not match their count".to_owned());
            }
        }
        let sos = &self.visibility.sum_of_sg;
        expect("visibility (sum of SGs) images", sos.segment_count, images)?;
        expect("sum-of-SG weights", sos.all_weights().len(), images * sos.count)?;
        expect("sum-of-SG rotations", sos.rotations().len(), images)?;
        expect("sum-of-SG axes", sos.all_packed_axes().len(), images * sos.count)?;
        expect("transfer (IIRTF cells) segments", self.transfer.cells.segment_count(), segments)?;
        expect("IIRTF matrices", self.transfer.iirtf.cells.len(), self.transfer.cells.cell_count())?;
        let order = self.transfer.iirtf.sh_order;
        expect("IIRTF SH order", order, self.settings.sh_order)?;
        expect("C_S tables", self.cs_tables.len(), self.materials.len())?;
        for table in self.cs_tables.iter().flatten() {
            expect("C_S table SH order", table.sh_order(), order)?;
        }
        let volume = &self.volume.volume;
        let voxels = volume.dims.iter().map(|&d| d as usize).product::<usize>();
        expect("voxel ids", volume.ids.len(), voxels)?;
        if let Some(id) = volume.ids.iter().find(|&&id| id != EMPTY_VOXEL && id as usize >= segments) {
            return Err(format!("a voxel names segment {id}, but there are {segments}"));
        }
        if let Some(m) = self.volume.segments.material.iter().find(|&&m| m as usize >= self.materials.len()) {
            return Err(format!("a segment names material slot {m}, but there are {}", self.materials.len()));
        }
        Ok(())
    }
}

/// Whether a stage ran or came from the cache.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StageSource {
    Computed,
    Cached,
    /// Kept from the previous bake ([`bake_material_preview`]): stale on purpose.
    Kept,
    /// Evaluated at the new colours from a recolouring basis ([`bake_material_preview`] with a
    /// [`RecolourBasis`]): an approximation until the full bake replaces it.
    Recoloured,
}

/// One stage of one bake: its key, where its result came from and how long it took.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageRun {
    pub stage: Stage,
    pub key: ContentHash,
    pub source: StageSource,
    pub seconds: f64,
}

/// A finished bake with its whole-file key and the record of its stages.
#[derive(Debug, Clone)]
pub struct BakeOutcome {
    pub key: ContentHash,
    pub baked: Baked,
    pub stages: Vec<StageRun>,
}

impl BakeOutcome {
    /// The stages that were computed (not loaded from the cache).
    #[must_use]
    pub fn computed(&self) -> Vec<Stage> {
        self.stages.iter().filter(|s| s.source == StageSource::Computed).map(|s| s.stage).collect()
    }
}

/// Why a bake failed.
#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    #[error("bake cancelled")]
    Cancelled,
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error("fabric: {0}")]
    Fabric(String),
    #[error("visibility: {0}")]
    Svf(#[from] SvfError),
    #[error("PCA: {0}")]
    Pca(#[from] PcaError),
    #[error("sum of SGs: {0}")]
    SumOfSg(#[from] SumOfSgError),
    #[error("IIRTF cells: {0}")]
    Cells(#[from] CellError),
    #[error("IIRTF: {0}")]
    Iirtf(#[from] IirtfError),
    #[error("C_S table: {0}")]
    CsTable(#[from] CsTableError),
    #[error("recolouring: {0}")]
    Recolour(#[from] RecolourError),
    #[error("volume: {0}")]
    Volume(#[from] VolumeError),
    #[error(transparent)]
    File(#[from] BakeFileError),
    #[error("patterned cloth: {0}")]
    Pattern(String),
    #[error("{stage}: could not serialize the result: {message}")]
    Serialize { stage: &'static str, message: String },
    #[error(
        "{}: this bake was made for another fabric: {bake}; the scene's fabric: {scene} (bake it for this scene, or render the scene it was made for)",
        file.display()
    )]
    OtherFabric { file: std::path::PathBuf, bake: String, scene: String },
}

impl From<Cancelled> for BakeError {
    fn from(_: Cancelled) -> Self {
        Self::Cancelled
    }
}

/// Progress of a bake: the stage and the fraction of it done.
pub type BakeProgress<'a> = &'a (dyn Fn(Stage, f64) + Sync);

/// Runs every stage (or loads it from `cache`), checking `cancel` often.
pub fn bake(
    inputs: &BakeInputs<'_>,
    cache: Option<&Cache>,
    cancel: &Cancel,
    progress: BakeProgress<'_>,
) -> Result<BakeOutcome, BakeError> {
    bake_stages(inputs, cache, cancel, progress, None, None)
}

/// A quick preview of a material edit: every stage of `inputs` except the two that carry
/// multiple scattering, transfer (the IIRTF, seconds to minutes) and the C_S tables. Without a
/// `recolour` basis they are kept from `previous`: single scattering (the Gn tables) is exact
/// for the new materials while multiple scattering stays as it was. With the basis of this
/// geometry and these settings ([`recolour_basis`]) they are evaluated at the new colours
/// (`bake::recolour`, milliseconds): multiple scattering follows the edit too, as an
/// approximation of the full bake. Either way the full [`bake`] replaces it when it finishes:
/// what an interactive editor shows in the meantime. `previous` must have been baked from the
/// same geometry with the same settings and material count (the geometry is the caller's
/// promise; settings and count are checked, and the basis's cell and slot counts). The result's
/// key marks it as a preview; never store it as a bake file.
pub fn bake_material_preview(
    inputs: &BakeInputs<'_>,
    previous: &Baked,
    recolour: Option<&RecolourBasis>,
    cache: Option<&Cache>,
    cancel: &Cancel,
    progress: BakeProgress<'_>,
) -> Result<BakeOutcome, BakeError> {
    if previous.settings != inputs.settings || previous.materials.len() != inputs.materials.len() {
        return Err(BakeError::Fabric(format!(
            "a material preview needs the previous bake's settings and {} material slots; it has {}",
            inputs.materials.len(),
            previous.materials.len()
        )));
    }
    // A basis made for other lobes does not hold: the preview keeps the previous bake's
    // multiple scattering then, as without one.
    let recolour = recolour.filter(|basis| basis.fits(inputs.materials));
    if let Some(basis) = recolour
        && (basis.cells.len() + basis.segment_cells != previous.transfer.iirtf.cells.len()
            || basis.slot_count != inputs.materials.len()
            || basis.sh_order != previous.settings.sh_order)
    {
        return Err(BakeError::Fabric(format!(
            "the recolouring basis ({} cells, {} slots, SH order {}) was not made for this bake ({} cells, {} slots, SH order {})",
            basis.cells.len() + basis.segment_cells,
            basis.slot_count,
            basis.sh_order,
            previous.transfer.iirtf.cells.len(),
            inputs.materials.len(),
            previous.settings.sh_order
        )));
    }
    bake_stages(inputs, cache, cancel, progress, Some((previous, recolour)), None)
}

/// The recolouring basis of `inputs` (`bake::recolour`): what [`bake_material_preview`] needs to
/// follow a colour edit with multiple scattering. Cached like a stage, under a key of the
/// geometry, the materials with their colours left out (the basis does not depend on them), the
/// mean free path and the transfer settings, so every recolouring of a fabric shares one.
///
/// # Errors
/// As [`bake`].
pub fn recolour_basis(
    inputs: &BakeInputs<'_>,
    cache: Option<&Cache>,
    cancel: &Cancel,
    progress: &(dyn Fn(f64) + Sync),
) -> Result<RecolourBasis, BakeError> {
    let s = &inputs.settings;
    s.validate()?;
    let keys = StageKeys::new(inputs)?;
    let mfp = StageRunner { cache, runs: &mut Vec::new() }
        .run(Stage::MeanFreePath, keys.mfp, || measure_mfp(inputs, cancel))?;
    let colour_free: Vec<MaterialDesc> = inputs.materials.iter().map(super::recolour::colour_free).collect();
    let free_hash = Hasher::new("twill.materials.colour_free")
        .serde(&colour_free)
        .map_err(|e| BakeError::Serialize { stage: "recolour key", message: e.to_string() })?
        .finish();
    let mut h = Hasher::new("twill.recolour");
    h.u32(RECOLOUR_VERSION)
        .hash(&keys.geometry)
        .hash(&free_hash)
        .f64(mfp.mean_cm)
        .f64(s.cell_size_mfp)
        .f64(s.cell_depth_mfp)
        .usize(s.iirtf_paths_per_cell)
        .usize(s.iirtf_light_samples)
        .usize(s.sh_order)
        .usize(s.cs_theta_count)
        .u64(s.seed)
        .bool(s.fiber_lobes)
        .bool(s.exposed_starts)
        .usize(s.segment_transfer_paths);
    let key = h.finish();
    let name = "recolour_basis";
    if let Some(file) = cache.and_then(|c| c.load(key)) {
        match decode_section::<RecolourBasis>(&file, name) {
            Ok(basis) => match basis.check_sizes() {
                Ok(()) => return Ok(basis),
                Err(e) => log::warn!("ignoring cached {name}: {e}"),
            },
            Err(e) => log::warn!("ignoring cached {name}: {e}"),
        }
    }
    let cells = CellGrid::for_bake(inputs.exemplar, mfp.mean_cm, s)?;
    let basis =
        bake_recolour_basis(inputs.exemplar, inputs.materials, &cells, s, cancel, progress).map_err(|e| {
            match e {
                RecolourError::Iirtf(IirtfError::Cancelled(_)) => BakeError::Cancelled,
                e => BakeError::Recolour(e),
            }
        })?;
    if let Some(cache) = cache {
        cache.store(&streamed(BakeWriter::new(key), name, name, key, &basis)?)?;
    }
    Ok(basis)
}

/// Version of the recolouring basis's code and layout: part of its cache key (8: the forward
/// lobes, `RecolourBasis::forward_lobe`; 9: their per-cell fold, the forward chains' own matrix;
/// 10: the fiber lobes, `RecolourBasis::fiber_lobes`: the whole matrix, both lobes' strengths at
/// `LOBE_SH_ORDER`, the forward cosine and both shapes per cell; 11: the shapes' azimuthal
/// Fourier terms; 12: 24 longitudinal terms per shape; 13: 24 azimuthal
/// terms per elevation node; 14: `RecolourBasis::segment_cells`; 15: the shapes' azimuth per
/// elevation about the fiber, their longitudinal terms per node of ω0·t).
const RECOLOUR_VERSION: u32 = 15;

/// Measures the mean free path of `inputs`' fabric (the mean free path stage).
fn measure_mfp(inputs: &BakeInputs<'_>, cancel: &Cancel) -> Result<MeanFreePathData, BakeError> {
    cancel.check()?;
    let fibers =
        FiberScene::new(inputs.exemplar, Extent::Unbounded).map_err(|e| BakeError::Fabric(e.to_string()))?;
    let m = mean_free_path(&fibers, inputs.settings.mfp_samples, inputs.settings.seed);
    if !(m.mean_cm.is_finite() && m.mean_cm > 0.0) {
        return Err(BakeError::Fabric(format!(
            "no mean free path could be measured ({:.0}% of rays escaped the fabric)",
            100.0 * m.escaped_fraction
        )));
    }
    Ok(MeanFreePathData {
        mean_cm: m.mean_cm,
        std_error_cm: m.std_error_cm,
        escaped_fraction: m.escaped_fraction,
    })
}

/// The raw results of the two expensive stages, computed elsewhere (the shards of a sharded
/// bake, `shard.rs`): the visibility image of every segment and every cell's IIRTF.
pub struct Precomputed {
    pub images: VisibilityImages,
    pub cells: Vec<CellTransfer>,
}

/// [`bake`] with the visibility images and the IIRTF cells taken (moved, not copied) from
/// `precomputed` instead of computed: the same pipeline on the same data, so the same bake (no
/// stage cache is used).
///
/// # Errors
/// As [`bake`], and when `precomputed` does not fit the inputs.
pub fn bake_precomputed(
    inputs: &BakeInputs<'_>,
    precomputed: Precomputed,
    cancel: &Cancel,
    progress: BakeProgress<'_>,
) -> Result<BakeOutcome, BakeError> {
    let points = inputs.settings.visibility_points;
    if precomputed.images.segment_count() != inputs.exemplar.segment_count() * points {
        return Err(BakeError::Fabric(format!(
            "{} precomputed visibility images for {} segments at {points} points each",
            precomputed.images.segment_count(),
            inputs.exemplar.segment_count()
        )));
    }
    bake_stages(inputs, None, cancel, progress, None, Some(precomputed))
}

/// The material of every material slot of `inputs`, and of every yarn of its exemplar.
///
/// # Errors
/// A material that cannot be built, or a yarn naming a slot that does not exist.
pub fn yarn_materials(inputs: &BakeInputs<'_>) -> Result<(Vec<Material>, Vec<Material>), ParamError> {
    let materials: Vec<Material> =
        inputs.materials.iter().map(Material::from_desc).collect::<Result<_, _>>()?;
    let yarn_materials: Vec<Material> = inputs
        .exemplar
        .yarns
        .iter()
        .map(|y| {
            materials.get(y.material as usize).cloned().ok_or_else(|| {
                ParamError::new(
                    "yarn material",
                    y.material,
                    format!("a material slot below {}", materials.len()),
                )
            })
        })
        .collect::<Result<_, _>>()?;
    Ok((materials, yarn_materials))
}

/// [`bake`], or with `keep` the preview of [`bake_material_preview`], or with `precomputed`
/// [`bake_precomputed`].
fn bake_stages(
    inputs: &BakeInputs<'_>,
    cache: Option<&Cache>,
    cancel: &Cancel,
    progress: BakeProgress<'_>,
    keep: Option<(&Baked, Option<&RecolourBasis>)>,
    precomputed: Option<Precomputed>,
) -> Result<BakeOutcome, BakeError> {
    let (precomputed_images, precomputed_cells) = precomputed.map(|p| (p.images, p.cells)).unzip();
    let s = &inputs.settings;
    s.validate()?;
    let (materials, yarn_materials) = yarn_materials(inputs)?;
    let keys = StageKeys::new(inputs)?;
    let mut runs = Vec::new();
    let mut stage_runner = StageRunner { cache, runs: &mut runs };

    let mfp = stage_runner.run(Stage::MeanFreePath, keys.mfp, || {
        let m = measure_mfp(inputs, cancel)?;
        progress(Stage::MeanFreePath, 1.0);
        Ok(m)
    })?;

    let visibility = stage_runner.run(Stage::Visibility, keys.visibility, || {
        let report = |f: f64| progress(Stage::Visibility, f);
        let images = match precomputed_images {
            Some(images) => images,
            None => render_exemplar(inputs.exemplar, s.svf_resolution, s.visibility_points, cancel, &|f| {
                report(0.7 * f);
            })?,
        };
        // The SSDFs are computed block by block as PCA reads them, never all held.
        let ssdf = compress_images(&images, s.pca_components, s.seed, cancel)?;
        report(0.95);
        let sum_of_sg =
            fit_weights(&images, s.sos_count, s.sos_sharpness, s.seed, s.visibility_points, cancel)?;
        let n = images.segment_count().max(1);
        let mean_visible_solid_angle =
            (0..images.segment_count()).map(|k| images.visible_solid_angle(k)).sum::<f64>() / n as f64;
        report(1.0);
        Ok(VisibilityData {
            resolution: s.svf_resolution,
            points: s.visibility_points,
            ssdf,
            bits: s.visibility_bits.then_some(images),
            sum_of_sg,
            mean_visible_solid_angle,
        })
    })?;

    let transfer_key = keys.transfer(&mfp);
    let transfer = if let Some((previous, recolour)) = keep {
        if let Some(basis) = recolour {
            stage_runner.recoloured(Stage::Transfer, transfer_key);
            let colours: Vec<SlotColour> = materials.iter().map(SlotColour::of).collect();
            // The basis holds the lattice's cells: the segment cells stay empty until a rebake.
            TransferData { cells: previous.transfer.cells.clone(), iirtf: basis.iirtf(&colours)? }
        } else {
            stage_runner.keep(Stage::Transfer, transfer_key);
            previous.transfer.clone()
        }
    } else {
        stage_runner.run(Stage::Transfer, transfer_key, || {
            let cells = CellGrid::for_bake(inputs.exemplar, mfp.mean_cm, s)?;
            let mut iirtf = match precomputed_cells {
                Some(precomputed) if precomputed.len() == cells.cell_count() => Iirtf {
                    sh_order: s.sh_order,
                    light_domain: IirtfOptions::default().light_domain,
                    cells: precomputed,
                },
                Some(precomputed) => {
                    return Err(BakeError::Fabric(format!(
                        "{} precomputed IIRTF cells for a grid of {}",
                        precomputed.len(),
                        cells.cell_count()
                    )));
                }
                None => bake_iirtf(
                    inputs.exemplar,
                    &yarn_materials,
                    &cells,
                    s,
                    &IirtfOptions::default(),
                    cancel,
                    &|f| progress(Stage::Transfer, f),
                )?,
            };
            // After the whole set of cells is in hand (a sharded bake's merged parts too).
            pool_segment_cells(inputs.exemplar, &cells, &mut iirtf.cells, s.segment_pool_mfp * mfp.mean_cm);
            Ok(TransferData { cells, iirtf })
        })?
    };

    let cs_tables = if let Some((previous, recolour)) = keep {
        if let Some(basis) = recolour {
            stage_runner.recoloured(Stage::CsTables, keys.cs);
            basis.cs_tables(inputs.materials)
        } else {
            stage_runner.keep(Stage::CsTables, keys.cs);
            previous.cs_tables.clone()
        }
    } else {
        stage_runner.run(Stage::CsTables, keys.cs, || {
            let mut tables = Vec::with_capacity(materials.len());
            for (i, m) in materials.iter().enumerate() {
                cancel.check()?;
                tables.push(match m {
                    Material::Fiber(fiber) => Some(CsTable::new(fiber, s.sh_order, s.cs_theta_count)?),
                    Material::Lambert(_) => None,
                });
                progress(Stage::CsTables, (i + 1) as f64 / materials.len() as f64);
            }
            Ok(tables)
        })?
    };

    let gn = stage_runner.run(Stage::GnTables, keys.gn, || Ok(GnTable::new(inputs.materials)?))?;
    let cg = stage_runner
        .run(Stage::CgTable, keys.cg, || Ok(CgTable::new(s.light_sh_order(), CG_DEFAULT_POINTS)?))?;

    let volume = stage_runner.run(Stage::Volume, keys.volume, || {
        let vpd = fit_resolution(inputs.exemplar, s.voxels_per_fiber_diameter)?;
        let volume =
            rasterize(inputs.exemplar, vpd, Occupancy::Touches, cancel, &|f| progress(Stage::Volume, f))?;
        Ok(VolumeData { volume, segments: SegmentTable::new(inputs.exemplar) })
    })?;

    let baked = Baked {
        settings: *s,
        materials: inputs.materials.to_vec(),
        mean_free_path: mfp,
        visibility,
        transfer,
        cs_tables,
        gn,
        cg,
        volume,
    };
    let key = whole_key(&runs);
    Ok(BakeOutcome { key, baked, stages: runs })
}

/// One or more baked exemplars and the map saying which exemplar covers each block of the
/// cloth (patterned cloth, paper section 6.4). A plain fabric is one exemplar and a uniform map.
#[derive(Debug, Clone)]
pub struct BakeSet {
    pub pattern: PatternMap,
    pub exemplars: Vec<BakeOutcome>,
}

impl BakeSet {
    /// A single exemplar covering every block.
    #[must_use]
    pub fn single(outcome: BakeOutcome) -> Self {
        Self { pattern: PatternMap::uniform(0), exemplars: vec![outcome] }
    }

    /// The whole file's key: the pattern and every exemplar's key.
    #[must_use]
    pub fn key(&self) -> ContentHash {
        let mut h = Hasher::new("twill.bake_set");
        h.u32(BAKE_LAYOUT_VERSION).u32(self.pattern.width).u32(self.pattern.height);
        for &e in &self.pattern.exemplar_of_block {
            h.u32(u32::from(e));
        }
        for outcome in &self.exemplars {
            h.hash(&outcome.key);
        }
        h.finish()
    }
}

/// A bake file as read back: its key, the pattern and every exemplar's data.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadedBake {
    pub key: ContentHash,
    pub pattern: PatternMap,
    pub exemplars: Vec<Baked>,
    /// The key of each exemplar's volume stage (its geometry and voxel size), to tell which
    /// fabric the bake was made for ([`LoadedBake::check_made_for`]).
    volume_keys: Vec<ContentHash>,
}

impl LoadedBake {
    /// Refuses a bake (read from `file`) that was not made for the fabric whose exemplars are
    /// `exemplars` (exemplar 0 first, then a patterned cloth's others), naming both: another
    /// number of exemplars, segments or fibers, or other fiber geometry.
    pub fn check_made_for(&self, file: &Path, exemplars: &[&Exemplar]) -> Result<(), BakeError> {
        let other =
            |bake: String, scene: String| BakeError::OtherFabric { file: file.to_owned(), bake, scene };
        if exemplars.len() != self.exemplars.len() {
            return Err(other(
                format!("{} exemplar(s)", self.exemplars.len()),
                format!("{} exemplar(s)", exemplars.len()),
            ));
        }
        for (i, ((baked, key), exemplar)) in
            self.exemplars.iter().zip(&self.volume_keys).zip(exemplars).enumerate()
        {
            let geometry = Hasher::new("twill.geometry").exemplar(exemplar).finish();
            if volume_key(&geometry, baked.settings.voxels_per_fiber_diameter) == *key {
                continue;
            }
            let scene_segments = exemplar.segment_count();
            let bake_segments = baked.volume.segments.len();
            let what = if scene_segments == bake_segments {
                "the same number of segments, other fiber geometry"
            } else {
                "another number of segments"
            };
            return Err(other(
                format!("exemplar {i} with {bake_segments} segments"),
                format!("{scene_segments} segments ({what})"),
            ));
        }
        Ok(())
    }
}

/// The volume stage's key: the geometry's hash and the voxel size.
fn volume_key(geometry: &ContentHash, voxels_per_fiber_diameter: f64) -> ContentHash {
    let mut h = Hasher::new("twill.stage");
    h.stage(Stage::Volume.name(), Stage::Volume.version()).hash(geometry).f64(voxels_per_fiber_diameter);
    h.finish()
}

/// Bakes every exemplar of a patterned cloth. All exemplars must have blocks of the same size
/// (blocks of different exemplars sit side by side), and the pattern may only name exemplars
/// that are given.
pub fn bake_set(
    inputs: &[BakeInputs<'_>],
    pattern: PatternMap,
    cache: Option<&Cache>,
    cancel: &Cancel,
    progress: BakeProgress<'_>,
) -> Result<BakeSet, BakeError> {
    if inputs.is_empty() {
        return Err(BakeError::Pattern("no exemplars to bake".into()));
    }
    if pattern.exemplar_count() > inputs.len() {
        return Err(BakeError::Pattern(format!(
            "the pattern names exemplar {} but only {} exemplar(s) are given",
            pattern.exemplar_count() - 1,
            inputs.len()
        )));
    }
    let block_size = |e: &Exemplar| match e.tiling {
        Tiling::Periodic { period } => Some(period / glam::Vec2::new(e.blocks.nx as f32, e.blocks.ny as f32)),
        Tiling::AsIs => None,
    };
    let describe = |size: Option<glam::Vec2>| {
        size.map_or_else(
            || "no blocks (used as-is)".to_owned(),
            |s| format!("blocks of {} x {} cm", s.x, s.y),
        )
    };
    let first = block_size(inputs[0].exemplar);
    for (i, input) in inputs.iter().enumerate().skip(1) {
        let size = block_size(input.exemplar);
        let same = match (first, size) {
            (Some(a), Some(b)) => (a - b).abs().max_element() <= 1e-5 * a.max_element(),
            _ => false,
        };
        if !same {
            return Err(BakeError::Pattern(format!(
                "exemplar {i} has {}, exemplar 0 has {}: patterned exemplars must be periodic with equal block sizes",
                describe(size),
                describe(first)
            )));
        }
    }
    let exemplars =
        inputs.iter().map(|input| bake(input, cache, cancel, progress)).collect::<Result<_, _>>()?;
    Ok(BakeSet { pattern, exemplars })
}

/// Writes a bake set atomically: the pattern, then for exemplar `i` one section `e{i}.STAGE`
/// per stage (with that stage's key) and `e{i}.inputs`.
pub fn write_bake(path: &Path, set: &BakeSet) -> Result<(), BakeError> {
    let mut writer = streamed(BakeWriter::new(set.key()), "pattern", "pattern", set.key(), &set.pattern)?;
    for (i, outcome) in set.exemplars.iter().enumerate() {
        let b = &outcome.baked;
        let sections: [(Stage, &dyn erased::Encode); 7] = [
            (Stage::MeanFreePath, &b.mean_free_path),
            (Stage::Visibility, &b.visibility),
            (Stage::Transfer, &b.transfer),
            (Stage::CsTables, &b.cs_tables),
            (Stage::GnTables, &b.gn),
            (Stage::CgTable, &b.cg),
            (Stage::Volume, &b.volume),
        ];
        for (stage, value) in sections {
            let key = outcome.stages.iter().find(|r| r.stage == stage).map_or(outcome.key, |r| r.key);
            writer = streamed(writer, &format!("e{i}.{}", stage.name()), stage.name(), key, value)?;
        }
        writer = writer.section(
            &format!("e{i}.inputs"),
            outcome.key,
            Array::vector(ArrayData::U8(encode_settings(b)?)),
        );
    }
    writer.write(path)?;
    Ok(())
}

/// Reads a bake file written by [`write_bake`]; every integrity check of the file format runs
/// first, and a section that does not decode is reported as corrupt.
pub fn read_bake(path: &Path) -> Result<LoadedBake, BakeError> {
    let file = BakeFile::open_unkeyed(path)?;
    let pattern: PatternMap = decode_section(&file, "pattern")?;
    let mut exemplars = Vec::new();
    let mut volume_keys = Vec::new();
    while file.section(&format!("e{}.inputs", exemplars.len())).is_some() {
        let e = format!("e{}.", exemplars.len());
        let inputs = decode_inputs(&file, &format!("{e}inputs"))?;
        let section = |stage: Stage| format!("{e}{}", stage.name());
        let volume = file
            .section(&section(Stage::Volume))
            .ok_or_else(|| corrupt_section(&file, &section(Stage::Volume), "missing".into()))?;
        volume_keys.push(volume.key);
        exemplars.push(Baked {
            settings: inputs.settings,
            materials: inputs.materials,
            mean_free_path: decode_section(&file, &section(Stage::MeanFreePath))?,
            visibility: decode_section(&file, &section(Stage::Visibility))?,
            transfer: decode_section(&file, &section(Stage::Transfer))?,
            cs_tables: decode_section(&file, &section(Stage::CsTables))?,
            gn: decode_section(&file, &section(Stage::GnTables))?,
            cg: decode_section(&file, &section(Stage::CgTable))?,
            volume: decode_section(&file, &section(Stage::Volume))?,
        });
    }
    for (i, baked) in exemplars.iter().enumerate() {
        baked.check_sections_agree().map_err(|what| corrupt_section(&file, &format!("e{i}"), what))?;
    }
    if exemplars.is_empty() || pattern.exemplar_count() > exemplars.len() {
        return Err(BakeError::File(BakeFileError::InvalidSection {
            name: format!("{}: pattern", path.display()),
            what: format!(
                "names {} exemplar(s), the file holds {}",
                pattern.exemplar_count(),
                exemplars.len()
            ),
        }));
    }
    Ok(LoadedBake { key: file.key(), pattern, exemplars, volume_keys })
}

/// The settings and materials a bake was made with, stored as TOML text (materials are
/// internally tagged enums, which postcard cannot decode; TOML also keeps them readable).
#[derive(serde::Serialize, serde::Deserialize)]
struct InputsRecord {
    settings: BakeSettings,
    materials: Vec<MaterialDesc>,
}

fn encode_settings(b: &Baked) -> Result<Vec<u8>, BakeError> {
    let record = InputsRecord { settings: b.settings, materials: b.materials.clone() };
    toml::to_string(&record)
        .map(String::into_bytes)
        .map_err(|e| BakeError::Serialize { stage: "inputs", message: e.to_string() })
}

fn decode_inputs(file: &BakeFile, name: &str) -> Result<InputsRecord, BakeError> {
    let bytes = section_bytes(file, name)?;
    let text =
        std::str::from_utf8(bytes).map_err(|e| corrupt_section(file, name, format!("not UTF-8: {e}")))?;
    toml::from_str(text).map_err(|e| corrupt_section(file, name, format!("does not parse: {e}")))
}

/// Adds `value` to `writer` as a streamed section `name` (encoded once here for its length,
/// then again as the file is written).
fn streamed<'a>(
    writer: BakeWriter<'a>,
    name: &str,
    what: &'static str,
    key: ContentHash,
    value: &'a dyn erased::Encode,
) -> Result<BakeWriter<'a>, BakeError> {
    let len = value
        .encode_into(&mut std::io::sink())
        .map_err(|e| BakeError::Serialize { stage: what, message: e.to_string() })?;
    Ok(writer.streamed_section(name, key, len, move |w| value.encode_into(w).map(|_| ())))
}

/// Postcard encoding straight into a writer, for the streamed sections of [`write_bake`].
mod erased {
    use std::io::{self, BufWriter, Write};

    use postcard::ser_flavors::Flavor;
    use serde::Serialize;

    /// A value that can be encoded (postcard) into any writer; object safe, so one list can
    /// hold every stage's result.
    pub trait Encode {
        /// Encodes into `w`, returning the byte count.
        fn encode_into(&self, w: &mut dyn Write) -> io::Result<u64>;
    }

    impl<T: Serialize> Encode for T {
        fn encode_into(&self, w: &mut dyn Write) -> io::Result<u64> {
            let mut flavor =
                WriterFlavor { out: BufWriter::with_capacity(1 << 16, w), count: 0, error: None };
            match postcard::serialize_with_flavor::<T, _, _>(self, &mut flavor) {
                Ok(()) => {
                    flavor.out.flush()?;
                    Ok(flavor.count)
                }
                Err(e) => Err(flavor.error.take().unwrap_or_else(|| io::Error::other(e.to_string()))),
            }
        }
    }

    /// A postcard output that writes through, counting bytes and keeping the first I/O error.
    struct WriterFlavor<'w> {
        out: BufWriter<&'w mut dyn Write>,
        count: u64,
        error: Option<io::Error>,
    }

    impl Flavor for &mut WriterFlavor<'_> {
        type Output = ();

        fn try_extend(&mut self, data: &[u8]) -> postcard::Result<()> {
            match self.out.write_all(data) {
                Ok(()) => {
                    self.count += data.len() as u64;
                    Ok(())
                }
                Err(e) => {
                    self.error = Some(e);
                    Err(postcard::Error::SerializeBufferFull)
                }
            }
        }

        fn try_push(&mut self, data: u8) -> postcard::Result<()> {
            self.try_extend(&[data])
        }

        fn finalize(self) -> postcard::Result<()> {
            Ok(())
        }
    }
}

fn decode_section<T: DeserializeOwned>(file: &BakeFile, name: &str) -> Result<T, BakeError> {
    postcard::from_bytes(section_bytes(file, name)?)
        .map_err(|e| corrupt_section(file, name, format!("does not decode: {e}")))
}

/// The bytes of a byte section, or an error naming the file and section.
fn section_bytes<'f>(file: &'f BakeFile, name: &str) -> Result<&'f [u8], BakeError> {
    let section = file.section(name).ok_or_else(|| corrupt_section(file, name, "missing".into()))?;
    section.array.as_u8().ok_or_else(|| corrupt_section(file, name, "not a byte section".into()))
}

fn corrupt_section(file: &BakeFile, name: &str, what: String) -> BakeError {
    BakeError::File(BakeFileError::InvalidSection {
        name: format!("{}: {name}", file.path().display()),
        what,
    })
}

/// Runs stages through the cache and records what happened.
struct StageRunner<'a, 'b> {
    cache: Option<&'a Cache>,
    runs: &'b mut Vec<StageRun>,
}

impl StageRunner<'_, '_> {
    fn run<T, F>(&mut self, stage: Stage, key: ContentHash, compute: F) -> Result<T, BakeError>
    where
        T: Serialize + DeserializeOwned,
        F: FnOnce() -> Result<T, BakeError>,
    {
        let started = Instant::now();
        if let Some(value) = self.cache.and_then(|c| c.load(key)).and_then(|file| {
            let decoded = decode_section(&file, stage.name());
            if let Err(e) = &decoded {
                log::warn!("ignoring cached {}: {e}", stage.name());
            }
            decoded.ok()
        }) {
            self.record(stage, key, StageSource::Cached, started);
            return Ok(value);
        }
        let value = compute()?;
        if let Some(cache) = self.cache {
            cache.store(&streamed(BakeWriter::new(key), stage.name(), stage.name(), key, &value)?)?;
        }
        self.record(stage, key, StageSource::Computed, started);
        Ok(value)
    }

    /// Records a stage whose result is kept from an earlier bake (a preview): its key is
    /// derived from the key the stage would have, so no preview's whole key equals a bake's.
    fn keep(&mut self, stage: Stage, key: ContentHash) {
        let kept = Hasher::new("twill.kept_from_previous").hash(&key).finish();
        self.record(stage, kept, StageSource::Kept, Instant::now());
    }

    /// Records a stage evaluated from a recolouring basis (a preview), keyed like [`Self::keep`].
    fn recoloured(&mut self, stage: Stage, key: ContentHash) {
        let recoloured = Hasher::new("twill.recoloured_from_basis").hash(&key).finish();
        self.record(stage, recoloured, StageSource::Recoloured, Instant::now());
    }

    fn record(&mut self, stage: Stage, key: ContentHash, source: StageSource, started: Instant) {
        self.runs.push(StageRun { stage, key, source, seconds: started.elapsed().as_secs_f64() });
    }
}

/// The cache key of every stage (see the module docs for what each depends on).
struct StageKeys {
    geometry: ContentHash,
    materials: ContentHash,
    settings: BakeSettings,
    mfp: ContentHash,
    visibility: ContentHash,
    cs: ContentHash,
    gn: ContentHash,
    cg: ContentHash,
    volume: ContentHash,
}

impl StageKeys {
    fn new(inputs: &BakeInputs<'_>) -> Result<Self, BakeError> {
        let s = inputs.settings;
        let geometry = Hasher::new("twill.geometry").exemplar(inputs.exemplar).finish();
        let materials = Hasher::new("twill.materials")
            .serde(&inputs.materials)
            .map_err(|e| BakeError::Serialize { stage: "materials key", message: e.to_string() })?
            .finish();
        let key = |stage: Stage| {
            let mut h = Hasher::new("twill.stage");
            h.stage(stage.name(), stage.version());
            h
        };
        let mfp = key(Stage::MeanFreePath).hash(&geometry).usize(s.mfp_samples).u64(s.seed).finish();
        let visibility = key(Stage::Visibility)
            .hash(&geometry)
            .usize(s.svf_resolution)
            .usize(s.visibility_points)
            .usize(s.pca_components)
            .bool(s.visibility_bits)
            .usize(s.sos_count)
            .f64(s.sos_sharpness)
            .u64(s.seed)
            .finish();
        let cs = key(Stage::CsTables).hash(&materials).usize(s.sh_order).usize(s.cs_theta_count).finish();
        let gn = key(Stage::GnTables).hash(&materials).finish();
        let cg = key(Stage::CgTable).usize(s.light_sh_order()).usize(CG_DEFAULT_POINTS).finish();
        let volume = volume_key(&geometry, s.voxels_per_fiber_diameter);
        Ok(Self { geometry, materials, settings: s, mfp, visibility, cs, gn, cg, volume })
    }

    /// The transfer stage also depends on the measured mean free path (it sizes the cells).
    fn transfer(&self, mfp: &MeanFreePathData) -> ContentHash {
        let s = self.settings;
        let mut h = Hasher::new("twill.stage");
        h.stage(Stage::Transfer.name(), Stage::Transfer.version())
            .hash(&self.geometry)
            .hash(&self.materials)
            .f64(mfp.mean_cm)
            .f64(s.cell_size_mfp)
            .f64(s.cell_depth_mfp)
            .usize(s.iirtf_paths_per_cell)
            .usize(s.iirtf_light_samples)
            .usize(s.sh_order)
            .u64(s.seed)
            .u32(u32::from(s.fiber_lobes))
            .u32(u32::from(s.exposed_starts))
            .usize(s.segment_transfer_paths)
            .f64(s.segment_pool_mfp);
        h.finish()
    }
}

/// The whole bake's key: every stage key plus the layout version.
fn whole_key(runs: &[StageRun]) -> ContentHash {
    let mut h = Hasher::new("twill.bake");
    h.u32(BAKE_LAYOUT_VERSION);
    for r in runs {
        h.str(r.stage.name()).hash(&r.key);
    }
    h.finish()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::Rgb;
    use crate::bcsdf::FiberParams;
    use crate::fabric::presets::{FabricSpec, WeaveSource, fabric_preset};
    use crate::fabric::weave::WeavePreset;

    /// A plain weave with very few fibers, and settings small enough for a test.
    pub(crate) fn tiny(weave: WeavePreset) -> (Exemplar, Vec<MaterialDesc>) {
        tiny_with_blocks(weave, [1, 1])
    }

    fn tiny_with_blocks(weave: WeavePreset, blocks: [u32; 2]) -> (Exemplar, Vec<MaterialDesc>) {
        let preset = fabric_preset("cotton_plain").unwrap();
        let FabricSpec::Woven(mut spec) = preset.fabric else { panic!("cotton_plain is woven") };
        spec.weave = WeaveSource::Preset(weave);
        spec.blocks = blocks;
        spec.warp.fibers_per_ply = 3;
        spec.weft.fibers_per_ply = 3;
        let exemplar = FabricSpec::Woven(spec).build(Path::new(".")).unwrap();
        (exemplar, vec![preset.warp_material, preset.weft_material])
    }

    fn test_settings() -> BakeSettings {
        BakeSettings {
            svf_resolution: 8,
            visibility_points: 2,
            pca_components: 4,
            visibility_bits: true,
            sos_count: 8,
            sos_sharpness: 128.0,
            cell_size_mfp: 16.0,
            cell_depth_mfp: 16.0,
            iirtf_paths_per_cell: 8,
            iirtf_light_samples: 1,
            sh_order: 2,
            cs_theta_count: 8,
            voxels_per_fiber_diameter: 0.5,
            mfp_samples: 400,
            seed: 3,
            fiber_lobes: false,
            exposed_starts: true,
            segment_transfer_paths: 0,
            segment_pool_mfp: 0.0,
        }
    }

    fn run(
        exemplar: &Exemplar,
        materials: &[MaterialDesc],
        settings: BakeSettings,
        cache: &Cache,
    ) -> BakeOutcome {
        let inputs = BakeInputs { exemplar, materials, settings };
        bake(&inputs, Some(cache), &Cancel::new(), &|_, _| {}).unwrap()
    }

    fn with_colour(material: MaterialDesc, c_tt: Rgb) -> MaterialDesc {
        match material {
            MaterialDesc::Fiber(p) => MaterialDesc::Fiber(FiberParams { c_tt, ..p }),
            MaterialDesc::Lambert { .. } => MaterialDesc::Lambert { albedo: c_tt },
        }
    }

    #[test]
    fn each_kind_of_edit_reruns_exactly_the_stages_that_depend_on_it() {
        use Stage::{CgTable as Cg, CsTables, GnTables, MeanFreePath, Transfer, Visibility, Volume};
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::new(dir.path()).unwrap();
        let (exemplar, materials) = tiny(WeavePreset::Plain);
        let settings = test_settings();

        let first = run(&exemplar, &materials, settings, &cache);
        assert_eq!(first.computed(), Stage::ALL.to_vec(), "a cold cache computes everything");

        // Nothing changed (a light edit changes no bake input): everything comes from the cache.
        let again = run(&exemplar, &materials, settings, &cache);
        assert!(again.computed().is_empty(), "{:?}", again.computed());
        assert_eq!(again.key, first.key);
        assert_eq!(again.baked, first.baked);

        // A BCSDF colour edit: transfer and the material tables, not visibility or geometry.
        let recoloured = [with_colour(materials[0], Rgb::new(0.2, 0.6, 0.3)), materials[1]];
        let edit = run(&exemplar, &recoloured, settings, &cache);
        assert_eq!(edit.computed(), vec![Transfer, CsTables, GnTables]);
        assert_ne!(edit.key, first.key);

        // Keeping the binary visibility images or not: the visibility stage alone.
        let without_bits = BakeSettings { visibility_bits: false, ..settings };
        let edit = run(&exemplar, &materials, without_bits, &cache);
        assert_eq!(edit.computed(), vec![Visibility]);
        assert!(edit.baked.visibility.bits.is_none() && first.baked.visibility.bits.is_some());

        // SH order: transfer and the SH tables.
        let higher = BakeSettings { sh_order: 3, ..settings };
        assert_eq!(run(&exemplar, &materials, higher, &cache).computed(), vec![Transfer, CsTables, Cg]);

        // A weave edit: everything that depends on geometry.
        let (twill, _) = tiny(WeavePreset::Twill2_2);
        assert_eq!(
            run(&twill, &materials, settings, &cache).computed(),
            vec![MeanFreePath, Visibility, Transfer, Volume]
        );
    }

    #[test]
    fn a_material_preview_updates_single_scattering_and_keeps_multiple_scattering() {
        use Stage::{CsTables, GnTables, Transfer};
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::new(dir.path()).unwrap();
        let (exemplar, materials) = tiny(WeavePreset::Plain);
        let settings = test_settings();
        let before = run(&exemplar, &materials, settings, &cache);

        // A new colour and a wider TT lobe for the warp.
        let recoloured = match with_colour(materials[0], Rgb::new(0.2, 0.6, 0.3)) {
            MaterialDesc::Fiber(p) => {
                [MaterialDesc::Fiber(FiberParams { beta_tt_deg: p.beta_tt_deg + 5.0, ..p }), materials[1]]
            }
            MaterialDesc::Lambert { .. } => panic!("cotton_plain has fiber materials"),
        };
        let inputs = BakeInputs { exemplar: &exemplar, materials: &recoloured, settings };
        let preview =
            bake_material_preview(&inputs, &before.baked, None, Some(&cache), &Cancel::new(), &|_, _| {})
                .unwrap();
        // Only the Gn tables are computed; transfer and C_S are the old ones, on purpose.
        assert_eq!(preview.computed(), vec![GnTables]);
        let kept: Vec<Stage> =
            preview.stages.iter().filter(|r| r.source == StageSource::Kept).map(|r| r.stage).collect();
        assert_eq!(kept, vec![Transfer, CsTables]);
        assert_eq!(preview.baked.transfer, before.baked.transfer);
        assert_eq!(preview.baked.cs_tables, before.baked.cs_tables);
        assert_eq!(preview.baked.materials, recoloured.to_vec());

        // The full bake then computes what the preview kept, and agrees with it on the rest.
        let full = run(&exemplar, &recoloured, settings, &cache);
        assert_eq!(full.computed(), vec![Transfer, CsTables]);
        assert_eq!(full.baked.gn, preview.baked.gn);
        assert_ne!(full.baked.gn, before.baked.gn, "the edit changed single scattering");
        assert_ne!(full.baked.transfer, before.baked.transfer, "and multiple scattering");
        assert_ne!(preview.key, full.key, "a preview's key is never a bake's");

        // A preview from a bake with other settings is refused.
        let other = BakeSettings { sh_order: 3, ..settings };
        let inputs = BakeInputs { exemplar: &exemplar, materials: &recoloured, settings: other };
        let refused = bake_material_preview(&inputs, &before.baked, None, None, &Cancel::new(), &|_, _| {});
        assert!(matches!(refused, Err(BakeError::Fabric(_))), "{refused:?}");
    }

    #[test]
    fn a_preview_recolours_from_a_basis_of_the_same_lobes_only() {
        use Stage::{CsTables, Transfer};
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::new(dir.path()).unwrap();
        let (exemplar, materials) = tiny(WeavePreset::Plain);
        let settings = test_settings();
        let before = run(&exemplar, &materials, settings, &cache);
        let inputs = BakeInputs { exemplar: &exemplar, materials: &materials, settings };
        let basis = recolour_basis(&inputs, Some(&cache), &Cancel::new(), &|_| {}).unwrap();
        // Cached under a key without the colours: another colouring loads the same basis (loads
        // it: nothing is computed, so no progress is reported).
        let recoloured = [with_colour(materials[0], Rgb::new(0.2, 0.6, 0.3)), materials[1]];
        let inputs = BakeInputs { exemplar: &exemplar, materials: &recoloured, settings };
        let computed = std::sync::atomic::AtomicBool::new(false);
        let progress = |_: f64| computed.store(true, std::sync::atomic::Ordering::Relaxed);
        assert_eq!(recolour_basis(&inputs, Some(&cache), &Cancel::new(), &progress).unwrap(), basis);
        assert!(!computed.into_inner(), "the cached basis was computed again, not loaded");
        let preview =
            bake_material_preview(&inputs, &before.baked, Some(&basis), None, &Cancel::new(), &|_, _| {})
                .unwrap();
        let recoloured_stages: Vec<Stage> =
            preview.stages.iter().filter(|r| r.source == StageSource::Recoloured).map(|r| r.stage).collect();
        assert_eq!(recoloured_stages, vec![Transfer, CsTables]);
        assert_ne!(preview.baked.transfer.iirtf, before.baked.transfer.iirtf, "multiple scattering follows");
        let full = run(&exemplar, &recoloured, settings, &cache);
        assert_eq!(preview.baked.cs_tables.len(), full.baked.cs_tables.len());
        for (a, b) in preview.baked.cs_tables.iter().flatten().zip(full.baked.cs_tables.iter().flatten()) {
            for (x, y) in a.coefficients().iter().zip(b.coefficients()) {
                assert!((*x - *y).abs().max_element() <= 1e-9 * (1.0 + y.abs().max_element()));
            }
        }
        // Other lobes: the basis does not hold, and the preview keeps the previous transfer.
        let MaterialDesc::Fiber(p) = recoloured[0] else { panic!("cotton_plain has fiber materials") };
        let wider =
            [MaterialDesc::Fiber(FiberParams { beta_tt_deg: p.beta_tt_deg + 5.0, ..p }), materials[1]];
        let inputs = BakeInputs { exemplar: &exemplar, materials: &wider, settings };
        let preview =
            bake_material_preview(&inputs, &before.baked, Some(&basis), None, &Cancel::new(), &|_, _| {})
                .unwrap();
        assert!(preview.stages.iter().all(|r| r.source != StageSource::Recoloured));
        assert_eq!(preview.baked.transfer, before.baked.transfer);
    }

    #[test]
    fn a_cancelled_bake_stores_nothing_and_writes_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::new(&dir.path().join("cache")).unwrap();
        let (exemplar, materials) = tiny(WeavePreset::Plain);
        let cancel = Cancel::new();
        cancel.cancel();
        let inputs = BakeInputs { exemplar: &exemplar, materials: &materials, settings: test_settings() };
        let result = bake(&inputs, Some(&cache), &cancel, &|_, _| {});
        assert!(matches!(result, Err(BakeError::Cancelled)), "{result:?}");
        let stored = std::fs::read_dir(cache.dir()).unwrap().filter_map(Result::ok).count();
        assert_eq!(stored, 0, "a cancelled bake leaves no cache entry");
    }

    #[test]
    fn bake_files_round_trip_and_corruption_is_detected() {
        let dir = tempfile::tempdir().unwrap();
        let (exemplar, materials) = tiny(WeavePreset::Plain);
        let inputs = BakeInputs { exemplar: &exemplar, materials: &materials, settings: test_settings() };
        let outcome = bake(&inputs, None, &Cancel::new(), &|_, _| {}).unwrap();
        let path = dir.path().join("x.twillbake");
        let set = BakeSet::single(outcome.clone());
        write_bake(&path, &set).unwrap();
        let loaded = read_bake(&path).unwrap();
        assert_eq!(loaded.key, set.key());
        assert_eq!(loaded.exemplars, vec![outcome.baked.clone()]);
        assert_eq!(loaded.pattern, PatternMap::uniform(0));
        // Made for this fabric, not for another weave or a patterned cloth of two exemplars.
        loaded.check_made_for(&path, &[&exemplar]).expect("made for this fabric");
        let (twill, _) = tiny(WeavePreset::Twill2_2);
        let err = loaded.check_made_for(&path, &[&twill]).unwrap_err().to_string();
        assert!(err.contains("x.twillbake") && err.contains("another fabric"), "{err}");
        assert!(err.contains(&format!("{} segments", exemplar.segment_count())), "{err}");
        assert!(err.contains(&format!("{} segments", twill.segment_count())), "{err}");
        let err = loaded.check_made_for(&path, &[&exemplar, &twill]).unwrap_err().to_string();
        assert!(err.contains("1 exemplar(s)") && err.contains("2 exemplar(s)"), "{err}");
        // An intact file whose sections come from different bakes is refused, naming what.
        let twill_inputs = BakeInputs { exemplar: &twill, materials: &materials, settings: test_settings() };
        let twill_baked = bake(&twill_inputs, None, &Cancel::new(), &|_, _| {}).unwrap().baked;
        let mixed_path = dir.path().join("mixed.twillbake");
        for (what, mixed) in [
            ("visibility", Baked { visibility: twill_baked.visibility.clone(), ..outcome.baked.clone() }),
            ("transfer", Baked { transfer: twill_baked.transfer.clone(), ..outcome.baked.clone() }),
            (
                "binary visibility images",
                Baked {
                    visibility: VisibilityData {
                        bits: twill_baked.visibility.bits.clone(),
                        ..outcome.baked.visibility.clone()
                    },
                    ..outcome.baked.clone()
                },
            ),
            (
                "SH order",
                Baked {
                    settings: BakeSettings {
                        sh_order: outcome.baked.settings.sh_order + 1,
                        ..outcome.baked.settings
                    },
                    ..outcome.baked.clone()
                },
            ),
        ] {
            let mut set = BakeSet::single(outcome.clone());
            set.exemplars[0].baked = mixed;
            write_bake(&mixed_path, &set).unwrap();
            let err = read_bake(&mixed_path).map(|_| ()).unwrap_err().to_string();
            assert!(err.contains("mixed.twillbake") && err.contains("e0"), "{what}: {err}");
            assert!(err.contains(what), "{what}: {err}");
        }

        let bytes = std::fs::read(&path).unwrap();
        for position in [0, 9, 70, bytes.len() / 2, bytes.len() - 1] {
            let mut bad = bytes.clone();
            bad[position] ^= 0x10;
            std::fs::write(&path, &bad).unwrap();
            assert!(read_bake(&path).is_err(), "flipped byte {position} went unnoticed");
        }
        std::fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
        let err = read_bake(&path).unwrap_err().to_string();
        assert!(err.contains("x.twillbake"), "{err}");
    }

    #[test]
    fn a_patterned_bake_holds_every_exemplar_and_its_map() {
        let dir = tempfile::tempdir().unwrap();
        let (plain, materials) = tiny(WeavePreset::Plain);
        // Basket repeats over 4 x 4 yarns, plain over 2 x 2: 2 x 2 blocks make them the same size.
        let (basket, _) = tiny_with_blocks(WeavePreset::Basket, [2, 2]);
        let settings = test_settings();
        let inputs = [
            BakeInputs { exemplar: &plain, materials: &materials, settings },
            BakeInputs { exemplar: &basket, materials: &materials, settings },
        ];
        let pattern = PatternMap::from_rows(&["0110", "1001"]).unwrap();
        let set = bake_set(&inputs, pattern.clone(), None, &Cancel::new(), &|_, _| {}).unwrap();
        let path = dir.path().join("patterned.twillbake");
        write_bake(&path, &set).unwrap();
        let loaded = read_bake(&path).unwrap();
        assert_eq!(loaded.pattern, pattern);
        assert_eq!(loaded.exemplars.len(), 2);
        assert_ne!(loaded.exemplars[0].volume, loaded.exemplars[1].volume, "different weaves");

        // The map may not name an exemplar that is not given.
        let three = PatternMap::from_rows(&["012"]).unwrap();
        let err = bake_set(&inputs, three, None, &Cancel::new(), &|_, _| {}).unwrap_err().to_string();
        assert!(err.contains("exemplar 2"), "{err}");
    }
}
