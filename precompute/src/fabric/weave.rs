//! Weave drafts: which yarn lies on top at every crossing of one weave repeat.
//!
//! How it works: a [`WeaveDraft`] is a `rows x cols` binary matrix. Row `i` is weft pick `i`
//! (a yarn along +x at `y = (i + 0.5) * spacing_weft`), column `j` is warp end `j` (a yarn along
//! +y at `x = (j + 0.5) * spacing_warp`). Cell `(i, j)` is `true` when the warp passes *over* the
//! weft there (seen from +z). The draft repeats periodically in both directions.
//!
//! Every draft is validated on construction and stays valid: it is non-empty, at most
//! [`WeaveDraft::MAX_SIZE`] along each side, and every row and every column interlaces at least
//! once (contains both a `true` and a `false` cell). A row without interlacing would be a weft
//! that floats over (or under) the whole fabric, held by nothing; the crimp model in
//! [`super::exemplar`] would also leave it sitting on top of the warp without ever crossing it.
//!
//! Text form (for [`WeaveDraft::from_rows`] and [`std::fmt::Display`]): one string per row, row 0
//! first; `X` (or `x`, `#`, `1`) means warp over, `.` (or `-`, `0`) means weft over.

use std::fmt;

/// A weave draft that failed validation.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WeaveError {
    #[error("weave draft is empty: it needs at least one row and one column")]
    Empty,
    #[error("weave draft is {rows} x {cols}: at most {max} x {max} is supported", max = WeaveDraft::MAX_SIZE)]
    TooLarge { rows: usize, cols: usize },
    #[error("weave draft row {row} has {len} cells, expected {expected} like row 0")]
    RaggedRow { row: usize, len: usize, expected: usize },
    #[error("weave draft row {row}, column {col}: {ch:?} is neither `X` (warp over) nor `.` (weft over)")]
    BadCell { row: usize, col: usize, ch: char },
    #[error("weave draft row {row} (a weft pick) never interlaces: it needs both `X` and `.`")]
    RowDoesNotInterlace { row: usize },
    #[error("weave draft column {col} (a warp end) never interlaces: it needs both `X` and `.`")]
    ColumnDoesNotInterlace { col: usize },
    #[error("weave draft cell ({row}, {col}) is outside the {rows} x {cols} draft")]
    OutOfBounds { row: usize, col: usize, rows: usize, cols: usize },
}

/// The named weaves of the scene file's `weave = "..."`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum WeavePreset {
    /// Plain (tabby) weave, 2 x 2.
    #[serde(rename = "plain")]
    Plain,
    /// 2/1 twill (warp over 2, under 1; diagonal moves one end per pick), 3 x 3.
    #[serde(rename = "twill_2_1")]
    Twill2_1,
    /// 2/2 twill, 4 x 4 (gabardine and denim-like cloths).
    #[serde(rename = "twill_2_2")]
    Twill2_2,
    /// Five-harness warp-faced satin, warp over 4 under 1, move number 2, 5 x 5.
    #[serde(rename = "satin_4_1")]
    Satin4_1,
    /// Five-harness weft-faced satin (sateen): the complement of `satin_4_1`.
    #[serde(rename = "satin_1_4")]
    Satin1_4,
    /// The paper's "2/3 Satin": a five-end repeat where the warp goes over 2 and under 3 picks,
    /// the 2-float advancing by the satin move number 2 from pick to pick (so no twill diagonal
    /// forms). Our reading of the name; the paper does not print its draft.
    #[serde(rename = "satin_2_3")]
    Satin2_3,
    /// 2 x 2 basket (hopsack) weave: plain weave with doubled ends and picks, 4 x 4.
    #[serde(rename = "basket")]
    Basket,
}

impl WeavePreset {
    pub const ALL: [WeavePreset; 7] = [
        WeavePreset::Plain,
        WeavePreset::Twill2_1,
        WeavePreset::Twill2_2,
        WeavePreset::Satin4_1,
        WeavePreset::Satin1_4,
        WeavePreset::Satin2_3,
        WeavePreset::Basket,
    ];

    /// The serde / scene-file name.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            WeavePreset::Plain => "plain",
            WeavePreset::Twill2_1 => "twill_2_1",
            WeavePreset::Twill2_2 => "twill_2_2",
            WeavePreset::Satin4_1 => "satin_4_1",
            WeavePreset::Satin1_4 => "satin_1_4",
            WeavePreset::Satin2_3 => "satin_2_3",
            WeavePreset::Basket => "basket",
        }
    }

    /// The draft of this weave.
    #[must_use]
    pub fn draft(self) -> WeaveDraft {
        let rows: &[&str] = match self {
            WeavePreset::Plain => &["X.", ".X"],
            WeavePreset::Twill2_1 => &["XX.", ".XX", "X.X"],
            WeavePreset::Twill2_2 => &["XX..", ".XX.", "..XX", "X..X"],
            // Single weft-over cell per pick at column 2i mod 5.
            WeavePreset::Satin4_1 => &[".XXXX", "XX.XX", "XXXX.", "X.XXX", "XXX.X"],
            WeavePreset::Satin1_4 => &["X....", "..X..", "....X", ".X...", "...X."],
            // Two warp-over cells starting at column 2i mod 5.
            WeavePreset::Satin2_3 => &["XX...", "..XX.", "X...X", ".XX..", "...XX"],
            WeavePreset::Basket => &["XX..", "XX..", "..XX", "..XX"],
        };
        WeaveDraft::from_rows(rows).expect("preset drafts are valid")
    }
}

/// A validated binary interlacing matrix; see the module documentation.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct WeaveDraft {
    rows: usize,
    cols: usize,
    /// Row-major, `cells[i * cols + j]` = warp `j` over weft `i`.
    cells: Vec<bool>,
}

impl WeaveDraft {
    /// Largest number of rows or columns.
    pub const MAX_SIZE: usize = 64;

    /// A draft from row-major cells; validated.
    pub fn new(rows: usize, cols: usize, cells: Vec<bool>) -> Result<Self, WeaveError> {
        if rows == 0 || cols == 0 {
            return Err(WeaveError::Empty);
        }
        if rows > Self::MAX_SIZE || cols > Self::MAX_SIZE {
            return Err(WeaveError::TooLarge { rows, cols });
        }
        assert_eq!(cells.len(), rows * cols, "WeaveDraft::new: cells.len() must be rows * cols");
        let draft = Self { rows, cols, cells };
        draft.validate()?;
        Ok(draft)
    }

    /// Parses one string per row, e.g. `["X.", ".X"]` (plain weave).
    pub fn from_rows<S: AsRef<str>>(rows: &[S]) -> Result<Self, WeaveError> {
        let Some(first) = rows.first() else { return Err(WeaveError::Empty) };
        let cols = first.as_ref().chars().count();
        if cols == 0 {
            return Err(WeaveError::Empty);
        }
        if rows.len() > Self::MAX_SIZE || cols > Self::MAX_SIZE {
            return Err(WeaveError::TooLarge { rows: rows.len(), cols });
        }
        let mut cells = Vec::with_capacity(rows.len() * cols);
        for (row, text) in rows.iter().enumerate() {
            let text = text.as_ref();
            let len = text.chars().count();
            if len != cols {
                return Err(WeaveError::RaggedRow { row, len, expected: cols });
            }
            for (col, ch) in text.chars().enumerate() {
                cells.push(match ch {
                    'X' | 'x' | '#' | '1' => true,
                    '.' | '-' | '0' => false,
                    _ => return Err(WeaveError::BadCell { row, col, ch }),
                });
            }
        }
        Self::new(rows.len(), cols, cells)
    }

    fn validate(&self) -> Result<(), WeaveError> {
        for row in 0..self.rows {
            let over = (0..self.cols).filter(|&c| self.warp_over(row, c)).count();
            if over == 0 || over == self.cols {
                return Err(WeaveError::RowDoesNotInterlace { row });
            }
        }
        for col in 0..self.cols {
            let over = (0..self.rows).filter(|&r| self.warp_over(r, col)).count();
            if over == 0 || over == self.rows {
                return Err(WeaveError::ColumnDoesNotInterlace { col });
            }
        }
        Ok(())
    }

    /// Number of weft picks (rows).
    #[must_use]
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Number of warp ends (columns).
    #[must_use]
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// Whether warp `col` passes over weft `row`; indices wrap around (the draft is periodic).
    #[must_use]
    pub fn warp_over(&self, row: usize, col: usize) -> bool {
        self.cells[(row % self.rows) * self.cols + col % self.cols]
    }

    /// Flips one crossing. Refused (draft unchanged) if the cell is outside the draft or the flip
    /// would leave a row or column without interlacing.
    pub fn flip(&mut self, row: usize, col: usize) -> Result<(), WeaveError> {
        if row >= self.rows || col >= self.cols {
            return Err(WeaveError::OutOfBounds { row, col, rows: self.rows, cols: self.cols });
        }
        let k = row * self.cols + col;
        self.cells[k] = !self.cells[k];
        if let Err(e) = self.validate() {
            self.cells[k] = !self.cells[k];
            return Err(e);
        }
        Ok(())
    }

    /// The rows in text form (`X` = warp over, `.` = weft over).
    #[must_use]
    pub fn to_rows(&self) -> Vec<String> {
        (0..self.rows)
            .map(|r| (0..self.cols).map(|c| if self.warp_over(r, c) { 'X' } else { '.' }).collect())
            .collect()
    }

    /// Longest run of consecutive picks a warp end floats over, counted cyclically (the draft
    /// repeats) over all columns.
    #[must_use]
    pub fn longest_warp_float(&self) -> usize {
        (0..self.cols).map(|c| longest_cyclic_run(self.rows, |r| self.warp_over(r, c))).max().unwrap_or(0)
    }

    /// Longest run of consecutive ends a weft pick floats over, counted cyclically over all rows.
    #[must_use]
    pub fn longest_weft_float(&self) -> usize {
        (0..self.rows).map(|r| longest_cyclic_run(self.cols, |c| !self.warp_over(r, c))).max().unwrap_or(0)
    }

    /// Fraction of crossings where the warp is on top (1/2 for balanced weaves).
    #[must_use]
    pub fn warp_cover(&self) -> f64 {
        self.cells.iter().filter(|&&c| c).count() as f64 / self.cells.len() as f64
    }
}

/// Longest cyclic run of `true` in `pred(0..n)`; `n` if all are true.
fn longest_cyclic_run(n: usize, pred: impl Fn(usize) -> bool) -> usize {
    let mut best = 0;
    let mut run = 0;
    // Walking twice around the cycle finds runs that wrap; cap at n.
    for k in 0..2 * n {
        if pred(k % n) {
            run += 1;
            best = best.max(run);
        } else {
            run = 0;
        }
    }
    best.min(n)
}

impl fmt::Display for WeaveDraft {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, row) in self.to_rows().iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            f.write_str(row)?;
        }
        Ok(())
    }
}

impl std::str::FromStr for WeaveDraft {
    type Err = WeaveError;

    /// Parses the [`Display`](fmt::Display) form: rows separated by newlines or `/`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let rows: Vec<&str> = s.split(['\n', '/']).map(str::trim).filter(|r| !r.is_empty()).collect();
        Self::from_rows(&rows)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_with_expected_floats_and_cover() {
        let expect = [
            (WeavePreset::Plain, 2, 2, 1, 1, 0.5),
            (WeavePreset::Twill2_1, 3, 3, 2, 1, 2.0 / 3.0),
            (WeavePreset::Twill2_2, 4, 4, 2, 2, 0.5),
            (WeavePreset::Satin4_1, 5, 5, 4, 1, 0.8),
            (WeavePreset::Satin1_4, 5, 5, 1, 4, 0.2),
            (WeavePreset::Satin2_3, 5, 5, 1, 3, 0.4),
            (WeavePreset::Basket, 4, 4, 2, 2, 0.5),
        ];
        for (preset, rows, cols, warp_float, weft_float, cover) in expect {
            let d = preset.draft();
            assert_eq!((d.rows(), d.cols()), (rows, cols), "{preset:?}");
            assert_eq!(d.longest_warp_float(), warp_float, "{preset:?}\n{d}");
            assert_eq!(d.longest_weft_float(), weft_float, "{preset:?}\n{d}");
            assert!((d.warp_cover() - cover).abs() < 1e-12, "{preset:?}");
        }
    }

    #[test]
    fn satins_have_no_adjacent_interlacings_on_consecutive_picks() {
        // A satin's single interlacing per pick moves by 2 (not 1, which would be a twill).
        let d = WeavePreset::Satin4_1.draft();
        let under: Vec<usize> = (0..5).map(|r| (0..5).find(|&c| !d.warp_over(r, c)).unwrap()).collect();
        for r in 0..5 {
            let step = (under[(r + 1) % 5] + 5 - under[r]) % 5;
            assert_eq!(step, 2);
        }
        let inv = WeavePreset::Satin1_4.draft();
        for r in 0..5 {
            for c in 0..5 {
                assert_ne!(d.warp_over(r, c), inv.warp_over(r, c));
            }
        }
    }

    #[test]
    fn parse_display_round_trip_and_serde_names() {
        #[derive(serde::Deserialize)]
        struct W {
            w: WeavePreset,
        }
        for p in WeavePreset::ALL {
            let d = p.draft();
            let text = d.to_string();
            assert_eq!(text.parse::<WeaveDraft>().unwrap(), d);
            let toml_text = format!("w = \"{}\"", p.name());
            assert_eq!(toml::from_str::<W>(&toml_text).unwrap().w, p);
        }
        assert_eq!(WeaveDraft::from_rows(&["x-", "01"]).unwrap(), WeavePreset::Plain.draft());
    }

    #[test]
    fn rejects_invalid_drafts_with_specific_errors() {
        assert_eq!(WeaveDraft::from_rows::<&str>(&[]), Err(WeaveError::Empty));
        assert_eq!(WeaveDraft::from_rows(&[""]), Err(WeaveError::Empty));
        assert_eq!(
            WeaveDraft::from_rows(&["X.", ".X."]),
            Err(WeaveError::RaggedRow { row: 1, len: 3, expected: 2 })
        );
        assert_eq!(
            WeaveDraft::from_rows(&["X?", ".X"]),
            Err(WeaveError::BadCell { row: 0, col: 1, ch: '?' })
        );
        assert_eq!(WeaveDraft::from_rows(&["XX", ".X"]), Err(WeaveError::RowDoesNotInterlace { row: 0 }));
        assert_eq!(WeaveDraft::from_rows(&["X.", "X."]), Err(WeaveError::ColumnDoesNotInterlace { col: 0 }));
        let big = vec!["X.".repeat(33); 2];
        assert!(matches!(WeaveDraft::from_rows(&big), Err(WeaveError::TooLarge { .. })));
        let msg = WeaveDraft::from_rows(&["X?", ".X"]).unwrap_err().to_string();
        assert!(msg.contains("row 0, column 1") && msg.contains("'?'"), "{msg}");
    }

    #[test]
    fn flip_keeps_the_draft_valid() {
        let mut d = WeavePreset::Twill2_2.draft();
        d.flip(0, 0).unwrap();
        assert!(!d.warp_over(0, 0));
        assert_eq!(d.to_rows()[0], ".X..");
        let before = WeavePreset::Plain.draft();
        let mut p = before.clone();
        assert_eq!(p.flip(0, 1), Err(WeaveError::RowDoesNotInterlace { row: 0 }));
        assert_eq!(p, before, "a refused flip leaves the draft unchanged");
        assert!(matches!(p.flip(2, 0), Err(WeaveError::OutOfBounds { .. })));
        // Periodic indexing.
        assert_eq!(before.warp_over(2, 3), before.warp_over(0, 1));
    }
}
