//! The light arriving in every IIRTF cell, A c_in, once per frame (paper 5.3, hoisted out of
//! the shading pass).
//!
//! How it works: where the lights' SH c_in is the same at every pixel — a shell whose
//! tetrahedra share one flat-fabric frame ([`ShellGpu::uniform_frame`]), lit without shadow
//! maps — every pixel would multiply the same transfer matrices by the same vector. One
//! invocation per cell (shaders/transfer.wgsl) computes c_in as the shading pass does and
//! writes A c_in; the shading pass then interpolates the cells' results. The plan runs it only
//! then (`Pass::CellTransfer`); otherwise the shading pass binds a one-element placeholder.

use super::shell_gpu::ShellGpu;
use super::{
    FrameEncoder, bind_group, compute_pipeline, params_buffer, params_entry, pass_module, storage_entry,
};
use crate::fabric_data::{FabricData, make_buffer};

/// Twin of `TransferUniforms` in shaders/transfer.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TransferUniformsGpu {
    /// Lights, slots (cells with segments).
    pub counts: [u32; 4],
    /// Rows of the shell's common world → uvw linear map; `[0][3]` the slab thickness (cm).
    pub uvw_from_world: [[f32; 4]; 3],
}

/// The cell-transfer pipeline.
pub struct CellTransferPass {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

impl CellTransferPass {
    #[must_use]
    pub fn new(device: &wgpu::Device, fabric_layout: &wgpu::BindGroupLayout) -> Self {
        let compute = wgpu::ShaderStages::COMPUTE;
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("twill.transfer.bind_group_layout"),
            entries: &[
                params_entry(0, compute),
                storage_entry(1, compute, true),
                storage_entry(2, compute, false),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("twill.transfer.pipeline_layout"),
            bind_group_layouts: &[Some(&layout), Some(fabric_layout)],
            immediate_size: 0,
        });
        let module = pass_module(device, "transfer.wgsl");
        let pipeline =
            compute_pipeline(device, "twill.transfer.pipeline", &module, Some(&pipeline_layout), &[]);
        Self { layout, pipeline }
    }

    /// What the shading pass binds when the frame has no cell transfer.
    #[must_use]
    pub fn unused(device: &wgpu::Device, queue: &wgpu::Queue) -> wgpu::Buffer {
        make_buffer(device, queue, "twill.transfer.unused", &[0; 16], wgpu::BufferUsages::STORAGE)
    }

    /// Records the pass for `light_count` lights in `lights`, timed as `name`, and returns its
    /// output (`slots × sh_count` vec4s: one row per cell that holds segments). `None` when the
    /// shell has no common frame (the plan does not run it then).
    #[must_use]
    pub fn encode(
        &self,
        frame: &mut FrameEncoder,
        shell: &ShellGpu,
        fabric: &FabricData,
        lights: &wgpu::Buffer,
        light_count: usize,
        name: &str,
    ) -> Option<wgpu::Buffer> {
        let (device, queue) = (&frame.device.clone(), &frame.queue.clone());
        let mut rows = shell.uniform_frame?;
        let header = fabric.arrays.header;
        let slots = fabric.arrays.slot_count as u32;
        rows[0][3] = header.z_range[1] - header.z_range[0];
        let uniforms =
            TransferUniformsGpu { counts: [light_count as u32, slots, 0, 0], uvw_from_world: rows };
        let uniforms = params_buffer(device, queue, "twill.transfer.uniforms", &uniforms);
        let output = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("twill.transfer.cells"),
            size: (u64::from(slots.max(1)) * u64::from(header.sh_count) * 16).max(16),
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let group = bind_group(
            device,
            "twill.transfer.bind_group",
            &self.layout,
            &[uniforms.as_entire_binding(), lights.as_entire_binding(), output.as_entire_binding()],
        );
        let mut pass = frame.compute_pass("twill.transfer.pass", name);
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.set_bind_group(1, &fabric.bind_group, &[]);
        pass.dispatch_workgroups(slots.div_ceil(64), 1, 1);
        drop(pass);
        Some(output)
    }
}
