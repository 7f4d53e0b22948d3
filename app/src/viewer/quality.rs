//! The quality and performance panel: what the renderer is doing and what it costs, and the
//! render-time settings that trade one for the other.
//!
//! How it works: [`quality_panel`] shows the fabric on screen (its bake quality, bake and upload
//! time, GPU memory), the bake running in the background (stage, progress, a rough ETA; it can be
//! cancelled, or a bake at another quality started, which cancels the one in flight), the
//! progressive accumulation (samples so far out of the target, the size rendered — reduced while
//! the view is being changed), the frame plan of the last batch (`FramePlan`'s own text) and the
//! GPU time of each of its passes (timestamp queries; G-buffer and shading times are summed over
//! the batch's samples). The controls edit [`RenderControls`]; every one of them is a render-time
//! setting, so a change restarts the picture and never rebakes. Exposure and the tone curve only
//! re-tone-map the samples already accumulated.

use eframe::egui;
use twill_precompute::bake::pipeline::Stage;
use twill_precompute::bake::settings::Quality;
use twill_precompute::scene::GpuSection;
use twill_renderer::frame::describe_timings;
use twill_renderer::plan::Components;

use super::accumulate::Accumulation;
use super::bake::BakeProgress;
use super::timing::FrameStats;

/// Render-time settings the panel edits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderControls {
    /// Samples per pixel to accumulate while the view is still.
    pub target_spp: u32,
    /// Choose the size rendered while the view is being changed from the measured cost, so a
    /// frame takes about [`INTERACTION_BUDGET_MS`].
    pub interaction_auto: bool,
    /// Fraction of the viewport's size rendered while the view is being changed (when not auto).
    pub interaction_scale: f64,
    pub exposure: f64,
    pub filmic: bool,
    pub components: Components,
    /// The scene's `[gpu]` section.
    pub gpu: GpuSection,
}

/// Limits of the panel's sliders.
pub const TARGET_SPP_RANGE: (u32, u32) = (1, 4096);
pub const INTERACTION_SCALE_RANGE: (f64, f64) = (0.125, 1.0);
/// Time the automatic size while moving aims at per frame.
pub const INTERACTION_BUDGET_MS: f64 = 100.0;
pub const SIGMA_GLO_RANGE_CM: (f64, f64) = (0.0, 1.0);
pub const PCF_RADIUS_RANGE: (f64, f64) = (0.0, 8.0);
pub const SHADOW_BIAS_RANGE: (f64, f64) = (0.0, 8.0);

/// The fabric on screen.
#[derive(Debug, Clone)]
pub struct FabricInfo {
    pub id: u64,
    pub quality: Quality,
    /// A material preview: multiple scattering is still the previous bake's.
    pub preview: bool,
    pub bake_seconds: f64,
    /// Stages computed (the rest came from the stage cache or, for a preview, the last bake).
    pub computed_stages: Vec<Stage>,
    pub upload_seconds: f64,
    pub adapter: String,
    pub resident_bytes: u64,
    pub bounds: (glam::Vec3, glam::Vec3),
}

/// What the panel shows besides the controls.
pub struct QualityView<'a> {
    pub fabric: Option<&'a FabricInfo>,
    pub bake: Option<BakeProgress>,
    pub accumulation: Option<&'a Accumulation>,
    /// Whether the accumulation on screen is of the current view.
    pub current: bool,
    /// The viewport's size in pixels.
    pub full_size: [u32; 2],
    /// The fraction of it rendered while the view changes.
    pub interaction_scale: f64,
    /// CPU time of the viewer's recent frames, with and without a bake running.
    pub ui_baking: Option<FrameStats>,
    pub ui_idle: Option<FrameStats>,
    /// What the latest `twill accuracy` report measured for each preset (GPU).
    pub expected: &'a [(Quality, crate::accuracy_report::ExpectedAccuracy)],
}

/// What the user asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QualityAction {
    Bake(Quality),
    CancelBake,
}

/// Where the shown quality sits: its expected error and cost from the latest accuracy report.
fn expected_accuracy_label(
    ui: &mut egui::Ui,
    quality: Quality,
    expected: &[(Quality, crate::accuracy_report::ExpectedAccuracy)],
) {
    match expected.iter().find(|(q, _)| *q == quality) {
        Some((_, e)) => {
            ui.label(format!(
                "Expected error against path tracing (latest `twill accuracy` report: flat swatches of {} \
                 under hard views and lights): image mean {:.1}% RMS, worst view {:+.1}%, per pixel {:.0}%; \
                 frame {:.0} ms there, bake {:.1} s.",
                e.fabrics.join(", "),
                100.0 * e.mean_error,
                100.0 * e.worst_error,
                100.0 * e.pixel_error,
                e.frame_ms,
                e.bake_s
            ))
            .on_hover_text("Measured on the report's fabrics and image size, not on this scene; rerun `twill accuracy` to update");
        }
        None => {
            ui.weak(format!(
                "No accuracy report for the {} preset yet: `twill accuracy` measures its error and cost.",
                quality.name()
            ));
        }
    }
}

fn quality_name(q: Quality) -> &'static str {
    q.name()
}

/// The panel (see the module docs).
pub fn quality_panel(
    ui: &mut egui::Ui,
    controls: &mut RenderControls,
    view: &QualityView<'_>,
    bake_choice: &mut Quality,
) -> Option<QualityAction> {
    let mut action = None;
    egui::CollapsingHeader::new("Fabric and bake").default_open(true).show(ui, |ui| {
        match view.fabric {
            Some(f) => {
                let stages = match f.computed_stages.len() {
                    0 => "every stage from the cache".to_owned(),
                    n if n >= Stage::ALL.len() => "every stage computed".to_owned(),
                    _ => {
                        let names: Vec<&str> = f.computed_stages.iter().map(|s| s.name()).collect();
                        format!("computed {}, the rest from the cache", names.join(", "))
                    }
                };
                ui.label(format!(
                    "Showing the {} bake ({:.1} s, {stages}).",
                    f.quality.name(),
                    f.bake_seconds
                ));
                if f.preview {
                    ui.colored_label(
                        ui.visuals().warn_fg_color,
                        "Material preview: single scattering is new, multiple scattering is the \
                         previous bake's until the bake in progress finishes.",
                    );
                }
                ui.label(format!(
                    "Uploaded in {:.2} s: {:.1} MB on the GPU.",
                    f.upload_seconds,
                    f.resident_bytes as f64 / 1e6
                ));
                expected_accuracy_label(ui, f.quality, view.expected);
            }
            None => {
                ui.label("No fabric on screen yet.");
            }
        }
        if let Some(p) = view.bake {
            let stage = p.stage.map_or("building the scene", |s| s.name());
            let eta = p.eta_seconds().map_or_else(|| "ETA …".to_owned(), |s| format!("ETA ~{s:.0} s"));
            ui.label(format!("Baking {} in the background: {stage}", p.quality.name()));
            ui.add(egui::ProgressBar::new(p.overall as f32).text(format!("{:.0}%, {eta}", 100.0 * p.overall)));
            if ui.button("Cancel bake").clicked() {
                action = Some(QualityAction::CancelBake);
            }
        }
        ui.horizontal(|ui| {
            egui::ComboBox::from_id_salt("bake quality")
                .selected_text(quality_name(*bake_choice))
                .show_ui(ui, |ui| {
                    for q in [Quality::Draft, Quality::Interactive, Quality::Paper] {
                        ui.selectable_value(bake_choice, q, quality_name(q));
                    }
                });
            if ui
                .button("Bake")
                .on_hover_text("Bake the fabric at this quality (cancels a bake in progress; cached stages load at once)")
                .clicked()
            {
                action = Some(QualityAction::Bake(*bake_choice));
            }
        });
    });

    egui::CollapsingHeader::new("Progressive rendering").default_open(true).show(ui, |ui| {
        let [w, h] = view.full_size;
        match view.accumulation {
            Some(acc) => {
                let fraction = acc.samples as f32 / controls.target_spp.max(1) as f32;
                let state = if !view.current {
                    "updating…"
                } else if acc.samples >= controls.target_spp {
                    "done"
                } else {
                    "accumulating"
                };
                ui.add(
                    egui::ProgressBar::new(fraction.min(1.0))
                        .text(format!("{} / {} spp, {state}", acc.samples, controls.target_spp)),
                );
                let reduced = if [acc.width, acc.height] == [w, h] { "" } else { " (reduced while moving)" };
                ui.label(format!("{}×{} px{reduced}; viewport {w}×{h}", acc.width, acc.height));
                let b = &acc.last_batch;
                ui.label(format!(
                    "Last batch: {} spp in {:.0} ms ({:.1} ms per sample, wall)",
                    b.spp,
                    b.wall_ms,
                    b.wall_ms / f64::from(b.spp.max(1))
                ));
            }
            None => {
                ui.label(format!("Nothing rendered yet; viewport {w}×{h}"));
            }
        }
        ui.add(
            egui::Slider::new(&mut controls.target_spp, TARGET_SPP_RANGE.0..=TARGET_SPP_RANGE.1)
                .logarithmic(true)
                .text("target spp"),
        );
        if controls.interaction_auto {
            controls.interaction_scale = view.interaction_scale;
        }
        ui.add_enabled(
            !controls.interaction_auto,
            egui::Slider::new(
                &mut controls.interaction_scale,
                INTERACTION_SCALE_RANGE.0..=INTERACTION_SCALE_RANGE.1,
            )
            .fixed_decimals(2)
            .text("size while moving"),
        )
        .on_hover_text("Fraction of the viewport's size rendered while the view changes (1 = full size)");
        ui.checkbox(&mut controls.interaction_auto, "size while moving: automatic")
            .on_hover_text(format!("Pick the size so a frame takes about {INTERACTION_BUDGET_MS:.0} ms"));
        ui.add(
            egui::Slider::new(&mut controls.exposure, -8.0..=8.0)
                .clamping(egui::SliderClamping::Edits)
                .text("exposure"),
        );
        ui.checkbox(&mut controls.filmic, "filmic tone curve (else clamp)");
    });

    egui::CollapsingHeader::new("Method settings").default_open(true).show(ui, |ui| {
        ui.horizontal(|ui| {
            ui.label("Scattering");
            ui.selectable_value(&mut controls.components, Components::All, "all");
            ui.selectable_value(&mut controls.components, Components::SingleOnly, "single");
            ui.selectable_value(&mut controls.components, Components::MultipleOnly, "multiple");
        });
        ui.add(
            egui::Slider::new(&mut controls.gpu.pcf_radius_texels, PCF_RADIUS_RANGE.0..=PCF_RADIUS_RANGE.1)
                .clamping(egui::SliderClamping::Edits)
                .text("PCF radius (texels)"),
        )
        .on_hover_text("Shadow-map filter radius of directional lights (SG lights use PCSS, sized by λ)");
        ui.add(
            egui::Slider::new(
                &mut controls.gpu.shadow_bias_texels,
                SHADOW_BIAS_RANGE.0..=SHADOW_BIAS_RANGE.1,
            )
            .text("shadow bias (texels)"),
        );
        ui.add(
            egui::Slider::new(&mut controls.gpu.sigma_glo_cm, SIGMA_GLO_RANGE_CM.0..=SIGMA_GLO_RANGE_CM.1)
                .clamping(egui::SliderClamping::Edits)
                .text("σ_glo (cm)"),
        )
        .on_hover_text(
            "Blur of the macro-scale visibility used by multiple scattering (0: none). \
             Only curved shells have shadow maps to blur.",
        );
        for (label, value) in [
            ("shadow map", &mut controls.gpu.shadow_map_size),
            ("visibility texture", &mut controls.gpu.visibility_texture_size),
        ] {
            egui::ComboBox::from_label(label).selected_text(format!("{value}²")).show_ui(ui, |ui| {
                for size in [256_u32, 512, 1024, 2048, 4096] {
                    ui.selectable_value(value, size, format!("{size}²"));
                }
            });
        }
    });

    egui::CollapsingHeader::new("Frame plan and GPU time").default_open(true).show(ui, |ui| {
        match view.accumulation {
            Some(acc) => {
                let b = &acc.last_batch;
                ui.label(egui::RichText::new(b.plan.to_string().trim_end()).monospace().small());
                match &b.timings {
                    Some(t) => {
                        ui.label(format!("GPU time per pass, last batch ({} spp):", b.spp));
                        ui.label(egui::RichText::new(describe_timings(t).trim_end()).monospace().small());
                        if !b.reused.is_empty() {
                            ui.label(format!("Reused from an earlier frame: {}.", b.reused.join(", ")));
                        }
                    }
                    None => {
                        ui.label("GPU time per pass: the adapter has no timestamp queries.");
                    }
                }
            }
            None => {
                ui.label("No frame yet.");
            }
        }
        if let Some(f) = view.fabric {
            ui.label(egui::RichText::new(format!("Adapter: {}", f.adapter)).small().weak());
        }
        for (what, stats) in [("UI frames while baking", view.ui_baking), ("UI frames", view.ui_idle)] {
            if let Some(stats) = stats {
                ui.label(egui::RichText::new(format!("{what}: {stats}")).small().weak())
                    .on_hover_text("CPU time of the viewer's own frames (layout and scheduling)");
            }
        }
    });
    action
}
