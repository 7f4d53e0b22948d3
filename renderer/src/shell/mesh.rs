//! [`BaseMesh`] and its validation: the checks and repairs every mesh passes before it is shelled.
//!
//! [`repair`] is the one place that decides what is wrong with a mesh. It never mutates its input;
//! it returns a clean copy plus a [`RepairReport`] and, for each kept triangle, the index it had in
//! the input (so later errors, e.g. an inverted prism, can name the triangle the user knows).
//!
//! Order of checks (the first failure is returned):
//! 1. shape of the data: UVs present, attribute counts equal the position count, indices in range;
//! 2. every position and UV finite (NaN/Inf is an error, never guessed away);
//! 3. triangles degenerate in world space or in UV space are dropped, then exact duplicates
//!    (the same three vertices, either winding) are dropped; all counted in the report;
//! 4. topology: an edge shared by more than two triangles, or traversed twice in the same direction,
//!    is an error naming the edge; a triangle whose UVs wind clockwise is an error (mirrored UVs);
//! 5. normals: missing normals are computed (area-weighted); zero or non-finite file normals are
//!    replaced by the area-weighted normal; all are normalised;
//! 6. vertices no kept triangle uses are removed (and indices remapped);
//! 7. size: the bounding-box diagonal must be in [[`MIN_DIAGONAL_CM`], [`MAX_DIAGONAL_CM`]] and every
//!    coordinate within ±[`MAX_COORDINATE_CM`].

use std::collections::HashMap;
use std::collections::hash_map::Entry;
use std::fmt;

use glam::{DVec2, DVec3, Vec2, Vec3};

use super::ShellError;

/// Smallest supported bounding-box diagonal of a base mesh, in centimetres.
pub const MIN_DIAGONAL_CM: f64 = 1e-4;
/// Largest supported bounding-box diagonal of a base mesh, in centimetres (one kilometre).
pub const MAX_DIAGONAL_CM: f64 = 1e5;
/// Largest supported |coordinate| of a base-mesh vertex, in centimetres.
pub const MAX_COORDINATE_CM: f64 = 1e6;
/// A triangle is degenerate when twice its area is at most this times its longest edge squared
/// (i.e. its smallest angle is below about 1e-7 radians), in world space or in UV space.
pub const DEGENERATE_SINE: f64 = 1e-7;

/// A triangle mesh with per-vertex normals and UVs: the surface the fabric shell is grown from.
///
/// Positions are in centimetres. Triangles wind counter-clockwise seen from the side the normals
/// point to (the outside; the shell grows towards it). UVs wind counter-clockwise too (u right,
/// v up, the OBJ convention); their unit is whatever the mesh uses, turned into centimetres by
/// [`ShellSpec::cm_per_uv`](super::ShellSpec::cm_per_uv). `normals` may be empty (computed then).
#[derive(Debug, Clone, PartialEq)]
pub struct BaseMesh {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub uvs: Vec<Vec2>,
    pub triangles: Vec<[u32; 3]>,
    /// Where the mesh came from, for messages: a file path or `builtin:NAME`.
    pub source: String,
}

/// What [`BaseMesh::validate_and_repair`] changed. All triangle indices are those of the mesh
/// before the repair.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RepairReport {
    /// The mesh had no normals: every normal was computed (area-weighted face normals).
    pub normals_computed: bool,
    /// Zero-length or non-finite normals that were replaced by the area-weighted normal.
    pub normals_replaced: usize,
    /// Triangles dropped because they have (near) zero area in world space.
    pub degenerate_world_dropped: usize,
    /// Triangles dropped because they have (near) zero area in UV space (but not in world space).
    pub degenerate_uv_dropped: usize,
    /// Triangles dropped because an earlier triangle has the same three vertices.
    pub duplicates_dropped: usize,
    /// Vertices removed because no kept triangle uses them.
    pub unreferenced_vertices_removed: usize,
    /// Input indices of every dropped triangle, ascending.
    pub dropped_triangles: Vec<usize>,
}

impl RepairReport {
    /// True when nothing but normalising normals was done.
    #[must_use]
    pub fn is_clean(&self) -> bool {
        !self.normals_computed
            && self.normals_replaced == 0
            && self.dropped_triangles.is_empty()
            && self.unreferenced_vertices_removed == 0
    }
}

impl fmt::Display for RepairReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.is_clean() {
            return f.write_str("no repairs");
        }
        let mut parts = Vec::new();
        if self.normals_computed {
            parts.push("computed all normals (the mesh had none)".to_owned());
        }
        if self.normals_replaced > 0 {
            parts.push(format!("replaced {} unusable normals", self.normals_replaced));
        }
        if self.degenerate_world_dropped > 0 {
            parts.push(format!("dropped {} zero-area triangles", self.degenerate_world_dropped));
        }
        if self.degenerate_uv_dropped > 0 {
            parts.push(format!("dropped {} triangles with zero UV area", self.degenerate_uv_dropped));
        }
        if self.duplicates_dropped > 0 {
            parts.push(format!("dropped {} duplicate triangles", self.duplicates_dropped));
        }
        if self.unreferenced_vertices_removed > 0 {
            parts.push(format!("removed {} unused vertices", self.unreferenced_vertices_removed));
        }
        f.write_str(&parts.join(", "))
    }
}

/// A repaired mesh together with where its triangles came from.
pub(crate) struct Repaired {
    pub mesh: BaseMesh,
    pub report: RepairReport,
    /// For each triangle of `mesh`, its index in the input mesh.
    pub triangle_origin: Vec<usize>,
    /// For each vertex of `mesh`, its index in the input mesh.
    pub vertex_origin: Vec<usize>,
}

impl BaseMesh {
    /// Checks the mesh and applies the documented repairs in place (see the module docs of
    /// `shell::mesh` and docs/SHELL.md). On error the mesh is left unchanged.
    pub fn validate_and_repair(&mut self) -> Result<RepairReport, ShellError> {
        let repaired = repair(self)?;
        *self = repaired.mesh;
        Ok(repaired.report)
    }

    /// Axis-aligned bounds of all positions, `None` for an empty mesh.
    #[must_use]
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let first = *self.positions.first()?;
        Some(self.positions.iter().fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p))))
    }
}

/// Largest vertex count: the shell has two vertices per base vertex, indexed by `u32`.
pub(crate) const MAX_VERTICES: usize = (u32::MAX / 2) as usize;

pub(crate) fn repair(mesh: &BaseMesh) -> Result<Repaired, ShellError> {
    let file = mesh.source.clone();
    let vertex_count = mesh.positions.len();
    check_shape(mesh)?;

    for (vertex, p) in mesh.positions.iter().enumerate() {
        if !p.is_finite() {
            return Err(ShellError::NonFinite { file, attribute: "position", vertex, value: format!("{p}") });
        }
    }
    for (vertex, uv) in mesh.uvs.iter().enumerate() {
        if !uv.is_finite() {
            return Err(ShellError::NonFinite { file, attribute: "UV", vertex, value: format!("{uv}") });
        }
    }

    let mut report = RepairReport::default();
    let mut kept = Vec::with_capacity(mesh.triangles.len());
    let mut seen: HashMap<[u32; 3], usize> = HashMap::with_capacity(mesh.triangles.len());
    for (index, &tri) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = tri.map(|i| i as usize);
        let world = [a, b, c].map(|i| mesh.positions[i].as_dvec3());
        let uv = [a, b, c].map(|i| mesh.uvs[i].as_dvec2());
        if a == b || b == c || a == c || is_degenerate_3d(world) {
            report.degenerate_world_dropped += 1;
            report.dropped_triangles.push(index);
            continue;
        }
        if is_degenerate_2d(uv) {
            report.degenerate_uv_dropped += 1;
            report.dropped_triangles.push(index);
            continue;
        }
        let mut key = tri;
        key.sort_unstable();
        if let Entry::Vacant(slot) = seen.entry(key) {
            slot.insert(index);
            kept.push(index);
        } else {
            report.duplicates_dropped += 1;
            report.dropped_triangles.push(index);
        }
    }
    if kept.is_empty() {
        let detail = if mesh.triangles.is_empty() {
            "the mesh has no triangles".to_owned()
        } else {
            format!("all {} triangles are degenerate or duplicates ({report})", mesh.triangles.len())
        };
        return Err(ShellError::NoTriangles { file, detail });
    }

    check_topology(mesh, &kept)?;
    check_uv_winding(mesh, &kept)?;

    // Normals over the full vertex set (indices are still the input's).
    let area_weighted = area_weighted_normals(&mesh.positions, kept.iter().map(|&t| mesh.triangles[t]));
    let mut normals = Vec::with_capacity(vertex_count);
    if mesh.normals.is_empty() {
        report.normals_computed = true;
        normals.clone_from(&area_weighted);
    } else {
        for (file_normal, &fallback) in mesh.normals.iter().zip(&area_weighted) {
            if file_normal.is_finite() && file_normal.length_squared() > 1e-24 {
                normals.push(file_normal.normalize());
            } else {
                report.normals_replaced += 1;
                normals.push(fallback);
            }
        }
    }

    // Compact: keep only referenced vertices, in their original order.
    let mut new_index = vec![u32::MAX; vertex_count];
    for &t in &kept {
        for &i in &mesh.triangles[t] {
            new_index[i as usize] = 0;
        }
    }
    let mut vertex_origin = Vec::new();
    for (old, slot) in new_index.iter_mut().enumerate() {
        if *slot == 0 {
            *slot = vertex_origin.len() as u32;
            vertex_origin.push(old);
        }
    }
    report.unreferenced_vertices_removed = vertex_count - vertex_origin.len();

    for &old in &vertex_origin {
        let n = normals[old];
        if !(n.is_finite() && (n.length() - 1.0).abs() < 1e-3) {
            let value = mesh.normals.get(old).map_or_else(|| "(none)".to_owned(), |v| format!("{v}"));
            return Err(ShellError::BadNormal { file, vertex: old, value });
        }
    }

    let repaired = BaseMesh {
        positions: vertex_origin.iter().map(|&i| mesh.positions[i]).collect(),
        normals: vertex_origin.iter().map(|&i| normals[i]).collect(),
        uvs: vertex_origin.iter().map(|&i| mesh.uvs[i]).collect(),
        triangles: kept.iter().map(|&t| mesh.triangles[t].map(|i| new_index[i as usize])).collect(),
        source: file,
    };
    check_size(&repaired, &vertex_origin)?;
    Ok(Repaired { mesh: repaired, report, triangle_origin: kept, vertex_origin })
}

fn check_shape(mesh: &BaseMesh) -> Result<(), ShellError> {
    let file = || mesh.source.clone();
    let vertex_count = mesh.positions.len();
    if vertex_count > MAX_VERTICES {
        return Err(ShellError::TooManyVertices { file: file(), count: vertex_count, max: MAX_VERTICES });
    }
    if mesh.triangles.is_empty() || vertex_count == 0 {
        return Err(ShellError::NoTriangles { file: file(), detail: "the mesh has no triangles".to_owned() });
    }
    if mesh.uvs.is_empty() {
        return Err(ShellError::MissingUvs { file: file(), part: "the mesh".to_owned() });
    }
    if mesh.uvs.len() != vertex_count {
        return Err(ShellError::AttributeCount {
            file: file(),
            attribute: "uvs",
            count: mesh.uvs.len(),
            expected: vertex_count,
        });
    }
    if !mesh.normals.is_empty() && mesh.normals.len() != vertex_count {
        return Err(ShellError::AttributeCount {
            file: file(),
            attribute: "normals",
            count: mesh.normals.len(),
            expected: vertex_count,
        });
    }
    for (triangle, tri) in mesh.triangles.iter().enumerate() {
        for (corner, &index) in tri.iter().enumerate() {
            if index as usize >= vertex_count {
                return Err(ShellError::IndexOutOfRange {
                    file: file(),
                    triangle,
                    corner,
                    index,
                    vertex_count,
                });
            }
        }
    }
    Ok(())
}

/// Edges: at most two triangles each, and two triangles must traverse a shared edge in opposite
/// directions.
fn check_topology(mesh: &BaseMesh, kept: &[usize]) -> Result<(), ShellError> {
    // (min, max) -> triangles using it, with the direction they traverse it.
    let mut edges: HashMap<[u32; 2], Vec<(usize, bool)>> = HashMap::with_capacity(kept.len() * 2);
    for &t in kept {
        let tri = mesh.triangles[t];
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            edges.entry([a.min(b), a.max(b)]).or_default().push((t, a < b));
        }
    }
    let mut worst: Option<ShellError> = None;
    let mut worst_key = (usize::MAX, [u32::MAX; 2]);
    for (edge, users) in &edges {
        let error = if users.len() > 2 {
            let triangles: Vec<usize> = users.iter().map(|&(t, _)| t).collect();
            Some(ShellError::NonManifoldEdge { file: mesh.source.clone(), edge: *edge, triangles })
        } else if users.len() == 2 && users[0].1 == users[1].1 {
            let forward = if users[0].1 { *edge } else { [edge[1], edge[0]] };
            Some(ShellError::InconsistentWinding {
                file: mesh.source.clone(),
                edge: forward,
                triangles: [users[0].0, users[1].0],
            })
        } else {
            None
        };
        // Report the problem at the lowest triangle index, so the message is deterministic.
        let key = (users.iter().map(|&(t, _)| t).min().unwrap_or(usize::MAX), *edge);
        if error.is_some() && key < worst_key {
            worst_key = key;
            worst = error;
        }
    }
    worst.map_or(Ok(()), Err)
}

fn check_uv_winding(mesh: &BaseMesh, kept: &[usize]) -> Result<(), ShellError> {
    let signed = |t: usize| {
        let [a, b, c] = mesh.triangles[t].map(|i| mesh.uvs[i as usize].as_dvec2());
        (b - a).perp_dot(c - a) * 0.5
    };
    let mirrored: Vec<usize> = kept.iter().copied().filter(|&t| signed(t) < 0.0).collect();
    if let Some(&triangle) = mirrored.first() {
        return Err(ShellError::MirroredUv {
            file: mesh.source.clone(),
            triangle,
            vertices: mesh.triangles[triangle],
            signed_area: signed(triangle),
            mirrored_count: mirrored.len(),
            triangle_count: kept.len(),
        });
    }
    Ok(())
}

fn check_size(mesh: &BaseMesh, vertex_origin: &[usize]) -> Result<(), ShellError> {
    for (i, p) in mesh.positions.iter().enumerate() {
        if f64::from(p.abs().max_element()) > MAX_COORDINATE_CM {
            return Err(ShellError::FarFromOrigin {
                file: mesh.source.clone(),
                vertex: vertex_origin[i],
                position: format!("{p}"),
                max_cm: MAX_COORDINATE_CM,
            });
        }
    }
    let diagonal_cm = diagonal_cm(mesh);
    if !(MIN_DIAGONAL_CM..=MAX_DIAGONAL_CM).contains(&diagonal_cm) {
        return Err(ShellError::MeshSize {
            file: mesh.source.clone(),
            diagonal_cm,
            min_cm: MIN_DIAGONAL_CM,
            max_cm: MAX_DIAGONAL_CM,
        });
    }
    Ok(())
}

/// Bounding-box diagonal in centimetres (0 for an empty mesh).
pub(crate) fn diagonal_cm(mesh: &BaseMesh) -> f64 {
    mesh.bounds().map_or(0.0, |(lo, hi)| (hi.as_dvec3() - lo.as_dvec3()).length())
}

fn is_degenerate_3d([a, b, c]: [DVec3; 3]) -> bool {
    let longest = (b - a).length_squared().max((c - b).length_squared()).max((a - c).length_squared());
    let twice_area = (b - a).cross(c - a).length();
    longest == 0.0 || twice_area <= DEGENERATE_SINE * longest
}

fn is_degenerate_2d([a, b, c]: [DVec2; 3]) -> bool {
    let longest = (b - a).length_squared().max((c - b).length_squared()).max((a - c).length_squared());
    let twice_area = (b - a).perp_dot(c - a).abs();
    longest == 0.0 || twice_area <= DEGENERATE_SINE * longest
}

/// Area-weighted vertex normals (the sum of the cross products of the incident triangles,
/// normalised). Vertices no triangle touches, or whose face normals cancel, get `Vec3::ZERO`.
/// Every index must be in range.
pub(crate) fn area_weighted_normals(
    positions: &[Vec3],
    triangles: impl Iterator<Item = [u32; 3]>,
) -> Vec<Vec3> {
    let mut sums = vec![DVec3::ZERO; positions.len()];
    for tri in triangles {
        let [a, b, c] = tri.map(|i| positions[i as usize].as_dvec3());
        let cross = (b - a).cross(c - a);
        for i in tri {
            sums[i as usize] += cross;
        }
    }
    sums.iter().map(|s| s.try_normalize().map_or(Vec3::ZERO, DVec3::as_vec3)).collect()
}
