//! The `[fabric]` section of a scene file, and named fabrics resembling the 2017 paper's.
//!
//! How it works: [`FabricSpec`] is either a procedural woven fabric (a weave preset or draft
//! rows, spacings, crimp, warp and weft [`YarnParams`], blocks, seed) or imported fibers (a file,
//! its format, how it tiles, an optional radius override). In TOML both are flat tables told apart
//! by the presence of `file`:
//!
//! ```toml
//! [fabric]
//! weave = "twill_2_2"            # or rows = ["XX..", ".XX.", "..XX", "X..X"]
//! spacing_warp = 0.035           # cm; default: the warp yarn width
//! spacing_weft = 0.035           # cm; default: the weft yarn width
//! crimp = 0.009                  # cm; default: yarns just touching at crossings
//! blocks = [2, 2]                # default [1, 1]
//! seed = 7                       # default 0
//! warp = { width = 0.03, height = 0.018, fibers_per_ply = 60 }   # other fields default
//! weft = { width = 0.03, height = 0.018 }
//!
//! # or
//! [fabric]
//! file = "fibers/silk.txt"       # relative to the scene file
//! format = "mitsuba"             # or "hair"; default from the extension (.hair = hair)
//! tiling = { period = [0.2, 0.2] }   # or "as_is" (default)
//! radius = 0.0005                # optional: overrides (and supplies missing) fiber radii
//! ```
//!
//! Deserialization goes through a flat table with `deny_unknown_fields` (so a misspelt or
//! misplaced field is named, with its line, by the TOML error) and is then checked for fields
//! that do not belong to the chosen kind. [`FabricSpec::build`] validates the numbers and makes
//! the [`Exemplar`].
//!
//! Presets ([`fabric_presets`]) pair a fabric with warp and weft materials. Their numbers are
//! chosen to keep precomputation fast (tens of thousands of segments) rather than to match the
//! paper's CT-scanned models (75k-580k segments): fewer, thicker fibers than real yarns.

use std::path::{Path, PathBuf};

use super::exemplar::WovenFabric;
use super::fiber_io::{FiberFormat, FiberIoError, exemplar_from_fibers, read_fibers};
use super::weave::{WeaveDraft, WeaveError, WeavePreset};
use super::yarn::YarnParams;
use super::{BlockGrid, Exemplar, Tiling};
use crate::Rgb;
use crate::bcsdf::{FiberParams, MaterialDesc};
use crate::params::{ParamError, check_count, check_positive, check_range};

/// A fabric that could not be built.
#[derive(Debug, thiserror::Error)]
pub enum FabricError {
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error(transparent)]
    Weave(#[from] WeaveError),
    #[error(transparent)]
    Io(#[from] FiberIoError),
    #[error("{}: the file holds no fibers", file.display())]
    NoFibers { file: PathBuf },
}

/// Where a woven fabric's draft comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum WeaveSource {
    Preset(WeavePreset),
    Draft(WeaveDraft),
}

impl WeaveSource {
    #[must_use]
    pub fn draft(&self) -> WeaveDraft {
        match self {
            WeaveSource::Preset(p) => p.draft(),
            WeaveSource::Draft(d) => d.clone(),
        }
    }
}

/// A procedural woven fabric as the scene file gives it.
#[derive(Debug, Clone, PartialEq)]
pub struct WovenSpec {
    pub weave: WeaveSource,
    /// cm; `None` = the warp yarn width.
    pub spacing_warp: Option<f64>,
    /// cm; `None` = the weft yarn width.
    pub spacing_weft: Option<f64>,
    /// cm; `None` = [`WovenFabric::touching_crimp`].
    pub crimp: Option<f64>,
    pub warp: YarnParams,
    pub weft: YarnParams,
    pub blocks: [u32; 2],
    pub seed: u64,
}

impl WovenSpec {
    /// The woven fabric with defaults filled in (not yet validated).
    #[must_use]
    pub fn woven_fabric(&self) -> WovenFabric {
        let mut f = WovenFabric::new(
            self.weave.draft(),
            self.spacing_warp.unwrap_or(self.warp.width),
            self.spacing_weft.unwrap_or(self.weft.width),
            self.warp,
            self.weft,
        );
        if let Some(c) = self.crimp {
            f.crimp = c;
        }
        f.blocks = BlockGrid { nx: self.blocks[0], ny: self.blocks[1] };
        f.seed = self.seed;
        f
    }
}

/// How imported fibers tile the plane.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "RawTiling", into = "RawTiling")]
pub enum TilingSpec {
    /// `tiling = "as_is"`: used once, as given.
    AsIs,
    /// `tiling = { period = [px, py] }` (cm).
    Periodic { period: [f64; 2] },
}

#[derive(serde::Serialize, serde::Deserialize)]
#[serde(untagged, expecting = "`tiling = \"as_is\"` or `tiling = { period = [px, py] }`")]
enum RawTiling {
    Name(String),
    Periodic { period: [f64; 2] },
}

impl TryFrom<RawTiling> for TilingSpec {
    type Error = String;
    fn try_from(raw: RawTiling) -> Result<Self, String> {
        match raw {
            RawTiling::Name(n) if n == "as_is" => Ok(TilingSpec::AsIs),
            RawTiling::Name(n) => {
                Err(format!("tiling = {n:?}: expected \"as_is\" or {{ period = [px, py] }}"))
            }
            RawTiling::Periodic { period } => Ok(TilingSpec::Periodic { period }),
        }
    }
}

impl From<TilingSpec> for RawTiling {
    fn from(t: TilingSpec) -> Self {
        match t {
            TilingSpec::AsIs => RawTiling::Name("as_is".into()),
            TilingSpec::Periodic { period } => RawTiling::Periodic { period },
        }
    }
}

/// Imported fibers as the scene file gives them.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportedSpec {
    /// Relative paths are taken relative to the scene file's directory.
    pub file: PathBuf,
    /// `None` = by extension.
    pub format: Option<FiberFormat>,
    pub tiling: TilingSpec,
    /// cm; replaces every fiber's radius (and supplies it for points without one).
    pub radius: Option<f64>,
    pub blocks: [u32; 2],
}

/// The `[fabric]` section of a scene file; see the module documentation for its TOML form.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "RawFabricSpec", into = "RawFabricSpec")]
pub enum FabricSpec {
    Woven(Box<WovenSpec>),
    Imported(ImportedSpec),
}

/// The flat TOML table behind [`FabricSpec`].
#[derive(Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFabricSpec {
    #[serde(skip_serializing_if = "Option::is_none")]
    weave: Option<WeavePreset>,
    #[serde(skip_serializing_if = "Option::is_none")]
    rows: Option<Vec<String>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    spacing_warp: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    spacing_weft: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    crimp: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    blocks: Option<[u32; 2]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    seed: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    file: Option<PathBuf>,
    #[serde(skip_serializing_if = "Option::is_none")]
    format: Option<FiberFormat>,
    #[serde(skip_serializing_if = "Option::is_none")]
    tiling: Option<TilingSpec>,
    #[serde(skip_serializing_if = "Option::is_none")]
    radius: Option<f64>,
    // Tables last, so serialized TOML puts plain values first.
    #[serde(skip_serializing_if = "Option::is_none")]
    warp: Option<YarnParams>,
    #[serde(skip_serializing_if = "Option::is_none")]
    weft: Option<YarnParams>,
}

impl TryFrom<RawFabricSpec> for FabricSpec {
    type Error = String;

    fn try_from(raw: RawFabricSpec) -> Result<Self, String> {
        let blocks = raw.blocks.unwrap_or([1, 1]);
        if let Some(file) = raw.file {
            let woven_only = [
                ("weave", raw.weave.is_some()),
                ("rows", raw.rows.is_some()),
                ("spacing_warp", raw.spacing_warp.is_some()),
                ("spacing_weft", raw.spacing_weft.is_some()),
                ("crimp", raw.crimp.is_some()),
                ("seed", raw.seed.is_some()),
                ("warp", raw.warp.is_some()),
                ("weft", raw.weft.is_some()),
            ];
            if let Some((name, _)) = woven_only.iter().find(|(_, set)| *set) {
                return Err(format!(
                    "`{name}` describes a woven fabric and cannot be used with `file` (imported fibers)"
                ));
            }
            return Ok(FabricSpec::Imported(ImportedSpec {
                file,
                format: raw.format,
                tiling: raw.tiling.unwrap_or(TilingSpec::AsIs),
                radius: raw.radius,
                blocks,
            }));
        }
        let import_only = [
            ("format", raw.format.is_some()),
            ("tiling", raw.tiling.is_some()),
            ("radius", raw.radius.is_some()),
        ];
        if let Some((name, _)) = import_only.iter().find(|(_, set)| *set) {
            return Err(format!("`{name}` only applies to imported fibers and needs `file = \"...\"`"));
        }
        let weave = match (raw.weave, raw.rows) {
            (Some(_), Some(_)) => return Err("give either `weave` or `rows`, not both".into()),
            (Some(p), None) => WeaveSource::Preset(p),
            (None, Some(rows)) => {
                WeaveSource::Draft(WeaveDraft::from_rows(&rows).map_err(|e| e.to_string())?)
            }
            (None, None) => {
                return Err(
                    "no fabric given: set `weave = \"twill_2_2\"` (or plain, twill_2_1, satin_4_1, satin_1_4, \
                     satin_2_3, basket), `rows = [\"X.\", \".X\"]`, or `file = \"fibers.txt\"`"
                        .into(),
                );
            }
        };
        Ok(FabricSpec::Woven(Box::new(WovenSpec {
            weave,
            spacing_warp: raw.spacing_warp,
            spacing_weft: raw.spacing_weft,
            crimp: raw.crimp,
            warp: raw.warp.unwrap_or_default(),
            weft: raw.weft.unwrap_or_default(),
            blocks,
            seed: raw.seed.unwrap_or(0),
        })))
    }
}

impl From<FabricSpec> for RawFabricSpec {
    fn from(spec: FabricSpec) -> Self {
        match spec {
            FabricSpec::Woven(w) => {
                let (weave, rows) = match w.weave {
                    WeaveSource::Preset(p) => (Some(p), None),
                    WeaveSource::Draft(d) => (None, Some(d.to_rows())),
                };
                RawFabricSpec {
                    weave,
                    rows,
                    spacing_warp: w.spacing_warp,
                    spacing_weft: w.spacing_weft,
                    crimp: w.crimp,
                    blocks: Some(w.blocks),
                    seed: Some(w.seed),
                    warp: Some(w.warp),
                    weft: Some(w.weft),
                    ..RawFabricSpec::default()
                }
            }
            FabricSpec::Imported(i) => RawFabricSpec {
                file: Some(i.file),
                format: i.format,
                tiling: Some(i.tiling),
                radius: i.radius,
                blocks: Some(i.blocks),
                ..RawFabricSpec::default()
            },
        }
    }
}

impl FabricSpec {
    /// Parses the body of a `[fabric]` table (without the header).
    pub fn from_toml(text: &str) -> Result<Self, toml::de::Error> {
        toml::from_str(text)
    }

    /// Builds the exemplar; relative file paths are taken relative to `base_dir`.
    pub fn build(&self, base_dir: &Path) -> Result<Exemplar, FabricError> {
        match self {
            FabricSpec::Woven(w) => Ok(w.woven_fabric().build()?),
            FabricSpec::Imported(spec) => {
                check_count("blocks[0]", spec.blocks[0] as usize, 1, 64)?;
                check_count("blocks[1]", spec.blocks[1] as usize, 1, 64)?;
                let radius = spec.radius.map(|r| check_range("radius", r, 1e-6, 1.0)).transpose()?;
                let tiling = match spec.tiling {
                    TilingSpec::AsIs => Tiling::AsIs,
                    TilingSpec::Periodic { period } => {
                        check_positive("tiling.period[0]", period[0])?;
                        check_positive("tiling.period[1]", period[1])?;
                        Tiling::Periodic { period: glam::Vec2::new(period[0] as f32, period[1] as f32) }
                    }
                };
                let path = base_dir.join(&spec.file);
                let mut fibers = read_fibers(&path, spec.format, radius.map(|r| r as f32))?;
                if fibers.is_empty() {
                    return Err(FabricError::NoFibers { file: path });
                }
                if let Some(r) = radius {
                    for f in &mut fibers {
                        f.radius = r as f32;
                    }
                }
                let blocks = BlockGrid { nx: spec.blocks[0], ny: spec.blocks[1] };
                Ok(exemplar_from_fibers(fibers, tiling, blocks))
            }
        }
    }
}

/// A named fabric with its warp (material 0) and weft (material 1) materials.
#[derive(Debug, Clone, PartialEq)]
pub struct FabricPreset {
    pub name: &'static str,
    pub description: &'static str,
    pub fabric: FabricSpec,
    pub warp_material: MaterialDesc,
    pub weft_material: MaterialDesc,
}

/// Silk BCSDF lobe widths from math-notes (a public port of Khungurn 2015): beta_R 1.0,
/// beta_TT 10, gamma_TT 19.823 degrees. Colours (C_R, C_TT) are ours: dyed silk is a clear
/// colour in transmission with a faint tinted sheen.
fn silk(c_r: [f64; 3], c_tt: [f64; 3]) -> MaterialDesc {
    MaterialDesc::Fiber(FiberParams {
        c_r: Rgb::from_array(c_r),
        beta_r_deg: 1.0,
        c_tt: Rgb::from_array(c_tt),
        beta_tt_deg: 10.0,
        gamma_tt_deg: 19.823,
    })
}

/// Cotton BCSDF lobe widths from math-notes: beta_R 1.0, beta_TT 27.197, gamma_TT 38.269 degrees;
/// colours are ours.
fn cotton(c_r: [f64; 3], c_tt: [f64; 3]) -> MaterialDesc {
    MaterialDesc::Fiber(FiberParams {
        c_r: Rgb::from_array(c_r),
        beta_r_deg: 1.0,
        c_tt: Rgb::from_array(c_tt),
        beta_tt_deg: 27.197,
        gamma_tt_deg: 38.269,
    })
}

/// Fleece BCSDF from math-notes, all five values as reported there (used for the wool-like
/// gabardine).
fn fleece() -> MaterialDesc {
    MaterialDesc::Fiber(FiberParams {
        c_r: Rgb::new(0.04, 0.087, 0.087),
        beta_r_deg: 7.238,
        c_tt: Rgb::new(0.452, 0.725, 0.948),
        beta_tt_deg: 10.0,
        gamma_tt_deg: 25.989,
    })
}

fn woven(weave: WeavePreset, spacing: [f64; 2], warp: YarnParams, weft: YarnParams, seed: u64) -> FabricSpec {
    FabricSpec::Woven(Box::new(WovenSpec {
        weave: WeaveSource::Preset(weave),
        spacing_warp: Some(spacing[0]),
        spacing_weft: Some(spacing[1]),
        crimp: None,
        warp,
        weft,
        blocks: [1, 1],
        seed,
    }))
}

/// Filament silk yarn: untwisted-ish (silk is reeled, lightly thrown), one ply, flat.
fn silk_yarn(width: f64, fibers: u32, fiber_radius: f64) -> YarnParams {
    YarnParams {
        width,
        height: 0.45 * width,
        plies: 1,
        fibers_per_ply: fibers,
        fiber_radius,
        ply_twist: 2.0,
        fiber_twist: 0.0,
        migration_min: 0.4,
        migration_max: 1.0,
        migration_period: 0.1,
        flyaways_per_ply: 0,
        ..YarnParams::default()
    }
}

/// Staple (cotton / wool) yarn: two plies, Z-ply of S-twisted fibers, a few loops.
fn staple_yarn(width: f64, fibers_per_ply: u32, fiber_radius: f64) -> YarnParams {
    YarnParams { width, height: 0.6 * width, plies: 2, fibers_per_ply, fiber_radius, ..YarnParams::default() }
}

/// All named fabrics. Segment counts are listed in the tests.
#[must_use]
pub fn fabric_presets() -> Vec<FabricPreset> {
    vec![
        FabricPreset {
            name: "default",
            description: "Navy and cream 2/2 cotton twill, small (~20k segments) for fast precomputation",
            // Guessed: a plausible shirting twill; fibers far fewer and thicker than real cotton.
            fabric: woven(
                WeavePreset::Twill2_2,
                [0.035, 0.035],
                staple_yarn(0.03, 80, 0.0005),
                staple_yarn(0.03, 80, 0.0005),
                1,
            ),
            warp_material: cotton([0.03, 0.03, 0.05], [0.15, 0.22, 0.55]),
            weft_material: cotton([0.04, 0.04, 0.04], [0.85, 0.8, 0.68]),
        },
        FabricPreset {
            name: "silk_satin",
            description: "Warp-faced 4/1 silk satin in deep red, strong sheen along the warp",
            // Paper Table 1 "4/1 Satin" and "Silk" (fiber radius 0.00047 cm, used here); yarn sizes
            // and fiber count guessed (the paper's silk has ~7.7k fibers; ours ~2k).
            fabric: woven(
                WeavePreset::Satin4_1,
                [0.025, 0.03],
                silk_yarn(0.028, 160, 0.00047),
                silk_yarn(0.03, 120, 0.00047),
                2,
            ),
            warp_material: silk([0.06, 0.04, 0.04], [0.8, 0.12, 0.15]),
            weft_material: silk([0.05, 0.04, 0.04], [0.6, 0.1, 0.12]),
        },
        FabricPreset {
            name: "gabardine_twill",
            description: "Khaki wool gabardine: steep warp-faced 2/1 twill with fleece-like fibers",
            // Paper Table 1 "Gabardine" fiber radius 0.00161 cm (used); BCSDF lobes from the fleece
            // values in math-notes with the colour changed to khaki (guess); weave and sizes guessed.
            // Thick fibers leave room for only 16 per ply, so segments are made short instead.
            fabric: woven(
                WeavePreset::Twill2_1,
                [0.028, 0.035],
                YarnParams { segment_length: 0.003, ..staple_yarn(0.03, 16, 0.00161) },
                YarnParams { segment_length: 0.003, ..staple_yarn(0.032, 16, 0.00161) },
                3,
            ),
            warp_material: with_colour(fleece(), [0.05, 0.05, 0.04], [0.75, 0.62, 0.4]),
            weft_material: with_colour(fleece(), [0.05, 0.05, 0.04], [0.68, 0.56, 0.36]),
        },
        FabricPreset {
            name: "shot_silk_a",
            description: "Shot silk, plain weave: red warp, green weft (colour shifts with angle)",
            // Paper Table 1 "Shot Silk A" is procedural, plain-woven silk with two colours; its
            // fibers are 0.0001 cm, ours 0.0004 cm so a yarn needs fewer (guess). The 2 x 2 repeat
            // is short, so segments are short too (the paper's shot silks have ~38 per fiber).
            fabric: woven(
                WeavePreset::Plain,
                [0.03, 0.03],
                YarnParams { segment_length: 0.003, ..silk_yarn(0.028, 150, 0.0004) },
                YarnParams { segment_length: 0.003, ..silk_yarn(0.028, 150, 0.0004) },
                4,
            ),
            warp_material: silk([0.05, 0.03, 0.03], [0.85, 0.1, 0.08]),
            weft_material: silk([0.03, 0.05, 0.03], [0.15, 0.7, 0.2]),
        },
        FabricPreset {
            name: "shot_silk_b",
            description: "Shot silk, plain weave: blue warp, gold weft",
            // As shot_silk_a, denser weft (guess), different colours.
            fabric: woven(
                WeavePreset::Plain,
                [0.03, 0.026],
                YarnParams { segment_length: 0.003, ..silk_yarn(0.028, 150, 0.0004) },
                YarnParams { segment_length: 0.003, ..silk_yarn(0.024, 120, 0.0004) },
                5,
            ),
            warp_material: silk([0.03, 0.03, 0.06], [0.1, 0.2, 0.85]),
            weft_material: silk([0.06, 0.05, 0.02], [0.9, 0.7, 0.15]),
        },
        FabricPreset {
            name: "cotton_plain",
            description: "Undyed cotton plain weave (calico)",
            // Cotton BCSDF lobes from math-notes; fiber radius 8 um (cotton); sizes guessed.
            fabric: woven(
                WeavePreset::Plain,
                [0.032, 0.032],
                YarnParams { segment_length: 0.004, ..staple_yarn(0.03, 50, 0.0008) },
                YarnParams { segment_length: 0.004, ..staple_yarn(0.03, 50, 0.0008) },
                6,
            ),
            warp_material: cotton([0.04, 0.04, 0.04], [0.9, 0.87, 0.8]),
            weft_material: cotton([0.04, 0.04, 0.04], [0.9, 0.87, 0.8]),
        },
        FabricPreset {
            name: "satin_2_3",
            description: "2/3 satin with a black weft and a white silk warp",
            // Paper Table 1 "2/3 Satin" (fiber radius 0.0015 cm, used) whose one yarn is black
            // (paper section 7); the draft is our reading of the name (see WeavePreset::Satin2_3).
            fabric: woven(
                WeavePreset::Satin2_3,
                [0.03, 0.03],
                YarnParams { segment_length: 0.006, ..silk_yarn(0.028, 30, 0.0015) },
                YarnParams { segment_length: 0.006, ..silk_yarn(0.03, 30, 0.0015) },
                7,
            ),
            warp_material: silk([0.05, 0.05, 0.05], [0.9, 0.88, 0.82]),
            weft_material: silk([0.04, 0.04, 0.04], [0.03, 0.03, 0.03]),
        },
        FabricPreset {
            name: "large",
            description: "Benchmark fabric: 4/1 satin with ~100k segments",
            // Guessed sizes; cotton-like fibers so light travels deep (a harder case).
            fabric: woven(
                WeavePreset::Satin4_1,
                [0.035, 0.035],
                YarnParams { segment_length: 0.007, ..staple_yarn(0.03, 200, 0.0004) },
                YarnParams { segment_length: 0.007, ..staple_yarn(0.03, 200, 0.0004) },
                8,
            ),
            warp_material: cotton([0.04, 0.04, 0.04], [0.2, 0.5, 0.45]),
            weft_material: cotton([0.04, 0.04, 0.04], [0.85, 0.85, 0.8]),
        },
    ]
}

fn with_colour(material: MaterialDesc, c_r: [f64; 3], c_tt: [f64; 3]) -> MaterialDesc {
    match material {
        MaterialDesc::Fiber(p) => {
            MaterialDesc::Fiber(FiberParams { c_r: Rgb::from_array(c_r), c_tt: Rgb::from_array(c_tt), ..p })
        }
        other @ MaterialDesc::Lambert { .. } => other,
    }
}

/// The preset called `name`.
#[must_use]
pub fn fabric_preset(name: &str) -> Option<FabricPreset> {
    fabric_presets().into_iter().find(|p| p.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fabric::exemplar::volume_fraction;

    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Scene {
        fabric: FabricSpec,
    }

    fn parse(text: &str) -> Result<FabricSpec, String> {
        toml::from_str::<Scene>(text).map(|s| s.fabric).map_err(|e| e.to_string())
    }

    #[test]
    fn presets_build_with_reasonable_sizes() {
        let names: Vec<_> = fabric_presets().iter().map(|p| p.name).collect();
        for required in [
            "default",
            "silk_satin",
            "gabardine_twill",
            "shot_silk_a",
            "shot_silk_b",
            "cotton_plain",
            "large",
        ] {
            assert!(names.contains(&required), "missing preset {required}");
        }
        for preset in fabric_presets() {
            let ex = preset.fabric.build(Path::new(".")).unwrap();
            let n = ex.segment_count();
            let vf = volume_fraction(&ex);
            println!(
                "{:16} {:>7} segments {:>6} fibers, volume fraction {vf:.3}",
                preset.name,
                n,
                ex.fibers.len()
            );
            match preset.name {
                "default" => assert!((15_000..=40_000).contains(&n), "default has {n} segments"),
                "large" => assert!((80_000..=130_000).contains(&n), "large has {n} segments"),
                _ => assert!((5_000..=100_000).contains(&n), "{} has {n} segments", preset.name),
            }
            assert!(vf > 0.05 && vf < 0.7, "{}: volume fraction {vf}", preset.name);
            // Round trip through TOML.
            let text = toml::to_string(&preset.fabric).unwrap();
            assert_eq!(FabricSpec::from_toml(&text).unwrap(), preset.fabric, "{text}");
        }
        assert!(fabric_preset("shot_silk_b").is_some() && fabric_preset("nope").is_none());
        let a = fabric_preset("shot_silk_a").unwrap();
        assert_ne!(a.warp_material, a.weft_material);
    }

    #[test]
    fn woven_spec_parses_with_defaults() {
        let spec = parse(
            "[fabric]\nweave = \"satin_4_1\"\nblocks = [2, 3]\nseed = 9\nwarp = { width = 0.02, height = 0.01 }\n",
        )
        .unwrap();
        let FabricSpec::Woven(w) = &spec else { panic!("{spec:?}") };
        assert_eq!(w.weave, WeaveSource::Preset(WeavePreset::Satin4_1));
        assert_eq!((w.blocks, w.seed), ([2, 3], 9));
        let fabric = w.woven_fabric();
        assert!((fabric.spacing_warp - 0.02).abs() < 1e-12);
        assert!((fabric.warp.height - 0.01).abs() < 1e-12);
        assert_eq!(fabric.weft, YarnParams::default());
        let spec = parse("[fabric]\nrows = [\"X..\", \".X.\", \"..X\"]\n").unwrap();
        let FabricSpec::Woven(w) = &spec else { panic!() };
        assert_eq!(w.weave.draft().cols(), 3);
    }

    #[test]
    fn errors_name_the_field_and_line() {
        let cases = [
            ("[fabric]\nweave = \"plain\"\nspacing_wrap = 0.1\n", ["spacing_wrap", "line 3"]),
            ("[fabric]\nweave = \"plain\"\nspacing_warp = \"wide\"\n", ["spacing_warp", "line 3"]),
            ("[fabric]\nweave = \"plaid\"\n", ["plaid", "line 2"]),
            ("[fabric]\nweave = \"plain\"\nwarp = { widht = 0.1 }\n", ["widht", "line 3"]),
            (
                "[fabric]\nweave = \"plain\"\nrows = [\"X.\", \".X\"]\n",
                ["either `weave` or `rows`", "line 1"],
            ),
            ("[fabric]\nrows = [\"XX\", \".X\"]\n", ["row 0", "interlace"]),
            ("[fabric]\nfile = \"a.txt\"\ncrimp = 0.1\n", ["`crimp`", "file"]),
            ("[fabric]\nweave = \"plain\"\ntiling = \"as_is\"\n", ["`tiling`", "file"]),
            ("[fabric]\nfile = \"a.txt\"\ntiling = \"wrap\"\n", ["wrap", "as_is"]),
            ("[fabric]\n", ["no fabric given", "weave"]),
        ];
        for (text, needles) in cases {
            let msg = parse(text).unwrap_err();
            for needle in needles {
                assert!(msg.contains(needle), "{text:?}: {msg:?} lacks {needle:?}");
            }
        }
    }

    #[test]
    fn build_errors_name_the_value_or_file() {
        let spec = parse("[fabric]\nweave = \"plain\"\ncrimp = -1.0\n").unwrap();
        let msg = spec.build(Path::new(".")).unwrap_err().to_string();
        assert!(msg.contains("crimp = -1"), "{msg}");
        let spec = parse("[fabric]\nfile = \"missing.hair\"\n").unwrap();
        let msg = spec.build(Path::new("/nonexistent-dir")).unwrap_err().to_string();
        assert!(msg.contains("/nonexistent-dir/missing.hair"), "{msg}");
    }

    #[test]
    fn imported_fibers_build_relative_to_the_base_dir() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("f.txt"), "0 0 0\n0.1 0 0\n\n0 0.1 0\n0.1 0.1 0.01\n").unwrap();
        let spec =
            parse("[fabric]\nfile = \"f.txt\"\ntiling = { period = [0.1, 0.1] }\nradius = 0.001\n").unwrap();
        let ex = spec.build(dir.path()).unwrap();
        assert_eq!(ex.fibers.len(), 2);
        assert_eq!(ex.tiling, Tiling::Periodic { period: glam::Vec2::new(0.1, 0.1) });
        assert!(ex.fibers.iter().all(|f| (f.radius - 0.001).abs() < 1e-9 && f.yarn == 0));
        let text = toml::to_string(&spec).unwrap();
        assert_eq!(FabricSpec::from_toml(&text).unwrap(), spec);
        let no_radius = parse("[fabric]\nfile = \"f.txt\"\n").unwrap();
        let msg = no_radius.build(dir.path()).unwrap_err().to_string();
        assert!(msg.contains("f.txt:1") && msg.contains("no radius"), "{msg}");
    }
}
