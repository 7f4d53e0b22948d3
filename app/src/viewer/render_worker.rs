//! The render worker: twill's GPU renderer on eframe's own wgpu device, driven from a thread of
//! its own so the window never waits for a frame.
//!
//! How it works: the worker thread owns the [`Renderer`] (built on the device and queue that
//! eframe opened, which the viewer asks for with the adapter's limits and timestamp queries).
//! The viewer posts work into a small inbox — a new fabric to upload, new colours to write
//! into the uploaded one from its recolouring bases ([`Renderer::recolour`]; a newer fabric
//! drops them), an export, and the one viewport frame it wants next — and the worker takes
//! them in that order. The inbox holds at most one frame request: posting a newer one replaces
//! a request not yet started, so the worker never renders a picture that is already stale.
//! Each request adds samples
//! `first_sample .. first_sample + spp` of the view's sample sequence to the picture the
//! renderer keeps on the GPU and tone-maps it there ([`Renderer::render_progressive`]); an
//! exposure or curve edit tone-maps the same samples again ([`RenderWorker::tone_map`]). On the
//! window's own device the picture is not read back at all: the result carries the display
//! texture, which the window draws as a native egui texture. On a device of the worker's own
//! (the default on a CPU adapter, where one long submission would stall the window's queue) only
//! the 8-bit display image is read back, for the window to upload. A request that does not
//! continue the picture on the GPU (a rebake or a new device came between) is answered with
//! [`WorkerEvent::FrameRestart`], and the viewer starts the picture again.
//!
//! A batch whose samples would take longer than four times [`BAND_BUDGET_MS`] at the worker's measured
//! cost (a software renderer's full-size sample takes seconds) is rendered in bands of rows
//! about that long ([`Renderer::render_progressive_in_bands`]; tests fix the rows); between two bands the worker
//! looks at its inbox and stops the batch when newer work has come that replaces the picture
//! (another view, new colours, a fabric, a mesh, a device loss or shutdown), answering
//! [`WorkerEvent::FrameInterrupted`]. So an edit waits behind at most one band, not a whole
//! batch; an export or a tone map waits for the batch.
//! Results and errors come back as [`WorkerEvent`]s, with a repaint request so the window picks
//! them up at once. A render that panics is caught and reported as an error; the viewer goes on.
//!
//! Exports render at their own size with the same renderer into targets of their own (the
//! picture on the GPU is untouched), a few samples per batch (so a cancel takes effect
//! quickly), read back, accumulate on the CPU and write the files (see `export.rs`).
//!
//! A lost device (a driver reset, a GPU unplugged, or [`RenderWorker::lose_device`], which
//! destroys the worker's device to simulate one) is noticed through wgpu's device-lost callback
//! and after every piece of work. The worker then reports [`WorkerEvent::DeviceLost`] instead of
//! the failure, opens a new device of its own ([`Gpu::headless`]; eframe's device, if the
//! worker shared it, is eframe's to recover), uploads the current fabric on it again and reports
//! [`WorkerEvent::DeviceRecovered`]; the viewer then asks for its frame again. If no device can
//! be opened, [`WorkerEvent::DeviceUnavailable`] says why and frames fail until a later fabric
//! upload finds one.

use std::panic::AssertUnwindSafe;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::Instant;

use eframe::egui;
use glam::Vec3;
use twill_precompute::bake::pipeline::Baked;
use twill_precompute::bake::settings::Quality;
use twill_precompute::bcsdf::MaterialDesc;
use twill_precompute::pathtrace::Light;
use twill_precompute::scene::{CameraSection, MeshSection, Scene};
use twill_renderer::frame::{
    FrameSettings, ProgressiveFrame, Readback, RenderError, Renderer, RowBands, clamp_at_zero,
};
use twill_renderer::gpu::Gpu;
use twill_renderer::headless::shell_for_mesh;
use twill_renderer::headless::{HeadlessError, renderer_on_mesh};

use super::bake::{BakedSet, RecolourBases};
use super::export::{ExportImage, write_export};

/// Samples per export batch.
const EXPORT_BATCH_SPP: u32 = 4;
/// About how long one band of a banded batch takes: the longest newer work waits behind a
/// batch in flight. Batches of up to four times this are one submission: a small picture's
/// time is mostly the frame's fixed work, which bands would only repeat (the viewer's reduced
/// picture after an edit, 0.14 s on lavapipe at 81 x 97, is one).
pub const BAND_BUDGET_MS: f64 = 150.0;
/// Tries at opening a new device after a loss, and the wait before the second, doubling.
const RECOVERY_TRIES: u32 = 4;
const RECOVERY_FIRST_WAIT: std::time::Duration = std::time::Duration::from_millis(250);

/// The device the renderer runs on.
#[derive(Clone)]
pub struct DeviceHandles {
    pub adapter_info: wgpu::AdapterInfo,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    /// Whether the device is the worker's own (not the window's): only its own device may be
    /// destroyed to simulate a loss.
    pub own: bool,
}

impl DeviceHandles {
    fn gpu(&self) -> Gpu {
        Gpu {
            adapter_info: self.adapter_info.clone(),
            device: self.device.clone(),
            queue: self.queue.clone(),
        }
    }

    /// A new device of the worker's own.
    fn open_own() -> Result<Self, String> {
        let gpu = Gpu::headless().map_err(|e| e.to_string())?;
        Ok(Self { adapter_info: gpu.adapter_info, device: gpu.device, queue: gpu.queue, own: true })
    }
}

/// Why the device was lost, once wgpu or the worker says so.
type LossReport = Arc<Mutex<Option<String>>>;

/// Watches `device` for loss: the returned report fills in when wgpu calls its device-lost
/// callback (and the window is woken to show it).
fn watch_for_loss(device: &wgpu::Device, repaint: &egui::Context) -> LossReport {
    let report: LossReport = Arc::default();
    let (slot, repaint) = (Arc::clone(&report), repaint.clone());
    device.set_device_lost_callback(move |reason, message| {
        let text = match reason {
            wgpu::DeviceLostReason::Destroyed => format!("the device was destroyed ({message})"),
            wgpu::DeviceLostReason::Unknown => format!("the driver lost the device ({message})"),
        };
        slot.lock().unwrap_or_else(PoisonError::into_inner).get_or_insert(text);
        repaint.request_repaint();
    });
    report
}

/// A fabric to upload (it replaces the current one once uploaded).
#[derive(Clone)]
pub struct NewFabric {
    pub fabric_id: u64,
    pub quality: Quality,
    /// A material preview (multiple scattering still the previous bake's).
    pub preview: bool,
    pub baked: Arc<BakedSet>,
    pub scene: Arc<Scene>,
}

/// New yarn colours for the uploaded fabric, evaluated from its recolouring bases on the worker
/// and written into its buffers in place ([`Renderer::recolour`]): a colour edit's picture in
/// tens of milliseconds, before its rebake. The bases must be those of the uploaded fabric's
/// geometry, lobes and quality (one per exemplar); the renderer checks the cell counts.
pub struct RecolourRequest {
    pub bases: RecolourBases,
    pub materials: Vec<MaterialDesc>,
}

/// A new base surface for the fabric (a mesh edit; no rebake).
#[derive(Debug, Clone, PartialEq)]
pub struct MeshRequest {
    pub mesh: MeshSection,
    /// Default size of a built-in surface (the scene's `[swatch] size_cm`).
    pub swatch_cm: [f64; 2],
    /// Folder a relative mesh path is resolved against.
    pub base_dir: PathBuf,
}

/// One batch of samples of a view.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRequest {
    /// Which edit of the view this is (the viewer's change counter).
    pub generation: u64,
    pub fabric_id: u64,
    pub camera: CameraSection,
    pub lights: Vec<Light>,
    /// Size and the number of samples of this batch.
    pub settings: FrameSettings,
    pub first_sample: u32,
}

/// A rendered batch.
pub struct FrameResult {
    pub request: FrameRequest,
    /// The picture with the batch's samples added.
    pub frame: ProgressiveFrame,
    /// Wall time from the start of the render to the readback.
    pub wall_ms: f64,
}

/// A new exposure and tone curve for the picture on the GPU.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToneRequest {
    pub exposure: f64,
    pub filmic: bool,
}

/// An off-screen render to files.
pub struct ExportRequest {
    pub camera: CameraSection,
    pub lights: Vec<Light>,
    /// Size and total samples; exposure and tone curve apply to PNG output.
    pub settings: FrameSettings,
    pub image_path: PathBuf,
    /// The scene settings, written beside the image.
    pub scene_toml: String,
}

/// What the worker reports.
pub enum WorkerEvent {
    FabricReady {
        fabric_id: u64,
        quality: Quality,
        preview: bool,
        adapter: String,
        resident_bytes: u64,
        bounds: (Vec3, Vec3),
        seconds: f64,
    },
    FabricFailed {
        message: String,
    },
    MeshReady {
        bounds: (Vec3, Vec3),
        seconds: f64,
    },
    /// New colours written into the uploaded fabric ([`RenderWorker::recolour`]); the picture
    /// starts again.
    Recoloured {
        seconds: f64,
    },
    RecolourFailed {
        message: String,
    },
    MeshFailed {
        message: String,
    },
    Frame(Box<FrameResult>),
    /// The picture tone-mapped again ([`RenderWorker::tone_map`]).
    Toned(Box<ProgressiveFrame>),
    /// The request continued a picture the renderer no longer holds: start again from sample 0.
    FrameRestart {
        generation: u64,
    },
    /// The batch was stopped between two bands of rows for newer work; the picture on the GPU
    /// ended with it (the next batch starts again from sample 0).
    FrameInterrupted {
        request: FrameRequest,
        bands_done: u32,
    },
    FrameFailed {
        generation: u64,
        message: String,
    },
    ExportProgress {
        done: u32,
        total: u32,
    },
    ExportDone {
        files: Vec<PathBuf>,
        seconds: f64,
    },
    ExportFailed {
        message: String,
    },
    /// The render device was lost; the worker is opening a new one.
    DeviceLost {
        reason: String,
    },
    /// A new device is open and the current fabric is uploaded on it.
    DeviceRecovered {
        adapter: String,
        seconds: f64,
    },
    /// No new device could be opened after a loss (or a simulated loss was refused).
    DeviceUnavailable {
        message: String,
    },
}

#[derive(Default)]
struct Inbox {
    fabric: Option<NewFabric>,
    recolour: Option<RecolourRequest>,
    mesh: Option<MeshRequest>,
    export: Option<ExportRequest>,
    frame: Option<FrameRequest>,
    tone: Option<ToneRequest>,
    lose_device: bool,
    shutdown: bool,
}

impl Inbox {
    /// A fabric to upload next; a recolouring not yet done is dropped (the fabric is newer).
    fn replace_fabric(&mut self, fabric: NewFabric) {
        self.fabric = Some(fabric);
        self.recolour = None;
    }
}

impl Inbox {
    /// Whether something waits that replaces the picture of `rendering` (between two bands of
    /// its batch): another frame request, new colours, a fabric, a mesh, a device loss or
    /// shutdown. An export or a tone map waits for the batch.
    fn replaces_picture_of(&self, rendering: &FrameRequest) -> bool {
        self.frame.as_ref().is_some_and(|next| next != rendering)
            || self.fabric.is_some()
            || self.recolour.is_some()
            || self.mesh.is_some()
            || self.lose_device
            || self.shutdown
    }
}

struct Shared {
    inbox: Mutex<Inbox>,
    wake: Condvar,
    cancel_export: AtomicBool,
    /// Rows per band when set (`RenderWorker::set_band_rows`); 0: chosen from the measured cost.
    band_rows: AtomicU32,
}

/// A measure of the render device: the wall time of a pixel's sample, in nanoseconds, over the
/// batches rendered (the worker sizes its bands by it, the viewer its batches and its picture
/// while the view moves).
///
/// A batch can take longer than its pixels' samples for one-off work (the first frame compiles
/// the pipelines: 35 s on lavapipe under load, against seconds for a sample), never shorter; so
/// a cheaper batch replaces the estimate at once and a dearer one moves it halfway. Averaged
/// both ways, one compile kept the bands at their least for several batches after it.
#[derive(Debug, Default)]
pub struct FrameCost {
    pub ns_per_pixel_sample: Option<f64>,
}

impl FrameCost {
    /// Takes a batch of `settings` that took `wall_ms`.
    pub fn add(&mut self, settings: &FrameSettings, wall_ms: f64) {
        let work = f64::from(settings.width) * f64::from(settings.height) * f64::from(settings.spp.max(1));
        let cost = wall_ms * 1e6 / work.max(1.0);
        self.ns_per_pixel_sample = Some(match self.ns_per_pixel_sample {
            Some(old) if cost > old => 0.5 * (old + cost),
            _ => cost,
        });
    }

    /// Rows per band for a batch of `settings` (a multiple of 8), or `None` for one submission:
    /// the first batch (nothing measured yet) and batches within four times [`BAND_BUDGET_MS`].
    fn band_rows(&self, settings: &FrameSettings) -> Option<u32> {
        let row_ms = self.ns_per_pixel_sample? * f64::from(settings.width) * 1e-6;
        let batch_ms = row_ms * f64::from(settings.height) * f64::from(settings.spp.max(1));
        if batch_ms <= 4.0 * BAND_BUDGET_MS {
            return None;
        }
        let rows = (BAND_BUDGET_MS / row_ms.max(1e-9)).floor().min(f64::from(settings.height)) as u32;
        Some((rows / 8 * 8).max(8))
    }
}

/// The viewer's handle on the worker thread.
pub struct RenderWorker {
    shared: Arc<Shared>,
    events: Receiver<WorkerEvent>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl RenderWorker {
    /// Starts the worker on `device` (eframe's, or one of its own).
    pub fn start(device: DeviceHandles, repaint: egui::Context) -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            inbox: Mutex::new(Inbox::default()),
            wake: Condvar::new(),
            cancel_export: AtomicBool::new(false),
            band_rows: AtomicU32::new(0),
        });
        let (sender, events) = channel();
        let thread_shared = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("twill-render".into())
            .spawn(move || worker_loop(device, &thread_shared, &sender, &repaint))?;
        Ok(Self { shared, events, thread: Some(thread) })
    }

    fn post(&self, fill: impl FnOnce(&mut Inbox)) {
        fill(&mut self.shared.inbox.lock().unwrap_or_else(PoisonError::into_inner));
        self.shared.wake.notify_one();
    }

    /// Uploads a new fabric (replacing one waiting to be uploaded, and dropping a recolouring
    /// not yet done: the fabric is the newer bake).
    pub fn set_fabric(&self, fabric: NewFabric) {
        self.post(|inbox| inbox.replace_fabric(fabric));
    }

    /// Writes new colours into the uploaded fabric from its recolouring bases (after a fabric
    /// waiting to be uploaded; a newer request replaces one not yet done).
    pub fn recolour(&self, request: RecolourRequest) {
        self.post(|inbox| inbox.recolour = Some(request));
    }

    /// Replaces the base surface (kept for fabrics uploaded later too).
    pub fn set_mesh(&self, mesh: MeshRequest) {
        self.post(|inbox| inbox.mesh = Some(mesh));
    }

    /// Asks for a viewport frame, replacing a frame request not yet started.
    pub fn request_frame(&self, request: FrameRequest) {
        self.post(|inbox| inbox.frame = Some(request));
    }

    /// Tone-maps the picture on the GPU again (after the batch in progress; a newer request
    /// replaces one not yet started).
    pub fn tone_map(&self, request: ToneRequest) {
        self.post(|inbox| inbox.tone = Some(request));
    }

    /// Drops a frame request not yet started.
    pub fn clear_frame_request(&self) {
        self.post(|inbox| inbox.frame = None);
    }

    /// Starts an export (after the batch in progress).
    pub fn export(&self, request: ExportRequest) {
        self.shared.cancel_export.store(false, Ordering::Relaxed);
        self.post(|inbox| inbox.export = Some(request));
    }

    /// Stops the export in progress (at its next batch).
    pub fn cancel_export(&self) {
        self.shared.cancel_export.store(true, Ordering::Relaxed);
        self.post(|inbox| inbox.export = None);
    }

    /// Renders every batch in bands of `rows` rows (rounded up to a multiple of 8), or with
    /// `None` in bands chosen from the measured cost (see [`BAND_BUDGET_MS`]).
    #[cfg(test)]
    pub fn set_band_rows(&self, rows: Option<u32>) {
        self.shared.band_rows.store(rows.map_or(0, |r| r.max(1)), Ordering::Relaxed);
    }

    /// Simulates losing the render device: the worker destroys its device (when it is its own,
    /// not the window's) and recovers as from a real loss.
    pub fn lose_device(&self) {
        self.post(|inbox| inbox.lose_device = true);
    }

    /// Events since the last call.
    pub fn poll(&self) -> Vec<WorkerEvent> {
        self.events.try_iter().collect()
    }
}

impl Drop for RenderWorker {
    fn drop(&mut self) {
        self.shared.cancel_export.store(true, Ordering::Relaxed);
        self.post(|inbox| inbox.shutdown = true);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

enum Work {
    LoseDevice,
    Fabric(NewFabric),
    Recolour(RecolourRequest),
    Mesh(MeshRequest),
    Export(ExportRequest),
    Frame(FrameRequest),
    Tone(ToneRequest),
}

fn next_work(shared: &Shared) -> Option<Work> {
    let mut inbox = shared.inbox.lock().unwrap_or_else(PoisonError::into_inner);
    loop {
        if inbox.shutdown {
            return None;
        }
        if std::mem::take(&mut inbox.lose_device) {
            return Some(Work::LoseDevice);
        }
        if let Some(mesh) = inbox.mesh.take() {
            return Some(Work::Mesh(mesh));
        }
        if let Some(fabric) = inbox.fabric.take() {
            return Some(Work::Fabric(fabric));
        }
        if let Some(recolour) = inbox.recolour.take() {
            return Some(Work::Recolour(recolour));
        }
        if let Some(export) = inbox.export.take() {
            return Some(Work::Export(export));
        }
        if let Some(frame) = inbox.frame.take() {
            return Some(Work::Frame(frame));
        }
        if let Some(tone) = inbox.tone.take() {
            return Some(Work::Tone(tone));
        }
        inbox = shared.wake.wait(inbox).unwrap_or_else(PoisonError::into_inner);
    }
}

/// Text of a caught panic.
fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}

fn worker_loop(
    mut device: DeviceHandles,
    shared: &Shared,
    sender: &Sender<WorkerEvent>,
    repaint: &egui::Context,
) {
    let send = |event: WorkerEvent| {
        let _ = sender.send(event);
        repaint.request_repaint();
    };
    let mut loss = watch_for_loss(&device.device, repaint);
    let mut renderer: Option<Renderer> = None;
    // The mesh edited in the viewer, which replaces the scene's own for every later upload.
    let mut edited_mesh: Option<MeshRequest> = None;
    // The fabric uploaded last, uploaded again on a new device after a loss.
    let mut current: Option<NewFabric> = None;
    // Lost, and no new device could be opened yet.
    let mut dead = false;
    let mut cost = FrameCost::default();
    while let Some(work) = next_work(shared) {
        match work {
            Work::LoseDevice if !device.own => send(WorkerEvent::DeviceUnavailable {
                message: "a device loss can only be simulated on the renderer's own device, not on the \
                          window's (TWILL_VIEWER_DEVICE=separate gives the renderer one)"
                    .into(),
            }),
            Work::LoseDevice => {
                device.device.destroy();
                loss.lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .get_or_insert_with(|| "the device was destroyed (a simulated loss)".into());
            }
            Work::Mesh(request) => {
                let started = Instant::now();
                let outcome = renderer.as_mut().map(|r| {
                    let shell = shell_for_mesh(
                        &request.mesh,
                        request.swatch_cm,
                        &request.base_dir,
                        r.fabric_z_range(),
                    )
                    .map_err(|e| format!("the mesh cannot be used: {e}"))?;
                    r.set_shell(&shell);
                    Ok::<_, String>(r.bounds())
                });
                match outcome {
                    Some(Ok(bounds)) => {
                        send(WorkerEvent::MeshReady { bounds, seconds: started.elapsed().as_secs_f64() });
                        edited_mesh = Some(request);
                    }
                    Some(Err(message)) => send(WorkerEvent::MeshFailed { message }),
                    // No fabric yet: the mesh applies to the first upload.
                    None => edited_mesh = Some(request),
                }
            }
            Work::Fabric(fabric) => {
                let started = Instant::now();
                if dead {
                    match DeviceHandles::open_own() {
                        Ok(fresh) => {
                            loss = watch_for_loss(&fresh.device, repaint);
                            (device, dead) = (fresh, false);
                        }
                        Err(e) => {
                            send(WorkerEvent::FabricFailed { message: format!("no render device: {e}") });
                            continue;
                        }
                    }
                }
                // Same shell, same buffer layout (a material rebake or preview): written into the
                // uploaded fabric's buffers in place, keeping the pipelines and cached passes.
                let same_surface = current.as_ref().is_some_and(|c| {
                    c.scene.mesh == fabric.scene.mesh
                        && c.scene.swatch == fabric.scene.swatch
                        && c.scene.base_dir == fabric.scene.base_dir
                });
                let mut written_in_place = false;
                if let (Some(r), true) = (renderer.as_mut(), same_surface) {
                    let exemplars: Vec<&Baked> = fabric.baked.exemplars.iter().collect();
                    let updated = std::panic::catch_unwind(AssertUnwindSafe(|| {
                        r.update_fabric(&exemplars, &fabric.baked.pattern)
                    }));
                    if let Ok(Ok(Some(written))) = updated {
                        log::info!("fabric written in place ({written:?})");
                        send(fabric_ready(&fabric, r, started));
                        written_in_place = true;
                    }
                }
                if written_in_place {
                    current = Some(fabric);
                } else {
                    let built = upload_with_mesh(&device, &fabric, &mut edited_mesh, &send);
                    if is_lost(&device, &loss) {
                        // The failure (if any) was the loss: the recovery below uploads this fabric.
                        current = Some(fabric);
                    } else {
                        match built {
                            Ok(r) => {
                                send(fabric_ready(&fabric, &r, started));
                                renderer = Some(r);
                                current = Some(fabric);
                            }
                            Err(message) => send(WorkerEvent::FabricFailed { message }),
                        }
                    }
                }
            }
            Work::Recolour(request) => {
                let started = Instant::now();
                let Some(r) = renderer.as_mut() else {
                    send(WorkerEvent::RecolourFailed { message: "no fabric is uploaded yet".into() });
                    continue;
                };
                let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| {
                    for (exemplar, basis) in request.bases.iter().enumerate() {
                        r.recolour(exemplar, basis, &request.materials)?;
                    }
                    Ok::<_, RenderError>(())
                }));
                let message = match outcome {
                    Ok(Ok(())) => {
                        send(WorkerEvent::Recoloured { seconds: started.elapsed().as_secs_f64() });
                        continue;
                    }
                    Ok(Err(e)) => e.to_string(),
                    Err(payload) => format!("recolouring panicked: {}", panic_text(payload.as_ref())),
                };
                send(WorkerEvent::RecolourFailed { message });
            }
            Work::Frame(request) => {
                let Some(r) = renderer.as_mut() else {
                    send(WorkerEvent::FrameFailed {
                        generation: request.generation,
                        message: "no fabric is uploaded yet".into(),
                    });
                    continue;
                };
                let started = Instant::now();
                let readback = picture_readback(&device);
                let band_rows = match shared.band_rows.load(Ordering::Relaxed) {
                    0 => cost.band_rows(&request.settings),
                    fixed => Some(fixed),
                };
                let stop = || {
                    shared.inbox.lock().unwrap_or_else(PoisonError::into_inner).replaces_picture_of(&request)
                };
                let bands = band_rows.map(|rows| RowBands { rows, stop: &stop });
                let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
                    r.render_progressive_in_bands(
                        &request.camera,
                        &request.lights,
                        &request.settings,
                        request.first_sample,
                        readback,
                        bands.as_ref(),
                    )
                }));
                let wall_ms = started.elapsed().as_secs_f64() * 1e3;
                let s = &request.settings;
                log::debug!(
                    "frame: generation {}, {}x{}, samples {}..{}, {}, {wall_ms:.0} ms",
                    request.generation,
                    s.width,
                    s.height,
                    request.first_sample,
                    request.first_sample + s.spp,
                    band_rows.map_or_else(|| "whole".to_owned(), |rows| format!("bands of {rows} rows")),
                );
                let failure = match result {
                    Ok(Ok(frame)) => {
                        if let Some(timings) = &frame.timings {
                            let passes: Vec<String> = timings
                                .iter()
                                .map(|t| format!("{} {:.1} ms", t.pass, t.milliseconds))
                                .collect();
                            log::debug!(
                                "frame passes (GPU): {}; reused: {:?}",
                                passes.join(", "),
                                frame.reused
                            );
                        }
                        cost.add(&request.settings, wall_ms);
                        send(WorkerEvent::Frame(Box::new(FrameResult { request, frame, wall_ms })));
                        continue;
                    }
                    Ok(Err(RenderError::Interrupted { bands_done })) => {
                        send(WorkerEvent::FrameInterrupted { request, bands_done });
                        continue;
                    }
                    Ok(Err(RenderError::Continuation { .. })) => {
                        send(WorkerEvent::FrameRestart { generation: request.generation });
                        continue;
                    }
                    Ok(Err(e)) => format!("render failed: {e}"),
                    Err(payload) => format!("render crashed: {}", panic_text(payload.as_ref())),
                };
                // A frame that failed because the device was lost is rendered again after the
                // recovery below; any other failure is the viewer's to show.
                if !is_lost(&device, &loss) {
                    send(WorkerEvent::FrameFailed { generation: request.generation, message: failure });
                }
            }
            Work::Tone(request) => {
                let Some(r) = renderer.as_mut() else { continue };
                let readback = picture_readback(&device);
                let toned = std::panic::catch_unwind(AssertUnwindSafe(|| {
                    r.tone_map_progressive(request.exposure, request.filmic, readback)
                }));
                match toned {
                    Ok(Ok(frame)) => send(WorkerEvent::Toned(Box::new(frame))),
                    // No picture yet: the next batch is tone mapped with the new settings.
                    Ok(Err(RenderError::Continuation { .. })) => {}
                    Ok(Err(e)) => log::warn!("tone map failed: {e}"),
                    Err(payload) => log::warn!("tone map crashed: {}", panic_text(payload.as_ref())),
                }
            }
            Work::Export(request) => {
                let Some(r) = renderer.as_mut() else {
                    send(WorkerEvent::ExportFailed { message: "no fabric is uploaded yet".into() });
                    continue;
                };
                let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
                    run_export(r, &request, &shared.cancel_export, &|done, total| {
                        send(WorkerEvent::ExportProgress { done, total });
                    })
                }));
                let lost =
                    if is_lost(&device, &loss) { " (the render device was lost: export again)" } else { "" };
                match result {
                    Ok(Ok(Some((files, seconds)))) => send(WorkerEvent::ExportDone { files, seconds }),
                    Ok(Ok(None)) => send(WorkerEvent::ExportFailed { message: "export cancelled".into() }),
                    Ok(Err(message)) => {
                        send(WorkerEvent::ExportFailed { message: format!("{message}{lost}") });
                    }
                    Err(payload) => send(WorkerEvent::ExportFailed {
                        message: format!("export crashed: {}{lost}", panic_text(payload.as_ref())),
                    }),
                }
            }
        }
        let reason = if is_lost(&device, &loss) {
            loss.lock().unwrap_or_else(PoisonError::into_inner).clone()
        } else {
            None
        };
        if let Some(reason) = reason {
            renderer = None;
            send(WorkerEvent::DeviceLost { reason });
            let started = Instant::now();
            match recover(current.as_ref(), &mut edited_mesh, &send) {
                Ok((new_device, new_renderer)) => {
                    loss = watch_for_loss(&new_device.device, repaint);
                    device = new_device;
                    let adapter = device.adapter_info.name.clone();
                    renderer = new_renderer;
                    send(WorkerEvent::DeviceRecovered { adapter, seconds: started.elapsed().as_secs_f64() });
                }
                Err(message) => {
                    // Frames fail ("no fabric is uploaded yet") until a fabric upload finds a
                    // device: the next one tries again.
                    dead = true;
                    loss.lock().unwrap_or_else(PoisonError::into_inner).take();
                    send(WorkerEvent::DeviceUnavailable { message });
                }
            }
        }
    }
}

/// What a viewport picture reads back: nothing on the window's device (it draws the display
/// texture itself), the 8-bit display image on a device of the worker's own.
fn picture_readback(device: &DeviceHandles) -> Readback {
    if device.own { Readback::Display } else { Readback::Nothing }
}

/// The event saying `fabric` is on screen through `r`, uploaded since `started`.
fn fabric_ready(fabric: &NewFabric, r: &Renderer, started: Instant) -> WorkerEvent {
    WorkerEvent::FabricReady {
        fabric_id: fabric.fabric_id,
        quality: fabric.quality,
        preview: fabric.preview,
        adapter: r.adapter().to_owned(),
        resident_bytes: r.resident_bytes(),
        bounds: r.bounds(),
        seconds: started.elapsed().as_secs_f64(),
    }
}

/// Whether `device` is lost: wgpu's callback said so (it runs when the device is polled) or
/// the worker destroyed it.
fn is_lost(device: &DeviceHandles, loss: &LossReport) -> bool {
    // A destroyed device reports its loss at its next maintenance; an error here means the same.
    let polled = device.device.poll(wgpu::PollType::Poll);
    let mut report = loss.lock().unwrap_or_else(PoisonError::into_inner);
    if let Err(e) = polled
        && report.is_none()
    {
        *report = Some(format!("polling the device failed: {e}"));
    }
    report.is_some()
}

/// Opens a new device of the worker's own and uploads `fabric` (if any) on it, trying a few
/// times with a growing wait (a driver that just reset may need a moment).
fn recover(
    fabric: Option<&NewFabric>,
    edited_mesh: &mut Option<MeshRequest>,
    send: &dyn Fn(WorkerEvent),
) -> Result<(DeviceHandles, Option<Renderer>), String> {
    let mut wait = RECOVERY_FIRST_WAIT;
    let mut last_error = String::new();
    for attempt in 1..=RECOVERY_TRIES {
        match DeviceHandles::open_own() {
            Ok(device) => {
                let Some(fabric) = fabric else { return Ok((device, None)) };
                match upload_with_mesh(&device, fabric, edited_mesh, send) {
                    Ok(renderer) => return Ok((device, Some(renderer))),
                    Err(e) => last_error = e,
                }
            }
            Err(e) => last_error = format!("no new render device: {e}"),
        }
        log::warn!("device recovery, try {attempt} of {RECOVERY_TRIES}: {last_error}");
        if attempt < RECOVERY_TRIES {
            std::thread::sleep(wait);
            wait *= 2;
        }
    }
    Err(format!("the render device was lost and could not be replaced: {last_error}"))
}

/// Uploads `fabric` on `device` with the edited mesh, or, when that mesh cannot be used (said
/// with [`WorkerEvent::MeshFailed`] and forgotten), with the scene's own; a panic is an error.
fn upload_with_mesh(
    device: &DeviceHandles,
    fabric: &NewFabric,
    edited_mesh: &mut Option<MeshRequest>,
    send: &dyn Fn(WorkerEvent),
) -> Result<Renderer, String> {
    let built =
        std::panic::catch_unwind(AssertUnwindSafe(|| match upload(device, fabric, edited_mesh.as_ref()) {
            // A bad edited mesh: say so and show the fabric on the scene's own.
            Err(message) if edited_mesh.is_some() => {
                send(WorkerEvent::MeshFailed { message });
                *edited_mesh = None;
                upload(device, fabric, None)
            }
            other => other,
        }));
    match built {
        Ok(Ok(r)) => Ok(r),
        Ok(Err(e)) => Err(format!("uploading the {} bake failed: {e}", fabric.quality.name())),
        Err(payload) => Err(format!("uploading the bake crashed: {}", panic_text(payload.as_ref()))),
    }
}

/// Uploads a bake with the scene's shell, or the edited mesh's.
fn upload(
    device: &DeviceHandles,
    fabric: &NewFabric,
    mesh: Option<&MeshRequest>,
) -> Result<Renderer, String> {
    let exemplars: Vec<&Baked> = fabric.baked.exemplars.iter().collect();
    let scene = &fabric.scene;
    let (surface, swatch_cm, base_dir) = match mesh {
        Some(m) => (&m.mesh, m.swatch_cm, m.base_dir.as_path()),
        None => (&scene.mesh, scene.swatch.size_cm, scene.base_dir.as_path()),
    };
    renderer_on_mesh(&device.gpu(), &exemplars, &fabric.baked.pattern, surface, swatch_cm, base_dir).map_err(
        |e| match e {
            HeadlessError::Shell(e) => format!("the mesh cannot be used: {e}"),
            e => e.to_string(),
        },
    )
}

/// Renders an export in batches and writes its files; `None` when cancelled.
fn run_export(
    renderer: &mut Renderer,
    request: &ExportRequest,
    cancel: &AtomicBool,
    progress: &dyn Fn(u32, u32),
) -> Result<Option<(Vec<PathBuf>, f64)>, String> {
    let started = Instant::now();
    let total = request.settings.spp.max(1);
    let (width, height) = (request.settings.width, request.settings.height);
    let mut sum = vec![[0.0_f32; 3]; width as usize * height as usize];
    let mut done = 0;
    progress(0, total);
    while done < total {
        if cancel.load(Ordering::Relaxed) {
            return Ok(None);
        }
        let batch = EXPORT_BATCH_SPP.min(total - done);
        let settings = FrameSettings { spp: batch, ..request.settings.clone() };
        let frame = renderer
            .render_samples(&request.camera, &request.lights, &settings, done)
            .map_err(|e| format!("export render failed: {e}"))?;
        let weight = batch as f32;
        // Signed means: only the whole picture's mean is clamped at zero.
        for (s, p) in sum.iter_mut().zip(&frame.signed_radiance) {
            for c in 0..3 {
                s[c] += p[c] * weight;
            }
        }
        done += batch;
        log::debug!("export: {done}/{total} samples after {:.0} ms", started.elapsed().as_secs_f64() * 1e3);
        progress(done, total);
    }
    let inv = 1.0 / total as f32;
    for p in &mut sum {
        *p = p.map(|c| c * inv);
    }
    let mean = clamp_at_zero(&sum);
    let image = ExportImage {
        width,
        height,
        radiance: &mean,
        exposure: request.settings.exposure,
        filmic: request.settings.filmic,
    };
    let files = write_export(&request.image_path, &image, &request.scene_toml)?;
    Ok(Some((files, started.elapsed().as_secs_f64())))
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use twill_precompute::bake::Cancel;
    use twill_precompute::bake::pattern::PatternMap;
    use twill_precompute::bake::pipeline::{bake, recolour_basis};
    use twill_precompute::bake::settings::BakeSettings;
    use twill_precompute::bcsdf::FiberParams;
    use twill_precompute::scene::SceneFile;

    use super::*;

    /// The worker's events until `done` says stop (failures panic), at most five minutes.
    fn events_until(worker: &RenderWorker, done: impl Fn(&WorkerEvent) -> bool) -> Vec<WorkerEvent> {
        let started = Instant::now();
        let mut events = Vec::new();
        loop {
            for event in worker.poll() {
                if let WorkerEvent::FabricFailed { message } = &event {
                    panic!("upload failed: {message}");
                }
                let finished = done(&event);
                events.push(event);
                if finished {
                    return events;
                }
            }
            assert!(started.elapsed() < Duration::from_mins(5), "no such event in five minutes");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// A worker on the test's device (`None` without one), the default scene, and bake
    /// settings of cells so big that its bake and bases take a moment.
    fn started_worker(test: &str) -> Option<(RenderWorker, Arc<Scene>, BakeSettings)> {
        let gpu = Gpu::for_test(test)?;
        let device =
            DeviceHandles { adapter_info: gpu.adapter_info, device: gpu.device, queue: gpu.queue, own: true };
        let worker = RenderWorker::start(device, egui::Context::default()).expect("worker thread");
        let settings =
            BakeSettings { cell_size_mfp: 8.0, iirtf_paths_per_cell: 32, ..Quality::Draft.settings() };
        let scene = Arc::new(SceneFile::default_scene().build().expect("default scene"));
        Some((worker, scene, settings))
    }

    #[test]
    fn bands_are_about_the_budget_long_at_the_measured_cost() {
        let settings = |width, height, spp| FrameSettings {
            width,
            height,
            spp,
            exposure: 0.0,
            filmic: true,
            components: twill_renderer::plan::Components::All,
            gpu: twill_precompute::scene::GpuSection::default(),
            frame_transfer: true,
        };
        let mut cost = FrameCost::default();
        assert_eq!(cost.band_rows(&settings(651, 775, 1)), None, "nothing measured: one submission");
        // lavapipe at interactive: a first sample that compiled the pipelines (35 s), then
        // 651 x 775 samples in about 4.8 s: the compile is forgotten at once.
        cost.add(&settings(651, 775, 1), 35_000.0);
        cost.add(&settings(651, 775, 1), 4_800.0);
        let rows = cost.band_rows(&settings(651, 775, 1)).expect("a 4.8 s sample is banded");
        assert_eq!(rows % 8, 0);
        let band_ms = 4_800.0 * f64::from(rows) / 775.0;
        assert!((0.5 * BAND_BUDGET_MS..=BAND_BUDGET_MS).contains(&band_ms), "{rows} rows: {band_ms} ms");
        // The reduced picture after an edit (81 x 97, 75 ms at this cost) is one submission;
        // a slower device's bands are never under 8 rows.
        assert_eq!(cost.band_rows(&settings(81, 97, 1)), None);
        cost.add(&settings(651, 775, 1), 1e6);
        assert_eq!(cost.band_rows(&settings(651, 775, 4)), Some(8));
        // A fast GPU (5 ms at 512 x 512): a 1080p sample is one submission; a batch of 16 of
        // them (0.6 s) is one submission per sample, so it can be stopped between samples.
        let mut fast = FrameCost::default();
        fast.add(&settings(512, 512, 1), 5.0);
        assert_eq!(fast.band_rows(&settings(1920, 1080, 1)), None);
        assert_eq!(fast.band_rows(&settings(1920, 1080, 16)), Some(1080));
    }

    #[test]
    fn a_batch_in_bands_stops_for_newer_work_and_the_newer_work_is_done() {
        // A batch of 4 samples x 32 bands of 8 rows; a new view posted while its first band renders stops
        // it at the next band (answered `FrameInterrupted`, never `Frame`), and the new view's
        // batch is rendered next. An exposure edit (a tone map) would wait for the batch.
        let Some((worker, scene, settings)) =
            started_worker("a_batch_in_bands_stops_for_newer_work_and_the_newer_work_is_done")
        else {
            return;
        };
        let baked =
            bake(&scene.bake_inputs(settings)[0], None, &Cancel::new(), &|_, _| {}).expect("bake").baked;
        worker.set_fabric(NewFabric {
            fabric_id: 1,
            quality: Quality::Draft,
            preview: false,
            baked: Arc::new(BakedSet { exemplars: vec![baked], pattern: PatternMap::uniform(0) }),
            scene: Arc::clone(&scene),
        });
        events_until(&worker, |e| matches!(e, WorkerEvent::FabricReady { fabric_id: 1, .. }));
        worker.set_band_rows(Some(8));
        let frame = |generation, width, height| FrameRequest {
            generation,
            fabric_id: 1,
            camera: scene.camera,
            lights: scene.path_scene.lights.clone(),
            settings: FrameSettings {
                width,
                height,
                spp: 1,
                ..twill_renderer::headless::frame_settings(&scene, twill_renderer::plan::Components::All)
            },
            first_sample: 0,
        };
        let (slow, next) = (
            FrameRequest {
                settings: FrameSettings { spp: 4, ..frame(1, 256, 256).settings },
                ..frame(1, 256, 256)
            },
            frame(2, 48, 40),
        );
        worker.request_frame(slow.clone());
        // The worker has taken the batch once it left the inbox; post the new view at once.
        let started = Instant::now();
        while worker.shared.inbox.lock().unwrap_or_else(PoisonError::into_inner).frame.is_some() {
            assert!(started.elapsed() < Duration::from_secs(30), "the worker never took the batch");
            std::hint::spin_loop();
        }
        worker.request_frame(next.clone());
        let events =
            events_until(&worker, |e| matches!(e, WorkerEvent::Frame(_) | WorkerEvent::FrameFailed { .. }));
        let interrupted = events.iter().find_map(|e| match e {
            WorkerEvent::FrameInterrupted { request, bands_done } => Some((request, *bands_done)),
            _ => None,
        });
        let Some((request, bands_done)) = interrupted else { panic!("the slow batch was not stopped") };
        assert_eq!(request, &slow);
        assert!((1..128).contains(&bands_done), "stopped after {bands_done} of 128 bands");
        match events.last() {
            Some(WorkerEvent::Frame(result)) => {
                assert_eq!(result.request, next, "the new view's batch, not the stopped one");
                assert_eq!(result.frame.samples, 1);
            }
            Some(WorkerEvent::FrameFailed { message, .. }) => panic!("frame failed: {message}"),
            _ => unreachable!(),
        }
    }

    #[test]
    fn colour_edits_are_written_from_the_bases_into_the_uploaded_fabric() {
        let Some((worker, scene, settings)) =
            started_worker("colour_edits_are_written_from_the_bases_into_the_uploaded_fabric")
        else {
            return;
        };
        let inputs = &scene.bake_inputs(settings)[0];
        let baked = bake(inputs, None, &Cancel::new(), &|_, _| {}).expect("bake").baked;
        let basis = recolour_basis(inputs, None, &Cancel::new(), &|_| {}).expect("bases");
        let fabric = |fabric_id| NewFabric {
            fabric_id,
            quality: Quality::Draft,
            preview: false,
            baked: Arc::new(BakedSet { exemplars: vec![baked.clone()], pattern: PatternMap::uniform(0) }),
            scene: Arc::clone(&scene),
        };
        let bases: RecolourBases = Arc::new(vec![basis]);
        let recoloured = |c_tt: [f64; 3]| -> Vec<MaterialDesc> {
            let mut materials = scene.material_descs.clone();
            let MaterialDesc::Fiber(p) = materials[0] else { panic!("the default warp is fiber") };
            materials[0] =
                MaterialDesc::Fiber(FiberParams { c_tt: twill_precompute::Rgb::from_array(c_tt), ..p });
            materials
        };
        // Nothing uploaded yet: refused, and said so.
        worker
            .recolour(RecolourRequest { bases: Arc::clone(&bases), materials: recoloured([0.9, 0.2, 0.1]) });
        let events = events_until(&worker, |e| matches!(e, WorkerEvent::RecolourFailed { .. }));
        assert!(
            matches!(events.last(), Some(WorkerEvent::RecolourFailed { message }) if message.contains("no fabric"))
        );
        worker.set_fabric(fabric(1));
        events_until(&worker, |e| matches!(e, WorkerEvent::FabricReady { fabric_id: 1, .. }));
        worker
            .recolour(RecolourRequest { bases: Arc::clone(&bases), materials: recoloured([0.9, 0.2, 0.1]) });
        let events = events_until(&worker, |e| {
            matches!(e, WorkerEvent::Recoloured { .. } | WorkerEvent::RecolourFailed { .. })
        });
        let Some(WorkerEvent::Recoloured { seconds }) = events.last() else {
            let message = match events.last() {
                Some(WorkerEvent::RecolourFailed { message }) => message.clone(),
                _ => String::new(),
            };
            panic!("not recoloured: {message}");
        };
        assert!(seconds.is_finite() && *seconds >= 0.0);
        // Colours the bases cannot hold (another slot count) are refused with a reason; the
        // fabric stays usable.
        worker.recolour(RecolourRequest {
            bases: Arc::clone(&bases),
            materials: recoloured([0.5; 3])[..1].to_vec(),
        });
        let events = events_until(&worker, |e| matches!(e, WorkerEvent::RecolourFailed { .. }));
        assert!(
            matches!(events.last(), Some(WorkerEvent::RecolourFailed { message }) if message.contains("recolouring"))
        );
        // A newer fabric drops a recolouring still waiting (both in the inbox at once, as
        // `set_fabric` finds it): only the fabric is done.
        worker.post(|inbox| {
            inbox.recolour =
                Some(RecolourRequest { bases: Arc::clone(&bases), materials: recoloured([0.1; 3]) });
            inbox.replace_fabric(fabric(2));
        });
        let events = events_until(&worker, |e| matches!(e, WorkerEvent::FabricReady { fabric_id: 2, .. }));
        std::thread::sleep(Duration::from_millis(200));
        let later = worker.poll();
        assert!(
            !events.iter().chain(&later).any(|e| matches!(e, WorkerEvent::Recoloured { .. })),
            "a recolouring older than the fabric was applied"
        );
    }
}
