//! Spherical Fibonacci point sets: nearly uniform directions on the sphere.
//!
//! How it works: point `i` of `n` has `z_i = 1 - (2i + 1)/n` (equal-area bands) and azimuth
//! `phi_i = 2 pi frac(i / golden_ratio)`. The fractional part is computed exactly in 64-bit
//! fixed point: `i * floor(2^64 / golden_ratio)` wrapping modulo `2^64` is `frac(i /
//! golden_ratio)` to within `i * 2^-64` (5e-14 at `i = 1e6`), where f32 would have lost it by
//! `i ~ 1e5`. [`rotate_about_z`] turns a set about the pole (e.g. to decorrelate frames).

use glam::DVec3;
use std::f64::consts::PI;

/// `floor(2^64 / golden_ratio)`: the golden-ratio increment in 64-bit fixed point.
const INV_GOLDEN_RATIO_FIXED: u64 = 0x9E37_79B9_7F4A_7C15;

/// `frac(i / golden_ratio)` in `[0, 1)`, exact to about `i * 5e-20`.
fn golden_fraction(i: usize) -> f64 {
    let fixed = (i as u64).wrapping_mul(INV_GOLDEN_RATIO_FIXED);
    // Top 53 bits to an f64 in [0, 1).
    (fixed >> 11) as f64 * (1.0 / (1_u64 << 53) as f64)
}

/// `n` spherical Fibonacci points (unit vectors), `n >= 1`; nearest-neighbour spacing is about
/// `sqrt(4 pi / n)`. Deterministic; correct for `n` well beyond 1e6.
#[must_use]
pub fn spherical_fibonacci(n: usize) -> Vec<DVec3> {
    let nf = n as f64;
    (0..n)
        .map(|i| {
            let z = 1.0 - (2 * i + 1) as f64 / nf;
            let r = ((1.0 - z) * (1.0 + z)).max(0.0).sqrt();
            let phi = 2.0 * PI * golden_fraction(i);
            DVec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// Rotates every point by `angle` radians about +z (counter-clockwise seen from +z), in place.
pub fn rotate_about_z(points: &mut [DVec3], angle: f64) {
    let (s, c) = angle.sin_cos();
    for p in points {
        *p = DVec3::new(c * p.x - s * p.y, s * p.x + c * p.y, p.z);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sh::{sh_count, sh_eval};
    use glam::DMat3;

    #[test]
    fn points_are_unit_and_small_sets_are_valid() {
        for n in [1_usize, 2, 3, 17, 1000] {
            let points = spherical_fibonacci(n);
            assert_eq!(points.len(), n);
            for p in &points {
                assert!(p.is_finite() && (p.length() - 1.0).abs() < 1e-15, "n = {n}: {p}");
            }
        }
        let two = spherical_fibonacci(2);
        assert!((two[0].z - 0.5).abs() < 1e-15 && (two[1].z + 0.5).abs() < 1e-15);
        assert!(spherical_fibonacci(1)[0].z.abs() < 1e-15);
        assert!(spherical_fibonacci(0).is_empty());
    }

    #[test]
    fn fixed_point_fraction_matches_f64_and_golden_ratio() {
        let golden_inverse = (5.0_f64.sqrt() - 1.0) / 2.0;
        assert!((golden_fraction(1) - golden_inverse).abs() < 3e-16);
        // Against f64 arithmetic, whose own error is i * 1e-16: agreement to 1e-9 up to 1e6.
        for i in (0..1_000_000).step_by(997).chain([999_999, 1_000_000]) {
            let reference = (i as f64 * golden_inverse).fract();
            let diff = (golden_fraction(i) - reference).abs();
            assert!(diff.min(1.0 - diff) < 1e-9, "i = {i}: {} vs {reference}", golden_fraction(i));
        }
    }

    #[test]
    fn points_are_nearly_uniform() {
        let n = 2000;
        let points = spherical_fibonacci(n);
        // Mean of every SH of bands 1..=6 is small (it is 0 for a uniform density).
        let order = 6;
        let mut mean = vec![0.0; sh_count(order)];
        let mut y = vec![0.0; sh_count(order)];
        for p in &points {
            sh_eval(order, *p, &mut y);
            for (m, v) in mean.iter_mut().zip(&y) {
                *m += v / n as f64;
            }
        }
        let worst = mean[1..].iter().fold(0.0_f64, |a, b| a.max(b.abs()));
        eprintln!("fibonacci n = {n}: worst |mean Y_lm| over bands 1..=6: {worst:e}");
        assert!(worst < 2e-4, "worst SH mean {worst:e}");
        // Nearest-neighbour spacing close to sqrt(4 pi / n) for every point.
        let spacing = (4.0 * PI / n as f64).sqrt();
        let (mut min_nn, mut max_nn) = (f64::INFINITY, 0.0_f64);
        for (i, p) in points.iter().enumerate() {
            let nn = points
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, q)| p.distance(*q))
                .fold(f64::INFINITY, f64::min);
            min_nn = min_nn.min(nn);
            max_nn = max_nn.max(nn);
        }
        eprintln!(
            "fibonacci n = {n}: nn spacing / sqrt(4 pi/n) in [{}, {}]",
            min_nn / spacing,
            max_nn / spacing
        );
        assert!(
            min_nn > 0.6 * spacing && max_nn < 1.3 * spacing,
            "nn in [{min_nn}, {max_nn}], spacing {spacing}"
        );
    }

    #[test]
    fn rotate_about_z_matches_rotation_matrix() {
        let mut points = spherical_fibonacci(50);
        let original = points.clone();
        let angle = 1.234;
        rotate_about_z(&mut points, angle);
        let r = DMat3::from_rotation_z(angle);
        for (p, q) in points.iter().zip(&original) {
            assert!((*p - r * *q).length() < 1e-15, "{p} vs {}", r * *q);
        }
    }
}
