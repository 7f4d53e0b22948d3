// Separable Gaussian blur of the shell-space visibility (paper 5.3.2): K is a 2D Gaussian of
// standard deviation sigma_glo in flat-fabric cm. Each texel holds (V * coverage, coverage), and
// both channels are blurred alike, so V-bar = x / y averages V over the fabric's own area (the
// paper's normalization by the integral of K over A). Run once along u, once along v.
// Twin struct: renderer/src/passes/blur.rs (BlurUniformsGpu).

struct BlurUniforms {
    // xy: step between taps in texels ((1, 0) or (0, 1)); z: sigma in texels; w: radius in taps.
    axis: vec4<f32>,
}

@group(0) @binding(0) var<storage, read> blur: BlurUniforms;
@group(0) @binding(1) var source: texture_2d_array<f32>;
@group(0) @binding(2) var destination: texture_storage_2d_array<rg32float, write>;

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(source);
    if (id.x >= size.x || id.y >= size.y) {
        return;
    }
    let layer = i32(id.z);
    let step = vec2<i32>(blur.axis.xy);
    let radius = i32(blur.axis.w);
    let inv_two_sigma2 = 0.5 / (blur.axis.z * blur.axis.z);
    var sum = vec2<f32>(0.0);
    for (var k = -radius; k <= radius; k++) {
        let p = vec2<i32>(id.xy) + k * step;
        if (all(p >= vec2<i32>(0)) && all(p < vec2<i32>(size))) {
            let w = exp(-f32(k * k) * inv_two_sigma2);
            sum += w * textureLoad(source, p, layer, 0).xy;
        }
    }
    textureStore(destination, vec2<i32>(id.xy), layer, vec4<f32>(sum, 0.0, 0.0));
}
