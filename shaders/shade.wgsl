// Deferred shading (paper 5.2, 5.3): one invocation per pixel reads the G-buffer, moves the
// view and light directions into the hit tetrahedron's flat-fabric frame, and adds single and
// multiple scattering (with the bake's fiber lobes, when it has them) from every light to the
// accumulation buffer. Which terms and which
// local-visibility paths exist is fixed by override constants from the frame plan, so a path
// the scene does not need is not even compiled.
// Twin structs: renderer/src/passes/shade.rs (ShadeUniformsGpu, LightGpu).
#import shared/shading.wgsl
#import shared/shell.wgsl

override ENABLE_SINGLE: bool = true;
override ENABLE_MULTIPLE: bool = true;
override ENABLE_SSDF_SIGN: bool = true;
override ENABLE_SUM_OF_SG: bool = true;
override ENABLE_SSDF_ERF: bool = true;
override ENABLE_GLOBAL_VISIBILITY: bool = true;
// The light arriving in every cell, A c_in, was computed once for the frame (transfer.wgsl):
// the light's SH is the same at every pixel (a shell with one flat-fabric frame and no shadow
// maps), so each pixel reads it instead of multiplying eight transfer matrices.
override ENABLE_FRAME_TRANSFER: bool = false;
// Some cells of the bake hold their light as fiber lobes (BakeSettings::fiber_lobes) instead of
// their matrices: each light adds the lobes' light (shared/shading.wgsl fiber_lobes_light), with
// multiple scattering and before the clamp. Off, `lobes` is a placeholder and is never read.
override ENABLE_FIBER_LOBES: bool = false;


struct ShadeUniforms {
    // x: lights, y: image width, z: the end (exclusive) of the rows this dispatch shades, the
    // image height for a whole frame; w: the first of those rows (a band of rows, frame.rs
    // `render_progressive_in_bands`; 0 for a whole frame).
    counts: vec4<u32>,
    // Eye position (w = 1) or viewing direction (w = 0).
    eye: vec4<f32>,
    // (u_min, v_min, u_max - u_min, v_max - v_min) of the shell, cm.
    uv_rect: vec4<f32>,
    // x: fabric slab thickness in cm.
    fabric: vec4<f32>,
}

@group(0) @binding(0) var<storage, read> shade: ShadeUniforms;
@group(0) @binding(1) var<storage, read> lights: array<LightGpu>;
@group(0) @binding(2) var<storage, read> tetras: array<TetraGpu>;
@group(0) @binding(3) var gbuffer_position: texture_2d<f32>;
@group(0) @binding(4) var gbuffer_ids: texture_2d<u32>;
@group(0) @binding(5) var visibility_sharp: texture_2d_array<f32>;
@group(0) @binding(6) var visibility_blurred: texture_2d_array<f32>;
@group(0) @binding(7) var<storage, read_write> accumulation: array<vec4<f32>>;
// A c_in per slot (cell with segments) for this frame, `slot * sh_count + j` (ENABLE_FRAME_TRANSFER; else unused).
@group(0) @binding(8) var<storage, read> cell_transfer: array<vec4<f32>>;

// transferred_at (shared/shading.wgsl) from the frame's cell_transfer: the cells' A c_in,
// interpolated around the shaded point, or the segment's own cell's.
fn frame_transferred_at(e: u32, segment: u32, p: vec3<f32>, coeffs: ptr<function, array<vec3<f32>, 49>>) {
    let n = fabric.sh_count;
    let around = transfer_cells(e, segment, p);
    for (var k = 0u; k < 8u; k++) {
        let w = around.weights[k];
        if (w > 0.0) {
            let base = around.slots[k] * n;
            for (var j = 0u; j < n; j++) {
                (*coeffs)[j] += w * cell_transfer[base + j].xyz;
            }
        }
    }
}

// Bilinear lookup of a (V * coverage, coverage) texture at shell coordinates uv (cm): V
// averaged over covered texels, 1 where nothing is covered.
fn shell_visibility(tex: texture_2d_array<f32>, layer: i32, uv: vec2<f32>) -> f32 {
    let size = vec2<f32>(textureDimensions(tex));
    let st = (uv - shade.uv_rect.xy) / shade.uv_rect.zw * size - 0.5;
    let base = floor(st);
    let f = st - base;
    var sum = vec2<f32>(0.0);
    for (var j = 0; j < 2; j++) {
        for (var i = 0; i < 2; i++) {
            let p = clamp(vec2<i32>(base) + vec2<i32>(i, j), vec2<i32>(0), vec2<i32>(size) - 1);
            let w = select(1.0 - f.x, f.x, i == 1) * select(1.0 - f.y, f.y, j == 1);
            sum += w * textureLoad(tex, p, layer, 0).xy;
        }
    }
    if (sum.y <= 1e-6) {
        return 1.0;
    }
    return clamp(sum.x / sum.y, 0.0, 1.0);
}

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = shade.counts.y;
    let row = id.y + shade.counts.w;
    if (id.x >= width || row >= shade.counts.z) {
        return;
    }
    let pixel = vec2<i32>(i32(id.x), i32(row));
    let ids = textureLoad(gbuffer_ids, pixel, 0);
    if (ids.w == 0u) {
        return;
    }
    let hit = textureLoad(gbuffer_position, pixel, 0).xyz;
    let segment = ids.x;
    let e = ids.z;
    let tetra = tetras[ids.y];
    // Flat-fabric frame of this tetrahedron: fabric vectors are (du, dv, dw * thickness).
    let m = tetra.uvw_from_world;
    let h = shade.fabric.x;
    let uvw = vec3<f32>(dot(m[0], vec4<f32>(hit, 1.0)), dot(m[1], vec4<f32>(hit, 1.0)), dot(m[2], vec4<f32>(hit, 1.0)));
    var to_eye = -shade.eye.xyz;
    if (shade.eye.w > 0.5) {
        to_eye = shade.eye.xyz - hit;
    }
    let wo = to_fabric_frame(m, h, to_eye);

    // The shaded point in the exemplar's coordinates (as the G-buffer pass found it).
    let z = fabric.z_range.x + clamp(uvw.z, 0.0, 1.0) * (fabric.z_range.y - fabric.z_range.x);
    let p = vec3<f32>(uvw.xy, z);
    // The visibility image of the point along the segment nearest p.
    let image = visibility_image(e, segment, p);

    var radiance = vec3<f32>(0.0);
    // Zero, as every WGSL var starts (no loop: unused when the frame's cell transfer is read).
    var c_in: array<vec3<f32>, 49>;
    // The fiber lobes' cells and shapes at p, gathered once for every light
    // (ENABLE_FIBER_LOBES); none around p: the term is zero.
    var lobes_at: FiberLobesAt;
    var with_lobes = false;
    if (ENABLE_MULTIPLE && ENABLE_FIBER_LOBES) {
        with_lobes = fiber_lobes_at(e, segment, p, &lobes_at);
    }
    for (var i = 0u; i < shade.counts.x; i++) {
        let light = lights[i];
        let dir = to_fabric_frame(m, h, light.direction);
        var v_sharp = 1.0;
        var v_blurred = 1.0;
        if (ENABLE_GLOBAL_VISIBILITY && light.layer >= 0) {
            v_sharp = shell_visibility(visibility_sharp, light.layer, uvw.xy);
            v_blurred = shell_visibility(visibility_blurred, light.layer, uvw.xy);
        }
        if (ENABLE_SINGLE && v_sharp > 0.0) {
            var single = vec3<f32>(0.0);
            if (light.kind == LIGHT_DIRECTIONAL) {
                if (ENABLE_SSDF_SIGN) {
                    single = shade_single_directional(e, segment, image, wo, dir);
                }
            } else {
                if (ENABLE_SUM_OF_SG && light.w_sum_of_sg > 0.0) {
                    single += light.w_sum_of_sg * shade_single_sg_sum_of_sg(e, segment, image, wo, dir, light.sharpness);
                }
                if (ENABLE_SSDF_ERF && light.w_ssdf_erf > 0.0) {
                    single += light.w_ssdf_erf * shade_single_sg_ssdf_erf(e, segment, image, wo, dir, light.sharpness);
                }
            }
            radiance += v_sharp * light.color * single;
        }
        if (ENABLE_MULTIPLE && !ENABLE_FRAME_TRANSFER && v_blurred > 0.0) {
            light_sh_add(light, dir, v_blurred * light.color, &c_in);
        }
        // The fiber lobes' light, per light in either transfer path (its SH is never summed),
        // into the radiance the clamp below acts on (shading::render::shade_segment).
        if (with_lobes && v_blurred > 0.0) {
            let sharpness = select(-1.0, light.sharpness, light.kind == LIGHT_SG);
            radiance += v_blurred * light.color * fiber_lobes_light(segment, wo, dir, sharpness, &lobes_at);
        }
    }
    if (ENABLE_MULTIPLE) {
        // A truncated SH product can ring below zero where little light arrives. The sample
        // goes into the accumulation signed: the tone map and the readback clamp each pixel's
        // mean at zero (shading::render::ClampAtZero::PixelMean, the CPU twin), so ringing that
        // changes sign between a pixel's samples cancels instead of lifting the mean;
        // `radiance` already holds the fiber lobes.
        if (ENABLE_FRAME_TRANSFER) {
            var coeffs: array<vec3<f32>, 49>;
            for (var j = 0u; j < fabric.sh_count; j++) {
                coeffs[j] = vec3<f32>(0.0);
            }
            frame_transferred_at(e, segment, p, &coeffs);
            radiance += multiple_from_transferred(segment, wo, &coeffs);
        } else {
            radiance += shade_multiple(e, segment, p, wo, &c_in);
        }
    }
    let index = row * width + id.x;
    accumulation[index] += vec4<f32>(radiance, 1.0);
}
