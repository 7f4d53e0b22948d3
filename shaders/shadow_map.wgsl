// Shadow maps (paper 5.3.2): the shell's top and bottom surfaces rasterized, depth only, into
// layer `instance_index` of the shadow-map array, from each shadowing light (orthographic).
// Twin struct: renderer/src/passes/shadow_map.rs (ShadowUniformsGpu).
#import shared/shell.wgsl

struct ShadowUniforms {
    // One orthographic clip-from-world matrix per shadow-map layer.
    light_clip_from_world: array<mat4x4<f32>, MAX_SHADOWED_LIGHTS>,
}

@group(0) @binding(0) var<storage, read> shadow: ShadowUniforms;
@group(0) @binding(1) var<storage, read> surface_vertices: array<SurfaceVertex>;

@vertex
fn vs_shadow(@builtin(vertex_index) index: u32, @builtin(instance_index) layer: u32) -> @builtin(position) vec4<f32> {
    return shadow.light_clip_from_world[layer] * vec4<f32>(surface_vertices[index].position.xyz, 1.0);
}
