//! Frame planning: the passes a frame runs, derived from its scene, so that nothing runs that
//! the picture does not need ("simulate only the effects a scene calls for").
//!
//! How it works: [`FramePlan::new`] looks at the lights, the shell and the requested scattering
//! components and decides
//! - per light, which local-visibility path shading uses: the SSDF sign for directional lights;
//!   for SG lights the sum-of-SGs path when λ ≤ 100, the erf-smoothed SSDF when λ ≥ 200, both
//!   blended linearly in λ between (paper 5.2.2);
//! - per light, whether it needs a shadow map, and which filter: nothing on a flat shell can
//!   occlude a light above it (the fibers' own shadowing is in the precomputed visibility), so
//!   a flat swatch needs no shadow pass at all; a light below a flat shell's plane is fully
//!   blocked (the fabric is opaque from below at the scale of the shell) and contributes
//!   nothing, so it is dropped; on curved shells every light gets a shadow map, filtered by PCF
//!   for directional lights and PCSS for SG lights;
//! - whether the shell-space passes run (top-surface positions X[u, v] and visibility V[u, v]:
//!   only with shadow maps), and the Gaussian blur of V (only with multiple scattering, shadow
//!   maps and σ_glo > 0);
//! - which shading terms are compiled into the shading pipeline (single, multiple, each
//!   visibility path, the fiber lobes of a bake that has them), as WGSL override constants,
//!   so a skipped path costs nothing.
//!
//! The thresholds are the shading twins' (`twill_precompute::shading::sg_path_weights`).
//! The plan prints as a list of passes (`twill render --print-plan`), and the tests assert it.

use std::fmt;

use twill_precompute::shading::visibility::{SSDF_ONLY_ABOVE, SUM_OF_SG_ONLY_BELOW};

/// A light as planning sees it (world space; `to_light` unit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PlanLight {
    Directional { to_light: [f64; 3] },
    Sg { axis: [f64; 3], sharpness: f64 },
}

/// How one light's local visibility is evaluated in single scattering.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LocalVisibility {
    /// Sign of the SSDF at the light direction (directional lights).
    SsdfSign,
    /// Sum-of-SGs visibility (SG lights, λ ≤ 100).
    SumOfSg,
    /// erf-smoothed SSDF (SG lights, λ ≥ 200).
    SsdfErf,
    /// Both, blended linearly in λ (100 < λ < 200).
    Blend,
}

/// How one light's global (macro-scale) visibility is found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GlobalVisibility {
    /// Nothing in the scene can occlude it.
    Unoccluded,
    /// Shadow map with percentage-closer filtering.
    Pcf,
    /// Shadow map with percentage-closer soft shadows.
    Pcss,
}

/// The plan for one light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightPlan {
    /// Index of the light in the scene.
    pub light: usize,
    pub local: LocalVisibility,
    pub global: GlobalVisibility,
    /// Layer of the shadow map / visibility textures, when it has one.
    pub shadow_layer: Option<u32>,
}

/// Which scattering components to render.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Components {
    #[default]
    All,
    SingleOnly,
    MultipleOnly,
}

/// What the planner needs to know about the scene besides its lights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanInputs {
    /// The shell's normal when it is flat (then nothing on it occludes lights above it).
    pub flat_normal: Option<[f64; 3]>,
    pub components: Components,
    /// σ_glo in cm.
    pub sigma_glo_cm: f64,
    pub spp: u32,
    /// Every tetrahedron of the shell has the same world → flat-fabric frame (the flat swatch):
    /// then the lights' SH is the same at every pixel unless shadow maps vary it.
    pub uniform_frame: bool,
    /// The loaded bake carries fiber lobes (`BakeSettings::fiber_lobes`: some cell with
    /// `CellTransfer::has_lobes`, `FabricArrays::has_lobes`).
    pub fiber_lobes: bool,
}

/// One pass of a frame, with everything that decides how it runs (the frame executes these:
/// `renderer/src/passes/` has one module per variant).
#[derive(Debug, Clone, PartialEq)]
pub enum Pass {
    /// The shell's surfaces, depth only, from light `light` into shadow-map layer `layer`.
    ShadowMap {
        light: usize,
        filter: GlobalVisibility,
        layer: u32,
    },
    TopSurface,
    Visibility {
        lights: usize,
    },
    Blur {
        sigma_glo_cm: f64,
    },
    /// The light arriving in every IIRTF cell, A c_in, once per frame (when c_in is the same at
    /// every pixel: one flat-fabric frame, no shadow maps).
    CellTransfer,
    GBuffer,
    /// Deferred shading, compiled with exactly these terms: single scattering by the listed
    /// local-visibility paths, multiple scattering, the shadow maps' visibility, the cells'
    /// once-per-frame transfer in place of the per-pixel one, and the bake's fiber lobes.
    Shade {
        single: bool,
        multiple: bool,
        paths: Vec<LocalVisibility>,
        global_visibility: bool,
        cell_transfer: bool,
        fiber_lobes: bool,
    },
    ToneMap,
}

impl Pass {
    /// The name used for timings and the viewer's pass list.
    #[must_use]
    pub fn name(&self) -> String {
        match self {
            Self::ShadowMap { light, .. } => format!("shadow map (light {light})"),
            Self::TopSurface => "top surface X[u,v]".into(),
            Self::Visibility { .. } => "visibility V[u,v]".into(),
            Self::Blur { .. } => "blur sigma_glo".into(),
            Self::CellTransfer => "cell transfer A c_in".into(),
            Self::GBuffer => "eye rays (G-buffer)".into(),
            Self::Shade { .. } => "shading".into(),
            Self::ToneMap => "tone map".into(),
        }
    }

    /// Whether the pass runs once per sample (the eye rays and the shading depend on the
    /// sub-pixel jitter); every other pass runs once per frame.
    #[must_use]
    pub fn per_sample(&self) -> bool {
        matches!(self, Self::GBuffer | Self::Shade { .. })
    }

    /// Whether the pass's result depends on neither the camera nor the sample (shell-space
    /// visibility: shadow maps, X, V and its blur): a frame reuses it from an earlier frame
    /// with the same lights, shell and settings.
    #[must_use]
    pub fn view_independent(&self) -> bool {
        matches!(
            self,
            Self::ShadowMap { .. } | Self::TopSurface | Self::Visibility { .. } | Self::Blur { .. }
        )
    }
}

/// Everything a frame runs.
#[derive(Debug, Clone, PartialEq)]
#[allow(clippy::struct_excessive_bools)]
pub struct FramePlan {
    pub lights: Vec<LightPlan>,
    /// Lights dropped because nothing of them reaches the fabric (below a flat shell).
    pub dropped_lights: Vec<usize>,
    pub single: bool,
    pub multiple: bool,
    pub shadow_maps: bool,
    pub blur: bool,
    /// Multiple scattering reads each cell's A c_in from a once-per-frame pass.
    pub cell_transfer: bool,
    /// Multiple scattering adds each light's fiber lobes (the bake has them).
    pub fiber_lobes: bool,
    pub sigma_glo_cm: f64,
    pub spp: u32,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The local-visibility path for an SG light of sharpness `lambda`.
#[must_use]
pub fn sg_local_visibility(lambda: f64) -> LocalVisibility {
    if lambda <= SUM_OF_SG_ONLY_BELOW {
        LocalVisibility::SumOfSg
    } else if lambda >= SSDF_ONLY_ABOVE {
        LocalVisibility::SsdfErf
    } else {
        LocalVisibility::Blend
    }
}

impl FramePlan {
    /// Plans a frame.
    #[must_use]
    pub fn new(lights: &[PlanLight], inputs: &PlanInputs) -> Self {
        let mut plans = Vec::new();
        let mut dropped = Vec::new();
        let mut layers = 0;
        for (i, light) in lights.iter().enumerate() {
            let (local, direction) = match *light {
                PlanLight::Directional { to_light } => (LocalVisibility::SsdfSign, to_light),
                PlanLight::Sg { axis, sharpness } => (sg_local_visibility(sharpness), axis),
            };
            let global = match (inputs.flat_normal, light) {
                (Some(n), PlanLight::Directional { .. }) if dot(n, direction) <= 0.0 => {
                    dropped.push(i);
                    continue;
                }
                (Some(_), _) => GlobalVisibility::Unoccluded,
                (None, PlanLight::Directional { .. }) => GlobalVisibility::Pcf,
                (None, PlanLight::Sg { .. }) => GlobalVisibility::Pcss,
            };
            let shadow_layer = (global != GlobalVisibility::Unoccluded).then(|| {
                layers += 1;
                layers - 1
            });
            plans.push(LightPlan { light: i, local, global, shadow_layer });
        }
        let single = inputs.components != Components::MultipleOnly;
        let multiple = inputs.components != Components::SingleOnly;
        let shadow_maps = layers > 0;
        Self {
            lights: plans,
            dropped_lights: dropped,
            single,
            multiple,
            shadow_maps,
            blur: shadow_maps && multiple && inputs.sigma_glo_cm > 0.0,
            cell_transfer: multiple && !shadow_maps && inputs.uniform_frame,
            fiber_lobes: multiple && inputs.fiber_lobes,
            sigma_glo_cm: inputs.sigma_glo_cm,
            spp: inputs.spp,
        }
    }

    /// Whether any light uses a local-visibility path (the shading pipeline's override constants).
    #[must_use]
    pub fn uses(&self, path: LocalVisibility) -> bool {
        self.single
            && self.lights.iter().any(|l| {
                l.local == path
                    || (l.local == LocalVisibility::Blend
                        && matches!(path, LocalVisibility::SumOfSg | LocalVisibility::SsdfErf))
            })
    }

    /// Whether any light is filtered with `filter`.
    #[must_use]
    pub fn filters_with(&self, filter: GlobalVisibility) -> bool {
        self.lights.iter().any(|l| l.global == filter)
    }

    /// Number of shadow-map layers.
    #[must_use]
    pub fn shadow_layers(&self) -> u32 {
        self.lights.iter().filter(|l| l.shadow_layer.is_some()).count() as u32
    }

    /// The passes, in the order they run: what the frame executes (the G-buffer and shading
    /// passes, [`Pass::per_sample`], run once per sample).
    #[must_use]
    pub fn passes(&self) -> Vec<Pass> {
        let mut passes = Vec::new();
        for l in &self.lights {
            if let Some(layer) = l.shadow_layer {
                passes.push(Pass::ShadowMap { light: l.light, filter: l.global, layer });
            }
        }
        if self.shadow_maps {
            passes.push(Pass::TopSurface);
            passes.push(Pass::Visibility { lights: self.shadow_layers() as usize });
        }
        if self.blur {
            passes.push(Pass::Blur { sigma_glo_cm: self.sigma_glo_cm });
        }
        if self.cell_transfer {
            passes.push(Pass::CellTransfer);
        }
        passes.push(Pass::GBuffer);
        let mut paths: Vec<LocalVisibility> = Vec::new();
        for p in [
            LocalVisibility::SsdfSign,
            LocalVisibility::SumOfSg,
            LocalVisibility::SsdfErf,
            LocalVisibility::Blend,
        ] {
            if self.single && self.lights.iter().any(|l| l.local == p) {
                paths.push(p);
            }
        }
        passes.push(Pass::Shade {
            single: self.single,
            multiple: self.multiple,
            paths,
            global_visibility: self.shadow_maps,
            cell_transfer: self.cell_transfer,
            fiber_lobes: self.fiber_lobes,
        });
        passes.push(Pass::ToneMap);
        passes
    }
}

impl fmt::Display for FramePlan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "frame plan ({} spp):", self.spp)?;
        for pass in self.passes() {
            match &pass {
                Pass::ShadowMap { filter, .. } => {
                    let filter = if *filter == GlobalVisibility::Pcss { "PCSS" } else { "PCF" };
                    writeln!(f, "  {} [{filter}]", pass.name())?;
                }
                Pass::Visibility { lights } => writeln!(f, "  {} ({lights} light layer(s))", pass.name())?,
                Pass::Blur { sigma_glo_cm } => writeln!(f, "  {} ({sigma_glo_cm} cm)", pass.name())?,
                Pass::GBuffer => writeln!(f, "  {} (to the first fiber entered; per sample)", pass.name())?,
                Pass::CellTransfer => {
                    writeln!(f, "  {} (once per frame: one fabric frame, no shadows)", pass.name())?;
                }
                Pass::Shade { single, multiple, paths, global_visibility, cell_transfer, fiber_lobes } => {
                    let mut terms = Vec::new();
                    if *single {
                        terms.push(format!(
                            "single scattering [{}]",
                            paths.iter().map(|p| format!("{p:?}")).collect::<Vec<_>>().join(", ")
                        ));
                    }
                    if *multiple {
                        let cells = if *cell_transfer { "cells' A c_in" } else { "per pixel" };
                        let lobes = if *fiber_lobes { " + fiber lobes" } else { "" };
                        terms.push(format!("multiple scattering [IIRTF, {cells}{lobes}]"));
                    }
                    let shadows = if *global_visibility { " x shadow-map visibility" } else { "" };
                    writeln!(f, "  {}: {}{shadows}; per sample", pass.name(), terms.join(" + "))?;
                }
                _ => writeln!(f, "  {}", pass.name())?,
            }
        }
        for l in &self.lights {
            writeln!(f, "  light {}: local {:?}, global {:?}", l.light, l.local, l.global)?;
        }
        for i in &self.dropped_lights {
            writeln!(f, "  light {i}: below the flat fabric, contributes nothing (skipped)")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inputs(flat: bool) -> PlanInputs {
        PlanInputs {
            flat_normal: flat.then_some([0.0, 0.0, 1.0]),
            components: Components::All,
            sigma_glo_cm: 0.05,
            spp: 4,
            uniform_frame: flat,
            fiber_lobes: false,
        }
    }

    const SUN: PlanLight = PlanLight::Directional { to_light: [0.3, 0.1, 0.9] };

    #[test]
    fn a_directional_only_scene_runs_no_pcss_and_no_sum_of_sg_path() {
        let plan =
            FramePlan::new(&[SUN, PlanLight::Directional { to_light: [0.0, 0.6, 0.8] }], &inputs(false));
        assert!(!plan.filters_with(GlobalVisibility::Pcss));
        assert!(plan.filters_with(GlobalVisibility::Pcf));
        assert!(!plan.uses(LocalVisibility::SumOfSg));
        assert!(!plan.uses(LocalVisibility::SsdfErf));
        assert!(plan.uses(LocalVisibility::SsdfSign));
    }

    #[test]
    fn a_flat_swatch_lit_from_above_runs_no_shadow_pass() {
        let plan =
            FramePlan::new(&[SUN, PlanLight::Sg { axis: [0.0, 0.0, 1.0], sharpness: 8.0 }], &inputs(true));
        assert!(!plan.shadow_maps);
        assert!(!plan.blur);
        let passes = plan.passes();
        assert!(!passes.iter().any(|p| matches!(
            p,
            Pass::ShadowMap { .. } | Pass::TopSurface | Pass::Visibility { .. } | Pass::Blur { .. }
        )));
        assert!(passes.iter().any(|p| matches!(p, Pass::GBuffer)));
        // One fabric frame and no shadows: the cells' transferred light once per frame.
        assert!(plan.cell_transfer && passes.contains(&Pass::CellTransfer));
    }

    #[test]
    fn the_cell_transfer_runs_only_where_every_pixel_sees_the_same_light() {
        let sky = PlanLight::Sg { axis: [0.0, 0.0, 1.0], sharpness: 8.0 };
        // A curved shell (frames differ, shadow maps vary the light): per pixel.
        assert!(!FramePlan::new(&[SUN, sky], &inputs(false)).cell_transfer);
        // A flat shell whose UV map differs between triangles: per pixel.
        let skewed = PlanInputs { uniform_frame: false, ..inputs(true) };
        assert!(!FramePlan::new(&[SUN, sky], &skewed).cell_transfer);
        // No multiple scattering: nothing to transfer.
        let single = PlanInputs { components: Components::SingleOnly, ..inputs(true) };
        let plan = FramePlan::new(&[SUN, sky], &single);
        assert!(!plan.cell_transfer && !plan.passes().contains(&Pass::CellTransfer));
    }

    #[test]
    fn fiber_lobes_are_shaded_only_for_a_bake_that_has_them() {
        let sky = PlanLight::Sg { axis: [0.0, 0.0, 1.0], sharpness: 8.0 };
        let shade = |plan: &FramePlan| {
            plan.passes().into_iter().find_map(|p| match p {
                Pass::Shade { fiber_lobes, .. } => Some(fiber_lobes),
                _ => None,
            })
        };
        for flat in [true, false] {
            // A bake without fiber lobes: the shading pass is compiled without them.
            let plan = FramePlan::new(&[SUN, sky], &inputs(flat));
            assert!(!plan.fiber_lobes && shade(&plan) == Some(false), "{plan}");
            assert!(!plan.to_string().contains("lobes"), "{plan}");
            // With them: on, in either transfer path.
            let with = PlanInputs { fiber_lobes: true, ..inputs(flat) };
            let plan = FramePlan::new(&[SUN, sky], &with);
            assert!(plan.fiber_lobes && shade(&plan) == Some(true), "{plan}");
            assert!(plan.to_string().contains("fiber lobes"), "{plan}");
            // ... but not without multiple scattering.
            let single = PlanInputs { components: Components::SingleOnly, ..with };
            assert_eq!(shade(&FramePlan::new(&[SUN, sky], &single)), Some(false));
        }
    }

    #[test]
    fn a_light_below_a_flat_swatch_is_dropped() {
        let plan =
            FramePlan::new(&[PlanLight::Directional { to_light: [0.0, 0.0, -1.0] }, SUN], &inputs(true));
        assert_eq!(plan.dropped_lights, vec![0]);
        assert_eq!(plan.lights.len(), 1);
    }

    #[test]
    fn sg_paths_follow_the_sharpness() {
        assert_eq!(sg_local_visibility(1e-4), LocalVisibility::SumOfSg);
        assert_eq!(sg_local_visibility(100.0), LocalVisibility::SumOfSg);
        assert_eq!(sg_local_visibility(150.0), LocalVisibility::Blend);
        assert_eq!(sg_local_visibility(200.0), LocalVisibility::SsdfErf);
        assert_eq!(sg_local_visibility(1e5), LocalVisibility::SsdfErf);
        let sharp =
            FramePlan::new(&[PlanLight::Sg { axis: [0.0, 0.0, 1.0], sharpness: 500.0 }], &inputs(false));
        assert!(!sharp.uses(LocalVisibility::SumOfSg) && sharp.uses(LocalVisibility::SsdfErf));
        assert!(sharp.filters_with(GlobalVisibility::Pcss) && !sharp.filters_with(GlobalVisibility::Pcf));
        let mid =
            FramePlan::new(&[PlanLight::Sg { axis: [0.0, 0.0, 1.0], sharpness: 150.0 }], &inputs(false));
        assert!(mid.uses(LocalVisibility::SumOfSg) && mid.uses(LocalVisibility::SsdfErf));
    }

    #[test]
    fn components_and_sigma_switch_passes_off() {
        let mut i = inputs(false);
        i.components = Components::SingleOnly;
        let plan = FramePlan::new(&[SUN], &i);
        assert!(!plan.multiple && !plan.blur);
        i.components = Components::All;
        i.sigma_glo_cm = 0.0;
        assert!(!FramePlan::new(&[SUN], &i).blur);
        i.components = Components::MultipleOnly;
        i.sigma_glo_cm = 0.05;
        let plan = FramePlan::new(&[SUN], &i);
        assert!(!plan.single && plan.blur && !plan.uses(LocalVisibility::SsdfSign));
        let text = plan.to_string();
        assert!(text.contains("multiple scattering") && !text.contains("single scattering"), "{text}");
    }
}
