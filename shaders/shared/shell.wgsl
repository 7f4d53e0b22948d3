// The shell on the GPU as the passes read it: its tetrahedra (the passes that walk or shade the
// shell) and its surface vertices (the passes that rasterize its surfaces). Twin structs:
// renderer/src/passes/shell_gpu.rs (TetraGpu, SurfaceVertexGpu). NO_NEIGHBOR comes from the
// prelude (renderer/src/shell).

// One tetrahedron: rows of its world -> (u, v, w) affine map, its four face planes in (u, v, w)
// space (n . x + d >= 0 inside; plane k is the face opposite corner k), and the tetrahedron
// across each face (NO_NEIGHBOR on the shell's surface).
struct TetraGpu {
    uvw_from_world: array<vec4<f32>, 3>,
    planes: array<vec4<f32>, 4>,
    neighbors: vec4<u32>,
}

// A vertex of the shell's top or bottom surface: world position (w = 1) and flat-fabric
// (u, v, w) (w of the vector unused).
struct SurfaceVertex {
    position: vec4<f32>,
    uvw: vec4<f32>,
}
