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
//!
//! [[stroke]]
//! cells = "8000-8003"           # cells by number (what the viewer writes for the cells a
//! colour = [0.9, 0.9, 0.1]      # thread list cannot name: the copies beyond the edges)
//! ```
//!
//! [`Painting::colours`] resolves it against a swatch's [`PaintCells`]: one colour per cell.
//! [`Painting::from_colours`] writes one colour per cell back as strokes (the viewer's "Save
//! painting"): whole threads as thread lists, parts of threads with their sections, the rest
//! by cell number.
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
    /// Cells by number, as `"0-3, 7"` (0 to the swatch's cell count − 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cells: Option<String>,
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
                if stroke.colour.is_some()
                    || stroke.warp.is_some()
                    || stroke.weft.is_some()
                    || stroke.all
                    || stroke.cells.is_some()
                {
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
                if stroke.warp.is_some()
                    || stroke.weft.is_some()
                    || stroke.sections.is_some()
                    || stroke.cells.is_some()
                {
                    return Err(at(
                        "`all` paints every cell: give no `warp`, `weft`, `sections` or `cells`".into()
                    ));
                }
                out.fill(colour);
                continue;
            }
            if let Some(list) = &stroke.cells {
                if stroke.warp.is_some() || stroke.weft.is_some() || stroke.sections.is_some() {
                    return Err(at(
                        "`cells` names cells by number: give no `warp`, `weft` or `sections`".into()
                    ));
                }
                let numbers = parse_ranges(list, cells.count() as i64)
                    .map_err(|m| at(format!("cells = \"{list}\": {m}")))?;
                for c in numbers {
                    out[c as usize] = colour;
                }
                continue;
            }
            if stroke.warp.is_none() && stroke.weft.is_none() {
                return Err(at("say which cells: `warp`, `weft`, `cells`, `all` or `random`".into()));
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

impl Painting {
    /// The painting that gives `colours` (one per cell of `cells`) over `scene_colours`: per
    /// colour that differs from the scene's somewhere, the threads inside the swatch painted
    /// in it along their whole length as thread lists, parts of such threads with their
    /// sections, and every other cell by number. [`Painting::colours`] of it gives `colours`
    /// back exactly.
    #[must_use]
    pub fn from_colours(cells: &PaintCells, colours: &[Rgb], scene_colours: &[Rgb]) -> Self {
        let key = |c: Rgb| [c.x.to_bits(), c.y.to_bits(), c.z.to_bits()];
        // The painted cells by colour, in order of first appearance (a deterministic file).
        let mut by_colour: Vec<([u64; 3], Vec<u32>)> = Vec::new();
        for (cell, (&c, &scene)) in colours.iter().zip(scene_colours).enumerate() {
            if key(c) == key(scene) {
                continue;
            }
            match by_colour.iter_mut().find(|(k, _)| *k == key(c)) {
                Some((_, list)) => list.push(cell as u32),
                None => by_colour.push((key(c), vec![cell as u32])),
            }
        }
        let mut strokes = Vec::new();
        for (k, painted) in by_colour {
            let colour = Some(k.map(f64::from_bits));
            let mut loose = Vec::new();
            // Per thread set and thread (inside the swatch): its painted sections.
            let mut threads: std::collections::BTreeMap<(bool, i64), Vec<i64>> =
                std::collections::BTreeMap::new();
            for &cell in &painted {
                match cells.thread_of(cell) {
                    Some((warp, thread, section)) => {
                        let set = if warp { &cells.warp } else { &cells.weft };
                        if (0..i64::from(set.inside)).contains(&thread) {
                            threads.entry((warp, thread)).or_default().push(i64::from(section));
                        } else {
                            loose.push(i64::from(cell));
                        }
                    }
                    None => loose.push(i64::from(cell)),
                }
            }
            let mut whole: [Vec<i64>; 2] = [Vec::new(), Vec::new()];
            for ((warp, thread), sections) in &threads {
                let set = if *warp { &cells.warp } else { &cells.weft };
                if sections.len() == set.sections as usize {
                    whole[usize::from(*warp)].push(*thread);
                } else {
                    let name = Some(thread.to_string());
                    strokes.push(Stroke {
                        colour,
                        warp: if *warp { name.clone() } else { None },
                        weft: if *warp { None } else { name },
                        sections: Some(write_ranges(sections)),
                        ..Stroke::default()
                    });
                }
            }
            let [weft, warp] = whole;
            if !warp.is_empty() || !weft.is_empty() {
                let list = |v: &[i64]| (!v.is_empty()).then(|| write_ranges(v));
                strokes.push(Stroke { colour, warp: list(&warp), weft: list(&weft), ..Stroke::default() });
            }
            if !loose.is_empty() {
                strokes.push(Stroke { colour, cells: Some(write_ranges(&loose)), ..Stroke::default() });
            }
        }
        Self { base: None, strokes }
    }
}

/// `[0, 1, 2, 5]` as `"0-2, 5"` (sorted, no repeats).
fn write_ranges(values: &[i64]) -> String {
    let mut sorted = values.to_vec();
    sorted.sort_unstable();
    sorted.dedup();
    let mut parts = Vec::new();
    let mut i = 0;
    while i < sorted.len() {
        let mut j = i;
        while j + 1 < sorted.len() && sorted[j + 1] == sorted[j] + 1 {
            j += 1;
        }
        parts.push(if i == j { sorted[i].to_string() } else { format!("{}-{}", sorted[i], sorted[j]) });
        i = j + 1;
    }
    parts.join(", ")
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
    fn ranges_are_written_as_they_are_read() {
        assert_eq!(write_ranges(&[5, 0, 1, 2, 2, 9, 10]), "0-2, 5, 9-10");
        assert_eq!(parse_ranges(&write_ranges(&[7, 3, 4, 0]), 8).unwrap(), vec![0, 3, 4, 7]);
    }

    #[test]
    fn a_painting_names_its_file_and_refuses_unknown_keys() {
        let err = Painting::parse("[[stroke]]\ncolor = [1, 0, 0]\n", Path::new("p.toml")).unwrap_err();
        let text = err.to_string();
        assert!(text.starts_with("p.toml:") && text.contains("color"), "{text}");
    }
}
