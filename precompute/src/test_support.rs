//! Test-only support shared by every module's tests: random unit vectors and Pearson's
//! chi-square test of a direction sampler against its pdf.
//!
//! How it works: directions are binned in (θ, φ) of a test frame (θ from the plane normal to
//! the frame axis, so each bin is a (sin θ, φ) rectangle); expected counts integrate the pdf
//! over every bin with 6×6 Gauss–Legendre (bins are chosen narrower than the lobes). Samples
//! the sampler declined (`None`) form one more category, expected `N (1 - ∫pdf)`. Categories
//! expecting fewer than 5 samples are pooled into one; the p-value is the chi-square upper
//! tail `Q(dof/2, X²/2)` (regularized incomplete gamma, Numerical Recipes style).

use std::f64::consts::PI;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use crate::quadrature::gauss_legendre_pairs;

/// A uniformly distributed unit vector (rejection from the cube; deterministic for a seed).
pub(crate) fn random_unit(rng: &mut Pcg64) -> DVec3 {
    loop {
        let v = DVec3::new(rng.random::<f64>(), rng.random::<f64>(), rng.random::<f64>()) * 2.0 - 1.0;
        let len2 = v.length_squared();
        if len2 > 1e-4 && len2 <= 1.0 {
            return v / len2.sqrt();
        }
    }
}

/// An orthonormal test frame chosen independently of the code under test.
#[derive(Debug, Clone, Copy)]
pub(crate) struct TestFrame {
    pub axis: DVec3,
    pub e1: DVec3,
    pub e2: DVec3,
}

impl TestFrame {
    pub(crate) fn new(axis: DVec3) -> Self {
        let axis = axis.normalize();
        let other = if axis.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
        let e1 = axis.cross(other).normalize();
        Self { axis, e1, e2: axis.cross(e1) }
    }

    pub(crate) fn dir(&self, theta: f64, phi: f64) -> DVec3 {
        theta.sin() * self.axis + theta.cos() * (phi.cos() * self.e1 + phi.sin() * self.e2)
    }

    pub(crate) fn angles(&self, w: DVec3) -> (f64, f64) {
        let (x, y) = (w.dot(self.e1), w.dot(self.e2));
        (w.dot(self.axis).atan2(x.hypot(y)), y.atan2(x))
    }
}

/// Sorted bin edges over `[lo, hi]`: `n_uniform` equal bins refined to half-widths `w/2`
/// within `±6 w` of `centre` for every `w` in `widths`.
pub(crate) fn lobe_edges(lo: f64, hi: f64, centre: f64, widths: &[f64], n_uniform: usize) -> Vec<f64> {
    let mut e: Vec<f64> = (0..=n_uniform).map(|k| lo + (hi - lo) * k as f64 / n_uniform as f64).collect();
    for &w in widths {
        for k in -12i32..=12 {
            let x = centre + 0.5 * w * f64::from(k);
            if x > lo && x < hi {
                e.push(x);
            }
        }
    }
    e.sort_by(f64::total_cmp);
    e.dedup_by(|a, b| (*a - *b).abs() < 1e-7);
    e
}

#[derive(Debug)]
pub(crate) struct Chi2 {
    pub p_value: f64,
    pub dof: usize,
    pub stat: f64,
    /// ∫ pdf over the sphere by the bin quadrature.
    pub pdf_mass: f64,
}

/// Chi-square test of `sample` against `pdf`; `phi_edges` must span exactly 2π.
pub(crate) fn chi2_test(
    frame: TestFrame,
    theta_edges: &[f64],
    phi_edges: &[f64],
    n_samples: usize,
    seed: u64,
    mut sample: impl FnMut(&mut Pcg64) -> Option<DVec3>,
    pdf: impl Fn(DVec3) -> f64,
) -> Chi2 {
    let (nt, np) = (theta_edges.len() - 1, phi_edges.len() - 1);
    let phi0 = phi_edges[0];
    assert!((phi_edges[np] - phi0 - 2.0 * PI).abs() < 1e-12);
    let mut observed = vec![0.0f64; nt * np + 1];
    let mut rng = Pcg64::seed_from_u64(seed);
    for _ in 0..n_samples {
        match sample(&mut rng) {
            Some(w) => {
                let (th, ph) = frame.angles(w);
                let ph = phi0 + (ph - phi0).rem_euclid(2.0 * PI);
                let i = theta_edges.partition_point(|&e| e <= th).clamp(1, nt) - 1;
                let j = phi_edges.partition_point(|&e| e <= ph).clamp(1, np) - 1;
                observed[i * np + j] += 1.0;
            }
            None => observed[nt * np] += 1.0,
        }
    }
    let rule = gauss_legendre_pairs(6);
    let mut expected = vec![0.0f64; nt * np + 1];
    let mut mass = 0.0;
    for i in 0..nt {
        let (ta, tb) = (theta_edges[i], theta_edges[i + 1]);
        for j in 0..np {
            let (pa, pb) = (phi_edges[j], phi_edges[j + 1]);
            let mut s = 0.0;
            for &(x, wx) in &rule {
                let th = 0.5 * (ta + tb) + 0.5 * (tb - ta) * x;
                for &(y, wy) in &rule {
                    let ph = 0.5 * (pa + pb) + 0.5 * (pb - pa) * y;
                    s += wx * wy * pdf(frame.dir(th, ph)) * th.cos();
                }
            }
            let m = s * 0.25 * (tb - ta) * (pb - pa);
            mass += m;
            expected[i * np + j] = m * n_samples as f64;
        }
    }
    expected[nt * np] = ((1.0 - mass) * n_samples as f64).max(0.0);
    let (mut stat, mut dof) = (0.0, 0usize);
    let (mut pool_o, mut pool_e) = (0.0, 0.0);
    for (&o, &e) in observed.iter().zip(&expected) {
        if e < 5.0 {
            pool_o += o;
            pool_e += e;
        } else {
            stat += (o - e) * (o - e) / e;
            dof += 1;
        }
    }
    if pool_o > 0.0 || pool_e > 0.0 {
        // Samples where the pdf puts (almost) nothing make the statistic blow up, as they should.
        stat += (pool_o - pool_e) * (pool_o - pool_e) / pool_e.max(1e-300);
        dof += 1;
    }
    let dof = dof - 1;
    Chi2 { p_value: gamma_q(0.5 * dof as f64, 0.5 * stat), dof, stat, pdf_mass: mass }
}

fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 9] = [
        0.99999999999980993,
        676.5203681218851,
        -1259.1392167224028,
        771.32342877765313,
        -176.61502916214059,
        12.507343278686905,
        -0.13857109526572012,
        9.9843695780195716e-6,
        1.5056327351493116e-7,
    ];
    if x < 0.5 {
        return (PI / (PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let t = x + 7.5;
    let a = C[0] + (1..9).map(|i| C[i] / (x + i as f64)).sum::<f64>();
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Regularized upper incomplete gamma function Q(a, x).
pub(crate) fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let front = (-x + a * x.ln() - ln_gamma(a)).exp();
    if x < a + 1.0 {
        let (mut ap, mut del) = (a, 1.0 / a);
        let mut sum = del;
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        1.0 - sum * front
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -f64::from(i) * (f64::from(i) - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-16 {
                break;
            }
        }
        front * h
    }
}

#[test]
fn gamma_q_matches_closed_forms() {
    for x in [0.01, 0.5, 1.0, 3.0, 10.0, 50.0] {
        assert!((gamma_q(1.0, x) / (-x).exp() - 1.0).abs() < 1e-12, "{x}");
        let e = crate::special::erfc(x.sqrt());
        assert!((gamma_q(0.5, x) / e - 1.0).abs() < 1e-10, "{x}: {} {e}", gamma_q(0.5, x));
    }
    // Chi-square with 2000 dof: median near dof.
    assert!((gamma_q(1000.0, 999.667) - 0.5).abs() < 1e-3);
}
