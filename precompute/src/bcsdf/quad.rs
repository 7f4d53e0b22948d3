//! Gauss–Legendre quadrature on panels, used to build the Gn table and by the tests.
//!
//! How it works: the nodes of an n-point rule on [-1, 1] come from Newton's method on the
//! Legendre recurrence (converged to machine precision); [`integrate_panels`] maps the rule onto
//! each interval between consecutive breakpoints. Callers put breakpoints where the integrand
//! changes scale (a lobe centre, multiples of its width) so a fixed rule is exact to rounding.

use std::f64::consts::PI;

/// Nodes and weights of the `n`-point Gauss–Legendre rule on `[-1, 1]`.
pub(crate) fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    let mut rule = Vec::with_capacity(n);
    let nf = n as f64;
    for i in 0..n {
        let mut x = (PI * (i as f64 + 0.75) / (nf + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            // P_n(x) and P_n'(x) by the three-term recurrence.
            let (mut p0, mut p1) = (1.0, x);
            for k in 2..=n {
                let kf = k as f64;
                let p2 = ((2.0 * kf - 1.0) * x * p1 - (kf - 1.0) * p0) / kf;
                p0 = p1;
                p1 = p2;
            }
            let pn = if n == 0 { 1.0 } else { p1 };
            let pn1 = if n == 1 { 1.0 } else { p0 };
            dp = nf * (x * pn - pn1) / (x * x - 1.0);
            let dx = pn / dp;
            x -= dx;
            if dx.abs() < 1e-16 {
                break;
            }
        }
        rule.push((x, 2.0 / ((1.0 - x * x) * dp * dp)));
    }
    rule
}

/// `∫ f` over `[breaks[0], breaks[last]]`, applying `rule` on every panel between consecutive
/// breakpoints (which must be sorted).
pub(crate) fn integrate_panels(rule: &[(f64, f64)], breaks: &[f64], mut f: impl FnMut(f64) -> f64) -> f64 {
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
#[cfg(test)]
pub(crate) fn graded_breaks(lo: f64, hi: f64, centre: f64, width: f64) -> Vec<f64> {
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
        let rule = gauss_legendre(16);
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
}
