// Eye rays (paper 5.1), walked through the shell: only the faces on the shell's surface are
// rasterized (front faces: where an eye ray enters the shell). Each fragment follows its ray
// from tetrahedron to tetrahedron across shared faces (TetraGpu.neighbors) until it hits or
// leaves the shell. Inside a tetrahedron the world -> (u, v, w) map is affine, so the ray is a
// straight line in flat-fabric space, where it steps voxel by voxel (a 3D DDA,
// shared/fabric_data.wgsl first_fiber_hit) and at each occupied voxel intersects the capsules
// of it and its face neighbours: the first fiber the ray enters, at its true surface, whatever
// the view angle or the size of the tetrahedra, found by one fragment per shell layer instead
// of one per tetrahedron crossed.
// The fragment writes the hit's world position and ids to the G-buffer and its true depth, so
// the depth test keeps the nearest hit where the ray enters the shell more than once (folded
// cloth).
// Twin struct: renderer/src/passes/gbuffer.rs (FrameUniformsGpu).
#import shared/fabric_data.wgsl
#import shared/shell.wgsl

struct FrameUniforms {
    clip_from_world: mat4x4<f32>,
    // xyz: eye position (perspective) or the viewing direction (orthographic); w: 1 or 0.
    eye: vec4<f32>,
    // Sub-pixel jitter in clip units (xy); zw unused.
    jitter: vec4<f32>,
    // Bottom of the fabric slab (x) and its thickness (y) in cm; zw unused.
    fabric_z: vec4<f32>,
    // x: for an orthographic camera, the film plane's offset along the viewing direction
    // (dot(eye, view)): eye rays start there, as the path tracer's do. Unused for perspective.
    film: vec4<f32>,
}

// Most tetrahedra one eye ray walks through (a guard against a cycle on a malformed shell).
const MAX_RAY_TETRAS: u32 = 4096u;
// Tetrahedra in a row an eye ray may cross without moving on (through an edge or a corner).
const MAX_RAY_STALLS: u32 = 8u;

@group(0) @binding(0) var<storage, read> frame: FrameUniforms;
@group(0) @binding(1) var<storage, read> tetra_corners: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> tetras: array<TetraGpu>;
// The shell's surface faces: tetrahedron * 4 + the corner the face is opposite to.
@group(0) @binding(3) var<storage, read> surface_faces: array<u32>;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) @interpolate(flat) tetra: u32,
    // The face (opposite corner k) the ray enters the tetrahedron through.
    @location(2) @interpolate(flat) face: u32,
}

// Face k of a positively oriented tetrahedron (the corners other than k), counter-clockwise
// seen from outside.
const FACE_CORNERS: array<u32, 12> = array<u32, 12>(1u, 2u, 3u, 0u, 3u, 2u, 0u, 1u, 3u, 0u, 2u, 1u);

@vertex
fn vs_main(@builtin(vertex_index) index: u32) -> VertexOut {
    let face = surface_faces[index / 3u];
    let tetra = face >> 2u;
    let corner = FACE_CORNERS[(face & 3u) * 3u + index % 3u];
    let world = tetra_corners[tetra * 4u + corner].xyz;
    var out: VertexOut;
    out.clip = frame.clip_from_world * vec4<f32>(world, 1.0);
    out.clip = vec4<f32>(out.clip.xy + frame.jitter.xy * out.clip.w, out.clip.zw);
    out.world = world;
    out.tetra = tetra;
    out.face = face & 3u;
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
    // The ray is entry + t dir, t >= 0, entry where it enters the shell.
    let entry = in.world;
    var dir = frame.eye.xyz;
    if (frame.eye.w > 0.5) {
        dir = normalize(in.world - frame.eye.xyz);
    }
    // An orthographic eye ray starts on the film plane: what lies behind it is not seen (the
    // near plane lies behind the film so that a shell the film cuts is still rasterized).
    var t_film = 0.0;
    if (frame.eye.w < 0.5) {
        t_film = max(frame.film.x - dot(entry, dir), 0.0);
    }
    var tetra_id = in.tetra;
    var previous = NO_NEIGHBOR;
    var t = 0.0;
    var budget = 0u;
    var stalls = 0u;
    var best: VoxelHit;
    best.t = NO_HIT;
    best.segment = EMPTY_VOXEL;
    for (var walked = 0u; walked < MAX_RAY_TETRAS; walked++) {
        let tetra = tetras[tetra_id];
        // The face the ray came in through: the one shared with the previous tetrahedron.
        var entry_face = in.face;
        if (previous != NO_NEIGHBOR) {
            let across = tetra.neighbors;
            entry_face = select(select(select(3u, 2u, across.z == previous), 1u, across.y == previous), 0u, across.x == previous);
        }
        let start = to_uvw(tetra, vec4<f32>(entry, 1.0));
        let step_dir = to_uvw(tetra, vec4<f32>(dir, 0.0));
        // Where the ray leaves the tetrahedron: the nearest plane it moves out of, other than
        // the face it came in through (rounding can make a ray that runs nearly along that face
        // seem to move out of it, and walk back and forth).
        var t_exit = NO_HIT;
        var exit_face = 4u;
        for (var k = 0u; k < 4u; k++) {
            let plane = tetra.planes[k];
            let rate = dot(plane.xyz, step_dir);
            if (rate < 0.0 && k != entry_face) {
                let t_plane = -(dot(plane.xyz, start) + plane.w) / rate;
                if (t_plane < t_exit) {
                    t_exit = t_plane;
                    exit_face = k;
                }
            }
        }
        if (exit_face == 4u) {
            break;
        }
        // A ray through an edge or a corner can pass through tetrahedra without moving on; a
        // few in a row is a ray stuck where f32 cannot tell the faces apart: it is let go.
        if (t_exit <= t) {
            stalls += 1u;
            if (stalls > MAX_RAY_STALLS) {
                break;
            }
        } else {
            stalls = 0u;
        }
        t_exit = max(t_exit, t);
        let t_from = max(t, t_film);
        if (t_from < t_exit) {
            // The ray in flat-fabric space (u, v, z in cm; w in [0, 1] spans the fabric slab).
            let fabric_start = vec3<f32>(start.xy, frame.fabric_z.x + start.z * frame.fabric_z.y);
            let fabric_dir = vec3<f32>(step_dir.xy, step_dir.z * frame.fabric_z.y);
            first_fiber_hit(fabric_start, fabric_dir, t_film, t_from, t_exit, &budget, &best);
            // A fiber entered within this tetrahedron's piece of the ray is the first; one
            // entered further on waits for the pieces before it.
            if (best.segment != EMPTY_VOXEL && best.t <= t_exit) {
                let hit = entry + best.t * dir;
                let clip = frame.clip_from_world * vec4<f32>(hit, 1.0);
                var out: GBufferOut;
                out.depth = clamp(clip.z / clip.w, 0.0, 1.0);
                out.position = vec4<f32>(hit, 1.0);
                out.ids = vec4<u32>(best.segment, tetra_id, best.exemplar, 1u);
                return out;
            }
        }
        let next = tetra.neighbors[exit_face];
        if (next == NO_NEIGHBOR || budget >= MAX_RAY_VOXELS) {
            break;
        }
        previous = tetra_id;
        tetra_id = next;
        t = t_exit;
    }
    // Every way out of the walk leads here, not to a discard inside it: llvmpipe keeps a
    // discarded invocation stepping through the loop with the others (measured: 16x slower).
    discard;
}
