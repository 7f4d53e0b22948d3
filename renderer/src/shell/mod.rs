//! The shell map (Khungurn et al. 2017, §2 and §5.1; Porumbescu et al. 2005): a thin volume grown
//! from a base mesh, in which the flat fabric exemplar is tiled.
//!
//! How it works:
//! - A [`BaseMesh`] (positions in cm, per-vertex normals, UVs, counter-clockwise triangles) comes
//!   from an OBJ/glTF file ([`BaseMesh::load`]) or a procedural surface ([`BaseMesh::builtin`]).
//!   [`BaseMesh::validate_and_repair`] checks it and applies the documented repairs; it is also run
//!   on a copy inside [`Shell::build`], so an unrepaired mesh can be passed directly.
//! - Every base vertex `p` with unit normal `n` gives two shell vertices: `p + n·w_range_cm[0]`
//!   (w = 0, the bottom of the fabric) and `p + n·w_range_cm[1]` (w = 1, the top). Their shell
//!   coordinates are `(u, v, w) = (uv·cm_per_uv, w)`: (u, v) are flat-fabric coordinates in
//!   centimetres, so they index the tiled exemplar blocks directly.
//! - Each base triangle becomes a prism, split into three tetrahedra by a rule that depends only on
//!   vertex indices ([`tetra`]), so neighbouring prisms cut their shared quad face the same way.
//!   Inside a tetrahedron the map world ↔ uvw is affine ([`Shell::tetra_affine`]); over the whole
//!   shell it is continuous and piecewise affine.
//! - The flat swatch maps identically: builtin `swatch` lies in the plane z = 0 with normal +z and
//!   UVs equal to (x, y) in cm, so with `cm_per_uv = 1` a shell point at world (x, y, z) has
//!   (u, v) = (x, y) and z = lerp(w_range_cm[0], w_range_cm[1], w).
//!
//! Conventions are collected in docs/SHELL.md.

mod builtin;
mod error;
pub mod fibers;
mod load;
mod mesh;
#[cfg(test)]
mod tests;
mod tetra;

use std::collections::HashSet;

use glam::{DMat3, DMat4, DVec3, Mat4, Vec2, Vec3};

pub use builtin::{MAX_BUILTIN_SIDE_CM, MIN_BUILTIN_SIDE_CM};
pub use error::ShellError;
pub use mesh::{
    BaseMesh, DEGENERATE_SINE, MAX_COORDINATE_CM, MAX_DIAGONAL_CM, MIN_DIAGONAL_CM, RepairReport,
};

/// [`Shell::tetra_neighbors`] of a face on the shell's surface.
pub const NO_NEIGHBOR: u32 = u32::MAX;
/// Thinnest supported shell, in centimetres (absolute floor; see [`MIN_THICKNESS_RELATIVE`]).
pub const MIN_THICKNESS_CM: f32 = 1e-6;
/// The shell must be at least this times the mesh's largest |coordinate| thick, so that f32
/// positions keep the top and bottom apart (about 170 f32 steps).
pub const MIN_THICKNESS_RELATIVE: f32 = 1e-5;
/// The shell may be at most this times the mesh's bounding-box diagonal thick; the same bound
/// applies to each |w_range_cm| end (how far the shell is offset from the base surface).
pub const MAX_THICKNESS_FRACTION: f32 = 0.5;
/// Relative tolerance for `thickness_cm == w_range_cm[1] - w_range_cm[0]`.
pub const THICKNESS_MATCH_TOLERANCE: f32 = 1e-4;
/// Relative tolerance of [`Shell::is_flat`] (normal difference, and distance from the plane
/// relative to the bounding-box diagonal).
pub const FLAT_TOLERANCE: f64 = 1e-5;

/// One shell vertex: where it is in the world (cm) and where that is in the flat fabric.
///
/// `uvw.x`, `uvw.y` are flat-fabric coordinates in cm; `uvw.z` is the depth w ∈ [0, 1]
/// (0 = bottom of the fabric, 1 = top).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShellVertex {
    pub position: Vec3,
    pub uvw: Vec3,
}

/// How to grow a shell from a base mesh.
///
/// `w_range_cm` is the fabric exemplar's depth range: w = 0 sits at `base + n·w_range_cm[0]`, and
/// w = 1 at `base + n·w_range_cm[1]`. `thickness_cm` is redundant with it and must equal
/// `w_range_cm[1] - w_range_cm[0]` (within [`THICKNESS_MATCH_TOLERANCE`] relative); it is kept
/// so that callers state the thickness they expect. [`ShellSpec::new`] fills it in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShellSpec {
    pub thickness_cm: f32,
    /// Centimetres of fabric per UV unit (1 for the builtin meshes, whose UVs are already in cm).
    pub cm_per_uv: f32,
    pub w_range_cm: [f32; 2],
}

impl ShellSpec {
    /// A spec whose thickness is the span of `w_range_cm`.
    #[must_use]
    pub fn new(w_range_cm: [f32; 2], cm_per_uv: f32) -> Self {
        Self { thickness_cm: w_range_cm[1] - w_range_cm[0], cm_per_uv, w_range_cm }
    }

    /// A shell of the given thickness grown outward from the base surface (w_range = [0, t]).
    #[must_use]
    pub fn outward(thickness_cm: f32, cm_per_uv: f32) -> Self {
        Self { thickness_cm, cm_per_uv, w_range_cm: [0.0, thickness_cm] }
    }

    /// Checks the spec against a (repaired) base mesh.
    fn check(&self, mesh: &BaseMesh) -> Result<(), ShellError> {
        let file = || mesh.source.clone();
        if !(self.cm_per_uv.is_finite() && self.cm_per_uv > 0.0) {
            return Err(ShellError::CmPerUv { file: file(), value: self.cm_per_uv });
        }
        let [w0, w1] = self.w_range_cm;
        let w_range_error =
            |reason: String| ShellError::WRange { file: file(), w_range_cm: self.w_range_cm, reason };
        if !(w0.is_finite() && w1.is_finite()) {
            return Err(w_range_error("both ends must be finite".to_owned()));
        }
        if w1 <= w0 {
            return Err(w_range_error("w_range_cm[1] must be greater than w_range_cm[0]".to_owned()));
        }
        let range_cm = w1 - w0;
        let thickness_cm = self.thickness_cm;
        if !thickness_cm.is_finite()
            || (thickness_cm - range_cm).abs() > THICKNESS_MATCH_TOLERANCE * range_cm.max(thickness_cm.abs())
        {
            return Err(ShellError::ThicknessMismatch {
                file: file(),
                thickness_cm,
                w_range_cm: self.w_range_cm,
                range_cm,
            });
        }
        let diagonal_cm = mesh::diagonal_cm(mesh) as f32;
        let max_cm = MAX_THICKNESS_FRACTION * diagonal_cm;
        let largest_coordinate = mesh.positions.iter().map(|p| p.abs().max_element()).fold(0.0, f32::max);
        let relative_min = MIN_THICKNESS_RELATIVE * largest_coordinate;
        let min_cm = MIN_THICKNESS_CM.max(relative_min);
        if range_cm > max_cm {
            return Err(ShellError::Thickness {
                file: file(),
                thickness_cm: range_cm,
                min_cm,
                max_cm,
                reason: "at most 0.5 x the mesh's bounding-box diagonal",
            });
        }
        if range_cm < min_cm {
            let reason = if relative_min > MIN_THICKNESS_CM {
                "at least 1e-5 x the largest |coordinate|, or f32 positions cannot resolve it"
            } else {
                "at least 1e-6 cm"
            };
            return Err(ShellError::Thickness {
                file: file(),
                thickness_cm: range_cm,
                min_cm,
                max_cm,
                reason,
            });
        }
        if w0.abs().max(w1.abs()) > max_cm {
            return Err(w_range_error(format!(
                "the shell may be offset from the base surface by at most {max_cm:e} cm \
                 (0.5 x the mesh's bounding-box diagonal)"
            )));
        }
        Ok(())
    }
}

/// The shell: tetrahedra carrying world positions and flat-fabric coordinates, plus its surfaces.
///
/// Tetrahedra `3k..3k + 3` are the prism over base triangle `source_triangles[k]`. Every
/// tetrahedron `[a, b, c, d]` is positively oriented in world space *and* in uvw space:
/// `((b - a) × (c - a)) · (d - a) > 0`. All surface triangles are counter-clockwise seen from
/// outside the shell: the top (w = 1) from the +normal side, the bottom (w = 0) from the −normal
/// side, the sides (over the base mesh's boundary edges) from outside the border.
#[derive(Debug, Clone)]
pub struct Shell {
    pub tetrahedra: Vec<[ShellVertex; 4]>,
    pub top_triangles: Vec<[ShellVertex; 3]>,
    pub bottom_triangles: Vec<[ShellVertex; 3]>,
    pub side_triangles: Vec<[ShellVertex; 3]>,
    /// World bounds of the whole shell (cm).
    pub bounds_min: Vec3,
    pub bounds_max: Vec3,
    /// Bounds of (u, v) in cm.
    pub uv_min: Vec2,
    pub uv_max: Vec2,
    /// Every base normal is the same direction and every base point lies in one plane (within
    /// [`FLAT_TOLERANCE`] relative): the renderer can skip shadow passes.
    pub is_flat: bool,
    /// That common normal, when `is_flat`.
    pub flat_normal: Option<Vec3>,
    /// Indexed form: shell vertex `i` is base vertex `i` (of the repaired mesh) at w = 0, vertex
    /// `i + n` the same at w = 1.
    pub vertices: Vec<ShellVertex>,
    /// `tetrahedra` as indices into `vertices`.
    pub tetra_indices: Vec<[u32; 4]>,
    /// For prism `k` (tetrahedra `3k..3k + 3`), the index of its triangle in the input mesh.
    pub source_triangles: Vec<usize>,
    /// What validation repaired in the input mesh.
    pub repairs: RepairReport,
}

impl Shell {
    /// Validates (and repairs a copy of) `mesh`, checks `spec` against it, and builds the shell.
    pub fn build(mesh: &BaseMesh, spec: &ShellSpec) -> Result<Shell, ShellError> {
        let mesh::Repaired { mesh: base, report, triangle_origin, vertex_origin } = mesh::repair(mesh)?;
        spec.check(&base)?;
        let file = || base.source.clone();
        let vertex_count = base.positions.len();
        let n = vertex_count as u32; // repair() bounds the count by MAX_VERTICES.
        let cm_per_uv = f64::from(spec.cm_per_uv);

        let mut vertices = Vec::with_capacity(2 * vertex_count);
        for (w, offset_cm) in [(0.0, spec.w_range_cm[0]), (1.0, spec.w_range_cm[1])] {
            for ((p, normal), uv) in base.positions.iter().zip(&base.normals).zip(&base.uvs) {
                let position = (p.as_dvec3() + normal.as_dvec3() * f64::from(offset_cm)).as_vec3();
                let uv_cm = (uv.as_dvec2() * cm_per_uv).as_vec2();
                if !uv_cm.is_finite() {
                    return Err(ShellError::CmPerUv { file: file(), value: spec.cm_per_uv });
                }
                vertices.push(ShellVertex { position, uvw: uv_cm.extend(w) });
            }
        }

        let mut tetra_indices = Vec::with_capacity(3 * base.triangles.len());
        for (k, &tri) in base.triangles.iter().enumerate() {
            for (t, tet) in tetra::split_prism(tri, n).into_iter().enumerate() {
                let [a, b, c, d] = tet.map(|i| vertices[i as usize]);
                let world_volume =
                    tetra::det6(a.position.into(), b.position.into(), c.position.into(), d.position.into())
                        / 6.0;
                let uvw_volume = tetra::det6(a.uvw.into(), b.uvw.into(), c.uvw.into(), d.uvw.into()) / 6.0;
                if !(world_volume > 0.0 && uvw_volume > 0.0) {
                    return Err(ShellError::InvertedPrism {
                        file: file(),
                        triangle: triangle_origin[k],
                        vertices: tri.map(|i| vertex_origin[i as usize] as u32),
                        tetrahedron: t,
                        world_volume,
                        uvw_volume,
                    });
                }
                tetra_indices.push(tet);
            }
        }

        let directed: HashSet<[u32; 2]> =
            base.triangles.iter().flat_map(|t| [[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]]).collect();
        let mut side_indices = Vec::new();
        for tri in &base.triangles {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                if !directed.contains(&[b, a]) {
                    side_indices.extend(tetra::split_side_quad(a, b, n));
                }
            }
        }

        let lookup3 = |t: [u32; 3]| t.map(|i| vertices[i as usize]);
        let top_triangles = base.triangles.iter().map(|t| lookup3(t.map(|i| i + n))).collect();
        let bottom_triangles = base.triangles.iter().map(|&[a, b, c]| lookup3([a, c, b])).collect();
        let side_triangles = side_indices.into_iter().map(lookup3).collect();
        let tetrahedra = tetra_indices.iter().map(|t| t.map(|i| vertices[i as usize])).collect();

        let first = vertices[0];
        let (mut bounds_min, mut bounds_max) = (first.position, first.position);
        let (mut uv_min, mut uv_max) = (first.uvw.truncate(), first.uvw.truncate());
        for v in &vertices {
            bounds_min = bounds_min.min(v.position);
            bounds_max = bounds_max.max(v.position);
            uv_min = uv_min.min(v.uvw.truncate());
            uv_max = uv_max.max(v.uvw.truncate());
        }

        let flat_normal = flat_normal(&base);
        Ok(Shell {
            tetrahedra,
            top_triangles,
            bottom_triangles,
            side_triangles,
            bounds_min,
            bounds_max,
            uv_min,
            uv_max,
            is_flat: flat_normal.is_some(),
            flat_normal,
            vertices,
            tetra_indices,
            source_triangles: triangle_origin,
            repairs: report,
        })
    }

    /// The affine maps of one tetrahedron: `(world → uvw, uvw → world)`, as homogeneous matrices
    /// (last row 0, 0, 0, 1). Computed in f64 from the four vertex pairs. For a degenerate
    /// tetrahedron (zero volume in either space) the matrices contain non-finite values; every
    /// tetrahedron of a built [`Shell`] has positive volume in both.
    #[must_use]
    pub fn tetra_affine(t: &[ShellVertex; 4]) -> (Mat4, Mat4) {
        let world = t.map(|v| v.position.as_dvec3());
        let uvw = t.map(|v| v.uvw.as_dvec3());
        let edges = |p: [DVec3; 4]| DMat3::from_cols(p[1] - p[0], p[2] - p[0], p[3] - p[0]);
        let affine = |from: [DVec3; 4], to: [DVec3; 4]| {
            let linear = edges(to) * edges(from).inverse();
            let translation = to[0] - linear * from[0];
            DMat4::from_cols(
                linear.x_axis.extend(0.0),
                linear.y_axis.extend(0.0),
                linear.z_axis.extend(0.0),
                translation.extend(1.0),
            )
            .as_mat4()
        };
        (affine(world, uvw), affine(uvw, world))
    }

    /// For each tetrahedron, the tetrahedron across each of its faces: entry `k` is the one
    /// sharing the face opposite corner `k` (the corners other than `k`), or [`NO_NEIGHBOR`]
    /// where that face is on the shell's surface. Eye rays walk from tetrahedron to tetrahedron
    /// through these (shaders/gbuffer.wgsl).
    #[must_use]
    pub fn tetra_neighbors(&self) -> Vec<[u32; 4]> {
        let face_key = |tet: &[u32; 4], k: usize| {
            let mut key = [0_u32; 3];
            let mut n = 0;
            for (corner, &v) in tet.iter().enumerate() {
                if corner != k {
                    key[n] = v;
                    n += 1;
                }
            }
            key.sort_unstable();
            key
        };
        let mut first_use: std::collections::HashMap<[u32; 3], (u32, usize)> =
            std::collections::HashMap::with_capacity(2 * self.tetra_indices.len());
        let mut neighbors = vec![[NO_NEIGHBOR; 4]; self.tetra_indices.len()];
        for (t, tet) in self.tetra_indices.iter().enumerate() {
            for k in 0..4 {
                match first_use.entry(face_key(tet, k)) {
                    std::collections::hash_map::Entry::Occupied(other) => {
                        let (u, j) = *other.get();
                        neighbors[t][k] = u;
                        neighbors[u as usize][j] = t as u32;
                    }
                    std::collections::hash_map::Entry::Vacant(slot) => {
                        slot.insert((t as u32, k));
                    }
                }
            }
        }
        neighbors
    }

    /// Total world volume of the shell (cm³), the sum of its tetrahedra.
    #[must_use]
    pub fn volume_cm3(&self) -> f64 {
        self.tetrahedra
            .iter()
            .map(|t| {
                let [a, b, c, d] = t.map(|v| v.position.as_dvec3());
                tetra::det6(a, b, c, d) / 6.0
            })
            .sum()
    }
}

/// The common normal when every normal agrees and every point lies in one plane.
fn flat_normal(mesh: &BaseMesh) -> Option<Vec3> {
    let normal = mesh.normals.first()?.as_dvec3();
    let origin = mesh.positions.first()?.as_dvec3();
    let tolerance = FLAT_TOLERANCE * mesh::diagonal_cm(mesh);
    let same_normal = mesh.normals.iter().all(|n| (n.as_dvec3() - normal).length() <= FLAT_TOLERANCE);
    let in_plane = mesh.positions.iter().all(|p| (p.as_dvec3() - origin).dot(normal).abs() <= tolerance);
    (same_normal && in_plane).then_some(normal.as_vec3())
}
