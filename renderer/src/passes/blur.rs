//! The blur of shell-space visibility by σ_glo (paper 5.3.2): multiple scattering sees the
//! macro-scale shadows through a 2D Gaussian of standard deviation σ_glo in flat-fabric cm.
//!
//! How it works: two compute dispatches (shaders/blur.wgsl), along u and then along v, each
//! a 1D Gaussian of σ_glo converted to texels of its axis (the shell's uv rectangle may not be
//! square), cut at 3σ (at most 256 taps). Both channels, V · coverage and coverage, are blurred
//! alike, so their ratio averages V over the fabric's own area.

use super::visibility::visibility_texture;
use super::{FrameEncoder, array_view, bind_group, compute_pass_pipeline, params_buffer};

/// Twin of `BlurUniforms` in shaders/blur.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct BlurUniformsGpu {
    /// Step between taps in texels ((1, 0) or (0, 1)), σ in texels, radius in taps.
    pub axis: [f32; 4],
}

/// The blur pipeline.
pub struct BlurPass {
    pipeline: wgpu::ComputePipeline,
}

impl BlurPass {
    #[must_use]
    pub fn new(device: &wgpu::Device) -> Self {
        Self { pipeline: compute_pass_pipeline(device, "blur") }
    }

    /// Blurs `sharp` by `sigma_glo_cm` over a shell whose uv rectangle is `uv_rect`, timed as
    /// `name` (both dispatches), into a new texture, which it returns.
    #[must_use]
    pub fn encode(
        &self,
        frame: &mut FrameEncoder,
        sharp: &wgpu::Texture,
        sigma_glo_cm: f64,
        uv_rect: [f32; 4],
        name: &str,
    ) -> wgpu::Texture {
        let (device, queue) = (&frame.device.clone(), &frame.queue.clone());
        let size = sharp.width();
        let layers = sharp.depth_or_array_layers();
        let across = visibility_texture(device, "twill.visibility.blur_u", size, layers);
        let blurred = visibility_texture(device, "twill.visibility.blurred", size, layers);
        for (axis, extent, source, destination) in
            [([1.0, 0.0], uv_rect[2], sharp, &across), ([0.0, 1.0], uv_rect[3], &across, &blurred)]
        {
            let sigma = (sigma_glo_cm as f32 * size as f32 / extent).max(1e-3);
            let radius = (3.0 * sigma).ceil().min(256.0);
            let uniforms = BlurUniformsGpu { axis: [axis[0], axis[1], sigma, radius] };
            let buffer = params_buffer(device, queue, "twill.blur.uniforms", &uniforms);
            let (source_view, destination_view) = (array_view(source), array_view(destination));
            let group = bind_group(
                device,
                "twill.blur.bind_group",
                &self.pipeline.get_bind_group_layout(0),
                &[
                    buffer.as_entire_binding(),
                    wgpu::BindingResource::TextureView(&source_view),
                    wgpu::BindingResource::TextureView(&destination_view),
                ],
            );
            let mut pass = frame.compute_pass("twill.blur.pass", name);
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(size.div_ceil(8), size.div_ceil(8), layers);
        }
        blurred
    }
}
