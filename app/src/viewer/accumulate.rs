//! Progressive accumulation: samples of one view summed over many frames, and the tone
//! mapping that turns the running mean into the picture on screen.
//!
//! How it works: every batch the render worker returns holds the mean radiance of its own
//! samples; [`Accumulation::add`] weights it by its sample count and adds it to a running sum,
//! but only when it continues the same view (same edit generation, fabric and size) exactly
//! where the sum stopped. A batch that starts a sequence (`first_sample == 0`) replaces the sum,
//! anything else is stale and dropped. The picture is the sum divided by the sample count, tone
//! mapped on the CPU with the renderer's own tone curve (`twill_renderer::export::display_srgb8`,
//! the twin of the GPU tone-map pass), so exposure and curve edits need no new samples.

use twill_precompute::Rgb;
use twill_renderer::export::{Display, ToneCurve, display_srgb8};
use twill_renderer::frame::PassTiming;
use twill_renderer::plan::FramePlan;

use super::render_worker::FrameResult;

/// What the last batch reported.
#[derive(Debug, Clone)]
pub struct BatchInfo {
    pub plan: FramePlan,
    pub timings: Option<Vec<PassTiming>>,
    /// Passes the batch did not run because it reused an earlier frame's result.
    pub reused: Vec<String>,
    pub wall_ms: f64,
    pub spp: u32,
}

/// The running sum of one view's samples.
pub struct Accumulation {
    pub generation: u64,
    pub fabric_id: u64,
    pub width: u32,
    pub height: u32,
    pub samples: u32,
    sum: Vec<[f32; 3]>,
    pub last_batch: BatchInfo,
}

/// Whether a batch was taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Added {
    /// It started a new picture.
    Restarted,
    /// It added samples to the picture.
    Accumulated,
    /// It belonged to an older view or arrived out of order.
    Dropped,
}

impl Accumulation {
    /// A picture from one batch.
    #[must_use]
    pub fn from_result(result: &FrameResult) -> Self {
        let request = &result.request;
        let spp = request.settings.spp as f32;
        Self {
            generation: request.generation,
            fabric_id: request.fabric_id,
            width: result.frame.width,
            height: result.frame.height,
            samples: request.settings.spp,
            sum: result.frame.radiance.iter().map(|p| p.map(|c| c * spp)).collect(),
            last_batch: batch_info(result),
        }
    }

    /// Adds a batch (see the module docs).
    pub fn add(this: &mut Option<Self>, result: &FrameResult) -> Added {
        let request = &result.request;
        if request.first_sample == 0 {
            // Never replace a newer view with an older one.
            if this.as_ref().is_some_and(|a| a.generation > request.generation) {
                return Added::Dropped;
            }
            *this = Some(Self::from_result(result));
            return Added::Restarted;
        }
        let Some(acc) = this.as_mut() else { return Added::Dropped };
        let continues = acc.generation == request.generation
            && acc.fabric_id == request.fabric_id
            && (acc.width, acc.height) == (result.frame.width, result.frame.height)
            && acc.samples == request.first_sample;
        if !continues {
            return Added::Dropped;
        }
        let spp = request.settings.spp as f32;
        for (s, p) in acc.sum.iter_mut().zip(&result.frame.radiance) {
            for c in 0..3 {
                s[c] += p[c] * spp;
            }
        }
        acc.samples += request.settings.spp;
        acc.last_batch = batch_info(result);
        Added::Accumulated
    }

    /// The mean radiance per pixel.
    #[cfg(test)]
    #[must_use]
    pub fn mean(&self) -> Vec<[f32; 3]> {
        let inv = 1.0 / self.samples.max(1) as f32;
        self.sum.iter().map(|p| p.map(|c| c * inv)).collect()
    }

    /// The picture, tone mapped, as RGBA8 (sRGB).
    #[must_use]
    pub fn display_rgba8(&self, exposure: f64, filmic: bool) -> Vec<u8> {
        let scale = 1.0 / f64::from(self.samples.max(1));
        tone_map_rgba8(&self.sum, scale, exposure, filmic)
    }
}

fn batch_info(result: &FrameResult) -> BatchInfo {
    BatchInfo {
        plan: result.frame.plan.clone(),
        timings: result.frame.timings.clone(),
        reused: result.frame.reused.clone(),
        wall_ms: result.wall_ms,
        spp: result.request.settings.spp,
    }
}

/// The display settings of the renderer's tone map.
#[must_use]
pub fn display_settings(exposure: f64, filmic: bool) -> Display {
    Display { exposure, curve: if filmic { ToneCurve::Filmic } else { ToneCurve::Clamp } }
}

/// Tone maps `radiance × scale` to RGBA8 with the renderer's curve, on a few scoped threads.
/// (Not on rayon's pool: a bake keeps that busy for seconds at a time, and the window would wait.)
#[must_use]
pub fn tone_map_rgba8(radiance: &[[f32; 3]], scale: f64, exposure: f64, filmic: bool) -> Vec<u8> {
    let display = display_settings(exposure, filmic);
    let mut out = vec![0_u8; radiance.len() * 4];
    let threads = std::thread::available_parallelism().map_or(1, std::num::NonZero::get).min(8);
    let chunk = radiance.len().div_ceil(threads).max(1);
    let map = |out: &mut [u8], pixels: &[[f32; 3]]| {
        for (o, p) in out.chunks_exact_mut(4).zip(pixels) {
            let rgb = Rgb::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])) * scale;
            let [r, g, b] = display_srgb8(rgb, display);
            o.copy_from_slice(&[r, g, b, 255]);
        }
    };
    std::thread::scope(|scope| {
        for (out, pixels) in out.chunks_mut(4 * chunk).zip(radiance.chunks(chunk)) {
            scope.spawn(move || map(out, pixels));
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::viewer::render_worker::FrameRequest;
    use twill_precompute::scene::SceneFile;
    use twill_renderer::frame::{Frame, plan_frame};
    use twill_renderer::headless::frame_settings;
    use twill_renderer::plan::Components;

    fn result(generation: u64, first_sample: u32, spp: u32, value: f32) -> FrameResult {
        let scene = SceneFile::default_scene();
        let built = scene.build().unwrap();
        let mut settings = frame_settings(&built, Components::All);
        (settings.width, settings.height, settings.spp) = (2, 1, spp);
        let plan = plan_frame(&built.path_scene.lights, &settings, None, false);
        FrameResult {
            request: FrameRequest {
                generation,
                fabric_id: 1,
                camera: scene.camera,
                lights: built.path_scene.lights.clone(),
                settings,
                first_sample,
            },
            frame: Frame {
                width: 2,
                height: 1,
                radiance: vec![[value; 3]; 2],
                display: vec![[0; 4]; 2],
                plan,
                timings: None,
                reused: Vec::new(),
            },
            wall_ms: 1.0,
        }
    }

    #[test]
    fn batches_weight_by_their_samples_and_stale_ones_are_dropped() {
        let mut acc = None;
        assert_eq!(Accumulation::add(&mut acc, &result(1, 0, 1, 1.0)), Added::Restarted);
        assert_eq!(Accumulation::add(&mut acc, &result(1, 1, 3, 3.0)), Added::Accumulated);
        let a = acc.as_ref().unwrap();
        assert_eq!(a.samples, 4);
        assert!((a.mean()[0][0] - 2.5).abs() < 1e-6);
        // Out of order, and an older view's batch.
        assert_eq!(Accumulation::add(&mut acc, &result(1, 1, 1, 9.0)), Added::Dropped);
        assert_eq!(Accumulation::add(&mut acc, &result(2, 0, 1, 5.0)), Added::Restarted);
        assert_eq!(Accumulation::add(&mut acc, &result(1, 0, 1, 9.0)), Added::Dropped);
        assert!((acc.unwrap().mean()[0][0] - 5.0).abs() < 1e-6);
    }

    /// Known answers, worked by hand from the sRGB transfer function (IEC 61966-2-1) and
    /// Narkowicz's filmic fit: sRGB 0.5 is linear 0.21404 (level 127.5), so linear 0.213 is
    /// level 127 and 0.215 level 128; the filmic curve maps 1 to 2.54 / 3.16 = 0.8038 (level
    /// 232), 0.18 to level 141 and 4 to level 252.
    #[test]
    fn the_cpu_tone_map_gives_the_known_levels() {
        let clamp = |p: [f32; 3], scale: f64, exposure: f64| tone_map_rgba8(&[p], scale, exposure, false);
        assert_eq!(clamp([0.0, 1.0, 2.0], 1.0, 0.0), [0, 255, 255, 255]);
        assert_eq!(clamp([-1.0, 0.001, 0.213], 1.0, 0.0), [0, 3, 127, 255]);
        assert_eq!(clamp([0.215, 0.0, 0.0], 1.0, 0.0), [128, 0, 0, 255]);
        // The scale and the exposure (in stops) multiply: 0.05375 x 2 x 2^1 = 0.215.
        assert_eq!(clamp([0.053_75, 0.25, 0.0], 2.0, 1.0), [128, 255, 0, 255]);
        let filmic = tone_map_rgba8(&[[1.0, 0.18, 4.0], [100.0, 0.0, -3.0]], 1.0, 0.0, true);
        assert_eq!(filmic, [232, 141, 252, 255, 255, 0, 0, 255]);
    }

    /// The picture is split over threads: every pixel lands in its own place, whatever the count.
    #[test]
    fn the_tone_map_keeps_every_pixel_in_place() {
        for n in [1_usize, 7, 1000, 1001] {
            let radiance: Vec<[f32; 3]> = (0..n).map(|i| [i as f32 / n as f32, 0.0, 1.0]).collect();
            let rgba = tone_map_rgba8(&radiance, 1.0, 0.0, false);
            assert_eq!(rgba.len(), 4 * n);
            for (i, px) in rgba.chunks_exact(4).enumerate() {
                assert_eq!(px[1..], [0, 255, 255], "pixel {i} of {n}");
                // Red rises with the pixel index: no chunk was written twice or out of order.
                assert!(i == 0 || px[0] >= rgba[4 * (i - 1)], "pixel {i} of {n}");
            }
            assert_eq!(rgba[4 * (n - 1)], tone_map_rgba8(&radiance[n - 1..], 1.0, 0.0, false)[0]);
        }
    }
}
