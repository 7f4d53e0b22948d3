//! The fabric panels: fiber scattering (BCSDF) parameters per yarn, and the weave (draft editor,
//! weave presets, WIF import, repeat size, yarn geometry).
//!
//! How it works: the panels edit the viewer's [`SceneFile`] in place, in the scene format's own
//! terms, so what is on screen is exactly what Save writes. A fabric given as a preset is turned
//! into the equivalent `[fabric.spec]` (with the preset's materials written into `[materials]`)
//! at its first weave edit; material edits only write `[materials]`. The panels never bake: the
//! viewer compares the edited scene with the one last baked and decides what to rerun (a
//! material edit: a quick single-scattering preview, then the full bake; a weave or yarn edit:
//! everything that depends on geometry). Edits that would make an invalid draft (a row or column
//! that no longer interlaces) are refused with the reason shown under the grid.

use std::path::Path;

use eframe::egui;
use twill_precompute::Rgb;
use twill_precompute::bcsdf::{BETA_RANGE_DEG, FiberParams, GAMMA_RANGE_DEG, MaterialDesc};
use twill_precompute::fabric::presets::{FabricSpec, WeaveSource, WovenSpec, fabric_preset};
use twill_precompute::fabric::weave::{WeaveDraft, WeavePreset};
use twill_precompute::fabric::yarn::YarnParams;
use twill_precompute::scene::{FabricSection, SceneFile};

/// The two yarn roles and their material slots.
pub const YARNS: [(&str, usize); 2] = [("warp", 0), ("weft", 1)];
/// Largest repeat the draft editor offers (the format allows up to `WeaveDraft::MAX_SIZE`).
pub const MAX_EDITOR_REPEAT: usize = 24;
/// Side of a draft cell on screen, points.
const CELL_POINTS: f32 = 14.0;

/// The scene's woven fabric as a full specification (a preset resolved), or `None` for
/// imported fibers or an unknown preset.
#[must_use]
pub fn woven_spec(scene: &SceneFile) -> Option<WovenSpec> {
    let spec = match (&scene.fabric.preset, &scene.fabric.spec) {
        (Some(name), None) => fabric_preset(name)?.fabric,
        (None, Some(spec)) => spec.clone(),
        _ => return None,
    };
    match spec {
        FabricSpec::Woven(w) => Some(*w),
        FabricSpec::Imported(_) => None,
    }
}

/// The material of each slot (warp 0, weft 1) as the scene resolves it: `[materials]` over the
/// preset's, weft falling back to warp (as `SceneFile::build` does).
#[must_use]
pub fn materials(scene: &SceneFile) -> [Option<MaterialDesc>; 2] {
    let preset = scene.fabric.preset.as_deref().and_then(fabric_preset);
    let warp = scene.materials.warp.or(preset.as_ref().map(|p| p.warp_material));
    let weft = scene.materials.weft.or(preset.as_ref().map(|p| p.weft_material));
    [warp.or(weft), weft.or(warp)]
}

/// Replaces the fabric with `spec`, keeping the materials a preset gave it.
pub fn set_woven(scene: &mut SceneFile, spec: WovenSpec) {
    let [warp, weft] = materials(scene);
    scene.materials.warp = warp;
    scene.materials.weft = weft;
    scene.fabric = FabricSection { preset: None, spec: Some(FabricSpec::Woven(Box::new(spec))) };
}

/// Sets the material of `slot` (0 warp, 1 weft).
pub fn set_material(scene: &mut SceneFile, slot: usize, desc: MaterialDesc) {
    let [warp, weft] = materials(scene);
    scene.materials.warp = warp;
    scene.materials.weft = weft;
    if slot == 0 {
        scene.materials.warp = Some(desc);
    } else {
        scene.materials.weft = Some(desc);
    }
}

/// Flips one crossing of the draft (`row` = weft pick, `col` = warp end).
pub fn flip_cell(scene: &mut SceneFile, row: usize, col: usize) -> Result<(), String> {
    let mut spec = woven_spec(scene).ok_or("the fabric is not a procedural weave")?;
    let mut draft = spec.weave.draft();
    draft.flip(row, col).map_err(|e| format!("cannot flip pick {row}, end {col}: {e}"))?;
    spec.weave = WeaveSource::Draft(draft);
    set_woven(scene, spec);
    Ok(())
}

/// Sets the weave to a preset.
pub fn set_weave_preset(scene: &mut SceneFile, preset: WeavePreset) -> Result<(), String> {
    let mut spec = woven_spec(scene).ok_or("the fabric is not a procedural weave")?;
    spec.weave = WeaveSource::Preset(preset);
    set_woven(scene, spec);
    Ok(())
}

/// Sets the weave to `draft` (e.g. imported from a WIF file).
pub fn set_draft(scene: &mut SceneFile, draft: WeaveDraft) -> Result<(), String> {
    let mut spec = woven_spec(scene).ok_or("the fabric is not a procedural weave")?;
    spec.weave = WeaveSource::Draft(draft);
    set_woven(scene, spec);
    Ok(())
}

/// Changes the repeat to `rows` picks by `cols` ends, repeating the old draft to fill it.
pub fn resize_draft(scene: &mut SceneFile, rows: usize, cols: usize) -> Result<(), String> {
    let mut spec = woven_spec(scene).ok_or("the fabric is not a procedural weave")?;
    let old = spec.weave.draft();
    if (old.rows(), old.cols()) == (rows, cols) {
        return Ok(());
    }
    let cells = (0..rows).flat_map(|r| (0..cols).map(move |c| (r, c))).map(|(r, c)| old.warp_over(r, c));
    let draft = WeaveDraft::new(rows, cols, cells.collect()).map_err(|e| {
        format!(
            "a {rows} x {cols} repeat of this draft does not weave ({e}); flip cells or pick a preset first"
        )
    })?;
    spec.weave = WeaveSource::Draft(draft);
    set_woven(scene, spec);
    Ok(())
}

/// Reads a WIF file into the scene's weave.
pub fn import_wif(scene: &mut SceneFile, path: &Path) -> Result<(), String> {
    let draft = twill_precompute::fabric::wif::read_wif(path).map_err(|e| e.to_string())?;
    set_draft(scene, draft)
}

/// A fiber parameter a script or slider sets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FiberField {
    ColourR([f64; 3]),
    ColourTt([f64; 3]),
    BetaR(f64),
    BetaTt(f64),
    GammaTt(f64),
}

/// Sets one fiber parameter of `slot`, checking its range.
pub fn set_fiber_field(scene: &mut SceneFile, slot: usize, field: FiberField) -> Result<(), String> {
    let Some(MaterialDesc::Fiber(mut p)) = materials(scene)[slot] else {
        return Err(format!("the {} yarn has no fiber scattering material", YARNS[slot].0));
    };
    let check = |name: &str, v: f64, (lo, hi): (f64, f64)| {
        if (lo..=hi).contains(&v) { Ok(v) } else { Err(format!("{name} = {v} is outside {lo}..={hi}")) }
    };
    let colour = |name: &str, c: [f64; 3]| {
        c.iter().try_for_each(|&x| check(name, x, (0.0, 1.0)).map(|_| ())).map(|()| Rgb::from_array(c))
    };
    match field {
        FiberField::ColourR(c) => p.c_r = colour("c_r", c)?,
        FiberField::ColourTt(c) => p.c_tt = colour("c_tt", c)?,
        FiberField::BetaR(b) => p.beta_r_deg = check("beta_r_deg", b, BETA_RANGE_DEG)?,
        FiberField::BetaTt(b) => p.beta_tt_deg = check("beta_tt_deg", b, BETA_RANGE_DEG)?,
        FiberField::GammaTt(g) => p.gamma_tt_deg = check("gamma_tt_deg", g, GAMMA_RANGE_DEG)?,
    }
    set_material(scene, slot, MaterialDesc::Fiber(p));
    Ok(())
}

/// The fibers panel: C_R, β_R, C_TT, β_TT, γ_TT of the warp and weft yarns.
pub fn fibers_panel(ui: &mut egui::Ui, scene: &mut SceneFile) {
    let resolved = materials(scene);
    if woven_spec(scene).is_none() && scene.fabric.preset.is_none() {
        ui.label("Imported fibers: one material (the warp's).");
    }
    for (name, slot) in YARNS {
        ui.label(egui::RichText::new(name).strong());
        match resolved[slot] {
            Some(MaterialDesc::Fiber(p)) => {
                let mut edited = p;
                fiber_controls(ui, slot, &mut edited);
                if edited != p {
                    set_material(scene, slot, MaterialDesc::Fiber(edited));
                }
            }
            Some(MaterialDesc::Lambert { albedo }) => {
                ui.colored_label(
                    ui.visuals().warn_fg_color,
                    "A Lambertian material: the path tracer renders it, the GPU renderer cannot.",
                );
                if ui.button("Use the fiber model").on_hover_text("C_TT from the albedo").clicked() {
                    let fiber = FiberParams {
                        c_r: Rgb::splat(0.04),
                        beta_r_deg: 5.0,
                        c_tt: albedo,
                        beta_tt_deg: 10.0,
                        gamma_tt_deg: 25.0,
                    };
                    set_material(scene, slot, MaterialDesc::Fiber(fiber));
                }
            }
            None => {
                ui.label("No material.");
            }
        }
        ui.add_space(4.0);
    }
    ui.label(
        egui::RichText::new(
            "Single scattering follows at once; multiple scattering when its background bake \
             finishes (the old one stays until then).",
        )
        .small()
        .weak(),
    );
}

fn fiber_controls(ui: &mut egui::Ui, slot: usize, p: &mut FiberParams) {
    egui::Grid::new(("twill.fibers", slot)).num_columns(2).show(ui, |ui| {
        colour_row(ui, "C_R (sheen)", &mut p.c_r, "Reflectance of the R lobe at normal incidence");
        angle_row(ui, "β_R", &mut p.beta_r_deg, BETA_RANGE_DEG, "Longitudinal width of the R lobe");
        ui.end_row();
        colour_row(ui, "C_TT (colour)", &mut p.c_tt, "Transmission colour of the TT lobe");
        angle_row(ui, "β_TT", &mut p.beta_tt_deg, BETA_RANGE_DEG, "Longitudinal width of the TT lobe");
        ui.end_row();
        angle_row(ui, "γ_TT", &mut p.gamma_tt_deg, GAMMA_RANGE_DEG, "Azimuthal width of the TT lobe");
        ui.end_row();
    });
}

fn colour_row(ui: &mut egui::Ui, label: &str, colour: &mut Rgb, hover: &str) {
    ui.label(label).on_hover_text(hover);
    let mut rgb = colour.to_array().map(|c| c as f32);
    // egui's picker edits linear RGB here, as the scene format stores it.
    if ui.color_edit_button_rgb(&mut rgb).changed() {
        *colour = Rgb::from_array(rgb.map(|c| f64::from(c).clamp(0.0, 1.0)));
    }
    ui.end_row();
}

fn angle_row(ui: &mut egui::Ui, label: &str, degrees: &mut f64, (lo, hi): (f64, f64), hover: &str) {
    ui.label(label).on_hover_text(hover);
    ui.add(egui::Slider::new(degrees, lo..=hi).logarithmic(true).suffix("°").max_decimals(2));
}

/// What the weave panel asks of the viewer.
pub enum WeaveAction {
    ImportWif(String),
}

/// Text fields of the weave panel that live between frames.
#[derive(Default)]
pub struct WeaveForm {
    pub wif_path: String,
    pub message: Option<String>,
}

/// The weave panel: presets, the draft grid (click to flip), repeat size, WIF import and the
/// yarns' geometry.
pub fn weave_panel(ui: &mut egui::Ui, scene: &mut SceneFile, form: &mut WeaveForm) -> Option<WeaveAction> {
    let Some(spec) = woven_spec(scene) else {
        ui.label("Imported fibers: there is no weave to edit.");
        return None;
    };
    let mut action = None;
    let draft = spec.weave.draft();
    let current_preset = match spec.weave {
        WeaveSource::Preset(p) => Some(p),
        WeaveSource::Draft(_) => None,
    };
    egui::ComboBox::from_label("weave")
        .selected_text(current_preset.map_or("custom draft", WeavePreset::name))
        .show_ui(ui, |ui| {
            for p in WeavePreset::ALL {
                if ui.selectable_label(current_preset == Some(p), p.name()).clicked() {
                    form.message = set_weave_preset(scene, p).err();
                }
            }
        });

    let (mut rows, mut cols) = (draft.rows(), draft.cols());
    ui.horizontal(|ui| {
        ui.label("repeat");
        let r = ui.add(egui::DragValue::new(&mut cols).range(2..=MAX_EDITOR_REPEAT).suffix(" ends"));
        ui.label("×");
        let c = ui.add(egui::DragValue::new(&mut rows).range(2..=MAX_EDITOR_REPEAT).suffix(" picks"));
        if r.changed() || c.changed() {
            form.message = resize_draft(scene, rows, cols).err();
        }
    });

    let colours = yarn_colours(scene);
    if let Some((row, col)) = draft_grid(ui, &draft, colours) {
        form.message = flip_cell(scene, row, col).err();
    }
    ui.label(
        egui::RichText::new(format!(
            "dark: warp over · light: weft over · warp cover {:.0}% · longest floats: warp {}, weft {}",
            100.0 * draft.warp_cover(),
            draft.longest_warp_float(),
            draft.longest_weft_float()
        ))
        .small()
        .weak(),
    );
    if let Some(m) = &form.message {
        ui.colored_label(ui.visuals().error_fg_color, m);
    }

    ui.horizontal(|ui| {
        ui.add(egui::TextEdit::singleline(&mut form.wif_path).hint_text("draft.wif").desired_width(140.0));
        if ui.button("Import WIF").on_hover_text("A Weaving Information File's draft").clicked() {
            action = Some(WeaveAction::ImportWif(form.wif_path.trim().to_owned()));
        }
    });

    egui::CollapsingHeader::new("Yarns").default_open(false).show(ui, |ui| {
        let mut edited = woven_spec(scene).unwrap_or(spec);
        yarn_controls(ui, &mut edited);
        if Some(&edited) != woven_spec(scene).as_ref() {
            set_woven(scene, edited);
        }
    });
    action
}

/// The draft as a grid of cells, pick 0 at the top; returns the cell clicked.
fn draft_grid(
    ui: &mut egui::Ui,
    draft: &WeaveDraft,
    [warp, weft]: [egui::Color32; 2],
) -> Option<(usize, usize)> {
    let (rows, cols) = (draft.rows(), draft.cols());
    let cell = CELL_POINTS.min((ui.available_width() - 4.0) / cols as f32).max(4.0);
    let size = egui::vec2(cell * cols as f32, cell * rows as f32);
    let (rect, response) = ui.allocate_exact_size(size, egui::Sense::click());
    let painter = ui.painter_at(rect);
    for r in 0..rows {
        for c in 0..cols {
            let min = rect.min + egui::vec2(c as f32 * cell, r as f32 * cell);
            let square = egui::Rect::from_min_size(min, egui::vec2(cell, cell)).shrink(0.5);
            painter.rect_filled(square, 1.0, if draft.warp_over(r, c) { warp } else { weft });
        }
    }
    let hovered = response.hover_pos().map(|p| {
        let v = (p - rect.min) / cell;
        ((v.y as usize).min(rows - 1), (v.x as usize).min(cols - 1))
    });
    if let Some((r, c)) = hovered {
        let min = rect.min + egui::vec2(c as f32 * cell, r as f32 * cell);
        painter.rect_stroke(
            egui::Rect::from_min_size(min, egui::vec2(cell, cell)),
            1.0,
            egui::Stroke::new(1.5, ui.visuals().selection.stroke.color),
            egui::StrokeKind::Inside,
        );
    }
    let response = response.on_hover_text("Click a crossing to flip it");
    if response.clicked() { hovered } else { None }
}

/// Warp and weft colours for the grid: the yarns' C_TT, warp darkened so the two always differ.
fn yarn_colours(scene: &SceneFile) -> [egui::Color32; 2] {
    let colour = |slot: usize, scale: f64, fallback: u8| match materials(scene)[slot] {
        Some(MaterialDesc::Fiber(p)) => srgb(p.c_tt.to_array().map(|c| c * scale)),
        Some(MaterialDesc::Lambert { albedo }) => srgb(albedo.to_array().map(|c| c * scale)),
        None => egui::Color32::from_gray(fallback),
    };
    [colour(0, 0.45, 60), colour(1, 1.0, 200)]
}

fn srgb(linear: [f64; 3]) -> egui::Color32 {
    let [r, g, b] = linear.map(|c| egui::ecolor::gamma_u8_from_linear_f32(c.clamp(0.0, 1.0) as f32));
    egui::Color32::from_rgb(r, g, b)
}

/// Spacing, crimp and each yarn's main parameters. Values are range-limited here; the bake
/// validates the whole fabric and reports anything else.
fn yarn_controls(ui: &mut egui::Ui, spec: &mut WovenSpec) {
    egui::Grid::new("twill.yarns").num_columns(3).show(ui, |ui| {
        ui.label("");
        ui.label("warp");
        ui.label("weft");
        ui.end_row();
        let pair = |ui: &mut egui::Ui,
                    label: &str,
                    warp: &mut f64,
                    weft: &mut f64,
                    range: std::ops::RangeInclusive<f64>,
                    speed| {
            ui.label(label);
            for v in [warp, weft] {
                ui.add(egui::DragValue::new(v).range(range.clone()).speed(speed).max_decimals(4));
            }
            ui.end_row();
        };
        pair(ui, "width (cm)", &mut spec.warp.width, &mut spec.weft.width, 0.002..=0.5, 0.0005);
        pair(ui, "height (cm)", &mut spec.warp.height, &mut spec.weft.height, 0.001..=0.5, 0.0005);
        pair(
            ui,
            "fiber radius (cm)",
            &mut spec.warp.fiber_radius,
            &mut spec.weft.fiber_radius,
            0.0001..=0.01,
            0.00005,
        );
        pair(ui, "ply twist (1/cm)", &mut spec.warp.ply_twist, &mut spec.weft.ply_twist, -50.0..=50.0, 0.1);
        let counts = |ui: &mut egui::Ui,
                      label: &str,
                      warp: &mut u32,
                      weft: &mut u32,
                      range: std::ops::RangeInclusive<u32>| {
            ui.label(label);
            for v in [warp, weft] {
                ui.add(egui::DragValue::new(v).range(range.clone()));
            }
            ui.end_row();
        };
        counts(ui, "plies", &mut spec.warp.plies, &mut spec.weft.plies, 1..=6);
        counts(ui, "fibers per ply", &mut spec.warp.fibers_per_ply, &mut spec.weft.fibers_per_ply, 1..=200);
        let mut spacing =
            [spec.spacing_warp.unwrap_or(spec.warp.width), spec.spacing_weft.unwrap_or(spec.weft.width)];
        let before = spacing;
        let [a, b] = &mut spacing;
        pair(ui, "spacing (cm)", a, b, 0.002..=0.5, 0.0005);
        // Exactly the values the widgets wrote: a change, not a tolerance.
        #[allow(clippy::float_cmp)]
        let changed = spacing != before;
        if changed {
            spec.spacing_warp = Some(spacing[0]);
            spec.spacing_weft = Some(spacing[1]);
        }
    });
    let default = YarnParams::default();
    if ui.small_button("Reset yarns").on_hover_text("The scene format's default yarn").clicked() {
        spec.warp = default;
        spec.weft = default;
        spec.spacing_warp = None;
        spec.spacing_weft = None;
        spec.crimp = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn default_scene() -> SceneFile {
        SceneFile::default_scene()
    }

    #[test]
    fn a_weave_edit_turns_a_preset_into_its_spec_and_keeps_its_materials() {
        let mut scene = default_scene();
        let before_materials = materials(&scene);
        let before = woven_spec(&scene).unwrap();
        flip_cell(&mut scene, 0, 0).unwrap();
        assert!(scene.fabric.preset.is_none());
        assert_eq!(materials(&scene), before_materials);
        let after = woven_spec(&scene).unwrap();
        assert_ne!(after.weave.draft().warp_over(0, 0), before.weave.draft().warp_over(0, 0));
        assert_eq!(after.warp, before.warp);
        // The edited scene builds (what the bake does first).
        scene.build().unwrap();
    }

    #[test]
    fn refused_edits_leave_the_scene_unchanged_and_say_why() {
        let mut scene = default_scene();
        set_weave_preset(&mut scene, WeavePreset::Plain).unwrap();
        let before = scene.clone();
        // Plain weave: flipping one cell leaves its row all one colour.
        let e = flip_cell(&mut scene, 0, 0).unwrap_err();
        assert!(e.contains("pick 0, end 0"), "{e}");
        assert_eq!(scene, before);
        let e = flip_cell(&mut scene, 5, 0).unwrap_err();
        assert!(e.contains("pick 5"), "{e}");
        // Satin 5 cut to 3 ends leaves a pick with no interlacing.
        set_weave_preset(&mut scene, WeavePreset::Satin4_1).unwrap();
        let before = scene.clone();
        assert!(resize_draft(&mut scene, 5, 3).unwrap_err().contains("does not weave"));
        assert_eq!(scene, before);
    }

    #[test]
    fn resizing_repeats_the_draft() {
        let mut scene = default_scene();
        set_weave_preset(&mut scene, WeavePreset::Plain).unwrap();
        resize_draft(&mut scene, 4, 6).unwrap();
        let draft = woven_spec(&scene).unwrap().weave.draft();
        assert_eq!((draft.rows(), draft.cols()), (4, 6));
        for r in 0..4 {
            for c in 0..6 {
                assert_eq!(draft.warp_over(r, c), (r + c) % 2 == 0, "({r}, {c})");
            }
        }
    }

    #[test]
    fn fiber_fields_are_range_checked_and_written_to_the_materials_section() {
        let mut scene = default_scene();
        set_fiber_field(&mut scene, 1, FiberField::BetaTt(12.5)).unwrap();
        let Some(MaterialDesc::Fiber(p)) = scene.materials.weft else { panic!("weft material") };
        assert!((p.beta_tt_deg - 12.5).abs() < 1e-12);
        assert!(scene.materials.warp.is_some(), "the preset's warp material is kept");
        let before = scene.clone();
        let e = set_fiber_field(&mut scene, 0, FiberField::GammaTt(0.1)).unwrap_err();
        assert!(e.contains("gamma_tt_deg") && e.contains("0.5"), "{e}");
        let e = set_fiber_field(&mut scene, 0, FiberField::ColourTt([0.5, 1.5, 0.0])).unwrap_err();
        assert!(e.contains("c_tt"), "{e}");
        assert_eq!(scene, before);
    }
}
