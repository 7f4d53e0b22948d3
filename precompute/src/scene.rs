//! Scene files: fabric, materials, swatch, camera, lights and render settings in TOML.
//!
//! A scene file is parsed with serde into [`SceneFile`] (unknown fields are errors, and every
//! range check runs during parsing, so a bad value is reported with its file, line and column
//! by the TOML parser), then [`SceneFile::build`] turns it into the objects the renderers use.
//! [`SceneFile::to_toml`] writes a scene back out (every section, defaults included, floats
//! exact) so that parsing the text gives the same [`SceneFile`]; [`SceneFile::save`] writes it
//! atomically. The built-in default scene is `assets/scenes/default.toml`, compiled in; it
//! doubles as the documented example of the format (see `docs/SCENE_FORMAT.md`).
//!
//! Patterned cloth (paper section 6.4): an optional `[pattern]` section lists alternative
//! weaves and a map of which weave each block of the cloth uses. Exemplar 0 is `[fabric]`'s own
//! weave, exemplar `k` the `k`-th of `[pattern] weaves`; all share `[fabric]`'s yarns, spacings,
//! crimp and seed. Blocks of different exemplars sit side by side, so all must be the same size:
//! [`pattern_blocks`] makes the block side, in yarns, the greatest common divisor of all the
//! drafts' repeats along each axis. The built [`Scene`] then holds every exemplar and the map
//! ([`ScenePattern`]); [`Scene::bake_inputs`] and [`Scene::pattern_map`] give callers one code
//! path for plain and patterned cloth.

use std::path::{Path, PathBuf};

use glam::{DVec3, Vec2};
use serde::{Deserialize, Deserializer, Serialize};

use crate::Rgb;
use crate::bake::pattern::{PatternError, PatternMap};
use crate::bake::pipeline::BakeInputs;
use crate::bake::settings::BakeSettings;
use crate::bcsdf::{Material, MaterialDesc};
use crate::fabric::colour_order::{ColourOrder, exemplar_repeat};
use crate::fabric::presets::{FabricSpec, WeaveSource, WovenSpec, fabric_preset, fabric_presets};
use crate::fabric::weave::{WeaveDraft, WeavePreset};
use crate::fabric::wif::{WifColours, WifError, read_wif};
use crate::fabric::{Exemplar, Tiling};
use crate::params::{ParamError, check_count, check_positive, check_range};
use crate::pathtrace::{Camera, Component, Light, PathScene, Projection, RenderSettings};
use crate::raycast::pattern::PatternedFibers;
use crate::raycast::{Extent, FiberScene};

/// Why colour orders are refused on imported fibers.
const COLOUR_ORDERS_NEED_WOVEN: &str = "colour orders need a woven [fabric] (a preset or a procedural [fabric.spec]): imported fibers have no threads to colour";

/// sRGB-encoded display value (0..1) to linear.
fn srgb_to_linear(v: f64) -> f64 {
    if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
}

/// The material of a slot nothing gives (no `[materials]` entry, no preset).
const FALLBACK_MATERIAL: MaterialDesc = MaterialDesc::Lambert { albedo: Rgb::splat(0.5) };

/// The built-in default scene (its text).
pub const DEFAULT_SCENE_TOML: &str = include_str!("../../assets/scenes/default.toml");

/// Errors reading, building or writing a scene; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("{path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("{path}: could not write the scene: {source}")]
    Write { path: PathBuf, source: std::io::Error },
    #[error("{path}: the scene cannot be written as TOML: {message}")]
    Serialize { path: PathBuf, message: String },
    /// The TOML parser's message already names the line, column and field.
    #[error("{path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("{path}: [fabric]: {source}")]
    Fabric { path: PathBuf, source: crate::fabric::presets::FabricError },
    #[error("{path}: {source}")]
    Param { path: PathBuf, source: ParamError },
    #[error("{path}: [pattern]: {source}")]
    Pattern { path: PathBuf, source: PatternError },
    /// The WIF error names the WIF file, its line, key and value.
    #[error("{path}: [pattern]: {source}")]
    Wif { path: PathBuf, source: WifError },
}

/// A parsed scene file, before any geometry is built.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub fabric: FabricSection,
    #[serde(default)]
    pub materials: MaterialsSection,
    /// Patterned cloth: other weaves and the map of which one each block uses.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pattern: Option<PatternSection>,
    #[serde(default)]
    pub swatch: SwatchSection,
    pub camera: CameraSection,
    #[serde(default)]
    pub lights: Vec<LightSection>,
    #[serde(default)]
    pub render: RenderSection,
    #[serde(default)]
    pub mesh: MeshSection,
    #[serde(default)]
    pub gpu: GpuSection,
    /// Where the file was read from (relative paths inside it are resolved against its folder).
    #[serde(skip)]
    pub path: PathBuf,
}

/// `[fabric]`: a built-in preset by name, or a full fabric specification.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FabricSection {
    /// Name of a built-in fabric preset (`twill fabric presets` lists them).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preset: Option<String>,
    /// A full specification (procedural weave or imported fiber file): `[fabric.spec]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub spec: Option<FabricSpec>,
}

/// `[materials]`: material of warp and weft yarns (defaults: the preset's), and optionally a
/// palette of yarn colours with warp and weft colour orders (a colourway).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialsSection {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warp: Option<MaterialDesc>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub weft: Option<MaterialDesc>,
    /// `warp_order = "2 navy, 2 cream, 1 red"`: the warp's colour order over the palette.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warp_order: Option<String>,
    /// The weft's colour order over the palette.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub weft_order: Option<String>,
    /// `[materials.palette]`: named yarn colours, each a recolouring of the warp or weft yarn;
    /// palette colour `k` (names in alphabetical order) is material `k`.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub palette: std::collections::BTreeMap<String, PaletteColour>,
}

/// The most colours a palette holds.
pub const MAX_PALETTE_COLOURS: usize = 16;

/// Which yarn's material a palette colour recolours.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum YarnSlot {
    Warp,
    Weft,
}

/// One palette colour: the `base` yarn's material (as `[materials]` or the preset give it) with
/// its colours replaced: `c_r` and `c_tt` for the fiber model, `albedo` for Lambert.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PaletteColour {
    pub base: YarnSlot,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub c_r: Option<Rgb>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub c_tt: Option<Rgb>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub albedo: Option<Rgb>,
}

/// The colourway of a scene: the palette's materials in order, its names, and the parsed orders.
#[derive(Debug, Clone, PartialEq)]
pub struct Colourway {
    pub names: Vec<String>,
    pub materials: Vec<MaterialDesc>,
    pub warp: ColourOrder,
    pub weft: ColourOrder,
}

/// Most weaves `[pattern]` may add to `[fabric]`'s (map indices go up to `z` = 35).
pub const MAX_PATTERN_WEAVES: usize = 35;
/// Largest side, in blocks, of a pattern map.
pub const MAX_PATTERN_MAP_SIDE: usize = crate::bake::pattern::MAX_PATTERN_SIDE;

/// `[pattern]`: patterned cloth (paper section 6.4). `weaves` are exemplars 1, 2, ...
/// (exemplar 0 being `[fabric]`'s own weave); the map says which exemplar each block uses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawPatternSection", into = "RawPatternSection")]
pub struct PatternSection {
    pub weaves: Vec<PatternWeave>,
    pub map: PatternMapSource,
}

/// One of `[pattern] weaves`: `{ weave = "plain" }`, `{ rows = ["X.", ".X"] }` or
/// `{ wif = "draft.wif" }` (relative to the scene file's folder).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawPatternWeave", into = "RawPatternWeave")]
pub enum PatternWeave {
    Preset(WeavePreset),
    Draft(WeaveDraft),
    Wif(PathBuf),
}

impl PatternWeave {
    /// The weave, a WIF file read from `base_dir`.
    ///
    /// # Errors
    /// A WIF file that does not read.
    pub fn source(&self, base_dir: &Path) -> Result<WeaveSource, WifError> {
        Ok(match self {
            PatternWeave::Preset(p) => WeaveSource::Preset(*p),
            PatternWeave::Draft(d) => WeaveSource::Draft(d.clone()),
            PatternWeave::Wif(file) => WeaveSource::Draft(read_wif(&base_dir.join(file))?),
        })
    }
}

/// Where a pattern map comes from: `rows = ["0011", "0110"]` (top row first, one character per
/// block, `0`-`9` then `a`-`z`) or `png = "map.png"` (gray levels, darkest = exemplar 0;
/// relative to the scene file's folder). See [`PatternMap`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PatternMapSource {
    Rows(Vec<String>),
    Png(PathBuf),
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPatternSection {
    #[serde(skip_serializing_if = "Option::is_none")]
    rows: Option<Vec<String>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    png: Option<PathBuf>,
    weaves: Vec<PatternWeave>,
}

impl From<PatternSection> for RawPatternSection {
    fn from(section: PatternSection) -> Self {
        let (rows, png) = match section.map {
            PatternMapSource::Rows(rows) => (Some(rows), None),
            PatternMapSource::Png(png) => (None, Some(png)),
        };
        Self { rows, png, weaves: section.weaves }
    }
}

impl TryFrom<RawPatternSection> for PatternSection {
    type Error = String;

    fn try_from(raw: RawPatternSection) -> Result<Self, String> {
        check_count("pattern.weaves", raw.weaves.len(), 1, MAX_PATTERN_WEAVES)
            .map_err(|e| format!("{e} (the weaves besides [fabric]'s own, which is exemplar 0)"))?;
        let map = match (raw.rows, raw.png) {
            (Some(rows), None) => {
                PatternMap::from_rows(&rows).map_err(|e| format!("rows: {e}"))?;
                PatternMapSource::Rows(rows)
            }
            (None, Some(png)) => PatternMapSource::Png(png),
            _ => {
                return Err("give exactly one of `rows = [\"0110\", ...]` and `png = \"map.png\"`: \
                            the map of which exemplar each block uses"
                    .into());
            }
        };
        Ok(Self { weaves: raw.weaves, map })
    }
}

#[derive(Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPatternWeave {
    #[serde(skip_serializing_if = "Option::is_none")]
    weave: Option<WeavePreset>,
    #[serde(skip_serializing_if = "Option::is_none")]
    rows: Option<Vec<String>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    wif: Option<PathBuf>,
}

impl From<PatternWeave> for RawPatternWeave {
    fn from(weave: PatternWeave) -> Self {
        match weave {
            PatternWeave::Preset(p) => Self { weave: Some(p), ..Self::default() },
            PatternWeave::Draft(d) => Self { rows: Some(d.to_rows()), ..Self::default() },
            PatternWeave::Wif(file) => Self { wif: Some(file), ..Self::default() },
        }
    }
}

impl TryFrom<RawPatternWeave> for PatternWeave {
    type Error = String;

    fn try_from(raw: RawPatternWeave) -> Result<Self, String> {
        match (raw.weave, raw.rows, raw.wif) {
            (Some(preset), None, None) => Ok(Self::Preset(preset)),
            (None, Some(rows), None) => {
                WeaveDraft::from_rows(&rows).map(Self::Draft).map_err(|e| format!("rows: {e}"))
            }
            (None, None, Some(file)) => Ok(Self::Wif(file)),
            _ => Err("each of `weaves` gives exactly one of `weave = \"plain\"`, `rows = [\"X.\", \".X\"]` \
                      and `wif = \"draft.wif\"`"
                .into()),
        }
    }
}

/// Block grid of each draft of a patterned cloth, `[nx, ny]`: the block side in yarns is the
/// greatest common divisor of all the drafts' repeats, columns (warp ends, along x) and rows
/// (weft picks, along y) separately, so with equal yarn spacings every block has the same size.
/// E.g. a 2/2 twill (4 x 4) with a plain weave (2 x 2) gives 2-yarn blocks: `[2, 2]` and
/// `[1, 1]`.
#[must_use]
pub fn pattern_blocks(drafts: &[WeaveDraft]) -> Vec<[u32; 2]> {
    let [gx, gy] = pattern_block_side(drafts);
    drafts.iter().map(|d| [(d.cols() / gx) as u32, (d.rows() / gy) as u32]).collect()
}

/// The side of a pattern block in yarns, along x (ends) and y (picks): the greatest common
/// divisor of the drafts' repeats.
#[must_use]
pub fn pattern_block_side(drafts: &[WeaveDraft]) -> [usize; 2] {
    fn gcd(a: usize, b: usize) -> usize {
        if b == 0 { a } else { gcd(b, a % b) }
    }
    [
        drafts.iter().map(WeaveDraft::cols).fold(0, gcd).max(1),
        drafts.iter().map(WeaveDraft::rows).fold(0, gcd).max(1),
    ]
}

/// The exemplar repeat `[ends, picks]` of `draft` with `colourway`'s orders: the least common
/// multiple of the weave's and the colours' repeat along each direction (the draft's own repeat
/// without colour orders).
///
/// # Errors
/// A joint repeat past the limit, naming both repeats.
fn joint_repeat(draft: &WeaveDraft, colourway: Option<&Colourway>) -> Result<[usize; 2], String> {
    let Some(colourway) = colourway else { return Ok([draft.cols(), draft.rows()]) };
    let cols = exemplar_repeat("warp_order", draft.cols(), colourway.warp.threads().len())
        .map_err(|e| e.to_string())?;
    let rows = exemplar_repeat("weft_order", draft.rows(), colourway.weft.threads().len())
        .map_err(|e| e.to_string())?;
    Ok([cols, rows])
}

/// `[swatch]`: the flat tiled piece of fabric that is rendered.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SwatchSection {
    /// Size along x and y in cm, centred on the origin (ignored for fabrics used as-is).
    #[serde(deserialize_with = "positive_pair")]
    pub size_cm: [f64; 2],
    /// A black ground plane under the fabric (absorbs light, shadows from below).
    pub ground: bool,
}

impl Default for SwatchSection {
    fn default() -> Self {
        Self { size_cm: [1.0, 1.0], ground: true }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ProjectionKind {
    #[default]
    Perspective,
    Orthographic,
}

/// `[camera]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSection {
    /// Perspective unless given.
    #[serde(default)]
    pub projection: ProjectionKind,
    pub eye: [f64; 3],
    pub target: [f64; 3],
    #[serde(default = "default_up")]
    pub up: [f64; 3],
    /// Full vertical field of view (perspective).
    #[serde(default = "default_fov")]
    pub fov_y_deg: f64,
    /// Film height in cm (orthographic).
    #[serde(default = "default_height")]
    pub height_cm: f64,
}

fn default_up() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}
fn default_fov() -> f64 {
    30.0
}
fn default_height() -> f64 {
    1.0
}

/// `[[lights]]`: a directional or a normalized SG light.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub enum LightSection {
    /// Irradiance perpendicular to the beam, arriving from `direction` (toward the light).
    Directional { direction: [f64; 3], irradiance: [f64; 3] },
    /// Radiance `intensity * G(w; axis, sharpness) / M(sharpness)`; `axis` points toward the light.
    Sg {
        axis: [f64; 3],
        #[serde(deserialize_with = "sg_sharpness")]
        sharpness: f64,
        intensity: [f64; 3],
    },
}

/// `[render]`: resolution and sampling.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderSection {
    pub width: usize,
    pub height: usize,
    pub spp: u32,
    pub max_depth: u32,
    pub seed: u64,
    /// Exposure in stops for PNG output.
    pub exposure: f64,
}

impl Default for RenderSection {
    fn default() -> Self {
        Self { width: 256, height: 256, spp: 64, max_depth: 64, seed: 1, exposure: 0.0 }
    }
}

/// `[mesh]`: the base surface the fabric is shell-mapped onto (GPU renderer). Give at most one
/// of `builtin` and `path`; with neither, the flat swatch of `[swatch]` is used.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MeshSection {
    /// A built-in surface: `swatch`, `drape` or `cushion` (UVs in cm).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub builtin: Option<String>,
    /// An OBJ or glTF file with UVs (relative to the scene file's folder).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub path: Option<PathBuf>,
    /// Size in cm of a built-in surface (default: `[swatch] size_cm`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub size_cm: Option<[f64; 2]>,
    /// Centimetres of fabric per unit of the mesh's UV coordinates (1 for the built-ins).
    pub cm_per_uv: f64,
    /// Shell thickness as a multiple of the fabric's own thickness (1 keeps fibers unstretched).
    pub thickness_scale: f64,
}

impl Default for MeshSection {
    fn default() -> Self {
        Self { builtin: None, path: None, size_cm: None, cm_per_uv: 1.0, thickness_scale: 1.0 }
    }
}

impl MeshSection {
    /// A surface is given, a built-in or a mesh file (else the flat swatch of `[swatch]`).
    #[must_use]
    pub fn names_a_surface(&self) -> bool {
        self.builtin.is_some() || self.path.is_some()
    }

    /// No surface but the flat swatch: neither a mesh file nor a built-in other than `swatch`.
    #[must_use]
    pub fn is_flat_swatch(&self) -> bool {
        self.path.is_none() && self.builtin.as_deref().is_none_or(|name| name == "swatch")
    }
}

/// `[gpu]`: settings of the GPU renderer (`twill render`, the viewer).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GpuSection {
    /// Standard deviation of the multiple-scattering visibility blur, cm of flat fabric (0: none).
    pub sigma_glo_cm: f64,
    /// Side of each light's shadow map in texels.
    pub shadow_map_size: u32,
    /// Side of the shell-space textures (top-surface positions X[u, v], visibility V[u, v]).
    pub visibility_texture_size: u32,
    /// PCF kernel radius in shadow-map texels (directional lights).
    pub pcf_radius_texels: f64,
    /// Depth bias of shadow lookups, in shadow-map texels.
    pub shadow_bias_texels: f64,
}

impl Default for GpuSection {
    fn default() -> Self {
        Self {
            sigma_glo_cm: 0.05,
            shadow_map_size: 2048,
            visibility_texture_size: 1024,
            pcf_radius_texels: 1.5,
            shadow_bias_texels: 2.0,
        }
    }
}

impl GpuSection {
    /// Checks every field against its valid range.
    pub fn validate(&self) -> Result<(), ParamError> {
        check_range("gpu.sigma_glo_cm", self.sigma_glo_cm, 0.0, 100.0)?;
        check_count("gpu.shadow_map_size", self.shadow_map_size as usize, 64, 16384)?;
        check_count("gpu.visibility_texture_size", self.visibility_texture_size as usize, 16, 16384)?;
        check_range("gpu.pcf_radius_texels", self.pcf_radius_texels, 0.0, 64.0)?;
        check_range("gpu.shadow_bias_texels", self.shadow_bias_texels, 0.0, 64.0)?;
        Ok(())
    }
}

fn positive_pair<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 2], D::Error> {
    let v = <[f64; 2]>::deserialize(d)?;
    for x in v {
        check_positive("swatch.size_cm", x).map_err(serde::de::Error::custom)?;
    }
    Ok(v)
}

fn sg_sharpness<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    let v = f64::deserialize(d)?;
    let (lo, hi) = crate::pathtrace::light::SG_SHARPNESS_RANGE;
    check_range("sharpness", v, lo, hi).map_err(serde::de::Error::custom)
}

/// A scene ready to render: the fabric exemplar, the ray-traceable swatch with its materials
/// and lights, the camera and the settings.
pub struct Scene {
    /// The fabric (exemplar 0 of a patterned cloth).
    pub exemplar: Exemplar,
    /// Patterned cloth: every exemplar and the map; `None` for a plain fabric.
    pub pattern: Option<ScenePattern>,
    /// Warp and weft material as described (slot 0 warp, slot 1 weft).
    pub material_descs: Vec<MaterialDesc>,
    /// The swatch as the path tracer sees it.
    pub path_scene: PathScene,
    pub swatch: SwatchSection,
    pub camera: CameraSection,
    pub render: RenderSection,
    pub mesh: MeshSection,
    pub gpu: GpuSection,
    /// Folder of the scene file (relative mesh paths resolve against it).
    pub base_dir: PathBuf,
}

/// The built `[pattern]`: every exemplar (index 0, `[fabric]`'s weave, first; each with the
/// blocks of [`pattern_blocks`]) and the map of which one each block uses.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenePattern {
    pub map: PatternMap,
    pub exemplars: Vec<Exemplar>,
}

impl Scene {
    /// Every exemplar: the pattern's, or just [`Scene::exemplar`].
    #[must_use]
    pub fn exemplars(&self) -> &[Exemplar] {
        self.pattern.as_ref().map_or(std::slice::from_ref(&self.exemplar), |p| &p.exemplars)
    }

    /// The map of which exemplar each block uses (every block exemplar 0 without a pattern).
    #[must_use]
    pub fn pattern_map(&self) -> PatternMap {
        self.pattern.as_ref().map_or_else(|| PatternMap::uniform(0), |p| p.map.clone())
    }

    /// What baking every exemplar needs (for `bake::pipeline::bake_set` with
    /// [`Scene::pattern_map`]); all exemplars share the scene's materials.
    #[must_use]
    pub fn bake_inputs(&self, settings: BakeSettings) -> Vec<BakeInputs<'_>> {
        self.exemplars()
            .iter()
            .map(|exemplar| BakeInputs { exemplar, materials: &self.material_descs, settings })
            .collect()
    }
}

/// Gap between the lowest fiber and the black ground plane, in cm.
pub const GROUND_GAP_CM: f64 = 1e-4;

impl SceneFile {
    /// Parses scene text; `path` is used in messages and to resolve relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<Self, SceneError> {
        let mut scene: SceneFile = toml::from_str(text).map_err(|e| SceneError::Parse {
            path: path.into(),
            message: e.to_string().trim_end().to_owned(),
        })?;
        scene.path = path.into();
        Ok(scene)
    }

    /// Reads and parses a scene file.
    pub fn load(path: &Path) -> Result<Self, SceneError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| SceneError::Read { path: path.into(), source })?;
        Self::parse(&text, path)
    }

    /// The built-in default scene.
    #[must_use]
    pub fn default_scene() -> Self {
        Self::parse(DEFAULT_SCENE_TOML, Path::new("<built-in default scene>"))
            .expect("the built-in default scene parses (tested)")
    }

    /// The scene as TOML text, every section written out (defaults included), such that
    /// [`SceneFile::parse`] gives this scene back exactly (floats keep every bit). The `path`
    /// is not written; relative paths inside are kept as they are.
    pub fn to_toml(&self) -> Result<String, SceneError> {
        let body = toml::to_string(self)
            .map_err(|e| SceneError::Serialize { path: self.path.clone(), message: e.to_string() })?;
        Ok(format!("# twill scene (docs/SCENE_FORMAT.md)\n\n{body}"))
    }

    /// Writes the scene to `path` atomically (see [`crate::atomic_file`]). Relative paths inside
    /// it (fiber file, mesh, pattern map and WIF files) are resolved against the folder of the
    /// scene's own `path`; when `path` is in another folder they are written as absolute paths,
    /// so the saved scene still finds them.
    pub fn save(&self, path: &Path) -> Result<(), SceneError> {
        let text = self.rebased(path).to_toml()?;
        crate::atomic_file::write_atomically(path, |w| std::io::Write::write_all(w, text.as_bytes()))
            .map_err(|source| SceneError::Write { path: path.into(), source })
    }

    /// This scene with its relative paths made absolute if `target` is in another folder.
    #[must_use]
    pub fn rebased(&self, target: &Path) -> SceneFile {
        let folder = |p: &Path| std::path::absolute(p.parent().unwrap_or(Path::new("")));
        let (Ok(from), Ok(to)) = (folder(&self.path), folder(target)) else { return self.clone() };
        let mut out = self.clone();
        if from == to {
            return out;
        }
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = from.join(&*p);
            }
        };
        if let Some(FabricSpec::Imported(spec)) = &mut out.fabric.spec {
            fix(&mut spec.file);
        }
        if let Some(p) = &mut out.mesh.path {
            fix(p);
        }
        if let Some(pattern) = &mut out.pattern {
            if let PatternMapSource::Png(p) = &mut pattern.map {
                fix(p);
            }
            for weave in &mut pattern.weaves {
                if let PatternWeave::Wif(p) = weave {
                    fix(p);
                }
            }
        }
        out
    }

    /// Loads `path`, or the built-in default scene when `None`.
    pub fn load_or_default(path: Option<&Path>) -> Result<Self, SceneError> {
        path.map_or_else(|| Ok(Self::default_scene()), Self::load)
    }

    /// Builds the fabric and validates everything else.
    pub fn build(&self) -> Result<Scene, SceneError> {
        let path = &self.path;
        let invalid = |message: String| SceneError::Invalid { path: path.clone(), message };
        let param = |source: ParamError| SceneError::Param { path: path.clone(), source };

        let spec = match (&self.fabric.preset, &self.fabric.spec) {
            (Some(name), None) => {
                let preset = fabric_preset(name).ok_or_else(|| {
                    let names: Vec<_> = fabric_presets().into_iter().map(|p| p.name).collect();
                    invalid(format!("[fabric]: unknown preset {name:?}; known presets: {}", names.join(", ")))
                })?;
                preset.fabric
            }
            (None, Some(spec)) => spec.clone(),
            _ => return Err(invalid("[fabric]: give exactly one of `preset` or `[fabric.spec]`".into())),
        };
        let base_dir = path.parent().unwrap_or(Path::new("."));
        let colourway = self.colourway().map_err(|message| invalid(format!("[materials]: {message}")))?;
        let fabric_error = |source| SceneError::Fabric { path: path.clone(), source };
        let (exemplar, pattern) = match (&self.pattern, &colourway, &spec) {
            (None, None, _) => (spec.build(base_dir).map_err(fabric_error)?, None),
            (None, Some(colourway), FabricSpec::Woven(woven)) => {
                let mut fabric = woven.woven_fabric();
                fabric.warp_colours = Some(colourway.warp.clone());
                fabric.weft_colours = Some(colourway.weft.clone());
                (fabric.build().map_err(|e| fabric_error(e.into()))?, None)
            }
            (None, Some(_), _) => {
                return Err(invalid(format!("[materials]: {COLOUR_ORDERS_NEED_WOVEN}")));
            }
            (Some(section), colourway, _) => {
                let pattern = self.build_pattern(section, &spec, base_dir, colourway.as_ref())?;
                (pattern.exemplars[0].clone(), Some(pattern))
            }
        };

        let material_descs = self.slot_materials(colourway.map(|c| c.materials));
        let materials: Vec<Material> =
            material_descs.iter().map(Material::from_desc).collect::<Result<_, _>>().map_err(param)?;
        // A patterned cloth numbers its yarns across its exemplars (`raycast::pattern`).
        let yarn_materials = pattern
            .as_ref()
            .map_or(std::slice::from_ref(&exemplar), |p| &p.exemplars)
            .iter()
            .flat_map(|e| &e.yarns)
            .map(|y| materials[(y.material as usize).min(materials.len() - 1)].clone())
            .collect();

        let lights = self
            .lights
            .iter()
            .map(|l| match *l {
                LightSection::Directional { direction, irradiance } => {
                    Light::directional(DVec3::from(direction), Rgb::from(irradiance))
                }
                LightSection::Sg { axis, sharpness, intensity } => {
                    Light::sg(DVec3::from(axis), sharpness, Rgb::from(intensity))
                }
            })
            .collect::<Result<Vec<_>, _>>()
            .map_err(param)?;
        if lights.is_empty() {
            return Err(invalid("no [[lights]]: the scene would render black".into()));
        }
        let r = &self.render;
        check_count("render.width", r.width, 1, 16384).map_err(param)?;
        check_count("render.height", r.height, 1, 16384).map_err(param)?;
        self.render_settings(None).validate().map_err(param)?;
        check_range("render.exposure", r.exposure, -30.0, 30.0).map_err(param)?;
        self.gpu.validate().map_err(param)?;
        let m = &self.mesh;
        if m.builtin.is_some() && m.path.is_some() {
            return Err(invalid("[mesh]: give at most one of `builtin` and `path`".into()));
        }
        check_range("mesh.cm_per_uv", m.cm_per_uv, 1e-6, 1e6).map_err(param)?;
        check_range("mesh.thickness_scale", m.thickness_scale, 0.01, 100.0).map_err(param)?;
        for x in m.size_cm.into_iter().flatten() {
            check_range("mesh.size_cm", x, 1e-3, 1e4).map_err(param)?;
        }
        self.camera(r.width, r.height).map_err(param)?;
        // The projection not in use is checked too: a NaN there is a broken file, not a choice.
        check_range("camera.fov_y_deg", self.camera.fov_y_deg, 0.01, 179.0).map_err(param)?;
        check_positive("camera.height_cm", self.camera.height_cm).map_err(param)?;
        let extent = match exemplar.tiling {
            Tiling::Periodic { .. } => {
                let half = Vec2::new(self.swatch.size_cm[0] as f32, self.swatch.size_cm[1] as f32) * 0.5;
                Extent::Rectangle { min: -half, max: half }
            }
            Tiling::AsIs => Extent::Unbounded,
        };
        let fibers = FiberScene::new(&exemplar, extent).map_err(|e| invalid(format!("[fabric]: {e}")))?;
        let patterned_fibers = match (&pattern, extent) {
            (Some(p), Extent::Rectangle { min, max }) => Some(
                PatternedFibers::new(&p.exemplars, p.map.clone(), (min, max))
                    .map_err(|e| invalid(format!("[pattern]: {e}")))?,
            ),
            _ => None,
        };
        let lowest = patterned_fibers.as_ref().map_or_else(|| fibers.slab().0, |p| p.slab().0);
        let ground_z = self.swatch.ground.then(|| f64::from(lowest) - GROUND_GAP_CM);
        let path_scene =
            PathScene { fibers, pattern: patterned_fibers, yarn_materials, lights, ground_z, painted: None };
        Ok(Scene {
            exemplar,
            pattern,
            material_descs,
            path_scene,
            swatch: self.swatch,
            camera: self.camera,
            render: self.render,
            mesh: self.mesh.clone(),
            gpu: self.gpu,
            base_dir: base_dir.to_path_buf(),
        })
    }

    /// Builds every exemplar of a patterned cloth and reads its map.
    ///
    /// With colour orders, each exemplar repeats over its weave's joint repeat with them (as a
    /// cloth without `[pattern]` does) while the blocks stay the weaves' own (the greatest
    /// common divisor of the drafts alone), so a colour order never changes the pattern's
    /// scale: every exemplar holds a whole number of blocks, and end `j` of every exemplar has
    /// the colour of thread `j` of the warp order, so a yarn keeps its colour from one block
    /// into the next.
    fn build_pattern(
        &self,
        section: &PatternSection,
        spec: &FabricSpec,
        base_dir: &Path,
        colourway: Option<&Colourway>,
    ) -> Result<ScenePattern, SceneError> {
        let path = &self.path;
        let invalid = |message: String| SceneError::Invalid { path: path.clone(), message };
        let FabricSpec::Woven(woven) = spec else {
            return Err(invalid(
                "[pattern]: patterned cloth needs a woven [fabric] (a preset, `weave` or `rows`); \
                 imported fibers cannot be combined with other weaves"
                    .into(),
            ));
        };
        if woven.blocks != [1, 1] {
            return Err(invalid(format!(
                "[fabric.spec]: blocks = {:?}: with a [pattern] the blocks are set from the drafts; remove `blocks`",
                woven.blocks
            )));
        }
        let mut weaves = vec![woven.weave.clone()];
        for weave in &section.weaves {
            weaves.push(
                weave.source(base_dir).map_err(|source| SceneError::Wif { path: path.clone(), source })?,
            );
        }
        let drafts: Vec<WeaveDraft> = weaves.iter().map(WeaveSource::draft).collect();
        let [side_x, side_y] = pattern_block_side(&drafts);
        let mut exemplars = Vec::with_capacity(weaves.len());
        for (k, (weave, draft)) in weaves.into_iter().zip(&drafts).enumerate() {
            let place = if k == 0 { "[fabric]".to_owned() } else { format!("[pattern] weaves[{}]", k - 1) };
            let [cols, rows] = joint_repeat(draft, colourway)
                .map_err(|e| invalid(format!("[materials]: with {place}'s weave: {e}")))?;
            let blocks = [(cols / side_x) as u32, (rows / side_y) as u32];
            let spec = WovenSpec { weave, blocks, ..(**woven).clone() };
            let mut fabric = spec.woven_fabric();
            if let Some(colourway) = colourway {
                fabric.warp_colours = Some(colourway.warp.clone());
                fabric.weft_colours = Some(colourway.weft.clone());
            }
            let exemplar = fabric.build().map_err(|e| invalid(format!("{place}: {e}")))?;
            exemplars.push(exemplar);
        }
        let map = match &section.map {
            PatternMapSource::Rows(rows) => PatternMap::from_rows(rows),
            PatternMapSource::Png(png) => PatternMap::from_png(&base_dir.join(png)).map(|(map, _)| map),
        }
        .map_err(|source| SceneError::Pattern { path: path.clone(), source })?;
        let param = |source: ParamError| SceneError::Param { path: path.clone(), source };
        check_count("pattern map width", map.width as usize, 1, MAX_PATTERN_MAP_SIDE).map_err(param)?;
        check_count("pattern map height", map.height as usize, 1, MAX_PATTERN_MAP_SIDE).map_err(param)?;
        if map.exemplar_count() > exemplars.len() {
            let what = match &section.map {
                PatternMapSource::Rows(_) => "rows".to_owned(),
                PatternMapSource::Png(png) => format!("{} (its gray levels, darkest first)", png.display()),
            };
            return Err(invalid(format!(
                "[pattern]: the map ({what}) names exemplar {}, but there are only {} exemplars: \
                 0 ([fabric]'s weave) to {} (the `weaves`)",
                map.exemplar_count() - 1,
                exemplars.len(),
                exemplars.len() - 1
            )));
        }
        Ok(ScenePattern { map, exemplars })
    }

    /// The material of every slot a bake of this scene has, without building the fabric (what
    /// a colour edit needs): material slot 0 is warp (or the only material of imported fibers),
    /// slot 1 weft; with a colourway, material k is palette colour k.
    ///
    /// # Errors
    /// A colourway that does not parse (as [`Self::build`] says it).
    pub fn material_descs(&self) -> Result<Vec<MaterialDesc>, SceneError> {
        let colourway = self.colourway().map_err(|message| SceneError::Invalid {
            path: self.path.clone(),
            message: format!("[materials]: {message}"),
        })?;
        Ok(self.slot_materials(colourway.map(|c| c.materials)))
    }

    /// The palette's materials when there is one, else the warp and weft slots.
    fn slot_materials(&self, palette: Option<Vec<MaterialDesc>>) -> Vec<MaterialDesc> {
        palette.unwrap_or_else(|| self.material_slots().map(|m| m.unwrap_or(FALLBACK_MATERIAL)).to_vec())
    }

    /// The material of each slot (0 warp, 1 weft) as given: `[materials]` over the preset's, a
    /// missing one taking the other's; `None` where neither is given ([`SceneFile::build`] then
    /// uses a gray Lambertian).
    #[must_use]
    pub fn material_slots(&self) -> [Option<MaterialDesc>; 2] {
        let preset = self.fabric.preset.as_deref().and_then(fabric_preset);
        let warp = self.materials.warp.or(preset.as_ref().map(|p| p.warp_material));
        let weft = self.materials.weft.or(preset.as_ref().map(|p| p.weft_material));
        [warp.or(weft), weft.or(warp)]
    }

    /// The colourway of `[materials]`: `None` without a palette; the palette's materials (in
    /// name order) and both colour orders parsed against it otherwise.
    ///
    /// # Errors
    /// A message naming the key and value: orders without a palette or a palette without both
    /// orders, too many colours, a colour that does not fit its base material, a bad order.
    pub fn colourway(&self) -> Result<Option<Colourway>, String> {
        let m = &self.materials;
        if m.palette.is_empty() {
            if m.warp_order.is_some() || m.weft_order.is_some() {
                return Err(
                    "warp_order and weft_order name colours of [materials.palette], which is missing".into(),
                );
            }
            return Ok(None);
        }
        if m.palette.len() > MAX_PALETTE_COLOURS {
            return Err(format!(
                "the palette has {} colours; at most {MAX_PALETTE_COLOURS}",
                m.palette.len()
            ));
        }
        let (Some(warp_order), Some(weft_order)) = (&m.warp_order, &m.weft_order) else {
            return Err(
                "a palette needs both warp_order and weft_order (e.g. warp_order = \"2 navy, 1 cream\")"
                    .into(),
            );
        };
        let slots = self.material_slots().map(|m| m.unwrap_or(FALLBACK_MATERIAL));
        let mut materials = Vec::with_capacity(m.palette.len());
        for (name, colour) in &m.palette {
            let base = slots[colour.base as usize];
            let recoloured = match (base, colour.albedo, colour.c_r.or(colour.c_tt)) {
                (MaterialDesc::Fiber(p), None, _) => MaterialDesc::Fiber(crate::bcsdf::FiberParams {
                    c_r: colour.c_r.unwrap_or(p.c_r),
                    c_tt: colour.c_tt.unwrap_or(p.c_tt),
                    ..p
                }),
                (MaterialDesc::Lambert { albedo }, _, None) => {
                    MaterialDesc::Lambert { albedo: colour.albedo.unwrap_or(albedo) }
                }
                (MaterialDesc::Fiber(_), Some(_), _) => {
                    return Err(format!(
                        "palette.{name}: `albedo` recolours a Lambert yarn, but its base ({:?}) is a fiber \
                         material: give c_r and c_tt",
                        colour.base
                    ));
                }
                (MaterialDesc::Lambert { .. }, _, Some(_)) => {
                    return Err(format!(
                        "palette.{name}: c_r and c_tt recolour a fiber yarn, but its base ({:?}) is Lambert: \
                         give albedo",
                        colour.base
                    ));
                }
            };
            Material::from_desc(&recoloured).map_err(|e| format!("palette.{name}: {e}"))?;
            materials.push(recoloured);
        }
        let names: Vec<String> = m.palette.keys().cloned().collect();
        let name_refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let warp = ColourOrder::parse("warp_order", warp_order, &name_refs).map_err(|e| e.to_string())?;
        let weft = ColourOrder::parse("weft_order", weft_order, &name_refs).map_err(|e| e.to_string())?;
        Ok(Some(Colourway { names, materials, warp, weft }))
    }

    /// Checks `[materials]`' colourway as [`SceneFile::build`] would, without building the
    /// fabric: the palette and orders ([`SceneFile::colourway`]), and the joint repeat of the
    /// weave and the colour orders.
    ///
    /// # Errors
    /// The message `build` would give.
    pub fn check_colourway(&self) -> Result<(), String> {
        let Some(colourway) = self.colourway()? else { return Ok(()) };
        // An unknown preset or a missing fabric is build's to report.
        let Some(draft) = self.colour_order_draft()? else { return Ok(()) };
        let Some(section) = &self.pattern else {
            return joint_repeat(&draft, Some(&colourway)).map(|_| ());
        };
        joint_repeat(&draft, Some(&colourway)).map_err(|e| format!("with [fabric]'s weave: {e}"))?;
        let base_dir = self.path.parent().unwrap_or(Path::new("."));
        for (k, weave) in section.weaves.iter().enumerate() {
            // A WIF file that does not read is build's to report.
            let Ok(source) = weave.source(base_dir) else { continue };
            joint_repeat(&source.draft(), Some(&colourway))
                .map_err(|e| format!("with [pattern] weaves[{k}]'s weave: {e}"))?;
        }
        Ok(())
    }

    /// The weave draft that colour orders repeat against (warp orders against its columns,
    /// weft orders against its rows): `[fabric]`'s own draft, for a woven fabric (with
    /// `[pattern]`, the weaves of the other exemplars repeat against them too); `Ok(None)` for
    /// an unknown preset or a missing fabric (which [`SceneFile::build`] reports).
    ///
    /// # Errors
    /// Imported fibers: they take no colour orders (the message says so).
    pub fn colour_order_draft(&self) -> Result<Option<WeaveDraft>, String> {
        let spec = match (&self.fabric.preset, &self.fabric.spec) {
            (Some(name), None) => fabric_preset(name).map(|p| p.fabric),
            (None, Some(spec)) => Some(spec.clone()),
            _ => None,
        };
        match spec {
            Some(FabricSpec::Woven(woven)) => Ok(Some(woven.weave.draft())),
            None => Ok(None),
            Some(_) => Err(COLOUR_ORDERS_NEED_WOVEN.into()),
        }
    }

    /// Takes a WIF file's colours as this scene's colourway: palette colour `wifK` for each
    /// table colour `K` a thread uses (recolouring the warp yarn if a warp end uses it, else
    /// the weft yarn: `c_tt` for fiber yarns, `albedo` for Lambert ones, the display colour
    /// decoded from sRGB to linear), and the warp and weft orders from the threads' colours. A
    /// direction the file gives no colours keeps its yarn as it is (palette colour `warp` or
    /// `weft`).
    pub fn apply_wif_colours(&mut self, colours: &WifColours) {
        let slots = self.material_slots();
        let mut palette = std::collections::BTreeMap::new();
        let mut order = |threads: &[u32], base: YarnSlot, plain: &str| -> String {
            if threads.is_empty() {
                palette.insert(plain.to_owned(), PaletteColour { base, c_r: None, c_tt: None, albedo: None });
                return format!("1 {plain}");
            }
            let names: Vec<String> = threads.iter().map(|k| format!("wif{}", k + 1)).collect();
            for (k, name) in threads.iter().zip(&names) {
                let display = colours.table[*k as usize].unwrap_or([0.5; 3]);
                let linear = Rgb::from_array(display.map(srgb_to_linear));
                let lambert = matches!(slots[base as usize], Some(MaterialDesc::Lambert { .. }));
                palette.entry(name.clone()).or_insert(PaletteColour {
                    base,
                    c_r: None,
                    c_tt: (!lambert).then_some(linear),
                    albedo: lambert.then_some(linear),
                });
            }
            names
                .chunk_by(|a, b| a == b)
                .map(|run| format!("{} {}", run.len(), run[0]))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let warp_order = order(&colours.warp, YarnSlot::Warp, "warp");
        let weft_order = order(&colours.weft, YarnSlot::Weft, "weft");
        [self.materials.warp, self.materials.weft] = slots;
        self.materials.palette = palette;
        self.materials.warp_order = Some(warp_order);
        self.materials.weft_order = Some(weft_order);
    }

    /// The camera for a film of `width` x `height`.
    pub fn camera(&self, width: usize, height: usize) -> Result<Camera, ParamError> {
        camera_from(&self.camera, width, height)
    }

    /// Sampling settings, optionally restricted to one scattering component.
    #[must_use]
    pub fn render_settings(&self, component: Option<Component>) -> RenderSettings {
        RenderSettings {
            spp: self.render.spp,
            max_depth: self.render.max_depth,
            component: component.unwrap_or_default(),
            seed: self.render.seed,
        }
    }
}

/// Builds a camera from its scene section.
pub fn camera_from(c: &CameraSection, width: usize, height: usize) -> Result<Camera, ParamError> {
    let projection = match c.projection {
        ProjectionKind::Perspective => Projection::Perspective { fov_y_deg: c.fov_y_deg },
        ProjectionKind::Orthographic => Projection::Orthographic { height_cm: c.height_cm },
    };
    Camera::new(DVec3::from(c.eye), DVec3::from(c.target), DVec3::from(c.up), projection, width, height)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fabric::YarnRole;

    #[test]
    fn the_default_scene_parses_and_builds() {
        let scene = SceneFile::default_scene().build().unwrap();
        assert!(scene.exemplar.segment_count() > 1000);
        assert!(!scene.path_scene.lights.is_empty());
        assert_eq!(scene.path_scene.yarn_materials.len(), scene.exemplar.yarns.len());
    }

    /// The default scene with a three-colour palette: a 2/2 twill (4 x 4) with a warp order
    /// of 5 threads repeats every 20 ends.
    const COLOURWAY: &str = "[materials]\n\
        warp_order = \"2 navy, 2 cream, 1 red\"\n\
        weft_order = \"4 cream\"\n\
        [materials.palette]\n\
        navy = { base = \"warp\", c_tt = [0.05, 0.07, 0.3] }\n\
        cream = { base = \"weft\" }\n\
        red = { base = \"warp\", c_r = [0.05, 0.03, 0.03], c_tt = [0.8, 0.1, 0.08] }\n";

    fn with_colourway(extra: &str) -> String {
        DEFAULT_SCENE_TOML.replace("[swatch]", &format!("{extra}\n[swatch]"))
    }

    #[test]
    fn colour_orders_set_each_yarns_material_and_the_exemplar_repeat() {
        let file = SceneFile::parse(&with_colourway(COLOURWAY), Path::new("colourway.toml")).unwrap();
        let plain = SceneFile::default_scene().build().unwrap();
        let scene = file.build().unwrap();
        // Palette colours in name order: cream 0, navy 1, red 2.
        assert_eq!(scene.material_descs.len(), 3);
        let MaterialDesc::Fiber(navy) = scene.material_descs[1] else { panic!("navy is a fiber material") };
        assert_eq!(navy.c_tt, Rgb::new(0.05, 0.07, 0.3));
        let MaterialDesc::Fiber(preset_warp) = plain.material_descs[0] else { panic!("fiber warp") };
        assert_eq!(navy.c_r, preset_warp.c_r, "colours not given keep the base yarn's");
        assert_eq!(navy.beta_r_deg.to_bits(), preset_warp.beta_r_deg.to_bits());
        assert_eq!(scene.material_descs[0], plain.material_descs[1], "cream is the weft unchanged");

        let warp: Vec<u32> =
            scene.exemplar.yarns.iter().filter(|y| y.role == YarnRole::Warp).map(|y| y.material).collect();
        let weft: Vec<u32> =
            scene.exemplar.yarns.iter().filter(|y| y.role == YarnRole::Weft).map(|y| y.material).collect();
        let plain_warp = plain.exemplar.yarns.iter().filter(|y| y.role == YarnRole::Warp).count();
        assert_eq!(plain_warp, 4, "the default fabric is a 4-end twill");
        assert_eq!(warp.len(), 20, "lcm(4 ends, 5 colours)");
        assert_eq!(&warp[..10], &[1, 1, 0, 0, 2, 1, 1, 0, 0, 2]);
        assert_eq!(weft, vec![0; 4]);
        let (Tiling::Periodic { period }, Tiling::Periodic { period: plain_period }) =
            (scene.exemplar.tiling, plain.exemplar.tiling)
        else {
            panic!("woven exemplars are periodic")
        };
        assert!(
            (period.x - 5.0 * plain_period.x).abs() < 1e-6 && period.y.to_bits() == plain_period.y.to_bits()
        );
        // The path tracer shades every yarn with its own palette colour.
        assert_eq!(scene.path_scene.yarn_materials.len(), scene.exemplar.yarns.len());
        // And the scene writes back out as it was read.
        let again = SceneFile::parse(&file.to_toml().unwrap(), Path::new("again.toml")).unwrap();
        assert_eq!(again.materials, file.materials);
    }

    #[test]
    fn the_colourway_example_is_the_tested_colourway() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/scenes/colourway.toml");
        let example = SceneFile::load(&path).unwrap();
        let tested = SceneFile::parse(&with_colourway(COLOURWAY), Path::new("colourway.toml")).unwrap();
        assert_eq!(example.materials, tested.materials);
        assert_eq!(example.build().unwrap().exemplar.yarns.len(), 24);
    }

    #[test]
    fn wif_colours_become_the_palette_and_colour_orders() {
        let weaves = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/weaves");
        // One colour per direction: warp all wif1, weft all wif2.
        let mut file = SceneFile::default_scene();
        let colours = crate::fabric::wif::read_wif_colours(&weaves.join("twill_2_2.wif")).unwrap().unwrap();
        file.apply_wif_colours(&colours);
        assert_eq!(file.materials.warp_order.as_deref(), Some("1 wif1"));
        assert_eq!(file.materials.weft_order.as_deref(), Some("1 wif2"));
        let navy = file.materials.palette["wif1"];
        assert_eq!(navy.base, YarnSlot::Warp);
        let c_tt = navy.c_tt.expect("the preset's yarns are fiber materials");
        assert!(
            (c_tt.x - srgb_to_linear(20.0 / 255.0)).abs() < 1e-12
                && (c_tt.z - srgb_to_linear(90.0 / 255.0)).abs() < 1e-12
        );
        let scene = file.build().unwrap();
        assert_eq!(scene.material_descs.len(), 2);
        assert_eq!(scene.exemplar.yarns.len(), 8, "the weave's own 4 x 4 repeat");

        // Stripes: the draft and the colours of an 8-end file.
        let stripes = weaves.join("twill_2_2_stripes.wif");
        let draft = read_wif(&stripes).unwrap();
        assert_eq!((draft.rows(), draft.cols()), (4, 8));
        let mut file = SceneFile::default_scene();
        file.fabric = FabricSection {
            preset: None,
            spec: Some(FabricSpec::Woven(Box::new(WovenSpec {
                weave: WeaveSource::Draft(draft),
                ..match fabric_preset("default").unwrap().fabric {
                    FabricSpec::Woven(w) => *w,
                    FabricSpec::Imported(_) => unreachable!("the default fabric is woven"),
                }
            }))),
        };
        file.materials = MaterialsSection {
            warp: SceneFile::default_scene().material_slots()[0],
            weft: SceneFile::default_scene().material_slots()[1],
            ..MaterialsSection::default()
        };
        file.apply_wif_colours(&read_wif_colours_of(&stripes));
        assert_eq!(file.materials.warp_order.as_deref(), Some("4 wif1, 4 wif3"));
        assert_eq!(file.materials.weft_order.as_deref(), Some("3 wif2, 1 wif3"));
        assert_eq!(file.materials.palette["wif3"].base, YarnSlot::Warp, "red is first used by the warp");
        let scene = file.build().unwrap();
        assert_eq!(scene.material_descs.len(), 3);
        let warp: Vec<u32> = scene.exemplar.yarns.iter().take(8).map(|y| y.material).collect();
        assert_eq!(warp, [0, 0, 0, 0, 2, 2, 2, 2], "palette: wif1 0, wif2 1, wif3 2");
        // And it survives a save and a load.
        let again = SceneFile::parse(&file.to_toml().unwrap(), Path::new("again.toml")).unwrap();
        assert_eq!(again.materials, file.materials);
    }

    fn read_wif_colours_of(path: &Path) -> WifColours {
        crate::fabric::wif::read_wif_colours(path).unwrap().expect("a colour table")
    }

    #[test]
    fn bad_colourways_are_refused_naming_the_key_and_what_is_valid() {
        for (extra, expect) in [
            ("[materials]\nwarp_order = \"2 navy\"\n", "[materials.palette], which is missing"),
            (&COLOURWAY.replace("weft_order = \"4 cream\"\n", ""), "needs both warp_order and weft_order"),
            (&COLOURWAY.replace("2 cream, 1 red", "2 teal"), "one of cream, navy, red"),
            (&COLOURWAY.replace("\"4 cream\"", "\"17 cream\""), "weft_order"),
            (
                &COLOURWAY.replace(
                    "cream = { base = \"weft\" }",
                    "cream = { base = \"weft\", albedo = [0.5, 0.5, 0.5] }",
                ),
                "palette.cream: `albedo` recolours a Lambert yarn",
            ),
            (&COLOURWAY.replace("c_tt = [0.05, 0.07, 0.3]", "c_tt = [0.05, 0.07, 1.3]"), "palette.navy"),
            (&COLOURWAY.replace("base = \"weft\"", "base = \"selvedge\""), "selvedge"),
        ] {
            let message = parse_err(&with_colourway(extra));
            assert!(message.contains(expect), "{extra}: {message}");
            assert!(message.contains("bad.toml"), "{message}");
        }
        // A pattern weave whose joint repeat with the orders is too long: build and the check
        // that edits use both name the weave (a 5-end satin with a 16-thread warp order, 80
        // ends; the 2/2 twill of [fabric] repeats in 16).
        let long = with_colourway(&format!(
            "{}[pattern]\nweaves = [{{ weave = \"satin_4_1\" }}]\nrows = [\"01\"]\n",
            COLOURWAY.replace("2 navy, 2 cream, 1 red", "14 navy, 1 cream, 1 red")
        ));
        let message = parse_err(&long);
        assert!(message.contains("with [pattern] weaves[0]'s weave") && message.contains("80"), "{message}");
        let file = SceneFile::parse(&long, Path::new("p.toml")).unwrap();
        let check = file.check_colourway().unwrap_err();
        assert!(check.contains("with [pattern] weaves[0]'s weave") && check.contains("80"), "{check}");
    }

    /// Colour orders on patterned cloth: each exemplar repeats over its weave's joint repeat with
    /// the orders, the blocks stay the weaves' own (2 x 2 yarns for a 2/2 twill beside a plain
    /// weave, as without colours), and every exemplar's end `j` and pick `i` take the colours of
    /// thread `j` and `i` of the orders, so a yarn keeps its colour across blocks.
    #[test]
    fn patterned_cloth_takes_colour_orders_and_keeps_its_blocks() {
        let text = with_colourway(&format!(
            "{COLOURWAY}[pattern]\nweaves = [{{ weave = \"plain\" }}]\nrows = [\"01\"]\n"
        ));
        let file = SceneFile::parse(&text, Path::new("p.toml")).unwrap();
        assert_eq!(file.check_colourway(), Ok(()));
        let scene = file.build().unwrap();
        let colourway = file.colourway().unwrap().unwrap();
        let pattern = scene.pattern.as_ref().expect("patterned");
        // Warp order 5 threads: the twill's 4 ends repeat in 20 (10 blocks of 2), the plain
        // weave's 2 in 10 (5 blocks); weft order 4 threads: both repeat in 4 picks (2 blocks).
        let blocks: Vec<_> = pattern.exemplars.iter().map(|e| [e.blocks.nx, e.blocks.ny]).collect();
        assert_eq!(blocks, [[10, 2], [5, 2]]);
        let plain = SceneFile::default_scene().build().unwrap();
        let spacing = match plain.exemplar.tiling {
            Tiling::Periodic { period } => period / 4.0,
            Tiling::AsIs => panic!("woven exemplars are periodic"),
        };
        for (k, exemplar) in pattern.exemplars.iter().enumerate() {
            let Tiling::Periodic { period } = exemplar.tiling else { panic!("periodic") };
            let block = period / Vec2::new(exemplar.blocks.nx as f32, exemplar.blocks.ny as f32);
            assert!((block - 2.0 * spacing).abs().max_element() < 1e-6, "exemplar {k}: block {block}");
            let warp_ends = (exemplar.blocks.nx * 2) as usize;
            let materials: Vec<u32> = exemplar.yarns.iter().map(|y| y.material).collect();
            let want: Vec<u32> = (0..warp_ends)
                .map(|j| colourway.warp.colour_of(j))
                .chain((0..exemplar.yarns.len() - warp_ends).map(|i| colourway.weft.colour_of(i)))
                .collect();
            assert_eq!(materials, want, "exemplar {k}");
        }
        assert_eq!(pattern.exemplars[0], scene.exemplar);
        // Every exemplar's bake gets the palette's materials.
        for inputs in scene.bake_inputs(crate::bake::settings::Quality::Draft.settings()) {
            assert_eq!(inputs.materials, scene.material_descs);
            assert_eq!(inputs.materials.len(), 3);
        }
    }

    fn parse_err(text: &str) -> String {
        SceneFile::parse(text, Path::new("bad.toml"))
            .and_then(|s| s.build().map(|_| ()))
            .unwrap_err()
            .to_string()
    }

    /// Every documented default applies when its key is left out (docs/SCENE_FORMAT.md), section
    /// by section: a scene naming only what is required equals one spelling out the defaults.
    #[test]
    fn documented_defaults_apply_to_every_section_when_keys_are_left_out() {
        let parse = |text: &str| SceneFile::parse(text, Path::new("defaults.toml")).unwrap();
        let minimal = "[fabric]\npreset = \"default\"\n[camera]\neye = [0, 2, 3]\ntarget = [0, 0, 0]\n\
                       [[lights]]\ntype = \"directional\"\ndirection = [0, 0, 1]\nirradiance = [1, 1, 1]\n";
        let scene = parse(minimal);
        // [swatch]: absent, empty, or with one key given.
        assert_eq!(scene.swatch, SwatchSection { size_cm: [1.0, 1.0], ground: true });
        assert_eq!(parse(&format!("{minimal}[swatch]\n")).swatch, scene.swatch);
        let only_size = parse(&format!("{minimal}[swatch]\nsize_cm = [2, 3]\n")).swatch;
        assert_eq!(only_size, SwatchSection { size_cm: [2.0, 3.0], ground: true });
        let only_ground = parse(&format!("{minimal}[swatch]\nground = false\n")).swatch;
        assert_eq!(only_ground, SwatchSection { size_cm: [1.0, 1.0], ground: false });
        // [camera]: projection perspective, up +z, 30° field of view, 1 cm film height.
        let camera = scene.camera;
        assert_eq!(camera.projection, ProjectionKind::Perspective);
        assert_eq!((camera.up, camera.fov_y_deg, camera.height_cm), ([0.0, 0.0, 1.0], 30.0, 1.0));
        // [render], [gpu], [mesh]: every key optional.
        assert_eq!(
            scene.render,
            RenderSection { width: 256, height: 256, spp: 64, max_depth: 64, seed: 1, exposure: 0.0 }
        );
        assert_eq!(parse(&format!("{minimal}[render]\n")).render, scene.render);
        assert_eq!(parse(&format!("{minimal}[gpu]\n")).gpu, GpuSection::default());
        assert_eq!(parse(&format!("{minimal}[mesh]\n")).mesh, scene.mesh);
        SceneFile::parse(minimal, Path::new("defaults.toml")).unwrap().build().expect("builds");
    }

    const CAMERA: &str =
        "[camera]\nprojection = \"perspective\"\neye = [0, 0, 3]\ntarget = [0, 0, 0]\nup = [0, 1, 0]\n";

    #[test]
    fn the_projection_not_in_use_is_checked_too() {
        let light = "[[lights]]\ntype = \"directional\"\ndirection = [0, 0, 1]\nirradiance = [1, 1, 1]\n";
        for (projection, field) in [("perspective", "height_cm"), ("orthographic", "fov_y_deg")] {
            for value in ["nan", "inf", "-inf"] {
                let msg = parse_err(&format!(
                    "[fabric]\npreset = \"default\"\n[camera]\nprojection = \"{projection}\"\neye = [0, 0, 3]\ntarget = [0, 0, 0]\nup = [0, 1, 0]\n{field} = {value}\n{light}"
                ));
                assert!(msg.contains(&format!("camera.{field}")), "{projection} {field} = {value}: {msg}");
            }
        }
    }

    #[test]
    fn errors_name_the_file_line_and_field() {
        let text = format!(
            "[fabric]\npreset = \"default\"\n{CAMERA}[[lights]]\ntype = \"sg\"\naxis = [0, 0, 1]\nsharpness = -3\nintensity = [1, 1, 1]\n"
        );
        let msg = parse_err(&text);
        assert!(msg.starts_with("bad.toml:"), "{msg}");
        // Tagged tables ([[lights]]) are buffered by serde, so the line is the table's header.
        assert!(msg.contains("line 8"), "{msg}");
        assert!(msg.contains("sharpness"), "{msg}");
        assert!(msg.contains("0.0001 <= sharpness <= 100000"), "{msg}");

        let msg = parse_err(&format!("[fabric]\npreset = \"default\"\ncolour = 3\n{CAMERA}"));
        assert!(msg.contains("colour") && msg.contains("line 3"), "{msg}");

        let msg = parse_err(&format!(
            "[fabric]\npreset = \"nope\"\n{CAMERA}[[lights]]\ntype = \"directional\"\ndirection = [0, 0, 1]\nirradiance = [1, 1, 1]\n"
        ));
        assert!(msg.contains("unknown preset \"nope\"") && msg.contains("default"), "{msg}");

        let msg = parse_err(&format!("[fabric]\npreset = \"default\"\n{CAMERA}"));
        assert!(msg.contains("no [[lights]]"), "{msg}");

        let msg = parse_err(&format!(
            "[fabric]\npreset = \"default\"\n{CAMERA}[[lights]]\ntype = \"directional\"\ndirection = [0, 0, 0]\nirradiance = [1, 1, 1]\n"
        ));
        assert!(msg.contains("light.direction"), "{msg}");
    }

    #[test]
    fn a_missing_file_is_an_error_naming_it() {
        let msg = SceneFile::load(Path::new("/no/such/scene.toml")).unwrap_err().to_string();
        assert!(msg.contains("/no/such/scene.toml"), "{msg}");
    }

    const LIGHT: &str = "[[lights]]\ntype = \"directional\"\ndirection = [0, 0, 1]\nirradiance = [1, 1, 1]\n";

    fn patterned(pattern: &str) -> String {
        format!("[fabric]\npreset = \"default\"\n{pattern}{CAMERA}{LIGHT}")
    }

    fn patterned_scene_path() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/scenes/patterned.toml")
    }

    #[test]
    fn pattern_blocks_are_the_gcd_of_the_repeats() {
        let d = |p: WeavePreset| p.draft();
        assert_eq!(pattern_blocks(&[d(WeavePreset::Twill2_2), d(WeavePreset::Plain)]), [[2, 2], [1, 1]]);
        assert_eq!(pattern_blocks(&[d(WeavePreset::Twill2_1), d(WeavePreset::Plain)]), [[3, 3], [2, 2]]);
        assert_eq!(pattern_blocks(&[d(WeavePreset::Satin4_1), d(WeavePreset::Satin1_4)]), [[1, 1], [1, 1]]);
        // Rows and columns separately: a 4-pick x 2-end draft with a 4 x 4 twill.
        let tall = WeaveDraft::from_rows(&["X.", ".X", "X.", "X."]).unwrap();
        assert_eq!(
            pattern_blocks(&[tall, d(WeavePreset::Basket), d(WeavePreset::Twill2_2)]),
            [[1, 1], [2, 1], [2, 1]]
        );
    }

    #[test]
    fn the_patterned_example_builds_with_equal_blocks() {
        let file = SceneFile::load(&patterned_scene_path()).unwrap();
        let scene = file.build().unwrap();
        let pattern = scene.pattern.as_ref().expect("the example is patterned");
        assert_eq!(pattern.exemplars.len(), 2);
        assert_eq!(pattern.exemplars[0], scene.exemplar);
        let blocks: Vec<_> = pattern.exemplars.iter().map(|e| [e.blocks.nx, e.blocks.ny]).collect();
        assert_eq!(blocks, [[2, 2], [1, 1]]);
        let block_size = |e: &Exemplar| match e.tiling {
            Tiling::Periodic { period } => period / Vec2::new(e.blocks.nx as f32, e.blocks.ny as f32),
            Tiling::AsIs => panic!("woven exemplars are periodic"),
        };
        let (a, b) = (block_size(&pattern.exemplars[0]), block_size(&pattern.exemplars[1]));
        assert!((a - b).abs().max_element() < 1e-6 && (a.x - 0.07).abs() < 1e-6, "{a} vs {b}");
        // Exemplar 1 is the plain weave of the same yarns: a 2 x 2 repeat of the same spacing.
        assert_ne!(pattern.exemplars[1].fibers, scene.exemplar.fibers);
        assert_eq!((pattern.map.width, pattern.map.height), (8, 8));
        assert_eq!(pattern.map.exemplar_count(), 2);
        assert_eq!(scene.pattern_map(), pattern.map);
        assert_eq!(scene.exemplars().len(), 2);
        let inputs = scene.bake_inputs(crate::bake::settings::Quality::Draft.settings());
        assert_eq!(inputs.len(), 2);
        assert_eq!(inputs[1].exemplar, &pattern.exemplars[1]);
        assert_eq!(inputs[1].materials, scene.material_descs);

        // Without a pattern: one exemplar, every block exemplar 0.
        let plain = SceneFile::default_scene().build().unwrap();
        assert!(plain.pattern.is_none());
        assert_eq!(plain.pattern_map(), PatternMap::uniform(0));
        assert_eq!(plain.bake_inputs(crate::bake::settings::Quality::Draft.settings()).len(), 1);
        assert_eq!(plain.exemplars(), std::slice::from_ref(&plain.exemplar));
    }

    #[test]
    fn pattern_weaves_from_rows_and_wif_files_and_a_png_map() {
        let dir = tempfile::tempdir().unwrap();
        let wif = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/weaves/twill_2_2.wif");
        std::fs::copy(&wif, dir.path().join("t.wif")).unwrap();
        // A 2 x 1 PNG: gray 40 (exemplar 0) then 200 (exemplar 2); 120 unused in between.
        let png = dir.path().join("map.png");
        let mut enc = png::Encoder::new(std::fs::File::create(&png).unwrap(), 3, 1);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header().unwrap().write_image_data(&[40, 120, 200]).unwrap();
        let text = format!(
            "[fabric]\nspec = {{ weave = \"plain\" }}\n\
             [pattern]\nweaves = [{{ wif = \"t.wif\" }}, {{ rows = [\"XX..\", \".XX.\", \"..XX\", \"X..X\"] }}]\n\
             png = \"map.png\"\n{CAMERA}{LIGHT}"
        );
        let path = dir.path().join("s.toml");
        let scene = SceneFile::parse(&text, &path).unwrap().build().unwrap();
        let pattern = scene.pattern.unwrap();
        assert_eq!(pattern.map.exemplar_of_block, [0, 1, 2]);
        // The WIF twill and the same draft given as rows build the same exemplar.
        assert_eq!(pattern.exemplars[1], pattern.exemplars[2]);
        assert_eq!(pattern.exemplars[1].blocks, crate::fabric::BlockGrid { nx: 2, ny: 2 });
        assert_eq!(pattern.exemplars[0].blocks, crate::fabric::BlockGrid { nx: 1, ny: 1 });

        // A broken WIF file is named with its line.
        std::fs::write(dir.path().join("t.wif"), "[WEAVING]\nShafts=x\n").unwrap();
        let msg = SceneFile::parse(&text, &path).unwrap().build().err().unwrap().to_string();
        assert!(msg.contains("s.toml: [pattern]:") && msg.contains("t.wif:2: [WEAVING] Shafts=x"), "{msg}");
        std::fs::copy(&wif, dir.path().join("t.wif")).unwrap();
        std::fs::remove_file(&png).unwrap();
        let msg = SceneFile::parse(&text, &path).unwrap().build().err().unwrap().to_string();
        assert!(msg.contains("map.png"), "{msg}");
    }

    #[test]
    fn pattern_errors_name_the_place_and_the_valid_values() {
        let cases: Vec<(String, Vec<&str>)> = vec![
            (
                patterned("[pattern]\nweaves = [{ weave = \"plain\" }]\nrows = [\"0120\"]\n"),
                vec![
                    "bad.toml: [pattern]",
                    "names exemplar 2",
                    "only 2 exemplars",
                    "0 ([fabric]'s weave) to 1",
                ],
            ),
            (
                patterned("[pattern]\nweaves = [{ weave = \"plain\" }]\nrows = [\"01\"]\npng = \"m.png\"\n"),
                vec!["line 3", "exactly one of `rows"],
            ),
            (
                patterned("[pattern]\nweaves = [{ weave = \"plain\" }]\n"),
                vec!["line 3", "exactly one of `rows"],
            ),
            (
                patterned("[pattern]\nweaves = []\nrows = [\"0\"]\n"),
                vec!["line 3", "1 <= pattern.weaves <= 35"],
            ),
            (
                patterned(
                    "[pattern]\nweaves = [{ weave = \"plain\", rows = [\"X.\", \".X\"] }]\nrows = [\"01\"]\n",
                ),
                vec!["line 4", "exactly one of `weave"],
            ),
            (
                patterned("[pattern]\nweaves = [{ rows = [\"XX\", \".X\"] }]\nrows = [\"01\"]\n"),
                vec!["line 4", "row 0", "never interlaces"],
            ),
            (
                patterned("[pattern]\nweaves = [{ weave = \"plain\" }]\nrows = [\"01\", \"0-\"]\n"),
                vec!["line 3", "pattern row 1, column 1", "'-'"],
            ),
            (
                patterned("[pattern]\nweaves = [{ weave = \"plian\" }]\nrows = [\"01\"]\n"),
                vec!["line 4", "plian"],
            ),
            (
                patterned("[pattern]\nweaves = [{ weave = \"plain\" }]\nrows = [\"01\"]\ncolour = 1\n"),
                vec!["line 6", "colour"],
            ),
            (
                format!(
                    "[fabric]\nspec = {{ file = \"f.txt\" }}\n[pattern]\nweaves = [{{ weave = \"plain\" }}]\nrows = [\"01\"]\n{CAMERA}{LIGHT}"
                ),
                vec!["[pattern]", "woven [fabric]", "imported fibers"],
            ),
            (
                format!(
                    "[fabric]\nspec = {{ weave = \"plain\", blocks = [2, 2] }}\n[pattern]\nweaves = [{{ weave = \"basket\" }}]\nrows = [\"01\"]\n{CAMERA}{LIGHT}"
                ),
                vec!["blocks = [2, 2]", "remove `blocks`"],
            ),
        ];
        for (text, needles) in cases {
            let msg = parse_err(&text);
            assert!(msg.starts_with("bad.toml"), "{msg}");
            for needle in needles {
                assert!(msg.contains(needle), "{msg:?} lacks {needle:?}\n{text}");
            }
        }
    }

    /// `to_toml` then `parse` gives the scene back, `path` aside.
    fn assert_round_trip(scene: &SceneFile) -> String {
        let text = scene.to_toml().unwrap();
        let back = SceneFile::parse(&text, &scene.path).unwrap_or_else(|e| panic!("{e}\n{text}"));
        assert_eq!(&back, scene, "{text}");
        text
    }

    #[test]
    fn scenes_round_trip_through_toml() {
        let default = SceneFile::default_scene();
        let text = assert_round_trip(&default);
        assert!(text.starts_with("# twill scene"), "{text}");
        for section in ["[fabric]", "[swatch]", "[camera]", "[[lights]]", "[render]", "[mesh]", "[gpu]"] {
            assert!(text.contains(section), "{section} missing from\n{text}");
        }

        let patterned = SceneFile::load(&patterned_scene_path()).unwrap();
        let text = assert_round_trip(&patterned);
        assert!(text.contains("[pattern]") && text.contains("plain"), "{text}");

        // A procedural spec with draft rows, material overrides, a mesh file, a PNG map and a WIF
        // weave, and floats that need every digit.
        let text = format!(
            "[fabric.spec]\nrows = [\"X..\", \".X.\", \"..X\"]\nspacing_warp = 0.1\ncrimp = 0.0123456789012345678\nseed = 3\n\
             warp = {{ width = 0.03, height = 0.015 }}\n\
             [materials]\nwarp = {{ model = \"lambert\", albedo = [0.1, 0.2, 0.3] }}\n\
             weft = {{ model = \"fiber\", c_r = [0.04, 0.04, 0.04], beta_r_deg = 5.0, c_tt = [0.8, 0.3, 0.2], beta_tt_deg = 10.0, gamma_tt_deg = 25.0 }}\n\
             [pattern]\nweaves = [{{ rows = [\"X.\", \".X\"] }}, {{ wif = \"w.wif\" }}, {{ weave = \"satin_4_1\" }}]\npng = \"maps/m.png\"\n\
             [mesh]\npath = \"cloth.obj\"\nsize_cm = [3, 4]\n\
             {CAMERA}{LIGHT}\
             [[lights]]\ntype = \"sg\"\naxis = [0.1, 0.2, 0.3]\nsharpness = 1e-4\nintensity = [1e300, 5e-324, 0.30000000000000004]\n\
             [render]\nseed = 9007199254740993\nexposure = -1.25\n[gpu]\nshadow_map_size = 512\n"
        );
        let mut spec = SceneFile::parse(&text, Path::new("/some/dir/spec.toml")).unwrap();
        spec.camera.eye = [0.1 + 0.2, 1.0 / 3.0, -2.0_f64.sqrt()];
        spec.camera.fov_y_deg = std::f64::consts::PI * 10.0;
        spec.gpu.sigma_glo_cm = f64::MIN_POSITIVE;
        let text = assert_round_trip(&spec);
        assert!(text.contains("rows = [\"X..\", \".X.\", \"..X\"]"), "{text}");
        let fabric = text.split("[fabric").nth(1).unwrap();
        assert!(!fabric.contains("preset"), "{text}");
    }

    #[test]
    fn save_writes_atomically_and_keeps_relative_paths_working() {
        let dir = tempfile::tempdir().unwrap();
        let scene_dir = dir.path().join("scenes");
        std::fs::create_dir(&scene_dir).unwrap();
        let text = format!(
            "[fabric]\npreset = \"default\"\n[pattern]\nweaves = [{{ wif = \"w.wif\" }}]\nrows = [\"01\"]\n[mesh]\npath = \"m.obj\"\n{CAMERA}{LIGHT}"
        );
        let scene = SceneFile::parse(&text, &scene_dir.join("a.toml")).unwrap();
        // Same folder: saved as is.
        let same = scene_dir.join("b.toml");
        scene.save(&same).unwrap();
        let mut back = SceneFile::load(&same).unwrap();
        back.path.clone_from(&scene.path);
        assert_eq!(back, scene);
        // Another folder: relative paths become absolute, pointing at the same files.
        let other = dir.path().join("c.toml");
        scene.save(&other).unwrap();
        let moved = SceneFile::load(&other).unwrap();
        assert_eq!(moved.mesh.path.unwrap(), scene_dir.join("m.obj"));
        let Some(PatternSection { weaves, .. }) = moved.pattern else { panic!("no pattern") };
        assert_eq!(weaves, [PatternWeave::Wif(scene_dir.join("w.wif"))]);
        // Nothing but the saved files (no temporaries) is left; an unwritable place is an error.
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 2, "{names:?}");
        let msg = scene.save(Path::new("/nonexistent-dir/s.toml")).unwrap_err().to_string();
        assert!(msg.starts_with("/nonexistent-dir/s.toml: could not write"), "{msg}");
    }

    #[test]
    fn the_largest_seed_round_trips() {
        let mut scene = SceneFile::default_scene();
        scene.render.seed = u64::MAX;
        assert_round_trip(&scene);
    }
}
