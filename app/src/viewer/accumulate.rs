//! The picture on screen: the progressive picture the renderer accumulates and tone-maps on
//! the GPU, as the window last received it.
//!
//! How it works: every batch the render worker returns adds samples to the picture the renderer
//! keeps on the GPU ([`twill_renderer::frame::Renderer::render_progressive`]) and carries the
//! tone-mapped result: on the window's own device the display texture itself, which the window
//! draws as a native egui texture (nothing is read back); on a device of the worker's own, the
//! 8-bit display image read back. [`Accumulation::add`] takes a batch only when it starts a
//! picture (`first_sample == 0`, not of an older view) or continues the current one exactly
//! where it stopped (same edit generation, fabric and size); anything else is stale and
//! dropped. An exposure or curve edit comes back as the same samples tone-mapped again
//! ([`Accumulation::retoned`]): no new samples.

use twill_renderer::frame::{PassTiming, ProgressiveFrame};
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

/// The tone-mapped picture, where the window can take it from.
#[derive(Debug, Clone)]
pub enum Picture {
    /// On the window's device: the renderer's display texture (`Rgba8Unorm`, sRGB-encoded).
    Texture(wgpu::Texture),
    /// Read back from the worker's own device: RGBA8 (sRGB) rows.
    Pixels(Vec<u8>),
}

impl Picture {
    fn of(frame: &ProgressiveFrame) -> Self {
        match &frame.display {
            Some(pixels) => Self::Pixels(pixels.iter().flatten().copied().collect()),
            None => Self::Texture(frame.display_texture.clone()),
        }
    }
}

/// The picture of one view.
pub struct Accumulation {
    pub generation: u64,
    pub fabric_id: u64,
    pub width: u32,
    pub height: u32,
    pub samples: u32,
    /// The exposure and curve the picture is tone mapped with.
    pub tone: (f64, bool),
    pub picture: Picture,
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
        Self {
            generation: request.generation,
            fabric_id: request.fabric_id,
            width: result.frame.width,
            height: result.frame.height,
            samples: result.frame.samples,
            tone: (result.frame.exposure, result.frame.filmic),
            picture: Picture::of(&result.frame),
            last_batch: batch_info(result),
        }
    }

    /// Takes a batch (see the module docs).
    pub fn add(this: &mut Option<Self>, result: &FrameResult) -> Added {
        let request = &result.request;
        let batch = Batch {
            generation: request.generation,
            fabric_id: request.fabric_id,
            size: (result.frame.width, result.frame.height),
            first_sample: request.first_sample,
        };
        let shown = this.as_ref().map(|a| Shown {
            generation: a.generation,
            fabric_id: a.fabric_id,
            size: (a.width, a.height),
            samples: a.samples,
        });
        let added = judge(shown, batch);
        if added != Added::Dropped {
            *this = Some(Self::from_result(result));
        }
        added
    }

    /// Takes the same samples tone-mapped again; `false` when they are not this picture's.
    pub fn retoned(&mut self, frame: &ProgressiveFrame) -> bool {
        if (frame.width, frame.height, frame.samples) != (self.width, self.height, self.samples) {
            return false;
        }
        self.tone = (frame.exposure, frame.filmic);
        self.picture = Picture::of(frame);
        true
    }
}

/// The view a picture on screen is of, and its samples.
#[derive(Debug, Clone, Copy)]
struct Shown {
    generation: u64,
    fabric_id: u64,
    size: (u32, u32),
    samples: u32,
}

/// The view a batch is of, and where its samples start.
#[derive(Debug, Clone, Copy)]
struct Batch {
    generation: u64,
    fabric_id: u64,
    size: (u32, u32),
    first_sample: u32,
}

/// Whether a batch replaces the picture on screen, adds to it, or is stale.
fn judge(shown: Option<Shown>, batch: Batch) -> Added {
    if batch.first_sample == 0 {
        // Never replace a newer view with an older one.
        return if shown.is_some_and(|s| s.generation > batch.generation) {
            Added::Dropped
        } else {
            Added::Restarted
        };
    }
    let continues = shown.is_some_and(|s| {
        s.generation == batch.generation
            && s.fabric_id == batch.fabric_id
            && s.size == batch.size
            && s.samples == batch.first_sample
    });
    if continues { Added::Accumulated } else { Added::Dropped }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn batch(generation: u64, first_sample: u32) -> Batch {
        Batch { generation, fabric_id: 1, size: (2, 1), first_sample }
    }

    fn shown(generation: u64, samples: u32) -> Shown {
        Shown { generation, fabric_id: 1, size: (2, 1), samples }
    }

    #[test]
    fn batches_start_or_continue_a_picture_and_stale_ones_are_dropped() {
        assert_eq!(judge(None, batch(1, 0)), Added::Restarted);
        assert_eq!(judge(None, batch(1, 1)), Added::Dropped, "nothing to continue");
        assert_eq!(judge(Some(shown(1, 1)), batch(1, 1)), Added::Accumulated);
        assert_eq!(judge(Some(shown(1, 4)), batch(1, 1)), Added::Dropped, "out of order");
        assert_eq!(judge(Some(shown(2, 1)), batch(1, 0)), Added::Dropped, "an older view's first batch");
        assert_eq!(judge(Some(shown(1, 4)), batch(2, 0)), Added::Restarted, "a newer view");
        assert_eq!(judge(Some(shown(1, 4)), batch(2, 4)), Added::Dropped, "another view's continuation");
        let other_fabric = Batch { fabric_id: 2, ..batch(1, 4) };
        assert_eq!(judge(Some(shown(1, 4)), other_fabric), Added::Dropped);
        let other_size = Batch { size: (4, 2), ..batch(1, 4) };
        assert_eq!(judge(Some(shown(1, 4)), other_size), Added::Dropped);
    }
}
