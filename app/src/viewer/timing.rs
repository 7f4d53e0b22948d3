//! How long the viewer's own frames take: the UI's responsiveness, above all while a bake
//! runs in the background.
//!
//! How it works: [`UiTiming::frame`] is called at the end of every egui frame with the time the
//! frame's `ui` call started. It keeps the CPU time of the call (layout, painting commands,
//! scheduling) and the interval since the previous frame, split by whether a bake was running.
//! The interval is what a user feels, but it includes idle time when nothing asked for a
//! repaint; scripts that measure it (`spin`) ask for a repaint every frame, so there it is the
//! frame time. [`FrameStats`] gives the median, 95th percentile and maximum.

use std::time::Instant;

/// Frames kept per kind (the most recent ones).
const KEPT: usize = 4096;

/// Frame times (milliseconds) of recent frames.
#[derive(Default)]
pub struct UiTiming {
    last_frame: Option<Instant>,
    /// (ui call ms, interval since the previous frame ms), while a bake ran.
    pub baking: Vec<(f64, f64)>,
    /// The same with no bake running.
    pub idle: Vec<(f64, f64)>,
}

impl UiTiming {
    /// Records a frame whose `ui` call began at `started`.
    pub fn frame(&mut self, started: Instant, baking: bool) {
        let now = Instant::now();
        let ui_ms = (now - started).as_secs_f64() * 1e3;
        let interval_ms = self.last_frame.map_or(f64::NAN, |last| (now - last).as_secs_f64() * 1e3);
        self.last_frame = Some(now);
        let list = if baking { &mut self.baking } else { &mut self.idle };
        if list.len() == KEPT {
            list.remove(0);
        }
        list.push((ui_ms, interval_ms));
    }

    /// Forgets what was recorded (a measurement starts).
    pub fn clear(&mut self) {
        self.baking.clear();
        self.idle.clear();
    }
}

/// Summary of a set of frame times.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameStats {
    pub frames: usize,
    pub median_ms: f64,
    pub p95_ms: f64,
    pub max_ms: f64,
}

impl FrameStats {
    /// Statistics of the finite values (None without any).
    #[must_use]
    pub fn of(values: impl Iterator<Item = f64>) -> Option<Self> {
        let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
        Some(Self { frames: v.len(), median_ms: at(0.5), p95_ms: at(0.95), max_ms: v[v.len() - 1] })
    }
}

impl std::fmt::Display for FrameStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} frames: median {:.1} ms, p95 {:.1} ms, max {:.1} ms",
            self.frames, self.median_ms, self.p95_ms, self.max_ms
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statistics_ignore_non_finite_values_and_pick_order_statistics() {
        let s = FrameStats::of([f64::NAN, 5.0, 1.0, 3.0, 2.0, 4.0].into_iter()).unwrap();
        assert_eq!(s.frames, 5);
        assert!((s.median_ms - 3.0).abs() < 1e-12);
        assert!((s.p95_ms - 5.0).abs() < 1e-12);
        assert!((s.max_ms - 5.0).abs() < 1e-12);
        assert!(FrameStats::of([f64::NAN].into_iter()).is_none());
    }

    #[test]
    fn frames_are_split_by_whether_a_bake_ran() {
        let mut t = UiTiming::default();
        t.frame(Instant::now(), true);
        t.frame(Instant::now(), false);
        t.frame(Instant::now(), false);
        assert_eq!((t.baking.len(), t.idle.len()), (1, 2));
        assert!(t.baking[0].1.is_nan(), "the first frame has no interval");
        assert!(t.idle.iter().all(|(ui, interval)| *ui >= 0.0 && *interval >= 0.0));
    }
}
