//! Bake tables for the renderer: the zonal SH of normalized SGs `C_G[λ, l]` and the BCSDF's
//! longitudinal normalizer `Gn(μ; λ)` per material and lobe.
//!
//! How it works:
//! - [`CgTable`] samples `z_l(λ)` ([`crate::sg::sg_zonal_sh`]) at `n` sharpnesses uniform in
//!   `ln λ` from [`CG_LAMBDA_MIN`] = 1e-4 to [`CG_LAMBDA_MAX`] = 1e5, stored as f32, row `k`
//!   holding bands `0..=order`. Lookups interpolate linearly in `ln λ`. Outside the grid they
//!   interpolate toward the exact limits instead of clamping flat: below 1e-4 linearly in `λ`
//!   toward `λ = 0` (the constant lobe: `z_0 = 1/sqrt(4π)`, the rest 0; `z_l = O(λ^l)` so this is
//!   exact to `O(λ_min²)`), above 1e5 linearly in `1/λ` toward `λ = ∞` (the delta lobe:
//!   `z_l = sqrt((2l+1)/(4π))`; `z_l ≈ that · e^{-l(l+1)/(2λ)}`, so this is exact to
//!   `O(λ^-2)`). With [`CG_DEFAULT_POINTS`] = 1024 points the largest error against
//!   `sg_zonal_sh` at interval midpoints, for every band up to order 8, is below 2e-5 (measured
//!   in the tests, which print it).
//! - [`GnTable`] holds, for every material and for its R and TT lobes, `Gn(μ)` and `dGn/dμ` at
//!   [`GN_INTERVALS`] + 1 nodes uniform over `μ ∈ [0, π/2]` (Gn is even in μ, so this is the table
//!   over `[-π/2, π/2]`), f32, for cubic Hermite interpolation on the GPU exactly as the CPU does
//!   it. The values come from the BCSDF itself ([`FiberScattering::eval_angles`] with the R lobe
//!   alone and `θo = -θi`, where `S = sqrt(λ/π) / (2π Gn(-θi))`), so CPU and GPU agree; the
//!   slopes are three-point one-sided differences of that same Gn inside the interval left of
//!   each node (0 at μ = 0 by evenness). Hermite interpolation of the stored data is within
//!   1e-7 relative (f32 rounding; 6e-8 measured) of the BCSDF's Gn everywhere, poles included,
//!   for β from 0.5° to 60° (tested). Lambertian materials have no Gn: their rows hold Gn = 1,
//!   slope 0.

use std::f64::consts::{FRAC_PI_2, PI};

use crate::bcsdf::{FiberScattering, GN_TABLE_INTERVALS, LobeGnTable, MaterialDesc};
use crate::params::{ParamError, check_count};
use crate::sg::sg_zonal_sh;

/// Smallest tabulated SG sharpness.
pub const CG_LAMBDA_MIN: f64 = 1e-4;
/// Largest tabulated SG sharpness.
pub const CG_LAMBDA_MAX: f64 = 1e5;
/// Default number of sharpness samples.
pub const CG_DEFAULT_POINTS: usize = 1024;

/// Zonal SH coefficients of the normalized SG, `z_l(λ)`, tabulated over `ln λ`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CgTable {
    order: usize,
    points: usize,
    /// `points × (order + 1)` values, row-major (row = sharpness sample).
    values: Vec<f32>,
}

impl CgTable {
    /// Tabulates bands `0..=order` (order ≤ 8) at `points` sharpnesses (2 ≤ points ≤ 65536).
    pub fn new(order: usize, points: usize) -> Result<Self, ParamError> {
        check_count("sh_order", order, 0, 8)?;
        check_count("cg_points", points, 2, 65_536)?;
        let mut values = Vec::with_capacity(points * (order + 1));
        for k in 0..points {
            values.extend(sg_zonal_sh(order, Self::lambda_of(points, k)).into_iter().map(|z| z as f32));
        }
        Ok(Self { order, points, values })
    }

    /// Rebuilds a table from its stored parts (as read from a bake file).
    pub fn from_parts(order: usize, points: usize, values: Vec<f32>) -> Result<Self, ParamError> {
        check_count("sh_order", order, 0, 8)?;
        check_count("cg_points", points, 2, 65_536)?;
        check_count("cg_values", values.len(), points * (order + 1), points * (order + 1))?;
        if let Some(bad) = values.iter().find(|v| !v.is_finite()) {
            return Err(ParamError::new("cg_values", bad, "finite numbers"));
        }
        Ok(Self { order, points, values })
    }

    /// Sharpness of sample `k`: `exp(ln λmin + k (ln λmax - ln λmin) / (points - 1))`.
    #[must_use]
    pub fn lambda_of(points: usize, k: usize) -> f64 {
        let (u0, u1) = (CG_LAMBDA_MIN.ln(), CG_LAMBDA_MAX.ln());
        (u0 + (u1 - u0) * k as f64 / (points - 1) as f64).exp()
    }

    #[must_use]
    pub fn order(&self) -> usize {
        self.order
    }

    #[must_use]
    pub fn points(&self) -> usize {
        self.points
    }

    /// The stored values, `points × (order + 1)`, row-major.
    #[must_use]
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    fn row(&self, k: usize) -> &[f32] {
        let w = self.order + 1;
        &self.values[k * w..(k + 1) * w]
    }

    /// `z_l(λ)` for `l = 0..=order`, interpolated (see the module doc). `λ ≤ 0` or NaN gives the
    /// `λ = 0` limit, `λ = ∞` the delta-lobe limit.
    #[must_use]
    pub fn lookup(&self, lambda: f64) -> Vec<f64> {
        let w = self.order + 1;
        let zero_limit = |l: usize| if l == 0 { 1.0 / (4.0 * PI).sqrt() } else { 0.0 };
        let inf_limit = |l: usize| ((2 * l + 1) as f64 / (4.0 * PI)).sqrt();
        if lambda.is_nan() || lambda <= CG_LAMBDA_MIN {
            let t = if lambda > 0.0 { lambda / CG_LAMBDA_MIN } else { 0.0 };
            let first = self.row(0);
            return (0..w).map(|l| zero_limit(l) + t * (f64::from(first[l]) - zero_limit(l))).collect();
        }
        if lambda >= CG_LAMBDA_MAX {
            let t = CG_LAMBDA_MAX / lambda; // 1 at λmax, 0 at ∞
            let last = self.row(self.points - 1);
            return (0..w).map(|l| inf_limit(l) + t * (f64::from(last[l]) - inf_limit(l))).collect();
        }
        let (u0, u1) = (CG_LAMBDA_MIN.ln(), CG_LAMBDA_MAX.ln());
        let x = (lambda.ln() - u0) / (u1 - u0) * (self.points - 1) as f64;
        let k = (x.max(0.0) as usize).min(self.points - 2);
        let t = (x - k as f64).clamp(0.0, 1.0);
        let (r0, r1) = (self.row(k), self.row(k + 1));
        (0..w).map(|l| f64::from(r0[l]) + t * (f64::from(r1[l]) - f64::from(r0[l]))).collect()
    }
}

/// Intervals of the Gn tables over μ ∈ [0, π/2] (the BCSDF's CPU table uses the same grid).
pub const GN_INTERVALS: usize = GN_TABLE_INTERVALS;

/// The two lobes of the fiber model, in table order.
pub const GN_LOBES: [&str; 2] = ["R", "TT"];

/// `Gn(μ)` and `dGn/dμ` per material and lobe, for GPU upload.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GnTable {
    materials: usize,
    /// `materials × 2 lobes × (GN_INTERVALS + 1) nodes × 2 (Gn, dGn/dμ)`, row-major.
    data: Vec<f32>,
}

/// Node values and exact slopes of one lobe's Gn, interleaved `(Gn, dGn/dμ)`: exactly the
/// BCSDF's own table, so the bake and the CPU model agree node for node.
fn gn_nodes(lobe: &LobeGnTable) -> Vec<f32> {
    lobe.values().iter().zip(lobe.slopes()).flat_map(|(&v, &d)| [v as f32, d as f32]).collect()
}

impl GnTable {
    /// Tabulates both lobes of every material (Lambertian ones get Gn = 1). A few ms per lobe.
    pub fn new(materials: &[MaterialDesc]) -> Result<Self, ParamError> {
        let mut data = Vec::with_capacity(materials.len() * 4 * (GN_INTERVALS + 1));
        for m in materials {
            match m {
                MaterialDesc::Fiber(p) => {
                    let fiber = FiberScattering::new(p)?;
                    let (r, tt) = fiber.gn_tables();
                    data.extend(gn_nodes(r));
                    data.extend(gn_nodes(tt));
                }
                MaterialDesc::Lambert { .. } => {
                    for _ in 0..2 * (GN_INTERVALS + 1) {
                        data.extend([1.0, 0.0]);
                    }
                }
            }
        }
        Ok(Self { materials: materials.len(), data })
    }

    /// Rebuilds a table from stored data (as read from a bake file).
    pub fn from_parts(materials: usize, data: Vec<f32>) -> Result<Self, ParamError> {
        let n = materials * 4 * (GN_INTERVALS + 1);
        check_count("gn_values", data.len(), n, n)?;
        if let Some(bad) = data.iter().find(|v| !v.is_finite()) {
            return Err(ParamError::new("gn_values", bad, "finite numbers"));
        }
        Ok(Self { materials, data })
    }

    #[must_use]
    pub fn materials(&self) -> usize {
        self.materials
    }

    /// The stored data, shape `[materials, 2, GN_INTERVALS + 1, 2]` (last axis: Gn, dGn/dμ).
    #[must_use]
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// The shape of [`Self::data`].
    #[must_use]
    pub fn shape(&self) -> [usize; 4] {
        [self.materials, 2, GN_INTERVALS + 1, 2]
    }

    /// `Gn(μ)` of `lobe` (0 = R, 1 = TT) of `material` by cubic Hermite interpolation of the
    /// stored f32 data, as the GPU does it; μ is clamped to [-π/2, π/2].
    #[must_use]
    pub fn eval(&self, material: usize, lobe: usize, mu: f64) -> f64 {
        let base = (material * 2 + lobe) * 2 * (GN_INTERVALS + 1);
        let step = FRAC_PI_2 / GN_INTERVALS as f64;
        let x = mu.abs().min(FRAC_PI_2) / step;
        let k = (x as usize).min(GN_INTERVALS - 1);
        let t = x - k as f64;
        let node = |i: usize| {
            let j = base + 2 * i;
            (f64::from(self.data[j]), f64::from(self.data[j + 1]) * step)
        };
        let ((p0, d0), (p1, d1)) = (node(k), node(k + 1));
        let (t2, t3) = (t * t, t * t * t);
        (2.0 * t3 - 3.0 * t2 + 1.0) * p0
            + (t3 - 2.0 * t2 + t) * d0
            + (-2.0 * t3 + 3.0 * t2) * p1
            + (t3 - t2) * d1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Rgb;
    use crate::bcsdf::FiberParams;
    use crate::quadrature::{gauss_legendre_pairs, integrate_panels};

    fn max_midpoint_error(order: usize, points: usize) -> (f64, f64) {
        let table = CgTable::new(order, points).unwrap();
        let mut worst = (0.0_f64, 0.0);
        for k in 0..points - 1 {
            let lam =
                (0.5 * (CgTable::lambda_of(points, k).ln() + CgTable::lambda_of(points, k + 1).ln())).exp();
            let exact = sg_zonal_sh(order, lam);
            for (a, b) in table.lookup(lam).iter().zip(&exact) {
                assert!(a.is_finite());
                if (a - b).abs() > worst.0 {
                    worst = ((a - b).abs(), lam);
                }
            }
        }
        worst
    }

    #[test]
    fn cg_interpolation_error_at_midpoints_is_small() {
        let (err, at) = max_midpoint_error(8, CG_DEFAULT_POINTS);
        println!("C_G order 8, {CG_DEFAULT_POINTS} points: max |error| {err:.3e} at lambda {at:.4e}");
        assert!(err < 2e-5, "{err} at {at}");
        let (err5, _) = max_midpoint_error(5, CG_DEFAULT_POINTS);
        println!("C_G order 5: max |error| {err5:.3e}");
        // Nodes themselves are exact to f32 rounding.
        let table = CgTable::new(8, 64).unwrap();
        for k in [0, 17, 63] {
            let lam = CgTable::lambda_of(64, k);
            for (a, b) in table.lookup(lam).iter().zip(sg_zonal_sh(8, lam)) {
                assert!((a - b).abs() < 1e-7, "{a} {b}");
            }
        }
    }

    #[test]
    fn cg_has_the_right_limits_and_extremes() {
        let table = CgTable::new(6, CG_DEFAULT_POINTS).unwrap();
        for lam in [0.0, -1.0, f64::NAN] {
            let z = table.lookup(lam);
            assert!((z[0] - 1.0 / (4.0 * PI).sqrt()).abs() < 1e-7);
            assert!(z[1..].iter().all(|&v| v == 0.0), "{z:?}");
        }
        for lam in [1e-9, 1e-6, 5e-5, 1e-4, 1e5, 3e5, 1e7, 1e12] {
            let exact = sg_zonal_sh(6, lam);
            for (l, (a, b)) in table.lookup(lam).iter().zip(&exact).enumerate() {
                assert!((a - b).abs() < 1e-6, "lam {lam} l {l}: {a} vs {b}");
            }
        }
        let z = table.lookup(f64::INFINITY);
        for (l, v) in z.iter().enumerate() {
            assert!((v - ((2 * l + 1) as f64 / (4.0 * PI)).sqrt()).abs() < 1e-12);
        }
        assert!(CgTable::new(9, 10).is_err() && CgTable::new(2, 1).is_err());
        let parts = CgTable::from_parts(6, table.points(), table.values().to_vec()).unwrap();
        assert_eq!(parts, table);
        assert!(CgTable::from_parts(6, 3, vec![0.0; 20]).is_err());
        assert!(CgTable::from_parts(0, 2, vec![0.0, f32::NAN]).is_err());
    }

    /// Independent reference: `sqrt(λ/π) ∫ exp(-λ(θ-μ)²) cos²θ dθ` on panels of β/2.
    fn gn_reference(mu: f64, beta: f64) -> f64 {
        let lam = 0.5 / (beta * beta);
        let lo = (mu - 16.0 * beta).max(-FRAC_PI_2);
        let hi = (mu + 16.0 * beta).min(FRAC_PI_2);
        let panels = ((hi - lo) / (0.5 * beta)).ceil() as usize;
        let breaks: Vec<f64> = (0..=panels).map(|k| lo + (hi - lo) * k as f64 / panels as f64).collect();
        let rule = gauss_legendre_pairs(12);
        (lam / PI).sqrt()
            * integrate_panels(&rule, &breaks, |th| {
                (-lam * (th - mu) * (th - mu)).exp() * th.cos() * th.cos()
            })
    }

    #[test]
    fn gn_table_matches_the_bcsdf_and_quadrature_including_the_poles() {
        let betas = [0.5, 3.0, 15.0, 60.0];
        let mats: Vec<MaterialDesc> = betas
            .iter()
            .map(|&b| {
                MaterialDesc::Fiber(FiberParams {
                    c_r: Rgb::splat(0.1),
                    beta_r_deg: b,
                    c_tt: Rgb::splat(0.5),
                    beta_tt_deg: (b * 2.0).min(60.0),
                    gamma_tt_deg: 20.0,
                })
            })
            .chain([MaterialDesc::Lambert { albedo: Rgb::splat(0.5) }])
            .collect();
        let table = GnTable::new(&mats).unwrap();
        assert_eq!(table.data().len(), table.shape().iter().product::<usize>());
        for (m, &b) in betas.iter().enumerate() {
            for (lobe, beta_deg) in [b, (b * 2.0).min(60.0)].into_iter().enumerate() {
                let beta = beta_deg.to_radians();
                let lobe_table = LobeGnTable::new(beta);
                let gn = |mu: f64| lobe_table.eval(mu);
                let mut mus: Vec<f64> =
                    (0..3000).map(|k| -FRAC_PI_2 + PI * (f64::from(k) + 0.29) / 3000.0).collect();
                let near = (20.0 * beta).min(FRAC_PI_2);
                mus.extend((0..1000).map(|k| FRAC_PI_2 - near * (f64::from(k) + 0.53) / 1000.0));
                mus.extend([FRAC_PI_2, -FRAC_PI_2, 0.0]);
                let (mut worst_cpu, mut worst_ref) = (0.0_f64, 0.0_f64);
                for &mu in &mus {
                    let v = table.eval(m, lobe, mu);
                    assert!(v.is_finite() && v > 0.0);
                    worst_cpu = worst_cpu.max((v / gn(mu) - 1.0).abs());
                    worst_ref = worst_ref.max((v / gn_reference(mu, beta) - 1.0).abs());
                }
                println!(
                    "Gn beta {beta_deg} deg: max rel error vs BCSDF {worst_cpu:.2e}, vs quadrature {worst_ref:.2e}"
                );
                assert!(worst_cpu < 2e-7, "beta {beta_deg}: {worst_cpu}");
                assert!(worst_ref < 2e-7, "beta {beta_deg}: {worst_ref}");
            }
        }
        // Pole value ≈ β²/2 at β = 0.5° (Gn is tiny there).
        let beta = 0.5f64.to_radians();
        assert!((table.eval(0, 0, FRAC_PI_2) / (0.5 * beta * beta) - 1.0).abs() < 1e-4);
        assert!((table.eval(4, 1, 0.3) - 1.0).abs() < 1e-12);
        let bad = MaterialDesc::Fiber(FiberParams {
            c_r: Rgb::ZERO,
            beta_r_deg: 0.1,
            c_tt: Rgb::ZERO,
            beta_tt_deg: 5.0,
            gamma_tt_deg: 5.0,
        });
        assert!(GnTable::new(&[bad]).unwrap_err().to_string().contains("beta_r_deg"));
        assert_eq!(GnTable::from_parts(5, table.data().to_vec()).unwrap(), table);
        assert!(GnTable::from_parts(4, table.data().to_vec()).is_err());
    }
}
