//! The top-surface position texture X[u, v] (paper 5.2.1): the shell's top surface rasterized
//! in (u, v) space, each texel holding the world position of the top surface above (u, v) —
//! where the visibility pass looks the shadow maps up.
//!
//! How it works: one render pass draws the top-surface triangles with (u, v) mapped onto the
//! texture by the shell's uv rectangle (shaders/top_surface.wgsl); texels the surface does not
//! cover stay transparent (w = 0: no fabric there).

use super::shell_gpu::ShellGpu;
use super::{FrameEncoder, bind_group, cleared_colour, params_buffer, pass_module, texture_2d, view};

/// Twin of `TopSurfaceUniforms` in shaders/top_surface.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TopSurfaceUniformsGpu {
    pub uv_rect: [f32; 4],
}

/// The top-surface pipeline.
pub struct TopSurfacePass {
    pipeline: wgpu::RenderPipeline,
}

impl TopSurfacePass {
    #[must_use]
    pub fn new(device: &wgpu::Device) -> Self {
        let module = pass_module(device, "top_surface.wgsl");
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("twill.top_surface.pipeline"),
            layout: None,
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_top"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_top"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                targets: &[Some(wgpu::TextureFormat::Rgba32Float.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        Self { pipeline }
    }

    /// Renders X[u, v] at `size`² texels, timed as `name`, and returns it.
    #[must_use]
    pub fn encode(&self, frame: &mut FrameEncoder, shell: &ShellGpu, size: u32, name: &str) -> wgpu::Texture {
        let (device, queue) = (&frame.device.clone(), &frame.queue.clone());
        let top = texture_2d(
            device,
            "twill.top_surface",
            [size, size, 1],
            wgpu::TextureFormat::Rgba32Float,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let uniforms = TopSurfaceUniformsGpu { uv_rect: shell.uv_rect };
        let buffer = params_buffer(device, queue, "twill.top_surface.uniforms", &uniforms);
        let group = bind_group(
            device,
            "twill.top_surface.bind_group",
            &self.pipeline.get_bind_group_layout(0),
            &[buffer.as_entire_binding(), shell.surface_vertices.as_entire_binding()],
        );
        let top_view = view(&top);
        let mut pass =
            frame.render_pass("twill.top_surface.pass", name, &[Some(cleared_colour(&top_view))], None);
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.draw(0..shell.top_vertex_count, 0..1);
        drop(pass);
        top
    }
}
