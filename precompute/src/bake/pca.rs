//! PCA compression of the SSDFs (paper section 4.1: "compressed with PCA using 48 principal
//! components").
//!
//! Each segment's SSDF is a vector of `dims = n²` values. PCA keeps the mean vector, the `K`
//! leading principal directions (orthonormal, stored f32, `K x dims` row-major) and each
//! segment's `K` coefficients (f32), so that
//! `d_k(p) ≈ mean[p] + Σ_c coefficient[k][c] component[c][p]`.
//!
//! How it works: the data (`segments x dims`, f32) is never held centred in f64 as a whole;
//! every pass streams blocks of [`BLOCK_ROWS`] segments, centres them in f64 and multiplies with
//! faer (parallel GEMM), checking the [`Cancel`] token between blocks. Two methods:
//! - [`PcaMethod::CovarianceEigen`] (used when `dims <= 4096`, e.g. `n <= 64`): accumulate the
//!   `dims x dims` scatter matrix `Σ (x − μ)(x − μ)ᵀ` and take its symmetric eigendecomposition
//!   (faer `self_adjoint_eigen`); the components are the eigenvectors of the `K` largest
//!   eigenvalues. Cost `O(segments dims² + dims³)`.
//! - [`PcaMethod::RandomizedRangeFinder`] (larger `dims`, e.g. the paper's 128² = 16384):
//!   Halko, Martinsson and Tropp 2011. With `l = K + 10` Gaussian test vectors `Ω` (seeded),
//!   `Y = X Ω`, then two power iterations (`Y ← X qr(Xᵀ qr(Y))`, re-orthonormalizing with QR
//!   each time), `Q = qr(Y)`; the data's row space is then captured by `W = Xᵀ Q` (`dims x l`,
//!   `X ≈ Q Wᵀ`). The small `l x l` eigendecomposition `Wᵀ W = V Σ² Vᵀ` gives the principal
//!   directions `W V` (orthonormalized by one more QR), of which the `K` largest are kept.
//!   Cost: about 7 streaming passes of `2 segments dims l` flops.
//!
//! Stats ([`PcaStats`]) come from one more pass that projects and reconstructs every segment in
//! f64: explained variance fraction (kept eigenvalues over the total sum of squares about the
//! mean), RMS reconstruction error in radians over all pixels, and the fraction of pixels whose
//! reconstructed SSDF has the sign of the original (which by construction is the binary
//! visibility, see [`super::ssdf`]).

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatRef, Par, Side};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use super::{Cancel, Cancelled};

/// Segments per streamed block.
pub const BLOCK_ROWS: usize = 1024;
/// Largest `dims` for which [`compress`] uses [`PcaMethod::CovarianceEigen`].
pub const COVARIANCE_EIGEN_MAX_DIMS: usize = 4096;
/// Extra test vectors of the randomized range finder.
const OVERSAMPLING: usize = 10;
/// Power iterations of the randomized range finder.
const POWER_ITERATIONS: usize = 2;

/// How the principal directions are found; see the module docs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PcaMethod {
    CovarianceEigen,
    RandomizedRangeFinder,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PcaError {
    #[error("PCA needs at least one segment and one value per segment")]
    Empty,
    #[error("PCA input has {len} values, not a multiple of {dims} values per segment")]
    LengthMismatch { len: usize, dims: usize },
    #[error("PCA needs at least one component")]
    NoComponents,
    #[error("PCA input value {index} is not finite")]
    NonFinite { index: usize },
    #[error("eigendecomposition failed: {0}")]
    Eigen(String),
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
}

/// Quality of a compression (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PcaStats {
    pub method: PcaMethod,
    /// Fraction of the variance about the mean that the kept components explain, in [0, 1].
    pub explained_variance: f64,
    /// Root-mean-square reconstruction error over all segments and pixels (radians).
    pub rms_error: f64,
    /// Fraction of pixels whose reconstructed value has the sign of the original value.
    pub sign_agreement: f64,
}

/// Mean, components and per-segment coefficients of the compressed SSDFs.
#[derive(Debug, Clone, PartialEq)]
pub struct PcaBasis {
    /// Values per segment (`n²`).
    pub dims: usize,
    /// Number of components `K`.
    pub component_count: usize,
    pub segment_count: usize,
    mean: Vec<f32>,
    /// `K x dims`, row-major, orthonormal rows, largest variance first.
    components: Vec<f32>,
    /// `segments x K`, row-major.
    coefficients: Vec<f32>,
    pub stats: PcaStats,
}

impl PcaBasis {
    /// The mean SSDF (`dims` values).
    #[must_use]
    pub fn mean(&self) -> &[f32] {
        &self.mean
    }

    /// All components, `K x dims` row-major (component `c` at `c dims`).
    #[must_use]
    pub fn components(&self) -> &[f32] {
        &self.components
    }

    /// Component `c` (`dims` values).
    #[must_use]
    pub fn component(&self, c: usize) -> &[f32] {
        &self.components[c * self.dims..(c + 1) * self.dims]
    }

    /// All coefficients, `segments x K` row-major.
    #[must_use]
    pub fn all_coefficients(&self) -> &[f32] {
        &self.coefficients
    }

    /// The `K` coefficients of one segment.
    #[must_use]
    pub fn coefficients(&self, segment: usize) -> &[f32] {
        &self.coefficients[segment * self.component_count..(segment + 1) * self.component_count]
    }

    /// The reconstructed SSDF of `segment` (`dims` values).
    #[must_use]
    pub fn reconstruct(&self, segment: usize) -> Vec<f32> {
        (0..self.dims).map(|p| self.eval_pixel(segment, p)).collect()
    }

    /// Reconstructed value at pixel `pixel` (row-major index).
    #[must_use]
    pub fn eval_pixel(&self, segment: usize, pixel: usize) -> f32 {
        let coeffs = self.coefficients(segment);
        let mut v = f64::from(self.mean[pixel]);
        for (c, &a) in coeffs.iter().enumerate() {
            v += f64::from(a) * f64::from(self.components[c * self.dims + pixel]);
        }
        v as f32
    }

    /// Reconstructed value at (`row`, `col`) of an `n x n` image, `n = sqrt(dims)`.
    #[must_use]
    pub fn eval(&self, segment: usize, row: usize, col: usize) -> f32 {
        self.eval_pixel(segment, row * self.dims.isqrt() + col)
    }
}

/// Compresses `ssdfs` (row-major `segments x dims`) to `k` components (clamped to at most
/// `min(segments, dims)`), choosing the method by `dims` (see the module docs). `seed` drives
/// the randomized method's test vectors.
pub fn compress(
    ssdfs: &[f32],
    dims: usize,
    k: usize,
    seed: u64,
    cancel: &Cancel,
) -> Result<PcaBasis, PcaError> {
    let method = if dims <= COVARIANCE_EIGEN_MAX_DIMS {
        PcaMethod::CovarianceEigen
    } else {
        PcaMethod::RandomizedRangeFinder
    };
    compress_with(ssdfs, dims, k, method, seed, cancel)
}

/// [`compress`] with the method chosen by the caller.
pub fn compress_with(
    ssdfs: &[f32],
    dims: usize,
    k: usize,
    method: PcaMethod,
    seed: u64,
    cancel: &Cancel,
) -> Result<PcaBasis, PcaError> {
    if dims == 0 || ssdfs.is_empty() {
        return Err(PcaError::Empty);
    }
    if !ssdfs.len().is_multiple_of(dims) {
        return Err(PcaError::LengthMismatch { len: ssdfs.len(), dims });
    }
    if k == 0 {
        return Err(PcaError::NoComponents);
    }
    if let Some(index) = ssdfs.iter().position(|v| !v.is_finite()) {
        return Err(PcaError::NonFinite { index });
    }
    let segments = ssdfs.len() / dims;
    let k = k.min(segments).min(dims);
    let data = Data { values: ssdfs, dims, segments, mean: mean(ssdfs, dims, segments) };
    cancel.check()?;
    let total_square = data.total_square(cancel)?;
    let (basis, kept_square) = match method {
        PcaMethod::CovarianceEigen => covariance_eigen(&data, k, cancel)?,
        PcaMethod::RandomizedRangeFinder => randomized(&data, k, seed, cancel)?,
    };
    let (coefficients, square_error, agree) = data.project(basis.as_ref(), cancel)?;
    let explained_variance =
        if total_square > 0.0 { (kept_square / total_square).clamp(0.0, 1.0) } else { 1.0 };
    let pixels = (segments * dims) as f64;
    let stats = PcaStats {
        method,
        explained_variance,
        rms_error: (square_error / pixels).sqrt(),
        sign_agreement: agree as f64 / pixels,
    };
    let mut components = vec![0.0_f32; k * dims];
    for c in 0..k {
        for p in 0..dims {
            components[c * dims + p] = basis[(p, c)] as f32;
        }
    }
    Ok(PcaBasis {
        dims,
        component_count: k,
        segment_count: segments,
        mean: data.mean.iter().map(|&m| m as f32).collect(),
        components,
        coefficients,
        stats,
    })
}

fn mean(values: &[f32], dims: usize, segments: usize) -> Vec<f64> {
    let mut sum = vec![0.0_f64; dims];
    for row in values.chunks_exact(dims) {
        for (s, &v) in sum.iter_mut().zip(row) {
            *s += f64::from(v);
        }
    }
    sum.iter().map(|s| s / segments as f64).collect()
}

/// The input and its mean; yields centred f64 blocks.
struct Data<'a> {
    values: &'a [f32],
    dims: usize,
    segments: usize,
    mean: Vec<f64>,
}

impl Data<'_> {
    fn blocks(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..self.segments).step_by(BLOCK_ROWS).map(|s| (s, (s + BLOCK_ROWS).min(self.segments)))
    }

    /// Segments `start..end`, centred, as a `(end − start) x dims` matrix.
    fn block(&self, start: usize, end: usize) -> Mat<f64> {
        let d = self.dims;
        Mat::from_fn(end - start, d, |i, j| f64::from(self.values[(start + i) * d + j]) - self.mean[j])
    }

    fn total_square(&self, cancel: &Cancel) -> Result<f64, Cancelled> {
        let mut total = 0.0;
        for row in self.values.chunks_exact(self.dims) {
            total += row.iter().zip(&self.mean).map(|(&v, m)| (f64::from(v) - m).powi(2)).sum::<f64>();
        }
        cancel.check()?;
        Ok(total)
    }

    /// `X R` for the centred data `X` (`segments x dims`) and `R` (`dims x l`).
    fn times(&self, right: MatRef<'_, f64>, cancel: &Cancel) -> Result<Mat<f64>, Cancelled> {
        let mut out = Mat::zeros(self.segments, right.ncols());
        for (start, end) in self.blocks() {
            cancel.check()?;
            let block = self.block(start, end);
            matmul(
                out.as_mut().subrows_mut(start, end - start),
                Accum::Replace,
                block.as_ref(),
                right,
                1.0,
                Par::rayon(0),
            );
        }
        Ok(out)
    }

    /// `Xᵀ L` for the centred data `X` and `L` (`segments x l`).
    fn transpose_times(&self, left: MatRef<'_, f64>, cancel: &Cancel) -> Result<Mat<f64>, Cancelled> {
        let mut out = Mat::zeros(self.dims, left.ncols());
        for (start, end) in self.blocks() {
            cancel.check()?;
            let block = self.block(start, end);
            matmul(
                out.as_mut(),
                Accum::Add,
                block.transpose(),
                left.subrows(start, end - start),
                1.0,
                Par::rayon(0),
            );
        }
        Ok(out)
    }

    /// Coefficients (f32, `segments x K`), squared reconstruction error and the number of
    /// pixels whose reconstruction has the original's sign, for orthonormal `basis` (`dims x K`).
    fn project(&self, basis: MatRef<'_, f64>, cancel: &Cancel) -> Result<(Vec<f32>, f64, usize), Cancelled> {
        let k = basis.ncols();
        let mut coefficients = vec![0.0_f32; self.segments * k];
        let (mut square_error, mut agree) = (0.0, 0_usize);
        for (start, end) in self.blocks() {
            cancel.check()?;
            let block = self.block(start, end);
            let coeffs = &block * basis;
            let recon = &coeffs * basis.transpose();
            for i in 0..end - start {
                for c in 0..k {
                    coefficients[(start + i) * k + c] = coeffs[(i, c)] as f32;
                }
                for p in 0..self.dims {
                    let original = f64::from(self.values[(start + i) * self.dims + p]);
                    let approx = recon[(i, p)] + self.mean[p];
                    square_error += (approx - original).powi(2);
                    agree += usize::from((approx > 0.0) == (original > 0.0));
                }
            }
        }
        Ok((coefficients, square_error, agree))
    }
}

/// Leading `k` eigenvectors of the scatter matrix, and the sum of their eigenvalues.
fn covariance_eigen(data: &Data, k: usize, cancel: &Cancel) -> Result<(Mat<f64>, f64), PcaError> {
    let d = data.dims;
    let mut scatter = Mat::<f64>::zeros(d, d);
    for (start, end) in data.blocks() {
        cancel.check()?;
        let block = data.block(start, end);
        matmul(scatter.as_mut(), Accum::Add, block.transpose(), block.as_ref(), 1.0, Par::rayon(0));
    }
    cancel.check()?;
    let eigen =
        scatter.as_ref().self_adjoint_eigen(Side::Lower).map_err(|e| PcaError::Eigen(format!("{e:?}")))?;
    // Eigenvalues are sorted nondecreasing: the last k, largest first.
    let values = eigen.S().column_vector();
    let vectors = eigen.U();
    let basis = Mat::from_fn(d, k, |i, c| vectors[(i, d - 1 - c)]);
    let kept = (0..k).map(|c| values[d - 1 - c].max(0.0)).sum();
    Ok((basis, kept))
}

/// Orthonormal basis of the column space of `m` (thin Q of its QR).
fn orthonormalize(m: &Mat<f64>) -> Mat<f64> {
    m.as_ref().qr().compute_thin_Q()
}

/// Randomized range finder (see the module docs): `k` leading directions and their variance.
fn randomized(data: &Data, k: usize, seed: u64, cancel: &Cancel) -> Result<(Mat<f64>, f64), PcaError> {
    let l = (k + OVERSAMPLING).min(data.dims).min(data.segments);
    let mut rng = Pcg64::seed_from_u64(seed ^ 0x5EED_F00D_5CA1_AB1E);
    let omega = Mat::from_fn(data.dims, l, |_, _| standard_normal(&mut rng));
    let mut y = data.times(omega.as_ref(), cancel)?;
    for _ in 0..POWER_ITERATIONS {
        let q = orthonormalize(&y);
        let z = orthonormalize(&data.transpose_times(q.as_ref(), cancel)?);
        y = data.times(z.as_ref(), cancel)?;
    }
    let q = orthonormalize(&y);
    let w = data.transpose_times(q.as_ref(), cancel)?;
    let gram = w.transpose() * &w;
    let eigen =
        gram.as_ref().self_adjoint_eigen(Side::Lower).map_err(|e| PcaError::Eigen(format!("{e:?}")))?;
    let values = eigen.S().column_vector();
    let vectors = eigen.U();
    let top = Mat::from_fn(l, k, |i, c| vectors[(i, l - 1 - c)]);
    let directions = &w * &top;
    let basis = orthonormalize(&directions);
    let kept = (0..k).map(|c| values[l - 1 - c].max(0.0)).sum();
    Ok((basis, kept))
}

/// A standard normal sample (Box–Muller).
fn standard_normal(rng: &mut Pcg64) -> f64 {
    let u: f64 = 1.0 - rng.random::<f64>();
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `segments` vectors `mean + Σ a_i u_i` in a random `rank`-dimensional subspace.
    fn low_rank(segments: usize, dims: usize, rank: usize, seed: u64) -> Vec<f32> {
        let mut rng = Pcg64::seed_from_u64(seed);
        let mean: Vec<f64> = (0..dims).map(|_| rng.random_range(-1.0..1.0)).collect();
        let dirs: Vec<Vec<f64>> =
            (0..rank).map(|_| (0..dims).map(|_| standard_normal(&mut rng)).collect()).collect();
        let mut out = Vec::with_capacity(segments * dims);
        for _ in 0..segments {
            let a: Vec<f64> = (0..rank).map(|i| standard_normal(&mut rng) / (1.0 + i as f64)).collect();
            out.extend(
                (0..dims).map(|p| (mean[p] + (0..rank).map(|i| a[i] * dirs[i][p]).sum::<f64>()) as f32),
            );
        }
        out
    }

    fn check_orthonormal(basis: &PcaBasis) -> f64 {
        let mut worst = 0.0_f64;
        for a in 0..basis.component_count {
            for b in 0..basis.component_count {
                let dot: f64 = basis
                    .component(a)
                    .iter()
                    .zip(basis.component(b))
                    .map(|(&x, &y)| f64::from(x) * f64::from(y))
                    .sum();
                worst = worst.max((dot - f64::from(u8::from(a == b))).abs());
            }
        }
        worst
    }

    #[test]
    fn data_in_a_subspace_is_reconstructed_by_both_methods() {
        let (segments, dims, rank) = (1500, 100, 6);
        let data = low_rank(segments, dims, rank, 7);
        for method in [PcaMethod::CovarianceEigen, PcaMethod::RandomizedRangeFinder] {
            let basis = compress_with(&data, dims, 8, method, 1, &Cancel::new()).unwrap();
            let ortho = check_orthonormal(&basis);
            let worst = (0..segments)
                .step_by(37)
                .flat_map(|s| {
                    basis
                        .reconstruct(s)
                        .into_iter()
                        .zip(&data[s * dims..(s + 1) * dims])
                        .map(|(a, &b)| (a - b).abs())
                        .collect::<Vec<_>>()
                })
                .fold(0.0_f32, f32::max);
            eprintln!(
                "{method:?}: stats {:?}, orthonormality error {ortho:e}, worst reconstruction error {worst:e}",
                basis.stats
            );
            assert!(ortho < 1e-6, "{ortho}");
            assert!(basis.stats.rms_error < 1e-5 && worst < 1e-4, "{:?} {worst}", basis.stats);
            assert!((basis.stats.explained_variance - 1.0).abs() < 1e-9);
            assert!(basis.stats.sign_agreement > 1.0 - 1e-12);
        }
    }

    #[test]
    fn both_methods_agree_on_the_leading_components() {
        // Full-rank data with a decaying spectrum: the kept variance must match.
        let (segments, dims) = (800, 64);
        let mut data = low_rank(segments, dims, 40, 3);
        let mut rng = Pcg64::seed_from_u64(9);
        for v in &mut data {
            *v += 1e-3 * standard_normal(&mut rng) as f32;
        }
        let exact = compress_with(&data, dims, 5, PcaMethod::CovarianceEigen, 1, &Cancel::new()).unwrap();
        let approx =
            compress_with(&data, dims, 5, PcaMethod::RandomizedRangeFinder, 1, &Cancel::new()).unwrap();
        eprintln!("exact {:?}\nrandomized {:?}", exact.stats, approx.stats);
        assert!((exact.stats.explained_variance - approx.stats.explained_variance).abs() < 1e-3);
        assert!(
            (exact.stats.rms_error - approx.stats.rms_error).abs() < 1e-3 * exact.stats.rms_error.max(1e-3)
        );
    }

    #[test]
    fn bad_input_is_an_error() {
        let c = Cancel::new();
        assert_eq!(compress(&[], 4, 2, 0, &c), Err(PcaError::Empty));
        assert_eq!(compress(&[1.0; 5], 4, 2, 0, &c), Err(PcaError::LengthMismatch { len: 5, dims: 4 }));
        assert_eq!(compress(&[1.0; 8], 4, 0, 0, &c), Err(PcaError::NoComponents));
        assert_eq!(compress(&[1.0, f32::NAN, 1.0, 1.0], 4, 1, 0, &c), Err(PcaError::NonFinite { index: 1 }));
        let cancelled = Cancel::new();
        cancelled.cancel();
        assert_eq!(compress(&[1.0; 8], 4, 1, 0, &cancelled), Err(PcaError::Cancelled(Cancelled)));
        // k is clamped to min(segments, dims); constant data has zero variance.
        let basis = compress(&[1.0; 8], 4, 10, 0, &c).unwrap();
        assert_eq!(basis.component_count, 2);
        assert!(basis.stats.rms_error < 1e-12 && basis.reconstruct(1) == vec![1.0; 4]);
    }
}
