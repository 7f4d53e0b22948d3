//! WIF import: a weave draft from a Weaving Information File, the INI-like format weaving
//! software exchanges drafts in.
//!
//! How it works: the text is split into sections (`[NAME]`, case-insensitive) of `key=value`
//! lines (keys case-insensitive, `;` starts a comment, blank lines ignored). When a
//! `[CONTENTS]` section is present, a section counts only if `[CONTENTS]` lists it as true;
//! without one, every section found counts. Sections this module does not read (`[NOTES]`,
//! colours, ...) are skipped unparsed; in the ones it reads, every line must be `key=value`.
//!
//! - `[WEAVING]`: `Shafts=` (required), `Treadles=` (required with a tie-up),
//!   `Rising Shed=` (default true; false means a sinking shed).
//! - `[WARP]` / `[WEFT]`: `Threads=`, the number of ends / picks (default: the largest end /
//!   pick listed).
//! - `[THREADING]`: `end=shaft[,shaft...]` (required).
//! - `[LIFTPLAN]`: `pick=shaft,shaft,...`, the shafts lifted on each pick; or else
//!   `[TIEUP]`: `treadle=shaft,shaft,...` with `[TREADLING]`: `pick=treadle[,treadle...]`, the
//!   shafts lifted on a pick being those tied to any of its treadles.
//!
//! Colours ([`parse_wif_colours`], read separately so that a colour section a draft import does
//! not need can never break it): `[COLOR TABLE]` `k=r,g,b` scaled by `[COLOR PALETTE]`
//! `Range=lo,hi` (default 0,255) to 0..1; `[WARP COLORS]` / `[WEFT COLORS]` `thread=k`, threads
//! not listed taking `[WARP]` / `[WEFT]` `Color=k`. Each direction's sequence is cut to its
//! shortest period (files list every thread of several colour repeats).
//!
//! Ends and picks not listed are unthreaded and unlifted. Warp end `e` passes over pick `p`
//! when one of its shafts is lifted on that pick (with a rising shed; a sinking shed inverts
//! this, its tie-up naming the shafts that sink). End `e` becomes draft column `e - 1` (the
//! warp yarn at `x = (e - 0.5) * spacing`) and pick `p` row `p - 1`, seen from the side that
//! faces up on the loom; see [`super::weave`] for the draft's layout.
//!
//! A draft wider or longer than [`WeaveDraft::MAX_SIZE`] is cut to its smallest repeat when the
//! threading and the lifts repeat exactly (files often hold several repeats); if that repeat is
//! still too large, the import fails. Every error names the file, and where it comes from a
//! line, the 1-based line, the section, the key and the value.

use std::path::{Path, PathBuf};

use super::weave::{WeaveDraft, WeaveError};

/// Most shafts or treadles a file may declare.
pub const MAX_SHAFTS: usize = 1024;
/// Most ends or picks a file may declare.
pub const MAX_THREADS: usize = 100_000;

/// Why a WIF file could not be turned into a draft.
#[derive(Debug, thiserror::Error)]
pub enum WifError {
    #[error("{}: {source}", file.display())]
    Read { file: PathBuf, source: std::io::Error },
    #[error("{}:{line}: expected `key=value` in [{section}], found {text:?}", file.display())]
    Syntax { file: PathBuf, line: usize, section: String, text: String },
    #[error("{}:{line}: {text:?}: a section header must end with `]`", file.display())]
    BadHeader { file: PathBuf, line: usize, text: String },
    #[error("{}: no [{section}] section{note}: the draft needs its {what}", file.display())]
    MissingSection { file: PathBuf, section: &'static str, what: &'static str, note: String },
    #[error("{}: the draft needs a [LIFTPLAN], or a [TREADLING] and a [TIEUP]{note}", file.display())]
    NoLifts { file: PathBuf, note: String },
    #[error("{}:{line}: [{section}] has no `{key}=`: it is needed to {why}", file.display())]
    MissingKey { file: PathBuf, line: usize, section: String, key: &'static str, why: &'static str },
    #[error("{at}: {item:?} is not {expected}")]
    NotANumber { at: Box<WifLine>, item: String, expected: &'static str },
    #[error("{at}: {what} {number} is out of range: expected 1..={max} ({limit})")]
    OutOfRange { at: Box<WifLine>, what: &'static str, number: u64, max: usize, limit: String },
    #[error("{at}: expected true or false (yes/no, on/off, 1/0)")]
    NotABool { at: Box<WifLine> },
    #[error("{}:{line}: [{section}] {key} is given twice (first on line {first})", file.display())]
    Duplicate { file: PathBuf, line: usize, section: String, key: String, first: usize },
    #[error(
        "{}: the draft is {rows} picks x {cols} ends{repeat}: at most {max} x {max} is supported; \
         keep one repeat of the pattern in the file",
        file.display(),
        max = WeaveDraft::MAX_SIZE
    )]
    TooLarge { file: PathBuf, rows: usize, cols: usize, repeat: String },
    #[error("{}: {source} (draft rows are picks and columns ends, both counted from 0)", file.display())]
    Weave { file: PathBuf, source: WeaveError },
    #[error("{at}: colour {colour} is not in [COLOR TABLE]")]
    UnknownColour { at: Box<WifLine>, colour: u32 },
    #[error(
        "{}: {what} {thread} has no colour: [{listing}] does not list it and [{default}] has no `Color=`",
        file.display()
    )]
    NoColour {
        file: PathBuf,
        what: &'static str,
        thread: usize,
        listing: &'static str,
        default: &'static str,
    },
    #[error("{at}: expected {expected}")]
    BadColourValue { at: Box<WifLine>, expected: String },
    #[error("{}: the {what} colour sequence repeats every {period} threads: at most {max} are supported", file.display())]
    ColourRepeat { file: PathBuf, what: &'static str, period: usize, max: usize },
}

/// The line a [`WifError`] is about: the file, the 1-based line number, the section and the
/// line's key and value.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WifLine {
    pub file: PathBuf,
    pub line: usize,
    pub section: String,
    pub key: String,
    pub value: String,
}

impl std::fmt::Display for WifLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}: [{}] {}={}", self.file.display(), self.line, self.section, self.key, self.value)
    }
}

/// One `key=value` line.
#[derive(Debug)]
struct Entry {
    line: usize,
    key: String,
    value: String,
}

/// One section: its name as written, the line of its (first) header and its entries.
#[derive(Debug)]
struct Section {
    name: String,
    line: usize,
    entries: Vec<Entry>,
}

/// The sections this module reads (upper case, as the WIF specification spells them).
const READ_SECTIONS: [&str; 8] =
    ["CONTENTS", "WEAVING", "WARP", "WEFT", "THREADING", "TIEUP", "TREADLING", "LIFTPLAN"];

/// The sections the colour import reads.
const COLOUR_SECTIONS: [&str; 7] =
    ["CONTENTS", "WARP", "WEFT", "COLOR PALETTE", "COLOR TABLE", "WARP COLORS", "WEFT COLORS"];

/// Most entries a `[COLOR TABLE]` may have.
pub const MAX_TABLE_COLOURS: usize = 4096;

/// The parsed file: the sections this module reads, with `[CONTENTS]` applied.
struct WifFile {
    sections: Vec<Section>,
    /// `[CONTENTS]` as (upper-case section name, listed as true).
    contents: Option<Vec<(String, bool)>>,
}

impl WifFile {
    /// The section called `name` (upper case) if it is in the file and, with a `[CONTENTS]`,
    /// listed there as true.
    fn section(&self, name: &str) -> Option<&Section> {
        let listed = self.contents.as_ref().is_none_or(|c| c.iter().any(|(n, on)| n == name && *on));
        self.sections.iter().find(|s| s.name.eq_ignore_ascii_case(name)).filter(|_| listed)
    }

    /// Why `name` counts as absent, for messages: empty, or a note that `[CONTENTS]` leaves
    /// out a section that is in the file.
    fn absence_note(&self, name: &str) -> String {
        if self.sections.iter().any(|s| s.name.eq_ignore_ascii_case(name)) {
            format!(" ([{name}] is in the file, but [CONTENTS] does not list it as true)")
        } else {
            String::new()
        }
    }
}

impl Section {
    fn get(&self, key: &str) -> Option<&Entry> {
        self.entries.iter().find(|e| e.key.eq_ignore_ascii_case(key))
    }
}

/// Reads and imports a WIF file.
pub fn read_wif(path: &Path) -> Result<WeaveDraft, WifError> {
    let bytes = std::fs::read(path).map_err(|source| WifError::Read { file: path.to_owned(), source })?;
    // Notes and names in older files are often Latin-1; the parts read here are ASCII.
    parse_wif(&String::from_utf8_lossy(&bytes), path)
}

/// Imports WIF text; `file` names it in errors.
pub fn parse_wif(text: &str, file: &Path) -> Result<WeaveDraft, WifError> {
    let wif = split_sections(text, file, &READ_SECTIONS)?;

    // [WEAVING]
    let weaving = wif.section("WEAVING").ok_or_else(|| WifError::MissingSection {
        file: file.to_owned(),
        section: "WEAVING",
        what: "number of shafts (`Shafts=`)",
        note: wif.absence_note("WEAVING"),
    })?;
    let shafts_entry = weaving.get("Shafts").ok_or_else(|| WifError::MissingKey {
        file: file.to_owned(),
        line: weaving.line,
        section: weaving.name.clone(),
        key: "Shafts",
        why: "check the shaft numbers",
    })?;
    let shafts = Place::new(file, weaving, shafts_entry).count("the number of shafts", MAX_SHAFTS)?;
    let treadles = weaving
        .get("Treadles")
        .map(|e| Place::new(file, weaving, e).count("the number of treadles", MAX_SHAFTS))
        .transpose()?;
    let rising = weaving
        .get("Rising Shed")
        .map(|e| Place::new(file, weaving, e).boolean())
        .transpose()?
        .unwrap_or(true);

    // [WARP] and [WEFT] Threads=
    let threads = |name: &str, what| -> Result<Option<(usize, String)>, WifError> {
        let Some(section) = wif.section(name) else { return Ok(None) };
        let Some(e) = section.get("Threads") else { return Ok(None) };
        let n = Place::new(file, section, e).count(what, MAX_THREADS)?;
        Ok(Some((n, format!("[{}] Threads={n}", section.name))))
    };
    let ends_declared = threads("WARP", "the number of warp ends")?;
    let picks_declared = threads("WEFT", "the number of weft picks")?;
    let thread_limit = |declared: &Option<(usize, String)>| {
        declared.clone().unwrap_or_else(|| (MAX_THREADS, "the most a file may have".to_owned()))
    };
    let shaft_limit = (shafts, format!("Shafts={shafts} in [{}]", weaving.name));

    // [THREADING]
    let threading = wif.section("THREADING").ok_or_else(|| WifError::MissingSection {
        file: file.to_owned(),
        section: "THREADING",
        what: "threading (which shafts each warp end is threaded on)",
        note: wif.absence_note("THREADING"),
    })?;
    let ends = read_lists(file, threading, ("end", &thread_limit(&ends_declared)), ("shaft", &shaft_limit))?;

    // The shafts lifted on each pick: [LIFTPLAN], else [TREADLING] through [TIEUP].
    let pick_limit = thread_limit(&picks_declared);
    let picks = if let Some(liftplan) = wif.section("LIFTPLAN") {
        read_lists(file, liftplan, ("pick", &pick_limit), ("shaft", &shaft_limit))?
    } else {
        let (Some(tieup), Some(treadling)) = (wif.section("TIEUP"), wif.section("TREADLING")) else {
            let note = ["LIFTPLAN", "TIEUP", "TREADLING"].iter().map(|s| wif.absence_note(s)).collect();
            return Err(WifError::NoLifts { file: file.to_owned(), note });
        };
        let treadles = treadles.ok_or_else(|| WifError::MissingKey {
            file: file.to_owned(),
            line: weaving.line,
            section: weaving.name.clone(),
            key: "Treadles",
            why: "read the tie-up and treadling",
        })?;
        let treadle_limit = (treadles, format!("Treadles={treadles} in [{}]", weaving.name));
        let tied = read_lists(file, tieup, ("treadle", &treadle_limit), ("shaft", &shaft_limit))?;
        let treadled = read_lists(file, treadling, ("pick", &pick_limit), ("treadle", &treadle_limit))?;
        treadled
            .into_iter()
            .map(|(pick, treadles)| {
                let mut lifted: Vec<u32> = treadles
                    .iter()
                    .flat_map(|t| tied.iter().filter(move |(k, _)| k == t).flat_map(|(_, s)| s.clone()))
                    .collect();
                lifted.sort_unstable();
                lifted.dedup();
                (pick, lifted)
            })
            .collect()
    };

    // Every end / pick up to the declared (or largest listed) number, in order.
    let dense = |lists: Vec<(u32, Vec<u32>)>, declared: Option<(usize, String)>| {
        let n = declared.map_or_else(|| lists.iter().map(|&(k, _)| k as usize).max().unwrap_or(0), |d| d.0);
        let mut out = vec![Vec::new(); n];
        for (k, list) in lists {
            out[k as usize - 1] = list;
        }
        out
    };
    let mut ends = dense(ends, ends_declared);
    let mut picks = dense(picks, picks_declared);
    let max = WeaveDraft::MAX_SIZE;
    if ends.len() > max || picks.len() > max {
        let (rows, cols) = (picks.len(), ends.len());
        let (repeat_rows, repeat_cols) = (smallest_repeat(&picks), smallest_repeat(&ends));
        if repeat_rows > max || repeat_cols > max {
            let repeat = if (repeat_rows, repeat_cols) == (rows, cols) {
                " and does not repeat".to_owned()
            } else {
                format!(" (its smallest repeat is {repeat_rows} x {repeat_cols})")
            };
            return Err(WifError::TooLarge { file: file.to_owned(), rows, cols, repeat });
        }
        picks.truncate(repeat_rows);
        ends.truncate(repeat_cols);
    }
    let (rows, cols) = (picks.len(), ends.len());
    let mut cells = Vec::with_capacity(rows * cols);
    for lifted in &picks {
        for threaded in &ends {
            let up = threaded.iter().any(|s| lifted.binary_search(s).is_ok());
            cells.push(up == rising);
        }
    }
    let weave = |source| WifError::Weave { file: file.to_owned(), source };
    if rows == 0 || cols == 0 {
        return Err(weave(WeaveError::Empty));
    }
    WeaveDraft::new(rows, cols, cells).map_err(weave)
}

/// A WIF file's colours: its colour table and the colour of every end and pick.
#[derive(Debug, Clone, PartialEq)]
pub struct WifColours {
    /// `[COLOR TABLE]` entry `k + 1` as display RGB in 0..=1 (`None` where the table skips `k + 1`).
    pub table: Vec<Option<[f64; 3]>>,
    /// The table index (0-based) of each warp end's colour over the warp's colour repeat; empty
    /// when the file gives the warp no colour at all.
    pub warp: Vec<u32>,
    /// The same for the weft's picks.
    pub weft: Vec<u32>,
}

/// Reads a WIF file's colours (`None`: it has no `[COLOR TABLE]`).
pub fn read_wif_colours(path: &Path) -> Result<Option<WifColours>, WifError> {
    let bytes = std::fs::read(path).map_err(|source| WifError::Read { file: path.to_owned(), source })?;
    parse_wif_colours(&String::from_utf8_lossy(&bytes), path)
}

/// The colours of WIF text (`None`: no `[COLOR TABLE]`); `file` names it in errors. Every
/// thread up to `[WARP]` / `[WEFT]` `Threads=` (or the last one listed) needs a colour, its own
/// or the default `Color=`; a sequence longer than [`WeaveDraft::MAX_SIZE`] must repeat within
/// it.
pub fn parse_wif_colours(text: &str, file: &Path) -> Result<Option<WifColours>, WifError> {
    let wif = split_sections(text, file, &COLOUR_SECTIONS)?;
    let Some(table_section) = wif.section("COLOR TABLE") else { return Ok(None) };
    let range = match wif.section("COLOR PALETTE").and_then(|s| s.get("Range").map(|e| (s, e))) {
        None => (0.0, 255.0),
        Some((section, entry)) => {
            let place = Place::new(file, section, entry);
            let bad = || WifError::BadColourValue {
                at: Box::new(place.at()),
                expected: "`lo,hi`, two numbers with lo < hi (e.g. 0,255)".into(),
            };
            let numbers = place.numbers().ok_or_else(bad)?;
            match numbers[..] {
                [lo, hi] if lo.is_finite() && hi.is_finite() && lo < hi => (lo, hi),
                _ => return Err(bad()),
            }
        }
    };
    let table_limit = (MAX_TABLE_COLOURS, "colours a table may hold".to_owned());
    let mut table: Vec<Option<[f64; 3]>> = Vec::new();
    for entry in &table_section.entries {
        let place = Place::new(file, table_section, entry);
        let k = place.number(&entry.key, "colour", &table_limit)? as usize;
        let bad = || WifError::BadColourValue {
            at: Box::new(place.at()),
            expected: format!("`r,g,b`, three numbers in {}..={} ([COLOR PALETTE] Range)", range.0, range.1),
        };
        let values = place.numbers().ok_or_else(bad)?;
        let [r, g, b] = values[..] else { return Err(bad()) };
        let rgb = [r, g, b];
        if !rgb.iter().all(|v| (range.0..=range.1).contains(v)) {
            return Err(bad());
        }
        if table.len() < k {
            table.resize(k, None);
        }
        table[k - 1] = Some(rgb.map(|v| (v - range.0) / (range.1 - range.0)));
    }
    let colour_number = |place: &Place, item: &str| -> Result<u32, WifError> {
        let k = place.number(item, "colour", &table_limit)?;
        if table.get(k as usize - 1).copied().flatten().is_none() {
            return Err(WifError::UnknownColour { at: Box::new(place.at()), colour: k });
        }
        Ok(k - 1)
    };
    let sequence = |direction: &'static str, listing: &'static str, what: &'static str| {
        let section = wif.section(direction);
        let default = section
            .and_then(|s| s.get("Color").map(|e| (s, e)))
            .map(|(s, e)| colour_number(&Place::new(file, s, e), e.value.split(',').next().unwrap_or("")))
            .transpose()?;
        let declared = section
            .and_then(|s| s.get("Threads").map(|e| (s, e)))
            .map(|(s, e)| Place::new(file, s, e).count("the number of threads", MAX_THREADS))
            .transpose()?;
        let thread_limit = (MAX_THREADS, "threads a file may have".to_owned());
        let mut listed: Vec<(usize, u32)> = Vec::new();
        if let Some(s) = wif.section(listing) {
            for entry in &s.entries {
                let place = Place::new(file, s, entry);
                let thread = place.number(&entry.key, "thread", &thread_limit)? as usize;
                listed.push((thread, colour_number(&place, &entry.value)?));
            }
        }
        let n = declared.unwrap_or_else(|| listed.iter().map(|&(t, _)| t).max().unwrap_or(0));
        if n == 0 || (listed.is_empty() && default.is_none()) {
            return Ok(Vec::new());
        }
        let mut colours = vec![default; n];
        for (thread, colour) in listed {
            if thread <= n {
                colours[thread - 1] = Some(colour);
            }
        }
        let colours = colours
            .into_iter()
            .enumerate()
            .map(|(i, c)| {
                c.ok_or(WifError::NoColour {
                    file: file.to_owned(),
                    what,
                    thread: i + 1,
                    listing,
                    default: direction,
                })
            })
            .collect::<Result<Vec<u32>, _>>()?;
        let period = smallest_repeat(&colours);
        if period > WeaveDraft::MAX_SIZE {
            return Err(WifError::ColourRepeat {
                file: file.to_owned(),
                what,
                period,
                max: WeaveDraft::MAX_SIZE,
            });
        }
        Ok(colours[..period].to_vec())
    };
    let warp = sequence("WARP", "WARP COLORS", "warp end")?;
    let weft = sequence("WEFT", "WEFT COLORS", "weft pick")?;
    Ok(Some(WifColours { table, warp, weft }))
}

/// The length of the shortest prefix whose repetition is `items` (`items.len()` if none).
fn smallest_repeat<T: PartialEq>(items: &[T]) -> usize {
    let n = items.len();
    (1..=n).find(|&p| n.is_multiple_of(p) && (p..n).all(|k| items[k] == items[k - p])).unwrap_or(n)
}

/// Splits the text into the sections this module reads, and reads `[CONTENTS]`.
fn split_sections(text: &str, file: &Path, read: &[&str]) -> Result<WifFile, WifError> {
    let mut sections: Vec<Section> = Vec::new();
    // Index into `sections` of the current section, if it is one this module reads.
    let mut current: Option<usize> = None;
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let raw = if index == 0 { raw.trim_start_matches('\u{feff}') } else { raw };
        let content = raw.split(';').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        if let Some(rest) = content.strip_prefix('[') {
            let Some(name) = rest.strip_suffix(']') else {
                return Err(WifError::BadHeader { file: file.to_owned(), line, text: content.to_owned() });
            };
            let name = name.trim();
            current = read.iter().any(|s| s.eq_ignore_ascii_case(name)).then(|| {
                sections.iter().position(|s| s.name.eq_ignore_ascii_case(name)).unwrap_or_else(|| {
                    sections.push(Section { name: name.to_owned(), line, entries: Vec::new() });
                    sections.len() - 1
                })
            });
            continue;
        }
        let Some(section) = current.map(|i| &mut sections[i]) else { continue };
        let Some((key, value)) = content.split_once('=') else {
            return Err(WifError::Syntax {
                file: file.to_owned(),
                line,
                section: section.name.clone(),
                text: content.to_owned(),
            });
        };
        let (key, value) = (key.trim(), value.trim());
        if let Some(first) = section.get(key) {
            return Err(WifError::Duplicate {
                file: file.to_owned(),
                line,
                section: section.name.clone(),
                key: key.to_owned(),
                first: first.line,
            });
        }
        section.entries.push(Entry { line, key: key.to_owned(), value: value.to_owned() });
    }
    let contents = sections
        .iter()
        .find(|s| s.name.eq_ignore_ascii_case("CONTENTS"))
        .map(|section| {
            section
                .entries
                .iter()
                .map(|e| {
                    let on = Place::new(file, section, e).boolean()?;
                    Ok((e.key.to_ascii_uppercase(), on))
                })
                .collect::<Result<Vec<_>, WifError>>()
        })
        .transpose()?;
    Ok(WifFile { sections, contents })
}

/// A `key=value` line being read, for error messages.
struct Place<'a> {
    file: &'a Path,
    line: usize,
    section: &'a str,
    entry: &'a Entry,
}

impl<'a> Place<'a> {
    fn new(file: &'a Path, section: &'a Section, entry: &'a Entry) -> Self {
        Self { file, line: entry.line, section: &section.name, entry }
    }

    fn at(&self) -> WifLine {
        WifLine {
            file: self.file.to_owned(),
            line: self.line,
            section: self.section.to_owned(),
            key: self.entry.key.clone(),
            value: self.entry.value.clone(),
        }
    }

    /// A whole number `1..=max` (`item` is the text, `what` names it).
    fn number(
        &self,
        item: &str,
        what: &'static str,
        (max, limit): &(usize, String),
    ) -> Result<u32, WifError> {
        let n: u64 = item.trim().parse().map_err(|_| WifError::NotANumber {
            at: Box::new(self.at()),
            item: item.to_owned(),
            expected: "a whole number",
        })?;
        if n == 0 || n > *max as u64 {
            return Err(WifError::OutOfRange {
                at: Box::new(self.at()),
                what,
                number: n,
                max: *max,
                limit: limit.clone(),
            });
        }
        Ok(n as u32)
    }

    /// The value as comma-separated numbers (`None` if any is not one).
    fn numbers(&self) -> Option<Vec<f64>> {
        self.entry.value.split(',').map(|v| v.trim().parse::<f64>().ok()).collect()
    }

    /// The value as a count `1..=max`.
    fn count(&self, what: &'static str, max: usize) -> Result<usize, WifError> {
        let limit = (max, format!("{what} a file may declare"));
        self.number(&self.entry.value, what, &limit).map(|n| n as usize)
    }

    fn boolean(&self) -> Result<bool, WifError> {
        match self.entry.value.to_ascii_lowercase().as_str() {
            "true" | "yes" | "on" | "1" => Ok(true),
            "false" | "no" | "off" | "0" => Ok(false),
            _ => Err(WifError::NotABool { at: Box::new(self.at()) }),
        }
    }
}

/// Reads a section of `key=n[,n...]` lines: keys are `key_what` numbers within `key_limit`,
/// values lists of `item_what` numbers within `item_limit` (sorted, duplicates removed; an
/// empty value is an empty list).
fn read_lists(
    file: &Path,
    section: &Section,
    (key_what, key_limit): (&'static str, &(usize, String)),
    (item_what, item_limit): (&'static str, &(usize, String)),
) -> Result<Vec<(u32, Vec<u32>)>, WifError> {
    section
        .entries
        .iter()
        .map(|entry| {
            let place = Place::new(file, section, entry);
            let key = place.number(&entry.key, key_what, key_limit)?;
            let mut items = entry
                .value
                .split(',')
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .map(|s| place.number(s, item_what, item_limit))
                .collect::<Result<Vec<_>, _>>()?;
            items.sort_unstable();
            items.dedup();
            Ok((key, items))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use std::fmt::Write;

    use super::*;
    use crate::fabric::weave::WeavePreset;

    const HEAD: &str =
        "[WIF]\nVersion=1.1\nSource Program=test\n[CONTENTS]\nWEAVING=true\nWARP=true\nWEFT=true\n";

    /// A 2/2 twill: straight draw on 4 shafts, tie-up 1-2, 2-3, 3-4, 4-1, treadled 1 to 4.
    fn twill_wif(rising: &str) -> String {
        format!(
            "{HEAD}THREADING=true\nTIEUP=true\nTREADLING=true\n\
             [WEAVING]\nShafts=4\nTreadles=4\nRising Shed={rising}\n\
             [WARP]\nThreads=4\n[WEFT]\nThreads=4\n\
             [THREADING]\n1=1\n2=2\n3=3\n4=4\n\
             [TIEUP]\n1=1,2\n2=2,3\n3=3,4\n4=4,1\n\
             [TREADLING]\n1=1\n2=2\n3=3\n4=4\n"
        )
    }

    fn parse(text: &str) -> Result<WeaveDraft, WifError> {
        parse_wif(text, Path::new("t.wif"))
    }

    fn err(text: &str) -> String {
        parse(text).unwrap_err().to_string()
    }

    #[test]
    fn a_treadled_2_2_twill_is_the_preset() {
        let d = parse(&twill_wif("true")).unwrap();
        assert_eq!(d, WeavePreset::Twill2_2.draft(), "\n{d}");
        // Pick 2 (row 1) lifts shafts 2 and 3: ends 2 and 3 (columns 1 and 2) are on top.
        assert_eq!(d.to_rows()[1], ".XX.");
    }

    #[test]
    fn the_example_file_is_the_preset() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/weaves/twill_2_2.wif");
        assert_eq!(read_wif(&path).unwrap(), WeavePreset::Twill2_2.draft());
    }

    #[test]
    fn a_liftplan_gives_the_same_draft_and_wins_over_treadling() {
        let text = format!(
            "{HEAD}THREADING=true\nLIFTPLAN=true\n\
             [WEAVING]\nShafts=4\n[WARP]\nThreads=4\n[WEFT]\nThreads=4\n\
             [THREADING]\n1=1\n2=2\n3=3\n4=4\n\
             [LIFTPLAN]\n1=1,2\n2=2,3\n3=3,4\n4=4,1\n"
        );
        assert_eq!(parse(&text).unwrap(), WeavePreset::Twill2_2.draft());
        // Lower-case sections and keys, comments, blank lines and spaces around values.
        let lower = text
            .to_lowercase()
            .replace("[liftplan]\n", "[liftplan] ; lifts\n\n")
            .replace("1=1,2", "1 = 1 , 2");
        assert_eq!(parse(&lower).unwrap(), WeavePreset::Twill2_2.draft());
        // With both, the lift plan is used (here a plain weave instead of the treadled twill).
        let both = twill_wif("true").replace("[CONTENTS]\n", "[CONTENTS]\nLIFTPLAN=yes\n")
            + "[LIFTPLAN]\n1=1,3\n2=2,4\n3=1,3\n4=2,4\n";
        assert_eq!(parse(&both).unwrap().to_rows(), ["X.X.", ".X.X", "X.X.", ".X.X"]);
    }

    #[test]
    fn a_sinking_shed_inverts_the_draft() {
        let rising = parse(&twill_wif("true")).unwrap();
        let sinking = parse(&twill_wif("no")).unwrap();
        for r in 0..4 {
            for c in 0..4 {
                assert_ne!(rising.warp_over(r, c), sinking.warp_over(r, c));
            }
        }
    }

    #[test]
    fn sections_left_out_of_contents_are_absent() {
        let text = twill_wif("true").replace("TREADLING=true\n", "TREADLING=false\n");
        let msg = err(&text);
        assert!(msg.contains("t.wif: the draft needs a [LIFTPLAN]"), "{msg}");
        assert!(msg.contains("[TREADLING] is in the file, but [CONTENTS] does not list it"), "{msg}");
        let no_threading = twill_wif("true").replace("THREADING=true\n", "");
        let msg = err(&no_threading);
        assert!(msg.contains("no [THREADING] section") && msg.contains("[CONTENTS]"), "{msg}");
        // Without [CONTENTS], every section found counts.
        let text = twill_wif("true").replace("[CONTENTS]", "[NOT CONTENTS]");
        assert_eq!(parse(&text).unwrap(), WeavePreset::Twill2_2.draft());
    }

    #[test]
    fn unlisted_picks_and_ends_are_unlifted_and_unthreaded() {
        // Six ends declared, ends 5 and 6 unthreaded: columns 4 and 5 never rise.
        let text = twill_wif("true").replace("[WARP]\nThreads=4", "[WARP]\nThreads=6");
        let msg = err(&text);
        assert!(msg.contains("t.wif: weave draft column 4") && msg.contains("never interlaces"), "{msg}");
        // Without Threads=, the size is the largest end and pick listed.
        let text = twill_wif("true").replace("Threads=4\n", "");
        assert_eq!(parse(&text).unwrap(), WeavePreset::Twill2_2.draft());
    }

    #[test]
    fn each_error_names_the_file_line_key_and_value() {
        let twill = twill_wif("true");
        let line_of = |text: &str, needle: &str| {
            1 + text.lines().position(|l| l == needle).unwrap_or_else(|| panic!("{needle:?} not in {text}"))
        };
        let cases: Vec<(String, &str, Vec<&str>)> = vec![
            (
                twill.replace("3=3,4\n", "3=3,5\n"),
                "3=3,5",
                vec!["[TIEUP] 3=3,5", "shaft 5", "1..=4", "Shafts=4"],
            ),
            (twill.replace("[THREADING]\n1=1", "[THREADING]\n1=0"), "1=0", vec!["shaft 0", "1..=4"]),
            (
                twill.replace("[THREADING]\n1=1\n2=2", "[THREADING]\n1=1\n7=2"),
                "7=2",
                vec!["end 7", "1..=4", "[WARP] Threads=4"],
            ),
            (
                twill.replace("[TREADLING]\n1=1\n2=2", "[TREADLING]\n1=1\n2=5"),
                "2=5",
                vec!["treadle 5", "Treadles=4"],
            ),
            (
                twill.replace("[TREADLING]\n1=1\n2=2", "[TREADLING]\n1=1\n2=two"),
                "2=two",
                vec!["[TREADLING] 2=two", "\"two\" is not a whole number"],
            ),
            (
                twill.replace("[THREADING]\n1=1", "[THREADING]\nx=1"),
                "x=1",
                vec!["\"x\" is not a whole number"],
            ),
            (twill.replace("Shafts=4", "Shafts=four"), "Shafts=four", vec!["Shafts=four", "\"four\""]),
            (twill.replace("Shafts=4", "Shafts=5000"), "Shafts=5000", vec!["5000", "1..=1024"]),
            (
                twill.replace("Rising Shed=true", "Rising Shed=maybe"),
                "Rising Shed=maybe",
                vec!["Rising Shed=maybe", "true or false"],
            ),
            (
                twill.replace("[TIEUP]\n1=1,2", "[TIEUP]\n1=1,2\n1=3"),
                "1=3",
                vec!["given twice", "first on line"],
            ),
            (
                twill.replace("[TIEUP]\n1=1,2", "[TIEUP]\n1 1 2"),
                "1 1 2",
                vec!["expected `key=value` in [TIEUP]"],
            ),
            (twill.replace("[TIEUP]", "[TIEUP"), "[TIEUP", vec!["must end with `]`"]),
            (twill.replace("Shafts=4\n", ""), "[WEAVING]", vec!["no `Shafts=`"]),
            (twill.replace("Treadles=4\n", ""), "[WEAVING]", vec!["no `Treadles=`"]),
        ];
        for (text, line, needles) in cases {
            let msg = err(&text);
            let at = format!("t.wif:{}:", line_of(&text, line));
            assert!(msg.starts_with(&at), "{msg:?} does not start with {at:?}");
            for needle in needles {
                assert!(msg.contains(needle), "{msg:?} lacks {needle:?}");
            }
        }
        let msg = err("[WIF]\nVersion=1.1\n");
        assert!(msg.contains("t.wif: no [WEAVING] section"), "{msg}");
    }

    #[test]
    fn large_drafts_are_cut_to_one_repeat_or_refused() {
        // 100 ends and 80 picks of the twill: cut to its 4 x 4 repeat.
        let mut text = format!(
            "{HEAD}[WEAVING]\nShafts=4\nTreadles=4\n[WARP]\nThreads=100\n[WEFT]\nThreads=80\n[THREADING]\n"
        );
        text = text.replace("[CONTENTS]\nWEAVING=true\nWARP=true\nWEFT=true\n", "");
        for e in 1..=100 {
            writeln!(text, "{e}={}", (e - 1) % 4 + 1).unwrap();
        }
        text += "[TIEUP]\n1=1,2\n2=2,3\n3=3,4\n4=4,1\n[TREADLING]\n";
        for p in 1..=80 {
            writeln!(text, "{p}={}", (p - 1) % 4 + 1).unwrap();
        }
        assert_eq!(parse(&text).unwrap(), WeavePreset::Twill2_2.draft());
        // One end threaded differently: the ends no longer repeat.
        let broken = text.replacen("\n66=2\n", "\n66=3\n", 1);
        let msg = err(&broken);
        assert!(msg.contains("80 picks x 100 ends") && msg.contains("at most 64 x 64"), "{msg}");
        assert!(msg.contains("(its smallest repeat is 4 x 100)"), "{msg}");
    }

    #[test]
    fn a_million_threads_are_refused_before_allocating() {
        // Declared: [WARP] or [WEFT] Threads=1000000, refused from the number alone.
        let twill = twill_wif("true");
        for (section, what) in [("[WARP]", "warp ends"), ("[WEFT]", "weft picks")] {
            let text =
                twill.replace(&format!("{section}\nThreads=4"), &format!("{section}\nThreads=1000000"));
            let msg = err(&text);
            assert!(
                msg.starts_with("t.wif:")
                    && msg
                        .contains(&format!("Threads=1000000: the number of {what} 1000000 is out of range"))
                    && msg.contains(&format!("1..={MAX_THREADS}")),
                "{msg}"
            );
        }
        // Not declared: an end or pick numbered 1000000 is refused by the most a file may have.
        let undeclared = twill.replace("[WARP]\nThreads=4\n", "").replace("[WEFT]\nThreads=4\n", "");
        for (section, line) in [("[THREADING]", "1000000=1"), ("[TREADLING]", "1000000=1")] {
            let text = undeclared.replace(&format!("{section}\n1=1"), &format!("{section}\n{line}"));
            let msg = err(&text);
            assert!(
                msg.contains(&format!("{section} {line}"))
                    && msg
                        .contains("1000000 is out of range: expected 1..=100000 (the most a file may have)"),
                "{msg}"
            );
        }
    }

    #[test]
    fn a_missing_file_is_named() {
        let msg = read_wif(Path::new("/no/such/draft.wif")).unwrap_err().to_string();
        assert!(msg.starts_with("/no/such/draft.wif:"), "{msg}");
    }

    /// The 2/2 twill with colours: warp ends default to colour 1 (`Color=1`), the weft all
    /// `Color=2`; `warp_colours` lists ends of [WARP COLORS].
    fn coloured_wif(extra_table: &str, warp_colours: &str) -> String {
        twill_wif("true")
            .replace("[CONTENTS]\n", "[CONTENTS]\nCOLOR PALETTE=true\nCOLOR TABLE=true\nWARP COLORS=true\n")
            .replace("[WARP]\nThreads=4\n", "[WARP]\nThreads=4\nColor=1\n")
            .replace("[WEFT]\nThreads=4\n", "[WEFT]\nThreads=4\nColor=2\n")
            + &format!(
                "[COLOR PALETTE]\nEntries=3\nForm=RGB\nRange=0,255\n\
             [COLOR TABLE]\n1=0,0,128\n2=255,255,204\n3=204,0,0\n{extra_table}\
             [WARP COLORS]\n{warp_colours}"
            )
    }

    #[test]
    fn colours_come_from_the_table_and_each_thread_cut_to_the_colour_repeat() {
        let text = coloured_wif("", "2=3\n4=3\n");
        let colours = parse_wif_colours(&text, Path::new("c.wif")).unwrap().expect("a colour table");
        assert_eq!(colours.table.len(), 3);
        assert_eq!(colours.table[0], Some([0.0, 0.0, 128.0 / 255.0]));
        assert_eq!(colours.table[1], Some([1.0, 1.0, 0.8]));
        // Ends 1 and 3 take [WARP] Color=1; the sequence 1,3,1,3 repeats every 2.
        assert_eq!(colours.warp, [0, 2]);
        assert_eq!(colours.weft, [1]);
        // The draft import reads the same file as without colours.
        assert!(parse_wif(&text, Path::new("c.wif")).is_ok());
        // No table: no colours.
        assert_eq!(parse_wif_colours(&twill_wif("true"), Path::new("t.wif")).unwrap(), None);
    }

    #[test]
    fn colour_errors_name_the_line_and_what_is_expected() {
        let cases = [
            (coloured_wif("", "2=4\n"), "[WARP COLORS] 2=4: colour 4 is not in [COLOR TABLE]"),
            (coloured_wif("4=1,2\n", ""), "[COLOR TABLE] 4=1,2: expected `r,g,b`"),
            (coloured_wif("4=1,2,300\n", ""), "three numbers in 0..=255"),
            (
                coloured_wif("", "")
                    .replace("Threads=4\nColor=1\n", "Threads=4\n")
                    .replace("[WARP COLORS]\n", "[WARP COLORS]\n1=1\n"),
                "warp end 2 has no colour",
            ),
            (coloured_wif("", "").replace("Range=0,255", "Range=255,0"), "Range=255,0: expected `lo,hi`"),
        ];
        for (text, expect) in cases {
            let message = parse_wif_colours(&text, Path::new("c.wif")).unwrap_err().to_string();
            assert!(message.contains(expect) && message.starts_with("c.wif"), "{expect}: {message}");
        }
        // A broken colour section never breaks the draft import.
        let broken = coloured_wif("this line has no equals sign\n", "");
        assert!(parse_wif(&broken, Path::new("c.wif")).is_ok());
        assert!(parse_wif_colours(&broken, Path::new("c.wif")).is_err());
    }

    #[test]
    fn a_colour_sequence_that_never_repeats_within_the_limit_is_refused() {
        let mut listed = String::new();
        for t in 1..=70 {
            writeln!(listed, "{t}={}", 1 + u32::from(t % 7 == 0 || t == 69)).unwrap();
        }
        let text = coloured_wif("", &listed).replace("[WARP]\nThreads=4", "[WARP]\nThreads=70");
        let message = parse_wif_colours(&text, Path::new("c.wif")).unwrap_err().to_string();
        assert!(message.contains("repeats every 70 threads") && message.contains("at most 64"), "{message}");
    }
}
