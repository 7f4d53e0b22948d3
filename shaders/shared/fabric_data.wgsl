// A baked fabric on the GPU: bind group 1 of every pass that reads bake data.
// Twin of renderer/src/fabric_data.rs (FabricHeaderGpu, ExemplarGpu, SegmentGpu, MaterialGpu
// and the buffer layouts): keep them in sync. All exemplars of a bake set share one set of
// buffers; each exemplar's slices start at the offsets in its ExemplarGpu.
//
// Layouts (row-major, x fastest):
//   voxels          [voxel_offset + (k * ny + j) * nx + i] = exemplar-local segment id or EMPTY_VOXEL
//   segments        [segment_offset + local id]
//   pca_basis       [pca_offset + p] = mean SSDF at pixel p; [pca_offset + (1 + c) * dims + p] = component c
//   pca_coefficients[global segment * pca_components + c]
//   sos_weights     [global segment * sos_count + q]
//   iirtf           f16 pairs: entry e = ((global cell * 3 + channel) * sh_count + j1) * sh_count + j0,
//                   the value a_C[j0, j1] (light coefficient j0 -> incoming-radiance coefficient j1)
//                   is unpack2x16float(iirtf[e / 2])[e % 2]
//   cs_table        [((global material * cs_theta_count + row) * sh_count + j) * 3 + channel]
//   cg_table        [point * (sh_order + 1) + l]
//   gn_table        [(((global material * 2 + lobe) * (gn_intervals + 1) + node) * 2 + {0: Gn, 1: dGn/dmu}]
//   pattern         [block_y * pattern_width + block_x] = exemplar index
//   cell_flags      [global cell] = 1 if the cell holds segments (has a transfer matrix), else 0

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
    cell: u32,
    sos_rotation: f32,
    _pad0: u32,
    _pad1: u32,
}

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
@group(1) @binding(8) var<storage, read> sos_weights: array<f32>;
@group(1) @binding(9) var<storage, read> iirtf: array<u32>;
@group(1) @binding(10) var<storage, read> cs_table: array<f32>;
@group(1) @binding(11) var<storage, read> cg_table: array<f32>;
@group(1) @binding(12) var<storage, read> gn_table: array<f32>;
@group(1) @binding(13) var<storage, read> cell_flags: array<u32>;

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

// Global id of the segment stored in the voxel containing `p` (flat-fabric cm, z in the
// exemplar's own coordinates) of exemplar `e`, or EMPTY_VOXEL.
fn voxel_segment(e: u32, p: vec3<f32>) -> u32 {
    let ex = exemplars[e];
    var q = p;
    if (ex.periodic != 0u) {
        q = vec3<f32>(wrap_f32(p.x, ex.period.x), wrap_f32(p.y, ex.period.y), p.z);
    }
    let cell = vec3<i32>(floor((q - ex.volume_origin) / ex.voxel_size));
    var c = cell;
    let dims = vec3<i32>(ex.volume_dims);
    if (ex.periodic != 0u) {
        c = vec3<i32>(wrap_i32(cell.x, dims.x), wrap_i32(cell.y, dims.y), cell.z);
    }
    if (any(c < vec3<i32>(0)) || any(c >= dims)) {
        return EMPTY_VOXEL;
    }
    let local = voxels[ex.voxel_offset + u32((c.z * dims.y + c.y) * dims.x + c.x)];
    if (local == EMPTY_VOXEL) {
        return EMPTY_VOXEL;
    }
    return ex.segment_offset + local;
}

// a_C[j0, j1] of one channel of a global cell.
fn iirtf_entry(cell: u32, channel: u32, j0: u32, j1: u32) -> f32 {
    let n = fabric.sh_count;
    let e = ((cell * 3u + channel) * n + j1) * n + j0;
    let pair = unpack2x16float(iirtf[e / 2u]);
    return select(pair.x, pair.y, (e & 1u) == 1u);
}

// Global id of the cell at lattice position i of exemplar e (CellGrid::cell_at).
fn cell_at(ex: ExemplarGpu, i: vec3<u32>) -> u32 {
    let d = ex.cell_dims;
    let block = (i.y / d.y) * ex.cell_blocks_x + i.x / d.x;
    return ex.cell_offset + block * (d.x * d.y * d.z) + (i.z * d.y + i.y % d.y) * d.x + i.x % d.x;
}

// The eight cells around point p (exemplar cm) and their trilinear weights, empty cells left
// out and the rest renormalized (CellGrid::interpolation). Where all eight are empty, the
// returned weights are all zero and the caller keeps the segment's own cell.
struct CellWeights {
    cells: array<u32, 8>,
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
        var w = t.x * t.y * t.z;
        if (cell_flags[cell] == 0u) {
            w = 0.0;
        }
        out.cells[k] = cell;
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
