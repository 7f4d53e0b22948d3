//! Deferred shading (paper 5.2, 5.3), once per sample: single scattering from the SG and
//! directional lights and multiple scattering from the IIRTF (and each light's fiber lobes,
//! for a bake that has them), per G-buffer pixel, added to the accumulation buffer.
//!
//! How it works: the pipeline is specialized by WGSL override constants from the plan's
//! `Pass::Shade` ([`ShadeVariant`]), so a term or a local-visibility path no light needs is not
//! compiled; [`ShadePass::pipeline`] compiles each variant on first use and keeps it. The
//! frame's lights are uploaded once as [`LightGpu`]s (only the ones the plan kept, with their
//! shadow layer and SG path weights), and one bind group serves every sample of the frame (one
//! per band of rows where a frame is shaded in bands, `Renderer::render_progressive_in_bands`).

use std::collections::HashMap;
use std::ops::Range;

use twill_precompute::pathtrace::Light;
use twill_precompute::shading::sg_path_weights;

use super::targets::FrameTargets;
use super::{
    FrameEncoder, array_view, bind_group, compute_pipeline, params_buffer, params_entry, pass_module,
    storage_entry, texture_entry,
};
use crate::fabric_data::{FabricData, make_buffer};
use crate::plan::{FramePlan, LocalVisibility, Pass};

/// Twin of `LightGpu` in shaders/shared/shading.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LightGpu {
    pub direction: [f32; 3],
    pub kind: u32,
    pub color: [f32; 3],
    pub sharpness: f32,
    pub layer: i32,
    pub w_sum_of_sg: f32,
    pub w_ssdf_erf: f32,
    pub pad: f32,
}

/// Twin of `ShadeUniforms` in shaders/shade.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ShadeUniformsGpu {
    /// Lights, width, the end (exclusive) and the start of the rows shaded.
    pub counts: [u32; 4],
    pub eye: [f32; 4],
    pub uv_rect: [f32; 4],
    /// x: the fabric slab's thickness, cm.
    pub fabric: [f32; 4],
}

/// Which terms the shading pipeline is compiled with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[allow(clippy::struct_excessive_bools)]
pub struct ShadeVariant {
    pub single: bool,
    pub multiple: bool,
    pub ssdf_sign: bool,
    pub sum_of_sg: bool,
    pub ssdf_erf: bool,
    pub global_visibility: bool,
    pub frame_transfer: bool,
    /// Each light's fiber lobes (the bake has them; `ENABLE_FIBER_LOBES`).
    pub fiber_lobes: bool,
}

impl ShadeVariant {
    /// The variant a `Pass::Shade` asks for (`None` for any other pass). A blended light needs
    /// both SG paths.
    #[must_use]
    pub fn of(pass: &Pass) -> Option<Self> {
        let Pass::Shade { single, multiple, paths, global_visibility, cell_transfer, fiber_lobes } = pass
        else {
            return None;
        };
        let uses = |path: LocalVisibility| {
            *single && (paths.contains(&path) || paths.contains(&LocalVisibility::Blend))
        };
        Some(Self {
            single: *single,
            multiple: *multiple,
            ssdf_sign: *single && paths.contains(&LocalVisibility::SsdfSign),
            sum_of_sg: uses(LocalVisibility::SumOfSg),
            ssdf_erf: uses(LocalVisibility::SsdfErf),
            global_visibility: *global_visibility,
            frame_transfer: *cell_transfer,
            fiber_lobes: *multiple && *fiber_lobes,
        })
    }
}

/// The lights the plan kept, as the shading and cell-transfer passes read them.
#[must_use]
pub fn lights_gpu(lights: &[Light], plan: &FramePlan) -> Vec<LightGpu> {
    plan.lights
        .iter()
        .map(|l| {
            let layer = l.shadow_layer.map_or(-1, |k| k as i32);
            match lights[l.light] {
                Light::Directional { to_light, irradiance } => LightGpu {
                    direction: to_light.as_vec3().to_array(),
                    kind: 0,
                    color: irradiance.as_vec3().to_array(),
                    sharpness: 0.0,
                    layer,
                    w_sum_of_sg: 0.0,
                    w_ssdf_erf: 0.0,
                    pad: 0.0,
                },
                Light::Sg { axis, sharpness, intensity } => {
                    let (w_sum_of_sg, w_ssdf_erf) = sg_path_weights(sharpness);
                    LightGpu {
                        direction: axis.as_vec3().to_array(),
                        kind: 1,
                        color: intensity.as_vec3().to_array(),
                        sharpness: sharpness as f32,
                        layer,
                        w_sum_of_sg: w_sum_of_sg as f32,
                        w_ssdf_erf: w_ssdf_erf as f32,
                        pad: 0.0,
                    }
                }
            }
        })
        .collect()
}

/// `lights` in a storage buffer. The shaders' `array<LightGpu>` binding needs room for one
/// element even when the plan dropped every light (all below a flat shell): a zeroed one,
/// never read (count 0).
#[must_use]
pub fn lights_buffer(device: &wgpu::Device, queue: &wgpu::Queue, lights: &[LightGpu]) -> wgpu::Buffer {
    let placeholder = [<LightGpu as bytemuck::Zeroable>::zeroed()];
    let lights = if lights.is_empty() { &placeholder[..] } else { lights };
    make_buffer(
        device,
        queue,
        "twill.shade.lights",
        bytemuck::cast_slice(lights),
        wgpu::BufferUsages::STORAGE,
    )
}

/// What one frame's shading reads besides the G-buffer and the bake.
pub struct ShadeInputs<'a> {
    pub lights: &'a wgpu::Buffer,
    pub light_count: usize,
    pub eye: [f32; 4],
    pub uv_rect: [f32; 4],
    /// The fabric slab's thickness, cm.
    pub fabric_thickness_cm: f32,
    pub tetras: &'a wgpu::Buffer,
    /// V[u, v] and its blur (placeholders when the frame has no shadow maps).
    pub visibility_sharp: &'a wgpu::Texture,
    pub visibility_blurred: &'a wgpu::Texture,
    /// The cells' A c_in (a placeholder when the frame has no cell transfer).
    pub cell_transfer: &'a wgpu::Buffer,
}

/// The shading pipelines, one per variant.
pub struct ShadePass {
    layout: wgpu::BindGroupLayout,
    pipelines: HashMap<ShadeVariant, wgpu::ComputePipeline>,
}

impl ShadePass {
    #[must_use]
    pub fn new(device: &wgpu::Device) -> Self {
        let compute = wgpu::ShaderStages::COMPUTE;
        let float = wgpu::TextureSampleType::Float { filterable: false };
        let array = wgpu::TextureViewDimension::D2Array;
        let plain = wgpu::TextureViewDimension::D2;
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("twill.shade.bind_group_layout"),
            entries: &[
                params_entry(0, compute),
                storage_entry(1, compute, true),
                storage_entry(2, compute, true),
                texture_entry(3, float, plain),
                texture_entry(4, wgpu::TextureSampleType::Uint, plain),
                texture_entry(5, float, array),
                texture_entry(6, float, array),
                storage_entry(7, compute, false),
                storage_entry(8, compute, true),
            ],
        });
        Self { layout, pipelines: HashMap::new() }
    }

    /// The pipeline of `variant`, compiled on first use.
    pub fn pipeline(
        &mut self,
        device: &wgpu::Device,
        fabric_layout: &wgpu::BindGroupLayout,
        variant: ShadeVariant,
    ) -> wgpu::ComputePipeline {
        let layout = &self.layout;
        self.pipelines
            .entry(variant)
            .or_insert_with(|| {
                let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some("twill.shade.pipeline_layout"),
                    bind_group_layouts: &[Some(layout), Some(fabric_layout)],
                    immediate_size: 0,
                });
                let module = pass_module(device, "shade.wgsl");
                let flag = |b: bool| if b { 1.0 } else { 0.0 };
                let constants = [
                    ("ENABLE_SINGLE", flag(variant.single)),
                    ("ENABLE_MULTIPLE", flag(variant.multiple)),
                    ("ENABLE_SSDF_SIGN", flag(variant.ssdf_sign)),
                    ("ENABLE_SUM_OF_SG", flag(variant.sum_of_sg)),
                    ("ENABLE_SSDF_ERF", flag(variant.ssdf_erf)),
                    ("ENABLE_GLOBAL_VISIBILITY", flag(variant.global_visibility)),
                    ("ENABLE_FRAME_TRANSFER", flag(variant.frame_transfer)),
                    ("ENABLE_FIBER_LOBES", flag(variant.fiber_lobes)),
                ];
                compute_pipeline(device, "twill.shade.pipeline", &module, Some(&pipeline_layout), &constants)
            })
            .clone()
    }

    /// The bind group every sample of a frame shades `rows` of the image with (all its rows,
    /// or one band of them).
    #[must_use]
    pub fn bind(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        inputs: &ShadeInputs<'_>,
        targets: &FrameTargets,
        rows: &Range<u32>,
    ) -> wgpu::BindGroup {
        let (width, height) = targets.size;
        debug_assert!(rows.start <= rows.end && rows.end <= height, "rows {rows:?} of {height}");
        let uniforms = ShadeUniformsGpu {
            counts: [inputs.light_count as u32, width, rows.end, rows.start],
            eye: inputs.eye,
            uv_rect: inputs.uv_rect,
            fabric: [inputs.fabric_thickness_cm, 0.0, 0.0, 0.0],
        };
        let uniforms = params_buffer(device, queue, "twill.shade.uniforms", &uniforms);
        let (position, ids) = (&targets.views.position, &targets.views.ids);
        let (sharp, blurred) = (array_view(inputs.visibility_sharp), array_view(inputs.visibility_blurred));
        bind_group(
            device,
            "twill.shade.bind_group",
            &self.layout,
            &[
                uniforms.as_entire_binding(),
                inputs.lights.as_entire_binding(),
                inputs.tetras.as_entire_binding(),
                wgpu::BindingResource::TextureView(position),
                wgpu::BindingResource::TextureView(ids),
                wgpu::BindingResource::TextureView(&sharp),
                wgpu::BindingResource::TextureView(&blurred),
                targets.accumulation.as_entire_binding(),
                inputs.cell_transfer.as_entire_binding(),
            ],
        )
    }

    /// Shades one sample: `pipeline` over the pixels of `rows` (those `group` was bound for),
    /// adding to the accumulation.
    pub fn encode(
        frame: &mut FrameEncoder,
        pipeline: &wgpu::ComputePipeline,
        group: &wgpu::BindGroup,
        fabric: &FabricData,
        width: u32,
        rows: &Range<u32>,
        name: &str,
    ) {
        let mut pass = frame.compute_pass("twill.shade.pass", name);
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, group, &[]);
        pass.set_bind_group(1, &fabric.bind_group, &[]);
        pass.dispatch_workgroups(width.div_ceil(8), rows.len().div_ceil(8) as u32, 1);
    }
}
