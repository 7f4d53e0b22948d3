//! The fabric's fibers carried onto the shell, for the path tracer: what the GPU renderer draws on
//! a curved surface, as explicit fibers in world space.
//!
//! How it works:
//! - A point of the flat fabric (u, v in cm, height z) lies over the base triangle whose UVs
//!   hold (u, v) ([`UvLocator`]: a uniform grid over the UV bounds, each cell listing the
//!   triangles whose UV box meets it), at depth `w = (z − z0) / (z1 − z0)` over the slab
//!   `z_range` the shell was grown around. Of that triangle's prism's three tetrahedra, the one
//!   holding (u, v, w) maps it to the world by its affine map: the GPU's shell map exactly (it
//!   marches the same tetrahedra), not the smooth map `base + z · normal` they approximate (on
//!   the cushion the two differ by up to about a fiber radius where it curves most).
//! - The flat fibers are the tiled exemplar's over the mesh's UV bounds: every copy of every
//!   fiber whose box meets them. Patterned cloth goes block by block, each block's exemplar's
//!   copies cut to the block's rectangle, as the GPU cuts its eye rays at block edges.
//! - Each fiber's control points are mapped. Where a fiber leaves the mesh's UV domain it ends,
//!   at the crossing found by bisection along its segment; a re-entry starts a new fiber.
//! - Radii are kept: the built-in curved meshes stretch the fabric by at most about 10%, and a
//!   `thickness_scale` other than 1 moves the fibers apart in depth without thickening them.

use glam::{DMat3, DVec2, DVec3, Vec3};
use rayon::prelude::*;

use super::Shell;
use twill_precompute::bake::pattern::PatternMap;
use twill_precompute::fabric::{BlockGrid, Exemplar, Fiber, Tiling};
use twill_precompute::raycast::clip_slab;
use twill_precompute::raycast::pattern::numbered_across;

/// Most segments a mapped fabric may have (about 100 bytes each in the path tracer's scene).
pub const MAX_MAPPED_SEGMENTS: usize = 30_000_000;
/// Bisection steps for where a fiber leaves the UV domain (2^-30 of a segment).
const CROSSING_STEPS: u32 = 30;
/// Barycentric slack of a point on a triangle's edge (UV rounding between neighbours).
const EDGE_SLACK: f64 = 1e-9;

/// Why a fabric could not be carried onto a shell.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FiberMapError {
    #[error("exemplar {exemplar} does not tile periodically; only woven exemplars tile a mesh")]
    NotPeriodic { exemplar: usize },
    #[error(
        "the mesh's UVs cover {area_cm2:.1} cm² of fabric, about {segments} fiber segments; the path \
         tracer takes at most {MAX_MAPPED_SEGMENTS}: give the mesh a smaller size_cm or cm_per_uv"
    )]
    TooLarge { area_cm2: f64, segments: usize },
    #[error("the pattern map names exemplar {named}, but there are only {count}")]
    MissingExemplar { named: usize, count: usize },
    #[error("the slab z_range {0:?} is empty or not finite")]
    Slab([f32; 2]),
}

/// Finds the base triangle under a point of the flat fabric.
pub struct UvLocator<'a> {
    shell: &'a Shell,
    /// Per tetrahedron, its corners in uvw and in the world (f64).
    tetrahedra: Vec<[(DVec3, DVec3); 4]>,
    min: DVec2,
    cell: DVec2,
    dims: [usize; 2],
    /// Cell `c`'s triangles are `triangles[starts[c]..starts[c + 1]]`.
    starts: Vec<u32>,
    triangles: Vec<u32>,
}

impl<'a> UvLocator<'a> {
    /// A grid of about one triangle per cell over the shell's UV bounds.
    #[must_use]
    pub fn new(shell: &'a Shell) -> Self {
        let (min, max) = (shell.uv_min.as_dvec2(), shell.uv_max.as_dvec2());
        let extent = (max - min).max(DVec2::splat(1e-9));
        let side = (shell.bottom_triangles.len() as f64).sqrt().ceil().clamp(1.0, 4096.0);
        let aspect = (extent.x / extent.y).clamp(1e-3, 1e3);
        let dims = [
            (side * aspect.sqrt()).ceil().clamp(1.0, 4096.0) as usize,
            (side / aspect.sqrt()).ceil().clamp(1.0, 4096.0) as usize,
        ];
        let cell = extent / DVec2::new(dims[0] as f64, dims[1] as f64);
        let cells_of = |k: usize| {
            let uv = shell.bottom_triangles[k].map(|v| v.uvw.truncate().as_dvec2());
            let lo = uv[0].min(uv[1]).min(uv[2]);
            let hi = uv[0].max(uv[1]).max(uv[2]);
            let first = ((lo - min) / cell).floor().max(DVec2::ZERO);
            let last = ((hi - min) / cell).floor();
            let last = [(last.x as usize).min(dims[0] - 1), (last.y as usize).min(dims[1] - 1)];
            (first.x as usize..=last[0])
                .flat_map(move |x| (first.y as usize..=last[1]).map(move |y| y * dims[0] + x))
        };
        let mut counts = vec![0_u32; dims[0] * dims[1] + 1];
        for k in 0..shell.bottom_triangles.len() {
            cells_of(k).for_each(|c| counts[c + 1] += 1);
        }
        for c in 1..counts.len() {
            counts[c] += counts[c - 1];
        }
        let mut fill = counts.clone();
        let mut triangles = vec![0_u32; counts[counts.len() - 1] as usize];
        for k in 0..shell.bottom_triangles.len() {
            cells_of(k).for_each(|c| {
                triangles[fill[c] as usize] = k as u32;
                fill[c] += 1;
            });
        }
        let tetrahedra =
            shell.tetrahedra.iter().map(|t| t.map(|v| (v.uvw.as_dvec3(), v.position.as_dvec3()))).collect();
        Self { shell, tetrahedra, min, cell, dims, starts: counts, triangles }
    }

    /// The base triangle under `uv` and the barycentrics of `uv` in it, if any.
    #[must_use]
    pub fn locate(&self, uv: DVec2) -> Option<(usize, [f64; 3])> {
        let c = ((uv - self.min) / self.cell).floor();
        if !(c.x >= 0.0 && c.y >= 0.0 && (c.x as usize) < self.dims[0] && (c.y as usize) < self.dims[1]) {
            return None;
        }
        let cell = c.y as usize * self.dims[0] + c.x as usize;
        let range = self.starts[cell] as usize..self.starts[cell + 1] as usize;
        self.triangles[range].iter().find_map(|&k| {
            let t = self.shell.bottom_triangles[k as usize].map(|v| v.uvw.truncate().as_dvec2());
            let area = (t[1] - t[0]).perp_dot(t[2] - t[0]);
            if area.abs() < f64::MIN_POSITIVE {
                return None;
            }
            let b1 = (uv - t[0]).perp_dot(t[2] - t[0]) / area;
            let b2 = (t[1] - t[0]).perp_dot(uv - t[0]) / area;
            let b = [1.0 - b1 - b2, b1, b2];
            b.iter().all(|&x| x >= -EDGE_SLACK).then_some((k as usize, b))
        })
    }

    /// World position of the flat-fabric point `p` (u, v, height z in cm) over a shell grown
    /// around the slab `z_range`, if (u, v) lies on the mesh: the affine map of the tetrahedron
    /// of its prism that holds it (of the three, the one it lies deepest in).
    #[must_use]
    pub fn world_at(&self, p: DVec3, z_range: [f64; 2]) -> Option<DVec3> {
        let (k, _) = self.locate(p.truncate())?;
        let uvw = p.truncate().extend((p.z - z_range[0]) / (z_range[1] - z_range[0]));
        self.tetrahedra[3 * k..3 * k + 3]
            .iter()
            .filter_map(|t| {
                let edges = DMat3::from_cols(t[1].0 - t[0].0, t[2].0 - t[0].0, t[3].0 - t[0].0);
                let det = edges.determinant();
                if det.abs() < f64::MIN_POSITIVE {
                    return None;
                }
                let l = edges.inverse() * (uvw - t[0].0);
                let depth = l.min_element().min(1.0 - l.element_sum());
                let world =
                    t[0].1 + l.x * (t[1].1 - t[0].1) + l.y * (t[2].1 - t[0].1) + l.z * (t[3].1 - t[0].1);
                Some((depth, world))
            })
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, world)| world)
    }
}

/// The fabric (`exemplars` under `pattern`, one exemplar and a uniform map for plain cloth) on
/// `shell`, grown around the slab `z_range`, as one exemplar of explicit fibers in world space
/// (`Tiling::AsIs`). Yarns are numbered across the exemplars, exemplar 0's first (as the path
/// tracer's patterned cloth numbers them), so the scene's yarn materials apply unchanged.
///
/// # Errors
/// An exemplar that does not tile, a map naming a missing exemplar, a bad slab, or a mesh that
/// covers more fabric than [`MAX_MAPPED_SEGMENTS`].
pub fn map_fabric(
    shell: &Shell,
    z_range: [f32; 2],
    exemplars: &[Exemplar],
    pattern: &PatternMap,
) -> Result<Exemplar, FiberMapError> {
    if !(z_range[0].is_finite() && z_range[1].is_finite() && z_range[0] < z_range[1]) {
        return Err(FiberMapError::Slab(z_range));
    }
    if pattern.exemplar_count() > exemplars.len() {
        return Err(FiberMapError::MissingExemplar {
            named: pattern.exemplar_count() - 1,
            count: exemplars.len(),
        });
    }
    let mut periods = Vec::with_capacity(exemplars.len());
    for (e, exemplar) in exemplars.iter().enumerate() {
        let Tiling::Periodic { period } = exemplar.tiling else {
            return Err(FiberMapError::NotPeriodic { exemplar: e });
        };
        periods.push(period.as_dvec2());
    }
    let (uv_min, uv_max) = (shell.uv_min.as_dvec2(), shell.uv_max.as_dvec2());
    let area = (uv_max - uv_min).x * (uv_max - uv_min).y;
    let density = exemplars
        .iter()
        .zip(&periods)
        .map(|(e, p)| e.segments().len() as f64 / (p.x * p.y))
        .fold(0.0, f64::max);
    let segments = (area * density).ceil() as usize;
    if segments > MAX_MAPPED_SEGMENTS {
        return Err(FiberMapError::TooLarge { area_cm2: area, segments });
    }

    // The regions to fill: the whole UV box with exemplar 0, or every block with its exemplar,
    // cut to the block.
    let mut regions: Vec<(usize, DVec2, DVec2, bool)> = Vec::new();
    if pattern.width * pattern.height <= 1 {
        regions.push((usize::from(pattern.exemplar_at(0, 0)), uv_min, uv_max, false));
    } else {
        let blocks = &exemplars[0].blocks;
        let block = periods[0] / DVec2::new(f64::from(blocks.nx), f64::from(blocks.ny));
        let first = (uv_min / block).floor();
        let last = (uv_max / block).floor();
        for by in first.y as i64..=last.y as i64 {
            for bx in first.x as i64..=last.x as i64 {
                let lo = DVec2::new(bx as f64, by as f64) * block;
                regions.push((usize::from(pattern.exemplar_at(bx, by)), lo, lo + block, true));
            }
        }
    }
    let locator = UvLocator::new(shell);
    let z = [f64::from(z_range[0]), f64::from(z_range[1])];
    let yarn_offsets = numbered_across(exemplars, |e| e.yarns.len());
    let fibers: Vec<Fiber> = regions
        .par_iter()
        .flat_map_iter(|&(e, lo, hi, cut)| {
            let exemplar = &exemplars[e];
            let period = periods[e];
            let locator = &locator;
            let yarn_offset = yarn_offsets[e];
            exemplar.fibers.iter().flat_map(move |fiber| {
                copies_over(fiber, period, lo, hi).flat_map(move |shift| {
                    let flat: Vec<DVec3> =
                        fiber.points.iter().map(|p| p.as_dvec3() + shift.extend(0.0)).collect();
                    let pieces = if cut { cut_to_rectangle(&flat, lo, hi) } else { vec![flat] };
                    pieces.into_iter().flat_map(move |piece| map_polyline(&piece, locator, z)).map(
                        move |points| Fiber { points, radius: fiber.radius, yarn: fiber.yarn + yarn_offset },
                    )
                })
            })
        })
        .collect();
    let yarns = exemplars.iter().flat_map(|e| e.yarns.iter().copied()).collect();
    Ok(Exemplar { fibers, yarns, tiling: Tiling::AsIs, blocks: BlockGrid { nx: 1, ny: 1 } })
}

/// The shifts by whole periods that bring `fiber` (its box padded by its radius) over the
/// rectangle `lo..hi`.
fn copies_over(fiber: &Fiber, period: DVec2, lo: DVec2, hi: DVec2) -> impl Iterator<Item = DVec2> + use<> {
    let pad = DVec2::splat(f64::from(fiber.radius));
    let (min, max) = fiber.points.iter().fold((DVec2::INFINITY, DVec2::NEG_INFINITY), |(a, b), p| {
        (a.min(p.truncate().as_dvec2()), b.max(p.truncate().as_dvec2()))
    });
    let first = ((lo - max - pad) / period).ceil();
    let last = ((hi - min + pad) / period).floor();
    (first.y as i64..=last.y as i64).flat_map(move |j| {
        (first.x as i64..=last.x as i64).map(move |i| DVec2::new(i as f64, j as f64) * period)
    })
}

/// The pieces of the polyline `points` whose xy lies in the rectangle `lo..hi`.
fn cut_to_rectangle(points: &[DVec3], lo: DVec2, hi: DVec2) -> Vec<Vec<DVec3>> {
    let mut pieces = Vec::new();
    let mut piece: Vec<DVec3> = Vec::new();
    let mut finish = |piece: &mut Vec<DVec3>| {
        if piece.len() >= 2 {
            pieces.push(std::mem::take(piece));
        }
        piece.clear();
    };
    for pair in points.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        let Some((t0, t1)) = segment_in_rectangle(a.truncate(), b.truncate(), lo, hi) else {
            finish(&mut piece);
            continue;
        };
        if t0 > 0.0 {
            finish(&mut piece);
        }
        if piece.is_empty() {
            piece.push(a.lerp(b, t0));
        }
        piece.push(a.lerp(b, t1));
        if t1 < 1.0 {
            finish(&mut piece);
        }
    }
    finish(&mut piece);
    pieces
}

/// The parameter interval of the segment `a..b` inside the rectangle `lo..hi` (Liang–Barsky).
fn segment_in_rectangle(a: DVec2, b: DVec2, lo: DVec2, hi: DVec2) -> Option<(f64, f64)> {
    let mut span = (0.0, 1.0);
    for axis in 0..2 {
        clip_slab(&mut span, a[axis], b[axis] - a[axis], lo[axis], hi[axis]);
    }
    (span.0 < span.1).then_some(span)
}

/// The polyline `flat` carried onto the shell, in pieces: it ends where it leaves the mesh's UV
/// domain (at the crossing) and starts again where it comes back.
fn map_polyline(flat: &[DVec3], locator: &UvLocator<'_>, z: [f64; 2]) -> Vec<Vec<Vec3>> {
    let world = |p: DVec3| locator.world_at(p, z);
    // The last point along a -> b (a on the mesh, b not) that is still on the mesh.
    let crossing = |a: DVec3, b: DVec3| {
        let (mut inside, mut outside) = (0.0, 1.0);
        for _ in 0..CROSSING_STEPS {
            let mid = 0.5 * (inside + outside);
            if world(a.lerp(b, mid)).is_some() {
                inside = mid;
            } else {
                outside = mid;
            }
        }
        world(a.lerp(b, inside))
    };
    let mut pieces = Vec::new();
    let mut piece: Vec<Vec3> = Vec::new();
    let mut previous: Option<(DVec3, bool)> = None;
    for &p in flat {
        let here = world(p);
        match (previous, here) {
            (Some((_, true)) | None, Some(w)) => piece.push(w.as_vec3()),
            (Some((q, false)), Some(w)) => {
                piece.extend(crossing(p, q).map(DVec3::as_vec3));
                piece.push(w.as_vec3());
            }
            (Some((q, true)), None) => {
                piece.extend(crossing(q, p).map(DVec3::as_vec3));
                if piece.len() >= 2 {
                    pieces.push(std::mem::take(&mut piece));
                }
                piece.clear();
            }
            (Some((_, false)) | None, None) => {}
        }
        previous = Some((p, here.is_some()));
    }
    if piece.len() >= 2 {
        pieces.push(piece);
    }
    pieces
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shell::{BaseMesh, ShellSpec};
    use glam::Vec2;
    use twill_precompute::raycast::testing::{SyntheticWeave, synthetic_weave};
    use twill_precompute::raycast::{Extent, FiberScene};

    fn slab(exemplar: &Exemplar) -> [f32; 2] {
        let (lo, hi) = exemplar.bounds().expect("fibers");
        let r = exemplar.fibers[0].radius;
        [lo.z - r, hi.z + r]
    }

    fn shell(name: &str, size: [f32; 2], z_range: [f32; 2]) -> Shell {
        let mesh = BaseMesh::builtin(name, size).expect("built-in mesh");
        Shell::build(&mesh, &ShellSpec::new(z_range, 1.0)).expect("shell")
    }

    /// Rays down onto the fabric, slanted up to about 17 degrees, aimed at random points of the
    /// plane z = 0 within `half` of the origin, from 0.5 cm above it.
    fn rays_down(half: [f32; 2], n: usize) -> Vec<(Vec3, Vec3)> {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        (0..n)
            .map(|_| {
                let target =
                    Vec3::new(rng.random_range(-half[0]..half[0]), rng.random_range(-half[1]..half[1]), 0.0);
                let d = Vec3::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3), -1.0).normalize();
                (target - d * (0.5 / -d.z), d)
            })
            .collect()
    }

    /// On the flat swatch the shell map is the identity, so the mapped fibers are the tiled
    /// exemplar cut to the swatch: every ray hits what the periodic scene clipped to the same
    /// rectangle hits, at the same distance. (Rays stay 0.02 cm from the edges, where the cut
    /// fibers' end caps, which the periodic scene's clipped rays do not see, stick out.)
    #[test]
    fn the_flat_swatch_maps_to_the_periodic_fabric_cut_to_its_rectangle() {
        let exemplar =
            synthetic_weave(&SyntheticWeave { period: 0.05, fibers_per_yarn: 16, ..SyntheticWeave::small() });
        let z = slab(&exemplar);
        let shell = shell("swatch", [0.3, 0.2], z);
        let mapped = map_fabric(&shell, z, std::slice::from_ref(&exemplar), &PatternMap::uniform(0)).unwrap();
        let flat = FiberScene::new(
            &exemplar,
            Extent::Rectangle { min: Vec2::new(-0.15, -0.1), max: Vec2::new(0.15, 0.1) },
        )
        .unwrap();
        let on_mesh = FiberScene::new(&mapped, Extent::Unbounded).unwrap();
        let mut hits = 0;
        for (i, (o, d)) in rays_down([0.13, 0.08], 3000).into_iter().enumerate() {
            let (a, b) =
                (flat.closest_hit(o, d, f32::INFINITY, None), on_mesh.closest_hit(o, d, f32::INFINITY, None));
            match (a, b) {
                (None, None) => {}
                (Some(a), Some(b)) => {
                    assert!((a.t - b.t).abs() < 2e-5, "ray {i}: t {} against {}", a.t, b.t);
                    assert_eq!(a.yarn, b.yarn, "ray {i}");
                    hits += 1;
                }
                _ => panic!("ray {i}: flat {a:?}, mapped {b:?}"),
            }
        }
        assert!(hits > 1500, "{hits} hits");
    }

    /// On the cushion every mapped control point is where the GPU's shell map puts it: the
    /// affine map (`Shell::tetra_affine`) of the tetrahedron of its prism that holds its
    /// (u, v, w), to f32 rounding.
    #[test]
    fn on_a_curved_mesh_the_fibers_lie_where_the_gpus_tetrahedra_put_them() {
        let exemplar =
            synthetic_weave(&SyntheticWeave { period: 0.05, fibers_per_yarn: 8, ..SyntheticWeave::small() });
        let z = slab(&exemplar);
        let shell = shell("cushion", [0.4, 0.4], z);
        let locator = UvLocator::new(&shell);
        let z64 = [f64::from(z[0]), f64::from(z[1])];
        let mut worst = 0.0_f64;
        let mut tested = 0;
        for (fiber, shift) in exemplar.fibers.iter().flat_map(|f| [(f, -0.1), (f, 0.0), (f, 0.1)]) {
            for p in &fiber.points {
                let flat = p.as_dvec3() + DVec3::new(shift, 0.5 * shift, 0.0);
                let Some(world) = locator.world_at(flat, z64) else { continue };
                let (k, _) = locator.locate(flat.truncate()).unwrap();
                let w = (flat.z - z64[0]) / (z64[1] - z64[0]);
                let uvw = flat.truncate().extend(w).as_vec3();
                // The tetrahedron of prism k holding uvw, by its inverse map's barycentrics.
                let gpu = shell.tetrahedra[3 * k..3 * k + 3].iter().find_map(|t| {
                    let (_, to_world) = Shell::tetra_affine(t);
                    let corners = t.map(|v| v.uvw);
                    inside_tetrahedron(uvw, corners).then(|| to_world.transform_point3(uvw))
                });
                let gpu = gpu.expect("some tetrahedron of the prism holds the point");
                worst = worst.max((gpu.as_dvec3() - world).length());
                tested += 1;
            }
        }
        assert!(tested > 1000, "{tested} points");
        eprintln!("largest distance from the tetrahedra's map: {worst:.2e} cm");
        assert!(worst < 1e-3 * f64::from(exemplar.fibers[0].radius), "{worst}");
    }

    /// A mesh that would need more fiber segments than the path tracer takes is refused before
    /// any is made, with the area and the count.
    #[test]
    fn a_mesh_too_large_for_the_path_tracer_is_refused_up_front() {
        let exemplar = synthetic_weave(&SyntheticWeave::small());
        let z = slab(&exemplar);
        let shell = shell("swatch", [60.0, 60.0], z);
        let err =
            map_fabric(&shell, z, std::slice::from_ref(&exemplar), &PatternMap::uniform(0)).unwrap_err();
        assert!(
            matches!(err, FiberMapError::TooLarge { segments, .. } if segments > MAX_MAPPED_SEGMENTS),
            "{err}"
        );
        assert!(err.to_string().contains("3600.0 cm²"), "{err}");
        let mut loose = exemplar;
        loose.tiling = Tiling::AsIs;
        let err = map_fabric(&shell, z, &[loose], &PatternMap::uniform(0)).unwrap_err();
        assert_eq!(err, FiberMapError::NotPeriodic { exemplar: 0 });
    }

    fn inside_tetrahedron(p: Vec3, c: [Vec3; 4]) -> bool {
        let volume = |a: Vec3, b: Vec3, cc: Vec3, d: Vec3| (b - a).cross(cc - a).dot(d - a);
        let total = volume(c[0], c[1], c[2], c[3]);
        let parts = [
            volume(p, c[1], c[2], c[3]),
            volume(c[0], p, c[2], c[3]),
            volume(c[0], c[1], p, c[3]),
            volume(c[0], c[1], c[2], p),
        ];
        parts.iter().all(|&v| v / total >= -1e-5)
    }

    /// A fiber leaving the mesh ends on its edge; one crossing a block edge of patterned cloth is
    /// cut there, and the other block's exemplar takes over.
    #[test]
    fn fibers_end_at_the_mesh_edge_and_at_block_edges() {
        let flat = vec![DVec3::new(0.0, 0.0, 0.0), DVec3::new(0.3, 0.0, 0.0), DVec3::new(0.3, 0.3, 0.0)];
        let pieces = cut_to_rectangle(&flat, DVec2::new(0.1, -0.1), DVec2::new(0.5, 0.2));
        assert_eq!(pieces.len(), 1);
        let piece = &pieces[0];
        assert_eq!(piece.len(), 3);
        assert!((piece[0] - DVec3::new(0.1, 0.0, 0.0)).length() < 1e-12);
        assert!((piece[2] - DVec3::new(0.3, 0.2, 0.0)).length() < 1e-12);
        // Out and back in: two pieces.
        let zigzag = vec![DVec3::new(0.2, 0.0, 0.0), DVec3::new(0.2, 0.5, 0.0), DVec3::new(0.3, 0.0, 0.0)];
        assert_eq!(cut_to_rectangle(&zigzag, DVec2::new(0.1, -0.1), DVec2::new(0.5, 0.2)).len(), 2);

        let exemplar =
            synthetic_weave(&SyntheticWeave { period: 0.05, fibers_per_yarn: 8, ..SyntheticWeave::small() });
        let z = slab(&exemplar);
        let shell = shell("swatch", [0.2, 0.2], z);
        let locator = UvLocator::new(&shell);
        let line = [DVec3::new(0.0, 0.0, 0.0), DVec3::new(0.15, 0.02, 0.0)];
        let mapped = map_polyline(&line, &locator, [f64::from(z[0]), f64::from(z[1])]);
        assert_eq!(mapped.len(), 1);
        let end = mapped[0][1];
        assert!((end.x - 0.1).abs() < 1e-6 && (end.y - 0.02 / 1.5).abs() < 1e-6, "{end}");

        // Two exemplars in checkerboard blocks: every mapped fiber lies within one block and
        // carries that block's exemplar's yarns.
        let mut twin =
            synthetic_weave(&SyntheticWeave { period: 0.05, fibers_per_yarn: 4, ..SyntheticWeave::small() });
        let mut first = exemplar.clone();
        (first.blocks, twin.blocks) = (BlockGrid { nx: 2, ny: 2 }, BlockGrid { nx: 2, ny: 2 });
        let map = PatternMap::from_rows(&["01", "10"]).unwrap();
        let both = map_fabric(&shell, z, &[first.clone(), twin.clone()], &map).unwrap();
        let yarns = first.yarns.len() as u32;
        assert_eq!(both.yarns.len(), 2 * yarns as usize);
        let mut per = [0_usize; 2];
        for fiber in &both.fibers {
            let mid = fiber.points.iter().fold(Vec3::ZERO, |s, p| s + *p) / fiber.points.len() as f32;
            let block = (mid.truncate() / 0.025).floor();
            let e = usize::from(map.exemplar_at(block.x as i64, block.y as i64));
            assert_eq!(usize::from(fiber.yarn >= yarns), e, "a fiber of the wrong exemplar in block {block}");
            for p in &fiber.points {
                let within = p.truncate() / 0.025 - block;
                assert!(
                    within.min_element() >= -1e-4 && within.max_element() <= 1.0 + 1e-4,
                    "a fiber runs out of its block {block}: {p}"
                );
            }
            per[e] += 1;
        }
        assert!(per[0] > 100 && per[1] > 100, "{per:?}");
        assert_eq!(
            map_fabric(&shell, z, &[first], &map).unwrap_err(),
            FiberMapError::MissingExemplar { named: 1, count: 1 }
        );
    }
}
