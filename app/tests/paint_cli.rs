//! End to end: `twill paint` (precompute, threads, apply, verify) and `twill reference
//! --painting`, each running the real binary on the default scene at a tiny size.

use std::path::Path;
use std::process::{Command, Output};

fn twill(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_twill")).args(args).current_dir(dir).output().expect("twill runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn succeeds(args: &[&str], dir: &Path) -> (String, String) {
    let out = twill(args, dir);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{args:?} failed:\n{stdout}\n{stderr}");
    (stdout, stderr)
}

fn fails_naming(args: &[&str], dir: &Path, needles: &[&str]) {
    let out = twill(args, dir);
    let stderr = text(&out.stderr);
    assert!(!out.status.success(), "{args:?} should fail");
    assert!(!stderr.contains("panicked"), "{args:?} panicked:\n{stderr}");
    for needle in needles {
        assert!(stderr.contains(needle), "{args:?}: expected {needle:?} in\n{stderr}");
    }
}

/// Width, height and pixels of an EXR file.
fn read_exr(path: &Path) -> (usize, usize, Vec<[f32; 3]>) {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |size, _| (size.width(), size.height(), vec![[0.0_f32; 3]; size.width() * size.height()]),
        |(w, _, pixels): &mut (usize, usize, Vec<[f32; 3]>), at, (r, g, b, _): (f32, f32, f32, f32)| {
            pixels[at.y() * *w + at.x()] = [r, g, b];
        },
    )
    .unwrap();
    image.layer_data.channel_data.pixels
}

#[test]
fn a_painting_is_precomputed_applied_listed_verified_and_path_traced() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (_, stderr) = succeeds(
        &[
            "paint",
            "precompute",
            "--size",
            "12x10",
            "--spp",
            "16",
            "--gradient-spp",
            "32",
            "-o",
            "p.twillpaint",
        ],
        d,
    );
    assert!(stderr.contains("--gradient-spp 32 is more than --spp 16"), "{stderr}");
    for key in ["12x10", "cells", "warp ends", "weft picks", "weights stored", "MB in memory", "file"] {
        assert!(stderr.contains(key), "missing {key:?} in\n{stderr}");
    }

    // The default twill over its 2 cm swatch: the threads a painting may name.
    let (threads, _) = succeeds(&["paint", "threads", "p.twillpaint"], d);
    let inside = |key: &str| -> u32 {
        let line = threads.lines().find(|l| l.starts_with(key)).unwrap_or_else(|| panic!("{threads}"));
        line.split_whitespace().nth(2).unwrap().parse().unwrap()
    };
    let (ends, picks) = (inside("warp ends"), inside("weft picks"));
    assert!(ends > 10 && picks > 10, "{threads}");
    assert!(threads.contains(&format!("warp = \"0-{}\"", ends - 1)), "{threads}");
    assert!(threads.contains("cells"), "{threads}");

    std::fs::write(
        d.join("stripes.toml"),
        "base = [0.8, 0.8, 0.8]\n[[stroke]]\ncolour = [0.05, 0.06, 0.3]\nwarp = \"10-20, 30\"\n\
         [[stroke]]\ncolour = [0.7, 0.1, 0.1]\nweft = \"25-28\"\nsections = \"0-40\"\n",
    )
    .unwrap();
    std::fs::write(d.join("empty.toml"), "").unwrap();
    let (_, stderr) =
        succeeds(&["paint", "apply", "p.twillpaint", "--painting", "stripes.toml", "-o", "s.png"], d);
    assert!(stderr.contains(" ms") && stderr.contains("stripes.toml"), "{stderr}");
    assert!(d.join("s.png").metadata().unwrap().len() > 0);
    // No painting and a painting of no strokes are both the scene's own colours.
    succeeds(&["paint", "apply", "p.twillpaint", "-o", "own.exr"], d);
    succeeds(&["paint", "apply", "p.twillpaint", "--painting", "empty.toml", "-o", "empty.exr"], d);
    succeeds(&["paint", "apply", "p.twillpaint", "--painting", "stripes.toml", "-o", "s.exr"], d);
    // PNGs take the scene's exposure as precomputed unless told otherwise.
    let dim =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/scenes/default.toml"))
            .unwrap()
            .replace("exposure = 0.5", "exposure = -1.5");
    std::fs::write(d.join("dim.toml"), dim).unwrap();
    succeeds(&["paint", "precompute", "dim.toml", "--size", "4x4", "--spp", "2", "-o", "dim.twillpaint"], d);
    succeeds(&["paint", "apply", "dim.twillpaint", "-o", "dim.png"], d);
    succeeds(&["paint", "apply", "dim.twillpaint", "-o", "dim-1.5.png", "--exposure", "-1.5"], d);
    succeeds(&["paint", "apply", "dim.twillpaint", "-o", "dim0.5.png", "--exposure", "0.5"], d);
    let bytes = |name: &str| std::fs::read(d.join(name)).unwrap();
    assert_eq!(bytes("dim.png"), bytes("dim-1.5.png"), "the default is the scene's exposure");
    assert_ne!(bytes("dim.png"), bytes("dim0.5.png"));

    let (w, h, own) = read_exr(&d.join("own.exr"));
    assert_eq!((w, h), (12, 10));
    assert_eq!(own, read_exr(&d.join("empty.exr")).2);
    assert_ne!(own, read_exr(&d.join("s.exr")).2, "the stripes change the picture");

    let (stdout, stderr) = succeeds(
        &["paint", "verify", "p.twillpaint", "--painting", "stripes.toml", "--spp", "16", "--images", "v"],
        d,
    );
    let value = |label: &str| -> f64 {
        let line = stdout.lines().find(|l| l.starts_with(label)).unwrap_or_else(|| panic!("{stdout}"));
        line[label.len()..].split_whitespace().next().unwrap().parse().unwrap()
    };
    let (error, floor, ratio) = (
        value("relative L2, painting vs reference 1"),
        value("relative L2, reference 2 vs reference 1"),
        value("ratio"),
    );
    assert!(error > 0.0 && floor > 0.0, "{stdout}");
    // At 16 spp both are mostly noise; a painting on the wrong cells would stand far above it.
    assert!(ratio.is_finite() && ratio < 3.0, "{stdout}");
    assert!(stdout.contains("seeds 2 and 3") && stdout.contains("image mean, reference 2"), "{stdout}");
    for name in ["painted.png", "reference.png", "difference.png"] {
        assert!(d.join("v").join(name).metadata().unwrap().len() > 0, "{name}: {stderr}");
    }

    // The path tracer paints the same way: an empty painting changes nothing at all.
    succeeds(&["reference", "-o", "r.exr", "--size", "6x5", "--spp", "2"], d);
    succeeds(
        &["reference", "--painting", "empty.toml", "-o", "r-empty.exr", "--size", "6x5", "--spp", "2"],
        d,
    );
    succeeds(
        &["reference", "--painting", "stripes.toml", "-o", "r-stripes.exr", "--size", "6x5", "--spp", "2"],
        d,
    );
    let plain = read_exr(&d.join("r.exr")).2;
    assert_eq!(plain, read_exr(&d.join("r-empty.exr")).2);
    assert_ne!(plain, read_exr(&d.join("r-stripes.exr")).2);

    // Errors name the file and the value.
    std::fs::write(d.join("outside.toml"), "[[stroke]]\ncolour = [0.5, 0.5, 0.5]\nwarp = \"999\"\n").unwrap();
    let range = format!("outside 0-{}", ends - 1);
    fails_naming(
        &["paint", "apply", "p.twillpaint", "--painting", "outside.toml", "-o", "x.png"],
        d,
        &["outside.toml", "999", &range],
    );
    fails_naming(
        &["reference", "--painting", "outside.toml", "-o", "x.png", "--size", "4x4", "--spp", "1"],
        d,
        &["outside.toml", &range],
    );
    fails_naming(
        &["paint", "apply", "stripes.toml", "-o", "x.png"],
        d,
        &["stripes.toml", "not a twill paint file"],
    );
    fails_naming(&["paint", "apply", "p.twillpaint", "-o", "x.jpg"], d, &["x.jpg"]);
    fails_naming(&["paint", "apply", "p.twillpaint", "-o", "x.png", "--exposure", "31"], d, &["-30 to 30"]);
    fails_naming(&["paint", "precompute", "-o", "x.twillpaint", "--spp", "0"], d, &["--spp", "1..=1048576"]);
    fails_naming(&["paint", "precompute", "-o", "x.twillpaint", "--size", "5000x4"], d, &["--size", "4096"]);
    fails_naming(&["paint", "precompute", "-o", "no-dir/x.twillpaint", "--size", "4x4"], d, &["no-dir"]);
    fails_naming(
        &["paint", "verify", "p.twillpaint", "--painting", "stripes.toml", "--seed", "0"],
        d,
        &["--seed 0", "p.twillpaint"],
    );
    // Another swatch divides into other cells: verify refuses it by name.
    let scene =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/scenes/default.toml"))
            .unwrap()
            .replace("size_cm = [2.0, 2.0]", "size_cm = [1.0, 1.0]");
    std::fs::write(d.join("small.toml"), scene).unwrap();
    fails_naming(
        &["paint", "verify", "p.twillpaint", "small.toml", "--painting", "stripes.toml", "--spp", "1"],
        d,
        &["p.twillpaint", "was not precomputed from", "small.toml"],
    );
    // The same cloth from another eye: the paths were traced from the first, and the
    // fingerprints the paint file keeps say so.
    let default_scene =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/scenes/default.toml"))
            .unwrap();
    let eye =
        default_scene.lines().find(|l| l.starts_with("eye")).expect("the default scene's eye").to_owned();
    std::fs::write(d.join("moved.toml"), default_scene.replace(&eye, "eye = [0.3, -1.4, 1.6]")).unwrap();
    fails_naming(
        &["paint", "verify", "p.twillpaint", "moved.toml", "--painting", "stripes.toml", "--spp", "1"],
        d,
        &["p.twillpaint", "was not precomputed from", "moved.toml", "the camera differs"],
    );
    let patterned = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../assets/scenes/patterned.toml")
        .to_string_lossy()
        .into_owned();
    fails_naming(
        &["paint", "precompute", &patterned, "-o", "x.twillpaint", "--size", "4x4"],
        d,
        &["patterned.toml", "[pattern]"],
    );
    assert!(!d.join("x.twillpaint").exists() && !d.join("x.png").exists());
}

#[test]
fn a_painting_that_is_a_colour_order_is_committed_into_the_scene() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/paintings");
    let painting = |name: &str| assets.join(name).to_string_lossy().into_owned();
    // The cells are all a commit reads of the paint file: the smallest precompute does.
    succeeds(
        &["paint", "precompute", "--size", "4x4", "--spp", "1", "--gradient-spp", "1", "-o", "p.twillpaint"],
        d,
    );

    // The check: red blocks of 8 threads in every 16 over cream, both ways.
    let check = painting("check.toml");
    let (stdout, stderr) =
        succeeds(&["paint", "commit", "p.twillpaint", "--painting", &check, "-o", "checked.toml"], d);
    assert!(stdout.contains("warp: 2 colours over 16 threads; weft: 2 colours over 16 threads"), "{stdout}");
    assert!(stdout.contains("checked.toml") && stdout.contains("check.toml"), "{stdout}");
    // The cream base reaches the copies beyond the edges, where the order puts red too.
    assert!(stderr.contains("just beyond the swatch's edges"), "{stderr}");
    let scene = twill_precompute::scene::SceneFile::load(&d.join("checked.toml")).unwrap();
    let colourway = scene.colourway().unwrap().expect("a colourway");
    assert_eq!(colourway.names, ["paint01", "paint02", "paint03", "paint04"]);
    assert_eq!((colourway.warp.threads().len(), colourway.weft.threads().len()), (16, 16));
    for order in [&colourway.warp, &colourway.weft] {
        let red = order.threads().iter().filter(|&&k| order.threads()[0] != k).count();
        assert_eq!(red.min(16 - red), 8, "8 threads of each colour: {:?}", order.threads());
    }
    let built = scene.build().unwrap();
    assert_eq!(built.exemplar.yarns.len(), 32, "a 16 x 16 exemplar repeat");

    // A pick painted in sections is no colour order; nor is another scene's paint file.
    fails_naming(
        &["paint", "commit", "p.twillpaint", "--painting", &painting("highlight.toml"), "-o", "x.toml"],
        d,
        &[
            "highlight.toml",
            "weft pick 30 has 2 colours along it (sections 0-19, 20-35 and 36-",
            "whole threads",
        ],
    );
    let small =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/scenes/default.toml"))
            .unwrap()
            .replace("size_cm = [2.0, 2.0]", "size_cm = [1.0, 1.0]");
    std::fs::write(d.join("small.toml"), small).unwrap();
    fails_naming(
        &["paint", "commit", "p.twillpaint", "small.toml", "--painting", &check, "-o", "x.toml"],
        d,
        &["p.twillpaint", "was not precomputed from", "small.toml"],
    );
    assert!(!d.join("x.toml").exists());
}
