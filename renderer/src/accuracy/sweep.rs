//! `twill accuracy`: what each knob's accuracy costs in time, on hard light/view configurations
//! of several fabrics, against cached path-traced references.
//!
//! How it works:
//! - [`hard_configurations`]: views up to 75° and lights up to 80° from the fabric normal. The
//!   first four are fixed (head-on; grazing and front-lit; backlit; grazing and backlit under a
//!   broad SG); the rest follow a Halton sequence. Lights alternate directional and normalized
//!   SG with λ log-uniform in [2, 2000]; every light delivers 1 in every channel.
//! - References ([`ReferenceCache`]): per fabric and configuration the path tracer renders
//!   single and multiple scattering separately (all light is their sum), keeping each pixel's
//!   mean and the variance of that mean. With a noise target
//!   ([`SweepSettings::reference_noise`]) a reference is rendered again with fresh seeds,
//!   doubling its samples, until the standard error of each component's image mean is within
//!   the target (`Reference::meets`) or the samples reach a cap, so that each configuration's
//!   own error is measured, not only the Fig. 13 figure (whose noise is subtracted). They are
//!   stored in `DIR/references/` under a key hashed from everything they depend on (fabric
//!   geometry, materials, camera, light, size, spp, noise target, depth, seed,
//!   [`REFERENCE_VERSION`]), with their spp and a checksum; a file that does not match is
//!   rendered again, never trusted.
//! - Points ([`Point`]): the quality presets, and one bake knob or frame setting at a time
//!   varied around the base preset ([`Knob`]). Each point bakes every fabric through one stage
//!   cache (so a knob reruns only the stages that depend on it; a stage's time is the time it
//!   took when it was computed in this run) and renders each configuration twice on the GPU:
//!   all light (timed: wall time and GPU time per pass) and single scattering alone, with the
//!   same seed, so multiple scattering is their difference on the same eye rays.
//! - Errors per component ([`ComponentErrors`]): the paper's Fig. 13 figure (RMSE over
//!   configurations and channels of the image-average intensity, relative to the RMS of the
//!   reference averages), the worst configuration's relative error of its image mean, the
//!   per-pixel RMSE relative to the same scale with the reference's noise subtracted, the
//!   path-tracer spp whose noise equals that per-pixel error, and SSIM of tone-mapped luminance
//!   ([`ssim`]).
//! - [`Sweep::pareto`]: a point is on the front when no other point is at least as accurate
//!   (all light, averaged over fabrics) with no more frame time and no more bake time, and
//!   strictly better in one of them.

use std::fmt::Write as _;
use std::io::{self, Read as _, Write as _};
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::DVec3;
use twill_precompute::Rgb;
use twill_precompute::atomic_file::write_atomically;
use twill_precompute::bake::file::{Cache, ContentHash, Hasher};
use twill_precompute::bake::pattern::PatternMap;
use twill_precompute::bake::pipeline::{Baked, Stage, StageSource, bake};
use twill_precompute::bake::settings::{BakeSettings, Quality};
use twill_precompute::bake::{Cancel, pipeline::BakeInputs};
use twill_precompute::image::Image;
use twill_precompute::pathtrace::{self, Component, Light, RenderSettings};
use twill_precompute::scene::{Scene, camera_from};
use twill_precompute::shading::render_flat;

use super::{AccuracyError, camera_for, direction};
use crate::frame::{FrameSettings, halton};
use crate::gpu::Gpu;
use crate::headless::{SceneRenderer, frame_settings};
use crate::plan::Components;

/// Bump when the path tracer's output for the same inputs changes: cached references made by
/// older code are then rendered again.
pub const REFERENCE_VERSION: u32 = 2;

/// The most samples per pixel a reference may take (`SweepSettings::reference_max_spp`).
pub const MAX_REFERENCE_SPP: u32 = 1 << 20;

/// In a reference's stopping rule, the share of all light below which a component is held to
/// that share instead of to its own mean (`SweepSettings::reference_noise`).
const DIM_COMPONENT_SHARE: f64 = 0.25;

/// One light/view pair, with the kind of case it is.
#[derive(Debug, Clone, Copy)]
pub struct HardConfiguration {
    /// Unit direction from the swatch toward the camera.
    pub view: DVec3,
    pub light: Light,
    /// "head-on", "grazing", "backlit", "grazing, backlit" or "general".
    pub class: &'static str,
}

impl HardConfiguration {
    fn light_direction(&self) -> DVec3 {
        match self.light {
            Light::Directional { to_light, .. } => to_light,
            Light::Sg { axis, .. } => axis,
        }
    }

    /// Azimuth between the view and the light, degrees in [0, 180] (180: backlit).
    #[must_use]
    pub fn azimuth_apart_deg(&self) -> f64 {
        let l = self.light_direction();
        let azimuth = (self.view.y.atan2(self.view.x) - l.y.atan2(l.x)).abs().to_degrees();
        if azimuth > 180.0 { 360.0 - azimuth } else { azimuth }
    }

    /// One line: angles from the normal, the light's kind and the class.
    #[must_use]
    pub fn describe(&self) -> String {
        let light = match self.light {
            Light::Directional { .. } => "directional".to_owned(),
            Light::Sg { sharpness, .. } => format!("SG λ={sharpness:.0}"),
        };
        let l = self.light_direction();
        let azimuth = self.azimuth_apart_deg();
        format!(
            "view {:.0}°, {light} at {:.0}°, {azimuth:.0}° apart in azimuth ({})",
            self.view.z.clamp(-1.0, 1.0).acos().to_degrees(),
            l.z.clamp(-1.0, 1.0).acos().to_degrees(),
            self.class
        )
    }
}

fn classify(view: DVec3, to_light: DVec3) -> &'static str {
    let (view_deg, light_deg) = (view.z.acos().to_degrees(), to_light.z.acos().to_degrees());
    let across = view.x * to_light.x + view.y * to_light.y;
    let flat = |v: DVec3| v.x.hypot(v.y).max(1e-12);
    let backlit = light_deg > 30.0 && view_deg > 15.0 && across / (flat(view) * flat(to_light)) < -0.5;
    let grazing = view_deg >= 60.0 || light_deg >= 65.0;
    match (grazing, backlit) {
        (true, true) => "grazing, backlit",
        (true, false) => "grazing",
        (false, true) => "backlit",
        _ if view_deg < 15.0 && light_deg < 15.0 => "head-on",
        _ => "general",
    }
}

/// `count` configurations (see the module docs); the same every call.
pub fn hard_configurations(count: usize) -> Result<Vec<HardConfiguration>, AccuracyError> {
    let deg = f64::to_radians;
    let at = |theta_deg: f64, phi_deg: f64| direction(deg(theta_deg).cos(), deg(phi_deg));
    let fixed = [
        (at(0.0, 0.0), Light::directional(at(5.0, 30.0), Rgb::ONE)?),
        (at(75.0, 0.0), Light::sg(at(80.0, 20.0), 2000.0, Rgb::ONE)?),
        (at(55.0, 0.0), Light::directional(at(60.0, 180.0), Rgb::ONE)?),
        (at(75.0, 90.0), Light::sg(at(80.0, 260.0), 2.0, Rgb::ONE)?),
    ];
    let (max_view, max_light) = (deg(75.0).cos(), deg(80.0).cos());
    let mut out = Vec::with_capacity(count);
    for i in 0..count {
        let (view, light) = if let Some(&pair) = fixed.get(i) {
            pair
        } else {
            let h = |base| halton(i as u32, base);
            let view = direction(1.0 - h(2) * (1.0 - max_view), std::f64::consts::TAU * h(3));
            let to_light = direction(1.0 - h(5) * (1.0 - max_light), std::f64::consts::TAU * h(7));
            let light = if i % 2 == 0 {
                Light::directional(to_light, Rgb::ONE)?
            } else {
                Light::sg(to_light, 2.0 * 1000f64.powf(h(11)), Rgb::ONE)?
            };
            (view, light)
        };
        let to_light = match light {
            Light::Directional { to_light, .. } => to_light,
            Light::Sg { axis, .. } => axis,
        };
        out.push(HardConfiguration { view, light, class: classify(view, to_light) });
    }
    Ok(out)
}

/// A knob the sweep varies: a bake setting or a frame setting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Knob {
    ShOrder,
    PcaComponents,
    VisibilityBits,
    SvfResolution,
    VisibilityPoints,
    SosCount,
    SosSharpness,
    IirtfPaths,
    LightSamples,
    CellSize,
    CellDepth,
    Spp,
    SigmaGlo,
    FiberLobes,
    ExposedStarts,
    SegmentPaths,
    SegmentPool,
    /// The bake's random seed: its points differ by the bake's own noise alone, the spread
    /// against which every other knob's effect is read.
    Seed,
}

impl Knob {
    pub const ALL: [Knob; 18] = [
        Knob::ShOrder,
        Knob::PcaComponents,
        Knob::VisibilityBits,
        Knob::SvfResolution,
        Knob::VisibilityPoints,
        Knob::SosCount,
        Knob::SosSharpness,
        Knob::IirtfPaths,
        Knob::LightSamples,
        Knob::CellSize,
        Knob::CellDepth,
        Knob::Spp,
        Knob::SigmaGlo,
        Knob::FiberLobes,
        Knob::ExposedStarts,
        Knob::SegmentPaths,
        Knob::SegmentPool,
        Knob::Seed,
    ];

    /// Its name: the bake knob's (`--set`), or the frame setting's.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::ShOrder => "sh_order",
            Self::PcaComponents => "pca_components",
            Self::VisibilityBits => "visibility_bits",
            Self::SvfResolution => "svf_resolution",
            Self::VisibilityPoints => "visibility_points",
            Self::SosCount => "sos_count",
            Self::SosSharpness => "sos_sharpness",
            Self::IirtfPaths => "iirtf_paths_per_cell",
            Self::LightSamples => "iirtf_light_samples",
            Self::CellSize => "cell_size_mfp",
            Self::CellDepth => "cell_depth_mfp",
            Self::Spp => "spp",
            Self::SigmaGlo => "sigma_glo_cm",
            Self::FiberLobes => "fiber_lobes",
            Self::ExposedStarts => "exposed_starts",
            Self::SegmentPaths => "segment_transfer_paths",
            Self::SegmentPool => "segment_pool_mfp",
            Self::Seed => "seed",
        }
    }

    /// The knob named `name`, or an error listing the names.
    pub fn parse(name: &str) -> Result<Self, AccuracyError> {
        Self::ALL.into_iter().find(|k| k.name() == name).ok_or_else(|| {
            let names: Vec<&str> = Self::ALL.iter().map(|k| k.name()).collect();
            AccuracyError::Settings(format!("unknown knob {name:?}; knobs: {}", names.join(", ")))
        })
    }

    /// Whether it acts on a bake of `bake`: pooling segment transfers needs some
    /// (`segment_transfer_paths > 0`); around a base without them its points are left out.
    #[must_use]
    pub fn acts_on(self, bake: &BakeSettings) -> bool {
        self != Self::SegmentPool || bake.segment_transfer_paths > 0
    }

    /// Whether it changes the bake (else only the frame).
    #[must_use]
    pub fn is_bake_knob(self) -> bool {
        !matches!(self, Self::Spp | Self::SigmaGlo)
    }

    /// The values swept by default (around the draft preset; the GPU holds SH order 6 at most).
    #[must_use]
    pub fn default_values(self) -> Vec<f64> {
        match self {
            Self::ShOrder => vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            Self::PcaComponents => vec![2.0, 4.0, 8.0, 16.0],
            Self::SvfResolution => vec![8.0, 12.0, 16.0, 24.0, 32.0],
            Self::VisibilityPoints => vec![1.0, 2.0, 3.0, 4.0, 6.0],
            Self::SosCount => vec![4.0, 8.0, 16.0, 32.0],
            Self::SosSharpness => vec![16.0, 32.0, 64.0, 256.0],
            Self::IirtfPaths => vec![24.0, 48.0, 96.0, 192.0, 384.0],
            Self::LightSamples => vec![1.0, 2.0, 4.0, 8.0],
            Self::CellSize => vec![2.0, 3.0, 4.0, 6.0],
            Self::CellDepth => vec![0.25, 0.5, 1.0, 2.0],
            Self::Spp => vec![4.0, 8.0, 16.0, 32.0, 64.0],
            Self::SigmaGlo => vec![0.0, 0.02, 0.05, 0.1],
            Self::VisibilityBits | Self::FiberLobes | Self::ExposedStarts => vec![0.0, 1.0],
            Self::SegmentPaths => vec![0.0, 24.0, 48.0, 96.0, 192.0],
            Self::SegmentPool => vec![0.0, 0.25, 0.5, 1.0],
            Self::Seed => vec![1.0, 2.0, 3.0, 4.0],
        }
    }

    fn apply(self, value: f64, bake: &mut BakeSettings, frame: &mut FrameSettings) {
        let count = value.round().max(0.0) as usize;
        match self {
            Self::ShOrder => bake.sh_order = count,
            Self::PcaComponents => bake.pca_components = count,
            Self::VisibilityBits => bake.visibility_bits = value >= 0.5,
            Self::SvfResolution => bake.svf_resolution = count,
            Self::VisibilityPoints => bake.visibility_points = count,
            Self::SosCount => bake.sos_count = count,
            Self::SosSharpness => bake.sos_sharpness = value,
            Self::IirtfPaths => bake.iirtf_paths_per_cell = count,
            Self::LightSamples => bake.iirtf_light_samples = count,
            Self::CellSize => bake.cell_size_mfp = value,
            Self::CellDepth => bake.cell_depth_mfp = value,
            Self::Spp => frame.spp = count as u32,
            Self::SigmaGlo => frame.gpu.sigma_glo_cm = value,
            Self::FiberLobes => bake.fiber_lobes = value >= 0.5,
            Self::ExposedStarts => bake.exposed_starts = value >= 0.5,
            Self::SegmentPaths => bake.segment_transfer_paths = count,
            Self::SegmentPool => bake.segment_pool_mfp = value,
            Self::Seed => bake.seed = count as u64,
        }
    }

    /// Its value in these settings.
    #[must_use]
    pub fn value(self, bake: &BakeSettings, frame: &FrameSettings) -> f64 {
        match self {
            Self::ShOrder => bake.sh_order as f64,
            Self::PcaComponents => bake.pca_components as f64,
            Self::VisibilityBits => f64::from(u8::from(bake.visibility_bits)),
            Self::SvfResolution => bake.svf_resolution as f64,
            Self::VisibilityPoints => bake.visibility_points as f64,
            Self::SosCount => bake.sos_count as f64,
            Self::SosSharpness => bake.sos_sharpness,
            Self::IirtfPaths => bake.iirtf_paths_per_cell as f64,
            Self::LightSamples => bake.iirtf_light_samples as f64,
            Self::CellSize => bake.cell_size_mfp,
            Self::CellDepth => bake.cell_depth_mfp,
            Self::Spp => f64::from(frame.spp),
            Self::SigmaGlo => frame.gpu.sigma_glo_cm,
            Self::FiberLobes => f64::from(u8::from(bake.fiber_lobes)),
            Self::ExposedStarts => f64::from(u8::from(bake.exposed_starts)),
            Self::SegmentPaths => bake.segment_transfer_paths as f64,
            Self::SegmentPool => bake.segment_pool_mfp,
            Self::Seed => bake.seed as f64,
        }
    }
}

/// What a point is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PointKind {
    Preset(Quality),
    Knob { knob: Knob, value: f64 },
}

/// Which renderer a point measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// The GPU renderer (voxel-volume eye rays).
    Gpu,
    /// The CPU version of the method (exact fiber hits).
    Cpu,
}

/// What to run.
#[derive(Debug, Clone)]
pub struct SweepSettings {
    pub configurations: usize,
    /// Square image side in pixels.
    pub size: usize,
    /// Samples per pixel of a reference (with `reference_noise`, of its first pass).
    pub reference_spp: u32,
    /// The noise a reference is rendered down to: passes with fresh seeds, each doubling its
    /// samples, until the standard error of each component's image mean is at most this
    /// fraction of that mean ([`image_mean_noise`]; a component under a quarter of all light is
    /// held to a quarter of all light), or until `reference_max_spp`. `None`: `reference_spp`
    /// samples for every configuration.
    pub reference_noise: Option<f64>,
    /// The most samples per pixel a reference takes toward `reference_noise`.
    pub reference_max_spp: u32,
    /// Samples per pixel of the method's frames (the `spp` knob overrides it).
    pub method_spp: u32,
    /// The preset the knobs vary around.
    pub base: Quality,
    /// The bake settings the knobs vary around: `base`'s, or those with some knobs changed
    /// (`twill accuracy --set`).
    pub base_bake: BakeSettings,
    /// Presets measured as points of their own.
    pub presets: Vec<Quality>,
    /// Knobs and the values each is swept over.
    pub knobs: Vec<(Knob, Vec<f64>)>,
    /// Also measure the CPU method at each preset.
    pub cpu_method: bool,
    pub max_depth: u32,
    /// Configurations whose images are kept for the report (side by side with the reference).
    pub example_images: usize,
}

impl SweepSettings {
    fn validate(&self) -> Result<(), AccuracyError> {
        let bad = |what: String| Err(AccuracyError::Settings(what));
        if self.configurations == 0 || !(4..=1024).contains(&self.size) {
            return bad(format!(
                "need at least 1 configuration and an image side in 4..=1024 (got {} and {})",
                self.configurations, self.size
            ));
        }
        if self.reference_spp == 0 || self.method_spp == 0 {
            return bad("reference and method spp must be at least 1".into());
        }
        if let Some(noise) = self.reference_noise {
            if !(noise.is_finite() && noise > 0.0 && noise < 1.0) {
                return bad(format!(
                    "reference noise {noise}: must be in (0, 1), a fraction of the image mean"
                ));
            }
            if !(self.reference_spp..=MAX_REFERENCE_SPP).contains(&self.reference_max_spp) {
                return bad(format!(
                    "reference max spp {}: must be in {}..={MAX_REFERENCE_SPP} (at least the reference spp)",
                    self.reference_max_spp, self.reference_spp
                ));
            }
        }
        if self.presets.is_empty() && self.knobs.is_empty() {
            return bad("nothing to measure: give at least one preset or knob".into());
        }
        for (knob, values) in &self.knobs {
            let (mut bake, mut frame) = (self.base_bake, placeholder_frame());
            for &v in values {
                if !v.is_finite() {
                    return bad(format!("{}: value {v} is not finite", knob.name()));
                }
                knob.apply(v, &mut bake, &mut frame);
                bake.validate()?;
                frame.gpu.validate()?;
                if bake.sh_order > crate::fabric_data::MAX_SH_ORDER {
                    return bad(format!(
                        "sh_order {}: the GPU renderer holds SH order {} at most",
                        bake.sh_order,
                        crate::fabric_data::MAX_SH_ORDER
                    ));
                }
                if !(1..=4096).contains(&frame.spp) {
                    return bad(format!("spp {}: must be in 1..=4096", frame.spp));
                }
            }
        }
        Ok(())
    }
}

fn placeholder_frame() -> FrameSettings {
    FrameSettings {
        width: 1,
        height: 1,
        spp: 1,
        exposure: 0.0,
        filmic: true,
        components: Components::All,
        gpu: twill_precompute::scene::GpuSection::default(),
        frame_transfer: true,
    }
}

/// A fabric to measure on: a flat swatch scene (its camera and lights are replaced).
pub struct Fabric {
    pub name: String,
    pub scene: Scene,
}

/// One configuration's path-traced reference: mean and variance of the mean per pixel, per
/// component.
#[derive(Debug, Clone)]
pub struct Reference {
    pub single: Image,
    pub single_variance: Image,
    pub multiple: Image,
    pub multiple_variance: Image,
    /// Samples per pixel it was rendered with.
    pub spp: u32,
    /// Seconds it took to render (when it was rendered, not loaded).
    pub seconds: f64,
}

impl Reference {
    /// The standard error of `c`'s image mean and that mean's magnitude ([`image_mean_noise`]).
    fn noise(&self, c: ReportComponent) -> (f64, f64) {
        let (mean, variance) = self.component(c);
        image_mean_noise(&mean, &variance)
    }

    /// The standard error of `c`'s image mean relative to that mean.
    #[must_use]
    pub fn relative_noise(&self, c: ReportComponent) -> f64 {
        let (noise, magnitude) = self.noise(c);
        if magnitude > 0.0 { noise / magnitude } else { 0.0 }
    }

    /// Whether every component is as precise as `target` asks (`SweepSettings::reference_noise`).
    fn meets(&self, target: f64) -> bool {
        let (_, all) = self.noise(ReportComponent::All);
        [ReportComponent::Single, ReportComponent::Multiple].into_iter().all(|c| {
            let (noise, magnitude) = self.noise(c);
            noise <= target * magnitude.max(DIM_COMPONENT_SHARE * all)
        })
    }

    fn component(&self, c: ReportComponent) -> (Image, Image) {
        match c {
            ReportComponent::Single => (self.single.clone(), self.single_variance.clone()),
            ReportComponent::Multiple => (self.multiple.clone(), self.multiple_variance.clone()),
            ReportComponent::All => {
                (add(&self.single, &self.multiple), add(&self.single_variance, &self.multiple_variance))
            }
        }
    }
}

fn add(a: &Image, b: &Image) -> Image {
    Image {
        width: a.width,
        height: a.height,
        pixels: a.pixels.iter().zip(&b.pixels).map(|(x, y)| *x + *y).collect(),
    }
}

fn sub(a: &Image, b: &Image) -> Image {
    Image {
        width: a.width,
        height: a.height,
        pixels: a.pixels.iter().zip(&b.pixels).map(|(x, y)| *x - *y).collect(),
    }
}

/// The standard error of an image's mean over pixels, from each pixel's variance of its mean,
/// and the magnitude of that mean: both per channel, the channels averaged (the standard error
/// as an RMS over channels).
fn image_mean_noise(mean: &Image, variance: &Image) -> (f64, f64) {
    let pixels = variance.pixels.len().max(1) as f64;
    let variance_sum = variance.pixels.iter().map(|v| v.element_sum()).sum::<f64>() / 3.0;
    (variance_sum.sqrt() / pixels, mean.mean().element_sum().abs() / 3.0)
}

/// Path-traced references on disk: one file per fabric and configuration.
#[derive(Debug)]
pub struct ReferenceCache {
    dir: PathBuf,
}

const REFERENCE_MAGIC: &[u8; 8] = b"TWILLREF";

impl ReferenceCache {
    /// Uses `dir`, creating it if missing.
    pub fn new(dir: &Path) -> io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        Ok(Self { dir: dir.to_owned() })
    }

    fn key(scene: &Scene, config: &HardConfiguration, settings: &SweepSettings, seed: u64) -> ContentHash {
        let mut h = Hasher::new("twill.accuracy.reference");
        h.u32(REFERENCE_VERSION).exemplar(&scene.exemplar);
        for m in &scene.material_descs {
            h.str(&format!("{m:?}"));
        }
        h.bool(scene.path_scene.ground_z.is_some()).f64(scene.path_scene.ground_z.unwrap_or(0.0));
        h.f64s(&scene.swatch.size_cm).str(&format!("{:?}", scene.camera));
        match config.light {
            Light::Directional { to_light, irradiance } => {
                h.u32(0).f64s(&to_light.to_array()).f64s(&irradiance.to_array());
            }
            Light::Sg { axis, sharpness, intensity } => {
                h.u32(1).f64s(&axis.to_array()).f64(sharpness).f64s(&intensity.to_array());
            }
        }
        h.usize(settings.size).u32(settings.reference_spp).u32(settings.max_depth).u64(seed);
        match settings.reference_noise {
            Some(noise) => h.u32(1).f64(noise).u32(settings.reference_max_spp),
            None => h.u32(0),
        };
        h.finish()
    }

    fn path(&self, key: ContentHash) -> PathBuf {
        self.dir.join(format!("{}.ref", key.to_hex()))
    }

    /// The stored reference for `key`, or `None` when missing or not a valid file for it.
    fn load(&self, key: ContentHash, size: usize) -> Option<Reference> {
        let mut bytes = Vec::new();
        std::fs::File::open(self.path(key)).ok()?.read_to_end(&mut bytes).ok()?;
        let images = 4 * size * size * 3 * 4;
        if bytes.len() != 8 + 32 + 8 + 4 + images + 32
            || &bytes[..8] != REFERENCE_MAGIC
            || bytes[8..40] != key.0
        {
            return None;
        }
        let (payload, checksum) = bytes.split_at(bytes.len() - 32);
        if Hasher::new("twill.accuracy.reference.file").bytes(payload).finish().0 != checksum {
            return None;
        }
        let seconds = f64::from_le_bytes(payload[40..48].try_into().ok()?);
        let spp = u32::from_le_bytes(payload[48..52].try_into().ok()?);
        let mut floats =
            payload[52..].chunks_exact(4).map(|c| f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])));
        let mut image = || {
            let mut out = Image::new(size, size);
            for p in &mut out.pixels {
                *p = Rgb::new(floats.next()?, floats.next()?, floats.next()?);
            }
            Some(out)
        };
        Some(Reference {
            single: image()?,
            single_variance: image()?,
            multiple: image()?,
            multiple_variance: image()?,
            spp,
            seconds,
        })
    }

    fn store(&self, key: ContentHash, reference: &Reference) -> io::Result<()> {
        let mut payload = Vec::new();
        payload.extend_from_slice(REFERENCE_MAGIC);
        payload.extend_from_slice(&key.0);
        payload.extend_from_slice(&reference.seconds.to_le_bytes());
        payload.extend_from_slice(&reference.spp.to_le_bytes());
        for image in
            [&reference.single, &reference.single_variance, &reference.multiple, &reference.multiple_variance]
        {
            for p in &image.pixels {
                for v in p.to_array() {
                    payload.extend_from_slice(&(v as f32).to_le_bytes());
                }
            }
        }
        let checksum = Hasher::new("twill.accuracy.reference.file").bytes(&payload).finish();
        write_atomically(&self.path(key), |w| {
            w.write_all(&payload)?;
            w.write_all(&checksum.0)
        })
    }
}

/// The three components errors are reported for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReportComponent {
    Single,
    Multiple,
    All,
}

impl ReportComponent {
    pub const ALL: [ReportComponent; 3] = [Self::Single, Self::Multiple, Self::All];

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Single => "single",
            Self::Multiple => "multiple",
            Self::All => "all",
        }
    }
}

/// One component's errors over all configurations of one fabric.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ComponentErrors {
    /// RMSE of the image-average intensity over configurations and channels, over the RMS of
    /// the reference averages (Fig. 13), with the reference's noise subtracted.
    pub mean_relative_rmse: f64,
    /// The configuration with the largest |relative error| of its image mean: that error.
    pub worst_relative: f64,
    pub worst_configuration: usize,
    /// Per-pixel RMSE over the RMS of the reference averages, reference noise subtracted.
    pub pixel_relative_rmse: f64,
    /// Path-tracer samples per pixel whose noise equals the per-pixel error.
    pub equal_error_spp: f64,
    /// Mean SSIM of tone-mapped luminance (1: identical).
    pub ssim: f64,
}

/// One point on one fabric.
#[derive(Debug, Clone)]
pub struct FabricResult {
    /// Time per bake stage as computed in this run (seconds).
    pub stage_seconds: Vec<(Stage, f64)>,
    /// Median wall time of a frame of all light (seconds).
    pub frame_seconds: f64,
    /// Median GPU milliseconds per pass (empty without timestamp queries, or for the CPU method).
    pub pass_ms: Vec<(String, f64)>,
    /// GPU memory the renderer holds (bytes; 0 for the CPU method).
    pub resident_bytes: u64,
    /// Errors per [`ReportComponent`], in `ReportComponent::ALL` order.
    pub errors: [ComponentErrors; 3],
    /// Relative error of each configuration's image mean, per component.
    pub configuration_errors: Vec<[f64; 3]>,
    /// The same per channel (red, green, blue), per component: where a figure over channels
    /// (Fig. 13's) and one over their sum part, the colour is wrong.
    pub configuration_channel_errors: Vec<[DVec3; 3]>,
    /// Each configuration's reference image mean (the mean over pixels and channels), per
    /// component: the weight a configuration has in the Fig. 13 figure.
    pub configuration_reference_means: Vec<[f64; 3]>,
    /// The first `example_images` configurations' images of all light.
    pub images: Vec<Image>,
}

impl FabricResult {
    #[must_use]
    pub fn bake_seconds(&self) -> f64 {
        self.stage_seconds.iter().map(|(_, s)| s).sum()
    }
}

/// One point of the sweep: settings and results per fabric.
#[derive(Debug, Clone)]
pub struct Point {
    pub label: String,
    pub kind: PointKind,
    pub method: Method,
    pub bake: BakeSettings,
    pub spp: u32,
    pub sigma_glo_cm: f64,
    /// In [`Sweep::fabrics`] order.
    pub fabrics: Vec<FabricResult>,
}

impl Point {
    /// The value `knob` had at this point.
    #[must_use]
    pub fn value_of(&self, knob: Knob) -> f64 {
        let mut frame = placeholder_frame();
        (frame.spp, frame.gpu.sigma_glo_cm) = (self.spp, self.sigma_glo_cm);
        knob.value(&self.bake, &frame)
    }

    /// The mean over fabrics of `f` of each fabric's result.
    pub fn mean_over_fabrics(&self, f: impl Fn(&FabricResult) -> f64) -> f64 {
        self.fabrics.iter().map(f).sum::<f64>() / self.fabrics.len().max(1) as f64
    }

    /// The worst configuration's relative error of all light over every fabric (signed).
    #[must_use]
    pub fn worst_error(&self) -> f64 {
        self.worst().0
    }

    /// The worst configuration of all light over every fabric: its relative error (signed),
    /// its fabric's index and its index.
    #[must_use]
    pub fn worst(&self) -> (f64, usize, usize) {
        self.fabrics
            .iter()
            .enumerate()
            .map(|(i, f)| (f.errors[2].worst_relative, i, f.errors[2].worst_configuration))
            .max_by(|a, b| a.0.abs().total_cmp(&b.0.abs()))
            .unwrap_or((0.0, 0, 0))
    }

    /// Fig. 13 error of all light, averaged over fabrics.
    #[must_use]
    pub fn error(&self) -> f64 {
        self.mean_over_fabrics(|f| f.errors[2].mean_relative_rmse)
    }

    /// Per-pixel relative RMSE of all light, averaged over fabrics.
    #[must_use]
    pub fn pixel_error(&self) -> f64 {
        self.mean_over_fabrics(|f| f.errors[2].pixel_relative_rmse)
    }

    /// Mean frame time over fabrics, milliseconds.
    #[must_use]
    pub fn frame_ms(&self) -> f64 {
        1e3 * self.mean_over_fabrics(|f| f.frame_seconds)
    }

    /// Mean bake time over fabrics, seconds.
    #[must_use]
    pub fn bake_seconds(&self) -> f64 {
        self.mean_over_fabrics(FabricResult::bake_seconds)
    }
}

/// Per fabric: its references' summary.
#[derive(Debug, Clone)]
pub struct FabricReferences {
    pub name: String,
    /// Seconds per sample per image of the path tracer (both components).
    pub path_seconds_per_spp: f64,
    /// How many references were loaded from the cache (the rest were rendered).
    pub loaded: usize,
    /// RMS of the reference image averages per component (the scale of relative errors).
    pub rms: [f64; 3],
    /// Reference noise relative to `rms`: image average and per pixel, per component.
    pub average_noise: [f64; 3],
    pub pixel_noise: [f64; 3],
    /// Each configuration's reference noise: the standard error of its image mean relative to
    /// that mean ([`Reference::relative_noise`]), per component.
    pub configuration_noise: Vec<[f64; 3]>,
    /// Each configuration's reference samples per pixel.
    pub configuration_spp: Vec<u32>,
    /// The example configurations' reference images (all light).
    pub images: Vec<Image>,
}

/// Everything measured.
#[derive(Debug, Clone)]
pub struct Sweep {
    pub settings: SweepSettings,
    pub configurations: Vec<HardConfiguration>,
    pub fabrics: Vec<FabricReferences>,
    pub points: Vec<Point>,
    /// The device the GPU frames ran on.
    pub adapter: String,
}

struct Prepared<'a> {
    fabric: &'a mut Fabric,
    references: Vec<Reference>,
}

/// Per-pixel statistics of one method image against one reference.
fn compare(image: &Image, reference: &Image, variance: &Image) -> (DVec3, DVec3, f64, f64, f64) {
    let n = image.pixels.len().max(1) as f64;
    let mse =
        image.pixels.iter().zip(&reference.pixels).map(|(a, b)| (*a - *b).length_squared()).sum::<f64>()
            / (3.0 * n);
    let noise = variance.pixels.iter().map(|v| v.element_sum()).sum::<f64>() / (3.0 * n);
    (image.mean(), reference.mean(), mse, noise, ssim(image, reference))
}

/// SSIM (Wang et al. 2004, 8x8 windows with stride 4, C1 = 0.01², C2 = 0.03²) of the luminance
/// of two linear images, both tone-mapped with the reference's exposure: scaled so the
/// reference's mean luminance is 0.18, then x / (1 + x).
#[must_use]
pub fn ssim(image: &Image, reference: &Image) -> f64 {
    let luminance = |p: Rgb| 0.2126 * p.x + 0.7152 * p.y + 0.0722 * p.z;
    let mean =
        reference.pixels.iter().map(|&p| luminance(p)).sum::<f64>() / reference.pixels.len().max(1) as f64;
    let scale = if mean > 0.0 { 0.18 / mean } else { 1.0 };
    let tone = |p: Rgb| {
        let x = (luminance(p) * scale).max(0.0);
        x / (1.0 + x)
    };
    let (a, b): (Vec<f64>, Vec<f64>) =
        image.pixels.iter().zip(&reference.pixels).map(|(&p, &q)| (tone(p), tone(q))).unzip();
    let (w, h) = (image.width, image.height);
    let window = 8.min(w).min(h);
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let starts = |n: usize| (0..=n - window).step_by(4.min(window).max(1)).collect::<Vec<_>>();
    let (mut total, mut count) = (0.0, 0usize);
    for &y0 in &starts(h) {
        for &x0 in &starts(w) {
            let index = |x: usize, y: usize| (y0 + y) * w + x0 + x;
            let pixels = (window * window) as f64;
            let (mut ma, mut mb) = (0.0, 0.0);
            for y in 0..window {
                for x in 0..window {
                    ma += a[index(x, y)];
                    mb += b[index(x, y)];
                }
            }
            (ma, mb) = (ma / pixels, mb / pixels);
            let (mut va, mut vb, mut cov) = (0.0, 0.0, 0.0);
            for y in 0..window {
                for x in 0..window {
                    let (da, db) = (a[index(x, y)] - ma, b[index(x, y)] - mb);
                    va += da * da;
                    vb += db * db;
                    cov += da * db;
                }
            }
            let d = (pixels - 1.0).max(1.0);
            (va, vb, cov) = (va / d, vb / d, cov / d);
            total += ((2.0 * ma * mb + c1) * (2.0 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            count += 1;
        }
    }
    total / count.max(1) as f64
}

/// Errors of one component over all configurations: `images[i]` against reference `i`,
/// rendered with `reference_spp[i]` samples per pixel.
fn component_errors(
    images: &[Image],
    references: &[(Image, Image)],
    reference_spp: &[u32],
) -> (ComponentErrors, Vec<(f64, f64, DVec3)>) {
    let n = images.len().max(1) as f64;
    let (mut avg_sq, mut ref_sq, mut avg_noise, mut pixel_sq, mut pixel_noise, mut ssim_sum) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    // The per-pixel variance of one path-traced sample, summed over configurations.
    let mut sample_variance = 0.0;
    let mut relative = Vec::with_capacity(images.len());
    for ((image, (reference, variance)), &spp) in images.iter().zip(references).zip(reference_spp) {
        let (mean, ref_mean, mse, noise, s) = compare(image, reference, variance);
        sample_variance += noise * f64::from(spp);
        avg_sq += (mean - ref_mean).length_squared() / 3.0;
        ref_sq += ref_mean.length_squared() / 3.0;
        let pixels = variance.pixels.len().max(1) as f64;
        avg_noise += variance.pixels.iter().map(|v| v.element_sum()).sum::<f64>() / (3.0 * pixels * pixels);
        pixel_sq += mse;
        pixel_noise += noise;
        ssim_sum += s;
        let (m, r) = (mean.element_sum(), ref_mean.element_sum());
        let relative_to = |a: f64, b: f64| if b > 0.0 { a / b - 1.0 } else { 0.0 };
        let per_channel = DVec3::new(
            relative_to(mean.x, ref_mean.x),
            relative_to(mean.y, ref_mean.y),
            relative_to(mean.z, ref_mean.z),
        );
        relative.push((relative_to(m, r), r / 3.0, per_channel));
    }
    let rms = (ref_sq / n).sqrt().max(1e-300);
    let pixel_excess = ((pixel_sq - pixel_noise) / n).max(0.0);
    let worst = relative
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.0.abs().total_cmp(&b.1.0.abs()))
        .map_or((0, 0.0), |(i, &(e, _, _))| (i, e));
    let errors = ComponentErrors {
        mean_relative_rmse: ((avg_sq - avg_noise) / n).max(0.0).sqrt() / rms,
        worst_relative: worst.1,
        worst_configuration: worst.0,
        pixel_relative_rmse: pixel_excess.sqrt() / rms,
        // Each reference's per-pixel variance at its spp times that spp: one sample's variance.
        equal_error_spp: if pixel_excess > 0.0 { sample_variance / n / pixel_excess } else { f64::INFINITY },
        ssim: ssim_sum / n,
    };
    (errors, relative)
}

/// Runs the sweep over `fabrics` (flat swatch scenes). References are read from and written to
/// `references`; bake stages go through `stage_cache` (a fresh folder keeps every stage's time
/// measured in this run). `progress` gets one line per step.
pub fn run(
    fabrics: &mut [Fabric],
    gpu: Gpu,
    settings: &SweepSettings,
    references: &ReferenceCache,
    stage_cache: &Cache,
    progress: &dyn Fn(&str),
) -> Result<Sweep, AccuracyError> {
    settings.validate()?;
    let configurations = hard_configurations(settings.configurations)?;
    let size = settings.size;
    let adapter = gpu.describe();
    let mut prepared = Vec::with_capacity(fabrics.len());
    let mut summaries = Vec::with_capacity(fabrics.len());
    for fabric in fabrics.iter_mut() {
        (fabric.scene.render.width, fabric.scene.render.height) = (size, size);
        let (refs, summary) = reference_set(fabric, &configurations, settings, references, progress)?;
        summaries.push(summary);
        prepared.push(Prepared { fabric, references: refs });
    }

    let mut points = Vec::new();
    let base_frame = |scene: &Scene| {
        let mut f = frame_settings(scene, Components::All);
        (f.width, f.height, f.spp) = (size as u32, size as u32, settings.method_spp);
        f
    };
    let mut plans: Vec<(String, PointKind, BakeSettings)> = Vec::new();
    for &q in &settings.presets {
        plans.push((format!("preset {}", q.name()), PointKind::Preset(q), q.settings()));
    }
    for &(knob, ref values) in &settings.knobs {
        for &value in values {
            let mut bake_settings = settings.base_bake;
            knob.apply(value, &mut bake_settings, &mut placeholder_frame());
            if !knob.acts_on(&bake_settings) {
                continue;
            }
            plans.push((
                format!("{} = {value}", knob.name()),
                PointKind::Knob { knob, value },
                bake_settings,
            ));
        }
    }
    let mut stage_times: Vec<(ContentHash, f64)> = Vec::new();
    let mut session: Option<(SceneRenderer, usize, ContentHash)> = None;
    let mut gpu = Some(gpu);
    let total = plans.len();
    for (index, (label, kind, bake_settings)) in plans.iter().enumerate() {
        progress(&format!("point {}/{total}: {label}", index + 1));
        let mut gpu_point = Point {
            label: label.clone(),
            kind: *kind,
            method: Method::Gpu,
            bake: *bake_settings,
            spp: 0,
            sigma_glo_cm: 0.0,
            fabrics: Vec::new(),
        };
        let mut cpu_point = gpu_point.clone();
        cpu_point.method = Method::Cpu;
        cpu_point.label = format!("{label} (CPU method)");
        for (fabric_index, p) in prepared.iter_mut().enumerate() {
            let scene = &mut p.fabric.scene;
            let PointBake { baked, stage_seconds, key } =
                bake_point(scene, *bake_settings, stage_cache, &mut stage_times)?;
            let mut frame = base_frame(scene);
            if let PointKind::Knob { knob, value } = *kind {
                // Bake knobs were applied above; this applies frame knobs.
                knob.apply(value, &mut bake_settings.clone(), &mut frame);
            }
            (gpu_point.spp, gpu_point.sigma_glo_cm) = (frame.spp, frame.gpu.sigma_glo_cm);
            // One device, re-uploaded only when the fabric or bake changes.
            let reuse = matches!(&session, Some((_, f, k)) if *f == fabric_index && *k == key);
            if !reuse {
                let device = match session.take() {
                    Some((s, _, _)) => s.gpu,
                    None => gpu.take().expect("the device is held by the session or here"),
                };
                session = Some((
                    SceneRenderer::with_gpu(device, scene, &[&baked], &PatternMap::uniform(0))?,
                    fabric_index,
                    key,
                ));
            }
            let renderer = &mut session.as_mut().expect("opened above").0;
            let result = gpu_fabric(
                renderer,
                scene,
                &configurations,
                &p.references,
                &frame,
                stage_seconds.clone(),
                settings,
            )?;
            gpu_point.fabrics.push(result);
            if settings.cpu_method && matches!(kind, PointKind::Preset(_)) {
                cpu_point.fabrics.push(cpu_fabric(
                    scene,
                    &baked,
                    &configurations,
                    &p.references,
                    stage_seconds,
                    settings,
                )?);
            }
        }
        (cpu_point.spp, cpu_point.sigma_glo_cm) = (settings.method_spp, 0.0);
        points.push(gpu_point);
        if !cpu_point.fabrics.is_empty() {
            points.push(cpu_point);
        }
    }
    Ok(Sweep { settings: settings.clone(), configurations, fabrics: summaries, points, adapter })
}

/// A bake of one point, with each stage's time and the bake's key.
struct PointBake {
    baked: Baked,
    stage_seconds: Vec<(Stage, f64)>,
    key: ContentHash,
}

/// Bakes `scene` through the stage cache; returns the bake, each stage's time as measured when
/// it was computed in this run, and the bake's key.
fn bake_point(
    scene: &Scene,
    settings: BakeSettings,
    cache: &Cache,
    stage_times: &mut Vec<(ContentHash, f64)>,
) -> Result<PointBake, AccuracyError> {
    let inputs = BakeInputs { exemplar: &scene.exemplar, materials: &scene.material_descs, settings };
    let outcome = bake(&inputs, Some(cache), &Cancel::new(), &|_, _| {})
        .map_err(|e| AccuracyError::Settings(format!("bake failed: {e}")))?;
    let mut seconds = Vec::with_capacity(outcome.stages.len());
    for run in &outcome.stages {
        let s = match run.source {
            StageSource::Computed => {
                stage_times.push((run.key, run.seconds));
                run.seconds
            }
            // Computed earlier in this run (the cache folder is this run's own), else unknown.
            _ => stage_times.iter().find(|(k, _)| *k == run.key).map_or(f64::NAN, |(_, s)| *s),
        };
        seconds.push((run.stage, s));
    }
    Ok(PointBake { baked: outcome.baked, stage_seconds: seconds, key: outcome.key })
}

/// The references of every configuration of one fabric, loaded or rendered.
fn reference_set(
    fabric: &mut Fabric,
    configurations: &[HardConfiguration],
    settings: &SweepSettings,
    cache: &ReferenceCache,
    progress: &dyn Fn(&str),
) -> Result<(Vec<Reference>, FabricReferences), AccuracyError> {
    let size = settings.size;
    let mut out = Vec::with_capacity(configurations.len());
    let (mut loaded, mut seconds, mut rendered_spp) = (0, 0.0, 0u64);
    for (index, config) in configurations.iter().enumerate() {
        let scene = &mut fabric.scene;
        scene.camera = camera_for(config.view);
        scene.path_scene.lights = vec![config.light];
        let seed = 1 + index as u64;
        let key = ReferenceCache::key(scene, config, settings, seed);
        if let Some(reference) = cache.load(key, size) {
            loaded += 1;
            seconds += reference.seconds;
            rendered_spp += u64::from(reference.spp);
            out.push(reference);
            continue;
        }
        progress(&format!(
            "{}: reference {}/{} ({})",
            fabric.name,
            index + 1,
            configurations.len(),
            config.describe()
        ));
        let camera = camera_from(&scene.camera, size, size)?;
        let started = Instant::now();
        let render = |component, spp, pass: u64| {
            // Pass 0 keeps the configuration's seed (a reference without a noise target is
            // that pass alone); later passes draw from streams of their own.
            let seed = seed ^ pass.wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let s = RenderSettings { spp, max_depth: settings.max_depth, component, seed };
            pathtrace::render(&scene.path_scene, &camera, &s, &|_| {})
        };
        let (mut single, mut multiple) = (
            render(Component::Single, settings.reference_spp, 0),
            render(Component::Multiple, settings.reference_spp, 0),
        );
        let mut spp = settings.reference_spp;
        let reference = loop {
            let reference = Reference {
                single: single.mean(),
                single_variance: single.variance_of_mean(),
                multiple: multiple.mean(),
                multiple_variance: multiple.variance_of_mean(),
                spp,
                seconds: started.elapsed().as_secs_f64(),
            };
            let Some(target) = settings.reference_noise else { break reference };
            // Doubling: the next pass takes as many samples as all before it, within the cap.
            let more = spp.min(settings.reference_max_spp - spp);
            if more == 0 || reference.meets(target) {
                break reference;
            }
            let pass = u64::from(spp / settings.reference_spp);
            single.merge(&render(Component::Single, more, pass));
            multiple.merge(&render(Component::Multiple, more, pass));
            spp += more;
        };
        seconds += reference.seconds;
        rendered_spp += u64::from(reference.spp);
        cache.store(key, &reference).map_err(|e| {
            AccuracyError::Settings(format!("{}: could not store a reference: {e}", cache.dir.display()))
        })?;
        out.push(reference);
    }
    let n = out.len().max(1) as f64;
    let mut rms = [0.0; 3];
    let mut average_noise = [0.0; 3];
    let mut pixel_noise = [0.0; 3];
    for (c, component) in ReportComponent::ALL.into_iter().enumerate() {
        let (mut sq, mut avg_var, mut px_var) = (0.0, 0.0, 0.0);
        for r in &out {
            let (mean, variance) = r.component(component);
            let pixels = variance.pixels.len().max(1) as f64;
            let var_sum = variance.pixels.iter().map(|v| v.element_sum()).sum::<f64>() / 3.0;
            sq += mean.mean().length_squared() / 3.0;
            avg_var += var_sum / (pixels * pixels);
            px_var += var_sum / pixels;
        }
        rms[c] = (sq / n).sqrt();
        average_noise[c] = (avg_var / n).sqrt() / rms[c].max(1e-300);
        pixel_noise[c] = (px_var / n).sqrt() / rms[c].max(1e-300);
    }
    let images = out.iter().take(settings.example_images).map(|r| add(&r.single, &r.multiple)).collect();
    let configuration_noise = out.iter().map(|r| ReportComponent::ALL.map(|c| r.relative_noise(c))).collect();
    let configuration_spp = out.iter().map(|r| r.spp).collect();
    let summary = FabricReferences {
        name: fabric.name.clone(),
        path_seconds_per_spp: seconds / (rendered_spp.max(1) as f64),
        loaded,
        rms,
        average_noise,
        pixel_noise,
        configuration_noise,
        configuration_spp,
        images,
    };
    Ok((out, summary))
}

/// One method's errors on one fabric: over all configurations and per configuration (the
/// fields of [`FabricResult`] of the same names).
struct Summary {
    errors: [ComponentErrors; 3],
    configuration_errors: Vec<[f64; 3]>,
    configuration_reference_means: Vec<[f64; 3]>,
    configuration_channel_errors: Vec<[DVec3; 3]>,
}

fn summarize(all: &[Image], single: &[Image], references: &[Reference]) -> Summary {
    let multiple: Vec<Image> = all.iter().zip(single).map(|(a, s)| sub(a, s)).collect();
    let mut errors = [ComponentErrors::default(); 3];
    let mut per_config = vec![[0.0; 3]; all.len()];
    let mut reference_means = vec![[0.0; 3]; all.len()];
    let mut per_channel = vec![[DVec3::ZERO; 3]; all.len()];
    let spp: Vec<u32> = references.iter().map(|r| r.spp).collect();
    for (c, (component, images)) in ReportComponent::ALL.into_iter().zip([single, &multiple, all]).enumerate()
    {
        let refs: Vec<(Image, Image)> = references.iter().map(|r| r.component(component)).collect();
        let (e, relative) = component_errors(images, &refs, &spp);
        errors[c] = e;
        for (((row, means), channels), (r, mean, channel)) in
            per_config.iter_mut().zip(&mut reference_means).zip(&mut per_channel).zip(relative)
        {
            row[c] = r;
            means[c] = mean;
            channels[c] = channel;
        }
    }
    Summary {
        errors,
        configuration_errors: per_config,
        configuration_reference_means: reference_means,
        configuration_channel_errors: per_channel,
    }
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(f64::NAN)
}

/// The GPU renderer on every configuration of one fabric.
fn gpu_fabric(
    session: &mut SceneRenderer,
    scene: &mut Scene,
    configurations: &[HardConfiguration],
    references: &[Reference],
    frame: &FrameSettings,
    stage_seconds: Vec<(Stage, f64)>,
    settings: &SweepSettings,
) -> Result<FabricResult, AccuracyError> {
    let (mut all, mut single) = (Vec::new(), Vec::new());
    let mut wall = Vec::new();
    let mut passes: Vec<(String, Vec<f64>)> = Vec::new();
    for config in configurations {
        scene.camera = camera_for(config.view);
        scene.path_scene.lights = vec![config.light];
        let started = Instant::now();
        let out = session.render(scene, frame)?;
        wall.push(started.elapsed().as_secs_f64());
        for t in out.timings.iter().flatten() {
            match passes.iter_mut().find(|(name, _)| *name == t.pass) {
                Some((_, v)) => v.push(t.milliseconds),
                None => passes.push((t.pass.clone(), vec![t.milliseconds])),
            }
        }
        all.push(out.radiance_image());
        let single_frame = FrameSettings { components: Components::SingleOnly, ..*frame };
        single.push(session.render(scene, &single_frame)?.radiance_image());
    }
    let Summary { errors, configuration_errors, configuration_reference_means, configuration_channel_errors } =
        summarize(&all, &single, references);
    Ok(FabricResult {
        stage_seconds,
        frame_seconds: median(&mut wall),
        pass_ms: passes.into_iter().map(|(name, mut v)| (name, median(&mut v))).collect(),
        resident_bytes: session.renderer.resident_bytes(),
        errors,
        configuration_errors,
        configuration_channel_errors,
        configuration_reference_means,
        images: all.into_iter().take(settings.example_images).collect(),
    })
}

/// The CPU method (exact fiber hits) on every configuration of one fabric.
fn cpu_fabric(
    scene: &mut Scene,
    baked: &Baked,
    configurations: &[HardConfiguration],
    references: &[Reference],
    stage_seconds: Vec<(Stage, f64)>,
    settings: &SweepSettings,
) -> Result<FabricResult, AccuracyError> {
    let (mut all, mut single) = (Vec::new(), Vec::new());
    let mut wall = Vec::new();
    for (index, config) in configurations.iter().enumerate() {
        scene.camera = camera_for(config.view);
        scene.path_scene.lights = vec![config.light];
        let seed = 1 + index as u64;
        let started = Instant::now();
        let s = render_flat(scene, baked, Component::Single, settings.method_spp, seed)?.mean();
        let m = render_flat(scene, baked, Component::Multiple, settings.method_spp, seed)?.mean();
        wall.push(started.elapsed().as_secs_f64());
        all.push(add(&s, &m));
        single.push(s);
    }
    let Summary { errors, configuration_errors, configuration_reference_means, configuration_channel_errors } =
        summarize(&all, &single, references);
    Ok(FabricResult {
        stage_seconds,
        frame_seconds: median(&mut wall),
        pass_ms: Vec::new(),
        resident_bytes: 0,
        errors,
        configuration_errors,
        configuration_channel_errors,
        configuration_reference_means,
        images: all.into_iter().take(settings.example_images).collect(),
    })
}

impl Sweep {
    /// Whether each point is on the Pareto front of (error, frame time, bake time) among the
    /// points of its method (the CPU method's frame times are not comparable with the GPU's).
    #[must_use]
    pub fn pareto(&self) -> Vec<bool> {
        let key = |p: &Point| [p.error(), p.frame_ms(), p.bake_seconds()];
        let keys: Vec<[f64; 3]> = self.points.iter().map(key).collect();
        let dominates = |b: &[f64; 3], a: &[f64; 3]| {
            b.iter().zip(a).all(|(x, y)| x <= y) && b.iter().zip(a).any(|(x, y)| x < y)
        };
        (0..keys.len())
            .map(|i| {
                !(0..keys.len())
                    .any(|j| self.points[j].method == self.points[i].method && dominates(&keys[j], &keys[i]))
            })
            .collect()
    }

    /// One CSV row per point and fabric, with a header.
    #[must_use]
    pub fn csv(&self) -> String {
        let mut out = String::from(
            "fabric,point,method,knob,value,preset,pareto,bake_s,frame_ms,gpu_resident_mb,spp,sigma_glo_cm,sh_order,pca_components,svf_resolution,visibility_points,sos_count,sos_sharpness,iirtf_paths_per_cell,cell_size_mfp,cell_depth_mfp",
        );
        for stage in Stage::ALL {
            let _ = write!(out, ",stage_{}_s", stage.name());
        }
        for c in ReportComponent::ALL {
            let n = c.name();
            let _ = write!(
                out,
                ",{n}_mean_rel_rmse,{n}_worst_rel,{n}_worst_config,{n}_pixel_rel_rmse,{n}_equal_error_spp,{n}_ssim"
            );
        }
        out.push_str(",gpu_pass_ms\n");
        let pareto = self.pareto();
        for (point, on_front) in self.points.iter().zip(pareto) {
            let (knob, value, preset) = match point.kind {
                PointKind::Preset(q) => (String::new(), String::new(), q.name().to_owned()),
                PointKind::Knob { knob, value } => {
                    (knob.name().to_owned(), format!("{value}"), String::new())
                }
            };
            let method = match point.method {
                Method::Gpu => "gpu",
                Method::Cpu => "cpu",
            };
            for (fabric, result) in self.fabrics.iter().zip(&point.fabrics) {
                let b = &point.bake;
                let _ = write!(
                    out,
                    "{},{},{method},{knob},{value},{preset},{on_front},{:.3},{:.2},{:.2},{},{},{},{},{},{},{},{},{},{},{}",
                    fabric.name,
                    point.label.replace(',', ";"),
                    result.bake_seconds(),
                    1e3 * result.frame_seconds,
                    result.resident_bytes as f64 / 1e6,
                    point.spp,
                    point.sigma_glo_cm,
                    b.sh_order,
                    b.pca_components,
                    b.svf_resolution,
                    b.visibility_points,
                    b.sos_count,
                    b.sos_sharpness,
                    b.iirtf_paths_per_cell,
                    b.cell_size_mfp,
                    b.cell_depth_mfp
                );
                for stage in Stage::ALL {
                    let s = result
                        .stage_seconds
                        .iter()
                        .find(|(st, _)| *st == stage)
                        .map_or(f64::NAN, |(_, s)| *s);
                    let _ = write!(out, ",{s:.3}");
                }
                for e in &result.errors {
                    let _ = write!(
                        out,
                        ",{:.5},{:.5},{},{:.5},{:.2},{:.4}",
                        e.mean_relative_rmse,
                        e.worst_relative,
                        e.worst_configuration,
                        e.pixel_relative_rmse,
                        e.equal_error_spp,
                        e.ssim
                    );
                }
                let passes: Vec<String> =
                    result.pass_ms.iter().map(|(name, ms)| format!("{name}: {ms:.2}")).collect();
                let _ = writeln!(out, ",{}", passes.join("; ").replace(',', " "));
            }
        }
        out
    }

    /// The mean signed relative error of the image mean per kind of configuration
    /// ([`HardConfiguration::class`]) for one point on one fabric: (class, count, [single,
    /// multiple, all]), in order of first appearance.
    #[must_use]
    pub fn errors_by_class(&self, point: &Point, fabric: usize) -> Vec<(&'static str, usize, [f64; 3])> {
        let mut out: Vec<(&'static str, usize, [f64; 3])> = Vec::new();
        let Some(result) = point.fabrics.get(fabric) else { return out };
        for (c, e) in self.configurations.iter().zip(&result.configuration_errors) {
            let i = out.iter().position(|(class, _, _)| *class == c.class).unwrap_or_else(|| {
                out.push((c.class, 0, [0.0; 3]));
                out.len() - 1
            });
            out[i].1 += 1;
            for (sum, value) in out[i].2.iter_mut().zip(e) {
                *sum += value;
            }
        }
        for (_, n, sums) in &mut out {
            for v in sums.iter_mut() {
                *v /= *n as f64;
            }
        }
        out
    }

    /// One CSV row per point, fabric and configuration: the relative error of the image mean
    /// per component and the reference's image mean (a configuration's weight in the Fig. 13
    /// figure), with the configuration's angles.
    #[must_use]
    pub fn configurations_csv(&self) -> String {
        let mut out = String::from(
            "fabric,point,method,configuration,class,view_deg,light,sharpness,light_deg,azimuth_apart_deg,single_rel,multiple_rel,all_rel,single_reference,multiple_reference,all_reference,single_rel_rgb,multiple_rel_rgb,all_rel_rgb,single_reference_noise,multiple_reference_noise,all_reference_noise,reference_spp\n",
        );
        let channels = |e: DVec3| format!("{:.5}/{:.5}/{:.5}", e.x, e.y, e.z);
        for point in &self.points {
            let method = if point.method == Method::Gpu { "gpu" } else { "cpu" };
            for (fabric, result) in self.fabrics.iter().zip(&point.fabrics) {
                let errors = result
                    .configuration_errors
                    .iter()
                    .zip(&result.configuration_reference_means)
                    .zip(&result.configuration_channel_errors);
                for (i, (c, ((e, m), rgb))) in self.configurations.iter().zip(errors).enumerate() {
                    let (kind, sharpness) = match c.light {
                        Light::Directional { .. } => ("directional", String::new()),
                        Light::Sg { sharpness, .. } => ("sg", format!("{sharpness:.2}")),
                    };
                    let l = c.light_direction();
                    let noise = fabric.configuration_noise.get(i).copied().unwrap_or([f64::NAN; 3]);
                    let _ = writeln!(
                        out,
                        "{},{},{method},{i},{},{:.1},{kind},{sharpness},{:.1},{:.1},{:.5},{:.5},{:.5},{:.6e},{:.6e},{:.6e},{},{},{},{:.5},{:.5},{:.5},{}",
                        fabric.name,
                        point.label.replace(',', ";"),
                        c.class.replace(',', ";"),
                        c.view.z.clamp(-1.0, 1.0).acos().to_degrees(),
                        l.z.clamp(-1.0, 1.0).acos().to_degrees(),
                        c.azimuth_apart_deg(),
                        e[0],
                        e[1],
                        e[2],
                        m[0],
                        m[1],
                        m[2],
                        channels(rgb[0]),
                        channels(rgb[1]),
                        channels(rgb[2]),
                        noise[0],
                        noise[1],
                        noise[2],
                        fabric.configuration_spp.get(i).copied().unwrap_or(0)
                    );
                }
            }
        }
        out
    }

    /// The presets' rows as a Markdown table (the README's headline table).
    #[must_use]
    pub fn headline_markdown(&self) -> String {
        let mut out = String::from(
            "| preset | method | image-mean error (Fig. 13), all / single / multiple | worst configuration | per-pixel error | equal to path tracing at | SSIM | frame | bake |\n|---|---|---|---|---|---|---|---|---|\n",
        );
        for p in self.points.iter().filter(|p| matches!(p.kind, PointKind::Preset(_))) {
            let mean = |c: usize, f: fn(&ComponentErrors) -> f64| p.mean_over_fabrics(|r| f(&r.errors[c]));
            let (worst, fabric, configuration) = p.worst();
            let worst_noise = self
                .fabrics
                .get(fabric)
                .and_then(|f| f.configuration_noise.get(configuration))
                .map_or(f64::NAN, |n| n[2]);
            let _ = writeln!(
                out,
                "| {} | {} | {:.1}% / {:.1}% / {:.1}% | {:+.1}% (reference ±{:.1}%) | {:.1}% | {:.0} spp | {:.3} | {:.0} ms | {:.1} s |",
                p.label.trim_start_matches("preset "),
                match p.method {
                    Method::Gpu => "GPU",
                    Method::Cpu => "CPU",
                },
                100.0 * mean(2, |e| e.mean_relative_rmse),
                100.0 * mean(0, |e| e.mean_relative_rmse),
                100.0 * mean(1, |e| e.mean_relative_rmse),
                100.0 * worst,
                100.0 * worst_noise,
                100.0 * mean(2, |e| e.pixel_relative_rmse),
                mean(2, |e| e.equal_error_spp),
                mean(2, |e| e.ssim),
                p.frame_ms(),
                p.bake_seconds()
            );
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hard_configurations_cover_grazing_and_backlit_within_their_cones() {
        let configs = hard_configurations(100).unwrap();
        assert_eq!(configs.len(), 100);
        let mut classes = std::collections::HashSet::new();
        for c in &configs {
            classes.insert(c.class);
            assert!((c.view.length() - 1.0).abs() < 1e-12);
            assert!(c.view.z >= 75f64.to_radians().cos() - 1e-12, "{}", c.describe());
            assert!(c.light_direction().z >= 80f64.to_radians().cos() - 1e-12, "{}", c.describe());
            if let Light::Sg { sharpness, .. } = c.light {
                assert!((2.0..=2000.0 + 1e-9).contains(&sharpness));
            }
        }
        for class in ["head-on", "grazing", "backlit", "grazing, backlit", "general"] {
            assert!(classes.contains(class), "no {class} configuration among {classes:?}");
        }
        let sharp = configs.iter().filter_map(|c| match c.light {
            Light::Sg { sharpness, .. } => Some(sharpness),
            Light::Directional { .. } => None,
        });
        let (lo, hi) = sharp.fold((f64::MAX, 0f64), |(lo, hi), s| (lo.min(s), hi.max(s)));
        assert!(lo < 5.0 && hi > 500.0, "SG sharpness spans {lo}..{hi}");
    }

    #[test]
    fn ssim_is_one_for_equal_images_and_falls_with_noise_and_bias() {
        let mut reference = Image::new(16, 16);
        for (i, p) in reference.pixels.iter_mut().enumerate() {
            *p = Rgb::splat(0.1 + 0.05 * ((i * 7919) % 13) as f64);
        }
        assert!((ssim(&reference, &reference) - 1.0).abs() < 1e-12);
        let mut darker = reference.clone();
        for p in &mut darker.pixels {
            *p *= 0.5;
        }
        let mut flat = reference.clone();
        let mean = reference.mean();
        for p in &mut flat.pixels {
            *p = mean;
        }
        let (s_dark, s_flat) = (ssim(&darker, &reference), ssim(&flat, &reference));
        assert!(s_dark < 0.99 && s_dark > 0.5, "{s_dark}");
        assert!(s_flat < 0.2, "structure lost: {s_flat}");
        assert!(ssim(&Image::new(16, 16), &Image::new(16, 16)).is_finite());
    }

    #[test]
    fn component_errors_subtract_reference_noise_and_find_the_worst_configuration() {
        let image = |v: f64| Image { width: 2, height: 2, pixels: vec![Rgb::splat(v); 4] };
        let references = vec![(image(1.0), image(0.0)), (image(2.0), image(0.0))];
        let (exact, _) = component_errors(&[image(1.0), image(2.0)], &references, &[16, 16]);
        assert!(exact.mean_relative_rmse.abs() < 1e-15 && exact.pixel_relative_rmse.abs() < 1e-15);
        assert!(exact.equal_error_spp.is_infinite());
        let (biased, relative) = component_errors(&[image(1.1), image(1.0)], &references, &[16, 16]);
        assert_eq!(biased.worst_configuration, 1);
        assert!((biased.worst_relative + 0.5).abs() < 1e-12);
        assert!((relative[0].0 - 0.1).abs() < 1e-12);
        // Each configuration's reference mean, per pixel and channel.
        assert!((relative[0].1 - 1.0).abs() < 1e-12 && (relative[1].1 - 2.0).abs() < 1e-12);
        // RMSE sqrt((0.01 + 1) / 2) over the RMS sqrt((1 + 4) / 2).
        assert!((biased.mean_relative_rmse - (1.01f64 / 5.0).sqrt()).abs() < 1e-12);
        // Noise in the reference is not counted as error.
        let noisy = vec![(image(1.0), image(0.01)), (image(2.0), image(0.01))];
        let (with_noise, _) = component_errors(&[image(1.1), image(2.1)], &noisy, &[16, 16]);
        assert!(with_noise.pixel_relative_rmse < biased.pixel_relative_rmse);
        assert!(with_noise.pixel_relative_rmse < 1e-6, "{}", with_noise.pixel_relative_rmse);
        // The equal-error spp weighs each reference's variance by its own spp: a pixel error
        // of 0.1 against one sample's variance (0.01 · 16 + 0.0025 · 64) / 2 = 0.16.
        let unequal = vec![(image(1.0), image(0.01)), (image(2.0), image(0.0025))];
        let (e, _) = component_errors(&[image(1.0 + 0.1), image(2.0 + 0.1)], &unequal, &[16, 64]);
        let excess = 0.01 - f64::midpoint(0.01, 0.0025);
        assert!(
            (e.equal_error_spp - 0.16 / excess).abs() < 1e-9 * e.equal_error_spp,
            "{}",
            e.equal_error_spp
        );
    }

    #[test]
    fn a_reference_meets_its_noise_target_on_each_component_a_dim_one_against_a_quarter_of_all() {
        let image = |v: f64| Image { width: 2, height: 2, pixels: vec![Rgb::splat(v); 4] };
        // Standard error of a 2x2 image's mean with each pixel's variance of its mean v: √(4v)/4.
        let reference = |single: f64, single_var: f64, multiple: f64, multiple_var: f64| Reference {
            single: image(single),
            single_variance: image(single_var),
            multiple: image(multiple),
            multiple_variance: image(multiple_var),
            spp: 16,
            seconds: 0.0,
        };
        // Single 1 ± 0.01, multiple 1 ± 0.05.
        let r = reference(1.0, 4e-4, 1.0, 1e-2);
        assert!((r.relative_noise(ReportComponent::Single) - 0.01).abs() < 1e-12);
        assert!((r.relative_noise(ReportComponent::Multiple) - 0.05).abs() < 1e-12);
        assert!(r.meets(0.0501) && !r.meets(0.0499), "the noisier component decides");
        // Multiple 0.01 ± 0.005 beside single 1: 50% of itself, but 2% of a quarter of all light.
        let dim = reference(1.0, 0.0, 0.01, 1e-4);
        assert!((dim.relative_noise(ReportComponent::Multiple) - 0.5).abs() < 1e-12);
        let quarter = 0.005 / (0.25 * 1.01);
        assert!(dim.meets(quarter * 1.001) && !dim.meets(quarter * 0.999));
    }

    #[test]
    fn a_stored_reference_loads_with_its_spp_and_a_damaged_file_is_rendered_again() {
        let dir = tempfile::tempdir().unwrap();
        let cache = ReferenceCache::new(dir.path()).unwrap();
        let image = |v: f64| Image { width: 4, height: 4, pixels: vec![Rgb::new(v, 2.0 * v, 0.5); 16] };
        let reference = Reference {
            single: image(1.0),
            single_variance: image(0.01),
            multiple: image(2.0),
            multiple_variance: image(0.02),
            spp: 1536,
            seconds: 3.5,
        };
        let key = Hasher::new("test").u32(7).finish();
        cache.store(key, &reference).unwrap();
        let loaded = cache.load(key, 4).expect("the stored reference loads");
        assert_eq!((loaded.spp, loaded.seconds), (1536, 3.5));
        assert_eq!(loaded.multiple.pixels, reference.multiple.pixels);
        assert!(cache.load(key, 5).is_none(), "another size is another file layout");
        assert!(cache.load(Hasher::new("test").u32(8).finish(), 4).is_none());
        let path = cache.path(key);
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[60] ^= 1;
        std::fs::write(&path, &bytes).unwrap();
        assert!(cache.load(key, 4).is_none(), "a checksum that does not match is not trusted");
    }

    #[test]
    fn a_reference_noise_target_outside_its_range_is_refused_with_the_range() {
        let settings = |noise: Option<f64>, max_spp: u32| SweepSettings {
            configurations: 4,
            size: 8,
            reference_spp: 64,
            reference_noise: noise,
            reference_max_spp: max_spp,
            method_spp: 4,
            base: Quality::Draft,
            base_bake: Quality::Draft.settings(),
            presets: vec![Quality::Draft],
            knobs: Vec::new(),
            cpu_method: false,
            max_depth: 8,
            example_images: 0,
        };
        assert!(settings(None, 0).validate().is_ok(), "without a target the cap is not read");
        assert!(settings(Some(0.02), 4096).validate().is_ok());
        for (noise, max_spp) in
            [(0.0, 4096), (1.0, 4096), (f64::NAN, 4096), (0.02, 32), (0.02, MAX_REFERENCE_SPP + 1)]
        {
            let message = settings(Some(noise), max_spp).validate().unwrap_err().to_string();
            assert!(message.contains("(0, 1)") || message.contains("64..="), "{noise} {max_spp}: {message}");
        }
    }

    #[test]
    fn knobs_parse_by_name_and_bad_names_list_the_knobs() {
        for k in Knob::ALL {
            assert_eq!(Knob::parse(k.name()).unwrap(), k);
            let (mut bake, mut frame) = (Quality::Draft.settings(), placeholder_frame());
            for v in k.default_values() {
                k.apply(v, &mut bake, &mut frame);
                assert!((k.value(&bake, &frame) - v).abs() < 1e-12, "{} = {v}", k.name());
            }
        }
        let e = Knob::parse("sh").unwrap_err().to_string();
        assert!(e.contains("sh_order") && e.contains("sigma_glo_cm"), "{e}");
        // Pooling is swept only around a base with segment transfers.
        assert!(!Knob::SegmentPool.acts_on(&Quality::Draft.settings()));
        assert!(Knob::SegmentPool.acts_on(&Quality::Interactive.settings()));
        assert!(Knob::ShOrder.acts_on(&Quality::Draft.settings()));
    }
}
