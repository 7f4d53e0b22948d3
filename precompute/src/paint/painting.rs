//! A painting: strokes of colour on the cells of a swatch, as a designer writes them.
//!
//! ```toml
//! # Colours are linear RGB in [0, 1]: a fiber yarn's C_TT, a Lambertian yarn's albedo.
//! base = [0.8, 0.8, 0.8]        # optional: every cell first (default: the scene's own colours)
//!
//! [[stroke]]                    # strokes apply in order, a later one over an earlier
//! colour = [0.05, 0.06, 0.3]
//! warp = "4-7, 12"              # warp ends, 0 = the first inside the swatch's left edge
//! weft = "2"                    # weft picks, 0 = the first inside its near edge
//! sections = "0-9"              # optional: only these sections along the threads
//!
//! [[stroke]]
//! all = true                    # every cell
//! colour = [0.7, 0.2, 0.2]
//!
//! [[stroke]]
//! random = { seed = 3, min = 0.05, max = 0.95 }   # every cell its own colour
//! ```
//!
//! [`Painting::colours`] resolves it against a swatch's [`PaintCells`]: one colour per cell.
//! Every number is checked; an error names the stroke and the value and gives the valid range.

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use super::cells::PaintCells;
use crate::Rgb;

/// A painting as written ([module docs](self)).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Painting {
    /// Every cell's colour before the strokes; `None`: the scene's own colours.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base: Option<[f64; 3]>,
    #[serde(default, rename = "stroke")]
    pub strokes: Vec<Stroke>,
}

/// One stroke: a colour on a set of cells, or random colours.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stroke {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colour: Option<[f64; 3]>,
    /// Warp ends, as `"0-3, 7"`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warp: Option<String>,
    /// Weft picks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weft: Option<String>,
    /// Sections along the threads (default: all).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sections: Option<String>,
    /// Every cell.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub all: bool,
    /// Every cell a random colour, each channel uniform in `[min, max]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub random: Option<RandomColours>,
}

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RandomColours {
    pub seed: u64,
    #[serde(default)]
    pub min: f64,
    #[serde(default = "one")]
    pub max: f64,
}

fn one() -> f64 {
    1.0
}

/// A painting that cannot be read or does not fit the swatch.
#[derive(Debug, thiserror::Error)]
pub enum PaintingError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

impl Painting {
    /// Reads a painting file (TOML).
    pub fn load(path: &Path) -> Result<Self, PaintingError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| PaintingError::Io { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    /// Parses painting text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, PaintingError> {
        toml::from_str(text)
            .map_err(|e| PaintingError::Invalid { path: path.to_path_buf(), message: e.to_string() })
    }

    /// One colour per cell of `cells`: the base (or `scene_colours`), then every stroke.
    /// `path` names the painting in errors.
    pub fn colours(
        &self,
        cells: &PaintCells,
        scene_colours: &[Rgb],
        path: &Path,
    ) -> Result<Vec<Rgb>, PaintingError> {
        let invalid = |message: String| PaintingError::Invalid { path: path.to_path_buf(), message };
        let mut out = match self.base {
            Some(base) => vec![check_colour(base).map_err(|m| invalid(format!("base: {m}")))?; cells.count()],
            None => scene_colours.to_vec(),
        };
        for (i, stroke) in self.strokes.iter().enumerate() {
            let at = |m: String| invalid(format!("[[stroke]] {}: {m}", i + 1));
            if let Some(r) = stroke.random {
                if !(0.0..=1.0).contains(&r.min) || !(0.0..=1.0).contains(&r.max) || r.min > r.max {
                    return Err(at(format!(
                        "random: min {} and max {} must lie in [0, 1] with min <= max",
                        r.min, r.max
                    )));
                }
                if stroke.colour.is_some() || stroke.warp.is_some() || stroke.weft.is_some() || stroke.all {
                    return Err(at("`random` colours every cell: give it alone".into()));
                }
                let mut rng = Pcg64Mcg::seed_from_u64(r.seed);
                for c in &mut out {
                    *c = Rgb::new(
                        rng.random_range(r.min..=r.max),
                        rng.random_range(r.min..=r.max),
                        rng.random_range(r.min..=r.max),
                    );
                }
                continue;
            }
            let colour = check_colour(stroke.colour.ok_or_else(|| at("`colour` is missing".into()))?)
                .map_err(|m| at(format!("colour: {m}")))?;
            if stroke.all {
                if stroke.warp.is_some() || stroke.weft.is_some() || stroke.sections.is_some() {
                    return Err(at("`all` paints every cell: give no `warp`, `weft` or `sections`".into()));
                }
                out.fill(colour);
                continue;
            }
            if stroke.warp.is_none() && stroke.weft.is_none() {
                return Err(at("say which cells: `warp`, `weft`, `all` or `random`".into()));
            }
            for (warp, list, set) in [(true, &stroke.warp, &cells.warp), (false, &stroke.weft, &cells.weft)] {
                let Some(list) = list else { continue };
                let name = if warp { "warp" } else { "weft" };
                if set.inside == 0 {
                    return Err(at(format!("`{name}`: this fabric has no {name} threads")));
                }
                let threads = parse_ranges(list, i64::from(set.inside))
                    .map_err(|m| at(format!("{name} = \"{list}\": {m}")))?;
                let sections = match &stroke.sections {
                    Some(s) => parse_ranges(s, i64::from(set.sections))
                        .map_err(|m| at(format!("sections = \"{s}\": {m}")))?,
                    None => (0..i64::from(set.sections)).collect(),
                };
                for t in threads {
                    for &s in &sections {
                        let cell =
                            cells.thread_cells(warp, t, s as u32..s as u32 + 1).expect("checked ranges");
                        out[cell[0] as usize] = colour;
                    }
                }
            }
        }
        Ok(out)
    }
}

fn check_colour(c: [f64; 3]) -> Result<Rgb, String> {
    if c.iter().all(|v| (0.0..=1.0).contains(v)) {
        Ok(Rgb::from(c))
    } else {
        Err(format!("{c:?}: each channel must lie in [0, 1]"))
    }
}

/// Parses `"0-3, 7"` into indices, each checked to lie in `0..count`.
fn parse_ranges(text: &str, count: i64) -> Result<Vec<i64>, String> {
    let mut out = Vec::new();
    for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let number =
            |s: &str| s.trim().parse::<i64>().map_err(|_| format!("`{}` is not a whole number", s.trim()));
        let (lo, hi) = if let Some((a, b)) = part.split_once('-') {
            (number(a)?, number(b)?)
        } else {
            let n = number(part)?;
            (n, n)
        };
        if lo > hi {
            return Err(format!("`{part}` runs backwards"));
        }
        if lo < 0 || hi >= count {
            return Err(format!("`{part}` is outside 0-{} (the swatch has {count})", count - 1));
        }
        out.extend(lo..=hi);
    }
    if out.is_empty() {
        return Err("names nothing".into());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_parse_and_refuse_what_is_outside() {
        assert_eq!(parse_ranges("0-2, 5", 6).unwrap(), vec![0, 1, 2, 5]);
        assert!(parse_ranges("3-1", 6).unwrap_err().contains("backwards"));
        assert!(parse_ranges("6", 6).unwrap_err().contains("outside 0-5"));
        assert!(parse_ranges("x", 6).unwrap_err().contains("not a whole number"));
        assert!(parse_ranges(" , ", 6).unwrap_err().contains("nothing"));
    }

    #[test]
    fn a_painting_names_its_file_and_refuses_unknown_keys() {
        let err = Painting::parse("[[stroke]]\ncolor = [1, 0, 0]\n", Path::new("p.toml")).unwrap_err();
        let text = err.to_string();
        assert!(text.starts_with("p.toml:") && text.contains("color"), "{text}");
    }
}
