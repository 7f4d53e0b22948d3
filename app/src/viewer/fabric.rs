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
//!
//! Patterned cloth ([`pattern_panel`]) edits the scene's `[pattern]`: the other weaves (exemplars
//! 1, 2, ...) and the block map, painted block by block with one exemplar as the brush, or
//! loaded from a grayscale PNG. Block sizes follow from the drafts (the scene format's rule), so
//! the panel never sets them.

use std::path::Path;

use eframe::egui;
use twill_precompute::Rgb;
use twill_precompute::bcsdf::{BETA_RANGE_DEG, FiberParams, GAMMA_RANGE_DEG, MaterialDesc};
use twill_precompute::fabric::presets::{FabricSpec, WeaveSource, WovenSpec, fabric_preset};
use twill_precompute::fabric::weave::{WeaveDraft, WeavePreset};
use twill_precompute::fabric::yarn::YarnParams;
use twill_precompute::scene::{
    FabricSection, MAX_PATTERN_WEAVES, PatternMapSource, PatternSection, PatternWeave, SceneFile,
};

/// The two yarn roles and their material slots.
pub const YARNS: [(&str, usize); 2] = [("warp", 0), ("weft", 1)];
/// Largest repeat the draft editor offers (the format allows up to `WeaveDraft::MAX_SIZE`).
pub const MAX_EDITOR_REPEAT: usize = 24;
/// Side of a draft cell on screen, points.
const CELL_POINTS: f32 = 18.0;

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

/// Writes both slots' materials into `[materials]` (a preset's would otherwise be lost with it).
pub(super) fn pin_materials(scene: &mut SceneFile) {
    [scene.materials.warp, scene.materials.weft] = scene.material_slots();
}

/// Replaces the fabric with `spec`, keeping the materials a preset gave it.
pub fn set_woven(scene: &mut SceneFile, spec: WovenSpec) {
    pin_materials(scene);
    scene.fabric = FabricSection { preset: None, spec: Some(FabricSpec::Woven(Box::new(spec))) };
}

/// Sets the material of `slot` (0 warp, 1 weft).
pub fn set_material(scene: &mut SceneFile, slot: usize, desc: MaterialDesc) {
    pin_materials(scene);
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

/// Reads a WIF file into the scene's weave, and its colours, when it has a colour table, into
/// the scene's colourway (palette `wif1`, `wif2`, ... and the warp and weft orders).
pub fn import_wif(scene: &mut SceneFile, path: &Path) -> Result<(), String> {
    let draft = twill_precompute::fabric::wif::read_wif(path).map_err(|e| e.to_string())?;
    let colours = twill_precompute::fabric::wif::read_wif_colours(path).map_err(|e| e.to_string())?;
    let mut candidate = scene.clone();
    set_draft(&mut candidate, draft)?;
    if let Some(colours) = colours {
        candidate.apply_wif_colours(&colours);
        candidate.check_colourway().map_err(|e| format!("{}: its colours: {e}", path.display()))?;
    }
    *scene = candidate;
    Ok(())
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
    let Some(MaterialDesc::Fiber(mut p)) = scene.material_slots()[slot] else {
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
    let resolved = scene.material_slots();
    if woven_spec(scene).is_none() && scene.fabric.preset.is_none() {
        ui.label("Imported fibers: one material (the warp's).");
    }
    for (name, slot) in YARNS {
        ui.label(egui::RichText::new(name).strong());
        match resolved[slot] {
            Some(MaterialDesc::Fiber(p)) => {
                let mut edited = p;
                if fiber_controls(ui, slot, &mut edited) {
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
            "Single scattering follows at once. Multiple scattering follows a colour edit at once \
             too from the fabric's second colour edit on (the first makes its recolouring basis), \
             and a lobe edit when its background bake finishes (the old one stays until then).",
        )
        .small()
        .weak(),
    );
}

/// The fiber parameters' widgets; true when the user changed one (showing them never does).
fn fiber_controls(ui: &mut egui::Ui, slot: usize, p: &mut FiberParams) -> bool {
    egui::Grid::new(("twill.fibers", slot))
        .num_columns(2)
        .show(ui, |ui| {
            let mut changed =
                colour_row(ui, "C_R (sheen)", &mut p.c_r, "Reflectance of the R lobe at normal incidence");
            changed |=
                angle_row(ui, "β_R", &mut p.beta_r_deg, BETA_RANGE_DEG, "Longitudinal width of the R lobe");
            changed |= colour_row(ui, "C_TT (colour)", &mut p.c_tt, "Transmission colour of the TT lobe");
            changed |= angle_row(
                ui,
                "β_TT",
                &mut p.beta_tt_deg,
                BETA_RANGE_DEG,
                "Longitudinal width of the TT lobe",
            );
            changed |=
                angle_row(ui, "γ_TT", &mut p.gamma_tt_deg, GAMMA_RANGE_DEG, "Azimuthal width of the TT lobe");
            changed
        })
        .inner
}

fn colour_row(ui: &mut egui::Ui, label: &str, colour: &mut Rgb, hover: &str) -> bool {
    ui.label(label).on_hover_text(hover);
    let mut rgb = colour.to_array().map(|c| c as f32);
    // egui's picker edits linear RGB here, as the scene format stores it.
    let changed = ui.color_edit_button_rgb(&mut rgb).changed();
    if changed {
        *colour = Rgb::from_array(rgb.map(|c| f64::from(c).clamp(0.0, 1.0)));
    }
    ui.end_row();
    changed
}

fn angle_row(ui: &mut egui::Ui, label: &str, degrees: &mut f64, (lo, hi): (f64, f64), hover: &str) -> bool {
    ui.label(label).on_hover_text(hover);
    let mut value = *degrees;
    let changed = ui
        .add(
            egui::Slider::new(&mut value, lo..=hi)
                .logarithmic(true)
                .clamping(egui::SliderClamping::Edits)
                .suffix("°")
                .max_decimals(2),
        )
        .changed();
    if changed {
        *degrees = value;
    }
    ui.end_row();
    changed
}

/// What the weave panel asks of the viewer.
pub enum WeaveAction {
    ImportWif(String),
}

/// Text fields of the weave panel that live between frames.
#[derive(Default)]
pub struct WeaveForm {
    pub wif_path: String,
    pub png_path: String,
    /// The exemplar painted into the pattern map.
    pub brush: usize,
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
        let r = ui.add(
            egui::DragValue::new(&mut cols)
                .range(2..=MAX_EDITOR_REPEAT)
                .clamp_existing_to_range(false)
                .suffix(" ends"),
        );
        ui.label("×");
        let c = ui.add(
            egui::DragValue::new(&mut rows)
                .range(2..=MAX_EDITOR_REPEAT)
                .clamp_existing_to_range(false)
                .suffix(" picks"),
        );
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

    egui::CollapsingHeader::new("Pattern").default_open(false).show(ui, |ui| {
        pattern_panel(ui, scene, form);
    });
    egui::CollapsingHeader::new("Yarns").default_open(false).show(ui, |ui| {
        let mut edited = woven_spec(scene).unwrap_or(spec);
        if yarn_controls(ui, &mut edited) {
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
    let colour = |slot: usize, scale: f64, fallback: u8| match scene.material_slots()[slot] {
        Some(MaterialDesc::Fiber(p)) => srgb(p.c_tt.to_array().map(|c| c * scale)),
        Some(MaterialDesc::Lambert { albedo }) => srgb(albedo.to_array().map(|c| c * scale)),
        None => egui::Color32::from_gray(fallback),
    };
    [colour(0, 0.45, 60), colour(1, 1.0, 200)]
}

pub(super) fn srgb(linear: [f64; 3]) -> egui::Color32 {
    let [r, g, b] = linear.map(|c| egui::ecolor::gamma_u8_from_linear_f32(c.clamp(0.0, 1.0) as f32));
    egui::Color32::from_rgb(r, g, b)
}

/// Spacing and each yarn's main parameters; true when the user changed one (showing them never
/// does: values outside the widgets' ranges are left alone until edited). The bake validates the
/// whole fabric and reports anything else.
fn yarn_controls(ui: &mut egui::Ui, spec: &mut WovenSpec) -> bool {
    let mut changed = egui::Grid::new("twill.yarns")
        .num_columns(3)
        .show(ui, |ui| {
            ui.label("");
            ui.label("warp");
            ui.label("weft");
            ui.end_row();
            let pair = |ui: &mut egui::Ui,
                        label: &str,
                        values: [&mut f64; 2],
                        range: std::ops::RangeInclusive<f64>,
                        speed: f64| {
                ui.label(label);
                let mut changed = false;
                for v in values {
                    let drag = egui::DragValue::new(v)
                        .range(range.clone())
                        .clamp_existing_to_range(false)
                        .speed(speed)
                        .max_decimals(5);
                    changed |= ui.add(drag).changed();
                }
                ui.end_row();
                changed
            };
            let (w, f) = (&mut spec.warp, &mut spec.weft);
            let mut changed = pair(ui, "width (cm)", [&mut w.width, &mut f.width], 0.002..=0.5, 0.0005);
            changed |= pair(ui, "height (cm)", [&mut w.height, &mut f.height], 0.001..=0.5, 0.0005);
            changed |= pair(
                ui,
                "fiber radius (cm)",
                [&mut w.fiber_radius, &mut f.fiber_radius],
                0.0001..=0.01,
                0.00005,
            );
            changed |= pair(ui, "ply twist (1/cm)", [&mut w.ply_twist, &mut f.ply_twist], -50.0..=50.0, 0.1);
            let counts = |ui: &mut egui::Ui,
                          label: &str,
                          values: [&mut u32; 2],
                          range: std::ops::RangeInclusive<u32>| {
                ui.label(label);
                let mut changed = false;
                for v in values {
                    changed |= ui
                        .add(egui::DragValue::new(v).range(range.clone()).clamp_existing_to_range(false))
                        .changed();
                }
                ui.end_row();
                changed
            };
            changed |= counts(ui, "plies", [&mut w.plies, &mut f.plies], 1..=6);
            changed |= counts(ui, "fibers per ply", [&mut w.fibers_per_ply, &mut f.fibers_per_ply], 1..=200);
            let mut spacing =
                [spec.spacing_warp.unwrap_or(spec.warp.width), spec.spacing_weft.unwrap_or(spec.weft.width)];
            let [a, b] = &mut spacing;
            if pair(ui, "spacing (cm)", [a, b], 0.002..=0.5, 0.0005) {
                spec.spacing_warp = Some(spacing[0]);
                spec.spacing_weft = Some(spacing[1]);
                changed = true;
            }
            changed
        })
        .inner;
    if ui.small_button("Reset yarns").on_hover_text("The scene format's default yarn").clicked() {
        let default = YarnParams::default();
        spec.warp = default;
        spec.weft = default;
        spec.spacing_warp = None;
        spec.spacing_weft = None;
        spec.crimp = None;
        changed = true;
    }
    changed
}

/// Largest side of a painted pattern map, in blocks.
pub const MAX_PAINTED_MAP: usize = 32;

/// Turns patterned cloth on (a checkerboard of the fabric's weave and a plain weave) or off.
pub fn set_patterned(scene: &mut SceneFile, on: bool) -> Result<(), String> {
    if !on {
        scene.pattern = None;
        return Ok(());
    }
    let spec = woven_spec(scene).ok_or("only a procedural weave can be patterned")?;
    if scene.pattern.is_none() {
        // The pattern sets the blocks from the drafts.
        let mut spec = spec;
        spec.blocks = [1, 1];
        set_woven(scene, spec);
        scene.pattern = Some(PatternSection {
            weaves: vec![PatternWeave::Preset(WeavePreset::Plain)],
            map: PatternMapSource::Rows(vec!["01".into(), "10".into()]),
        });
    }
    Ok(())
}

/// Paints block (`row` from the top, `col`) of the pattern map with exemplar `exemplar`.
pub fn paint_block(scene: &mut SceneFile, row: usize, col: usize, exemplar: usize) -> Result<(), String> {
    let pattern = scene.pattern.as_mut().ok_or("the cloth is not patterned")?;
    if exemplar > pattern.weaves.len() {
        return Err(format!("exemplar {exemplar}: the pattern has exemplars 0..={}", pattern.weaves.len()));
    }
    let PatternMapSource::Rows(rows) = &mut pattern.map else {
        return Err("the map is a PNG file: paint a new map first (New map)".into());
    };
    let width = rows.first().map_or(0, |r| r.chars().count());
    if row >= rows.len() || col >= width {
        return Err(format!("block ({row}, {col}) is outside the {width} x {} map", rows.len()));
    }
    let glyph = char::from_digit(exemplar as u32, 36).ok_or("too many exemplars")?;
    rows[row] = rows[row].chars().enumerate().map(|(c, g)| if c == col { glyph } else { g }).collect();
    Ok(())
}

/// Resizes a painted map to `height` x `width` blocks, repeating the old one.
pub fn resize_map(scene: &mut SceneFile, height: usize, width: usize) -> Result<(), String> {
    let pattern = scene.pattern.as_mut().ok_or("the cloth is not patterned")?;
    if !(1..=MAX_PAINTED_MAP).contains(&height) || !(1..=MAX_PAINTED_MAP).contains(&width) {
        return Err(format!("a painted map has 1..={MAX_PAINTED_MAP} blocks per side"));
    }
    let old: Vec<Vec<char>> = match &pattern.map {
        PatternMapSource::Rows(rows) => rows.iter().map(|r| r.chars().collect()).collect(),
        PatternMapSource::Png(_) => vec![vec!['0']],
    };
    let at = |r: usize, c: usize| old[r % old.len()][c % old[r % old.len()].len()];
    pattern.map =
        PatternMapSource::Rows((0..height).map(|r| (0..width).map(|c| at(r, c)).collect()).collect());
    Ok(())
}

/// The patterned-cloth panel (inside the weave panel).
fn pattern_panel(ui: &mut egui::Ui, scene: &mut SceneFile, form: &mut WeaveForm) {
    let mut on = scene.pattern.is_some();
    if ui
        .checkbox(&mut on, "patterned cloth")
        .on_hover_text("Blocks of different weaves of the same yarns (paper section 6.4)")
        .changed()
    {
        form.message = set_patterned(scene, on).err();
    }
    let Some(pattern) = scene.pattern.as_mut() else { return };
    let palette = |k: usize| {
        let hue = (k as f32 * 0.61803).fract();
        egui::Color32::from(egui::ecolor::Hsva::new(hue, 0.55, 0.85, 1.0))
    };
    ui.horizontal_wrapped(|ui| {
        ui.label("exemplar 0: the weave above");
    });
    let mut remove = None;
    for (i, weave) in pattern.weaves.iter_mut().enumerate() {
        let k = i + 1;
        ui.horizontal(|ui| {
            ui.colored_label(palette(k), "■");
            let name = match weave {
                PatternWeave::Preset(p) => p.name().to_owned(),
                PatternWeave::Draft(d) => format!("draft {} x {}", d.rows(), d.cols()),
                PatternWeave::Wif(path) => path.display().to_string(),
            };
            egui::ComboBox::from_id_salt(("twill.pattern.weave", k)).selected_text(name).show_ui(ui, |ui| {
                for p in WeavePreset::ALL {
                    if ui.selectable_label(*weave == PatternWeave::Preset(p), p.name()).clicked() {
                        *weave = PatternWeave::Preset(p);
                    }
                }
            });
            ui.label(format!("exemplar {k}"));
            if ui.small_button("×").on_hover_text("Remove (its blocks become exemplar 0)").clicked() {
                remove = Some(k);
            }
        });
    }
    if let Some(k) = remove {
        pattern.weaves.remove(k - 1);
        if let PatternMapSource::Rows(rows) = &mut pattern.map {
            // Blocks of the removed exemplar become 0, later ones move down by one.
            for row in rows.iter_mut() {
                *row = row
                    .chars()
                    .map(|g| match g.to_digit(36).map(|d| d as usize) {
                        Some(d) if d == k => '0',
                        Some(d) if d > k => char::from_digit((d - 1) as u32, 36).unwrap_or('0'),
                        _ => g,
                    })
                    .collect();
            }
        }
        form.brush = form.brush.min(pattern.weaves.len());
    }
    if pattern.weaves.len() < MAX_PATTERN_WEAVES && ui.button("Add a weave").clicked() {
        pattern.weaves.push(PatternWeave::Preset(WeavePreset::Satin4_1));
    }

    ui.horizontal(|ui| {
        ui.label("brush");
        for k in 0..=pattern.weaves.len() {
            let text = egui::RichText::new(k.to_string()).color(palette(k));
            if ui.selectable_label(form.brush == k, text).clicked() {
                form.brush = k;
            }
        }
    });
    match &pattern.map {
        PatternMapSource::Rows(rows) => {
            let cells: Vec<Vec<usize>> = rows
                .iter()
                .map(|r| r.chars().map(|g| g.to_digit(36).unwrap_or(0) as usize).collect())
                .collect();
            let (h, w) = (cells.len(), cells.first().map_or(0, Vec::len));
            let (mut new_h, mut new_w) = (h, w);
            ui.horizontal(|ui| {
                ui.label("map");
                ui.add(egui::DragValue::new(&mut new_w).range(1..=MAX_PAINTED_MAP).suffix(" wide"));
                ui.add(egui::DragValue::new(&mut new_h).range(1..=MAX_PAINTED_MAP).suffix(" high"));
            });
            if let Some((r, c)) = block_grid(ui, &cells, palette) {
                form.message = paint_block(scene, r, c, form.brush).err();
            } else if (new_h, new_w) != (h, w) {
                form.message = resize_map(scene, new_h, new_w).err();
            }
        }
        PatternMapSource::Png(path) => {
            ui.label(format!("map: {} (gray levels, darkest = exemplar 0)", path.display()));
            if ui.button("New painted map").clicked() {
                pattern.map = PatternMapSource::Rows(vec!["01".into(), "10".into()]);
            }
        }
    }
    ui.horizontal(|ui| {
        ui.add(egui::TextEdit::singleline(&mut form.png_path).hint_text("map.png").desired_width(140.0));
        if ui.button("Load PNG map").on_hover_text("A grayscale image, one pixel per block").clicked()
            && let Some(pattern) = scene.pattern.as_mut()
            && !form.png_path.trim().is_empty()
        {
            pattern.map = PatternMapSource::Png(form.png_path.trim().into());
        }
    });
}

/// The pattern map as a grid of blocks, top row first; returns the block clicked or dragged over.
fn block_grid(
    ui: &mut egui::Ui,
    cells: &[Vec<usize>],
    palette: impl Fn(usize) -> egui::Color32,
) -> Option<(usize, usize)> {
    let (rows, cols) = (cells.len(), cells.first().map_or(0, Vec::len));
    if rows == 0 || cols == 0 {
        return None;
    }
    let cell = CELL_POINTS.min((ui.available_width() - 4.0) / cols as f32).max(4.0);
    let (rect, response) = ui.allocate_exact_size(
        egui::vec2(cell * cols as f32, cell * rows as f32),
        egui::Sense::click_and_drag(),
    );
    let painter = ui.painter_at(rect);
    for (r, row) in cells.iter().enumerate() {
        for (c, &k) in row.iter().enumerate() {
            let min = rect.min + egui::vec2(c as f32 * cell, r as f32 * cell);
            painter.rect_filled(
                egui::Rect::from_min_size(min, egui::vec2(cell, cell)).shrink(0.5),
                1.0,
                palette(k),
            );
        }
    }
    let response = response.on_hover_text("Click or drag to paint blocks with the brush");
    if !(response.clicked() || response.dragged()) {
        return None;
    }
    let p = response.interact_pointer_pos()?;
    let v = (p - rect.min) / cell;
    (v.x >= 0.0 && v.y >= 0.0).then(|| ((v.y as usize).min(rows - 1), (v.x as usize).min(cols - 1)))
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
        let before_materials = scene.material_slots();
        let before = woven_spec(&scene).unwrap();
        flip_cell(&mut scene, 0, 0).unwrap();
        assert!(scene.fabric.preset.is_none());
        assert_eq!(scene.material_slots(), before_materials);
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
    fn patterned_cloth_is_painted_block_by_block_and_builds() {
        let mut scene = default_scene();
        set_patterned(&mut scene, true).unwrap();
        resize_map(&mut scene, 4, 4).unwrap();
        paint_block(&mut scene, 0, 0, 1).unwrap();
        paint_block(&mut scene, 0, 1, 1).unwrap();
        let Some(PatternSection { map: PatternMapSource::Rows(rows), .. }) = &scene.pattern else {
            panic!("rows")
        };
        assert_eq!(rows, &["11".to_owned() + "01", "1010".into(), "0101".into(), "1010".into()]);
        assert!(paint_block(&mut scene, 0, 0, 2).unwrap_err().contains("0..=1"));
        assert!(paint_block(&mut scene, 4, 0, 1).unwrap_err().contains("outside"));
        assert!(resize_map(&mut scene, 0, 3).is_err());
        let built = scene.build().unwrap();
        assert_eq!(built.exemplars().len(), 2);
        assert_eq!((built.pattern_map().width, built.pattern_map().height), (4, 4));
        set_patterned(&mut scene, false).unwrap();
        assert!(scene.pattern.is_none());
    }

    #[test]
    fn showing_the_panels_changes_nothing() {
        // A scene with values outside the widgets' ranges (yarns and mesh) and a pattern: the
        // panels must show them without writing anything (a write would start a bake).
        let mut scenes = vec![default_scene()];
        let mut odd = default_scene();
        let mut spec = woven_spec(&odd).unwrap();
        spec.warp.fibers_per_ply = 400;
        spec.weft.fiber_radius = 0.02;
        set_woven(&mut odd, spec);
        odd.mesh.thickness_scale = 40.0;
        odd.mesh.builtin = Some("cushion".into());
        set_patterned(&mut odd, true).unwrap();
        scenes.push(odd);
        let ctx = egui::Context::default();
        for scene in scenes {
            let mut shown = scene.clone();
            let mut form = WeaveForm::default();
            let mut mesh_form = super::super::mesh::MeshForm::default();
            for _ in 0..3 {
                let mut output = ctx.run_ui(egui::RawInput::default(), |ui| {
                    fibers_panel(ui, &mut shown);
                    let _ = weave_panel(ui, &mut shown, &mut form);
                    // The collapsed sections' contents, directly.
                    pattern_panel(ui, &mut shown, &mut form);
                    let mut spec = woven_spec(&shown).unwrap();
                    assert!(!yarn_controls(ui, &mut spec), "showing the yarns is no edit");
                    assert_eq!(Some(spec), woven_spec(&shown));
                    let swatch = shown.swatch.size_cm;
                    super::super::mesh::mesh_panel(ui, &mut shown.mesh, swatch, &mut mesh_form);
                });
                output.textures_delta.clear();
            }
            assert_eq!(shown, scene);
            assert!(form.message.is_none(), "{:?}", form.message);
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
