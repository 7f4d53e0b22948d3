//! Paint cells: the pieces of yarn a painting colours, over the whole swatch.
//!
//! Hašan & Ramamoorthy give every cell C_j of space its own albedo. Here a cell is one section
//! of one thread: threads are counted over the swatch, not per exemplar period (a single warp
//! end can be painted across the whole cloth, and its copies in other periods are other
//! threads), and a section is one crossing long (a warp end has one section per weft pick it
//! passes, and the reverse). A fiber hit finds its cell from the exemplar yarn it belongs to,
//! the copy of the exemplar it was found in, and its position along the thread.
//!
//! Numbering, as a painting names threads: warp ends from the swatch's left edge (smallest x)
//! rightwards, weft picks from its near edge (smallest y) away, sections from the same edges,
//! each counted from 0 at the first thread whose centre lies inside the swatch. Threads of the
//! exemplar copies just outside the edge (whose fibers reach into the swatch) have cells too
//! (negative thread numbers here; a painting reaches them only through `base`, `all` or
//! `random`). Yarns with no weave role (imported fibers) get one cell per exemplar
//! copy.

use glam::{DVec2, DVec3};

use crate::fabric::{Exemplar, Tiling, YarnRole};
use crate::raycast::{FiberScene, Hit};

/// How a thread set (warp or weft) divides into cells.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ThreadSet {
    /// Yarns of this role per exemplar period.
    pub per_period: u32,
    /// Position of each such yarn in centre order within a period, by its rank in the role.
    order_in_period: Vec<u32>,
    /// Threads counted over the swatch (including the copies just outside it).
    pub threads: u32,
    /// Index of the first thread whose centre lies inside the swatch.
    pub first_inside: u32,
    /// Threads whose centres lie inside the swatch.
    pub inside: u32,
    /// Sections along each thread.
    pub sections: u32,
    /// Length of one section along the thread (cm); sections are centred on the crossings
    /// (their edges at whole multiples of it from the period's origin).
    section_cm: f64,
    /// Which multiple of `section_cm` section 0 starts at (the one holding the swatch's edge).
    first_section: i64,
    /// First cell of this set.
    offset: u32,
}

impl ThreadSet {
    /// The cell of thread `thread` (0-based over all threads) and section `section`.
    fn cell(&self, thread: u32, section: u32) -> u32 {
        self.offset + thread * self.sections + section
    }

    fn cells(&self) -> u32 {
        self.threads * self.sections
    }
}

/// Which exemplar yarn is which thread.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
enum YarnPlace {
    Warp { rank: u32 },
    Weft { rank: u32 },
    Other { rank: u32 },
}

/// The cells of a swatch ([module docs](self)).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PaintCells {
    yarns: Vec<YarnPlace>,
    /// Exemplar copies along x and y: the first copy and how many.
    tiles_x: (i32, u32),
    tiles_y: (i32, u32),
    pub warp: ThreadSet,
    pub weft: ThreadSet,
    /// Yarns with no weave role per exemplar copy; their cells come after weft's.
    other_per_tile: u32,
    other_offset: u32,
    count: u32,
}

/// Why a swatch cannot be divided into paint cells.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CellsError {
    #[error("painting needs a finite swatch (a periodic fabric over `[swatch] size_cm`)")]
    UnboundedSwatch,
    #[error("the swatch would have {count} paint cells; at most {max}")]
    TooMany { count: u64, max: u64 },
}

/// The most cells a painting holds (the weight matrix has a column per cell).
pub const MAX_CELLS: u64 = 1 << 24;

impl PaintCells {
    /// Divides the swatch of `scene` (built from `exemplar`) into cells.
    pub fn new(exemplar: &Exemplar, scene: &FiberScene) -> Result<Self, CellsError> {
        let (period, (min, max)) = match exemplar.tiling {
            Tiling::Periodic { .. } => {
                let period = scene.period().ok_or(CellsError::UnboundedSwatch)?.as_dvec2();
                let rect = scene.rectangle().ok_or(CellsError::UnboundedSwatch)?;
                (period, (rect.0.as_dvec2(), rect.1.as_dvec2()))
            }
            Tiling::AsIs => (DVec2::ONE, (DVec2::ZERO, DVec2::ZERO)),
        };
        let as_is = matches!(exemplar.tiling, Tiling::AsIs);
        // One copy beyond each edge: fibers of those copies reach into the swatch.
        let tiles = |lo: f64, hi: f64, p: f64| -> (i32, u32) {
            if as_is {
                return (0, 1);
            }
            let first = (lo / p).floor() as i32 - 1;
            let last = (hi / p).ceil() as i32 + 1;
            (first, (last - first).max(1) as u32)
        };
        let (tiles_x, tiles_y) = (tiles(min.x, max.x, period.x), tiles(min.y, max.y, period.y));

        // Each yarn's mean position across its direction, for the centre order.
        let mut centre_sum = vec![DVec3::ZERO; exemplar.yarns.len()];
        let mut centre_count = vec![0_u32; exemplar.yarns.len()];
        for fiber in &exemplar.fibers {
            for p in &fiber.points {
                centre_sum[fiber.yarn as usize] += p.as_dvec3();
                centre_count[fiber.yarn as usize] += 1;
            }
        }
        let centre = |y: usize| centre_sum[y] / f64::from(centre_count[y].max(1));
        let mut yarns = Vec::with_capacity(exemplar.yarns.len());
        let (mut warp_x, mut weft_y, mut other) = (Vec::new(), Vec::new(), 0_u32);
        for (y, yarn) in exemplar.yarns.iter().enumerate() {
            yarns.push(match yarn.role {
                YarnRole::Warp if !as_is => {
                    warp_x.push(centre(y).x);
                    YarnPlace::Warp { rank: warp_x.len() as u32 - 1 }
                }
                YarnRole::Weft if !as_is => {
                    weft_y.push(centre(y).y);
                    YarnPlace::Weft { rank: weft_y.len() as u32 - 1 }
                }
                _ => {
                    other += 1;
                    YarnPlace::Other { rank: other - 1 }
                }
            });
        }
        // A warp end is one crossing long per weft pick of the period, and the reverse.
        let crossings = |n: usize| n.max(1) as f64;
        let warp = thread_set(
            &warp_x,
            period.x,
            tiles_x,
            (min.x, max.x),
            period.y / crossings(weft_y.len()),
            (min.y, max.y),
            0,
        );
        let weft = thread_set(
            &weft_y,
            period.y,
            tiles_y,
            (min.y, max.y),
            period.x / crossings(warp_x.len()),
            (min.x, max.x),
            warp.cells(),
        );
        let other_offset = warp.cells() + weft.cells();
        let count = u64::from(other_offset) + u64::from(other) * u64::from(tiles_x.1) * u64::from(tiles_y.1);
        if count > MAX_CELLS {
            return Err(CellsError::TooMany { count, max: MAX_CELLS });
        }
        Ok(Self {
            yarns,
            tiles_x,
            tiles_y,
            warp,
            weft,
            other_per_tile: other,
            other_offset,
            count: count as u32,
        })
    }

    /// Checks the layout's numbers against each other (a decoded file must pass this before
    /// its cells are indexed).
    pub fn check(&self) -> Result<(), String> {
        let tiles = [self.tiles_x.1, self.tiles_y.1];
        for (name, set, offset, copies) in
            [("warp", &self.warp, 0, tiles[0]), ("weft", &self.weft, self.warp.cells(), tiles[1])]
        {
            let mut order = set.order_in_period.clone();
            order.sort_unstable();
            let permutation = order.iter().enumerate().all(|(i, &o)| o as usize == i);
            if set.offset != offset
                || order.len() != set.per_period as usize
                || !permutation
                || set.threads != set.per_period.saturating_mul(copies)
                || set.first_inside.saturating_add(set.inside) > set.threads
                || (set.per_period > 0
                    && (set.sections == 0
                        || set.section_cm.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)))
            {
                return Err(format!("paint cells: the {name} layout does not add up"));
            }
        }
        let count = u64::from(self.warp.cells())
            + u64::from(self.weft.cells())
            + u64::from(self.other_per_tile) * u64::from(tiles[0]) * u64::from(tiles[1]);
        let other = self.yarns.iter().filter(|y| matches!(y, YarnPlace::Other { .. })).count();
        let ranks_fit = self.yarns.iter().all(|y| match *y {
            YarnPlace::Warp { rank } => rank < self.warp.per_period,
            YarnPlace::Weft { rank } => rank < self.weft.per_period,
            YarnPlace::Other { rank } => rank < self.other_per_tile,
        });
        if self.other_offset != self.warp.cells() + self.weft.cells()
            || u64::from(self.count) != count
            || other != self.other_per_tile as usize
            || !ranks_fit
        {
            return Err("paint cells: the layout does not add up".into());
        }
        Ok(())
    }

    /// Number of cells.
    #[must_use]
    pub fn count(&self) -> usize {
        self.count as usize
    }

    /// The cell a fiber hit lies in.
    #[must_use]
    pub fn cell_of(&self, hit: &Hit) -> u32 {
        let tile = |t: i32, (first, n): (i32, u32)| (t - first).clamp(0, n as i32 - 1) as u32;
        let (tx, ty) = (tile(hit.tile[0], self.tiles_x), tile(hit.tile[1], self.tiles_y));
        let section = |set: &ThreadSet, along: f64| {
            let k = (along / set.section_cm).floor() as i64 - set.first_section;
            k.clamp(0, i64::from(set.sections) - 1) as u32
        };
        match self.yarns[hit.yarn as usize] {
            YarnPlace::Warp { rank } => {
                let set = &self.warp;
                let thread = tx * set.per_period + set.order_in_period[rank as usize];
                set.cell(thread, section(set, f64::from(hit.position.y)))
            }
            YarnPlace::Weft { rank } => {
                let set = &self.weft;
                let thread = ty * set.per_period + set.order_in_period[rank as usize];
                set.cell(thread, section(set, f64::from(hit.position.x)))
            }
            YarnPlace::Other { rank } => {
                self.other_offset + (ty * self.tiles_x.1 + tx) * self.other_per_tile + rank
            }
        }
    }

    /// Cells of a thread set's thread (0 = the first inside the swatch; may be negative for
    /// the copies just outside) over the given sections; `None` past the set's threads.
    #[must_use]
    pub fn thread_cells(&self, warp: bool, thread: i64, sections: std::ops::Range<u32>) -> Option<Vec<u32>> {
        let set = if warp { &self.warp } else { &self.weft };
        let t = thread + i64::from(set.first_inside);
        if t < 0 || t >= i64::from(set.threads) || sections.end > set.sections {
            return None;
        }
        Some(sections.map(|s| set.cell(t as u32, s)).collect())
    }

    /// The global index of a thread set's thread (numbered as a painting names it, so possibly
    /// negative or past the inside threads): the thread's column (warp) or row (weft) of the
    /// exemplar tiled over the whole plane, 0 being the first yarn of the copy at the origin.
    /// It is yarn `g.rem_euclid(per_period)` of copy `g.div_euclid(per_period)`, wherever the
    /// swatch's edges fall, and does not depend on the exemplar's repeat: for a woven
    /// exemplar it is the weave column (row) of the warp end (weft pick) centred at
    /// `(g + 0.5)` spacings, so a colour order of `L` threads gives it `order[g mod L]`.
    #[must_use]
    pub fn global_thread(&self, warp: bool, thread: i64) -> i64 {
        let (set, first_tile) =
            if warp { (&self.warp, self.tiles_x.0) } else { (&self.weft, self.tiles_y.0) };
        i64::from(first_tile) * i64::from(set.per_period) + i64::from(set.first_inside) + thread
    }

    /// Which thread set (`Some(true)` warp, `Some(false)` weft) and which thread (numbered as
    /// a painting names it) and section a cell is; `None` for cells of yarns with no weave role.
    #[must_use]
    pub fn thread_of(&self, cell: u32) -> Option<(bool, i64, u32)> {
        for (warp, set) in [(true, &self.warp), (false, &self.weft)] {
            if (set.offset..set.offset + set.cells()).contains(&cell) {
                let local = cell - set.offset;
                let thread = i64::from(local / set.sections) - i64::from(set.first_inside);
                return Some((warp, thread, local % set.sections));
            }
        }
        None
    }

    /// The exemplar yarn each cell belongs to (what its material is).
    #[must_use]
    pub fn yarn_of_cells(&self) -> Vec<u32> {
        let mut out = vec![0_u32; self.count()];
        for (y, place) in self.yarns.iter().enumerate() {
            let (set, rank) = match *place {
                YarnPlace::Warp { rank } => (&self.warp, rank),
                YarnPlace::Weft { rank } => (&self.weft, rank),
                YarnPlace::Other { rank } => {
                    for tile in 0..self.tiles_x.1 * self.tiles_y.1 {
                        out[(self.other_offset + tile * self.other_per_tile + rank) as usize] = y as u32;
                    }
                    continue;
                }
            };
            let pos = set.order_in_period[rank as usize];
            for copy in 0..set.threads / set.per_period.max(1) {
                for s in 0..set.sections {
                    out[set.cell(copy * set.per_period + pos, s) as usize] = y as u32;
                }
            }
        }
        out
    }
}

/// The thread set of yarns centred at `centres` (across their direction, within one period
/// `period` along that axis), repeated over `tiles`, with sections `section_cm` long over the
/// swatch's extent `along` their direction.
fn thread_set(
    centres: &[f64],
    period: f64,
    tiles: (i32, u32),
    (lo, hi): (f64, f64),
    section_cm: f64,
    along: (f64, f64),
    offset: u32,
) -> ThreadSet {
    let per_period = centres.len() as u32;
    let mut by_centre: Vec<u32> = (0..per_period).collect();
    by_centre.sort_by(|&a, &b| centres[a as usize].total_cmp(&centres[b as usize]));
    let mut order_in_period = vec![0_u32; centres.len()];
    for (pos, &rank) in by_centre.iter().enumerate() {
        order_in_period[rank as usize] = pos as u32;
    }
    let threads = per_period * tiles.1;
    let centre_of = |thread: u32| {
        let (copy, pos) = (thread / per_period.max(1), thread % per_period.max(1));
        f64::from(tiles.0 + copy as i32) * period + centres[by_centre[pos as usize] as usize]
    };
    let inside: Vec<u32> = (0..threads).filter(|&t| (lo..hi).contains(&centre_of(t))).collect();
    let first_section = (along.0 / section_cm).floor() as i64;
    let last_section = (along.1 / section_cm).ceil() as i64;
    let sections = if per_period == 0 { 0 } else { (last_section - first_section).max(1) as u32 };
    ThreadSet {
        per_period,
        order_in_period,
        threads,
        first_inside: inside.first().copied().unwrap_or(0),
        inside: inside.len() as u32,
        sections,
        section_cm,
        first_section,
        offset,
    }
}
