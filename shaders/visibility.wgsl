// Global visibility in shell space (paper 5.2.1, 5.2.2, 5.3.2): for every texel of the
// top-surface position texture X[u, v] and every shadowing light, look the shadow map up at
// the top-surface point: PCF for directional lights, PCSS (Fernando 2005) for SG lights. Writes
// (V * coverage, coverage) so the blur can renormalize over the fabric's own area.
// Twin struct: renderer/src/passes/visibility.rs (VisibilityUniformsGpu).

struct VisibilityUniforms {
    light_clip_from_world: array<mat4x4<f32>, MAX_SHADOWED_LIGHTS>,
    // Per layer: x = filter (1 PCF, 2 PCSS), y = kernel radius in texels (PCF),
    // z = penumbra width in texels per cm of blocker-to-receiver distance (PCSS),
    // w = depth bias in depth units.
    filters: array<vec4<f32>, MAX_SHADOWED_LIGHTS>,
    // x = layers, y = shadow-map size, z = depth range of the light frusta in cm.
    info: vec4<f32>,
}

@group(0) @binding(0) var<uniform> vis: VisibilityUniforms;
@group(0) @binding(1) var top_positions: texture_2d<f32>;
@group(0) @binding(2) var shadow_maps: texture_depth_2d_array;
@group(0) @binding(3) var visibility_out: texture_storage_2d_array<rg32float, write>;

fn shadow_depth(layer: u32, texel: vec2<i32>) -> f32 {
    let size = i32(vis.info.y);
    let t = clamp(texel, vec2<i32>(0), vec2<i32>(size - 1));
    return textureLoad(shadow_maps, t, i32(layer), 0);
}

// Fraction of the (2n+1)^2 taps within `radius` texels of `centre` that see the light.
fn pcf(layer: u32, centre: vec2<f32>, receiver: f32, radius: f32, bias: f32) -> f32 {
    let n = 3;
    var lit = 0.0;
    var count = 0.0;
    for (var j = -n; j <= n; j++) {
        for (var i = -n; i <= n; i++) {
            let offset = vec2<f32>(f32(i), f32(j)) * (radius / f32(n));
            let texel = vec2<i32>(floor(centre + offset));
            lit += select(0.0, 1.0, receiver - bias <= shadow_depth(layer, texel));
            count += 1.0;
        }
    }
    return lit / count;
}

fn pcss(layer: u32, centre: vec2<f32>, receiver: f32, penumbra_per_cm: f32, bias: f32) -> f32 {
    let depth_range = vis.info.z;
    // Blocker search over the widest penumbra any blocker between the light and the receiver
    // could cast.
    let search = clamp(receiver * depth_range * penumbra_per_cm * 0.5, 1.0, 24.0);
    let n = 3;
    var blocker_sum = 0.0;
    var blockers = 0.0;
    for (var j = -n; j <= n; j++) {
        for (var i = -n; i <= n; i++) {
            let offset = vec2<f32>(f32(i), f32(j)) * (search / f32(n));
            let d = shadow_depth(layer, vec2<i32>(floor(centre + offset)));
            if (d < receiver - bias) {
                blocker_sum += d;
                blockers += 1.0;
            }
        }
    }
    if (blockers == 0.0) {
        return 1.0;
    }
    let blocker = blocker_sum / blockers;
    let penumbra = (receiver - blocker) * depth_range * penumbra_per_cm;
    return pcf(layer, centre, receiver, clamp(0.5 * penumbra, 1.0, 32.0), bias);
}

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(top_positions);
    if (id.x >= size.x || id.y >= size.y) {
        return;
    }
    let x = textureLoad(top_positions, vec2<i32>(id.xy), 0);
    let layers = u32(vis.info.x);
    for (var layer = 0u; layer < layers; layer++) {
        var v = vec2<f32>(0.0, 0.0);
        if (x.w > 0.5) {
            let clip = vis.light_clip_from_world[layer] * vec4<f32>(x.xyz, 1.0);
            let ndc = clip.xyz / clip.w;
            let shadow_size = vis.info.y;
            let centre = vec2<f32>(0.5 * ndc.x + 0.5, 0.5 - 0.5 * ndc.y) * shadow_size;
            let f = vis.filters[layer];
            var lit = 1.0;
            if (f.x > 1.5) {
                lit = pcss(layer, centre, ndc.z, f.z, f.w);
            } else {
                lit = pcf(layer, centre, ndc.z, f.y, f.w);
            }
            v = vec2<f32>(lit, 1.0);
        }
        textureStore(visibility_out, vec2<i32>(id.xy), i32(layer), vec4<f32>(v, 0.0, 0.0));
    }
}
