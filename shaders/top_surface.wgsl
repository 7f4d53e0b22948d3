// The top-surface position texture X[u, v] (paper 5.2.1): the shell's top surface rasterized in
// (u, v) space, each texel storing the world position of the point of the top surface above
// (u, v). Twin struct: renderer/src/passes/top_surface.rs (TopSurfaceUniformsGpu).
#import shared/shell.wgsl

struct TopSurfaceUniforms {
    // (u_min, v_min, u_max - u_min, v_max - v_min) of the shell, cm.
    uv_rect: vec4<f32>,
}

@group(0) @binding(0) var<storage, read> top: TopSurfaceUniforms;
@group(0) @binding(1) var<storage, read> surface_vertices: array<SurfaceVertex>;

struct TopOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
}

// Texel (i, j) of the shell-space textures covers u = u_min + (i + 0.5) du / size and
// v = v_min + (j + 0.5) dv / size: row j grows with v.
@vertex
fn vs_top(@builtin(vertex_index) index: u32) -> TopOut {
    let v = surface_vertices[index];
    let st = (v.uvw.xy - top.uv_rect.xy) / top.uv_rect.zw;
    var out: TopOut;
    out.clip = vec4<f32>(2.0 * st.x - 1.0, 1.0 - 2.0 * st.y, 0.5, 1.0);
    out.world = v.position.xyz;
    return out;
}

@fragment
fn fs_top(in: TopOut) -> @location(0) vec4<f32> {
    return vec4<f32>(in.world, 1.0);
}
