//! Local visibility at render time (paper 5.2): the SSDF lookup, its hard and soft steps, the
//! sum-of-SGs product with an SG light, and the blend between the two for SG lights.
//!
//! How it works:
//! - **SSDF lookup** ([`ssdf_lookup`]): the PCA reconstruction `d(p) = mean[p] + Σ_c a_c
//!   comp_c[p]` (f32 data, summed in f64), interpolated **bilinearly between pixel centres**
//!   of the `n × n` (θ, φ) image of `bake::svf`: for a unit direction
//!   `θ = atan2(sqrt(x² + y²), z)` ∈ [0, π], `φ = atan2(y, x)` (+2π if negative) ∈ [0, 2π],
//!   row coordinate `u = θ n/π − ½` **clamped** to [0, n − 1] (so within half a pixel of a pole
//!   the first/last row is used alone in θ), column coordinate `v = φ n/(2π) − ½`, **wrapped**
//!   (columns `floor(v) mod n` and `floor(v) + 1 mod n`, `v = −½` near φ = 0 interpolates
//!   between the last and the first column). Rows `r0 = min(floor(u), n − 2)`, `r1 = r0 + 1`
//!   (`r0 = r1 = 0` for n = 1), weights `fu = u − r0`, `fv = v − floor(v)`:
//!   `d = (1−fu)((1−fv) d[r0,c0] + fv d[r0,c1]) + fu((1−fv) d[r1,c0] + fv d[r1,c1])`.
//! - **Kept binary images** ([`bits_lookup`], with `BakeSettings::visibility_bits`): the
//!   image's bits, 1 visible and 0 occluded, bilinear between pixel centres exactly as the
//!   SSDF: the visible fraction toward the direction, in [0, 1].
//! - **Hard step** (directional lights, [`ssdf_step_visibility`]): 1 where `d > 0` (visible),
//!   0 where `d ≤ 0` or NaN.
//! - **Soft step** (sharp SG lights, [`erf_soft_visibility`]): `½[erf(sqrt(λ/2) d) + 1]`,
//!   evaluated as `½ erfc(−sqrt(λ/2) d)` so a deep shadow keeps its relative precision.
//! - **Sum of SGs** ([`sum_of_sg_path`]): `Σ_q w_q/M(λ_svf) · Γ(p_q/|p_q|, |p_q|, ωo) ·
//!   exp(−(λ_svf + λ − |p_q|))` with `p_q = λ_svf ξ_q + λ ξ`, the exponent's argument computed
//!   as `λ_svf λ |ξ_q − ξ|² / (λ_svf + λ + |p_q|)` (no cancellation, as `sg::sg_product`);
//!   zero weights are skipped, so a fully occluded segment gives exactly 0.
//! - **Where the SGs stand** ([`sos_centroid_share`]): each SG at the centroid of the visible
//!   directions it holds (`bake::sum_of_sg`, which keeps a light broader than a cell from
//!   meeting visible mass moved across a visibility edge), or at its Fibonacci axis (cells on
//!   fixed bands of elevation, turned at random about z per segment, whose positions sample a
//!   light narrower than a cell without favouring any elevation: the centroids of the cells
//!   that straddle the horizon gather on one band, and an SG light of λ 58 at 11.5° above the
//!   horizon came out 10 points darker on them). Both paths are [`sum_of_sg_path`] over the
//!   same weights; [`sos_centroid_share`] takes the centroids alone while the light covers 8
//!   cells or more, the Fibonacci axes alone from a light the size of one cell, a smoothstep in
//!   the log of the ratio between.
//! - **Blend** ([`sg_path_weights`]): `b = 0` for λ ≤ 100, 1 for λ ≥ 200, `(λ − 100)/100`
//!   between; the sum-of-SGs path has weight 1 − b and the erf-SSDF path weight b.

use std::f64::consts::PI;

use glam::DVec3;

use super::bcsdf::FiberConstants;
use super::gamma::gamma;
use crate::Rgb;
use crate::bake::pca::PcaBasis;
use crate::bake::svf::VisibilityImages;
use crate::bake::tables::GnTable;
use crate::sg::sg_mass;
use crate::special::erfc;

/// Below this sharpness SG lights use only the sum-of-SGs visibility.
pub const SUM_OF_SG_ONLY_BELOW: f64 = 100.0;
/// Above this sharpness SG lights use only the erf-SSDF visibility.
pub const SSDF_ONLY_ABOVE: f64 = 200.0;

/// `(w_sos, w_ssdf)`: the weights of the sum-of-SGs and the erf-SSDF single-scattering paths
/// for an SG light of sharpness `lambda` (paper 5.2.2; they add up to 1). A renderer runs a
/// path only when its weight is nonzero. NaN gives the sum-of-SGs path alone.
#[must_use]
pub fn sg_path_weights(lambda: f64) -> (f64, f64) {
    let b = if lambda >= SSDF_ONLY_ABOVE {
        1.0
    } else if lambda > SUM_OF_SG_ONLY_BELOW {
        (lambda - SUM_OF_SG_ONLY_BELOW) / (SSDF_ONLY_ABOVE - SUM_OF_SG_ONLY_BELOW)
    } else {
        0.0
    };
    (1.0 - b, b)
}

/// Ratio of a sum-of-SGs cell's solid angle `4π/Q` to an SG light's `2π/λ` at and below which
/// the sum of SGs stands at its centroids alone ([`sos_centroid_share`]).
pub const SOS_CENTROIDS_ONLY_BELOW: f64 = 0.125;
/// The ratio at and above which it stands at its Fibonacci axes alone.
pub const SOS_FIBONACCI_ONLY_ABOVE: f64 = 1.0;

/// The share of the sum-of-SGs path taken with each SG at the centroid of its visible
/// directions (the rest at its Fibonacci axis) for an SG light of sharpness `lambda` and a sum
/// of `count` SGs: with `r = (4π/Q) / (2π/λ) = 2λ/Q`, 1 for `r ≤` [`SOS_CENTROIDS_ONLY_BELOW`],
/// 0 for `r ≥` [`SOS_FIBONACCI_ONLY_ABOVE`], `1 − smoothstep` of `ln r` between (at Q = 64: λ 4
/// and 32). See the module docs. NaN gives the centroids.
#[must_use]
pub fn sos_centroid_share(lambda: f64, count: usize) -> f64 {
    let ratio = 2.0 * lambda / count.max(1) as f64;
    if ratio.is_nan() || ratio <= SOS_CENTROIDS_ONLY_BELOW {
        return 1.0;
    }
    if ratio >= SOS_FIBONACCI_ONLY_ABOVE {
        return 0.0;
    }
    let x =
        (ratio / SOS_CENTROIDS_ONLY_BELOW).ln() / (SOS_FIBONACCI_ONLY_ABOVE / SOS_CENTROIDS_ONLY_BELOW).ln();
    1.0 - x * x * (3.0 - 2.0 * x)
}

/// The pixel (row, column) grid coordinates of a unit direction in an `n × n` image, before
/// clamping and wrapping: `(θ n/π − ½, φ n/(2π) − ½)`.
#[must_use]
pub fn ssdf_grid_coordinates(n: usize, dir: DVec3) -> (f64, f64) {
    let theta = dir.x.hypot(dir.y).atan2(dir.z);
    let mut phi = dir.y.atan2(dir.x);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    let nf = n as f64;
    (theta * nf / PI - 0.5, phi * nf / (2.0 * PI) - 0.5)
}

/// The PCA-reconstructed SSDF of `segment` at pixel `pixel` (row-major), f32 data summed in f64.
#[must_use]
pub fn ssdf_pixel(ssdf: &PcaBasis, segment: usize, pixel: usize) -> f64 {
    let coefficients = ssdf.coefficients(segment);
    let components = ssdf.components();
    let mut d = f64::from(ssdf.mean()[pixel]);
    for (c, &a) in coefficients.iter().enumerate() {
        d += f64::from(a) * f64::from(components[c * ssdf.dims + pixel]);
    }
    d
}

/// The value at the unit direction `dir` of an `n x n` image whose pixel `p` (row-major) holds
/// `pixel(p)`, bilinear between pixel centres, φ wrapping and θ clamped (see the module docs).
#[must_use]
pub fn bilinear_over_pixel_centres(n: usize, dir: DVec3, pixel: impl Fn(usize) -> f64) -> f64 {
    let (u, v) = ssdf_grid_coordinates(n, dir);
    let u = u.clamp(0.0, (n - 1) as f64);
    let r0 = (u.floor() as usize).min(n.saturating_sub(2));
    let r1 = (r0 + 1).min(n - 1);
    let fu = u - r0 as f64;
    let v0 = v.floor();
    let fv = v - v0;
    let c0 = (v0 as i64).rem_euclid(n as i64) as usize;
    let c1 = (c0 + 1) % n;
    let d = |r: usize, c: usize| pixel(r * n + c);
    (1.0 - fu) * ((1.0 - fv) * d(r0, c0) + fv * d(r0, c1)) + fu * ((1.0 - fv) * d(r1, c0) + fv * d(r1, c1))
}

/// `d_k(dir)`: the SSDF of `segment` (radians, positive where visible) toward the unit
/// direction `dir`, bilinear between pixel centres (see the module docs).
#[must_use]
pub fn ssdf_lookup(ssdf: &PcaBasis, segment: usize, dir: DVec3) -> f64 {
    bilinear_over_pixel_centres(ssdf.dims.isqrt(), dir, |p| ssdf_pixel(ssdf, segment, p))
}

/// The visible fraction of image `image` of `images` toward the unit direction `dir`: its
/// bits (1 visible, 0 occluded) bilinear between pixel centres as [`ssdf_lookup`], in
/// [0, 1]. A light between pixel centres takes its neighbours' visibility by how near it is
/// to each, so a shadow edge moves smoothly with the light rather than in pixel steps.
#[must_use]
pub fn bits_lookup(images: &VisibilityImages, image: usize, dir: DVec3) -> f64 {
    bilinear_over_pixel_centres(images.resolution, dir, |p| f64::from(u8::from(images.get_pixel(image, p))))
}

/// The hard step of a directional light: 1 where the SSDF says visible (`d > 0`), else 0.
#[must_use]
pub fn ssdf_step_visibility(d: f64) -> f64 {
    if d > 0.0 { 1.0 } else { 0.0 }
}

/// The soft step of a sharp SG light: `½[erf(sqrt(λ/2) d) + 1] = ½ erfc(−sqrt(λ/2) d)`.
#[must_use]
pub fn erf_soft_visibility(d: f64, lambda: f64) -> f64 {
    0.5 * erfc(-(0.5 * lambda).sqrt() * d)
}

/// The sum-of-SGs path: `∫ V^ssg(ωi) G(ωi; ξ, λ) S(ωi, ωo) cos θi dωi` for the unnormalized
/// SG (ξ unit, λ ≥ 0), with `V^ssg = Σ_q w_q G(·; axes[q], λ_svf)/M(λ_svf)`; see the module
/// docs. `weights` and `axes` pair up (extra entries of the longer are ignored).
#[must_use]
pub fn sum_of_sg_path(
    fiber: &FiberConstants,
    gn: &GnTable,
    t: DVec3,
    wo: DVec3,
    axes: &[DVec3],
    weights: &[f32],
    lambda_svf: f64,
    xi: DVec3,
    lambda: f64,
) -> Rgb {
    let inv_mass = 1.0 / sg_mass(lambda_svf);
    let mut total = Rgb::ZERO;
    for (&axis, &w) in axes.iter().zip(weights) {
        if w == 0.0 {
            continue;
        }
        let p = lambda_svf * axis + lambda * xi;
        let sharpness = p.length();
        let loss = lambda_svf * lambda * (axis - xi).length_squared() / (lambda_svf + lambda + sharpness);
        let product_axis = if sharpness > 0.0 { p / sharpness } else { axis };
        total += gamma(fiber, gn, t, product_axis, sharpness, wo) * (f64::from(w) * inv_mass * (-loss).exp());
    }
    total
}
