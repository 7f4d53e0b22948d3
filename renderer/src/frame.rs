//! The GPU frame: shell-mapped volume ray casting, SG single scattering, SH multiple
//! scattering and shadow mapping (paper section 5), run pass by pass as the frame plan says.
//!
//! How it works: [`Renderer::new`] uploads the shell (tetrahedra with their world → shell affine
//! maps, face planes and neighbours, and the top and bottom surfaces) next to an uploaded bake
//! ([`FabricData`]) and builds the fixed pipelines. [`Renderer::render`] plans the frame
//! ([`FramePlan`]) and records, in order:
//! 1. a depth-only shadow map per shadowing light (orthographic, fitted to the shell's bounding
//!    sphere), into one layer of a depth array;
//! 2. the top-surface position texture X[u, v], rasterizing the top surface in shell space;
//! 3. the visibility V[u, v] per light (PCF or PCSS lookups at X), stored as
//!    (V · coverage, coverage);
//! 4. its Gaussian blur by σ_glo (separable, along u then v);
//! 5. when every pixel receives the same light SH (a shell with one flat-fabric frame and no
//!    shadow maps: the flat swatch), the light arriving in every IIRTF cell, A c_in, once for
//!    the frame (shaders/transfer.wgsl), which the shading pass then interpolates instead of
//!    multiplying eight transfer matrices per pixel;
//! 6. per sample: the G-buffer (the shell's surface faces where eye rays enter it; each
//!    fragment walks its ray through the tetrahedra, stepping voxel by voxel to the first
//!    occupied voxel; jittered sub-pixel position), then the shading pass, which adds radiance
//!    to an accumulation buffer;
//! 7. tone mapping with exposure into an 8-bit image.
//!
//! Passes 1–5 run once per frame (they do not depend on the pixel jitter); 1–4 only when the plan
//! has shadow maps, 5 only when it has none and the shell one frame. Passes 1–4 do not depend on
//! the camera either: their result is kept and reused by the next frame while the lights, the
//! plan's shadow filters, the GPU settings and the shell are the same ([`ShellVisibility`]), so
//! progressive batches and camera moves skip them. The shading pipeline is specialized by override
//! constants from the plan, so a local-visibility path no light needs is not compiled. With
//! `TIMESTAMP_QUERY` each pass is timed on the GPU; [`Frame::timings`] sums them per pass.
//!
//! PCSS for SG lights needs a light size, which an SG does not have; we use the angle α at which
//! the lobe falls to 1/e of its peak, `cos α = 1 − 1/λ` (α ≈ sqrt(2/λ) for sharp lobes; α = 90°
//! for λ ≤ 1), and the penumbra a blocker at distance Δ casts is `2 Δ tan α`, capped at 60°.

use std::collections::HashMap;
use std::fmt::Write as _;

use glam::camera::rh::proj::directx::{orthographic, perspective};
use glam::camera::rh::view::look_at_mat4;
use glam::{DVec3, Mat4, Vec3};
use twill_precompute::pathtrace::Light;
use twill_precompute::scene::{CameraSection, GpuSection, ProjectionKind};
use twill_precompute::shading::sg_path_weights;

use crate::fabric_data::{FabricData, make_buffer};
use crate::gpu::Gpu;
use crate::plan::{Components, FramePlan, GlobalVisibility, LocalVisibility, Pass, PlanInputs, PlanLight};
use crate::shaders;
use crate::shell::Shell;

/// Most lights with a shadow map in one frame.
pub const MAX_SHADOWED_LIGHTS: usize = 8;
/// Most lights in one frame.
pub const MAX_LIGHTS: usize = 64;
/// End of the sample sequence [`Renderer::render_samples`] can continue (exclusive).
pub const MAX_SAMPLE_INDEX: u32 = 1 << 24;
/// Largest SG light angle used for PCSS penumbrae.
const MAX_PCSS_ANGLE_DEG: f64 = 60.0;

/// Why a frame could not be rendered.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("invalid render setting: {0}")]
    Settings(String),
    #[error("the adapter {adapter:?} cannot run the renderer: {what} is {have}, the renderer needs {need}")]
    Limit { adapter: String, what: &'static str, have: u64, need: u64 },
    #[error("GPU error in {label}: {message}")]
    Gpu { label: String, message: String },
    #[error(transparent)]
    Readback(#[from] crate::gpu::GpuError),
    #[error(transparent)]
    Fabric(#[from] crate::fabric_data::FabricDataError),
}

/// Per-frame settings.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameSettings {
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    /// Exposure in stops for the display image.
    pub exposure: f64,
    /// Filmic (true) or clamp (false) tone curve for the display image.
    pub filmic: bool,
    pub components: Components,
    pub gpu: GpuSection,
    /// Compute each cell's transferred light once per frame where every pixel receives the same
    /// light SH (one flat-fabric frame, no shadow maps); `false` forces the per-pixel product
    /// (the two agree to f32 rounding; tests compare them).
    pub frame_transfer: bool,
}

/// Time one pass took, summed over the frame's samples.
#[derive(Debug, Clone, PartialEq)]
pub struct PassTiming {
    pub pass: String,
    pub milliseconds: f64,
}

/// A rendered frame, read back.
#[derive(Debug, Clone)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    /// Linear radiance per pixel, row-major from the top-left.
    pub radiance: Vec<[f32; 3]>,
    /// Tone-mapped sRGB, RGBA8.
    pub display: Vec<[u8; 4]>,
    pub plan: FramePlan,
    /// GPU time per pass, when the adapter has timestamp queries.
    pub timings: Option<Vec<PassTiming>>,
    /// Passes of the plan this frame did not run because it reused an earlier frame's result
    /// (shell-space visibility: shadow maps, X, V, blur), by their plan names.
    pub reused: Vec<String>,
}

impl Frame {
    /// The linear radiance as an f64 image (for comparisons with CPU renders).
    #[must_use]
    pub fn radiance_image(&self) -> twill_precompute::image::Image {
        twill_precompute::image::Image {
            width: self.width as usize,
            height: self.height as usize,
            pixels: self.radiance.iter().map(|p| glam::DVec3::from_array(p.map(f64::from))).collect(),
        }
    }
}

/// Twin of `FrameUniforms` in shaders/gbuffer.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FrameUniformsGpu {
    clip_from_world: [[f32; 4]; 4],
    eye: [f32; 4],
    jitter: [f32; 4],
    fabric_z: [f32; 4],
    /// x: for an orthographic camera, where its film plane lies along the viewing direction
    /// (`dot(eye, view)`): eye rays start there, as the path tracer's do. Unused for perspective.
    film: [f32; 4],
}
const _: () = assert!(size_of::<FrameUniformsGpu>() == 128);

/// Twin of `TransferUniforms` in shaders/transfer.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TransferUniformsGpu {
    counts: [u32; 4],
    /// Rows of the shell's common world → uvw linear map; `[0][3]` the slab thickness (cm).
    uvw_from_world: [[f32; 4]; 3],
}
const _: () = assert!(size_of::<TransferUniformsGpu>() == 64);

/// Twin of `TetraGpu` in shaders/gbuffer.wgsl and shaders/shade.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TetraGpu {
    uvw_from_world: [[f32; 4]; 3],
    planes: [[f32; 4]; 4],
    /// The tetrahedron across the face opposite each corner ([`crate::shell::NO_NEIGHBOR`] on
    /// the shell's surface).
    neighbors: [u32; 4],
}
const _: () = assert!(size_of::<TetraGpu>() == 128);

/// Twin of `SurfaceVertex` in shaders/shell_surface.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SurfaceVertexGpu {
    position: [f32; 4],
    uvw: [f32; 4],
}

/// Twin of `SurfaceUniforms` in shaders/shell_surface.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SurfaceUniformsGpu {
    light_clip_from_world: [[[f32; 4]; 4]; MAX_SHADOWED_LIGHTS],
    uv_rect: [f32; 4],
}

/// Twin of `VisibilityUniforms` in shaders/visibility.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct VisibilityUniformsGpu {
    light_clip_from_world: [[[f32; 4]; 4]; MAX_SHADOWED_LIGHTS],
    filters: [[f32; 4]; MAX_SHADOWED_LIGHTS],
    info: [f32; 4],
}

/// Twin of `BlurUniforms` in shaders/blur.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BlurUniformsGpu {
    axis: [f32; 4],
}

/// Twin of `LightGpu` in shaders/shade.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct LightGpu {
    direction: [f32; 3],
    kind: u32,
    color: [f32; 3],
    sharpness: f32,
    layer: i32,
    w_sum_of_sg: f32,
    w_ssdf_erf: f32,
    pad: f32,
}
const _: () = assert!(size_of::<LightGpu>() == 48);

/// Twin of `ShadeUniforms` in shaders/shade.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ShadeUniformsGpu {
    counts: [u32; 4],
    eye: [f32; 4],
    uv_rect: [f32; 4],
    fabric: [f32; 4],
}

/// Twin of `ToneMapUniforms` in shaders/tonemap.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ToneMapUniformsGpu {
    size: [u32; 4],
    scale: [f32; 4],
}

/// The shell on the GPU.
struct ShellGpu {
    tetra_corners: wgpu::Buffer,
    tetras: wgpu::Buffer,
    /// The shell's surface faces, `tetrahedron * 4 + k` for the face opposite corner `k`: what
    /// the G-buffer pass rasterizes.
    surface_faces: wgpu::Buffer,
    surface_face_count: u32,
    /// The rows of the world → uvw map's linear part when every tetrahedron has the same one
    /// (within [`UNIFORM_FRAME_TOLERANCE`]): the flat swatch.
    uniform_frame: Option<[[f32; 4]; 3]>,
    surface_vertices: wgpu::Buffer,
    /// Top-surface vertices come first in `surface_vertices`.
    top_vertex_count: u32,
    surface_vertex_count: u32,
    uv_rect: [f32; 4],
    bounds: (Vec3, Vec3),
    flat_normal: Option<Vec3>,
}

/// Which terms the shading pipeline is compiled with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[allow(clippy::struct_excessive_bools)]
struct ShadeVariant {
    single: bool,
    multiple: bool,
    ssdf_sign: bool,
    sum_of_sg: bool,
    ssdf_erf: bool,
    global_visibility: bool,
    frame_transfer: bool,
}

/// Shell-space visibility V[u, v] of a frame with shadow maps (passes 1–4), and a hash of what
/// it depends on: the lights, the plan's shadow filters, the GPU settings and the shell. It does
/// not depend on the camera or the sample, so progressive batches and camera moves reuse it.
struct ShellVisibility {
    key: u64,
    sharp: wgpu::Texture,
    blurred: wgpu::Texture,
}

/// The textures and buffers a frame of one size renders into and reads back from: the
/// G-buffer, the display image, the accumulation buffer and the two readback buffers. The
/// renderer keeps one set and makes a new one only when the size changes (the accumulation
/// buffer is cleared by every frame; the readback buffers are unmapped after every read).
#[derive(Clone)]
struct FrameTargets {
    size: (u32, u32),
    position: wgpu::Texture,
    ids: wgpu::Texture,
    depth: wgpu::Texture,
    display: wgpu::Texture,
    accumulation: wgpu::Buffer,
    radiance_readback: wgpu::Buffer,
    display_readback: wgpu::Buffer,
}

/// Bytes per row of the display image's readback (rows padded to wgpu's copy alignment).
fn display_row_bytes(width: u32) -> u32 {
    (width * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
}

impl FrameTargets {
    fn new(device: &wgpu::Device, width: u32, height: u32) -> Self {
        let target = |label: &str, format: wgpu::TextureFormat, usage: wgpu::TextureUsages| {
            texture_2d(device, label, [width, height, 1], format, usage)
        };
        let attach = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
        let pixels = u64::from(width) * u64::from(height);
        Self {
            size: (width, height),
            position: target("twill.gbuffer.position", wgpu::TextureFormat::Rgba32Float, attach),
            ids: target("twill.gbuffer.ids", wgpu::TextureFormat::Rgba32Uint, attach),
            depth: target(
                "twill.gbuffer.depth",
                wgpu::TextureFormat::Depth32Float,
                wgpu::TextureUsages::RENDER_ATTACHMENT,
            ),
            display: target(
                "twill.display",
                wgpu::TextureFormat::Rgba8Unorm,
                wgpu::TextureUsages::STORAGE_BINDING
                    | wgpu::TextureUsages::COPY_SRC
                    | wgpu::TextureUsages::TEXTURE_BINDING,
            ),
            accumulation: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("twill.accumulation"),
                size: pixels * 16,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            radiance_readback: readback_buffer(device, "twill.readback.radiance", pixels * 16),
            display_readback: readback_buffer(
                device,
                "twill.readback.display",
                u64::from(display_row_bytes(width)) * u64::from(height),
            ),
        }
    }
}

/// Shell-mapped fabric renderer on one device.
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    fabric: FabricData,
    shell: ShellGpu,
    fabric_z: [f32; 2],
    gbuffer_layout: wgpu::BindGroupLayout,
    gbuffer_pipeline: wgpu::RenderPipeline,
    shadow_pipeline: wgpu::RenderPipeline,
    top_pipeline: wgpu::RenderPipeline,
    visibility_pipeline: wgpu::ComputePipeline,
    blur_pipeline: wgpu::ComputePipeline,
    tonemap_pipeline: wgpu::ComputePipeline,
    shade_layout: wgpu::BindGroupLayout,
    transfer_layout: wgpu::BindGroupLayout,
    transfer_pipeline: wgpu::ComputePipeline,
    /// Bumped by every [`Renderer::set_shell`]: part of what shell-space visibility depends on.
    shell_generation: u64,
    /// The last frame's shell-space visibility, reused while what it depends on is unchanged.
    shell_visibility: Option<ShellVisibility>,
    shade_pipelines: HashMap<ShadeVariant, wgpu::ComputePipeline>,
    /// The last frame's targets, reused by the next frame of the same size.
    frame_targets: Option<FrameTargets>,
    timestamps: bool,
}

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

fn texture_entry(
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
fn pass_source(file: &str) -> String {
    shaders::compose(file).unwrap_or_else(|e| panic!("twill's own shaders compose: {e}"))
}

fn shader_module(device: &wgpu::Device, label: &str, source: String) -> wgpu::ShaderModule {
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    })
}

/// A 2D texture (or array of `layers`) with one mip level and one sample.
fn texture_2d(
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

/// A view of every layer of a texture as a 2D array.
fn array_view(texture: &wgpu::Texture) -> wgpu::TextureView {
    texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    })
}

fn compute_pipeline(
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

/// (world → uvw rows, face planes in uvw, neighbours) of one tetrahedron.
fn tetra_gpu(corners: &[crate::shell::ShellVertex; 4], neighbors: [u32; 4]) -> TetraGpu {
    let (uvw_from_world, _) = Shell::tetra_affine(corners);
    let rows = [uvw_from_world.row(0), uvw_from_world.row(1), uvw_from_world.row(2)];
    let uvw: Vec<DVec3> = corners.iter().map(|c| c.uvw.as_dvec3()).collect();
    let mut planes = [[0.0_f32; 4]; 4];
    for (i, plane) in planes.iter_mut().enumerate() {
        let others: Vec<DVec3> = (0..4).filter(|&k| k != i).map(|k| uvw[k]).collect();
        let mut n = (others[1] - others[0]).cross(others[2] - others[0]);
        if n.dot(uvw[i] - others[0]) < 0.0 {
            n = -n;
        }
        let scale = 1.0 / n.length().max(1e-30);
        let n = n * scale;
        *plane = [n.x as f32, n.y as f32, n.z as f32, (-n.dot(others[0])) as f32];
    }
    TetraGpu { uvw_from_world: rows.map(|r| r.to_array()), planes, neighbors }
}

/// Largest difference, relative to the row's length, between two tetrahedra's linear maps that
/// still counts as one frame (f32 rounding of maps computed per tetrahedron: ~1e-7).
const UNIFORM_FRAME_TOLERANCE: f32 = 1e-5;

/// The linear part of the world → uvw map shared by every tetrahedron, if they share one.
fn uniform_frame(tetras: &[TetraGpu]) -> Option<[[f32; 4]; 3]> {
    let first = tetras.first()?;
    let rows = first.uvw_from_world.map(|r| glam::Vec3::new(r[0], r[1], r[2]));
    let same = tetras.iter().all(|t| {
        (0..3).all(|i| {
            let row = glam::Vec3::new(t.uvw_from_world[i][0], t.uvw_from_world[i][1], t.uvw_from_world[i][2]);
            (row - rows[i]).length() <= UNIFORM_FRAME_TOLERANCE * rows[i].length()
        })
    });
    same.then(|| rows.map(|r| r.extend(0.0).to_array()))
}

fn upload_shell(device: &wgpu::Device, queue: &wgpu::Queue, shell: &Shell) -> ShellGpu {
    let corners: Vec<[f32; 4]> =
        shell.tetrahedra.iter().flat_map(|t| t.iter().map(|v| v.position.extend(1.0).to_array())).collect();
    let neighbors = shell.tetra_neighbors();
    let tetras: Vec<TetraGpu> = shell
        .tetrahedra
        .iter()
        .zip(&neighbors)
        .map(|(corners, &across)| tetra_gpu(corners, across))
        .collect();
    let surface_faces: Vec<u32> = neighbors
        .iter()
        .enumerate()
        .flat_map(|(t, across)| {
            (0..4_u32)
                .filter(|&k| across[k as usize] == crate::shell::NO_NEIGHBOR)
                .map(move |k| t as u32 * 4 + k)
        })
        .collect();
    let vertex = |v: &crate::shell::ShellVertex| SurfaceVertexGpu {
        position: v.position.extend(1.0).to_array(),
        uvw: v.uvw.extend(0.0).to_array(),
    };
    let mut surface: Vec<SurfaceVertexGpu> = shell.top_triangles.iter().flatten().map(vertex).collect();
    let top_vertex_count = surface.len() as u32;
    surface.extend(shell.bottom_triangles.iter().flatten().map(vertex));
    let usage = wgpu::BufferUsages::STORAGE;
    let uv_size = (shell.uv_max - shell.uv_min).max(glam::Vec2::splat(1e-6));
    ShellGpu {
        tetra_corners: make_buffer(
            device,
            queue,
            "twill.shell.tetra_corners",
            bytemuck::cast_slice(&corners),
            usage,
        ),
        tetras: make_buffer(device, queue, "twill.shell.tetras", bytemuck::cast_slice(&tetras), usage),
        surface_faces: make_buffer(
            device,
            queue,
            "twill.shell.surface_faces",
            bytemuck::cast_slice(&surface_faces),
            usage,
        ),
        surface_face_count: surface_faces.len() as u32,
        uniform_frame: uniform_frame(&tetras),
        surface_vertices: make_buffer(
            device,
            queue,
            "twill.shell.surface_vertices",
            bytemuck::cast_slice(&surface),
            usage,
        ),
        top_vertex_count,
        surface_vertex_count: surface.len() as u32,
        uv_rect: [shell.uv_min.x, shell.uv_min.y, uv_size.x, uv_size.y],
        bounds: (shell.bounds_min, shell.bounds_max),
        flat_normal: if shell.is_flat { shell.flat_normal } else { None },
    }
}

/// The renderer needs this many storage buffers in one shader stage (shading pass).
const STORAGE_BUFFERS_NEEDED: u32 = 17;

impl Renderer {
    /// Uploads the shell and builds the pipelines. `fabric` must come from the same device.
    pub fn new(gpu: &Gpu, fabric: FabricData, shell: &Shell) -> Result<Self, RenderError> {
        let device = gpu.device.clone();
        let queue = gpu.queue.clone();
        let limits = device.limits();
        if limits.max_storage_buffers_per_shader_stage < STORAGE_BUFFERS_NEEDED {
            return Err(RenderError::Limit {
                adapter: gpu.adapter_info.name.clone(),
                what: "max_storage_buffers_per_shader_stage",
                have: u64::from(limits.max_storage_buffers_per_shader_stage),
                need: u64::from(STORAGE_BUFFERS_NEEDED),
            });
        }
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let shell_gpu = upload_shell(&device, &queue, shell);
        let header = fabric.arrays.header;
        let fabric_z = [header.z_range[0], header.z_range[1] - header.z_range[0]];

        let fragment = wgpu::ShaderStages::VERTEX_FRAGMENT;
        let gbuffer_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("twill.gbuffer.bind_group_layout"),
            entries: &[
                uniform_entry(0, fragment),
                storage_entry(1, fragment, true),
                storage_entry(2, fragment, true),
                storage_entry(3, fragment, true),
            ],
        });
        let gbuffer_pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("twill.gbuffer.pipeline_layout"),
            bind_group_layouts: &[Some(&gbuffer_layout), Some(&fabric.layout)],
            immediate_size: 0,
        });
        let gbuffer_module = shader_module(&device, "twill.gbuffer.shader", pass_source("gbuffer.wgsl"));
        let gbuffer_pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("twill.gbuffer.pipeline"),
            layout: Some(&gbuffer_pipeline_layout),
            vertex: wgpu::VertexState {
                module: &gbuffer_module,
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
            depth_stencil: Some(wgpu::DepthStencilState {
                format: wgpu::TextureFormat::Depth32Float,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState::default(),
            }),
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &gbuffer_module,
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

        let surface_module =
            shader_module(&device, "twill.shell_surface.shader", pass_source("shell_surface.wgsl"));
        let shadow_pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("twill.shadow.pipeline"),
            layout: None,
            vertex: wgpu::VertexState {
                module: &surface_module,
                entry_point: Some("vs_shadow"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: Some(wgpu::DepthStencilState {
                format: wgpu::TextureFormat::Depth32Float,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState::default(),
            }),
            multisample: wgpu::MultisampleState::default(),
            fragment: None,
            multiview_mask: None,
            cache: None,
        });
        let top_pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("twill.top_surface.pipeline"),
            layout: None,
            vertex: wgpu::VertexState {
                module: &surface_module,
                entry_point: Some("vs_top"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &surface_module,
                entry_point: Some("fs_top"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                targets: &[Some(wgpu::TextureFormat::Rgba32Float.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        let visibility_module =
            shader_module(&device, "twill.visibility.shader", pass_source("visibility.wgsl"));
        let visibility_pipeline =
            compute_pipeline(&device, "twill.visibility.pipeline", &visibility_module, None, &[]);
        let blur_module = shader_module(&device, "twill.blur.shader", pass_source("blur.wgsl"));
        let blur_pipeline = compute_pipeline(&device, "twill.blur.pipeline", &blur_module, None, &[]);
        let tonemap_module = shader_module(&device, "twill.tonemap.shader", pass_source("tonemap.wgsl"));
        let tonemap_pipeline =
            compute_pipeline(&device, "twill.tonemap.pipeline", &tonemap_module, None, &[]);

        let compute = wgpu::ShaderStages::COMPUTE;
        let float = wgpu::TextureSampleType::Float { filterable: false };
        let array = wgpu::TextureViewDimension::D2Array;
        let plain = wgpu::TextureViewDimension::D2;
        let shade_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("twill.shade.bind_group_layout"),
            entries: &[
                uniform_entry(0, compute),
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
        let transfer_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("twill.transfer.bind_group_layout"),
            entries: &[
                uniform_entry(0, compute),
                storage_entry(1, compute, true),
                storage_entry(2, compute, false),
            ],
        });
        let transfer_pipeline = {
            let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("twill.transfer.pipeline_layout"),
                bind_group_layouts: &[Some(&transfer_layout), Some(&fabric.layout)],
                immediate_size: 0,
            });
            let module = shader_module(&device, "twill.transfer.shader", pass_source("transfer.wgsl"));
            compute_pipeline(&device, "twill.transfer.pipeline", &module, Some(&layout), &[])
        };
        if let Some(error) = pollster::block_on(scope.pop()) {
            return Err(RenderError::Gpu { label: "pipeline setup".into(), message: error.to_string() });
        }
        let timestamps = device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        Ok(Self {
            device,
            queue,
            adapter: gpu.describe(),
            fabric,
            shell: shell_gpu,
            fabric_z,
            gbuffer_layout,
            gbuffer_pipeline,
            shadow_pipeline,
            top_pipeline,
            visibility_pipeline,
            blur_pipeline,
            tonemap_pipeline,
            shade_layout,
            transfer_layout,
            transfer_pipeline,
            shell_generation: 0,
            shell_visibility: None,
            shade_pipelines: HashMap::new(),
            frame_targets: None,
            timestamps,
        })
    }

    /// The adapter this renderer runs on, in words.
    #[must_use]
    pub fn adapter(&self) -> &str {
        &self.adapter
    }

    /// Bytes of GPU memory held by the bake and the shell (not counting per-frame targets).
    #[must_use]
    pub fn resident_bytes(&self) -> u64 {
        self.fabric.gpu_bytes
            + self.shell.tetra_corners.size()
            + self.shell.tetras.size()
            + self.shell.surface_faces.size()
            + self.shell.surface_vertices.size()
    }

    /// The uploaded fabric.
    #[must_use]
    pub fn fabric(&self) -> &FabricData {
        &self.fabric
    }

    /// The shell's world-space bounding box (min, max corners), e.g. to fit a camera to it.
    #[must_use]
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.shell.bounds
    }

    /// Plans a frame for these lights and settings.
    #[must_use]
    pub fn plan(&self, lights: &[Light], settings: &FrameSettings) -> FramePlan {
        plan_frame(lights, settings, self.shell.flat_normal, self.shell.uniform_frame.is_some())
    }

    fn shade_pipeline(&mut self, variant: ShadeVariant) -> &wgpu::ComputePipeline {
        let device = &self.device;
        let (shade_layout, fabric_layout) = (&self.shade_layout, &self.fabric.layout);
        self.shade_pipelines.entry(variant).or_insert_with(|| {
            let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("twill.shade.pipeline_layout"),
                bind_group_layouts: &[Some(shade_layout), Some(fabric_layout)],
                immediate_size: 0,
            });
            let module = shader_module(device, "twill.shade.shader", pass_source("shade.wgsl"));
            let flag = |b: bool| if b { 1.0 } else { 0.0 };
            let constants = [
                ("ENABLE_SINGLE", flag(variant.single)),
                ("ENABLE_MULTIPLE", flag(variant.multiple)),
                ("ENABLE_SSDF_SIGN", flag(variant.ssdf_sign)),
                ("ENABLE_SUM_OF_SG", flag(variant.sum_of_sg)),
                ("ENABLE_SSDF_ERF", flag(variant.ssdf_erf)),
                ("ENABLE_GLOBAL_VISIBILITY", flag(variant.global_visibility)),
                ("ENABLE_FRAME_TRANSFER", flag(variant.frame_transfer)),
            ];
            compute_pipeline(device, "twill.shade.pipeline", &module, Some(&layout), &constants)
        })
    }

    /// Records the once-per-frame cell transfer (shaders/transfer.wgsl) when the plan has it,
    /// and returns its output buffer (`cells × sh_count` vec4s); otherwise a one-element buffer
    /// the shading pass binds but does not read.
    fn encode_cell_transfer(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        plan: &FramePlan,
        lights: &wgpu::Buffer,
        light_count: usize,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) -> wgpu::Buffer {
        let usage = wgpu::BufferUsages::STORAGE;
        let frame = self.shell.uniform_frame.filter(|_| plan.cell_transfer);
        let Some(mut rows) = frame else {
            return make_buffer(&self.device, &self.queue, "twill.transfer.unused", &[0; 16], usage);
        };
        let cells = self.fabric.arrays.cell_flags.len() as u32;
        let sh_count = self.fabric.arrays.header.sh_count;
        rows[0][3] = self.fabric_z[1];
        let uniforms =
            TransferUniformsGpu { counts: [light_count as u32, cells, 0, 0], uvw_from_world: rows };
        let uniforms = make_buffer(
            &self.device,
            &self.queue,
            "twill.transfer.uniforms",
            bytemuck::bytes_of(&uniforms),
            wgpu::BufferUsages::UNIFORM,
        );
        let output = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("twill.transfer.cells"),
            size: (u64::from(cells.max(1)) * u64::from(sh_count) * 16).max(16),
            usage,
            mapped_at_creation: false,
        });
        let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("twill.transfer.bind_group"),
            layout: &self.transfer_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: uniforms.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: lights.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: output.as_entire_binding() },
            ],
        });
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("twill.transfer.pass"),
            timestamp_writes: timestamps,
        });
        pass.set_pipeline(&self.transfer_pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.set_bind_group(1, &self.fabric.bind_group, &[]);
        pass.dispatch_workgroups(cells.div_ceil(64), 1, 1);
        drop(pass);
        output
    }

    /// `settings` within the adapter's texture limit: an image larger than
    /// `max_texture_dimension_2d` is an error naming the limit; shadow maps and visibility
    /// textures larger than it are shrunk to it (logged), since they only lose sharpness.
    fn fit_to_adapter(&self, settings: &FrameSettings) -> Result<FrameSettings, RenderError> {
        let max_2d = self.device.limits().max_texture_dimension_2d;
        let side = settings.width.max(settings.height);
        if side > max_2d {
            return Err(RenderError::Limit {
                adapter: self.adapter.clone(),
                what: "max_texture_dimension_2d (the image's larger side)",
                have: u64::from(max_2d),
                need: u64::from(side),
            });
        }
        let mut fitted = settings.clone();
        for (name, size) in [
            ("shadow_map_size", &mut fitted.gpu.shadow_map_size),
            ("visibility_texture_size", &mut fitted.gpu.visibility_texture_size),
        ] {
            if *size > max_2d {
                log::warn!("{name} = {size} exceeds the adapter's max_texture_dimension_2d; using {max_2d}");
                *size = max_2d;
            }
        }
        Ok(fitted)
    }

    /// Replaces the base surface (a mesh edit): only the shell is uploaded again, the fabric
    /// stays. `shell` must span [`Renderer::fabric_z_range`] (see `headless::shell_for_mesh`).
    pub fn set_shell(&mut self, shell: &Shell) {
        self.shell = upload_shell(&self.device, &self.queue, shell);
        self.shell_generation += 1;
        self.shell_visibility = None;
    }

    /// What shell-space visibility depends on, hashed (see [`ShellVisibility`]).
    fn visibility_key(&self, lights: &[Light], plan: &FramePlan, settings: &FrameSettings) -> u64 {
        use std::hash::{Hash, Hasher};
        let mut hasher = std::collections::hash_map::DefaultHasher::new();
        let described = format!(
            "{lights:?}|{:?}|{}|{}|{:?}|{}",
            plan.lights, plan.blur, plan.sigma_glo_cm, settings.gpu, self.shell_generation
        );
        described.hash(&mut hasher);
        hasher.finish()
    }

    /// A new bake set written into the fabric's GPU buffers in place when its layout is the
    /// same ([`FabricData::update_in_place`]): no new buffers, bind groups, pipelines or shell,
    /// and shell-space visibility stays cached (it depends on the shell and lights only). What a
    /// material edit needs, in a fraction of a rebuild. Returns the buffers written, or `None`
    /// when the layout differs (build a new renderer).
    ///
    /// # Errors
    /// When the bake set cannot be packed.
    pub fn update_fabric(
        &mut self,
        exemplars: &[&twill_precompute::bake::pipeline::Baked],
        pattern: &twill_precompute::bake::pattern::PatternMap,
    ) -> Result<Option<Vec<&'static str>>, RenderError> {
        Ok(self.fabric.update_in_place(&self.queue, exemplars, pattern)?)
    }

    /// The baked fabric slab's depth range (cm), which a shell must span.
    #[must_use]
    pub fn fabric_z_range(&self) -> [f32; 2] {
        self.fabric.arrays.header.z_range
    }

    /// Renders one frame and reads it back.
    pub fn render(
        &mut self,
        camera: &CameraSection,
        lights: &[Light],
        settings: &FrameSettings,
    ) -> Result<Frame, RenderError> {
        self.render_samples(camera, lights, settings, 0)
    }

    /// As [`Renderer::render`], for samples `first_sample .. first_sample + settings.spp` of
    /// one longer sample sequence (the sub-pixel jitter continues where the previous frame
    /// stopped). The frame's `radiance` is the mean of its own samples, so a
    /// viewer that weights each frame by its `spp` and sums them gets the same image as one
    /// frame with all the samples: progressive rendering without keeping state on the GPU.
    /// `first_sample = 0` is exactly [`Renderer::render`].
    #[allow(clippy::too_many_lines)]
    pub fn render_samples(
        &mut self,
        camera: &CameraSection,
        lights: &[Light],
        settings: &FrameSettings,
        first_sample: u32,
    ) -> Result<Frame, RenderError> {
        validate(settings, lights)?;
        twill_precompute::scene::camera_from(camera, settings.width as usize, settings.height as usize)
            .map_err(|e| RenderError::Settings(e.to_string()))?;
        if first_sample.checked_add(settings.spp).is_none_or(|end| end > MAX_SAMPLE_INDEX) {
            return Err(RenderError::Settings(format!(
                "samples {first_sample}..{first_sample}+{}: the sequence ends at {MAX_SAMPLE_INDEX}",
                settings.spp
            )));
        }
        let settings = &self.fit_to_adapter(settings)?;
        let plan = self.plan(lights, settings);
        let (width, height) = (settings.width, settings.height);
        let device = self.device.clone();
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);

        let variant = ShadeVariant {
            single: plan.single,
            multiple: plan.multiple,
            ssdf_sign: plan.uses(LocalVisibility::SsdfSign),
            sum_of_sg: plan.uses(LocalVisibility::SumOfSg),
            ssdf_erf: plan.uses(LocalVisibility::SsdfErf),
            global_visibility: plan.shadow_maps,
            frame_transfer: plan.cell_transfer,
        };
        self.shade_pipeline(variant);
        let shade_pipeline = &self.shade_pipelines[&variant];
        // Shell-space visibility is reused from the previous frame when nothing it depends on
        // changed (a progressive batch, a camera move).
        let visibility_key = plan.shadow_maps.then(|| self.visibility_key(lights, &plan, settings));
        let cached_visibility = self
            .shell_visibility
            .as_ref()
            .filter(|cached| Some(cached.key) == visibility_key)
            .map(|cached| (cached.sharp.clone(), cached.blurred.clone()));
        let visibility_passes = cached_visibility.is_none() && plan.shadow_maps;

        // Queries: two per pass instance.
        let pass_instances = if visibility_passes { plan.shadow_layers() as usize } else { 0 }
            + if visibility_passes { 2 } else { 0 }
            + if visibility_passes && plan.blur { 2 } else { 0 }
            + usize::from(plan.cell_transfer)
            + 2 * settings.spp as usize
            + 1;
        let queries = self.timestamps.then(|| {
            device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("twill.frame.timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: (2 * pass_instances) as u32,
            })
        });
        let mut query_names: Vec<String> = Vec::new();
        let mut next_query = |name: &str| -> Option<u32> {
            queries.as_ref()?;
            query_names.push(name.to_owned());
            Some(2 * (query_names.len() as u32 - 1))
        };

        let mut encoder = device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("twill.frame.encoder") });

        // Shell-space visibility (once per frame).
        let layers = plan.shadow_layers().max(1);
        let vis_size = settings.gpu.visibility_texture_size;
        let vis_texture = |label: &str, usage: wgpu::TextureUsages| {
            texture_2d(&device, label, [vis_size, vis_size, layers], wgpu::TextureFormat::Rg32Float, usage)
        };
        let (vis_sharp, vis_blurred) = if let Some(cached) = cached_visibility {
            cached
        } else if plan.shadow_maps {
            let storage = wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::TEXTURE_BINDING;
            let sharp = vis_texture("twill.visibility.sharp", storage);
            let light_matrices = self.light_matrices(lights, &plan);
            self.encode_shadow_maps(
                &mut encoder,
                &plan,
                lights,
                &light_matrices,
                settings,
                &sharp,
                &mut next_query,
                queries.as_ref(),
            );
            let blurred = if plan.blur {
                let blurred = vis_texture("twill.visibility.blurred", storage);
                self.encode_blur(&mut encoder, &sharp, &blurred, settings, &mut next_query, queries.as_ref());
                blurred
            } else {
                sharp.clone()
            };
            (sharp, blurred)
        } else {
            let t = vis_texture("twill.visibility.none", wgpu::TextureUsages::TEXTURE_BINDING);
            (t.clone(), t)
        };

        // Frame targets, kept while the size stays (a progressive batch, a camera move).
        let targets = match &self.frame_targets {
            Some(kept) if kept.size == (width, height) => kept.clone(),
            _ => {
                let made = FrameTargets::new(&device, width, height);
                self.frame_targets = Some(made.clone());
                made
            }
        };
        let FrameTargets {
            position,
            ids,
            depth,
            display,
            accumulation,
            radiance_readback,
            display_readback,
            ..
        } = targets;
        let pixels = u64::from(width) * u64::from(height);
        encoder.clear_buffer(&accumulation, 0, None);

        // Camera and lights.
        let aspect = width as f32 / height as f32;
        let (clip_from_world, eye, film_plane) = camera_matrices(camera, aspect, self.shell.bounds);
        let frame_buffer = |jitter: [f32; 4]| {
            let uniforms = FrameUniformsGpu {
                clip_from_world: clip_from_world.to_cols_array_2d(),
                eye,
                jitter,
                fabric_z: [self.fabric_z[0], self.fabric_z[1], 0.0, 0.0],
                film: [film_plane, 0.0, 0.0, 0.0],
            };
            make_buffer(
                &device,
                &self.queue,
                "twill.gbuffer.uniforms",
                bytemuck::bytes_of(&uniforms),
                wgpu::BufferUsages::UNIFORM,
            )
        };
        let lights_gpu = Self::lights_gpu(lights, &plan);
        // The shader's `array<LightGpu>` binding needs room for one element even when the plan
        // dropped every light (all below a flat shell): a zeroed one, never read (count 0).
        let placeholder = [<LightGpu as bytemuck::Zeroable>::zeroed()];
        let lights_buffer = make_buffer(
            &device,
            &self.queue,
            "twill.shade.lights",
            bytemuck::cast_slice(if lights_gpu.is_empty() { &placeholder } else { &lights_gpu }),
            wgpu::BufferUsages::STORAGE,
        );
        let cell_transfer =
            self.encode_cell_transfer(&mut encoder, &plan, &lights_buffer, lights_gpu.len(), {
                let query = if plan.cell_transfer { next_query("cell transfer A c_in") } else { None };
                compute_timestamps(queries.as_ref(), query)
            });
        let shade_uniforms = ShadeUniformsGpu {
            counts: [lights_gpu.len() as u32, width, height, 0],
            eye,
            uv_rect: self.shell.uv_rect,
            fabric: [self.fabric_z[1], 0.0, 0.0, 0.0],
        };
        let shade_buffer = make_buffer(
            &device,
            &self.queue,
            "twill.shade.uniforms",
            bytemuck::bytes_of(&shade_uniforms),
            wgpu::BufferUsages::UNIFORM,
        );
        let view = |t: &wgpu::Texture| t.create_view(&wgpu::TextureViewDescriptor::default());
        let shade_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("twill.shade.bind_group"),
            layout: &self.shade_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: shade_buffer.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: lights_buffer.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: self.shell.tetras.as_entire_binding() },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::TextureView(&view(&position)),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::TextureView(&view(&ids)),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: wgpu::BindingResource::TextureView(&array_view(&vis_sharp)),
                },
                wgpu::BindGroupEntry {
                    binding: 6,
                    resource: wgpu::BindingResource::TextureView(&array_view(&vis_blurred)),
                },
                wgpu::BindGroupEntry { binding: 7, resource: accumulation.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 8, resource: cell_transfer.as_entire_binding() },
            ],
        });

        let (position_view, ids_view, depth_view) = (view(&position), view(&ids), view(&depth));
        for sample in 0..settings.spp {
            let index = first_sample + sample;
            let (jx, jy) = (halton(index + 1, 2) as f32, halton(index + 1, 3) as f32);
            let jitter = if settings.spp == 1 && first_sample == 0 {
                [0.0; 4]
            } else {
                [(2.0 * jx - 1.0) / width as f32, -(2.0 * jy - 1.0) / height as f32, 0.0, 0.0]
            };
            let uniforms = frame_buffer(jitter);
            let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("twill.gbuffer.bind_group"),
                layout: &self.gbuffer_layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: uniforms.as_entire_binding() },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: self.shell.tetra_corners.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry { binding: 2, resource: self.shell.tetras.as_entire_binding() },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: self.shell.surface_faces.as_entire_binding(),
                    },
                ],
            });
            let query = next_query("eye rays (G-buffer)");
            {
                let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("twill.gbuffer.pass"),
                    color_attachments: &[
                        Some(wgpu::RenderPassColorAttachment {
                            view: &position_view,
                            depth_slice: None,
                            resolve_target: None,
                            ops: wgpu::Operations {
                                load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                                store: wgpu::StoreOp::Store,
                            },
                        }),
                        Some(wgpu::RenderPassColorAttachment {
                            view: &ids_view,
                            depth_slice: None,
                            resolve_target: None,
                            ops: wgpu::Operations {
                                load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                                store: wgpu::StoreOp::Store,
                            },
                        }),
                    ],
                    depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                        view: &depth_view,
                        depth_ops: Some(wgpu::Operations {
                            load: wgpu::LoadOp::Clear(1.0),
                            store: wgpu::StoreOp::Store,
                        }),
                        stencil_ops: None,
                    }),
                    timestamp_writes: render_timestamps(queries.as_ref(), query),
                    occlusion_query_set: None,
                    multiview_mask: None,
                });
                pass.set_pipeline(&self.gbuffer_pipeline);
                pass.set_bind_group(0, &group, &[]);
                pass.set_bind_group(1, &self.fabric.bind_group, &[]);
                pass.draw(0..self.shell.surface_face_count * 3, 0..1);
            }
            let query = next_query("shading");
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("twill.shade.pass"),
                    timestamp_writes: compute_timestamps(queries.as_ref(), query),
                });
                pass.set_pipeline(shade_pipeline);
                pass.set_bind_group(0, &shade_group, &[]);
                pass.set_bind_group(1, &self.fabric.bind_group, &[]);
                pass.dispatch_workgroups(width.div_ceil(8), height.div_ceil(8), 1);
            }
        }

        if let Some(key) = visibility_key.filter(|_| visibility_passes) {
            let (sharp, blurred) = (vis_sharp.clone(), vis_blurred.clone());
            self.shell_visibility = Some(ShellVisibility { key, sharp, blurred });
        }

        // Tone mapping.
        let tone = ToneMapUniformsGpu {
            size: [width, height, u32::from(settings.filmic), 0],
            scale: [(settings.exposure.exp2() / f64::from(settings.spp)) as f32, 0.0, 0.0, 0.0],
        };
        let tone_buffer = make_buffer(
            &device,
            &self.queue,
            "twill.tonemap.uniforms",
            bytemuck::bytes_of(&tone),
            wgpu::BufferUsages::UNIFORM,
        );
        let tone_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("twill.tonemap.bind_group"),
            layout: &self.tonemap_pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: tone_buffer.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: accumulation.as_entire_binding() },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&view(&display)),
                },
            ],
        });
        let query = next_query("tone map");
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("twill.tonemap.pass"),
                timestamp_writes: compute_timestamps(queries.as_ref(), query),
            });
            pass.set_pipeline(&self.tonemap_pipeline);
            pass.set_bind_group(0, &tone_group, &[]);
            pass.dispatch_workgroups(width.div_ceil(8), height.div_ceil(8), 1);
        }

        // Readback.
        encoder.copy_buffer_to_buffer(&accumulation, 0, &radiance_readback, 0, pixels * 16);
        let row_bytes = display_row_bytes(width);
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &display,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &display_readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row_bytes),
                    rows_per_image: Some(height),
                },
            },
            wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
        );
        let query_count = 2 * query_names.len() as u32;
        let timing_readback = queries.as_ref().map(|set| {
            let resolve = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("twill.timestamps.resolve"),
                size: u64::from(query_count) * 8,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            encoder.resolve_query_set(set, 0..query_count, &resolve, 0);
            let readback = readback_buffer(&device, "twill.readback.timestamps", u64::from(query_count) * 8);
            encoder.copy_buffer_to_buffer(&resolve, 0, &readback, 0, u64::from(query_count) * 8);
            readback
        });
        self.queue.submit([encoder.finish()]);
        if let Some(error) = pollster::block_on(scope.pop()) {
            return Err(RenderError::Gpu { label: "frame".into(), message: error.to_string() });
        }

        let accumulated: Vec<[f32; 4]> = read_buffer(&device, &radiance_readback)?;
        let inv = 1.0 / settings.spp as f32;
        let radiance = accumulated.iter().map(|p| [p[0] * inv, p[1] * inv, p[2] * inv]).collect();
        let display_bytes: Vec<u8> = read_buffer(&device, &display_readback)?;
        let mut display_pixels = Vec::with_capacity(pixels as usize);
        for row in display_bytes.chunks_exact(row_bytes as usize) {
            display_pixels
                .extend(row[..(width * 4) as usize].chunks_exact(4).map(|p| [p[0], p[1], p[2], p[3]]));
        }
        let timings = match timing_readback {
            Some(buffer) => {
                let ticks: Vec<u64> = read_buffer(&device, &buffer)?;
                let period_ns = f64::from(self.queue.get_timestamp_period());
                let mut sums: Vec<PassTiming> = Vec::new();
                for (i, name) in query_names.iter().enumerate() {
                    let ms = ticks[2 * i + 1].saturating_sub(ticks[2 * i]) as f64 * period_ns * 1e-6;
                    match sums.iter_mut().find(|t| &t.pass == name) {
                        Some(t) => t.milliseconds += ms,
                        None => sums.push(PassTiming { pass: name.clone(), milliseconds: ms }),
                    }
                }
                Some(sums)
            }
            None => None,
        };
        let reused = if visibility_passes {
            Vec::new()
        } else {
            plan.passes()
                .iter()
                .filter(|p| {
                    matches!(
                        p,
                        Pass::ShadowMap { .. }
                            | Pass::TopSurface
                            | Pass::Visibility { .. }
                            | Pass::Blur { .. }
                    )
                })
                .map(Pass::name)
                .collect()
        };
        Ok(Frame { width, height, radiance, display: display_pixels, plan, timings, reused })
    }

    /// Orthographic light frusta fitted to the shell's bounding sphere.
    fn light_matrices(&self, lights: &[Light], plan: &FramePlan) -> Vec<(Mat4, f32, f32)> {
        let (lo, hi) = self.shell.bounds;
        let centre = 0.5 * (lo + hi);
        let radius = (0.5 * (hi - lo).length()).max(1e-3) * 1.05;
        plan.lights
            .iter()
            .filter(|l| l.shadow_layer.is_some())
            .map(|l| {
                let dir = light_direction(&lights[l.light]).as_vec3();
                let up = if dir.z.abs() < 0.9 { Vec3::Z } else { Vec3::X };
                let view = look_at_mat4(centre + dir * 2.0 * radius, centre, up);
                let proj = orthographic(-radius, radius, -radius, radius, 0.0, 4.0 * radius);
                (proj * view, 2.0 * radius, 4.0 * radius)
            })
            .collect()
    }

    #[allow(clippy::too_many_arguments)]
    fn encode_shadow_maps(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        plan: &FramePlan,
        lights: &[Light],
        matrices: &[(Mat4, f32, f32)],
        settings: &FrameSettings,
        visibility: &wgpu::Texture,
        next_query: &mut dyn FnMut(&str) -> Option<u32>,
        queries: Option<&wgpu::QuerySet>,
    ) {
        let device = &self.device;
        let size = settings.gpu.shadow_map_size;
        let layers = plan.shadow_layers();
        let shadow = texture_2d(
            device,
            "twill.shadow_maps",
            [size, size, layers],
            wgpu::TextureFormat::Depth32Float,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let mut surface = SurfaceUniformsGpu {
            light_clip_from_world: [[[0.0; 4]; 4]; MAX_SHADOWED_LIGHTS],
            uv_rect: self.shell.uv_rect,
        };
        let mut vis = VisibilityUniformsGpu {
            light_clip_from_world: [[[0.0; 4]; 4]; MAX_SHADOWED_LIGHTS],
            filters: [[0.0; 4]; MAX_SHADOWED_LIGHTS],
            info: [layers as f32, size as f32, matrices.first().map_or(1.0, |m| m.2), 0.0],
        };
        let shadowed: Vec<_> = plan.lights.iter().filter(|l| l.shadow_layer.is_some()).collect();
        for (k, (l, (matrix, width_cm, depth_cm))) in shadowed.iter().zip(matrices).enumerate() {
            surface.light_clip_from_world[k] = matrix.to_cols_array_2d();
            vis.light_clip_from_world[k] = matrix.to_cols_array_2d();
            let texel_cm = f64::from(*width_cm) / f64::from(size);
            let bias = settings.gpu.shadow_bias_texels * texel_cm / f64::from(*depth_cm);
            let penumbra_per_cm = match lights[l.light] {
                Light::Sg { sharpness, .. } => 2.0 * sg_light_angle(sharpness).tan() / texel_cm,
                Light::Directional { .. } => 0.0,
            };
            let filter = if l.global == GlobalVisibility::Pcss { 2.0 } else { 1.0 };
            vis.filters[k] =
                [filter, settings.gpu.pcf_radius_texels as f32, penumbra_per_cm as f32, bias as f32];
        }
        let surface_buffer = make_buffer(
            device,
            &self.queue,
            "twill.shell_surface.uniforms",
            bytemuck::bytes_of(&surface),
            wgpu::BufferUsages::UNIFORM,
        );
        let shadow_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("twill.shadow.bind_group"),
            layout: &self.shadow_pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: surface_buffer.as_entire_binding() },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: self.shell.surface_vertices.as_entire_binding(),
                },
            ],
        });
        for layer in 0..layers {
            let layer_view = shadow.create_view(&wgpu::TextureViewDescriptor {
                label: Some("twill.shadow_maps.layer"),
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_array_layer: layer,
                array_layer_count: Some(1),
                ..Default::default()
            });
            // Named as the plan names it, so timings and plan speak of the same passes.
            let name = plan.lights.iter().find(|l| l.shadow_layer == Some(layer)).map_or_else(
                || "shadow map".to_owned(),
                |l| Pass::ShadowMap { light: l.light, filter: l.global }.name(),
            );
            let query = next_query(&name);
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("twill.shadow.pass"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &layer_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: render_timestamps(queries, query),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.shadow_pipeline);
            pass.set_bind_group(0, &shadow_group, &[]);
            pass.draw(0..self.shell.surface_vertex_count, layer..layer + 1);
        }

        // X[u, v].
        let vis_size = settings.gpu.visibility_texture_size;
        let top = texture_2d(
            device,
            "twill.top_surface",
            [vis_size, vis_size, 1],
            wgpu::TextureFormat::Rgba32Float,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let top_view = top.create_view(&wgpu::TextureViewDescriptor::default());
        let top_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("twill.top_surface.bind_group"),
            layout: &self.top_pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: surface_buffer.as_entire_binding() },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: self.shell.surface_vertices.as_entire_binding(),
                },
            ],
        });
        {
            let query = next_query("top surface X[u,v]");
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("twill.top_surface.pass"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &top_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: render_timestamps(queries, query),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.top_pipeline);
            pass.set_bind_group(0, &top_group, &[]);
            pass.draw(0..self.shell.top_vertex_count, 0..1);
        }

        // V[u, v].
        let vis_buffer = make_buffer(
            device,
            &self.queue,
            "twill.visibility.uniforms",
            bytemuck::bytes_of(&vis),
            wgpu::BufferUsages::UNIFORM,
        );
        let shadow_view = array_view(&shadow);
        let vis_view = array_view(visibility);
        let vis_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("twill.visibility.bind_group"),
            layout: &self.visibility_pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: vis_buffer.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&top_view) },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&shadow_view),
                },
                wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::TextureView(&vis_view) },
            ],
        });
        let query = next_query("visibility V[u,v]");
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("twill.visibility.pass"),
            timestamp_writes: compute_timestamps(queries, query),
        });
        pass.set_pipeline(&self.visibility_pipeline);
        pass.set_bind_group(0, &vis_group, &[]);
        pass.dispatch_workgroups(vis_size.div_ceil(8), vis_size.div_ceil(8), 1);
    }

    fn encode_blur(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        sharp: &wgpu::Texture,
        blurred: &wgpu::Texture,
        settings: &FrameSettings,
        next_query: &mut dyn FnMut(&str) -> Option<u32>,
        queries: Option<&wgpu::QuerySet>,
    ) {
        let device = &self.device;
        let size = settings.gpu.visibility_texture_size;
        let layers = sharp.depth_or_array_layers();
        let across = texture_2d(
            device,
            "twill.visibility.blur_u",
            [size, size, layers],
            wgpu::TextureFormat::Rg32Float,
            wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let [du, dv] = [self.shell.uv_rect[2], self.shell.uv_rect[3]];
        for (axis, extent, source, destination) in
            [([1.0, 0.0], du, sharp, &across), ([0.0, 1.0], dv, &across, blurred)]
        {
            let sigma = (settings.gpu.sigma_glo_cm as f32 * size as f32 / extent).max(1e-3);
            let radius = (3.0 * sigma).ceil().min(256.0);
            let uniforms = BlurUniformsGpu { axis: [axis[0], axis[1], sigma, radius] };
            let buffer = make_buffer(
                device,
                &self.queue,
                "twill.blur.uniforms",
                bytemuck::bytes_of(&uniforms),
                wgpu::BufferUsages::UNIFORM,
            );
            let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("twill.blur.bind_group"),
                layout: &self.blur_pipeline.get_bind_group_layout(0),
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: buffer.as_entire_binding() },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::TextureView(&array_view(source)),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::TextureView(&array_view(destination)),
                    },
                ],
            });
            let query = next_query("blur sigma_glo");
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("twill.blur.pass"),
                timestamp_writes: compute_timestamps(queries, query),
            });
            pass.set_pipeline(&self.blur_pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(size.div_ceil(8), size.div_ceil(8), layers);
        }
    }

    fn lights_gpu(lights: &[Light], plan: &FramePlan) -> Vec<LightGpu> {
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
}

/// The angular radius used for an SG light's PCSS penumbra: `cos α = 1 − 1/λ`, capped.
#[must_use]
pub fn sg_light_angle(lambda: f64) -> f64 {
    let alpha = if lambda <= 1.0 { std::f64::consts::FRAC_PI_2 } else { (1.0 - 1.0 / lambda).acos() };
    alpha.min(MAX_PCSS_ANGLE_DEG.to_radians())
}

fn light_direction(light: &Light) -> DVec3 {
    match *light {
        Light::Directional { to_light, .. } => to_light,
        Light::Sg { axis, .. } => axis,
    }
}

/// Plans a frame (also usable without a device, e.g. for `--print-plan`). `uniform_frame`:
/// every tetrahedron of the shell has the same world → flat-fabric frame.
#[must_use]
pub fn plan_frame(
    lights: &[Light],
    settings: &FrameSettings,
    flat_normal: Option<Vec3>,
    uniform_frame: bool,
) -> FramePlan {
    let plan_lights: Vec<PlanLight> = lights
        .iter()
        .map(|l| match *l {
            Light::Directional { to_light, .. } => PlanLight::Directional { to_light: to_light.to_array() },
            Light::Sg { axis, sharpness, .. } => PlanLight::Sg { axis: axis.to_array(), sharpness },
        })
        .collect();
    FramePlan::new(
        &plan_lights,
        &PlanInputs {
            flat_normal: flat_normal.map(|n| n.as_dvec3().to_array()),
            components: settings.components,
            sigma_glo_cm: settings.gpu.sigma_glo_cm,
            spp: settings.spp,
            uniform_frame: uniform_frame && settings.frame_transfer,
        },
    )
}

fn validate(settings: &FrameSettings, lights: &[Light]) -> Result<(), RenderError> {
    let bad = |m: String| Err(RenderError::Settings(m));
    if !(1..=16384).contains(&settings.width) || !(1..=16384).contains(&settings.height) {
        return bad(format!("size {}x{}: each side must be in 1..=16384", settings.width, settings.height));
    }
    if !(1..=65536).contains(&settings.spp) {
        return bad(format!("spp {}: must be in 1..=65536", settings.spp));
    }
    if lights.len() > MAX_LIGHTS {
        return bad(format!("{} lights: at most {MAX_LIGHTS} are supported", lights.len()));
    }
    if !(-30.0..=30.0).contains(&settings.exposure) {
        return bad(format!("exposure {}: must be in -30..=30 stops", settings.exposure));
    }
    settings.gpu.validate().map_err(|e| RenderError::Settings(e.to_string()))
}

/// Clip-from-world matrix (wgpu depth 0..1, near and far fitted around the shell), the eye
/// uniform (position with w = 1, or the viewing direction with w = 0) and, for an orthographic
/// camera, its film plane's offset along the viewing direction (0 for perspective). The
/// orthographic near plane may lie behind the film so that every tetrahedron the film cuts is
/// still rasterized; the G-buffer starts each eye ray at the film plane.
fn camera_matrices(camera: &CameraSection, aspect: f32, bounds: (Vec3, Vec3)) -> (Mat4, [f32; 4], f32) {
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
            (proj * view, eye.extend(1.0).to_array(), 0.0)
        }
        ProjectionKind::Orthographic => {
            let half_h = 0.5 * camera.height_cm as f32;
            let half_w = half_h * aspect;
            let near = near - 0.01 * span;
            let proj = orthographic(-half_w, half_w, -half_h, half_h, near, far);
            (proj * view, forward.extend(0.0).to_array(), eye.dot(forward))
        }
    }
}

/// Radical inverse of `index` in `base` (Halton sequence), in [0, 1).
pub(crate) fn halton(mut index: u32, base: u32) -> f64 {
    let mut result = 0.0;
    let mut f = 1.0;
    while index > 0 {
        f /= f64::from(base);
        result += f * f64::from(index % base);
        index /= base;
    }
    result
}

fn render_timestamps(
    queries: Option<&wgpu::QuerySet>,
    index: Option<u32>,
) -> Option<wgpu::RenderPassTimestampWrites<'_>> {
    let (set, i) = (queries?, index?);
    Some(wgpu::RenderPassTimestampWrites {
        query_set: set,
        beginning_of_pass_write_index: Some(i),
        end_of_pass_write_index: Some(i + 1),
    })
}

fn compute_timestamps(
    queries: Option<&wgpu::QuerySet>,
    index: Option<u32>,
) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
    let (set, i) = (queries?, index?);
    Some(wgpu::ComputePassTimestampWrites {
        query_set: set,
        beginning_of_pass_write_index: Some(i),
        end_of_pass_write_index: Some(i + 1),
    })
}

fn readback_buffer(device: &wgpu::Device, label: &str, size: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.max(16),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

fn read_buffer<T: bytemuck::Pod>(
    device: &wgpu::Device,
    buffer: &wgpu::Buffer,
) -> Result<Vec<T>, RenderError> {
    Ok(crate::gpu::read_buffer(device, buffer)?)
}

/// A one-paragraph summary of a frame's timings.
#[must_use]
pub fn describe_timings(timings: &[PassTiming]) -> String {
    let mut text = String::new();
    let total: f64 = timings.iter().map(|t| t.milliseconds).sum();
    for t in timings {
        let _ = writeln!(text, "  {:<28} {:>9.3} ms", t.pass, t.milliseconds);
    }
    let _ = writeln!(text, "  {:<28} {:>9.3} ms", "total (GPU)", total);
    text
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fabric_data::{ExemplarGpu, FabricHeaderGpu, MaterialGpu, SegmentGpu};

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
            (
                "SurfaceVertex",
                &pass_source("shell_surface.wgsl"),
                rust_struct!(SurfaceVertexGpu; position, uvw),
            ),
            (
                "SurfaceUniforms",
                &pass_source("shell_surface.wgsl"),
                rust_struct!(SurfaceUniformsGpu; light_clip_from_world, uv_rect),
            ),
            (
                "VisibilityUniforms",
                &pass_source("visibility.wgsl"),
                rust_struct!(VisibilityUniformsGpu; light_clip_from_world, filters, info),
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
                    pattern_width, pattern_height, block_size, z_range),
            ),
            (
                "ExemplarGpu",
                &shared,
                rust_struct!(ExemplarGpu; volume_origin, voxel_offset, voxel_size, periodic, volume_dims,
                    segment_offset, period, pca_offset, segment_count, cell_origin, cell_offset, cell_size,
                    cell_blocks_x, cell_dims, cell_blocks_y),
            ),
            ("SegmentGpu", &shared, rust_struct!(SegmentGpu; direction, material, cell, sos_rotation)),
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

    /// Twin of the walk in shaders/gbuffer.wgsl `fs_main` (f32, as the shader): from a point
    /// on surface face `face` of tetrahedron `tetra` along `dir`, the tetrahedra the ray passes
    /// through until it leaves the shell, as (tetrahedron, t where it leaves it).
    fn walk(tetras: &[TetraGpu], tetra: u32, face: u32, entry: Vec3, dir: Vec3) -> Vec<(u32, f32)> {
        let to_uvw = |t: &TetraGpu, p: glam::Vec4| {
            Vec3::new(
                glam::Vec4::from(t.uvw_from_world[0]).dot(p),
                glam::Vec4::from(t.uvw_from_world[1]).dot(p),
                glam::Vec4::from(t.uvw_from_world[2]).dot(p),
            )
        };
        let (mut id, mut entry_face, mut t, mut path) = (tetra, face, 0.0_f32, Vec::new());
        for _ in 0..4096 {
            let tet = &tetras[id as usize];
            let start = to_uvw(tet, entry.extend(1.0));
            let step = to_uvw(tet, dir.extend(0.0));
            let (mut t_exit, mut exit_face) = (f32::MAX, 4);
            for (k, plane) in tet.planes.iter().enumerate() {
                let n = Vec3::new(plane[0], plane[1], plane[2]);
                let rate = n.dot(step);
                if rate < 0.0 && k as u32 != entry_face {
                    let t_plane = -(n.dot(start) + plane[3]) / rate;
                    if t_plane < t_exit {
                        (t_exit, exit_face) = (t_plane, k);
                    }
                }
            }
            assert!(exit_face < 4, "tetrahedron {id}: no face to leave by");
            t = t_exit.max(t);
            path.push((id, t));
            let next = tet.neighbors[exit_face];
            if next == crate::shell::NO_NEIGHBOR {
                return path;
            }
            entry_face = tetras[next as usize].neighbors.iter().position(|&n| n == id).unwrap() as u32;
            id = next;
        }
        panic!("the walk did not leave the shell: {:?}", &path[..20]);
    }

    #[test]
    fn eye_rays_walk_through_the_shell_and_leave_it_by_the_far_side() {
        use crate::shell::{BaseMesh, ShellSpec};
        let mesh = BaseMesh::builtin("swatch", [2.0, 2.0]).unwrap();
        let shell = Shell::build(&mesh, &ShellSpec::new([-0.0185, 0.0185], 1.0)).unwrap();
        let neighbors = shell.tetra_neighbors();
        let tetras: Vec<TetraGpu> =
            shell.tetrahedra.iter().zip(&neighbors).map(|(c, &n)| tetra_gpu(c, n)).collect();
        let mut longest = 0;
        for (t, across) in neighbors.iter().enumerate() {
            for (k, &neighbor) in across.iter().enumerate() {
                if neighbor != crate::shell::NO_NEIGHBOR {
                    continue;
                }
                let corners: Vec<Vec3> =
                    (0..4).filter(|&c| c != k).map(|c| shell.tetrahedra[t][c].position).collect();
                // Only the top faces, entered from above by a ray 36 degrees off the normal.
                if corners.iter().any(|c| c.z < 0.0) {
                    continue;
                }
                let entry = (corners[0] + corners[1] + corners[2]) / 3.0;
                for dir in
                    [Vec3::new(0.0, 0.55, -0.75), Vec3::new(0.3, -0.2, -0.9), Vec3::new(-0.8, 0.1, -0.2)]
                {
                    let path = walk(&tetras, t as u32, k as u32, entry, dir.normalize());
                    longest = longest.max(path.len());
                    // It leaves through the bottom (z = -0.0185) or a side (|x| or |y| = 1).
                    let out = entry + path.last().unwrap().1 * dir.normalize();
                    let on_side = out.x.abs().max(out.y.abs()) >= 1.0 - 1e-4;
                    assert!(
                        (out.z + 0.0185).abs() < 1e-5 || on_side,
                        "tetrahedron {t}: the ray leaves at {out}"
                    );
                }
            }
        }
        assert!(longest <= 12, "a ray walked {longest} tetrahedra");
    }

    #[test]
    fn sg_light_angle_shrinks_with_sharpness() {
        assert!((sg_light_angle(1e4) - (2.0_f64 / 1e4).sqrt()).abs() < 1e-4);
        assert!((sg_light_angle(0.5) - 60_f64.to_radians()).abs() < 1e-12);
        assert!(sg_light_angle(100.0) < sg_light_angle(10.0));
    }

    #[test]
    fn halton_points_are_in_the_unit_interval() {
        assert!((halton(1, 2) - 0.5).abs() < 1e-7);
        assert!((halton(2, 2) - 0.25).abs() < 1e-7);
        assert!((halton(1, 3) - 1.0 / 3.0).abs() < 1e-7);
    }
}
