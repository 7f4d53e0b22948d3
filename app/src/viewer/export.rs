//! Screenshot export: the current view rendered off-screen at a chosen size and sample count,
//! written as PNG (tone mapped, sRGB) or EXR (linear radiance), with the scene settings that
//! reproduce it saved beside it as TOML.
//!
//! How it works: the export panel ([`export_panel`]) collects the file, size and samples; the
//! viewer sends the render worker an export request with the current camera, lights and GPU
//! settings, and the worker renders it with the viewport's own renderer in small batches and
//! calls [`write_export`]. The TOML ([`export_toml`]) is the scene as shown — edited fabric,
//! materials and mesh, camera, lights, render and GPU settings — in the scene format, with
//! relative file paths made absolute when the TOML lands in another folder, so
//! `twill render SHOT.toml -o SHOT.png` renders the same view again. Writes are atomic: a failed
//! export leaves no partial file.

use std::path::{Path, PathBuf};

use eframe::egui;
use twill_precompute::Rgb;
use twill_precompute::atomic_file::write_atomically;
use twill_precompute::image::Image;
use twill_precompute::scene::{RenderSection, SceneFile};
use twill_renderer::export::{Display, ToneCurve, display_srgb8, write_image, write_rgb8_png};

/// Largest export side in pixels (the renderer's limit).
pub const MAX_EXPORT_SIDE: u32 = 16384;
/// Most samples per pixel an export takes.
pub const MAX_EXPORT_SPP: u32 = 4096;

/// An exported picture's mean radiance and display settings.
pub struct ExportImage<'a> {
    pub width: u32,
    pub height: u32,
    pub radiance: &'a [[f32; 3]],
    pub exposure: f64,
    pub filmic: bool,
}

/// The image format, from the file's extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportFormat {
    Png,
    Exr,
}

impl ExportFormat {
    /// The format `path` asks for, or an error naming the file.
    pub fn of(path: &Path) -> Result<Self, String> {
        match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
            Some("png") => Ok(Self::Png),
            Some("exr") => Ok(Self::Exr),
            _ => Err(format!("{}: the file name must end in .png or .exr", path.display())),
        }
    }
}

/// The TOML file written beside an exported image.
#[must_use]
pub fn settings_path(image: &Path) -> PathBuf {
    image.with_extension("toml")
}

/// Writes the image and the scene settings beside it; returns the files written.
pub fn write_export(path: &Path, image: &ExportImage<'_>, scene_toml: &str) -> Result<Vec<PathBuf>, String> {
    let format = ExportFormat::of(path)?;
    let settings = settings_path(path);
    match format {
        ExportFormat::Png => {
            let rgba = tone_map_rgba8(image.radiance, 1.0, image.exposure, image.filmic);
            let rgb: Vec<u8> = rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
            write_rgb8_png(path, image.width, image.height, &rgb)
                .map_err(|e| format!("{}: {e}", path.display()))?;
        }
        ExportFormat::Exr => {
            let pixels = image
                .radiance
                .iter()
                .map(|p| twill_precompute::Rgb::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])))
                .collect();
            let hdr = Image { width: image.width as usize, height: image.height as usize, pixels };
            write_image(path, &hdr, display_settings(image.exposure, image.filmic))
                .map_err(|e| e.to_string())?;
        }
    }
    write_atomically(&settings, |w| std::io::Write::write_all(w, scene_toml.as_bytes()))
        .map_err(|e| format!("{}: {e}", settings.display()))?;
    Ok(vec![path.to_path_buf(), settings])
}

/// The scene settings written beside an image exported to `image`: `scene` (the scene as shown:
/// edited fabric, materials, mesh, camera, lights, render settings) with `[render]` sized like
/// the export and relative file paths rebased for the TOML's folder, so
/// `twill render SHOT.toml -o SHOT.png` renders the same view again.
pub fn export_toml(scene: &SceneFile, image: &Path, render: RenderSection) -> Result<String, String> {
    let toml_path = settings_path(image);
    let mut scene = scene.rebased(&toml_path);
    scene.render = render;
    let body = scene.to_toml().map_err(|e| format!("the scene settings do not serialize: {e}"))?;
    Ok(format!(
        "# Scene settings of an image exported by the twill viewer (from {}).\n\
         # Render it again: twill render THIS_FILE -o OUT.png\n\n{body}",
        scene.path.display()
    ))
}

/// The export panel's fields.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportForm {
    pub path: String,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
}

impl Default for ExportForm {
    fn default() -> Self {
        Self { path: "twill-shot.png".into(), width: 1024, height: 768, spp: 64 }
    }
}

/// What the export panel shows of an export in progress.
#[derive(Debug, Clone, PartialEq)]
pub enum ExportStatus {
    Idle,
    Running { done: u32, total: u32 },
}

/// What the user asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportAction {
    Start,
    Cancel,
}

/// The export panel; `viewport_size` fills the size from the viewport.
pub fn export_panel(
    ui: &mut egui::Ui,
    form: &mut ExportForm,
    status: &ExportStatus,
    viewport_size: Option<[u32; 2]>,
    can_export: bool,
) -> Option<ExportAction> {
    let mut action = None;
    ui.horizontal(|ui| {
        ui.label("File");
        ui.text_edit_singleline(&mut form.path).on_hover_text(
            ".png (tone mapped) or .exr (linear radiance); the scene settings go beside it as .toml",
        );
    });
    ui.horizontal(|ui| {
        let mut format = ExportFormat::of(Path::new(&form.path)).ok();
        let before = format;
        ui.radio_value(&mut format, Some(ExportFormat::Png), "PNG");
        ui.radio_value(&mut format, Some(ExportFormat::Exr), "EXR");
        if format != before
            && let Some(f) = format
        {
            let ext = if f == ExportFormat::Png { "png" } else { "exr" };
            form.path = Path::new(&form.path).with_extension(ext).to_string_lossy().into_owned();
        }
    });
    ui.horizontal(|ui| {
        ui.label("Size");
        ui.add(egui::DragValue::new(&mut form.width).range(1..=MAX_EXPORT_SIDE).suffix(" px"));
        ui.label("×");
        ui.add(egui::DragValue::new(&mut form.height).range(1..=MAX_EXPORT_SIDE).suffix(" px"));
        if let Some([w, h]) = viewport_size
            && ui.small_button("= view").on_hover_text("The viewport's size").clicked()
        {
            (form.width, form.height) = (w, h);
        }
    });
    ui.horizontal(|ui| {
        ui.label("Samples");
        ui.add(egui::DragValue::new(&mut form.spp).range(1..=MAX_EXPORT_SPP).suffix(" spp"));
    });
    match status {
        ExportStatus::Idle => {
            let valid = ExportFormat::of(Path::new(&form.path));
            let button = ui.add_enabled(can_export && valid.is_ok(), egui::Button::new("Export"));
            let button = match &valid {
                Err(reason) => button.on_disabled_hover_text(reason.as_str()),
                Ok(_) => button.on_disabled_hover_text("Waiting for the fabric's first picture"),
            };
            if button.clicked() {
                action = Some(ExportAction::Start);
            }
        }
        ExportStatus::Running { done, total } => {
            ui.horizontal(|ui| {
                let fraction = *done as f32 / (*total).max(1) as f32;
                ui.add(
                    egui::ProgressBar::new(fraction).text(format!("{done}/{total} spp")).desired_width(150.0),
                );
                if ui.button("Cancel").clicked() {
                    action = Some(ExportAction::Cancel);
                }
            });
        }
    }
    action
}

/// The display settings of the renderer's tone map.
#[must_use]
pub fn display_settings(exposure: f64, filmic: bool) -> Display {
    Display { exposure, curve: if filmic { ToneCurve::Filmic } else { ToneCurve::Clamp } }
}

/// Tone maps `radiance × scale` to RGBA8 with the renderer's curve, on a few scoped threads.
/// (Not on rayon's pool: a bake keeps that busy for seconds at a time, and the window would wait.)
#[must_use]
pub fn tone_map_rgba8(radiance: &[[f32; 3]], scale: f64, exposure: f64, filmic: bool) -> Vec<u8> {
    let display = display_settings(exposure, filmic);
    let mut out = vec![0_u8; radiance.len() * 4];
    let threads = std::thread::available_parallelism().map_or(1, std::num::NonZero::get).min(8);
    let chunk = radiance.len().div_ceil(threads).max(1);
    let map = |out: &mut [u8], pixels: &[[f32; 3]]| {
        for (o, p) in out.chunks_exact_mut(4).zip(pixels) {
            let rgb = Rgb::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])) * scale;
            let [r, g, b] = display_srgb8(rgb, display);
            o.copy_from_slice(&[r, g, b, 255]);
        }
    };
    std::thread::scope(|scope| {
        for (out, pixels) in out.chunks_mut(4 * chunk).zip(radiance.chunks(chunk)) {
            scope.spawn(move || map(out, pixels));
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_exported_settings_load_back_as_the_same_scene_with_paths_that_still_resolve() {
        let dir = tempfile::tempdir().unwrap();
        let text = "[fabric]\npreset = \"default\"\n[mesh]\npath = \"meshes/cloth.obj\"\n\
                    [camera]\nprojection = \"perspective\"\neye = [0, 0, 1]\ntarget = [0, 0, 0]\n\
                    [[lights]]\ntype = \"sg\"\naxis = [0, 0.6, 0.8]\nsharpness = 30.0\nintensity = [1, 2, 3]\n";
        let source = dir.path().join("scene.toml");
        let scene = SceneFile::parse(text, &source).unwrap();
        let render = RenderSection { width: 320, height: 200, spp: 16, exposure: -1.5, ..scene.render };
        std::fs::create_dir(dir.path().join("shots")).unwrap();
        let image = dir.path().join("shots/shot.png");
        let out = export_toml(&scene, &image, render).unwrap();
        let back = SceneFile::parse(&out, &settings_path(&image)).unwrap();
        assert_eq!(back.render, render);
        assert_eq!(
            (back.lights.clone(), back.camera, back.fabric.clone()),
            (scene.lights.clone(), scene.camera, scene.fabric.clone())
        );
        assert_eq!(back.mesh.path.unwrap(), dir.path().join("meshes/cloth.obj"));
        // Beside the scene, the path stays relative.
        let beside = export_toml(&scene, &dir.path().join("shot.png"), render).unwrap();
        let back = SceneFile::parse(&beside, Path::new("x.toml")).unwrap();
        assert_eq!(back.mesh.path.unwrap(), Path::new("meshes/cloth.obj"));
    }

    #[test]
    fn exports_write_the_image_and_the_settings_or_name_the_bad_file() {
        let dir = tempfile::tempdir().unwrap();
        let radiance = vec![[0.2_f32, 0.4, 0.8]; 6];
        let image = ExportImage { width: 3, height: 2, radiance: &radiance, exposure: 0.0, filmic: true };
        for name in ["shot.png", "shot.exr"] {
            let files = write_export(&dir.path().join(name), &image, "# settings\n").unwrap();
            assert!(files.iter().all(|f| f.exists()), "{files:?}");
            assert_eq!(files[1], dir.path().join("shot.toml"));
        }
        let err = write_export(&dir.path().join("shot.jpg"), &image, "").unwrap_err();
        assert!(err.contains("shot.jpg"), "{err}");
        let err = write_export(&dir.path().join("missing/shot.png"), &image, "").unwrap_err();
        assert!(err.contains("missing"), "{err}");
    }

    /// Known answers, worked by hand from the sRGB transfer function (IEC 61966-2-1) and
    /// Narkowicz's filmic fit: sRGB 0.5 is linear 0.21404 (level 127.5), so linear 0.213 is
    /// level 127 and 0.215 level 128; the filmic curve maps 1 to 2.54 / 3.16 = 0.8038 (level
    /// 232), 0.18 to level 141 and 4 to level 252.
    #[test]
    fn the_cpu_tone_map_gives_the_known_levels() {
        let clamp = |p: [f32; 3], scale: f64, exposure: f64| tone_map_rgba8(&[p], scale, exposure, false);
        assert_eq!(clamp([0.0, 1.0, 2.0], 1.0, 0.0), [0, 255, 255, 255]);
        assert_eq!(clamp([-1.0, 0.001, 0.213], 1.0, 0.0), [0, 3, 127, 255]);
        assert_eq!(clamp([0.215, 0.0, 0.0], 1.0, 0.0), [128, 0, 0, 255]);
        // The scale and the exposure (in stops) multiply: 0.05375 x 2 x 2^1 = 0.215.
        assert_eq!(clamp([0.053_75, 0.25, 0.0], 2.0, 1.0), [128, 255, 0, 255]);
        let filmic = tone_map_rgba8(&[[1.0, 0.18, 4.0], [100.0, 0.0, -3.0]], 1.0, 0.0, true);
        assert_eq!(filmic, [232, 141, 252, 255, 255, 0, 0, 255]);
    }

    /// The picture is split over threads: every pixel lands in its own place, whatever the count.
    #[test]
    fn the_tone_map_keeps_every_pixel_in_place() {
        for n in [1_usize, 7, 1000, 1001] {
            let radiance: Vec<[f32; 3]> = (0..n).map(|i| [i as f32 / n as f32, 0.0, 1.0]).collect();
            let rgba = tone_map_rgba8(&radiance, 1.0, 0.0, false);
            assert_eq!(rgba.len(), 4 * n);
            for (i, px) in rgba.chunks_exact(4).enumerate() {
                assert_eq!(px[1..], [0, 255, 255], "pixel {i} of {n}");
                // Red rises with the pixel index: no chunk was written twice or out of order.
                assert!(i == 0 || px[0] >= rgba[4 * (i - 1)], "pixel {i} of {n}");
            }
            assert_eq!(rgba[4 * (n - 1)], tone_map_rgba8(&radiance[n - 1..], 1.0, 0.0, false)[0]);
        }
    }
}
