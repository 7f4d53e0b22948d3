// The shell's tetrahedra as the passes that walk or shade the shell read them. Twin struct:
// renderer/src/frame.rs (TetraGpu). NO_NEIGHBOR comes from the prelude (renderer/src/shell).

// One tetrahedron: rows of its world -> (u, v, w) affine map, its four face planes in (u, v, w)
// space (n . x + d >= 0 inside; plane k is the face opposite corner k), and the tetrahedron
// across each face (NO_NEIGHBOR on the shell's surface).
struct TetraGpu {
    uvw_from_world: array<vec4<f32>, 3>,
    planes: array<vec4<f32>, 4>,
    neighbors: vec4<u32>,
}
