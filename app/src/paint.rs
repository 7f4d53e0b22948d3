//! `twill paint`: albedo painting at path-traced quality (Hašan & Ramamoorthy 2013), from the
//! command line.
//!
//! How it works: `paint precompute` loads a scene as the other commands do (plain cloth only:
//! paint cells run along one exemplar's threads), divides its swatch into paint cells (one crossing-long
//! section of one thread each, `twill_precompute::paint::PaintCells`) and traces colour-free
//! camera paths at the scene's camera and lights, keeping per pixel the homogeneous curve and
//! the sparse gradient weights (`paint::precompute`) in a checksummed paint file, written
//! atomically. `paint apply` reads that file and a painting (a TOML file of strokes, see
//! `twill_precompute::paint::Painting`), resolves the painting to one colour per cell and
//! evaluates Theorem 1 (`PaintData::evaluate`, milliseconds) into a PNG or EXR, as `twill
//! reference` writes them. `paint threads` prints how the swatch divides (which warp ends, weft
//! picks and sections a painting may name). `paint verify` is the paper's section 6 check of one
//! painting: the painted cloth path-traced twice with the standard path tracer (independent
//! seeds), the painting's relative L2 error against the first reference beside the references'
//! own (the noise floor). `paint commit` takes a painting that is a colour order (every thread one
//! colour, repeating) into the scene as its colourway (`paint::commit_colour_orders`) and writes
//! the scene atomically. `verify` and `commit` first check, in `precomputed_scene`, that the
//! scene given is the one the paint file was precomputed from. `twill reference --painting` (in
//! commands.rs) path-traces a painted cloth through [`paint_scene`].

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail, ensure};
use clap::Subcommand;
use twill_precompute::Rgb;
use twill_precompute::image::Image;
use twill_precompute::paint::{
    self, PaintCells, PaintData, PaintSettings, PaintedMaterials, Painting, SceneKeys, ThreadSet,
};
use twill_precompute::pathtrace::{self, Camera, Component, RenderSettings};
use twill_precompute::scene::{Scene, SceneFile};
use twill_renderer::export::{Display, write_image};

use crate::commands::{parse_size, refuse_mesh, refuse_pattern, rows_bar};

/// Largest image side of a paint precompute (what `PaintSettings` accepts).
const MAX_SIDE: usize = 4096;

#[derive(Debug, Subcommand)]
pub enum PaintCommand {
    /// Trace a scene's view once for painting: per pixel the homogeneous curve and the weights
    /// of every paint cell, into a paint file (minutes; then any painting takes milliseconds).
    Precompute {
        /// Scene file (default: the built-in default scene); plain cloth only.
        scene: Option<PathBuf>,
        /// Output paint file (written atomically).
        #[arg(short, long)]
        output: PathBuf,
        /// Image size as WIDTHxHEIGHT, each at most 4096 (default: the scene's).
        #[arg(long, value_parser = parse_size)]
        size: Option<(usize, usize)>,
        /// Paths per pixel for the homogeneous curves.
        #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=1_048_576))]
        spp: u32,
        /// Of those, the first this many also give the gradient weights (their storage grows
        /// with it; clamped to --spp).
        #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u32).range(1..=1_048_576))]
        gradient_spp: u32,
        /// Random seed (default: the scene's).
        #[arg(long)]
        seed: Option<u64>,
        /// Most scattering events on a path (default: the scene's).
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=10_000))]
        max_depth: Option<u32>,
    },
    /// Evaluate a painting on a paint file into an image (Theorem 1: milliseconds).
    Apply {
        /// Paint file (`twill paint precompute`).
        file: PathBuf,
        /// Painting (TOML strokes; default: the scene's own colours, as precomputed).
        #[arg(long)]
        painting: Option<PathBuf>,
        /// Output image: .exr (linear HDR) or .png (tone-mapped sRGB).
        #[arg(short, long)]
        output: PathBuf,
        /// Exposure in stops for PNG output, -30 to 30 (default: the scene's, as precomputed).
        #[arg(long, allow_hyphen_values = true, value_parser = parse_exposure)]
        exposure: Option<f64>,
    },
    /// Print how a paint file's swatch divides: the warp ends, weft picks and sections a
    /// painting may name, and the cells in all.
    Threads {
        /// Paint file (`twill paint precompute`).
        file: PathBuf,
    },
    /// Check a painting against the path tracer (Hašan & Ramamoorthy section 6): the painted
    /// cloth path-traced twice (seeds S and S+1), the painting's relative L2 error against the
    /// first beside the references' own.
    Verify {
        /// Paint file (`twill paint precompute`).
        file: PathBuf,
        /// The scene the paint file was precomputed from (default: the built-in default scene).
        scene: Option<PathBuf>,
        /// Painting (TOML strokes).
        #[arg(long)]
        painting: PathBuf,
        /// Samples per pixel of each reference.
        #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=1_048_576))]
        spp: u32,
        /// Seed of the first reference; the second takes S+1 (default: the paint file's seed
        /// plus 1, so that neither reference shares the precomputed paths' random numbers).
        #[arg(long)]
        seed: Option<u64>,
        /// Also write painted.png, reference.png and difference.png (|painted - reference| x 4)
        /// into this folder (made if missing).
        #[arg(long)]
        images: Option<PathBuf>,
    },
    /// Take a painting that is a colour order (every thread one colour along its length,
    /// repeating within 64 threads) into the scene as its palette and warp and weft orders.
    Commit {
        /// Paint file (`twill paint precompute`).
        file: PathBuf,
        /// The scene the paint file was precomputed from (default: the built-in default scene).
        scene: Option<PathBuf>,
        /// Painting (TOML strokes).
        #[arg(long)]
        painting: PathBuf,
        /// Output scene file (written atomically).
        #[arg(short, long)]
        output: PathBuf,
    },
}

/// Runs one `twill paint` command.
pub fn run(command: PaintCommand) -> Result<()> {
    match command {
        PaintCommand::Precompute { scene, output, size, spp, gradient_spp, seed, max_depth } => {
            precompute(&PrecomputeOptions { scene, output, size, spp, gradient_spp, seed, max_depth })
        }
        PaintCommand::Apply { file, painting, output, exposure } => {
            apply(&file, painting.as_deref(), &output, exposure)
        }
        PaintCommand::Threads { file } => threads(&file),
        PaintCommand::Verify { file, scene, painting, spp, seed, images } => {
            verify(&VerifyOptions { file, scene, painting, spp, seed, images })
        }
        PaintCommand::Commit { file, scene, painting, output } => {
            commit(&file, scene.as_deref(), &painting, &output)
        }
    }
}

fn parse_exposure(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if (-30.0..=30.0).contains(&v) => Ok(v),
        _ => Err(format!("{text:?} is not an exposure: expected stops from -30 to 30")),
    }
}

/// The scene's paint cells; an error names the scene file.
pub(crate) fn scene_cells(scene: &Scene, scene_path: &Path) -> Result<PaintCells> {
    PaintCells::new(&scene.exemplar, &scene.path_scene.fibers)
        .map_err(|e| anyhow!("{}: {e}", scene_path.display()))
}

/// Paints the scene's cloth for the path tracer: `colours` (one per cell of `cells`, which are
/// the scene's) from the painting at `painting_path` (named in errors).
pub(crate) fn paint_scene(
    scene: &mut Scene,
    cells: PaintCells,
    colours: &[Rgb],
    painting_path: &Path,
) -> Result<()> {
    let painted = PaintedMaterials::new(&scene.path_scene, cells, colours)
        .map_err(|e| anyhow!("{}: {e}", painting_path.display()))?;
    scene.path_scene.painted = Some(painted);
    Ok(())
}

/// Fails early (before minutes of work) when `path`'s folder does not exist.
fn check_folder_of(path: &Path) -> Result<()> {
    let folder = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    ensure!(folder.is_dir(), "{}: the folder {} does not exist", path.display(), folder.display());
    Ok(())
}

/// Fails early when `path` is not a .png or .exr file name (what `write_image` writes).
fn check_image_name(path: &Path) -> Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    ensure!(
        matches!(ext.as_deref(), Some("png" | "exr")),
        "{}: unsupported image format: expected .png (tone-mapped) or .exr (linear)",
        path.display()
    );
    check_folder_of(path)
}

fn load_painting(path: &Path, cells: &PaintCells, scene_colours: &[Rgb]) -> Result<Vec<Rgb>> {
    Ok(Painting::load(path)?.colours(cells, scene_colours, path)?)
}

fn rgb(v: Rgb) -> String {
    format!("[{:.4}, {:.4}, {:.4}]", v.x, v.y, v.z)
}

struct PrecomputeOptions {
    scene: Option<PathBuf>,
    output: PathBuf,
    size: Option<(usize, usize)>,
    spp: u32,
    gradient_spp: u32,
    seed: Option<u64>,
    max_depth: Option<u32>,
}

fn precompute(options: &PrecomputeOptions) -> Result<()> {
    let mut file = SceneFile::load_or_default(options.scene.as_deref())?;
    let render = &mut file.render;
    if let Some((w, h)) = options.size {
        (render.width, render.height) = (w, h);
    }
    render.seed = options.seed.unwrap_or(render.seed);
    render.max_depth = options.max_depth.unwrap_or(render.max_depth);
    let (width, height) = (render.width, render.height);
    if width > MAX_SIDE || height > MAX_SIDE {
        let given = if options.size.is_some() {
            "--size".to_owned()
        } else {
            format!("{}: [render] width and height", file.path.display())
        };
        bail!("{given} {width}x{height}: a paint precompute takes 1 to {MAX_SIDE} pixels on a side");
    }
    refuse_pattern(&file, "`twill paint` (the path tracer's paths)")?;
    refuse_mesh(&file, "`twill paint`")?;
    check_folder_of(&options.output)?;
    let gradient_spp = if options.gradient_spp > options.spp {
        eprintln!(
            "note: --gradient-spp {} is more than --spp {}: the weights come from all {} paths",
            options.gradient_spp, options.spp, options.spp
        );
        options.spp
    } else {
        options.gradient_spp
    };
    let scene = file.build()?;
    let camera = file.camera(width, height).map_err(|e| anyhow!("{}: {e}", file.path.display()))?;
    let cells = scene_cells(&scene, &file.path)?;
    let keys = SceneKeys::of(&file).map_err(|e| anyhow!("{}: {e}", file.path.display()))?;
    let settings = PaintSettings {
        width: width as u32,
        height: height as u32,
        curve_spp: options.spp,
        gradient_spp,
        max_depth: file.render.max_depth,
        seed: file.render.seed,
    };

    let bar = rows_bar(
        height,
        format!("painting precompute {width}x{height} at {} spp ({gradient_spp} with weights)", options.spp),
    );
    let mut data = paint::precompute(&scene.path_scene, cells, &camera, &settings, &|rows| {
        bar.set_position(rows as u64);
    })
    .map_err(|e| anyhow!("{}: {e}", file.path.display()))?;
    bar.finish_and_clear();
    data.scene_keys = Some(keys);
    data.exposure = Some(file.render.exposure);
    data.save(&options.output)?;
    let file_bytes = std::fs::metadata(&options.output)
        .with_context(|| format!("{}: written but cannot be read back", options.output.display()))?
        .len();
    let (warp, weft) = (&data.cells.warp, &data.cells.weft);
    eprintln!(
        "wrote {} ({width}x{height}, {} spp, weights from {gradient_spp}, seed {}, max depth {}): \
         {} cells ({} warp ends x {} sections, {} weft picks x {} sections inside the swatch), \
         {} weights stored, {:.1} MB in memory, file {:.1} MB; {:.2} s",
        options.output.display(),
        options.spp,
        settings.seed,
        settings.max_depth,
        data.cells.count(),
        warp.inside,
        warp.sections,
        weft.inside,
        weft.sections,
        data.weight_count(),
        data.bytes() as f64 / 1e6,
        file_bytes as f64 / 1e6,
        data.seconds
    );
    Ok(())
}

fn apply(file: &Path, painting: Option<&Path>, output: &Path, exposure: Option<f64>) -> Result<()> {
    check_image_name(output)?;
    let data = PaintData::load(file)?;
    let scene_colours = data.scene_painting();
    let colours = match painting {
        Some(path) => load_painting(path, &data.cells, &scene_colours)?,
        None => scene_colours,
    };
    let started = Instant::now();
    let image = data.evaluate(&colours);
    let first_ms = started.elapsed().as_secs_f64() * 1e3;
    // Once more, warm (threads started, memory touched): what each further stroke costs.
    let started = Instant::now();
    let _again = data.evaluate(&colours);
    let warm_ms = started.elapsed().as_secs_f64() * 1e3;
    let exposure = exposure.or(data.exposure).unwrap_or(0.0);
    write_image(output, &image, Display { exposure, ..Display::default() })?;
    let (w, h) = data.size();
    eprintln!(
        "wrote {} ({w}x{h}, {}): evaluated in {first_ms:.2} ms ({warm_ms:.2} ms warm), mean radiance {}",
        output.display(),
        painting
            .map_or_else(|| "the scene's own colours".to_owned(), |p| format!("painting {}", p.display())),
        rgb(image.mean())
    );
    Ok(())
}

/// `"0-56"`, or `"none"`.
fn span(count: u32) -> String {
    match count {
        0 => "none".to_owned(),
        1 => "\"0\"".to_owned(),
        n => format!("\"0-{}\"", n - 1),
    }
}

fn describe_set(set: &ThreadSet, threads: &str, key: &str, across: &str, along: &str) -> String {
    if set.per_period == 0 {
        return format!(
            "{threads:<11} none: this fabric has no {key} threads (a `{key}` stroke is refused)\n"
        );
    }
    let beyond = set.threads - set.inside;
    format!(
        "{threads:<11} {} inside the swatch: {key} = {} ({across}); {beyond} more, of the exemplar copies \
         beyond the edges, cannot be named (only `base`, `all` and `random` colour them)\n  sections  {} along \
         each: sections = {} ({along})\n",
        set.inside,
        span(set.inside),
        set.sections,
        span(set.sections)
    )
}

fn threads(file: &Path) -> Result<()> {
    let data = PaintData::load(file)?;
    let s = &data.settings;
    let cells = &data.cells;
    let (warp, weft) = (&cells.warp, &cells.weft);
    println!(
        "{}: {}x{} pixels, {} spp (weights from {}), seed {}, max depth {}",
        file.display(),
        s.width,
        s.height,
        s.curve_spp,
        s.gradient_spp,
        s.seed,
        s.max_depth
    );
    print!(
        "{}",
        describe_set(
            warp,
            "warp ends",
            "warp",
            "from the left edge, smallest x",
            "from the near edge, smallest y"
        )
    );
    print!(
        "{}",
        describe_set(
            weft,
            "weft picks",
            "weft",
            "from the near edge, smallest y",
            "from the left edge, smallest x"
        )
    );
    let on_threads = u64::from(warp.threads) * u64::from(warp.sections)
        + u64::from(weft.threads) * u64::from(weft.sections);
    let nameable =
        u64::from(warp.inside) * u64::from(warp.sections) + u64::from(weft.inside) * u64::from(weft.sections);
    let other = (cells.count() as u64).saturating_sub(on_threads);
    print!(
        "cells       {} in all: {nameable} on the threads inside the swatch (what `warp`/`weft` strokes name), \
         {} on the copies beyond its edges",
        cells.count(),
        on_threads - nameable
    );
    if other > 0 {
        print!(", {other} of yarns with no weave role (only `base`, `all` and `random` colour them)");
    }
    println!();
    Ok(())
}

/// The scene `file` built, with its camera at the paint file's image size and its paint cells,
/// checked to be the scene `data` (read from `paint_file`) was precomputed from: the same image
/// size and the same cells. An error names both files.
fn precomputed_scene(
    data: &PaintData,
    paint_file: &Path,
    file: &SceneFile,
) -> Result<(Scene, Camera, PaintCells)> {
    let scene = file.build()?;
    let (w, h) = data.size();
    let camera = file.camera(w, h).map_err(|e| anyhow!("{}: {e}", file.path.display()))?;
    let cells = scene_cells(&scene, &file.path)?;
    let other_scene = |what: String| {
        anyhow!(
            "{} was not precomputed from {}: {what}; give the scene it was precomputed from",
            paint_file.display(),
            file.path.display()
        )
    };
    if (camera.width(), camera.height()) != (w, h) {
        return Err(other_scene(format!(
            "its images are {w}x{h}, the scene's camera {}x{}",
            camera.width(),
            camera.height()
        )));
    }
    if let Some(keys) = &data.scene_keys {
        let now = SceneKeys::of(file).map_err(|e| anyhow!("{}: {e}", file.path.display()))?;
        let differences = keys.differences(&now);
        if !differences.is_empty() {
            let verb = if differences.len() == 1 { "differs" } else { "differ" };
            return Err(other_scene(format!("{} {verb}", differences.join(" and "))));
        }
    }
    if cells != data.cells {
        return Err(other_scene(format!(
            "its swatch divides into {} cells ({} warp ends x {} sections, {} weft picks x {} sections), \
             the scene's into {} ({} x {}, {} x {})",
            data.cells.count(),
            data.cells.warp.inside,
            data.cells.warp.sections,
            data.cells.weft.inside,
            data.cells.weft.sections,
            cells.count(),
            cells.warp.inside,
            cells.warp.sections,
            cells.weft.inside,
            cells.weft.sections
        )));
    }
    Ok((scene, camera, cells))
}

struct VerifyOptions {
    file: PathBuf,
    scene: Option<PathBuf>,
    painting: PathBuf,
    spp: u32,
    seed: Option<u64>,
    images: Option<PathBuf>,
}

fn verify(options: &VerifyOptions) -> Result<()> {
    let data = PaintData::load(&options.file)?;
    let file = SceneFile::load_or_default(options.scene.as_deref())?;
    refuse_pattern(&file, "`twill paint` (the path tracer's paths)")?;
    refuse_mesh(&file, "`twill paint`")?;
    let seed = options.seed.unwrap_or(data.settings.seed.wrapping_add(1));
    let second_seed = seed
        .checked_add(1)
        .with_context(|| format!("--seed {seed}: the second reference takes S+1; give a smaller seed"))?;
    if seed == data.settings.seed || second_seed == data.settings.seed {
        bail!(
            "--seed {seed}: the references take seeds {seed} and {second_seed}, and {} was precomputed with \
             seed {} (the same random numbers per pixel would make the check look better than it is); \
             give another seed",
            options.file.display(),
            data.settings.seed
        );
    }
    if let Some(dir) = &options.images {
        std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot make the folder", dir.display()))?;
    }
    let (mut scene, camera, cells) = precomputed_scene(&data, &options.file, &file)?;
    let (w, h) = data.size();
    // Unpainted cells take the paint file's colours on both sides, whatever the scene's are now.
    let scene_colours = data.scene_painting();
    let now: Vec<[f32; 3]> = paint::scene_colours(&scene.path_scene, &cells)
        .into_iter()
        .map(|c| [c.x as f32, c.y as f32, c.z as f32])
        .collect();
    if now != data.scene_colours {
        eprintln!(
            "note: {}'s yarn colours differ from those {} was precomputed with; cells the painting \
             leaves alone keep the paint file's",
            file.path.display(),
            options.file.display()
        );
    }
    let colours = load_painting(&options.painting, &data.cells, &scene_colours)?;
    paint_scene(&mut scene, cells, &colours, &options.painting)?;

    let started = Instant::now();
    let mut references = Vec::with_capacity(2);
    for (i, seed) in [seed, second_seed].into_iter().enumerate() {
        let settings = RenderSettings {
            spp: options.spp,
            max_depth: data.settings.max_depth,
            component: Component::All,
            seed,
        };
        let bar = rows_bar(h, format!("reference {}/2: path tracing {w}x{h} at {} spp", i + 1, options.spp));
        let film =
            pathtrace::render(&scene.path_scene, &camera, &settings, &|rows| bar.set_position(rows as u64));
        bar.finish_and_clear();
        references.push(film.mean());
    }
    let reference_s = started.elapsed().as_secs_f64();
    let started = Instant::now();
    let painted = data.evaluate(&colours);
    let evaluate_ms = started.elapsed().as_secs_f64() * 1e3;

    let (first, second) = (&references[0], &references[1]);
    ensure!(
        first.pixels.iter().any(|p| p.length_squared() > 0.0),
        "{}: the reference is black: the camera sees no lit cloth, so there is nothing to compare",
        file.path.display()
    );
    let error = painted.relative_l2(first);
    let floor = second.relative_l2(first);
    println!(
        "painting {} on {} ({w}x{h}, precomputed at {} spp, seed {}); references at {} spp, seeds {seed} and \
         {second_seed}, max depth {}",
        options.painting.display(),
        options.file.display(),
        data.settings.curve_spp,
        data.settings.seed,
        options.spp,
        data.settings.max_depth
    );
    let line = |label: &str, value: String| println!("{label:<44} {value}");
    line("relative L2, painting vs reference 1", format!("{error:.4}"));
    line("relative L2, reference 2 vs reference 1", format!("{floor:.4}  (the noise floor)"));
    line("ratio", format!("{:.2}", error / floor));
    // E|P − R1|² = |P − T|² + E|R1 − T|² and E|R2 − R1|² = 2 E|R − T|²: the painting's own error
    // with the first reference's noise taken out (where the estimate is positive).
    let own = error * error - floor * floor / 2.0;
    line(
        "painting's own error, reference noise out",
        if own > 0.0 { format!("{:.4}", own.sqrt()) } else { "below the references' noise".to_owned() },
    );
    line("image mean, painting", rgb(painted.mean()));
    line("image mean, reference 1", rgb(first.mean()));
    line("image mean, reference 2", rgb(second.mean()));
    line("times", format!("evaluation {evaluate_ms:.2} ms, references {reference_s:.2} s"));

    if let Some(dir) = &options.images {
        let display = Display { exposure: file.render.exposure, ..Display::default() };
        let mut difference = Image::new(w, h);
        for ((d, a), b) in difference.pixels.iter_mut().zip(&painted.pixels).zip(&first.pixels) {
            *d = (*a - *b).abs() * 4.0;
        }
        for (name, image) in
            [("painted.png", &painted), ("reference.png", first), ("difference.png", &difference)]
        {
            write_image(&dir.join(name), image, display)?;
        }
        eprintln!("wrote painted.png, reference.png and difference.png (x4) into {}", dir.display());
    }
    Ok(())
}

fn commit(file: &Path, scene: Option<&Path>, painting: &Path, output: &Path) -> Result<()> {
    check_folder_of(output)?;
    let data = PaintData::load(file)?;
    let scene_file = SceneFile::load_or_default(scene)?;
    refuse_pattern(&scene_file, "`twill paint` (the path tracer's paths)")?;
    refuse_mesh(&scene_file, "`twill paint`")?;
    let (_, _, cells) = precomputed_scene(&data, file, &scene_file)?;
    // Unpainted cells take the paint file's colours, as `apply` shows them.
    let colours = load_painting(painting, &cells, &data.scene_painting())?;
    let committed = paint::commit_colour_orders(&scene_file, &cells, &colours)
        .map_err(|e| anyhow!("{}: {e}", painting.display()))?;
    committed.scene.save(output)?;
    let m = &committed.scene.materials;
    println!(
        "wrote {} (painting {} as a colourway): {}",
        output.display(),
        painting.display(),
        committed.summary
    );
    println!(
        "  warp_order = {:?}\n  weft_order = {:?}",
        m.warp_order.as_deref().unwrap_or_default(),
        m.weft_order.as_deref().unwrap_or_default()
    );
    if let Some(note) = committed.edge_note() {
        eprintln!("note: {note}");
    }
    Ok(())
}
