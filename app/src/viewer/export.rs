//! Screenshot export: the current view rendered off-screen at a chosen size and sample count,
//! written as PNG (tone mapped, sRGB) or EXR (linear radiance), with the scene settings that
//! reproduce it saved beside it as TOML.
//!
//! How it works: the export panel ([`export_panel`]) collects the file, size and samples; the
//! viewer sends the render worker an export request with the current camera, lights and GPU
//! settings, and the worker renders it with the viewport's own renderer in small batches and
//! calls [`write_export`]. The TOML ([`scene_toml`]) is the scene file the viewer was started
//! with, with `[camera]`, `[[lights]]`, `[render]` and `[gpu]` replaced by what is on screen
//! and relative file paths made absolute, so `twill render SHOT.toml -o SHOT.png` renders the
//! same view again. Writes are atomic: a failed export leaves no partial file.

use std::path::{Path, PathBuf};

use eframe::egui;
use twill_precompute::atomic_file::write_atomically;
use twill_precompute::image::Image;
use twill_precompute::scene::{CameraSection, GpuSection, LightSection, ProjectionKind, RenderSection};
use twill_renderer::export::{write_image, write_rgb8_png};

use super::accumulate::{display_settings, tone_map_rgba8};

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

/// What the viewer shows, for [`scene_toml`].
pub struct ViewSettings<'a> {
    pub camera: CameraSection,
    pub lights: &'a [LightSection],
    pub render: RenderSection,
    pub gpu: GpuSection,
}

fn float_array(values: &[f64]) -> toml::Value {
    toml::Value::Array(values.iter().map(|v| toml::Value::Float(*v)).collect())
}

fn table(entries: Vec<(&str, toml::Value)>) -> toml::Value {
    toml::Value::Table(entries.into_iter().map(|(k, v)| (k.to_owned(), v)).collect())
}

fn light_value(light: &LightSection) -> toml::Value {
    match *light {
        LightSection::Directional { direction, irradiance } => table(vec![
            ("type", toml::Value::String("directional".into())),
            ("direction", float_array(&direction)),
            ("irradiance", float_array(&irradiance)),
        ]),
        LightSection::Sg { axis, sharpness, intensity } => table(vec![
            ("type", toml::Value::String("sg".into())),
            ("axis", float_array(&axis)),
            ("sharpness", toml::Value::Float(sharpness)),
            ("intensity", float_array(&intensity)),
        ]),
    }
}

fn integer(value: u64) -> toml::Value {
    toml::Value::Integer(i64::try_from(value).unwrap_or(i64::MAX))
}

/// Makes the path at `keys` inside `root` absolute (against `base`) when it is relative.
fn absolutize(root: &mut toml::Table, keys: &[&str], base: &Path) {
    let Some((last, parents)) = keys.split_last() else { return };
    let mut table = root;
    for key in parents {
        match table.get_mut(*key) {
            Some(toml::Value::Table(t)) => table = t,
            _ => return,
        }
    }
    if let Some(toml::Value::String(path)) = table.get_mut(*last)
        && Path::new(path.as_str()).is_relative()
    {
        *path = base.join(path.as_str()).to_string_lossy().into_owned();
    }
}

/// The scene file `source_text` (read from `source_path`) with the viewer's camera, lights,
/// render and GPU settings (see the module docs).
pub fn scene_toml(source_text: &str, source_path: &Path, view: &ViewSettings<'_>) -> Result<String, String> {
    let mut root: toml::Table = source_text.parse().map_err(|e| format!("{}: {e}", source_path.display()))?;
    let c = &view.camera;
    let projection = match c.projection {
        ProjectionKind::Perspective => "perspective",
        ProjectionKind::Orthographic => "orthographic",
    };
    root.insert(
        "camera".into(),
        table(vec![
            ("projection", toml::Value::String(projection.into())),
            ("eye", float_array(&c.eye)),
            ("target", float_array(&c.target)),
            ("up", float_array(&c.up)),
            ("fov_y_deg", toml::Value::Float(c.fov_y_deg)),
            ("height_cm", toml::Value::Float(c.height_cm)),
        ]),
    );
    root.insert("lights".into(), toml::Value::Array(view.lights.iter().map(light_value).collect()));
    let r = &view.render;
    root.insert(
        "render".into(),
        table(vec![
            ("width", integer(r.width as u64)),
            ("height", integer(r.height as u64)),
            ("spp", integer(u64::from(r.spp))),
            ("max_depth", integer(u64::from(r.max_depth))),
            ("seed", integer(r.seed)),
            ("exposure", toml::Value::Float(r.exposure)),
        ]),
    );
    let g = &view.gpu;
    root.insert(
        "gpu".into(),
        table(vec![
            ("volume_samples", integer(u64::from(g.volume_samples))),
            ("sigma_glo_cm", toml::Value::Float(g.sigma_glo_cm)),
            ("shadow_map_size", integer(u64::from(g.shadow_map_size))),
            ("visibility_texture_size", integer(u64::from(g.visibility_texture_size))),
            ("pcf_radius_texels", toml::Value::Float(g.pcf_radius_texels)),
            ("shadow_bias_texels", toml::Value::Float(g.shadow_bias_texels)),
        ]),
    );
    if source_path.is_file() {
        let base = source_path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let base = std::path::absolute(base).unwrap_or_else(|_| base.to_path_buf());
        absolutize(&mut root, &["mesh", "path"], &base);
        absolutize(&mut root, &["fabric", "spec", "file"], &base);
    }
    let body = toml::to_string(&root).map_err(|e| format!("the scene settings do not serialize: {e}"))?;
    Ok(format!(
        "# Scene settings of an image exported by the twill viewer (from {}).\n\
         # Render it again: twill render THIS_FILE -o OUT.png\n\n{body}",
        source_path.display()
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

#[cfg(test)]
mod tests {
    use super::*;
    use twill_precompute::scene::{DEFAULT_SCENE_TOML, SceneFile};

    #[test]
    fn the_saved_settings_load_back_as_the_same_view() {
        let scene = SceneFile::default_scene();
        let lights = [
            LightSection::Sg { axis: [0.0, 0.6, 0.8], sharpness: 30.0, intensity: [1.0, 2.0, 3.0] },
            LightSection::Directional { direction: [1.0, 0.0, 1.0], irradiance: [0.5, 0.5, 0.5] },
        ];
        let mut gpu = scene.gpu;
        gpu.volume_samples = 32;
        let render = RenderSection { width: 320, height: 200, spp: 16, exposure: -1.5, ..scene.render };
        let view = ViewSettings { camera: scene.camera, lights: &lights, render, gpu };
        let text = scene_toml(DEFAULT_SCENE_TOML, Path::new("<built-in default scene>"), &view).unwrap();
        let back = SceneFile::parse(&text, Path::new("saved.toml")).unwrap();
        assert_eq!(back.lights, lights);
        assert_eq!(back.camera, scene.camera);
        assert_eq!(back.render, render);
        assert_eq!(back.gpu, gpu);
        assert_eq!(back.fabric, scene.fabric);
        back.build().unwrap();
    }

    #[test]
    fn relative_paths_become_absolute() {
        let text = "[fabric]\npreset = \"default\"\n[mesh]\npath = \"meshes/cloth.obj\"\n[camera]\nprojection = \"perspective\"\neye = [0, 0, 1]\ntarget = [0, 0, 0]\n";
        let scene = SceneFile::default_scene();
        let view = ViewSettings { camera: scene.camera, lights: &[], render: scene.render, gpu: scene.gpu };
        let dir = tempfile::tempdir().unwrap();
        let source = dir.path().join("scene.toml");
        std::fs::write(&source, text).unwrap();
        let out = scene_toml(text, &source, &view).unwrap();
        let back = SceneFile::parse(&out, Path::new("x.toml")).unwrap();
        assert_eq!(back.mesh.path.unwrap(), dir.path().join("meshes/cloth.obj"));
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
}
