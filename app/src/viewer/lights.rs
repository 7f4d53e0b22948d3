//! The lights panel: the scene's lights as editable values, environment presets and the
//! widgets that edit them.
//!
//! How it works: each light is a [`LightEdit`] — its kind, its direction as azimuth (degrees
//! around +z from +x toward +y) and elevation (degrees above the fabric plane), a colour
//! (linear RGB scaled so its largest channel is 1) and an intensity (the irradiance of a
//! directional light, the integrated radiance of an SG light: colour × intensity is the
//! scene file's `irradiance` / `intensity`), and for SG lights the sharpness λ. The panel edits
//! these with sliders and a direction disc (the upper hemisphere seen from above: the centre is
//! the zenith, the rim the horizon; drag the dot). [`LightEdit::light`] turns an edit into the
//! renderer's [`Light`]; lights are render-time inputs, so an edit only restarts the picture and
//! never rebakes. Environment presets ([`ENVIRONMENT_PRESETS`]) replace the list with several SG
//! lights at once.

use eframe::egui;
use glam::DVec3;
use twill_precompute::Rgb;
use twill_precompute::params::ParamError;
use twill_precompute::pathtrace::Light;
use twill_precompute::pathtrace::light::SG_SHARPNESS_RANGE;
use twill_precompute::scene::LightSection;
use twill_renderer::frame::MAX_SHADOWED_LIGHTS;
use twill_renderer::plan::{LocalVisibility, sg_local_visibility};

/// Most lights the panel lets a scene have (every light of a curved shell needs a shadow map).
pub const MAX_VIEWER_LIGHTS: usize = MAX_SHADOWED_LIGHTS;
/// Largest intensity the sliders offer (the scene format allows up to 1e6).
pub const MAX_SLIDER_INTENSITY: f64 = 50.0;

/// Directional light or spherical Gaussian environment light.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LightKind {
    Directional,
    Sg,
}

impl LightKind {
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Directional => "directional",
            Self::Sg => "SG",
        }
    }
}

/// One light as the panel edits it (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightEdit {
    pub kind: LightKind,
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
    /// Linear RGB with the largest channel 1 (all zero for a black light).
    pub colour: [f32; 3],
    pub intensity: f64,
    /// SG sharpness λ (ignored by directional lights).
    pub sharpness: f64,
}

impl LightEdit {
    /// A light of `kind` from azimuth/elevation in degrees with colour × intensity `rgb`.
    #[must_use]
    pub fn new(kind: LightKind, azimuth_deg: f64, elevation_deg: f64, rgb: [f64; 3], sharpness: f64) -> Self {
        let (colour, intensity) = split_colour(rgb);
        let azimuth_deg = wrap_degrees(azimuth_deg);
        Self { kind, azimuth_deg, elevation_deg, colour, intensity, sharpness }
    }

    /// The edit of a scene file's light.
    #[must_use]
    pub fn from_section(section: &LightSection) -> Self {
        let (kind, direction, rgb, sharpness) = match *section {
            LightSection::Directional { direction, irradiance } => {
                (LightKind::Directional, direction, irradiance, 100.0)
            }
            LightSection::Sg { axis, sharpness, intensity } => (LightKind::Sg, axis, intensity, sharpness),
        };
        let d = DVec3::from(direction).normalize_or(DVec3::Z);
        let azimuth_deg = if d.truncate().length() > 1e-12 { d.y.atan2(d.x).to_degrees() } else { 0.0 };
        let elevation_deg = d.z.clamp(-1.0, 1.0).asin().to_degrees();
        Self::new(kind, azimuth_deg, elevation_deg, rgb, sharpness)
    }

    /// Unit vector toward the light.
    #[must_use]
    pub fn direction(&self) -> DVec3 {
        let (az, el) = (self.azimuth_deg.to_radians(), self.elevation_deg.to_radians());
        DVec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin())
    }

    /// Colour × intensity.
    #[must_use]
    pub fn rgb(&self) -> Rgb {
        let c = self.colour.map(f64::from);
        Rgb::from(c) * self.intensity
    }

    /// The scene file's form of this light.
    #[must_use]
    pub fn section(&self) -> LightSection {
        let direction = self.direction().to_array();
        let rgb = self.rgb().to_array();
        match self.kind {
            LightKind::Directional => LightSection::Directional { direction, irradiance: rgb },
            LightKind::Sg => LightSection::Sg { axis: direction, sharpness: self.sharpness, intensity: rgb },
        }
    }

    /// The renderer's light (validated as a scene file's light is).
    pub fn light(&self) -> Result<Light, ParamError> {
        match self.kind {
            LightKind::Directional => Light::directional(self.direction(), self.rgb()),
            LightKind::Sg => Light::sg(self.direction(), self.sharpness, self.rgb()),
        }
    }

    /// One line describing the light.
    #[must_use]
    pub fn summary(&self) -> String {
        let base = format!(
            "{} az {:.0}° el {:.0}°, {:.2}",
            self.kind.name(),
            self.azimuth_deg,
            self.elevation_deg,
            self.intensity
        );
        match self.kind {
            LightKind::Directional => base,
            LightKind::Sg => format!("{base}, λ {}", format_sharpness(self.sharpness)),
        }
    }
}

/// An angle in degrees wrapped into (-180, 180] (the azimuth slider's range).
#[must_use]
pub fn wrap_degrees(angle: f64) -> f64 {
    let a = angle.rem_euclid(360.0);
    if a > 180.0 { a - 360.0 } else { a }
}

/// Splits linear RGB into a colour whose largest channel is 1 and that channel's value.
#[must_use]
pub fn split_colour(rgb: [f64; 3]) -> ([f32; 3], f64) {
    let intensity = rgb.iter().copied().fold(0.0_f64, f64::max);
    if intensity <= 0.0 {
        return ([1.0; 3], 0.0);
    }
    (rgb.map(|c| (c.max(0.0) / intensity) as f32), intensity)
}

fn format_sharpness(lambda: f64) -> String {
    if lambda >= 100.0 { format!("{lambda:.0}") } else { format!("{lambda:.3}") }
}

/// A named set of lights.
#[derive(Debug, Clone, Copy)]
pub struct EnvironmentPreset {
    pub name: &'static str,
    pub description: &'static str,
    pub lights: fn() -> Vec<LightEdit>,
}

/// The environment presets, each several SG lights.
pub const ENVIRONMENT_PRESETS: [EnvironmentPreset; 3] = [
    EnvironmentPreset {
        name: "overcast sky",
        description: "a broad zenith SG and four soft SGs low around the horizon",
        lights: overcast_sky,
    },
    EnvironmentPreset {
        name: "studio three-point",
        description: "a sharp key, a soft fill and a rim SG from behind",
        lights: studio_three_point,
    },
    EnvironmentPreset {
        name: "sunset",
        description: "a low, warm, nearly directional sun, its glow, and a blue sky dome",
        lights: sunset,
    },
];

fn overcast_sky() -> Vec<LightEdit> {
    let mut lights = vec![LightEdit::new(LightKind::Sg, 0.0, 90.0, [1.9, 2.0, 2.1], 1.5)];
    for az in [0.0, 90.0, 180.0, 270.0] {
        lights.push(LightEdit::new(LightKind::Sg, az, 15.0, [0.35, 0.37, 0.40], 4.0));
    }
    lights
}

fn studio_three_point() -> Vec<LightEdit> {
    // The default camera looks from azimuth -90° (from -y): key front-left, fill front-right,
    // rim from behind the fabric.
    vec![
        LightEdit::new(LightKind::Sg, 225.0, 40.0, [3.0, 2.9, 2.7], 300.0),
        LightEdit::new(LightKind::Sg, 315.0, 25.0, [0.9, 0.95, 1.0], 10.0),
        LightEdit::new(LightKind::Sg, 90.0, 20.0, [2.0, 2.0, 2.0], 150.0),
    ]
}

fn sunset() -> Vec<LightEdit> {
    vec![
        LightEdit::new(LightKind::Sg, 160.0, 8.0, [3.2, 1.7, 0.7], 2000.0),
        LightEdit::new(LightKind::Sg, 160.0, 10.0, [0.9, 0.45, 0.25], 8.0),
        LightEdit::new(LightKind::Sg, 0.0, 90.0, [0.5, 0.6, 0.9], 2.0),
    ]
}

/// The preset named `name`.
#[must_use]
pub fn preset(name: &str) -> Option<&'static EnvironmentPreset> {
    ENVIRONMENT_PRESETS.iter().find(|p| p.name.eq_ignore_ascii_case(name))
}

/// A new light of `kind`, from above and in front-left of a camera at azimuth `camera_yaw_deg`.
#[must_use]
pub fn new_light(kind: LightKind, camera_yaw_deg: f64) -> LightEdit {
    let azimuth = camera_yaw_deg - 45.0;
    match kind {
        LightKind::Directional => LightEdit::new(kind, azimuth, 45.0, [2.0, 2.0, 2.0], 100.0),
        LightKind::Sg => LightEdit::new(kind, azimuth, 45.0, [2.0, 2.0, 2.0], 20.0),
    }
}

/// What the lights panel did this frame.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct PanelOutcome {
    /// Any light changed (the picture restarts).
    pub changed: bool,
}

/// The lights panel. `scene_lights` is what "scene's lights" resets to; `camera_yaw_deg` marks
/// the viewer on the direction disc.
pub fn lights_panel(
    ui: &mut egui::Ui,
    lights: &mut Vec<LightEdit>,
    selected: &mut usize,
    scene_lights: &[LightEdit],
    camera_yaw_deg: f64,
) -> PanelOutcome {
    let mut outcome = PanelOutcome::default();
    ui.horizontal_wrapped(|ui| {
        let room = lights.len() < MAX_VIEWER_LIGHTS;
        for kind in [LightKind::Directional, LightKind::Sg] {
            if ui
                .add_enabled(room, egui::Button::new(format!("+ {}", kind.name())))
                .on_hover_text(format!("Add a {} light (at most {MAX_VIEWER_LIGHTS})", kind.name()))
                .clicked()
            {
                lights.push(new_light(kind, camera_yaw_deg));
                *selected = lights.len() - 1;
                outcome.changed = true;
            }
        }
        let can_remove = lights.len() > 1 && *selected < lights.len();
        if ui
            .add_enabled(can_remove, egui::Button::new("− remove"))
            .on_hover_text("Remove the selected light (a scene keeps at least one)")
            .clicked()
        {
            lights.remove(*selected);
            *selected = selected.saturating_sub(1);
            outcome.changed = true;
        }
    });
    ui.horizontal_wrapped(|ui| {
        ui.label("Environment:");
        for p in &ENVIRONMENT_PRESETS {
            if ui.button(p.name).on_hover_text(p.description).clicked() {
                *lights = (p.lights)();
                *selected = 0;
                outcome.changed = true;
            }
        }
        if ui.button("scene's lights").on_hover_text("The lights of the scene file").clicked() {
            *lights = scene_lights.to_vec();
            *selected = 0;
            outcome.changed = true;
        }
    });
    ui.separator();
    for (i, light) in lights.iter().enumerate() {
        let text = format!("{}: {}", i, light.summary());
        if ui.selectable_label(*selected == i, text).clicked() {
            *selected = i;
        }
    }
    *selected = (*selected).min(lights.len().saturating_sub(1));
    let Some(light) = lights.get_mut(*selected) else { return outcome };
    ui.separator();
    ui.label(egui::RichText::new(format!("Light {}", *selected)).strong());
    outcome.changed |= light_editor(ui, light, camera_yaw_deg);
    outcome
}

/// Sliders and the direction disc for one light; true when anything changed.
fn light_editor(ui: &mut egui::Ui, light: &mut LightEdit, camera_yaw_deg: f64) -> bool {
    let before = *light;
    ui.horizontal(|ui| {
        ui.label("Kind");
        ui.radio_value(&mut light.kind, LightKind::Directional, "directional");
        ui.radio_value(&mut light.kind, LightKind::Sg, "SG");
    });
    direction_disc(ui, light, camera_yaw_deg);
    ui.add(egui::Slider::new(&mut light.azimuth_deg, -180.0..=180.0).text("azimuth °"));
    ui.add(egui::Slider::new(&mut light.elevation_deg, -90.0..=90.0).text("elevation °"));
    if light.kind == LightKind::Sg {
        let (lo, hi) = SG_SHARPNESS_RANGE;
        ui.add(
            egui::Slider::new(&mut light.sharpness, lo..=hi)
                .logarithmic(true)
                .text("sharpness λ")
                .custom_formatter(|v, _| format_sharpness(v)),
        )
        .on_hover_text("Small λ: a broad sky; large λ: nearly a directional light");
        let path = match sg_local_visibility(light.sharpness) {
            LocalVisibility::SumOfSg => "sum-of-SGs visibility (λ ≤ 100)",
            LocalVisibility::SsdfErf => "erf-smoothed SSDF visibility (λ ≥ 200)",
            _ => "both visibility paths, blended (100 < λ < 200)",
        };
        ui.label(egui::RichText::new(path).small().weak());
    }
    ui.horizontal(|ui| {
        ui.label("Colour");
        ui.color_edit_button_rgb(&mut light.colour);
    });
    let what = if light.kind == LightKind::Sg { "intensity" } else { "irradiance" };
    // A scene's light may be brighter than the slider reaches: keep it until it is edited.
    ui.add(
        egui::Slider::new(&mut light.intensity, 0.0..=MAX_SLIDER_INTENSITY)
            .logarithmic(true)
            .clamping(egui::SliderClamping::Edits)
            .text(what),
    );
    *light != before
}

/// The direction disc: the upper hemisphere seen from above (+x right, +y up on screen), rings
/// at 30° and 60° elevation, the light as a dot (hollow on the rim when below the horizon) and
/// the camera's azimuth as a tick on the rim. Dragging places the light under the pointer.
fn direction_disc(ui: &mut egui::Ui, light: &mut LightEdit, camera_yaw_deg: f64) -> egui::Response {
    let size = 112.0;
    let (rect, response) = ui.allocate_exact_size(egui::vec2(size, size), egui::Sense::click_and_drag());
    let centre = rect.center();
    let radius = 0.5 * size - 6.0;
    if let Some(pos) = response.interact_pointer_pos()
        && (response.dragged() || response.clicked())
    {
        let offset = (pos - centre) / radius;
        let (x, y) = (f64::from(offset.x), -f64::from(offset.y));
        let r = x.hypot(y).min(1.0);
        if r > 1e-6 {
            light.azimuth_deg = y.atan2(x).to_degrees();
        }
        light.elevation_deg = r.acos().to_degrees();
    }
    let painter = ui.painter_at(rect);
    let visuals = ui.visuals();
    let stroke = egui::Stroke::new(1.0, visuals.weak_text_color());
    painter.circle_filled(centre, radius, visuals.extreme_bg_color);
    painter.circle_stroke(centre, radius, stroke);
    for elevation in [30.0_f32, 60.0] {
        painter.circle_stroke(centre, radius * elevation.to_radians().cos(), stroke);
    }
    painter.line_segment([centre - egui::vec2(radius, 0.0), centre + egui::vec2(radius, 0.0)], stroke);
    painter.line_segment([centre - egui::vec2(0.0, radius), centre + egui::vec2(0.0, radius)], stroke);
    let font = egui::FontId::proportional(9.0);
    painter.text(
        centre + egui::vec2(radius + 1.0, 0.0),
        egui::Align2::RIGHT_BOTTOM,
        "+x",
        font.clone(),
        visuals.weak_text_color(),
    );
    painter.text(
        centre - egui::vec2(0.0, radius),
        egui::Align2::LEFT_TOP,
        "+y",
        font,
        visuals.weak_text_color(),
    );
    let on_rim = |azimuth_deg: f64, r: f32| {
        let a = azimuth_deg.to_radians() as f32;
        centre + egui::vec2(a.cos(), -a.sin()) * r
    };
    // The camera's azimuth, as a tick outside the rim.
    let camera_colour = visuals.text_color();
    painter.line_segment(
        [on_rim(camera_yaw_deg, radius + 1.0), on_rim(camera_yaw_deg, radius + 6.0)],
        egui::Stroke::new(2.0, camera_colour),
    );
    let elevation = light.elevation_deg.to_radians();
    let dot_colour = egui::Color32::from_rgb(255, 200, 60);
    if elevation >= 0.0 {
        painter.circle_filled(on_rim(light.azimuth_deg, radius * elevation.cos() as f32), 5.0, dot_colour);
    } else {
        painter.circle_stroke(on_rim(light.azimuth_deg, radius), 5.0, egui::Stroke::new(2.0, dot_colour));
    }
    response.on_hover_text(
        "Drag to place the light: centre = straight above, rim = horizon; the tick marks the camera",
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use twill_precompute::scene::SceneFile;

    #[test]
    fn scene_lights_round_trip_through_the_edit_form() {
        for section in SceneFile::default_scene().lights {
            let back = LightEdit::from_section(&section).section();
            let (a, b) = match (section, back) {
                (
                    LightSection::Directional { direction: d0, irradiance: e0 },
                    LightSection::Directional { direction: d1, irradiance: e1 },
                ) => ((DVec3::from(d0).normalize(), e0), (DVec3::from(d1), e1)),
                (
                    LightSection::Sg { axis: d0, intensity: e0, sharpness: s0 },
                    LightSection::Sg { axis: d1, intensity: e1, sharpness: s1 },
                ) => {
                    assert!((s0 - s1).abs() < 1e-12);
                    ((DVec3::from(d0).normalize(), e0), (DVec3::from(d1), e1))
                }
                _ => panic!("kind changed"),
            };
            assert!((a.0 - b.0).length() < 1e-12, "{a:?} {b:?}");
            for i in 0..3 {
                assert!((a.1[i] - b.1[i]).abs() < 1e-6, "{a:?} {b:?}");
            }
        }
    }

    #[test]
    fn azimuths_stay_inside_the_slider_range() {
        assert!((wrap_degrees(225.0) + 135.0).abs() < 1e-12);
        assert!((wrap_degrees(-190.0) - 170.0).abs() < 1e-12);
        assert!((wrap_degrees(180.0) - 180.0).abs() < 1e-12);
        let light = new_light(LightKind::Sg, -170.0);
        assert!((-180.0..=180.0).contains(&light.azimuth_deg), "{light:?}");
    }

    #[test]
    fn presets_make_valid_sg_lights_within_the_panel_limit() {
        for p in &ENVIRONMENT_PRESETS {
            let lights = (p.lights)();
            assert!(lights.len() >= 2 && lights.len() <= MAX_VIEWER_LIGHTS, "{}", p.name);
            for l in &lights {
                assert_eq!(l.kind, LightKind::Sg);
                assert!(l.light().is_ok(), "{}: {l:?}", p.name);
                assert!(l.elevation_deg > 0.0, "{}: every light is above the fabric", p.name);
                assert!((-180.0..=180.0).contains(&l.azimuth_deg), "{}: {l:?}", p.name);
            }
        }
        assert!(preset("Sunset").is_some());
        assert!(preset("nope").is_none());
    }

    #[test]
    #[allow(clippy::float_cmp)] // halving and quartering are exact
    fn a_black_light_keeps_a_white_colour() {
        assert_eq!(split_colour([0.0; 3]), ([1.0; 3], 0.0));
        let (c, i) = split_colour([1.0, 2.0, 0.5]);
        assert!((i - 2.0).abs() < 1e-12);
        assert_eq!(c, [0.5, 1.0, 0.25]);
    }
}
