//! The mesh panel: the base surface the fabric is shell-mapped onto, and the shell's thickness.
//!
//! How it works: [`mesh_panel`] edits the scene's `[mesh]` section (a built-in surface with its
//! size, or an OBJ/glTF file with its centimetres per UV unit, and the thickness scale). A mesh
//! edit never rebakes: the viewer sends the new section to the render worker, which builds the
//! new shell around the baked fabric's slab and swaps it in (`Renderer::set_shell`). A file that
//! cannot be used comes back as an error message and the fabric stays on the surface it had.

use eframe::egui;
use twill_precompute::scene::MeshSection;
use twill_renderer::shell::{BaseMesh, MAX_BUILTIN_SIDE_CM, MIN_BUILTIN_SIDE_CM};

/// Range of the thickness scale (as the scene format checks it).
pub const THICKNESS_SCALE_RANGE: (f64, f64) = (0.01, 100.0);

/// The file-name field, kept between frames.
#[derive(Default)]
pub struct MeshForm {
    pub path: String,
}

/// Sets a built-in surface by name, refusing unknown names with the valid ones.
pub fn set_builtin(mesh: &mut MeshSection, name: &str) -> Result<(), String> {
    if !BaseMesh::BUILTIN_NAMES.contains(&name) {
        return Err(format!(
            "unknown built-in mesh {name:?}; built-ins: {}",
            BaseMesh::BUILTIN_NAMES.join(", ")
        ));
    }
    mesh.path = None;
    mesh.builtin = Some(name.to_owned());
    Ok(())
}

/// Sets the shell thickness scale, refusing values outside [`THICKNESS_SCALE_RANGE`].
pub fn set_thickness(mesh: &mut MeshSection, scale: f64) -> Result<(), String> {
    let (lo, hi) = THICKNESS_SCALE_RANGE;
    if !(lo..=hi).contains(&scale) {
        return Err(format!("thickness scale {scale} is outside {lo}..={hi}"));
    }
    mesh.thickness_scale = scale;
    Ok(())
}

/// The mesh panel; `swatch_cm` is the default size of a built-in surface.
pub fn mesh_panel(ui: &mut egui::Ui, mesh: &mut MeshSection, swatch_cm: [f64; 2], form: &mut MeshForm) {
    let current = match (&mesh.builtin, &mesh.path) {
        (_, Some(path)) => path.display().to_string(),
        (Some(name), None) => name.clone(),
        (None, None) => "swatch".to_owned(),
    };
    egui::ComboBox::from_label("surface").selected_text(&current).show_ui(ui, |ui| {
        for name in BaseMesh::BUILTIN_NAMES {
            if ui.selectable_label(mesh.path.is_none() && current == *name, *name).clicked() {
                let _ = set_builtin(mesh, name);
            }
        }
    });
    if mesh.path.is_none() {
        let mut size = mesh.size_cm.unwrap_or(swatch_cm);
        let before = size;
        ui.horizontal(|ui| {
            ui.label("size (cm)");
            for s in &mut size {
                let range = f64::from(MIN_BUILTIN_SIDE_CM).max(0.05)..=f64::from(MAX_BUILTIN_SIDE_CM);
                ui.add(
                    egui::DragValue::new(s)
                        .range(range)
                        .clamp_existing_to_range(false)
                        .speed(0.01)
                        .max_decimals(3),
                );
            }
        });
        // Exactly the values the widgets wrote: a change, not a tolerance.
        #[allow(clippy::float_cmp)]
        let changed = size != before;
        if changed {
            mesh.size_cm = Some(size);
        }
    } else {
        ui.horizontal(|ui| {
            ui.label("cm per UV unit");
            ui.add(
                egui::DragValue::new(&mut mesh.cm_per_uv)
                    .range(1e-3..=1e4)
                    .clamp_existing_to_range(false)
                    .speed(0.01)
                    .max_decimals(4),
            );
        });
    }
    ui.horizontal(|ui| {
        ui.add(
            egui::TextEdit::singleline(&mut form.path)
                .hint_text("mesh.obj or .gltf/.glb")
                .desired_width(150.0),
        );
        if ui.button("Load mesh").on_hover_text("An OBJ or glTF surface with UVs").clicked()
            && !form.path.trim().is_empty()
        {
            mesh.builtin = None;
            mesh.path = Some(form.path.trim().into());
        }
    });
    let (lo, hi) = THICKNESS_SCALE_RANGE;
    ui.add(
        egui::Slider::new(&mut mesh.thickness_scale, lo.max(0.1)..=hi.min(10.0))
            .logarithmic(true)
            .clamping(egui::SliderClamping::Edits)
            .text("shell thickness ×"),
    )
    .on_hover_text("Shell thickness as a multiple of the fabric's own (1 keeps fibers unstretched)");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mesh_edits_are_checked() {
        let mut mesh = MeshSection { path: Some("a.obj".into()), ..MeshSection::default() };
        set_builtin(&mut mesh, "cushion").unwrap();
        assert_eq!((mesh.builtin.as_deref(), mesh.path.as_ref()), (Some("cushion"), None));
        let e = set_builtin(&mut mesh, "teapot").unwrap_err();
        assert!(e.contains("teapot") && e.contains("drape"), "{e}");
        set_thickness(&mut mesh, 2.0).unwrap();
        assert!(set_thickness(&mut mesh, 0.0).unwrap_err().contains("0.01"));
        assert!((mesh.thickness_scale - 2.0).abs() < 1e-12);
    }
}
