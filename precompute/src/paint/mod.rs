//! Albedo painting at path-traced quality: Hašan & Ramamoorthy 2013 on fiber cloth.
//!
//! For a fixed view and lights, a designer paints colours onto yarns and sees the path-traced
//! picture of the painted cloth at once. The paintable colour of a yarn is the colour of its TT
//! events (a fiber's C_TT; a Lambertian yarn's albedo), per [cell](cells): one crossing-long
//! section of one thread of the swatch. A pixel of the cloth is then
//! `I(α) = ∫ a(x̄) Π_j α_j^(b_j(x̄)) dμ(x̄)`, `b_j` counting the path's TT events in cell j.
//!
//! [`precompute`] traces colour-free camera paths ([`walk`]: sampled without the colours, so
//! one path serves every painting and the gradient is unbiased) and keeps, per pixel and
//! channel:
//! - the **homogeneous curve** `I_h(α)`, every cell at α, as its values and slopes at
//!   [`CURVE_ALBEDOS`] (denser toward 1, where long paths make it steep): each path adds
//!   `a α^B` and `a B α^(B−1)` at every grid albedo (`B = Σ b_j`), so one set of paths gives
//!   the whole curve;
//! - the **weights** `W`: the gradient `∂I/∂α_j = Σ a b_j α0^(B−1)` at the expansion point
//!   α0 = [`EXPANSION_ALBEDO`] (the event-counting estimator, from the first `gradient_spp`
//!   paths), normalized to sum to 1, stored sparsely (a path touches a few cells).
//!
//! Beyond the paper, a path whose TT events all lie in **one cell** is a function of that
//! cell's colour alone: per pixel, the [`PURE_CELLS_PER_PIXEL`] strongest such cells keep
//! their own exact curve, and only the other paths (through several cells, or through the
//! weaker single cells) form the mixed class that the curve `I_h` and the weights `W` above
//! describe. A fiber pixel is mostly light scattered in the cell it sees (single scattering,
//! and multiple scattering within one crossing of its yarn): measured on the default twill,
//! this cut the error against the very paths it was computed from from 5–35% to 4–8%
//! (relative L2; stripes, a check, random cells, one highlighted yarn).
//!
//! [`PaintData::evaluate`] is then Theorem 1 for the mixed class plus the exact curves:
//! `J(α) = I_mixed(W α) + Σ_c I_c(α_c)` per pixel and channel, every curve read by cubic
//! Hermite interpolation; exact for homogeneous paintings, with the true gradient at α0. [`PaintData::save`]/[`PaintData::load`] keep it in a checksummed file,
//! [`Painting`] reads the designer's strokes, and [`PaintedMaterials`] gives the path tracer a
//! painted cloth to check against.

mod cells;
mod commit;
mod file;
mod keys;
mod painting;
#[cfg(test)]
mod tests;
mod walk;

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use rand::Rng;
use rayon::prelude::*;

pub use cells::{CellsError, MAX_CELLS, PaintCells, ThreadSet};
pub use commit::{CommittedOrder, CommittedOrders, NotAColourOrder, commit_colour_orders};
pub use file::PaintFileError;
pub use keys::SceneKeys;
pub use painting::{Painting, PaintingError, Stroke};

use crate::Rgb;
use crate::bcsdf::Material;
use crate::image::{Film, Image, PixelRow};
use crate::params::{ParamError, check_count, check_range};
use crate::pathtrace::integrator::pixel_rng;
use crate::pathtrace::{Camera, PathScene};

/// The albedos at which the homogeneous curve is kept (value and slope), denser toward 1.
pub const CURVE_ALBEDOS: [f64; 11] = [0.0, 0.2, 0.4, 0.55, 0.68, 0.78, 0.86, 0.92, 0.96, 0.985, 1.0];
/// Most single-cell classes kept exactly per pixel (the rest join the mixed class).
pub const PURE_CELLS_PER_PIXEL: usize = 4;
/// The expansion point α0 of the weights (Hašan & Ramamoorthy use 0.772).
pub const EXPANSION_ALBEDO: f64 = 0.78;
const EXPANSION_INDEX: usize = 5;
const POINTS: usize = CURVE_ALBEDOS.len();

/// How much to trace.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct PaintSettings {
    pub width: u32,
    pub height: u32,
    /// Paths per pixel for the homogeneous curves.
    pub curve_spp: u32,
    /// Of those, the first this many also give the weights (their storage grows with it).
    pub gradient_spp: u32,
    /// Most scattering events on a path.
    pub max_depth: u32,
    pub seed: u64,
}

impl PaintSettings {
    pub fn validate(&self) -> Result<(), ParamError> {
        check_count("width", self.width as usize, 1, 4096)?;
        check_count("height", self.height as usize, 1, 4096)?;
        check_count("curve_spp", self.curve_spp as usize, 1, 1 << 20)?;
        check_count("gradient_spp", self.gradient_spp as usize, 1, self.curve_spp as usize)?;
        check_count("max_depth", self.max_depth as usize, 1, 10_000)?;
        Ok(())
    }
}

/// What a painting needs of a fixed view and lights ([module docs](self)).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PaintData {
    pub settings: PaintSettings,
    pub cells: PaintCells,
    /// Each cell's colour in the scene as precomputed (what an unpainted cell keeps).
    pub scene_colours: Vec<[f32; 3]>,
    /// Per pixel, per grid albedo: the mixed class's `I_h` and its slope
    /// (`[pixel * POINTS + k]`).
    curve_values: Vec<[f32; 3]>,
    curve_slopes: Vec<[f32; 3]>,
    /// The single-cell classes, pixel by pixel: `pure_rows[p]..pure_rows[p + 1]` index
    /// `pure_cells`, and entry e's curve is `pure_values[e * POINTS..]` (and slopes).
    pure_rows: Vec<u32>,
    pure_cells: Vec<u32>,
    pure_values: Vec<[f32; 3]>,
    pure_slopes: Vec<[f32; 3]>,
    /// Per pixel, per grid albedo: the standard error of `I_h` (from the spread of its paths).
    curve_errors: Vec<[f32; 3]>,
    /// The weights, row by row (a row per pixel): `rows[p]..rows[p + 1]` index `weight_cells`
    /// and `weights`; each row's weights sum to 1 per channel (or are all zero).
    rows: Vec<u32>,
    weight_cells: Vec<u32>,
    weights: Vec<[f32; 3]>,
    /// Seconds the precompute took (curves and weights together).
    pub seconds: f64,
    /// What the paths were traced in, when the caller knew the scene file
    /// ([`SceneKeys::of`]; `twill paint precompute` records them, `verify` and `commit`
    /// check them).
    pub scene_keys: Option<SceneKeys>,
    /// The scene's display exposure (stops) when the caller knew it: what `twill paint apply`
    /// writes PNGs with unless told otherwise.
    pub exposure: Option<f64>,
}

/// Why a painting cannot be precomputed.
#[derive(Debug, thiserror::Error)]
pub enum PaintError {
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error(transparent)]
    Cells(#[from] CellsError),
    #[error("the camera is {camera_w}x{camera_h}; the settings say {width}x{height}")]
    CameraSize { camera_w: usize, camera_h: usize, width: u32, height: u32 },
    #[error("a painted scene cannot be precomputed: paint the precomputed data instead")]
    AlreadyPainted,
    #[error("the painting precompute was cancelled")]
    Cancelled,
}

/// A curve's sums over a pixel's paths: `Σ a α_k^B` and `Σ a B α_k^(B−1)` at every grid albedo.
#[derive(Clone, Copy)]
struct CurveSums {
    values: [Rgb; POINTS],
    slopes: [Rgb; POINTS],
}

impl CurveSums {
    const ZERO: Self = Self { values: [Rgb::ZERO; POINTS], slopes: [Rgb::ZERO; POINTS] };

    fn add(&mut self, value: Rgb, b: u32) {
        for (k, &alpha) in CURVE_ALBEDOS.iter().enumerate() {
            self.values[k] += value * power(alpha, b);
            if b > 0 {
                self.slopes[k] += value * (f64::from(b) * power(alpha, b - 1));
            }
        }
    }

    fn merge(&mut self, other: &Self) {
        for k in 0..POINTS {
            self.values[k] += other.values[k];
            self.slopes[k] += other.slopes[k];
        }
    }
}

/// One pixel's accumulation: the mixed class with its gradient, the single-cell classes, and
/// the squares of every path's whole estimate (for the standard error).
struct PixelSums {
    mixed: CurveSums,
    gradient: Vec<(u32, Rgb)>,
    pure: Vec<(u32, CurveSums)>,
    squares: [Rgb; POINTS],
}

/// One pixel's result.
struct PixelResult {
    values: [[f32; 3]; POINTS],
    slopes: [[f32; 3]; POINTS],
    errors: [[f32; 3]; POINTS],
    weights: Vec<(u32, [f32; 3])>,
    /// `(cell, values, slopes)` of each kept single-cell class.
    pure: Vec<(u32, Curve, Curve)>,
}

/// A curve's values (or slopes) at [`CURVE_ALBEDOS`], per channel.
type Curve = [[f32; 3]; POINTS];

fn f32s(v: Rgb) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

fn rgb(v: [f32; 3]) -> Rgb {
    Rgb::new(v[0].into(), v[1].into(), v[2].into())
}

/// Traces the colour-free paths of every pixel and keeps the curves and weights; `cells` are
/// the scene's ([`PaintCells::new`]); `progress` is called with the rows done.
pub fn precompute(
    scene: &PathScene,
    cells: PaintCells,
    camera: &Camera,
    settings: &PaintSettings,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<PaintData, PaintError> {
    precompute_cancellable(scene, cells, camera, settings, progress, &AtomicBool::new(false))
}

/// [`precompute`] that stops early with [`PaintError::Cancelled`] once `cancel` is set (rows
/// already started finish first; the viewer's paint mode sets it when the designer leaves).
pub fn precompute_cancellable(
    scene: &PathScene,
    cells: PaintCells,
    camera: &Camera,
    settings: &PaintSettings,
    progress: &(dyn Fn(usize) + Sync),
    cancel: &AtomicBool,
) -> Result<PaintData, PaintError> {
    settings.validate()?;
    if scene.painted.is_some() {
        return Err(PaintError::AlreadyPainted);
    }
    let (w, h) = (settings.width as usize, settings.height as usize);
    if (camera.width(), camera.height()) != (w, h) {
        return Err(PaintError::CameraSize {
            camera_w: camera.width(),
            camera_h: camera.height(),
            width: settings.width,
            height: settings.height,
        });
    }
    let started = std::time::Instant::now();
    let scene_colours = scene_colours(scene, &cells).into_iter().map(f32s).collect();
    let rows_done = AtomicUsize::new(0);
    let rows: Vec<Vec<PixelResult>> = (0..h)
        .into_par_iter()
        .map(|y| {
            if cancel.load(Ordering::Relaxed) {
                return Vec::new();
            }
            let row = (0..w).map(|x| trace_pixel(scene, &cells, camera, settings, x, y)).collect();
            progress(rows_done.fetch_add(1, Ordering::Relaxed) + 1);
            row
        })
        .collect();
    if cancel.load(Ordering::Relaxed) {
        return Err(PaintError::Cancelled);
    }
    let mut data = PaintData {
        settings: *settings,
        cells,
        scene_colours,
        curve_values: Vec::with_capacity(w * h * POINTS),
        curve_slopes: Vec::with_capacity(w * h * POINTS),
        curve_errors: Vec::with_capacity(w * h * POINTS),
        pure_rows: Vec::with_capacity(w * h + 1),
        pure_cells: Vec::new(),
        pure_values: Vec::new(),
        pure_slopes: Vec::new(),
        rows: Vec::with_capacity(w * h + 1),
        weight_cells: Vec::new(),
        weights: Vec::new(),
        seconds: 0.0,
        scene_keys: None,
        exposure: None,
    };
    data.rows.push(0);
    data.pure_rows.push(0);
    for pixel in rows.into_iter().flatten() {
        for (cell, values, slopes) in pixel.pure {
            data.pure_cells.push(cell);
            data.pure_values.extend_from_slice(&values);
            data.pure_slopes.extend_from_slice(&slopes);
        }
        data.pure_rows.push(data.pure_cells.len() as u32);
        data.curve_values.extend_from_slice(&pixel.values);
        data.curve_slopes.extend_from_slice(&pixel.slopes);
        data.curve_errors.extend_from_slice(&pixel.errors);
        for (cell, weight) in pixel.weights {
            data.weight_cells.push(cell);
            data.weights.push(weight);
        }
        data.rows.push(data.weight_cells.len() as u32);
    }
    data.seconds = started.elapsed().as_secs_f64();
    Ok(data)
}

fn trace_pixel(
    scene: &PathScene,
    cells: &PaintCells,
    camera: &Camera,
    settings: &PaintSettings,
    x: usize,
    y: usize,
) -> PixelResult {
    let mut sums = PixelSums {
        mixed: CurveSums::ZERO,
        gradient: Vec::new(),
        pure: Vec::new(),
        squares: [Rgb::ZERO; POINTS],
    };
    let mut path_values = [Rgb::ZERO; POINTS];
    pixel_paths(scene, cells, camera, settings, x, y, |sample, walk_path| {
        let with_gradient = sample < settings.gradient_spp;
        path_values.fill(Rgb::ZERO);
        walk_path(&mut |c| {
            let b = c.tt_events;
            for (k, &alpha) in CURVE_ALBEDOS.iter().enumerate() {
                path_values[k] += c.value * power(alpha, b);
            }
            // A path whose TT events all lie in one cell is a curve of that cell's colour
            // alone: kept exactly (up to PURE_CELLS_PER_PIXEL cells per pixel).
            if let [(cell, _)] = c.cells {
                if let Some((_, curve)) = sums.pure.iter_mut().find(|(p, _)| p == cell) {
                    curve.add(c.value, b);
                } else {
                    let mut curve = CurveSums::ZERO;
                    curve.add(c.value, b);
                    sums.pure.push((*cell, curve));
                }
                return;
            }
            sums.mixed.add(c.value, b);
            if with_gradient && b > 0 {
                let base = c.value * power(EXPANSION_ALBEDO, b - 1);
                for &(cell, count) in c.cells {
                    sums.gradient.push((cell, base * f64::from(count)));
                }
            }
        });
        for (k, v) in path_values.iter().enumerate() {
            sums.squares[k] += *v * *v;
        }
    });
    finish_pixel(sums, settings)
}

/// Walks the `curve_spp` colour-free paths of pixel (x, y): for each, `path` gets its index and
/// a walk to hand the path's terms to. The one place a pixel's paths come from, so the
/// precompute and [`render_painted_paths`] trace the very same paths for a seed.
fn pixel_paths(
    scene: &PathScene,
    cells: &PaintCells,
    camera: &Camera,
    settings: &PaintSettings,
    x: usize,
    y: usize,
    mut path: impl FnMut(u32, &mut dyn FnMut(&mut dyn FnMut(&walk::Contribution<'_>))),
) {
    let mut rng = pixel_rng(settings.seed, (y * settings.width as usize + x) as u64);
    for sample in 0..settings.curve_spp {
        let (px, py) = (x as f64 + rng.random::<f64>(), y as f64 + rng.random::<f64>());
        let (origin, dir) = camera.ray(px, py);
        path(sample, &mut |add| walk::walk(scene, cells, origin, dir, settings.max_depth, &mut rng, add));
    }
}

/// `a^b` with `0^0 = 1`.
fn power(a: f64, b: u32) -> f64 {
    a.powi(b.min(i32::MAX as u32) as i32)
}

fn finish_pixel(mut sums: PixelSums, settings: &PaintSettings) -> PixelResult {
    let n = f64::from(settings.curve_spp);
    let g = f64::from(settings.gradient_spp);
    let mut result = PixelResult {
        values: [[0.0; 3]; POINTS],
        slopes: [[0.0; 3]; POINTS],
        errors: [[0.0; 3]; POINTS],
        weights: Vec::new(),
        pure: Vec::new(),
    };
    // Keep the strongest single-cell classes; the rest join the mixed class with their
    // gradient (all of it on their one cell: the curve's slope at α0, from every path, so
    // scaled to the gradient's path count).
    let strength = |c: &CurveSums| c.values[EXPANSION_INDEX].element_sum();
    sums.pure.sort_by(|a, b| strength(&b.1).total_cmp(&strength(&a.1)).then(a.0.cmp(&b.0)));
    let mut total = sums.mixed;
    for (i, (cell, curve)) in sums.pure.iter().enumerate() {
        total.merge(curve);
        if i < PURE_CELLS_PER_PIXEL {
            let scaled = |v: &[Rgb; POINTS]| v.map(|x| f32s(x / n));
            result.pure.push((*cell, scaled(&curve.values), scaled(&curve.slopes)));
        } else {
            sums.mixed.merge(curve);
            sums.gradient.push((*cell, curve.slopes[EXPANSION_INDEX] * (g / n)));
        }
    }
    for k in 0..POINTS {
        result.values[k] = f32s(sums.mixed.values[k] / n);
        result.slopes[k] = f32s(sums.mixed.slopes[k] / n);
        let mean = total.values[k] / n;
        let variance = (sums.squares[k] / n - mean * mean).max(Rgb::ZERO) / (n - 1.0).max(1.0);
        result.errors[k] = f32s(Rgb::new(variance.x.sqrt(), variance.y.sqrt(), variance.z.sqrt()));
    }
    sums.gradient.sort_unstable_by_key(|&(cell, _)| cell);
    let mut merged: Vec<(u32, Rgb)> = Vec::new();
    for (cell, g) in sums.gradient {
        match merged.last_mut() {
            Some((c, sum)) if *c == cell => *sum += g,
            _ => merged.push((cell, g)),
        }
    }
    let total = merged.iter().fold(Rgb::ZERO, |acc, (_, g)| acc + *g);
    let inverse = |t: f64| if t > 0.0 { 1.0 / t } else { 0.0 };
    let scale = Rgb::new(inverse(total.x), inverse(total.y), inverse(total.z));
    result.weights = merged.into_iter().map(|(cell, g)| (cell, f32s(g * scale))).collect();
    result
}

/// Cubic Hermite interpolation of `(CURVE_ALBEDOS, values, slopes)` at `a` in [0, 1].
fn hermite(values: &[[f32; 3]], slopes: &[[f32; 3]], channel: usize, a: f64) -> f64 {
    let a = a.clamp(0.0, 1.0);
    let k = CURVE_ALBEDOS.partition_point(|&x| x <= a).clamp(1, POINTS - 1) - 1;
    let (x0, x1) = (CURVE_ALBEDOS[k], CURVE_ALBEDOS[k + 1]);
    let h = x1 - x0;
    let t = (a - x0) / h;
    let (t2, t3) = (t * t, t * t * t);
    let v = |i: usize| f64::from(values[i][channel]);
    let d = |i: usize| f64::from(slopes[i][channel]);
    (2.0 * t3 - 3.0 * t2 + 1.0) * v(k)
        + (t3 - 2.0 * t2 + t) * h * d(k)
        + (-2.0 * t3 + 3.0 * t2) * v(k + 1)
        + (t3 - t2) * h * d(k + 1)
}

impl PaintData {
    /// Checks that the parts fit together (what a decoded file must pass before it is used).
    fn check(&self) -> Result<(), String> {
        self.settings.validate().map_err(|e| format!("settings: {e}"))?;
        self.cells.check()?;
        let (w, h) = self.size();
        let pixels = w * h;
        let cells = self.cells.count();
        let sized = |name: &str, len: usize, want: usize| {
            if len == want { Ok(()) } else { Err(format!("{name} holds {len} entries where {want} belong")) }
        };
        sized("curve_values", self.curve_values.len(), pixels * POINTS)?;
        sized("curve_slopes", self.curve_slopes.len(), pixels * POINTS)?;
        sized("curve_errors", self.curve_errors.len(), pixels * POINTS)?;
        // Both sparse structures: a row per pixel, in order, indexing cells of the swatch.
        let sparse = |name: &str, rows: &[u32], entry_cells: &[u32]| {
            sized(name, rows.len(), pixels + 1)?;
            if rows[0] != 0 || rows.windows(2).any(|r| r[0] > r[1]) {
                return Err(format!("{name} are not in order"));
            }
            sized(name, entry_cells.len(), rows[pixels] as usize)?;
            match entry_cells.iter().find(|&&c| c as usize >= cells) {
                Some(c) => Err(format!("{name}: an entry of cell {c}; the swatch has {cells} cells")),
                None => Ok(()),
            }
        };
        sparse("pure_rows", &self.pure_rows, &self.pure_cells)?;
        sized("pure_values", self.pure_values.len(), self.pure_cells.len() * POINTS)?;
        sized("pure_slopes", self.pure_slopes.len(), self.pure_cells.len() * POINTS)?;
        sparse("rows", &self.rows, &self.weight_cells)?;
        sized("weights", self.weights.len(), self.weight_cells.len())?;
        sized("scene_colours", self.scene_colours.len(), cells)?;
        let finite = |v: &[f32; 3]| v.iter().all(|x| x.is_finite());
        for (name, values) in [
            ("curve_values", &self.curve_values),
            ("curve_slopes", &self.curve_slopes),
            ("curve_errors", &self.curve_errors),
            ("weights", &self.weights),
            ("pure_values", &self.pure_values),
            ("pure_slopes", &self.pure_slopes),
            ("scene_colours", &self.scene_colours),
        ] {
            if let Some(i) = values.iter().position(|v| !finite(v)) {
                return Err(format!("{name}[{i}] is {:?}", values[i]));
            }
        }
        Ok(())
    }

    /// Image size.
    #[must_use]
    pub fn size(&self) -> (usize, usize) {
        (self.settings.width as usize, self.settings.height as usize)
    }

    /// Number of stored weights (nonzero entries of W).
    #[must_use]
    pub fn weight_count(&self) -> usize {
        self.weights.len()
    }

    /// Bytes the curves and weights take in memory.
    #[must_use]
    pub fn bytes(&self) -> usize {
        12 * (self.curve_values.len()
            + self.curve_slopes.len()
            + self.pure_values.len()
            + self.pure_slopes.len()
            + self.curve_errors.len()
            + self.weights.len())
            + 4 * (self.rows.len() + self.weight_cells.len() + self.pure_rows.len() + self.pure_cells.len())
    }

    /// The scene's own colours, one per cell (an unpainted cloth).
    #[must_use]
    pub fn scene_painting(&self) -> Vec<Rgb> {
        self.scene_colours.iter().copied().map(rgb).collect()
    }

    /// Theorem 1 at cell colours `colours` (one per cell, each channel in [0, 1]): per pixel
    /// and channel, `I_h(Σ_j W_j α_j)`.
    ///
    /// # Panics
    /// If `colours` does not hold one colour per cell.
    #[must_use]
    pub fn evaluate(&self, colours: &[Rgb]) -> Image {
        assert_eq!(colours.len(), self.cells.count(), "one colour per paint cell");
        let (w, h) = self.size();
        let pixels: Vec<Rgb> = (0..w * h)
            .into_par_iter()
            .map(|p| {
                let curve = |values: &[[f32; 3]], slopes: &[[f32; 3]], a: Rgb| {
                    Rgb::new(
                        hermite(values, slopes, 0, a.x),
                        hermite(values, slopes, 1, a.y),
                        hermite(values, slopes, 2, a.z),
                    )
                };
                let at = p * POINTS..(p + 1) * POINTS;
                let mut value = curve(
                    &self.curve_values[at.clone()],
                    &self.curve_slopes[at],
                    self.local_albedo(p, colours),
                );
                for e in self.pure_rows[p] as usize..self.pure_rows[p + 1] as usize {
                    let at = e * POINTS..(e + 1) * POINTS;
                    let colour = colours[self.pure_cells[e] as usize];
                    value += curve(&self.pure_values[at.clone()], &self.pure_slopes[at], colour);
                }
                value
            })
            .collect();
        let mut image = Image::new(w, h);
        image.pixels = pixels;
        image
    }

    /// Step R1 of every pixel ([`Self::evaluate`] before the curves): the blended albedo per
    /// channel, as an image.
    #[must_use]
    pub fn local_albedos(&self, colours: &[Rgb]) -> Image {
        let (w, h) = self.size();
        let mut image = Image::new(w, h);
        image.pixels = (0..w * h).map(|p| self.local_albedo(p, colours)).collect();
        image
    }

    /// Step R1 of the paper: the pixel's blend `W α` of the cell colours (α0 where the pixel
    /// has no weights: no TT event reached it, and its curve is flat).
    fn local_albedo(&self, pixel: usize, colours: &[Rgb]) -> Rgb {
        let (lo, hi) = (self.rows[pixel] as usize, self.rows[pixel + 1] as usize);
        let mut blend = Rgb::ZERO;
        let mut total = Rgb::ZERO;
        for (&cell, w) in self.weight_cells[lo..hi].iter().zip(&self.weights[lo..hi]) {
            let w = rgb(*w);
            blend += w * colours[cell as usize];
            total += w;
        }
        let pick = |b: f64, t: f64| if t > 0.5 { b / t } else { EXPANSION_ALBEDO };
        Rgb::new(pick(blend.x, total.x), pick(blend.y, total.y), pick(blend.z, total.z))
    }

    /// The homogeneous curve at grid albedo `k` ([`CURVE_ALBEDOS`]) as an image, with its
    /// standard error per pixel.
    #[must_use]
    pub fn curve_image(&self, k: usize) -> (Image, Image) {
        let (w, h) = self.size();
        let mut value = Image::new(w, h);
        let mut error = Image::new(w, h);
        for p in 0..w * h {
            let mut v = rgb(self.curve_values[p * POINTS + k]);
            for e in self.pure_rows[p] as usize..self.pure_rows[p + 1] as usize {
                v += rgb(self.pure_values[e * POINTS + k]);
            }
            value.pixels[p] = v;
            error.pixels[p] = rgb(self.curve_errors[p * POINTS + k]);
        }
        (value, error)
    }

    /// `∂I/∂α_j` at α0 summed over the pixels of `pixels` and the cells of `of`: the weights
    /// times the curve's slope at α0 (for checks against finite differences).
    #[must_use]
    pub fn gradient_sum(&self, pixels: &[usize], of: &[u32]) -> Rgb {
        let mut sum = Rgb::ZERO;
        for &p in pixels {
            for e in self.pure_rows[p] as usize..self.pure_rows[p + 1] as usize {
                if of.contains(&self.pure_cells[e]) {
                    sum += rgb(self.pure_slopes[e * POINTS + EXPANSION_INDEX]);
                }
            }
            let slope = rgb(self.curve_slopes[p * POINTS + EXPANSION_INDEX]);
            let (lo, hi) = (self.rows[p] as usize, self.rows[p + 1] as usize);
            for (&cell, w) in self.weight_cells[lo..hi].iter().zip(&self.weights[lo..hi]) {
                if of.contains(&cell) {
                    sum += slope * rgb(*w);
                }
            }
        }
        sum
    }
}

/// The cell seen through film position (`px`, `py`) of `camera` (pixel units, as
/// [`Camera::ray`] takes them): the first fiber the eye ray meets above the ground, as the
/// path tracer finds it; `None` where it meets none. `cells` must be the scene's.
#[must_use]
pub fn cell_at(scene: &PathScene, cells: &PaintCells, camera: &Camera, px: f64, py: f64) -> Option<u32> {
    let (origin, dir) = camera.ray(px, py);
    let hit = crate::pathtrace::integrator::trace(scene, origin, dir, None)?;
    Some(cells.cell_of(&hit))
}

/// Each cell's colour in `scene` as it is (its yarn material's paintable colour).
#[must_use]
pub fn scene_colours(scene: &PathScene, cells: &PaintCells) -> Vec<Rgb> {
    cells.yarn_of_cells().iter().map(|&y| scene.yarn_materials[y as usize].paint_colour()).collect()
}

/// Renders the cloth at cell colours `colours` with the colour-free paths themselves: every
/// path's terms evaluated exactly at those colours. With the precompute's seed and
/// `curve_spp` these are the very paths its curves came from, so this is what Theorem 1
/// approximates, free of the paths' noise; with another seed, an unbiased path-traced image.
pub fn render_painted_paths(
    scene: &PathScene,
    cells: &PaintCells,
    camera: &Camera,
    settings: &PaintSettings,
    colours: &[Rgb],
) -> Result<Film, PaintError> {
    settings.validate()?;
    check_count("colours", colours.len(), cells.count(), cells.count())?;
    let (w, h) = (camera.width(), camera.height());
    let rows: Vec<PixelRow> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut row = PixelRow::new(w);
            for x in 0..w {
                pixel_paths(scene, cells, camera, settings, x, y, |_, walk_path| {
                    let mut total = Rgb::ZERO;
                    walk_path(&mut |c| total += c.at(colours));
                    row.add(x, total);
                });
            }
            row
        })
        .collect();
    let mut film = Film::new(w, h);
    for (y, row) in rows.iter().enumerate() {
        film.set_row(y, row);
    }
    Ok(film)
}

/// A painted cloth for the path tracer ([`PathScene::painted`]): each cell's material is its
/// yarn's with the cell's colour.
#[derive(Debug, Clone)]
pub struct PaintedMaterials {
    pub cells: PaintCells,
    pub materials: Vec<Material>,
    /// Index into `materials` per cell.
    pub of_cell: Vec<u32>,
}

impl PaintedMaterials {
    /// The cloth of `scene` painted with `colours` (one per cell of `cells`, which must be the
    /// scene's). Materials are shared between cells of one yarn and colour.
    pub fn new(scene: &PathScene, cells: PaintCells, colours: &[Rgb]) -> Result<Self, ParamError> {
        check_count("colours", colours.len(), cells.count(), cells.count())?;
        let mut materials = Vec::new();
        let mut index = std::collections::HashMap::new();
        let mut of_cell = Vec::with_capacity(colours.len());
        for (cell, yarn) in cells.yarn_of_cells().into_iter().enumerate() {
            let c = colours[cell];
            for v in [c.x, c.y, c.z] {
                check_range("paint colour", v, 0.0, 1.0)?;
            }
            let key = (yarn, c.x.to_bits(), c.y.to_bits(), c.z.to_bits());
            let i = if let Some(&i) = index.get(&key) {
                i
            } else {
                materials.push(scene.yarn_materials[yarn as usize].with_paint_colour(c)?);
                index.insert(key, materials.len() as u32 - 1);
                materials.len() as u32 - 1
            };
            of_cell.push(i);
        }
        Ok(Self { cells, materials, of_cell })
    }
}
