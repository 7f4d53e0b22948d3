//! Shared helpers for twill's workspace-level tests: small scenes whose answers are known.

use glam::{DVec3, Vec3};
use twill_precompute::Rgb;
use twill_precompute::bcsdf::{Lambertian, Material};
use twill_precompute::fabric::fiber_io::exemplar_from_fibers;
use twill_precompute::fabric::{BlockGrid, Exemplar, Fiber, Tiling};
use twill_precompute::pathtrace::{Light, PathScene};
use twill_precompute::raycast::{Extent, FiberScene};
use twill_renderer::export::write_rgb8_png;

/// One straight fiber along x, centred on the origin, `length` long, used as-is.
#[must_use]
pub fn straight_fiber(radius: f32, length: f32) -> Exemplar {
    let points = (0..=16).map(|i| Vec3::new(length * (i as f32 / 16.0 - 0.5), 0.0, 0.0)).collect();
    exemplar_from_fibers(vec![Fiber { points, radius, yarn: 0 }], Tiling::AsIs, BlockGrid { nx: 1, ny: 1 })
}

/// A path scene of `exemplar` with every yarn Lambertian of `albedo`.
#[must_use]
pub fn lambert_scene(exemplar: &Exemplar, extent: Extent, albedo: f64, lights: Vec<Light>) -> PathScene {
    let material = Material::Lambert(Lambertian::new(Rgb::splat(albedo)).expect("albedo in [0, 1]"));
    PathScene {
        fibers: FiberScene::new(exemplar, extent).expect("valid fabric"),
        yarn_materials: vec![material; exemplar.yarns.len()],
        lights,
        ground_z: None,
        painted: None,
        pattern: None,
    }
}

/// Mean radiance over the projected width of a Lambertian cylinder of albedo `rho`, seen along
/// a direction perpendicular to its axis, under a directional light of irradiance `e` whose
/// direction is perpendicular to the axis at angle `alpha` (0..=pi/2) from the view direction:
/// `rho e (sin a + (pi - a) cos a) / (4 pi)`.
#[must_use]
pub fn lambert_cylinder_mean_radiance(rho: f64, e: f64, alpha: f64) -> f64 {
    rho * e * (alpha.sin() + (std::f64::consts::PI - alpha) * alpha.cos()) / (4.0 * std::f64::consts::PI)
}

/// Unit vector at angle `alpha` from +z toward +y.
#[must_use]
pub fn tilted_from_z(alpha: f64) -> DVec3 {
    DVec3::new(0.0, alpha.sin(), alpha.cos())
}

/// Where golden images live (`tests/goldens/NAME.png`).
#[must_use]
pub fn golden_path(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("goldens").join(format!("{name}.png"))
}

/// Golden-image metric: the RMSE of 8-bit sRGB channel values over the image must be at most
/// `GOLDEN_MAX_RMSE`, and at most `GOLDEN_MAX_OUTLIERS` of the pixels may differ by more than
/// `GOLDEN_OUTLIER_LEVEL` in any channel.
///
/// Lavapipe's run-to-run noise, measured 2026-11-25: RMSE 0.000 and no outliers for all five
/// goldens (the four GPU frames and the viewer's), in two runs on this machine against goldens
/// blessed on another of its kind — the renders are bit-exact. The bounds leave room for a
/// different LLVM or CPU vector width changing a few fiber-edge pixels, and no more: half a
/// level of RMSE, 0.1% of pixels off by more than 16 levels. (They were 3 levels, 1% and 32.)
pub const GOLDEN_MAX_RMSE: f64 = 0.5;
pub const GOLDEN_OUTLIER_LEVEL: u8 = 16;
pub const GOLDEN_MAX_OUTLIERS: f64 = 0.001;

fn read_rgb_png(path: &std::path::Path) -> Result<(u32, u32, Vec<u8>), String> {
    let file = std::fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder.read_info().map_err(|e| format!("{}: {e}", path.display()))?;
    let mut buf = vec![0; reader.output_buffer_size().unwrap_or(0)];
    let info = reader.next_frame(&mut buf).map_err(|e| format!("{}: {e}", path.display()))?;
    if info.color_type != png::ColorType::Rgb || info.bit_depth != png::BitDepth::Eight {
        return Err(format!(
            "{}: expected 8-bit RGB, got {:?} {:?}",
            path.display(),
            info.color_type,
            info.bit_depth
        ));
    }
    buf.truncate(info.buffer_size());
    Ok((info.width, info.height, buf))
}

/// Compares an RGBA8 image with the golden `name` (see the metric above). On failure writes
/// `target/golden-diffs/NAME.actual.png` and `NAME.diff.png` (absolute difference, x4) and
/// returns the reason. A missing golden fails. Blessing (`scripts/bless-goldens.sh`, which sets
/// `TWILL_BLESS=1`) writes the golden instead, after saving the previous one as
/// `NAME.previous.png` beside its difference from the new image and measuring the change; it
/// is refused when `CI` is set.
pub fn compare_with_golden(name: &str, width: u32, height: u32, rgba: &[[u8; 4]]) -> Result<String, String> {
    let actual: Vec<u8> = rgba.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
    let path = golden_path(name);
    let diff_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/golden-diffs");
    if std::env::var("TWILL_BLESS").is_ok_and(|v| v == "1") {
        if std::env::var_os("CI").is_some_and(|v| !v.is_empty()) {
            return Err(format!(
                "{name}: TWILL_BLESS is refused in CI (CI is set); goldens are blessed by hand"
            ));
        }
        let change = match read_rgb_png(&path) {
            Ok((gw, gh, previous)) if (gw, gh) == (width, height) => {
                std::fs::create_dir_all(&diff_dir).expect("create diff folder");
                write_rgb8_png(&diff_dir.join(format!("{name}.previous.png")), width, height, &previous)
                    .expect("write the previous golden");
                let diff: Vec<u8> =
                    previous.iter().zip(&actual).map(|(a, b)| a.abs_diff(*b).saturating_mul(4)).collect();
                write_rgb8_png(&diff_dir.join(format!("{name}.diff.png")), width, height, &diff)
                    .expect("write the difference image");
                let (rmse, outliers) = golden_metric(&previous, &actual);
                format!(
                    "previous golden: RMSE {rmse:.3}, outliers {:.3}% (see {}/{name}.*.png)",
                    100.0 * outliers,
                    diff_dir.display()
                )
            }
            Ok((gw, gh, _)) => format!("previous golden was {gw}x{gh}"),
            Err(_) => "no previous golden".to_owned(),
        };
        std::fs::create_dir_all(path.parent().expect("goldens folder")).expect("create goldens folder");
        write_rgb8_png(&path, width, height, &actual).expect("write the golden");
        return Ok(format!("{name}: golden blessed (TWILL_BLESS=1); {change}"));
    }
    let fail = |reason: String, golden: Option<&[u8]>| {
        std::fs::create_dir_all(&diff_dir).expect("create diff folder");
        write_rgb8_png(&diff_dir.join(format!("{name}.actual.png")), width, height, &actual)
            .expect("write the actual image");
        if let Some(g) = golden {
            let diff: Vec<u8> =
                g.iter().zip(&actual).map(|(a, b)| a.abs_diff(*b).saturating_mul(4)).collect();
            write_rgb8_png(&diff_dir.join(format!("{name}.diff.png")), width, height, &diff)
                .expect("write the difference image");
        }
        Err(format!("{name}: {reason}; wrote {}/{name}.*.png", diff_dir.display()))
    };
    let (gw, gh, golden) = match read_rgb_png(&path) {
        Ok(g) => g,
        Err(e) => {
            return fail(
                format!("missing or unreadable golden ({e}); run scripts/bless-goldens.sh to create it"),
                None,
            );
        }
    };
    if (gw, gh) != (width, height) {
        return fail(format!("golden is {gw}x{gh}, image is {width}x{height}"), None);
    }
    let (rmse, outliers) = golden_metric(&golden, &actual);
    let summary = format!(
        "RMSE {rmse:.3} (max {GOLDEN_MAX_RMSE}), outliers {:.3}% (max {:.1}%)",
        100.0 * outliers,
        100.0 * GOLDEN_MAX_OUTLIERS
    );
    if rmse > GOLDEN_MAX_RMSE || outliers > GOLDEN_MAX_OUTLIERS {
        return fail(summary, Some(&golden));
    }
    Ok(format!("{name}: {summary}"))
}

/// The golden metric of two RGB8 images of one size: RMSE over 8-bit channels, and the
/// fraction of pixels with a channel off by more than [`GOLDEN_OUTLIER_LEVEL`].
fn golden_metric(golden: &[u8], actual: &[u8]) -> (f64, f64) {
    let n = golden.len() as f64;
    let sq: f64 = golden.iter().zip(actual).map(|(a, b)| (f64::from(*a) - f64::from(*b)).powi(2)).sum();
    let outliers = golden
        .chunks_exact(3)
        .zip(actual.chunks_exact(3))
        .filter(|(a, b)| a.iter().zip(b.iter()).any(|(x, y)| x.abs_diff(*y) > GOLDEN_OUTLIER_LEVEL))
        .count() as f64
        / (n / 3.0);
    ((sq / n).sqrt(), outliers)
}

/// An accuracy band around a measured error, one-sided: `|value|` above `|measured| + margin`
/// is a regression and fails; below `|measured| − margin` is an improvement, printed as a
/// notice (tighten the band to the new measurement). NaN or Inf fails.
pub fn check_band(label: &str, value: f64, measured: f64, margin: f64) -> Result<(), String> {
    if !value.is_finite() {
        return Err(format!("{label}: {value} is not finite"));
    }
    let (value_abs, measured_abs) = (value.abs(), measured.abs());
    if value_abs > measured_abs + margin {
        return Err(format!(
            "{label}: {value:+.4} is worse than the measured {measured:+.4} by more than {margin:.4} (a regression)"
        ));
    }
    if value_abs < measured_abs - margin {
        eprintln!(
            "NOTICE {label}: {value:+.4} is better than the measured {measured:+.4} by more than {margin:.4}: \
             tighten the band"
        );
    }
    Ok(())
}

/// The `twill` binary this test run goes with: `$TWILL_BIN`, else `twill` in the test's own
/// profile folder (`cargo test --workspace` builds it).
///
/// # Panics
/// When it is missing, saying how to build it.
#[must_use]
pub fn twill_binary() -> std::path::PathBuf {
    if let Some(path) = std::env::var_os("TWILL_BIN") {
        return std::path::PathBuf::from(path);
    }
    let exe = std::env::current_exe().expect("the test knows its own path");
    let profile_dir = exe.parent().and_then(std::path::Path::parent).expect("target/<profile>/deps/<test>");
    let binary = profile_dir.join("twill");
    assert!(
        binary.is_file(),
        "{} is missing: build it first (cargo build -p twill-app with this test's profile, or run \
         `cargo test --workspace`), or point TWILL_BIN at it",
        binary.display()
    );
    binary
}
