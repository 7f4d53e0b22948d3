//! What accuracy costs in time: the paper's Fig. 13 experiment (RMSE of the average intensity of
//! many small flat-swatch images against path-traced references) and the speed-up of the method
//! over the path tracer at equal error, measured in one run on one machine.
//!
//! How it works:
//! - [`configurations`]: `count` light/view pairs spread by a Halton sequence (bases 2, 3, 5, 7,
//!   11; `frame::halton`): views within 70° of the fabric normal, lights within 75°; even configurations get a
//!   directional light, odd ones an SG light with sharpness log-uniform in [2, 2000] (both
//!   sides of the sum-of-SGs / erf-SSDF switch). Irradiance and SG intensity are 1 in every
//!   channel.
//! - Per configuration [`run`] renders an orthographic view of the flat swatch
//!   (`height_cm = 0.4`, a few weave periods) with: the path tracer at `reference_spp` (the
//!   reference), the GPU method, optionally the CPU version
//!   of the method (`shading::render_flat`, exact fiber intersection), and the path tracer again
//!   at each `ladder_spp` with another seed (what a cheaper path-traced image would cost).
//! - Errors ([`Report`]): the RMSE over all configurations and channels of the image-average
//!   intensity (Fig. 13), and the per-pixel RMSE. Both are measured against a noisy reference,
//!   so the reference's own noise variance is subtracted before comparing methods ("excess"
//!   error, clamped at zero).
//! - Equal error: the path tracer's excess per-pixel MSE falls as c / spp; c is fitted to the
//!   ladder (least squares in 1/spp), the spp at which it would equal a method's excess MSE is
//!   c / MSE, and the path tracer's time is the ladder's time per sample times that spp. The
//!   speed-up is that time over the method's own frame time (precomputation excluded; the
//!   report states the bake time separately). Each configuration renders one untimed GPU frame
//!   first, so pipeline compilation for a new frame plan is not counted.

use std::fmt::Write as _;
use std::time::Instant;

use glam::DVec3;
use twill_precompute::Rgb;
use twill_precompute::bake::pattern::PatternMap;
use twill_precompute::bake::pipeline::Baked;
use twill_precompute::image::{Film, Image};
use twill_precompute::params::ParamError;
use twill_precompute::pathtrace::{self, Component, Light, RenderSettings};
use twill_precompute::scene::{CameraSection, ProjectionKind, Scene, camera_from};
use twill_precompute::shading::{ShadingError, render_flat};

use crate::frame::halton;
use crate::gpu::Gpu;
use crate::headless::{HeadlessError, SceneRenderer, frame_settings};
use crate::plan::Components;

pub mod sweep;

/// Why the experiment could not run.
#[derive(Debug, thiserror::Error)]
pub enum AccuracyError {
    #[error(transparent)]
    Gpu(#[from] HeadlessError),
    #[error(transparent)]
    Shading(#[from] ShadingError),
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error("{0}")]
    Settings(String),
}

/// One light/view pair of the experiment.
#[derive(Debug, Clone, Copy)]
pub struct Configuration {
    /// Unit direction from the swatch toward the camera.
    pub view: DVec3,
    pub light: Light,
}

/// Unit vector at polar angle with cosine `cos_theta` and azimuth `phi` about +z.
fn direction(cos_theta: f64, phi: f64) -> DVec3 {
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    DVec3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), cos_theta)
}

/// `count` configurations (see the module docs); the same every call.
pub fn configurations(count: usize) -> Result<Vec<Configuration>, ParamError> {
    let (max_view, max_light) = (70f64.to_radians().cos(), 75f64.to_radians().cos());
    (1..=count as u32)
        .map(|i| {
            let h = |base| halton(i, base);
            let view = direction(1.0 - h(2) * (1.0 - max_view), std::f64::consts::TAU * h(3));
            let to_light = direction(1.0 - h(5) * (1.0 - max_light), std::f64::consts::TAU * h(7));
            let light = if i % 2 == 0 {
                Light::directional(to_light, Rgb::ONE)?
            } else {
                Light::sg(to_light, 10f64.powf(0.3 + 3.0 * h(11)), Rgb::ONE)?
            };
            Ok(Configuration { view, light })
        })
        .collect()
}

/// What to run.
#[derive(Debug, Clone)]
pub struct ExperimentSettings {
    pub configurations: usize,
    /// Square image side in pixels.
    pub size: usize,
    pub reference_spp: u32,
    /// Samples per pixel of the method's images (GPU and CPU).
    pub method_spp: u32,
    /// Run the GPU method.
    pub gpu_method: bool,
    /// Also run the CPU version of the method.
    pub cpu_method: bool,
    /// Path-traced images at these spp, for the equal-error fit.
    pub ladder_spp: Vec<u32>,
    pub max_depth: u32,
}

impl ExperimentSettings {
    fn validate(&self) -> Result<(), AccuracyError> {
        let bad = |what: &str| Err(AccuracyError::Settings(what.to_owned()));
        if self.configurations == 0 || self.size == 0 || self.reference_spp == 0 || self.method_spp == 0 {
            return bad("configurations, size, reference spp and method spp must all be >= 1");
        }
        if self.ladder_spp.is_empty() || self.ladder_spp.contains(&0) {
            return bad("the path-tracer ladder needs at least one spp, each >= 1");
        }
        if !self.gpu_method && !self.cpu_method {
            return bad("run the GPU method, the CPU method or both");
        }
        Ok(())
    }
}

/// One method's results over all configurations.
#[derive(Debug, Clone)]
pub struct MethodResult {
    pub name: String,
    /// Samples per pixel it ran at.
    pub spp: u32,
    /// Image-average intensity per configuration (R, G, B).
    pub average: Vec<DVec3>,
    /// Per-pixel mean squared difference from the reference, per configuration (all channels).
    pub pixel_mse: Vec<f64>,
    /// Wall time summed over the configurations, seconds.
    pub seconds: f64,
}

/// The experiment's measurements; [`Report::markdown`] tabulates them.
#[derive(Debug, Clone)]
pub struct Report {
    pub settings: ExperimentSettings,
    pub configurations: Vec<Configuration>,
    pub reference: MethodResult,
    /// Variance of each reference image's average intensity (per channel, averaged).
    pub reference_average_variance: Vec<f64>,
    /// Mean per-pixel noise variance of each reference image (all channels).
    pub reference_pixel_variance: Vec<f64>,
    pub methods: Vec<MethodResult>,
    pub ladder: Vec<MethodResult>,
}

impl MethodResult {
    fn new(name: String, spp: u32, n: usize) -> Self {
        Self { name, spp, average: Vec::with_capacity(n), pixel_mse: Vec::with_capacity(n), seconds: 0.0 }
    }

    fn add(&mut self, image: &Image, reference: &Image, seconds: f64) {
        self.average.push(image_average(image));
        self.pixel_mse.push(pixel_mse(image, reference));
        self.seconds += seconds;
    }
}

fn image_average(image: &Image) -> DVec3 {
    image.pixels.iter().copied().sum::<DVec3>() / image.pixels.len().max(1) as f64
}

fn pixel_mse(a: &Image, b: &Image) -> f64 {
    let sum: f64 = a.pixels.iter().zip(&b.pixels).map(|(x, y)| (*x - *y).length_squared()).sum();
    sum / (3 * a.pixels.len().max(1)) as f64
}

fn film_noise(film: &Film) -> (f64, f64) {
    let var = film.variance_of_mean();
    let n = var.pixels.len().max(1) as f64;
    let total: f64 = var.pixels.iter().map(|v| v.element_sum()).sum();
    // Per channel, the image average's variance is sum(var) / n²; averaged over channels.
    (total / 3.0 / (n * n), total / (3.0 * n))
}

/// The camera of one configuration: orthographic, 0.4 cm tall, looking at the swatch centre.
fn camera_for(view: DVec3) -> CameraSection {
    let up = if view.z.abs() > 0.9 { [0.0, 1.0, 0.0] } else { [0.0, 0.0, 1.0] };
    CameraSection {
        projection: ProjectionKind::Orthographic,
        eye: (view * 0.6).to_array(),
        target: [0.0; 3],
        up,
        fov_y_deg: 30.0,
        height_cm: 0.4,
    }
}

/// Runs the experiment on `scene` (a flat swatch of the fabric `baked` was baked from; its
/// camera, lights and render size are replaced per configuration). `progress` gets
/// (configurations done, total).
pub fn run(
    scene: &mut Scene,
    baked: &Baked,
    gpu: Gpu,
    settings: &ExperimentSettings,
    progress: &dyn Fn(usize, usize),
) -> Result<Report, AccuracyError> {
    settings.validate()?;
    let configurations = configurations(settings.configurations)?;
    let n = configurations.len();
    let size = settings.size;
    (scene.render.width, scene.render.height) = (size, size);
    let mut session = SceneRenderer::with_gpu(gpu, scene, &[baked], &PatternMap::uniform(0))?;
    let mut frame = frame_settings(scene, Components::All);
    (frame.width, frame.height, frame.spp) = (size as u32, size as u32, settings.method_spp);

    let path_settings =
        |spp, seed| RenderSettings { spp, max_depth: settings.max_depth, component: Component::All, seed };
    let mut reference = MethodResult::new("path tracer (reference)".into(), settings.reference_spp, n);
    let mut methods = Vec::new();
    if settings.gpu_method {
        methods.push(MethodResult::new("GPU method".into(), settings.method_spp, n));
    }
    if settings.cpu_method {
        methods.push(MethodResult::new("CPU method (exact hits)".into(), settings.method_spp, n));
    }
    let mut ladder: Vec<MethodResult> = settings
        .ladder_spp
        .iter()
        .map(|&spp| MethodResult::new(format!("path tracer, {spp} spp"), spp, n))
        .collect();
    let (mut average_variance, mut pixel_variance) = (Vec::with_capacity(n), Vec::with_capacity(n));

    for (index, config) in configurations.iter().enumerate() {
        scene.camera = camera_for(config.view);
        scene.path_scene.lights = vec![config.light];
        let camera = camera_from(&scene.camera, size, size)?;
        let seed = 1 + index as u64;
        // Untimed: compiles this configuration's shading variant (the plan depends on the light).
        session.render(scene, &frame)?;

        let started = Instant::now();
        let film = pathtrace::render(
            &scene.path_scene,
            &camera,
            &path_settings(settings.reference_spp, seed),
            &|_| {},
        );
        let truth = film.mean();
        reference.add(&truth, &truth, started.elapsed().as_secs_f64());
        let (avg_var, px_var) = film_noise(&film);
        average_variance.push(avg_var);
        pixel_variance.push(px_var);

        if settings.gpu_method {
            let started = Instant::now();
            let out = session.render(scene, &frame)?;
            let seconds = started.elapsed().as_secs_f64();
            methods[0].add(&out.radiance_image(), &truth, seconds);
        }
        if settings.cpu_method {
            let started = Instant::now();
            let film = render_flat(scene, baked, Component::All, settings.method_spp, seed)?;
            let seconds = started.elapsed().as_secs_f64();
            methods.last_mut().expect("the CPU method's entry").add(&film.mean(), &truth, seconds);
        }
        for result in &mut ladder {
            let started = Instant::now();
            // Seeds disjoint from the reference's.
            let film = pathtrace::render(
                &scene.path_scene,
                &camera,
                &path_settings(result.spp, seed + 1_000_000),
                &|_| {},
            );
            let seconds = started.elapsed().as_secs_f64();
            result.add(&film.mean(), &truth, seconds);
        }
        progress(index + 1, n);
    }
    Ok(Report {
        settings: settings.clone(),
        configurations,
        reference,
        reference_average_variance: average_variance,
        reference_pixel_variance: pixel_variance,
        methods,
        ladder,
    })
}

/// A method's errors and the path tracer's cost at the same error.
#[derive(Debug, Clone, Copy)]
pub struct Summary {
    /// RMSE of the image-average intensities (all configurations and channels).
    pub average_rmse: f64,
    /// The same with the reference's noise variance subtracted.
    pub average_excess_rmse: f64,
    /// Per-pixel RMSE, and with the reference's noise variance subtracted.
    pub pixel_rmse: f64,
    pub pixel_excess_rmse: f64,
    /// Mean wall time per configuration, seconds.
    pub seconds_per_image: f64,
    /// spp at which the path tracer's per-pixel excess error equals this method's.
    pub equal_error_spp: f64,
    /// Path-tracer time at that spp over this method's time.
    pub speedup: f64,
}

impl Report {
    fn mean(values: impl Iterator<Item = f64>) -> f64 {
        let (mut sum, mut n) = (0.0, 0usize);
        for v in values {
            sum += v;
            n += 1;
        }
        sum / n.max(1) as f64
    }

    /// Mean squared error of `m`'s image averages against the reference's (per channel).
    fn average_mse(&self, m: &MethodResult) -> f64 {
        Self::mean(
            m.average.iter().zip(&self.reference.average).map(|(a, b)| (*a - *b).length_squared() / 3.0),
        )
    }

    /// RMS of the reference's image averages: the scale the RMSEs are relative to.
    #[must_use]
    pub fn reference_rms(&self) -> f64 {
        Self::mean(self.reference.average.iter().map(|a| a.length_squared() / 3.0)).sqrt()
    }

    /// The path tracer's excess per-pixel MSE times spp, fitted over the ladder: c in c / spp.
    fn ladder_constant(&self) -> f64 {
        let noise = Self::mean(self.reference_pixel_variance.iter().copied());
        // Least squares of e_s = c / s: c = sum(e_s / s) / sum(1 / s²).
        let (mut num, mut den) = (0.0, 0.0);
        for m in &self.ladder {
            let excess = (Self::mean(m.pixel_mse.iter().copied()) - noise).max(0.0);
            let inv = 1.0 / f64::from(m.spp);
            num += excess * inv;
            den += inv * inv;
        }
        num / den
    }

    /// Time the path tracer takes per sample per pixel per image, from the ladder.
    fn path_seconds_per_spp(&self) -> f64 {
        let spp: u32 = self.ladder.iter().map(|m| m.spp).sum();
        let seconds: f64 = self.ladder.iter().map(|m| m.seconds).sum();
        seconds / (f64::from(spp) * self.configurations.len() as f64)
    }

    #[must_use]
    pub fn summary(&self, m: &MethodResult) -> Summary {
        let average_noise = Self::mean(self.reference_average_variance.iter().copied());
        let pixel_noise = Self::mean(self.reference_pixel_variance.iter().copied());
        let average_mse = self.average_mse(m);
        let pixel_mse = Self::mean(m.pixel_mse.iter().copied());
        let pixel_excess = (pixel_mse - pixel_noise).max(0.0);
        let seconds_per_image = m.seconds / self.configurations.len() as f64;
        let equal_error_spp =
            if pixel_excess > 0.0 { self.ladder_constant() / pixel_excess } else { f64::INFINITY };
        Summary {
            average_rmse: average_mse.sqrt(),
            average_excess_rmse: (average_mse - average_noise).max(0.0).sqrt(),
            pixel_rmse: pixel_mse.sqrt(),
            pixel_excess_rmse: pixel_excess.sqrt(),
            seconds_per_image,
            equal_error_spp,
            speedup: equal_error_spp * self.path_seconds_per_spp() / seconds_per_image,
        }
    }

    /// The results as a Markdown table with a header naming the run.
    #[must_use]
    pub fn markdown(&self) -> String {
        let s = &self.settings;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{} configurations, {}x{} px; reference {} spp (its noise: image average {:.2e}, pixel {:.2e} RMS); methods {} spp; reference RMS image average {:.4}\n",
            self.configurations.len(),
            s.size,
            s.size,
            s.reference_spp,
            Self::mean(self.reference_average_variance.iter().copied()).sqrt(),
            Self::mean(self.reference_pixel_variance.iter().copied()).sqrt(),
            s.method_spp,
            self.reference_rms()
        );
        let _ = writeln!(
            out,
            "| method | RMSE of average intensity (excess) | relative | per-pixel RMSE (excess) | ms per image | path-tracer spp at equal per-pixel error | speed-up at equal error |"
        );
        let _ = writeln!(out, "|---|---|---|---|---|---|---|");
        let rms = self.reference_rms();
        for m in self.methods.iter().chain(&self.ladder) {
            let x = self.summary(m);
            let _ = writeln!(
                out,
                "| {} | {:.2e} ({:.2e}) | {:.2}% | {:.2e} ({:.2e}) | {:.1} | {:.2} | {:.1}x |",
                m.name,
                x.average_rmse,
                x.average_excess_rmse,
                100.0 * x.average_rmse / rms,
                x.pixel_rmse,
                x.pixel_excess_rmse,
                1e3 * x.seconds_per_image,
                x.equal_error_spp,
                x.speedup
            );
        }
        if let Some(m) = self.methods.first() {
            let _ = writeln!(out, "\nLargest differences of {} (image average, mean of R, G, B):\n", m.name);
            let _ = writeln!(
                out,
                "| configuration | view θ | light | light θ | reference | method | relative |\n|---|---|---|---|---|---|---|"
            );
            let mut order: Vec<usize> = (0..m.average.len()).collect();
            let diff = |i: usize| (m.average[i] - self.reference.average[i]).element_sum().abs();
            order.sort_by(|&a, &b| diff(b).total_cmp(&diff(a)));
            for &i in order.iter().take(5) {
                let c = &self.configurations[i];
                let (kind, dir) = match c.light {
                    Light::Directional { to_light, .. } => ("directional".to_owned(), to_light),
                    Light::Sg { axis, sharpness, .. } => (format!("SG, λ = {sharpness:.1}"), axis),
                };
                let (r, o) =
                    (self.reference.average[i].element_sum() / 3.0, m.average[i].element_sum() / 3.0);
                let _ = writeln!(
                    out,
                    "| {i} | {:.0}° | {kind} | {:.0}° | {r:.4} | {o:.4} | {:+.1}% |",
                    c.view.z.acos().to_degrees(),
                    dir.z.acos().to_degrees(),
                    100.0 * (o / r - 1.0)
                );
            }
        }
        let _ = writeln!(
            out,
            "\nReference: {:.1} ms per image at {} spp; path tracer {:.3} ms per spp per image.",
            1e3 * self.reference.seconds / self.configurations.len() as f64,
            s.reference_spp,
            1e3 * self.path_seconds_per_spp()
        );
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn configurations_cover_both_light_kinds_and_stay_in_their_cones() {
        let configs = configurations(50).unwrap();
        assert_eq!(configs.len(), 50);
        let (mut directional, mut sharpness) = (0, Vec::new());
        for c in &configs {
            assert!((c.view.length() - 1.0).abs() < 1e-12 && c.view.z >= 70f64.to_radians().cos() - 1e-12);
            match c.light {
                Light::Directional { to_light, .. } => {
                    directional += 1;
                    assert!(to_light.z >= 75f64.to_radians().cos() - 1e-12);
                }
                Light::Sg { sharpness: lambda, .. } => sharpness.push(lambda),
            }
        }
        assert_eq!(directional, 25);
        assert!(
            sharpness.iter().any(|&l| l < 100.0) && sharpness.iter().any(|&l| l > 200.0),
            "{sharpness:?}"
        );
        assert!(sharpness.iter().all(|&l| (2.0..=2000.0).contains(&l)));
    }
}
