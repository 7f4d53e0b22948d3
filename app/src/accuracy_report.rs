//! `twill accuracy`: runs the knob sweep (`twill_renderer::accuracy::sweep`) on flat swatches
//! of several fabrics and writes what it measured: `report.csv` (one row per point and fabric),
//! `configurations.csv` (each configuration's error per point and fabric),
//! `report.html` (self-contained: plots of error against time per knob, the Pareto front,
//! tables, and images side by side with the reference and an error map) and `headline.md`
//! (the presets' table the README shows). The CSV is also copied to the stage cache folder as
//! `accuracy/latest-report.csv`, where the viewer looks for the expected error of its settings.
//!
//! Plots are drawn with plotters' SVG backend into the HTML; images are PNGs inlined as data
//! URIs. References are cached in `DIR/references/` and reused by later runs; bake stages go
//! through a stage cache private to the run, so each stage's time is measured, and a knob
//! reruns only the stages that depend on it.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context as _, Result};
use base64::Engine as _;
use plotters::prelude::*;
use twill_precompute::bake::file::Cache;
use twill_precompute::bake::settings::{BakeSettings, Quality};
use twill_precompute::image::Image;
use twill_precompute::scene::{FabricSection, MeshSection, SceneFile};
use twill_renderer::accuracy::sweep::{
    self, Fabric, Knob, Method, PointKind, ReferenceCache, Sweep, SweepSettings,
};
use twill_renderer::export::{Display, display_srgb8, encode_rgb8_png};

/// What `twill accuracy` was asked for.
#[derive(Debug, Clone)]
pub struct ReportOptions {
    /// Fabric preset names or scene files.
    pub scenes: Vec<String>,
    pub output: Option<PathBuf>,
    pub settings: SweepSettings,
}

/// The file the viewer reads: the latest report's CSV, in the stage cache folder.
pub fn latest_report_path() -> Option<PathBuf> {
    crate::commands::default_cache_dir().map(|d| d.join("accuracy").join("latest-report.csv"))
}

/// Parses `--knobs`: `all`, `none`, or a comma list of knob names, each optionally with its
/// values as `name=v1/v2/...`.
pub fn parse_knobs(text: &str) -> Result<Vec<(Knob, Vec<f64>)>> {
    match text.trim() {
        "all" => return Ok(Knob::ALL.iter().map(|&k| (k, k.default_values())).collect()),
        "none" | "" => return Ok(Vec::new()),
        _ => {}
    }
    text.split(',')
        .map(|item| {
            let (name, values) = item.split_once('=').map_or((item, None), |(n, v)| (n, Some(v)));
            let knob = Knob::parse(name.trim())?;
            let values = match values {
                None => knob.default_values(),
                Some(v) => v
                    .split('/')
                    .map(|x| {
                        x.trim().parse::<f64>().with_context(|| {
                            format!("--knobs {item:?}: {x:?} is not a number (values are separated by '/')")
                        })
                    })
                    .collect::<Result<_>>()?,
            };
            Ok((knob, values))
        })
        .collect()
}

/// A flat swatch scene of each named fabric preset or scene file.
fn fabrics(names: &[String]) -> Result<Vec<Fabric>> {
    names
        .iter()
        .map(|name| {
            let path = Path::new(name);
            let mut file = if path.extension().is_some_and(|e| e == "toml") || path.exists() {
                SceneFile::load(path)?
            } else {
                let mut file = SceneFile::default_scene();
                file.fabric = FabricSection { preset: Some(name.clone()), spec: None };
                file
            };
            anyhow::ensure!(
                file.pattern.is_none(),
                "{name}: patterned cloth: the accuracy run measures the CPU method too, which shades one exemplar; remove [pattern]"
            );
            // A flat swatch over a black ground, large enough for grazing views of a 0.4 cm film.
            file.mesh = MeshSection::default();
            file.swatch.size_cm = [2.0, 2.0];
            file.swatch.ground = true;
            let scene = file.build().with_context(|| format!("fabric {name:?}"))?;
            let short = path.file_stem().map_or_else(|| name.clone(), |s| s.to_string_lossy().into_owned());
            Ok(Fabric { name: short, scene })
        })
        .collect()
}

/// Runs the sweep and writes the report; prints the headline table and where the files are.
pub fn run(options: &ReportOptions) -> Result<()> {
    let output = match &options.output {
        Some(dir) => dir.clone(),
        None => crate::commands::default_cache_dir()
            .context("no cache folder (set TWILL_CACHE_DIR or HOME), so give -o DIR")?
            .join("accuracy"),
    };
    std::fs::create_dir_all(&output).with_context(|| format!("{}: cannot create it", output.display()))?;
    let mut fabrics = fabrics(&options.scenes)?;
    let references = ReferenceCache::new(&output.join("references"))
        .with_context(|| format!("{}: cannot create the reference cache", output.display()))?;
    let stage_dir = tempfile::Builder::new()
        .prefix("stage-cache-")
        .tempdir_in(&output)
        .with_context(|| format!("{}: cannot create a stage cache", output.display()))?;
    let stage_cache = Cache::new(stage_dir.path())?;
    let gpu = twill_renderer::gpu::Gpu::headless()?;
    let sweep = sweep::run(&mut fabrics, gpu, &options.settings, &references, &stage_cache, &|line| {
        eprintln!("  {line}");
    })?;
    let csv = sweep.csv();
    let write = |name: &str, text: &str| -> Result<PathBuf> {
        let path = output.join(name);
        twill_precompute::atomic_file::write_atomically(&path, |w| {
            std::io::Write::write_all(w, text.as_bytes())
        })
        .with_context(|| format!("{}: cannot write", path.display()))?;
        Ok(path)
    };
    let csv_path = write("report.csv", &csv)?;
    write("configurations.csv", &sweep.configurations_csv())?;
    let html_path = write("report.html", &html(&sweep)?)?;
    let headline = sweep.headline_markdown();
    write("headline.md", &headline)?;
    if let Some(latest) = latest_report_path() {
        if let Some(dir) = latest.parent() {
            let _ = std::fs::create_dir_all(dir);
        }
        if latest != csv_path {
            twill_precompute::atomic_file::write_atomically(&latest, |w| {
                std::io::Write::write_all(w, csv.as_bytes())
            })
            .with_context(|| format!("{}: cannot write", latest.display()))?;
        }
    }
    println!("{}", describe_run(&sweep));
    print!("{headline}");
    println!("\nwrote {} and {}", html_path.display(), csv_path.display());
    Ok(())
}

/// The knobs of `base` that differ in `changed`, as `knob = value` (their TOML form).
fn base_changes(base: BakeSettings, changed: BakeSettings) -> Vec<String> {
    let table = |s: BakeSettings| toml::Table::try_from(s).unwrap_or_default();
    let (before, after) = (table(base), table(changed));
    after
        .iter()
        .filter(|(knob, value)| before.get(*knob) != Some(*value))
        .map(|(knob, value)| format!("{knob} = {value}"))
        .collect()
}

/// One paragraph: what was run, on what, with the references' noise.
fn describe_run(sweep: &Sweep) -> String {
    let s = &sweep.settings;
    let mut out = format!(
        "{} configurations ({} px, views ≤ 75°, lights ≤ 80°), method {} spp, references {} spp, on {}; knobs varied around {}.",
        sweep.configurations.len(),
        s.size,
        s.method_spp,
        s.reference_spp,
        sweep.adapter,
        s.base.name()
    );
    if let Some(noise) = s.reference_noise {
        let mut spp: Vec<u32> =
            sweep.fabrics.iter().flat_map(|f| f.configuration_spp.iter().copied()).collect();
        spp.sort_unstable();
        let _ = write!(
            out,
            " References are rendered again, doubling their samples, until each component's image mean is within {:.1}% (one standard error; a component under a quarter of all light against a quarter of all light) or {} spp: median {} spp, most {} spp.",
            100.0 * noise,
            s.reference_max_spp,
            spp.get(spp.len() / 2).copied().unwrap_or(0),
            spp.last().copied().unwrap_or(0)
        );
    }
    let changes = base_changes(s.base.settings(), s.base_bake);
    if !changes.is_empty() {
        let _ = write!(out, " The base's knobs changed: {}.", changes.join(", "));
    }
    for f in &sweep.fabrics {
        let worst_noise = f.configuration_noise.iter().map(|n| n[2]).fold(0.0, f64::max);
        let _ = write!(
            out,
            " {}: reference noise {:.2}% of the image average, {:.1}% per pixel, at most {:.1}% of one configuration's image mean ({} of {} loaded from the cache).",
            f.name,
            100.0 * f.average_noise[2],
            100.0 * f.pixel_noise[2],
            100.0 * worst_noise,
            f.loaded,
            sweep.configurations.len()
        );
    }
    out
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// A PNG data URI of `rgb` bytes.
fn png_uri(width: usize, height: usize, rgb: &[u8]) -> Result<String> {
    let mut bytes = Vec::new();
    encode_rgb8_png(&mut bytes, width as u32, height as u32, rgb)?;
    Ok(format!("data:image/png;base64,{}", base64::engine::general_purpose::STANDARD.encode(bytes)))
}

/// The image tone-mapped with an exposure that puts the reference's mean at mid-grey.
fn display_uri(image: &Image, reference_mean: f64) -> Result<String> {
    let exposure = if reference_mean > 0.0 { (0.18 / reference_mean).log2() } else { 0.0 };
    let display = Display { exposure, ..Display::default() };
    let rgb: Vec<u8> = image.pixels.iter().flat_map(|&p| display_srgb8(p, display)).collect();
    png_uri(image.width, image.height, &rgb)
}

/// Signed per-pixel error relative to the reference's mean: blue darker, red brighter, white
/// equal; full colour at ±`scale`.
fn error_map_uri(image: &Image, reference: &Image, scale: f64) -> Result<String> {
    let mean = reference.mean().element_sum() / 3.0;
    let rgb: Vec<u8> = image
        .pixels
        .iter()
        .zip(&reference.pixels)
        .flat_map(|(&a, &b)| {
            let e = ((a - b).element_sum() / 3.0 / mean.max(1e-300) / scale).clamp(-1.0, 1.0);
            let fade = |x: f64| (255.0 * (1.0 - x.abs())) as u8;
            if e >= 0.0 { [255, fade(e), fade(e)] } else { [fade(e), fade(e), 255] }
        })
        .collect();
    png_uri(image.width, image.height, &rgb)
}

/// A named series of (time, error, label) points, joined by a line or not.
type Series = (String, Vec<(f64, f64, String)>, bool);

const COLOURS: [RGBColor; 3] = [RGBColor(31, 119, 180), RGBColor(214, 39, 40), RGBColor(44, 160, 44)];

/// An SVG plot: for each named series, (time, error) points joined in order, labelled.
fn plot(title: &str, x_desc: &str, series: &[Series], highlight: &[(f64, f64, String)]) -> Result<String> {
    let all = series.iter().flat_map(|(_, p, _)| p.iter()).chain(highlight);
    let (mut x0, mut x1, mut y1) = (f64::MAX, 0f64, 0f64);
    for &(x, y, _) in all {
        if x.is_finite() && y.is_finite() && x > 0.0 {
            (x0, x1, y1) = (x0.min(x), x1.max(x), y1.max(y));
        }
    }
    if x0 > x1 {
        (x0, x1) = (0.0, 1.0);
    }
    // Linear; from zero when the times span more than a factor of two (they compare as ratios
    // at a glance), else zoomed on them (a knob that costs little time still spreads out).
    let (x0, x1) = if x0 < 0.5 * x1 {
        (0.0, x1 * 1.1)
    } else {
        let pad = 0.15 * (x1 - x0).max(0.02 * x1);
        ((x0 - pad).max(0.0), x1 + pad)
    };
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (560, 360)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(52)
            .build_cartesian_2d(x0..x1, 0f64..(y1 * 1.15).max(0.01))
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc("relative error")
            .y_label_formatter(&|y| format!("{:.0}%", 100.0 * y))
            .draw()
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        for (i, (name, points, joined)) in series.iter().enumerate() {
            let colour = COLOURS[i % COLOURS.len()];
            let xy: Vec<(f64, f64)> = if *joined {
                points
                    .iter()
                    .map(|(x, y, _)| (*x, *y))
                    .filter(|(x, y)| x.is_finite() && y.is_finite() && *x > 0.0)
                    .collect()
            } else {
                Vec::new()
            };
            chart
                .draw_series(LineSeries::new(xy, colour.stroke_width(2)))
                .map_err(|e| anyhow::anyhow!("plot: {e}"))?
                .label(name.as_str())
                .legend(move |(x, y)| Circle::new((x + 8, y), 3, colour.filled()));
            chart
                .draw_series(
                    points.iter().filter(|(x, y, _)| x.is_finite() && y.is_finite() && *x > 0.0).map(
                        |(x, y, label)| {
                            EmptyElement::at((*x, *y))
                                + Circle::new((0, 0), 3, colour.filled())
                                + Text::new(label.clone(), (4, -12), ("sans-serif", 10))
                        },
                    ),
                )
                .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        }
        chart
            .draw_series(highlight.iter().filter(|(x, y, _)| x.is_finite() && y.is_finite() && *x > 0.0).map(
                |(x, y, label)| {
                    EmptyElement::at((*x, *y))
                        + Cross::new((0, 0), 5, BLACK.stroke_width(2))
                        + Text::new(label.clone(), (6, 2), ("sans-serif", 11))
                },
            ))
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        root.present().map_err(|e| anyhow::anyhow!("plot: {e}"))?;
    }
    Ok(svg)
}

fn percent(x: f64) -> String {
    format!("{:.1}%", 100.0 * x)
}

/// The self-contained HTML report.
fn html(sweep: &Sweep) -> Result<String> {
    let mut out = String::from(
        "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>twill accuracy report</title><style>\
         body{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}\
         table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}\
         th{background:#eee}td:first-child,th:first-child{text-align:left}.front{background:#e7f5e7}\
         figure{display:inline-block;margin:4px}img{image-rendering:pixelated;width:160px}figcaption{font-size:11px}\
         </style></head><body>\n<h1>twill: what accuracy costs in time</h1>\n",
    );
    let _ = writeln!(out, "<p>{}</p>", escape(&describe_run(sweep)));
    out.push_str(
        "<p>Errors are against the path tracer with its noise subtracted. <b>Image-mean error</b>: RMSE over \
         configurations and channels of each image's average intensity, over the RMS of the references' averages \
         (the paper's Fig. 13). <b>Per pixel</b>: per-pixel RMSE over the same scale. <b>Equal spp</b>: the \
         path-traced samples per pixel whose noise equals that per-pixel error. <b>SSIM</b>: of tone-mapped \
         luminance. Frame time: median wall time of one frame (all light) on the device named above; bake time: \
         the sum of the bake's stages as computed in this run. Shadow-map knobs (PCF, PCSS) are not swept: a \
         flat swatch casts no shadows on itself.</p>\n",
    );

    out.push_str("<h2>Presets</h2>\n");
    out.push_str(&markdown_table_to_html(&sweep.headline_markdown()));

    // The Pareto front.
    let pareto = sweep.pareto();
    let gpu_points: Vec<usize> =
        (0..sweep.points.len()).filter(|&i| sweep.points[i].method == Method::Gpu).collect();
    let label_of = |i: usize| match sweep.points[i].kind {
        PointKind::Preset(q) => q.name().to_owned(),
        PointKind::Knob { knob, value } => format!("{}={value}", knob.name()),
    };
    let presets: Vec<usize> = gpu_points
        .iter()
        .copied()
        .filter(|&i| matches!(sweep.points[i].kind, PointKind::Preset(_)))
        .collect();
    for (axis, desc, time) in [
        (
            "frame time",
            "frame time (ms)",
            &(|p: &sweep::Point| p.frame_ms()) as &dyn Fn(&sweep::Point) -> f64,
        ),
        ("bake time", "bake time (s)", &|p: &sweep::Point| p.bake_seconds()),
    ] {
        let mut front: Vec<(f64, f64, String)> = gpu_points
            .iter()
            .filter(|&&i| pareto[i])
            .map(|&i| (time(&sweep.points[i]), sweep.points[i].error(), String::new()))
            .collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        let others: Vec<(f64, f64, String)> = gpu_points
            .iter()
            .filter(|&&i| !pareto[i])
            .map(|&i| (time(&sweep.points[i]), sweep.points[i].error(), String::new()))
            .collect();
        let marks: Vec<(f64, f64, String)> =
            presets.iter().map(|&i| (time(&sweep.points[i]), sweep.points[i].error(), label_of(i))).collect();
        let series = vec![
            ("on the Pareto front (error, frame time, bake time)".to_owned(), front, false),
            ("dominated".to_owned(), others, false),
        ];
        out.push_str(&plot(
            &format!("Image-mean error against {axis}, every GPU point"),
            desc,
            &series,
            &marks,
        )?);
    }

    // Per knob: error against the time the knob costs.
    out.push_str("<h2>Each knob</h2>\n<p>Each knob varied alone around the base preset (its point is the base preset's value). \
        Bake knobs are plotted against bake time, frame knobs against frame time; labels are the knob's values.</p>\n");
    let mut knobs: Vec<Knob> = Vec::new();
    for p in &sweep.points {
        if let PointKind::Knob { knob, .. } = p.kind
            && !knobs.contains(&knob)
        {
            knobs.push(knob);
        }
    }
    // The base preset's point is each knob's point at the base only when no knob of the base
    // was changed (`--set`).
    let base = sweep.points.iter().find(|p| {
        p.method == Method::Gpu
            && p.kind == PointKind::Preset(sweep.settings.base)
            && p.bake == sweep.settings.base_bake
    });
    for knob in knobs {
        let time = |p: &sweep::Point| if knob.is_bake_knob() { p.bake_seconds() } else { p.frame_ms() };
        let mut points: Vec<&sweep::Point> = sweep
            .points
            .iter()
            .filter(|p| {
                p.method == Method::Gpu && matches!(p.kind, PointKind::Knob { knob: k, .. } if k == knob)
            })
            .collect();
        let value_of = |p: &sweep::Point| p.value_of(knob);
        if let Some(b) = base {
            points.push(b);
        }
        points.sort_by(|a, b| value_of(a).total_cmp(&value_of(b)));
        points.dedup_by(|a, b| (value_of(a) - value_of(b)).abs() < 1e-12);
        let series: Vec<Series> = [("image mean, all light", 2usize), ("single", 0), ("multiple", 1)]
            .into_iter()
            .map(|(name, c)| {
                let pts = points
                    .iter()
                    .map(|p| {
                        let e = p.fabrics.iter().map(|f| f.errors[c].mean_relative_rmse).sum::<f64>()
                            / p.fabrics.len().max(1) as f64;
                        (time(p), e, if c == 2 { format!("{}", value_of(p)) } else { String::new() })
                    })
                    .collect();
                (name.to_owned(), pts, true)
            })
            .collect();
        let desc = if knob.is_bake_knob() { "bake time (s)" } else { "frame time (ms)" };
        out.push_str(&plot(knob.name(), desc, &series, &[])?);
    }

    // Every point.
    out.push_str("<h2>Every point</h2>\n<p>Errors averaged over the fabrics; green rows are on the Pareto front.</p>\n<table><tr><th>point</th><th>method</th><th>image mean: all</th><th>single</th><th>multiple</th><th>worst configuration</th><th>per pixel</th><th>equal spp</th><th>SSIM</th><th>frame ms</th><th>bake s</th><th>GPU MB</th></tr>\n");
    for (i, p) in sweep.points.iter().enumerate() {
        let mean = |f: &dyn Fn(&sweep::FabricResult) -> f64| p.mean_over_fabrics(f);
        let worst = p.worst_error();
        let _ = writeln!(
            out,
            "<tr{}><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:+.1}%</td><td>{}</td><td>{:.0}</td><td>{:.3}</td><td>{:.0}</td><td>{:.1}</td><td>{:.0}</td></tr>",
            if pareto[i] { " class=\"front\"" } else { "" },
            escape(&p.label),
            if p.method == Method::Gpu { "GPU" } else { "CPU" },
            percent(mean(&|f| f.errors[2].mean_relative_rmse)),
            percent(mean(&|f| f.errors[0].mean_relative_rmse)),
            percent(mean(&|f| f.errors[1].mean_relative_rmse)),
            100.0 * worst,
            percent(mean(&|f| f.errors[2].pixel_relative_rmse)),
            mean(&|f| f.errors[2].equal_error_spp),
            mean(&|f| f.errors[2].ssim),
            p.frame_ms(),
            p.bake_seconds(),
            mean(&|f| f.resident_bytes as f64 / 1e6)
        );
    }
    out.push_str("</table>\n");

    // Presets per fabric, with the worst configurations and the pass and stage times.
    for p in sweep.points.iter().filter(|p| matches!(p.kind, PointKind::Preset(_))) {
        let _ = writeln!(
            out,
            "<h3>{}{}</h3>",
            escape(&p.label),
            if p.method == Method::Gpu { " (GPU)" } else { "" }
        );
        out.push_str("<table><tr><th>fabric</th><th>image mean: all / single / multiple</th><th>worst configuration</th><th>per pixel</th><th>SSIM</th><th>bake stages (s)</th><th>GPU passes (ms)</th></tr>\n");
        for (f, r) in sweep.fabrics.iter().zip(&p.fabrics) {
            let worst = &r.errors[2];
            let stages: Vec<String> =
                r.stage_seconds.iter().map(|(s, t)| format!("{} {t:.2}", s.name())).collect();
            let passes: Vec<String> = r.pass_ms.iter().map(|(s, t)| format!("{s} {t:.1}")).collect();
            let _ = writeln!(
                out,
                "<tr><td>{}</td><td>{} / {} / {}</td><td>{:+.1}% (reference ±{:.1}%): {}</td><td>{}</td><td>{:.3}</td><td>{}</td><td>{}</td></tr>",
                escape(&f.name),
                percent(r.errors[2].mean_relative_rmse),
                percent(r.errors[0].mean_relative_rmse),
                percent(r.errors[1].mean_relative_rmse),
                100.0 * worst.worst_relative,
                100.0 * f.configuration_noise.get(worst.worst_configuration).map_or(f64::NAN, |n| n[2]),
                escape(&sweep.configurations[worst.worst_configuration].describe()),
                percent(worst.pixel_relative_rmse),
                worst.ssim,
                escape(&stages.join(", ")),
                escape(&passes.join(", "))
            );
        }
        out.push_str("</table>\n");
        out.push_str("<p>By kind of configuration: the mean signed error of the image mean, single / multiple / all.</p><table><tr><th>kind</th>");
        for f in &sweep.fabrics {
            let _ = write!(out, "<th>{}</th>", escape(&f.name));
        }
        out.push_str("</tr>\n");
        let classes = sweep.errors_by_class(p, 0);
        for (class, _, _) in &classes {
            let _ = write!(out, "<tr><td>{}</td>", escape(class));
            for fabric in 0..sweep.fabrics.len() {
                match sweep.errors_by_class(p, fabric).into_iter().find(|(c, _, _)| c == class) {
                    Some((_, n, e)) => {
                        let _ = write!(
                            out,
                            "<td>{:+.1}% / {:+.1}% / {:+.1}% ({n})</td>",
                            100.0 * e[0],
                            100.0 * e[1],
                            100.0 * e[2]
                        );
                    }
                    None => out.push_str("<td></td>"),
                }
            }
            out.push_str("</tr>\n");
        }
        out.push_str("</table>\n");
    }

    // Images side by side.
    out.push_str("<h2>Images</h2>\n<p>Per fabric and example configuration: the path-traced reference, each preset's GPU frame, \
        and its error map (signed error over the reference's mean: red brighter, blue darker, full colour at ±50%). \
        Each row shares one exposure, set from the reference's mean.</p>\n");
    for (fi, f) in sweep.fabrics.iter().enumerate() {
        let _ = writeln!(out, "<h3>{}</h3>", escape(&f.name));
        for (ci, reference) in f.images.iter().enumerate() {
            let mean = reference.mean().element_sum() / 3.0;
            let _ = write!(
                out,
                "<div><figure><img src=\"{}\"><figcaption>reference: {}</figcaption></figure>",
                display_uri(reference, mean)?,
                escape(&sweep.configurations[ci].describe())
            );
            for p in sweep
                .points
                .iter()
                .filter(|p| p.method == Method::Gpu && matches!(p.kind, PointKind::Preset(_)))
            {
                if let Some(image) = p.fabrics.get(fi).and_then(|r| r.images.get(ci)) {
                    let error = p.fabrics[fi].configuration_errors[ci][2];
                    let _ = write!(
                        out,
                        "<figure><img src=\"{}\"><figcaption>{}: mean {:+.1}%</figcaption></figure><figure><img src=\"{}\"><figcaption>error map</figcaption></figure>",
                        display_uri(image, mean)?,
                        escape(&p.label),
                        100.0 * error,
                        error_map_uri(image, reference, 0.5)?
                    );
                }
            }
            out.push_str("</div>\n");
        }
    }

    out.push_str("<h2>Configurations</h2>\n<ol start=\"0\">\n");
    for c in &sweep.configurations {
        let _ = writeln!(out, "<li>{}</li>", escape(&c.describe()));
    }
    out.push_str("</ol>\n</body></html>\n");
    Ok(out)
}

/// A Markdown table (as `Sweep::headline_markdown` writes) as HTML.
fn markdown_table_to_html(markdown: &str) -> String {
    let mut out = String::from("<table>\n");
    for (i, line) in markdown.lines().filter(|l| l.starts_with('|')).enumerate() {
        if i == 1 {
            continue;
        }
        let tag = if i == 0 { "th" } else { "td" };
        out.push_str("<tr>");
        for cell in line.trim_matches('|').split('|') {
            let _ = write!(out, "<{tag}>{}</{tag}>", escape(cell.trim()));
        }
        out.push_str("</tr>\n");
    }
    out.push_str("</table>\n");
    out
}

/// What the latest report measured for a preset's GPU point, and the report's path.
pub fn expected_accuracy(quality: Quality) -> Option<(ExpectedAccuracy, PathBuf)> {
    let path = latest_report_path()?;
    let text = std::fs::read_to_string(&path).ok()?;
    let expected = expected_from_csv(&text, quality)?;
    Some((expected, path))
}

/// What the latest report measured for a preset (GPU), averaged over its fabrics.
#[derive(Debug, Clone, PartialEq)]
pub struct ExpectedAccuracy {
    pub fabrics: Vec<String>,
    pub mean_error: f64,
    pub worst_error: f64,
    pub pixel_error: f64,
    pub frame_ms: f64,
    pub bake_s: f64,
}

fn expected_from_csv(text: &str, quality: Quality) -> Option<ExpectedAccuracy> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next()?.split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name);
    let (fabric, method, preset) = (column("fabric")?, column("method")?, column("preset")?);
    let (mean, worst, pixel) =
        (column("all_mean_rel_rmse")?, column("all_worst_rel")?, column("all_pixel_rel_rmse")?);
    let (frame, bake) = (column("frame_ms")?, column("bake_s")?);
    let mut out = ExpectedAccuracy {
        fabrics: Vec::new(),
        mean_error: 0.0,
        worst_error: 0.0,
        pixel_error: 0.0,
        frame_ms: 0.0,
        bake_s: 0.0,
    };
    for line in lines {
        let cells: Vec<&str> = line.split(',').collect();
        if cells.len() != header.len() || cells[method] != "gpu" || cells[preset] != quality.name() {
            continue;
        }
        let number = |i: usize| cells[i].parse::<f64>().ok().filter(|v| v.is_finite());
        out.fabrics.push(cells[fabric].to_owned());
        out.mean_error += number(mean)?;
        out.pixel_error += number(pixel)?;
        out.frame_ms += number(frame)?;
        out.bake_s += number(bake)?;
        let w = number(worst)?;
        if w.abs() > out.worst_error.abs() {
            out.worst_error = w;
        }
    }
    let n = out.fabrics.len() as f64;
    if n == 0.0 {
        return None;
    }
    out.mean_error /= n;
    out.pixel_error /= n;
    out.frame_ms /= n;
    out.bake_s /= n;
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use twill_precompute::Rgb;

    #[test]
    fn knob_lists_parse_with_and_without_values_and_name_bad_input() {
        assert_eq!(parse_knobs("all").unwrap().len(), Knob::ALL.len());
        assert!(parse_knobs("none").unwrap().is_empty());
        let k = parse_knobs("sh_order=1/3,spp").unwrap();
        assert_eq!(k[0], (Knob::ShOrder, vec![1.0, 3.0]));
        assert_eq!(k[1], (Knob::Spp, Knob::Spp.default_values()));
        assert!(parse_knobs("sh_order=one").unwrap_err().to_string().contains("not a number"));
        assert!(format!("{:#}", parse_knobs("colour").unwrap_err()).contains("sh_order"));
    }

    #[test]
    fn the_report_names_each_knob_set_on_the_base() {
        let base = Quality::Draft.settings();
        assert!(base_changes(base, base).is_empty());
        let changed = BakeSettings { sh_order: 3, segment_pool_mfp: 0.5, ..base };
        let mut named = base_changes(base, changed);
        named.sort();
        assert_eq!(named, ["segment_pool_mfp = 0.5", "sh_order = 3"]);
    }

    #[test]
    fn the_viewer_reads_a_presets_expected_error_from_the_csv() {
        let csv = "fabric,method,preset,frame_ms,bake_s,all_mean_rel_rmse,all_worst_rel,all_pixel_rel_rmse\n\
                   default,gpu,draft,100,9,0.10,-0.2,0.5\n\
                   satin,gpu,draft,300,11,0.20,0.3,0.7\n\
                   default,cpu,draft,50,9,0.5,0.9,0.9\n\
                   default,gpu,interactive,200,20,0.05,0.1,0.4\n";
        let e = expected_from_csv(csv, Quality::Draft).unwrap();
        assert_eq!(e.fabrics, ["default", "satin"]);
        assert!((e.mean_error - 0.15).abs() < 1e-12 && (e.frame_ms - 200.0).abs() < 1e-9);
        assert!((e.worst_error - 0.3).abs() < 1e-12 && (e.bake_s - 10.0).abs() < 1e-9);
        assert!(expected_from_csv(csv, Quality::Paper).is_none());
        assert!(expected_from_csv("garbage", Quality::Draft).is_none());
    }

    #[test]
    fn error_maps_are_white_where_equal_and_saturate_at_the_scale() {
        let reference = Image { width: 2, height: 1, pixels: vec![Rgb::ONE, Rgb::ONE] };
        let image = Image { width: 2, height: 1, pixels: vec![Rgb::ONE, Rgb::splat(3.0)] };
        let uri = error_map_uri(&image, &reference, 0.5).unwrap();
        assert!(uri.starts_with("data:image/png;base64,"));
        let bytes =
            base64::engine::general_purpose::STANDARD.decode(&uri["data:image/png;base64,".len()..]).unwrap();
        let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut buf).unwrap();
        assert_eq!(&buf[..6], &[255, 255, 255, 255, 0, 0]);
    }
}
