//! Gauss–Legendre quadrature, plain and on panels: SH projection, the fiber model's Gn table
//! and the tests' reference integrals all use it.
//!
//! How it works: the nodes of an n-point rule on [-1, 1] come from Newton's method on the
//! Legendre recurrence (converged to machine precision); [`integrate_panels`] maps the rule onto
//! each interval between consecutive breakpoints. Callers put breakpoints where the integrand
//! changes scale (a lobe centre, multiples of its width) so a fixed rule is exact to rounding.

use std::f64::consts::PI;

/// Gauss–Legendre nodes and weights on `[-1, 1]` (`n >= 1` nodes, exact for polynomials of
/// degree `<= 2n - 1`), by Newton iteration on `P_n` from Tricomi-style initial guesses.
/// Nodes are in decreasing order.
#[must_use]
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    assert!(n >= 1, "gauss_legendre: need at least one node");
    let nf = n as f64;
    let mut nodes = vec![0.0; n];
    let mut weights = vec![0.0; n];
    for i in 0..n.div_ceil(2) {
        let mut x = (PI * (i as f64 + 0.75) / (nf + 0.5)).cos();
        let mut dp = 1.0;
        for iteration in 0..100 {
            // P_n(x) and P_{n-1}(x) by the three-term recurrence.
            let (mut p_prev, mut p) = (1.0, x);
            for k in 2..=n {
                let kf = k as f64;
                (p_prev, p) = (p, ((2.0 * kf - 1.0) * x * p - (kf - 1.0) * p_prev) / kf);
            }
            if n == 1 {
                p_prev = 1.0;
            }
            dp = nf * (x * p - p_prev) / (x * x - 1.0);
            let dx = p / dp;
            x -= dx;
            if dx.abs() < 1e-16 || iteration == 99 {
                break;
            }
        }
        nodes[i] = x;
        nodes[n - 1 - i] = -x;
        let w = 2.0 / ((1.0 - x * x) * dp * dp);
        weights[i] = w;
        weights[n - 1 - i] = w;
    }
    (nodes, weights)
}

/// [`gauss_legendre`] as `(node, weight)` pairs.
#[must_use]
pub fn gauss_legendre_pairs(n: usize) -> Vec<(f64, f64)> {
    let (nodes, weights) = gauss_legendre(n);
    nodes.into_iter().zip(weights).collect()
}

/// `∫ f` over `[breaks[0], breaks[last]]`, applying `rule` on every panel between consecutive
/// breakpoints (which must be sorted).
pub fn integrate_panels(rule: &[(f64, f64)], breaks: &[f64], mut f: impl FnMut(f64) -> f64) -> f64 {
    let mut sum = 0.0;
    for w in breaks.windows(2) {
        let (a, b) = (w[0], w[1]);
        let (mid, half) = (0.5 * (a + b), 0.5 * (b - a));
        let mut panel = 0.0;
        for &(x, wt) in rule {
            panel += wt * f(mid + half * x);
        }
        sum += half * panel;
    }
    sum
}

/// Breakpoints on `[lo, hi]` graded around `centre`: `centre ± width·{0.5, 1, 2, 4, ...}`, so
/// panels are about `width` wide near the centre and double in size away from it.
#[must_use]
pub fn graded_breaks(lo: f64, hi: f64, centre: f64, width: f64) -> Vec<f64> {
    let mut b = vec![lo, hi];
    if centre > lo && centre < hi {
        b.push(centre);
    }
    let mut d = 0.5 * width;
    while d < hi - lo {
        for x in [centre - d, centre + d] {
            if x > lo && x < hi {
                b.push(x);
            }
        }
        d *= 2.0;
    }
    b.sort_by(f64::total_cmp);
    b.dedup_by(|a, b| (*a - *b).abs() < 1e-14);
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gauss_legendre_integrates_polynomials_and_gaussians_exactly() {
        let rule = gauss_legendre_pairs(16);
        let wsum: f64 = rule.iter().map(|r| r.1).sum();
        assert!((wsum - 2.0).abs() < 1e-14);
        // Exact for degree 31.
        let v = integrate_panels(&rule, &[-1.0, 1.0], |x| x.powi(30));
        assert!((v - 2.0 / 31.0).abs() < 1e-14, "{v}");
        // A narrow Gaussian with graded panels.
        let s = 1e-3;
        let b = graded_breaks(-1.0, 1.0, 0.3, s);
        let v = integrate_panels(&rule, &b, |x| (-(x - 0.3) * (x - 0.3) / (2.0 * s * s)).exp());
        let exact = s * (2.0 * PI).sqrt();
        assert!((v / exact - 1.0).abs() < 1e-13, "{v} {exact}");
    }

    #[test]
    fn gauss_legendre_integrates_polynomials_exactly() {
        for n in [1_usize, 2, 5, 16, 40] {
            let (nodes, weights) = gauss_legendre(n);
            for degree in 0..2 * n {
                let got: f64 = nodes.iter().zip(&weights).map(|(x, w)| w * x.powi(degree as i32)).sum();
                let exact = if degree % 2 == 1 { 0.0 } else { 2.0 / (degree as f64 + 1.0) };
                assert!((got - exact).abs() < 1e-14, "n = {n}, degree {degree}: {got} vs {exact}");
            }
        }
    }
}
