//! Background baking: the fabric's precomputation runs on its own thread while the viewer
//! keeps drawing, first at draft quality (for a first picture within seconds) and then at the
//! final quality, each result handed over as soon as it is ready.
//!
//! How it works: [`Baker::start`] cancels the bake in flight (its [`Cancel`] token; the old
//! thread stops at its next check and reports nothing) and spawns a thread that builds the
//! scene (fabric exemplar, materials), then bakes each requested quality in turn through the
//! stage cache (the same cache `twill bake` and `twill render` use, so a quality baked before
//! loads in a moment). Progress comes from the pipeline's `&|stage, fraction|` callback and is
//! kept in a shared [`BakeProgress`] that the quality panel reads; the overall fraction weights
//! each stage by its typical share of a bake's time, which is also what the ETA extrapolates
//! (a rough guide, not a promise). Finished bakes and failures arrive as [`BakeEvent`]s; the
//! viewer forwards a finished bake to the render worker, and keeps showing the old picture until
//! the new fabric's first frame is ready.
//!
//! The picture comes first: render and bake share the cores, so after handing over a bake that
//! more bakes follow (the draft before the final quality, a material preview before its full
//! bake), the bake thread holds until the viewer says that bake's picture is on screen
//! ([`Baker::picture_shown`]), at most [`MAX_PICTURE_HOLD`], and only then starts the next.
//!
//! A material edit ([`Baker::start_material_edit`]) first hands over a preview
//! (`bake_material_preview`: a fraction of a second), then the full bake, whose transfer stage
//! is the only slow one left (the geometry stages come from the stage cache). The preview
//! recomputes the single-scattering tables; its multiple scattering is the previous bake's, or,
//! once the fabric has a recolouring basis (`bake::recolour`), evaluated at the new colours from
//! it. The basis is made lazily: the full bake after the first material edit of a geometry goes
//! on to make it ([`BakeEvent::RecolourReady`]; cached like a stage, seconds at interactive
//! quality), so every later colour edit follows with multiple scattering at once, and a
//! designer who never edits a colour never pays for it. Once the fabric on the GPU is of the
//! bases' quality, the viewer writes a colour edit into it through the render worker instead
//! (`RenderWorker::recolour`, tens of milliseconds) and asks here only for the full bake.

use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::{Duration, Instant};

use eframe::egui;
use twill_precompute::bake::Cancel;
use twill_precompute::bake::pattern::PatternMap;
use twill_precompute::bake::pipeline::{
    BakeError, BakeOutcome, Baked, Stage, bake, bake_material_preview, recolour_basis,
};
use twill_precompute::bake::recolour::RecolourBasis;
use twill_precompute::bake::settings::Quality;
use twill_precompute::scene::{Scene, SceneFile};

/// Typical share of a bake's time per stage, in [`Stage::ALL`] order (from docs/BENCHMARKS.md:
/// visibility and the IIRTF dominate).
const STAGE_WEIGHTS: [f64; 7] = [0.05, 0.45, 0.35, 0.07, 0.03, 0.02, 0.03];
/// How often a running bake asks the window to redraw its progress.
const PROGRESS_REPAINT: Duration = Duration::from_millis(250);
/// Longest the bake thread waits for the picture of a bake it handed over before going on (a
/// render that fails or stalls must not stop the bakes).
pub const MAX_PICTURE_HOLD: Duration = Duration::from_secs(30);
/// How often a holding bake thread checks for a cancel.
const HOLD_POLL: Duration = Duration::from_millis(50);

/// A finished bake of the scene's fabric.
pub struct FabricBake {
    pub quality: Quality,
    pub baked: Arc<BakedSet>,
    pub scene: Arc<Scene>,
    /// Wall time of this quality's bake (cached stages load in milliseconds).
    pub seconds: f64,
    /// Stages computed rather than loaded from the cache.
    pub computed: Vec<Stage>,
    /// A material preview: multiple scattering is still the previous bake's.
    pub preview: bool,
}

/// The recolouring basis of every exemplar of a fabric (`bake::recolour`).
pub type RecolourBases = Arc<Vec<RecolourBasis>>;

/// What the bake thread reports.
pub enum BakeEvent {
    Ready(FabricBake),
    /// The recolouring basis of every exemplar of the fabric just baked at `quality`.
    RecolourReady {
        quality: Quality,
        bases: Arc<Vec<RecolourBasis>>,
        seconds: f64,
    },
    Failed {
        message: String,
    },
}

/// Where the bake in flight is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BakeProgress {
    pub quality: Quality,
    pub stage: Option<Stage>,
    pub stage_fraction: f64,
    /// Fraction of the whole bake of this quality, stages weighted by [`STAGE_WEIGHTS`].
    pub overall: f64,
    pub started: Instant,
}

impl BakeProgress {
    /// A bake of `quality` starting now.
    #[must_use]
    pub fn starting(quality: Quality) -> Self {
        Self { quality, stage: None, stage_fraction: 0.0, overall: 0.0, started: Instant::now() }
    }

    /// Seconds left, extrapolated from the time so far (None until there is something to go on).
    #[must_use]
    pub fn eta_seconds(&self) -> Option<f64> {
        (self.overall > 0.02).then(|| {
            let elapsed = self.started.elapsed().as_secs_f64();
            elapsed * (1.0 - self.overall) / self.overall
        })
    }
}

/// Fraction of a whole bake done when `stage` is `fraction` done.
#[must_use]
pub fn overall_fraction(stage: Stage, fraction: f64) -> f64 {
    let index = Stage::ALL.iter().position(|s| *s == stage).unwrap_or(0);
    let before: f64 = STAGE_WEIGHTS[..index].iter().sum();
    (before + STAGE_WEIGHTS[index] * fraction.clamp(0.0, 1.0)).min(1.0)
}

/// The stages computed by any of several bakes, in pipeline order.
fn union_of(lists: impl Iterator<Item = Vec<Stage>>) -> Vec<Stage> {
    let all: Vec<Stage> = lists.flatten().collect();
    Stage::ALL.into_iter().filter(|s| all.contains(s)).collect()
}

/// A baked fabric: one exemplar, or every exemplar of patterned cloth and its block map.
pub struct BakedSet {
    pub exemplars: Vec<Baked>,
    pub pattern: PatternMap,
}

/// Shared between the bake thread and the viewer: which bake is current, and its progress.
#[derive(Default)]
struct Shared {
    /// Id of the current bake; an older thread's reports are ignored.
    current: u64,
    progress: Option<BakeProgress>,
    /// Events of the current bake sent and not yet taken by [`Baker::poll`].
    unpolled: usize,
    /// The bake thread holds until the picture of the bake it handed over is shown.
    holding: bool,
}

/// Runs bakes in the background (see the module docs).
pub struct Baker {
    /// The stage cache's folder (None: the default one).
    cache_dir: Option<std::path::PathBuf>,
    shared: Arc<Mutex<Shared>>,
    /// Wakes a holding bake thread.
    released: Arc<Condvar>,
    cancel: Option<Cancel>,
    next_id: u64,
    sender: Sender<(u64, BakeEvent)>,
    receiver: Receiver<(u64, BakeEvent)>,
    repaint: egui::Context,
}

impl Baker {
    /// A baker using the stage cache in `cache_dir` (default: the one `twill bake` uses).
    #[must_use]
    pub fn new(repaint: egui::Context, cache_dir: Option<std::path::PathBuf>) -> Self {
        let (sender, receiver) = channel();
        Self {
            cache_dir,
            shared: Arc::default(),
            released: Arc::default(),
            cancel: None,
            next_id: 1,
            sender,
            receiver,
            repaint,
        }
    }

    /// Bakes `scene`'s fabric at each of `qualities` in turn, cancelling any bake in flight.
    pub fn start(&mut self, scene: SceneFile, qualities: Vec<Quality>) {
        self.spawn(scene, qualities, None);
    }

    /// After a material edit: a preview from `previous` (a bake of the same geometry at
    /// `quality`), recoloured from `recolour` (that geometry's bases at `quality`) when given,
    /// then the full bake at `quality`, and then, without `recolour`, the bases.
    pub fn start_material_edit(
        &mut self,
        scene: SceneFile,
        quality: Quality,
        previous: Arc<BakedSet>,
        recolour: Option<RecolourBases>,
    ) {
        self.spawn(scene, vec![quality], Some((previous, recolour)));
    }

    fn spawn(
        &mut self,
        scene: SceneFile,
        qualities: Vec<Quality>,
        preview_from: Option<(Arc<BakedSet>, Option<RecolourBases>)>,
    ) {
        log::info!("bake {qualities:?} (material preview first: {})", preview_from.is_some());
        self.cancel();
        let id = self.next_id;
        self.next_id += 1;
        let cancel = Cancel::new();
        self.cancel = Some(cancel.clone());
        {
            // In flight from now on, before the thread runs (a check in between must not see an
            // idle baker).
            let mut shared = lock(&self.shared);
            shared.current = id;
            shared.progress =
                Some(BakeProgress::starting(qualities.first().copied().unwrap_or(Quality::Draft)));
        }
        let (shared, sender, repaint) = (Arc::clone(&self.shared), self.sender.clone(), self.repaint.clone());
        let released = Arc::clone(&self.released);
        let cache_dir = self.cache_dir.clone();
        let spawned = std::thread::Builder::new().name("twill-bake".into()).spawn(move || {
            let (previous, recolour) = preview_from.unzip();
            let recolour = recolour.flatten();
            let job = BakeJob {
                id,
                qualities: &qualities,
                preview_from: previous.as_deref(),
                recolour: recolour.as_deref().map(Vec::as_slice),
                make_recolour: previous.is_some() && recolour.is_none(),
                cache_dir: cache_dir.as_deref(),
                released: &released,
            };
            run_bakes(&job, &scene, &cancel, &shared, &sender, &repaint);
        });
        if let Err(e) = spawned {
            let message = format!("could not start the bake thread: {e}");
            let _ = self.sender.send((id, BakeEvent::Failed { message }));
        }
    }

    /// Stops the bake in flight, if any.
    pub fn cancel(&mut self) {
        if let Some(cancel) = self.cancel.take() {
            cancel.cancel();
        }
        let mut shared = lock(&self.shared);
        shared.current = 0;
        shared.progress = None;
        shared.unpolled = 0;
        shared.holding = false;
        self.released.notify_all();
    }

    /// Whether the bake thread waits for the picture of the bake it handed over last.
    #[must_use]
    pub fn holding(&self) -> bool {
        lock(&self.shared).holding
    }

    /// The picture of the bake handed over last is on screen (or will not come): a holding bake
    /// thread goes on with the next bake.
    pub fn picture_shown(&self) {
        let mut shared = lock(&self.shared);
        if shared.holding {
            shared.holding = false;
            self.released.notify_all();
        }
    }

    /// Whether a bake is in flight or has results not yet taken by [`Baker::poll`].
    #[must_use]
    pub fn busy(&self) -> bool {
        let shared = lock(&self.shared);
        shared.progress.is_some() || shared.unpolled > 0
    }

    /// The progress of the bake in flight.
    #[must_use]
    pub fn progress(&self) -> Option<BakeProgress> {
        lock(&self.shared).progress
    }

    /// Events of the current bake since the last call (those of superseded bakes are dropped).
    pub fn poll(&self) -> Vec<BakeEvent> {
        let mut shared = lock(&self.shared);
        let current = shared.current;
        let events: Vec<BakeEvent> =
            self.receiver.try_iter().filter(|(id, _)| *id == current).map(|(_, e)| e).collect();
        shared.unpolled = shared.unpolled.saturating_sub(events.len());
        events
    }
}

impl Drop for Baker {
    fn drop(&mut self) {
        self.cancel();
    }
}

fn lock(shared: &Mutex<Shared>) -> std::sync::MutexGuard<'_, Shared> {
    shared.lock().unwrap_or_else(PoisonError::into_inner)
}

/// What one bake thread does.
struct BakeJob<'a> {
    id: u64,
    qualities: &'a [Quality],
    /// Start with a material preview from this bake.
    preview_from: Option<&'a BakedSet>,
    /// The recolouring bases the preview evaluates (one per exemplar).
    recolour: Option<&'a [RecolourBasis]>,
    /// After the last bake, make the recolouring bases and report them.
    make_recolour: bool,
    cache_dir: Option<&'a std::path::Path>,
    released: &'a Condvar,
}

fn run_bakes(
    job: &BakeJob<'_>,
    scene_file: &SceneFile,
    cancel: &Cancel,
    shared: &Mutex<Shared>,
    sender: &Sender<(u64, BakeEvent)>,
    repaint: &egui::Context,
) {
    let (id, qualities) = (job.id, job.qualities);
    let report = |event: BakeEvent| {
        // Counted and sent under the lock, so `poll` never takes an event it has not counted.
        let mut s = lock(shared);
        if s.current == id {
            s.unpolled += 1;
        }
        let _ = sender.send((id, event));
        drop(s);
        repaint.request_repaint();
    };
    let set_progress = |progress: Option<BakeProgress>| {
        let mut s = lock(shared);
        if s.current == id {
            s.progress = progress;
        }
    };
    // Hands over a bake that more bakes follow, then holds until its picture is shown (see the
    // module docs); false when the bake was cancelled meanwhile.
    let report_and_hold = |event: BakeEvent, next: Quality| {
        {
            let mut s = lock(shared);
            if s.current == id {
                s.holding = true;
                s.progress = Some(BakeProgress::starting(next));
            }
        }
        report(event);
        let started = Instant::now();
        let mut s = lock(shared);
        while s.current == id && s.holding && !cancel.is_cancelled() {
            if started.elapsed() >= MAX_PICTURE_HOLD {
                log::warn!(
                    "no picture after {} s: going on with the {} bake",
                    MAX_PICTURE_HOLD.as_secs(),
                    next.name()
                );
                s.holding = false;
                break;
            }
            s = job.released.wait_timeout(s, HOLD_POLL).unwrap_or_else(PoisonError::into_inner).0;
        }
        log::debug!("bake thread held {:.2} s for the picture", started.elapsed().as_secs_f64());
        !cancel.is_cancelled()
    };
    let scene = match scene_file.build() {
        Ok(scene) => Arc::new(scene),
        Err(e) => {
            set_progress(None);
            report(BakeEvent::Failed { message: format!("the scene cannot be built: {e}") });
            return;
        }
    };
    let cache = match crate::commands::open_cache(job.cache_dir, false) {
        Ok(cache) => cache,
        Err(e) => {
            log::warn!("baking without the stage cache: {e:#}");
            None
        }
    };
    for (index, &quality) in qualities.iter().enumerate() {
        let next = qualities.get(index + 1).copied();
        let start = BakeProgress::starting(quality);
        let started = start.started;
        set_progress(Some(start));
        let all_inputs = scene.bake_inputs(quality.settings());
        let count = all_inputs.len() as f64;
        let last_repaint = Mutex::new(Instant::now());
        // Exemplars of a patterned cloth bake one after another: each is 1/count of the whole.
        let progress = |exemplar: usize, stage: Stage, fraction: f64| {
            set_progress(Some(BakeProgress {
                stage: Some(stage),
                stage_fraction: fraction,
                overall: (exemplar as f64 + overall_fraction(stage, fraction)) / count,
                ..start
            }));
            let mut last = last_repaint.lock().unwrap_or_else(PoisonError::into_inner);
            if last.elapsed() >= PROGRESS_REPAINT {
                *last = Instant::now();
                repaint.request_repaint_after(PROGRESS_REPAINT);
            }
        };
        let pattern = scene.pattern_map();
        let set = |exemplars: Vec<Baked>, computed: Vec<Stage>, preview: bool| FabricBake {
            quality,
            baked: Arc::new(BakedSet { exemplars, pattern: pattern.clone() }),
            scene: Arc::clone(&scene),
            seconds: started.elapsed().as_secs_f64(),
            computed,
            preview,
        };
        if let Some(previous) = job.preview_from {
            let previews: Result<Vec<_>, BakeError> = all_inputs
                .iter()
                .zip(&previous.exemplars)
                .enumerate()
                .map(|(i, (inputs, prev))| {
                    let basis = job.recolour.and_then(|b| b.get(i));
                    bake_material_preview(inputs, prev, basis, cache.as_ref(), cancel, &|_, _| {})
                })
                .collect();
            match previews {
                Ok(outcomes) if outcomes.len() == all_inputs.len() => {
                    let computed = union_of(outcomes.iter().map(BakeOutcome::computed));
                    let preview = set(outcomes.into_iter().map(|o| o.baked).collect(), computed, true);
                    // The full bake of this quality follows.
                    if !report_and_hold(BakeEvent::Ready(preview), quality) {
                        return;
                    }
                }
                Err(BakeError::Cancelled) => return,
                // The full bake below says what is wrong.
                Ok(_) => log::warn!("no material preview: the pattern's exemplar count changed"),
                Err(e) => log::warn!("no material preview: {e}"),
            }
        }
        let mut exemplars = Vec::with_capacity(all_inputs.len());
        let mut computed = Vec::new();
        for (i, inputs) in all_inputs.iter().enumerate() {
            match bake(inputs, cache.as_ref(), cancel, &|stage, fraction| progress(i, stage, fraction)) {
                Ok(outcome) => {
                    computed.push(outcome.computed());
                    exemplars.push(outcome.baked);
                }
                Err(BakeError::Cancelled) => return,
                Err(e) => {
                    set_progress(None);
                    let which =
                        if all_inputs.len() > 1 { format!(" (pattern exemplar {i})") } else { String::new() };
                    report(BakeEvent::Failed {
                        message: format!("the {} bake failed{which}: {e}", quality.name()),
                    });
                    return;
                }
            }
        }
        let ready = BakeEvent::Ready(set(exemplars, union_of(computed.into_iter()), false));
        if let Some(next) = next {
            if !report_and_hold(ready, next) {
                return;
            }
        } else {
            report(ready);
            if job.make_recolour {
                make_recolour_bases(quality, &all_inputs, cache.as_ref(), cancel, &report);
            }
        }
    }
    set_progress(None);
    repaint.request_repaint();
}

/// Makes (or loads from the stage cache) the recolouring basis of every exemplar of `inputs`
/// and reports them; a failure is logged (colour edits then keep the previous multiple
/// scattering until their full bake, as before).
fn make_recolour_bases(
    quality: Quality,
    inputs: &[twill_precompute::bake::pipeline::BakeInputs<'_>],
    cache: Option<&twill_precompute::bake::file::Cache>,
    cancel: &Cancel,
    report: &dyn Fn(BakeEvent),
) {
    let started = Instant::now();
    let bases: Result<Vec<RecolourBasis>, BakeError> =
        inputs.iter().map(|inputs| recolour_basis(inputs, cache, cancel, &|_| {})).collect();
    match bases {
        Ok(bases) => {
            let seconds = started.elapsed().as_secs_f64();
            log::info!("recolouring bases ready in {seconds:.1} s");
            report(BakeEvent::RecolourReady { quality, bases: Arc::new(bases), seconds });
        }
        Err(BakeError::Cancelled) => {}
        Err(e) => log::warn!("no recolouring basis: {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Events from `baker` until `done` says so (the pictures count as shown at once), at most
    /// five minutes.
    fn events_until(baker: &Baker, done: impl Fn(&BakeEvent) -> bool) -> Vec<BakeEvent> {
        let started = Instant::now();
        let mut events = Vec::new();
        loop {
            baker.picture_shown();
            for event in baker.poll() {
                let finished = done(&event);
                if let BakeEvent::Failed { message } = &event {
                    panic!("bake failed: {message}");
                }
                events.push(event);
                if finished {
                    return events;
                }
            }
            assert!(started.elapsed() < Duration::from_mins(5), "no such event in five minutes");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// The default scene with the warp's C_TT set to `c_tt`.
    fn with_warp_colour(c_tt: [f64; 3]) -> SceneFile {
        use twill_precompute::bcsdf::{FiberParams, MaterialDesc};
        let mut scene = SceneFile::default_scene();
        let Some(MaterialDesc::Fiber(p)) = scene.material_slots()[0] else {
            panic!("the default warp is fiber")
        };
        scene.materials.warp =
            Some(MaterialDesc::Fiber(FiberParams { c_tt: twill_precompute::Rgb::from_array(c_tt), ..p }));
        scene
    }

    #[test]
    fn colour_edits_after_the_first_preview_their_multiple_scattering_from_the_bases() {
        let cache = std::env::temp_dir().join(format!("twill-recolour-viewer-{}", std::process::id()));
        let mut baker = Baker::new(egui::Context::default(), Some(cache.clone()));
        let full = |e: &BakeEvent| matches!(e, BakeEvent::Ready(b) if !b.preview);
        let ready = |events: Vec<BakeEvent>| -> Vec<FabricBake> {
            events
                .into_iter()
                .filter_map(|e| if let BakeEvent::Ready(b) = e { Some(b) } else { None })
                .collect()
        };
        baker.start(SceneFile::default_scene(), vec![Quality::Draft]);
        let first = ready(events_until(&baker, full)).pop().unwrap().baked;
        // The first colour edit: the preview keeps the previous transfer; its full bake goes on
        // to make the bases.
        baker.start_material_edit(
            with_warp_colour([0.1, 0.2, 0.6]),
            Quality::Draft,
            Arc::clone(&first),
            None,
        );
        let events = events_until(&baker, |e| matches!(e, BakeEvent::RecolourReady { .. }));
        let Some(BakeEvent::RecolourReady { quality, bases, .. }) = events.last() else { unreachable!() };
        assert_eq!(*quality, Quality::Draft);
        let (bases, bakes) = (Arc::clone(bases), ready(events));
        assert!(bakes[0].preview && !bakes[1].preview);
        assert_eq!(bakes[0].baked.exemplars[0].transfer, first.exemplars[0].transfer, "kept");
        let second = Arc::clone(&bakes[1].baked);
        assert!(bases.iter().zip(&second.exemplars).all(|(b, e)| b.fits(&e.materials)));
        // A later colour edit: the preview's multiple scattering follows the colours at once.
        baker.start_material_edit(
            with_warp_colour([0.9, 0.3, 0.1]),
            Quality::Draft,
            Arc::clone(&second),
            Some(bases),
        );
        let bakes = ready(events_until(&baker, full));
        assert!(bakes[0].preview);
        let (preview, rebaked) = (&bakes[0].baked.exemplars[0], &bakes[1].baked.exemplars[0]);
        assert_ne!(preview.transfer.iirtf, second.exemplars[0].transfer.iirtf, "recoloured, not kept");
        // Within a few percent of the rebake in total transfer (the red warp's red channel).
        let total = |b: &Baked| -> f64 {
            b.transfer.iirtf.cells.iter().filter(|c| !c.is_empty()).map(|c| f64::from(c.matrix[0][0])).sum()
        };
        let relative = total(preview) / total(rebaked) - 1.0;
        assert!(relative.abs() < 0.1, "preview against rebake: {relative:+.3}");
        drop(baker);
        let _ = std::fs::remove_dir_all(cache);
    }

    #[test]
    fn overall_progress_runs_from_zero_to_one_in_stage_order() {
        assert!((STAGE_WEIGHTS.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(overall_fraction(Stage::MeanFreePath, 0.0).abs() < 1e-12);
        assert!((overall_fraction(Stage::Volume, 1.0) - 1.0).abs() < 1e-12);
        let mut last = 0.0;
        for stage in Stage::ALL {
            for f in [0.0, 0.5, 1.0] {
                let o = overall_fraction(stage, f);
                assert!(o >= last, "{stage:?} {f}");
                last = o;
            }
        }
    }

    #[test]
    fn the_eta_extrapolates_the_elapsed_time() {
        let p = BakeProgress {
            quality: Quality::Draft,
            stage: Some(Stage::Transfer),
            stage_fraction: 0.5,
            overall: 0.5,
            started: Instant::now().checked_sub(Duration::from_secs(4)).unwrap(),
        };
        let eta = p.eta_seconds().unwrap();
        assert!((eta - 4.0).abs() < 0.5, "{eta}");
        assert!(BakeProgress { overall: 0.0, ..p }.eta_seconds().is_none());
    }
}
