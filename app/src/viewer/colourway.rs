//! The colourway panel: a palette of yarn colours and the warp and weft colour orders.
//!
//! How it works: like the other fabric panels it edits the viewer's [`SceneFile`] in place, in
//! the scene format's terms (`[materials.palette]`, `warp_order`, `weft_order`), so Save writes
//! what is on screen. Every edit is checked as the bake would check it
//! ([`SceneFile::check_colourway`]: names, counts, the joint repeat of weave and colours) and
//! refused with the reason, leaving the scene as it was. Each order shows as a strip of
//! squares, one per thread of its colour repeat, edited like a draft's threading: clicking a
//! square gives that thread the next palette colour; the order's text can also be typed. A
//! recolouring is a material edit (single scattering at once, multiple scattering after its
//! rebake); an order edit changes which yarn carries which colour, and with it the exemplar
//! repeat, so the viewer rebakes it like a weave edit.

use eframe::egui;
use twill_precompute::bcsdf::MaterialDesc;
use twill_precompute::fabric::colour_order::{ColourOrder, MAX_REPEAT_THREADS};
use twill_precompute::scene::{MAX_PALETTE_COLOURS, PaletteColour, SceneFile, YarnSlot};

use super::fabric::{pin_materials, srgb};

/// Side of a thread square on screen, points.
const THREAD_POINTS: f32 = 14.0;

/// Text fields of the colourway panel that live between frames.
#[derive(Default)]
pub struct ColourwayForm {
    pub warp_text: String,
    pub weft_text: String,
    pub new_name: String,
    pub message: Option<String>,
}

/// Applies `edit` to a copy of the scene and keeps it only if the colourway still checks.
fn checked(
    scene: &mut SceneFile,
    edit: impl FnOnce(&mut SceneFile) -> Result<(), String>,
) -> Result<(), String> {
    let mut candidate = scene.clone();
    edit(&mut candidate)?;
    candidate.check_colourway()?;
    *scene = candidate;
    Ok(())
}

/// Turns the two yarns into a two-colour palette (`warp`, `weft`) with one-colour orders, the
/// same cloth as before, ready to recolour and stripe.
pub fn start_colourway(scene: &mut SceneFile) -> Result<(), String> {
    checked(scene, |s| {
        pin_materials(s);
        let plain = |base| PaletteColour { base, c_r: None, c_tt: None, albedo: None };
        s.materials.palette =
            [("warp".to_owned(), plain(YarnSlot::Warp)), ("weft".to_owned(), plain(YarnSlot::Weft))]
                .into_iter()
                .collect();
        s.materials.warp_order = Some("1 warp".into());
        s.materials.weft_order = Some("1 weft".into());
        Ok(())
    })
}

/// Sets the warp or weft colour order from its text (`"2 navy, 1 red"`).
pub fn set_order(scene: &mut SceneFile, slot: YarnSlot, text: &str) -> Result<(), String> {
    checked(scene, |s| {
        let order = Some(text.trim().to_owned());
        match slot {
            YarnSlot::Warp => s.materials.warp_order = order,
            YarnSlot::Weft => s.materials.weft_order = order,
        }
        Ok(())
    })
}

/// Adds palette colour `name` (letters, digits and `_`), or recolours it if it exists: `c_tt`
/// (fiber yarns) or `albedo` (Lambert yarns) of its base yarn becomes `linear_rgb`.
pub fn set_palette_colour(
    scene: &mut SceneFile,
    name: &str,
    base: YarnSlot,
    linear_rgb: [f64; 3],
) -> Result<(), String> {
    if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(format!(
            "{name:?}: a colour's name is letters, digits and _ (it is written in the orders)"
        ));
    }
    if !linear_rgb.iter().all(|c| (0.0..=1.0).contains(c)) {
        return Err(format!("{name}: colour {linear_rgb:?} is outside 0..=1"));
    }
    checked(scene, |s| {
        if !s.materials.palette.contains_key(name) && s.materials.palette.len() >= MAX_PALETTE_COLOURS {
            return Err(format!("the palette holds at most {MAX_PALETTE_COLOURS} colours"));
        }
        let base = s.materials.palette.get(name).map_or(base, |c| c.base);
        let lambert = matches!(s.material_slots()[base as usize], Some(MaterialDesc::Lambert { .. }));
        let rgb = twill_precompute::Rgb::from_array(linear_rgb);
        let entry = s.materials.palette.entry(name.to_owned()).or_insert(PaletteColour {
            base,
            c_r: None,
            c_tt: None,
            albedo: None,
        });
        if lambert {
            entry.albedo = Some(rgb);
        } else {
            entry.c_tt = Some(rgb);
        }
        Ok(())
    })
}

/// Removes palette colour `name`; refused while an order uses it.
pub fn remove_palette_colour(scene: &mut SceneFile, name: &str) -> Result<(), String> {
    checked(scene, |s| {
        s.materials.palette.remove(name).ok_or_else(|| format!("the palette has no colour {name:?}"))?;
        Ok(())
    })
    .map_err(|e| format!("{name} cannot go: {e}"))
}

/// Gives thread `thread` of the `slot` order's colour repeat the next palette colour.
pub fn cycle_thread(scene: &mut SceneFile, slot: YarnSlot, thread: usize) -> Result<(), String> {
    let (order, names) = parsed_order(scene, slot)?;
    let mut threads = order.threads().to_vec();
    let Some(colour) = threads.get_mut(thread) else {
        return Err(format!("thread {thread} is past the colour repeat of {}", threads.len()));
    };
    *colour = (*colour + 1) % names.len() as u32;
    let text = written(&threads, &names)?;
    set_order(scene, slot, &text)
}

/// Lengthens (`delta > 0`) or shortens the `slot` order's colour repeat by one thread at its end
/// (a new thread takes the colour of the last).
pub fn resize_order(scene: &mut SceneFile, slot: YarnSlot, delta: isize) -> Result<(), String> {
    let (order, names) = parsed_order(scene, slot)?;
    let mut threads = order.threads().to_vec();
    match delta.signum() {
        1 if threads.len() < MAX_REPEAT_THREADS => threads.push(*threads.last().unwrap_or(&0)),
        -1 if threads.len() > 1 => {
            threads.pop();
        }
        _ => return Ok(()),
    }
    let text = written(&threads, &names)?;
    set_order(scene, slot, &text)
}

/// The order of `slot` parsed against the palette's names.
fn parsed_order(scene: &SceneFile, slot: YarnSlot) -> Result<(ColourOrder, Vec<String>), String> {
    let colourway = scene.colourway()?.ok_or("the cloth has no colourway yet")?;
    let order = match slot {
        YarnSlot::Warp => colourway.warp,
        YarnSlot::Weft => colourway.weft,
    };
    Ok((order, colourway.names))
}

/// Threads written as an order's text.
fn written(threads: &[u32], names: &[String]) -> Result<String, String> {
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let order = ColourOrder::from_threads("order", threads.to_vec()).map_err(|e| e.to_string())?;
    Ok(order.display(&refs).to_string())
}

/// A palette entry's colour in linear RGB: its transmission colour or albedo.
fn linear_colour(scene: &SceneFile, colour: &PaletteColour) -> twill_precompute::Rgb {
    match scene.material_slots()[colour.base as usize] {
        Some(MaterialDesc::Fiber(p)) => colour.c_tt.unwrap_or(p.c_tt),
        Some(MaterialDesc::Lambert { albedo }) => colour.albedo.unwrap_or(albedo),
        None => twill_precompute::Rgb::splat(0.5),
    }
}

/// The colourway panel.
pub fn colourway_panel(ui: &mut egui::Ui, scene: &mut SceneFile, form: &mut ColourwayForm) {
    if scene.materials.palette.is_empty() {
        ui.label("One colour per yarn. A colourway colours threads from a palette (stripes, checks).");
        if ui.button("Start a colourway").clicked() {
            form.message = start_colourway(scene).err();
        }
        show_message(ui, form);
        return;
    }
    let names: Vec<String> = scene.materials.palette.keys().cloned().collect();
    let linear: Vec<twill_precompute::Rgb> =
        scene.materials.palette.values().map(|c| linear_colour(scene, c)).collect();
    let colours: Vec<egui::Color32> = linear.iter().map(|c| srgb(c.to_array())).collect();
    egui::Grid::new("twill.palette").num_columns(3).show(ui, |ui| {
        for (name, shown) in names.iter().zip(&linear) {
            let colour = scene.materials.palette[name];
            ui.label(name).on_hover_text(format!("recolours the {:?} yarn", colour.base));
            // egui's picker edits linear RGB here, as the scene format stores it.
            let mut rgb = shown.to_array().map(|c| c as f32);
            if ui.color_edit_button_rgb(&mut rgb).changed() {
                let picked = rgb.map(|c| f64::from(c).clamp(0.0, 1.0));
                form.message = set_palette_colour(scene, name, colour.base, picked).err();
            }
            if ui.small_button("remove").clicked() {
                form.message = remove_palette_colour(scene, name).err();
            }
            ui.end_row();
        }
    });
    ui.horizontal(|ui| {
        ui.add(egui::TextEdit::singleline(&mut form.new_name).hint_text("new colour").desired_width(90.0));
        for (label, base) in [("+ warp yarn", YarnSlot::Warp), ("+ weft yarn", YarnSlot::Weft)] {
            if ui.button(label).on_hover_text("A new colour of that yarn (then pick it)").clicked() {
                let name = form.new_name.trim().to_owned();
                form.message = set_palette_colour(scene, &name, base, [0.5, 0.5, 0.5]).err();
                if form.message.is_none() {
                    form.new_name.clear();
                }
            }
        }
    });
    for (label, slot) in [("warp", YarnSlot::Warp), ("weft", YarnSlot::Weft)] {
        order_row(ui, scene, form, label, slot, &names, &colours);
    }
    show_message(ui, form);
}

/// One order: its strip of threads (click to recolour), -/+ for the repeat, and its text.
fn order_row(
    ui: &mut egui::Ui,
    scene: &mut SceneFile,
    form: &mut ColourwayForm,
    label: &str,
    slot: YarnSlot,
    names: &[String],
    colours: &[egui::Color32],
) {
    let Ok((order, _)) = parsed_order(scene, slot) else { return };
    ui.label(egui::RichText::new(format!("{label} order")).strong());
    ui.horizontal(|ui| {
        let threads = order.threads();
        let cell = THREAD_POINTS.min((ui.available_width() - 60.0) / threads.len() as f32).max(4.0);
        let (rect, response) =
            ui.allocate_exact_size(egui::vec2(cell * threads.len() as f32, cell), egui::Sense::click());
        let painter = ui.painter_at(rect);
        for (i, colour) in threads.iter().enumerate() {
            let min = rect.min + egui::vec2(i as f32 * cell, 0.0);
            let square = egui::Rect::from_min_size(min, egui::vec2(cell, cell)).shrink(0.5);
            painter.rect_filled(
                square,
                1.0,
                colours.get(*colour as usize).copied().unwrap_or(egui::Color32::GRAY),
            );
        }
        let hovered =
            response.hover_pos().map(|p| (((p.x - rect.min.x) / cell) as usize).min(threads.len() - 1));
        let response = response
            .on_hover_text(format!("Click a thread for the next palette colour ({})", names.join(", ")));
        if let (true, Some(thread)) = (response.clicked(), hovered) {
            form.message = cycle_thread(scene, slot, thread).err();
        }
        if ui.small_button("−").on_hover_text("One thread fewer in the colour repeat").clicked() {
            form.message = resize_order(scene, slot, -1).err();
        }
        if ui.small_button("+").on_hover_text("One thread more").clicked() {
            form.message = resize_order(scene, slot, 1).err();
        }
    });
    let current = match slot {
        YarnSlot::Warp => scene.materials.warp_order.clone(),
        YarnSlot::Weft => scene.materials.weft_order.clone(),
    }
    .unwrap_or_default();
    let text = match slot {
        YarnSlot::Warp => &mut form.warp_text,
        YarnSlot::Weft => &mut form.weft_text,
    };
    let response = ui.add(egui::TextEdit::singleline(text).hint_text(current.as_str()).desired_width(220.0));
    if response.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter)) && !text.trim().is_empty() {
        let typed = std::mem::take(text);
        form.message = set_order(scene, slot, &typed).err();
    }
}

fn show_message(ui: &mut egui::Ui, form: &ColourwayForm) {
    if let Some(m) = &form.message {
        ui.colored_label(ui.visuals().error_fg_color, m);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_colourway_starts_as_the_same_cloth_and_takes_stripes_thread_by_thread() {
        let mut scene = SceneFile::default_scene();
        let before = scene.build().unwrap();
        start_colourway(&mut scene).unwrap();
        let same = scene.build().unwrap();
        assert_eq!(same.material_descs, before.material_descs, "warp, weft: the yarns as they were");
        set_palette_colour(&mut scene, "red", YarnSlot::Warp, [0.8, 0.1, 0.08]).unwrap();
        // Palette: red 0, warp 1, weft 2. Lengthen the warp repeat to 2 and recolour thread 1.
        resize_order(&mut scene, YarnSlot::Warp, 1).unwrap();
        assert_eq!(scene.materials.warp_order.as_deref(), Some("2 warp"));
        cycle_thread(&mut scene, YarnSlot::Warp, 1).unwrap();
        assert_eq!(scene.materials.warp_order.as_deref(), Some("1 warp, 1 weft"));
        cycle_thread(&mut scene, YarnSlot::Warp, 1).unwrap();
        assert_eq!(scene.materials.warp_order.as_deref(), Some("1 warp, 1 red"));
        let built = scene.build().unwrap();
        let warp: Vec<u32> = built.exemplar.yarns.iter().take(4).map(|y| y.material).collect();
        assert_eq!(warp, [1, 0, 1, 0]);
        let MaterialDesc::Fiber(red) = built.material_descs[0] else { panic!("a fiber yarn") };
        assert!((red.c_tt.x - 0.8).abs() < 1e-12);
    }

    #[test]
    fn edits_that_would_not_bake_are_refused_and_leave_the_scene_as_it_was() {
        let mut scene = SceneFile::default_scene();
        start_colourway(&mut scene).unwrap();
        let before = scene.clone();
        for (result, expect) in [
            (set_order(&mut scene.clone(), YarnSlot::Warp, "2 teal"), "one of warp, weft"),
            (set_order(&mut scene.clone(), YarnSlot::Weft, "17 weft"), "weft_order"),
            (remove_palette_colour(&mut scene.clone(), "warp"), "warp cannot go"),
            (
                set_palette_colour(&mut scene.clone(), "navy blue", YarnSlot::Warp, [0.1; 3]),
                "letters, digits",
            ),
            (
                set_palette_colour(&mut scene.clone(), "navy", YarnSlot::Warp, [1.5, 0.0, 0.0]),
                "outside 0..=1",
            ),
        ] {
            let message = result.unwrap_err();
            assert!(message.contains(expect), "{expect}: {message}");
        }
        assert_eq!(set_order(&mut scene, YarnSlot::Weft, "17 weft").map_err(|_| ()), Err(()));
        assert_eq!(scene, before);
    }

    #[test]
    fn a_wif_import_takes_the_draft_and_the_colours() {
        let mut scene = SceneFile::default_scene();
        let stripes =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/weaves/twill_2_2_stripes.wif");
        super::super::fabric::import_wif(&mut scene, &stripes).unwrap();
        assert_eq!(scene.materials.warp_order.as_deref(), Some("4 wif1, 4 wif3"));
        assert_eq!(scene.materials.weft_order.as_deref(), Some("3 wif2, 1 wif3"));
        let built = scene.build().unwrap();
        assert_eq!(built.exemplar.yarns.len(), 12, "8 ends, 4 picks");
    }
}
