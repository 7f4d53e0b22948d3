//! Tone mapping: the accumulated radiance divided by the sample count, scaled by 2^exposure,
//! through the tone curve (clamp or filmic) and sRGB-encoded into the 8-bit display image.
//!
//! How it works: one compute dispatch over the pixels (shaders/tonemap.wgsl), the twin of
//! `crate::export::display_srgb8`. It reads only the accumulation, so a new exposure or curve
//! needs no new samples.

use super::targets::FrameTargets;
use super::{FrameEncoder, bind_group, compute_pass_pipeline, params_buffer};

/// Twin of `ToneMapUniforms` in shaders/tonemap.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ToneMapUniformsGpu {
    /// Width, height, curve (0 clamp, 1 filmic).
    pub size: [u32; 4],
    /// x: 2^exposure / samples.
    pub scale: [f32; 4],
}

/// The tone-map pipeline.
pub struct ToneMapPass {
    pipeline: wgpu::ComputePipeline,
}

impl ToneMapPass {
    #[must_use]
    pub fn new(device: &wgpu::Device) -> Self {
        Self { pipeline: compute_pass_pipeline(device, "tonemap") }
    }

    /// Tone-maps `targets`' accumulation of `samples` samples into its display image, timed as
    /// `name`.
    pub fn encode(
        &self,
        frame: &mut FrameEncoder,
        targets: &FrameTargets,
        exposure: f64,
        filmic: bool,
        samples: u32,
        name: &str,
    ) {
        let (device, queue) = (&frame.device.clone(), &frame.queue.clone());
        let (width, height) = targets.size;
        let uniforms = ToneMapUniformsGpu {
            size: [width, height, u32::from(filmic), 0],
            scale: [(exposure.exp2() / f64::from(samples.max(1))) as f32, 0.0, 0.0, 0.0],
        };
        let uniforms = params_buffer(device, queue, "twill.tonemap.uniforms", &uniforms);
        let display = &targets.views.display;
        let group = bind_group(
            device,
            "twill.tonemap.bind_group",
            &self.pipeline.get_bind_group_layout(0),
            &[
                uniforms.as_entire_binding(),
                targets.accumulation.as_entire_binding(),
                wgpu::BindingResource::TextureView(display),
            ],
        );
        let mut pass = frame.compute_pass("twill.tonemap.pass", name);
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(width.div_ceil(8), height.div_ceil(8), 1);
    }
}
