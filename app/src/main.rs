//! The `twill` program: the desktop viewer (no arguments, or `twill view`) and the command line.
//!
//! Each subcommand loads a scene (a TOML file, or the built-in default scene when none is
//! given), builds what it needs and reports errors through anyhow with the file and place that
//! caused them. Long work shows a progress bar on stderr. The viewer is in `viewer/`.

mod accuracy_report;
mod colorways;
mod commands;
mod paint;
mod shard;
mod viewer;

use std::path::PathBuf;

use anyhow::Result;
use clap::{Parser, Subcommand, ValueEnum};

#[derive(Debug, Parser)]
#[command(
    name = "twill",
    version,
    about = "Fiber-level woven fabric rendering (Khungurn et al. 2017)",
    long_about = "Fiber-level woven fabric rendering (Khungurn et al. 2017). Without a command, \
                  opens the viewer on the built-in default fabric (`twill view`)."
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Open the desktop viewer (the default without a command).
    View(ViewArgs),
    /// Inspect, list and export fabrics.
    Fabric {
        #[command(subcommand)]
        command: FabricCommand,
    },
    /// Path-trace a fiber-level reference image of a scene.
    Reference(ReferenceArgs),
    /// Render a scene on the GPU (headless: any Vulkan adapter, lavapipe included).
    Render(RenderArgs),
    /// Render a set of named colourways of a scene (from a TOML file of `[[colorway]]`s) to
    /// PNG (and EXR) and a contact sheet with their names (docs/COLOURWAYS.md).
    Colorways(ColorwaysArgs),
    /// Precompute a scene's fabric (visibility, IIRTF, tables, volume) into a bake file; with
    /// `--shard I/N` one shard of it into a part file, joined by `twill bake merge`.
    #[command(args_conflicts_with_subcommands = true)]
    Bake {
        #[command(subcommand)]
        command: Option<BakeCommand>,
        #[command(flatten)]
        args: BakeArgs,
    },
    /// What accuracy costs in time: every knob swept on hard light/view configurations of
    /// several fabrics against cached path-traced references; writes report.html, report.csv
    /// and headline.md (`twill accuracy budget` explains one scene's error instead).
    #[command(args_conflicts_with_subcommands = true)]
    Accuracy {
        #[command(subcommand)]
        command: Option<AccuracyCommand>,
        #[command(flatten)]
        report: ReportArgs,
    },
    /// Albedo painting at path-traced quality (Hašan & Ramamoorthy 2013): precompute a view
    /// once, then see paintings of the yarns in milliseconds, and check them against the path
    /// tracer.
    Paint {
        #[command(subcommand)]
        command: paint::PaintCommand,
    },
    /// Measure speed and accuracy (figures for docs/BENCHMARKS.md).
    Bench {
        #[command(subcommand)]
        command: BenchCommand,
    },
}

#[derive(Debug, Subcommand)]
enum AccuracyCommand {
    /// The error budget: a ladder from exact light transport to the method, one approximation
    /// at a time, single and multiple scattering separately, each rung's error against the path
    /// tracer and its time (on a flat swatch of the scene's fabric, with its camera and lights).
    Budget {
        /// Scene file (default: the built-in default scene).
        scene: Option<PathBuf>,
        /// Bake quality.
        #[arg(long, value_enum, default_value = "interactive")]
        quality: QualityArg,
        /// Image size as WIDTHxHEIGHT.
        #[arg(long, value_parser = commands::parse_size, default_value = "64x64")]
        size: (usize, usize),
        /// Samples per pixel of every rung.
        #[arg(long, default_value_t = 16)]
        spp: u32,
        /// Samples per pixel of the path-traced references.
        #[arg(long, default_value_t = 64)]
        reference_spp: u32,
        /// Light samples per hit for SG lights in the exact single-scattering rungs.
        #[arg(long, default_value_t = 16)]
        light_samples: u32,
        /// Override one bake knob, as `twill bake --set` (repeatable).
        #[arg(long = "set", value_name = "KNOB=VALUE")]
        overrides: Vec<String>,
        /// Seed of every rung's and reference's samplers (another seed: independent noise, to
        /// tell a rung's bias from its noise).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Also split multiple scattering's transfer into the first neighbour's transmission,
        /// its reflection and light scattered twice or more (rungs 4a-4c; three more transfer
        /// bakes).
        #[arg(long)]
        split_transfer: bool,
    },
}

#[derive(Debug, clap::Args)]
struct ReportArgs {
    /// Fabric presets or scene files, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "default,silk_satin,gabardine_twill")]
    scenes: Vec<String>,
    /// Output folder (default: `accuracy/` in the stage cache folder); references are cached
    /// in its `references/`.
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Light/view configurations per fabric (the first four: head-on, grazing, backlit,
    /// grazing and backlit).
    #[arg(long, default_value_t = 12)]
    configurations: usize,
    /// Square image side in pixels.
    #[arg(long, default_value_t = 32)]
    size: usize,
    /// Samples per pixel of a reference (with `--reference-noise`, of its first pass).
    #[arg(long, default_value_t = 256)]
    reference_spp: u32,
    /// Render each reference again with fresh seeds, doubling its samples, until the standard
    /// error of each component's image mean (single and multiple scattering) is at most this
    /// fraction of it; a component under a quarter of all light is held to a quarter of all
    /// light (0: `--reference-spp` samples for every configuration).
    #[arg(long, default_value_t = 0.02)]
    reference_noise: f64,
    /// The most samples per pixel a reference takes toward `--reference-noise`.
    #[arg(long, default_value_t = 16384)]
    reference_max_spp: u32,
    /// Samples per pixel of the method's frames.
    #[arg(long, default_value_t = 16)]
    spp: u32,
    /// The preset the knobs are varied around.
    #[arg(long, value_enum, default_value = "draft")]
    base: QualityArg,
    /// Change one knob of the base preset before the knobs are varied around it, e.g. `--set
    /// sh_order=3` (repeatable; the knobs are the fields of `BakeSettings`, as `twill bake
    /// --set` takes). The presets measured as points are not changed.
    #[arg(long = "set", value_name = "KNOB=VALUE")]
    base_set: Vec<String>,
    /// Presets measured as points, comma-separated (`--presets` alone: none, only the knobs).
    #[arg(long, value_enum, value_delimiter = ',', num_args = 0.., default_value = "draft,interactive")]
    presets: Vec<QualityArg>,
    /// Knobs to sweep: `all`, `none`, or a comma list of names, each optionally with values as
    /// `name=v1/v2/...` (sh_order, pca_components, svf_resolution, visibility_points, sos_count,
    /// sos_sharpness, iirtf_paths_per_cell, iirtf_light_samples, cell_size_mfp, cell_depth_mfp,
    /// segment_transfer_paths, segment_pool_mfp, spp, sigma_glo_cm; visibility_bits,
    /// fiber_lobes and exposed_starts: 0 or 1; seed, the bake's random seed, whose points
    /// differ by the bake's noise alone). segment_pool_mfp is swept only around a base with
    /// segment transfers (`--base interactive`).
    #[arg(long, default_value = "all")]
    knobs: String,
    /// Skip the CPU version of the method at the presets.
    #[arg(long)]
    no_cpu: bool,
    /// Configurations shown as images in the report.
    #[arg(long, default_value_t = 4)]
    examples: usize,
}

#[derive(Debug, Subcommand)]
enum BenchCommand {
    /// Incoherent fiber ray casting on the scene's fabric: rays per second per core for camera
    /// and scatter rays, closest and any hit (what reference renders, visibility and the IIRTF
    /// cast).
    Raycast {
        /// Scene file (default: the built-in default scene).
        scene: Option<PathBuf>,
        /// Side of the square swatch the rays are cast at, cm.
        #[arg(long, default_value_t = 2.0)]
        swatch_cm: f32,
        /// Rays per family.
        #[arg(long, default_value_t = 32_768)]
        rays: usize,
        /// Least time each measurement casts for, seconds (the best pass counts).
        #[arg(long, default_value_t = 2.0)]
        seconds: f64,
        /// Measure Embree 3 (round linear curves over explicit copies of the exemplar) beside
        /// our caster (a twill built with `--features embree`).
        #[arg(long)]
        embree: bool,
    },
    /// GPU time per pass of a scene's frame: the median over several frames after a warm-up.
    Passes {
        /// Scene file (default: the built-in default scene).
        scene: Option<PathBuf>,
        /// Image size as WIDTHxHEIGHT.
        #[arg(long, value_parser = commands::parse_size, default_value = "512x512")]
        size: (usize, usize),
        #[arg(long, default_value_t = 1)]
        spp: u32,
        /// Bake quality.
        #[arg(long, value_enum, default_value = "draft")]
        quality: QualityArg,
        /// Frames measured (after one warm-up frame).
        #[arg(long, default_value_t = 5)]
        frames: usize,
    },
    /// The time from a colour edit to its full picture over random recolourings of the
    /// scene's yarns (near-black and near-white included): material rebake, upload, one frame.
    Recolor {
        /// Scene file (default: the built-in default scene).
        scene: Option<PathBuf>,
        /// Image size as WIDTHxHEIGHT.
        #[arg(long, value_parser = commands::parse_size, default_value = "512x512")]
        size: (usize, usize),
        #[arg(long, default_value_t = 1)]
        spp: u32,
        /// Bake quality.
        #[arg(long, value_enum, default_value = "interactive")]
        quality: QualityArg,
        /// How many random colourways.
        #[arg(long, default_value_t = 20)]
        colourways: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// IIRTF paths per cell of the basis and the rebakes (default: the quality's).
        #[arg(long)]
        iirtf_paths: Option<usize>,
        /// Also write each colourway's live and rebaked pictures (PNG) into this folder, to
        /// look at side by side.
        #[arg(long)]
        images: Option<PathBuf>,
        /// Also render each colourway from the basis's own paths evaluated at its colours
        /// exactly in τ and to first order in C_R, as the basis holds C_R (the rebake walks the
        /// same paths and weighs C_R exactly): splits the live picture's error into the basis's
        /// curves and its first order in C_R (one basis pass per colourway).
        #[arg(long)]
        same_paths: bool,
    },
    /// The viewer's own frame times while a bake runs in the background (needs a display:
    /// run under `xvfb-run -a` without one). The bake starts from an empty stage cache.
    Ui {
        /// Scene file (default: the built-in default scene).
        scene: Option<PathBuf>,
        /// Quality of the background bake.
        #[arg(long, value_enum, default_value = "interactive")]
        quality: QualityArg,
        /// How long to orbit the view (and measure), seconds.
        #[arg(long, default_value_t = 20.0)]
        seconds: f64,
        /// Window size in points, WIDTHxHEIGHT.
        #[arg(long, value_parser = commands::parse_size, default_value = "1280x800")]
        window_size: (usize, usize),
    },
    /// The paper's Fig. 13 experiment on a flat swatch of the scene's fabric: RMSE of the
    /// average intensity over many light/view configurations against path-traced references,
    /// per method, and the path tracer's cost at equal error.
    Accuracy {
        /// Scene file whose fabric is used (default: the built-in default scene).
        scene: Option<PathBuf>,
        #[arg(long, default_value_t = 50)]
        configurations: usize,
        /// Square image side in pixels.
        #[arg(long, default_value_t = 32)]
        size: usize,
        #[arg(long, default_value_t = 256)]
        reference_spp: u32,
        /// Samples per pixel of the method's images.
        #[arg(long, default_value_t = 16)]
        spp: u32,
        /// Skip the GPU method.
        #[arg(long)]
        no_gpu: bool,
        /// Path-tracer spp for the equal-error fit.
        #[arg(long, value_delimiter = ',', default_value = "1,2,4,8")]
        ladder: Vec<u32>,
        /// Bake quality.
        #[arg(long, value_enum, default_value = "draft")]
        quality: QualityArg,
        /// Skip the CPU version of the method.
        #[arg(long)]
        no_cpu: bool,
    },
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum QualityArg {
    /// Fastest useful bake (first picture).
    Draft,
    /// Sized for seconds on the default fabric.
    Interactive,
    /// The 2017 paper's settings.
    Paper,
}

#[derive(Debug, clap::Args)]
struct ViewArgs {
    /// Scene file (default: the built-in default scene).
    scene: Option<PathBuf>,
    /// Bake quality the viewer refines to after the draft bake.
    #[arg(long, value_enum, default_value = "interactive")]
    quality: QualityArg,
    /// Window size in points, WIDTHxHEIGHT.
    #[arg(long, value_parser = commands::parse_size, default_value = "1280x800")]
    window_size: (usize, usize),
    /// Play a script of edits and screenshots, then close (for tests; see app/src/viewer/script.rs).
    #[arg(long, hide = true)]
    script: Option<PathBuf>,
}

impl Default for ViewArgs {
    fn default() -> Self {
        Self { scene: None, quality: QualityArg::Interactive, window_size: (1280, 800), script: None }
    }
}

#[derive(Debug, clap::Args)]
#[allow(clippy::struct_excessive_bools)]
struct BakeArgs {
    /// Scene file (default: the built-in default scene).
    scene: Option<PathBuf>,
    /// Quality preset.
    #[arg(long, value_enum, default_value = "interactive")]
    quality: QualityArg,
    /// Output bake file (default: SCENE-STEM.QUALITY.twillbake in the current folder).
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Stage cache folder (default: $TWILL_CACHE_DIR, else $XDG_CACHE_HOME/twill, else ~/.cache/twill).
    #[arg(long, conflicts_with = "no_cache")]
    cache: Option<PathBuf>,
    /// Recompute every stage and cache nothing.
    #[arg(long)]
    no_cache: bool,
    /// Override one knob of the quality preset, e.g. `--set iirtf_paths_per_cell=500`
    /// (repeatable; the knobs are the fields of `BakeSettings`, see docs/BENCHMARKS.md).
    #[arg(long = "set", value_name = "KNOB=VALUE")]
    overrides: Vec<String>,
    /// Print the stage cache's folder, entries, size and size limit, and bake nothing
    /// (the limit: $TWILL_CACHE_MAX_MB, default 4096; least recently used entries go first).
    #[arg(long, conflicts_with = "no_cache")]
    cache_info: bool,
    /// Delete every entry of the stage cache, and bake nothing.
    #[arg(long, conflicts_with = "no_cache")]
    cache_clear: bool,
    /// Compute shard I of N (0-based, e.g. 0/4) of the bake's visibility images and IIRTF
    /// cells into a part file (default SCENE-STEM.QUALITY.partIofN.twillpart); join the N
    /// parts with `twill bake merge`. Uses no stage cache.
    #[arg(long, value_name = "I/N", conflicts_with_all = ["cache_info", "cache_clear"])]
    shard: Option<String>,
    /// Bake on a Slurm cluster: submit a job array of N shards and a merge job that depends on
    /// it (scripts, part files and logs in OUTPUT.shards/), then follow them until the bake
    /// file is written. Needs sbatch and scontrol (and SLURM_CONF where the cluster wants it).
    #[arg(long, value_name = "N", conflicts_with_all = ["shard", "cache_info", "cache_clear"])]
    slurm: Option<usize>,
    /// With --slurm: the partition to submit to.
    #[arg(long, requires = "slurm")]
    partition: Option<String>,
    /// With --slurm: submit and return without following the jobs.
    #[arg(long, requires = "slurm")]
    no_wait: bool,
}

#[derive(Debug, Subcommand)]
enum BakeCommand {
    /// Join the part files of every shard of a sharded bake (`twill bake --shard I/N`) into
    /// its bake file: the same bytes a single `twill bake` of the scene writes.
    Merge {
        /// The part files, one per shard, in any order.
        #[arg(required = true)]
        parts: Vec<PathBuf>,
        /// Output bake file.
        #[arg(short, long)]
        output: PathBuf,
    },
}

#[derive(Debug, Subcommand)]
enum FabricCommand {
    /// List the built-in fabric presets.
    Presets,
    /// Print fiber and segment counts, bounds, volume fraction and the mean free path.
    Info {
        /// Scene file (default: the built-in default scene).
        scene: Option<PathBuf>,
        /// Rays cast to measure the mean free path.
        #[arg(long, default_value_t = 20_000)]
        mfp_samples: usize,
    },
    /// Write the scene's fabric exemplar as a fiber file.
    Export {
        /// Scene file (default: the built-in default scene).
        scene: Option<PathBuf>,
        #[arg(long, value_enum)]
        format: FiberFormat,
        /// Output file.
        #[arg(short, long)]
        output: PathBuf,
    },
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum FiberFormat {
    /// Mitsuba's curve text format (`x y z radius` per line, blank line between fibers).
    Mitsuba,
    /// The cyHair `.hair` binary format.
    Hair,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum Only {
    /// Light scattered exactly once by a fiber.
    Single,
    /// Light scattered two or more times.
    Multiple,
}

#[derive(Debug, clap::Args)]
struct ReferenceArgs {
    #[command(flatten)]
    image: commands::ImageOptions,
    /// Maximum number of scattering events per path (default: the scene's).
    #[arg(long)]
    max_depth: Option<u32>,
    /// Render only one scattering component.
    #[arg(long, value_enum)]
    only: Option<Only>,
    /// Random seed (default: the scene's).
    #[arg(long)]
    seed: Option<u64>,
    /// Paint the cloth with this painting first (TOML strokes, as `twill paint apply` takes).
    #[arg(long)]
    painting: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
#[allow(clippy::struct_excessive_bools)]
struct RenderArgs {
    #[command(flatten)]
    image: commands::ImageOptions,
    /// Bake quality when the fabric is baked for this render.
    #[arg(long, value_enum, default_value = "interactive")]
    quality: QualityArg,
    /// Use this bake file instead of baking (it must be the scene's fabric).
    #[arg(long, conflicts_with = "quality")]
    bake: Option<PathBuf>,
    /// Stage cache folder for baking (default as for `twill bake`).
    #[arg(long, conflicts_with = "no_cache")]
    cache: Option<PathBuf>,
    /// Bake without the stage cache.
    #[arg(long)]
    no_cache: bool,
    /// Render only one scattering component.
    #[arg(long, value_enum)]
    only: Option<Only>,
    /// Print the frame plan (the passes this scene needs) before rendering.
    #[arg(long)]
    print_plan: bool,
    /// Print GPU time per pass (timestamp queries) and GPU memory used.
    #[arg(long)]
    timings: bool,
}

#[derive(Debug, clap::Args)]
struct ColorwaysArgs {
    /// Scene file (default: the built-in default scene); its `warp` and `weft` yarns are the
    /// palette's bases.
    scene: Option<PathBuf>,
    /// The colourways: `[[colorway]]` entries with `name`, `warp_order`, `weft_order` and a
    /// `[colorway.palette]` (as a scene's `[materials]`).
    #[arg(long)]
    from: PathBuf,
    /// Output folder (made if missing).
    #[arg(short, long)]
    output: PathBuf,
    /// Image size as WIDTHxHEIGHT (default: the scene's).
    #[arg(long, value_parser = commands::parse_size)]
    size: Option<(usize, usize)>,
    /// Samples per pixel (default: the scene's).
    #[arg(long)]
    spp: Option<u32>,
    /// Bake quality for the GPU renders.
    #[arg(long, value_enum, default_value = "interactive", conflicts_with = "reference")]
    quality: QualityArg,
    /// Path-trace each colourway instead of rendering it on the GPU.
    #[arg(long)]
    reference: bool,
    /// Write each colourway as linear EXR too.
    #[arg(long)]
    exr: bool,
    /// Stage cache folder for baking (default as for `twill bake`).
    #[arg(long, conflicts_with = "no_cache")]
    cache: Option<PathBuf>,
    /// Bake without the stage cache.
    #[arg(long)]
    no_cache: bool,
}

fn quality_of(q: QualityArg) -> twill_precompute::bake::settings::Quality {
    match q {
        QualityArg::Draft => twill_precompute::bake::settings::Quality::Draft,
        QualityArg::Interactive => twill_precompute::bake::settings::Quality::Interactive,
        QualityArg::Paper => twill_precompute::bake::settings::Quality::Paper,
    }
}

fn main() -> std::process::ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(error) => {
            // Every error's message already names the file, place and value (and includes its
            // cause), so the top-level message is the whole story.
            eprintln!("error: {error}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    let Some(command) = cli.command else { return view(ViewArgs::default()) };
    match command {
        Command::View(args) => view(args),
        Command::Fabric { command } => match command {
            FabricCommand::Presets => {
                commands::fabric_presets();
                Ok(())
            }
            FabricCommand::Info { scene, mfp_samples } => {
                commands::fabric_info(scene.as_deref(), mfp_samples)
            }
            FabricCommand::Export { scene, format, output } => {
                commands::fabric_export(scene.as_deref(), matches!(format, FiberFormat::Hair), &output)
            }
        },
        Command::Bake { command: Some(BakeCommand::Merge { parts, output }), .. } => {
            shard::merge(&parts, &output)
        }
        Command::Bake { command: None, args } if args.slurm.is_some() => {
            let quality = quality_of(args.quality);
            shard::bake_slurm(&shard::SlurmOptions {
                scene: args.scene.as_deref(),
                quality,
                overrides: &args.overrides,
                shards: args.slurm.unwrap_or(1),
                partition: args.partition.as_deref(),
                output: args
                    .output
                    .unwrap_or_else(|| commands::default_bake_path(args.scene.as_deref(), quality)),
                no_wait: args.no_wait,
            })
        }
        Command::Bake { command: None, args } if args.shard.is_some() => shard::bake_shard(
            args.scene.as_deref(),
            quality_of(args.quality),
            &args.overrides,
            args.shard.as_deref().unwrap_or_default(),
            args.output,
        ),
        Command::Bake { command: None, args } => commands::bake(&commands::BakeOptions {
            scene: args.scene,
            quality: quality_of(args.quality),
            output: args.output,
            cache: args.cache,
            no_cache: args.no_cache,
            overrides: args.overrides,
            cache_info: args.cache_info,
            cache_clear: args.cache_clear,
        }),
        Command::Colorways(args) => colorways::colorways(&colorways::ColorwaysOptions {
            scene: args.scene,
            from: args.from,
            output_dir: args.output,
            size: args.size,
            spp: args.spp,
            quality: quality_of(args.quality),
            reference: args.reference,
            exr: args.exr,
            cache: args.cache,
            no_cache: args.no_cache,
        }),
        Command::Render(args) => commands::render(&commands::RenderOptions {
            image: args.image,
            quality: quality_of(args.quality),
            bake: args.bake,
            cache: args.cache,
            no_cache: args.no_cache,
            only: args.only.map(|o| match o {
                Only::Single => twill_renderer::plan::Components::SingleOnly,
                Only::Multiple => twill_renderer::plan::Components::MultipleOnly,
            }),
            print_plan: args.print_plan,
            timings: args.timings,
        }),
        Command::Accuracy { command: None, report } => {
            accuracy_report::run(&accuracy_report::ReportOptions {
                scenes: report.scenes,
                output: report.output,
                settings: twill_renderer::accuracy::sweep::SweepSettings {
                    configurations: report.configurations,
                    size: report.size,
                    reference_spp: report.reference_spp,
                    reference_noise: (report.reference_noise != 0.0).then_some(report.reference_noise),
                    reference_max_spp: report.reference_max_spp,
                    method_spp: report.spp,
                    base: quality_of(report.base),
                    base_bake: commands::apply_overrides(
                        quality_of(report.base).settings(),
                        &report.base_set,
                    )?,
                    presets: report.presets.into_iter().map(quality_of).collect(),
                    knobs: accuracy_report::parse_knobs(&report.knobs)?,
                    cpu_method: !report.no_cpu,
                    max_depth: 64,
                    example_images: report.examples,
                },
            })
        }
        Command::Accuracy {
            command:
                Some(AccuracyCommand::Budget {
                    scene,
                    quality,
                    size,
                    spp,
                    reference_spp,
                    light_samples,
                    overrides,
                    seed,
                    split_transfer,
                }),
            ..
        } => commands::accuracy_budget(
            scene.as_deref(),
            quality_of(quality),
            &overrides,
            size,
            &twill_precompute::shading::budget::BudgetSettings {
                spp,
                reference_spp,
                light_samples,
                seed,
                split_transfer,
            },
        ),
        Command::Bench { command } => match command {
            BenchCommand::Ui { scene, quality, seconds, window_size } => {
                let size = [window_size.0 as u32, window_size.1 as u32];
                let report = viewer::bench_ui(scene, quality_of(quality), seconds, size)?;
                println!("UI frame times (orbiting every frame; bake: {quality:?}, {seconds} s):\n{report}");
                Ok(())
            }
            BenchCommand::Recolor {
                scene,
                size,
                spp,
                quality,
                colourways,
                seed,
                iirtf_paths,
                images,
                same_paths,
            } => commands::bench_recolor(
                scene.as_deref(),
                size,
                spp,
                quality_of(quality),
                &commands::RecolorRun { count: colourways, seed, iirtf_paths, images, same_paths },
            ),
            BenchCommand::Raycast { scene, swatch_cm, rays, seconds, embree } => {
                commands::bench_raycast(scene.as_deref(), swatch_cm, rays, seconds, embree)
            }
            BenchCommand::Passes { scene, size, spp, quality, frames } => {
                commands::bench_passes(scene.as_deref(), size, spp, quality_of(quality), frames)
            }
            BenchCommand::Accuracy {
                scene,
                configurations,
                size,
                reference_spp,
                spp,
                no_gpu,
                ladder,
                quality,
                no_cpu,
            } => commands::bench_accuracy(
                scene.as_deref(),
                quality_of(quality),
                &twill_renderer::accuracy::ExperimentSettings {
                    configurations,
                    size,
                    reference_spp,
                    method_spp: spp,
                    gpu_method: !no_gpu,
                    cpu_method: !no_cpu,
                    ladder_spp: ladder,
                    max_depth: 64,
                },
            ),
        },
        Command::Reference(args) => commands::reference(&commands::ReferenceOptions {
            image: args.image,
            max_depth: args.max_depth,
            only: args.only.map(|o| match o {
                Only::Single => twill_precompute::pathtrace::Component::Single,
                Only::Multiple => twill_precompute::pathtrace::Component::Multiple,
            }),
            seed: args.seed,
            painting: args.painting,
        }),
        Command::Paint { command } => paint::run(command),
    }
}

fn view(args: ViewArgs) -> Result<()> {
    viewer::run(viewer::ViewerOptions {
        scene: args.scene,
        quality: quality_of(args.quality),
        script: args.script,
        window_size: [args.window_size.0 as u32, args.window_size.1 as u32],
        cache_dir: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_bad_sizes_name_the_valid_form() {
        assert_eq!(commands::parse_size("256x128"), Ok((256, 128)));
        assert!(commands::parse_size("0x5").unwrap_err().contains("WIDTHxHEIGHT"));
        assert!(commands::parse_size("abc").is_err());
        assert!(commands::parse_size("20000x2").is_err());
    }

    #[test]
    fn the_command_line_is_well_formed() {
        use clap::CommandFactory;
        Cli::command().debug_assert();
    }
}
