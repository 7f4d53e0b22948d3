//! Scene tests: the voxel grid + tiling against brute force, swatch clipping, mean free path.

#![allow(clippy::float_cmp)] // exact equality is the point: determinism, exact zeros.

use super::testing::{SyntheticWeave, random_fiber_cloud, synthetic_weave};
use super::*;
use crate::fabric::{BlockGrid, Fiber, Yarn, YarnRole};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn tiny_weave() -> Exemplar {
    synthetic_weave(&SyntheticWeave { fibers_per_yarn: 8, segment_length: 2.5e-3, ..SyntheticWeave::small() })
}

fn unit_sphere(rng: &mut Pcg64) -> Vec3 {
    let z: f32 = rng.random_range(-1.0..1.0);
    let phi = rng.random::<f32>() * std::f32::consts::TAU;
    let s = (1.0 - z * z).sqrt();
    Vec3::new(s * phi.cos(), s * phi.sin(), z)
}

/// Closest hit over every copy of every segment whose bounds the ray span can reach.
fn brute_force(
    ex: &Exemplar,
    o: DVec3,
    d: DVec3,
    t_max: f64,
    ignore: Option<u32>,
) -> Option<(f64, u32, [i32; 2])> {
    let Tiling::Periodic { period } = ex.tiling else { panic!() };
    let p = period.as_dvec2();
    let (lo, hi) = ex.bounds().unwrap();
    let mut span = (0.0, t_max);
    clip_slab(&mut span, o.z, d.z, f64::from(lo.z), f64::from(hi.z));
    if span.0 >= span.1 {
        return None;
    }
    assert!(span.1.is_finite());
    let (a, b) = (o + span.0 * d, o + span.1 * d);
    let (min, max) = (a.min(b), a.max(b));
    let i0 = ((min.x - f64::from(hi.x)) / p.x).floor() as i32;
    let i1 = ((max.x - f64::from(lo.x)) / p.x).ceil() as i32;
    let j0 = ((min.y - f64::from(hi.y)) / p.y).floor() as i32;
    let j1 = ((max.y - f64::from(lo.y)) / p.y).ceil() as i32;
    assert!((i1 - i0) * (j1 - j0) < 20_000);
    let segments = ex.segments();
    let mut best: Option<(f64, u32, [i32; 2])> = None;
    for j in j0..=j1 {
        for i in i0..=i1 {
            let offset = DVec3::new(f64::from(i) * p.x, f64::from(j) * p.y, 0.0);
            let local = (o - offset).as_vec3();
            for (k, s) in segments.iter().enumerate() {
                if Some(s.fiber) == ignore {
                    continue;
                }
                let c = Capsule::from_segment(s.a, s.b, s.radius);
                if let Some(h) = c.intersect(local, d.as_vec3(), t_max as f32)
                    && best.is_none_or(|b| f64::from(h.t) < b.0)
                {
                    best = Some((f64::from(h.t), k as u32, [i, j]));
                }
            }
        }
    }
    best
}

/// Random rays of three kinds: from far above aimed into the slab (possibly ~150 tiles from
/// the origin), from inside the slab in any direction, and grazing in from just above.
fn random_ray(rng: &mut Pcg64, period: f32, slab: (f32, f32), kind: u32) -> (Vec3, Vec3, f32) {
    let thickness = slab.1 - slab.0;
    match kind {
        0 => {
            let far = if rng.random::<bool>() { 150.0 * period } else { period };
            let target = Vec3::new(
                rng.random_range(-far..far),
                rng.random_range(-far..far),
                rng.random_range(slab.0..slab.1),
            );
            let o = target + Vec3::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3), 0.5);
            (o, (target - o).normalize(), f32::INFINITY)
        }
        1 => {
            let o = Vec3::new(
                rng.random_range(-period..period),
                rng.random_range(-period..period),
                rng.random_range(slab.0..slab.1),
            );
            (o, unit_sphere(rng), 4.0 * period)
        }
        _ => {
            let o = Vec3::new(
                rng.random_range(-period..period),
                rng.random_range(-period..period),
                slab.1 + 0.1 * thickness,
            );
            let phi = rng.random::<f32>() * std::f32::consts::TAU;
            let dz = -rng.random_range(0.01..0.2_f32);
            let s = (1.0 - dz * dz).sqrt();
            (o, Vec3::new(s * phi.cos(), s * phi.sin(), dz), 20.0 * period)
        }
    }
}

#[test]
fn grid_closest_hit_matches_brute_force_over_copies() {
    let ex = tiny_weave();
    let scene = FiberScene::new(&ex, Extent::Unbounded).unwrap();
    assert!(scene.primitive_count() > ex.segment_count());
    let period = scene.period().unwrap().x;
    let fibers = ex.fibers.len() as u32;
    let mut rng = Pcg64::seed_from_u64(11);
    let (mut hits, mut mismatches) = (0, 0);
    let rays = 1500;
    for n in 0..rays {
        let (o, d, t_max) = random_ray(&mut rng, period, scene.slab(), n % 3);
        let ignore = (n % 4 == 1).then(|| rng.random_range(0..fibers));
        let got = scene.closest_hit(o, d, t_max, ignore);
        let want = brute_force(&ex, o.as_dvec3(), d.as_dvec3(), f64::from(t_max), ignore);
        match (got, want) {
            (Some(g), Some(w)) => {
                hits += 1;
                let tol = 2e-6 * (1.0 + w.0);
                assert!((f64::from(g.t) - w.0).abs() < tol, "ray {n}: t {} vs {}", g.t, w.0);
                if (g.segment, g.tile) == (w.1, w.2) {
                    let s = ex.segments()[g.segment as usize];
                    assert_eq!((g.fiber, g.yarn), (s.fiber, s.yarn));
                    let offset = Vec3::new(g.tile[0] as f32 * period, g.tile[1] as f32 * period, 0.0);
                    assert!((g.position - offset - g.local_position).length() < 1e-5);
                    let axis_point = s.a + (s.b - s.a) * g.segment_param;
                    assert!(((g.local_position - axis_point).length() - s.radius).abs() < 2e-6, "ray {n}");
                    assert!(g.normal.dot((g.local_position - axis_point).normalize()) > 0.999);
                    assert!((g.tangent - s.tangent()).length() < 1e-5);
                    assert!(
                        (scene.world_position_f64(&g) - (o.as_dvec3() + f64::from(g.t) * d.as_dvec3()))
                            .length()
                            < 1e-5
                    );
                } else {
                    // Only a tie (two capsules entered at the same point, e.g. at a joint) may differ.
                    assert!((f64::from(g.t) - w.0).abs() < 1e-7 * (1.0 + w.0), "ray {n}: {g:?} vs {w:?}");
                }
            }
            (None, None) => {}
            (g, w) => {
                mismatches += 1;
                eprintln!("ray {n}: mismatch {g:?} vs {w:?}");
            }
        }
    }
    assert!(hits > rays / 3, "{hits}");
    assert!(mismatches <= 1, "{mismatches} hit/miss disagreements");
}

/// Rays along the grid's axes and in its planes (direction components exactly zero), from
/// inside the slab and from just above it: the DDA's degenerate steps and its box clipping.
#[test]
fn rays_along_the_axes_and_in_the_planes_match_brute_force() {
    let ex = tiny_weave();
    let scene = FiberScene::new(&ex, Extent::Unbounded).unwrap();
    let period = scene.period().unwrap().x;
    let slab = scene.slab();
    let mut rng = Pcg64::seed_from_u64(21);
    let mut hits = 0;
    let directions = [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::NEG_Z, Vec3::Z];
    for n in 0..1200 {
        let o = Vec3::new(
            rng.random_range(-period..period),
            rng.random_range(-period..period),
            if n % 5 == 0 { slab.1 + 1e-3 } else { rng.random_range(slab.0..slab.1) },
        );
        let d = if n % 3 == 0 {
            // In a coordinate plane: one zero component.
            let a = rng.random::<f32>() * std::f32::consts::TAU;
            match n % 2 {
                0 => Vec3::new(a.cos(), a.sin(), 0.0),
                _ => Vec3::new(a.cos(), 0.0, -a.sin().abs()),
            }
        } else {
            directions[n % directions.len()]
        };
        let t_max = 3.0 * period;
        let got = scene.closest_hit(o, d, t_max, None);
        let want = brute_force(&ex, o.as_dvec3(), d.as_dvec3(), f64::from(t_max), None);
        match (got, want) {
            (Some(g), Some(w)) => {
                hits += 1;
                assert!(
                    (f64::from(g.t) - w.0).abs() < 2e-6 * (1.0 + w.0),
                    "ray {n} {o} {d}: t {} vs {}",
                    g.t,
                    w.0
                );
            }
            (None, None) => {}
            (g, w) => panic!("ray {n} {o} {d}: {g:?} vs {w:?}"),
        }
        assert_eq!(scene.any_hit(o, d, t_max, None), want.is_some(), "ray {n}");
    }
    assert!(hits > 300, "{hits}");
}

#[test]
fn any_hit_and_ignore_fiber_agree_with_closest_hit() {
    let ex = tiny_weave();
    let scene = FiberScene::new(&ex, Extent::Unbounded).unwrap();
    let period = scene.period().unwrap().x;
    let mut rng = Pcg64::seed_from_u64(5);
    for n in 0..3000 {
        let (o, d, t_max) = random_ray(&mut rng, period, scene.slab(), n % 3);
        let closest = scene.closest_hit(o, d, t_max, None);
        assert_eq!(scene.any_hit(o, d, t_max, None), closest.is_some(), "ray {n}");
        if let Some(h) = closest {
            assert!(!scene.any_hit(o, d, h.t * 0.9999, None));
            assert!(scene.any_hit(o, d, h.t * 1.0001 + 1e-6, None));
            let other = scene.closest_hit(o, d, t_max, Some(h.fiber));
            if let Some(h2) = other {
                assert_ne!(h2.fiber, h.fiber);
                assert!(h2.t >= h.t - 1e-6);
            }
            assert_eq!(scene.any_hit(o, d, t_max, Some(h.fiber)), other.is_some());
        }
    }
}

#[test]
fn tiled_scene_equals_physically_duplicated_copies() {
    let ex = tiny_weave();
    let Tiling::Periodic { period } = ex.tiling else { unreachable!() };
    let mut dup = ex.clone();
    dup.tiling = Tiling::AsIs;
    dup.fibers.clear();
    let copies: Vec<[i32; 2]> = (-2..=2).flat_map(|j| (-2..=2).map(move |i| [i, j])).collect();
    for c in &copies {
        let shift = Vec3::new(c[0] as f32 * period.x, c[1] as f32 * period.y, 0.0);
        dup.fibers.extend(
            ex.fibers.iter().map(|f| Fiber { points: f.points.iter().map(|&p| p + shift).collect(), ..*f }),
        );
    }
    let tiled = FiberScene::new(&ex, Extent::Unbounded).unwrap();
    let flat = FiberScene::new(&dup, Extent::Unbounded).unwrap();
    assert_eq!(flat.primitive_count(), dup.segment_count());
    let per_copy = ex.segment_count() as u32;
    let slab = tiled.slab();
    let mut rng = Pcg64::seed_from_u64(9);
    let mut hits = 0;
    for n in 0..3000 {
        let target = Vec3::new(
            rng.random::<f32>() * period.x,
            rng.random::<f32>() * period.y,
            rng.random_range(slab.0..slab.1),
        );
        let mut d = unit_sphere(&mut rng);
        d.z = -d.z.abs().max(0.3);
        let d = d.normalize();
        let o = target - d * 0.5;
        let a = tiled.closest_hit(o, d, f32::INFINITY, None);
        let b = flat.closest_hit(o, d, f32::INFINITY, None);
        match (a, b) {
            (Some(a), Some(b)) => {
                hits += 1;
                assert!((a.t - b.t).abs() < 2e-6, "ray {n}: {} vs {}", a.t, b.t);
                assert!((a.position - b.position).length() < 2e-6);
                assert!((a.normal - b.normal).length() < 1e-3);
                if (a.t - b.t).abs() > 1e-7 {
                    assert_eq!(a.segment, b.segment % per_copy);
                    assert_eq!(a.tile, copies[(b.segment / per_copy) as usize]);
                }
            }
            (None, None) => {}
            (a, b) => panic!("ray {n}: {a:?} vs {b:?}"),
        }
    }
    assert!(hits > 1000);
}

#[test]
fn finite_swatch_clips_hits_to_its_rectangle() {
    let ex = tiny_weave();
    let (min, max) = (Vec2::new(0.013, -0.021), Vec2::new(0.137, 0.09));
    let swatch = FiberScene::new(&ex, Extent::Rectangle { min, max }).unwrap();
    let plane = FiberScene::new(&ex, Extent::Unbounded).unwrap();
    let slab = plane.slab();
    let mut rng = Pcg64::seed_from_u64(21);
    let (mut inside_hits, mut outside_hits) = (0, 0);
    for n in 0..3000 {
        let target = Vec3::new(
            rng.random_range(-0.05..0.2),
            rng.random_range(-0.1..0.15),
            rng.random_range(slab.0..slab.1),
        );
        let o = target + Vec3::new(rng.random_range(-0.1..0.1), rng.random_range(-0.1..0.1), 0.2);
        let d = (target - o).normalize();
        let clipped = swatch.closest_hit(o, d, f32::INFINITY, None);
        if let Some(h) = clipped {
            assert!(h.position.x >= min.x - 1e-6 && h.position.x <= max.x + 1e-6, "ray {n}: {h:?}");
            assert!(h.position.y >= min.y - 1e-6 && h.position.y <= max.y + 1e-6, "ray {n}: {h:?}");
        }
        match plane.closest_hit(o, d, f32::INFINITY, None) {
            Some(h)
                if h.position.truncate().cmpgt(min + 1e-4).all()
                    && h.position.truncate().cmplt(max - 1e-4).all() =>
            {
                inside_hits += 1;
                let c = clipped.expect("hit inside the swatch must stay");
                assert!((c.t - h.t).abs() < 1e-6 && c.segment == h.segment && c.tile == h.tile);
            }
            Some(_) => outside_hits += 1,
            None => assert!(clipped.is_none()),
        }
    }
    assert!(inside_hits > 200 && outside_hits > 200, "{inside_hits} {outside_hits}");
    // Vertical rays just outside the rectangle see nothing; `Copies` is the rectangle of whole periods.
    assert!(swatch.closest_hit(Vec3::new(0.0129, 0.03, 1.0), Vec3::NEG_Z, f32::INFINITY, None).is_none());
    assert!(swatch.closest_hit(Vec3::new(0.05, 0.0901, 1.0), Vec3::NEG_Z, f32::INFINITY, None).is_none());
    let copies = FiberScene::new(&ex, Extent::Copies { nx: 3, ny: 2 }).unwrap();
    assert_eq!(copies.rectangle(), Some((Vec2::ZERO, Vec2::new(0.15, 0.1))));
    assert_eq!(copies.central_tile(), [1, 1]);
}

#[test]
fn as_is_exemplar_and_degenerate_scenes() {
    let yarns = vec![Yarn { role: YarnRole::Other, material: 0 }];
    let fiber = Fiber {
        points: vec![Vec3::new(-1.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0)],
        radius: 0.1,
        yarn: 0,
    };
    let ex = Exemplar {
        fibers: vec![fiber],
        yarns: yarns.clone(),
        tiling: Tiling::AsIs,
        blocks: BlockGrid { nx: 1, ny: 1 },
    };
    let scene = FiberScene::new(&ex, Extent::Unbounded).unwrap();
    let h = scene.closest_hit(Vec3::new(0.5, 0.0, 3.0), Vec3::NEG_Z, f32::INFINITY, None).unwrap();
    assert!((h.t - 2.9).abs() < 1e-6 && h.segment == 0 && h.tile == [0, 0]);
    // The bend at (1, 0, 0) is closed: a ray down onto the joint's outer corner hits the sphere.
    let h = scene.closest_hit(Vec3::new(1.07, -0.07, 3.0), Vec3::NEG_Z, f32::INFINITY, None).unwrap();
    assert!(h.t < 3.0 && h.t > 2.9);
    assert!(scene.closest_hit(Vec3::new(0.5, 0.0, 3.0), Vec3::NEG_Z, f32::INFINITY, Some(0)).is_none());
    assert!(scene.closest_hit(Vec3::new(0.5, 0.0, 3.0), Vec3::ZERO, f32::INFINITY, None).is_none());
    // Empty and invalid exemplars.
    let empty = Exemplar {
        fibers: vec![],
        yarns,
        tiling: Tiling::Periodic { period: Vec2::ONE },
        blocks: BlockGrid { nx: 1, ny: 1 },
    };
    let scene = FiberScene::new(&empty, Extent::Unbounded).unwrap();
    assert!(scene.closest_hit(Vec3::Z, Vec3::NEG_Z, f32::INFINITY, None).is_none());
    let bad = Exemplar { tiling: Tiling::Periodic { period: Vec2::new(0.0, 1.0) }, ..empty.clone() };
    assert!(matches!(FiberScene::new(&bad, Extent::Unbounded), Err(SceneError::InvalidPeriod(_))));
    assert!(matches!(
        FiberScene::new(&empty, Extent::Copies { nx: 0, ny: 1 }),
        Err(SceneError::EmptyExtent { .. })
    ));
}

#[test]
fn horizontal_ray_in_unbounded_fabric_terminates() {
    let ex = tiny_weave();
    let scene = FiberScene::new(&ex, Extent::Unbounded).unwrap();
    let (lo, hi) = scene.slab();
    // Just above the top fibers, exactly horizontal: no hit, and the walk must end.
    // (Whether it grazes a fiber top does not matter; that it returns does.)
    let _ = scene.closest_hit(Vec3::new(0.0, 0.0, hi - 1e-7), Vec3::X, f32::INFINITY, None);
    let _ = scene.any_hit(Vec3::new(0.0, 0.0, hi - 1e-7), Vec3::X, f32::INFINITY, None);
    assert!(
        scene
            .closest_hit(Vec3::new(0.01, 0.0, 0.5 * (lo + hi)), Vec3::new(1.0, 0.3, 0.0), f32::INFINITY, None)
            .is_some()
    );
}

#[test]
fn mean_free_path_is_deterministic_and_matches_poisson_estimate() {
    // Random straight fibers: a Poisson medium with mean free path V / (N * mean projected area),
    // where a capsule's mean projected area is a quarter of its surface area.
    let (period, thickness, count, length, radius) = (0.1_f32, 0.25_f32, 3000, 0.03_f32, 5e-4_f32);
    let ex = random_fiber_cloud(period, thickness, count, length, radius, 1, 3);
    let scene = FiberScene::new(&ex, Extent::Unbounded).unwrap();
    let mfp = mean_free_path(&scene, 20_000, 42);
    let again = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| mean_free_path(&scene, 20_000, 42));
    assert_eq!(mfp, again);
    assert_ne!(mean_free_path(&scene, 2000, 43).mean_cm, mean_free_path(&scene, 2000, 42).mean_cm);
    let area = f64::from(
        2.0 * std::f32::consts::PI * radius * length + 4.0 * std::f32::consts::PI * radius * radius,
    ) / 4.0;
    let poisson = f64::from(period * period * thickness) / (f64::from(count as u32) * area);
    let rho = f64::from(count as u32) * f64::from(std::f32::consts::PI * radius * radius * length)
        / f64::from(period * period * thickness);
    let estimate_2r_over_rho = 2.0 * f64::from(radius) / rho;
    eprintln!("mfp {mfp:?}, Poisson {poisson}, 2r/rho {estimate_2r_over_rho}");
    assert!(mfp.std_error_cm < 0.02 * mfp.mean_cm);
    // Escaped samples (the longer paths) are excluded, so the measurement runs somewhat short.
    let ratio = mfp.mean_cm / poisson;
    assert!((0.7..1.1).contains(&ratio), "measured / Poisson = {ratio}");
    assert!(mfp.escaped_fraction > 0.0 && mfp.escaped_fraction < 0.5);
}
