//! The desktop viewer: `twill` with no arguments, or `twill view [SCENE]`.
//!
//! How it works: [`run`] opens an eframe window on wgpu (Vulkan only) and asks for a device
//! with the adapter's own limits and timestamp queries, because twill's renderer needs more
//! storage buffers per stage than wgpu's defaults and times its passes. The app
//! ([`app::ViewerApp`]) then
//! - bakes the scene's fabric in the background ([`bake`]): draft first, then the final quality;
//! - renders from a worker thread ([`render_worker`]) that owns twill's `Renderer`, adding
//!   samples to a picture kept and tone-mapped on the GPU while the view is still
//!   ([`accumulate`]); on eframe's device the window draws the renderer's display texture as a
//!   native egui texture, on a device of the worker's own (the default on a CPU adapter) it
//!   uploads the 8-bit picture read back;
//! - orbits, pans, zooms and fits the camera ([`camera`]);
//! - edits lights ([`lights`]) and render settings ([`quality`]), which only restart the picture;
//! - edits the fabric ([`fabric`]: fiber scattering parameters, the weave draft, WIF import,
//!   yarns; [`colourway`]: a palette and warp and weft colour orders) and the base mesh
//!   ([`mesh`]); a material edit shows new single scattering at once
//!   and rebakes multiple scattering in the background, a weave edit rebakes what depends on
//!   geometry, a mesh edit only swaps the shell; undo and redo cover every edit ([`history`]);
//! - paints colours onto single yarns and yarn sections of a frozen view at path-traced
//!   quality, and commits a painting that is a colour order to the scene ([`paint`]);
//! - saves and opens scenes in the CLI's format;
//! - measures its own frame times, above all while a bake runs ([`timing`]);
//! - exports the view at any size and sample count as PNG or EXR with its scene settings
//!   ([`export`]);
//! - plays scripts of edits and screenshots for tests ([`script`]).
//!
//! Errors (a scene that does not load, a failed bake, upload, render or export) are shown in the
//! window's message list; the viewer keeps running.

mod accumulate;
mod app;
mod bake;
mod camera;
mod colourway;
mod export;
mod fabric;
mod history;
mod lights;
mod mesh;
mod paint;
mod quality;
mod render_worker;
mod script;
mod timing;

use std::path::PathBuf;
use std::sync::{Arc, Mutex, PoisonError};

use anyhow::{Context, Result};
use eframe::{egui, egui_wgpu};
use twill_precompute::bake::settings::Quality;

/// How the viewer starts.
#[derive(Debug, Clone)]
pub struct ViewerOptions {
    /// Scene file (default: the built-in default scene).
    pub scene: Option<PathBuf>,
    /// Bake quality after the draft.
    pub quality: Quality,
    /// A script of edits to play (see [`script`]).
    pub script: Option<PathBuf>,
    /// Window's inner size in points.
    pub window_size: [u32; 2],
    /// Stage cache folder (default: the one `twill bake` uses).
    pub cache_dir: Option<PathBuf>,
}

/// `twill bench ui`: the viewer's own frame times while a bake of `quality` runs in the
/// background from an empty stage cache (so every stage is computed), with the view orbiting
/// every frame as if dragged. Runs the viewer with a script and returns its report.
pub fn bench_ui(
    scene: Option<PathBuf>,
    quality: Quality,
    seconds: f64,
    window_size: [u32; 2],
) -> Result<String> {
    let dir = tempfile::tempdir().context("a temporary folder for the benchmark")?;
    let report = dir.path().join("frame-times.txt");
    let script = dir.path().join("bench.script");
    let text = format!(
        "wait-fabric draft\nframe-times {}\nbake {}\nspin {seconds}\nframe-times {}\nquit\n",
        dir.path().join("warm-up.txt").display(),
        quality.name(),
        report.display()
    );
    std::fs::write(&script, text).context("writing the benchmark script")?;
    run(ViewerOptions {
        scene,
        quality: Quality::Draft,
        script: Some(script),
        window_size,
        cache_dir: Some(dir.path().join("cache")),
    })?;
    std::fs::read_to_string(&report).context("the benchmark wrote no report")
}

/// The device the viewer asks eframe for: Vulkan, the adapter's own limits, and timestamp
/// queries where the adapter has them.
fn wgpu_configuration() -> egui_wgpu::WgpuConfiguration {
    let mut setup = egui_wgpu::WgpuSetupCreateNew::without_display_handle();
    setup.instance_descriptor.backends = wgpu::Backends::VULKAN;
    setup.device_descriptor = Arc::new(|adapter: &wgpu::Adapter| wgpu::DeviceDescriptor {
        label: Some("twill.viewer.device"),
        required_features: adapter.features() & wgpu::Features::TIMESTAMP_QUERY,
        required_limits: adapter.limits(),
        ..Default::default()
    });
    egui_wgpu::WgpuConfiguration { wgpu_setup: egui_wgpu::WgpuSetup::CreateNew(setup), ..Default::default() }
}

/// Opens the viewer window and runs it until it is closed (or its script ends).
pub fn run(options: ViewerOptions) -> Result<()> {
    #[cfg(target_os = "linux")]
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        anyhow::bail!(
            "the viewer needs an X11 display and DISPLAY is not set. Run it on a desktop, under \
             `xvfb-run -a twill view` without one, or use a subcommand (`twill --help`)"
        );
    }
    let script = match &options.script {
        Some(path) => {
            let text = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
            Some(script::parse_script(&text, path).map_err(anyhow::Error::msg)?)
        }
        None => None,
    };
    let [w, h] = options.window_size;
    let title = match &options.scene {
        Some(path) => format!("twill — {}", path.display()),
        None => "twill — default fabric".to_owned(),
    };
    let native = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title(title)
            .with_app_id("twill")
            .with_inner_size([w as f32, h as f32])
            .with_min_inner_size([480.0, 320.0]),
        renderer: eframe::Renderer::Wgpu,
        wgpu_options: wgpu_configuration(),
        // Dithering would change the rendered fabric's pixels on screen.
        dithering: false,
        ..Default::default()
    };
    let outcome: Arc<Mutex<Option<Result<(), String>>>> = Arc::default();
    let app_outcome = Arc::clone(&outcome);
    eframe::run_native(
        "twill",
        native,
        Box::new(move |cc| Ok(Box::new(app::ViewerApp::new(cc, &options, script, app_outcome)))),
    )
    .map_err(|e| anyhow::anyhow!("the viewer window failed: {e}"))?;
    match outcome.lock().unwrap_or_else(PoisonError::into_inner).take() {
        Some(Err(message)) => Err(anyhow::anyhow!(message)),
        _ => Ok(()),
    }
}
