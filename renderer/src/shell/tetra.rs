//! Splitting a prism into three tetrahedra so that neighbouring prisms agree.
//!
//! Shell vertex `i` is base vertex `i` at w = 0 ("bottom") and shell vertex `i + n` is base vertex
//! `i` at w = 1 ("top"), where `n` is the base vertex count. A prism over the triangle (a, b, c)
//! has three quad side faces, one per base edge. Each quad must be cut by the *same* diagonal in
//! the two prisms that share it, or the tetrahedra would overlap on one side and leave a gap on
//! the other. The rule used here depends only on the edge's two vertex indices:
//!
//! > the side quad of edge {i, j} with i < j is cut along bottom(j)–top(i).
//!
//! It follows from sorting the triangle's vertices by index, v0 < v1 < v2, and taking
//! (v0, v1, v2, v0'), (v1, v2, v0', v1'), (v2, v0', v1', v2') (primes are top vertices), the
//! standard split of Dompierre et al. (1999). Those three are positively oriented when
//! (v0, v1, v2) is an even permutation of the counter-clockwise triangle; for an odd permutation
//! two vertices of each tetrahedron are swapped.

/// The three tetrahedra of the prism over the counter-clockwise triangle `tri`, as shell vertex
/// indices (bottom `i`, top `i + vertex_count`), each positively oriented for a well-formed prism.
pub(crate) fn split_prism(tri: [u32; 3], vertex_count: u32) -> [[u32; 4]; 3] {
    let mut sorted = tri;
    sorted.sort_unstable();
    let even = sorted == tri || sorted == [tri[1], tri[2], tri[0]] || sorted == [tri[2], tri[0], tri[1]];
    let [v0, v1, v2] = sorted;
    let top = |v: u32| v + vertex_count;
    let mut tets = [[v0, v1, v2, top(v0)], [v1, v2, top(v0), top(v1)], [v2, top(v0), top(v1), top(v2)]];
    if !even {
        for tet in &mut tets {
            tet.swap(2, 3);
        }
    }
    tets
}

/// The two outward triangles of the side quad over the boundary edge a → b (a → b in the
/// counter-clockwise order of its triangle), cut by the same diagonal as [`split_prism`].
pub(crate) fn split_side_quad(a: u32, b: u32, vertex_count: u32) -> [[u32; 3]; 2] {
    let top = |v: u32| v + vertex_count;
    if a < b {
        // Diagonal bottom(b)-top(a).
        [[a, b, top(a)], [b, top(b), top(a)]]
    } else {
        // Diagonal bottom(a)-top(b).
        [[a, b, top(b)], [a, top(b), top(a)]]
    }
}

/// Six times the signed volume of the tetrahedron (a, b, c, d): positive when d lies on the side
/// of (a, b, c) that a counter-clockwise (a, b, c) faces.
pub(crate) fn det6(a: glam::DVec3, b: glam::DVec3, c: glam::DVec3, d: glam::DVec3) -> f64 {
    (b - a).cross(c - a).dot(d - a)
}
