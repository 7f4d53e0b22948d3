//! Ray casting against fiber-level fabric: closest-hit and any-hit queries over a tiled exemplar.
//!
//! How it works:
//! - Every fiber segment is traced as a [`capsule::Capsule`] (cylinder plus hemispherical caps),
//!   so polylines close at their joints; see [`capsule`] for why and for the exact test.
//! - A periodic exemplar is stored once, *wrapped into one period cell*: each segment is moved by
//!   a whole number of periods so its midpoint lies in `[0, px) x [0, py)`, and segments whose
//!   capsule crosses the cell border are also stored shifted by one period (about 5 % extra for
//!   fiber-scale segments). One uniform voxel grid ([`grid`]) bins these capsules; it then holds
//!   *every* capsule of the infinite periodic fabric that overlaps a cell.
//! - A ray is clipped to the fabric slab (the exemplar's z range) and, for a finite swatch, to the
//!   swatch rectangle; then a 2D DDA walks the period cells its xy projection crosses, nearest
//!   first. In each cell the grid is walked (a 3D DDA over its voxels) with the piece of the ray
//!   inside that cell, in cell-local coordinates (the cell offset is subtracted in f64 before
//!   converting to f32, so precision does not degrade far from the origin). Hits in a cell's
//!   piece are exact closest hits, so the walk stops at the first cell with a hit.
//! - A finite swatch is "the infinite periodic fabric clipped to a rectangle": because the ray is
//!   clipped to the rectangle before the walk, no hit lies outside it and the edges are clean
//!   straight cuts (the cut fibers are open there: a ray entering a fiber through the cut sees
//!   what lies behind it).
//! - `Tiling::AsIs` exemplars are one grid over the fibers as given, walked once.
//! - Why a grid and not a BVH: fibers are capsules of one radius spread evenly through a thin
//!   slab, which a uniform grid with empty-space jumps walks in fewer instructions than a
//!   general BVH (obvhs's CWBVH was 1.6x slower on closest hits; docs/BENCHMARKS.md, "Fiber ray
//!   casting").
//!
//! Rays whose origin is inside a capsule do not hit it (see [`capsule`]). `ignore_fiber` skips
//! every segment of one fiber id in every copy: the path tracer passes the fiber a scattered ray
//! leaves, which both avoids self-intersection near the origin and is the per-fiber visibility
//! the paper's precomputation needs (a fiber never shadows itself).

pub mod capsule;
#[cfg(feature = "embree")]
pub mod embree;
pub mod grid;
mod mean_free_path;
pub mod pattern;
pub mod testing;
pub mod throughput;

pub use mean_free_path::{MeanFreePath, mean_free_path};

use crate::fabric::{Exemplar, Segment, Tiling};
use capsule::{Capsule, CapsuleHit};
use glam::{DVec2, DVec3, Vec2, Vec3};

/// Each cell's ray piece is extended by this much (cm) so that a hit exactly on a cell border
/// is not lost to rounding between the two cells.
const CELL_OVERLAP: f64 = 1e-6;
/// An unbounded walk that has crossed this many cells without a hit gives up (only a ray
/// running almost exactly in the plane of the fabric through a gap can get there).
const MAX_UNBOUNDED_CELLS: u32 = 100_000;

/// Which part of the plane a periodic exemplar covers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Extent {
    /// The whole plane.
    Unbounded,
    /// `nx x ny` periods from the origin: the rectangle `[0, nx px) x [0, ny py)`.
    Copies { nx: u32, ny: u32 },
    /// An axis-aligned rectangle in cm.
    Rectangle { min: Vec2, max: Vec2 },
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SceneError {
    #[error("the tiling period must be positive and finite, got {0:?}")]
    InvalidPeriod(Vec2),
    #[error("the swatch rectangle is empty or not finite: {min:?}..{max:?}")]
    EmptyExtent { min: Vec2, max: Vec2 },
    #[error("fiber geometry is not finite")]
    NonFiniteGeometry,
}

/// A ray's first fiber hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance from the ray origin in cm (the direction is normalised).
    pub t: f32,
    /// World position of the hit.
    pub position: Vec3,
    /// The same point in the exemplar's own frame (`position - tile * period`), exact.
    pub local_position: Vec3,
    /// Unit outward normal of the capsule at the hit.
    pub normal: Vec3,
    /// Unit fiber tangent (segment direction from its first to its second point).
    pub tangent: Vec3,
    /// Where along the segment the hit projects, 0 at its first point, 1 at its second.
    pub segment_param: f32,
    /// Index into [`Exemplar::segments`].
    pub segment: u32,
    pub fiber: u32,
    pub yarn: u32,
    /// Which copy of the exemplar was hit (always `[0, 0]` for `Tiling::AsIs`).
    pub tile: [i32; 2],
    /// Which exemplar of a patterned cloth was hit ([`pattern::PatternedFibers`]; 0 otherwise):
    /// `segment`, `local_position` and `tile` are that exemplar's.
    pub exemplar: u16,
}

/// Per-primitive data read only on a hit, in the order of [`FiberScene::capsules`].
#[derive(Debug, Clone, Copy)]
struct PrimitiveInfo {
    segment: u32,
    yarn: u32,
    /// The primitive is the exemplar segment moved by `shift * period`.
    shift: [i32; 2],
}

#[derive(Debug, Clone, Copy)]
enum Layout {
    Periodic { period: DVec2, rect: Option<(DVec2, DVec2)> },
    AsIs { lo: DVec3, hi: DVec3 },
}

/// A fabric ready for ray casting: an exemplar, its voxel grid and how it is tiled.
#[derive(Debug)]
pub struct FiberScene {
    segments: Vec<Segment>,
    /// Every capsule the grid bins, in Morton order of their centres.
    capsules: Vec<Capsule>,
    /// The fiber of each capsule (checked on a hit, for `ignore_fiber`).
    fibers: Vec<u32>,
    infos: Vec<PrimitiveInfo>,
    grid: grid::CapsuleGrid,
    layout: Layout,
    /// z range of the fibers including their radius, padded by [`CELL_OVERLAP`].
    z_range: (f64, f64),
}

impl FiberScene {
    /// Builds the scene. `extent` is ignored for `Tiling::AsIs` exemplars.
    pub fn new(exemplar: &Exemplar, extent: Extent) -> Result<Self, SceneError> {
        let segments = exemplar.segments();
        if segments.iter().any(|s| !(s.a.is_finite() && s.b.is_finite() && s.radius.is_finite())) {
            return Err(SceneError::NonFiniteGeometry);
        }
        let (lo, hi) = exemplar.bounds().unwrap_or((Vec3::ZERO, Vec3::ZERO));
        let z_range = (f64::from(lo.z) - CELL_OVERLAP, f64::from(hi.z) + CELL_OVERLAP);
        let mut placed: Vec<(Capsule, PrimitiveInfo, u32)> = Vec::with_capacity(segments.len() * 21 / 20);
        let layout = match exemplar.tiling {
            Tiling::AsIs => {
                for (i, s) in segments.iter().enumerate() {
                    let info = PrimitiveInfo { segment: i as u32, yarn: s.yarn, shift: [0, 0] };
                    placed.push((Capsule::from_segment(s.a, s.b, s.radius), info, s.fiber));
                }
                let pad = DVec3::splat(CELL_OVERLAP);
                Layout::AsIs { lo: lo.as_dvec3() - pad, hi: hi.as_dvec3() + pad }
            }
            Tiling::Periodic { period } => {
                if !(period.x > 0.0 && period.y > 0.0 && period.is_finite()) {
                    return Err(SceneError::InvalidPeriod(period));
                }
                let rect = match extent {
                    Extent::Unbounded => None,
                    Extent::Copies { nx, ny } => Some((Vec2::ZERO, period * Vec2::new(nx as f32, ny as f32))),
                    Extent::Rectangle { min, max } => Some((min, max)),
                };
                if let Some((min, max)) = rect
                    && !(min.is_finite() && max.is_finite() && min.x < max.x && min.y < max.y)
                {
                    return Err(SceneError::EmptyExtent { min, max });
                }
                for (i, s) in segments.iter().enumerate() {
                    place_periodic(s, i as u32, period, &mut placed);
                }
                Layout::Periodic {
                    period: period.as_dvec2(),
                    rect: rect.map(|(a, b)| (a.as_dvec2(), b.as_dvec2())),
                }
            }
        };
        // Primitives in the order of their capsules' centres along a Morton curve, so that the
        // capsules one voxel lists lie near each other in memory.
        let order = morton_order(&placed);
        let capsules: Vec<Capsule> = order.iter().map(|&i| placed[i as usize].0).collect();
        let fibers = order.iter().map(|&i| placed[i as usize].2).collect();
        let infos = order.iter().map(|&i| placed[i as usize].1).collect();
        let (box_lo, box_hi) = match layout {
            Layout::AsIs { lo, hi } => (lo.as_vec3(), hi.as_vec3()),
            Layout::Periodic { period, .. } => (
                Vec3::new(0.0, 0.0, z_range.0 as f32),
                Vec3::new(period.x as f32, period.y as f32, z_range.1 as f32),
            ),
        };
        let grid = grid::CapsuleGrid::new(&capsules, box_lo, box_hi);
        Ok(Self { segments, capsules, fibers, infos, grid, layout, z_range })
    }

    /// The exemplar's segments (what [`Hit::segment`] indexes).
    #[must_use]
    pub fn segments(&self) -> &[Segment] {
        &self.segments
    }

    /// The tiling period, `None` for `Tiling::AsIs`.
    #[must_use]
    pub fn period(&self) -> Option<Vec2> {
        match self.layout {
            Layout::Periodic { period, .. } => Some(period.as_vec2()),
            Layout::AsIs { .. } => None,
        }
    }

    /// The swatch rectangle of a finite periodic scene.
    #[must_use]
    pub fn rectangle(&self) -> Option<(Vec2, Vec2)> {
        match self.layout {
            Layout::Periodic { rect, .. } => rect.map(|(a, b)| (a.as_vec2(), b.as_vec2())),
            Layout::AsIs { .. } => None,
        }
    }

    /// The z range (cm) all fibers lie in.
    #[must_use]
    pub fn slab(&self) -> (f32, f32) {
        ((self.z_range.0 + CELL_OVERLAP) as f32, (self.z_range.1 - CELL_OVERLAP) as f32)
    }

    /// Number of capsules in the grid (segments plus the border copies of a periodic scene).
    #[must_use]
    pub fn primitive_count(&self) -> usize {
        self.capsules.len()
    }

    /// A line describing the voxel grid (for reports).
    #[must_use]
    pub fn grid_summary(&self) -> String {
        self.grid.summary()
    }

    /// The copy at the centre of the scene: `[0, 0]` unless the swatch is a rectangle.
    #[must_use]
    pub fn central_tile(&self) -> [i32; 2] {
        match self.layout {
            Layout::Periodic { period, rect: Some((min, max)) } => {
                let c = (0.5 * (min + max) / period).floor();
                [c.x as i32, c.y as i32]
            }
            _ => [0, 0],
        }
    }

    /// World position of a hit in f64 (exact composition of tile offset and local position).
    #[must_use]
    pub fn world_position_f64(&self, hit: &Hit) -> DVec3 {
        hit.local_position.as_dvec3() + self.tile_offset(hit.tile)
    }

    /// World offset of a copy of the exemplar.
    #[must_use]
    pub fn tile_offset(&self, tile: [i32; 2]) -> DVec3 {
        match self.layout {
            Layout::Periodic { period, .. } => {
                DVec3::new(f64::from(tile[0]) * period.x, f64::from(tile[1]) * period.y, 0.0)
            }
            Layout::AsIs { .. } => DVec3::ZERO,
        }
    }

    /// First fiber hit along `origin + t * dir` with `0 <= t < t_max` (`dir` need not be unit;
    /// `t` is a distance in cm along it), skipping every segment of `ignore_fiber`.
    #[must_use]
    pub fn closest_hit(&self, origin: Vec3, dir: Vec3, t_max: f32, ignore_fiber: Option<u32>) -> Option<Hit> {
        self.closest_hit_f64(origin.as_dvec3(), dir.as_dvec3(), f64::from(t_max), ignore_fiber)
    }

    /// [`Self::closest_hit`] for double-precision callers.
    #[must_use]
    pub fn closest_hit_f64(
        &self,
        origin: DVec3,
        dir: DVec3,
        t_max: f64,
        ignore_fiber: Option<u32>,
    ) -> Option<Hit> {
        self.walk(origin, dir, (0.0, t_max), ignore_fiber, false)
    }

    /// Whether anything blocks `origin + t * dir` for `0 <= t < t_max` (shadow rays).
    #[must_use]
    pub fn any_hit(&self, origin: Vec3, dir: Vec3, t_max: f32, ignore_fiber: Option<u32>) -> bool {
        self.any_hit_f64(origin.as_dvec3(), dir.as_dvec3(), f64::from(t_max), ignore_fiber)
    }

    /// [`Self::any_hit`] for double-precision callers.
    #[must_use]
    pub fn any_hit_f64(&self, origin: DVec3, dir: DVec3, t_max: f64, ignore_fiber: Option<u32>) -> bool {
        self.walk(origin, dir, (0.0, t_max), ignore_fiber, true).is_some()
    }

    /// Clips the ray's `span` to the slab (and rectangle), then walks the cells; see the module
    /// docs.
    fn walk(
        &self,
        origin: DVec3,
        dir: DVec3,
        span: (f64, f64),
        ignore: Option<u32>,
        any: bool,
    ) -> Option<Hit> {
        let d = dir.try_normalize()?;
        if !origin.is_finite() || self.capsules.is_empty() || span.0.is_nan() || span.1.is_nan() {
            return None;
        }
        let mut span = span;
        clip_slab(&mut span, origin.z, d.z, self.z_range.0, self.z_range.1);
        match self.layout {
            Layout::AsIs { lo, hi } => {
                clip_slab(&mut span, origin.x, d.x, lo.x, hi.x);
                clip_slab(&mut span, origin.y, d.y, lo.y, hi.y);
                if span.0 >= span.1 {
                    return None;
                }
                self.trace_piece(origin, d, span.0, span.1, DVec2::ZERO, [0, 0], ignore, any)
            }
            Layout::Periodic { period, rect } => {
                if let Some((min, max)) = rect {
                    clip_slab(&mut span, origin.x, d.x, min.x, max.x);
                    clip_slab(&mut span, origin.y, d.y, min.y, max.y);
                }
                if span.0 >= span.1 {
                    return None;
                }
                self.walk_cells(origin, d, span, period, rect.is_none(), ignore, any)
            }
        }
    }

    fn walk_cells(
        &self,
        o: DVec3,
        d: DVec3,
        span: (f64, f64),
        period: DVec2,
        unbounded: bool,
        ignore: Option<u32>,
        any: bool,
    ) -> Option<Hit> {
        let most = unbounded.then_some(MAX_UNBOUNDED_CELLS);
        walk_lattice(o, d, span, period, most, |cell, t_from, t_to| {
            let offset = DVec2::new(cell[0] as f64 * period.x, cell[1] as f64 * period.y);
            let tile = [cell[0] as i32, cell[1] as i32];
            self.trace_piece(o, d, t_from, t_to, offset, tile, ignore, any)
        })
    }

    /// Walks the grid with the ray piece `t_from..t_to` in the frame of the cell at `offset`.
    fn trace_piece(
        &self,
        o: DVec3,
        d: DVec3,
        t_from: f64,
        t_to: f64,
        offset: DVec2,
        cell: [i32; 2],
        ignore: Option<u32>,
        any: bool,
    ) -> Option<Hit> {
        let start = o + t_from * d;
        let local_origin = (start - offset.extend(0.0)).as_vec3();
        let ray_origin = if t_from == 0.0 { local_origin } else { (o - offset.extend(0.0)).as_vec3() };
        let dir = d.as_vec3();
        let t_len = (t_to - t_from) as f32;
        let (index, capsule_hit) =
            self.traverse(local_origin, ray_origin, dir, t_len, ignore.unwrap_or(u32::MAX), any)?;
        let info = self.infos[index as usize];
        let tile = [cell[0] + info.shift[0], cell[1] + info.shift[1]];
        let cell_local = local_origin + capsule_hit.t * dir;
        let shift = match self.layout {
            Layout::Periodic { period, .. } => {
                Vec3::new(info.shift[0] as f32 * period.x as f32, info.shift[1] as f32 * period.y as f32, 0.0)
            }
            Layout::AsIs { .. } => Vec3::ZERO,
        };
        let local_position = cell_local - shift;
        let t = t_from + f64::from(capsule_hit.t);
        let position = (local_position.as_dvec3() + self.tile_offset(tile)).as_vec3();
        Some(Hit {
            t: t as f32,
            position,
            local_position,
            normal: capsule_hit.normal,
            tangent: self.capsules[index as usize].axis,
            segment_param: capsule_hit.segment_param,
            segment: info.segment,
            fiber: self.fibers[index as usize],
            yarn: info.yarn,
            tile,
            exemplar: 0,
        })
    }

    /// Closest (or, with `any`, first found) capsule entry with `0 <= t < t_max` of the ray piece
    /// from `origin`, in cell-local coordinates, skipping capsules that contain the ray's true
    /// origin `ray_origin`; returns the primitive index.
    #[inline]
    fn traverse(
        &self,
        origin: Vec3,
        ray_origin: Vec3,
        dir: Vec3,
        t_max: f32,
        ignore: u32,
        any: bool,
    ) -> Option<(u32, CapsuleHit)> {
        self.grid.walk(origin, dir, t_max, any, |item, best_t| {
            // The ignored fiber is checked on a hit only: dropping a hit leaves the best `t` as
            // skipping the test would.
            let hit = self.capsules[item as usize].intersect_piece(origin, dir, best_t, ray_origin)?;
            (self.fibers[item as usize] != ignore).then_some(hit)
        })
    }
}

/// Walks the cells of the lattice of `side`-sized rectangles (cell `[i, j]` covering
/// `[i, i + 1) side.x × [j, j + 1) side.y`) that the xy projection of `o + t d` crosses for `t`
/// in `span`, nearest first (a 2D DDA), and calls `piece(cell, t_from, t_to)` with the ray's
/// piece over each, extended by [`CELL_OVERLAP`] past an inner border so a hit exactly on it is
/// not lost to rounding; returns the first piece's answer that is `Some`. With `most`, gives up
/// after that many cells.
pub(crate) fn walk_lattice<T>(
    o: DVec3,
    d: DVec3,
    (mut t_enter, t_end): (f64, f64),
    side: DVec2,
    most: Option<u32>,
    mut piece: impl FnMut([i64; 2], f64, f64) -> Option<T>,
) -> Option<T> {
    let start = o + t_enter * d;
    let mut cell = [(start.x / side.x).floor() as i64, (start.y / side.y).floor() as i64];
    let step = [d.x.signum() as i64, d.y.signum() as i64];
    let mut visited = 0u32;
    loop {
        let boundary = |axis: usize, c: i64| {
            if d[axis] > 0.0 {
                ((c + 1) as f64 * side[axis] - o[axis]) / d[axis]
            } else if d[axis] < 0.0 {
                (c as f64 * side[axis] - o[axis]) / d[axis]
            } else {
                f64::INFINITY
            }
        };
        let next = [boundary(0, cell[0]), boundary(1, cell[1])];
        let t_exit = next[0].min(next[1]).min(t_end);
        if t_exit > t_enter {
            let piece_end = if t_exit < t_end { (t_exit + CELL_OVERLAP).min(t_end) } else { t_end };
            if let Some(found) = piece(cell, t_enter, piece_end) {
                return Some(found);
            }
        }
        if t_exit >= t_end {
            return None;
        }
        visited += 1;
        if most.is_some_and(|most| visited >= most) {
            return None;
        }
        let axis = usize::from(next[1] < next[0]);
        cell[axis] += step[axis];
        t_enter = t_enter.max(t_exit);
    }
}

/// Narrows `span` to where `o + t d` (one coordinate) lies in `[lo, hi]` (empty, `span.0 >=
/// span.1`, when it never does).
pub fn clip_slab(span: &mut (f64, f64), o: f64, d: f64, lo: f64, hi: f64) {
    if d == 0.0 {
        if o < lo || o > hi {
            *span = (1.0, 0.0);
        }
        return;
    }
    let (a, b) = ((lo - o) / d, (hi - o) / d);
    span.0 = span.0.max(a.min(b));
    span.1 = span.1.min(a.max(b));
}

/// Adds segment `s` wrapped into the period cell, plus its copies shifted by a period wherever
/// its capsule crosses the cell border.
fn place_periodic(s: &Segment, index: u32, period: Vec2, out: &mut Vec<(Capsule, PrimitiveInfo, u32)>) {
    let wrap = -(s.midpoint().truncate() / period).floor();
    let shift0 = (wrap * period).extend(0.0);
    let (a, b) = (s.a + shift0, s.b + shift0);
    let lo = a.min(b).truncate() - s.radius;
    let hi = a.max(b).truncate() + s.radius;
    // Shifts k (in periods) whose copy overlaps the closed cell [0, p]: lo + k p <= p and hi + k p >= 0.
    let k_min = (-hi / period).ceil();
    let k_max = ((period - lo) / period).floor();
    for ky in k_min.y as i32..=k_max.y as i32 {
        for kx in k_min.x as i32..=k_max.x as i32 {
            let shift = (Vec2::new(kx as f32, ky as f32) * period).extend(0.0);
            let info = PrimitiveInfo {
                segment: index,
                yarn: s.yarn,
                shift: [wrap.x as i32 + kx, wrap.y as i32 + ky],
            };
            out.push((Capsule::from_segment(a + shift, b + shift, s.radius), info, s.fiber));
        }
    }
}

/// The indices of `placed` sorted by the Morton code of their capsules' centres (10 bits per
/// axis over the capsules' box).
fn morton_order(placed: &[(Capsule, PrimitiveInfo, u32)]) -> Vec<u32> {
    let (lo, hi) = placed.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), (c, _, _)| {
        (lo.min(c.center), hi.max(c.center))
    });
    let scale = 1023.0 / (hi - lo).max(Vec3::splat(1e-12));
    let spread = |v: u32| {
        // Bits of a 10-bit value moved to every third position.
        let mut x = u64::from(v) & 0x3ff;
        x = (x | x << 16) & 0x0300_00ff;
        x = (x | x << 8) & 0x0300_f00f;
        x = (x | x << 4) & 0x030c_30c3;
        (x | x << 2) & 0x0924_9249
    };
    let mut keyed: Vec<(u64, u32)> = placed
        .iter()
        .enumerate()
        .map(|(i, (c, _, _))| {
            let q = ((c.center - lo) * scale).round().as_uvec3();
            (spread(q.x) | spread(q.y) << 1 | spread(q.z) << 2, i as u32)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

#[cfg(test)]
mod tests;
