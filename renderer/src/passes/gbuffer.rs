//! Eye rays into the G-buffer (paper 5.1), once per sample.
//!
//! How it works: the shell's surface faces are rasterized (front faces: where an eye ray
//! enters the shell) with the camera's clip-from-world matrix, jittered by the sample's
//! sub-pixel offset. Each fragment walks its ray from tetrahedron to tetrahedron and, inside
//! each, voxel by voxel to the first fiber they enter (shaders/gbuffer.wgsl); it writes the hit's
//! world position and ids and its true depth, so the depth test keeps the nearest hit where a
//! ray enters the shell more than once.

use glam::camera::rh::proj::directx::{orthographic, perspective};
use glam::camera::rh::view::look_at_mat4;
use glam::{DVec3, Mat4, Vec3};
use twill_precompute::scene::{CameraSection, ProjectionKind};

use super::shell_gpu::ShellGpu;
use super::targets::FrameTargets;
use super::{
    FrameEncoder, bind_group, cleared_colour, cleared_depth, depth_less, params_buffer, params_entry,
    pass_module, storage_entry,
};
use crate::fabric_data::FabricData;

/// Twin of `FrameUniforms` in shaders/gbuffer.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FrameUniformsGpu {
    pub clip_from_world: [[f32; 4]; 4],
    pub eye: [f32; 4],
    pub jitter: [f32; 4],
    pub fabric_z: [f32; 4],
    /// x: for an orthographic camera, where its film plane lies along the viewing direction
    /// (`dot(eye, view)`): eye rays start there, as the path tracer's do. Unused for perspective.
    pub film: [f32; 4],
}

/// A frame's camera as the passes use it.
#[derive(Debug, Clone, Copy)]
pub struct EyeRays {
    /// wgpu depth 0..1, near and far fitted around the shell.
    pub clip_from_world: Mat4,
    /// Position with w = 1 (perspective) or the viewing direction with w = 0 (orthographic).
    pub eye: [f32; 4],
    /// An orthographic camera's film-plane offset along the viewing direction (0 for perspective).
    pub film_plane: f32,
}

impl EyeRays {
    /// The camera's matrices for an image of `aspect` over a shell with these `bounds`. The
    /// orthographic near plane may lie behind the film so that every tetrahedron the film cuts
    /// is still rasterized; the G-buffer starts each eye ray at the film plane.
    #[must_use]
    pub fn new(camera: &CameraSection, aspect: f32, bounds: (Vec3, Vec3)) -> Self {
        let eye = DVec3::from(camera.eye).as_vec3();
        let target = DVec3::from(camera.target).as_vec3();
        let up = DVec3::from(camera.up).as_vec3();
        let forward = (target - eye).normalize();
        let view = look_at_mat4(eye, target, up);
        let (lo, hi) = bounds;
        let mut near = f32::INFINITY;
        let mut far = 0.0_f32;
        for i in 0..8 {
            let corner = Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            let d = (corner - eye).dot(forward);
            near = near.min(d);
            far = far.max(d);
        }
        let span = (hi - lo).length().max(1e-3);
        let far = far.max(1e-3) + 0.01 * span;
        match camera.projection {
            ProjectionKind::Perspective => {
                let near = (near - 0.01 * span).max(far * 1e-4);
                let proj = perspective((camera.fov_y_deg as f32).to_radians(), aspect, near, far);
                Self { clip_from_world: proj * view, eye: eye.extend(1.0).to_array(), film_plane: 0.0 }
            }
            ProjectionKind::Orthographic => {
                let half_h = 0.5 * camera.height_cm as f32;
                let half_w = half_h * aspect;
                let near = near - 0.01 * span;
                let proj = orthographic(-half_w, half_w, -half_h, half_h, near, far);
                Self {
                    clip_from_world: proj * view,
                    eye: forward.extend(0.0).to_array(),
                    film_plane: eye.dot(forward),
                }
            }
        }
    }
}

/// The G-buffer pipeline.
pub struct GBufferPass {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::RenderPipeline,
}

impl GBufferPass {
    #[must_use]
    pub fn new(device: &wgpu::Device, fabric_layout: &wgpu::BindGroupLayout) -> Self {
        let stages = wgpu::ShaderStages::VERTEX_FRAGMENT;
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("twill.gbuffer.bind_group_layout"),
            entries: &[
                params_entry(0, stages),
                storage_entry(1, stages, true),
                storage_entry(2, stages, true),
                storage_entry(3, stages, true),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("twill.gbuffer.pipeline_layout"),
            bind_group_layouts: &[Some(&layout), Some(fabric_layout)],
            immediate_size: 0,
        });
        let module = pass_module(device, "gbuffer.wgsl");
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("twill.gbuffer.pipeline"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
                front_face: wgpu::FrontFace::Ccw,
                cull_mode: Some(wgpu::Face::Back),
                ..Default::default()
            },
            depth_stencil: Some(depth_less()),
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                targets: &[
                    Some(wgpu::TextureFormat::Rgba32Float.into()),
                    Some(wgpu::TextureFormat::Rgba32Uint.into()),
                ],
            }),
            multiview_mask: None,
            cache: None,
        });
        Self { layout, pipeline }
    }

    /// Renders one sample's G-buffer into `rows` of `targets` (all of them, or one band: the
    /// other rows are cleared), its eye rays offset by `jitter` (clip units), timed as `name`.
    #[allow(clippy::too_many_arguments)]
    pub fn encode(
        &self,
        frame: &mut FrameEncoder,
        eye: &EyeRays,
        jitter: [f32; 2],
        shell: &ShellGpu,
        fabric: &FabricData,
        targets: &FrameTargets,
        rows: &std::ops::Range<u32>,
        name: &str,
    ) {
        let (device, queue) = (&frame.device.clone(), &frame.queue.clone());
        let z = fabric.arrays.header.z_range;
        let uniforms = FrameUniformsGpu {
            clip_from_world: eye.clip_from_world.to_cols_array_2d(),
            eye: eye.eye,
            jitter: [jitter[0], jitter[1], 0.0, 0.0],
            fabric_z: [z[0], z[1] - z[0], 0.0, 0.0],
            film: [eye.film_plane, 0.0, 0.0, 0.0],
        };
        let uniforms = params_buffer(device, queue, "twill.gbuffer.uniforms", &uniforms);
        let group = bind_group(
            device,
            "twill.gbuffer.bind_group",
            &self.layout,
            &[
                uniforms.as_entire_binding(),
                shell.tetra_corners.as_entire_binding(),
                shell.tetras.as_entire_binding(),
                shell.surface_faces.as_entire_binding(),
            ],
        );
        let (position, ids, depth) = (&targets.views.position, &targets.views.ids, &targets.views.depth);
        let mut pass = frame.render_pass(
            "twill.gbuffer.pass",
            name,
            &[Some(cleared_colour(position)), Some(cleared_colour(ids))],
            Some(cleared_depth(depth)),
        );
        let (width, height) = targets.size;
        if rows.start > 0 || rows.end < height {
            pass.set_scissor_rect(0, rows.start, width, rows.len() as u32);
        }
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.set_bind_group(1, &fabric.bind_group, &[]);
        pass.draw(0..shell.surface_face_count * 3, 0..1);
    }
}
