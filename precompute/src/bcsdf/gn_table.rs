//! The longitudinal normalizer `Gn(μ; λ) = sqrt(λ/π) ∫_{-π/2}^{π/2} exp(-λ(θ-μ)²) cos²θ dθ`.
//!
//! How it works: Gn is even in μ, so the table covers μ ∈ [0, π/2] (which is the table over
//! [-π/2, π/2] at twice the resolution). Every node holds Gn and dGn/dμ computed by 16-point
//! Gauss–Legendre on panels 2β wide over the Gaussian's support μ ± 14β (clipped to
//! [-π/2, π/2]); that is exact to rounding for every β the model accepts, 0.5° included.
//! Lookups use cubic Hermite interpolation with those exact derivatives (C¹, fourth order).
//! Near the poles Gn falls to about β²/2 (3.8e-5 at β = 0.5°); the table resolves that
//! region with ≥ 10 nodes per β, and lookups are clamped to stay positive.

use std::f64::consts::{FRAC_PI_2, PI};

use crate::quadrature::{gauss_legendre_pairs, integrate_panels};

/// Number of intervals over μ ∈ [0, π/2].
pub const GN_TABLE_INTERVALS: usize = 2048;

/// Tabulated `Gn(·; λ)` for one lobe width.
#[derive(Debug, Clone)]
pub struct GnTable {
    step: f64,
    values: Vec<f64>,
    slopes: Vec<f64>,
}

impl GnTable {
    /// Builds the table for lobe width `beta` (radians, `λ = 1/(2β²)`).
    #[must_use]
    pub fn new(beta: f64) -> Self {
        let rule = gauss_legendre_pairs(16);
        let step = FRAC_PI_2 / GN_TABLE_INTERVALS as f64;
        let (values, slopes) =
            (0..=GN_TABLE_INTERVALS).map(|k| gn_direct_with_rule(&rule, k as f64 * step, beta)).unzip();
        Self { step, values, slopes }
    }

    /// `Gn(μ)`, for any μ (clamped to [-π/2, π/2]); always positive.
    #[must_use]
    pub fn eval(&self, mu: f64) -> f64 {
        let m = mu.abs().min(FRAC_PI_2);
        let x = m / self.step;
        let k = (x as usize).min(GN_TABLE_INTERVALS - 1);
        let t = x - k as f64;
        let (p0, p1) = (self.values[k], self.values[k + 1]);
        let (d0, d1) = (self.slopes[k] * self.step, self.slopes[k + 1] * self.step);
        let t2 = t * t;
        let t3 = t2 * t;
        let v = (2.0 * t3 - 3.0 * t2 + 1.0) * p0
            + (t3 - 2.0 * t2 + t) * d0
            + (-2.0 * t3 + 3.0 * t2) * p1
            + (t3 - t2) * d1;
        // Hermite interpolation of a positive, smooth function on nodes ≤ β/10 apart cannot go
        // far; the floor only guards the division downstream.
        v.max(0.5 * p0.min(p1))
    }

    /// Node values `Gn(k·π/(2·GN_TABLE_INTERVALS))`, `k = 0..=GN_TABLE_INTERVALS`.
    #[must_use]
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Exact node slopes `dGn/dμ` at the same nodes.
    #[must_use]
    pub fn slopes(&self) -> &[f64] {
        &self.slopes
    }
}

/// `(Gn(μ), dGn/dμ)` by direct quadrature (the reference the table is measured against).
#[cfg(test)]
pub(crate) fn gn_direct(mu: f64, beta: f64) -> (f64, f64) {
    gn_direct_with_rule(&gauss_legendre_pairs(16), mu, beta)
}

fn gn_direct_with_rule(rule: &[(f64, f64)], mu: f64, beta: f64) -> (f64, f64) {
    let lam = 0.5 / (beta * beta);
    let lo = (mu - 14.0 * beta).max(-FRAC_PI_2);
    let hi = (mu + 14.0 * beta).min(FRAC_PI_2);
    let panels = ((hi - lo) / (2.0 * beta)).ceil().max(1.0) as usize;
    let breaks: Vec<f64> = (0..=panels).map(|k| lo + (hi - lo) * k as f64 / panels as f64).collect();
    let norm = (lam / PI).sqrt();
    let gauss = |th: f64| (-lam * (th - mu) * (th - mu)).exp() * th.cos() * th.cos();
    let v = integrate_panels(rule, &breaks, gauss);
    let d = integrate_panels(rule, &breaks, |th| 2.0 * lam * (th - mu) * gauss(th));
    (norm * v, norm * d)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn max_rel_error(beta_deg: f64) -> (f64, f64) {
        let beta = beta_deg.to_radians();
        let table = GnTable::new(beta);
        let mut worst = (0.0, 0.0);
        // Off-node points everywhere, densely near the pole where Gn is tiny.
        let mut mus: Vec<f64> =
            (0..4000u32).map(|k| -FRAC_PI_2 + PI * (f64::from(k) + 0.37) / 4000.0).collect();
        mus.extend(
            (0..2000u32).map(|k| FRAC_PI_2 - (20.0 * beta).min(FRAC_PI_2) * (f64::from(k) + 0.61) / 2000.0),
        );
        mus.extend([FRAC_PI_2, -FRAC_PI_2, 0.0]);
        for mu in mus {
            let exact = gn_direct(mu, beta).0;
            let err = (table.eval(mu) / exact - 1.0).abs();
            if err > worst.0 {
                worst = (err, mu);
            }
        }
        worst
    }

    #[test]
    fn table_matches_direct_quadrature_including_the_poles() {
        for beta_deg in [0.5, 2.0, 10.0, 60.0] {
            let (err, at) = max_rel_error(beta_deg);
            println!("beta = {beta_deg} deg: max rel error {err:.3e} at mu = {at:.6}");
            assert!(err < 1e-7, "beta = {beta_deg}: {err:e} at mu = {at}");
        }
    }

    #[test]
    fn quadrature_matches_the_untruncated_closed_form_and_the_pole_asymptote() {
        // Away from the poles the truncation is > 9 sigma away: Gn = (1 + e^{-1/λ} cos 2μ)/2.
        for (beta_deg, mu) in [(10.0f64, 0.0f64), (2.0, 0.7), (0.5, -1.2), (5.0, 0.3)] {
            let beta = beta_deg.to_radians();
            let lam = 0.5 / (beta * beta);
            let closed = 0.5 * (1.0 + (-1.0 / lam).exp() * (2.0 * mu).cos());
            let (v, _) = gn_direct(mu, beta);
            assert!((v / closed - 1.0).abs() < 1e-13, "{beta_deg} {mu}: {v} vs {closed}");
        }
        // At the pole, Gn -> E[x² ; half-normal]/… = β²/2 (1 - O(β²)).
        let beta = 0.5f64.to_radians();
        let (v, _) = gn_direct(FRAC_PI_2, beta);
        assert!((v / (0.5 * beta * beta) - 1.0).abs() < 1e-4, "{v}");
        // math-notes: about 6e-4 at β = 2°.
        let (v2, _) = gn_direct(FRAC_PI_2, 2.0f64.to_radians());
        assert!((v2 - 6.1e-4).abs() < 0.2e-4, "{v2}");
    }
}
