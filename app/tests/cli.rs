//! End-to-end tests of the `twill` command line: each runs the real binary.

use std::path::Path;
use std::process::{Command, Output};

fn twill(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_twill")).args(args).current_dir(dir).output().expect("twill runs")
}

fn twill_env(args: &[&str], dir: &Path, vars: &[(&str, &str)]) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_twill"));
    command.args(args).current_dir(dir).envs(vars.iter().copied());
    command.output().expect("twill runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn no_arguments_open_the_viewer_which_says_when_there_is_no_display() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_twill"))
        .current_dir(dir.path())
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .expect("twill runs");
    assert!(!out.status.success());
    let stderr = text(&out.stderr);
    assert!(stderr.contains("the viewer needs an X11 display") && stderr.contains("xvfb-run"), "{stderr}");
}

#[test]
fn help_lists_the_viewer_and_the_subcommands() {
    let dir = tempfile::tempdir().unwrap();
    let out = twill(&["--help"], dir.path());
    assert!(out.status.success());
    let stdout = text(&out.stdout);
    for command in ["view", "render", "reference", "bake"] {
        assert!(stdout.contains(command), "missing {command:?} in\n{stdout}");
    }
}

#[test]
fn fabric_info_reports_counts_and_mean_free_path() {
    let dir = tempfile::tempdir().unwrap();
    let out = twill(&["fabric", "info", "--mfp-samples", "2000"], dir.path());
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    for key in ["fibers", "segments", "volume fraction", "mean free path", "periodic"] {
        assert!(stdout.contains(key), "missing {key:?} in\n{stdout}");
    }
}

#[test]
fn exported_fibers_reimport_as_a_tiled_exemplar_and_render() {
    let dir = tempfile::tempdir().unwrap();
    for format in ["mitsuba", "hair"] {
        let file = if format == "hair" { "fibers.hair" } else { "fibers.txt" };
        let out = twill(&["fabric", "export", "--format", format, "-o", file], dir.path());
        assert!(out.status.success(), "{}", text(&out.stderr));

        // The default fabric's period is 0.14 cm; tile the imported fibers with it.
        let scene = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/scenes/default.toml"),
        )
        .unwrap()
        .replace(
            "preset = \"default\"",
            &format!("spec = {{ file = \"{file}\", tiling = {{ period = [0.14, 0.14] }} }}"),
        );
        std::fs::write(dir.path().join("imported.toml"), scene).unwrap();
        let info = twill(&["fabric", "info", "imported.toml", "--mfp-samples", "500"], dir.path());
        assert!(info.status.success(), "{}", text(&info.stderr));
        assert!(text(&info.stdout).contains("fibers           1296"), "{}", text(&info.stdout));

        let out =
            twill(&["reference", "imported.toml", "-o", "x.exr", "--size", "12x8", "--spp", "2"], dir.path());
        assert!(out.status.success(), "{}", text(&out.stderr));
        let image = exr::prelude::read_first_rgba_layer_from_file(
            dir.path().join("x.exr"),
            |size, _| (size.width(), size.height()),
            |_: &mut (usize, usize), _, _: (f32, f32, f32, f32)| {},
        )
        .unwrap();
        assert_eq!(image.layer_data.channel_data.pixels, (12, 8));
    }
}

#[test]
fn reference_writes_png_for_each_component() {
    let dir = tempfile::tempdir().unwrap();
    for only in ["single", "multiple"] {
        let out =
            twill(&["reference", "-o", "x.png", "--size", "8x8", "--spp", "1", "--only", only], dir.path());
        assert!(out.status.success(), "{}", text(&out.stderr));
        assert!(text(&out.stderr).contains(if only == "single" { "Single" } else { "Multiple" }));
        assert!(dir.path().join("x.png").metadata().unwrap().len() > 0);
    }
}

#[test]
fn bad_input_is_a_clear_error_never_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("bad.toml"),
        "[fabric]\npreset = \"default\"\n[camera]\nprojection = \"fisheye\"\n",
    )
    .unwrap();
    let cases: &[(&[&str], &str)] = &[
        (&["reference", "bad.toml", "-o", "x.png"], "bad.toml"),
        (&["reference", "missing.toml", "-o", "x.png"], "missing.toml"),
        (&["reference", "-o", "x.jpg", "--size", "4x4", "--spp", "1"], "x.jpg"),
        (&["reference", "-o", "x.png", "--size", "0x4"], "WIDTHxHEIGHT"),
        (&["reference", "-o", "x.png", "--spp", "0"], "spp"),
        (
            &["accuracy", "budget", "--quality", "draft", "--set", "cell_depth_mfp=0"],
            "0.25 <= cell_depth_mfp <= 64",
        ),
        (&["accuracy", "budget", "missing.toml"], "missing.toml"),
        (
            &["fabric", "export", "--format", "mitsuba", "-o", "/nonexistent-dir/f.txt"],
            "/nonexistent-dir/f.txt",
        ),
    ];
    for (args, needle) in cases {
        let out = twill(args, dir.path());
        let stderr = text(&out.stderr);
        assert!(!out.status.success(), "{args:?} should fail");
        assert!(!stderr.contains("panicked"), "{args:?} panicked:\n{stderr}");
        assert!(stderr.contains(needle), "{args:?}: expected {needle:?} in\n{stderr}");
    }
    let stderr = text(&twill(&["reference", "bad.toml", "-o", "x.png"], dir.path()).stderr);
    assert!(stderr.contains("line 4") && stderr.contains("fisheye"), "{stderr}");
}

#[test]
fn bake_writes_a_bake_file_and_reports_every_stage() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let cache_arg = cache.to_str().unwrap();
    let out = twill(&["bake", "--quality", "draft", "--cache", cache_arg, "-o", "d.twillbake"], dir.path());
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    for stage in ["mean_free_path", "visibility", "transfer", "cs_tables", "gn_tables", "cg_table", "volume"]
    {
        assert!(stderr.contains(stage), "missing {stage} in\n{stderr}");
    }
    assert!(dir.path().join("d.twillbake").metadata().unwrap().len() > 1000);
    // The second bake comes entirely from the stage cache.
    let again = twill(&["bake", "--quality", "draft", "--cache", cache_arg, "-o", "d.twillbake"], dir.path());
    let again = text(&again.stderr);
    for stage in ["mean_free_path", "visibility", "transfer", "cs_tables", "gn_tables", "cg_table", "volume"]
    {
        let line = again.lines().find(|l| l.trim_start().starts_with(stage));
        assert!(
            line.is_some_and(|l| l.split_whitespace().nth(1) == Some("cached")),
            "{stage} should come from the cache:\n{again}"
        );
    }

    // The bake is refused for a scene of another fabric, naming the file and both fabrics.
    std::fs::write(
        dir.path().join("gabardine.toml"),
        "[fabric]\npreset = \"gabardine_twill\"\n[camera]\neye = [0, 1, 2]\ntarget = [0, 0, 0]\n\
         [[lights]]\ntype = \"directional\"\ndirection = [0, 0, 1]\nirradiance = [1, 1, 1]\n",
    )
    .unwrap();
    let out = twill(&["render", "gabardine.toml", "--bake", "d.twillbake", "-o", "g.png"], dir.path());
    let stderr = text(&out.stderr);
    assert!(!out.status.success() && stderr.contains("d.twillbake"), "{stderr}");
    assert!(stderr.contains("another fabric") && stderr.matches("segments").count() >= 2, "{stderr}");
    assert!(!dir.path().join("g.png").exists());

    // --cache-info lists the entries; --cache-clear empties the folder; a bad limit is named.
    let info = twill(&["bake", "--cache", cache_arg, "--cache-info"], dir.path());
    let listed = text(&info.stdout);
    assert!(info.status.success() && listed.contains("7 entries") && listed.contains("4096 MB"), "{listed}");
    let limited = twill_env(
        &["bake", "--cache", cache_arg, "--cache-info"],
        dir.path(),
        &[("TWILL_CACHE_MAX_MB", "64")],
    );
    assert!(text(&limited.stdout).contains("of 64 MB"), "{}", text(&limited.stdout));
    let bad = twill_env(
        &["bake", "--cache", cache_arg, "--cache-info"],
        dir.path(),
        &[("TWILL_CACHE_MAX_MB", "-3")],
    );
    assert!(!bad.status.success() && text(&bad.stderr).contains("1..=1000000000"), "{}", text(&bad.stderr));
    let cleared = twill(&["bake", "--cache", cache_arg, "--cache-clear"], dir.path());
    assert!(
        cleared.status.success() && text(&cleared.stdout).contains("0 entries"),
        "{}",
        text(&cleared.stderr)
    );
    assert!(text(&cleared.stderr).contains("deleted 7 cache entries"), "{}", text(&cleared.stderr));

    // A file where the cache folder should be, and an unwritable output, are clear errors.
    std::fs::write(dir.path().join("not-a-dir"), "x").unwrap();
    let out =
        twill(&["bake", "--quality", "draft", "--cache", "not-a-dir/c", "-o", "e.twillbake"], dir.path());
    assert!(!out.status.success() && text(&out.stderr).contains("not-a-dir"), "{}", text(&out.stderr));
    let out = twill(
        &["bake", "--quality", "draft", "--cache", cache_arg, "-o", "/nonexistent-dir/x.twillbake"],
        dir.path(),
    );
    assert!(!out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stderr).contains("/nonexistent-dir/x.twillbake"), "{}", text(&out.stderr));
}

/// `twill accuracy` end to end on a tiny sweep (GPU frames on lavapipe without a GPU): the
/// CSV has a row per point with finite errors, the HTML holds plots and images, the viewer's
/// copy is written, and references are reused on the next run unless a file is damaged.
#[test]
fn accuracy_report_writes_csv_and_html_and_reuses_only_valid_references() {
    let dir = tempfile::tempdir().unwrap();
    let run = |knobs: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_twill"))
            .args([
                "accuracy",
                "--scenes",
                "default",
                "--configurations",
                "2",
                "--size",
                "8",
                "--reference-spp",
                "4",
                "--spp",
                "2",
                "--presets",
                "draft",
                "--no-cpu",
                "--examples",
                "1",
                "--knobs",
                knobs,
                "-o",
                "out",
            ])
            .env("TWILL_CACHE_DIR", dir.path().join("cache"))
            .current_dir(dir.path())
            .output()
            .expect("twill runs");
        let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
        assert!(out.status.success(), "{stdout}\n{stderr}");
        (stdout, stderr)
    };
    let (stdout, stderr) = run("sh_order=1,spp=3");
    assert!(stderr.contains("reference 1/2") && stdout.contains("0 of 2 loaded"), "{stdout}\n{stderr}");
    let csv = std::fs::read_to_string(dir.path().join("out/report.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows.len(), 4, "header + draft + two knob points:\n{csv}");
    let header: Vec<&str> = rows[0].split(',').collect();
    for row in &rows[1..] {
        let cells: Vec<&str> = row.split(',').collect();
        assert_eq!(cells.len(), header.len(), "{row}");
        for (name, cell) in header.iter().zip(&cells) {
            if name.ends_with("_rel_rmse")
                || name.ends_with("_ssim")
                || *name == "frame_ms"
                || *name == "bake_s"
            {
                let v: f64 = cell.parse().unwrap_or_else(|_| panic!("{name} = {cell:?}"));
                assert!(v.is_finite() && v >= 0.0, "{name} = {v} in {row}");
            }
        }
    }
    assert!(rows[2].contains("sh_order = 1") && rows[3].contains("spp = 3"), "{csv}");
    let html = std::fs::read_to_string(dir.path().join("out/report.html")).unwrap();
    assert!(html.matches("<svg").count() >= 4, "two Pareto plots and one per knob");
    let per_configuration = std::fs::read_to_string(dir.path().join("out/configurations.csv")).unwrap();
    assert_eq!(per_configuration.lines().count(), 1 + 3 * 2, "a row per point and configuration");
    assert!(
        html.contains("data:image/png;base64,")
            && html.contains("Pareto")
            && html.contains("By kind of configuration")
    );
    assert!(std::fs::read_to_string(dir.path().join("out/headline.md")).unwrap().contains("| draft | GPU |"));
    assert_eq!(std::fs::read_to_string(dir.path().join("cache/accuracy/latest-report.csv")).unwrap(), csv);

    let (stdout, stderr) = run("none");
    assert!(stdout.contains("2 of 2 loaded") && !stderr.contains("reference 1/2"), "{stdout}\n{stderr}");

    // A damaged reference is rendered again, never trusted.
    let references = dir.path().join("out/references");
    let damaged = std::fs::read_dir(&references).unwrap().next().unwrap().unwrap().path();
    let mut bytes = std::fs::read(&damaged).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x40;
    std::fs::write(&damaged, bytes).unwrap();
    let (stdout, _) = run("none");
    assert!(stdout.contains("1 of 2 loaded"), "{stdout}");
    assert!(
        std::fs::read_dir(dir.path().join("out"))
            .unwrap()
            .all(|e| { !e.unwrap().file_name().to_string_lossy().starts_with("stage-cache-") }),
        "the run's private stage cache is removed"
    );
}

#[test]
fn accuracy_report_rejects_bad_knobs_and_fabrics_by_name() {
    let dir = tempfile::tempdir().unwrap();
    for (args, needle) in [
        (&["accuracy", "--knobs", "colour"][..], "sh_order"),
        (&["accuracy", "--knobs", "sh_order=7", "-o", "o"][..], "0 <= sh_order <= 6"),
        (&["accuracy", "--scenes", "no_such_fabric", "-o", "o"][..], "no_such_fabric"),
        (&["accuracy", "--size", "2", "-o", "o"][..], "4..=1024"),
    ] {
        let out = twill(args, dir.path());
        let stderr = text(&out.stderr);
        assert!(!out.status.success(), "{args:?} should fail");
        assert!(!stderr.contains("panicked"), "{args:?} panicked:\n{stderr}");
        assert!(stderr.contains(needle), "{args:?}: expected {needle:?} in\n{stderr}");
    }
}

/// `twill bake` killed with SIGKILL mid-bake, at several points in time: the previous bake file
/// stays intact (never half-written), every stage-cache entry left behind opens and passes its
/// checksum, and the next run removes the killed writers' temporaries, reuses what was stored
/// and recomputes the rest.
#[test]
fn a_killed_bake_loses_nothing_and_the_next_run_recomputes_only_what_was_lost() {
    use std::time::{Duration, Instant};
    use twill_precompute::bake::file::BakeFile;
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let cache_arg = cache.to_str().unwrap();
    let bake = |seed: &str| {
        let mut command = Command::new(env!("CARGO_BIN_EXE_twill"));
        command
            .args(["bake", "--quality", "draft", "--cache", cache_arg, "-o", "out.twillbake", "--set"])
            .arg(format!("seed={seed}"))
            .current_dir(dir.path());
        command
    };
    // A finished bake (timed), then bakes of other seeds killed at different moments.
    let started = Instant::now();
    let first = bake("1").output().unwrap();
    let full = started.elapsed();
    assert!(first.status.success(), "{}", text(&first.stderr));
    let out = dir.path().join("out.twillbake");
    let previous = std::fs::read(&out).unwrap();
    let entries = || {
        std::fs::read_dir(&cache)
            .unwrap()
            .filter_map(Result::ok)
            .filter(|e| e.path().extension().is_some_and(|x| x == "twillbake"))
            .count()
    };
    let mut stored_by_last_kill = 0;
    for (i, fraction) in [0.15, 0.45, 0.8].into_iter().enumerate() {
        let before = entries();
        let seed = format!("{}", i + 2);
        // Each killed run starts from the entries the earlier kills left behind.
        let mut child = bake(&seed).stderr(std::process::Stdio::null()).spawn().unwrap();
        std::thread::sleep(full.mul_f64(fraction).max(Duration::from_millis(200)));
        child.kill().unwrap();
        child.wait().unwrap();
        // The output is the previous bake or a complete new one, never a torn file.
        let now = std::fs::read(&out).unwrap();
        if now != previous {
            BakeFile::open_unkeyed(&out).expect("a replaced bake file is complete");
        }
        for entry in std::fs::read_dir(&cache).unwrap().filter_map(Result::ok) {
            let path = entry.path();
            if path.extension().is_some_and(|x| x == "twillbake") {
                BakeFile::open_unkeyed(&path)
                    .unwrap_or_else(|e| panic!("torn cache entry after a kill: {e}"));
            }
        }
        stored_by_last_kill = entries() - before;
        let temporaries = [dir.path(), cache.as_path()]
            .iter()
            .flat_map(|f| std::fs::read_dir(f).unwrap().filter_map(Result::ok))
            .filter(|e| e.path().extension().is_some_and(|x| x == "tmp"))
            .count();
        eprintln!(
            "killed at {:.0}% of a bake: {stored_by_last_kill} stage entries stored, {temporaries} temporaries left, output {}",
            100.0 * fraction,
            if now == previous { "unchanged" } else { "replaced" }
        );
    }
    // The next run of the last killed seed finishes, keeps what its killed run stored, and
    // leaves no temporary anywhere.
    let finished = bake("4").output().unwrap();
    let stderr = text(&finished.stderr);
    assert!(finished.status.success(), "{stderr}");
    let cached = stderr.lines().filter(|l| l.split_whitespace().nth(1) == Some("cached")).count();
    // The four seed-independent stages (C_S, g_n, C_G, volume) were stored by the first bake;
    // the seed-dependent ones the killed run finished are reused, the rest recomputed.
    assert_eq!(cached, 4 + stored_by_last_kill, "stages from the cache:\n{stderr}");
    for folder in [dir.path(), cache.as_path()] {
        let leftovers: Vec<_> = std::fs::read_dir(folder)
            .unwrap()
            .filter_map(Result::ok)
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| Path::new(n).extension().is_some_and(|x| x == "tmp"))
            .collect();
        assert!(leftovers.is_empty(), "{}: leftover temporaries {leftovers:?}", folder.display());
    }
    BakeFile::open_unkeyed(&out).expect("the final bake file is complete");
}
