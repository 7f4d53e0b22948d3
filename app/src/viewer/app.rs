//! The viewer window: panels, the viewport and the glue between the bake thread, the render
//! worker and what is on screen.
//!
//! How it works: every egui frame [`ViewerApp`]
//! 1. takes finished bakes from the [`Baker`] and hands them to the render worker for upload,
//!    and takes the worker's results: uploaded fabrics, rendered batches (added to the
//!    progressive [`Accumulation`]), export progress and every error, which goes to the message
//!    list at the bottom of the window;
//! 2. lays out the panels (lights and export on the left, quality and performance on the right)
//!    and the viewport in the middle, with messages drawn over its bottom edge, where dragging orbits, right or
//!    middle dragging pans, scrolling zooms, and F or a double click fits the fabric to the view;
//! 3. compares the view (fabric, camera, lights, render settings, viewport size) with the last
//!    one: any difference starts a new generation. After an edit the picture is rendered at a
//!    reduced size, one sample a batch, until the edits have stopped for a moment and a reduced
//!    picture of the last one has been shown, so dragging stays fluid even when full-size
//!    samples take seconds (lavapipe);
//! 4. asks the worker for the next batch of the current view: the first sample of a new view,
//!    then batches that double in size (up to [`MAX_BATCH_SPP`], and no more than the measured
//!    cost allows in [`BATCH_BUDGET_MS`]) until the target sample count is reached, after which
//!    nothing is rendered until something changes;
//! 5. plays the next step of a script, if one was given.
//!
//! The picture on screen is replaced only when a new batch arrives, so the old picture stays
//! while a new view, a new bake or a resize is being rendered.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use eframe::egui;
use twill_precompute::bake::pipeline::Stage;
use twill_precompute::bake::settings::Quality;
use twill_precompute::pathtrace::Light;
use twill_precompute::pathtrace::light::SG_SHARPNESS_RANGE;
use twill_precompute::scene::{CameraSection, GpuSection, RenderSection, SceneFile};
use twill_renderer::export::{Display, ToneCurve, write_rgb8_png};
use twill_renderer::frame::FrameSettings;
use twill_renderer::plan::Components;

use super::ViewerOptions;
use super::accumulate::{Accumulation, Added, Picture};
use super::bake::{BakeEvent, BakedSet, Baker};
use super::camera::OrbitCamera;
use super::colourway::{ColourwayForm, colourway_panel};
use super::export::{ExportAction, ExportForm, ExportFormat, ExportStatus, export_panel, export_toml};
use super::fabric::{WeaveAction, WeaveForm, fibers_panel, import_wif, weave_panel};
use super::history::History;
use super::lights::{LightEdit, MAX_VIEWER_LIGHTS, lights_panel, new_light, preset};
use super::mesh::{MeshForm, mesh_panel};
use super::paint::{
    KeptPaint, PaintForm, PaintSession, SIDE_CHOICES, SPP_CHOICES, Scope, Shown, VERIFY_SPP_CHOICES,
    Verification,
};
use super::quality::{
    FabricInfo, INTERACTION_BUDGET_MS, INTERACTION_SCALE_RANGE, QualityAction, QualityView, RenderControls,
    SIGMA_GLO_RANGE_CM, TARGET_SPP_RANGE, quality_panel,
};
use super::render_worker::{
    DeviceHandles, ExportRequest, FrameCost, FrameRequest, MeshRequest, NewFabric, RecolourRequest,
    RenderWorker, ToneRequest, WorkerEvent,
};
use super::script::{LightField, STEP_TIMEOUT, ScriptLine, Setting, Step, viewport_screenshot_path};
use super::timing::FrameStats;

/// How long after an edit the picture is still rendered at the reduced size.
const INTERACTION_SETTLE: Duration = Duration::from_millis(300);
/// Largest batch of samples per request once a view is still.
const MAX_BATCH_SPP: u32 = 16;
/// Longest a batch should take (the worker takes no new view until its batch is done).
const BATCH_BUDGET_MS: f64 = 250.0;
/// How often a waiting script step is checked when nothing else wakes the window.
const SCRIPT_POLL: Duration = Duration::from_millis(250);
/// Side panels' widths (points) and their sliders' length.
const LEFT_PANEL_WIDTH: f32 = 290.0;
const RIGHT_PANEL_WIDTH: f32 = 310.0;
const SLIDER_WIDTH: f32 = 120.0;
/// The smallest viewport rendered, in pixels per side.
const MIN_VIEWPORT_PX: u32 = 8;
/// How long a fabric edit must rest before its bake starts (a drag restarts it each frame).
const FABRIC_EDIT_SETTLE: Duration = Duration::from_millis(250);
/// How long after a colour edit its full bake waits, at most, for the first picture of the
/// colours written live (a software renderer shares the cores with the bake).
const LIVE_PICTURE_BEFORE_BAKE: Duration = Duration::from_secs(2);

/// Severity of a message in the message list.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Level {
    Error,
    Info,
}

/// How long an information message stays on screen (errors stay until dismissed).
const INFO_SECONDS: Duration = Duration::from_secs(10);

/// The message list, drawn over the bottom of the viewport (so messages never resize it).
#[derive(Default)]
struct Messages {
    shown: Vec<(Level, String, Instant)>,
    /// Every error shown since the start (scripts check these).
    errors: Vec<String>,
}

impl Messages {
    fn error(&mut self, text: impl Into<String>) {
        let text = text.into();
        log::error!("{text}");
        self.errors.push(text.clone());
        self.shown.push((Level::Error, text, Instant::now()));
    }

    fn info(&mut self, text: impl Into<String>) {
        let text = text.into();
        log::info!("{text}");
        self.shown.push((Level::Info, text, Instant::now()));
    }
}

/// Everything that decides the picture; a change restarts the accumulation.
#[derive(Debug, Clone, PartialEq)]
struct ViewKey {
    fabric_id: u64,
    shell_id: u64,
    camera: CameraSection,
    lights: Vec<Light>,
    components: Components,
    gpu: GpuSection,
    size: [u32; 2],
}

impl ViewKey {
    /// The same view except for the fabric (a new bake is no interaction).
    fn same_edit(&self, other: &Self) -> bool {
        Self { fabric_id: other.fabric_id, ..self.clone() } == *other
    }
}

/// What undo and redo restore: everything a user edits except the camera.
#[derive(Debug, Clone, PartialEq)]
struct Snapshot {
    scene: SceneFile,
    lights: Vec<LightEdit>,
    gpu: GpuSection,
}

/// A bake sent to the worker and not yet on screen.
struct Uploading {
    fabric_id: u64,
    bake_seconds: f64,
    computed: Vec<Stage>,
    baked: Arc<BakedSet>,
}

/// A script being played.
struct ScriptRun {
    lines: Vec<ScriptLine>,
    next: usize,
    step_started: Instant,
    screenshot: Arc<Mutex<Option<Arc<egui::ColorImage>>>>,
    /// Viewport rectangle in window pixels when the screenshot was asked for.
    screenshot_rect: Option<egui::Rect>,
    errors_seen: usize,
    expected_error_seen: bool,
    finished: bool,
    /// When a `spin` step ends.
    spin_until: Option<Instant>,
    /// Device recoveries counted when a `lose-device` step destroyed the device.
    recoveries_before_loss: Option<u32>,
}

/// The state of the last export.
enum ExportOutcome {
    Done,
    Failed(String),
}

/// The viewer (see the module docs).
pub struct ViewerApp {
    source_path: PathBuf,
    scene_file: Option<SceneFile>,
    final_quality: Quality,
    /// Per preset, what the latest `twill accuracy` report measured (read at start).
    expected_accuracy: Vec<(Quality, crate::accuracy_report::ExpectedAccuracy)>,
    bake_choice: Quality,

    camera: OrbitCamera,
    initial_camera: OrbitCamera,
    lights: Vec<LightEdit>,
    scene_lights: Vec<LightEdit>,
    selected_light: usize,
    lights_error: Option<String>,
    controls: RenderControls,

    baker: Baker,
    worker: Option<RenderWorker>,
    next_fabric_id: u64,
    uploading: Vec<Uploading>,
    fabric: Option<FabricInfo>,
    /// The bake on screen (a material edit previews from it).
    shown_bake: Option<Arc<BakedSet>>,
    /// The recolouring bases of the fabric's geometry and the quality they were made at
    /// (`bake::recolour`): colour edits evaluate them for their preview.
    recolour: Option<(Quality, super::bake::RecolourBases)>,
    /// The scene whose fabric and materials the last bake was started for.
    baked_scene: Option<SceneFile>,
    /// The colours last sent to the render worker while an edit is still moving (a colour
    /// dragged in the picker): one live recolouring in flight at a time, the full bake only
    /// once the edit rests.
    live_recoloured: Option<SceneFile>,
    live_recolour_in_flight: bool,
    /// When the colours now being written were edited, until their first picture is on screen.
    recolour_edited_at: Option<Instant>,
    /// The last colour edit's time from the edit to its first picture, and that picture's size.
    last_recolour_to_picture: Option<(Duration, [u32; 2])>,
    /// A fabric edit waiting for [`FABRIC_EDIT_SETTLE`], and since when.
    pending_fabric: Option<(SceneFile, Instant)>,
    /// The mesh (and swatch size) last sent to the worker.
    mesh_sent: Option<(twill_precompute::scene::MeshSection, [f64; 2])>,
    shell_id: u64,

    history: History<Snapshot>,
    weave_form: WeaveForm,
    colourway_form: ColourwayForm,
    mesh_form: MeshForm,
    scene_path_field: String,
    ui_timing: super::timing::UiTiming,

    generation: u64,
    /// The generation of the last edit (a fabric change is no edit).
    edit_generation: u64,
    view_key: Option<ViewKey>,
    last_edit: Instant,
    failed_generation: Option<u64>,
    in_flight: Option<FrameRequest>,
    /// Render devices replaced after a loss since the start.
    device_recoveries: u32,
    accumulation: Option<Accumulation>,
    /// The worker answered that the picture on the GPU is not the one the view continues.
    restart_picture: bool,
    /// eframe's wgpu state: the window draws a picture on its own device as a native texture.
    render_state: Option<eframe::egui_wgpu::RenderState>,
    viewport_texture: Option<ViewportTexture>,
    texture_dirty: bool,
    shown_tone: (f64, bool),
    viewport_px: [u32; 2],
    viewport_rect_px: egui::Rect,
    /// Measured wall time per pixel and sample (smoothed over batches).
    frame_cost: FrameCost,

    export_form: ExportForm,
    export_status: ExportStatus,
    last_export: Option<ExportOutcome>,

    /// Paint mode, while it is on ([`super::paint`]).
    paint: Option<PaintSession>,
    paint_form: PaintForm,
    /// The last paint session's precompute and painting, for painting the same view again.
    paint_kept: Option<KeptPaint>,
    /// What paint mode's viewport shows: the painting, or the verification's pictures.
    paint_shown: Shown,
    /// The last path-traced check of a painting (it runs on after paint mode ends).
    verification: Option<Verification>,

    messages: Messages,
    script: Option<ScriptRun>,
    outcome: Arc<Mutex<Option<Result<(), String>>>>,
}

fn default_controls(scene: &SceneFile) -> RenderControls {
    RenderControls {
        target_spp: scene.render.spp.clamp(TARGET_SPP_RANGE.0, TARGET_SPP_RANGE.1),
        interaction_auto: true,
        interaction_scale: 0.5,
        exposure: scene.render.exposure,
        filmic: true,
        components: Components::All,
        gpu: scene.gpu,
    }
}

impl ViewerApp {
    pub fn new(
        cc: &eframe::CreationContext<'_>,
        options: &ViewerOptions,
        script: Option<Vec<ScriptLine>>,
        outcome: Arc<Mutex<Option<Result<(), String>>>>,
    ) -> Self {
        let mut messages = Messages::default();
        let (scene_file, source_path) = match &options.scene {
            None => (Some(SceneFile::default_scene()), PathBuf::from("<built-in default scene>")),
            Some(path) => (read_scene(path).map_err(|e| messages.error(e)).ok(), path.clone()),
        };
        // Without a scene the panels show the default scene's camera and lights (nothing renders).
        let shown = scene_file.clone().unwrap_or_else(SceneFile::default_scene);
        let camera = OrbitCamera::from_section(&shown.camera);
        let lights: Vec<LightEdit> = shown.lights.iter().map(LightEdit::from_section).collect();

        let worker = if let Some(state) = &cc.wgpu_render_state {
            let device = render_device(state).unwrap_or_else(|e| {
                messages.error(format!("{e}; rendering on the window's device"));
                DeviceHandles {
                    adapter_info: state.adapter.get_info(),
                    device: state.device.clone(),
                    queue: state.queue.clone(),
                    own: false,
                }
            });
            RenderWorker::start(device, cc.egui_ctx.clone())
                .map_err(|e| messages.error(format!("could not start the render thread: {e}")))
                .ok()
        } else {
            messages.error("eframe opened no wgpu device: nothing can be rendered");
            None
        };
        let mut baker = Baker::new(cc.egui_ctx.clone(), options.cache_dir.clone());
        if let Some(file) = &scene_file {
            baker.start(file.clone(), bake_sequence(options.quality));
        }
        let scene_path_field = options.scene.as_ref().map_or_else(String::new, |p| p.display().to_string());
        let baked_scene = scene_file.clone();
        Self {
            source_path,
            final_quality: options.quality,
            bake_choice: options.quality,
            expected_accuracy: Quality::ALL
                .into_iter()
                .filter_map(|q| crate::accuracy_report::expected_accuracy(q).map(|(e, _)| (q, e)))
                .collect(),
            camera,
            initial_camera: camera,
            scene_lights: lights.clone(),
            lights,
            selected_light: 0,
            lights_error: None,
            controls: default_controls(&shown),
            scene_file,
            baker,
            worker,
            next_fabric_id: 1,
            uploading: Vec::new(),
            fabric: None,
            shown_bake: None,
            recolour: None,
            baked_scene: baked_scene.clone(),
            live_recoloured: None,
            live_recolour_in_flight: false,
            recolour_edited_at: None,
            last_recolour_to_picture: None,
            pending_fabric: None,
            mesh_sent: baked_scene.as_ref().map(|f| (f.mesh.clone(), f.swatch.size_cm)),
            shell_id: 0,
            history: History::default(),
            weave_form: WeaveForm::default(),
            colourway_form: ColourwayForm::default(),
            mesh_form: MeshForm::default(),
            scene_path_field,
            ui_timing: super::timing::UiTiming::default(),
            generation: 0,
            edit_generation: 0,
            view_key: None,
            last_edit: Instant::now(),
            failed_generation: None,
            in_flight: None,
            device_recoveries: 0,
            accumulation: None,
            restart_picture: false,
            render_state: cc.wgpu_render_state.clone(),
            viewport_texture: None,
            texture_dirty: false,
            shown_tone: (f64::NAN, true),
            viewport_px: [0, 0],
            viewport_rect_px: egui::Rect::NOTHING,
            frame_cost: FrameCost::default(),
            export_form: ExportForm::default(),
            export_status: ExportStatus::Idle,
            last_export: None,
            paint: None,
            paint_form: PaintForm::default(),
            paint_kept: None,
            paint_shown: Shown::Painting,
            verification: None,
            messages,
            script: script.map(|lines| ScriptRun {
                lines,
                next: 0,
                step_started: Instant::now(),
                screenshot: Arc::default(),
                screenshot_rect: None,
                errors_seen: 0,
                expected_error_seen: false,
                finished: false,
                spin_until: None,
                recoveries_before_loss: None,
            }),
            outcome,
        }
    }

    fn start_bake(&mut self, quality: Quality) {
        if let Some(file) = &self.scene_file {
            let sequence = if self.fabric.is_none() { bake_sequence(quality) } else { vec![quality] };
            self.baker.start(file.clone(), sequence);
            self.final_quality = quality;
            self.baked_scene = Some(file.clone());
            self.pending_fabric = None;
        }
    }

    /// Starts what an edit of the fabric or its materials needs, once the edit has rested for
    /// [`FABRIC_EDIT_SETTLE`] with no pointer button held: a material edit previews single
    /// scattering from the bake on screen and then bakes in full (only the material stages are
    /// not in the stage cache); a weave or yarn edit bakes a draft first, then the final quality.
    /// A mesh or swatch edit goes to the render worker, which swaps the shell (no bake).
    fn follow_scene_edits(&mut self, ctx: &egui::Context) {
        let Some(scene) = &self.scene_file else { return };
        if let Some(worker) = &self.worker {
            let mesh = (scene.mesh.clone(), scene.swatch.size_cm);
            if self.mesh_sent.as_ref() != Some(&mesh) {
                worker.set_mesh(MeshRequest {
                    mesh: mesh.0.clone(),
                    swatch_cm: mesh.1,
                    base_dir: scene.path.parent().unwrap_or(Path::new(".")).to_path_buf(),
                });
                self.mesh_sent = Some(mesh);
            }
        }
        let (geometry_changed, materials_changed) = bake_changes(self.baked_scene.as_ref(), scene);
        if !geometry_changed && !materials_changed {
            self.pending_fabric = None;
            return;
        }
        match &self.pending_fabric {
            Some((pending, _)) if pending == scene => {}
            _ => self.pending_fabric = Some((scene.clone(), Instant::now())),
        }
        // A colour edit shows at once, while it still moves: the bases' colours are written
        // live (tens of milliseconds), one write in flight at a time; the full bake waits for
        // the edit to rest (below).
        if !geometry_changed
            && !self.live_recolour_in_flight
            && self.live_recoloured.as_ref() != Some(scene)
            && let Some(request) = self.live_recolour_request(scene)
            && let Some(worker) = &self.worker
        {
            worker.recolour(request);
            self.baker.cancel();
            self.live_recolour_in_flight = true;
            self.live_recoloured = Some(scene.clone());
            self.recolour_edited_at =
                Some(self.pending_fabric.as_ref().map_or_else(Instant::now, |(_, at)| *at));
        }
        let rested = self.pending_fabric.as_ref().map_or(Duration::ZERO, |(_, at)| at.elapsed());
        if rested < FABRIC_EDIT_SETTLE || ctx.input(|i| i.pointer.any_down()) {
            ctx.request_repaint_after(FABRIC_EDIT_SETTLE.saturating_sub(rested));
            return;
        }
        if self.live_recolour_in_flight {
            // The full bake waits for the colours being written: started at once, its transfer
            // stage would hold every core (and rayon's pool, which the recolouring uses) for
            // seconds.
            ctx.request_repaint_after(Duration::from_millis(20));
            return;
        }
        if let Some(edited) = self.recolour_edited_at
            && edited.elapsed() < LIVE_PICTURE_BEFORE_BAKE
        {
            // The first picture of the colours written live renders before the full bake takes
            // the cores: on lavapipe the reduced picture took 0.44–0.68 s beside the bake's
            // transfer stage against about 0.2 s alone. The picture's arrival wakes the window.
            ctx.request_repaint_after(LIVE_PICTURE_BEFORE_BAKE.saturating_sub(edited.elapsed()));
            return;
        }
        let scene = scene.clone();
        if self.live_recoloured.as_ref() == Some(&scene) {
            // These colours are on the GPU, written from the bases while the edit moved (the
            // write's failure, if it failed, was logged): the full bake follows without a
            // preview of its own.
            self.baker.start(scene.clone(), vec![self.final_quality]);
        } else if let (Some(previous), false) = (&self.shown_bake, geometry_changed) {
            // A material edit the bases cannot write live (a lobe edit: its full bake makes new
            // bases; or a fabric on the GPU not yet at the bases' quality) previews first.
            let materials = scene.material_descs().unwrap_or_default();
            let recolour = (self.recolour.as_ref())
                .filter(|(quality, bases)| {
                    *quality == self.final_quality && bases.iter().all(|b| b.fits(&materials))
                })
                .map(|(_, bases)| Arc::clone(bases));
            self.baker.start_material_edit(scene.clone(), self.final_quality, Arc::clone(previous), recolour);
        } else {
            self.recolour = None;
            self.live_recoloured = None;
            self.baker.start(scene.clone(), bake_sequence(self.final_quality));
        }
        self.baked_scene = Some(scene);
        self.pending_fabric = None;
    }

    /// A live recolouring of the fabric on the GPU to `scene`'s colours, where the bases fit
    /// its lobes and the fabric on the GPU is at the bases' quality.
    fn live_recolour_request(&self, scene: &SceneFile) -> Option<RecolourRequest> {
        let materials = scene.material_descs().ok()?;
        let (quality, bases) = self.recolour.as_ref()?;
        let on_gpu = self.fabric.as_ref().is_some_and(|f| f.quality == *quality);
        (*quality == self.final_quality && on_gpu && bases.iter().all(|b| b.fits(&materials)))
            .then(|| RecolourRequest { bases: Arc::clone(bases), materials })
    }

    /// Stops the bake in flight.
    fn cancel_bakes(&mut self) {
        self.baker.cancel();
    }

    /// No bake running or waiting, the latest bake of the scene as edited on screen (not a
    /// preview) and its picture current.
    fn is_idle(&self) -> bool {
        let baked_current = self
            .scene_file
            .as_ref()
            .is_some_and(|s| bake_changes(self.baked_scene.as_ref(), s) == (false, false));
        baked_current
            && self.pending_fabric.is_none()
            && !self.baker.busy()
            && self.uploading.is_empty()
            && self.fabric.as_ref().is_some_and(|f| !f.preview)
            && self.picture_is_current()
    }

    /// The UI frame times recorded so far, as text.
    fn frame_times_report(&self) -> String {
        use std::fmt::Write as _;
        let mut text = String::new();
        for (what, frames) in [("while baking", &self.ui_timing.baking), ("not baking", &self.ui_timing.idle)]
        {
            let interval = FrameStats::of(frames.iter().map(|f| f.1));
            let ui = FrameStats::of(frames.iter().map(|f| f.0));
            match (interval, ui) {
                (Some(interval), Some(ui)) => {
                    let _ = writeln!(text, "{what}: frame interval {interval}; ui() CPU time {ui}");
                }
                _ => {
                    let _ = writeln!(text, "{what}: no frames");
                }
            }
        }
        text
    }

    fn snapshot(&self) -> Option<Snapshot> {
        Some(Snapshot {
            scene: self.scene_file.clone()?,
            lights: self.lights.clone(),
            gpu: self.controls.gpu,
        })
    }

    fn apply_snapshot(&mut self, snapshot: Snapshot) {
        self.scene_file = Some(snapshot.scene);
        self.lights = snapshot.lights;
        self.selected_light = self.selected_light.min(self.lights.len().saturating_sub(1));
        self.controls.gpu = snapshot.gpu;
    }

    fn undo(&mut self) -> bool {
        let Some(current) = self.snapshot() else { return false };
        self.history.undo(&current).map(|s| self.apply_snapshot(s)).is_some()
    }

    fn redo(&mut self) -> bool {
        let Some(current) = self.snapshot() else { return false };
        self.history.redo(&current).map(|s| self.apply_snapshot(s)).is_some()
    }

    /// The scene as it is on screen: the edited fabric, materials and mesh, the camera, lights
    /// and render settings.
    fn current_scene_file(&self) -> Result<SceneFile, String> {
        let mut scene = self.scene_file.clone().ok_or("no scene is loaded")?;
        scene.camera = self.camera.section();
        scene.lights = self.lights.iter().map(LightEdit::section).collect();
        scene.gpu = self.controls.gpu;
        scene.render.spp = self.controls.target_spp;
        scene.render.exposure = self.controls.exposure;
        Ok(scene)
    }

    fn save_scene(&mut self, path: &Path) -> Result<(), String> {
        let scene = self.current_scene_file()?;
        scene.save(path).map_err(|e| format!("the scene could not be saved: {e}"))?;
        self.messages.info(format!("saved {}", path.display()));
        Ok(())
    }

    /// Opens another scene: its fabric is baked (draft first), its camera, lights and
    /// settings replace the current ones, and undo starts afresh.
    fn load_scene(&mut self, path: &Path) -> Result<(), String> {
        let file = read_scene(path)?;
        file.build().map_err(|e| format!("the scene cannot be built: {e}"))?;
        self.camera = OrbitCamera::from_section(&file.camera);
        self.initial_camera = self.camera;
        self.lights = file.lights.iter().map(LightEdit::from_section).collect();
        self.scene_lights = self.lights.clone();
        self.selected_light = 0;
        self.controls = default_controls(&file);
        self.source_path = path.to_path_buf();
        self.paint = None;
        self.paint_kept = None;
        self.scene_file = Some(file.clone());
        self.shown_bake = None;
        self.recolour = None;
        self.live_recoloured = None;
        self.fabric = None;
        self.baker.start(file.clone(), bake_sequence(self.final_quality));
        self.baked_scene = Some(file);
        self.pending_fabric = None;
        if let Some(current) = self.snapshot() {
            self.history.reset(&current);
        }
        self.messages.info(format!("loaded {}", path.display()));
        Ok(())
    }

    fn handle_bake_events(&mut self) {
        for event in self.baker.poll() {
            match event {
                BakeEvent::Ready(bake) => {
                    let Some(worker) = &self.worker else { continue };
                    let fabric_id = self.next_fabric_id;
                    self.next_fabric_id += 1;
                    self.uploading.push(Uploading {
                        fabric_id,
                        bake_seconds: bake.seconds,
                        computed: bake.computed.clone(),
                        baked: Arc::clone(&bake.baked),
                    });
                    worker.set_fabric(NewFabric {
                        fabric_id,
                        quality: bake.quality,
                        preview: bake.preview,
                        baked: bake.baked,
                        scene: bake.scene,
                    });
                }
                BakeEvent::RecolourReady { quality, bases, seconds } => {
                    self.messages.info(format!(
                        "colour edits now update multiple scattering at once (recolouring basis ready in \
                         {seconds:.1} s)"
                    ));
                    self.recolour = Some((quality, bases));
                }
                BakeEvent::Failed { message } => self.messages.error(message),
            }
        }
    }

    fn handle_worker_events(&mut self) {
        let Some(worker) = &self.worker else { return };
        for event in worker.poll() {
            match event {
                WorkerEvent::FabricReady {
                    fabric_id,
                    quality,
                    preview,
                    adapter,
                    resident_bytes,
                    bounds,
                    seconds,
                } => {
                    let uploaded = self.uploading.iter().position(|u| u.fabric_id == fabric_id);
                    let (bake_seconds, computed_stages) = match uploaded {
                        Some(i) => {
                            let u = &self.uploading[i];
                            self.shown_bake = Some(Arc::clone(&u.baked));
                            (u.bake_seconds, u.computed.clone())
                        }
                        None => (0.0, Vec::new()),
                    };
                    self.uploading.retain(|u| u.fabric_id > fabric_id);
                    // A new fabric replaces whatever colours were written live (and drops a
                    // recolouring the worker had not started).
                    self.live_recoloured = None;
                    if std::mem::take(&mut self.live_recolour_in_flight) {
                        self.recolour_edited_at = None;
                    }
                    self.fabric = Some(FabricInfo {
                        id: fabric_id,
                        quality,
                        preview,
                        bake_seconds,
                        computed_stages,
                        upload_seconds: seconds,
                        adapter,
                        resident_bytes,
                        bounds,
                    });
                }
                WorkerEvent::FabricFailed { message } | WorkerEvent::MeshFailed { message } => {
                    self.messages.error(message);
                }
                WorkerEvent::Recoloured { seconds } => {
                    if let Some(f) = &mut self.fabric {
                        f.preview = true;
                    }
                    self.live_recolour_in_flight = false;
                    self.restart_picture = true;
                    // Shown as an edit is: first at the reduced size, then refined. A picture of
                    // its own (a new generation), so the reduced one is asked for until it is
                    // shown, even when a batch of the old colours holds the worker past the
                    // interaction's settle time (that batch is stopped between two bands).
                    self.generation += 1;
                    self.last_edit = Instant::now();
                    self.edit_generation = self.generation;
                    log::info!("colours written from the recolouring bases in {:.0} ms", seconds * 1e3);
                }
                WorkerEvent::RecolourFailed { message } => {
                    self.live_recolour_in_flight = false;
                    self.recolour_edited_at = None;
                    // The full bake that follows the edit's rest shows the new colours.
                    log::warn!("no live recolouring: {message}");
                }
                WorkerEvent::MeshReady { bounds, seconds } => {
                    self.shell_id += 1;
                    if let Some(f) = &mut self.fabric {
                        f.bounds = bounds;
                    }
                    log::info!("new shell in {seconds:.2} s");
                }
                WorkerEvent::Frame(result) => {
                    if self.in_flight.as_ref() == Some(&result.request) {
                        self.in_flight = None;
                    }
                    self.frame_cost.add(&result.request.settings, result.wall_ms);
                    match Accumulation::add(&mut self.accumulation, &result) {
                        Added::Dropped => {}
                        added => {
                            self.texture_dirty = true;
                            if added == Added::Restarted
                                && self.restart_picture
                                && !self.live_recolour_in_flight
                                && let Some(edited) = self.recolour_edited_at.take()
                            {
                                let size = [result.request.settings.width, result.request.settings.height];
                                let took = edited.elapsed();
                                log::info!(
                                    "colour edit to picture: {:.0} ms ({}x{})",
                                    took.as_secs_f64() * 1e3,
                                    size[0],
                                    size[1]
                                );
                                self.last_recolour_to_picture = Some((took, size));
                            }
                            self.restart_picture &= added != Added::Restarted;
                        }
                    }
                }
                WorkerEvent::Toned(frame) => {
                    if self.accumulation.as_mut().is_some_and(|acc| acc.retoned(&frame)) {
                        self.texture_dirty = true;
                    }
                }
                WorkerEvent::FrameRestart { generation } => {
                    self.in_flight = None;
                    self.restart_picture = true;
                    log::debug!(
                        "generation {generation}: the picture on the GPU was replaced; starting again"
                    );
                }
                WorkerEvent::FrameInterrupted { request, bands_done } => {
                    // Stopped for newer work, which the worker takes next: the picture on the GPU
                    // ended, so whatever follows starts from sample 0.
                    if self.in_flight.as_ref() == Some(&request) {
                        self.in_flight = None;
                    }
                    self.restart_picture = true;
                    log::debug!(
                        "generation {}: batch stopped after {bands_done} bands for newer work",
                        request.generation
                    );
                }
                WorkerEvent::FrameFailed { generation, message } => {
                    self.in_flight = None;
                    if self.failed_generation != Some(generation) {
                        self.failed_generation = Some(generation);
                        self.messages.error(message);
                    }
                }
                WorkerEvent::ExportProgress { done, total } => {
                    self.export_status = ExportStatus::Running { done, total };
                }
                WorkerEvent::ExportDone { files, seconds } => {
                    self.export_status = ExportStatus::Idle;
                    self.last_export = Some(ExportOutcome::Done);
                    let names: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
                    self.messages.info(format!("exported {} in {seconds:.1} s", names.join(" and ")));
                }
                WorkerEvent::ExportFailed { message } => {
                    self.export_status = ExportStatus::Idle;
                    self.last_export = Some(ExportOutcome::Failed(message.clone()));
                    self.messages.error(message);
                }
                WorkerEvent::DeviceLost { reason } => {
                    // The frame in flight is lost with the device: ask again once it is back.
                    self.in_flight = None;
                    self.messages.info(format!(
                        "The render device was lost: {reason}. Opening a new one and uploading the fabric again."
                    ));
                }
                WorkerEvent::DeviceRecovered { adapter, seconds } => {
                    self.in_flight = None;
                    self.failed_generation = None;
                    self.device_recoveries += 1;
                    if let Some(f) = &mut self.fabric {
                        f.adapter.clone_from(&adapter);
                    }
                    self.messages.info(format!(
                        "Rendering again on a new device ({adapter}, ready in {seconds:.1} s)."
                    ));
                }
                WorkerEvent::DeviceUnavailable { message } => self.messages.error(message),
            }
        }
    }

    /// Shows the newest picture: a picture on the window's device as a native texture (the
    /// renderer's display texture itself), pixels read back from the worker's device through
    /// an egui texture. An exposure or curve edit asks the worker to tone-map the picture again.
    fn refresh_texture(&mut self, ctx: &egui::Context) {
        let tone = (self.controls.exposure, self.controls.filmic);
        if tone != self.shown_tone {
            self.shown_tone = tone;
            if let Some(worker) = &self.worker {
                worker.tone_map(ToneRequest { exposure: tone.0, filmic: tone.1 });
            }
        }
        let Some(acc) = self.accumulation.as_ref().filter(|_| self.texture_dirty) else { return };
        match &acc.picture {
            Picture::Pixels(rgba) => {
                let size = [acc.width as usize, acc.height as usize];
                let image = egui::ColorImage::from_rgba_unmultiplied(size, rgba);
                match &mut self.viewport_texture {
                    Some(ViewportTexture::Managed(handle)) => handle.set(image, egui::TextureOptions::LINEAR),
                    shown => {
                        if let (Some(ViewportTexture::Native { id, .. }), Some(state)) =
                            (shown.as_ref(), &self.render_state)
                        {
                            state.renderer.write().free_texture(id);
                        }
                        let handle = ctx.load_texture("twill.viewport", image, egui::TextureOptions::LINEAR);
                        *shown = Some(ViewportTexture::Managed(handle));
                    }
                }
            }
            Picture::Texture(texture) => {
                let Some(state) = &self.render_state else { return };
                let view = texture.create_view(&wgpu::TextureViewDescriptor {
                    label: Some("twill.viewport.view"),
                    ..Default::default()
                });
                let mut renderer = state.renderer.write();
                let filter = wgpu::FilterMode::Linear;
                match &mut self.viewport_texture {
                    Some(ViewportTexture::Native { id, texture: shown }) => {
                        if shown != texture {
                            renderer.update_egui_texture_from_wgpu_texture(&state.device, &view, filter, *id);
                            shown.clone_from(texture);
                        }
                    }
                    shown => {
                        let id = renderer.register_native_texture(&state.device, &view, filter);
                        *shown = Some(ViewportTexture::Native { id, texture: texture.clone() });
                    }
                }
            }
        }
        self.texture_dirty = false;
    }

    fn fit_view(&mut self) -> Result<(), String> {
        let fabric = self.fabric.as_ref().ok_or("no fabric on screen yet")?;
        let [w, h] = self.viewport_px;
        let (lo, hi) = fabric.bounds;
        self.camera.fit(lo.as_dvec3(), hi.as_dvec3(), f64::from(w.max(1)) / f64::from(h.max(1)));
        Ok(())
    }

    fn current_lights(&self) -> Result<Vec<Light>, String> {
        self.lights
            .iter()
            .enumerate()
            .map(|(i, l)| l.light().map_err(|e| format!("light {i}: {e}")))
            .collect()
    }

    /// Whether the accumulation on screen is of the current view at the viewport's full size.
    /// Lets a bake thread that holds for the picture go on (`bake.rs`: the picture comes first)
    /// once the fabric it handed over last has a frame on screen, or when nothing can render it.
    fn release_bake_for_picture(&self) {
        if !self.baker.holding() {
            return;
        }
        let handed_over = self.pending_fabric.is_none() && self.uploading.is_empty();
        let shown = match (&self.accumulation, &self.fabric) {
            (Some(acc), Some(fabric)) => acc.fabric_id == fabric.id,
            _ => false,
        };
        if (handed_over && shown) || self.worker.is_none() {
            self.baker.picture_shown();
        }
    }

    fn picture_is_current(&self) -> bool {
        match (&self.accumulation, &self.fabric) {
            (Some(acc), Some(fabric)) => {
                acc.generation == self.generation
                    && acc.fabric_id == fabric.id
                    && [acc.width, acc.height] == self.viewport_px
            }
            _ => false,
        }
    }

    fn shortcuts(&mut self, ctx: &egui::Context) {
        if ctx.egui_wants_keyboard_input() {
            return;
        }
        let (undo, redo) = ctx.input_mut(|i| {
            let redo = i.consume_key(egui::Modifiers::COMMAND | egui::Modifiers::SHIFT, egui::Key::Z)
                || i.consume_key(egui::Modifiers::COMMAND, egui::Key::Y);
            (i.consume_key(egui::Modifiers::COMMAND, egui::Key::Z), redo)
        });
        if let Some(paint) = &mut self.paint {
            // The scene is frozen while painting: Ctrl+Z undoes a stroke.
            if undo {
                paint.undo();
            }
            return;
        }
        if undo {
            self.undo();
        }
        if redo {
            self.redo();
        }
    }

    fn top_bar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            ui.label(egui::RichText::new("twill").strong());
            ui.label(egui::RichText::new(self.source_path.display().to_string()).weak());
            ui.separator();
            let has_fabric = self.fabric.is_some();
            if ui
                .add_enabled(has_fabric, egui::Button::new("Fit view (F)"))
                .on_hover_text("Frame the whole fabric")
                .clicked()
            {
                let _ = self.fit_view();
            }
            if ui.button("Reset view").on_hover_text("The scene's camera").clicked() {
                self.camera = self.initial_camera;
            }
            ui.separator();
            let current = self.snapshot();
            let painting = self.paint.is_some();
            let can_undo = !painting && current.as_ref().is_some_and(|c| self.history.can_undo(c));
            if ui.add_enabled(can_undo, egui::Button::new("Undo")).on_hover_text("Ctrl+Z").clicked() {
                self.undo();
            }
            if ui
                .add_enabled(!painting && self.history.can_redo(), egui::Button::new("Redo"))
                .on_hover_text("Ctrl+Shift+Z or Ctrl+Y")
                .clicked()
            {
                self.redo();
            }
            ui.separator();
            ui.add(
                egui::TextEdit::singleline(&mut self.scene_path_field)
                    .hint_text("scene.toml")
                    .desired_width(160.0),
            );
            let path = PathBuf::from(self.scene_path_field.trim());
            let has_path = !self.scene_path_field.trim().is_empty();
            if ui
                .add_enabled(has_path && self.scene_file.is_some(), egui::Button::new("Save"))
                .on_hover_text("Save the scene as shown (the CLI's format)")
                .clicked()
                && let Err(e) = self.save_scene(&path)
            {
                self.messages.error(e);
            }
            if ui
                .add_enabled(has_path, egui::Button::new("Open"))
                .on_hover_text("Open a scene file")
                .clicked()
                && let Err(e) = self.load_scene(&path)
            {
                self.messages.error(e);
            }
            ui.separator();
            match (self.baker.progress(), &self.fabric) {
                (Some(p), _) => {
                    ui.label(format!("baking {} ({:.0}%)", p.quality.name(), 100.0 * p.overall));
                }
                (None, Some(f)) => {
                    ui.label(format!("{} bake", f.quality.name()));
                }
                (None, None) => {}
            }
        });
    }

    /// The messages, over the bottom of the viewport (`area`).
    fn messages_overlay(&mut self, ctx: &egui::Context, area: egui::Rect) {
        self.messages.shown.retain(|(level, _, at)| *level == Level::Error || at.elapsed() < INFO_SECONDS);
        if self.messages.shown.is_empty() || !area.is_positive() {
            return;
        }
        if self.messages.shown.iter().any(|(level, ..)| *level == Level::Info) {
            ctx.request_repaint_after(Duration::from_secs(1));
        }
        let mut remove = None;
        let width = (area.width() - 16.0).max(100.0);
        egui::Area::new(egui::Id::unique("twill.messages"))
            .order(egui::Order::Foreground)
            .pivot(egui::Align2::LEFT_BOTTOM)
            .fixed_pos(area.left_bottom() + egui::vec2(8.0, -26.0))
            .show(ctx, |ui| {
                egui::Frame::popup(ui.style()).show(ui, |ui| {
                    ui.set_max_width(width);
                    egui::ScrollArea::vertical().max_height(140.0).show(ui, |ui| {
                        remove = self.messages_list(ui);
                    });
                });
            });
        if let Some(i) = remove {
            self.messages.shown.remove(i);
        }
    }

    /// The messages with their dismiss buttons; returns the one dismissed.
    fn messages_list(&self, ui: &mut egui::Ui) -> Option<usize> {
        let mut remove = None;
        for (i, (level, text, _)) in self.messages.shown.iter().enumerate() {
            ui.horizontal(|ui| {
                if ui.small_button("×").on_hover_text("Dismiss").clicked() {
                    remove = Some(i);
                }
                let colour = match level {
                    Level::Error => ui.visuals().error_fg_color,
                    Level::Info => ui.visuals().text_color(),
                };
                ui.add(egui::Label::new(egui::RichText::new(text).color(colour)).wrap());
            });
        }
        remove
    }

    fn left_panel(&mut self, ui: &mut egui::Ui) {
        if self.paint.is_some() {
            // The view, lights and fabric are frozen while painting: only the paint panel.
            egui::ScrollArea::vertical().show(ui, |ui| self.paint_panel(ui));
            return;
        }
        egui::ScrollArea::vertical().show(ui, |ui| {
            egui::CollapsingHeader::new("Paint").default_open(false).show(ui, |ui| self.paint_panel(ui));
            egui::CollapsingHeader::new("Lights").default_open(true).show(ui, |ui| {
                let outcome = lights_panel(
                    ui,
                    &mut self.lights,
                    &mut self.selected_light,
                    &self.scene_lights,
                    self.camera.yaw_deg,
                );
                if outcome.changed {
                    ui.ctx().request_repaint();
                }
                if let Some(e) = &self.lights_error {
                    ui.colored_label(ui.visuals().error_fg_color, e);
                }
            });
            if let Some(scene) = self.scene_file.as_mut() {
                egui::CollapsingHeader::new("Fibers").default_open(true).show(ui, |ui| {
                    fibers_panel(ui, scene);
                });
                let has_palette = !scene.materials.palette.is_empty();
                egui::CollapsingHeader::new("Colourway").default_open(has_palette).show(ui, |ui| {
                    colourway_panel(ui, scene, &mut self.colourway_form);
                });
                egui::CollapsingHeader::new("Weave").default_open(true).show(ui, |ui| {
                    match weave_panel(ui, scene, &mut self.weave_form) {
                        Some(WeaveAction::ImportWif(path)) => {
                            self.weave_form.message = import_wif(scene, Path::new(&path)).err();
                        }
                        None => {}
                    }
                });
                egui::CollapsingHeader::new("Mesh").default_open(false).show(ui, |ui| {
                    let swatch = scene.swatch.size_cm;
                    mesh_panel(ui, &mut scene.mesh, swatch, &mut self.mesh_form);
                });
            }
            egui::CollapsingHeader::new("Export").default_open(true).show(ui, |ui| {
                let size = (self.viewport_px[0] > 0).then_some(self.viewport_px);
                let can_export = self.fabric.is_some() && self.worker.is_some();
                match export_panel(ui, &mut self.export_form, &self.export_status, size, can_export) {
                    Some(ExportAction::Start) => {
                        let form = self.export_form.clone();
                        if let Err(e) = self.start_export(&form) {
                            self.messages.error(e);
                        }
                    }
                    Some(ExportAction::Cancel) => {
                        if let Some(worker) = &self.worker {
                            worker.cancel_export();
                        }
                    }
                    None => {}
                }
            });
        });
    }

    /// Takes paint mode's precompute and the verification's references when they arrive.
    fn handle_paint_events(&mut self) {
        if let Some(outcome) = self.paint.as_mut().and_then(PaintSession::poll) {
            match outcome {
                Ok(line) => self.messages.info(line),
                Err(e) => self.messages.error(e),
            }
        }
        if let Some(outcome) = self.verification.as_mut().and_then(Verification::poll) {
            match outcome {
                Ok(line) => self.messages.info(line),
                Err(e) => self.messages.error(e),
            }
        }
    }

    /// Freezes the view and starts paint mode's precompute.
    fn start_paint(&mut self, ctx: &egui::Context) -> Result<(), String> {
        let scene = self.current_scene_file()?;
        let [w, h] = self.viewport_px;
        if w < MIN_VIEWPORT_PX || h < MIN_VIEWPORT_PX {
            return Err("the viewport is too small to paint in".into());
        }
        if let Some(kept) = self.paint_kept.take_if(|k| k.fits(&scene, &self.paint_form)) {
            self.paint = Some(PaintSession::resume(kept));
            self.messages.info("paint mode: the same view as before, its precompute and painting kept");
            return Ok(());
        }
        self.paint = Some(PaintSession::start(scene, [w, h], &self.paint_form, ctx)?);
        Ok(())
    }

    /// Ends paint mode, keeping its precompute and painting for the same view.
    fn leave_paint(&mut self) {
        if let Some(session) = self.paint.take() {
            self.paint_kept = session.into_kept();
        }
    }

    /// Saves the painting, opens one, or saves the precompute, at the panel's file.
    fn paint_file_action(&mut self, action: PaintFileAction) -> Result<(), String> {
        let paint = self.paint.as_mut().ok_or("paint mode is not on")?;
        let path = PathBuf::from(self.paint_form.file.trim());
        if path.as_os_str().is_empty() {
            return Err("give a file name".into());
        }
        let line = match action {
            PaintFileAction::SavePainting => paint.save_painting(&path)?,
            PaintFileAction::OpenPainting => paint.open_painting(&path)?,
            PaintFileAction::SavePaintFile => paint.save_paint_file(&path.with_extension("twillpaint"))?,
        };
        self.messages.info(line);
        Ok(())
    }

    /// Turns the painting into the scene's colour orders, leaves paint mode and queues the
    /// verification of the committed scene.
    fn commit_paint(&mut self, ctx: &egui::Context) -> Result<(), String> {
        let paint = self.paint.as_ref().ok_or("paint mode is not on")?;
        let (committed, line) = paint.commit()?;
        let verification = paint.verify(Some(&committed), self.paint_form.verify_spp, ctx)?;
        let scene = self.scene_file.as_mut().ok_or("no scene is loaded")?;
        // Only the colours change: the view and render settings stay as they are on screen.
        scene.materials = committed.materials;
        self.verification = Some(verification);
        self.leave_paint();
        self.messages.info(format!("{line}; a path-traced verification is queued"));
        Ok(())
    }

    /// Path-traces the painted cloth to check the painting (paint mode stays on).
    fn verify_paint(&mut self, ctx: &egui::Context) -> Result<(), String> {
        let paint = self.paint.as_ref().ok_or("paint mode is not on")?;
        self.verification = Some(paint.verify(None, self.paint_form.verify_spp, ctx)?);
        self.paint_shown = Shown::Painting;
        Ok(())
    }

    fn paint_panel(&mut self, ui: &mut egui::Ui) {
        let ctx = ui.ctx().clone();
        let Some(paint) = &mut self.paint else {
            ui.label(
                "Freeze this view and paint colours onto single yarns and yarn sections, seeing the \
                 path-traced result at once (Hašan & Ramamoorthy 2013).",
            );
            let form = &mut self.paint_form;
            ui.horizontal(|ui| {
                ui.label("image side");
                choice(ui, "twill.paint.side", &mut form.side, &SIDE_CHOICES, "px");
            });
            ui.horizontal(|ui| {
                ui.label("paths per pixel");
                choice(ui, "twill.paint.spp", &mut form.spp, &SPP_CHOICES, "");
            });
            let can_start = self.scene_file.is_some();
            if ui
                .add_enabled(can_start, egui::Button::new("Paint this view"))
                .on_hover_text("Freezes the view and lights, then precomputes in the background")
                .clicked()
                && let Err(e) = self.start_paint(&ctx)
            {
                self.messages.error(e);
            }
            self.verification_status(ui);
            return;
        };
        let [w, h] = paint.size();
        ui.label(egui::RichText::new("Paint mode").strong());
        if let Some((fraction, seconds)) = paint.progress() {
            ui.label(format!("Precomputing {w}x{h} at {} spp…", self.paint_form.spp));
            ui.add(egui::ProgressBar::new(fraction).show_percentage().text(format!("{seconds:.0} s")));
        } else if let Some(e) = paint.failure() {
            ui.colored_label(ui.visuals().error_fg_color, e.to_owned());
        } else {
            ui.horizontal(|ui| {
                ui.label("brush");
                // egui's picker round-trips the colour through HSV every frame: only a change
                // the designer made is taken.
                let mut rgb = paint.colour;
                if ui.color_edit_button_rgb(&mut rgb).on_hover_text("Linear RGB: the yarn's C_TT").changed() {
                    paint.colour = rgb.map(|c| c.clamp(0.0, 1.0));
                }
                for c in paint.colours_in_use(6) {
                    let swatch = super::fabric::srgb(c.map(f64::from));
                    let button = egui::Button::new("").fill(swatch).min_size(egui::vec2(16.0, 16.0));
                    if ui.add(button).on_hover_text("A colour on the cloth now").clicked() {
                        paint.colour = c;
                    }
                }
            });
            ui.horizontal(|ui| {
                ui.label("paints");
                for scope in Scope::ALL {
                    ui.radio_value(&mut paint.scope, scope, scope.label());
                }
            });
            ui.horizontal(|ui| {
                if ui.add_enabled(paint.can_undo(), egui::Button::new("Undo stroke")).clicked() {
                    paint.undo();
                }
                if ui.button("Reset").on_hover_text("The scene's own colours").clicked() {
                    paint.reset();
                }
            });
            ui.label(format!("each stroke: {:.1} ms ({w}x{h})", paint.edit_ms));
            if let Some(action) = &paint.last_action {
                ui.label(egui::RichText::new(action).weak());
            }
            ui.separator();
            ui.horizontal(|ui| {
                ui.label("verification");
                choice(
                    ui,
                    "twill.paint.verify_spp",
                    &mut self.paint_form.verify_spp,
                    &VERIFY_SPP_CHOICES,
                    "spp",
                );
            });
            let mut action = None;
            ui.horizontal(|ui| {
                if ui
                    .button("Commit")
                    .on_hover_text(
                        "The painting as the scene's colour orders (each thread one colour, repeating), \
                         then a path-traced check",
                    )
                    .clicked()
                {
                    action = Some(true);
                }
                if ui.button("Verify").on_hover_text("Path-trace the painted cloth and compare").clicked() {
                    action = Some(false);
                }
            });
            let outcome = match action {
                Some(true) => self.commit_paint(&ctx),
                Some(false) => self.verify_paint(&ctx),
                None => Ok(()),
            };
            if let Err(e) = outcome {
                self.messages.error(e);
            }
        }
        let size = self.paint.as_ref().map(PaintSession::size);
        if let (Some(size), Some(verification)) = (size, self.verification.as_mut())
            && verification.picture(Shown::Reference, size).is_some()
        {
            ui.horizontal(|ui| {
                ui.label("show");
                for shown in Shown::ALL {
                    ui.radio_value(&mut self.paint_shown, shown, shown.label());
                }
            });
        }
        if self.paint.as_ref().is_some_and(PaintSession::is_ready) {
            ui.separator();
            ui.add(egui::TextEdit::singleline(&mut self.paint_form.file).hint_text("painting.toml"));
            let mut action = None;
            ui.horizontal(|ui| {
                if ui
                    .button("Save painting")
                    .on_hover_text("The strokes, as `twill paint` reads them")
                    .clicked()
                {
                    action = Some(PaintFileAction::SavePainting);
                }
                if ui.button("Open painting").on_hover_text("Paint a painting file's strokes").clicked() {
                    action = Some(PaintFileAction::OpenPainting);
                }
            });
            ui.horizontal(|ui| {
                if ui
                    .button("Save precompute")
                    .on_hover_text(
                        "A .twillpaint file beside it, for `twill paint apply`, `verify` and `commit`",
                    )
                    .clicked()
                {
                    action = Some(PaintFileAction::SavePaintFile);
                }
            });
            if let Some(action) = action
                && let Err(e) = self.paint_file_action(action)
            {
                self.messages.error(e);
            }
        }
        if self.paint.is_some() && ui.button("Leave paint mode").clicked() {
            self.leave_paint();
        }
        self.verification_status(ui);
    }

    fn verification_status(&self, ui: &mut egui::Ui) {
        let Some(verification) = &self.verification else { return };
        if let Some(fraction) = verification.progress() {
            ui.add(egui::ProgressBar::new(fraction).show_percentage().text("verifying"));
        } else if let Some(report) = verification.report() {
            let (text, colour) = match report {
                Ok(text) => (text, ui.visuals().text_color()),
                Err(e) => (e, ui.visuals().error_fg_color),
            };
            ui.add(egui::Label::new(egui::RichText::new(text).small().color(colour)).wrap());
        }
    }

    /// The viewport in paint mode: the painted picture; a click or drag paints, a right click
    /// picks a colour.
    fn paint_viewport(&mut self, ui: &mut egui::Ui, rect: egui::Rect, response: &egui::Response) {
        let painter = ui.painter_at(rect);
        painter.rect_filled(rect, 0.0, egui::Color32::from_gray(18));
        let display = Display {
            exposure: self.controls.exposure,
            curve: if self.controls.filmic { ToneCurve::Filmic } else { ToneCurve::Clamp },
        };
        let ctx = ui.ctx().clone();
        let Some(paint) = &mut self.paint else { return };
        let [w, h] = paint.size().map(|s| s as f32);
        let scale = (rect.width() / w).min(rect.height() / h);
        let image_rect = egui::Rect::from_center_size(rect.center(), egui::vec2(w, h) * scale);
        let verification_picture =
            self.verification.as_mut().and_then(|v| v.picture(self.paint_shown, paint.size()));
        let showing = if verification_picture.is_some() { self.paint_shown.label() } else { "painting" };
        let texture = match verification_picture {
            Some(picture) => Some(picture.texture(&ctx, display, self.controls.filmic)),
            None => paint.texture(&ctx, display, self.controls.filmic),
        };
        if let Some(texture) = texture {
            let uv = egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0));
            painter.image(texture.id(), image_rect, uv, egui::Color32::WHITE);
        } else {
            let text = match (paint.progress(), paint.failure()) {
                (Some((fraction, _)), _) => format!("Precomputing the paint view… {:.0}%", 100.0 * fraction),
                (None, Some(_)) => "The paint precompute failed: see the messages.".to_owned(),
                _ => String::new(),
            };
            painter.text(
                rect.center(),
                egui::Align2::CENTER_CENTER,
                text,
                egui::FontId::proportional(16.0),
                egui::Color32::from_gray(200),
            );
        }
        let at = response.interact_pointer_pos().map(|p| {
            let f = (p - image_rect.min) / image_rect.size();
            (f64::from(f.x), f64::from(f.y))
        });
        if paint.is_ready()
            && let Some((fx, fy)) = at
        {
            let outcome = if response.clicked_by(egui::PointerButton::Secondary) {
                paint.pick_at(fx, fy).map(|_| ())
            } else if response.clicked_by(egui::PointerButton::Primary)
                || response.dragged_by(egui::PointerButton::Primary)
            {
                let new_stroke = response.clicked() || response.drag_started();
                paint.paint_at(fx, fy, new_stroke).map(|_| ())
            } else {
                Ok(())
            };
            if let Err(e) = outcome {
                self.messages.error(e);
            }
        }
        overlay_text(
            &painter,
            rect.left_top() + egui::vec2(4.0, 4.0),
            egui::Align2::LEFT_TOP,
            format!("paint mode · {}×{} · view frozen · {showing}", w as u32, h as u32),
        );
        overlay_text(
            &painter,
            rect.left_bottom() + egui::vec2(4.0, -4.0),
            egui::Align2::LEFT_BOTTOM,
            "click or drag: paint · right click: pick a colour · Ctrl+Z: undo a stroke".into(),
        );
    }

    fn right_panel(&mut self, ui: &mut egui::Ui) {
        let view = QualityView {
            fabric: self.fabric.as_ref(),
            bake: self.baker.progress(),
            accumulation: self.accumulation.as_ref(),
            current: self.picture_is_current(),
            full_size: self.viewport_px,
            interaction_scale: self.interaction_scale(),
            ui_baking: FrameStats::of(self.ui_timing.baking.iter().map(|f| f.0)),
            ui_idle: FrameStats::of(self.ui_timing.idle.iter().map(|f| f.0)),
            expected: &self.expected_accuracy,
        };
        let (controls, bake_choice) = (&mut self.controls, &mut self.bake_choice);
        let action =
            egui::ScrollArea::vertical().show(ui, |ui| quality_panel(ui, controls, &view, bake_choice)).inner;
        match action {
            Some(QualityAction::Bake(q)) => self.start_bake(q),
            Some(QualityAction::CancelBake) => self.cancel_bakes(),
            None => {}
        }
    }

    fn viewport(&mut self, ui: &mut egui::Ui) {
        let ppp = ui.ctx().pixels_per_point();
        let available = ui.available_rect_before_wrap();
        // Whole physical pixels, so the picture maps 1:1 onto the screen.
        let min_px = (available.min.to_vec2() * ppp).round();
        let size_px = (available.size() * ppp).floor().max(egui::Vec2::ZERO);
        let rect = egui::Rect::from_min_size((min_px / ppp).to_pos2(), size_px / ppp);
        let response = ui.allocate_rect(rect, egui::Sense::click_and_drag());
        self.viewport_px = [size_px.x as u32, size_px.y as u32];
        self.viewport_rect_px = egui::Rect::from_min_size(min_px.to_pos2(), size_px);
        if self.paint.is_some() {
            self.paint_viewport(ui, rect, &response);
            return;
        }

        let delta = response.drag_delta();
        if response.dragged_by(egui::PointerButton::Primary) {
            self.camera.orbit_by_drag(f64::from(delta.x), f64::from(delta.y));
        } else if response.dragged_by(egui::PointerButton::Secondary)
            || response.dragged_by(egui::PointerButton::Middle)
        {
            self.camera.pan_by_drag(f64::from(delta.x), f64::from(delta.y), f64::from(rect.height()));
        }
        if response.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y);
            if scroll != 0.0 {
                self.camera.zoom((-f64::from(scroll) * 0.002).exp());
            }
        }
        let fit_key = !ui.ctx().egui_wants_keyboard_input() && ui.input(|i| i.key_pressed(egui::Key::F));
        if response.double_clicked() || fit_key {
            let _ = self.fit_view();
        }

        let painter = ui.painter_at(rect);
        painter.rect_filled(rect, 0.0, egui::Color32::from_gray(18));
        if let Some(texture) = &self.viewport_texture {
            let [w, h] = texture.size().map(|s| s as f32);
            let scale = (rect.width() / w).min(rect.height() / h);
            let image_rect = egui::Rect::from_center_size(rect.center(), egui::vec2(w, h) * scale);
            let uv = egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0));
            painter.image(texture.id(), image_rect, uv, egui::Color32::WHITE);
        } else {
            let text = if self.scene_file.is_none() {
                "The scene could not be loaded: see the messages.".to_owned()
            } else if let Some(p) = self.baker.progress() {
                format!("Baking the {} fabric… {:.0}%", p.quality.name(), 100.0 * p.overall)
            } else if self.fabric.is_some() {
                "Rendering…".to_owned()
            } else {
                "No fabric: see the messages.".to_owned()
            };
            painter.text(
                rect.center(),
                egui::Align2::CENTER_CENTER,
                text,
                egui::FontId::proportional(16.0),
                egui::Color32::from_gray(200),
            );
        }
        let status = match &self.accumulation {
            Some(acc) => {
                let state = if self.picture_is_current() { "" } else { " · updating" };
                format!("{} spp · {}×{}{state}", acc.samples, acc.width, acc.height)
            }
            None => String::new(),
        };
        overlay_text(&painter, rect.left_top() + egui::vec2(4.0, 4.0), egui::Align2::LEFT_TOP, status);
        overlay_text(
            &painter,
            rect.left_bottom() + egui::vec2(4.0, -4.0),
            egui::Align2::LEFT_BOTTOM,
            "drag: orbit · right/middle drag: pan · scroll: zoom · F: fit".into(),
        );
    }

    /// Compares the view with the last one and asks the worker for the next batch.
    fn schedule(&mut self, ctx: &egui::Context) {
        let lights = match self.current_lights() {
            Ok(lights) => {
                self.lights_error = None;
                lights
            }
            Err(e) => {
                self.lights_error = Some(e);
                return;
            }
        };
        let (Some(worker), Some(fabric)) = (&self.worker, &self.fabric) else { return };
        if self.live_recolour_in_flight {
            // New colours are being written: a batch asked for now would be rendered after
            // them as a picture of the old edit, and dropped. The next one is asked for once
            // they are written (a new generation, at the reduced size first), or refused.
            worker.clear_frame_request();
            self.in_flight = None;
            return;
        }
        if self.paint.is_some() {
            // Paint mode shows its own picture: the live renderer rests (and leaves the cores
            // to the precompute).
            worker.clear_frame_request();
            self.in_flight = None;
            return;
        }
        let [w, h] = self.viewport_px;
        if w < MIN_VIEWPORT_PX || h < MIN_VIEWPORT_PX {
            return;
        }
        let key = ViewKey {
            fabric_id: fabric.id,
            shell_id: self.shell_id,
            camera: self.camera.section(),
            lights,
            components: self.controls.components,
            gpu: self.controls.gpu,
            size: [w, h],
        };
        if self.view_key.as_ref() != Some(&key) {
            self.generation += 1;
            if self.view_key.as_ref().is_some_and(|old| !old.same_edit(&key)) {
                self.last_edit = Instant::now();
                self.edit_generation = self.generation;
            }
            self.view_key = Some(key.clone());
        }
        if self.failed_generation == Some(self.generation) {
            return;
        }
        let since_edit = self.last_edit.elapsed();
        let scale = self.interaction_scale();
        // A reduced preview while edits come in, and as the first picture after an edit (or the
        // very first picture) even when the worker was too busy to show one in time.
        let shown_since_edit =
            self.accumulation.as_ref().is_some_and(|a| a.generation >= self.edit_generation);
        let interacting = scale < 1.0 && (since_edit < INTERACTION_SETTLE || !shown_since_edit);
        let size = if interacting {
            let s = scale;
            [((f64::from(w) * s).round() as u32).max(1), ((f64::from(h) * s).round() as u32).max(1)]
        } else {
            [w, h]
        };
        if interacting {
            ctx.request_repaint_after(INTERACTION_SETTLE.saturating_sub(since_edit));
        }
        let first_sample = match &self.accumulation {
            Some(acc)
                if !self.restart_picture
                    && acc.generation == self.generation
                    && acc.fabric_id == fabric.id
                    && [acc.width, acc.height] == size =>
            {
                acc.samples
            }
            _ => 0,
        };
        let target = if interacting { 1 } else { self.controls.target_spp.max(1) };
        if first_sample >= target {
            worker.clear_frame_request();
            return;
        }
        // Batches double (1, 1, 2, 4, ...) but stay near BATCH_BUDGET_MS at the measured cost.
        let affordable = self.frame_cost.ns_per_pixel_sample.map_or(1, |cost| {
            let per_sample_ms = cost * f64::from(size[0]) * f64::from(size[1]) * 1e-6;
            (BATCH_BUDGET_MS / per_sample_ms.max(1e-6)).floor().clamp(1.0, f64::from(MAX_BATCH_SPP)) as u32
        });
        let spp = if first_sample == 0 {
            1
        } else {
            first_sample.min(MAX_BATCH_SPP).min(affordable).min(target - first_sample)
        };
        let request = FrameRequest {
            generation: self.generation,
            fabric_id: fabric.id,
            camera: key.camera,
            lights: key.lights,
            settings: FrameSettings {
                width: size[0],
                height: size[1],
                spp,
                // Tone mapped on the GPU; an exposure edit alone tone-maps the samples again.
                exposure: self.controls.exposure,
                filmic: self.controls.filmic,
                components: key.components,
                gpu: key.gpu,
                frame_transfer: true,
            },
            first_sample,
        };
        if self.in_flight.as_ref() != Some(&request) {
            worker.request_frame(request.clone());
            self.in_flight = Some(request);
        }
    }

    /// The fraction of the viewport rendered while the view changes: the chosen one, or with
    /// "auto" the one whose frame takes about `INTERACTION_BUDGET_MS` at the measured cost.
    fn interaction_scale(&self) -> f64 {
        let (lo, hi) = INTERACTION_SCALE_RANGE;
        if !self.controls.interaction_auto {
            return self.controls.interaction_scale.clamp(lo, hi);
        }
        let [w, h] = self.viewport_px;
        let pixels = f64::from(w) * f64::from(h);
        match self.frame_cost.ns_per_pixel_sample {
            Some(cost) if pixels > 0.0 => {
                let scale = (INTERACTION_BUDGET_MS * 1e6 / (cost * pixels)).sqrt().clamp(lo, hi);
                // Whole sixteenths, so the size does not change with every measurement.
                ((scale * 16.0).floor() / 16.0).clamp(lo, hi)
            }
            _ => 0.25,
        }
    }

    fn start_export(&mut self, form: &ExportForm) -> Result<(), String> {
        let worker = self.worker.as_ref().ok_or("no GPU device: nothing can be exported")?;
        if self.fabric.is_none() {
            return Err("no fabric on screen yet: nothing to export".into());
        }
        if matches!(self.export_status, ExportStatus::Running { .. }) {
            return Err("an export is already running".into());
        }
        let scene = self.current_scene_file()?;
        let path = PathBuf::from(form.path.trim());
        ExportFormat::of(&path)?;
        let lights = self.current_lights()?;
        let camera = scene.camera;
        let c = &self.controls;
        let render = RenderSection {
            width: form.width as usize,
            height: form.height as usize,
            spp: form.spp,
            exposure: c.exposure,
            ..scene.render
        };
        let mut toml = export_toml(&scene, &path, render)?;
        if c.components != Components::All {
            let only = if c.components == Components::SingleOnly { "single" } else { "multiple" };
            toml = format!("# Exported with only {only} scattering: twill render --only {only}\n{toml}");
        }
        worker.export(ExportRequest {
            camera,
            lights,
            settings: FrameSettings {
                width: form.width,
                height: form.height,
                spp: form.spp,
                exposure: c.exposure,
                filmic: c.filmic,
                components: c.components,
                gpu: c.gpu,
                frame_transfer: true,
            },
            image_path: path,
            scene_toml: toml,
        });
        self.export_status = ExportStatus::Running { done: 0, total: form.spp };
        self.last_export = None;
        Ok(())
    }

    fn run_script(&mut self, ctx: &egui::Context) {
        let Some(mut run) = self.script.take() else { return };
        if !run.finished {
            let before = run.next;
            if let Err(message) = self.advance_script(&mut run, ctx) {
                self.finish_script(&mut run, ctx, Err(message));
            } else if run.next >= run.lines.len() {
                self.finish_script(&mut run, ctx, Ok(()));
            } else if run.next != before {
                ctx.request_repaint();
            } else {
                // Waiting: the worker, the bake thread and the screenshot wake the window; this
                // only bounds how late a timeout is noticed.
                ctx.request_repaint_after(SCRIPT_POLL);
            }
        }
        self.script = Some(run);
    }

    fn advance_script(&mut self, run: &mut ScriptRun, ctx: &egui::Context) -> Result<(), String> {
        let Some(line) = run.lines.get(run.next).cloned() else { return Ok(()) };
        let at = |message: String| format!("script line {} ({}): {message}", line.line, line.text);
        while run.errors_seen < self.messages.errors.len() {
            let error = &self.messages.errors[run.errors_seen];
            run.errors_seen += 1;
            match &line.step {
                Step::ExpectError(text) if error.contains(text.as_str()) => run.expected_error_seen = true,
                _ => return Err(at(format!("the viewer showed an error: {error}"))),
            }
        }
        if self.script_step(&line.step, run, ctx).map_err(at)? {
            eprintln!(
                "script line {}: {} (done after {:.1} s)",
                line.line,
                line.text,
                run.step_started.elapsed().as_secs_f64()
            );
            run.next += 1;
            run.step_started = Instant::now();
            run.expected_error_seen = false;
            run.screenshot_rect = None;
        } else if run.step_started.elapsed() > STEP_TIMEOUT {
            return Err(at(format!("still waiting after {} s", STEP_TIMEOUT.as_secs())));
        }
        Ok(())
    }

    fn finish_script(&mut self, run: &mut ScriptRun, ctx: &egui::Context, result: Result<(), String>) {
        run.finished = true;
        match &result {
            Ok(()) => eprintln!("script finished"),
            Err(e) => eprintln!("script failed: {e}"),
        }
        *self.outcome.lock().unwrap_or_else(PoisonError::into_inner) = Some(result);
        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
    }

    /// Plays one step; `Ok(true)` when it is done, `Ok(false)` while it waits.
    fn script_step(&mut self, step: &Step, run: &mut ScriptRun, ctx: &egui::Context) -> Result<bool, String> {
        match step {
            Step::WaitFabric(q) => Ok(self.fabric.as_ref().is_some_and(|f| {
                f.quality == *q && self.accumulation.as_ref().is_some_and(|a| a.fabric_id == f.id)
            })),
            Step::ExpectBaking(q) => match self.baker.progress() {
                Some(p) if p.quality == *q => Ok(true),
                Some(p) => Err(format!("the bake in flight is {}, not {}", p.quality.name(), q.name())),
                None => Err(format!("no {} bake is in flight", q.name())),
            },
            Step::Bake(q) => {
                self.start_bake(*q);
                Ok(true)
            }
            Step::CancelBake => {
                self.cancel_bakes();
                Ok(true)
            }
            Step::Orbit { yaw_deg, pitch_deg } => {
                self.camera.orbit(*yaw_deg, *pitch_deg);
                Ok(true)
            }
            Step::Zoom(factor) => {
                self.camera.zoom(*factor);
                Ok(true)
            }
            Step::Fit => self.fit_view().map(|()| true),
            Step::Light { index, field } => {
                let count = self.lights.len();
                let light =
                    self.lights.get_mut(*index).ok_or(format!("no light {index}: the scene has {count}"))?;
                apply_light_field(light, *field)?;
                Ok(true)
            }
            Step::AddLight(kind) => {
                if self.lights.len() >= MAX_VIEWER_LIGHTS {
                    return Err(format!("at most {MAX_VIEWER_LIGHTS} lights"));
                }
                self.lights.push(new_light(*kind, self.camera.yaw_deg));
                Ok(true)
            }
            Step::RemoveLight(index) => {
                if *index >= self.lights.len() || self.lights.len() == 1 {
                    return Err(format!("cannot remove light {index} of {}", self.lights.len()));
                }
                self.lights.remove(*index);
                Ok(true)
            }
            Step::Preset(name) => {
                let p = preset(name).ok_or_else(|| {
                    let names: Vec<_> = super::lights::ENVIRONMENT_PRESETS.iter().map(|p| p.name).collect();
                    format!("unknown preset {name:?}; presets: {}", names.join(", "))
                })?;
                self.lights = (p.lights)();
                self.selected_light = 0;
                Ok(true)
            }
            Step::Set(setting) => {
                apply_setting(&mut self.controls, *setting)?;
                Ok(true)
            }
            Step::WaitSpp(n) => {
                let samples = self.accumulation.as_ref().map_or(0, |a| a.samples);
                let toned = self.accumulation.as_ref().is_some_and(|a| a.tone == self.shown_tone);
                if !self.picture_is_current() || self.texture_dirty || !toned || samples < *n {
                    return Ok(false);
                }
                if samples > *n {
                    return Err(format!(
                        "the picture has {samples} samples, more than {n}: lower the target with \
                         `set spp {n}` before the view settles"
                    ));
                }
                Ok(true)
            }
            Step::Screenshot(path) => {
                if run.screenshot_rect.is_none() {
                    run.screenshot_rect = Some(self.viewport_rect_px);
                    let (slot, repaint) = (Arc::clone(&run.screenshot), ctx.clone());
                    ctx.request_screenshot(move |image| {
                        *slot.lock().unwrap_or_else(PoisonError::into_inner) = Some(image);
                        repaint.request_repaint();
                    });
                    return Ok(false);
                }
                let Some(image) = run.screenshot.lock().unwrap_or_else(PoisonError::into_inner).take() else {
                    return Ok(false);
                };
                let rect = run.screenshot_rect.unwrap_or(egui::Rect::NOTHING);
                write_screenshots(path, &image, rect)?;
                Ok(true)
            }
            Step::Export { path, width, height, spp } => {
                let form = ExportForm {
                    path: path.display().to_string(),
                    width: *width,
                    height: *height,
                    spp: *spp,
                };
                self.start_export(&form)?;
                Ok(true)
            }
            Step::WaitExport => match (&self.export_status, &self.last_export) {
                (ExportStatus::Running { .. }, _) => Ok(false),
                (ExportStatus::Idle, Some(ExportOutcome::Done)) => Ok(true),
                (ExportStatus::Idle, Some(ExportOutcome::Failed(e))) => {
                    Err(format!("the export failed: {e}"))
                }
                (ExportStatus::Idle, None) => Err("no export was started".into()),
            },
            Step::ExpectError(_) => Ok(run.expected_error_seen),
            Step::Flip { .. }
            | Step::Weave(_)
            | Step::Repeat { .. }
            | Step::ImportWif(_)
            | Step::Palette { .. }
            | Step::Order { .. }
            | Step::Fiber { .. }
            | Step::Mesh(_) => {
                let scene = self.scene_file.as_mut().ok_or("no scene is loaded")?;
                edit_scene(scene, step)?;
                Ok(true)
            }
            Step::Undo => self.undo().then_some(true).ok_or_else(|| "nothing to undo".into()),
            Step::Redo => self.redo().then_some(true).ok_or_else(|| "nothing to redo".into()),
            Step::Save(path) => self.save_scene(path).map(|()| true),
            Step::Open(path) => self.load_scene(path).map(|()| true),
            Step::WaitIdle => {
                let idle = self.is_idle();
                if let (true, Some(f)) = (idle, &self.fabric) {
                    let names: Vec<&str> = f.computed_stages.iter().map(|s| s.name()).collect();
                    eprintln!(
                        "idle: the {} bake on screen computed [{}]",
                        f.quality.name(),
                        names.join(", ")
                    );
                }
                Ok(idle)
            }
            Step::Spin(seconds) => {
                let until =
                    *run.spin_until.get_or_insert_with(|| Instant::now() + Duration::from_secs_f64(*seconds));
                if Instant::now() >= until {
                    run.spin_until = None;
                    return Ok(true);
                }
                self.camera.orbit(0.5, 0.0);
                ctx.request_repaint();
                Ok(false)
            }
            Step::LoseDevice => {
                let Some(worker) = &self.worker else { return Err("no render worker is running".into()) };
                match run.recoveries_before_loss {
                    None => {
                        run.recoveries_before_loss = Some(self.device_recoveries);
                        worker.lose_device();
                        Ok(false)
                    }
                    Some(before) if self.device_recoveries > before => {
                        run.recoveries_before_loss = None;
                        Ok(true)
                    }
                    Some(_) => Ok(false),
                }
            }
            Step::FrameTimes(path) => {
                let text = self.frame_times_report();
                twill_precompute::atomic_file::write_atomically(path, |w| {
                    std::io::Write::write_all(w, text.as_bytes())
                })
                .map_err(|e| format!("{}: {e}", path.display()))?;
                eprint!("{text}");
                self.ui_timing.clear();
                Ok(true)
            }
            Step::WaitRecolourPicture => {
                Ok(self.last_recolour_to_picture.take().is_some_and(|(took, [w, h])| {
                    eprintln!("colour edit to picture: {:.0} ms ({w}x{h})", took.as_secs_f64() * 1e3);
                    true
                }))
            }
            Step::PaintStart { side, spp, verify_spp } => {
                self.paint_form.side = *side;
                self.paint_form.spp = *spp;
                self.paint_form.verify_spp = verify_spp.unwrap_or(self.paint_form.verify_spp);
                self.start_paint(ctx).map(|()| true)
            }
            Step::WaitPaint => {
                let paint = self.paint.as_ref().ok_or("paint mode is not on")?;
                match paint.failure() {
                    Some(e) => Err(format!("the paint precompute failed: {e}")),
                    None => Ok(paint.is_ready()),
                }
            }
            Step::PaintColour(rgb) => {
                self.paint.as_mut().ok_or("paint mode is not on")?.colour = *rgb;
                Ok(true)
            }
            Step::PaintScope(scope) => {
                self.paint.as_mut().ok_or("paint mode is not on")?.scope = *scope;
                Ok(true)
            }
            Step::PaintAt { x, y } => {
                let paint = self.paint.as_mut().ok_or("paint mode is not on")?;
                let what = paint.paint_at(*x, *y, true)?.ok_or("no yarn there")?;
                eprintln!("painted {what}: evaluated in {:.2} ms", paint.edit_ms);
                Ok(true)
            }
            Step::PaintPick { x, y } => {
                let paint = self.paint.as_mut().ok_or("paint mode is not on")?;
                paint.pick_at(*x, *y)?.then_some(true).ok_or_else(|| "no yarn there".into())
            }
            Step::PaintUndo => {
                let paint = self.paint.as_mut().ok_or("paint mode is not on")?;
                paint.undo().then_some(true).ok_or_else(|| "no stroke to undo".into())
            }
            Step::PaintCommit => {
                // As the panel's button does: a painting that is no colour order is an error in
                // the message list (a script expects it with `expect-error`).
                if let Err(e) = self.commit_paint(ctx) {
                    self.messages.error(e);
                }
                Ok(true)
            }
            Step::PaintVerify => self.verify_paint(ctx).map(|()| true),
            Step::WaitVerify => {
                let verification = self.verification.as_ref().ok_or("no verification was started")?;
                match verification.report() {
                    None => Ok(false),
                    Some(Ok(report)) => {
                        eprintln!("{report}");
                        Ok(true)
                    }
                    Some(Err(e)) => Err(e.clone()),
                }
            }
            Step::PaintLeave => {
                if self.paint.is_none() {
                    return Err("paint mode is not on".into());
                }
                self.leave_paint();
                Ok(true)
            }
            Step::PaintShow(shown) => {
                self.paint_shown = *shown;
                Ok(true)
            }
            Step::PaintFile { action, path } => {
                self.paint_form.file = path.display().to_string();
                self.paint_file_action(*action).map(|()| true)
            }
            Step::Quit => {
                run.next = run.lines.len() - 1;
                Ok(true)
            }
        }
    }
}

/// Applies a script's fabric or mesh edit through the panels' own functions.
fn edit_scene(scene: &mut SceneFile, step: &Step) -> Result<(), String> {
    use super::fabric::{flip_cell, resize_draft, set_fiber_field, set_weave_preset};
    use super::mesh::{set_builtin, set_thickness};
    use super::script::MeshEdit;
    match step {
        Step::Flip { row, col } => flip_cell(scene, *row, *col),
        Step::Weave(name) => {
            let preset = twill_precompute::fabric::weave::WeavePreset::ALL
                .into_iter()
                .find(|p| p.name() == name)
                .ok_or_else(|| format!("unknown weave {name:?}"))?;
            set_weave_preset(scene, preset)
        }
        Step::Repeat { rows, cols } => resize_draft(scene, *rows, *cols),
        Step::ImportWif(path) => import_wif(scene, path),
        Step::Palette { name, base, rgb } => super::colourway::set_palette_colour(scene, name, *base, *rgb),
        Step::Order { slot, text } => super::colourway::set_order(scene, *slot, text),
        Step::Fiber { slot, field } => set_fiber_field(scene, *slot, *field),
        Step::Mesh(MeshEdit::Builtin(name)) => set_builtin(&mut scene.mesh, name),
        Step::Mesh(MeshEdit::File(path)) => {
            scene.mesh.builtin = None;
            scene.mesh.path = Some(path.clone());
            Ok(())
        }
        Step::Mesh(MeshEdit::Thickness(t)) => set_thickness(&mut scene.mesh, *t),
        _ => Err("not a scene edit".into()),
    }
}

/// Small text on a dark plate over the picture.
/// What the Paint panel's file buttons do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PaintFileAction {
    SavePainting,
    OpenPainting,
    SavePaintFile,
}

/// A drop-down of choices for a number (`unit` after each).
fn choice(ui: &mut egui::Ui, id: &str, value: &mut u32, choices: &[u32], unit: &str) {
    egui::ComboBox::from_id_salt(id).selected_text(format!("{value} {unit}")).show_ui(ui, |ui| {
        for &c in choices {
            ui.selectable_value(value, c, format!("{c} {unit}"));
        }
    });
}

fn overlay_text(painter: &egui::Painter, anchor: egui::Pos2, align: egui::Align2, text: String) {
    if text.is_empty() {
        return;
    }
    let galley =
        painter.layout_no_wrap(text, egui::FontId::proportional(12.0), egui::Color32::from_gray(210));
    let rect = align.anchor_size(anchor, galley.size()).expand(2.0);
    painter.rect_filled(rect, 3.0, egui::Color32::from_black_alpha(150));
    painter.galley(rect.min + egui::vec2(2.0, 2.0), galley, egui::Color32::from_gray(210));
}

/// The device the renderer runs on: eframe's own, except on a software adapter (lavapipe),
/// whose single queue runs one submission at a time, so the window's frames would wait behind
/// every fabric frame (seconds each): there the renderer gets a device of its own.
/// `TWILL_VIEWER_DEVICE=shared|separate` overrides the choice.
/// The picture as egui draws it.
enum ViewportTexture {
    /// Pixels read back from the worker's own device, uploaded by egui.
    Managed(egui::TextureHandle),
    /// The renderer's display texture on the window's device, registered with egui's renderer.
    Native { id: egui::TextureId, texture: wgpu::Texture },
}

impl ViewportTexture {
    fn id(&self) -> egui::TextureId {
        match self {
            Self::Managed(handle) => handle.id(),
            Self::Native { id, .. } => *id,
        }
    }

    fn size(&self) -> [usize; 2] {
        match self {
            Self::Managed(handle) => handle.size(),
            Self::Native { texture, .. } => [texture.width() as usize, texture.height() as usize],
        }
    }
}

fn render_device(state: &eframe::egui_wgpu::RenderState) -> Result<DeviceHandles, String> {
    let info = state.adapter.get_info();
    let separate = match std::env::var("TWILL_VIEWER_DEVICE").as_deref() {
        Ok("shared") => false,
        Ok("separate") => true,
        _ => info.device_type == wgpu::DeviceType::Cpu,
    };
    if !separate {
        return Ok(DeviceHandles {
            adapter_info: info,
            device: state.device.clone(),
            queue: state.queue.clone(),
            own: false,
        });
    }
    let gpu = twill_renderer::gpu::Gpu::headless()
        .map_err(|e| format!("could not open a render device beside the window's: {e}"))?;
    Ok(DeviceHandles { adapter_info: gpu.adapter_info, device: gpu.device, queue: gpu.queue, own: true })
}

/// Reads and parses a scene file; the message says which of the two failed.
fn read_scene(path: &Path) -> Result<SceneFile, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("the scene could not be read: {}: {e}", path.display()))?;
    SceneFile::parse(&text, path).map_err(|e| format!("the scene could not be loaded: {e}"))
}

/// What differs between the scene last baked and `scene` in what a bake depends on:
/// (geometry: `[fabric]` or `[pattern]`, or the colour orders and palette names, which say which
/// yarn carries which material and set the exemplar repeat; materials: `[materials]`);
/// everything without a bake.
fn bake_changes(baked: Option<&SceneFile>, scene: &SceneFile) -> (bool, bool) {
    let colour_layout = |s: &SceneFile| {
        let m = &s.materials;
        (m.warp_order.clone(), m.weft_order.clone(), m.palette.keys().cloned().collect::<Vec<_>>())
    };
    baked.map_or((true, true), |b| {
        (
            b.fabric != scene.fabric
                || b.pattern != scene.pattern
                || colour_layout(b) != colour_layout(scene),
            b.materials != scene.materials,
        )
    })
}

/// The bakes to run for a final quality: draft first, for a quick first picture.
fn bake_sequence(quality: Quality) -> Vec<Quality> {
    if quality == Quality::Draft { vec![Quality::Draft] } else { vec![Quality::Draft, quality] }
}

fn apply_light_field(light: &mut LightEdit, field: LightField) -> Result<(), String> {
    match field {
        LightField::Azimuth(a) => light.azimuth_deg = super::lights::wrap_degrees(a),
        LightField::Elevation(e) if (-90.0..=90.0).contains(&e) => light.elevation_deg = e,
        LightField::Elevation(e) => return Err(format!("elevation {e} is outside -90..=90")),
        LightField::Sharpness(s) => {
            let (lo, hi) = SG_SHARPNESS_RANGE;
            if !(lo..=hi).contains(&s) {
                return Err(format!("sharpness {s} is outside {lo}..={hi}"));
            }
            light.sharpness = s;
        }
        LightField::Intensity(i) if i >= 0.0 => light.intensity = i,
        LightField::Intensity(i) => return Err(format!("intensity {i} is negative")),
        LightField::Colour(rgb) => {
            let (colour, scale) = super::lights::split_colour(rgb.map(f64::from));
            light.colour = colour;
            light.intensity *= scale;
        }
    }
    Ok(())
}

fn apply_setting(controls: &mut RenderControls, setting: Setting) -> Result<(), String> {
    let out_of = |what: &str, lo: f64, hi: f64| Err(format!("{what} must be in {lo}..={hi}"));
    match setting {
        Setting::Exposure(e) if (-30.0..=30.0).contains(&e) => controls.exposure = e,
        Setting::Exposure(_) => return out_of("exposure", -30.0, 30.0),
        Setting::Spp(n) if (TARGET_SPP_RANGE.0..=TARGET_SPP_RANGE.1).contains(&n) => controls.target_spp = n,
        Setting::Spp(_) => {
            return out_of("spp", f64::from(TARGET_SPP_RANGE.0), f64::from(TARGET_SPP_RANGE.1));
        }
        Setting::SigmaGlo(s) if (SIGMA_GLO_RANGE_CM.0..=SIGMA_GLO_RANGE_CM.1).contains(&s) => {
            controls.gpu.sigma_glo_cm = s;
        }
        Setting::SigmaGlo(_) => return out_of("sigma_glo", SIGMA_GLO_RANGE_CM.0, SIGMA_GLO_RANGE_CM.1),
        Setting::InteractionScale(s)
            if (INTERACTION_SCALE_RANGE.0..=INTERACTION_SCALE_RANGE.1).contains(&s) =>
        {
            controls.interaction_auto = false;
            controls.interaction_scale = s;
        }
        Setting::InteractionScale(_) => {
            return out_of("interaction scale", INTERACTION_SCALE_RANGE.0, INTERACTION_SCALE_RANGE.1);
        }
    }
    Ok(())
}

/// Writes the window screenshot to `path` and the viewport part of it beside it.
fn write_screenshots(path: &Path, image: &egui::ColorImage, viewport_px: egui::Rect) -> Result<(), String> {
    let [w, h] = image.size;
    let rgb: Vec<u8> = image.pixels.iter().flat_map(|c| [c.r(), c.g(), c.b()]).collect();
    write_rgb8_png(path, w as u32, h as u32, &rgb).map_err(|e| format!("{}: {e}", path.display()))?;
    let x0 = (viewport_px.min.x.max(0.0) as usize).min(w);
    let y0 = (viewport_px.min.y.max(0.0) as usize).min(h);
    let x1 = (viewport_px.max.x.max(0.0) as usize).min(w);
    let y1 = (viewport_px.max.y.max(0.0) as usize).min(h);
    if x1 <= x0 || y1 <= y0 {
        return Err(format!("the viewport {viewport_px:?} is not inside the {w}x{h} screenshot"));
    }
    let mut crop = Vec::with_capacity((x1 - x0) * (y1 - y0) * 3);
    for y in y0..y1 {
        crop.extend_from_slice(&rgb[(y * w + x0) * 3..(y * w + x1) * 3]);
    }
    let crop_path = viewport_screenshot_path(path);
    write_rgb8_png(&crop_path, (x1 - x0) as u32, (y1 - y0) as u32, &crop)
        .map_err(|e| format!("{}: {e}", crop_path.display()))?;
    eprintln!(
        "screenshot: {} ({w}x{h}) and {} ({}x{})",
        path.display(),
        crop_path.display(),
        x1 - x0,
        y1 - y0
    );
    Ok(())
}

impl eframe::App for ViewerApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let frame_started = Instant::now();
        let ctx = ui.ctx().clone();
        self.shortcuts(&ctx);
        self.handle_bake_events();
        self.handle_worker_events();
        self.handle_paint_events();
        self.release_bake_for_picture();
        self.refresh_texture(&ctx);

        egui::Panel::top("twill.top").show(ui, |ui| self.top_bar(ui));
        egui::Panel::left("twill.left")
            .resizable(true)
            .default_size(LEFT_PANEL_WIDTH)
            .size_range(220.0..=640.0)
            .show(ui, |ui| {
                ui.spacing_mut().slider_width = SLIDER_WIDTH;
                self.left_panel(ui);
            });
        egui::Panel::right("twill.right")
            .resizable(true)
            .default_size(RIGHT_PANEL_WIDTH)
            .size_range(220.0..=640.0)
            .show(ui, |ui| {
                ui.spacing_mut().slider_width = SLIDER_WIDTH;
                self.right_panel(ui);
            });
        egui::CentralPanel::no_frame().show(ui, |ui| self.viewport(ui));
        let viewport = egui::Rect::from_min_size(
            (self.viewport_rect_px.min.to_vec2() / ctx.pixels_per_point()).to_pos2(),
            self.viewport_rect_px.size() / ctx.pixels_per_point(),
        );
        self.messages_overlay(&ctx, viewport);

        self.follow_scene_edits(&ctx);
        if !ctx.input(|i| i.pointer.any_down())
            && let Some(current) = self.snapshot()
        {
            self.history.record(&current);
        }
        self.schedule(&ctx);
        self.run_script(&ctx);
        self.ui_timing.frame(frame_started, self.baker.progress().is_some());
    }
}

#[cfg(test)]
mod tests {
    use twill_precompute::scene::YarnSlot;

    use super::super::colourway::{set_order, set_palette_colour, start_colourway};
    use super::*;

    #[test]
    fn a_colour_order_edit_rebakes_geometry_and_a_recolouring_only_materials() {
        let mut baked = SceneFile::default_scene();
        start_colourway(&mut baked).unwrap();
        let mut recoloured = baked.clone();
        set_palette_colour(&mut recoloured, "warp", YarnSlot::Warp, [0.2, 0.1, 0.6]).unwrap();
        assert_eq!(bake_changes(Some(&baked), &recoloured), (false, true));
        let mut striped = baked.clone();
        set_order(&mut striped, YarnSlot::Warp, "1 warp, 1 weft").unwrap();
        assert_eq!(bake_changes(Some(&baked), &striped), (true, true));
        assert_eq!(bake_changes(Some(&baked), &baked), (false, false));
    }
}
