//! Shadow maps (paper 5.3.2): the shell's top and bottom surfaces rasterized, depth only, from
//! each light that can be occluded, into one layer of a depth array per light.
//!
//! How it works: [`ShadowMapPass::prepare`] fits an orthographic frustum per layer to the
//! shell's bounding sphere, looking along the light ([`LightFrustum`]), makes the depth array
//! and one uniform buffer holding every layer's clip-from-world matrix. [`ShadowMapPass::encode`]
//! then draws the surface triangles once per layer (the plan's `Pass::ShadowMap`), instanced
//! with the layer so the vertex shader picks its matrix (shaders/shadow_map.wgsl).

use glam::camera::rh::proj::directx::orthographic;
use glam::camera::rh::view::look_at_mat4;
use glam::{DVec3, Mat4, Vec3};

use super::shell_gpu::ShellGpu;
use super::{
    FrameEncoder, array_view, bind_group, cleared_depth, depth_less, params_buffer, pass_module, texture_2d,
};
use crate::frame::MAX_SHADOWED_LIGHTS;
use crate::plan::GlobalVisibility;

/// Twin of `ShadowUniforms` in shaders/shadow_map.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ShadowUniformsGpu {
    pub light_clip_from_world: [[[f32; 4]; 4]; MAX_SHADOWED_LIGHTS],
}

/// One layer of the shadow maps: the light it is seen from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadowLayer {
    /// Index of the light in the scene.
    pub light: usize,
    pub filter: GlobalVisibility,
    /// Unit vector towards the light (an SG light's axis).
    pub to_light: DVec3,
    /// An SG light's sharpness λ (PCSS sizes its penumbra by it); `None` for directional lights.
    pub sg_sharpness: Option<f64>,
}

/// A light's orthographic frustum, fitted to the shell's bounding sphere.
#[derive(Debug, Clone, Copy)]
pub struct LightFrustum {
    pub clip_from_world: Mat4,
    /// Side of the square it covers, cm.
    pub width_cm: f32,
    /// Its depth range, cm.
    pub depth_cm: f32,
}

impl LightFrustum {
    /// The frustum looking along `-to_light` at a sphere around the shell's bounds.
    #[must_use]
    pub fn fit(to_light: DVec3, bounds: (Vec3, Vec3)) -> Self {
        let (lo, hi) = bounds;
        let centre = 0.5 * (lo + hi);
        let radius = (0.5 * (hi - lo).length()).max(1e-3) * 1.05;
        let dir = to_light.as_vec3();
        let up = if dir.z.abs() < 0.9 { Vec3::Z } else { Vec3::X };
        let view = look_at_mat4(centre + dir * 2.0 * radius, centre, up);
        let proj = orthographic(-radius, radius, -radius, radius, 0.0, 4.0 * radius);
        Self { clip_from_world: proj * view, width_cm: 2.0 * radius, depth_cm: 4.0 * radius }
    }
}

/// A frame's shadow maps: the depth array, and what each layer was rendered with.
pub struct ShadowMaps {
    pub texture: wgpu::Texture,
    pub size: u32,
    pub layers: Vec<ShadowLayer>,
    pub frusta: Vec<LightFrustum>,
    bind_group: wgpu::BindGroup,
}

impl ShadowMaps {
    /// A view of every layer.
    #[must_use]
    pub fn array_view(&self) -> wgpu::TextureView {
        array_view(&self.texture)
    }
}

/// The shadow-map pipeline.
pub struct ShadowMapPass {
    pipeline: wgpu::RenderPipeline,
}

impl ShadowMapPass {
    #[must_use]
    pub fn new(device: &wgpu::Device) -> Self {
        let module = pass_module(device, "shadow_map.wgsl");
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("twill.shadow_map.pipeline"),
            layout: None,
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_shadow"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: Some(depth_less()),
            multisample: wgpu::MultisampleState::default(),
            fragment: None,
            multiview_mask: None,
            cache: None,
        });
        Self { pipeline }
    }

    /// The depth array and matrices for `layers` (at most [`MAX_SHADOWED_LIGHTS`]) at
    /// `size`² texels.
    #[must_use]
    pub fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        shell: &ShellGpu,
        layers: Vec<ShadowLayer>,
        size: u32,
    ) -> ShadowMaps {
        let frusta: Vec<LightFrustum> =
            layers.iter().map(|l| LightFrustum::fit(l.to_light, shell.bounds)).collect();
        let mut uniforms = ShadowUniformsGpu { light_clip_from_world: [[[0.0; 4]; 4]; MAX_SHADOWED_LIGHTS] };
        for (slot, frustum) in uniforms.light_clip_from_world.iter_mut().zip(&frusta) {
            *slot = frustum.clip_from_world.to_cols_array_2d();
        }
        let texture = texture_2d(
            device,
            "twill.shadow_maps",
            [size, size, layers.len().max(1) as u32],
            wgpu::TextureFormat::Depth32Float,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let buffer = params_buffer(device, queue, "twill.shadow_map.uniforms", &uniforms);
        let bind_group = bind_group(
            device,
            "twill.shadow_map.bind_group",
            &self.pipeline.get_bind_group_layout(0),
            &[buffer.as_entire_binding(), shell.surface_vertices.as_entire_binding()],
        );
        ShadowMaps { texture, size, layers, frusta, bind_group }
    }

    /// Renders layer `layer` of `maps`, timed as `name`.
    pub fn encode(
        &self,
        frame: &mut FrameEncoder,
        maps: &ShadowMaps,
        shell: &ShellGpu,
        layer: u32,
        name: &str,
    ) {
        let layer_view = maps.texture.create_view(&wgpu::TextureViewDescriptor {
            label: Some("twill.shadow_maps.layer"),
            dimension: Some(wgpu::TextureViewDimension::D2),
            base_array_layer: layer,
            array_layer_count: Some(1),
            ..Default::default()
        });
        let mut pass =
            frame.render_pass("twill.shadow_map.pass", name, &[], Some(cleared_depth(&layer_view)));
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &maps.bind_group, &[]);
        pass.draw(0..shell.surface_vertex_count, layer..layer + 1);
    }
}
