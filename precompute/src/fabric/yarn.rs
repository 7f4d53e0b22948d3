//! Procedural yarns: plies twisted around a centre line, fibers twisted and migrating in each ply.
//!
//! How it works (after Zhao et al. 2016, "Fitting procedural yarn models for realistic cloth
//! rendering", simplified): the caller gives the yarn's centre line `c(s)` as a function of the
//! axial coordinate `s`, periodic in the sense `c(s + L) = c(s) + L * axis` with `L` the exemplar
//! period along the yarn. Around it we build a frame: tangent `T` (finite difference of `c`),
//! width direction `W = normalize(T x z)` (horizontal) and height direction `H = W x T`. In the
//! (W, H) cross-section:
//!
//! - `plies` ply centres sit on a circle of radius `d` and turn about the axis with the ply
//!   twist; ply radius `r_p` and `d` pack the plies inside the yarn circle of radius `width / 2`;
//! - each fiber starts at a random point `(R_k, theta_k)` of its ply's unit disk (uniform in area)
//!   and turns about the ply centre with the ply plus the fiber twist (fiber twist is relative to
//!   the ply, as in Zhao 2016);
//! - fiber migration: its distance to the ply centre is
//!   `R_k * r_p * (m_min + (m_max - m_min) * (1 + cos(2 pi s / P_mig + phi_k)) / 2)`;
//! - flyaway (loop) fibers: `flyaways_per_ply` extra fibers per ply whose migration reaches out to
//!   `flyaway_max * r_p`, forming loose loops. Hair-like flyaways with free ends are not generated:
//!   free ends would break periodicity;
//! - the circular section is squashed to an ellipse, `height / width` along H, so yarns flatten.
//!
//! Periodicity: twist and migration must repeat exactly over `L`, so the user's rates are rounded
//! ([`TwistCounts::for_period`]): ply and fiber twist to the nearest whole number of turns per
//! period (0 = untwisted is allowed), migration to the nearest whole number (at least one) of
//! cycles per period. Each fiber is sampled at `N + 1` points `s = L i / N`, with `N` chosen so
//! segments are at most `segment_length` long along the axis and every turn about an axis gets at
//! least `points_per_turn` points; its last point is its first plus `L * axis` (to f32 rounding).
//! All randomness comes from a PCG generator seeded with `(seed, yarn)`, so a yarn is reproducible.

use glam::{DVec3, Vec3};
use rand::{Rng, SeedableRng};

use super::Fiber;
use crate::params::{ParamError, check_count, check_positive, check_range};

/// Parameters of one procedural yarn; lengths in centimetres.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct YarnParams {
    /// Full width of the elliptical yarn cross-section, in the fabric plane (cm).
    pub width: f64,
    /// Full height of the cross-section, along the fabric normal (cm); at most `width`.
    pub height: f64,
    /// Number of plies twisted together.
    pub plies: u32,
    /// Regular fibers per ply.
    pub fibers_per_ply: u32,
    /// Fiber radius (cm).
    pub fiber_radius: f64,
    /// Ply twist in turns per cm along the yarn; sign gives the direction (positive = Z twist).
    pub ply_twist: f64,
    /// Fiber twist within a ply, turns per cm relative to the ply (usually opposite to the ply
    /// twist).
    pub fiber_twist: f64,
    /// Smallest migration radius, as a fraction of the ply radius, in [0, 1].
    pub migration_min: f64,
    /// Largest migration radius, as a fraction of the ply radius, in [migration_min, 1].
    pub migration_max: f64,
    /// Length of one migration cycle (cm).
    pub migration_period: f64,
    /// Extra loop fibers per ply that migrate out to `flyaway_max` ply radii.
    pub flyaways_per_ply: u32,
    /// Outermost radius of flyaway loops, in ply radii, in [1, 3].
    pub flyaway_max: f64,
    /// Longest segment along the yarn axis (cm); each segment later gets precomputed data.
    pub segment_length: f64,
    /// Fewest points per turn of a fiber about its ply or of a ply about the yarn.
    pub points_per_turn: u32,
}

impl Default for YarnParams {
    /// A two-ply staple yarn about 0.03 cm wide with 2 x 40 fibers of 8 um radius: far fewer and
    /// thicker fibers than a real yarn (~100+), so an exemplar stays small; a guess informed by
    /// Zhao 2016's fitted cotton/polyester yarns (plies 2-3, migration 0.5-1.0).
    fn default() -> Self {
        Self {
            width: 0.03,
            height: 0.018,
            plies: 2,
            fibers_per_ply: 40,
            fiber_radius: 0.0008,
            ply_twist: 6.0,
            fiber_twist: -12.0,
            migration_min: 0.5,
            migration_max: 1.0,
            migration_period: 0.08,
            flyaways_per_ply: 1,
            flyaway_max: 1.4,
            segment_length: 0.01,
            points_per_turn: 8,
        }
    }
}

/// Twist and migration rounded to whole counts per period (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TwistCounts {
    /// Signed turns of the plies about the yarn axis per period.
    pub ply_turns: i64,
    /// Signed turns of fibers about their ply centre, relative to the ply, per period.
    pub fiber_turns: i64,
    /// Migration cycles per period (at least 1).
    pub migration_cycles: u64,
}

impl TwistCounts {
    /// Rounds `params`' rates to whole counts over a period of `length` cm.
    #[must_use]
    pub fn for_period(params: &YarnParams, length: f64) -> Self {
        Self {
            ply_turns: (params.ply_twist * length).round() as i64,
            fiber_turns: (params.fiber_twist * length).round() as i64,
            migration_cycles: ((length / params.migration_period).round() as u64).max(1),
        }
    }
}

impl YarnParams {
    /// Checks every field against its range; errors name the field (prefixed by `prefix`, e.g.
    /// `warp.`).
    pub fn validate(&self, prefix: &str) -> Result<(), ParamError> {
        let n = |field: &str| format!("{prefix}{field}");
        check_range(&n("width"), self.width, 1e-4, 1.0)?;
        check_range(&n("height"), self.height, 1e-4, self.width)?;
        check_count(&n("plies"), self.plies as usize, 1, 8)?;
        check_count(&n("fibers_per_ply"), self.fibers_per_ply as usize, 1, 4000)?;
        check_range(&n("fiber_radius"), self.fiber_radius, 1e-6, self.ply_radius() * 0.5)?;
        check_range(&n("ply_twist"), self.ply_twist, -500.0, 500.0)?;
        check_range(&n("fiber_twist"), self.fiber_twist, -500.0, 500.0)?;
        check_range(&n("migration_min"), self.migration_min, 0.0, 1.0)?;
        check_range(&n("migration_max"), self.migration_max, self.migration_min, 1.0)?;
        check_positive(&n("migration_period"), self.migration_period)?;
        check_count(&n("flyaways_per_ply"), self.flyaways_per_ply as usize, 0, 1000)?;
        check_range(&n("flyaway_max"), self.flyaway_max, 1.0, 3.0)?;
        check_range(&n("segment_length"), self.segment_length, 1e-4, 1.0)?;
        check_count(&n("points_per_turn"), self.points_per_turn as usize, 3, 64)?;
        Ok(())
    }

    /// Radius of one ply (cm) in the circular (unsquashed) section of radius `width / 2`.
    #[must_use]
    pub fn ply_radius(&self) -> f64 {
        let yarn_radius = 0.5 * self.width;
        if self.plies <= 1 {
            yarn_radius
        } else {
            let s = (std::f64::consts::PI / f64::from(self.plies)).sin();
            yarn_radius * s / (1.0 + s)
        }
    }

    /// Fibers per yarn, flyaways included.
    #[must_use]
    pub fn fibers_per_yarn(&self) -> usize {
        self.plies as usize * (self.fibers_per_ply + self.flyaways_per_ply) as usize
    }

    /// Segments per fiber for a period of `length` cm.
    #[must_use]
    pub fn segments_per_fiber(&self, length: f64) -> usize {
        let t = TwistCounts::for_period(self, length);
        let fastest = t.ply_turns.unsigned_abs().max((t.ply_turns + t.fiber_turns).unsigned_abs());
        let by_turns = u64::from(self.points_per_turn) * fastest.max(t.migration_cycles);
        let by_length = (length / self.segment_length).ceil() as u64;
        by_turns.max(by_length).max(2) as usize
    }
}

/// A yarn's path through the exemplar: its periodic centre line.
pub struct YarnPath<'a> {
    /// Centre at axial coordinate `s` (cm); must satisfy `center(s + length) = center(s) + length * axis`.
    pub center: &'a (dyn Fn(f64) -> DVec3 + Sync),
    /// Unit direction the yarn runs along (+x or +y in a weave).
    pub axis: DVec3,
    /// Period along the axis (cm).
    pub length: f64,
}

/// Generates the fibers of one yarn (index `yarn` in the exemplar) along `path`.
pub fn yarn_fibers(
    params: &YarnParams,
    path: &YarnPath<'_>,
    yarn: u32,
    seed: u64,
) -> Result<Vec<Fiber>, ParamError> {
    use std::f64::consts::TAU;
    params.validate("")?;
    check_positive("yarn period", path.length)?;
    let length = path.length;
    let counts = TwistCounts::for_period(params, length);
    let samples = params.segments_per_fiber(length);
    let mut rng =
        rand_pcg::Pcg64::seed_from_u64(seed ^ (u64::from(yarn) + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15));

    // Frame along the centre line, sampled once per point and shared by all fibers.
    let h = 1e-4 * length;
    let frames: Vec<(DVec3, DVec3, DVec3)> = (0..=samples)
        .map(|i| {
            let s = length * i as f64 / samples as f64;
            let c = (path.center)(s);
            let t = ((path.center)(s + h) - (path.center)(s - h)).normalize();
            let w = t.cross(DVec3::Z).normalize();
            (c, w, w.cross(t))
        })
        .collect();

    let ply_radius = params.ply_radius();
    let ply_offset = 0.5 * params.width - if params.plies <= 1 { 0.5 * params.width } else { ply_radius };
    let squash = params.height / params.width;
    let yarn_phase = rng.random::<f64>() * TAU;
    let mut fibers = Vec::with_capacity(params.fibers_per_yarn());
    for ply in 0..params.plies {
        let ply_phase = yarn_phase + TAU * f64::from(ply) / f64::from(params.plies);
        for k in 0..params.fibers_per_ply + params.flyaways_per_ply {
            let flyaway = k >= params.fibers_per_ply;
            let (r0, m_min, m_max) = if flyaway {
                (1.0, params.migration_max, params.flyaway_max)
            } else {
                (rng.random::<f64>().sqrt(), params.migration_min, params.migration_max)
            };
            let theta0 = rng.random::<f64>() * TAU;
            let mig_phase = rng.random::<f64>() * TAU;
            let points = frames
                .iter()
                .enumerate()
                .map(|(i, &(c, w, up))| {
                    let u = i as f64 / samples as f64;
                    let alpha = ply_phase + TAU * counts.ply_turns as f64 * u;
                    let beta = theta0 + alpha + TAU * counts.fiber_turns as f64 * u;
                    let mig = 0.5 * (1.0 + (TAU * counts.migration_cycles as f64 * u + mig_phase).cos());
                    let rho = r0 * ply_radius * (m_min + (m_max - m_min) * mig);
                    let x = ply_offset * alpha.cos() + rho * beta.cos();
                    let y = (ply_offset * alpha.sin() + rho * beta.sin()) * squash;
                    let p = c + x * w + y * up;
                    Vec3::new(p.x as f32, p.y as f32, p.z as f32)
                })
                .collect();
            fibers.push(Fiber { points, radius: params.fiber_radius as f32, yarn });
        }
    }
    Ok(fibers)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wavy(s: f64) -> DVec3 {
        // A crimped centre line along +y with period 0.2 cm.
        DVec3::new(0.05, s, 0.004 * (std::f64::consts::TAU * s / 0.2).cos())
    }

    fn path() -> YarnPath<'static> {
        YarnPath { center: &wavy, axis: DVec3::Y, length: 0.2 }
    }

    #[test]
    fn fibers_are_periodic_and_finely_sampled() {
        let p = YarnParams::default();
        let fibers = yarn_fibers(&p, &path(), 3, 7).unwrap();
        assert_eq!(fibers.len(), p.fibers_per_yarn());
        let n = p.segments_per_fiber(0.2);
        for f in &fibers {
            assert_eq!(f.points.len(), n + 1);
            assert_eq!(f.yarn, 3);
            let first = f.points[0];
            let last = *f.points.last().unwrap();
            assert!((last - first - Vec3::new(0.0, 0.2, 0.0)).abs().max_element() < 1e-5, "{first} {last}");
            for pair in f.points.windows(2) {
                let d = pair[1] - pair[0];
                assert!(d.y > 0.0 && d.y <= p.segment_length as f32 * 1.2);
                assert!(d.length() < 0.02, "segment too long: {d}");
            }
        }
    }

    #[test]
    fn fibers_stay_inside_the_elliptical_section_and_are_reproducible() {
        let p = YarnParams { flyaways_per_ply: 0, ..YarnParams::default() };
        let fibers = yarn_fibers(&p, &path(), 0, 11).unwrap();
        for f in &fibers {
            for q in &f.points {
                let c = wavy(f64::from(q.y));
                let dx = (f64::from(q.x) - c.x) / (0.5 * p.width);
                let dz = (f64::from(q.z) - c.z) / (0.5 * p.height);
                // The crimp tilts the section a little; allow a small margin.
                assert!(dx * dx + dz * dz <= 1.05, "point outside the yarn: {dx} {dz}");
            }
        }
        assert_eq!(fibers, yarn_fibers(&p, &path(), 0, 11).unwrap());
        assert_ne!(fibers, yarn_fibers(&p, &path(), 0, 12).unwrap());
        assert_ne!(fibers[0].points, yarn_fibers(&p, &path(), 1, 11).unwrap()[0].points);
    }

    #[test]
    fn twist_rounds_to_whole_turns_per_period() {
        let p = YarnParams {
            ply_twist: 6.0,
            fiber_twist: -12.0,
            migration_period: 0.07,
            ..YarnParams::default()
        };
        let t = TwistCounts::for_period(&p, 0.2);
        assert_eq!(t, TwistCounts { ply_turns: 1, fiber_turns: -2, migration_cycles: 3 });
        let slow = YarnParams { ply_twist: 0.1, migration_period: 10.0, ..p };
        let t = TwistCounts::for_period(&slow, 0.2);
        assert_eq!((t.ply_turns, t.migration_cycles), (0, 1));
        // Points per turn drive the sampling when the twist is fast.
        let fast = YarnParams { ply_twist: 50.0, ..p };
        assert_eq!(fast.segments_per_fiber(0.2), 8 * 10);
    }

    #[test]
    fn validation_names_the_field() {
        let p = YarnParams { height: 0.05, ..YarnParams::default() };
        let e = p.validate("warp.").unwrap_err();
        assert_eq!(e.name, "warp.height");
        let p = YarnParams { migration_max: 0.2, ..YarnParams::default() };
        assert_eq!(p.validate("").unwrap_err().name, "migration_max");
        let p = YarnParams { fiber_radius: f64::NAN, ..YarnParams::default() };
        assert!(p.validate("").is_err());
        assert!(YarnParams::default().validate("").is_ok());
    }
}
