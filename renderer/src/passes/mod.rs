//! The frame's passes, one module each: its pipeline, its GPU structs (twins of its WGSL's),
//! and how it records itself into a frame.
//!
//! How it works: [`FramePasses::new`] builds every pass's pipeline once, when a renderer is
//! made (the shading pass compiles one variant per set of plan switches, on first use). A frame
//! is recorded through a [`FrameEncoder`]: the command encoder, and a GPU timestamp pair around
//! every pass it begins, named by the plan's [`crate::plan::Pass::name`]. The executor in
//! `frame.rs` walks `plan.passes()` and hands each pass to its module, in the order they run:
//! - [`shadow_map`]: the shell's surfaces, depth only, from each shadowing light;
//! - [`top_surface`]: the top-surface position texture X[u, v];
//! - [`visibility`]: V[u, v] per light, PCF or PCSS lookups of the shadow maps at X;
//! - [`blur`]: V blurred by σ_glo, separably;
//! - [`cell_transfer`]: the light arriving in every IIRTF cell, once per frame;
//! - [`gbuffer`]: eye rays walked through the shell to the first fiber they enter (per sample);
//! - [`shade`]: single and multiple scattering per pixel, added to the accumulation (per sample);
//! - [`tone_map`]: the accumulated radiance into an 8-bit sRGB image.
//!
//! What several passes read lives beside them: the shell on the GPU ([`shell_gpu`]) and the
//! textures and buffers a frame renders into ([`targets`]). The helpers below are the
//! descriptor boilerplate every module would otherwise repeat.

pub mod blur;
pub mod cell_transfer;
pub mod gbuffer;
pub mod shade;
pub mod shadow_map;
pub mod shell_gpu;
pub mod targets;
pub mod tone_map;
pub mod top_surface;
pub mod visibility;

use crate::fabric_data::make_buffer;
use crate::frame::{PassTiming, RenderError};
use crate::shaders;

/// Every pass's pipeline, built once per renderer.
pub struct FramePasses {
    pub shadow_map: shadow_map::ShadowMapPass,
    pub top_surface: top_surface::TopSurfacePass,
    pub visibility: visibility::VisibilityPass,
    pub blur: blur::BlurPass,
    pub cell_transfer: cell_transfer::CellTransferPass,
    pub gbuffer: gbuffer::GBufferPass,
    pub shade: shade::ShadePass,
    pub tone_map: tone_map::ToneMapPass,
}

impl FramePasses {
    /// Builds the pipelines; the passes that read the bake bind `fabric_layout` as group 1.
    #[must_use]
    pub fn new(device: &wgpu::Device, fabric_layout: &wgpu::BindGroupLayout) -> Self {
        Self {
            shadow_map: shadow_map::ShadowMapPass::new(device),
            top_surface: top_surface::TopSurfacePass::new(device),
            visibility: visibility::VisibilityPass::new(device),
            blur: blur::BlurPass::new(device),
            cell_transfer: cell_transfer::CellTransferPass::new(device, fabric_layout),
            gbuffer: gbuffer::GBufferPass::new(device, fabric_layout),
            shade: shade::ShadePass::new(device),
            tone_map: tone_map::ToneMapPass::new(device),
        }
    }
}

/// Most timed pass instances in one frame (a query set holds at most 4096 queries, two per
/// instance); a frame with more (thousands of samples in one call) is not timed.
pub const MAX_TIMED_PASS_INSTANCES: u32 = 2048;

/// A frame being recorded: the command encoder and, when the adapter has timestamp queries,
/// the timestamps of every pass begun through it, by name.
pub struct FrameEncoder {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub encoder: wgpu::CommandEncoder,
    queries: Option<wgpu::QuerySet>,
    names: Vec<String>,
}

/// The timestamps of a recorded frame, to read after it was submitted.
pub struct TimingReadback {
    buffer: wgpu::Buffer,
    names: Vec<String>,
}

impl FrameEncoder {
    /// A new frame on `device`; `timed_instances`: how many pass instances it will time
    /// (`None`: no timing).
    #[must_use]
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue, timed_instances: Option<u32>) -> Self {
        let queries = timed_instances.filter(|&n| n > 0).map(|n| {
            device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("twill.frame.timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: 2 * n,
            })
        });
        let encoder = device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("twill.frame.encoder") });
        Self { device: device.clone(), queue: queue.clone(), encoder, queries, names: Vec::new() }
    }

    /// The first of the two query slots of the next timed pass, `name`.
    fn slot(&mut self, name: &str) -> Option<u32> {
        let set = self.queries.as_ref()?;
        let index = 2 * self.names.len() as u32;
        if index + 1 >= set.count() {
            return None;
        }
        self.names.push(name.to_owned());
        Some(index)
    }

    /// Begins a compute pass, timed as `name`.
    pub fn compute_pass(&mut self, label: &str, name: &str) -> wgpu::ComputePass<'_> {
        let slot = self.slot(name);
        let timestamp_writes =
            slot.zip(self.queries.as_ref()).map(|(i, set)| wgpu::ComputePassTimestampWrites {
                query_set: set,
                beginning_of_pass_write_index: Some(i),
                end_of_pass_write_index: Some(i + 1),
            });
        self.encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(label), timestamp_writes })
    }

    /// Begins a render pass into these attachments, timed as `name`.
    pub fn render_pass(
        &mut self,
        label: &str,
        name: &str,
        color_attachments: &[Option<wgpu::RenderPassColorAttachment<'_>>],
        depth_stencil_attachment: Option<wgpu::RenderPassDepthStencilAttachment<'_>>,
    ) -> wgpu::RenderPass<'_> {
        let slot = self.slot(name);
        let timestamp_writes =
            slot.zip(self.queries.as_ref()).map(|(i, set)| wgpu::RenderPassTimestampWrites {
                query_set: set,
                beginning_of_pass_write_index: Some(i),
                end_of_pass_write_index: Some(i + 1),
            });
        self.encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some(label),
            color_attachments,
            depth_stencil_attachment,
            timestamp_writes,
            occlusion_query_set: None,
            multiview_mask: None,
        })
    }

    /// Resolves the timestamps into a readback buffer and finishes the encoder.
    #[must_use]
    pub fn finish(mut self) -> (wgpu::CommandBuffer, Option<TimingReadback>) {
        let device = &self.device;
        let count = 2 * self.names.len() as u32;
        let readback = self.queries.as_ref().filter(|_| count > 0).map(|set| {
            let bytes = u64::from(count) * 8;
            let resolve = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("twill.timestamps.resolve"),
                size: bytes,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            self.encoder.resolve_query_set(set, 0..count, &resolve, 0);
            let buffer = readback_buffer(device, "twill.readback.timestamps", bytes);
            self.encoder.copy_buffer_to_buffer(&resolve, 0, &buffer, 0, bytes);
            TimingReadback { buffer, names: std::mem::take(&mut self.names) }
        });
        (self.encoder.finish(), readback)
    }
}

impl TimingReadback {
    /// GPU milliseconds per pass name (instances of one name summed), in the order they ran.
    ///
    /// # Errors
    /// When the readback fails.
    pub fn read(self, device: &wgpu::Device, queue: &wgpu::Queue) -> Result<Vec<PassTiming>, RenderError> {
        let ticks: Vec<u64> = crate::gpu::read_buffer(device, &self.buffer)?;
        let period_ns = f64::from(queue.get_timestamp_period());
        let mut sums: Vec<PassTiming> = Vec::new();
        for (i, name) in self.names.iter().enumerate() {
            let ms = ticks[2 * i + 1].saturating_sub(ticks[2 * i]) as f64 * period_ns * 1e-6;
            match sums.iter_mut().find(|t| &t.pass == name) {
                Some(t) => t.milliseconds += ms,
                None => sums.push(PassTiming { pass: name.clone(), milliseconds: ms }),
            }
        }
        Ok(sums)
    }
}

/// A uniform buffer's layout entry: only for data fixed while a bake is loaded (the fabric
/// header). What changes from frame to frame goes in [`params_entry`] buffers.
pub(crate) fn uniform_entry(binding: u32, visibility: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// The layout entry of a pass's parameters (a [`params_buffer`]): a read-only storage buffer.
pub(crate) fn params_entry(binding: u32, visibility: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    storage_entry(binding, visibility, true)
}

pub(crate) fn storage_entry(
    binding: u32,
    visibility: wgpu::ShaderStages,
    read_only: bool,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

pub(crate) fn texture_entry(
    binding: u32,
    sample_type: wgpu::TextureSampleType,
    view_dimension: wgpu::TextureViewDimension,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture { sample_type, view_dimension, multisampled: false },
        count: None,
    }
}

/// The WGSL of a pass: its file under `shaders/` with its imports resolved.
pub(crate) fn pass_source(file: &str) -> String {
    shaders::compose(file).unwrap_or_else(|e| panic!("twill's own shaders compose: {e}"))
}

/// The shader module of a pass's WGSL file, labelled `twill.<file stem>.shader`.
pub(crate) fn pass_module(device: &wgpu::Device, file: &str) -> wgpu::ShaderModule {
    let stem = file.trim_end_matches(".wgsl");
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(&format!("twill.{stem}.shader")),
        source: wgpu::ShaderSource::Wgsl(pass_source(file).into()),
    })
}

/// A 2D texture (or array of `layers`) with one mip level and one sample.
pub(crate) fn texture_2d(
    device: &wgpu::Device,
    label: &str,
    [width, height, layers]: [u32; 3],
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width, height, depth_or_array_layers: layers },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

/// A view of the whole texture.
pub(crate) fn view(texture: &wgpu::Texture) -> wgpu::TextureView {
    texture.create_view(&wgpu::TextureViewDescriptor::default())
}

/// A view of every layer of a texture as a 2D array.
pub(crate) fn array_view(texture: &wgpu::Texture) -> wgpu::TextureView {
    texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    })
}

/// A compute pipeline with entry point `main`, specialized by override `constants`.
pub(crate) fn compute_pipeline(
    device: &wgpu::Device,
    label: &str,
    module: &wgpu::ShaderModule,
    layout: Option<&wgpu::PipelineLayout>,
    constants: &[(&str, f64)],
) -> wgpu::ComputePipeline {
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(label),
        layout,
        module,
        entry_point: Some("main"),
        compilation_options: wgpu::PipelineCompilationOptions { constants, ..Default::default() },
        cache: None,
    })
}

/// The compute pipeline of a pass's WGSL file `shaders/<stem>.wgsl` (entry point `main`, the
/// bind group layout taken from the shader), labelled `twill.<stem>.pipeline`.
pub(crate) fn compute_pass_pipeline(device: &wgpu::Device, stem: &str) -> wgpu::ComputePipeline {
    let module = pass_module(device, &format!("{stem}.wgsl"));
    compute_pipeline(device, &format!("twill.{stem}.pipeline"), &module, None, &[])
}

/// A pass's parameters for one frame (or one sample), `value`, in a read-only storage buffer
/// (`var<storage, read>` in its shader).
///
/// Not a uniform buffer: lavapipe (Mesa 22.3, the headless renderer) specializes a shader on
/// the values of the uniforms that steer its branches and loops, compiling a new variant for
/// every new set of values and never freeing one. Per-sample parameters (the sub-pixel
/// jitter) in a uniform buffer made every sample compile the eye-ray shader again: about 2 MB
/// and 6 ms per sample, without bound (an accuracy sweep grew to 24 GB). Mesa inlines only
/// uniform buffers; on other GPUs a small read-only storage buffer should cost about the same
/// (not measured: no GPU was at hand).
pub(crate) fn params_buffer<T: bytemuck::Pod>(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    label: &str,
    value: &T,
) -> wgpu::Buffer {
    make_buffer(device, queue, label, bytemuck::bytes_of(value), wgpu::BufferUsages::STORAGE)
}

/// A bind group of `layout` binding `resources` at 0, 1, 2, ...
pub(crate) fn bind_group(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::BindGroupLayout,
    resources: &[wgpu::BindingResource<'_>],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry<'_>> = resources
        .iter()
        .enumerate()
        .map(|(i, resource)| wgpu::BindGroupEntry { binding: i as u32, resource: resource.clone() })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some(label), layout, entries: &entries })
}

/// A buffer the CPU maps to read what the GPU copied into it.
pub(crate) fn readback_buffer(device: &wgpu::Device, label: &str, size: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.max(16),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// A colour attachment cleared to transparent and stored.
pub(crate) fn cleared_colour(view: &wgpu::TextureView) -> wgpu::RenderPassColorAttachment<'_> {
    wgpu::RenderPassColorAttachment {
        view,
        depth_slice: None,
        resolve_target: None,
        ops: wgpu::Operations {
            load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
            store: wgpu::StoreOp::Store,
        },
    }
}

/// A depth attachment cleared to the far plane and stored.
pub(crate) fn cleared_depth(view: &wgpu::TextureView) -> wgpu::RenderPassDepthStencilAttachment<'_> {
    wgpu::RenderPassDepthStencilAttachment {
        view,
        depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Store }),
        stencil_ops: None,
    }
}

/// Depth test and write with `Less` into a `Depth32Float` attachment.
pub(crate) fn depth_less() -> wgpu::DepthStencilState {
    wgpu::DepthStencilState {
        format: wgpu::TextureFormat::Depth32Float,
        depth_write_enabled: Some(true),
        depth_compare: Some(wgpu::CompareFunction::Less),
        stencil: wgpu::StencilState::default(),
        bias: wgpu::DepthBiasState::default(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Size and (member, offset) of WGSL struct `name` in `source` by naga's layout rules (what
    /// the GPU reads), padding members (`_pad...`) left out.
    fn wgsl_struct(source: &str, name: &str) -> (u32, Vec<(String, u32)>) {
        let module = naga::front::wgsl::parse_str(source).unwrap_or_else(|e| panic!("{name}: {e}"));
        let mut layouter = naga::proc::Layouter::default();
        layouter.update(module.to_ctx()).expect("naga lays the module out");
        let (handle, ty) = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("no struct {name} in the WGSL"));
        let naga::TypeInner::Struct { members, .. } = &ty.inner else { panic!("{name} is not a struct") };
        let fields = members
            .iter()
            .filter_map(|m| m.name.clone().filter(|n| !n.starts_with('_')).map(|n| (n, m.offset)))
            .collect();
        (layouter[handle].size, fields)
    }

    /// Size and (field, offset) of a Rust GPU struct, its `pad` fields left out.
    macro_rules! rust_struct {
        ($t:ty; $($field:ident),*) => {
            (
                size_of::<$t>() as u32,
                vec![$((stringify!($field).to_owned(), std::mem::offset_of!($t, $field) as u32)),*],
            )
        };
    }

    #[test]
    fn every_gpu_struct_matches_its_wgsl_twin_in_size_and_field_offsets() {
        use super::blur::BlurUniformsGpu;
        use super::cell_transfer::TransferUniformsGpu;
        use super::gbuffer::FrameUniformsGpu;
        use super::shade::{LightGpu, ShadeUniformsGpu};
        use super::shadow_map::ShadowUniformsGpu;
        use super::shell_gpu::{SurfaceVertexGpu, TetraGpu};
        use super::tone_map::ToneMapUniformsGpu;
        use super::top_surface::TopSurfaceUniformsGpu;
        use super::visibility::VisibilityUniformsGpu;
        use crate::fabric_data::{ExemplarGpu, FabricHeaderGpu, MaterialGpu, SegmentGpu};

        let gbuffer = pass_source("gbuffer.wgsl");
        let shade = pass_source("shade.wgsl");
        let transfer = pass_source("transfer.wgsl");
        let shared = shaders::shared_library();
        let cases = [
            (
                "FrameUniforms",
                &gbuffer,
                rust_struct!(FrameUniformsGpu; clip_from_world, eye, jitter, fabric_z, film),
            ),
            ("TetraGpu", &gbuffer, rust_struct!(TetraGpu; uvw_from_world, planes, neighbors)),
            ("TetraGpu", &shade, rust_struct!(TetraGpu; uvw_from_world, planes, neighbors)),
            ("TransferUniforms", &transfer, rust_struct!(TransferUniformsGpu; counts, uvw_from_world)),
            ("SurfaceVertex", &shared, rust_struct!(SurfaceVertexGpu; position, uvw)),
            (
                "ShadowUniforms",
                &pass_source("shadow_map.wgsl"),
                rust_struct!(ShadowUniformsGpu; light_clip_from_world),
            ),
            (
                "TopSurfaceUniforms",
                &pass_source("top_surface.wgsl"),
                rust_struct!(TopSurfaceUniformsGpu; uv_rect),
            ),
            (
                "VisibilityUniforms",
                &pass_source("visibility.wgsl"),
                rust_struct!(VisibilityUniformsGpu; light_clip_from_world, filters, slope_limits, info),
            ),
            ("BlurUniforms", &pass_source("blur.wgsl"), rust_struct!(BlurUniformsGpu; axis)),
            (
                "LightGpu",
                &shade,
                rust_struct!(LightGpu; direction, kind, color, sharpness, layer, w_sum_of_sg, w_ssdf_erf),
            ),
            ("ShadeUniforms", &shade, rust_struct!(ShadeUniformsGpu; counts, eye, uv_rect, fabric)),
            ("ToneMapUniforms", &pass_source("tonemap.wgsl"), rust_struct!(ToneMapUniformsGpu; size, scale)),
            (
                "FabricHeader",
                &shared,
                rust_struct!(FabricHeaderGpu; exemplar_count, sh_order, sh_count, svf_resolution,
                    pca_components, sos_count, sos_sharpness, cs_theta_count, cg_points, gn_intervals,
                    pattern_width, pattern_height, block_size, z_range, cg_order, visibility_points, visibility_words,
                    lobe_table_vec4s),
            ),
            (
                "ExemplarGpu",
                &shared,
                rust_struct!(ExemplarGpu; volume_origin, voxel_offset, voxel_size, periodic, volume_dims,
                    segment_offset, period, pca_offset, segment_count, cell_origin, cell_offset, cell_size,
                    cell_blocks_x, cell_dims, cell_blocks_y),
            ),
            (
                "SegmentGpu",
                &shared,
                rust_struct!(SegmentGpu; direction, material, midpoint, half_length, cell, sos_rotation, radius, segment_cell),
            ),
            (
                "MaterialGpu",
                &shared,
                rust_struct!(MaterialGpu; c_r, model, c_tt, beta_r, albedo, beta_tt, gamma_tt),
            ),
        ];
        for (name, source, rust) in cases {
            assert_eq!(wgsl_struct(source, name), rust, "{name}: WGSL (naga) against Rust");
        }
    }

    #[test]
    fn every_pass_of_a_plan_has_a_shading_variant_only_where_it_shades() {
        use crate::plan::{Components, FramePlan, PlanInputs, PlanLight};
        let inputs = PlanInputs {
            flat_normal: None,
            components: Components::All,
            sigma_glo_cm: 0.05,
            spp: 2,
            uniform_frame: false,
            fiber_lobes: false,
        };
        let lights = [
            PlanLight::Directional { to_light: [0.0, 0.6, 0.8] },
            PlanLight::Sg { axis: [0.0, 0.0, 1.0], sharpness: 150.0 },
        ];
        let plan = FramePlan::new(&lights, &inputs);
        let variants: Vec<_> = plan.passes().iter().filter_map(shade::ShadeVariant::of).collect();
        assert_eq!(variants.len(), 1, "{plan}");
        let v = variants[0];
        // The blended SG light needs both SG paths; the directional light the SSDF sign; the
        // curved shell's shadow maps the global visibility; no cell transfer with shadows.
        assert!(v.single && v.multiple && v.ssdf_sign && v.sum_of_sg && v.ssdf_erf);
        assert!(v.global_visibility && !v.frame_transfer && !v.fiber_lobes);
        // Exactly what the plan's own switches say.
        assert_eq!(v.ssdf_sign, plan.uses(crate::plan::LocalVisibility::SsdfSign));
        assert_eq!(v.sum_of_sg, plan.uses(crate::plan::LocalVisibility::SumOfSg));
        assert_eq!(v.ssdf_erf, plan.uses(crate::plan::LocalVisibility::SsdfErf));
        let flat = PlanInputs { flat_normal: Some([0.0, 0.0, 1.0]), uniform_frame: true, ..inputs };
        let single = PlanInputs { components: Components::SingleOnly, ..flat };
        for (inputs, transfer) in [(flat, true), (single, false)] {
            let plan = FramePlan::new(&lights, &inputs);
            let v = plan.passes().iter().find_map(shade::ShadeVariant::of).unwrap();
            assert!(!v.global_visibility);
            assert_eq!(v.frame_transfer, transfer, "{plan}");
        }
    }
}
