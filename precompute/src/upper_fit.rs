//! The least-squares fit of an SH expansion to a function known on the upper hemisphere only.
//!
//! Why: the IIRTF counts light from above the fabric's horizon only (`bake::iirtf::LightDomain`),
//! so over the light's direction its matrix holds the SH projection of `f H` (`f` cut to zero
//! below the horizon). Evaluated at a light's direction, that truncated projection rings at the
//! cut: a raking light met a transfer far below zero (order 4, a light 11° above the horizon:
//! −90% of the path tracer before the clamp at zero). Light from below never reaches the
//! transfer, so what matters is the expansion's values above the horizon, and the order-L
//! expansion closest to `f` there is the least-squares fit over the upper hemisphere,
//! `c = G⁻¹ b`, with `b_j = ∫_{z>0} f Y_j` (exactly the baked projection) and the upper
//! hemisphere's Gram matrix `G_jk = ∫_{z>0} Y_j Y_k`. It reproduces every polynomial of degree
//! ≤ L on the hemisphere exactly, whether `f` meets the horizon at a value (a jump when cut) or
//! at zero with a slope (a kink when mirrored), where taking `f`'s even or odd extension would
//! each fit only one of the two. Evaluating the fit against a light `L` is
//! `∫ L f_fit = bᵀ G⁻¹ c_L`, so the fit is applied to the light's SH instead of to every cell's
//! matrix: [`UpperHemisphereFit::apply`].
//!
//! How: G couples only coefficients of the same m and the same kind (cos or sin), with the same
//! block for `m` and `−m`, so it is `L + 1` blocks over the bands `l = m..=L`, computed by a
//! product rule exact for these polynomials (Gauss–Legendre in `z ∈ [0, 1]`, uniform in φ), and
//! each block inverted by its Cholesky factor (faer). The hemisphere's functions of high l and m
//! are nearly those of lower l (G's condition number is 2.5e2 at order 2, 1.5e5 at order 4,
//! 1.2e8 at order 6), so the inverse taken is of `G + ε I` with ε = [`UPPER_FIT_RIDGE`] (3e-4
//! of G's largest eigenvalue, 1): its entries stay below 1.6e3, so f32 rounding of a light's SH
//! reaches a value as about 1e-4 of the transfer's scale on the GPU (2e-5 at ε = 1e-3, 5e-4 at
//! 1e-4), and a polynomial transfer still comes out within about 1% (2% at 1e-3, 0.5% at 1e-4;
//! docs/MATH.md). The fit's noise: a transfer's sampling noise reaches a light's value about 1.3
//! times as strongly as through the plain projection at mid elevations, 2–3 times at the
//! horizon.
//! Packed for the GPU ([`UpperHemisphereFit::packed`]): block m after blocks 0..m, each
//! `(L + 1 − m)²` values row-major over `l = m..=L`; `(L+1)(L+2)(2L+3)/6` values in all.

use std::sync::OnceLock;

use faer::linalg::solvers::DenseSolveCore;
use faer::{Mat, Side};
use glam::DVec3;

use crate::Rgb;
use crate::quadrature::gauss_legendre;
use crate::sh::{sh_count, sh_eval, sh_index};

/// The ridge ε of the fit's inverse, `(G + ε I)⁻¹` (module docs).
pub const UPPER_FIT_RIDGE: f64 = 3e-4;

/// The lowest SH order the renderer fits at (`shading::multiple::hemisphere_light_sh`): at
/// order 2 (the draft preset's) the fit's nine functions overshoot in dim raking light (over
/// 12 configurations × 3 fabrics the worst case went +85% → +164%), so the light keeps its
/// plain SH there.
pub const UPPER_FIT_MIN_ORDER: usize = 4;

/// Highest SH order a fit is made for.
pub const UPPER_FIT_MAX_ORDER: usize = 10;

/// `(G + ε I)⁻¹` of the upper hemisphere at one SH order, as its m blocks.
#[derive(Debug, Clone, PartialEq)]
pub struct UpperHemisphereFit {
    order: usize,
    /// Block m, row-major over `l = m..=order`, after blocks `0..m`.
    blocks: Vec<f64>,
}

impl UpperHemisphereFit {
    /// The fit at `order`, computed once per process.
    ///
    /// # Panics
    /// If `order` is above [`UPPER_FIT_MAX_ORDER`].
    #[must_use]
    pub fn of_order(order: usize) -> &'static Self {
        static FITS: [OnceLock<UpperHemisphereFit>; UPPER_FIT_MAX_ORDER + 1] =
            [const { OnceLock::new() }; UPPER_FIT_MAX_ORDER + 1];
        assert!(
            order <= UPPER_FIT_MAX_ORDER,
            "upper-hemisphere fit: order {order} is above {UPPER_FIT_MAX_ORDER}"
        );
        FITS[order].get_or_init(|| Self::new(order))
    }

    fn new(order: usize) -> Self {
        let n = sh_count(order);
        // Exact for products of two band-≤L functions: degree 2L in z, frequency 2L in φ.
        let (nodes, weights) = gauss_legendre(order + 2);
        let phi_count = 2 * order + 2;
        let mut gram = vec![0.0; n * n];
        let mut y = vec![0.0; n];
        for (x, w) in nodes.iter().zip(&weights) {
            let z = 0.5 * (x + 1.0);
            let r = (1.0 - z * z).max(0.0).sqrt();
            for k in 0..phi_count {
                let phi = std::f64::consts::TAU * (k as f64 + 0.5) / phi_count as f64;
                sh_eval(order, DVec3::new(r * phi.cos(), r * phi.sin(), z), &mut y);
                let weight = 0.5 * w * std::f64::consts::TAU / phi_count as f64;
                for a in 0..n {
                    for b in 0..n {
                        gram[a * n + b] += weight * y[a] * y[b];
                    }
                }
            }
        }
        let mut blocks = Vec::with_capacity(Self::packed_len(order));
        for m in 0..=order {
            let size = order + 1 - m;
            let ridged = Mat::from_fn(size, size, |a, b| {
                let (ja, jb) = (sh_index(m + a, m as isize), sh_index(m + b, m as isize));
                gram[ja * n + jb] + if a == b { UPPER_FIT_RIDGE } else { 0.0 }
            });
            let inverse = ridged.llt(Side::Lower).expect("G + εI is symmetric positive definite").inverse();
            blocks.extend((0..size * size).map(|e| inverse[(e / size, e % size)]));
        }
        Self { order, blocks }
    }

    /// Values in the packed form at `order`: `(L+1)(L+2)(2L+3)/6`.
    #[must_use]
    pub const fn packed_len(order: usize) -> usize {
        (order + 1) * (order + 2) * (2 * order + 3) / 6
    }

    /// The blocks, packed as the module docs say.
    #[must_use]
    pub fn packed(&self) -> &[f64] {
        &self.blocks
    }

    /// `c ← (G + ε I)⁻¹ c` per channel, for the `(L+1)²` coefficients of `c`.
    ///
    /// # Panics
    /// If `c` does not hold `(L+1)²` coefficients.
    pub fn apply(&self, c: &mut [Rgb]) {
        let order = self.order;
        assert_eq!(
            c.len(),
            sh_count(order),
            "upper-hemisphere fit: {} coefficients at order {order}",
            c.len()
        );
        let mut offset = 0;
        let mut v = [Rgb::ZERO; UPPER_FIT_MAX_ORDER + 1];
        for m in 0..=order {
            let size = order + 1 - m;
            let block = &self.blocks[offset..offset + size * size];
            let signs: &[isize] = if m == 0 { &[0] } else { &[1, -1] };
            for &sign in signs {
                let index = |a: usize| sh_index(m + a, sign * m as isize);
                for (a, slot) in v.iter_mut().enumerate().take(size) {
                    *slot = c[index(a)];
                }
                for a in 0..size {
                    c[index(a)] = (0..size).map(|b| v[b] * block[a * size + b]).sum();
                }
            }
            offset += size * size;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sh::sh_project;

    fn at(elevation_deg: f64, azimuth: f64) -> DVec3 {
        let e = elevation_deg.to_radians();
        DVec3::new(e.cos() * azimuth.cos(), e.cos() * azimuth.sin(), e.sin())
    }

    /// Polynomials of degree ≤ L known above the horizon come back from their cut projection
    /// within the ridge's error at every elevation, where the plain projection rings.
    #[test]
    fn the_fit_recovers_polynomials_cut_at_the_horizon() {
        type Named = (&'static str, fn(DVec3) -> f64);
        let functions: [Named; 3] = [
            ("constant", |_| 1.0),
            ("cosine", |w| w.z),
            ("mixed", |w| 1.0 + 0.5 * w.x - 0.3 * w.y + 0.4 * w.z + 0.3 * w.x * w.z),
        ];
        for order in [2, 4, 6] {
            let fit = UpperHemisphereFit::of_order(order);
            assert_eq!(fit.packed().len(), UpperHemisphereFit::packed_len(order));
            for (name, f) in functions {
                let cut = sh_project(order, 128, |w| if w.z > 0.0 { f(w) } else { 0.0 });
                let mut worst_fit: f64 = 0.0;
                let mut worst_cut: f64 = 0.0;
                for elevation in [5.0, 11.0, 20.0, 45.0, 80.0] {
                    for azimuth in [0.3, 2.1, 4.0] {
                        let d = at(elevation, azimuth);
                        let mut y = vec![0.0; sh_count(order)];
                        sh_eval(order, d, &mut y);
                        let mut light: Vec<Rgb> = y.iter().map(|&v| Rgb::splat(v)).collect();
                        let plain: f64 = light.iter().zip(&cut).map(|(l, c)| l.x * c).sum();
                        fit.apply(&mut light);
                        let fitted: f64 = light.iter().zip(&cut).map(|(l, c)| l.x * c).sum();
                        // Absolute against the function's scale (the cosine is 0 at the horizon).
                        worst_fit = worst_fit.max((fitted - f(d)).abs());
                        worst_cut = worst_cut.max((plain - f(d)).abs());
                    }
                }
                eprintln!("order {order} {name}: fit {worst_fit:.2e}, plain projection {worst_cut:.2e}");
                // The ridge's shrinkage: measured up to 7.0e-3 (order 2, the constant).
                assert!(worst_fit < 1e-2, "order {order} {name}: fit off by {worst_fit}");
                assert!(worst_cut > 5.0 * worst_fit, "order {order} {name}: {worst_cut} vs {worst_fit}");
            }
        }
    }

    /// The blocks are the inverse of G + εI, G from an independent product rule over the upper
    /// hemisphere (more nodes than the fit's own, in another arrangement of φ).
    #[test]
    fn the_blocks_invert_the_ridged_gram_matrix() {
        for order in [0, 1, 3, 4, 6] {
            let fit = UpperHemisphereFit::of_order(order);
            let n = sh_count(order);
            let (nodes, weights) = gauss_legendre(3 * order + 5);
            let phi_count = 5 * order + 7;
            let mut gram = vec![0.0; n * n];
            let mut y = vec![0.0; n];
            for (x, w) in nodes.iter().zip(&weights) {
                let z = 0.5 * (x + 1.0);
                let r = (1.0 - z * z).sqrt();
                for k in 0..phi_count {
                    let phi = std::f64::consts::TAU * k as f64 / phi_count as f64 + 0.1;
                    sh_eval(order, DVec3::new(r * phi.cos(), r * phi.sin(), z), &mut y);
                    for a in 0..n {
                        for b in 0..n {
                            gram[a * n + b] +=
                                0.5 * w * std::f64::consts::TAU / phi_count as f64 * y[a] * y[b];
                        }
                    }
                }
            }
            // Blocks: G couples nothing across m or across cos and sin.
            for a in 0..n {
                for b in 0..n {
                    let same = |j: usize| {
                        let l = (j as f64).sqrt() as usize;
                        j as isize - (l * (l + 1)) as isize
                    };
                    if same(a) != same(b) {
                        assert!(
                            gram[a * n + b].abs() < 1e-12,
                            "order {order}: G[{a}, {b}] = {}",
                            gram[a * n + b]
                        );
                    }
                }
            }
            let mut offset = 0;
            let mut worst: f64 = 0.0;
            for m in 0..=order {
                let size = order + 1 - m;
                for sign in [1, -1] {
                    let j = |a: usize| sh_index(m + a, sign * m as isize);
                    for a in 0..size {
                        for b in 0..size {
                            let product: f64 = (0..size)
                                .map(|k| {
                                    let g =
                                        gram[j(a) * n + j(k)] + if a == k { UPPER_FIT_RIDGE } else { 0.0 };
                                    g * fit.packed()[offset + k * size + b]
                                })
                                .sum();
                            worst = worst.max((product - if a == b { 1.0 } else { 0.0 }).abs());
                        }
                    }
                }
                offset += size * size;
            }
            assert!(worst < 1e-10, "order {order}: (G + εI) (G + εI)⁻¹ − I off by {worst}");
        }
    }
}
