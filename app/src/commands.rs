//! The subcommands' work: load the scene, do the job, report.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use twill_precompute::fabric::{exemplar::volume_fraction, fiber_io, presets};
use twill_precompute::pathtrace::{self, Component};
use twill_precompute::raycast::mean_free_path;
use twill_precompute::scene::SceneFile;
use twill_renderer::export::{Display, write_image};

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
    Ok(())
}

pub fn fabric_export(scene_path: Option<&Path>, hair: bool, output: &Path) -> Result<()> {
    let scene = SceneFile::load_or_default(scene_path)?.build()?;
    let format = if hair { fiber_io::FiberFormat::Hair } else { fiber_io::FiberFormat::Mitsuba };
    fiber_io::write_fibers(output, &scene.exemplar.fibers, Some(format))?;
    eprintln!("wrote {} fibers to {}", scene.exemplar.fibers.len(), output.display());
    Ok(())
}

/// Options of `twill reference` (command-line overrides of the scene's settings).
pub struct ReferenceOptions {
    pub scene: Option<PathBuf>,
    pub output: PathBuf,
    pub size: Option<(usize, usize)>,
    pub spp: Option<u32>,
    pub max_depth: Option<u32>,
    pub only: Option<Component>,
    pub exposure: Option<f64>,
    pub seed: Option<u64>,
}

pub fn reference(options: &ReferenceOptions) -> Result<()> {
    let mut file = SceneFile::load_or_default(options.scene.as_deref())?;
    let render = &mut file.render;
    if let Some((w, h)) = options.size {
        (render.width, render.height) = (w, h);
    }
    render.spp = options.spp.unwrap_or(render.spp);
    render.max_depth = options.max_depth.unwrap_or(render.max_depth);
    render.exposure = options.exposure.unwrap_or(render.exposure);
    render.seed = options.seed.unwrap_or(render.seed);
    let scene = file.build()?;
    let camera = file.camera(file.render.width, file.render.height)?;
    let settings = file.render_settings(options.only);

    let started = Instant::now();

    let bar = ProgressBar::new(camera.height() as u64).with_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} rows, {elapsed} elapsed, eta {eta}")
            .expect("the progress template is valid"),
    );
    bar.set_message(format!("path tracing {}x{} at {} spp", camera.width(), camera.height(), settings.spp));
    let film =
        pathtrace::render(&scene.path_scene, &camera, &settings, &|rows| bar.set_position(rows as u64));
    bar.finish_and_clear();
    let render_s = started.elapsed().as_secs_f64();

    let image = film.mean();
    let variance = film.variance_of_mean();
    let display = Display { exposure: file.render.exposure, ..Display::default() };
    write_image(&options.output, &image, display)?;
    let mean = image.mean();
    let noise = (variance.pixels.iter().map(|v| v.element_sum() / 3.0).sum::<f64>()
        / variance.pixels.len() as f64)
        .sqrt();
    eprintln!(
        "wrote {} ({}x{}, {} spp, {:?}): mean radiance [{:.4}, {:.4}, {:.4}], per-pixel noise (std. error) {:.4}; \
         path tracing {:.2} s",
        options.output.display(),
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
