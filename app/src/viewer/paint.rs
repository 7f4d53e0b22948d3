//! Paint mode: Hašan & Ramamoorthy's albedo painting in the viewer.
//!
//! How it works: entering paint mode freezes the view. [`PaintSession::start`] takes the scene
//! as it is on screen (fabric, materials, camera, lights) and a paint image of the viewport's
//! aspect, and traces the colour-free paths of that view on a background thread
//! (`twill_precompute::paint::precompute_cancellable`, the same precompute as `twill paint
//! precompute`), with progress per row; leaving cancels it. Once it is done the viewport shows
//! the painted cloth, `J(α) = I_h(Wα)` per pixel ([`PaintData::evaluate`], milliseconds), in
//! place of the live renderer's picture. A click or a drag paints the brush colour onto the
//! cell under the pointer ([`paint::cell_at`]: the first fiber the pixel's eye ray meets): one
//! section of a thread, the whole thread, or every thread of its set ([`Scope`]); a right
//! click picks the colour of the yarn under the pointer. Every stroke can be undone.
//!
//! "Commit" turns the painting into the scene's colour orders where it is one
//! ([`paint::commit_colour_orders`]: each thread one colour, periodic across the swatch) and
//! queues a [`Verification`]: the committed scene path-traced twice at the paint image's size
//! (seeds apart from the precompute's), the painting's relative L2 error against the first
//! reference beside the references' own (the noise floor), as `twill paint verify` reports it.
//! "Verify" does the same for a painting that is not a colour order, path-tracing the painted
//! cloth itself.
//!
//! A painting can be saved as strokes ([`Painting::from_colours`], the TOML `twill paint`
//! reads) and opened again, and the precompute saved as a paint file for `twill paint apply`,
//! `verify` and `commit`. Leaving paint mode keeps the precompute and the painting
//! ([`KeptPaint`]): painting the same view again resumes them at once.

use std::io::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, mpsc};
use std::time::Instant;

use eframe::egui;
use twill_precompute::Rgb;
use twill_precompute::atomic_file::write_atomically;
use twill_precompute::image::Image;
use twill_precompute::paint::{
    self, PaintCells, PaintData, PaintSettings, PaintedMaterials, Painting, SceneKeys,
};
use twill_precompute::pathtrace::{self, Camera, Component, RenderSettings};
use twill_precompute::scene::{Scene, SceneFile};
use twill_renderer::export::{Display, display_srgb8};

/// Longest sides of the paint image a designer may choose (pixels).
pub const SIDE_CHOICES: [u32; 5] = [32, 64, 96, 128, 192];
/// Paths per pixel of the homogeneous curves a designer may choose.
pub const SPP_CHOICES: [u32; 5] = [16, 64, 128, 256, 512];
/// Samples per pixel of each verification reference.
pub const VERIFY_SPP_CHOICES: [u32; 4] = [16, 64, 256, 1024];
/// Of the curve paths, the fraction that also give the gradient weights (as `twill paint
/// precompute`'s defaults: 64 of 256).
const GRADIENT_SHARE: u32 = 4;
/// Strokes kept for undo.
const UNDO_DEPTH: usize = 64;

/// What one click paints.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scope {
    /// The section under the pointer: one crossing's length of one thread.
    Section,
    /// The whole thread under the pointer, edge to edge.
    Thread,
    /// Every thread of the set under the pointer (all warp ends, or all weft picks).
    Set,
}

impl Scope {
    pub const ALL: [Self; 3] = [Self::Section, Self::Thread, Self::Set];

    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            Self::Section => "section",
            Self::Thread => "thread",
            Self::Set => "all of its set",
        }
    }

    /// A script's word for a scope.
    pub fn parse(word: &str) -> Result<Self, String> {
        match word {
            "section" => Ok(Self::Section),
            "thread" => Ok(Self::Thread),
            "set" => Ok(Self::Set),
            other => Err(format!("a paint scope is section, thread or set, not {other:?}")),
        }
    }
}

/// Paint mode's settings before it starts, and the verification's sample count.
#[derive(Debug, Clone, PartialEq)]
pub struct PaintForm {
    /// Longest side of the paint image (pixels).
    pub side: u32,
    /// Paths per pixel of the precompute.
    pub spp: u32,
    /// Samples per pixel of each verification reference.
    pub verify_spp: u32,
    /// The file a painting is saved to or opened from (the paint file goes beside it).
    pub file: String,
}

impl Default for PaintForm {
    fn default() -> Self {
        Self { side: 96, spp: 128, verify_spp: 64, file: "painting.toml".to_owned() }
    }
}

/// The paint image's size for a viewport of `viewport` pixels: its aspect, `side` pixels
/// along the longer side.
#[must_use]
pub fn paint_size(viewport: [u32; 2], side: u32) -> [u32; 2] {
    let [w, h] = viewport.map(|v| f64::from(v.max(1)));
    let scale = f64::from(side) / w.max(h);
    [((w * scale).round() as u32).max(1), ((h * scale).round() as u32).max(1)]
}

/// Work on a background thread with a row count for progress and a cancel flag; dropping it
/// cancels the work.
struct Job<T> {
    rows: Arc<AtomicUsize>,
    total_rows: usize,
    cancel: Arc<AtomicBool>,
    receiver: mpsc::Receiver<Result<T, String>>,
    started: Instant,
}

impl<T: Send + 'static> Job<T> {
    fn spawn(
        name: &str,
        total_rows: usize,
        ctx: &egui::Context,
        work: impl FnOnce(&AtomicUsize, &AtomicBool) -> Result<T, String> + Send + 'static,
    ) -> Result<Self, String> {
        let (sender, receiver) = mpsc::channel();
        let rows = Arc::new(AtomicUsize::new(0));
        let cancel = Arc::new(AtomicBool::new(false));
        let (thread_rows, thread_cancel, repaint) = (Arc::clone(&rows), Arc::clone(&cancel), ctx.clone());
        std::thread::Builder::new()
            .name(name.to_owned())
            .spawn(move || {
                let outcome = work(&thread_rows, &thread_cancel);
                // The receiver is gone when the job was dropped (cancelled): nothing to tell.
                let _ = sender.send(outcome);
                repaint.request_repaint();
            })
            .map_err(|e| format!("could not start the {name} thread: {e}"))?;
        Ok(Self { rows, total_rows, cancel, receiver, started: Instant::now() })
    }

    fn fraction(&self) -> f32 {
        (self.rows.load(Ordering::Relaxed) as f32 / self.total_rows.max(1) as f32).min(1.0)
    }

    /// The outcome once the thread is done.
    fn poll(&self) -> Option<Result<T, String>> {
        match self.receiver.try_recv() {
            Ok(outcome) => Some(outcome),
            Err(mpsc::TryRecvError::Empty) => None,
            Err(mpsc::TryRecvError::Disconnected) => Some(Err("the background thread stopped".into())),
        }
    }
}

impl<T> Drop for Job<T> {
    fn drop(&mut self) {
        self.cancel.store(true, Ordering::Relaxed);
    }
}

/// A finished precompute and what picking needs.
struct Ready {
    scene: Arc<Scene>,
    camera: Camera,
    data: Arc<PaintData>,
}

enum Stage {
    Precomputing(Job<Ready>),
    Ready(Ready),
    Failed(String),
}

/// Paint mode ([module docs](self)).
pub struct PaintSession {
    /// The scene as it was on screen when paint mode started.
    frozen: SceneFile,
    size: [u32; 2],
    stage: Stage,
    /// The painting: one colour per cell (empty until the precompute is done).
    colours: Vec<Rgb>,
    undo: Vec<Vec<Rgb>>,
    /// The brush colour (linear RGB).
    pub colour: [f32; 3],
    pub scope: Scope,
    /// The painted picture, `J(α)` (`None` until the precompute is done).
    picture: Option<Picture>,
    /// The last evaluation's time (milliseconds).
    pub edit_ms: f64,
    /// What the last click painted or picked.
    pub last_action: Option<String>,
}

impl PaintSession {
    /// Freezes `scene` (as it is on screen) and starts precomputing its view at a paint image
    /// of `viewport`'s aspect.
    pub fn start(
        scene: SceneFile,
        viewport: [u32; 2],
        form: &PaintForm,
        ctx: &egui::Context,
    ) -> Result<Self, String> {
        if scene.pattern.is_some() {
            return Err("paint mode's cells run along one exemplar's threads: \
                        remove [pattern] to paint [fabric]'s weave"
                .into());
        }
        if !scene.mesh.is_flat_swatch() {
            return Err("paint mode paints the flat swatch's threads, not the cloth on the mesh: \
                        set the mesh to the flat swatch to paint"
                .into());
        }
        let size = paint_size(viewport, form.side);
        let [w, h] = size;
        let camera = scene.camera(w as usize, h as usize).map_err(|e| format!("the camera: {e}"))?;
        let settings = PaintSettings {
            width: w,
            height: h,
            curve_spp: form.spp,
            gradient_spp: (form.spp / GRADIENT_SHARE).max(1),
            max_depth: scene.render.max_depth,
            seed: scene.render.seed,
        };
        settings.validate().map_err(|e| e.to_string())?;
        let keys = SceneKeys::of(&scene)?;
        let frozen = scene.clone();
        let job = Job::spawn("twill-paint-precompute", h as usize, ctx, move |rows, cancel| {
            let built = scene.build().map_err(|e| format!("the scene cannot be built: {e}"))?;
            let cells =
                PaintCells::new(&built.exemplar, &built.path_scene.fibers).map_err(|e| e.to_string())?;
            let progress = |done: usize| rows.store(done, Ordering::Relaxed);
            let mut data = paint::precompute_cancellable(
                &built.path_scene,
                cells,
                &camera,
                &settings,
                &progress,
                cancel,
            )
            .map_err(|e| e.to_string())?;
            // A paint file saved from the viewer says what it was traced in, as the CLI's do.
            data.scene_keys = Some(keys);
            data.exposure = Some(scene.render.exposure);
            Ok(Ready { scene: Arc::new(built), camera, data: Arc::new(data) })
        })?;
        Ok(Self::new(frozen, size, Stage::Precomputing(job), Vec::new()))
    }

    /// A session at `stage` with the painting `colours` (empty until the precompute is done),
    /// the brush at its defaults.
    fn new(frozen: SceneFile, size: [u32; 2], stage: Stage, colours: Vec<Rgb>) -> Self {
        Self {
            frozen,
            size,
            stage,
            colours,
            undo: Vec::new(),
            colour: [0.05, 0.1, 0.45],
            scope: Scope::Thread,
            picture: None,
            edit_ms: 0.0,
            last_action: None,
        }
    }

    /// Paint mode again on a view painted before ([`KeptPaint`]): its precompute and painting
    /// as they were left.
    #[must_use]
    pub fn resume(kept: KeptPaint) -> Self {
        let KeptPaint { frozen, size, ready, colours } = kept;
        let mut session = Self::new(frozen, size, Stage::Ready(ready), colours);
        session.evaluate();
        session
    }

    /// What to keep of a session that ends, for [`Self::resume`]: its precompute and painting
    /// (`None` before the precompute is done).
    #[must_use]
    pub fn into_kept(self) -> Option<KeptPaint> {
        match self.stage {
            Stage::Ready(ready) => {
                Some(KeptPaint { frozen: self.frozen, size: self.size, ready, colours: self.colours })
            }
            _ => None,
        }
    }

    /// The painting as strokes (TOML, [`Painting::from_colours`]), written atomically.
    pub fn save_painting(&self, path: &Path) -> Result<String, String> {
        let Stage::Ready(ready) = &self.stage else { return Err("the precompute is not done".into()) };
        let painting = Painting::from_colours(&ready.data.cells, &self.colours, &ready.data.scene_painting());
        let text = toml::to_string(&painting).map_err(|e| format!("the painting cannot be written: {e}"))?;
        write_atomically(path, |w| w.write_all(text.as_bytes()))
            .map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(format!("saved the painting ({} strokes) to {}", painting.strokes.len(), path.display()))
    }

    /// Paints a painting file (TOML strokes) over the scene's colours, as one stroke.
    pub fn open_painting(&mut self, path: &Path) -> Result<String, String> {
        let Stage::Ready(ready) = &self.stage else { return Err("the precompute is not done".into()) };
        let painting = Painting::load(path).map_err(|e| e.to_string())?;
        let colours = painting
            .colours(&ready.data.cells, &ready.data.scene_painting(), path)
            .map_err(|e| e.to_string())?;
        self.undo.push(std::mem::replace(&mut self.colours, colours));
        self.evaluate();
        Ok(format!("painted {} ({} strokes)", path.display(), painting.strokes.len()))
    }

    /// The precompute as a paint file (with the scene's fingerprints), for `twill paint apply`,
    /// `verify` and `commit`.
    pub fn save_paint_file(&self, path: &Path) -> Result<String, String> {
        let Stage::Ready(ready) = &self.stage else { return Err("the precompute is not done".into()) };
        ready.data.save(path).map_err(|e| e.to_string())?;
        Ok(format!("saved the precompute to {}", path.display()))
    }

    /// Takes the precompute's outcome when it arrives: a line for the message list.
    pub fn poll(&mut self) -> Option<Result<String, String>> {
        let Stage::Precomputing(job) = &self.stage else { return None };
        let outcome = job.poll()?;
        let seconds = job.started.elapsed().as_secs_f64();
        Some(match outcome {
            Ok(ready) => {
                let data = &ready.data;
                self.colours = data.scene_painting();
                let [w, h] = self.size;
                let line = format!(
                    "paint mode: {w}x{h} precomputed at {} spp in {seconds:.1} s ({} cells, {:.1} MB); \
                     click or drag on a yarn to paint it",
                    data.settings.curve_spp,
                    data.cells.count(),
                    data.bytes() as f64 / 1e6
                );
                self.stage = Stage::Ready(ready);
                self.evaluate();
                Ok(line)
            }
            Err(e) => {
                self.stage = Stage::Failed(e.clone());
                Err(format!("paint mode: the precompute failed: {e}"))
            }
        })
    }

    /// Fraction of the precompute done and seconds since it started, while it runs.
    #[must_use]
    pub fn progress(&self) -> Option<(f32, f64)> {
        match &self.stage {
            Stage::Precomputing(job) => Some((job.fraction(), job.started.elapsed().as_secs_f64())),
            _ => None,
        }
    }

    #[must_use]
    pub fn is_ready(&self) -> bool {
        matches!(self.stage, Stage::Ready(_))
    }

    #[must_use]
    pub fn failure(&self) -> Option<&str> {
        match &self.stage {
            Stage::Failed(e) => Some(e),
            _ => None,
        }
    }

    #[must_use]
    pub fn size(&self) -> [u32; 2] {
        self.size
    }

    #[must_use]
    pub fn can_undo(&self) -> bool {
        !self.undo.is_empty()
    }

    /// The painting's distinct colours, most used first (what the palette row offers).
    #[must_use]
    pub fn colours_in_use(&self, most: usize) -> Vec<[f32; 3]> {
        // Colours compare by their bits (a painting holds exact copies of the brush colour).
        let mut counts: Vec<([u32; 3], usize)> = Vec::new();
        for c in &self.colours {
            let c = [c.x as f32, c.y as f32, c.z as f32].map(f32::to_bits);
            if let Some((_, n)) = counts.iter_mut().find(|(k, _)| *k == c) {
                *n += 1;
            } else if counts.len() < 256 {
                counts.push((c, 1));
            }
        }
        counts.sort_by_key(|&(_, n)| std::cmp::Reverse(n));
        counts.into_iter().take(most).map(|(c, _)| c.map(f32::from_bits)).collect()
    }

    /// The cell under film position (`fx`, `fy`) of the paint image, in fractions of its
    /// width and height.
    fn cell_under(&self, fx: f64, fy: f64) -> Result<Option<u32>, String> {
        let Stage::Ready(ready) = &self.stage else { return Err("the precompute is not done".into()) };
        let [w, h] = self.size.map(f64::from);
        if !(0.0..=1.0).contains(&fx) || !(0.0..=1.0).contains(&fy) {
            return Ok(None);
        }
        Ok(paint::cell_at(&ready.scene.path_scene, &ready.data.cells, &ready.camera, fx * w, fy * h))
    }

    /// Paints the brush colour at (`fx`, `fy`) (fractions of the paint image) over the brush's
    /// scope. `new_stroke` keeps the painting before it for undo (a drag is one stroke).
    /// Returns what was painted, `None` off the cloth.
    pub fn paint_at(&mut self, fx: f64, fy: f64, new_stroke: bool) -> Result<Option<String>, String> {
        let Some(cell) = self.cell_under(fx, fy)? else { return Ok(None) };
        let Stage::Ready(ready) = &self.stage else { return Ok(None) };
        let cells = &ready.data.cells;
        let place = cells.thread_of(cell);
        let targets: Vec<u32> = match (self.scope, place) {
            (Scope::Section, _) | (_, None) => vec![cell],
            (Scope::Thread, Some((warp, thread, _))) => {
                let set = if warp { &cells.warp } else { &cells.weft };
                cells.thread_cells(warp, thread, 0..set.sections).unwrap_or_else(|| vec![cell])
            }
            (Scope::Set, Some((warp, _, _))) => (0..cells.count() as u32)
                .filter(|&c| cells.thread_of(c).is_some_and(|(w, _, _)| w == warp))
                .collect(),
        };
        let what = describe(place, self.scope);
        let colour = Rgb::from_array(self.colour.map(|c| brush_channel(c.clamp(0.0, 1.0))));
        if targets.iter().all(|&c| self.colours[c as usize] == colour) {
            return Ok(Some(what));
        }
        if new_stroke {
            self.undo.push(self.colours.clone());
            if self.undo.len() > UNDO_DEPTH {
                self.undo.remove(0);
            }
        }
        for c in targets {
            self.colours[c as usize] = colour;
        }
        self.evaluate();
        self.last_action = Some(format!("painted {what}"));
        Ok(Some(what))
    }

    /// Takes the colour of the yarn at (`fx`, `fy`) as the brush colour.
    pub fn pick_at(&mut self, fx: f64, fy: f64) -> Result<bool, String> {
        let Some(cell) = self.cell_under(fx, fy)? else { return Ok(false) };
        let c = self.colours[cell as usize];
        self.colour = [c.x as f32, c.y as f32, c.z as f32];
        self.last_action = Some(format!("picked [{:.3}, {:.3}, {:.3}]", c.x, c.y, c.z));
        Ok(true)
    }

    /// Undoes the last stroke.
    pub fn undo(&mut self) -> bool {
        let Some(before) = self.undo.pop() else { return false };
        self.colours = before;
        self.evaluate();
        true
    }

    /// Back to the scene's own colours (one stroke, undoable).
    pub fn reset(&mut self) {
        let Stage::Ready(ready) = &self.stage else { return };
        let scene = ready.data.scene_painting();
        if scene != self.colours {
            self.undo.push(std::mem::replace(&mut self.colours, scene));
            self.evaluate();
        }
    }

    fn evaluate(&mut self) {
        let Stage::Ready(ready) = &self.stage else { return };
        let started = Instant::now();
        let image = ready.data.evaluate(&self.colours);
        self.edit_ms = started.elapsed().as_secs_f64() * 1e3;
        match &mut self.picture {
            Some(picture) => picture.set(image),
            None => self.picture = Some(Picture::new("twill.paint.picture", image)),
        }
    }

    /// The painted picture as a texture, tone-mapped with `display` (`filmic` chooses the
    /// curve as the viewer's controls do).
    pub fn texture(
        &mut self,
        ctx: &egui::Context,
        display: Display,
        filmic: bool,
    ) -> Option<&egui::TextureHandle> {
        Some(self.picture.as_mut()?.texture(ctx, display, filmic))
    }

    /// The scene with the painting as its colour orders, and a line saying what they are;
    /// an error saying why the painting is not a colour order.
    pub fn commit(&self) -> Result<(SceneFile, String), String> {
        let Stage::Ready(ready) = &self.stage else { return Err("the precompute is not done".into()) };
        let committed = paint::commit_colour_orders(&self.frozen, &ready.data.cells, &self.colours)
            .map_err(|e| format!("the painting is not a colour order: {e}"))?;
        let mut line = format!("committed the painting as colour orders: {}", committed.summary);
        if let Some(note) = committed.edge_note() {
            line = format!("{line}; {note}");
        }
        Ok((committed.scene, line))
    }

    /// Starts a path-traced check of the painting: against the `committed` scene when given,
    /// else against the painted cloth itself.
    pub fn verify(
        &self,
        committed: Option<&SceneFile>,
        spp: u32,
        ctx: &egui::Context,
    ) -> Result<Verification, String> {
        let (Stage::Ready(ready), Some(Picture { image, .. })) = (&self.stage, &self.picture) else {
            return Err("the precompute is not done".into());
        };
        let what = if committed.is_some() { "the committed colour orders" } else { "the painted cloth" };
        let settings = ready.data.settings;
        let scene = committed.unwrap_or(&self.frozen).clone();
        let painting = committed.is_none().then(|| (ready.data.cells.clone(), self.colours.clone()));
        let camera = ready.camera;
        let [w, h] = self.size;
        let job = Job::spawn("twill-paint-verify", 2 * h as usize, ctx, move |rows, cancel| {
            let mut built = scene.build().map_err(|e| format!("the scene cannot be built: {e}"))?;
            if let Some((cells, colours)) = painting {
                built.path_scene.painted = Some(
                    PaintedMaterials::new(&built.path_scene, cells, &colours).map_err(|e| e.to_string())?,
                );
            }
            let mut references = Vec::with_capacity(2);
            for k in 0..2_u64 {
                if cancel.load(Ordering::Relaxed) {
                    return Err("cancelled".into());
                }
                let render = RenderSettings {
                    spp,
                    max_depth: settings.max_depth,
                    component: Component::All,
                    seed: settings.seed.wrapping_add(1 + k),
                };
                let base = k as usize * h as usize;
                let film = pathtrace::render(&built.path_scene, &camera, &render, &|done| {
                    rows.store(base + done, Ordering::Relaxed);
                });
                references.push(film.mean());
            }
            let second = references.pop().expect("two references");
            let first = references.pop().expect("two references");
            Ok([first, second])
        })?;
        Ok(Verification {
            what: what.to_owned(),
            size: [w, h],
            spp,
            painted: image.clone(),
            job: Some(job),
            report: None,
            pictures: None,
        })
    }
}

/// A brush channel (egui's f32) as the f64 a designer would write: the shortest decimal that
/// reads back as the same f32 (0.6, not 0.6000000238418579), so a saved painting and a
/// committed palette say what was picked.
fn brush_channel(c: f32) -> f64 {
    c.to_string().parse().unwrap_or(f64::from(c))
}

/// "warp end 12, section 3" and the like, as a painting names them.
fn describe(place: Option<(bool, i64, u32)>, scope: Scope) -> String {
    match (place, scope) {
        (None, _) => "a yarn with no weave role".to_owned(),
        (Some((warp, _, _)), Scope::Set) => {
            (if warp { "every warp end" } else { "every weft pick" }).to_owned()
        }
        (Some((warp, thread, _)), Scope::Thread) => {
            format!("{} {thread}", if warp { "warp end" } else { "weft pick" })
        }
        (Some((warp, thread, section)), Scope::Section) => {
            format!("{} {thread}, section {section}", if warp { "warp end" } else { "weft pick" })
        }
    }
}

/// A session's precompute and painting, kept after it ends so that painting the same view
/// again (the same scene, image size and paths) resumes at once.
pub struct KeptPaint {
    frozen: SceneFile,
    size: [u32; 2],
    ready: Ready,
    colours: Vec<Rgb>,
}

impl KeptPaint {
    /// Whether paint mode on `scene` with `form` would paint this again: the same scene (view,
    /// lights, fabric), image side and paths. The viewport's aspect may have changed since (a
    /// panel resized); the kept image is shown as it was, letterboxed.
    #[must_use]
    pub fn fits(&self, scene: &SceneFile, form: &PaintForm) -> bool {
        self.frozen == *scene
            && self.size.into_iter().max() == Some(form.side)
            && self.ready.data.settings.curve_spp == form.spp
    }
}

/// An image shown in the viewport: tone-mapped into a texture when first shown and again
/// when the image or the display settings change.
pub struct Picture {
    image: Image,
    name: &'static str,
    texture: Option<egui::TextureHandle>,
    /// The exposure and curve the texture was made with; `None` when it needs making again.
    shown_with: Option<(f64, bool)>,
}

impl Picture {
    fn new(name: &'static str, image: Image) -> Self {
        Self { image, name, texture: None, shown_with: None }
    }

    fn set(&mut self, image: Image) {
        self.image = image;
        self.shown_with = None;
    }

    /// The texture, tone-mapped with `display` (`filmic`: the curve's choice, as the viewer's
    /// controls hold it).
    pub fn texture(&mut self, ctx: &egui::Context, display: Display, filmic: bool) -> &egui::TextureHandle {
        let key = (display.exposure, filmic);
        if self.shown_with != Some(key) || self.texture.is_none() {
            let pixels: Vec<egui::Color32> = self
                .image
                .pixels
                .iter()
                .map(|&p| {
                    let [r, g, b] = display_srgb8(p, display);
                    egui::Color32::from_rgb(r, g, b)
                })
                .collect();
            let colour_image = egui::ColorImage::new([self.image.width, self.image.height], pixels);
            match &mut self.texture {
                Some(texture) => texture.set(colour_image, egui::TextureOptions::LINEAR),
                None => {
                    self.texture =
                        Some(ctx.load_texture(self.name, colour_image, egui::TextureOptions::LINEAR));
                }
            }
            self.shown_with = Some(key);
        }
        self.texture.as_ref().expect("made above")
    }
}

/// What paint mode's viewport shows once a verification of the painting is done.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shown {
    Painting,
    /// The verification's first path-traced reference.
    Reference,
    /// `|painting − reference|`, four times brighter.
    Difference,
}

impl Shown {
    pub const ALL: [Self; 3] = [Self::Painting, Self::Reference, Self::Difference];

    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            Self::Painting => "painting",
            Self::Reference => "path traced",
            Self::Difference => "difference ×4",
        }
    }

    /// A script's word for it.
    pub fn parse(word: &str) -> Result<Self, String> {
        match word {
            "painting" => Ok(Self::Painting),
            "reference" => Ok(Self::Reference),
            "difference" => Ok(Self::Difference),
            other => Err(format!("paint-show takes painting, reference or difference, not {other:?}")),
        }
    }
}

/// A path-traced check of a painting ([module docs](self)); it runs on after paint mode ends.
pub struct Verification {
    what: String,
    size: [u32; 2],
    spp: u32,
    painted: Image,
    job: Option<Job<[Image; 2]>>,
    report: Option<Result<String, String>>,
    /// Once done: the first reference and `|painted − reference| × 4`.
    pictures: Option<(Picture, Picture)>,
}

impl Verification {
    /// Takes the references when they arrive: the report for the message list.
    pub fn poll(&mut self) -> Option<Result<String, String>> {
        let outcome = self.job.as_ref()?.poll()?;
        let seconds = self.job.take().map_or(0.0, |j| j.started.elapsed().as_secs_f64());
        let report = outcome
            .map(|[first, second]| {
                let line = self.compare(&first, &second, seconds);
                let mut difference = first.clone();
                for (d, p) in difference.pixels.iter_mut().zip(&self.painted.pixels) {
                    *d = (*p - *d).abs() * 4.0;
                }
                self.pictures = Some((
                    Picture::new("twill.paint.reference", first),
                    Picture::new("twill.paint.difference", difference),
                ));
                line
            })
            .map_err(|e| format!("the verification of {} failed: {e}", self.what));
        self.report = Some(report.clone());
        Some(report)
    }

    fn compare(&self, first: &Image, second: &Image, seconds: f64) -> String {
        let error = self.painted.relative_l2(first);
        let floor = second.relative_l2(first);
        let (painted, reference) = (self.painted.mean(), first.mean());
        let mean = |v: Rgb| (v.x + v.y + v.z) / 3.0;
        let [w, h] = self.size;
        format!(
            "verification of {} ({w}x{h}, path-traced twice at {} spp in {seconds:.1} s): relative L2 {error:.3} \
             against the path tracer, its own noise floor {floor:.3} (ratio {:.2}); image mean {:+.1}% from the \
             reference",
            self.what,
            self.spp,
            error / floor.max(f64::MIN_POSITIVE),
            100.0 * (mean(painted) / mean(reference).max(f64::MIN_POSITIVE) - 1.0)
        )
    }

    /// Fraction done while the references render.
    #[must_use]
    pub fn progress(&self) -> Option<f32> {
        self.job.as_ref().map(Job::fraction)
    }

    /// The picture `shown` of a finished verification of a `size` paint image (`None` for the
    /// painting itself, before it is done, or for another size).
    pub fn picture(&mut self, shown: Shown, size: [u32; 2]) -> Option<&mut Picture> {
        let (reference, difference) = self.pictures.as_mut().filter(|_| self.size == size)?;
        match shown {
            Shown::Painting => None,
            Shown::Reference => Some(reference),
            Shown::Difference => Some(difference),
        }
    }

    /// The finished report (or why it failed).
    #[must_use]
    pub fn report(&self) -> Option<&Result<String, String>> {
        self.report.as_ref()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paint_image_takes_the_viewport_aspect_and_the_brush_its_decimal() {
        assert_eq!(paint_size([371, 615], 128), [77, 128]);
        assert_eq!(paint_size([800, 400], 96), [96, 48]);
        assert_eq!(paint_size([0, 0], 32), [32, 32], "an empty viewport is square");
        assert_eq!(paint_size([4000, 3], 32), [32, 1], "never zero");
        for c in [0.6_f32, 0.05, 0.1, 1.0, 0.0, 0.123_456_79] {
            let written = brush_channel(c);
            assert_eq!(written.to_string(), c.to_string(), "{c} is written as picked");
            assert_eq!((written as f32).to_bits(), c.to_bits(), "and reads back as the same f32");
        }
        assert_eq!(Scope::parse("set"), Ok(Scope::Set));
        assert!(Scope::parse("yarn").is_err());
    }
}
