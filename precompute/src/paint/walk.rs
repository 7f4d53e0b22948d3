//! The colour-free camera path: the path tracer's estimator with every paintable colour left
//! out, so one path serves every painting.
//!
//! A path starts at the camera and scatters on fibers as [`crate::pathtrace`] does (next-event
//! estimation toward every light, a BCSDF-sampled continuation that picks up SG lights when it
//! escapes, MIS by the power heuristic, Russian roulette from the fourth event), but every
//! choice is made without the paintable colour (a fiber's C_TT, a Lambertian yarn's albedo):
//! lobes are chosen and sampled by [`Material::sample_colour_free`], MIS weighs with
//! [`Material::pdf_colour_free`], roulette runs on the throughput at a fixed TT albedo, and a
//! light connection is split into its R part and its TT part ([`Material::eval_cos_parts`]),
//! two separate paths (Hašan & Ramamoorthy: "every next-event connection a separate path").
//!
//! Each path then reaches [`Contribution`]: its value without the paintable colours, and how
//! many TT events it has in each cell. At colours α it contributes `value · Π_j α_j^(b_j)`
//! exactly, per channel; the homogeneous curve and the gradient are sums of such terms.

use glam::DVec3;
use rand::Rng;
use rand_pcg::Pcg64Mcg;

use super::cells::PaintCells;
use crate::Rgb;
use crate::bake::iirtf::COLOUR_FREE_ROULETTE_ALBEDO;
use crate::bcsdf::Lobe;
use crate::pathtrace::PathScene;
use crate::pathtrace::integrator::{below_ground, occluded, power_heuristic, russian_roulette, trace};

/// One light path's term: `value · Π_j α_j^(b_j)` at colours α.
pub(crate) struct Contribution<'a> {
    /// Everything but the paintable colours (light, geometry, lobe shapes, C_R factors).
    pub value: Rgb,
    /// Total number of TT events, `Σ_j b_j`.
    pub tt_events: u32,
    /// `(cell j, b_j)` for every cell with a TT event on the path.
    pub cells: &'a [(u32, u32)],
}

impl Contribution<'_> {
    /// The term at colours `colours` (indexed by cell).
    pub fn at(&self, colours: &[Rgb]) -> Rgb {
        let mut v = self.value;
        for &(cell, b) in self.cells {
            let c = colours[cell as usize];
            v *= Rgb::new(c.x.powi(b as i32), c.y.powi(b as i32), c.z.powi(b as i32));
        }
        v
    }
}

/// The TT counts of a path prefix, cell by cell.
#[derive(Default)]
struct Counts {
    cells: Vec<(u32, u32)>,
    total: u32,
}

impl Counts {
    fn add(&mut self, cell: u32) {
        self.total += 1;
        match self.cells.iter_mut().find(|(c, _)| *c == cell) {
            Some((_, b)) => *b += 1,
            None => self.cells.push((cell, 1)),
        }
    }

    fn remove(&mut self, cell: u32) {
        self.total -= 1;
        let i = self.cells.iter().position(|(c, _)| *c == cell).expect("the cell was added");
        self.cells[i].1 -= 1;
        if self.cells[i].1 == 0 {
            self.cells.swap_remove(i);
        }
    }
}

/// Walks one colour-free path from `origin` along `dir` (a camera ray) and hands every term to
/// `add`. `scene`'s materials give everything but their paintable colours, which are never read.
pub(crate) fn walk(
    scene: &PathScene,
    cells: &PaintCells,
    origin: DVec3,
    dir: DVec3,
    max_depth: u32,
    rng: &mut Pcg64Mcg,
    add: &mut (impl FnMut(&Contribution<'_>) + ?Sized),
) {
    let Some(mut hit) = trace(scene, origin, dir, None) else {
        return;
    };
    let mut dir = dir;
    let mut throughput = Rgb::ONE;
    let mut counts = Counts::default();
    for event in 1..=max_depth {
        let wo = -dir;
        let position = hit.position.as_dvec3();
        let (t, n) = (hit.tangent.as_dvec3(), hit.normal.as_dvec3());
        let material = &scene.yarn_materials[hit.yarn as usize];
        let cell = cells.cell_of(&hit);
        let c_r = material.colour_variables().1;

        for light in &scene.lights {
            let sample = light.sample([rng.random(), rng.random()]);
            let wi = sample.to_light;
            let (fixed, per_colour) = material.eval_cos_parts(t, n, wi, wo);
            if (fixed == Rgb::ZERO && per_colour == Rgb::ZERO) || occluded(scene, position, wi, hit.fiber) {
                continue;
            }
            let mis = sample
                .pdf
                .map_or(1.0, |light_pdf| power_heuristic(light_pdf, material.pdf_colour_free(t, n, wo, wi)));
            let weight = throughput * sample.weight * mis;
            if fixed != Rgb::ZERO {
                add(&Contribution { value: weight * fixed, tt_events: counts.total, cells: &counts.cells });
            }
            if per_colour != Rgb::ZERO {
                counts.add(cell);
                add(&Contribution {
                    value: weight * per_colour,
                    tt_events: counts.total,
                    cells: &counts.cells,
                });
                counts.remove(cell);
            }
        }

        let Some(e) = material.sample_colour_free(t, n, wo, [rng.random(), rng.random(), rng.random()])
        else {
            break;
        };
        let pdf = material.pdf_colour_free(t, n, wo, e.dir);
        if !(pdf > 0.0 && pdf.is_finite()) {
            break;
        }
        match e.lobe {
            Lobe::R => throughput *= (c_r + (Rgb::ONE - c_r) * e.schlick) * e.weight,
            Lobe::Tt => {
                throughput *= (Rgb::ONE - c_r) * e.weight;
                counts.add(cell);
            }
        }
        dir = e.dir;
        if let Some(next) = trace(scene, position, e.dir, Some(hit.fiber)) {
            hit = next;
        } else {
            if !below_ground(scene, position, e.dir) {
                for light in &scene.lights {
                    let light_pdf = light.pdf(e.dir);
                    if light_pdf > 0.0 {
                        let value = throughput * light.radiance(e.dir) * power_heuristic(pdf, light_pdf);
                        add(&Contribution { value, tt_events: counts.total, cells: &counts.cells });
                    }
                }
            }
            break;
        }
        // Roulette on the throughput at TT albedo COLOUR_FREE_ROULETTE_ALBEDO: never on the
        // paintable colours.
        let sampled = throughput.max_element() * COLOUR_FREE_ROULETTE_ALBEDO.powi(counts.total as i32);
        if !(sampled > 0.0 && sampled.is_finite()) {
            break;
        }
        let mut roulette = Rgb::splat(sampled);
        if !russian_roulette(event, &mut roulette, rng) {
            break;
        }
        throughput *= roulette.x / sampled;
    }
}
