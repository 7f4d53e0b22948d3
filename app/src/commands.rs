//! The subcommands' work: load the scene, do the job, report.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use glam::Vec3;
use indicatif::{ProgressBar, ProgressStyle};
use twill_precompute::bake::Cancel;
use twill_precompute::bake::file::{Cache, DEFAULT_CACHE_LIMIT_BYTES};
use twill_precompute::bake::pattern::PatternMap;
use twill_precompute::bake::pipeline::{
    BakeOutcome, Baked, Stage, StageSource, bake_set, read_bake, write_bake,
};
use twill_precompute::bake::settings::{BakeSettings, Quality};
use twill_precompute::fabric::{Exemplar, exemplar::volume_fraction, fiber_io, presets};
use twill_precompute::image::Image;
use twill_precompute::paint::Painting;
use twill_precompute::pathtrace::{self, Component};
use twill_precompute::raycast::mean_free_path;
use twill_precompute::scene::SceneFile;
use twill_renderer::export::{Display, write_display_png, write_image};
use twill_renderer::frame::describe_timings;
use twill_renderer::headless::{SceneRenderer, frame_settings};
use twill_renderer::plan::Components;

/// What every image-producing command takes: the scene, the output file and overrides of the
/// scene's `[render]` section.
#[derive(Debug, clap::Args)]
pub struct ImageOptions {
    /// Scene file (default: the built-in default scene).
    pub scene: Option<PathBuf>,
    /// Output image: .exr (linear HDR) or .png (tone-mapped sRGB).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Image size as WIDTHxHEIGHT (default: the scene's).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(usize, usize)>,
    /// Samples per pixel (default: the scene's).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Exposure in stops for PNG output (default: the scene's).
    #[arg(long, allow_hyphen_values = true)]
    pub exposure: Option<f64>,
}

impl ImageOptions {
    /// Loads the scene (or the default one) with the size, spp and exposure overrides applied.
    fn load_scene(&self) -> Result<SceneFile> {
        let mut file = SceneFile::load_or_default(self.scene.as_deref())?;
        let render = &mut file.render;
        if let Some((w, h)) = self.size {
            (render.width, render.height) = (w, h);
        }
        render.spp = self.spp.unwrap_or(render.spp);
        render.exposure = self.exposure.unwrap_or(render.exposure);
        Ok(file)
    }
}

/// Parses `WIDTHxHEIGHT`, each side in 1..=16384.
pub fn parse_size(text: &str) -> Result<(usize, usize), String> {
    let err = || format!("{text:?} is not a size: expected WIDTHxHEIGHT, e.g. 256x256, each 1..=16384");
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(err)?;
    let w: usize = w.trim().parse().map_err(|_| err())?;
    let h: usize = h.trim().parse().map_err(|_| err())?;
    if (1..=16384).contains(&w) && (1..=16384).contains(&h) { Ok((w, h)) } else { Err(err()) }
}

pub fn fabric_presets() {
    for preset in presets::fabric_presets() {
        println!("{:<18} {}", preset.name, preset.description);
    }
}

pub fn fabric_info(scene_path: Option<&Path>, mfp_samples: usize) -> Result<()> {
    let file = SceneFile::load_or_default(scene_path)?;
    let scene = file.build()?;
    let exemplar = &scene.exemplar;
    let segments = exemplar.segments();
    let (lo, hi) = exemplar.bounds().context("the fabric has no fibers")?;
    println!("scene            {}", file.path.display());
    println!("fibers           {}", exemplar.fibers.len());
    println!("segments         {}", segments.len());
    println!("yarns            {}", exemplar.yarns.len());
    let mean_len = segments.iter().map(|s| f64::from(s.length())).sum::<f64>() / segments.len().max(1) as f64;
    println!("segment length   {mean_len:.5} cm (mean)");
    println!(
        "bounds (cm)      [{:.4}, {:.4}, {:.4}] .. [{:.4}, {:.4}, {:.4}]",
        lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
    );
    match exemplar.tiling {
        twill_precompute::fabric::Tiling::Periodic { period } => {
            println!("tiling           periodic, period {:.4} x {:.4} cm", period.x, period.y);
        }
        twill_precompute::fabric::Tiling::AsIs => println!("tiling           as-is (no tiling)"),
    }
    println!("volume fraction  {:.4}", volume_fraction(exemplar));
    let mfp = mean_free_path(&scene.path_scene.fibers, mfp_samples, 1);
    println!(
        "mean free path   {:.5} cm +- {:.5} (std. error; {} rays, {:.1}% escaped the fabric)",
        mfp.mean_cm,
        mfp.std_error_cm,
        mfp.samples,
        100.0 * mfp.escaped_fraction
    );
    if let Some(pattern) = &scene.pattern {
        let blocks: Vec<String> =
            pattern.exemplars.iter().map(|e| format!("{}x{}", e.blocks.nx, e.blocks.ny)).collect();
        println!(
            "pattern          {} exemplars (blocks per exemplar {}), map of {}x{} blocks (the numbers above are exemplar 0's)",
            pattern.exemplars.len(),
            blocks.join(", "),
            pattern.map.width,
            pattern.map.height
        );
    }
    Ok(())
}

pub fn fabric_export(scene_path: Option<&Path>, hair: bool, output: &Path) -> Result<()> {
    let scene = SceneFile::load_or_default(scene_path)?.build()?;
    let format = if hair { fiber_io::FiberFormat::Hair } else { fiber_io::FiberFormat::Mitsuba };
    fiber_io::write_fibers(output, &scene.exemplar.fibers, Some(format))?;
    eprintln!("wrote {} fibers to {}", scene.exemplar.fibers.len(), output.display());
    Ok(())
}

/// Refuses a patterned scene for a command that works on one exemplar (the CPU method, the
/// error budget, paint cells); `twill render` and `twill reference` take patterned cloth.
pub(crate) fn refuse_pattern(file: &SceneFile, command: &str) -> Result<()> {
    anyhow::ensure!(
        file.pattern.is_none(),
        "{}: [pattern]: {command} cannot take patterned cloth: it works on one exemplar; \
         render it with `twill render` or `twill reference`, or remove [pattern] to use [fabric]'s weave alone",
        file.path.display()
    );
    Ok(())
}

/// Refuses a scene with a `[mesh]` for a command that paints the flat swatch's threads (paint
/// cells run along the flat exemplar's yarns): it would show the flat swatch, not the cloth on
/// the mesh the viewer and `twill render` draw.
pub(crate) fn refuse_mesh(file: &SceneFile, command: &str) -> Result<()> {
    anyhow::ensure!(
        file.mesh.is_flat_swatch(),
        "{}: [mesh]: {command} paints the flat swatch's threads, not the cloth on the mesh; \
         remove [mesh] to paint the flat swatch",
        file.path.display()
    );
    Ok(())
}

/// Options of `twill reference` (command-line overrides of the scene's settings).
pub struct ReferenceOptions {
    pub image: ImageOptions,
    pub max_depth: Option<u32>,
    pub only: Option<Component>,
    pub seed: Option<u64>,
    /// A painting to paint the cloth with first.
    pub painting: Option<PathBuf>,
}

pub fn reference(options: &ReferenceOptions) -> Result<()> {
    let mut file = options.image.load_scene()?;
    let render = &mut file.render;
    render.max_depth = options.max_depth.unwrap_or(render.max_depth);
    render.seed = options.seed.unwrap_or(render.seed);
    let mut scene = file.build()?;
    if let Some(path) = &options.painting {
        refuse_mesh(&file, &format!("`twill reference --painting {}`", path.display()))?;
        let cells = crate::paint::scene_cells(&scene, &file.path)?;
        let own = twill_precompute::paint::scene_colours(&scene.path_scene, &cells);
        let colours = Painting::load(path)?.colours(&cells, &own, path)?;
        crate::paint::paint_scene(&mut scene, cells, &colours, path)?;
    }
    let started = Instant::now();
    if twill_renderer::headless::trace_on_mesh(&mut scene)? {
        eprintln!(
            "the fabric on the mesh: {} fiber segments, shell-mapped ({:.1} s)",
            scene.path_scene.fibers.segments().len(),
            started.elapsed().as_secs_f64()
        );
    }
    let camera = file.camera(file.render.width, file.render.height)?;
    let settings = file.render_settings(options.only);

    let started = Instant::now();

    let bar = rows_bar(
        camera.height(),
        format!("path tracing {}x{} at {} spp", camera.width(), camera.height(), settings.spp),
    );
    let film =
        pathtrace::render(&scene.path_scene, &camera, &settings, &|rows| bar.set_position(rows as u64));
    bar.finish_and_clear();
    let render_s = started.elapsed().as_secs_f64();

    let image = film.mean();
    let variance = film.variance_of_mean();
    let display = Display { exposure: file.render.exposure, ..Display::default() };
    write_image(&options.image.output, &image, display)?;
    let mean = image.mean();
    let noise = (variance.pixels.iter().map(|v| v.element_sum() / 3.0).sum::<f64>()
        / variance.pixels.len() as f64)
        .sqrt();
    eprintln!(
        "wrote {} ({}x{}, {} spp, {:?}): mean radiance [{:.4}, {:.4}, {:.4}], per-pixel noise (std. error) {:.4}; \
         path tracing {:.2} s",
        options.image.output.display(),
        camera.width(),
        camera.height(),
        settings.spp,
        settings.component,
        mean.x,
        mean.y,
        mean.z,
        noise,
        render_s
    );
    Ok(())
}

/// A progress bar over image rows.
pub(crate) fn rows_bar(rows: usize, message: String) -> ProgressBar {
    let bar = ProgressBar::new(rows as u64).with_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} rows, {elapsed} elapsed, eta {eta}")
            .expect("the progress template is valid"),
    );
    bar.set_message(message);
    bar
}

/// Options of `twill render`.
#[allow(clippy::struct_excessive_bools)]
pub struct RenderOptions {
    pub image: ImageOptions,
    pub quality: Quality,
    pub bake: Option<PathBuf>,
    pub cache: Option<PathBuf>,
    pub no_cache: bool,
    pub only: Option<Components>,
    pub print_plan: bool,
    pub timings: bool,
}

/// The stage cache: `explicit`, else the default folder ([`default_cache_dir`]); none with
/// `no_cache`. The viewer bakes through it too.
pub(crate) fn open_cache(explicit: Option<&Path>, no_cache: bool) -> Result<Option<Cache>> {
    if no_cache {
        return Ok(None);
    }
    match explicit.map(Path::to_path_buf).or_else(default_cache_dir) {
        Some(dir) => Ok(Some(Cache::with_limit(&dir, cache_limit_bytes()?)?)),
        None => Ok(None),
    }
}

/// The stage cache's size limit: `$TWILL_CACHE_MAX_MB` megabytes (1 to 1,000,000,000), else
/// [`DEFAULT_CACHE_LIMIT_BYTES`].
pub(crate) fn cache_limit_bytes() -> Result<u64> {
    let Some(value) = std::env::var_os("TWILL_CACHE_MAX_MB").filter(|v| !v.is_empty()) else {
        return Ok(DEFAULT_CACHE_LIMIT_BYTES);
    };
    let text = value.to_string_lossy();
    match text.trim().parse::<u64>() {
        Ok(mb @ 1..=1_000_000_000) => Ok(mb << 20),
        _ => bail!("TWILL_CACHE_MAX_MB = {text:?}: expected whole megabytes in 1..=1000000000"),
    }
}

pub fn render(options: &RenderOptions) -> Result<()> {
    let file = options.image.load_scene()?;
    let scene = file.build()?;
    let settings = frame_settings(&scene, options.only.unwrap_or_default());

    let started = Instant::now();
    let (exemplars, pattern) = if let Some(path) = &options.bake {
        let loaded = read_bake(path)?;
        let exemplars: Vec<_> = scene.exemplars().iter().collect();
        loaded.check_made_for(path, &exemplars)?;
        (loaded.exemplars, loaded.pattern)
    } else {
        let cache = open_cache(options.cache.as_deref(), options.no_cache)?;
        bake_scene(&scene, options.quality.settings(), cache.as_ref())?
    };
    let bake_seconds = started.elapsed().as_secs_f64();
    let refs: Vec<&Baked> = exemplars.iter().collect();
    let mut session = SceneRenderer::new(&scene, &refs, &pattern)?;
    let plan = session.renderer.plan(&scene.path_scene.lights, &settings);
    if options.print_plan {
        print!("{plan}");
    }
    let started = Instant::now();
    let frame = session.render(&scene, &settings)?;
    let render_seconds = started.elapsed().as_secs_f64();

    let ext = options.image.output.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    if ext.as_deref() == Some("png") {
        write_display_png(&options.image.output, frame.width, frame.height, &frame.display)?;
    } else {
        let image = Image {
            width: frame.width as usize,
            height: frame.height as usize,
            pixels: frame.radiance.iter().map(|p| Vec3::from(*p).as_dvec3()).collect(),
        };
        write_image(
            &options.image.output,
            &image,
            Display { exposure: scene.render.exposure, ..Display::default() },
        )?;
    }
    eprintln!(
        "rendered {} on {} ({}x{}, {} spp) in {:.2} s (bake {:.2} s) -> {}",
        file.path.display(),
        session.renderer.adapter(),
        frame.width,
        frame.height,
        settings.spp,
        render_seconds,
        bake_seconds,
        options.image.output.display()
    );
    if options.timings {
        match &frame.timings {
            Some(timings) => print!("GPU time per pass:\n{}", describe_timings(timings)),
            None => println!("GPU time per pass: the adapter has no timestamp queries"),
        }
        let fabric = &session.renderer.fabric().arrays;
        println!(
            "GPU memory: {:.1} MB resident (bake and shell; IIRTF stored as f16, largest relative rounding {:.1e})",
            session.renderer.resident_bytes() as f64 / 1e6,
            fabric.iirtf_f16_max_rel_error
        );
    }
    Ok(())
}

/// Options of `twill bake`.
pub struct BakeOptions {
    pub scene: Option<PathBuf>,
    pub quality: Quality,
    pub output: Option<PathBuf>,
    pub cache: Option<PathBuf>,
    pub no_cache: bool,
    pub overrides: Vec<String>,
    /// Print the stage cache's folder, entries, size and limit instead of baking.
    pub cache_info: bool,
    /// Empty the stage cache instead of baking.
    pub cache_clear: bool,
}

/// Applies `KNOB=VALUE` overrides to bake settings (through their TOML form, so unknown knobs
/// and wrong types are rejected with the parser's message) and validates the result.
pub(crate) fn apply_overrides(settings: BakeSettings, overrides: &[String]) -> Result<BakeSettings> {
    if overrides.is_empty() {
        return Ok(settings);
    }
    let mut text = toml::to_string(&settings).context("bake settings serialize")?;
    let mut table: toml::Table = text.parse().context("bake settings parse")?;
    for item in overrides {
        let (knob, value) = item
            .split_once('=')
            .with_context(|| format!("--set {item:?}: expected KNOB=VALUE, e.g. iirtf_paths_per_cell=500"))?;
        let value: toml::Value = format!("v = {}", value.trim())
            .parse::<toml::Table>()
            .ok()
            .and_then(|mut t| t.remove("v"))
            .with_context(|| format!("--set {item:?}: {value:?} is not a number or boolean"))?;
        table.insert(knob.trim().to_owned(), value);
    }
    text = toml::to_string(&table).context("bake settings serialize")?;
    let settings: BakeSettings =
        toml::from_str(&text).map_err(|e| anyhow::anyhow!("--set: {}", e.message()))?;
    settings.validate()?;
    Ok(settings)
}

/// The stage cache folder: `$TWILL_CACHE_DIR`, else `$XDG_CACHE_HOME/twill`, else `~/.cache/twill`.
pub(crate) fn default_cache_dir() -> Option<PathBuf> {
    let var = |name| std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from);
    var("TWILL_CACHE_DIR")
        .or_else(|| var("XDG_CACHE_HOME").map(|d| d.join("twill")))
        .or_else(|| var("HOME").map(|d| d.join(".cache").join("twill")))
}

/// The name `twill bake` writes by default: `SCENE-STEM.QUALITY.twillbake` in the current
/// folder (`default` for the built-in scene).
pub(crate) fn default_bake_path(scene: Option<&Path>, quality: Quality) -> PathBuf {
    PathBuf::from(format!("{}.{}.twillbake", scene_stem(scene), quality.name()))
}

/// The scene file's name without its extension, `default` for the built-in scene.
pub(crate) fn scene_stem(scene: Option<&Path>) -> String {
    scene.and_then(Path::file_stem).map_or_else(|| "default".to_owned(), |s| s.to_string_lossy().into_owned())
}

/// A progress bar of a bake's stages: it restarts with each stage and shows its name.
pub(crate) struct StageBar {
    bar: ProgressBar,
    current: std::sync::Mutex<Option<Stage>>,
}

impl StageBar {
    pub(crate) fn new() -> Self {
        let bar = ProgressBar::new(1000).with_style(
            ProgressStyle::with_template("{msg:>16} [{bar:40}] {percent:>3}%, {elapsed} elapsed, eta {eta}")
                .expect("the progress template is valid"),
        );
        Self { bar, current: std::sync::Mutex::new(None) }
    }

    /// `stage` is `fraction` done.
    pub(crate) fn update(&self, stage: Stage, fraction: f64) {
        let mut current = self.current.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if *current != Some(stage) {
            *current = Some(stage);
            self.bar.reset();
            self.bar.set_message(stage.name());
        }
        self.bar.set_position((fraction.clamp(0.0, 1.0) * 1000.0) as u64);
    }

    pub(crate) fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

pub fn bake(options: &BakeOptions) -> Result<()> {
    if options.cache_info || options.cache_clear {
        let Some(cache) = open_cache(options.cache.as_deref(), false)? else {
            bail!("no stage cache folder: give --cache DIR or set TWILL_CACHE_DIR or HOME");
        };
        if options.cache_clear {
            let removed = cache.clear()?;
            eprintln!("{}: deleted {removed} cache entries", cache.dir().display());
        }
        let info = cache.info();
        println!(
            "{}: {} entries, {:.1} MB of {:.0} MB (least recently used entries go first; TWILL_CACHE_MAX_MB sets the limit)",
            cache.dir().display(),
            info.entries,
            info.bytes as f64 / f64::from(1 << 20),
            info.limit_bytes as f64 / f64::from(1 << 20),
        );
        return Ok(());
    }
    let file = SceneFile::load_or_default(options.scene.as_deref())?;
    let scene = file.build()?;
    let settings = apply_overrides(options.quality.settings(), &options.overrides)?;
    let output = options
        .output
        .clone()
        .unwrap_or_else(|| default_bake_path(options.scene.as_deref(), options.quality));
    let cache = open_cache(options.cache.as_deref(), options.no_cache)?;

    let bar = StageBar::new();
    let progress = |stage: Stage, fraction: f64| bar.update(stage, fraction);
    let inputs = scene.bake_inputs(settings);
    let started = Instant::now();
    let set = bake_set(&inputs, scene.pattern_map(), cache.as_ref(), &Cancel::new(), &progress);
    bar.finish();
    let set = set.map_err(|e| anyhow::anyhow!("bake failed: {e}"))?;
    write_bake(&output, &set)?;

    let segments: usize = scene.exemplars().iter().map(Exemplar::segment_count).sum();
    let exemplars = match set.exemplars.len() {
        1 => String::new(),
        n => format!("{n} exemplars, "),
    };
    eprintln!(
        "baked {} ({} quality, {exemplars}{segments} segments) in {:.2} s -> {} ({:.1} MB)",
        file.path.display(),
        options.quality.name(),
        started.elapsed().as_secs_f64(),
        output.display(),
        std::fs::metadata(&output).map_or(0.0, |m| m.len() as f64 / 1e6)
    );
    for (k, outcome) in set.exemplars.iter().enumerate() {
        if set.exemplars.len() > 1 {
            eprintln!("exemplar {k} ({} segments):", inputs[k].exemplar.segment_count());
        }
        report_bake(outcome);
    }
    Ok(())
}

/// Prints one exemplar's stages and the bake's key numbers.
fn report_bake(outcome: &BakeOutcome) {
    let b = &outcome.baked;
    for run in &outcome.stages {
        let how = match run.source {
            StageSource::Cached => "cached",
            StageSource::Computed => "computed",
            StageSource::Kept => "kept from the previous bake",
            StageSource::Recoloured => "recoloured from the basis",
        };
        eprintln!("  {:<16} {how:<8} {:>8.2} s", run.stage.name(), run.seconds);
    }
    let pca = &b.visibility.ssdf.stats;
    let noise = b.transfer.iirtf.noise();
    eprintln!(
        "  mean free path {:.5} cm; {} IIRTF cells ({} with segments), rms entry {:.3e} +- {:.3e}",
        b.mean_free_path.mean_cm,
        b.transfer.cells.cell_count(),
        b.transfer.iirtf.cells.iter().filter(|c| c.paths > 0).count(),
        noise.rms_entry,
        noise.rms_std_error
    );
    eprintln!(
        "  SSDF PCA: {} components explain {:.1}% of the variance, rms error {:.4} rad, sign agreement {:.2}%",
        b.visibility.ssdf.component_count,
        100.0 * pca.explained_variance,
        pca.rms_error,
        100.0 * pca.sign_agreement
    );
}

/// Bakes every exemplar of `scene` (one, or a patterned cloth's) with `settings` through
/// `cache` (no progress bar); returns them in pattern order with the pattern map.
pub(crate) fn bake_scene(
    scene: &twill_precompute::scene::Scene,
    settings: BakeSettings,
    cache: Option<&Cache>,
) -> Result<(Vec<Baked>, PatternMap)> {
    let inputs = scene.bake_inputs(settings);
    let set = bake_set(&inputs, scene.pattern_map(), cache, &Cancel::new(), &|_, _| {})
        .map_err(|e| anyhow::anyhow!("bake failed: {e}"))?;
    Ok((set.exemplars.into_iter().map(|o| o.baked).collect(), set.pattern))
}

/// `twill bench passes`: GPU time per pass, the median of `frames` frames after a warm-up.
pub fn bench_passes(
    scene: Option<&Path>,
    (width, height): (usize, usize),
    spp: u32,
    quality: Quality,
    frames: usize,
) -> Result<()> {
    anyhow::ensure!(frames >= 1, "--frames must be at least 1");
    let file = SceneFile::load_or_default(scene)?;
    let scene = file.build()?;
    let started = Instant::now();
    let (exemplars, pattern) = bake_scene(&scene, quality.settings(), open_cache(None, false)?.as_ref())?;
    let bake_seconds = started.elapsed().as_secs_f64();
    let baked: Vec<&Baked> = exemplars.iter().collect();
    let mut session = SceneRenderer::new(&scene, &baked, &pattern)?;
    let mut settings = frame_settings(&scene, Components::All);
    (settings.width, settings.height, settings.spp) = (width as u32, height as u32, spp);
    let plan = session.renderer.plan(&scene.path_scene.lights, &settings);
    session.render(&scene, &settings)?;
    let mut per_pass: Vec<(String, Vec<f64>)> = Vec::new();
    let mut wall = Vec::with_capacity(frames);
    for _ in 0..frames {
        let started = Instant::now();
        let frame = session.render(&scene, &settings)?;
        wall.push(started.elapsed().as_secs_f64() * 1e3);
        let timings = frame.timings.context("the adapter has no timestamp queries: no per-pass times")?;
        for t in timings {
            match per_pass.iter_mut().find(|(name, _)| *name == t.pass) {
                Some((_, v)) => v.push(t.milliseconds),
                None => per_pass.push((t.pass.clone(), vec![t.milliseconds])),
            }
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    println!(
        "{} on {}: {width}x{height}, {spp} spp, {quality:?} bake ({bake_seconds:.1} s), median of {frames} frames",
        file.path.display(),
        session.renderer.adapter(),
    );
    print!("{plan}");
    println!("| pass | ms (median) |\n|---|---|");
    let mut total = 0.0;
    for (name, v) in &mut per_pass {
        let m = median(v);
        total += m;
        println!("| {name} | {m:.1} |");
    }
    println!(
        "| total (GPU) | {total:.1} |\n| wall time per frame (submit to readback) | {:.1} |",
        median(&mut wall)
    );
    println!("GPU memory: {:.1} MB resident", session.renderer.resident_bytes() as f64 / 1e6);
    Ok(())
}

/// `twill bench accuracy`: the Fig. 13 experiment on a flat swatch of the scene's fabric.
pub fn bench_accuracy(
    scene: Option<&Path>,
    quality: Quality,
    settings: &twill_renderer::accuracy::ExperimentSettings,
) -> Result<()> {
    let mut file = SceneFile::load_or_default(scene)?;
    refuse_pattern(&file, "`twill bench accuracy` (against path-traced references)")?;
    // A flat swatch over a black ground, large enough for grazing views of a 0.4 cm film.
    file.mesh = twill_precompute::scene::MeshSection::default();
    file.swatch.size_cm = [2.0, 2.0];
    file.swatch.ground = true;
    let mut scene = file.build()?;
    let started = Instant::now();
    // One exemplar: patterned scenes were refused above.
    let (mut exemplars, _) = bake_scene(&scene, quality.settings(), open_cache(None, false)?.as_ref())?;
    let baked = exemplars.swap_remove(0);
    let bake_seconds = started.elapsed().as_secs_f64();
    let gpu = twill_renderer::gpu::Gpu::headless()?;
    let adapter = gpu.describe();
    let bar = ProgressBar::new(settings.configurations as u64).with_style(
        ProgressStyle::with_template("configurations [{bar:40}] {pos}/{len}, {elapsed} elapsed, eta {eta}")
            .expect("the progress template is valid"),
    );
    let report = twill_renderer::accuracy::run(&mut scene, &baked, gpu, settings, &|done, _| {
        bar.set_position(done as u64);
    })?;
    bar.finish_and_clear();
    println!(
        "{}, {quality:?} bake ({bake_seconds:.1} s, not counted in the speed-ups), on {adapter}",
        file.path.display()
    );
    print!("{}", report.markdown());
    Ok(())
}

/// `twill accuracy budget`: the method's error budget on a flat swatch of the scene's fabric,
/// seen by the scene's camera under its lights (`shading::budget`). A scene with a `[mesh]`
/// adds the GPU renderer's frames of the curved cloth at three shadow-map sizes, against the
/// path tracer on the same cloth (`headless::trace_on_mesh`): what global visibility (shadow
/// maps with PCF, PCSS for SG lights) and the curved shell cost.
pub fn accuracy_budget(
    scene: Option<&Path>,
    quality: Quality,
    overrides: &[String],
    size: (usize, usize),
    settings: &twill_precompute::shading::budget::BudgetSettings,
) -> Result<()> {
    let mut file = SceneFile::load_or_default(scene)?;
    refuse_pattern(&file, "`twill accuracy budget` (against path-traced references)")?;
    (file.render.width, file.render.height) = size;
    let curved = file.mesh.names_a_surface().then(|| file.clone());
    file.mesh = twill_precompute::scene::MeshSection::default();
    let scene = file.build()?;
    let bake_settings = apply_overrides(quality.settings(), overrides)?;
    let started = Instant::now();
    // One exemplar: patterned scenes were refused above.
    let (mut exemplars, _) = bake_scene(&scene, bake_settings, None)?;
    let baked = exemplars.swap_remove(0);
    let bake_seconds = started.elapsed().as_secs_f64();
    let mut budget = twill_precompute::shading::budget::error_budget(&scene, &baked, settings, &|rung| {
        eprintln!("  done: {rung}");
    })?;
    // The GPU renderer's frames, one per component: primary visibility from the voxel volume.
    match twill_renderer::gpu::Gpu::headless() {
        Ok(gpu) => {
            let mut session = SceneRenderer::with_gpu(gpu, &scene, &[&baked], &PatternMap::uniform(0))?;
            for (components, component) in
                [(Components::SingleOnly, Component::Single), (Components::MultipleOnly, Component::Multiple)]
            {
                let mut frame_options = frame_settings(&scene, components);
                (frame_options.width, frame_options.height) = (size.0 as u32, size.1 as u32);
                frame_options.spp = settings.spp;
                // One untimed frame compiles this plan's shaders.
                session.render(&scene, &frame_options)?;
                let started = Instant::now();
                let frame = session.render(&scene, &frame_options)?;
                let seconds = started.elapsed().as_secs_f64();
                let name = "GPU renderer: voxel-volume eye rays".to_owned();
                budget.add_rung(component, name, &frame.radiance_image(), seconds);
            }
            if let Some(curved) = &curved {
                session = budget_on_mesh(session, curved, &baked, size, settings, &mut budget)?;
            }
            drop(session);
        }
        Err(e) => eprintln!("no GPU rung: {e}"),
    }
    println!(
        "{}: error budget, {} bake ({bake_seconds:.1} s, no cache)\n",
        file.path.display(),
        quality.name()
    );
    print!("{}", budget.markdown());
    Ok(())
}

/// The budget's rungs on the curved cloth of `file` (its `[mesh]`): path-traced references of
/// single and multiple scattering on the mesh, then the GPU renderer's frame of each at shadow
/// maps of 512, the scene's size and 8192 texels a side.
fn budget_on_mesh(
    session: SceneRenderer,
    file: &SceneFile,
    baked: &twill_precompute::bake::pipeline::Baked,
    size: (usize, usize),
    settings: &twill_precompute::shading::budget::BudgetSettings,
    budget: &mut twill_precompute::shading::budget::Budget,
) -> Result<SceneRenderer> {
    let mut scene = file.build()?;
    twill_renderer::headless::trace_on_mesh(&mut scene)?;
    let camera = file.camera(size.0, size.1)?;
    let mesh = file.mesh.builtin.clone().or_else(|| file.mesh.path.as_ref().map(|p| p.display().to_string()));
    let mesh = mesh.unwrap_or_default();
    let references = [Component::Single, Component::Multiple].map(|component| {
        let started = Instant::now();
        let reference_settings = pathtrace::RenderSettings {
            spp: settings.reference_spp,
            max_depth: file.render.max_depth,
            component,
            seed: settings.seed,
        };
        let film = pathtrace::render(&scene.path_scene, &camera, &reference_settings, &|_| {});
        eprintln!(
            "  done: path-traced {component:?} reference on the mesh ({:.1} s)",
            started.elapsed().as_secs_f64()
        );
        film
    });
    let mut session = SceneRenderer::with_gpu(session.gpu, &scene, &[baked], &PatternMap::uniform(0))?;
    let own_size = scene.gpu.shadow_map_size;
    for shadow_map_size in [512, own_size, 8192] {
        for ((components, component), reference) in
            [(Components::SingleOnly, Component::Single), (Components::MultipleOnly, Component::Multiple)]
                .into_iter()
                .zip(&references)
        {
            let mut frame_options = frame_settings(&scene, components);
            (frame_options.width, frame_options.height) = (size.0 as u32, size.1 as u32);
            frame_options.spp = settings.spp;
            frame_options.gpu.shadow_map_size = shadow_map_size;
            session.render(&scene, &frame_options)?;
            let started = Instant::now();
            let frame = session.render(&scene, &frame_options)?;
            let seconds = started.elapsed().as_secs_f64();
            let name = format!(
                "GPU renderer on the mesh ({mesh}), shadow maps {shadow_map_size}² (PCF; PCSS for SG lights), \
                 against the path tracer on the mesh"
            );
            budget.add_rung_against(component, name, &frame.radiance_image(), reference, seconds);
        }
    }
    Ok(session)
}

/// The colours `twill bench recolor` tries: `count` recolourings of every yarn material of the
/// scene (the warp and weft, or each palette colour), C_TT drawn per channel; the first is
/// near-black (0.01..0.03) and the second near-white (0.90..0.95), the rest uniform in
/// 0.02..0.95. Deterministic for a seed.
fn random_recolourings(base: &SceneFile, count: usize, seed: u64) -> Vec<SceneFile> {
    use rand::{Rng, SeedableRng};
    use twill_precompute::Rgb;
    use twill_precompute::bcsdf::{FiberParams, MaterialDesc};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    (0..count)
        .map(|k| {
            let (lo, hi) = match k {
                0 => (0.01, 0.03),
                1 => (0.90, 0.95),
                _ => (0.02, 0.95),
            };
            let mut draw = || Rgb::from_array([(); 3].map(|()| rng.random_range(lo..=hi)));
            let mut file = base.clone();
            if file.materials.palette.is_empty() {
                let slots = file.material_slots();
                let recolour = |m: Option<MaterialDesc>, c_tt: Rgb| match m {
                    Some(MaterialDesc::Fiber(p)) => Some(MaterialDesc::Fiber(FiberParams { c_tt, ..p })),
                    Some(MaterialDesc::Lambert { .. }) => Some(MaterialDesc::Lambert { albedo: c_tt }),
                    None => None,
                };
                file.materials.warp = recolour(slots[0], draw());
                file.materials.weft = recolour(slots[1], draw());
            } else {
                for colour in file.materials.palette.values_mut() {
                    colour.c_tt = Some(draw());
                }
            }
            file
        })
        .collect()
}

/// `twill bench recolor`: the time from a colour edit to its full picture at `quality`, over
/// random recolourings (near-black and near-white included) of the scene's yarns, on both
/// paths, and the live path's error against the rebake:
/// - **live**: the IIRTF and C_S tables evaluated from the recolouring basis
///   (`bake::recolour`) and written into the GPU fabric in place
///   (`Renderer::recolour`), then one frame of `spp`;
/// - **rebake**: the material stages rebake through the stage cache (the geometry stages are
///   cached), the bake is written in place, one frame.
///
/// The error of the live picture against the rebake's is the relative difference of the image
/// mean (the largest over channels) and the per-pixel RMS difference over the rebake's mean.
/// Beside it, the same per-pixel figure between two rebakes that differ only in their seed:
/// how much the method's own picture moves with its Monte Carlo precomputation.
pub fn bench_recolor(
    scene: Option<&Path>,
    (width, height): (usize, usize),
    spp: u32,
    quality: Quality,
    run: &RecolorRun,
) -> Result<()> {
    use twill_precompute::bake::pipeline::{bake_material_preview, recolour_basis};
    let RecolorRun { count, seed, iirtf_paths, ref images, same_paths } = *run;
    if let Some(dir) = images {
        std::fs::create_dir_all(dir).with_context(|| format!("--images {}", dir.display()))?;
    }
    anyhow::ensure!((1..=1000).contains(&count), "--colourways {count}: expected 1..=1000");
    let base = SceneFile::load_or_default(scene)?;
    let cache = open_cache(None, false)?;
    let scene0 = base.build()?;
    let mut settings0 = quality.settings();
    if let Some(paths) = iirtf_paths {
        settings0.iirtf_paths_per_cell = paths;
        settings0.validate()?;
    }
    let started = Instant::now();
    let (base_exemplars, pattern) = bake_scene(&scene0, settings0, cache.as_ref())?;
    let warm_bake = started.elapsed().as_secs_f64();
    let started = Instant::now();
    let bases = scene0
        .bake_inputs(settings0)
        .iter()
        .map(|inputs| recolour_basis(inputs, cache.as_ref(), &Cancel::new(), &|_| {}))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow::anyhow!("recolouring basis: {e}"))?;
    let basis_seconds = started.elapsed().as_secs_f64();
    let (basis_bytes, mean_rank) = bases
        .iter()
        .map(twill_precompute::bake::recolour::RecolourBasis::size)
        .fold((0, 0.0_f64), |(b, r), (b1, r1)| (b + b1, r.max(r1)));
    let refs: Vec<&Baked> = base_exemplars.iter().collect();
    let mut session = SceneRenderer::new(&scene0, &refs, &pattern)?;
    let mut settings = frame_settings(&scene0, Components::All);
    (settings.width, settings.height, settings.spp) = (width as u32, height as u32, spp);
    session.render(&scene0, &settings)?;
    println!(
        "{} on {}: {quality:?} bake ({} IIRTF paths per cell; first, filling the stage cache: {warm_bake:.1} s), recolouring basis {basis_seconds:.1} s \
         (from the cache if it held it; {:.0} MB, {mean_rank:.1} curves per class), {width}x{height}, {spp} spp",
        base.path.display(),
        session.renderer.adapter(),
        settings0.iirtf_paths_per_cell,
        basis_bytes as f64 / 1e6
    );
    println!(
        "| colourway | live: materials ms | live: evaluate + write ms | live: frame ms | live: edit to picture ms | viewer preview: edit to picture ms \
         | rebake: material stages ms \
         | rebake: upload ms | rebake: edit to picture ms | live vs rebake: image mean | live vs rebake: per-pixel RMS \
         | rebake vs rebake (seed): image mean | rebake vs rebake (seed): per-pixel RMS |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let reseeded = BakeSettings { seed: settings0.seed.wrapping_add(1), ..settings0 };
    let mut floor_session: Option<SceneRenderer> = None;
    let (mut same_lines, mut worst_own_mean, mut worst_own_rms) = (Vec::new(), 0.0_f64, 0.0_f64);
    let mut worst_floor_mean = 0.0_f64;
    let (mut live_totals, mut rebake_totals, mut worst_mean, mut worst_excess) =
        (Vec::with_capacity(count), Vec::with_capacity(count), 0.0_f64, f64::NEG_INFINITY);
    for (k, file) in random_recolourings(&base, count, seed).iter().enumerate() {
        // Live: the basis evaluated at the new colours.
        // Live: the materials of the edited scene file (no fabric to build: a colour edit moves
        // no fibre), the basis evaluated at them and written in place, one frame.
        let t0 = Instant::now();
        let materials = file.material_descs()?;
        let t_build = t0.elapsed().as_secs_f64();
        for (e, basis) in bases.iter().enumerate() {
            session.renderer.recolour(e, basis, &materials)?;
        }
        let t_write = t0.elapsed().as_secs_f64();
        // The camera and lights are the base scene's: a colour edit changes neither.
        let live_frame = session.render(&scene0, &settings)?;
        let t_live = t0.elapsed().as_secs_f64();
        let live = live_frame.radiance_image();
        let scene = file.build()?;
        live_totals.push(t_live * 1e3);
        // The viewer's path: the material preview evaluated from the basis, packed and written
        // in place as a whole bake, one frame.
        let t0 = Instant::now();
        let previews = scene
            .bake_inputs(settings0)
            .iter()
            .zip(&base_exemplars)
            .zip(&bases)
            .map(|((inputs, previous), basis)| {
                bake_material_preview(
                    inputs,
                    previous,
                    Some(basis),
                    cache.as_ref(),
                    &Cancel::new(),
                    &|_, _| {},
                )
                .map(|o| o.baked)
            })
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| anyhow::anyhow!("material preview: {e}"))?;
        let refs: Vec<&Baked> = previews.iter().collect();
        (session, _) = upload_to(Some(session), &scene, &refs, &pattern)?;
        session.render(&scene, &settings)?;
        let t_viewer = t0.elapsed().as_secs_f64();
        // The basis's own paths at these colours, exactly: what the live picture approximates.
        let same = if same_paths {
            let exact = scene
                .bake_inputs(settings0)
                .iter()
                .zip(previews)
                .map(|(inputs, preview)| same_paths_bake(inputs, preview))
                .collect::<Result<Vec<_>>>()?;
            let refs: Vec<&Baked> = exact.iter().collect();
            (session, _) = upload_to(Some(session), &scene, &refs, &pattern)?;
            Some(session.render(&scene, &settings)?.radiance_image())
        } else {
            None
        };
        // Rebake.
        let t0 = Instant::now();
        let (exemplars, pattern) = bake_scene(&scene, settings0, cache.as_ref())?;
        let t_bake = t0.elapsed().as_secs_f64();
        let refs: Vec<&Baked> = exemplars.iter().collect();
        (session, _) = upload_to(Some(session), &scene, &refs, &pattern)?;
        let t_upload = t0.elapsed().as_secs_f64();
        let rebaked_frame = session.render(&scene, &settings)?;
        let t_rebake = t0.elapsed().as_secs_f64();
        let rebaked = rebaked_frame.radiance_image();
        if let Some(dir) = images {
            for (frame, what) in [(&live_frame, "live"), (&rebaked_frame, "rebake")] {
                let path = dir.join(format!("{:02}-{what}.png", k + 1));
                write_display_png(&path, frame.width, frame.height, &frame.display)?;
            }
        }
        rebake_totals.push(t_rebake * 1e3);
        // The same colours baked with another seed: the method's own per-pixel noise. Its own
        // renderer on the same device (another seed measures another mean free path, so another
        // cell grid, which the basis does not fit).
        let (exemplars, pattern) = bake_scene(&scene, reseeded, cache.as_ref())?;
        let refs: Vec<&Baked> = exemplars.iter().collect();
        let mut floor = if let Some(floor) = floor_session.take() {
            upload_to(Some(floor), &scene, &refs, &pattern)?.0
        } else {
            let g = &session.gpu;
            let gpu = twill_renderer::gpu::Gpu {
                adapter_info: g.adapter_info.clone(),
                device: g.device.clone(),
                queue: g.queue.clone(),
            };
            SceneRenderer::with_gpu(gpu, &scene, &refs, &pattern)?
        };
        let reseeded_image = floor.render(&scene, &settings)?.radiance_image();
        floor_session = Some(floor);
        if let Some(same) = &same {
            let (own, estimators) = (image_mean_error(&live, same), image_mean_error(same, &rebaked));
            worst_own_mean = worst_own_mean.max(own.abs());
            worst_own_rms = worst_own_rms.max(per_pixel_rms(&live, same));
            same_lines.push(format!(
                "| {} | {:+.2}% | {:.2}% | {:+.2}% |",
                k + 1,
                100.0 * own,
                100.0 * per_pixel_rms(&live, same),
                100.0 * estimators
            ));
        }
        let (mean_error, floor_mean) =
            (image_mean_error(&live, &rebaked), image_mean_error(&reseeded_image, &rebaked));
        let (live_rms, floor_rms) =
            (per_pixel_rms(&live, &rebaked), per_pixel_rms(&reseeded_image, &rebaked));
        worst_mean = worst_mean.max(mean_error.abs());
        worst_floor_mean = worst_floor_mean.max(floor_mean.abs());
        worst_excess = worst_excess.max(live_rms - floor_rms);
        println!(
            "| {} | {:.1} | {:.1} | {:.1} | {:.0} | {:.0} | {:.0} | {:.1} | {:.0} | {:+.2}% | {:.2}% | {:+.2}% | {:.2}% |",
            k + 1,
            t_build * 1e3,
            (t_write - t_build) * 1e3,
            (t_live - t_write) * 1e3,
            t_live * 1e3,
            t_viewer * 1e3,
            t_bake * 1e3,
            (t_upload - t_bake) * 1e3,
            t_rebake * 1e3,
            100.0 * mean_error,
            100.0 * live_rms,
            100.0 * floor_mean,
            100.0 * floor_rms
        );
    }
    let median_and_max = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[v.len() / 2], v[v.len() - 1])
    };
    let (live_median, live_max) = median_and_max(&mut live_totals);
    let (rebake_median, rebake_max) = median_and_max(&mut rebake_totals);
    println!(
        "edit to picture: live median {live_median:.0} ms, max {live_max:.0} ms; rebake median {rebake_median:.0} ms, \
         max {rebake_max:.0} ms, over {count} colourways (target 100 ms)"
    );
    println!(
        "live against the rebake: worst image-mean error {:.2}% (target 2%; two rebakes differing in their seed: \
         {:.2}%); per-pixel RMS at most {:+.2} points above the rebake's own seed-to-seed difference",
        100.0 * worst_mean,
        100.0 * worst_floor_mean,
        100.0 * worst_excess
    );
    if same_paths {
        println!(
            "\n| colourway | live vs the same paths at C_R's first order: image mean | per-pixel RMS | the same paths \
             vs the rebake (C_R's first order against exact): image mean |"
        );
        println!("|---|---|---|---|");
        for line in &same_lines {
            println!("{line}");
        }
        println!(
            "the basis's curves alone (live against its own paths at C_R's first order): worst image mean {:.2}% \
             (target 2%), per-pixel RMS at most {:.2}%",
            100.0 * worst_own_mean,
            100.0 * worst_own_rms
        );
    }
    Ok(())
}

/// `preview` (a material preview of `inputs`) with its IIRTF replaced by the recolouring
/// basis's own paths evaluated at `inputs`' colours, exactly in τ and to first order in C_R.
fn same_paths_bake(
    inputs: &twill_precompute::bake::pipeline::BakeInputs<'_>,
    mut preview: Baked,
) -> Result<Baked> {
    use twill_precompute::bake::recolour::{SlotColour, same_paths_iirtf};
    use twill_precompute::bcsdf::Material;
    let colours = inputs
        .materials
        .iter()
        .map(|d| Material::from_desc(d).map(|m| SlotColour::of(&m)))
        .collect::<Result<Vec<_>, _>>()?;
    preview.transfer.iirtf = same_paths_iirtf(
        inputs.exemplar,
        inputs.materials,
        &preview.transfer.cells,
        &inputs.settings,
        &colours,
        &Cancel::new(),
    )
    .map_err(|e| anyhow::anyhow!("the basis's paths at the new colours: {e}"))?;
    Ok(preview)
}

/// How many colourways `twill bench recolor` tries, their seed, and the IIRTF paths per cell
/// (`None`: the quality's).
#[derive(Debug, Clone)]
pub struct RecolorRun {
    pub count: usize,
    pub seed: u64,
    pub iirtf_paths: Option<usize>,
    /// Where to write each colourway's live and rebaked pictures (`None`: nowhere).
    pub images: Option<PathBuf>,
    /// Also compare with the basis's own paths evaluated at each colourway to first order in
    /// C_R (`twill_precompute::bake::recolour::same_paths_iirtf`).
    pub same_paths: bool,
}

/// Relative difference of the image means, the channel where it is largest (signed).
fn image_mean_error(image: &Image, reference: &Image) -> f64 {
    let (a, b) = (image.mean(), reference.mean());
    (0..3)
        .map(|ch| (a[ch] - b[ch]) / b[ch].max(1e-12))
        .fold(0.0, |m: f64, e| if e.abs() > m.abs() { e } else { m })
}

/// Per-pixel RMS difference (all channels) over the reference's mean value.
fn per_pixel_rms(image: &Image, reference: &Image) -> f64 {
    let n = (reference.pixels.len() * 3).max(1) as f64;
    let squares: f64 =
        image.pixels.iter().zip(&reference.pixels).map(|(a, b)| (*a - *b).length_squared()).sum();
    let mean = reference.pixels.iter().map(|p| p.x + p.y + p.z).sum::<f64>() / n;
    (squares / n).sqrt() / mean.max(1e-12)
}

/// `exemplars` on the GPU for `scene`: written into `session`'s fabric in place when the bake
/// has the layout it holds (another colouring of the same cloth, whose shell is the same), else
/// a new renderer on the session's device (a new device without a session). Returns whether it
/// went in place.
pub(crate) fn upload_to(
    session: Option<SceneRenderer>,
    scene: &twill_precompute::scene::Scene,
    exemplars: &[&Baked],
    pattern: &PatternMap,
) -> Result<(SceneRenderer, bool)> {
    let gpu = match session {
        Some(mut session) => {
            if session.renderer.update_fabric(exemplars, pattern)?.is_some() {
                return Ok((session, true));
            }
            session.gpu
        }
        None => twill_renderer::gpu::Gpu::headless()?,
    };
    Ok((SceneRenderer::with_gpu(gpu, scene, exemplars, pattern)?, false))
}

/// `twill bench raycast`: incoherent rays per second per core on the scene's fabric (camera and
/// scatter rays, closest and any hit; `twill_precompute::raycast::throughput`).
pub fn bench_raycast(
    scene: Option<&Path>,
    side_cm: f32,
    rays: usize,
    seconds: f64,
    embree: bool,
) -> Result<()> {
    use twill_precompute::raycast::FiberScene;
    use twill_precompute::raycast::throughput::{
        Query, camera_rays, cast, rays_per_second, scatter_rays, swatch_extent,
    };
    if embree && !cfg!(feature = "embree") {
        bail!(
            "--embree: this twill was built without Embree; build it with `cargo build --release --features embree` \
             (Debian: apt-get install libembree-dev)"
        );
    }
    if !(side_cm.is_finite() && (0.01..=1000.0).contains(&side_cm)) {
        bail!("--swatch-cm {side_cm}: must be in 0.01..=1000");
    }
    if !(1..=1 << 24).contains(&rays) {
        bail!("--rays {rays}: must be in 1..={}", 1 << 24);
    }
    if !(seconds.is_finite() && (0.01..=600.0).contains(&seconds)) {
        bail!("--seconds {seconds}: must be in 0.01..=600");
    }
    let file = SceneFile::load_or_default(scene)?;
    let built = file.build()?;
    let min_time = std::time::Duration::from_secs_f64(seconds);
    println!(
        "{}: incoherent rays per second on one core, {rays} rays per family over a {side_cm} cm swatch (best pass of {seconds} s)",
        file.path.display()
    );
    for (k, exemplar) in built.exemplars().iter().enumerate() {
        let built_at = std::time::Instant::now();
        let fibers = FiberScene::new(exemplar, swatch_extent(side_cm))
            .map_err(|e| anyhow::anyhow!("exemplar {k}: {e}"))?;
        println!(
            "exemplar {k}: {} segments, {} capsules (with the period's border copies), grid {}, built in {:.0} ms",
            exemplar.segment_count(),
            fibers.primitive_count(),
            fibers.grid_summary(),
            built_at.elapsed().as_secs_f64() * 1e3
        );
        println!("  {:<14} {:>14} {:>14} {:>8}", "rays", "closest hit", "any hit", "hit");
        for (family, set) in [
            ("camera", camera_rays(&fibers, side_cm, rays, 1)),
            ("scatter", scatter_rays(&fibers, side_cm, rays, 2)),
        ] {
            let closest = rays_per_second(&fibers, &set, Query::ClosestHit, min_time);
            let any = rays_per_second(&fibers, &set, Query::AnyHit, min_time);
            let hit = 100.0 * cast(&fibers, &set, Query::ClosestHit) as f64 / set.len() as f64;
            println!("  {family:<14} {:>11.3} M/s {:>11.3} M/s {hit:>7.1}%", closest * 1e-6, any * 1e-6);
            #[cfg(feature = "embree")]
            if embree {
                use twill_precompute::raycast::embree;
                let copies = embree::copies(&fibers);
                let variants = [
                    (embree::Layout::Instanced, embree::Batch::Single, "instanced"),
                    (embree::Layout::Instanced, embree::Batch::Packets4, "inst., 4-packets"),
                    (embree::Layout::Instanced, embree::Batch::Stream, "inst., stream"),
                    (embree::Layout::Explicit, embree::Batch::Single, "explicit"),
                ];
                for (layout, batch, name) in variants {
                    let closest =
                        embree::rays_per_second(&copies, layout, batch, &set, Query::ClosestHit, min_time);
                    let any = embree::rays_per_second(&copies, layout, batch, &set, Query::AnyHit, min_time);
                    let hits = embree::cast(&copies, layout, batch, &set, Query::ClosestHit)
                        .iter()
                        .flatten()
                        .count();
                    let hit = 100.0 * hits as f64 / set.len() as f64;
                    let label = format!("  Embree, {name}");
                    println!(
                        "  {label:<24} {:>11.3} M/s {:>11.3} M/s {hit:>7.1}%",
                        closest * 1e-6,
                        any * 1e-6
                    );
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What works on one exemplar or on the flat swatch says so, naming the file and section;
    /// the flat swatch, given as the built-in `swatch` or not at all, passes.
    #[test]
    fn one_exemplar_and_flat_swatch_commands_refuse_what_they_cannot_draw() {
        let mut file = SceneFile::default_scene();
        refuse_mesh(&file, "`twill paint`").unwrap();
        file.mesh.builtin = Some("swatch".into());
        refuse_mesh(&file, "`twill paint`").unwrap();
        file.mesh.builtin = Some("cushion".into());
        let message = refuse_mesh(&file, "`twill paint`").unwrap_err().to_string();
        assert!(message.contains("[mesh]") && message.contains("`twill paint`"), "{message}");
        let patterned = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/scenes/patterned.toml");
        let patterned = SceneFile::load(&patterned).unwrap();
        let message = refuse_pattern(&patterned, "`twill paint`").unwrap_err().to_string();
        assert!(
            message.contains("patterned.toml: [pattern]") && message.contains("twill reference"),
            "{message}"
        );
    }
}
