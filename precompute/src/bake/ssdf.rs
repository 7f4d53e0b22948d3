//! Spherical signed distance functions (SSDF, Wang et al. 2009) of the visibility images.
//!
//! Definition: for pixel `p` of a segment's image ([`super::svf`] parameterization), `d(p)` is
//! the great-circle angle (radians) between the centre direction of `p` and the centre direction
//! of the nearest pixel of the *opposite* value; positive where `p` is visible, negative where
//! it is occluded. `d` is never 0 (the nearest other pixel is at least one pixel spacing away), so
//! its sign is exactly the visibility. An image with no pixel of the opposite value (all visible
//! or all occluded) gets `+π` or `−π` everywhere: the largest possible angle, "no edge anywhere".
//!
//! How it works (exact, no approximation):
//! 1. For each row and each value, the circular column distance (φ wraps) from every column to
//!    the nearest column of that value in the row: two passes over the row, one forward and one
//!    backward, each started from the last (first) occurrence so that they wrap.
//! 2. Within one row the nearest pixel on the sphere is the nearest in φ, because for pixel
//!    centres `sin θ > 0` and `cos d = cos θ₁ cos θ₂ + sin θ₁ sin θ₂ cos Δφ` falls with `|Δφ|`.
//!    So for each pixel it is enough to look at one candidate per row, and to minimize over rows.
//!    Rows are visited outward from the pixel's own row (up and down alternately); a direction
//!    stops once even `Δφ = 0` in that row, i.e. `|Δθ|` alone, cannot beat the best found. Poles
//!    need no special case: the pixels of the first row on opposite sides of the pole are close
//!    in this 3D distance, through the `cos Δφ` term.
//! 3. Everything is compared as `cos d` (one multiply-add per candidate); `acos` runs once per
//!    pixel.
//!
//! Cost: proportional to the number of rows within `|d|` of each pixel, so `O(n²)` per image
//! when edges are near and at worst `O(n³)` (tiny islands). Images are processed in parallel.

use std::f64::consts::PI;

use rayon::prelude::*;

use super::svf::{VisibilityImages, col_phi, row_theta};
use super::{Cancel, Cancelled};

/// "No column of this value in this row".
const NONE: u32 = u32::MAX;

/// Per-resolution trigonometry shared by every image.
#[derive(Debug, Clone)]
struct SsdfTables {
    n: usize,
    cos_theta: Vec<f64>,
    sin_theta: Vec<f64>,
    /// `cos(d 2π/n)` for circular column distances `d = 0..=n/2`.
    cos_dphi: Vec<f64>,
}

impl SsdfTables {
    fn new(n: usize) -> Self {
        let (sin_theta, cos_theta) = (0..n).map(|r| row_theta(n, r).sin_cos()).unzip();
        let cos_dphi = (0..=n / 2).map(|d| (col_phi(n, d) - col_phi(n, 0)).cos()).collect();
        Self { n, cos_theta, sin_theta, cos_dphi }
    }

    /// Segment `segment`'s SSDF, rounded to f32, into `out`.
    fn ssdf_f32(&self, images: &VisibilityImages, segment: usize, out: &mut [f32]) {
        for (o, v) in out.iter_mut().zip(self.ssdf(|p| images.get_pixel(segment, p))) {
            *o = v as f32;
        }
    }

    /// SSDF in f64 of one image given as a pixel predicate.
    fn ssdf(&self, visible: impl Fn(usize) -> bool) -> Vec<f64> {
        let n = self.n;
        let values: Vec<bool> = (0..n * n).map(visible).collect();
        let any_visible = values.iter().any(|&v| v);
        let any_occluded = values.iter().any(|&v| !v);
        if !(any_visible && any_occluded) {
            return vec![if any_visible { PI } else { -PI }; n * n];
        }
        // nearest[v][r * n + c]: circular column distance to the nearest column of value v.
        let mut nearest = [vec![NONE; n * n], vec![NONE; n * n]];
        for (value, table) in nearest.iter_mut().enumerate() {
            let value = value == 1;
            for row in 0..n {
                nearest_in_row(&values[row * n..(row + 1) * n], value, &mut table[row * n..(row + 1) * n]);
            }
        }
        let mut out = vec![0.0; n * n];
        for row in 0..n {
            let (ci, si) = (self.cos_theta[row], self.sin_theta[row]);
            for col in 0..n {
                let value = values[row * n + col];
                let opposite = &nearest[usize::from(!value)];
                let mut best = -2.0_f64;
                let candidate = |r: usize, best: &mut f64| -> bool {
                    let (cr, sr) = (self.cos_theta[r], self.sin_theta[r]);
                    // Upper bound over the whole row (Δφ = 0): stop this direction if it cannot win.
                    if ci * cr + si * sr < *best {
                        return false;
                    }
                    let d = opposite[r * n + col];
                    if d != NONE {
                        let c = ci * cr + si * sr * self.cos_dphi[d as usize];
                        if c > *best {
                            *best = c;
                        }
                    }
                    true
                };
                candidate(row, &mut best);
                let (mut up, mut down) = (row > 0, row + 1 < n);
                let mut k = 1;
                while up || down {
                    if up {
                        up = candidate(row - k, &mut best) && row > k;
                    }
                    if down {
                        down = candidate(row + k, &mut best) && row + k + 1 < n;
                    }
                    k += 1;
                }
                let distance = best.clamp(-1.0, 1.0).acos();
                out[row * n + col] = if value { distance } else { -distance };
            }
        }
        out
    }
}

/// Circular distance from every column of `row` to the nearest column holding `value`
/// (`NONE` everywhere if there is none).
fn nearest_in_row(row: &[bool], value: bool, out: &mut [u32]) {
    let n = row.len();
    let Some(last) = row.iter().rposition(|&v| v == value) else {
        out.fill(NONE);
        return;
    };
    let first = row.iter().position(|&v| v == value).unwrap_or(last);
    // Forward: distance back to the previous occurrence, wrapping from the last one.
    let mut previous = last as isize - n as isize;
    for (c, slot) in out.iter_mut().enumerate() {
        if row[c] == value {
            previous = c as isize;
        }
        *slot = (c as isize - previous) as u32;
    }
    // Backward: distance ahead to the next occurrence, wrapping to the first one.
    let mut next = (first + n) as isize;
    for c in (0..n).rev() {
        if row[c] == value {
            next = c as isize;
        }
        out[c] = out[c].min((next - c as isize) as u32);
    }
}

/// SSDF of one segment's image, `n²` values row-major (radians; see the module docs).
#[must_use]
pub fn ssdf(images: &VisibilityImages, segment: usize) -> Vec<f32> {
    ssdf_f64(images, segment).into_iter().map(|d| d as f32).collect()
}

/// [`ssdf`] in f64.
#[must_use]
pub fn ssdf_f64(images: &VisibilityImages, segment: usize) -> Vec<f64> {
    SsdfTables::new(images.resolution).ssdf(|p| images.get_pixel(segment, p))
}

/// SSDFs of every segment, row-major `segments x n²` (segment `k`'s image at `k n²`), in
/// parallel; checks `cancel` before each image.
pub fn ssdf_all(images: &VisibilityImages, cancel: &Cancel) -> Result<Vec<f32>, Cancelled> {
    let pixels = images.pixel_count();
    let mut out = vec![0.0_f32; pixels * images.segment_count()];
    if pixels == 0 {
        return Ok(out);
    }
    let tables = SsdfTables::new(images.resolution);
    out.par_chunks_mut(pixels).enumerate().try_for_each(|(segment, chunk)| {
        cancel.check()?;
        tables.ssdf_f32(images, segment, chunk);
        Ok(())
    })?;
    Ok(out)
}

/// The SSDFs of segments `first..` into `out` (whole images, row-major as [`ssdf_all`]), in
/// parallel: what PCA reads block by block instead of holding [`ssdf_all`].
pub fn ssdf_into(images: &VisibilityImages, first: usize, out: &mut [f32]) {
    let pixels = images.pixel_count();
    if pixels == 0 {
        return;
    }
    let tables = SsdfTables::new(images.resolution);
    out.par_chunks_mut(pixels).enumerate().for_each(|(i, chunk)| tables.ssdf_f32(images, first + i, chunk));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::svf::pixel_direction;
    use glam::DVec3;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    /// Every pixel against every pixel of the opposite value, with an independent formula.
    fn brute_force(images: &VisibilityImages, segment: usize) -> Vec<f64> {
        let n = images.resolution;
        let dirs: Vec<DVec3> = (0..n * n).map(|p| pixel_direction(n, p / n, p % n)).collect();
        (0..n * n)
            .map(|p| {
                let v = images.get_pixel(segment, p);
                let d = (0..n * n)
                    .filter(|&q| images.get_pixel(segment, q) != v)
                    .map(|q| dirs[p].cross(dirs[q]).length().atan2(dirs[p].dot(dirs[q])))
                    .fold(f64::INFINITY, f64::min);
                let d = if d.is_finite() { d } else { PI };
                if v { d } else { -d }
            })
            .collect()
    }

    /// Random images: a few caps (blobs) of random size, some noise, and fixed features at both
    /// poles and across φ = 0.
    fn random_images(n: usize, count: usize, seed: u64) -> VisibilityImages {
        let mut rng = Pcg64::seed_from_u64(seed);
        let mut images = VisibilityImages::new(n, count);
        for k in 0..count {
            let caps: Vec<(DVec3, f64)> = (0..rng.random_range(1..5))
                .map(|_| {
                    let z: f64 = rng.random_range(-1.0..1.0);
                    let phi: f64 = rng.random_range(0.0..2.0 * PI);
                    let s = (1.0 - z * z).sqrt();
                    (DVec3::new(s * phi.cos(), s * phi.sin(), z), rng.random_range(0.1..1.5))
                })
                .collect();
            let noise = [0.0, 0.03, 0.2][k % 3];
            for row in 0..n {
                for col in 0..n {
                    let d = pixel_direction(n, row, col);
                    let mut v = caps.iter().any(|(axis, rho)| d.dot(*axis) > rho.cos());
                    if k % 4 == 1 {
                        // Pole features: a pixel in the top row, a half row at the bottom.
                        v ^= (row == 0 && col == 1) || (row == n - 1 && col < n / 2);
                    }
                    if k % 4 == 2 {
                        // A band straddling φ = 0.
                        v ^= col == 0 || col == n - 1;
                    }
                    if rng.random::<f64>() < noise {
                        v = !v;
                    }
                    images.set(k, row, col, v);
                }
            }
        }
        images
    }

    #[test]
    fn nearest_in_row_wraps() {
        let mut out = [0; 6];
        nearest_in_row(&[false, false, true, false, false, false], true, &mut out);
        assert_eq!(out, [2, 1, 0, 1, 2, 3]);
        nearest_in_row(&[true, false, false, false, false, false], true, &mut out);
        assert_eq!(out, [0, 1, 2, 3, 2, 1]);
        nearest_in_row(&[false; 6], true, &mut out);
        assert_eq!(out, [NONE; 6]);
    }

    #[test]
    fn ssdf_equals_brute_force_and_its_sign_is_the_visibility() {
        let mut worst = 0.0_f64;
        for (n, seed) in [(8_usize, 1_u64), (12, 2), (16, 3), (9, 4)] {
            let count = 24;
            let images = random_images(n, count, seed);
            let batch = ssdf_all(&images, &Cancel::new()).unwrap();
            for k in 0..count {
                let fast = ssdf_f64(&images, k);
                let slow = brute_force(&images, k);
                for p in 0..n * n {
                    worst = worst.max((fast[p] - slow[p]).abs());
                    assert!(
                        (fast[p] - slow[p]).abs() < 1e-10,
                        "n {n} image {k} pixel {p}: {} vs {}",
                        fast[p],
                        slow[p]
                    );
                    assert_eq!(fast[p] > 0.0, images.get_pixel(k, p));
                    assert_eq!(batch[k * n * n + p].to_bits(), (fast[p] as f32).to_bits());
                }
            }
        }
        eprintln!("ssdf vs brute force: worst difference {worst:e} rad");
    }

    #[test]
    fn uniform_images_are_plus_or_minus_pi() {
        let mut images = VisibilityImages::new(4, 2);
        for r in 0..4 {
            for c in 0..4 {
                images.set(1, r, c, true);
            }
        }
        assert!(ssdf(&images, 0).iter().all(|&d| d.to_bits() == (-PI as f32).to_bits()));
        assert!(ssdf(&images, 1).iter().all(|&d| d.to_bits() == (PI as f32).to_bits()));
    }

    #[test]
    fn across_the_pole_is_near() {
        // One visible pixel in the top row: the pixel opposite it across the pole is at 2 θ_0.
        let n = 16;
        let mut images = VisibilityImages::new(n, 1);
        images.set(0, 0, 0, true);
        let d = ssdf_f64(&images, 0);
        let expected = 2.0 * row_theta(n, 0);
        assert!((d[n / 2] + expected).abs() < 1e-12, "{} vs -{expected}", d[n / 2]);
    }

    #[test]
    fn cancelled_batch_is_an_error() {
        let cancel = Cancel::new();
        cancel.cancel();
        assert_eq!(ssdf_all(&VisibilityImages::new(4, 3), &cancel), Err(Cancelled));
    }
}
