//! Ray casting against patterned cloth (paper section 6.4): blocks of several exemplars side by
//! side, as the GPU renderer draws them.
//!
//! How it works:
//! - Every exemplar is its own periodic [`FiberScene`] over the whole plane, all in one world
//!   frame: copies at whole periods from the origin, as the GPU renderer's volumes are.
//! - The [`PatternMap`] says which exemplar each block uses; blocks are one size for all
//!   exemplars (each exemplar's period holds a whole number of them) and start at the origin.
//! - A ray is clipped to the swatch rectangle and to the z range of all the exemplars, then
//!   walks the blocks its xy projection crosses, nearest first (a 2D DDA over the block
//!   lattice). Each block's piece of the ray is traced in that block's exemplar alone, so a
//!   fiber ends where its block ends: a ray that enters a fiber through a block's edge sees what
//!   lies behind it, as at the swatch's edge, and as the GPU's march does (`first_fiber_hit` in
//!   `shaders/shared/fabric_data.wgsl` cuts its ray at the same edges). Hits in a piece are
//!   exact closest hits, so the walk stops at the first piece with one.
//! - Fibers and yarns are numbered across the exemplars: exemplar `e`'s fiber `f` is fiber
//!   `fiber_offset(e) + f` (yarns likewise), so `ignore_fiber` and a hit's material name one
//!   fiber of one exemplar. [`Hit::exemplar`] says which exemplar was hit; `segment`,
//!   `local_position` and `tile` are that exemplar's own.

use glam::{DVec2, DVec3, Vec2, Vec3};

use super::{CELL_OVERLAP, Extent, FiberScene, Hit, SceneError, clip_slab, walk_lattice};
use crate::bake::pattern::PatternMap;
use crate::fabric::{Exemplar, Tiling};

/// Largest relative difference between two exemplars' block sizes (they share their yarns'
/// spacing, so they agree to rounding).
const BLOCK_SIZE_TOLERANCE: f32 = 1e-4;

/// Why a patterned cloth could not be made ready for ray casting.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PatternSceneError {
    #[error("exemplar {exemplar}: {source}")]
    Scene { exemplar: usize, source: SceneError },
    #[error("exemplar {exemplar} does not tile periodically; patterned cloth is made of woven exemplars")]
    NotPeriodic { exemplar: usize },
    #[error(
        "exemplar {exemplar}'s blocks are {got:?} cm, exemplar 0's {expected:?} cm: the blocks of a \
         pattern must all be one size"
    )]
    BlockSize { exemplar: usize, expected: Vec2, got: Vec2 },
    #[error("the pattern map names exemplar {named}, but there are only {count} exemplars")]
    MissingExemplar { named: usize, count: usize },
}

/// Where each exemplar's numbers start when the things `count` counts (fibers, yarns) are
/// numbered across `exemplars` in order, and one past the last: `[0, n0, n0 + n1, …]`. How a
/// patterned cloth numbers its fibers and yarns (the module docs).
#[must_use]
pub fn numbered_across(exemplars: &[Exemplar], count: impl Fn(&Exemplar) -> usize) -> Vec<u32> {
    let mut starts = vec![0_u32];
    for exemplar in exemplars {
        starts.push(starts[starts.len() - 1] + count(exemplar) as u32);
    }
    starts
}

/// Patterned cloth ready for ray casting; see the module docs.
#[derive(Debug)]
pub struct PatternedFibers {
    /// One periodic scene per exemplar, over the whole plane.
    scenes: Vec<FiberScene>,
    map: PatternMap,
    /// Side of a block along x and y, cm.
    block: DVec2,
    /// The swatch rectangle.
    rect: (DVec2, DVec2),
    /// Global number of each exemplar's first fiber, and one past the last exemplar's last.
    fiber_offsets: Vec<u32>,
    /// Global number of each exemplar's first yarn (and one past the last).
    yarn_offsets: Vec<u32>,
    /// z range of every exemplar's fibers, padded by [`CELL_OVERLAP`].
    z_range: (f64, f64),
}

impl PatternedFibers {
    /// Builds the exemplars' scenes for the swatch rectangle `min..max` (cm).
    ///
    /// # Errors
    /// An exemplar that is not periodic or has broken geometry, blocks of different sizes, a map
    /// that names a missing exemplar, or an empty rectangle.
    pub fn new(
        exemplars: &[Exemplar],
        map: PatternMap,
        (min, max): (Vec2, Vec2),
    ) -> Result<Self, PatternSceneError> {
        if map.exemplar_count() > exemplars.len() {
            return Err(PatternSceneError::MissingExemplar {
                named: map.exemplar_count() - 1,
                count: exemplars.len(),
            });
        }
        if !(min.is_finite() && max.is_finite() && min.x < max.x && min.y < max.y) {
            return Err(PatternSceneError::Scene {
                exemplar: 0,
                source: SceneError::EmptyExtent { min, max },
            });
        }
        let mut block = None;
        let mut scenes = Vec::with_capacity(exemplars.len());
        for (e, exemplar) in exemplars.iter().enumerate() {
            let Tiling::Periodic { period } = exemplar.tiling else {
                return Err(PatternSceneError::NotPeriodic { exemplar: e });
            };
            let side = period / Vec2::new(exemplar.blocks.nx as f32, exemplar.blocks.ny as f32);
            let expected = *block.get_or_insert(side);
            if ((side - expected).abs() / expected).max_element() > BLOCK_SIZE_TOLERANCE {
                return Err(PatternSceneError::BlockSize { exemplar: e, expected, got: side });
            }
            let scene = FiberScene::new(exemplar, Extent::Unbounded)
                .map_err(|source| PatternSceneError::Scene { exemplar: e, source })?;
            scenes.push(scene);
        }
        let fiber_offsets = numbered_across(exemplars, |e| e.fibers.len());
        let yarn_offsets = numbered_across(exemplars, |e| e.yarns.len());
        let z_range = scenes
            .iter()
            .filter(|s| s.primitive_count() > 0)
            .map(|s| s.z_range)
            .reduce(|a, b| (a.0.min(b.0), a.1.max(b.1)))
            .unwrap_or((0.0, 0.0));
        let block = block.unwrap_or(Vec2::ONE).as_dvec2();
        Ok(Self {
            scenes,
            map,
            block,
            rect: (min.as_dvec2(), max.as_dvec2()),
            fiber_offsets,
            yarn_offsets,
            z_range,
        })
    }

    /// Number of exemplars.
    #[must_use]
    pub fn exemplar_count(&self) -> usize {
        self.scenes.len()
    }

    /// Exemplar `e`'s own scene (its fibers numbered from 0).
    #[must_use]
    pub fn exemplar_scene(&self, e: usize) -> &FiberScene {
        &self.scenes[e]
    }

    /// Global number of exemplar `e`'s first fiber.
    #[must_use]
    pub fn fiber_offset(&self, e: usize) -> u32 {
        self.fiber_offsets[e]
    }

    /// Global number of exemplar `e`'s first yarn (the index of its yarn 0's material).
    #[must_use]
    pub fn yarn_offset(&self, e: usize) -> u32 {
        self.yarn_offsets[e]
    }

    /// Side of a pattern block along x and y, cm.
    #[must_use]
    pub fn block_size(&self) -> Vec2 {
        self.block.as_vec2()
    }

    /// The z range (cm) all the exemplars' fibers lie in.
    #[must_use]
    pub fn slab(&self) -> (f32, f32) {
        ((self.z_range.0 + CELL_OVERLAP) as f32, (self.z_range.1 - CELL_OVERLAP) as f32)
    }

    /// First fiber hit along `origin + t * dir` with `0 <= t < t_max`, skipping every segment
    /// of the (global) fiber `ignore_fiber`; as [`FiberScene::closest_hit`].
    #[must_use]
    pub fn closest_hit(&self, origin: Vec3, dir: Vec3, t_max: f32, ignore_fiber: Option<u32>) -> Option<Hit> {
        self.walk(origin.as_dvec3(), dir.as_dvec3(), f64::from(t_max), ignore_fiber, false)
    }

    /// Whether anything blocks `origin + t * dir` for `0 <= t < t_max`.
    #[must_use]
    pub fn any_hit(&self, origin: Vec3, dir: Vec3, t_max: f32, ignore_fiber: Option<u32>) -> bool {
        self.walk(origin.as_dvec3(), dir.as_dvec3(), f64::from(t_max), ignore_fiber, true).is_some()
    }

    /// Clips the ray to the slab and the swatch, then walks the blocks; see the module docs.
    fn walk(&self, origin: DVec3, dir: DVec3, t_max: f64, ignore: Option<u32>, any: bool) -> Option<Hit> {
        let d = dir.try_normalize()?;
        if !origin.is_finite() || t_max.is_nan() {
            return None;
        }
        let mut span = (0.0, t_max);
        let (min, max) = self.rect;
        clip_slab(&mut span, origin.z, d.z, self.z_range.0, self.z_range.1);
        clip_slab(&mut span, origin.x, d.x, min.x, max.x);
        clip_slab(&mut span, origin.y, d.y, min.y, max.y);
        if span.0 >= span.1 {
            return None;
        }
        walk_lattice(origin, d, span, self.block, None, |block, t_from, t_to| {
            let e = usize::from(self.map.exemplar_at(block[0], block[1]));
            let (first, last) = (self.fiber_offsets[e], self.fiber_offsets[e + 1]);
            let own_ignore = ignore.filter(|f| (first..last).contains(f)).map(|f| f - first);
            let mut hit = self.scenes[e].walk(origin, d, (t_from, t_to), own_ignore, any)?;
            hit.fiber += first;
            hit.yarn += self.yarn_offsets[e];
            hit.exemplar = e as u16;
            Some(hit)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raycast::testing::{SyntheticWeave, synthetic_weave};
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    /// Camera-like and scatter-like rays over `rect`: from above the fabric at random points and
    /// angles up to 80 degrees, and from random points inside the slab in uniform directions.
    fn rays(rect: (Vec2, Vec2), slab: (f32, f32), n: usize, seed: u64) -> Vec<(Vec3, Vec3)> {
        let mut rng = Pcg64::seed_from_u64(seed);
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            let x = rng.random_range(rect.0.x..rect.1.x);
            let y = rng.random_range(rect.0.y..rect.1.y);
            let phi = rng.random_range(0.0..std::f32::consts::TAU);
            if i % 2 == 0 {
                let theta = rng.random_range(0.0_f32..80.0).to_radians();
                let dir = Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), -theta.cos());
                out.push((Vec3::new(x, y, slab.1 + 0.02) - dir * 0.02 / theta.cos(), dir));
            } else {
                let z = rng.random_range(slab.0..slab.1);
                let cos_theta: f32 = rng.random_range(-1.0..1.0);
                let sin_theta = (1.0 - cos_theta * cos_theta).sqrt();
                out.push((
                    Vec3::new(x, y, z),
                    Vec3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), cos_theta),
                ));
            }
        }
        out
    }

    fn weave(period: f32, fibers_per_yarn: u32) -> Exemplar {
        let mut exemplar =
            synthetic_weave(&SyntheticWeave { period, fibers_per_yarn, ..SyntheticWeave::small() });
        exemplar.blocks = crate::fabric::BlockGrid { nx: 2, ny: 2 };
        exemplar
    }

    /// A pattern of one exemplar, however its map reads, is that exemplar's plain swatch: the
    /// same hits, the blocks' edges invisible (the pieces join exactly).
    #[test]
    fn one_exemplar_in_every_block_is_the_plain_swatch() {
        let exemplar = weave(0.05, 24);
        let rect = (Vec2::new(-0.12, -0.07), Vec2::new(0.09, 0.11));
        let plain = FiberScene::new(&exemplar, Extent::Rectangle { min: rect.0, max: rect.1 }).unwrap();
        let map = PatternMap::from_rows(&["000", "000"]).unwrap();
        let patterned = PatternedFibers::new(&[exemplar.clone(), exemplar], map, rect).unwrap();
        let (mut hits, mut ignored) = (0, 0);
        for (i, (o, d)) in rays(rect, plain.slab(), 4000, 7).into_iter().enumerate() {
            let ignore = (i % 3 == 0).then_some(i as u32 % 24);
            let a = plain.closest_hit(o, d, f32::INFINITY, ignore);
            let b = patterned.closest_hit(o, d, f32::INFINITY, ignore);
            match (a, b) {
                (None, None) => {}
                (Some(a), Some(b)) => {
                    assert!((a.t - b.t).abs() <= 1e-6 * (1.0 + a.t), "ray {i}: t {} against {}", a.t, b.t);
                    assert_eq!(
                        (a.segment, a.fiber, a.yarn, b.exemplar),
                        (b.segment, b.fiber, b.yarn, 0),
                        "ray {i}"
                    );
                    hits += 1;
                    ignored += usize::from(ignore.is_some());
                }
                _ => panic!("ray {i} from {o} along {d}: plain {a:?}, patterned {b:?}"),
            }
            assert_eq!(plain.any_hit(o, d, 0.01, ignore), patterned.any_hit(o, d, 0.01, ignore), "ray {i}");
        }
        assert!(hits > 1000 && ignored > 200, "{hits} hits, {ignored} with a fiber ignored");
    }

    /// Two exemplars of different density: every hit lies in a block of the exemplar it came
    /// from, and it is the nearest entry into a fiber of that block's exemplar, found by testing
    /// every capsule of every copy of both exemplars near the ray (brute force).
    #[test]
    fn hits_are_the_nearest_fiber_entry_of_each_blocks_own_exemplar() {
        let exemplars = [weave(0.05, 24), weave(0.05, 48)];
        let rect = (Vec2::new(-0.06, -0.05), Vec2::new(0.07, 0.06));
        let map = PatternMap::from_rows(&["011", "100"]).unwrap();
        let patterned = PatternedFibers::new(&exemplars, map.clone(), rect).unwrap();
        let block = patterned.block_size();
        assert!((block - Vec2::splat(0.025)).abs().max_element() < 1e-7);
        let block_of = |p: Vec3| {
            let b = (p.truncate() / block).floor();
            usize::from(map.exemplar_at(b.x as i64, b.y as i64))
        };
        // Every capsule of every copy of each exemplar within a period of the rectangle.
        let mut capsules: Vec<(usize, super::super::Capsule, u32)> = Vec::new();
        for (e, exemplar) in exemplars.iter().enumerate() {
            for s in exemplar.segments() {
                for cx in -4..=4 {
                    for cy in -4..=4 {
                        let shift = Vec3::new(cx as f32 * 0.05, cy as f32 * 0.05, 0.0);
                        let capsule = super::super::Capsule::from_segment(s.a + shift, s.b + shift, s.radius);
                        capsules.push((e, capsule, s.fiber));
                    }
                }
            }
        }
        let mut hits = [0_usize; 2];
        for (i, (o, d)) in rays(rect, patterned.slab(), 300, 11).into_iter().enumerate() {
            let brute = capsules
                .iter()
                .filter_map(|(e, c, fiber)| {
                    let hit = c.intersect_piece(o, d, f32::INFINITY, o)?;
                    let p = o + hit.t * d;
                    let inside = p.x >= rect.0.x && p.x < rect.1.x && p.y >= rect.0.y && p.y < rect.1.y;
                    (inside && block_of(p) == *e).then_some((hit.t, *e, *fiber))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let hit = patterned.closest_hit(o, d, f32::INFINITY, None);
            match (brute, hit) {
                (None, None) => {}
                (Some((t, e, fiber)), Some(hit)) => {
                    assert!((t - hit.t).abs() <= 2e-6, "ray {i}: brute force t {t}, walk {}", hit.t);
                    assert_eq!(usize::from(hit.exemplar), e, "ray {i}");
                    assert_eq!(hit.fiber, patterned.fiber_offset(e) + fiber, "ray {i}");
                    assert_eq!(block_of(hit.position), e, "ray {i}: hit outside its exemplar's blocks");
                    hits[e] += 1;
                }
                _ => panic!("ray {i} from {o} along {d}: brute force {brute:?}, walk {hit:?}"),
            }
        }
        assert!(hits[0] > 40 && hits[1] > 40, "hits per exemplar {hits:?}");
    }

    /// Ignoring a fiber of one exemplar leaves the same-numbered fiber of another visible, and
    /// yarns are numbered after the earlier exemplars'.
    #[test]
    fn fibers_and_yarns_are_numbered_across_the_exemplars() {
        let exemplars = [weave(0.05, 24), weave(0.05, 24)];
        let rect = (Vec2::new(-0.1, -0.1), Vec2::new(0.1, 0.1));
        let patterned =
            PatternedFibers::new(&exemplars, PatternMap::from_rows(&["1"]).unwrap(), rect).unwrap();
        let (fibers, yarns) = (exemplars[0].fibers.len() as u32, exemplars[0].yarns.len() as u32);
        assert_eq!((patterned.fiber_offset(1), patterned.yarn_offset(1)), (fibers, yarns));
        let down = Vec3::new(0.1, 0.05, -1.0).normalize();
        let o = Vec3::new(0.01, 0.02, 0.5);
        let hit = patterned.closest_hit(o, down, f32::INFINITY, None).expect("a ray down hits the cloth");
        assert_eq!(hit.exemplar, 1);
        assert!(hit.fiber >= fibers && hit.yarn >= yarns);
        // Exemplar 0's fiber of the same local number is not the one hit: ignoring it changes nothing.
        let same_number = hit.fiber - fibers;
        assert_eq!(patterned.closest_hit(o, down, f32::INFINITY, Some(same_number)), Some(hit));
        let behind = patterned.closest_hit(o, down, f32::INFINITY, Some(hit.fiber)).expect("fibers behind");
        assert!(behind.t > hit.t && behind.fiber != hit.fiber);
    }

    #[test]
    fn mismatched_blocks_and_missing_exemplars_are_refused() {
        let rect = (Vec2::splat(-0.1), Vec2::splat(0.1));
        let mut coarse = weave(0.05, 8);
        coarse.blocks = crate::fabric::BlockGrid { nx: 1, ny: 2 };
        let err =
            PatternedFibers::new(&[weave(0.05, 8), coarse], PatternMap::from_rows(&["01"]).unwrap(), rect)
                .unwrap_err();
        assert!(matches!(err, PatternSceneError::BlockSize { exemplar: 1, .. }), "{err}");
        let err = PatternedFibers::new(&[weave(0.05, 8)], PatternMap::from_rows(&["02"]).unwrap(), rect)
            .unwrap_err();
        assert_eq!(err, PatternSceneError::MissingExemplar { named: 2, count: 1 });
        assert!(err.to_string().contains("exemplar 2"));
        let err = PatternedFibers::new(&[weave(0.05, 8)], PatternMap::uniform(0), (Vec2::ZERO, Vec2::ZERO))
            .unwrap_err();
        assert!(
            matches!(err, PatternSceneError::Scene { source: SceneError::EmptyExtent { .. }, .. }),
            "{err}"
        );
    }
}
