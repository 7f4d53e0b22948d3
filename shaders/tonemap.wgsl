// Final pass: the accumulated radiance divided by the sample count, scaled by 2^exposure, tone
// mapped and sRGB-encoded into an 8-bit image. Twin of renderer/src/export.rs (display_srgb8);
// compared by renderer/tests/gpu_frame.rs. Twin struct: renderer/src/passes/tone_map.rs (ToneMapUniformsGpu).

struct ToneMapUniforms {
    // x: width, y: height, z: curve (0 clamp, 1 filmic).
    size: vec4<u32>,
    // x: 2^exposure / samples.
    scale: vec4<f32>,
}

@group(0) @binding(0) var<storage, read> tone: ToneMapUniforms;
@group(0) @binding(1) var<storage, read> accumulation: array<vec4<f32>>;
@group(0) @binding(2) var display: texture_storage_2d<rgba8unorm, write>;

fn srgb_encode(c: f32) -> f32 {
    if (c <= 0.0031308) {
        return 12.92 * c;
    }
    return 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= tone.size.x || id.y >= tone.size.y) {
        return;
    }
    let scaled = accumulation[id.y * tone.size.x + id.x].xyz * tone.scale.x;
    var mapped = scaled;
    if (tone.size.z == 1u) {
        let x = max(scaled, vec3<f32>(0.0));
        mapped = (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14);
    }
    let c = clamp(mapped, vec3<f32>(0.0), vec3<f32>(1.0));
    textureStore(display, vec2<i32>(id.xy), vec4<f32>(srgb_encode(c.x), srgb_encode(c.y), srgb_encode(c.z), 1.0));
}
