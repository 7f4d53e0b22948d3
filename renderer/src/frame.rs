//! The GPU frame: shell-mapped volume ray casting, SG single scattering, SH multiple
//! scattering and shadow mapping (paper section 5), run pass by pass as the frame plan says.
//!
//! How it works: [`Renderer::new`] uploads the shell ([`ShellGpu`]) next to an uploaded bake
//! ([`FabricData`]) and builds every pass's pipeline ([`FramePasses`], one module per pass in
//! `crate::passes`). [`Renderer::render_samples`] plans the frame ([`FramePlan`]) and executes
//! `plan.passes()` in order, handing each [`Pass`] to its module: the passes before the first
//! per-sample pass once, the per-sample passes (eye rays into the G-buffer, then shading into
//! the accumulation buffer) once per sample with the sample's sub-pixel jitter, and the passes
//! after them (tone mapping) once. What a pass makes for later passes (shadow maps, X, V, the
//! cells' transfer, the shading bind group) is kept in the frame's [`FrameState`]. Each pass is
//! timed under its plan name, so `--print-plan`, the viewer's plan panel and the GPU timings
//! name the same passes.
//!
//! A progressive batch may also be rendered in bands of rows
//! ([`Renderer::render_progressive_in_bands`]): each band of each sample (its G-buffer rows,
//! then their shading) is its own submission, waited for, and the caller may stop the batch
//! between two of them. That bounds how long newer work waits behind a batch on a slow device
//! (a software renderer's full-size sample takes seconds); a stopped batch ends the picture.
//!
//! Kept between frames: the frame targets while the size stays ([`FrameTargets`]), the
//! compiled shading variants, and shell-space visibility (shadow maps, X, V, blur: the plan's
//! [`Pass::view_independent`] passes), which depends on neither the camera nor the sample. It
//! is reused while the lights, the plan's shadow filters, the GPU settings and the shell are
//! the same ([`ShellVisibility`]), so progressive batches and camera moves skip those passes
//! and report them in [`Frame::reused`].

use std::fmt::Write as _;

use twill_precompute::pathtrace::Light;
use twill_precompute::scene::{CameraSection, GpuSection};

use crate::fabric_data::{ExemplarGpu, FabricData};
use crate::gpu::Gpu;
use crate::passes::cell_transfer::CellTransferPass;
use crate::passes::gbuffer::EyeRays;
use crate::passes::shade::{ShadeInputs, ShadePass, ShadeVariant, lights_buffer, lights_gpu};
use crate::passes::shadow_map::{ShadowLayer, ShadowMaps};
use crate::passes::shell_gpu::ShellGpu;
use crate::passes::targets::{FrameTargets, display_row_bytes};
use crate::passes::visibility::visibility_texture;
use crate::passes::{FrameEncoder, FramePasses, MAX_TIMED_PASS_INSTANCES};
use crate::plan::{Components, FramePlan, Pass, PlanInputs, PlanLight};
use crate::shell::Shell;

pub use crate::passes::visibility::sg_light_angle;

/// Most lights with a shadow map in one frame.
pub const MAX_SHADOWED_LIGHTS: usize = 8;
/// Most lights in one frame.
pub const MAX_LIGHTS: usize = 64;
/// End of the sample sequence [`Renderer::render_samples`] can continue (exclusive).
pub const MAX_SAMPLE_INDEX: u32 = 1 << 24;

/// Why a frame could not be rendered.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("invalid render setting: {0}")]
    Settings(String),
    #[error("the adapter {adapter:?} cannot run the renderer: {what} is {have}, the renderer needs {need}")]
    Limit { adapter: String, what: &'static str, have: u64, need: u64 },
    #[error("GPU error in {label}: {message}")]
    Gpu { label: String, message: String },
    #[error(
        "samples from {first_sample} do not continue the progressive picture on the GPU ({kept} samples \
         of this view kept): start it again from sample 0"
    )]
    Continuation { first_sample: u32, kept: u32 },
    #[error("the batch was stopped between two bands of rows, after {bands_done} of them: the picture ends")]
    Interrupted { bands_done: u32 },
    #[error("the frame plan runs {pass:?} before {needs}, which it reads")]
    PassOrder { pass: String, needs: &'static str },
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

/// How [`Renderer::render_progressive_in_bands`] splits a batch: bands of `rows` image rows,
/// each submitted and waited for on its own, and `stop`, asked after each band but the last,
/// which ends the batch when it says so.
pub struct RowBands<'a> {
    /// Rows per band, a multiple of 8 (the shading's workgroup height): at least 8.
    pub rows: u32,
    pub stop: &'a dyn Fn() -> bool,
}

impl RowBands<'_> {
    /// The bands of an image `height` rows high, top to bottom.
    fn of(&self, height: u32) -> impl Iterator<Item = std::ops::Range<u32>> + use<> {
        let rows = self.rows.max(8).next_multiple_of(8);
        (0..height.div_ceil(rows)).map(move |i| i * rows..((i + 1) * rows).min(height))
    }
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
    /// Linear radiance per pixel, row-major from the top-left: the mean of the frame's samples
    /// clamped at zero per channel (the picture).
    pub radiance: Vec<[f32; 3]>,
    /// The same mean before its clamp at zero. The method's samples are signed (a truncated
    /// SH transfer rings below zero) and only a pixel's mean is clamped, so frames of one
    /// sample sequence are combined through this (weighted by their sample counts) and the
    /// sum clamped ([`clamp_at_zero`]); their clamped means would not add up.
    pub signed_radiance: Vec<[f32; 3]>,
    /// Tone-mapped sRGB, RGBA8.
    pub display: Vec<[u8; 4]>,
    pub plan: FramePlan,
    /// GPU time per pass, when the adapter has timestamp queries.
    pub timings: Option<Vec<PassTiming>>,
    /// Passes of the plan this frame did not run because it reused an earlier frame's result
    /// (shell-space visibility: shadow maps, X, V, blur), by their plan names.
    pub reused: Vec<String>,
}

/// A mean radiance clamped at zero per channel (the picture of signed samples' mean).
#[must_use]
pub fn clamp_at_zero(radiance: &[[f32; 3]]) -> Vec<[f32; 3]> {
    radiance.iter().map(|p| p.map(|v| v.max(0.0))).collect()
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

/// What a frame reads back to the CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Readback {
    /// Nothing: the picture stays on the GPU, where a window on the same device draws its
    /// display texture.
    Nothing,
    /// The tone-mapped display image (for a window on another device).
    Display,
    /// The display image and the mean radiance (exports, comparisons).
    Everything,
}

/// The progressive picture after a batch of samples or a new tone map.
#[derive(Debug, Clone)]
pub struct ProgressiveFrame {
    pub width: u32,
    pub height: u32,
    /// Samples in the picture.
    pub samples: u32,
    pub exposure: f64,
    pub filmic: bool,
    /// The tone-mapped picture on the GPU: `Rgba8Unorm` holding sRGB-encoded values (what
    /// egui's own textures hold), with `TEXTURE_BINDING`, so a window on the renderer's device
    /// can draw it as it is.
    pub display_texture: wgpu::Texture,
    /// The display image, when read back.
    pub display: Option<Vec<[u8; 4]>>,
    /// The mean radiance, when read back.
    pub radiance: Option<Vec<[f32; 3]>>,
    pub plan: FramePlan,
    /// GPU time per pass of this call, when the adapter has timestamp queries.
    pub timings: Option<Vec<PassTiming>>,
    /// Passes of the plan this call did not run because it reused an earlier frame's result.
    pub reused: Vec<String>,
}

/// The picture [`Renderer::render_progressive`] keeps on the GPU between calls.
struct ProgressivePicture {
    targets: FrameTargets,
    /// What the samples depend on, hashed ([`picture_key`]).
    key: u64,
    samples: u32,
    plan: FramePlan,
    exposure: f64,
    filmic: bool,
}

impl ProgressivePicture {
    fn frame(&self, read: ReadBack, reused: Vec<String>) -> ProgressiveFrame {
        ProgressiveFrame {
            width: self.targets.size.0,
            height: self.targets.size.1,
            samples: self.samples,
            exposure: self.exposure,
            filmic: self.filmic,
            display_texture: self.targets.display.clone(),
            display: read.display,
            radiance: read.radiance.as_deref().map(clamp_at_zero),
            plan: self.plan.clone(),
            timings: read.timings,
            reused,
        }
    }
}

/// A frame recorded and not yet submitted.
struct Recorded {
    frame: FrameEncoder,
    plan: FramePlan,
    reused: Vec<String>,
}

/// What a submitted frame read back.
struct ReadBack {
    /// The mean of the samples, signed (not clamped at zero).
    radiance: Option<Vec<[f32; 3]>>,
    display: Option<Vec<[u8; 4]>>,
    timings: Option<Vec<PassTiming>>,
}

/// What a progressive picture's samples depend on, hashed: the camera, the lights and the
/// settings but the sample count, the exposure and the tone curve.
fn picture_key(camera: &CameraSection, lights: &[Light], settings: &FrameSettings) -> u64 {
    use std::hash::{Hash, Hasher};
    let samples_alike = FrameSettings { spp: 1, exposure: 0.0, filmic: true, ..settings.clone() };
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    format!("{camera:?}|{lights:?}|{samples_alike:?}").hash(&mut hasher);
    hasher.finish()
}

/// Shell-space visibility V[u, v] of a frame with shadow maps (sharp, and blurred by σ_glo: the
/// same texture without a blur), and a hash of what it depends on: the lights, the plan's
/// shadow filters, the GPU settings and the shell. It does not depend on the camera or the
/// sample, so progressive batches and camera moves reuse it.
struct ShellVisibility {
    key: u64,
    sharp: wgpu::Texture,
    blurred: wgpu::Texture,
}

/// What a frame's passes hand on to later passes while it is recorded.
struct FrameState<'a> {
    lights: &'a [Light],
    passes: &'a [Pass],
    settings: &'a FrameSettings,
    targets: FrameTargets,
    eye: EyeRays,
    /// The sample the per-sample passes are recording, and the rows they record.
    sample: u32,
    rows: std::ops::Range<u32>,
    /// The samples the accumulation holds once the frame's are added (the tone map's divisor).
    tone_samples: u32,
    /// The frame's lights on the GPU, and how many.
    lights_gpu: (wgpu::Buffer, usize),
    shadow_maps: Option<ShadowMaps>,
    top_surface: Option<wgpu::Texture>,
    /// V[u, v] (sharp, blurred): made by the visibility and blur passes, or kept from an
    /// earlier frame.
    visibility: Option<(wgpu::Texture, wgpu::Texture)>,
    cell_transfer: Option<wgpu::Buffer>,
    /// The shading pipeline, and the bind group of the rows it was last bound for.
    shade: Option<(wgpu::ComputePipeline, std::ops::Range<u32>, wgpu::BindGroup)>,
}

/// Shell-mapped fabric renderer on one device.
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    fabric: FabricData,
    shell: ShellGpu,
    passes: FramePasses,
    /// Bumped by every [`Renderer::set_shell`]: part of what shell-space visibility depends on.
    shell_generation: u64,
    /// The last frame's shell-space visibility, reused while what it depends on is unchanged.
    shell_visibility: Option<ShellVisibility>,
    /// The last frame's targets, reused by the next frame of the same size.
    frame_targets: Option<FrameTargets>,
    /// The picture [`Renderer::render_progressive`] accumulates on the GPU.
    progressive: Option<ProgressivePicture>,
    timestamps: bool,
}

/// The renderer needs this many storage buffers in one shader stage (shading pass).
const STORAGE_BUFFERS_NEEDED: u32 = 19;

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
        let shell = ShellGpu::upload(&device, &queue, shell);
        let passes = FramePasses::new(&device, &fabric.layout);
        if let Some(error) = pollster::block_on(scope.pop()) {
            return Err(RenderError::Gpu { label: "pipeline setup".into(), message: error.to_string() });
        }
        let timestamps = device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        Ok(Self {
            device,
            queue,
            adapter: gpu.describe(),
            fabric,
            shell,
            passes,
            shell_generation: 0,
            shell_visibility: None,
            frame_targets: None,
            progressive: None,
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
        self.fabric.gpu_bytes + self.shell.bytes()
    }

    /// The uploaded fabric.
    #[must_use]
    pub fn fabric(&self) -> &FabricData {
        &self.fabric
    }

    /// The shell's world-space bounding box (min, max corners), e.g. to fit a camera to it.
    #[must_use]
    pub fn bounds(&self) -> (glam::Vec3, glam::Vec3) {
        self.shell.bounds
    }

    /// Plans a frame for these lights and settings.
    #[must_use]
    pub fn plan(&self, lights: &[Light], settings: &FrameSettings) -> FramePlan {
        plan_frame(
            lights,
            settings,
            self.shell.flat_normal,
            self.shell.uniform_frame.is_some(),
            self.fabric.arrays.has_lobes(),
        )
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
        self.shell = ShellGpu::upload(&self.device, &self.queue, shell);
        self.shell_generation += 1;
        self.shell_visibility = None;
        self.progressive = None;
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
    /// same ([`FabricData::update_in_place`]): no new pipelines or shell, and no new buffers or
    /// bind group but where the cells that keep fiber lobes change (a new lobes buffer),
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
        self.progressive = None;
        Ok(self.fabric.update_in_place(&self.device, &self.queue, exemplars, pattern)?)
    }

    /// Recolours exemplar `exemplar` (pattern order) to `materials` without a rebake: its IIRTF
    /// is evaluated from `basis` (`bake::recolour`, the cells in parallel) and written in place
    /// with the C_S tables and materials (`FabricData::write_recolouring`); every other buffer
    /// stays, but the fiber lobes' where the new colours change which cells keep them. Returns the buffers written.
    ///
    /// # Errors
    /// Materials that are invalid or do not match the basis's and the exemplar's slots.
    pub fn recolour(
        &mut self,
        exemplar: usize,
        basis: &twill_precompute::bake::recolour::RecolourBasis,
        materials: &[twill_precompute::bcsdf::MaterialDesc],
    ) -> Result<Vec<&'static str>, RenderError> {
        use twill_precompute::bake::recolour::SlotColour;
        use twill_precompute::bcsdf::Material;
        let colours: Vec<SlotColour> = materials
            .iter()
            .map(|m| Material::from_desc(m).map(|m| SlotColour::of(&m)))
            .collect::<Result<_, _>>()
            .map_err(|e| RenderError::Settings(format!("recolouring: {e}")))?;
        basis.check_colours(&colours).map_err(|e| RenderError::Settings(format!("recolouring: {e}")))?;
        let exemplar_cells = self.fabric.arrays.exemplars.get(exemplar).map_or(0, ExemplarGpu::cell_count);
        if basis.cells.len() != exemplar_cells {
            return Err(RenderError::Settings(format!(
                "recolouring: the basis has {} cells, the GPU fabric's exemplar {exemplar} {exemplar_cells}",
                basis.cells.len()
            )));
        }
        let write_cell = |c: usize, out: &mut [u16], lobe: Option<&mut [f32]>| {
            if basis.cells[c].paths == 0 {
                out.fill(0);
                if let Some(lobe) = lobe {
                    lobe.fill(0.0);
                }
                return;
            }
            let mut values = vec![0.0_f32; out.len()];
            match lobe {
                Some(lobe) => basis.write_cell(c, &colours, &mut values, lobe),
                None => basis.write_cell_folding(c, &colours, &mut values),
            }
            for (h, v) in out.iter_mut().zip(&values) {
                *h = crate::fabric_data::f32_to_f16_bits(*v);
            }
        };
        let cs_tables = basis.cs_tables(materials);
        self.progressive = None;
        let recolouring = crate::fabric_data::Recolouring {
            exemplar,
            materials,
            cs_tables: &cs_tables,
            write_cell: &write_cell,
            keeps_lobes: &|c| basis.keeps_lobes_at(c, &colours),
        };
        Ok(self.fabric.write_recolouring(&self.device, &self.queue, &recolouring)?)
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
    /// stopped). The frame's `signed_radiance` is the mean of its own samples, so a caller that
    /// weights each frame by its `spp`, sums them and clamps the sum at zero gets the same image
    /// as one frame with all the samples (what an export does). `first_sample = 0` is exactly [`Renderer::render`].
    /// These frames have targets of their own: they never touch the progressive picture.
    pub fn render_samples(
        &mut self,
        camera: &CameraSection,
        lights: &[Light],
        settings: &FrameSettings,
        first_sample: u32,
    ) -> Result<Frame, RenderError> {
        let settings = self.checked(camera, lights, settings, first_sample)?;
        let (width, height) = (settings.width, settings.height);
        let targets = self.targets(width, height);
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let recorded =
            self.record(camera, lights, &settings, first_sample, &targets, true, settings.spp, None)?;
        let read = self.submit(recorded.frame, scope, &targets, Readback::Everything, settings.spp)?;
        let signed_radiance = read.radiance.unwrap_or_default();
        Ok(Frame {
            width,
            height,
            radiance: clamp_at_zero(&signed_radiance),
            signed_radiance,
            display: read.display.unwrap_or_default(),
            plan: recorded.plan,
            timings: read.timings,
            reused: recorded.reused,
        })
    }

    /// Adds samples `first_sample .. first_sample + settings.spp` to the progressive picture
    /// kept on the GPU and tone-maps the running mean into its display texture: the viewer's
    /// frame, which stays on the GPU unless `readback` asks for it.
    ///
    /// `first_sample = 0` starts a new picture (the last picture's targets are reused when the
    /// size is the same). Any other `first_sample` must continue the kept picture exactly: the
    /// same camera, lights and settings (exposure and tone curve aside) and exactly
    /// `first_sample` samples so far, else [`RenderError::Continuation`] and nothing is added.
    /// A new bake written in place ([`Renderer::update_fabric`]) or a new shell ends the picture.
    ///
    /// # Errors
    /// Bad settings, a continuation of a different picture, or a GPU failure.
    pub fn render_progressive(
        &mut self,
        camera: &CameraSection,
        lights: &[Light],
        settings: &FrameSettings,
        first_sample: u32,
        readback: Readback,
    ) -> Result<ProgressiveFrame, RenderError> {
        self.render_progressive_in_bands(camera, lights, settings, first_sample, readback, None)
    }

    /// As [`Renderer::render_progressive`], with `bands`: each sample is rendered band by band
    /// of rows, each band its own submission, and `bands.stop` is asked after every band but
    /// the last. The picture is the same, to the bit, whatever the bands; the frame has no
    /// pass timings (they are taken within one submission). `None` is one submission.
    ///
    /// # Errors
    /// As [`Renderer::render_progressive`], and [`RenderError::Interrupted`] when `stop` said
    /// so: the accumulation then holds part of a sample, so the picture ends (a continuation
    /// is refused until a new picture starts from sample 0).
    pub fn render_progressive_in_bands(
        &mut self,
        camera: &CameraSection,
        lights: &[Light],
        settings: &FrameSettings,
        first_sample: u32,
        readback: Readback,
        bands: Option<&RowBands<'_>>,
    ) -> Result<ProgressiveFrame, RenderError> {
        let settings = self.checked(camera, lights, settings, first_sample)?;
        let key = picture_key(camera, lights, &settings);
        let size = (settings.width, settings.height);
        let targets = if first_sample == 0 {
            match self.progressive.take() {
                Some(kept) if kept.targets.size == size => kept.targets,
                _ => FrameTargets::new(&self.device, size.0, size.1),
            }
        } else {
            match &self.progressive {
                Some(kept) if kept.key == key && kept.samples == first_sample => kept.targets.clone(),
                kept => {
                    return Err(RenderError::Continuation {
                        first_sample,
                        kept: kept.as_ref().map_or(0, |k| if k.key == key { k.samples } else { 0 }),
                    });
                }
            }
        };
        let samples = first_sample + settings.spp;
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let clear = first_sample == 0;
        let recorded = self.record(camera, lights, &settings, first_sample, &targets, clear, samples, bands);
        let recorded = match recorded {
            Ok(recorded) => recorded,
            Err(e) => {
                // Part of a sample may be in the accumulation: no batch continues it.
                self.progressive = None;
                return Err(e);
            }
        };
        let read = self.submit(recorded.frame, scope, &targets, readback, samples)?;
        let picture = ProgressivePicture {
            targets,
            key,
            samples,
            plan: recorded.plan,
            exposure: settings.exposure,
            filmic: settings.filmic,
        };
        let frame = picture.frame(read, recorded.reused);
        self.progressive = Some(picture);
        Ok(frame)
    }

    /// Tone-maps the progressive picture again with a new exposure and curve (no new samples).
    ///
    /// # Errors
    /// When there is no picture, or on a GPU failure.
    pub fn tone_map_progressive(
        &mut self,
        exposure: f64,
        filmic: bool,
        readback: Readback,
    ) -> Result<ProgressiveFrame, RenderError> {
        check_exposure(exposure)?;
        let Some(picture) = self.progressive.as_mut() else {
            return Err(RenderError::Continuation { first_sample: 0, kept: 0 });
        };
        (picture.exposure, picture.filmic) = (exposure, filmic);
        let (targets, samples) = (picture.targets.clone(), picture.samples);
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut frame = FrameEncoder::new(&self.device, &self.queue, self.timestamps.then_some(1));
        let name = Pass::ToneMap.name();
        self.passes.tone_map.encode(&mut frame, &targets, exposure, filmic, samples, &name);
        let read = self.submit(frame, scope, &targets, readback, samples)?;
        let picture =
            self.progressive.as_ref().ok_or(RenderError::Continuation { first_sample: 0, kept: 0 })?;
        Ok(picture.frame(read, Vec::new()))
    }

    /// Validates a request and fits it to the adapter.
    fn checked(
        &self,
        camera: &CameraSection,
        lights: &[Light],
        settings: &FrameSettings,
        first_sample: u32,
    ) -> Result<FrameSettings, RenderError> {
        validate(settings, lights)?;
        twill_precompute::scene::camera_from(camera, settings.width as usize, settings.height as usize)
            .map_err(|e| RenderError::Settings(e.to_string()))?;
        if first_sample.checked_add(settings.spp).is_none_or(|end| end > MAX_SAMPLE_INDEX) {
            return Err(RenderError::Settings(format!(
                "samples {first_sample}..{first_sample}+{}: the sequence ends at {MAX_SAMPLE_INDEX}",
                settings.spp
            )));
        }
        self.fit_to_adapter(settings)
    }

    /// Records the plan's passes for samples `first_sample ..` into `targets`, clearing the
    /// accumulation first when `clear`; the tone map divides by `tone_samples`. With `bands`,
    /// the per-sample passes are recorded band by band of rows, and everything up to the end of
    /// each band but the last is submitted and waited for (see [`RowBands`]); the frame
    /// returned holds the rest.
    #[allow(clippy::too_many_arguments)]
    fn record(
        &mut self,
        camera: &CameraSection,
        lights: &[Light],
        settings: &FrameSettings,
        first_sample: u32,
        targets: &FrameTargets,
        clear: bool,
        tone_samples: u32,
        bands: Option<&RowBands<'_>>,
    ) -> Result<Recorded, RenderError> {
        let plan = self.plan(lights, settings);
        let passes = plan.passes();
        let device = self.device.clone();
        let (width, height) = targets.size;

        // Shell-space visibility is reused from the previous frame when nothing it depends on
        // changed (a progressive batch, a camera move): its passes do not run.
        let visibility_key = plan.shadow_maps.then(|| self.visibility_key(lights, &plan, settings));
        let kept = self
            .shell_visibility
            .as_ref()
            .filter(|cached| Some(cached.key) == visibility_key)
            .map(|cached| (cached.sharp.clone(), cached.blurred.clone()));
        let reuse = kept.is_some();
        let runs = |pass: &&Pass| !(reuse && pass.view_independent());
        let reused: Vec<String> = passes.iter().filter(|p| !runs(p)).map(Pass::name).collect();

        let first_per_sample = passes.iter().position(Pass::per_sample).unwrap_or(passes.len());
        let after_per_sample = passes.iter().rposition(Pass::per_sample).map_or(passes.len(), |i| i + 1);
        let (before, per_sample, after) = (
            &passes[..first_per_sample],
            &passes[first_per_sample..after_per_sample],
            &passes[after_per_sample..],
        );
        let timed_instances: u32 = passes
            .iter()
            .filter(runs)
            .map(|p| match p {
                Pass::Blur { .. } => 2,
                p if p.per_sample() => settings.spp,
                _ => 1,
            })
            .sum();
        let row_bands: Vec<std::ops::Range<u32>> =
            bands.map_or_else(|| std::iter::once(0..height).collect(), |b| b.of(height).collect());
        // Bands of the samples, each of all but the last submitted on its own.
        let band_count = if bands.is_some() { settings.spp as usize * row_bands.len() } else { 1 };
        // Timestamps are resolved within one submission: a frame of several has none.
        let timed = self
            .timestamps
            .then_some(timed_instances)
            .filter(|&n| n <= MAX_TIMED_PASS_INSTANCES && band_count == 1);
        let mut frame = FrameEncoder::new(&device, &self.queue, timed);
        if clear {
            frame.encoder.clear_buffer(&targets.accumulation, 0, None);
        }
        let lights_gpu = lights_gpu(lights, &plan);
        let mut state = FrameState {
            lights,
            passes: &passes,
            settings,
            eye: EyeRays::new(camera, width as f32 / height as f32, self.shell.bounds),
            targets: targets.clone(),
            sample: first_sample,
            rows: 0..height,
            tone_samples,
            lights_gpu: (lights_buffer(&device, &self.queue, &lights_gpu), lights_gpu.len()),
            shadow_maps: None,
            top_surface: None,
            visibility: kept,
            cell_transfer: None,
            shade: None,
        };
        for pass in before.iter().filter(runs) {
            self.encode_pass(pass, &mut frame, &mut state)?;
        }
        // Kept for later frames once its passes are submitted (with the first band, or with
        // the whole frame).
        let mut made_visibility = if reuse { None } else { visibility_key.zip(state.visibility.clone()) };
        let mut bands_done = 0;
        for sample in first_sample..first_sample + settings.spp {
            state.sample = sample;
            for rows in &row_bands {
                state.rows = rows.clone();
                for pass in per_sample {
                    self.encode_pass(pass, &mut frame, &mut state)?;
                }
                bands_done += 1;
                if let Some(bands) = bands.filter(|_| bands_done < band_count) {
                    let (commands, _) =
                        std::mem::replace(&mut frame, FrameEncoder::new(&device, &self.queue, None)).finish();
                    self.queue.submit([commands]);
                    device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| RenderError::Gpu {
                        label: format!("band {bands_done} of {band_count}"),
                        message: e.to_string(),
                    })?;
                    self.keep_shell_visibility(made_visibility.take());
                    if (bands.stop)() {
                        return Err(RenderError::Interrupted { bands_done: bands_done as u32 });
                    }
                }
            }
        }
        for pass in after {
            self.encode_pass(pass, &mut frame, &mut state)?;
        }
        self.keep_shell_visibility(made_visibility);
        Ok(Recorded { frame, plan, reused })
    }

    /// Keeps a frame's shell-space visibility (its key, sharp and blurred textures) for later
    /// frames; `None` leaves the kept one.
    fn keep_shell_visibility(&mut self, made: Option<(u64, (wgpu::Texture, wgpu::Texture))>) {
        if let Some((key, (sharp, blurred))) = made {
            self.shell_visibility = Some(ShellVisibility { key, sharp, blurred });
        }
    }

    /// Submits a recorded frame, with copies of what `readback` asks for, and reads them.
    fn submit(
        &self,
        mut frame: FrameEncoder,
        scope: wgpu::ErrorScopeGuard,
        targets: &FrameTargets,
        readback: Readback,
        samples: u32,
    ) -> Result<ReadBack, RenderError> {
        if readback != Readback::Nothing {
            targets.encode_readback(&mut frame.encoder, readback == Readback::Everything);
        }
        let (commands, timing_readback) = frame.finish();
        self.queue.submit([commands]);
        if let Some(error) = pollster::block_on(scope.pop()) {
            return Err(RenderError::Gpu { label: "frame".into(), message: error.to_string() });
        }
        let radiance = if readback == Readback::Everything {
            let accumulated: Vec<[f32; 4]> =
                crate::gpu::read_buffer(&self.device, &targets.radiance_readback)?;
            // The shade pass accumulates signed samples; the callers clamp the mean at zero
            // (`clamp_at_zero`), as the tone map does (shading::render::ClampAtZero::PixelMean).
            let inv = 1.0 / samples.max(1) as f32;
            Some(accumulated.iter().map(|p| [p[0] * inv, p[1] * inv, p[2] * inv]).collect())
        } else {
            None
        };
        let display =
            if readback == Readback::Nothing { None } else { Some(read_display(&self.device, targets)?) };
        let timings = timing_readback.map(|t| t.read(&self.device, &self.queue)).transpose()?;
        Ok(ReadBack { radiance, display, timings })
    }

    /// The targets for a frame of this size: the last frame's when the size is the same.
    fn targets(&mut self, width: u32, height: u32) -> FrameTargets {
        match &self.frame_targets {
            Some(kept) if kept.size == (width, height) => kept.clone(),
            _ => {
                let made = FrameTargets::new(&self.device, width, height);
                self.frame_targets = Some(made.clone());
                made
            }
        }
    }

    /// Records one pass of the plan, by its module; what it makes goes into `state`.
    fn encode_pass(
        &mut self,
        pass: &Pass,
        frame: &mut FrameEncoder,
        state: &mut FrameState<'_>,
    ) -> Result<(), RenderError> {
        let (device, queue, shell, fabric) = (&self.device, &self.queue, &self.shell, &self.fabric);
        let passes = &mut self.passes;
        let gpu = &state.settings.gpu;
        let name = pass.name();
        let out_of_order = |needs| RenderError::PassOrder { pass: name.clone(), needs };
        match pass {
            Pass::ShadowMap { layer, .. } => {
                let maps = state.shadow_maps.get_or_insert_with(|| {
                    let layers = shadow_layers(state.passes, state.lights);
                    passes.shadow_map.prepare(device, queue, shell, layers, gpu.shadow_map_size)
                });
                passes.shadow_map.encode(frame, maps, shell, *layer, &name);
            }
            Pass::TopSurface => {
                let size = gpu.visibility_texture_size;
                state.top_surface = Some(passes.top_surface.encode(frame, shell, size, &name));
            }
            Pass::Visibility { .. } => {
                let top = state.top_surface.as_ref().ok_or_else(|| out_of_order("the top surface X[u,v]"))?;
                let maps = state.shadow_maps.as_ref().ok_or_else(|| out_of_order("the shadow maps"))?;
                let size = gpu.visibility_texture_size;
                let sharp = passes.visibility.encode(frame, top, maps, gpu, size, &name);
                state.visibility = Some((sharp.clone(), sharp));
            }
            Pass::Blur { sigma_glo_cm } => {
                let (sharp, _) =
                    state.visibility.as_ref().ok_or_else(|| out_of_order("the visibility V[u,v]"))?;
                let blurred = passes.blur.encode(frame, sharp, *sigma_glo_cm, shell.uv_rect, &name);
                state.visibility = Some((sharp.clone(), blurred));
            }
            Pass::CellTransfer => {
                let (lights, count) = &state.lights_gpu;
                state.cell_transfer =
                    passes.cell_transfer.encode(frame, shell, fabric, lights, *count, &name);
            }
            Pass::GBuffer => {
                let (width, height) = state.targets.size;
                let jitter = sample_jitter(state.sample, width, height);
                let (eye, targets, rows) = (&state.eye, &state.targets, &state.rows);
                passes.gbuffer.encode(frame, eye, jitter, shell, fabric, targets, rows, &name);
            }
            Pass::Shade { .. } => {
                if state.shade.as_ref().is_none_or(|(_, rows, _)| *rows != state.rows) {
                    let pipeline = if let Some((pipeline, _, _)) = state.shade.take() {
                        pipeline
                    } else {
                        let variant =
                            ShadeVariant::of(pass).ok_or_else(|| out_of_order("its shading variant"))?;
                        passes.shade.pipeline(device, &fabric.layout, variant)
                    };
                    let (sharp, blurred) = state.visibility.clone().unwrap_or_else(|| {
                        let none = visibility_texture(device, "twill.visibility.none", 1, 1);
                        (none.clone(), none)
                    });
                    let cell_transfer = state
                        .cell_transfer
                        .clone()
                        .unwrap_or_else(|| CellTransferPass::unused(device, queue));
                    let z = fabric.arrays.header.z_range;
                    let inputs = ShadeInputs {
                        lights: &state.lights_gpu.0,
                        light_count: state.lights_gpu.1,
                        eye: state.eye.eye,
                        uv_rect: shell.uv_rect,
                        fabric_thickness_cm: z[1] - z[0],
                        tetras: &shell.tetras,
                        visibility_sharp: &sharp,
                        visibility_blurred: &blurred,
                        cell_transfer: &cell_transfer,
                    };
                    let group = passes.shade.bind(device, queue, &inputs, &state.targets, &state.rows);
                    state.shade = Some((pipeline, state.rows.clone(), group));
                }
                if let Some((pipeline, rows, group)) = &state.shade {
                    let width = state.targets.size.0;
                    ShadePass::encode(frame, pipeline, group, fabric, width, rows, &name);
                }
            }
            Pass::ToneMap => {
                let s = state.settings;
                passes.tone_map.encode(
                    frame,
                    &state.targets,
                    s.exposure,
                    s.filmic,
                    state.tone_samples,
                    &name,
                );
            }
        }
        Ok(())
    }
}

/// The shadow-map layers the plan's `Pass::ShadowMap`s render, in layer order.
fn shadow_layers(passes: &[Pass], lights: &[Light]) -> Vec<ShadowLayer> {
    let mut layers: Vec<(u32, ShadowLayer)> = passes
        .iter()
        .filter_map(|pass| match *pass {
            Pass::ShadowMap { light, filter, layer } => {
                let (to_light, sg_sharpness) = match lights[light] {
                    Light::Directional { to_light, .. } => (to_light, None),
                    Light::Sg { axis, sharpness, .. } => (axis, Some(sharpness)),
                };
                Some((layer, ShadowLayer { light, filter, to_light, sg_sharpness }))
            }
            _ => None,
        })
        .collect();
    layers.sort_by_key(|(layer, _)| *layer);
    layers.into_iter().map(|(_, l)| l).collect()
}

/// The sub-pixel offset of sample `index` in clip units, a function of the index alone (so a
/// picture accumulated over batches is the frame of all its samples): none for sample 0 (a
/// one-sample frame is the pixel centres, as the path tracer's), then the Halton (2, 3) points
/// 1, 2, ... over the pixel.
fn sample_jitter(index: u32, width: u32, height: u32) -> [f32; 2] {
    if index == 0 {
        return [0.0; 2];
    }
    let (jx, jy) = (halton(index, 2) as f32, halton(index, 3) as f32);
    [(2.0 * jx - 1.0) / width as f32, -(2.0 * jy - 1.0) / height as f32]
}

/// The display image of `targets`, read back (rows unpadded).
fn read_display(device: &wgpu::Device, targets: &FrameTargets) -> Result<Vec<[u8; 4]>, RenderError> {
    let (width, _) = targets.size;
    let bytes: Vec<u8> = crate::gpu::read_buffer(device, &targets.display_readback)?;
    let mut pixels = Vec::with_capacity(targets.pixels() as usize);
    for row in bytes.chunks_exact(display_row_bytes(width) as usize) {
        pixels.extend(row[..(width * 4) as usize].chunks_exact(4).map(|p| [p[0], p[1], p[2], p[3]]));
    }
    Ok(pixels)
}

/// Plans a frame (also usable without a device, e.g. for `--print-plan`). `uniform_frame`:
/// every tetrahedron of the shell has the same world → flat-fabric frame; `fiber_lobes`: the
/// bake carries fiber lobes (`FabricArrays::has_lobes`).
#[must_use]
pub fn plan_frame(
    lights: &[Light],
    settings: &FrameSettings,
    flat_normal: Option<glam::Vec3>,
    uniform_frame: bool,
    fiber_lobes: bool,
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
            fiber_lobes,
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
    check_exposure(settings.exposure)?;
    settings.gpu.validate().map_err(|e| RenderError::Settings(e.to_string()))
}

/// The display exposure, in stops, within -30..=30.
fn check_exposure(exposure: f64) -> Result<(), RenderError> {
    if (-30.0..=30.0).contains(&exposure) {
        Ok(())
    } else {
        Err(RenderError::Settings(format!("exposure {exposure}: must be in -30..=30 stops")))
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
    use glam::Vec3;

    use super::*;
    use crate::passes::shell_gpu::{TetraGpu, tetra_gpu};

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
