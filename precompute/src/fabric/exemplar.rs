//! Periodic woven exemplars: one repeat of a weave draft filled with procedural yarns.
//!
//! How it works: warp end `j` runs along +y at `x = (j + 0.5) * spacing_warp`, weft pick `i` along
//! +x at `y = (i + 0.5) * spacing_weft`. At each crossing the yarn on top (from the draft) has its
//! centre at `z = +crimp`, the one below at `z = -crimp`; between crossings the height follows a
//! cosine ease (`z = z0 + (z1 - z0) (1 - cos(pi t)) / 2`), which is periodic, C1, flat along
//! floats and never overshoots. The default crimp, [`WovenFabric::touching_crimp`], puts the yarns'
//! elliptical sections just in contact at crossings. Each yarn's fibers come from
//! [`super::yarn::yarn_fibers`] along that centre line over exactly one period, so the exemplar
//! tiles seamlessly with period `(cols * spacing_warp, rows * spacing_weft)`; fibers stick out
//! of the period rectangle by up to half a yarn width, which tiling expects.
//!
//! Colour orders: with a warp or weft [`ColourOrder`], end `j` takes the order's colour of
//! thread `j` (weft likewise), and the exemplar repeat grows to the least common multiple of
//! the weave's repeat and the colour repeat in that direction (the draft tiled to it), so the
//! cloth still tiles seamlessly; without one every warp end takes `warp_material` (weft
//! likewise).
//!
//! Yarn indices: warp end `j` is yarn `j`, weft pick `i` is yarn `cols + i` (`cols` and `rows`
//! of the exemplar repeat).

use glam::{DVec2, DVec3, Vec2};
use rayon::prelude::*;

use super::colour_order::{ColourOrder, exemplar_repeat};
use super::weave::WeaveDraft;
use super::yarn::{YarnParams, YarnPath, yarn_fibers};
use super::{BlockGrid, Exemplar, Tiling, Yarn, YarnRole};
use crate::params::{ParamError, check_count, check_range};

/// Everything that defines a procedural woven exemplar; lengths in centimetres.
#[derive(Debug, Clone, PartialEq)]
pub struct WovenFabric {
    pub draft: WeaveDraft,
    /// Distance between neighbouring warp ends (along x).
    pub spacing_warp: f64,
    /// Distance between neighbouring weft picks (along y).
    pub spacing_weft: f64,
    /// Height of the upper yarn's centre above the midplane at a crossing (the lower one is at
    /// `-crimp`).
    pub crimp: f64,
    pub warp: YarnParams,
    pub weft: YarnParams,
    pub blocks: BlockGrid,
    pub seed: u64,
    /// Material index given to warp yarns (default 0).
    pub warp_material: u32,
    /// Material index given to weft yarns (default 1).
    pub weft_material: u32,
    /// The warp's colour order (material index per end of the colour repeat); `None`: every
    /// end is `warp_material`.
    pub warp_colours: Option<ColourOrder>,
    /// The weft's colour order; `None`: every pick is `weft_material`.
    pub weft_colours: Option<ColourOrder>,
}

impl WovenFabric {
    /// A fabric with touching crimp, one block, seed 0, warp material 0 and weft material 1.
    #[must_use]
    pub fn new(
        draft: WeaveDraft,
        spacing_warp: f64,
        spacing_weft: f64,
        warp: YarnParams,
        weft: YarnParams,
    ) -> Self {
        Self {
            draft,
            spacing_warp,
            spacing_weft,
            crimp: Self::touching_crimp(&warp, &weft),
            warp,
            weft,
            blocks: BlockGrid { nx: 1, ny: 1 },
            seed: 0,
            warp_material: 0,
            weft_material: 1,
            warp_colours: None,
            weft_colours: None,
        }
    }

    /// The fabric over its exemplar repeat: the draft tiled to the least common multiple of the
    /// weave repeat and the colour repeats (itself when there are no colour orders or they
    /// divide the weave repeat).
    ///
    /// # Errors
    /// When the joint repeat exceeds [`super::colour_order::MAX_REPEAT_THREADS`] threads.
    pub fn over_colour_repeat(&self) -> Result<Self, ParamError> {
        let (rows, cols) = (self.draft.rows(), self.draft.cols());
        let repeat_cols = self
            .warp_colours
            .as_ref()
            .map_or(Ok(cols), |o| exemplar_repeat("warp_order", cols, o.threads().len()))?;
        let repeat_rows = self
            .weft_colours
            .as_ref()
            .map_or(Ok(rows), |o| exemplar_repeat("weft_order", rows, o.threads().len()))?;
        let mut fabric = self.clone();
        if (repeat_rows, repeat_cols) != (rows, cols) {
            let cells = (0..repeat_rows)
                .flat_map(|i| (0..repeat_cols).map(move |j| (i, j)))
                .map(|(i, j)| self.draft.warp_over(i % rows, j % cols))
                .collect();
            fabric.draft = WeaveDraft::new(repeat_rows, repeat_cols, cells)
                .expect("a tiled valid draft within the size limit is valid");
        }
        Ok(fabric)
    }

    /// The material of warp end `j`.
    #[must_use]
    pub fn warp_material_of(&self, j: usize) -> u32 {
        self.warp_colours.as_ref().map_or(self.warp_material, |o| o.colour_of(j))
    }

    /// The material of weft pick `i`.
    #[must_use]
    pub fn weft_material_of(&self, i: usize) -> u32 {
        self.weft_colours.as_ref().map_or(self.weft_material, |o| o.colour_of(i))
    }

    /// The crimp at which warp and weft sections just touch at a crossing: `2 crimp` equals the
    /// sum of their half heights.
    #[must_use]
    pub fn touching_crimp(warp: &YarnParams, weft: &YarnParams) -> f64 {
        0.25 * (warp.height + weft.height)
    }

    /// The exemplar period along x and y (cm).
    #[must_use]
    pub fn period(&self) -> DVec2 {
        DVec2::new(self.draft.cols() as f64 * self.spacing_warp, self.draft.rows() as f64 * self.spacing_weft)
    }

    /// Checks all numbers. Spacings may be as small as half a yarn width (yarns squeezed
    /// together); the crimp must keep crossing yarns' centres at least half a mean yarn height
    /// apart, so yarns may flatten into each other a little but never pass through.
    pub fn validate(&self) -> Result<(), ParamError> {
        self.warp.validate("warp.")?;
        self.weft.validate("weft.")?;
        check_range("spacing_warp", self.spacing_warp, 0.5 * self.warp.width, 1.0)?;
        check_range("spacing_weft", self.spacing_weft, 0.5 * self.weft.width, 1.0)?;
        let touching = Self::touching_crimp(&self.warp, &self.weft);
        check_range("crimp", self.crimp, 0.5 * touching, 4.0 * touching)?;
        check_count("blocks.nx", self.blocks.nx as usize, 1, 64)?;
        check_count("blocks.ny", self.blocks.ny as usize, 1, 64)?;
        Ok(())
    }

    /// Centre of warp end `j` at height `y` (any real `y`; periodic).
    #[must_use]
    pub fn warp_center(&self, j: usize, y: f64) -> DVec3 {
        let x = (j as f64 + 0.5) * self.spacing_warp;
        let z =
            self.crimp_height(y / self.spacing_weft - 0.5, self.draft.rows(), |i| self.draft.warp_over(i, j));
        DVec3::new(x, y, z)
    }

    /// Centre of weft pick `i` at position `x` (any real `x`; periodic).
    #[must_use]
    pub fn weft_center(&self, i: usize, x: f64) -> DVec3 {
        let y = (i as f64 + 0.5) * self.spacing_weft;
        let z = self
            .crimp_height(x / self.spacing_warp - 0.5, self.draft.cols(), |j| !self.draft.warp_over(i, j));
        DVec3::new(x, y, z)
    }

    /// Height at crossing coordinate `t` (crossing `k` at `t = k`, `n` crossings per period),
    /// `on_top(k)` telling whether the yarn is the upper one at crossing `k` in `0..n`.
    fn crimp_height(&self, t: f64, n: usize, on_top: impl Fn(usize) -> bool) -> f64 {
        let k = t.floor();
        let f = t - k;
        let k0 = (k as i64).rem_euclid(n as i64) as usize;
        let z = |k: usize| if on_top(k % n) { self.crimp } else { -self.crimp };
        let (z0, z1) = (z(k0), z(k0 + 1));
        z0 + (z1 - z0) * 0.5 * (1.0 - (std::f64::consts::PI * f).cos())
    }

    /// Builds the exemplar over the repeat of [`Self::over_colour_repeat`] (yarns in parallel;
    /// the result does not depend on thread count).
    pub fn build(&self) -> Result<Exemplar, ParamError> {
        self.validate()?;
        let fabric = self.over_colour_repeat()?;
        fabric.build_repeat()
    }

    /// Builds the exemplar of exactly this draft.
    fn build_repeat(&self) -> Result<Exemplar, ParamError> {
        let (rows, cols) = (self.draft.rows(), self.draft.cols());
        let period = self.period();
        let per_yarn: Vec<Result<Vec<super::Fiber>, ParamError>> = (0..cols + rows)
            .into_par_iter()
            .map(|y| {
                if y < cols {
                    let center = move |s: f64| self.warp_center(y, s);
                    let path = YarnPath { center: &center, axis: DVec3::Y, length: period.y };
                    yarn_fibers(&self.warp, &path, y as u32, self.seed)
                } else {
                    let i = y - cols;
                    let center = move |s: f64| self.weft_center(i, s);
                    let path = YarnPath { center: &center, axis: DVec3::X, length: period.x };
                    yarn_fibers(&self.weft, &path, y as u32, self.seed)
                }
            })
            .collect();
        let mut fibers = Vec::new();
        for yarn in per_yarn {
            fibers.extend(yarn?);
        }
        let yarns = (0..cols)
            .map(|j| Yarn { role: YarnRole::Warp, material: self.warp_material_of(j) })
            .chain((0..rows).map(|i| Yarn { role: YarnRole::Weft, material: self.weft_material_of(i) }))
            .collect();
        Ok(Exemplar {
            fibers,
            yarns,
            tiling: Tiling::Periodic { period: Vec2::new(period.x as f32, period.y as f32) },
            blocks: self.blocks,
        })
    }
}

/// Fiber volume over slab volume: the slab is the period rectangle (or, for [`Tiling::AsIs`], the
/// xy extent of the bounds) times the z extent of the bounds. 0 for an empty exemplar.
#[must_use]
pub fn volume_fraction(exemplar: &Exemplar) -> f32 {
    let Some((lo, hi)) = exemplar.bounds() else { return 0.0 };
    let area = match exemplar.tiling {
        Tiling::Periodic { period } => f64::from(period.x) * f64::from(period.y),
        Tiling::AsIs => f64::from(hi.x - lo.x) * f64::from(hi.y - lo.y),
    };
    let slab = area * f64::from(hi.z - lo.z);
    let fiber_volume: f64 = exemplar
        .fibers
        .iter()
        .map(|f| {
            let length: f64 = f.points.windows(2).map(|p| f64::from((p[1] - p[0]).length())).sum();
            std::f64::consts::PI * f64::from(f.radius).powi(2) * length
        })
        .sum();
    if slab > 0.0 { (fiber_volume / slab) as f32 } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fabric::weave::WeavePreset;

    fn small(preset: WeavePreset) -> WovenFabric {
        let yarn = YarnParams { fibers_per_ply: 12, ..YarnParams::default() };
        WovenFabric::new(preset.draft(), 0.035, 0.035, yarn, yarn)
    }

    #[test]
    fn crossings_follow_the_draft_with_enough_separation() {
        for preset in WeavePreset::ALL {
            let f = small(preset);
            let min_gap = 0.5 * 0.5 * (f.warp.height + f.weft.height);
            for i in 0..f.draft.rows() {
                for j in 0..f.draft.cols() {
                    let x = (j as f64 + 0.5) * f.spacing_warp;
                    let y = (i as f64 + 0.5) * f.spacing_weft;
                    let warp = f.warp_center(j, y);
                    let weft = f.weft_center(i, x);
                    assert!((warp.truncate() - weft.truncate()).length() < 1e-12);
                    let gap = if f.draft.warp_over(i, j) { warp.z - weft.z } else { weft.z - warp.z };
                    assert!(gap >= min_gap, "{preset:?} ({i}, {j}): gap {gap} < {min_gap}");
                }
            }
        }
    }

    #[test]
    fn fibers_at_a_crossing_lie_on_the_right_side() {
        let f = small(WeavePreset::Twill2_2);
        let ex = f.build().unwrap();
        let cols = f.draft.cols();
        for i in 0..f.draft.rows() {
            for j in 0..cols {
                let (x, y) = ((j as f64 + 0.5) * f.spacing_warp, (i as f64 + 0.5) * f.spacing_weft);
                let near = |yarn: usize| {
                    let zs: Vec<f32> = ex
                        .fibers
                        .iter()
                        .filter(|fib| fib.yarn as usize == yarn)
                        .flat_map(|fib| fib.points.iter())
                        .filter(|p| (f64::from(p.x) - x).abs() < 0.005 && (f64::from(p.y) - y).abs() < 0.005)
                        .map(|p| p.z)
                        .collect();
                    assert!(!zs.is_empty());
                    zs.iter().sum::<f32>() / zs.len() as f32
                };
                let (warp_z, weft_z) = (near(j), near(cols + i));
                assert_eq!(warp_z > weft_z, f.draft.warp_over(i, j), "crossing ({i}, {j})");
            }
        }
    }

    #[test]
    fn exemplar_is_periodic_with_roles_and_materials() {
        let f = WovenFabric { blocks: BlockGrid { nx: 2, ny: 3 }, ..small(WeavePreset::Satin4_1) };
        let ex = f.build().unwrap();
        let period = f.period();
        assert_eq!(ex.tiling, Tiling::Periodic { period: Vec2::new(0.175, 0.175) });
        assert_eq!(ex.blocks, BlockGrid { nx: 2, ny: 3 });
        assert_eq!(ex.yarns.len(), 10);
        assert_eq!(ex.yarns[0], Yarn { role: YarnRole::Warp, material: 0 });
        assert_eq!(ex.yarns[9], Yarn { role: YarnRole::Weft, material: 1 });
        for fiber in &ex.fibers {
            let axis =
                if (fiber.yarn as usize) < 5 { DVec2::new(0.0, period.y) } else { DVec2::new(period.x, 0.0) };
            let step = *fiber.points.last().unwrap() - fiber.points[0];
            assert!((f64::from(step.x) - axis.x).abs() < 1e-5 && (f64::from(step.y) - axis.y).abs() < 1e-5);
            assert!(step.z.abs() < 1e-5);
        }
        assert_eq!(ex, f.build().unwrap(), "reproducible");
        let vf = volume_fraction(&ex);
        assert!(vf > 0.02 && vf < 0.6, "volume fraction {vf}");
    }

    #[test]
    fn rejects_crimp_that_lets_yarns_pass_through() {
        let f = WovenFabric { crimp: 0.001, ..small(WeavePreset::Plain) };
        let e = f.build().unwrap_err();
        assert_eq!(e.name, "crimp");
        let f = WovenFabric { spacing_warp: 0.001, ..small(WeavePreset::Plain) };
        assert_eq!(f.validate().unwrap_err().name, "spacing_warp");
    }
}
