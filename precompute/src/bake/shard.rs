//! Sharded bakes: the two expensive stages of one bake split across processes or machines,
//! and the parts merged into the bake a single process would have written, byte for byte.
//!
//! How it works: a bake's cost is in two stages whose work items are independent — the
//! visibility image of every segment (`svf::render_segments`: each image depends only on its
//! segment) and the IIRTF of every cell (`iirtf::bake_iirtf_cells`: cell `c` draws from its own
//! random stream, `cell_stream(seed, c)`). Shard `I` of `N` ([`Shard`]) takes the `I`-th of `N`
//! contiguous, balanced slices of the segments and of the cells of every exemplar
//! ([`Shard::slice`]; cells weighted by whether they hold segments, [`Shard::slice_weighted`],
//! since an empty cell costs nothing) and writes their raw results, with the inputs' key and a caller's record
//! (what the command line needs to rebuild the inputs), to a part file ([`bake_part`],
//! [`write_part`]). [`merge_parts`] checks that the parts are the `N` shards of one bake of
//! these inputs, each once, joins the slices in order and runs the bake's pipeline with them in
//! place of the two stages (`pipeline::bake_precomputed`): the rest — the SSDFs and their PCA,
//! the sums of SGs, the tables and the voxel volume — is the same code on the same data, so the
//! merged bake equals the single-process bake whatever `N`.
//!
//! Segment cells (`bake::cells`, `BakeSettings::segment_transfer_paths`) are cells like the
//! others here, but what one holds depends on its lattice cell's fiber lobes and on the whole
//! lattice's reflected light (`iirtf::segment_cell_light`): with fiber lobes, a shard whose
//! slice reaches the segment cells bakes the whole lattice first, as a single-process bake does
//! (the lattice's cells are about a fifth of the interactive preset's paths on the default
//! fabric), so the two still agree byte for byte.
//!
//! The IIRTF entries are kept as the bake stores them (f32; rounding them again when merging
//! changes nothing), and empty cells (no segments, no paths) without entries, as in a bake file.
//! With fiber lobes (`BakeSettings::fiber_lobes`) every nonempty cell's flag says whether it
//! keeps its lobes (its matrix is then zero), and each cell that does has its forward strength
//! and cosine, its reflected strength and its two shapes in sections of their own
//! ([`write_part`]). Part files use the bake file container (`file.rs`: magic, version,
//! checksum, atomic writes), keyed by [`inputs_key`], which holds [`PART_LAYOUT_VERSION`]; a
//! part of an older layout, of other inputs, a missing or repeated shard, or a slice that does
//! not match its shard is an error naming the file.

use std::ops::Range;
use std::path::{Path, PathBuf};

use super::Cancel;
use super::cells::CellGrid;
use super::file::{Array, ArrayData, BakeFile, BakeFileError, BakeWriter, ContentHash, Hasher};
use super::iirtf::{CellTransfer, IirtfOptions, LOBE_SH_ORDER, LOBE_SHAPE_LEN, bake_iirtf_cells};
use super::pattern::PatternMap;
use super::pipeline::{
    BakeError, BakeInputs, BakeProgress, BakeSet, Precomputed, Stage, bake_precomputed, yarn_materials,
};
use super::settings::MAX_VISIBILITY_POINTS;
use super::svf::{VisibilityImages, render_segments};
use crate::raycast::{Extent, FiberScene, mean_free_path};
use crate::sh::sh_count;

/// Most shards of one bake.
pub const MAX_SHARDS: usize = 4096;

/// Version of the part file's layout: in its header (`layout`, absent in version 1) and in
/// [`inputs_key`], so a part of another layout is refused (2: the fiber lobes, each kept
/// cell's forward and reflected strength, forward cosine and two shapes, where version 1 held
/// a forward lobe of n coefficients and a cosine; 3: `e{i}.resolution` also holds the
/// visibility points per segment, and `e{i}.images` that many images per segment; 4: each
/// shape opens with its azimuthal Fourier terms; 5: the same layout, its IIRTF cells from the
/// colour-free walk, so that parts of two walks never merge into one bake; 6: 24 longitudinal
/// terms per shape; 7: 24 azimuthal terms per elevation node; 8: the cells include the segment
/// cells, `bake::cells`; 9: the same layout, a segment cell under fiber lobes holding its
/// reflected light or nothing, where it held all of its light and the merge emptied it; 10: a
/// lobe shape per colour channel, `iirtf::LOBE_SHAPE_LEN` three channels' floats).
pub const PART_LAYOUT_VERSION: u32 = 10;

/// Shard `index` of `count` (0-based: `0/4` .. `3/4`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

/// Why a shard, a part file or a merge was refused.
#[derive(Debug, thiserror::Error)]
pub enum ShardError {
    #[error("--shard {text:?}: expected I/N with 0 <= I < N <= {MAX_SHARDS}, e.g. 0/4")]
    Parse { text: String },
    #[error("{}: {what}", file.display())]
    Part { file: PathBuf, what: String },
    #[error("the parts do not make one bake: {0}")]
    Set(String),
    #[error(transparent)]
    File(#[from] BakeFileError),
    #[error(transparent)]
    Bake(#[from] BakeError),
}

impl Shard {
    /// Parses `I/N`.
    ///
    /// # Errors
    /// Anything but `I/N` with `0 <= I < N <= MAX_SHARDS`.
    pub fn parse(text: &str) -> Result<Self, ShardError> {
        let bad = || ShardError::Parse { text: text.to_owned() };
        let (i, n) = text.split_once('/').ok_or_else(bad)?;
        let (index, count): (usize, usize) =
            (i.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
        if count == 0 || count > MAX_SHARDS || index >= count {
            return Err(bad());
        }
        Ok(Self { index, count })
    }

    /// This shard's slice of `total` items: the `index`-th of `count` contiguous slices whose
    /// sizes differ by at most one.
    #[must_use]
    pub fn slice(&self, total: usize) -> Range<usize> {
        let at = |k: usize| (total as u128 * k as u128 / self.count as u128) as usize;
        at(self.index)..at(self.index + 1)
    }
}

impl Shard {
    /// This shard's slice of items of the given `weights`: the `index`-th of `count`
    /// contiguous slices of about equal total weight (slice `k` starts at the first item where
    /// the running total reaches `k / count` of the whole). Without any weight, [`Shard::slice`].
    #[must_use]
    pub fn slice_weighted(&self, weights: &[u64]) -> Range<usize> {
        let total: u128 = weights.iter().map(|&w| u128::from(w)).sum();
        if total == 0 {
            return self.slice(weights.len());
        }
        let start_of = |k: usize| -> usize {
            if k >= self.count {
                return weights.len();
            }
            let target = total * k as u128 / self.count as u128;
            let mut sum = 0_u128;
            for (i, &w) in weights.iter().enumerate() {
                if sum >= target {
                    return i;
                }
                sum += u128::from(w);
            }
            weights.len()
        };
        start_of(self.index)..start_of(self.index + 1)
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// One shard's results for one exemplar.
#[derive(Debug, Clone, PartialEq)]
pub struct ExemplarPart {
    pub segments: Range<usize>,
    /// Visibility images of `segments`, in order.
    pub images: VisibilityImages,
    pub cells: Range<usize>,
    /// IIRTF of `cells`, in order.
    pub transfer: Vec<CellTransfer>,
}

/// One shard's results for every exemplar of a bake set.
#[derive(Debug, Clone, PartialEq)]
pub struct BakePart {
    pub shard: Shard,
    /// [`inputs_key`] of the inputs it was computed from.
    pub key: ContentHash,
    pub exemplars: Vec<ExemplarPart>,
}

/// What identifies a bake's inputs: every exemplar's geometry, materials and settings.
///
/// # Errors
/// When the materials or settings cannot be serialized.
pub fn inputs_key(inputs: &[BakeInputs<'_>]) -> Result<ContentHash, BakeError> {
    let mut h = Hasher::new("twill.bake_part");
    h.u32(PART_LAYOUT_VERSION).usize(inputs.len());
    for input in inputs {
        let serialize =
            |e: toml::ser::Error| BakeError::Serialize { stage: "part key", message: e.to_string() };
        h.exemplar(input.exemplar);
        h.serde(&input.materials).map_err(serialize)?;
        h.serde(&input.settings).map_err(serialize)?;
    }
    Ok(h.finish())
}

/// Computes shard `shard` of a bake of `inputs`: its slice of every exemplar's visibility
/// images and IIRTF cells (the mean free path, which sets the cells, is measured in full:
/// it is cheap and the same in every shard).
///
/// # Errors
/// Bad settings or fabric, or a cancellation.
pub fn bake_part(
    inputs: &[BakeInputs<'_>],
    shard: Shard,
    cancel: &Cancel,
    progress: BakeProgress<'_>,
) -> Result<BakePart, BakeError> {
    let key = inputs_key(inputs)?;
    let mut exemplars = Vec::with_capacity(inputs.len());
    for input in inputs {
        let s = &input.settings;
        s.validate()?;
        let (_, yarns) = yarn_materials(input)?;
        let scene = FiberScene::new(input.exemplar, Extent::Unbounded)
            .map_err(|e| BakeError::Fabric(e.to_string()))?;
        let mfp = mean_free_path(&scene, s.mfp_samples, s.seed);
        progress(Stage::MeanFreePath, 1.0);
        let segments = shard.slice(input.exemplar.segment_count());
        let ids: Vec<u32> = segments.clone().map(|k| k as u32).collect();
        let images = render_segments(&scene, &ids, s.svf_resolution, s.visibility_points, cancel, &|f| {
            progress(Stage::Visibility, f);
        })?;
        let grid = CellGrid::for_bake(input.exemplar, mfp.mean_cm, s)?;
        // Balanced by work: a cell with segments costs its paths, an empty one nothing.
        let weights: Vec<u64> =
            (0..grid.cell_count() as u32).map(|c| u64::from(!grid.segments_in_cell(c).is_empty())).collect();
        let cells = shard.slice_weighted(&weights);
        let transfer = bake_iirtf_cells(
            input.exemplar,
            &yarns,
            &grid,
            s,
            &IirtfOptions::default(),
            cells.clone(),
            cancel,
            &|f| progress(Stage::Transfer, f),
        )?;
        exemplars.push(ExemplarPart { segments, images, cells, transfer });
    }
    Ok(BakePart { shard, key, exemplars })
}

/// Merges the parts of every shard of a bake of `inputs` into the bake set a single process
/// would have made.
///
/// # Errors
/// Parts of other inputs, a missing or repeated shard, slices that do not tile the work, or a
/// failure of the remaining stages.
pub fn merge_parts(
    inputs: &[BakeInputs<'_>],
    pattern: PatternMap,
    mut parts: Vec<BakePart>,
    cancel: &Cancel,
    progress: BakeProgress<'_>,
) -> Result<BakeSet, ShardError> {
    let key = inputs_key(inputs)?;
    let set = |what: String| ShardError::Set(what);
    let count = parts.first().map(|p| p.shard.count).ok_or_else(|| set("no parts given".into()))?;
    if let Some(p) = parts.iter().find(|p| p.key != key) {
        return Err(set(format!(
            "shard {} was computed from other inputs (another scene, quality or settings)",
            p.shard
        )));
    }
    if let Some(p) = parts.iter().find(|p| p.shard.count != count) {
        return Err(set(format!(
            "shard {} is of a {}-way split, the first part of a {count}-way split",
            p.shard, p.shard.count
        )));
    }
    parts.sort_by_key(|p| p.shard.index);
    for (k, p) in parts.iter().enumerate() {
        if p.shard.index != k {
            let what = if p.shard.index < k { "given twice" } else { "missing" };
            return Err(set(format!("shard {k}/{count} is {what} ({} parts given)", parts.len())));
        }
    }
    if parts.len() != count {
        return Err(set(format!("{} of {count} shards given", parts.len())));
    }
    let mut exemplars = Vec::with_capacity(inputs.len());
    for (e, input) in inputs.iter().enumerate() {
        let mut images = Vec::with_capacity(count);
        let mut cells = Vec::new();
        for p in &mut parts {
            let shard = p.shard;
            let part =
                p.exemplars.get_mut(e).ok_or_else(|| set(format!("shard {shard} has no exemplar {e}")))?;
            let expected = shard.slice(input.exemplar.segment_count());
            let images_expected = expected.len() * input.settings.visibility_points;
            if part.segments != expected || part.images.segment_count() != images_expected {
                return Err(set(format!(
                    "shard {shard}, exemplar {e}: segments {:?}, expected {expected:?}",
                    part.segments
                )));
            }
            if part.transfer.len() != part.cells.len() || (cells.len() != part.cells.start) {
                return Err(set(format!(
                    "shard {shard}, exemplar {e}: cells {:?} do not follow the previous shard's",
                    part.cells
                )));
            }
            // Moved out of the part, not copied: a merge holds each cell once.
            let resolution = part.images.resolution;
            images.push(std::mem::replace(&mut part.images, VisibilityImages::new(resolution, 0)));
            cells.append(&mut part.transfer);
        }
        let images = VisibilityImages::concat(&images)
            .ok_or_else(|| set(format!("exemplar {e}: the parts' visibility images differ in resolution")))?;
        let precomputed = Precomputed { images, cells };
        exemplars.push(bake_precomputed(input, precomputed, cancel, progress)?);
    }
    Ok(BakeSet { pattern, exemplars })
}

/// Writes `part` atomically, with `record`: what the caller needs to rebuild the inputs.
///
/// Sections: `part` (the header: shard, exemplar count, [`PART_LAYOUT_VERSION`]) and
/// `record`, then per exemplar `e{i}.`: `segments`, `resolution` (the visibility images'
/// resolution and points per segment) and `images` (their bits, point after point of each
/// segment), `cells`, `paths` (per cell), `entries` (n² of a nonempty cell), `matrix` and
/// `std_error` (RGB f32 per entry of every nonempty cell), `lobes` (per nonempty cell, 1 where
/// it keeps its fiber lobes), and for each cell that does: `forward` (its forward strength,
/// RGB per coefficient at `LOBE_SH_ORDER`, then its forward cosine), `reflected` (its
/// reflected strength) and `shapes` (its forward shape, then its reflected shape).
///
/// # Errors
/// When the file cannot be written.
pub fn write_part(path: &Path, part: &BakePart, record: &str) -> Result<(), ShardError> {
    let key = part.key;
    let bytes = |b: Vec<u8>| Array::vector(ArrayData::U8(b));
    let u32s = |v: Vec<u32>| Array::vector(ArrayData::U32(v));
    let header = format!(
        "shard = \"{}\"\nexemplars = {}\nlayout = {PART_LAYOUT_VERSION}\n",
        part.shard,
        part.exemplars.len()
    );
    let mut writer = BakeWriter::new(key).section("part", key, bytes(header.into_bytes())).section(
        "record",
        key,
        bytes(record.as_bytes().to_vec()),
    );
    for (e, x) in part.exemplars.iter().enumerate() {
        let range = |r: &Range<usize>| u32s(vec![r.start as u32, r.end as u32]);
        let (mut matrix, mut error, mut lobes) = (Vec::new(), Vec::new(), Vec::new());
        let (mut forward, mut reflected, mut shapes) = (Vec::new(), Vec::new(), Vec::new());
        for cell in x.transfer.iter().filter(|c| c.paths > 0) {
            matrix.extend(cell.matrix.iter().flatten());
            error.extend(cell.std_error.iter().flatten());
            lobes.push(u32::from(cell.has_lobes()));
            if cell.has_lobes() {
                forward.extend(cell.forward.iter().flatten().chain(&cell.forward_cosine));
                reflected.extend(cell.reflected.iter().flatten());
                shapes.extend(cell.forward_shape.iter().chain(&cell.reflected_shape));
            }
        }
        let entries = x.transfer.iter().find(|c| !c.is_empty()).map_or(0, |c| c.matrix.len()) as u32;
        let words: Vec<u8> = x.images.words().iter().flat_map(|w| w.to_le_bytes()).collect();
        let resolution = x.images.resolution as u32;
        let points = x.images.segment_count().checked_div(x.segments.len()).unwrap_or(1).max(1) as u32;
        writer = writer
            .section(&format!("e{e}.segments"), key, range(&x.segments))
            .section(&format!("e{e}.resolution"), key, u32s(vec![resolution, points]))
            .section(&format!("e{e}.images"), key, bytes(words))
            .section(&format!("e{e}.cells"), key, range(&x.cells))
            .section(&format!("e{e}.paths"), key, u32s(x.transfer.iter().map(|c| c.paths as u32).collect()))
            .section(&format!("e{e}.entries"), key, u32s(vec![entries]))
            .section(&format!("e{e}.matrix"), key, Array::vector(ArrayData::F32(matrix)))
            .section(&format!("e{e}.std_error"), key, Array::vector(ArrayData::F32(error)))
            .section(&format!("e{e}.lobes"), key, u32s(lobes))
            .section(&format!("e{e}.forward"), key, Array::vector(ArrayData::F32(forward)))
            .section(&format!("e{e}.reflected"), key, Array::vector(ArrayData::F32(reflected)))
            .section(&format!("e{e}.shapes"), key, Array::vector(ArrayData::F32(shapes)));
    }
    writer.write(path)?;
    Ok(())
}

/// Reads a part file: the part and its record.
///
/// # Errors
/// A file that is not a whole part file, naming the file and what is wrong.
pub fn read_part(path: &Path) -> Result<(BakePart, String), ShardError> {
    let file = BakeFile::open_unkeyed(path)?;
    let bad = |what: String| ShardError::Part { file: path.to_owned(), what };
    let section =
        |name: &str| file.section(name).ok_or_else(|| bad(format!("no section {name:?}: not a part file")));
    let text = |name: &str| -> Result<String, ShardError> {
        let bytes =
            section(name)?.array.as_u8().ok_or_else(|| bad(format!("section {name:?} is not text")))?;
        String::from_utf8(bytes.to_vec()).map_err(|_| bad(format!("section {name:?} is not UTF-8")))
    };
    let u32s = |name: &str| -> Result<Vec<u32>, ShardError> {
        Ok(section(name)?.array.as_u32().ok_or_else(|| bad(format!("section {name:?} is not u32")))?.to_vec())
    };
    let f32s = |name: &str| -> Result<Vec<f32>, ShardError> {
        Ok(section(name)?.array.as_f32().ok_or_else(|| bad(format!("section {name:?} is not f32")))?.to_vec())
    };
    let range = |name: &str| -> Result<Range<usize>, ShardError> {
        match u32s(name)?[..] {
            [a, b] if a <= b => Ok(a as usize..b as usize),
            ref v => Err(bad(format!("section {name:?}: {v:?} is not a range"))),
        }
    };
    let header: toml::Table = text("part")?.parse().map_err(|e| bad(format!("section \"part\": {e}")))?;
    let shard = header
        .get("shard")
        .and_then(toml::Value::as_str)
        .ok_or_else(|| bad("section \"part\" names no shard".into()))?;
    let shard = Shard::parse(shard).map_err(|e| bad(e.to_string()))?;
    let layout = header.get("layout").map_or(Some(1), toml::Value::as_integer);
    if layout != Some(i64::from(PART_LAYOUT_VERSION)) {
        return Err(bad(format!(
            "a part file of layout {}, this build reads layout {PART_LAYOUT_VERSION}: bake the shard again",
            layout.map_or_else(|| "?".to_owned(), |l| l.to_string())
        )));
    }
    let count =
        header.get("exemplars").and_then(toml::Value::as_integer).filter(|&n| (1..=4096).contains(&n));
    let count = count.ok_or_else(|| bad("section \"part\": exemplars must be 1..=4096".into()))? as usize;
    let mut exemplars = Vec::with_capacity(count);
    for e in 0..count {
        let segments = range(&format!("e{e}.segments"))?;
        let (resolution, points) = match u32s(&format!("e{e}.resolution"))?[..] {
            [r, p] if (1..=4096).contains(&r) && (1..=MAX_VISIBILITY_POINTS as u32).contains(&p) => {
                (r as usize, p as usize)
            }
            ref v => {
                return Err(bad(format!(
                    "e{e}.resolution: {v:?} is not a resolution in 1..=4096 and points per segment in 1..={MAX_VISIBILITY_POINTS}"
                )));
            }
        };
        let bytes = section(&format!("e{e}.images"))?
            .array
            .as_u8()
            .ok_or_else(|| bad(format!("e{e}.images is not bytes")))?;
        let words: Vec<u64> =
            bytes.chunks_exact(8).map(|w| u64::from_le_bytes(w.try_into().expect("8 bytes"))).collect();
        let image_count = segments.len() * points;
        let images = VisibilityImages::from_words(resolution, image_count, words).ok_or_else(|| {
            bad(format!("e{e}.images: not {image_count} images of {resolution}x{resolution} bits"))
        })?;
        let cells = range(&format!("e{e}.cells"))?;
        let paths = u32s(&format!("e{e}.paths"))?;
        let entries = match u32s(&format!("e{e}.entries"))?[..] {
            [n] if n <= 1 << 20 => n as usize,
            ref v => return Err(bad(format!("e{e}.entries: {v:?} is not an entry count"))),
        };
        let (matrix, error) = (f32s(&format!("e{e}.matrix"))?, f32s(&format!("e{e}.std_error"))?);
        let nonempty = paths.iter().filter(|&&p| p > 0).count();
        if paths.len() != cells.len() || matrix.len() != 3 * entries * nonempty || error.len() != matrix.len()
        {
            return Err(bad(format!(
                "e{e}: {} cells ({} path counts, {nonempty} with paths) of {entries} entries, but {} and {} transfer values",
                cells.len(),
                paths.len(),
                matrix.len(),
                error.len()
            )));
        }
        let rgb = |v: &[f32]| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        // Fiber lobes: which nonempty cells keep them (1) or not (0), and for each that does
        // its forward strength and cosine, its reflected strength and its two shapes.
        let lobes = u32s(&format!("e{e}.lobes"))?;
        let forward = f32s(&format!("e{e}.forward"))?;
        let reflected = f32s(&format!("e{e}.reflected"))?;
        let shapes = f32s(&format!("e{e}.shapes"))?;
        let lobe_n = 3 * sh_count(LOBE_SH_ORDER);
        let kept = lobes.iter().filter(|&&l| l == 1).count();
        if lobes.len() != nonempty
            || lobes.iter().any(|&l| l > 1)
            || forward.len() != (lobe_n + 3) * kept
            || reflected.len() != lobe_n * kept
            || shapes.len() != 2 * LOBE_SHAPE_LEN * kept
        {
            return Err(bad(format!(
                "e{e}: {} lobe flags ({kept} set) and {}, {} and {} forward, reflected and shape values for {nonempty} cells",
                lobes.len(),
                forward.len(),
                reflected.len(),
                shapes.len()
            )));
        }
        let mut lobe_flags = lobes.iter();
        let (mut lobe_at, mut at) = (0, 0);
        let transfer = paths
            .iter()
            .map(|&p| {
                if p == 0 {
                    return CellTransfer::empty();
                }
                let range = 3 * entries * at..3 * entries * (at + 1);
                at += 1;
                let mut cell = CellTransfer {
                    matrix: rgb(&matrix[range.clone()]),
                    std_error: rgb(&error[range]),
                    paths: p as usize,
                    ..CellTransfer::empty()
                };
                if lobe_flags.next() == Some(&1) {
                    let f = &forward[(lobe_n + 3) * lobe_at..(lobe_n + 3) * (lobe_at + 1)];
                    let s = &shapes[2 * LOBE_SHAPE_LEN * lobe_at..2 * LOBE_SHAPE_LEN * (lobe_at + 1)];
                    cell.forward = rgb(&f[..lobe_n]);
                    cell.forward_cosine = [f[lobe_n], f[lobe_n + 1], f[lobe_n + 2]];
                    cell.reflected = rgb(&reflected[lobe_n * lobe_at..lobe_n * (lobe_at + 1)]);
                    cell.forward_shape = s[..LOBE_SHAPE_LEN].to_vec();
                    cell.reflected_shape = s[LOBE_SHAPE_LEN..].to_vec();
                    lobe_at += 1;
                }
                cell
            })
            .collect();
        exemplars.push(ExemplarPart { segments, images, cells, transfer });
    }
    Ok((BakePart { shard, key: file.key(), exemplars }, text("record")?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::pipeline::{bake_set, write_bake};
    use crate::bake::settings::BakeSettings;
    use crate::bcsdf::MaterialDesc;
    use crate::fabric::Exemplar;
    use crate::fabric::weave::WeavePreset;

    fn tiny() -> (Exemplar, Vec<MaterialDesc>) {
        crate::bake::pipeline::tests::tiny(WeavePreset::Plain)
    }

    fn settings() -> BakeSettings {
        BakeSettings {
            svf_resolution: 8,
            visibility_points: 2,
            pca_components: 4,
            visibility_bits: true,
            sos_count: 8,
            sos_sharpness: 128.0,
            cell_size_mfp: 1.0,
            cell_depth_mfp: 1.0,
            iirtf_paths_per_cell: 16,
            // Several light samples an event: the shards' streams must still split them alike.
            iirtf_light_samples: 2,
            sh_order: 2,
            cs_theta_count: 8,
            voxels_per_fiber_diameter: 0.5,
            mfp_samples: 400,
            seed: 5,
            fiber_lobes: false,
            exposed_starts: true,
            segment_transfer_paths: 0,
            // Where segment cells are baked, pooled after the parts are merged.
            segment_pool_mfp: 0.5,
        }
    }

    fn parts(inputs: &[BakeInputs<'_>], count: usize) -> Vec<BakePart> {
        (0..count)
            .map(|index| bake_part(inputs, Shard { index, count }, &Cancel::new(), &|_, _| {}).unwrap())
            .collect()
    }

    fn merge(inputs: &[BakeInputs<'_>], parts: Vec<BakePart>) -> Result<BakeSet, ShardError> {
        merge_parts(inputs, PatternMap::uniform(0), parts, &Cancel::new(), &|_, _| {})
    }

    #[test]
    fn shards_parse_and_their_slices_tile_the_work() {
        assert_eq!(Shard::parse("2/5").unwrap(), Shard { index: 2, count: 5 });
        assert_eq!(Shard::parse(" 0 / 1 ").unwrap().to_string(), "0/1");
        for bad in ["3/3", "x/2", "1/0", "1", "0/5000", "-1/2", ""] {
            let err = Shard::parse(bad).unwrap_err().to_string();
            assert!(err.contains("0 <= I < N <= 4096"), "{bad:?}: {err}");
        }
        for total in [0, 1, 7, 100, 1001] {
            for count in [1, 2, 3, 7, 64] {
                let slices: Vec<_> = (0..count).map(|index| Shard { index, count }.slice(total)).collect();
                assert_eq!(slices[0].start, 0);
                assert_eq!(slices[count - 1].end, total);
                for pair in slices.windows(2) {
                    assert_eq!(pair[0].end, pair[1].start, "{total} in {count}");
                }
                let (min, max) =
                    slices.iter().fold((usize::MAX, 0), |(a, b), s| (a.min(s.len()), b.max(s.len())));
                assert!(max - min <= 1, "{total} in {count}: sizes {min}..{max}");
            }
        }
    }

    #[test]
    fn weighted_slices_tile_the_items_and_balance_their_weight() {
        let weights: Vec<u64> =
            (0..1000_u64).map(|i| u64::from(i % 7 == 0 || (400..600).contains(&i))).collect();
        let total: u64 = weights.iter().sum();
        for count in [1, 2, 3, 4, 7, 16] {
            let slices: Vec<_> =
                (0..count).map(|index| Shard { index, count }.slice_weighted(&weights)).collect();
            assert_eq!(slices[0].start, 0);
            assert_eq!(slices[count - 1].end, weights.len());
            for pair in slices.windows(2) {
                assert_eq!(pair[0].end, pair[1].start);
            }
            for s in &slices {
                let w: u64 = weights[s.clone()].iter().sum();
                let share = total as f64 / count as f64;
                assert!(
                    (w as f64 - share).abs() <= 1.0 + 1e-9,
                    "{count} shards: {s:?} weighs {w} of {total}"
                );
            }
        }
        // Nothing weighs anything: plain slices.
        let zero = vec![0_u64; 10];
        assert_eq!(Shard { index: 1, count: 2 }.slice_weighted(&zero), 5..10);
    }

    #[test]
    fn merged_parts_are_the_single_process_bake_byte_for_byte_whatever_the_split() {
        // With segment transfers too: the single-process bake skips the segment cells under
        // lobe cells, the shards trace them and the merge empties them.
        for (fiber_lobes, segment_transfer_paths) in [(false, 0), (true, 0), (true, 8)] {
            merged_parts_are_the_single_process_bake(fiber_lobes, segment_transfer_paths);
        }
    }

    fn merged_parts_are_the_single_process_bake(fiber_lobes: bool, segment_transfer_paths: usize) {
        let (exemplar, materials) = tiny();
        let settings = BakeSettings { fiber_lobes, segment_transfer_paths, ..settings() };
        let inputs = [BakeInputs { exemplar: &exemplar, materials: &materials, settings }];
        let dir = tempfile::tempdir().unwrap();
        let whole = bake_set(&inputs, PatternMap::uniform(0), None, &Cancel::new(), &|_, _| {}).unwrap();
        let cells = &whole.exemplars[0].baked.transfer.iirtf.cells;
        let lobes = cells.iter().filter(|c| c.has_lobes()).count();
        let folded = cells.iter().filter(|c| !c.is_empty() && !c.has_lobes()).count();
        assert_eq!(lobes > 0, fiber_lobes, "{lobes} cells with fiber lobes");
        // With lobes, both kinds of cell go through the parts.
        assert!(folded > 0, "{folded} cells without lobes");
        let grid = &whole.exemplars[0].baked.transfer.cells;
        let own = (grid.lattice_cell_count()..grid.cell_count()).filter(|&c| !cells[c].is_empty()).count();
        assert_eq!(own > 0, segment_transfer_paths > 0, "{own} segment cells with a transfer");
        let whole_path = dir.path().join("whole.twillbake");
        write_bake(&whole_path, &whole).unwrap();
        let whole_bytes = std::fs::read(&whole_path).unwrap();
        let cells = whole.exemplars[0].baked.transfer.cells.cell_count();
        assert!(cells > 5, "{cells} cells: too few to split five ways");
        for count in [1, 2, 3, 5] {
            let mut read = Vec::new();
            for part in parts(&inputs, count) {
                let path = dir.path().join(format!("part{}of{count}.twillpart", part.shard.index));
                write_part(&path, &part, "scene = \"tiny\"\n").unwrap();
                let (again, record) = read_part(&path).unwrap();
                assert_eq!(again, part, "a part file reads back as written");
                assert_eq!(record, "scene = \"tiny\"\n");
                read.push(again);
            }
            read.reverse();
            let merged = merge(&inputs, read).unwrap();
            let path = dir.path().join(format!("merged{count}.twillbake"));
            write_bake(&path, &merged).unwrap();
            assert!(
                std::fs::read(&path).unwrap() == whole_bytes,
                "{count} shards (fiber lobes {fiber_lobes}, segment paths {segment_transfer_paths}): the merged bake differs"
            );
        }
    }

    #[test]
    fn parts_that_do_not_make_one_bake_are_refused_with_the_reason() {
        let (exemplar, materials) = tiny();
        let inputs = [BakeInputs { exemplar: &exemplar, materials: &materials, settings: settings() }];
        let three = parts(&inputs, 3);
        let err = |parts: Vec<BakePart>| merge(&inputs, parts).map(|_| ()).unwrap_err().to_string();
        assert!(err(vec![three[0].clone(), three[2].clone()]).contains("shard 1/3 is missing"));
        assert!(err(vec![three[0].clone(), three[0].clone(), three[1].clone()]).contains("given twice"));
        assert!(err(three[..2].to_vec()).contains("2 of 3 shards"));
        assert!(err(Vec::new()).contains("no parts"));
        let two = parts(&inputs, 2);
        assert!(err(vec![three[0].clone(), two[1].clone()]).contains("2-way split"));
        let reseeded = [BakeInputs { settings: BakeSettings { seed: 6, ..settings() }, ..inputs[0] }];
        let other = parts(&reseeded, 1);
        assert!(err(other).contains("other inputs"));

        // A damaged part file is an error naming it.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("part.twillpart");
        write_part(&path, &three[1], "").unwrap();
        let mut bytes = std::fs::read(&path).unwrap();
        let middle = bytes.len() / 2;
        bytes[middle] ^= 0x40;
        std::fs::write(&path, bytes).unwrap();
        let message = read_part(&path).unwrap_err().to_string();
        assert!(message.contains("part.twillpart"), "{message}");
        // A bake file is not a part file.
        let whole = bake_set(&inputs, PatternMap::uniform(0), None, &Cancel::new(), &|_, _| {}).unwrap();
        let bake_path = dir.path().join("whole.twillbake");
        write_bake(&bake_path, &whole).unwrap();
        let message = read_part(&bake_path).unwrap_err().to_string();
        assert!(message.contains("not a part file"), "{message}");
        // A part of the layout before the fiber lobes (no `layout` in its header).
        let old = dir.path().join("old.twillpart");
        let header = b"shard = \"0/1\"\nexemplars = 1\n".to_vec();
        let key = three[0].key;
        BakeWriter::new(key)
            .section("part", key, Array::vector(ArrayData::U8(header)))
            .section("record", key, Array::vector(ArrayData::U8(Vec::new())))
            .write(&old)
            .unwrap();
        let message = read_part(&old).unwrap_err().to_string();
        assert!(message.contains("old.twillpart") && message.contains("layout 1"), "{message}");
    }
}
