// A baked fabric on the GPU: bind group 1 of every pass that reads bake data.
// Twin of renderer/src/fabric_data.rs (FabricHeaderGpu, ExemplarGpu, SegmentGpu, MaterialGpu
// and the buffer layouts): keep them in sync. All exemplars of a bake set share one set of
// buffers; each exemplar's slices start at the offsets in its ExemplarGpu.
//
// Layouts (row-major, x fastest):
//   voxels          [voxel_offset + (k * ny + j) * nx + i] = exemplar-local segment id or EMPTY_VOXEL
//   segments        [segment_offset + local id]
//   pca_basis       [pca_offset + p] = mean SSDF at pixel p; [pca_offset + (1 + c) * dims + p] = component c
//   pca_coefficients[image * pca_components + c]
//   sum_of_sg       [image * sos_count + q] = (bitcast<u32>(weight), axis: two snorm16s of its
//                   octahedral map, unpack_unit_vector)
//                   image = global segment * visibility_points + point (visibility_image)
//   visibility_bits [image * visibility_words + p / 32] bit p % 32 = pixel p of the binary
//                   visibility image (row-major, rows theta), when visibility_words > 0
//   iirtf           f16 pairs, one matrix per slot (a cell that holds segments; empty cells have
//                   none): entry e = ((slot * 3 + channel) * sh_count + j1) * sh_count + j0,
//                   the value a_C[j0, j1] (light coefficient j0 -> incoming-radiance coefficient j1)
//                   is unpack2x16float(iirtf[e / 2])[e % 2]
//   cs_table        [((global material * cs_theta_count + row) * sh_count + j) * 3 + channel]
//   cg_table        [point * (cg_order + 1) + l], at the table's own order (cg_order >= sh_order;
//                   LOBE_SH_ORDER when the bake has fiber lobes); then the upper-hemisphere
//                   fits of orders 0..=cg_order (shading.wgsl upper_fit_offset)
//   gn_table        [(((global material * 2 + lobe) * (gn_intervals + 1) + node) * 2 + {0: Gn, 1: dGn/dmu}]
//   pattern         [block_y * pattern_width + block_x] = exemplar index
//   cell_slots      [global cell] = 1 + its slot if the cell holds segments (has a transfer matrix),
//                   else 0; slots number the cells that hold segments in global cell order
//   lobes           first the lobe table: per lattice slot a u32 (the f32's bits, four per
//                   vec4, lobe_table_vec4s vec4s), 1 + the slot's lobe slot or 0 for a cell that
//                   keeps no lobes; then per lobe slot LOBE_PACKED_VEC4S vec4s
//                   (CellTransfer::pack_lobes, the layout's owner): from its base b (lobe_base),
//                   [b + j] = forward strength j (rgb, w = 0) and [b + LOBE_SH_COUNT + j] =
//                   reflected strength j, j < LOBE_SH_COUNT; then, as floats from vec4
//                   2 * LOBE_SH_COUNT on, the forward shape's LOBE_SHAPE_LEN sums (a
//                   LOBE_CHANNEL_SHAPE_LEN shape per colour channel) and the reflected shape's,
//                   back to back, zero-padded; zeros for a cell whose lobes a recolouring
//                   folded into its matrix (FabricArrays::lobes). A bake without fiber lobes binds one
//                   zeroed vec4, read only when ENABLE_FIBER_LOBES is set (shade.wgsl), which
//                   the plan sets only while some cell holds lobes.

const EMPTY_VOXEL: u32 = 0xffffffffu;
const MATERIAL_FIBER: u32 = 0u;
const MATERIAL_LAMBERT: u32 = 1u;

struct FabricHeader {
    exemplar_count: u32,
    sh_order: u32,
    sh_count: u32,
    svf_resolution: u32,
    pca_components: u32,
    sos_count: u32,
    sos_sharpness: f32,
    cs_theta_count: u32,
    cg_points: u32,
    gn_intervals: u32,
    pattern_width: u32,
    pattern_height: u32,
    block_size: vec2<f32>,
    z_range: vec2<f32>,
    // SH order of the C_G table (cg_table's rows hold cg_order + 1 values).
    cg_order: u32,
    // Visibility images per segment (VisibilityData::points): pca_coefficients and sum_of_sg
    // hold image segment * visibility_points + point.
    visibility_points: u32,
    // u32 words per binary visibility image in visibility_bits; 0 when the bake kept none
    // (local visibility is then the PCA SSDF's sign).
    visibility_words: u32,
    // vec4s of the lobe table at the start of `lobes`; 0 without lobes.
    lobe_table_vec4s: u32,
}

struct ExemplarGpu {
    volume_origin: vec3<f32>,
    voxel_offset: u32,
    voxel_size: vec3<f32>,
    periodic: u32,
    volume_dims: vec3<u32>,
    segment_offset: u32,
    period: vec2<f32>,
    pca_offset: u32,
    segment_count: u32,
    // The IIRTF cell lattice (precompute/src/bake/cells.rs CellGrid).
    cell_origin: vec3<f32>,
    cell_offset: u32,
    cell_size: vec3<f32>,
    cell_blocks_x: u32,
    cell_dims: vec3<u32>,
    // The lattice repeats across the fabric when `periodic` is set.
    cell_blocks_y: u32,
}

struct SegmentGpu {
    direction: vec3<f32>,
    material: u32,
    // Midpoint (exemplar coordinates, cm) and half length, to find a point's visibility image.
    midpoint: vec3<f32>,
    half_length: f32,
    cell: u32,
    // The sum of SGs' Fibonacci axes' rotation, shared by the segment's visibility points.
    sos_rotation: f32,
    // Fiber radius (cm): the capsule eye rays test.
    radius: f32,
    // Global id of the segment's own cell (CellGrid::segment_cell), NO_SEGMENT_CELL if none.
    segment_cell: u32,
}

const NO_SEGMENT_CELL: u32 = 0xffffffffu;

struct MaterialGpu {
    c_r: vec3<f32>,
    model: u32,
    c_tt: vec3<f32>,
    beta_r: f32,
    albedo: vec3<f32>,
    beta_tt: f32,
    gamma_tt: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(1) @binding(0) var<uniform> fabric: FabricHeader;
@group(1) @binding(1) var<storage, read> exemplars: array<ExemplarGpu>;
@group(1) @binding(2) var<storage, read> pattern: array<u32>;
@group(1) @binding(3) var<storage, read> voxels: array<u32>;
@group(1) @binding(4) var<storage, read> segments: array<SegmentGpu>;
@group(1) @binding(5) var<storage, read> materials: array<MaterialGpu>;
@group(1) @binding(6) var<storage, read> pca_basis: array<f32>;
@group(1) @binding(7) var<storage, read> pca_coefficients: array<f32>;
@group(1) @binding(8) var<storage, read> sum_of_sg: array<vec2<u32>>;
@group(1) @binding(9) var<storage, read> iirtf: array<u32>;
@group(1) @binding(10) var<storage, read> cs_table: array<f32>;
@group(1) @binding(11) var<storage, read> cg_table: array<f32>;
@group(1) @binding(12) var<storage, read> gn_table: array<f32>;
@group(1) @binding(13) var<storage, read> cell_slots: array<u32>;
@group(1) @binding(14) var<storage, read> lobes: array<vec4<f32>>;
@group(1) @binding(15) var<storage, read> visibility_bits: array<u32>;

// Euclidean remainder (WGSL's % keeps the sign of the dividend).
fn wrap_f32(x: f32, period: f32) -> f32 {
    return x - period * floor(x / period);
}

fn wrap_i32(x: i32, n: i32) -> i32 {
    return ((x % n) + n) % n;
}

// The exemplar a point of the flat fabric (u, v in cm) belongs to, by the pattern map.
fn exemplar_at(uv: vec2<f32>) -> u32 {
    let block = vec2<i32>(floor(uv / fabric.block_size));
    let bx = wrap_i32(block.x, i32(fabric.pattern_width));
    let by = wrap_i32(block.y, i32(fabric.pattern_height));
    return pattern[u32(by) * fabric.pattern_width + u32(bx)];
}

// Most voxels one eye ray visits (a guard: an 89-degree ray across the whole default fabric
// without meeting a fiber would visit about 2,700).
const MAX_RAY_VOXELS: u32 = 8192u;
// VOXEL_START_NUDGE (the prelude, from precompute's): the voxel a ray starts in is that of a
// point this fraction of the smallest voxel side past its start.
const NO_HIT: f32 = 3.0e38;

// The nearest fiber an eye ray has been found to enter so far (t = NO_HIT and segment =
// EMPTY_VOXEL while none).
struct VoxelHit {
    t: f32,
    segment: u32,
    exemplar: u32,
}

// Where the ray p0 + t d enters the capsule of (global) segment k moved by `shift`, t in units
// of d; NO_HIT if it misses. Twin of precompute's volume::ray_capsule_entry: from the ray's
// closest approach to the midpoint, so f32 works with offsets of the capsule's own size.
fn capsule_entry(k: u32, shift: vec3<f32>, p0: vec3<f32>, d: vec3<f32>) -> f32 {
    let s = segments[k];
    let len = length(d);
    if (!(len > 0.0)) {
        return NO_HIT;
    }
    let dn = d / len;
    let mid = s.midpoint + shift;
    let t_closest = dot(mid - p0, dn);
    let p = p0 + t_closest * dn - mid;
    // Past the capsule's bounding sphere: a miss (most neighbours' capsules end here).
    let reach = s.half_length + s.radius;
    if (dot(p, p) > reach * reach) {
        return NO_HIT;
    }
    let u = normalize(s.direction);
    let r2 = s.radius * s.radius;
    // The infinite cylinder; its entry counts where it lies on the body.
    let pu = dot(p, u);
    let du = dot(dn, u);
    let p_perp = p - pu * u;
    let d_perp = dn - du * u;
    let qa = dot(d_perp, d_perp);
    let qb = dot(p_perp, d_perp);
    let qc = dot(p_perp, p_perp) - r2;
    if (qa > 1e-12) {
        let disc = qb * qb - qa * qc;
        if (disc < 0.0) {
            return NO_HIT;
        }
        let sc = (-qb - sqrt(disc)) / qa;
        if (abs(pu + sc * du) <= s.half_length) {
            return (t_closest + sc) / len;
        }
    }
    // Otherwise through a cap (or along the axis): the nearer sphere.
    var entry = NO_HIT;
    for (var end = 0u; end < 2u; end++) {
        let q = p - select(-s.half_length, s.half_length, end == 1u) * u;
        let b = dot(q, dn);
        let disc = b * b - (dot(q, q) - r2);
        if (disc >= 0.0) {
            entry = min(entry, -b - sqrt(disc));
        }
    }
    if (entry == NO_HIT) {
        return NO_HIT;
    }
    return (t_closest + entry) / len;
}

// Tests the capsules of voxel c (wrapped; `cell` unwrapped) of exemplar e and of its six face
// neighbours, in the order itself, -x, +x, -y, +y, -z, +z (VoxelVolume::face_neighbourhood),
// each the copy nearest the voxel on a periodic volume, and keeps in `best` the nearest entry
// at t >= t_min. Twin of the loop body of VoxelVolume::first_fiber_hit. `recent` holds the
// last eight segments tested along this ray: one met again gives the same entry (its copy
// nearest the voxel is the same while the voxels lie within a capsule of it) and is skipped,
// which spares most tests, since neighbouring voxels share their fibers.
fn test_voxel_fibers(e: u32, c: vec3<i32>, cell: vec3<i32>, p0: vec3<f32>, d: vec3<f32>, t_min: f32, recent: ptr<function, array<vec4<u32>, 2>>, best: ptr<function, VoxelHit>) {
    let ex = exemplars[e];
    let dims = vec3<i32>(ex.volume_dims);
    let periodic = ex.periodic != 0u;
    let plane = u32(dims.x * dims.y);
    let centre = ex.volume_origin + (vec3<f32>(cell) + vec3<f32>(0.5)) * ex.voxel_size;
    for (var q = 0u; q < 7u; q++) {
        // Step q: 0 none, then -x, +x, -y, +y, -z, +z.
        let axis = (q + 1u) / 2u - 1u;
        let sign = select(1, -1, (q & 1u) == 1u);
        let step = select(vec3<i32>(0), vec3<i32>(sign) * vec3<i32>(vec3<u32>(0u, 1u, 2u) == vec3<u32>(axis)), q > 0u);
        var n = c + step;
        if (periodic) {
            n = vec3<i32>(select(select(n.xy, vec2<i32>(0), n.xy >= dims.xy), dims.xy - vec2<i32>(1), n.xy < vec2<i32>(0)), n.z);
        }
        if (any(n < vec3<i32>(0)) || any(n >= dims)) {
            continue;
        }
        let local = voxels[ex.voxel_offset + u32(n.z) * plane + u32(n.y * dims.x + n.x)];
        if (local == EMPTY_VOXEL) {
            continue;
        }
        let k = ex.segment_offset + local;
        if (any((*recent)[0] == vec4<u32>(k)) || any((*recent)[1] == vec4<u32>(k))) {
            continue;
        }
        (*recent)[1] = vec4<u32>((*recent)[0].w, (*recent)[1].xyz);
        (*recent)[0] = vec4<u32>(k, (*recent)[0].xyz);
        var shift = vec3<f32>(0.0);
        if (periodic) {
            let mid = segments[k].midpoint;
            shift = vec3<f32>(ex.period * round((centre.xy - mid.xy) / ex.period), 0.0);
        }
        let t = capsule_entry(k, shift, p0, d);
        if (t >= t_min && t < (*best).t) {
            (*best).t = t;
            (*best).segment = k;
            (*best).exemplar = e;
        }
    }
}

// Where the ray p0 + t d (flat-fabric cm) leaves the pattern block it is in at t.
fn block_exit(p0: vec3<f32>, d: vec3<f32>, t: f32) -> f32 {
    if (fabric.pattern_width * fabric.pattern_height <= 1u) {
        return NO_HIT;
    }
    let p = p0.xy + t * d.xy;
    let block = floor(p / fabric.block_size);
    var t_exit = NO_HIT;
    for (var axis = 0u; axis < 2u; axis++) {
        if (d[axis] != 0.0) {
            let face = (block[axis] + select(0.0, 1.0, d[axis] > 0.0)) * fabric.block_size[axis];
            t_exit = min(t_exit, (face - p0[axis]) / d[axis]);
        }
    }
    return max(t_exit, t);
}

// Walks the voxels of exemplar e's volume that the ray p0 + t d crosses for t in
// [t_from, t_to], in order (a 3D DDA, Amanatides & Woo), and at every occupied one tests the
// capsules of it and its face neighbours (test_voxel_fibers), keeping the nearest entry at
// t >= t_min in `best`; it stops at the first occupied voxel that starts past `best`. Twin of
// precompute's VoxelVolume::first_fiber_hit. `budget` counts the voxels visited.
// Written with whole-vector selects rather than indexing a vector by a variable axis, which
// llvmpipe runs several times slower.
fn march_exemplar(e: u32, p0: vec3<f32>, d: vec3<f32>, t_min: f32, t_from: f32, t_to: f32, budget: ptr<function, u32>, best: ptr<function, VoxelHit>) {
    let ex = exemplars[e];
    let lo = ex.volume_origin;
    let size = ex.voxel_size;
    let dims = vec3<i32>(ex.volume_dims);
    let hi = lo + size * vec3<f32>(ex.volume_dims);
    let periodic = ex.periodic != 0u;
    // Axes that are clipped to the grid: z always, x and y when they do not wrap.
    let clipped = vec3<bool>(!periodic, !periodic, true);
    let moving = d != vec3<f32>(0.0);
    // A clipped axis the ray runs level along must start inside the grid.
    if (any(clipped & !moving & ((p0 < lo) | (p0 >= hi)))) {
        return;
    }
    let safe_d = select(vec3<f32>(1.0), d, moving);
    let ta = (lo - p0) / safe_d;
    let tb = (hi - p0) / safe_d;
    let use_axis = clipped & moving;
    let t_enter = select(vec3<f32>(-NO_HIT), min(ta, tb), use_axis);
    let t_leave = select(vec3<f32>(NO_HIT), max(ta, tb), use_axis);
    let t0 = max(t_from, max(t_enter.x, max(t_enter.y, t_enter.z)));
    let t1 = min(t_to, min(t_leave.x, min(t_leave.y, t_leave.z)));
    if (!(t0 < t1)) {
        return;
    }
    let nudge = VOXEL_START_NUDGE * min(size.x, min(size.y, size.z)) / length(d);
    let start = p0 + (t0 + min(nudge, 0.5 * (t1 - t0))) * d;
    var cell = vec3<i32>(floor((start - lo) / size));
    cell = select(cell, clamp(cell, vec3<i32>(0), dims - vec3<i32>(1)), clipped);
    let positive = d > vec3<f32>(0.0);
    let step = select(select(vec3<i32>(0), vec3<i32>(-1), moving), vec3<i32>(1), positive);
    let face = vec3<f32>(cell + select(vec3<i32>(0), vec3<i32>(1), positive));
    var t_next = select(vec3<f32>(NO_HIT), (lo + face * size - p0) / safe_d, moving);
    let t_delta = select(vec3<f32>(NO_HIT), size / abs(safe_d), moving);
    let plane = u32(dims.x * dims.y);
    // The voxel in the stored grid: `cell` wrapped into it once here, then stepped with it and
    // wrapped by one comparison per step (an integer modulo per axis and step costs more than
    // the rest of the step on a CPU rasterizer).
    var c = cell;
    if (periodic) {
        c = vec3<i32>(wrap_i32(cell.x, dims.x), wrap_i32(cell.y, dims.y), cell.z);
    }
    var recent = array<vec4<u32>, 2>(vec4<u32>(EMPTY_VOXEL), vec4<u32>(EMPTY_VOXEL));
    var t = t0;
    loop {
        if (*budget >= MAX_RAY_VOXELS) {
            return;
        }
        *budget += 1u;
        let local = voxels[ex.voxel_offset + u32(c.z) * plane + u32(c.y * dims.x + c.x)];
        if (local != EMPTY_VOXEL) {
            // A fiber entered before this voxel starts is the nearest there is.
            if ((*best).t <= t) {
                return;
            }
            test_voxel_fibers(e, c, cell, p0, d, t_min, &recent, best);
        }
        // Step along the axis whose next face is nearest.
        let is_x = t_next.x <= t_next.y && t_next.x <= t_next.z;
        let is_y = !is_x && t_next.y <= t_next.z;
        let axis = vec3<bool>(is_x, is_y, !is_x && !is_y);
        t = min(t_next.x, min(t_next.y, t_next.z));
        if (t >= t1) {
            return;
        }
        let moved = select(vec3<i32>(0), step, axis);
        cell += moved;
        if (any(clipped & ((cell < vec3<i32>(0)) | (cell >= dims)))) {
            return;
        }
        c += moved;
        if (periodic) {
            c = select(c, vec3<i32>(0), c >= dims);
            c = select(c, dims - vec3<i32>(1), c < vec3<i32>(0));
        }
        t_next += select(vec3<f32>(0.0), t_delta, axis);
    }
}

// The first fiber along p0 + t d (flat-fabric cm) entered at t >= t_min, among those of the
// voxels crossed for t in [t_start, t_end], over the pattern's exemplars: the ray is cut where
// it crosses from one pattern block to the next, and each piece is marched through its own
// exemplar's volume. `best` carries the nearest entry found so far (also from earlier calls
// for the same ray: an entry may lie past the piece whose voxels found it); `budget` counts
// the voxels visited (over every call for one eye ray); past MAX_RAY_VOXELS the ray gives up.
fn first_fiber_hit(p0: vec3<f32>, d: vec3<f32>, t_min: f32, t_start: f32, t_end: f32, budget: ptr<function, u32>, best: ptr<function, VoxelHit>) {
    var t = t_start;
    for (var piece = 0u; piece < MAX_RAY_VOXELS; piece++) {
        if (!(t < t_end) || *budget >= MAX_RAY_VOXELS || (*best).t <= t) {
            break;
        }
        let t_piece = min(block_exit(p0, d, t), t_end);
        let nudge = VOXEL_START_NUDGE * min(fabric.block_size.x, fabric.block_size.y) / length(d);
        let e = exemplar_at((p0 + (t + min(nudge, 0.5 * (t_piece - t))) * d).xy);
        march_exemplar(e, p0, d, t_min, t, t_piece, budget, best);
        t = t_piece;
    }
}

// a_C[j0, j1] of one channel of the cell in `slot`.
fn iirtf_entry(slot: u32, channel: u32, j0: u32, j1: u32) -> f32 {
    let n = fabric.sh_count;
    let e = ((slot * 3u + channel) * n + j1) * n + j0;
    let pair = unpack2x16float(iirtf[e / 2u]);
    return select(pair.x, pair.y, (e & 1u) == 1u);
}

// Global id of the cell at lattice position i of exemplar e (CellGrid::cell_at).
fn cell_at(ex: ExemplarGpu, i: vec3<u32>) -> u32 {
    let d = ex.cell_dims;
    let block = (i.y / d.y) * ex.cell_blocks_x + i.x / d.x;
    return ex.cell_offset + block * (d.x * d.y * d.z) + (i.z * d.y + i.y % d.y) * d.x + i.x % d.x;
}

// The eight cells around point p (exemplar cm), as their slots, and their trilinear weights,
// empty cells left out (weight 0, slot unused) and the rest renormalized
// (CellGrid::interpolation). Where all eight are empty, the returned weights are all zero and
// the caller keeps the segment's own cell.
struct CellWeights {
    slots: array<u32, 8>,
    weights: array<f32, 8>,
}

// Cells of exemplar `ex`'s whole lattice along x, y, z (CellGrid::lattice_dims).
fn cell_lattice(ex: ExemplarGpu) -> vec3<u32> {
    return ex.cell_dims * vec3<u32>(ex.cell_blocks_x, ex.cell_blocks_y, 1u);
}

fn cell_interpolation(e: u32, p: vec3<f32>) -> CellWeights {
    let ex = exemplars[e];
    let n = vec3<i32>(cell_lattice(ex));
    let c = (p - ex.cell_origin) / ex.cell_size - vec3<f32>(0.5);
    let base = floor(c);
    let f = c - base;
    let b = vec3<i32>(base);
    var out: CellWeights;
    var total = 0.0;
    for (var k = 0u; k < 8u; k++) {
        let o = vec3<i32>(i32(k & 1u), i32((k >> 1u) & 1u), i32((k >> 2u) & 1u));
        var i = b + o;
        if (ex.periodic != 0u) {
            i = vec3<i32>(wrap_i32(i.x, n.x), wrap_i32(i.y, n.y), clamp(i.z, 0, n.z - 1));
        } else {
            i = clamp(i, vec3<i32>(0), n - 1);
        }
        let cell = cell_at(ex, vec3<u32>(i));
        let t = select(vec3<f32>(1.0) - f, f, o == vec3<i32>(1));
        let slot = cell_slots[cell];
        var w = t.x * t.y * t.z;
        if (slot == 0u) {
            w = 0.0;
        }
        out.slots[k] = max(slot, 1u) - 1u;
        out.weights[k] = w;
        total += w;
    }
    if (total > 0.0) {
        for (var k = 0u; k < 8u; k++) {
            out.weights[k] = out.weights[k] / total;
        }
    }
    return out;
}
