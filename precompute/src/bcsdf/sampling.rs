//! One-dimensional samplers behind the fiber model: truncated Gaussian and von Mises.
//!
//! How it works:
//! - [`TruncGauss`] draws θ from a normal N(μ, β²) truncated to [-π/2, π/2] by inverting its
//!   CDF. The lower and upper tail masses come from `erfc`, the quantile from Acklam's rational
//!   approximation polished by two Halley steps (so it is as accurate as `erfc`). Since
//!   μ ∈ [-π/2, π/2], at least half the mass lies inside and the inversion is well conditioned;
//!   the upper half is inverted through the complementary CDF to keep relative precision.
//!   Its density is exactly `sqrt(λ/π) exp(-λ(θ-μ)²) / Z` with Z the inside mass.
//! - [`sample_von_mises`] is Best & Fisher's (1979) wrapped-Cauchy rejection sampler, written
//!   with `r - 1` and `1 - f` carried explicitly so it stays accurate for κ up to ~1e6. The first
//!   attempt uses the two uniforms given; rejected attempts (probability ≤ ~1/3) draw further
//!   uniforms from a SplitMix64 stream seeded by the bits of those two, so the result is a
//!   deterministic function of its inputs. The accepted second uniform, rescaled, picks the sign.

use std::f64::consts::{FRAC_PI_2, PI, SQRT_2};

use crate::special::erfc;

/// Standard normal CDF Φ(x).
pub(crate) fn normal_cdf(x: f64) -> f64 {
    0.5 * erfc(-x / SQRT_2)
}

/// Quantile of the standard normal for `p ∈ [0, 0.5]` (lower half only: callers reflect).
pub(crate) fn normal_quantile_lower(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e+01,
        2.209460984245205e+02,
        -2.759285104469687e+02,
        1.383577518672690e+02,
        -3.066479806614716e+01,
        2.506628277459239e+00,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e+01,
        1.615858368580409e+02,
        -1.556989798598866e+02,
        6.680131188771972e+01,
        -1.328068155288572e+01,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-03,
        -3.223964580411365e-01,
        -2.400758277161838e+00,
        -2.549732539343734e+00,
        4.374664141464968e+00,
        2.938163982698783e+00,
    ];
    const D: [f64; 4] =
        [7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00, 3.754408661907416e+00];
    if p <= 0.0 {
        return f64::NEG_INFINITY;
    }
    let p = p.min(0.5);
    let mut x = if p < 0.02425 {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    };
    if p > 1e-306 {
        for _ in 0..2 {
            let e = normal_cdf(x) - p;
            let u = e * (2.0 * PI).sqrt() * (0.5 * x * x).exp();
            x -= u / (1.0 + 0.5 * x * u);
        }
    }
    x
}

/// A normal distribution N(μ, β²) truncated to θ ∈ [-π/2, π/2].
#[derive(Debug, Clone, Copy)]
pub(crate) struct TruncGauss {
    mu: f64,
    beta: f64,
    /// Φ(lo): mass below -π/2.
    below: f64,
    /// 1 - Φ(hi): mass above π/2.
    above: f64,
    /// Mass inside, `1 - below - above` (≥ 1/2 for μ inside the interval).
    inside: f64,
}

impl TruncGauss {
    pub(crate) fn new(mu: f64, beta: f64) -> Self {
        let below = normal_cdf((-FRAC_PI_2 - mu) / beta);
        let above = normal_cdf((mu - FRAC_PI_2) / beta);
        Self { mu, beta, below, above, inside: 1.0 - below - above }
    }

    /// Maps `u ∈ [0, 1)` to θ ∈ [-π/2, π/2].
    pub(crate) fn sample(&self, u: f64) -> f64 {
        let p = self.below + u * self.inside;
        let x = if p <= 0.5 {
            normal_quantile_lower(p)
        } else {
            -normal_quantile_lower(self.above + (1.0 - u) * self.inside)
        };
        (self.mu + self.beta * x).clamp(-FRAC_PI_2, FRAC_PI_2)
    }

    /// Density in θ (zero outside [-π/2, π/2]).
    pub(crate) fn pdf(&self, theta: f64) -> f64 {
        if theta.abs() > FRAC_PI_2 {
            return 0.0;
        }
        let z = (theta - self.mu) / self.beta;
        (-0.5 * z * z).exp() / (self.beta * (2.0 * PI).sqrt() * self.inside)
    }
}

/// Precomputed constants of Best & Fisher's sampler for one κ.
#[derive(Debug, Clone, Copy)]
pub(crate) struct VonMises {
    kappa: f64,
    /// 1 / (2π i0e(κ)), the density's normalization.
    norm: f64,
    /// r - 1, where r = (1 + ρ²) / (2ρ) is the wrapped-Cauchy envelope's parameter.
    r_minus_1: f64,
}

impl VonMises {
    pub(crate) fn new(kappa: f64) -> Self {
        debug_assert!(kappa > 1e-3, "kappa = {kappa}");
        let s = (1.0 + 4.0 * kappa * kappa).sqrt();
        let tau = 1.0 + s;
        // 1 - ρ with ρ = (τ - sqrt(2τ)) / (2κ), without cancellation.
        let one_minus_rho = ((2.0 * tau).sqrt() - 1.0 - 1.0 / (s + 2.0 * kappa)) / (2.0 * kappa);
        let rho = 1.0 - one_minus_rho;
        Self {
            kappa,
            norm: 1.0 / (2.0 * PI * crate::special::i0e(kappa)),
            r_minus_1: one_minus_rho * one_minus_rho / (2.0 * rho),
        }
    }

    /// Density `exp(κ (cos x - 1)) / (2π i0e(κ))` of the angle x (never overflows).
    pub(crate) fn pdf(&self, x: f64) -> f64 {
        (self.kappa * (x.cos() - 1.0)).exp() * self.norm
    }

    /// Draws an angle in [-π, π] with density [`Self::pdf`] from two uniforms.
    pub(crate) fn sample(&self, u1: f64, u2: f64) -> f64 {
        let (mut u1, mut u2) = (u1, u2);
        let mut rng = SplitMix64(u1.to_bits() ^ u2.to_bits().rotate_left(29) ^ 0x5851_f42d_4c95_7f2d);
        for _ in 0..1000 {
            let h = 0.5 * PI * u1;
            let (one_plus_z, one_minus_z) = (2.0 * h.cos() * h.cos(), 2.0 * h.sin() * h.sin());
            let d = self.r_minus_1;
            // f = (1 + r z) / (r + z);  1 - f = (r - 1)(1 - z) / (r + z).
            let one_minus_f = d * one_minus_z / (d + one_plus_z);
            let c = self.kappa * (d + one_minus_f);
            let accept = c * (1.0 - c).exp();
            if u2 <= accept {
                let angle = 2.0 * (0.5 * one_minus_f).sqrt().min(1.0).asin();
                return if u2 < 0.5 * accept { -angle } else { angle };
            }
            u1 = rng.next_f64();
            u2 = rng.next_f64();
        }
        0.0
    }
}

struct SplitMix64(u64);

impl SplitMix64 {
    fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantile_inverts_the_cdf_to_rounding() {
        for p in [1e-300, 1e-100, 1e-20, 1e-8, 0.001, 0.02, 0.02425, 0.1, 0.3, 0.4999, 0.5] {
            let x = normal_quantile_lower(p);
            let back = normal_cdf(x);
            assert!((back / p - 1.0).abs() < 1e-12, "p = {p}: x = {x}, Φ(x) = {back}");
        }
        assert!((normal_quantile_lower(0.5)).abs() < 1e-15);
        assert!(normal_quantile_lower(0.0).is_infinite() && normal_quantile_lower(0.0) < 0.0);
    }

    #[test]
    fn truncated_gauss_cdf_of_sample_is_linear_in_u() {
        // The sampler is the exact inverse CDF: ∫_{-π/2}^{θ(u)} pdf = u.
        let rule = crate::quadrature::gauss_legendre_pairs(16);
        for (mu, beta_deg) in [(0.0, 0.5), (FRAC_PI_2, 0.5), (-FRAC_PI_2, 2.0), (1.2, 60.0), (-0.3, 10.0)] {
            let tg = TruncGauss::new(mu, f64::to_radians(beta_deg));
            for u in [1e-9, 0.01, 0.3, 0.5, 0.77, 0.999, 1.0 - 1e-9] {
                let th = tg.sample(u);
                let b = crate::quadrature::graded_breaks(-FRAC_PI_2, th, mu, tg.beta);
                let mass = crate::quadrature::integrate_panels(&rule, &b, |t| tg.pdf(t));
                assert!((mass - u).abs() < 1e-11, "mu {mu} beta {beta_deg}: u {u} -> θ {th}, mass {mass}");
            }
        }
    }
}
