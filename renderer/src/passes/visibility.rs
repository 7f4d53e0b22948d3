//! Shell-space visibility V[u, v] (paper 5.2.1, 5.2.2, 5.3.2): for every texel of the
//! top-surface position texture X and every shadow-map layer, the shadow map looked up at the
//! top-surface point — percentage-closer filtering for directional lights, percentage-closer
//! soft shadows (Fernando 2005) for SG lights.
//!
//! How it works: one compute dispatch over the texels (shaders/visibility.wgsl) writes
//! (V · coverage, coverage) per layer, so the blur can renormalize over the fabric's own area.
//! Each layer's filter is resolved here from its light: PCF's kernel radius, PCSS's penumbra
//! per cm of blocker-to-receiver distance, and the depth bias in depth units. The receiver is
//! the top surface, which the shadow map holds too, so every tap compares against the
//! receiver's plane at that tap (its slope from X's neighbouring texels), not its depth at the
//! centre: with a constant bias alone a sloped receiver shadowed itself.
//!
//! PCSS for SG lights needs a light size, which an SG does not have; we use the angle α at which
//! the lobe falls to 1/e of its peak, `cos α = 1 − 1/λ` (α ≈ sqrt(2/λ) for sharp lobes; α = 90°
//! for λ ≤ 1), and the penumbra a blocker at distance Δ casts is `2 Δ tan α`, capped at 60°.

use twill_precompute::scene::GpuSection;

use super::shadow_map::ShadowMaps;
use super::{FrameEncoder, array_view, bind_group, compute_pass_pipeline, params_buffer, texture_2d, view};
use crate::frame::MAX_SHADOWED_LIGHTS;
use crate::plan::GlobalVisibility;

/// Widest PCSS light angle (an SG wider than this blurs shadows no further).
const MAX_PCSS_ANGLE_DEG: f64 = 60.0;
/// The steepest receiver, as the angle between its surface and the light's image plane, whose
/// plane the filter follows (receiver-plane depth bias, shaders/visibility.wgsl); a steeper one
/// is taken as this steep.
pub const MAX_RECEIVER_SLOPE_DEG: f64 = 85.0;

/// The angular radius used for an SG light's PCSS penumbra: `cos α = 1 − 1/λ`, capped.
#[must_use]
pub fn sg_light_angle(lambda: f64) -> f64 {
    let alpha = if lambda <= 1.0 { std::f64::consts::FRAC_PI_2 } else { (1.0 - 1.0 / lambda).acos() };
    alpha.min(MAX_PCSS_ANGLE_DEG.to_radians())
}

/// Twin of `VisibilityUniforms` in shaders/visibility.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct VisibilityUniformsGpu {
    pub light_clip_from_world: [[[f32; 4]; 4]; MAX_SHADOWED_LIGHTS],
    /// Per layer: filter (1 PCF, 2 PCSS), PCF radius in texels, PCSS penumbra in texels per cm,
    /// depth bias in depth units.
    pub filters: [[f32; 4]; MAX_SHADOWED_LIGHTS],
    /// Per layer: the most depth the receiver's plane may change per texel (depth units; see
    /// [`MAX_RECEIVER_SLOPE_DEG`]).
    pub slope_limits: [[f32; 4]; MAX_SHADOWED_LIGHTS],
    /// Layers, shadow-map size, depth range of the light frusta in cm.
    pub info: [f32; 4],
}

impl VisibilityUniformsGpu {
    /// The uniforms for `maps` with the scene's shadow settings.
    #[must_use]
    pub fn new(maps: &ShadowMaps, settings: &GpuSection) -> Self {
        let size = f64::from(maps.size);
        let mut uniforms = Self {
            light_clip_from_world: [[[0.0; 4]; 4]; MAX_SHADOWED_LIGHTS],
            filters: [[0.0; 4]; MAX_SHADOWED_LIGHTS],
            slope_limits: [[0.0; 4]; MAX_SHADOWED_LIGHTS],
            info: [
                maps.layers.len() as f32,
                maps.size as f32,
                maps.frusta.first().map_or(1.0, |f| f.depth_cm),
                0.0,
            ],
        };
        for (k, (layer, frustum)) in maps.layers.iter().zip(&maps.frusta).enumerate() {
            uniforms.light_clip_from_world[k] = frustum.clip_from_world.to_cols_array_2d();
            let texel_cm = f64::from(frustum.width_cm) / size;
            let bias = settings.shadow_bias_texels * texel_cm / f64::from(frustum.depth_cm);
            let penumbra_per_cm =
                layer.sg_sharpness.map_or(0.0, |l| 2.0 * sg_light_angle(l).tan() / texel_cm);
            let filter = if layer.filter == GlobalVisibility::Pcss { 2.0 } else { 1.0 };
            uniforms.filters[k] =
                [filter, settings.pcf_radius_texels as f32, penumbra_per_cm as f32, bias as f32];
            let most = MAX_RECEIVER_SLOPE_DEG.to_radians().tan() * texel_cm / f64::from(frustum.depth_cm);
            uniforms.slope_limits[k] = [most as f32, 0.0, 0.0, 0.0];
        }
        uniforms
    }
}

/// The visibility pipeline.
pub struct VisibilityPass {
    pipeline: wgpu::ComputePipeline,
}

impl VisibilityPass {
    #[must_use]
    pub fn new(device: &wgpu::Device) -> Self {
        Self { pipeline: compute_pass_pipeline(device, "visibility") }
    }

    /// Computes V[u, v] from X (`top`) and the shadow maps, timed as `name`, into a new texture
    /// of `size`² texels and one layer per shadow map, which it returns.
    #[must_use]
    pub fn encode(
        &self,
        frame: &mut FrameEncoder,
        top: &wgpu::Texture,
        maps: &ShadowMaps,
        settings: &GpuSection,
        size: u32,
        name: &str,
    ) -> wgpu::Texture {
        let (device, queue) = (&frame.device.clone(), &frame.queue.clone());
        let output = visibility_texture(device, "twill.visibility.sharp", size, maps.layers.len() as u32);
        let uniforms = params_buffer(
            device,
            queue,
            "twill.visibility.uniforms",
            &VisibilityUniformsGpu::new(maps, settings),
        );
        let (top_view, shadow_view, output_view) = (view(top), maps.array_view(), array_view(&output));
        let group = bind_group(
            device,
            "twill.visibility.bind_group",
            &self.pipeline.get_bind_group_layout(0),
            &[
                uniforms.as_entire_binding(),
                wgpu::BindingResource::TextureView(&top_view),
                wgpu::BindingResource::TextureView(&shadow_view),
                wgpu::BindingResource::TextureView(&output_view),
            ],
        );
        let mut pass = frame.compute_pass("twill.visibility.pass", name);
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(size.div_ceil(8), size.div_ceil(8), 1);
        drop(pass);
        output
    }
}

/// A shell-space visibility texture: (V · coverage, coverage) per texel and layer.
#[must_use]
pub fn visibility_texture(device: &wgpu::Device, label: &str, size: u32, layers: u32) -> wgpu::Texture {
    texture_2d(
        device,
        label,
        [size, size, layers.max(1)],
        wgpu::TextureFormat::Rg32Float,
        wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::TEXTURE_BINDING,
    )
}
