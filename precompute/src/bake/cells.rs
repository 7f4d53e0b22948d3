//! IIRTF cells: equal boxes that subdivide every exemplar block (paper section 4.2).
//!
//! How it works: the region divided is, for a periodic exemplar, the period rectangle
//! `[0, px) x [0, py)` split into `blocks.nx x blocks.ny` blocks; for a `Tiling::AsIs` exemplar,
//! the xy bounds of its fibers split the same way. Vertically every block spans the fabric slab
//! (the z range of the fibers including their radius). Each block is cut into
//! `dims = [dx, dy, dz]` equal cells with `d = max(1, round(side / target))` per axis, where
//! `target = cell_size_mfp × ℓ` across the fabric (x, y) and `cell_depth_mfp × ℓ` through it
//! (z), ℓ the measured mean free path, so every cell side is within a factor 1.5 of its target
//! unless the block side itself is shorter (then one cell spans it). Every block has the same
//! dims. Cells are thinner in depth than across because transfer changes fastest with depth:
//! light enters from one face of the slab, and the fibers a camera sees lie in its top layer of
//! about one ℓ (cubic 4ℓ cells averaged them with fibers three times deeper, and multiple
//! scattering of the default scene came out 30% too dark; see `docs/BENCHMARKS.md`).
//!
//! [`CellGrid::interpolation`] gives, for any point, the cells whose centres surround it and
//! their trilinear weights (periodic across the fabric, clamped in depth, empty cells left out),
//! so shading can interpolate transfer between cells instead of showing each cell as a block.
//!
//! A segment belongs to the cell containing its midpoint: for periodic exemplars the midpoint is
//! first wrapped into the period rectangle, and z (and, for `AsIs`, x and y) is clamped into the
//! region, so every segment lands in exactly one cell.
//!
//! Cell ids are block-major: `id = block * cells_per_block + (iz * dy + iy) * dx + ix` with
//! `block = by * nx + bx`. Cells that contain no segment midpoint are allowed; their IIRTF is
//! defined as zero (nothing can be shaded with it, since no segment maps there).
//!
//! **Segment cells** ([`CellGrid::with_segment_cells`], `BakeSettings::segment_transfer_paths`):
//! after the lattice's cells, one cell per segment holding that segment alone (id
//! `lattice_cell_count() + k`). A lattice cell 2.5ℓ across holds both sides of a yarn and a
//! view sees one of them, so its transfer, the mean over both, is too dark for front-lit views
//! and too bright for backlit ones; a segment's own transfer is not (docs/BENCHMARKS.md, "Where
//! the transfer loses multiple scattering"). The IIRTF, shards, the bake file and the GPU's
//! slots treat them as cells (the recolouring basis holds the lattice's alone); shading tells
//! them apart ([`CellGrid::segment_cell`]), and [`CellGrid::interpolation`] and
//! [`CellGrid::cell_of_segment`] stay on the lattice.

use glam::DVec3;

use crate::fabric::{Exemplar, Tiling};

/// Most cells a grid may have (guards against a tiny mean free path).
pub const MAX_CELLS: u64 = 1 << 22;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CellError {
    #[error("the exemplar has no fiber segments")]
    NoSegments,
    #[error("the mean free path must be positive and finite, got {0} cm")]
    InvalidMeanFreePath(f64),
    #[error("the target cell size must be positive and finite, got {0} mean free paths")]
    InvalidCellSize(f64),
    #[error("the target cell depth must be positive and finite, got {0} mean free paths")]
    InvalidCellDepth(f64),
    #[error("the block grid must be at least 1 x 1, got {nx} x {ny}")]
    InvalidBlocks { nx: u32, ny: u32 },
    #[error("{cells} IIRTF cells exceed the limit of {MAX_CELLS}: increase the cell size")]
    TooManyCells { cells: u64 },
}

/// The cells of an exemplar and the segments each one holds.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CellGrid {
    /// Lower corner of the divided region (cm).
    origin: DVec3,
    /// Block size (cm).
    block_size: DVec3,
    blocks: [u32; 2],
    dims: [u32; 3],
    cell_size: DVec3,
    periodic: bool,
    cell_of_segment: Vec<u32>,
    /// Segment ids sorted by cell; `cell_starts[c]..cell_starts[c + 1]` are cell `c`'s (the
    /// segment cells' after the lattice's: `0..n` again).
    segments_by_cell: Vec<u32>,
    cell_starts: Vec<u32>,
    /// Whether one cell per segment follows the lattice's (module docs).
    #[serde(default)]
    segment_cells: bool,
}

impl CellGrid {
    /// Builds the grid for cells of about `cell_size_mfp × mean_free_path_cm` across and
    /// `cell_depth_mfp × mean_free_path_cm` deep and assigns every segment to a cell; see the
    /// module docs.
    pub fn new(
        exemplar: &Exemplar,
        mean_free_path_cm: f64,
        cell_size_mfp: f64,
        cell_depth_mfp: f64,
    ) -> Result<Self, CellError> {
        if !(mean_free_path_cm.is_finite() && mean_free_path_cm > 0.0) {
            return Err(CellError::InvalidMeanFreePath(mean_free_path_cm));
        }
        if !(cell_size_mfp.is_finite() && cell_size_mfp > 0.0) {
            return Err(CellError::InvalidCellSize(cell_size_mfp));
        }
        if !(cell_depth_mfp.is_finite() && cell_depth_mfp > 0.0) {
            return Err(CellError::InvalidCellDepth(cell_depth_mfp));
        }
        let (nx, ny) = (exemplar.blocks.nx, exemplar.blocks.ny);
        if nx == 0 || ny == 0 {
            return Err(CellError::InvalidBlocks { nx, ny });
        }
        let segments = exemplar.segments();
        let Some((lo, hi)) = exemplar.bounds().filter(|_| !segments.is_empty()) else {
            return Err(CellError::NoSegments);
        };
        let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
        let (origin, extent, periodic) = match exemplar.tiling {
            Tiling::Periodic { period } => {
                let p = period.as_dvec2();
                (DVec3::new(0.0, 0.0, lo.z), DVec3::new(p.x, p.y, hi.z - lo.z), true)
            }
            Tiling::AsIs => (lo, hi - lo, false),
        };
        // A degenerate extent (flat fibers) still gets a positive size.
        let extent = extent.max(DVec3::splat(1e-9));
        let block_size = DVec3::new(extent.x / f64::from(nx), extent.y / f64::from(ny), extent.z);
        let (target, depth) = (cell_size_mfp * mean_free_path_cm, cell_depth_mfp * mean_free_path_cm);
        let count = |side: f64, target: f64| -> u64 { ((side / target).round() as u64).max(1) };
        let (cx, cy, cz) =
            (count(block_size.x, target), count(block_size.y, target), count(block_size.z, depth));
        let total = cx
            .saturating_mul(cy)
            .saturating_mul(cz)
            .saturating_mul(u64::from(nx))
            .saturating_mul(u64::from(ny));
        if total > MAX_CELLS {
            return Err(CellError::TooManyCells { cells: total });
        }
        let dims = [cx as u32, cy as u32, cz as u32];
        let cell_size = block_size / DVec3::new(cx as f64, cy as f64, cz as f64);
        let mut grid = Self {
            origin,
            block_size,
            blocks: [nx, ny],
            dims,
            cell_size,
            periodic,
            cell_of_segment: Vec::new(),
            segments_by_cell: Vec::new(),
            cell_starts: Vec::new(),
            segment_cells: false,
        };
        grid.cell_of_segment = segments.iter().map(|s| grid.cell_of_point(s.midpoint().as_dvec3())).collect();
        let cells = grid.lattice_cell_count();
        let mut counts = vec![0_u32; cells + 1];
        for &c in &grid.cell_of_segment {
            counts[c as usize + 1] += 1;
        }
        for c in 0..cells {
            counts[c + 1] += counts[c];
        }
        let mut next = counts.clone();
        let mut by_cell = vec![0_u32; segments.len()];
        for (k, &c) in grid.cell_of_segment.iter().enumerate() {
            by_cell[next[c as usize] as usize] = k as u32;
            next[c as usize] += 1;
        }
        grid.segments_by_cell = by_cell;
        grid.cell_starts = counts;
        Ok(grid)
    }

    /// The grid a bake with `settings` uses: its cell size and depth, and segment cells if it
    /// asks for them (`BakeSettings::segment_transfer_paths`).
    ///
    /// # Errors
    /// As [`Self::new`].
    pub fn for_bake(
        exemplar: &Exemplar,
        mean_free_path_cm: f64,
        settings: &super::settings::BakeSettings,
    ) -> Result<Self, CellError> {
        let grid = Self::new(exemplar, mean_free_path_cm, settings.cell_size_mfp, settings.cell_depth_mfp)?;
        Ok(if settings.segment_transfer_paths > 0 { grid.with_segment_cells() } else { grid })
    }

    /// The grid with one cell per segment after the lattice's (module docs); unchanged if it
    /// has them already.
    #[must_use]
    pub fn with_segment_cells(mut self) -> Self {
        if self.segment_cells {
            return self;
        }
        let n = self.segment_count() as u32;
        let end = *self.cell_starts.last().expect("cell_starts holds cell_count() + 1 entries");
        self.segments_by_cell.extend(0..n);
        self.cell_starts.extend((1..=n).map(|k| end + k));
        self.segment_cells = true;
        self
    }

    /// The grid without its segment cells (the lattice alone).
    #[must_use]
    pub fn lattice_only(mut self) -> Self {
        if self.segment_cells {
            let lattice = self.lattice_cell_count();
            self.cell_starts.truncate(lattice + 1);
            self.segments_by_cell.truncate(self.segment_count());
            self.segment_cells = false;
        }
        self
    }

    /// Total number of cells: the lattice's (all blocks), then the segment cells if any.
    #[must_use]
    pub fn cell_count(&self) -> usize {
        self.lattice_cell_count() + if self.segment_cells { self.segment_count() } else { 0 }
    }

    /// Cells of the lattice (all blocks), the ids below the segment cells'.
    #[must_use]
    pub fn lattice_cell_count(&self) -> usize {
        self.cells_per_block() * self.blocks[0] as usize * self.blocks[1] as usize
    }

    /// Whether the grid has a cell per segment (module docs).
    #[must_use]
    pub fn has_segment_cells(&self) -> bool {
        self.segment_cells
    }

    /// The cell holding segment `k` alone, if the grid has segment cells.
    #[must_use]
    pub fn segment_cell(&self, k: u32) -> Option<u32> {
        self.segment_cells.then(|| self.lattice_cell_count() as u32 + k)
    }

    /// Whether cell `c` is a segment cell (module docs).
    #[must_use]
    pub fn is_segment_cell(&self, c: u32) -> bool {
        c as usize >= self.lattice_cell_count()
    }

    /// Cells per block along x, y, z.
    #[must_use]
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// Blocks along x and y.
    #[must_use]
    pub fn blocks(&self) -> [u32; 2] {
        self.blocks
    }

    #[must_use]
    pub fn cells_per_block(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    /// Side lengths of a cell (cm).
    #[must_use]
    pub fn cell_size_cm(&self) -> DVec3 {
        self.cell_size
    }

    /// Size of a block (cm); z is the slab thickness.
    #[must_use]
    pub fn block_size_cm(&self) -> DVec3 {
        self.block_size
    }

    /// The cell holding segment `k`'s midpoint.
    #[must_use]
    pub fn cell_of_segment(&self, k: u32) -> u32 {
        self.cell_of_segment[k as usize]
    }

    /// Number of segments the grid was built for.
    #[must_use]
    pub fn segment_count(&self) -> usize {
        self.cell_of_segment.len()
    }

    /// The segments whose midpoints lie in cell `c`, in increasing id order (may be empty).
    #[must_use]
    pub fn segments_in_cell(&self, c: u32) -> &[u32] {
        let (a, b) = (self.cell_starts[c as usize], self.cell_starts[c as usize + 1]);
        &self.segments_by_cell[a as usize..b as usize]
    }

    /// Lower corner of the divided region (cm, exemplar coordinates).
    #[must_use]
    pub fn origin_cm(&self) -> DVec3 {
        self.origin
    }

    /// Size of the divided region (cm): the blocks side by side across, the slab in z; for a
    /// periodic exemplar, its period across.
    #[must_use]
    pub fn region_size_cm(&self) -> DVec3 {
        self.block_size * DVec3::new(f64::from(self.blocks[0]), f64::from(self.blocks[1]), 1.0)
    }

    /// Whether the grid repeats with the exemplar's period across the fabric.
    #[must_use]
    pub fn is_periodic(&self) -> bool {
        self.periodic
    }

    /// Cells of the whole region along x, y, z (blocks times cells per block).
    #[must_use]
    pub fn lattice_dims(&self) -> [u32; 3] {
        [self.dims[0] * self.blocks[0], self.dims[1] * self.blocks[1], self.dims[2]]
    }

    /// The id of the cell at lattice position (`ix`, `iy`, `iz`) (each within
    /// [`Self::lattice_dims`]).
    #[must_use]
    pub fn cell_at(&self, ix: u32, iy: u32, iz: u32) -> u32 {
        let [dx, dy, dz] = self.dims;
        let block = (iy / dy) * self.blocks[0] + ix / dx;
        block * (dx * dy * dz) + (iz * dy + iy % dy) * dx + ix % dx
    }

    /// The cells whose centres surround `p` (exemplar coordinates) and their trilinear weights,
    /// for interpolating a per-cell quantity at `p`. Across the fabric the lattice wraps with
    /// the period (periodic exemplars) or is clamped to the region; in depth it is clamped, so
    /// points above the top cells' centres take the top cells' values. Cells that hold no
    /// segment have no transfer and get weight 0; the remaining weights are renormalized to sum
    /// to 1. Where all eight are empty, every weight is 0 (callers fall back to the shaded
    /// segment's own cell).
    #[must_use]
    pub fn interpolation(&self, p: DVec3) -> [(u32, f64); 8] {
        let lattice = self.lattice_dims();
        let mut out = [(0_u32, 0.0_f64); 8];
        let c = (p - self.origin) / self.cell_size - DVec3::splat(0.5);
        let base = c.floor();
        let f = c - base;
        let corner = |axis: usize, offset: i64| -> u32 {
            let n = i64::from(lattice[axis]);
            let i = if base[axis].is_finite() { (base[axis] as i64).saturating_add(offset) } else { 0 };
            let wrapped = if self.periodic && axis < 2 { i.rem_euclid(n) } else { i.clamp(0, n - 1) };
            wrapped as u32
        };
        let mut total = 0.0;
        for (k, slot) in out.iter_mut().enumerate() {
            let o = [(k & 1) as i64, ((k >> 1) & 1) as i64, ((k >> 2) & 1) as i64];
            let cell = self.cell_at(corner(0, o[0]), corner(1, o[1]), corner(2, o[2]));
            let mut w = 1.0;
            for axis in 0..3 {
                let t = if f[axis].is_finite() { f[axis] } else { 0.0 };
                w *= if o[axis] == 1 { t } else { 1.0 - t };
            }
            if self.segments_in_cell(cell).is_empty() {
                w = 0.0;
            }
            *slot = (cell, w);
            total += w;
        }
        if total > 0.0 {
            for slot in &mut out {
                slot.1 /= total;
            }
        }
        out
    }

    /// The cell containing point `p` (exemplar coordinates): wrapped into the period rectangle
    /// for periodic exemplars, clamped into the region otherwise (and always in z).
    #[must_use]
    pub fn cell_of_point(&self, p: DVec3) -> u32 {
        let mut local = p - self.origin;
        let extent = self.region_size_cm();
        if self.periodic {
            local.x = local.x.rem_euclid(extent.x);
            local.y = local.y.rem_euclid(extent.y);
        }
        let index = |v: f64, size: f64, n: u64| -> u64 {
            let i = (v / size).floor();
            if i.is_nan() || i < 0.0 { 0 } else { (i as u64).min(n - 1) }
        };
        let bx = index(local.x, self.block_size.x, u64::from(self.blocks[0]));
        let by = index(local.y, self.block_size.y, u64::from(self.blocks[1]));
        let in_block = local - DVec3::new(bx as f64 * self.block_size.x, by as f64 * self.block_size.y, 0.0);
        let [dx, dy, dz] = self.dims.map(u64::from);
        let ix = index(in_block.x, self.cell_size.x, dx);
        let iy = index(in_block.y, self.cell_size.y, dy);
        let iz = index(in_block.z, self.cell_size.z, dz);
        let block = by * u64::from(self.blocks[0]) + bx;
        (block * (dx * dy * dz) + (iz * dy + iy) * dx + ix) as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fabric::{BlockGrid, Fiber, Yarn, YarnRole};
    use crate::raycast::testing::{SyntheticWeave, synthetic_weave};
    use glam::{Vec2, Vec3};

    #[test]
    fn every_segment_is_in_exactly_one_cell_and_sides_are_near_the_target() {
        let mut ex = synthetic_weave(&SyntheticWeave::small());
        ex.blocks = BlockGrid { nx: 2, ny: 1 };
        let mfp = 0.004;
        for size in [0.7, 1.0, 2.0] {
            let grid = CellGrid::new(&ex, mfp, size, size).unwrap();
            let mut seen = vec![0_u32; ex.segment_count()];
            for c in 0..grid.cell_count() as u32 {
                for &k in grid.segments_in_cell(c) {
                    seen[k as usize] += 1;
                    assert_eq!(grid.cell_of_segment(k), c);
                }
            }
            assert!(seen.iter().all(|&n| n == 1));
            let target = size * mfp;
            let s = grid.cell_size_cm();
            let block = grid.block_size_cm();
            for (side, block_side) in [(s.x, block.x), (s.y, block.y), (s.z, block.z)] {
                if block_side >= target {
                    assert!(
                        side <= 1.5 * target + 1e-12 && side >= target / 1.5 - 1e-12,
                        "{side} vs {target}"
                    );
                } else {
                    assert!((side - block_side).abs() < 1e-12);
                }
            }
            assert_eq!(grid.cell_count(), 2 * grid.cells_per_block());
        }
    }

    #[test]
    fn midpoints_outside_the_period_wrap_into_it() {
        let fiber = |a: Vec3, b: Vec3| Fiber { points: vec![a, b], radius: 0.01, yarn: 0 };
        let ex = Exemplar {
            fibers: vec![
                fiber(Vec3::new(0.1, 0.1, 0.0), Vec3::new(0.2, 0.1, 0.0)),
                // Same place one period to the right and one below.
                fiber(Vec3::new(1.1, -0.9, 0.0), Vec3::new(1.2, -0.9, 0.0)),
                fiber(Vec3::new(0.7, 0.7, 0.05), Vec3::new(0.8, 0.8, 0.05)),
            ],
            yarns: vec![Yarn { role: YarnRole::Other, material: 0 }],
            tiling: Tiling::Periodic { period: Vec2::new(1.0, 1.0) },
            blocks: BlockGrid { nx: 2, ny: 2 },
        };
        let grid = CellGrid::new(&ex, 0.1, 1.0, 1.0).unwrap();
        assert_eq!(grid.dims(), [5, 5, 1]);
        assert_eq!(grid.cell_of_segment(0), grid.cell_of_segment(1));
        assert_ne!(grid.cell_of_segment(0), grid.cell_of_segment(2));
        // Segment 2 is in block (1, 1): the last block.
        assert_eq!(grid.cell_of_segment(2) as usize / grid.cells_per_block(), 3);
        assert!(CellGrid::new(&ex, 0.0, 1.0, 1.0).is_err());
        assert!(matches!(CellGrid::new(&ex, 0.1, 1.0, f64::NAN), Err(CellError::InvalidCellDepth(_))));
        assert!(matches!(CellGrid::new(&ex, 1e-6, 1.0, 1.0), Err(CellError::TooManyCells { .. })));
    }

    #[test]
    fn cells_are_thinner_in_depth_when_asked() {
        let ex = synthetic_weave(&SyntheticWeave::small());
        let mfp = 0.004;
        let cubic = CellGrid::new(&ex, mfp, 4.0, 4.0).unwrap();
        let thin = CellGrid::new(&ex, mfp, 4.0, 1.0).unwrap();
        assert_eq!(cubic.dims()[..2], thin.dims()[..2]);
        assert!(thin.dims()[2] >= 3 * cubic.dims()[2], "{:?} vs {:?}", thin.dims(), cubic.dims());
        let depth = thin.cell_size_cm().z / mfp;
        assert!((2.0 / 3.0..=1.5).contains(&depth) || thin.dims()[2] == 1, "depth {depth} ℓ");
    }

    #[test]
    fn interpolation_weights_are_trilinear_periodic_and_skip_empty_cells() {
        let ex = synthetic_weave(&SyntheticWeave::small());
        let grid = CellGrid::new(&ex, 0.004, 2.0, 1.0).unwrap();
        let [nx, ny, nz] = grid.lattice_dims();
        let size = grid.cell_size_cm();
        let centre = |ix: u32, iy: u32, iz: u32| {
            grid.origin_cm() + (DVec3::new(f64::from(ix), f64::from(iy), f64::from(iz)) + 0.5) * size
        };
        // Lattice positions map to distinct cells, and each cell's own centre gives it alone
        // (or nothing, when it is empty).
        let mut seen = std::collections::HashSet::new();
        for iz in 0..nz {
            for iy in 0..ny {
                for ix in 0..nx {
                    let cell = grid.cell_at(ix, iy, iz);
                    assert!(seen.insert(cell));
                    assert_eq!(grid.cell_of_point(centre(ix, iy, iz)), cell);
                    let w = grid.interpolation(centre(ix, iy, iz));
                    let sum: f64 = w.iter().map(|e| e.1).sum();
                    assert!((sum - 1.0).abs() < 1e-12 || grid.segments_in_cell(cell).is_empty());
                    if !grid.segments_in_cell(cell).is_empty() {
                        let own: f64 = w.iter().filter(|e| e.0 == cell).map(|e| e.1).sum();
                        assert!((own - 1.0).abs() < 1e-9, "cell {cell}: own weight {own}");
                    }
                }
            }
        }
        assert_eq!(seen.len(), grid.cell_count());
        // Everywhere: weights are finite, non-negative, sum to 1 and name only non-empty cells;
        // a point one period away gets the same weights.
        let period = DVec3::new(f64::from(nx) * size.x, f64::from(ny) * size.y, 0.0);
        for i in 0..500 {
            let u = DVec3::new(
                (f64::from(i) * 0.618_034).fract(),
                (f64::from(i) * 0.414_214).fract(),
                (f64::from(i) * 0.732_051).fract(),
            );
            let p = grid.origin_cm() + u * DVec3::new(period.x, period.y, f64::from(nz) * size.z);
            let w = grid.interpolation(p);
            let sum: f64 = w.iter().map(|e| e.1).sum();
            let all_empty = w.iter().all(|e| grid.segments_in_cell(e.0).is_empty());
            assert!((sum - 1.0).abs() < 1e-12 || (all_empty && sum == 0.0), "{p}: weights sum to {sum}");
            for (cell, weight) in w {
                assert!(weight.is_finite() && weight >= 0.0);
                assert!(weight == 0.0 || !grid.segments_in_cell(cell).is_empty());
            }
            let shifted = grid.interpolation(p + period);
            for (a, b) in w.iter().zip(&shifted) {
                assert!(a.0 == b.0 && (a.1 - b.1).abs() < 1e-9, "{p}: {w:?} vs {shifted:?}");
            }
        }
        // A point that is not finite gets finite weights that still sum to 1 (or all 0).
        for p in [DVec3::NAN, DVec3::splat(f64::INFINITY), DVec3::new(0.0, f64::NEG_INFINITY, 1e300)] {
            let w = grid.interpolation(p);
            let sum: f64 = w.iter().map(|e| e.1).sum();
            assert!(w.iter().all(|e| e.1.is_finite() && e.1 >= 0.0), "{p}: {w:?}");
            assert!((sum - 1.0).abs() < 1e-12 || sum == 0.0, "{p}: {w:?}");
        }
        // Halfway between two non-empty neighbours across x: half each.
        let (ix, iy, iz) = (0..nz)
            .flat_map(|z| (0..ny).flat_map(move |y| (0..nx).map(move |x| (x, y, z))))
            .find(|&(x, y, z)| {
                let pair = [grid.cell_at(x, y, z), grid.cell_at((x + 1) % nx, y, z)];
                pair.iter().all(|&c| !grid.segments_in_cell(c).is_empty())
            })
            .expect("two non-empty neighbours");
        let mid = centre(ix, iy, iz) + DVec3::new(0.5 * size.x, 0.0, 0.0);
        let w = grid.interpolation(mid);
        let a: f64 = w.iter().filter(|e| e.0 == grid.cell_at(ix, iy, iz)).map(|e| e.1).sum();
        let b: f64 = w.iter().filter(|e| e.0 == grid.cell_at((ix + 1) % nx, iy, iz)).map(|e| e.1).sum();
        assert!((a - 0.5).abs() < 1e-9 && (b - 0.5).abs() < 1e-9, "{a} {b}");
    }

    #[test]
    fn segment_cells_follow_the_lattice_one_segment_each_and_leave_it_unchanged() {
        let mut ex = synthetic_weave(&SyntheticWeave::small());
        ex.blocks = BlockGrid { nx: 2, ny: 1 };
        let lattice = CellGrid::new(&ex, 0.004, 1.0, 0.5).unwrap();
        let grid = lattice.clone().with_segment_cells();
        let (n, first) = (ex.segment_count(), lattice.cell_count());
        assert!(grid.has_segment_cells() && !lattice.has_segment_cells());
        assert_eq!((grid.lattice_cell_count(), grid.cell_count()), (first, first + n));
        for c in 0..first as u32 {
            assert_eq!(grid.segments_in_cell(c), lattice.segments_in_cell(c));
            assert!(!grid.is_segment_cell(c));
        }
        for k in 0..n as u32 {
            let own = grid.segment_cell(k).expect("a segment cell");
            assert_eq!(own, first as u32 + k);
            assert!(grid.is_segment_cell(own));
            assert_eq!(grid.segments_in_cell(own), &[k]);
            // Shading's lattice lookups do not see the segment cells.
            assert_eq!(grid.cell_of_segment(k), lattice.cell_of_segment(k));
            assert_eq!(lattice.segment_cell(k), None);
        }
        let p = ex.segments()[0].midpoint().as_dvec3();
        assert_eq!(grid.interpolation(p), lattice.interpolation(p));
        assert_eq!(grid.clone().with_segment_cells(), grid, "adding them twice adds nothing");
        assert_eq!(grid.lattice_only(), lattice);
    }
}
