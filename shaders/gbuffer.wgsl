// Eye rays (paper 5.1): the front faces of every shell tetrahedron are rasterized; each
// fragment carries the eye ray into the tetrahedron's flat-fabric space (an affine map) and
// samples the voxel volume at `volume_samples` evenly spaced points between where the ray
// enters and leaves the tetrahedron, keeping the first non-empty voxel. The fragment writes
// the hit's world position and ids to the G-buffer and its true depth, so the depth test keeps
// the nearest hit over all tetrahedra. Needs shared/fabric_data.wgsl before it.
// Twin structs: renderer/src/frame.rs (FrameUniformsGpu, TetraGpu).

struct FrameUniforms {
    clip_from_world: mat4x4<f32>,
    // xyz: eye position (perspective) or the viewing direction (orthographic); w: 1 or 0.
    eye: vec4<f32>,
    // Sub-pixel jitter in clip units (xy), the sample's offset along the ray in [0, 1) (z).
    jitter: vec4<f32>,
    // Bottom of the fabric slab (x) and its thickness (y) in cm; volume samples (z, as f32).
    fabric_z: vec4<f32>,
    // x: for an orthographic camera, the film plane's offset along the viewing direction
    // (dot(eye, view)): eye rays start there, as the path tracer's do. Unused for perspective.
    film: vec4<f32>,
}

// One tetrahedron: rows of its world -> (u, v, w) affine map, and its four face planes in
// (u, v, w) space (n . x + d >= 0 inside).
struct TetraGpu {
    uvw_from_world: array<vec4<f32>, 3>,
    planes: array<vec4<f32>, 4>,
}

@group(0) @binding(0) var<uniform> frame: FrameUniforms;
@group(0) @binding(1) var<storage, read> tetra_corners: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> tetras: array<TetraGpu>;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) @interpolate(flat) tetra: u32,
}

// Outward faces of a positively oriented tetrahedron, counter-clockwise seen from outside.
const FACE_CORNERS: array<u32, 12> = array<u32, 12>(1u, 2u, 3u, 0u, 3u, 2u, 0u, 1u, 3u, 0u, 2u, 1u);

@vertex
fn vs_main(@builtin(vertex_index) index: u32) -> VertexOut {
    let tetra = index / 12u;
    let corner = FACE_CORNERS[index % 12u];
    let world = tetra_corners[tetra * 4u + corner].xyz;
    var out: VertexOut;
    out.clip = frame.clip_from_world * vec4<f32>(world, 1.0);
    out.clip = vec4<f32>(out.clip.xy + frame.jitter.xy * out.clip.w, out.clip.zw);
    out.world = world;
    out.tetra = tetra;
    return out;
}

struct GBufferOut {
    @builtin(frag_depth) depth: f32,
    // Hit position in world space; w = 1.
    @location(0) position: vec4<f32>,
    // Global segment id, tetrahedron id, exemplar id, 1.
    @location(1) ids: vec4<u32>,
}

fn to_uvw(t: TetraGpu, p: vec4<f32>) -> vec3<f32> {
    return vec3<f32>(dot(t.uvw_from_world[0], p), dot(t.uvw_from_world[1], p), dot(t.uvw_from_world[2], p));
}

@fragment
fn fs_main(in: VertexOut) -> GBufferOut {
    let tetra = tetras[in.tetra];
    var dir = frame.eye.xyz;
    if (frame.eye.w > 0.5) {
        dir = normalize(in.world - frame.eye.xyz);
    }
    // An orthographic eye ray starts on the film plane: the part of a tetrahedron behind it is
    // not seen (the near plane lies behind the film so that a tetrahedron the film cuts is still
    // rasterized).
    var entry = in.world;
    if (frame.eye.w < 0.5) {
        entry += max(frame.film.x - dot(in.world, dir), 0.0) * dir;
    }
    let start = to_uvw(tetra, vec4<f32>(entry, 1.0));
    let step_dir = to_uvw(tetra, vec4<f32>(dir, 0.0));
    // Where the ray leaves the tetrahedron: the nearest plane it moves out of.
    var t_exit = 3.0e38;
    for (var k = 0u; k < 4u; k++) {
        let plane = tetra.planes[k];
        let rate = dot(plane.xyz, step_dir);
        if (rate < 0.0) {
            t_exit = min(t_exit, -(dot(plane.xyz, start) + plane.w) / rate);
        }
    }
    if (!(t_exit < 3.0e38) || t_exit <= 0.0) {
        discard;
    }
    let samples = u32(frame.fabric_z.z);
    for (var s = 0u; s < samples; s++) {
        let t = (f32(s) + frame.jitter.z) / f32(samples) * t_exit;
        let q = start + t * step_dir;
        let fabric_point = vec3<f32>(q.xy, frame.fabric_z.x + clamp(q.z, 0.0, 1.0) * frame.fabric_z.y);
        let e = exemplar_at(q.xy);
        let segment = voxel_segment(e, fabric_point);
        if (segment != EMPTY_VOXEL) {
            let hit = entry + t * dir;
            let clip = frame.clip_from_world * vec4<f32>(hit, 1.0);
            var out: GBufferOut;
            out.depth = clamp(clip.z / clip.w, 0.0, 1.0);
            out.position = vec4<f32>(hit, 1.0);
            out.ids = vec4<u32>(segment, in.tetra, e, 1u);
            return out;
        }
    }
    discard;
}
