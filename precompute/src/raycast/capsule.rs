//! Exact ray–capsule intersection: the primitive every fiber segment is traced as.
//!
//! A fiber segment is a *capsule*: the set of points within `radius` of the segment `a..b`
//! (a cylinder of the fiber radius plus a hemisphere at each end). Consecutive segments of a
//! polyline share an end point, so their capsules share the sphere around it and the fiber is
//! closed at every joint, whatever the bend angle. Open cylinders would leave a wedge-shaped gap
//! on the outside of every bend (and a doubly-covered wedge on the inside) that rays leak
//! through; flat end caps would leave the same gap. A capsule is also convex, which makes the
//! "entry point" well defined and the test cheap.
//!
//! How the test works, in a frame centred at the segment midpoint (so the numbers are of the
//! order of the segment length, not of the scene coordinates):
//! 1. Move the ray origin to the point of the ray closest to the centre (`t_c`); if that point is
//!    farther than `half_length + radius` the capsule's bounding sphere is missed (early out);
//!    if the ray's line passes the axis farther than `radius`, so is the infinite cylinder.
//!    Solving from this point keeps the quadratic well conditioned for far origins.
//! 2. Enter the infinite cylinder around the axis (a quadratic in `t`, solved in the numerically
//!    stable form). A ray parallel to the axis has no quadratic; it is inside the cylinder or
//!    misses it.
//! 3. If the entry lies within the axial extent it is the hit (cylinder side). Otherwise the ray
//!    entered the infinite cylinder beyond one end, and since the end disc is covered by that
//!    end's sphere the first capsule point is on that sphere (or there is none).
//!
//! Rays whose origin is inside (or on, within a relative shell of [`INSIDE_SHELL`]) the capsule
//! do not hit it: only entries count. A ray leaving a fiber surface therefore never re-hits the
//! capsule it starts on, and neither does it "hit" the neighbouring segment of the same fiber
//! whose end sphere contains the start point. Rays starting inside the fiber to exit through
//! its surface are not supported (fibers are opaque surfaces to this module).

use glam::Vec3;

/// Origins closer to the axis segment than `radius * (1 + INSIDE_SHELL)` count as inside.
pub const INSIDE_SHELL: f32 = 1e-4;

/// One fiber segment as a capsule, in whatever frame the caller traces in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Capsule {
    /// Midpoint of the segment.
    pub center: Vec3,
    /// Unit direction from `a` to `b` (any unit vector for a degenerate segment).
    pub axis: Vec3,
    /// Half the segment length.
    pub half_length: f32,
    pub radius: f32,
}

/// Where a ray enters a capsule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CapsuleHit {
    /// Distance along the (unit) ray direction.
    pub t: f32,
    /// Position of the hit projected on the segment, 0 at `a`, 1 at `b` (0 or 1 on the caps).
    pub segment_param: f32,
    /// Unit outward surface normal of the capsule at the hit.
    pub normal: Vec3,
}

impl Capsule {
    /// The capsule around segment `a..b`.
    #[must_use]
    pub fn from_segment(a: Vec3, b: Vec3, radius: f32) -> Self {
        let d = b - a;
        let len = d.length();
        let axis = if len > 0.0 { d / len } else { Vec3::X };
        Self { center: 0.5 * (a + b), axis, half_length: 0.5 * len, radius }
    }

    /// Whether `p` is inside the capsule (or on its surface, within the [`INSIDE_SHELL`]).
    #[must_use]
    pub fn contains(&self, p: Vec3) -> bool {
        let q = p - self.center;
        let s = q.dot(self.axis).clamp(-self.half_length, self.half_length);
        let r = self.radius * (1.0 + INSIDE_SHELL);
        (q - s * self.axis).length_squared() <= r * r
    }

    /// First entry of the ray `origin + t * dir` (`dir` unit length) into the capsule with
    /// `0 <= t < t_max`; `None` if there is none or the origin is inside the capsule.
    #[must_use]
    #[inline]
    pub fn intersect(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<CapsuleHit> {
        self.intersect_piece(origin, dir, t_max, origin)
    }

    /// Like [`Self::intersect`] for the piece of a ray that starts at `start` (`t` is measured
    /// from there) but whose true origin is `ray_origin`: the capsule is skipped if `ray_origin`
    /// is inside it. A ray cut into pieces thus sees a capsule exactly as the whole ray would,
    /// even when a piece starts on or inside it.
    #[must_use]
    #[inline]
    pub fn intersect_piece(
        &self,
        start: Vec3,
        dir: Vec3,
        t_max: f32,
        ray_origin: Vec3,
    ) -> Option<CapsuleHit> {
        let (h, r, u) = (self.half_length, self.radius, self.axis);
        let oc = start - self.center;
        let t_c = -oc.dot(dir);
        let p = oc + t_c * dir;
        let reach = h + r;
        let p2 = p.length_squared();
        if p2 > reach * reach {
            return None;
        }
        // The line passes the axis farther than the radius: it misses the infinite cylinder,
        // which holds the capsule (|p · (d × u)| / |d × u| is the distance between the lines).
        let w = dir.cross(u);
        let qa = w.length_squared();
        let pw = p.dot(w);
        if qa > 1e-12 && pw * pw > r * r * qa {
            return None;
        }
        // Infinite cylinder, from p: |p_perp + s d_perp|^2 = r^2 (|d_perp|² = |d × u|² = qa).
        let pu = p.dot(u);
        let du = dir.dot(u);
        let p_perp = p - pu * u;
        let d_perp = dir - du * u;
        let qc = p_perp.length_squared() - r * r;
        // Axial coordinate at the cylinder entry; +-inf for a ray parallel to the axis.
        let (s_cyl, y_entry) = if qa > 1e-12 {
            let qb = p_perp.dot(d_perp);
            let disc = qb * qb - qa * qc;
            if disc < 0.0 {
                return None;
            }
            let q = -(qb + disc.sqrt().copysign(qb));
            let (r0, r1) = if q == 0.0 { (0.0, 0.0) } else { (q / qa, qc / q) };
            let s = r0.min(r1);
            (s, pu + s * du)
        } else {
            if qc > 0.0 {
                return None;
            }
            (f32::NEG_INFINITY, if du > 0.0 { f32::NEG_INFINITY } else { f32::INFINITY })
        };
        let (s, normal, y) = if y_entry.abs() <= h {
            let x = p + s_cyl * dir;
            (s_cyl, (x - y_entry * u).normalize(), y_entry)
        } else {
            // Entered the infinite cylinder beyond an end: the hit, if any, is on that end's sphere.
            let end = h.copysign(y_entry);
            let w = p - end * u;
            let b = w.dot(dir);
            let c = w.length_squared() - r * r;
            let disc = b * b - c;
            if disc < 0.0 {
                return None;
            }
            let s = -b - disc.sqrt();
            let x = p + s * dir;
            (s, (x - end * u).normalize(), end)
        };
        let t = t_c + s;
        if !(t >= 0.0 && t < t_max) {
            return None;
        }
        // An origin inside the capsule sees no entry. (A convex capsule's entry then lies behind
        // it, so only origins within the shell around the surface get here. Far origins cannot be
        // inside, and for them the offset is too large for the test to be precise.)
        if (ray_origin - self.center).length_squared() <= 1.0001 * reach * reach && self.contains(ray_origin)
        {
            return None;
        }
        let segment_param = if h > 0.0 { (0.5 + 0.5 * y / h).clamp(0.0, 1.0) } else { 0.5 };
        Some(CapsuleHit { t, segment_param, normal })
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // exact end-point parameters
mod tests {
    use super::*;
    use glam::DVec3;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    /// Signed distance to the capsule, in f64.
    fn sdf(a: DVec3, b: DVec3, r: f64, p: DVec3) -> f64 {
        let ab = b - a;
        let s = if ab.length_squared() > 0.0 {
            ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (p - (a + s * ab)).length() - r
    }

    /// Reference first hit by marching in f64 with small fixed steps then bisecting.
    fn march(a: DVec3, b: DVec3, r: f64, o: DVec3, d: DVec3, t_max: f64) -> Option<f64> {
        if sdf(a, b, r, o) <= 0.0 {
            return None;
        }
        let mut t = 0.0;
        loop {
            let dist = sdf(a, b, r, o + t * d);
            // Sphere tracing never overshoots a convex (indeed any) SDF.
            if dist < 1e-13 * (1.0 + t) {
                return (t < t_max).then_some(t);
            }
            t += dist;
            if t > t_max || t > 1e3 {
                return None;
            }
        }
    }

    fn check(c: &Capsule, a: Vec3, b: Vec3, o: Vec3, d: Vec3) {
        let got = c.intersect(o, d, f32::INFINITY);
        let want = march(a.as_dvec3(), b.as_dvec3(), f64::from(c.radius), o.as_dvec3(), d.as_dvec3(), 1e9);
        let tol = 2e-3 * f64::from(c.radius);
        match (got, want) {
            (Some(h), Some(t)) => {
                assert!((f64::from(h.t) - t).abs() < tol + 1e-6 * t, "t {} vs {t} for o={o} d={d}", h.t);
                let x = o + h.t * d;
                let dist = sdf(a.as_dvec3(), b.as_dvec3(), 0.0, o.as_dvec3() + f64::from(h.t) * d.as_dvec3());
                // The normal points from the closest axis point to the hit.
                let closest = a + (b - a) * h.segment_param;
                let n_ref = (x - closest).normalize();
                assert!(h.normal.dot(n_ref) > 0.999, "normal {} vs {n_ref}", h.normal);
                assert!((dist - f64::from(c.radius)).abs() < tol + 1e-6 * t);
            }
            (None, None) => {}
            (g, w) => {
                // Only near-tangent rays may disagree: the ray must pass within a hair of the surface.
                // The distance to the capsule is convex along the ray: ternary search its minimum.
                let f = |t: f64| {
                    sdf(a.as_dvec3(), b.as_dvec3(), f64::from(c.radius), o.as_dvec3() + t * d.as_dvec3())
                };
                let (mut lo, mut hi) = (0.0, 1e3);
                for _ in 0..200 {
                    let (m1, m2) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
                    if f(m1) < f(m2) { hi = m2 } else { lo = m1 }
                }
                let closest = f(lo).min(f(0.0));
                assert!(
                    closest.abs() < 1e-3 * f64::from(c.radius),
                    "disagree: {g:?} vs {w:?} (closest {closest}) o={o} d={d}"
                );
            }
        }
    }

    #[test]
    fn analytic_cases() {
        let r = 0.5;
        let c = Capsule::from_segment(Vec3::new(-1.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), r);
        // Perpendicular ray onto the side.
        let h = c.intersect(Vec3::new(0.3, 0.0, 5.0), Vec3::NEG_Z, f32::INFINITY).unwrap();
        assert!((h.t - 4.5).abs() < 1e-6);
        assert!((h.normal - Vec3::Z).length() < 1e-6);
        assert!((h.segment_param - 0.65).abs() < 1e-6);
        // Ray along the axis: enters the cap at x = -1.5.
        let h = c.intersect(Vec3::new(-5.0, 0.0, 0.0), Vec3::X, f32::INFINITY).unwrap();
        assert!((h.t - 3.5).abs() < 1e-6);
        assert!((h.normal - Vec3::NEG_X).length() < 1e-6);
        assert_eq!(h.segment_param, 0.0);
        // Parallel to the axis, off axis by 0.3: hits the cap sphere at x = -1 - sqrt(0.25 - 0.09).
        let h = c.intersect(Vec3::new(5.0, 0.3, 0.0), Vec3::NEG_X, f32::INFINITY).unwrap();
        assert!((h.t - (4.0 - 0.4)).abs() < 1e-6, "{}", h.t);
        assert_eq!(h.segment_param, 1.0);
        // Parallel outside the radius: miss.
        assert!(c.intersect(Vec3::new(5.0, 0.0, 0.51), Vec3::NEG_X, f32::INFINITY).is_none());
        // Through a cap at an angle, beyond the cylinder end.
        let d = Vec3::new(-1.0, 0.0, -1.0).normalize();
        let h = c.intersect(Vec3::new(1.2 + 3.0, 0.0, 3.0), d, f32::INFINITY).unwrap();
        let x = Vec3::new(4.2, 0.0, 3.0) + h.t * d;
        assert!(((x - Vec3::X).length() - r).abs() < 1e-5);
        // Grazing: tangent just inside and just outside.
        assert!(c.intersect(Vec3::new(0.0, -5.0, 0.4999), Vec3::Y, f32::INFINITY).is_some());
        assert!(c.intersect(Vec3::new(0.0, -5.0, 0.5001), Vec3::Y, f32::INFINITY).is_none());
        // Origin inside, and on the surface going out or in: ignored.
        assert!(c.intersect(Vec3::new(0.9, 0.1, 0.0), Vec3::Z, f32::INFINITY).is_none());
        assert!(c.intersect(Vec3::new(0.0, 0.0, 0.5), Vec3::Z, f32::INFINITY).is_none());
        assert!(c.intersect(Vec3::new(0.0, 0.0, 0.5), Vec3::NEG_Z, f32::INFINITY).is_none());
        // Behind the origin and beyond t_max: miss.
        assert!(c.intersect(Vec3::new(0.0, 0.0, 5.0), Vec3::Z, f32::INFINITY).is_none());
        assert!(c.intersect(Vec3::new(0.0, 0.0, 5.0), Vec3::NEG_Z, 4.4).is_none());
        // Degenerate segment: a sphere.
        let s = Capsule::from_segment(Vec3::ONE, Vec3::ONE, 0.25);
        let h = s.intersect(Vec3::new(1.0, 1.0, 3.0), Vec3::NEG_Z, f32::INFINITY).unwrap();
        assert!((h.t - 1.75).abs() < 1e-6);
    }

    #[test]
    fn tiny_fiber_far_from_origin_matches_reference() {
        // Fiber-scale capsule at scene coordinates ~10 cm, rays from a camera 10 cm away.
        let mut rng = Pcg64::seed_from_u64(7);
        let r = 5e-4_f32;
        for _ in 0..2000 {
            let a = Vec3::new(9.7, -8.3, 0.01) + Vec3::new(rng.random(), rng.random(), rng.random()) * 1e-3;
            let b = a + Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            )
            .normalize()
                * 2.5e-3;
            let c = Capsule::from_segment(a, b, r);
            let target = c.center
                + Vec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                ) * 2e-3;
            let o = target
                + Vec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(0.2..1.0),
                )
                .normalize()
                    * 10.0;
            let d = (target - o).normalize();
            // Compare in the segment-centred frame (as the scene does): translation is exact enough.
            check(&c, a, b, o, d);
        }
    }

    #[test]
    fn random_rays_match_sphere_tracing() {
        let mut rng = Pcg64::seed_from_u64(3);
        let mut hits = 0;
        for i in 0..5000 {
            let len = if i % 10 == 0 { 0.0 } else { rng.random_range(0.0..6.0) };
            let a = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let b = a + Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            )
            .normalize()
                * len;
            let c = Capsule::from_segment(a, b, 1.0);
            let o = Vec3::new(
                rng.random_range(-6.0..6.0),
                rng.random_range(-6.0..6.0),
                rng.random_range(-6.0..6.0),
            );
            let d = if i % 7 == 0 {
                // Exactly or nearly parallel to the axis.
                (c.axis + Vec3::new(rng.random(), rng.random(), rng.random()) * 1e-4 * (i % 2) as f32)
                    .normalize()
            } else {
                let target = c.center
                    + Vec3::new(
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                    ) * (len + 1.5);
                (target - o).normalize()
            };
            hits += usize::from(c.intersect(o, d, f32::INFINITY).is_some());
            check(&c, a, b, o, d);
        }
        assert!(hits > 500, "{hits}");
    }
}
