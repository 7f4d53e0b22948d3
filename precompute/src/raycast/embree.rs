//! Embree 3 as a second fiber ray caster, for measuring ours against an engine built for this
//! (feature `embree`; `twill bench raycast --embree`).
//!
//! How it works: Embree's round linear curves with a constant radius are exactly our capsules
//! (a cylinder with hemispherical caps at both ends), traversed with Embree's SIMD BVH. Every
//! segment becomes one curve of its own (two vertices `(x, y, z, r)`, both caps), in every copy
//! of a periodic exemplar whose period cell lies within one period of the swatch rectangle
//! ([`copies`]), either all in one BVH ([`Layout::Explicit`]) or as one BVH of the exemplar
//! instanced per copy ([`Layout::Instanced`], a two-level BVH: the nearest to [`FiberScene`]'s walk,
//! which walks the copies of one wrapped period). Rays are not clipped to the swatch here, so a
//! hit on a capsule sticking out of the rectangle counts, where ours would not: the measured hit
//! fractions say how much that matters. Closest hit is `rtcIntersect1`, any hit `rtcOccluded1`,
//! both with an incoherent context; [`Batch`] also hands the rays over in packets of four or as
//! one stream. The binding (the `embree` crate) keeps Embree's C API behind
//! a safe interface; this module has no `unsafe` of its own.

use std::time::Duration;

use cgmath::{Matrix4, Vector3, Vector4};
use embree::{Device, Geometry, Instance, IntersectContext, LinearCurve, Ray, Ray4, RayHit, RayHit4, Scene};
use glam::Vec3;

use super::FiberScene;
use super::throughput::{Query, best_rate};

/// The fabric as Embree sees it: the exemplar's capsules as (a, b, radius), and the offsets of
/// its copies that can reach the swatch rectangle (one zero offset for `Tiling::AsIs` or an
/// unbounded scene).
#[derive(Debug, Clone)]
pub struct Copies {
    pub capsules: Vec<(Vec3, Vec3, f32)>,
    pub offsets: Vec<Vec3>,
}

/// How the copies are put in the scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// Every capsule of every copy in one BVH.
    Explicit,
    /// One BVH of the exemplar, instanced once per copy (a two-level BVH).
    Instanced,
}

/// The copies of `scene`'s exemplar that can reach its swatch.
#[must_use]
pub fn copies(scene: &FiberScene) -> Copies {
    let capsules = scene.segments().iter().map(|s| (s.a, s.b, s.radius)).collect();
    let (Some(period), Some((min, max))) = (scene.period(), scene.rectangle()) else {
        return Copies { capsules, offsets: vec![Vec3::ZERO] };
    };
    let first = ((min / period).floor() - 1.0).as_ivec2();
    let last = ((max / period).floor() + 1.0).as_ivec2();
    let offsets = (first.y..=last.y)
        .flat_map(|ty| {
            (first.x..=last.x).map(move |tx| Vec3::new(tx as f32 * period.x, ty as f32 * period.y, 0.0))
        })
        .collect();
    Copies { capsules, offsets }
}

/// How rays are handed to Embree.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Batch {
    /// One ray per call (`rtcIntersect1`, `rtcOccluded1`).
    Single,
    /// Packets of four (`rtcIntersect4`, `rtcOccluded4`): SIMD across the rays of a packet.
    Packets4,
    /// All rays in one call (`rtcIntersect1M`, `rtcOccluded1M`): Embree orders the work.
    Stream,
}

/// Casts `rays` against `copies` with Embree: the distance of every closest hit (`None` for a
/// miss), or with [`Query::AnyHit`] whether each ray is occluded (`Some(0.0)` for a hit).
#[must_use]
pub fn cast(
    copies: &Copies,
    layout: Layout,
    batch: Batch,
    rays: &[(Vec3, Vec3)],
    query: Query,
) -> Vec<Option<f32>> {
    with_scene(copies, layout, |scene| trace_all(scene, batch, rays, query))
}

/// Rays per second on this thread with Embree: `rays` cast with `query` over and over for at
/// least `min_time` (after one untimed pass), the best pass. The BVH build is not timed.
#[must_use]
pub fn rays_per_second(
    copies: &Copies,
    layout: Layout,
    batch: Batch,
    rays: &[(Vec3, Vec3)],
    query: Query,
    min_time: Duration,
) -> f64 {
    with_scene(copies, layout, |scene| {
        best_rate(rays.len(), min_time, || trace_all(scene, batch, rays, query).iter().flatten().count())
    })
}

/// Builds the Embree scene of `copies` and runs `f` on it.
fn with_scene<T>(copies: &Copies, layout: Layout, f: impl FnOnce(&embree::CommittedScene<'_>) -> T) -> T {
    let device = Device::new();
    match layout {
        Layout::Explicit => {
            let all: Vec<(Vec3, Vec3, f32)> = copies
                .offsets
                .iter()
                .flat_map(|&o| copies.capsules.iter().map(move |&(a, b, r)| (a + o, b + o, r)))
                .collect();
            let mut scene = Scene::new(&device);
            scene.attach_geometry(curves(&device, &all));
            let committed = scene.commit();
            f(&committed)
        }
        Layout::Instanced => {
            let mut exemplar = Scene::new(&device);
            exemplar.attach_geometry(curves(&device, &copies.capsules));
            let exemplar = exemplar.commit();
            let mut scene = Scene::new(&device);
            for offset in &copies.offsets {
                let mut instance = Instance::unanimated(&device, &exemplar);
                instance
                    .set_transform(&Matrix4::from_translation(Vector3::new(offset.x, offset.y, offset.z)));
                let mut geometry = Geometry::Instance(instance);
                geometry.commit();
                scene.attach_geometry(geometry);
            }
            let committed = scene.commit();
            f(&committed)
        }
    }
}

/// One round linear curve per capsule, both caps on (each curve a whole capsule).
fn curves<'a>(device: &'a Device, capsules: &[(Vec3, Vec3, f32)]) -> Geometry<'a> {
    let mut curves = LinearCurve::round(device, capsules.len(), 2 * capsules.len(), false);
    {
        let mut vertices = curves.vertex_buffer.map();
        for (i, &(a, b, r)) in capsules.iter().enumerate() {
            vertices[2 * i] = Vector4::new(a.x, a.y, a.z, r);
            vertices[2 * i + 1] = Vector4::new(b.x, b.y, b.z, r);
        }
    }
    {
        let mut indices = curves.index_buffer.map();
        for i in 0..capsules.len() {
            indices[i] = 2 * i as u32;
        }
    }
    {
        let mut flags = curves.flag_buffer.map();
        for i in 0..capsules.len() {
            flags[i] = 0;
        }
    }
    let mut geometry = Geometry::LinearCurve(curves);
    geometry.commit();
    geometry
}

fn trace_all(
    scene: &embree::CommittedScene<'_>,
    batch: Batch,
    rays: &[(Vec3, Vec3)],
    query: Query,
) -> Vec<Option<f32>> {
    let v = |p: Vec3| Vector3::new(p.x, p.y, p.z);
    match batch {
        Batch::Single => rays.iter().map(|&(o, d)| trace(scene, o, d, query)).collect(),
        Batch::Packets4 => {
            let mut out = Vec::with_capacity(rays.len());
            let mut context = IntersectContext::incoherent();
            for chunk in rays.chunks(4) {
                let mut origins = [Vector3::new(0.0, 0.0, 0.0); 4];
                let mut dirs = [Vector3::new(0.0, 0.0, 1.0); 4];
                let mut valid = [0_i32; 4];
                for (k, &(o, d)) in chunk.iter().enumerate() {
                    (origins[k], dirs[k], valid[k]) = (v(o), v(d), -1);
                }
                let packet = Ray4::new(origins, dirs);
                match query {
                    Query::ClosestHit => {
                        let mut hits = RayHit4::new(packet);
                        scene.intersect4(&mut context, &mut hits, &valid);
                        out.extend(
                            (0..chunk.len())
                                .map(|k| (hits.hit.geomID[k] != u32::MAX).then_some(hits.ray.tfar[k])),
                        );
                    }
                    Query::AnyHit => {
                        let mut packet = packet;
                        scene.occluded4(&mut context, &mut packet, &valid);
                        out.extend((0..chunk.len()).map(|k| (packet.tfar[k] < 0.0).then_some(0.0)));
                    }
                }
            }
            out
        }
        Batch::Stream => {
            let mut context = IntersectContext::incoherent();
            match query {
                Query::ClosestHit => {
                    let mut all: Vec<RayHit> =
                        rays.iter().map(|&(o, d)| RayHit::new(Ray::new(v(o), v(d)))).collect();
                    scene.intersect_stream_aos(&mut context, &mut all);
                    all.iter().map(|h| h.hit.hit().then_some(h.ray.tfar)).collect()
                }
                Query::AnyHit => {
                    let mut all: Vec<Ray> = rays.iter().map(|&(o, d)| Ray::new(v(o), v(d))).collect();
                    scene.occluded_stream_aos(&mut context, &mut all);
                    all.iter().map(|r| (r.tfar < 0.0).then_some(0.0)).collect()
                }
            }
        }
    }
}

fn trace(scene: &embree::CommittedScene<'_>, o: Vec3, d: Vec3, query: Query) -> Option<f32> {
    let mut context = IntersectContext::incoherent();
    let ray = Ray::new(Vector3::new(o.x, o.y, o.z), Vector3::new(d.x, d.y, d.z));
    match query {
        Query::ClosestHit => {
            let mut hit = RayHit::new(ray);
            scene.intersect(&mut context, &mut hit);
            hit.hit.hit().then_some(hit.ray.tfar)
        }
        Query::AnyHit => {
            let mut ray = ray;
            scene.occluded(&mut context, &mut ray);
            // Embree marks an occluded ray by setting tfar to -inf.
            (ray.tfar < 0.0).then_some(0.0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raycast::testing::{SyntheticWeave, synthetic_weave};
    use crate::raycast::throughput::{camera_rays, scatter_rays, swatch_extent};

    /// Embree's round linear curves and our capsules give the same hits at the same distances on
    /// a periodic swatch, for camera rays whose hit or exit lies inside the swatch (a difference
    /// would make the throughput comparison one of different answers). Rays that start inside a
    /// fiber differ by definition: ours skips the capsule a ray starts in, Embree hits its wall.
    #[test]
    fn embree_and_our_caster_agree_hit_for_hit() {
        let exemplar = synthetic_weave(&SyntheticWeave { fibers_per_yarn: 16, ..SyntheticWeave::small() });
        let side = 0.3;
        let scene = FiberScene::new(&exemplar, swatch_extent(side)).unwrap();
        let copies = copies(&scene);
        assert!(copies.offsets.len() > 4, "copies of the period cover the swatch");
        let (lo, hi) = scene.slab();
        let rays = camera_rays(&scene, side, 4000, 7);
        let (mut compared, mut hits) = (0, 0);
        let explicit = cast(&copies, Layout::Explicit, Batch::Single, &rays, Query::ClosestHit);
        let instanced = cast(&copies, Layout::Instanced, Batch::Single, &rays, Query::ClosestHit);
        for (e, i) in explicit.iter().zip(&instanced) {
            assert_eq!(e.is_some(), i.is_some(), "both layouts hit the same rays");
        }
        for (&(o, d), embree) in rays.iter().zip(explicit) {
            let ours = scene.closest_hit(o, d, f32::INFINITY, None).map(|h| h.t);
            // Only where our swatch's edge cannot matter: the hit (or the ray's exit from the
            // slab) lies well inside the rectangle.
            let t = ours.or(embree).unwrap_or_else(|| {
                let exit = if d.z > 0.0 {
                    (hi - o.z) / d.z
                } else if d.z < 0.0 {
                    (lo - o.z) / d.z
                } else {
                    10.0
                };
                exit.max(0.0)
            });
            let p = o + t * d;
            let inside = |v: f32| (0.05..side - 0.05).contains(&v);
            let start_inside = o.z > hi || (inside(o.x) && inside(o.y));
            if !(inside(p.x) && inside(p.y) && start_inside) {
                continue;
            }
            compared += 1;
            match (ours, embree) {
                (Some(a), Some(b)) => {
                    hits += 1;
                    assert!((a - b).abs() <= 2e-5 + 1e-4 * a, "ray {o} {d}: ours t = {a}, Embree {b}");
                }
                (None, None) => {}
                (a, b) => panic!("ray {o} {d}: ours {a:?}, Embree {b:?}"),
            }
        }
        assert!(compared > 1000 && hits > 500, "{compared} rays compared, {hits} hits");
        // Any-hit agrees with closest-hit on Embree's side, scatter rays included.
        let mut all = rays.clone();
        all.extend(scatter_rays(&scene, side, 2000, 8));
        let closest = cast(&copies, Layout::Instanced, Batch::Single, &all, Query::ClosestHit);
        let any = cast(&copies, Layout::Instanced, Batch::Single, &all, Query::AnyHit);
        // Packets and streams give what single rays give (a ragged last packet included).
        let odd = &all[..all.len() - 1];
        for batch in [Batch::Packets4, Batch::Stream] {
            for query in [Query::ClosestHit, Query::AnyHit] {
                let single = cast(&copies, Layout::Instanced, Batch::Single, odd, query);
                let batched = cast(&copies, Layout::Instanced, batch, odd, query);
                assert_eq!(batched.len(), single.len());
                for (a, b) in single.iter().zip(&batched) {
                    match (a, b) {
                        (Some(a), Some(b)) => {
                            assert!((a - b).abs() <= 1e-6 + 1e-5 * a, "{batch:?}: {a} vs {b}");
                        }
                        (None, None) => {}
                        _ => panic!("{batch:?} {query:?}: {a:?} vs {b:?}"),
                    }
                }
            }
        }
        for (c, a) in closest.iter().zip(&any) {
            assert_eq!(c.is_some(), a.is_some());
        }
    }
}
