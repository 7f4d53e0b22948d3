//! Segment visibility functions (paper section 4.1): one binary visibility image per fiber
//! segment, over the (θ, φ) parameterization of the sphere.
//!
//! How it works:
//! - **Parameterization** (the GPU side indexes images the same way): an image has `n` rows by
//!   `n` columns, `n` = `svf_resolution`. Row `i` covers polar angles `[iπ/n, (i+1)π/n]` from
//!   +z, column `j` azimuths `[j 2π/n, (j+1) 2π/n]` measured from +x toward +y. The pixel's
//!   direction is its centre, `θ_i = (i + 0.5)π/n`, `φ_j = (j + 0.5)2π/n` ([`pixel_direction`]).
//!   Its solid angle is exact: `(2π/n)(cos θ_top − cos θ_bottom)` ([`pixel_solid_angle`]), so the
//!   pixels of an image add up to 4π. Pixel `p = i n + j` (row-major).
//! - **Visibility**: `V_k(ω) = 1` iff the infinite ray toward `ω` from `o_k = μ_k + (2/π) r_k
//!   û_k` ([`visibility_origin`]: the segment midpoint `μ_k` raised across the fiber toward
//!   the fabric's normal, `û_k` the unit part of +z across the tangent, by the centroid of the
//!   upper half of its cross-section) hits no fiber other than segment `k`'s own fiber (a
//!   fiber never shadows itself). That is the mean position of the points of the fiber an eye
//!   above the fabric sees, where the method's hits lie. The paper casts from `μ_k` itself, on
//!   the fiber axis, where the fiber's touching neighbours hide light that reaches its upper
//!   surface: single scattering of the default scene came out 14% too dark. Rays from the lit
//!   side of the fiber (`μ_k` moved by `r_k` across the fiber toward `ω`, twill's origin until
//!   2026-11-27) fixed that for lights from above, but at raking light the lit side is the
//!   fiber's flank, level with the neighbours it touches: two gabardine views lit 12–13° above
//!   the horizon came out 34% and 26% too dark against shadow rays from the hit point, from
//!   the centroid 12% and 0.5% (`twill accuracy budget`, docs/BENCHMARKS.md "Local visibility
//!   at raking light").
//!   The midpoint is placed in the copy of the exemplar nearest the centre of
//!   the scene ([`FiberScene::central_tile`]); with `Extent::Unbounded` on a periodic exemplar
//!   every copy is interior, so the fabric around the segment is infinite and there are no
//!   boundary effects. `Tiling::AsIs` exemplars are used as they are.
//! - **Points along the segment** (`visibility_points` P): a segment is cut into P equal
//!   pieces and each piece's centre gets its own image, cast from its raised centroid
//!   ([`visibility_point_fraction`]); image `k P + j` is point `j` of segment `k`. A hit shades
//!   with the image of the piece it lies on ([`visibility_point_of`]). Segments run ten fiber
//!   diameters and more; one crossed by a yarn half way is seen only where it is uncovered, and
//!   there the light reaches it too (the eye and a light near it see the same points), while its
//!   midpoint may lie in the shadow: with one image, single scattering of the default cotton
//!   seen and lit head-on was 15.7% too dark against shadow rays from the hit point, with 4
//!   points 6.7% (`twill accuracy budget`, rungs 3 and 3′).
//! - **Storage**: one bit per pixel, each image padded to whole `u64` words
//!   (`ceil(n²/64)` words per segment), bit `p % 64` of word `p / 64`.
//! - Segments are rendered in parallel with rayon; each image depends only on its segment, so
//!   the result is the same for any number of threads.

use std::f64::consts::PI;
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::DVec3;
use rayon::prelude::*;

use super::{Cancel, Cancelled, Progress};
use crate::fabric::Exemplar;
use crate::params::{ParamError, check_count};
use crate::raycast::{Extent, FiberScene, SceneError};

/// Segments rendered between two progress reports.
const PROGRESS_EVERY: usize = 256;

/// Why visibility images could not be rendered.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SvfError {
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error("segment {segment} is out of range (the scene has {count} segments)")]
    NoSuchSegment { segment: u32, count: usize },
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
}

/// Polar angle of the centre of row `row` of an `n`-row image: `(row + 0.5)π/n`.
#[must_use]
pub fn row_theta(n: usize, row: usize) -> f64 {
    (row as f64 + 0.5) * PI / n as f64
}

/// Azimuth of the centre of column `col` of an `n`-column image: `(col + 0.5)2π/n`.
#[must_use]
pub fn col_phi(n: usize, col: usize) -> f64 {
    (col as f64 + 0.5) * 2.0 * PI / n as f64
}

/// Unit direction of the centre of pixel (`row`, `col`) of an `n x n` image.
#[must_use]
pub fn pixel_direction(n: usize, row: usize, col: usize) -> DVec3 {
    let (st, ct) = row_theta(n, row).sin_cos();
    let (sp, cp) = col_phi(n, col).sin_cos();
    DVec3::new(st * cp, st * sp, ct)
}

/// Exact solid angle of any pixel of row `row`: `(2π/n)(cos(row π/n) − cos((row+1)π/n))`.
#[must_use]
pub fn pixel_solid_angle(n: usize, row: usize) -> f64 {
    let top = row as f64 * PI / n as f64;
    let bottom = (row + 1) as f64 * PI / n as f64;
    // cos a − cos b = 2 sin((a+b)/2) sin((b−a)/2), without cancellation near the poles.
    2.0 * PI / n as f64 * 2.0 * (0.5 * (top + bottom)).sin() * (0.5 * (bottom - top)).sin()
}

/// The pixel (`row`, `col`) of an `n x n` image whose cell contains the unit direction `dir`.
#[must_use]
pub fn pixel_of_direction(n: usize, dir: DVec3) -> (usize, usize) {
    let theta = dir.z.clamp(-1.0, 1.0).acos();
    let phi = dir.y.atan2(dir.x).rem_euclid(2.0 * PI);
    let row = ((theta / PI * n as f64) as usize).min(n - 1);
    let col = ((phi / (2.0 * PI) * n as f64) as usize).min(n - 1);
    (row, col)
}

/// How far above a fiber's axis visibility rays start, as a fraction of its radius: `2/π`, the
/// centroid of the upper half of its cross-section ([`visibility_origin`]).
pub const EXPOSED_CENTROID: f64 = std::f64::consts::FRAC_2_PI;

/// Where the visibility rays of a point on a segment (unit tangent `tangent`, fiber radius
/// `radius`) start: the point raised across the fiber toward the fabric's normal (+z) by
/// [`EXPOSED_CENTROID`] times the radius. That is the mean position of the fiber's points an
/// eye above the fabric sees (the upper half of its circumference, projected on the cross
/// section), where the method's hits lie; the fiber never shadows itself, so rays from inside
/// it are not blocked by it. A fiber along z keeps the point.
#[must_use]
pub fn visibility_origin(point: DVec3, tangent: DVec3, radius: f64) -> DVec3 {
    let up = (DVec3::Z - tangent * tangent.z).normalize_or_zero();
    point + up * (EXPOSED_CENTROID * radius)
}

/// Where visibility point `j` of `points` lies along a segment: the centre of piece `j` of
/// `points` equal pieces, as a fraction of the way from `a` to `b`.
#[must_use]
pub fn visibility_point_fraction(j: usize, points: usize) -> f64 {
    (j as f64 + 0.5) / points.max(1) as f64
}

/// The visibility point whose piece holds a point at signed distance `axial` from the
/// segment's midpoint along its tangent, on a segment `2 half_length` long with `points`
/// points: `floor((½ + axial/(2 half_length)) points)`, clamped to the segment (a hit on the
/// round cap beyond an end takes the end's piece). A zero-length segment, or a distance that
/// is not finite, takes the middle piece (the midpoint's).
#[must_use]
pub fn visibility_point_of(axial: f64, half_length: f64, points: usize) -> usize {
    let last = points.max(1) - 1;
    let u = 0.5 + axial / (2.0 * half_length);
    if half_length <= 0.0 || !u.is_finite() {
        return points.max(1) / 2;
    }
    ((u * points as f64).floor().max(0.0) as usize).min(last)
}

/// Binary visibility images of every segment of an exemplar (`points` images per segment,
/// one per visibility point, [`visibility_point_fraction`]); see the module docs for the
/// parameterization and the bit layout.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct VisibilityImages {
    /// `n`: images are `n` rows (θ) by `n` columns (φ).
    pub resolution: usize,
    segment_count: usize,
    words_per_image: usize,
    bits: Vec<u64>,
}

impl VisibilityImages {
    /// All-occluded images for `segment_count` segments.
    #[must_use]
    pub fn new(resolution: usize, segment_count: usize) -> Self {
        let words_per_image = (resolution * resolution).div_ceil(64);
        Self { resolution, segment_count, words_per_image, bits: vec![0; words_per_image * segment_count] }
    }

    #[must_use]
    pub fn segment_count(&self) -> usize {
        self.segment_count
    }

    /// Images from their bits (as [`VisibilityImages::words`] gives them); `None` when the
    /// count of words is not `segment_count` images of `resolution`² bits.
    #[must_use]
    pub fn from_words(resolution: usize, segment_count: usize, bits: Vec<u64>) -> Option<Self> {
        let words_per_image = (resolution * resolution).div_ceil(64);
        (bits.len() == words_per_image * segment_count).then_some(Self {
            resolution,
            segment_count,
            words_per_image,
            bits,
        })
    }

    /// Whether the words are `segment_count` images of `resolution`² bits (what a file read
    /// must check before any lookup).
    #[must_use]
    pub fn is_well_formed(&self) -> bool {
        self.words_per_image == (self.resolution * self.resolution).div_ceil(64)
            && self.bits.len() == self.words_per_image * self.segment_count
    }

    /// The images of `parts`, one after the other; `None` when their resolutions differ.
    #[must_use]
    pub fn concat(parts: &[Self]) -> Option<Self> {
        let resolution = parts.first().map_or(1, |p| p.resolution);
        if parts.iter().any(|p| p.resolution != resolution) {
            return None;
        }
        let bits: Vec<u64> = parts.iter().flat_map(|p| p.bits.iter().copied()).collect();
        Self::from_words(resolution, parts.iter().map(|p| p.segment_count).sum(), bits)
    }

    /// Pixels per image, `n²`.
    #[must_use]
    pub fn pixel_count(&self) -> usize {
        self.resolution * self.resolution
    }

    /// `u64` words per image (`ceil(n²/64)`).
    #[must_use]
    pub fn words_per_image(&self) -> usize {
        self.words_per_image
    }

    /// The packed bits of one image (bit `p % 64` of word `p / 64` is pixel `p`).
    #[must_use]
    pub fn image_words(&self, segment: usize) -> &[u64] {
        &self.bits[segment * self.words_per_image..(segment + 1) * self.words_per_image]
    }

    /// All packed bits, image after image.
    #[must_use]
    pub fn words(&self) -> &[u64] {
        &self.bits
    }

    /// Whether pixel (`row`, `col`) of `segment`'s image is visible.
    #[must_use]
    pub fn get(&self, segment: usize, row: usize, col: usize) -> bool {
        self.get_pixel(segment, row * self.resolution + col)
    }

    /// Whether pixel `pixel` (row-major) of `segment`'s image is visible.
    #[must_use]
    pub fn get_pixel(&self, segment: usize, pixel: usize) -> bool {
        let word = self.bits[segment * self.words_per_image + pixel / 64];
        (word >> (pixel % 64)) & 1 == 1
    }

    /// Sets pixel (`row`, `col`) of `segment`'s image.
    pub fn set(&mut self, segment: usize, row: usize, col: usize, visible: bool) {
        let pixel = row * self.resolution + col;
        let word = &mut self.bits[segment * self.words_per_image + pixel / 64];
        if visible {
            *word |= 1 << (pixel % 64);
        } else {
            *word &= !(1 << (pixel % 64));
        }
    }

    /// Visibility toward `dir` (unit): the pixel whose cell contains it.
    #[must_use]
    pub fn lookup(&self, segment: usize, dir: DVec3) -> bool {
        let (row, col) = pixel_of_direction(self.resolution, dir);
        self.get(segment, row, col)
    }

    /// Total solid angle of the visible pixels of `segment`'s image (steradians, 0 to 4π).
    #[must_use]
    pub fn visible_solid_angle(&self, segment: usize) -> f64 {
        let n = self.resolution;
        (0..n)
            .map(|row| {
                let visible = (0..n).filter(|&col| self.get(segment, row, col)).count();
                visible as f64 * pixel_solid_angle(n, row)
            })
            .sum()
    }

    /// Number of visible pixels of `segment`'s image.
    #[must_use]
    pub fn visible_pixel_count(&self, segment: usize) -> usize {
        self.image_words(segment).iter().map(|w| w.count_ones() as usize).sum()
    }
}

/// Renders the visibility images of every segment of `exemplar` at `points` points along each
/// (periodic exemplars tiled over the whole plane).
pub fn render_exemplar(
    exemplar: &Exemplar,
    resolution: usize,
    points: usize,
    cancel: &Cancel,
    progress: Progress,
) -> Result<VisibilityImages, SvfError> {
    let scene = FiberScene::new(exemplar, Extent::Unbounded)?;
    render_scene(&scene, resolution, points, cancel, progress)
}

/// Renders the visibility images of every segment of `scene` at `points` points along each
/// (build it with `Extent::Unbounded` for the paper's setting); image `k points + j` belongs
/// to point `j` of segment `k`.
pub fn render_scene(
    scene: &FiberScene,
    resolution: usize,
    points: usize,
    cancel: &Cancel,
    progress: Progress,
) -> Result<VisibilityImages, SvfError> {
    let all: Vec<u32> = (0..scene.segments().len() as u32).collect();
    render_segments(scene, &all, resolution, points, cancel, progress)
}

/// Renders the visibility images of the listed segments of `scene` at `points` points along
/// each; image `i points + j` belongs to point `j` of segment `segments[i]`.
pub fn render_segments(
    scene: &FiberScene,
    segments: &[u32],
    resolution: usize,
    points: usize,
    cancel: &Cancel,
    progress: Progress,
) -> Result<VisibilityImages, SvfError> {
    check_count("svf_resolution", resolution, 1, 4096)?;
    check_count("visibility_points", points, 1, super::settings::MAX_VISIBILITY_POINTS)?;
    let count = scene.segments().len();
    if let Some(&segment) = segments.iter().find(|&&s| s as usize >= count) {
        return Err(SvfError::NoSuchSegment { segment, count });
    }
    let mut images = VisibilityImages::new(resolution, segments.len() * points);
    let directions: Vec<DVec3> = (0..resolution * resolution)
        .map(|p| pixel_direction(resolution, p / resolution, p % resolution))
        .collect();
    let offset = scene.tile_offset(scene.central_tile());
    let done = AtomicUsize::new(0);
    let total = images.segment_count().max(1);
    let words_per_image = images.words_per_image;
    if words_per_image > 0 {
        images.bits.par_chunks_mut(words_per_image).enumerate().try_for_each(
            |(image, words)| -> Result<(), Cancelled> {
                cancel.check()?;
                let seg = &scene.segments()[segments[image / points] as usize];
                let along = visibility_point_fraction(image % points, points);
                let (a, b) = (seg.a.as_dvec3(), seg.b.as_dvec3());
                let point = a + (b - a) * along + offset;
                let origin = visibility_origin(point, seg.tangent().as_dvec3(), f64::from(seg.radius));
                for (p, &dir) in directions.iter().enumerate() {
                    if !scene.any_hit_f64(origin, dir, f64::INFINITY, Some(seg.fiber)) {
                        words[p / 64] |= 1 << (p % 64);
                    }
                }
                let finished = done.fetch_add(1, Ordering::Relaxed) + 1;
                if finished.is_multiple_of(PROGRESS_EVERY) {
                    progress(finished as f64 / total as f64);
                }
                Ok(())
            },
        )?;
    }
    progress(1.0);
    Ok(images)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::bake::no_progress;
    use crate::bake::settings::MAX_VISIBILITY_POINTS;
    use crate::fabric::{BlockGrid, Fiber, Tiling};
    use glam::{Vec2, Vec3};

    fn exemplar(fibers: Vec<Fiber>, tiling: Tiling) -> Exemplar {
        crate::fabric::fiber_io::exemplar_from_fibers(fibers, tiling, BlockGrid { nx: 1, ny: 1 })
    }

    fn fiber(a: Vec3, b: Vec3, radius: f32) -> Fiber {
        Fiber { points: vec![a, b], radius, yarn: 0 }
    }

    /// The default fabric preset's exemplar.
    pub(crate) fn default_exemplar() -> Exemplar {
        crate::fabric::presets::fabric_preset("default")
            .unwrap()
            .fabric
            .build(std::path::Path::new("."))
            .unwrap()
    }

    #[test]
    fn pixel_solid_angles_sum_to_the_sphere_and_directions_fall_in_their_pixels() {
        for n in [1_usize, 4, 7, 32, 128] {
            let total: f64 = (0..n).map(|r| n as f64 * pixel_solid_angle(n, r)).sum();
            assert!((total - 4.0 * PI).abs() < 1e-12, "n = {n}: {total}");
            for row in 0..n {
                for col in 0..n {
                    assert_eq!(pixel_of_direction(n, pixel_direction(n, row, col)), (row, col));
                }
            }
        }
    }

    #[test]
    fn visibility_points_sit_at_the_centres_of_equal_pieces_and_a_hit_takes_its_pieces() {
        for points in 1..=MAX_VISIBILITY_POINTS {
            let h = 0.3;
            for j in 0..points {
                // The point's own axial position, and positions just inside its piece's ends.
                let u = visibility_point_fraction(j, points);
                let axial = (u - 0.5) * 2.0 * h;
                assert_eq!(visibility_point_of(axial, h, points), j, "{points} points, point {j}");
                let piece = 2.0 * h / points as f64;
                assert_eq!(visibility_point_of(axial - 0.49 * piece, h, points), j);
                assert_eq!(visibility_point_of(axial + 0.49 * piece, h, points), j);
            }
            // Caps beyond the ends take the end pieces; degenerate input the middle one.
            assert_eq!(visibility_point_of(-2.0 * h, h, points), 0);
            assert_eq!(visibility_point_of(2.0 * h, h, points), points - 1);
            assert_eq!(visibility_point_of(0.1, 0.0, points), points / 2);
            assert_eq!(visibility_point_of(f64::NAN, h, points), points / 2);
        }
        // The midpoint's piece is the middle one, so one point is the paper's midpoint.
        assert!((visibility_point_fraction(0, 1) - 0.5).abs() < 1e-15);
    }

    #[test]
    fn each_visibility_point_sees_past_what_covers_only_the_rest_of_its_segment() {
        // A fiber along x from -1 to 1, and a thick fiber across it above its left half
        // (x from -0.7 to -0.3, z from 0.3 to 0.7): at two points the left one (x = -0.5) is
        // shadowed from straight above and the right one is not (the midpoint alone would see
        // the sky too).
        let host = fiber(Vec3::new(-1.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), 0.01);
        let cover = fiber(Vec3::new(-0.5, -1.0, 0.5), Vec3::new(-0.5, 1.0, 0.5), 0.2);
        let scene = FiberScene::new(&exemplar(vec![host, cover], Tiling::AsIs), Extent::Unbounded).unwrap();
        let k = scene.segments().iter().position(|s| s.fiber == 0).unwrap();
        let images = render_segments(&scene, &[k as u32], 8, 2, &Cancel::new(), &no_progress).unwrap();
        assert_eq!(images.segment_count(), 2);
        let up = DVec3::new(0.0, 0.05, 1.0).normalize();
        assert!(!images.lookup(0, up), "the left point lies under the cover");
        assert!(images.lookup(1, up), "the right point sees the sky");
        assert!(matches!(
            render_segments(&scene, &[k as u32], 8, MAX_VISIBILITY_POINTS + 1, &Cancel::new(), &no_progress),
            Err(SvfError::Param(_))
        ));
    }

    #[test]
    fn visibility_rays_start_at_the_centroid_of_the_fibers_upper_half() {
        let (mid, r) = (DVec3::new(1.0, 2.0, 3.0), 0.01);
        // A fiber in the fabric plane: straight up by 2r/π.
        let origin = visibility_origin(mid, DVec3::X, r);
        assert!((origin - (mid + DVec3::Z * (2.0 * r / PI))).length() < 1e-15);
        // A fiber rising at 30°: up across the fiber, perpendicular to it.
        let t = DVec3::new(30f64.to_radians().cos(), 0.0, 30f64.to_radians().sin());
        let offset = visibility_origin(mid, t, r) - mid;
        assert!(offset.dot(t).abs() < 1e-15 && offset.z > 0.0);
        assert!((offset.length() - 2.0 * r / PI).abs() < 1e-15);
        // A fiber along z has no up across it.
        assert_eq!(visibility_origin(mid, DVec3::Z, r), mid);
        // A thin fiber buried in this one's upper half (its top 0.6 r above the axis, below the
        // centroid's 2r/π) hides the sky from the axis but not from the raised origin.
        let host = fiber(Vec3::new(-1.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), 0.01);
        let buried = fiber(Vec3::new(0.0, -1.0, 0.005), Vec3::new(0.0, 1.0, 0.005), 0.001);
        let scene = FiberScene::new(&exemplar(vec![host, buried], Tiling::AsIs), Extent::Unbounded).unwrap();
        let images = render_scene(&scene, 8, 1, &Cancel::new(), &no_progress).unwrap();
        let k = scene.segments().iter().position(|s| s.fiber == 0).unwrap();
        let (row, col) = pixel_of_direction(8, DVec3::new(0.0, 0.05, 1.0).normalize());
        assert!(images.get(k, row, col), "the raised origin of the host fiber sees the sky");
        assert!(scene.any_hit_f64(
            scene.segments()[k].midpoint().as_dvec3(),
            DVec3::Z,
            f64::INFINITY,
            Some(0)
        ));
    }

    #[test]
    fn a_segment_alone_sees_everything() {
        let ex = exemplar(vec![fiber(Vec3::ZERO, Vec3::new(0.01, 0.0, 0.0), 5e-4)], Tiling::AsIs);
        let images = render_exemplar(&ex, 16, 1, &Cancel::new(), &no_progress).unwrap();
        assert_eq!(images.visible_pixel_count(0), 256);
        assert!((images.visible_solid_angle(0) - 4.0 * PI).abs() < 1e-12);
    }

    #[test]
    fn a_segment_under_an_infinite_roof_sees_the_lower_hemisphere() {
        // Periodic roof: parallel fibers along x at z = 0.01, overlapping (spacing 1.8 r), and
        // the segment of interest (its own fiber) below it at z = 0.
        let r = 5e-4_f32;
        let spacing = 1.8 * r;
        let rows = 10;
        let period = Vec2::new(0.02, spacing * rows as f32);
        let mut fibers = vec![fiber(Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.004, 0.0, 0.0), r)];
        for j in 0..rows {
            let y = j as f32 * spacing;
            fibers.push(Fiber {
                points: (0..=12).map(|i| Vec3::new(-0.02 + 0.005 * i as f32, y, 0.01)).collect(),
                radius: r,
                yarn: 0,
            });
        }
        let ex = exemplar(fibers, Tiling::Periodic { period });
        let n = 16;
        let images = render_exemplar(&ex, n, 1, &Cancel::new(), &no_progress).unwrap();
        for row in 0..n {
            for col in 0..n {
                assert_eq!(images.get(0, row, col), row >= n / 2, "pixel ({row}, {col})");
            }
        }
        assert!((images.visible_solid_angle(0) - 2.0 * PI).abs() < 1e-12);
    }

    #[test]
    fn default_fabric_top_layer_sees_more_sky_and_threads_do_not_matter() {
        let ex = default_exemplar();
        let scene = FiberScene::new(&ex, Extent::Unbounded).unwrap();
        let segs = scene.segments();
        // Every 40th segment, at 16 x 16, keeps this test fast.
        let ids: Vec<u32> = (0..segs.len() as u32).step_by(40).collect();
        let n = 16;
        let images = render_segments(&scene, &ids, n, 1, &Cancel::new(), &no_progress).unwrap();
        let upper = |i: usize| -> f64 {
            (0..n / 2)
                .map(|row| {
                    (0..n).filter(|&c| images.get(i, row, c)).count() as f64 * pixel_solid_angle(n, row)
                })
                .sum()
        };
        let mut by_z: Vec<(f32, usize)> =
            ids.iter().enumerate().map(|(i, &s)| (segs[s as usize].midpoint().z, i)).collect();
        by_z.sort_by(|a, b| a.0.total_cmp(&b.0));
        let tenth = by_z.len() / 10;
        let mean_upper =
            |part: &[(f32, usize)]| part.iter().map(|&(_, i)| upper(i)).sum::<f64>() / part.len() as f64;
        let (bottom, top) = (mean_upper(&by_z[..tenth]), mean_upper(&by_z[by_z.len() - tenth..]));
        let mean_total =
            (0..ids.len()).map(|i| images.visible_solid_angle(i)).sum::<f64>() / ids.len() as f64;
        eprintln!(
            "default fabric, {} segments at {n}x{n}: mean visible solid angle {mean_total:.3} sr; upper hemisphere seen by the top 10 %: {top:.3} sr, bottom 10 %: {bottom:.3} sr",
            ids.len()
        );
        for i in 0..ids.len() {
            let omega = images.visible_solid_angle(i);
            assert!(omega.is_finite() && (0.0..=4.0 * PI + 1e-9).contains(&omega));
        }
        assert!(top > bottom + 0.5, "top {top}, bottom {bottom}");
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let few = &ids[..ids.len().min(60)];
        let single =
            pool.install(|| render_segments(&scene, few, n, 1, &Cancel::new(), &no_progress).unwrap());
        let many = render_segments(&scene, few, n, 1, &Cancel::new(), &no_progress).unwrap();
        assert_eq!(single, many);
        assert_eq!(single.words(), &images.words()[..single.words().len()]);
    }

    #[test]
    fn cancellation_and_bad_input_are_errors() {
        let ex = exemplar(vec![fiber(Vec3::ZERO, Vec3::X * 0.01, 5e-4)], Tiling::AsIs);
        let scene = FiberScene::new(&ex, Extent::Unbounded).unwrap();
        let cancel = Cancel::new();
        cancel.cancel();
        assert_eq!(
            render_scene(&scene, 8, 1, &cancel, &no_progress).unwrap_err(),
            SvfError::Cancelled(Cancelled)
        );
        assert!(matches!(
            render_segments(&scene, &[3], 8, 1, &Cancel::new(), &no_progress),
            Err(SvfError::NoSuchSegment { segment: 3, count: 1 })
        ));
        assert!(matches!(render_scene(&scene, 0, 1, &Cancel::new(), &no_progress), Err(SvfError::Param(_))));
    }
}
