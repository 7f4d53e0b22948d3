// Passes over the shell's surfaces (paper 5.2.1, 5.3.2):
// - shadow maps: the shell's top and bottom surfaces rasterized, depth only, into layer
//   `instance_index` of the shadow-map array, from each shadowing light (orthographic);
// - the top-surface position texture X[u, v]: the top surface rasterized in (u, v) space,
//   each texel storing the world position of the point of the top surface above (u, v).
// Twin structs: renderer/src/frame.rs (SurfaceVertexGpu, SurfaceUniformsGpu).

struct SurfaceVertex {
    position: vec4<f32>,
    uvw: vec4<f32>,
}

struct SurfaceUniforms {
    // One orthographic clip-from-world matrix per shadow-map layer (at most 8 lights).
    light_clip_from_world: array<mat4x4<f32>, MAX_SHADOWED_LIGHTS>,
    // (u_min, v_min, u_max - u_min, v_max - v_min) of the shell, cm.
    uv_rect: vec4<f32>,
}

@group(0) @binding(0) var<uniform> surface: SurfaceUniforms;
@group(0) @binding(1) var<storage, read> surface_vertices: array<SurfaceVertex>;

@vertex
fn vs_shadow(@builtin(vertex_index) index: u32, @builtin(instance_index) layer: u32) -> @builtin(position) vec4<f32> {
    return surface.light_clip_from_world[layer] * vec4<f32>(surface_vertices[index].position.xyz, 1.0);
}

struct TopOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
}

// Texel (i, j) of the shell-space textures covers u = u_min + (i + 0.5) du / size and
// v = v_min + (j + 0.5) dv / size: row j grows with v.
@vertex
fn vs_top(@builtin(vertex_index) index: u32) -> TopOut {
    let v = surface_vertices[index];
    let st = (v.uvw.xy - surface.uv_rect.xy) / surface.uv_rect.zw;
    var out: TopOut;
    out.clip = vec4<f32>(2.0 * st.x - 1.0, 1.0 - 2.0 * st.y, 0.5, 1.0);
    out.world = v.position.xyz;
    return out;
}

@fragment
fn fs_top(in: TopOut) -> @location(0) vec4<f32> {
    return vec4<f32>(in.world, 1.0);
}
