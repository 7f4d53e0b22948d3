// The light arriving in every IIRTF cell, A_cell c_in, once per frame (paper 5.3, hoisted out of
// the shading pass): where the lights' SH c_in is the same at every pixel (a shell whose
// tetrahedra share one flat-fabric frame, lit without shadow maps), every pixel would multiply
// the same eight transfer matrices by the same vector. One invocation per slot (a cell that holds
// segments; empty cells transfer nothing and have none) computes c_in
// (shared/shading.wgsl hemisphere_light_sh_accumulate, as the shading pass does) and A c_in; the shading
// pass then interpolates the results (shade.wgsl frame_transferred_at).
// Twin structs: renderer/src/passes/cell_transfer.rs (TransferUniformsGpu) and
// renderer/src/passes/shade.rs (LightGpu).
#import shared/shading.wgsl

struct TransferUniforms {
    // x: lights, y: slots (cells with segments), zw: unused.
    counts: vec4<u32>,
    // Rows of the linear part of the shell's world -> (u, v, w) map (the same in every
    // tetrahedron); w of row 0: the fabric slab's thickness in cm.
    uvw_from_world: array<vec4<f32>, 3>,
}

@group(0) @binding(0) var<storage, read> transfer: TransferUniforms;
@group(0) @binding(1) var<storage, read> lights: array<LightGpu>;
@group(0) @binding(2) var<storage, read_write> cell_transfer: array<vec4<f32>>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let slot = id.x;
    if (slot >= transfer.counts.y) {
        return;
    }
    let n = fabric.sh_count;
    let m = transfer.uvw_from_world;
    let h = transfer.uvw_from_world[0].w;
    var c_in: array<vec3<f32>, 49>;
    for (var j = 0u; j < 49u; j++) {
        c_in[j] = vec3<f32>(0.0);
    }
    for (var i = 0u; i < transfer.counts.x; i++) {
        let light = lights[i];
        light_sh_add(light, to_fabric_frame(m, h, light.direction), light.color, &c_in);
    }
    var c_t: array<vec3<f32>, 49>;
    for (var j = 0u; j < n; j++) {
        c_t[j] = vec3<f32>(0.0);
    }
    add_transferred(slot, 1.0, n, &c_in, &c_t);
    for (var j = 0u; j < n; j++) {
        cell_transfer[slot * n + j] = vec4<f32>(c_t[j], 0.0);
    }
}
