// Global visibility in shell space (paper 5.2.1, 5.2.2, 5.3.2): for every texel of the
// top-surface position texture X[u, v] and every shadowing light, look the shadow map up at
// the top-surface point: PCF for directional lights, PCSS (Fernando 2005) for SG lights. Writes
// (V * coverage, coverage) so the blur can renormalize over the fabric's own area.
// The receiver is the top surface itself, which the shadow map also holds, so each tap compares
// the shadow map with the receiver's plane at that tap, not with the receiver's depth at the
// centre (receiver-plane depth bias, Isidoro 2006): the plane's slope in the shadow map comes
// from X's neighbouring texels. A constant bias alone shadowed a sloped receiver by its own
// surface wherever a tap lay downhill of it (the drape under a light from straight above lost
// 12% of its single scattering).
// Twin struct: renderer/src/passes/visibility.rs (VisibilityUniformsGpu).

struct VisibilityUniforms {
    light_clip_from_world: array<mat4x4<f32>, MAX_SHADOWED_LIGHTS>,
    // Per layer: x = filter (1 PCF, 2 PCSS), y = kernel radius in texels (PCF),
    // z = penumbra width in texels per cm of blocker-to-receiver distance (PCSS),
    // w = depth bias in depth units.
    filters: array<vec4<f32>, MAX_SHADOWED_LIGHTS>,
    // Per layer: x = the most depth a receiver's plane may change per texel (depth units).
    slope_limits: array<vec4<f32>, MAX_SHADOWED_LIGHTS>,
    // x = layers, y = shadow-map size, z = depth range of the light frusta in cm.
    info: vec4<f32>,
}

@group(0) @binding(0) var<storage, read> vis: VisibilityUniforms;
@group(0) @binding(1) var top_positions: texture_2d<f32>;
@group(0) @binding(2) var shadow_maps: texture_depth_2d_array;
@group(0) @binding(3) var visibility_out: texture_storage_2d_array<rg32float, write>;

fn shadow_depth(layer: u32, texel: vec2<i32>) -> f32 {
    let size = i32(vis.info.y);
    let t = clamp(texel, vec2<i32>(0), vec2<i32>(size - 1));
    return textureLoad(shadow_maps, t, i32(layer), 0);
}

// The receiver's depth, on its plane, at the centre of shadow-map texel `texel`.
fn receiver_at(texel: vec2<i32>, centre: vec2<f32>, receiver: f32, slope: vec2<f32>) -> f32 {
    return receiver + dot(slope, vec2<f32>(texel) + vec2<f32>(0.5) - centre);
}

// Fraction of the (2n+1)^2 taps within `radius` texels of `centre` that see the light; the
// receiver lies on the plane of depth `receiver` at `centre` and `slope` per texel.
fn pcf(layer: u32, centre: vec2<f32>, receiver: f32, slope: vec2<f32>, radius: f32, bias: f32) -> f32 {
    let n = 3;
    var lit = 0.0;
    var count = 0.0;
    for (var j = -n; j <= n; j++) {
        for (var i = -n; i <= n; i++) {
            let offset = vec2<f32>(f32(i), f32(j)) * (radius / f32(n));
            let texel = vec2<i32>(floor(centre + offset));
            let here = receiver_at(texel, centre, receiver, slope);
            lit += select(0.0, 1.0, here - bias <= shadow_depth(layer, texel));
            count += 1.0;
        }
    }
    return lit / count;
}

fn pcss(layer: u32, centre: vec2<f32>, receiver: f32, slope: vec2<f32>, penumbra_per_cm: f32, bias: f32) -> f32 {
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
            let texel = vec2<i32>(floor(centre + offset));
            let d = shadow_depth(layer, texel);
            if (d < receiver_at(texel, centre, receiver, slope) - bias) {
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
    return pcf(layer, centre, receiver, slope, clamp(0.5 * penumbra, 1.0, 32.0), bias);
}

// Where the top-surface point of X's texel `t` falls in shadow map `layer`: (texel x, texel y,
// depth); w = 0 when the texel holds no fabric.
fn in_shadow_map(layer: u32, t: vec2<i32>) -> vec4<f32> {
    let size = vec2<i32>(textureDimensions(top_positions));
    if (any(t < vec2<i32>(0)) || any(t >= size)) {
        return vec4<f32>(0.0);
    }
    let x = textureLoad(top_positions, t, 0);
    if (x.w <= 0.5) {
        return vec4<f32>(0.0);
    }
    let clip = vis.light_clip_from_world[layer] * vec4<f32>(x.xyz, 1.0);
    let ndc = clip.xyz / clip.w;
    let shadow_size = vis.info.y;
    return vec4<f32>(vec2<f32>(0.5 * ndc.x + 0.5, 0.5 - 0.5 * ndc.y) * shadow_size, ndc.z, 1.0);
}

// The change of the top surface's depth per shadow-map texel at X's texel `t` (whose point is
// `here`), from its neighbours along u and v (central differences where both hold fabric).
fn receiver_slope(layer: u32, t: vec2<i32>, here: vec4<f32>) -> vec2<f32> {
    var along: array<vec3<f32>, 2>;
    for (var axis = 0; axis < 2; axis++) {
        let step = select(vec2<i32>(0, 1), vec2<i32>(1, 0), axis == 0);
        let ahead = in_shadow_map(layer, t + step);
        let behind = in_shadow_map(layer, t - step);
        var d = vec3<f32>(0.0);
        if (ahead.w > 0.0 && behind.w > 0.0) {
            d = ahead.xyz - behind.xyz;
        } else if (ahead.w > 0.0) {
            d = ahead.xyz - here.xyz;
        } else if (behind.w > 0.0) {
            d = here.xyz - behind.xyz;
        }
        along[axis] = d;
    }
    // Solve [du.xy; dv.xy] slope = [du.z; dv.z].
    let du = along[0];
    let dv = along[1];
    let det = du.x * dv.y - du.y * dv.x;
    if (abs(det) < 1e-12) {
        return vec2<f32>(0.0);
    }
    let slope = vec2<f32>(du.z * dv.y - dv.z * du.y, dv.z * du.x - du.z * dv.x) / det;
    // A receiver the light sees nearly edge-on has an unbounded slope: held to its limit.
    let steepness = length(slope);
    let most = vis.slope_limits[layer].x;
    return select(slope, slope * (most / steepness), steepness > most);
}

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(top_positions);
    if (id.x >= size.x || id.y >= size.y) {
        return;
    }
    let layers = u32(vis.info.x);
    for (var layer = 0u; layer < layers; layer++) {
        var v = vec2<f32>(0.0, 0.0);
        let here = in_shadow_map(layer, vec2<i32>(id.xy));
        if (here.w > 0.0) {
            let slope = receiver_slope(layer, vec2<i32>(id.xy), here);
            let f = vis.filters[layer];
            var lit = 1.0;
            if (f.x > 1.5) {
                lit = pcss(layer, here.xy, here.z, slope, f.z, f.w);
            } else {
                lit = pcf(layer, here.xy, here.z, slope, f.y, f.w);
            }
            v = vec2<f32>(lit, 1.0);
        }
        textureStore(visibility_out, vec2<i32>(id.xy), i32(layer), vec4<f32>(v, 0.0, 0.0));
    }
}
