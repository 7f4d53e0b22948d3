//! Images, Monte Carlo films and noise-aware image comparison.
//!
//! An [`Image`] is a plain grid of linear RGB values. A [`Film`] accumulates independent Monte
//! Carlo estimates per pixel (their sum and sum of squares), so that besides the mean image it
//! knows the variance of each pixel's mean. Every path-traced result carries that variance, and
//! [`compare`] uses it: a difference between two images is judged against the noise both carry
//! (a per-pixel z-score), next to the plain relative error of the mean and the RMSE. Later parts
//! of twill (precomputation, the GPU renderer) are validated against path-traced films with it.

use crate::Rgb;

/// A grid of linear RGB pixels, row-major, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<Rgb>,
}

impl Image {
    /// The relative L2 error of `self` against `reference`, `sqrt(Σ |a − b|² / Σ |b|²)` over
    /// pixels and channels (Hašan & Ramamoorthy's measure).
    #[must_use]
    pub fn relative_l2(&self, reference: &Image) -> f64 {
        let (mut difference, mut norm) = (0.0, 0.0);
        for (a, b) in self.pixels.iter().zip(&reference.pixels) {
            difference += (*a - *b).length_squared();
            norm += b.length_squared();
        }
        (difference / norm).sqrt()
    }

    #[must_use]
    pub fn new(width: usize, height: usize) -> Self {
        Self { width, height, pixels: vec![Rgb::ZERO; width * height] }
    }

    #[must_use]
    pub fn get(&self, x: usize, y: usize) -> Rgb {
        self.pixels[y * self.width + x]
    }

    pub fn set(&mut self, x: usize, y: usize, value: Rgb) {
        self.pixels[y * self.width + x] = value;
    }

    /// Mean of all pixels, per channel.
    #[must_use]
    pub fn mean(&self) -> Rgb {
        if self.pixels.is_empty() {
            return Rgb::ZERO;
        }
        self.pixels.iter().copied().sum::<Rgb>() / self.pixels.len() as f64
    }

    /// True when every channel of every pixel is finite.
    #[must_use]
    pub fn is_finite(&self) -> bool {
        self.pixels.iter().all(|p| p.is_finite())
    }
}

/// Per-pixel accumulation of independent Monte Carlo estimates.
#[derive(Debug, Clone, PartialEq)]
pub struct Film {
    pub width: usize,
    pub height: usize,
    sum: Vec<Rgb>,
    sum_sq: Vec<Rgb>,
    count: Vec<u32>,
}

impl Film {
    #[must_use]
    pub fn new(width: usize, height: usize) -> Self {
        let n = width * height;
        Self { width, height, sum: vec![Rgb::ZERO; n], sum_sq: vec![Rgb::ZERO; n], count: vec![0; n] }
    }

    /// Adds one independent estimate of pixel `(x, y)`.
    pub fn add(&mut self, x: usize, y: usize, estimate: Rgb) {
        let i = y * self.width + x;
        self.sum[i] += estimate;
        self.sum_sq[i] += estimate * estimate;
        self.count[i] += 1;
    }

    /// Replaces one row with accumulated values (used when rows are rendered in parallel).
    pub fn set_row(&mut self, y: usize, row: &PixelRow) {
        let range = y * self.width..(y + 1) * self.width;
        self.sum[range.clone()].copy_from_slice(&row.sum);
        self.sum_sq[range.clone()].copy_from_slice(&row.sum_sq);
        self.count[range].copy_from_slice(&row.count);
    }

    /// The mean image (the estimate).
    #[must_use]
    pub fn mean(&self) -> Image {
        let pixels = self
            .sum
            .iter()
            .zip(&self.count)
            .map(|(&s, &n)| if n == 0 { Rgb::ZERO } else { s / f64::from(n) })
            .collect();
        Image { width: self.width, height: self.height, pixels }
    }

    /// Variance of each pixel's mean (sample variance / n), per channel.
    #[must_use]
    pub fn variance_of_mean(&self) -> Image {
        let pixels = self
            .sum
            .iter()
            .zip(&self.sum_sq)
            .zip(&self.count)
            .map(|((&s, &sq), &n)| {
                if n < 2 {
                    return Rgb::ZERO;
                }
                let n = f64::from(n);
                let mean = s / n;
                // Unbiased sample variance; clamp tiny negative round-off.
                let var = ((sq - mean * s) / (n - 1.0)).max(Rgb::ZERO);
                var / n
            })
            .collect();
        Image { width: self.width, height: self.height, pixels }
    }

    /// Adds the samples of `other`, a film of the same size whose samples are independent of
    /// this one's (another seed): the result is the film of both sets of samples.
    ///
    /// # Panics
    /// When the sizes differ.
    pub fn merge(&mut self, other: &Film) {
        assert_eq!((self.width, self.height), (other.width, other.height), "Film::merge: sizes differ");
        for (a, b) in self.sum.iter_mut().zip(&other.sum) {
            *a += *b;
        }
        for (a, b) in self.sum_sq.iter_mut().zip(&other.sum_sq) {
            *a += *b;
        }
        for (a, b) in self.count.iter_mut().zip(&other.count) {
            *a += *b;
        }
    }

    /// Clamps each pixel's mean at zero per channel (a negative sum becomes zero). The sums of
    /// squares stay, so [`Film::variance_of_mean`] of a clamped pixel is its samples' second
    /// moment about zero: no smaller than their variance.
    pub fn clamp_means_at_zero(&mut self) {
        for s in &mut self.sum {
            *s = s.max(Rgb::ZERO);
        }
    }

    /// Samples taken at pixel `(x, y)`.
    #[must_use]
    pub fn samples_at(&self, x: usize, y: usize) -> u32 {
        self.count[y * self.width + x]
    }
}

/// One row of a [`Film`] accumulated independently (for parallel rendering).
#[derive(Debug, Clone)]
pub struct PixelRow {
    pub sum: Vec<Rgb>,
    pub sum_sq: Vec<Rgb>,
    pub count: Vec<u32>,
}

impl PixelRow {
    #[must_use]
    pub fn new(width: usize) -> Self {
        Self { sum: vec![Rgb::ZERO; width], sum_sq: vec![Rgb::ZERO; width], count: vec![0; width] }
    }

    pub fn add(&mut self, x: usize, estimate: Rgb) {
        self.sum[x] += estimate;
        self.sum_sq[x] += estimate * estimate;
        self.count[x] += 1;
    }
}

/// An image together with the variance of each of its pixels (zero for exact images).
#[derive(Debug, Clone, Copy)]
pub struct Estimate<'a> {
    pub mean: &'a Image,
    pub variance: Option<&'a Image>,
}

/// How two images differ, judged against their noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Comparison {
    /// (mean(test) − mean(reference)) / mean(reference), on luminance-free channel average.
    pub relative_error_of_mean: f64,
    /// Standard error of that relative error, from the pixel variances.
    pub relative_error_of_mean_std: f64,
    /// Root mean square of per-pixel differences (all channels).
    pub rmse: f64,
    /// RMSE that the two images' noise alone would give (sqrt of mean total variance).
    pub expected_noise_rmse: f64,
    /// Fraction of pixel channels whose |z| exceeds 4 (about 6e-5 for pure noise).
    pub fraction_z_above_4: f64,
    /// Mean of z² over pixel channels with nonzero variance (about 1 when the difference is noise).
    pub mean_z_squared: f64,
}

/// Compares `test` against `reference`, using the variances each carries.
///
/// Pixel channels where both variances are zero contribute to the RMSE but not to the z
/// statistics. Panics if the image sizes differ (a programming error, never user input).
#[must_use]
pub fn compare(test: Estimate<'_>, reference: Estimate<'_>) -> Comparison {
    assert_eq!((test.mean.width, test.mean.height), (reference.mean.width, reference.mean.height));
    let n = test.mean.pixels.len();
    let zero = Rgb::ZERO;
    let mut diff_sq = 0.0;
    let mut total_var = 0.0;
    let mut z_sq_sum = 0.0;
    let mut z_count = 0usize;
    let mut z_above = 0usize;
    let mut sum_test = 0.0;
    let mut sum_ref = 0.0;
    for i in 0..n {
        let a = test.mean.pixels[i];
        let b = reference.mean.pixels[i];
        let va = test.variance.map_or(zero, |v| v.pixels[i]);
        let vb = reference.variance.map_or(zero, |v| v.pixels[i]);
        for c in 0..3 {
            let d = a[c] - b[c];
            let var = va[c] + vb[c];
            diff_sq += d * d;
            total_var += var;
            if var > 0.0 {
                let z_sq = d * d / var;
                z_sq_sum += z_sq;
                z_count += 1;
                if z_sq > 16.0 {
                    z_above += 1;
                }
            }
        }
        sum_test += a.element_sum();
        sum_ref += b.element_sum();
    }
    let channels = (3 * n).max(1) as f64;
    let relative_error_of_mean = if sum_ref == 0.0 { sum_test.abs() } else { sum_test / sum_ref - 1.0 };
    // Var(sum of means) = sum of variances; the relative error's std is sqrt(var)/|sum_ref|.
    let relative_error_of_mean_std = if sum_ref == 0.0 { 0.0 } else { total_var.sqrt() / sum_ref.abs() };
    Comparison {
        relative_error_of_mean,
        relative_error_of_mean_std,
        rmse: (diff_sq / channels).sqrt(),
        expected_noise_rmse: (total_var / channels).sqrt(),
        fraction_z_above_4: if z_count == 0 { 0.0 } else { z_above as f64 / z_count as f64 },
        mean_z_squared: if z_count == 0 { 0.0 } else { z_sq_sum / z_count as f64 },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    fn noisy_film(mean: f64, noise: f64, seed: u64) -> Film {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let mut film = Film::new(16, 8);
        for y in 0..8 {
            for x in 0..16 {
                for _ in 0..64 {
                    let e = mean + noise * (rng.random::<f64>() - 0.5);
                    film.add(x, y, Rgb::splat(e));
                }
            }
        }
        film
    }

    #[test]
    fn film_mean_and_variance_match_the_samples() {
        let mut film = Film::new(1, 1);
        for v in [1.0, 2.0, 3.0, 4.0] {
            film.add(0, 0, Rgb::splat(v));
        }
        assert_eq!(film.mean().get(0, 0), Rgb::splat(2.5));
        // Sample variance of 1..4 is 5/3; variance of the mean is that over 4.
        let v = film.variance_of_mean().get(0, 0).x;
        assert!((v - 5.0 / 12.0).abs() < 1e-12, "{v}");
    }

    #[test]
    fn a_merged_film_is_the_film_of_both_sample_sets() {
        let samples = [1.0, 2.0, 3.0, 4.0, 10.0, -2.0];
        let (mut first, mut second, mut whole) = (Film::new(1, 1), Film::new(1, 1), Film::new(1, 1));
        for (i, &v) in samples.iter().enumerate() {
            (if i < 2 { &mut first } else { &mut second }).add(0, 0, Rgb::splat(v));
            whole.add(0, 0, Rgb::splat(v));
        }
        first.merge(&second);
        assert_eq!(first.samples_at(0, 0), 6);
        assert_eq!(first.mean().get(0, 0), whole.mean().get(0, 0));
        let (merged, direct) = (first.variance_of_mean().get(0, 0).x, whole.variance_of_mean().get(0, 0).x);
        assert!((merged - direct).abs() < 1e-12 * direct, "{merged} against {direct}");
    }

    #[test]
    fn two_noisy_estimates_of_the_same_image_agree_and_a_biased_one_does_not() {
        let a = noisy_film(1.0, 0.5, 1);
        let b = noisy_film(1.0, 0.5, 2);
        let (am, av, bm, bv) = (a.mean(), a.variance_of_mean(), b.mean(), b.variance_of_mean());
        let same =
            compare(Estimate { mean: &am, variance: Some(&av) }, Estimate { mean: &bm, variance: Some(&bv) });
        assert!((same.mean_z_squared - 1.0).abs() < 0.2, "{same:?}");
        assert!(same.relative_error_of_mean.abs() < 4.0 * same.relative_error_of_mean_std, "{same:?}");
        assert!(same.rmse < 1.5 * same.expected_noise_rmse, "{same:?}");

        let c = noisy_film(1.05, 0.5, 3);
        let (cm, cv) = (c.mean(), c.variance_of_mean());
        let biased =
            compare(Estimate { mean: &cm, variance: Some(&cv) }, Estimate { mean: &bm, variance: Some(&bv) });
        assert!(biased.relative_error_of_mean > 10.0 * biased.relative_error_of_mean_std, "{biased:?}");
        assert!(biased.mean_z_squared > 2.0, "{biased:?}");
    }

    #[test]
    fn exact_images_compare_by_rmse_alone() {
        let mut a = Image::new(2, 1);
        a.set(1, 0, Rgb::new(1.0, 0.0, 0.0));
        let b = Image::new(2, 1);
        let c = compare(Estimate { mean: &a, variance: None }, Estimate { mean: &b, variance: None });
        assert!((c.rmse - (1.0f64 / 6.0).sqrt()).abs() < 1e-12);
        assert!(c.mean_z_squared.abs() < f64::MIN_POSITIVE, "no pixel has variance");
        assert!(a.is_finite());
    }
}
