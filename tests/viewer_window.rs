//! The desktop viewer end to end: the real `twill` binary in a real window under Xvfb, on
//! lavapipe (Mesa's software Vulkan) where there is no GPU.
//!
//! `scripted_edits_render_and_match_the_golden` starts the viewer on the built-in default
//! scene with a script (`twill view --script`, see app/src/viewer/script.rs) that waits for the
//! draft bake's picture, orbits the camera, moves the key light, changes the SG fill's
//! sharpness λ and intensity, flips a crossing of the weave draft (and waits for its bake),
//! waits for 4 accumulated samples, takes a window screenshot with
//! egui's screenshot API and exports the view as PNG and EXR with its scene TOML. The viewport
//! part of the screenshot, at half size (2×2 box average: a small golden, and single fiber-edge
//! pixels that flip between drivers count less), is compared with
//! `tests/goldens/viewer_scripted_edits.png` (`twill_tests::compare_with_golden`: RMSE of 8-bit
//! channels <= 0.5, at most 0.1% of pixels off by more than 16, lavapipe being bit-exact from run to
//! run; `scripts/bless-goldens.sh` re-blesses it).
//! Only the viewport is compared: the panels show timings that change from run to run.
//!
//! `fabric_edits_rebake_only_what_they_change_and_undo_restores_them` edits a fiber material
//! (single scattering previewed, then only the transfer and C_S stages computed), flips a weave
//! cell (only the geometry stages computed), swaps the mesh (no bake at all), loses the render
//! device (destroyed by `lose-device`: the viewer opens a new one, uploads the fabric and the
//! edited mesh again and goes on accumulating), saves the scene,
//! undoes everything (the bake comes back from the stage cache), saves again, and records UI
//! frame times while a bake runs; the saved scenes must load and hold exactly the edits.
//!
//! `the_draft_picture_shows_before_the_final_bake_finishes` starts at interactive quality on an
//! empty cache and checks that the draft's picture is on screen while the interactive bake runs.
//!
//! `a_failed_bake_and_a_missing_scene_are_shown_in_the_window` opens a scene whose fabric cannot
//! be built, then a scene file that does not exist, and checks that each error appears in the
//! window while the viewer keeps running (the scripted run above also exports to a folder that
//! does not exist).
//!
//! Both need `xvfb-run` (Debian package xvfb; scripts/setup.sh installs it). Without it they
//! fail, unless `TWILL_ALLOW_NO_GPU=1`, when they print a loud SKIPPED line. The binary is
//! `target/<profile>/twill` beside this test's own folder (`cargo test --workspace` builds it),
//! or `$TWILL_BIN`.

use std::io::Read as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use twill_precompute::scene::SceneFile;
use twill_tests::{compare_with_golden, twill_binary};

/// Window size of the scripted runs (points; Xvfb has one pixel per point).
const WINDOW: (u32, u32) = (1000, 640);
/// Longest a viewer run may take (two bakes at most, a few seconds of rendering).
const RUN_TIMEOUT: Duration = Duration::from_mins(10);

fn find_on_path(name: &str) -> Option<PathBuf> {
    std::env::split_paths(&std::env::var_os("PATH")?).map(|d| d.join(name)).find(|p| p.is_file())
}

/// `xvfb-run`, or `None` after a loud SKIPPED line when `TWILL_ALLOW_NO_GPU=1`.
fn xvfb_run_for(test: &str) -> Option<PathBuf> {
    if let Some(path) = find_on_path("xvfb-run") {
        return Some(path);
    }
    if std::env::var("TWILL_ALLOW_NO_GPU").is_ok_and(|v| v == "1") {
        twill_renderer::gpu::report_skip(test, "xvfb-run not found; install the xvfb package to run it");
        return None;
    }
    panic!(
        "{test}: xvfb-run not found. Install it (apt-get install xvfb, or run scripts/setup.sh), \
         or set TWILL_ALLOW_NO_GPU=1 to skip this test explicitly."
    );
}

struct Run {
    success: bool,
    stderr: String,
}

/// Runs `twill view ARGS` under xvfb-run in `dir`, with a private runtime folder and bake cache.
/// One at a time: `xvfb-run -a` can hand two concurrent runs the same display number.
fn run_viewer(xvfb: &Path, dir: &Path, args: &[&str]) -> Run {
    run_viewer_with(xvfb, dir, args, &[])
}

/// As [`run_viewer`], with extra environment variables.
fn run_viewer_with(xvfb: &Path, dir: &Path, args: &[&str], envs: &[(&str, &str)]) -> Run {
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let runtime = dir.join("xdg");
    std::fs::create_dir_all(&runtime).unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt as _;
        std::fs::set_permissions(&runtime, std::fs::Permissions::from_mode(0o700)).unwrap();
    }
    let stderr_path = dir.join("viewer.stderr");
    let mut command = Command::new(xvfb);
    command
        .args(["-a", "-s", "-screen 0 1280x800x24"])
        .arg(twill_binary())
        .arg("view")
        .args(args)
        .current_dir(dir)
        .env("XDG_RUNTIME_DIR", &runtime)
        .env("WGPU_DEBUG", "0")
        .env("TWILL_CACHE_DIR", dir.join("cache"))
        .env("RUST_LOG", "warn")
        .envs(envs.iter().copied())
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&stderr_path).unwrap());
    #[cfg(unix)]
    std::os::unix::process::CommandExt::process_group(&mut command, 0);
    let mut child = command.spawn().expect("xvfb-run starts");
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for the viewer") {
            break Some(status);
        }
        if started.elapsed() > RUN_TIMEOUT {
            // xvfb-run, Xvfb and the viewer share the process group.
            let _ = Command::new("kill").args(["-KILL", &format!("-{}", child.id())]).status();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let mut stderr = String::new();
    std::fs::File::open(&stderr_path).unwrap().read_to_string(&mut stderr).unwrap();
    eprintln!("--- viewer stderr ---\n{stderr}---");
    let Some(status) = status else {
        panic!("the viewer did not finish within {} s", RUN_TIMEOUT.as_secs());
    };
    Run { success: status.success(), stderr }
}

fn read_png_rgba(path: &Path) -> (u32, u32, Vec<[u8; 4]>) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut reader = png::Decoder::new(std::io::BufReader::new(file)).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb, "{}", path.display());
    let pixels = buf[..info.buffer_size()].chunks_exact(3).map(|p| [p[0], p[1], p[2], 255]).collect();
    (info.width, info.height, pixels)
}

/// The image at half size (2×2 box average of the 8-bit values; an odd last row or column is
/// dropped).
fn half_size(width: u32, height: u32, pixels: &[[u8; 4]]) -> (u32, u32, Vec<[u8; 4]>) {
    let (w, h) = (width / 2, height / 2);
    let at = |x: u32, y: u32| pixels[(y * width + x) as usize];
    let mut out = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let quad =
                [at(2 * x, 2 * y), at(2 * x + 1, 2 * y), at(2 * x, 2 * y + 1), at(2 * x + 1, 2 * y + 1)];
            let mean = |c: usize| ((quad.iter().map(|p| u32::from(p[c])).sum::<u32>() + 2) / 4) as u8;
            out.push([mean(0), mean(1), mean(2), 255]);
        }
    }
    (w, h, out)
}

#[test]
fn scripted_edits_render_and_match_the_golden() {
    let test = "scripted_edits_render_and_match_the_golden";
    let Some(xvfb) = xvfb_run_for(test) else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    let script = "\
        # The default scene's draft bake, then edits through the viewer's own code paths.\n\
        wait-fabric draft\n\
        set spp 4\n\
        orbit 25 -10\n\
        light 0 azimuth 120\n\
        light 0 elevation 35\n\
        light 1 sharpness 40\n\
        light 1 intensity 2.5\n\
        # Flip one crossing of the 2/2 twill: a geometry rebake.\n\
        flip 0 0\n\
        wait-idle\n\
        wait-spp 4\n\
        screenshot window.png\n\
        export export.png 96x64 2\n\
        wait-export\n\
        export export.exr 48x32 1\n\
        wait-export\n\
        # An export that cannot be written is an error in the window, not a crash.\n\
        export no-such-folder/shot.png 16x16 1\n\
        expect-error no-such-folder\n\
        quit\n";
    std::fs::write(out.join("edits.script"), script).unwrap();
    let size = format!("{}x{}", WINDOW.0, WINDOW.1);
    let run =
        run_viewer(&xvfb, out, &["--quality", "draft", "--window-size", &size, "--script", "edits.script"]);
    assert!(run.success, "the viewer failed:\n{}", run.stderr);
    assert!(run.stderr.contains("script finished"), "{}", run.stderr);

    let (w, h, _) = read_png_rgba(&out.join("window.png"));
    assert_eq!((w, h), WINDOW, "the window screenshot has the window's size");
    let (vw, vh, viewport) = read_png_rgba(&out.join("window.viewport.png"));
    assert!(vw > 200 && vh > 400, "viewport {vw}x{vh}");
    let bright = viewport.iter().filter(|p| p[..3].iter().any(|&c| c > 40)).count();
    assert!(bright > viewport.len() / 4, "the fabric is lit: {bright} of {} pixels", viewport.len());
    let (hw, hh, half) = half_size(vw, vh, &viewport);
    match compare_with_golden("viewer_scripted_edits", hw, hh, &half) {
        Ok(summary) => eprintln!("{summary}"),
        Err(reason) => panic!("{reason}"),
    }

    let (ew, eh, _) = read_png_rgba(&out.join("export.png"));
    assert_eq!((ew, eh), (96, 64));
    assert!(out.join("export.exr").is_file());
    let saved = SceneFile::load(&out.join("export.toml")).expect("the exported settings load");
    saved.build().expect("the exported settings build");
    assert_eq!((saved.render.width, saved.render.height, saved.render.spp), (48, 32, 1));
    let twill_precompute::scene::LightSection::Sg { sharpness, .. } = saved.lights[1] else {
        panic!("light 1 should be the SG fill, is {:?}", saved.lights[1]);
    };
    assert!((sharpness - 40.0).abs() < 1e-9, "the edited λ is saved: {sharpness}");
}

#[test]
fn the_gpu_picture_is_drawn_natively_on_the_window_device_and_read_back_on_another() {
    // The viewer's picture is accumulated and tone mapped on the GPU. On the window's own
    // device the window draws the renderer's display texture as it is (nothing read back); on
    // a device of the worker's own (the default on lavapipe) the 8-bit display image is read
    // back and uploaded. Both must show the same pixels, and an exposure edit tone-maps the
    // same samples again on the GPU.
    let test = "the_gpu_picture_is_drawn_natively_on_the_window_device_and_read_back_on_another";
    let Some(xvfb) = xvfb_run_for(test) else { return };
    let dir = tempfile::tempdir().unwrap();
    let script = "wait-fabric draft\nset spp 2\nwait-idle\nwait-spp 2\nscreenshot shot.png\n\
                  set exposure 1.5\nwait-spp 2\nscreenshot bright.png\nquit\n";
    std::fs::write(dir.path().join("tone.script"), script).unwrap();
    let mut shots = Vec::new();
    for device in ["shared", "separate"] {
        let out = dir.path().join(device);
        std::fs::create_dir_all(&out).unwrap();
        std::fs::copy(dir.path().join("tone.script"), out.join("tone.script")).unwrap();
        let args = ["--quality", "draft", "--window-size", "640x480", "--script", "tone.script"];
        // Both runs share one bake cache: the second reads the first's draft bake.
        let cache = dir.path().join("shared-cache");
        let cache = cache.to_str().unwrap();
        let run = run_viewer_with(
            &xvfb,
            &out,
            &args,
            &[("TWILL_VIEWER_DEVICE", device), ("TWILL_CACHE_DIR", cache)],
        );
        assert!(run.success && run.stderr.contains("script finished"), "{device}:\n{}", run.stderr);
        let (_, _, shot) = read_png_rgba(&out.join("shot.viewport.png"));
        let (_, _, bright) = read_png_rgba(&out.join("bright.viewport.png"));
        shots.push((device, shot, bright));
    }
    let mean = |p: &[[u8; 4]]| {
        p.iter().map(|p| f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2])).sum::<f64>()
            / (3.0 * p.len() as f64)
    };
    for (device, shot, bright) in &shots {
        assert!(mean(shot) > 20.0, "{device}: the fabric is on screen (mean level {:.1})", mean(shot));
        assert!(
            mean(bright) > mean(shot) + 10.0,
            "{device}: +1.5 stops brightens the picture ({:.1} -> {:.1})",
            mean(shot),
            mean(bright)
        );
    }
    let ((_, shared, shared_bright), (_, separate, separate_bright)) = (&shots[0], &shots[1]);
    for (what, a, b) in [("picture", shared, separate), ("retoned picture", shared_bright, separate_bright)] {
        assert_eq!(a.len(), b.len(), "{what}: same viewport");
        let largest = a
            .iter()
            .zip(b.iter())
            .flat_map(|(p, q)| (0..3).map(move |c| p[c].abs_diff(q[c])))
            .max()
            .unwrap_or(0);
        assert!(
            largest <= 1,
            "{what}: the native texture and the read-back pixels differ by {largest} levels"
        );
    }
}

/// The stages the `wait-idle` steps report, in order.
fn idle_reports(stderr: &str) -> Vec<String> {
    stderr
        .lines()
        .filter_map(|l| l.split_once("idle: the draft bake on screen computed ["))
        .map(|(_, rest)| rest.trim_end_matches(']').to_owned())
        .collect()
}

#[test]
fn fabric_edits_rebake_only_what_they_change_and_undo_restores_them() {
    let test = "fabric_edits_rebake_only_what_they_change_and_undo_restores_them";
    let Some(xvfb) = xvfb_run_for(test) else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    let script = "\
        wait-fabric draft\n\
        set spp 1\n\
        wait-idle\n\
        fiber warp beta_tt 20\n\
        fiber warp c_tt 0.6 0.2 0.1\n\
        wait-idle\n\
        flip 0 0\n\
        wait-idle\n\
        mesh builtin cushion\n\
        mesh thickness 1.5\n\
        wait-spp 1\n\
        # A lost render device: a new one, the fabric and the edited mesh uploaded again.\n\
        lose-device\n\
        set spp 2\n\
        wait-spp 2\n\
        screenshot cushion.png\n\
        save edited.toml\n\
        undo\n\
        undo\n\
        undo\n\
        wait-idle\n\
        save undone.toml\n\
        # A material edit whose transfer stage is not cached: frames while it bakes.\n\
        fiber weft beta_r 7\n\
        spin 2\n\
        frame-times frames.txt\n\
        wait-idle\n\
        quit\n";
    std::fs::write(out.join("fabric.script"), script).unwrap();
    let run = run_viewer(
        &xvfb,
        out,
        &["--quality", "draft", "--window-size", "900x600", "--script", "fabric.script"],
    );
    assert!(run.success, "the viewer failed:\n{}", run.stderr);

    let reports = idle_reports(&run.stderr);
    let expected = [
        // The first bake of an empty cache computes everything.
        "mean_free_path, visibility, transfer, cs_tables, gn_tables, cg_table, volume",
        // A material edit: its Gn tables came with the preview; transfer and C_S after it.
        "transfer, cs_tables",
        // A weave edit: the stages that depend on geometry.
        "mean_free_path, visibility, transfer, volume",
        // Undoing back to the material edit's scene: all of it from the cache.
        "",
        // The last material edit.
        "transfer, cs_tables",
    ];
    assert_eq!(reports, expected, "stages computed per bake:\n{}", run.stderr);

    // The lost device was replaced (the step waits for that) and the picture went on
    // accumulating on the new one, on the edited mesh.
    assert!(run.stderr.contains("lose-device (done after"), "{}", run.stderr);
    let (_, _, cushion) = read_png_rgba(&out.join("cushion.viewport.png"));
    let bright = cushion.iter().filter(|p| p[..3].iter().any(|&c| c > 40)).count();
    assert!(bright > cushion.len() / 10, "the cushion is lit: {bright} of {} pixels", cushion.len());

    let edited = SceneFile::load(&out.join("edited.toml")).expect("the saved scene loads");
    edited.build().expect("the saved scene builds");
    let Some(twill_precompute::bcsdf::MaterialDesc::Fiber(warp)) = edited.materials.warp else {
        panic!("the warp material is saved: {:?}", edited.materials.warp);
    };
    assert!((warp.beta_tt_deg - 20.0).abs() < 1e-12 && (warp.c_tt.to_array()[0] - 0.6).abs() < 1e-12);
    assert_eq!(edited.mesh.builtin.as_deref(), Some("cushion"));
    assert!((edited.mesh.thickness_scale - 1.5).abs() < 1e-12);
    let spec = edited.fabric.spec.as_ref().expect("a weave edit saves the full fabric spec");
    let twill_precompute::fabric::presets::FabricSpec::Woven(woven) = spec else { panic!("woven") };
    let draft = woven.weave.draft();
    assert!(!draft.warp_over(0, 0), "the flipped crossing is saved");
    assert!(draft.warp_over(0, 1));

    let undone = SceneFile::load(&out.join("undone.toml")).expect("the second save loads");
    assert_eq!(undone.fabric.preset.as_deref(), Some("default"), "the flip is undone");
    assert!(undone.mesh.builtin.is_none() && (undone.mesh.thickness_scale - 1.0).abs() < 1e-12);
    assert_eq!(undone.materials, edited.materials, "the material edit stays");

    let frames = std::fs::read_to_string(out.join("frames.txt")).unwrap();
    assert!(frames.contains("while baking: frame interval"), "{frames}");
}

/// The picture comes first: started on an empty bake cache at interactive quality, the viewer
/// shows the draft bake's picture while the interactive bake is still in flight (the bake
/// thread holds until that picture is on screen, so the first frame has the cores to itself).
/// Prints the time to the first picture; docs/BENCHMARKS.md records it.
#[test]
fn the_draft_picture_shows_before_the_final_bake_finishes() {
    let test = "the_draft_picture_shows_before_the_final_bake_finishes";
    let Some(xvfb) = xvfb_run_for(test) else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    std::fs::write(out.join("first.script"), "wait-fabric draft\nexpect-baking interactive\nquit\n").unwrap();
    let run = run_viewer(&xvfb, out, &["--quality", "interactive", "--script", "first.script"]);
    assert!(run.success, "the viewer failed:\n{}", run.stderr);
    let first = run
        .stderr
        .lines()
        .find_map(|l| l.strip_prefix("script line 1: wait-fabric draft (done after "))
        .and_then(|rest| rest.strip_suffix(')'))
        .expect("the draft picture was shown");
    eprintln!("time to the draft picture: {first} after the window opened");
    assert!(run.stderr.contains("script line 2: expect-baking interactive (done"), "{}", run.stderr);
}

#[test]
fn a_failed_bake_and_a_missing_scene_are_shown_in_the_window() {
    let test = "a_failed_bake_and_a_missing_scene_are_shown_in_the_window";
    let Some(xvfb) = xvfb_run_for(test) else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    let scene = "[fabric]\npreset = \"no-such-fabric\"\n\
                 [camera]\nprojection = \"perspective\"\neye = [0, -0.5, 0.7]\ntarget = [0, 0, 0]\n\
                 [[lights]]\ntype = \"directional\"\ndirection = [0, 0, 1]\nirradiance = [1, 1, 1]\n";
    std::fs::write(out.join("bad.toml"), scene).unwrap();
    let script = "expect-error unknown preset \"no-such-fabric\"\nscreenshot error.png\nquit\n";
    std::fs::write(out.join("error.script"), script).unwrap();
    let run = run_viewer(&xvfb, out, &["bad.toml", "--quality", "draft", "--script", "error.script"]);
    assert!(run.success, "the viewer failed:\n{}", run.stderr);
    assert!(out.join("error.png").is_file());

    std::fs::write(out.join("missing.script"), "expect-error could not be read\nquit\n").unwrap();
    let run = run_viewer(&xvfb, out, &["no-such-scene.toml", "--script", "missing.script"]);
    assert!(run.success, "the viewer failed:\n{}", run.stderr);
}

/// The `ratio N` a verification report printed by `wait-verify` gives, for the report whose
/// text contains `what`.
fn verification_ratio(stderr: &str, what: &str) -> f64 {
    let line = stderr
        .lines()
        .find(|l| l.starts_with("verification of") && l.contains(what))
        .unwrap_or_else(|| panic!("no verification of {what} reported:\n{stderr}"));
    let ratio = line.split("(ratio ").nth(1).and_then(|r| r.split(')').next()).expect("a ratio");
    ratio.parse().unwrap_or_else(|_| panic!("{line}"))
}

#[test]
fn paint_mode_paints_yarns_refuses_a_painting_that_is_no_colour_order_and_commits_one() {
    // Paint mode on the default scene: a small precompute of the frozen view, one section
    // painted (no colour order: the commit is refused, naming the thread), undone, then every
    // thread of the set under the pointer painted red, verified against the path tracer,
    // committed as colour orders (which queues a verification of the committed scene) and
    // saved. On the way the painting and the precompute are saved (`twill paint apply` reads
    // them back), and leaving paint mode and painting the same view again resumes both. The painted picture must change where the yarns were painted, and both
    // verifications must be within 2x the references' own noise (the CLI check's bound).
    let test = "paint_mode_paints_yarns_refuses_a_painting_that_is_no_colour_order_and_commits_one";
    let Some(xvfb) = xvfb_run_for(test) else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    let script = "\
        wait-fabric draft\n\
        paint-start 40 16 16\n\
        wait-paint\n\
        screenshot before.png\n\
        paint-colour 0.6 0.05 0.05\n\
        paint-scope section\n\
        paint-at 0.52 0.55\n\
        paint-commit\n\
        expect-error has 2 colours along it\n\
        paint-undo\n\
        paint-scope set\n\
        paint-at 0.52 0.55\n\
        screenshot painted.png\n\
        paint-save painting.toml\n\
        paint-save-data view.twillpaint\n\
        paint-leave\n\
        paint-start 40 16 16\n\
        wait-paint\n\
        screenshot resumed.png\n\
        paint-verify\n\
        wait-verify\n\
        paint-show reference\n\
        screenshot reference.png\n\
        paint-show difference\n\
        screenshot difference.png\n\
        paint-show painting\n\
        paint-commit\n\
        wait-verify\n\
        save committed.toml\n\
        quit\n";
    std::fs::write(out.join("paint.script"), script).unwrap();
    let run = run_viewer(
        &xvfb,
        out,
        &["--quality", "draft", "--window-size", "1000x640", "--script", "paint.script"],
    );
    assert!(run.success && run.stderr.contains("script finished"), "the viewer failed:\n{}", run.stderr);

    let (_, _, before) = read_png_rgba(&out.join("before.viewport.png"));
    let (_, _, painted) = read_png_rgba(&out.join("painted.viewport.png"));
    assert_eq!(before.len(), painted.len());
    let changed: Vec<([u8; 4], [u8; 4])> = before
        .iter()
        .zip(&painted)
        .filter(|(a, b)| (0..3).any(|c| a[c].abs_diff(b[c]) > 16))
        .map(|(a, b)| (*a, *b))
        .collect();
    assert!(
        changed.len() > before.len() / 20,
        "painting a thread set changes the picture: {} pixels",
        changed.len()
    );
    // Where it changed, it turned red (the default warp is blue).
    let red_minus_blue = |p: &[u8; 4]| f64::from(p[0]) - f64::from(p[2]);
    let shift = changed.iter().map(|(a, b)| red_minus_blue(b) - red_minus_blue(a)).sum::<f64>()
        / changed.len() as f64;
    assert!(shift > 20.0, "painted red: red - blue rose by {shift:.1} levels where the picture changed");

    // The verification's path-traced picture shows in the viewport: near the painting in its
    // mean level, not the same pixels; then the difference. (The top halves:
    // messages are drawn over the viewport's bottom.)
    let top = painted.len() / 2;
    let level = |p: &[[u8; 4]]| {
        p[..p.len() / 2].iter().map(|p| f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2])).sum::<f64>()
            / (1.5 * p.len() as f64)
    };
    let (_, _, reference) = read_png_rgba(&out.join("reference.viewport.png"));
    let (_, _, difference) = read_png_rgba(&out.join("difference.viewport.png"));
    let (lp, lr, ld) = (level(&painted), level(&reference), level(&difference));
    assert!(reference[..top] != painted[..top], "the path-traced picture is shown");
    // (At 16 spp the references are noisy: |painting − reference| × 4 is as bright as either.)
    assert!(
        (lr / lp - 1.0).abs() < 0.25 && difference[..top] != reference[..top] && ld > 0.0,
        "levels: painting {lp:.1}, reference {lr:.1}, difference {ld:.1}"
    );

    // Leaving and painting the same view again resumes the precompute and the painting.
    let (_, _, resumed) = read_png_rgba(&out.join("resumed.viewport.png"));
    assert!(resumed[..top] == painted[..top], "the resumed painting is the one left");
    // The saved painting and precompute are what `twill paint` reads.
    let saved = std::fs::read_to_string(out.join("painting.toml")).expect("the painting is saved");
    assert!(saved.contains("colour = [0.6, 0.05, 0.05]"), "{saved}");
    let apply = std::process::Command::new(twill_binary())
        .args(["paint", "apply", "view.twillpaint", "--painting", "painting.toml", "-o", "applied.png"])
        .current_dir(out)
        .output()
        .unwrap();
    assert!(apply.status.success(), "{}", String::from_utf8_lossy(&apply.stderr));
    let (aw, ah, _) = read_png_rgba(&out.join("applied.png"));
    assert!(aw > 0 && ah == 40, "the paint image's size: {aw}x{ah}");

    for what in ["the painted cloth", "the committed colour orders"] {
        let ratio = verification_ratio(&run.stderr, what);
        assert!(ratio < 2.0, "{what}: relative L2 {ratio} times the references' own");
    }
    let committed = SceneFile::load(&out.join("committed.toml")).expect("the committed scene loads");
    committed.build().expect("the committed scene builds");
    let materials = &committed.materials;
    assert!(materials.palette.len() >= 2, "a red and the other yarn: {:?}", materials.palette);
    assert!(materials.warp_order.is_some() && materials.weft_order.is_some(), "{materials:?}");
    let red = materials
        .palette
        .values()
        .filter_map(|c| c.c_tt)
        .any(|c| c.to_array().map(f64::to_bits) == [0.6, 0.05, 0.05].map(f64::to_bits));
    assert!(red, "the painted red is a palette colour, as painted: {:?}", materials.palette);
}

#[test]
fn a_colour_edit_shows_live_from_the_bases_before_its_full_bake() {
    // After the first material edit's full bake the viewer makes its recolouring bases; a later
    // colour edit is written into the fabric on the GPU from them at once (no rest, no bake
    // first) and its picture comes first at the reduced size, as any edit's does; the full
    // bake follows and replaces it. (How long edit to picture takes is measured, not tested:
    // docs/COLOURWAYS.md.)
    let test = "a_colour_edit_shows_live_from_the_bases_before_its_full_bake";
    let Some(xvfb) = xvfb_run_for(test) else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    let script = "\
        wait-fabric draft\n\
        set spp 1\n\
        fiber warp c_tt 0.2 0.3 0.6\n\
        wait-idle\n\
        fiber warp c_tt 0.7 0.2 0.1\n\
        wait-recolour-picture\n\
        wait-idle\n\
        save recoloured.toml\n\
        quit\n";
    std::fs::write(out.join("live.script"), script).unwrap();
    let run = run_viewer(
        &xvfb,
        out,
        &["--quality", "draft", "--window-size", "800x560", "--script", "live.script"],
    );
    assert!(run.success && run.stderr.contains("script finished"), "the viewer failed:\n{}", run.stderr);
    let line = run
        .stderr
        .lines()
        .find(|l| l.starts_with("colour edit to picture:"))
        .unwrap_or_else(|| panic!("no live picture reported:\n{}", run.stderr));
    // "colour edit to picture: 209 ms (93x154)": a reduced picture, smaller than the viewport.
    let size = line.split('(').nth(1).and_then(|s| s.strip_suffix(')')).expect("a size");
    let (w, h) =
        size.split_once('x').map(|(w, h)| (w.parse::<u32>().unwrap(), h.parse::<u32>().unwrap())).unwrap();
    assert!(w < 800 / 2 && h > 0, "the first picture after the edit is reduced: {line}");
    // The live picture came before the full bake of the new colours.
    let live_at = run.stderr.find("colour edit to picture:").unwrap();
    let bakes: Vec<usize> = run.stderr.match_indices("idle: the draft bake").map(|(i, _)| i).collect();
    assert!(bakes.len() == 2 && bakes[0] < live_at && live_at < bakes[1], "{}", run.stderr);
    let saved = SceneFile::load(&out.join("recoloured.toml")).expect("the scene saves");
    let Some(twill_precompute::bcsdf::MaterialDesc::Fiber(warp)) = saved.materials.warp else {
        panic!("a fiber warp: {:?}", saved.materials.warp)
    };
    assert!((warp.c_tt.x - 0.7).abs() < 1e-12, "the edit stays: {:?}", warp.c_tt);
}
