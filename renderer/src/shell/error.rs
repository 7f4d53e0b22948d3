//! [`ShellError`]: everything that can go wrong between a mesh file and a shell.
//!
//! Every message starts with the mesh's source (a file path, or `builtin:NAME`), then names the
//! place (triangle, vertex, edge, line when the parser reports one) and the offending value, and
//! ends with the valid range where one exists. Triangle and vertex indices always refer to the
//! [`BaseMesh`](super::BaseMesh) as it was handed to the failing call (before any repair).

/// Why a mesh could not be loaded, validated, or turned into a shell.
#[derive(Debug, thiserror::Error)]
pub enum ShellError {
    /// The file could not be read at all (missing, permissions, a directory, ...).
    #[error("{file}: cannot read the mesh file: {message}")]
    Read { file: String, message: String },

    /// The file name does not end in a format we load.
    #[error("{file}: unsupported mesh format {extension:?}; expected one of .obj, .gltf, .glb")]
    UnsupportedFormat { file: String, extension: String },

    /// The OBJ or glTF parser rejected the file, or its buffers/accessors are inconsistent.
    #[error("{file}{}: cannot parse the mesh: {message}", at_line(*.line))]
    Parse { file: String, line: Option<usize>, message: String },

    /// A part of the mesh has no texture coordinates; the shell needs UVs to place the fabric.
    #[error("{file}: {part} has no texture coordinates (UVs); the shell needs UVs on every vertex")]
    MissingUvs { file: String, part: String },

    /// A per-vertex attribute has a different count from the positions.
    #[error("{file}: {attribute} has {count} entries but there are {expected} vertex positions")]
    AttributeCount { file: String, attribute: &'static str, count: usize, expected: usize },

    /// More vertices than the shell's `u32` indices can address (the shell doubles them).
    #[error("{file}: {count} vertices is too many; at most {max} are supported")]
    TooManyVertices { file: String, count: usize, max: usize },

    /// No usable triangles (an empty mesh, or every triangle was dropped as degenerate).
    #[error("{file}: no usable triangles: {detail}")]
    NoTriangles { file: String, detail: String },

    /// A triangle refers to a vertex that does not exist.
    #[error(
        "{file}: triangle {triangle} corner {corner} refers to vertex {index}, \
         but valid vertex indices are 0..{vertex_count}"
    )]
    IndexOutOfRange { file: String, triangle: usize, corner: usize, index: u32, vertex_count: usize },

    /// A position, UV or normal component is NaN or infinite.
    #[error("{file}: vertex {vertex} has a non-finite {attribute} {value}; every component must be finite")]
    NonFinite { file: String, attribute: &'static str, vertex: usize, value: String },

    /// The mesh is too small or too large for f32 shell geometry.
    #[error(
        "{file}: bounding-box diagonal {diagonal_cm:.4e} cm is outside the supported range \
         [{min_cm:e}, {max_cm:e}] cm"
    )]
    MeshSize { file: String, diagonal_cm: f64, min_cm: f64, max_cm: f64 },

    /// A vertex lies so far from the origin that f32 positions lose the shell's thickness.
    #[error("{file}: vertex {vertex} at {position} lies beyond the supported |coordinate| <= {max_cm:e} cm")]
    FarFromOrigin { file: String, vertex: usize, position: String, max_cm: f64 },

    /// An edge is shared by more than two triangles.
    #[error(
        "{file}: non-manifold edge between vertices {} and {} is shared by {} triangles {:?}; \
         at most 2 triangles may share an edge",
        .edge[0], .edge[1], .triangles.len(), .triangles
    )]
    NonManifoldEdge { file: String, edge: [u32; 2], triangles: Vec<usize> },

    /// Two triangles share an edge but traverse it in the same direction (one is flipped).
    #[error(
        "{file}: triangles {} and {} both run along edge {} -> {} in the same direction; \
         neighbouring triangles must have consistent (counter-clockwise) winding",
        .triangles[0], .triangles[1], .edge[0], .edge[1]
    )]
    InconsistentWinding { file: String, edge: [u32; 2], triangles: [usize; 2] },

    /// A triangle's UVs wind clockwise while its positions wind counter-clockwise.
    #[error(
        "{file}: triangle {triangle} (vertices {vertices:?}) has mirrored UVs: signed UV area \
         {signed_area:.4e} (uv units squared) must be > 0; {mirrored_count} of {triangle_count} \
         triangles are mirrored"
    )]
    MirroredUv {
        file: String,
        triangle: usize,
        vertices: [u32; 3],
        signed_area: f64,
        mirrored_count: usize,
        triangle_count: usize,
    },

    /// A vertex normal could not be made unit length (zero, or cancelling face normals).
    #[error(
        "{file}: vertex {vertex} has no usable normal (file normal {value}, and its faces' normals cancel)"
    )]
    BadNormal { file: String, vertex: usize, value: String },

    /// A glTF primitive that is not made of triangles.
    #[error(
        "{file}: mesh {mesh} primitive {primitive} has mode {mode}; only triangle primitives can be shelled"
    )]
    UnsupportedPrimitive { file: String, mesh: usize, primitive: usize, mode: String },

    /// [`BaseMesh::builtin`](super::BaseMesh::builtin) was given a name it does not know.
    #[error("unknown builtin mesh {name:?}; valid names are: {valid}")]
    UnknownBuiltin { name: String, valid: String },

    /// A builtin mesh size that is not a finite positive number of centimetres.
    #[error(
        "builtin:{name}: size {size_cm:?} cm is invalid; each side must be finite and in \
         [{min_cm:e}, {max_cm:e}] cm"
    )]
    BuiltinSize { name: String, size_cm: [f32; 2], min_cm: f32, max_cm: f32 },

    /// `cm_per_uv` is not a finite positive number, or scaling the UVs by it overflows.
    #[error("{file}: cm_per_uv = {value} is invalid; it must be finite and > 0 (and uv * cm_per_uv finite)")]
    CmPerUv { file: String, value: f32 },

    /// `w_range_cm` is not an increasing pair of finite numbers, or offsets the shell too far.
    #[error("{file}: w_range_cm = {w_range_cm:?} is invalid: {reason}")]
    WRange { file: String, w_range_cm: [f32; 2], reason: String },

    /// `thickness_cm` disagrees with `w_range_cm[1] - w_range_cm[0]`.
    #[error(
        "{file}: thickness_cm = {thickness_cm} does not match w_range_cm {w_range_cm:?} \
         (which spans {range_cm} cm); they must agree within 1e-4 relative"
    )]
    ThicknessMismatch { file: String, thickness_cm: f32, w_range_cm: [f32; 2], range_cm: f32 },

    /// The thickness is out of its supported range for this mesh.
    #[error(
        "{file}: thickness_cm = {thickness_cm} is outside the supported range [{min_cm}, {max_cm}] cm \
         for this mesh ({reason})"
    )]
    Thickness { file: String, thickness_cm: f32, min_cm: f32, max_cm: f32, reason: &'static str },

    /// A prism (the extrusion of one triangle) has a tetrahedron of non-positive volume.
    #[error(
        "{file}: triangle {triangle} (vertices {vertices:?}) gives an inverted shell prism: tetrahedron \
         {tetrahedron} has volume {world_volume:.4e} cm^3 in world space and {uvw_volume:.4e} in uvw space; \
         both must be > 0 (vertex normals point against the triangle's winding, or fold over within \
         the shell thickness)"
    )]
    InvertedPrism {
        file: String,
        triangle: usize,
        vertices: [u32; 3],
        tetrahedron: usize,
        world_volume: f64,
        uvw_volume: f64,
    },
}

fn at_line(line: Option<usize>) -> String {
    line.map_or_else(String::new, |line| format!(":{line}"))
}

impl ShellError {
    /// The mesh source (file path or `builtin:NAME`) the error is about, when it has one.
    #[must_use]
    pub fn file(&self) -> Option<&str> {
        match self {
            Self::Read { file, .. }
            | Self::UnsupportedFormat { file, .. }
            | Self::Parse { file, .. }
            | Self::MissingUvs { file, .. }
            | Self::AttributeCount { file, .. }
            | Self::TooManyVertices { file, .. }
            | Self::NoTriangles { file, .. }
            | Self::IndexOutOfRange { file, .. }
            | Self::NonFinite { file, .. }
            | Self::MeshSize { file, .. }
            | Self::FarFromOrigin { file, .. }
            | Self::NonManifoldEdge { file, .. }
            | Self::InconsistentWinding { file, .. }
            | Self::MirroredUv { file, .. }
            | Self::BadNormal { file, .. }
            | Self::UnsupportedPrimitive { file, .. }
            | Self::CmPerUv { file, .. }
            | Self::WRange { file, .. }
            | Self::ThicknessMismatch { file, .. }
            | Self::Thickness { file, .. }
            | Self::InvertedPrism { file, .. } => Some(file),
            Self::UnknownBuiltin { .. } | Self::BuiltinSize { .. } => None,
        }
    }
}
