//! Tests of the fiber model and the materials: furnace, sampling weights, chi-square of every
//! sampler against its pdf, pdf normalization, extreme-parameter sweeps and validation.

use std::f64::consts::{FRAC_PI_2, PI};

use glam::DVec3;
use rand::Rng;
use rand_pcg::Pcg64;

use super::gn_table::gn_direct;
use super::*;
use crate::quadrature::{gauss_legendre_pairs, graded_breaks};
use crate::test_support::{TestFrame, chi2_test, lobe_edges};

fn fiber(c_r: f64, beta_r: f64, c_tt: Rgb, beta_tt: f64, gamma: f64) -> FiberParams {
    FiberParams { c_r: Rgb::splat(c_r), beta_r_deg: beta_r, c_tt, beta_tt_deg: beta_tt, gamma_tt_deg: gamma }
}

/// Named parameter sets: a published one, narrow lobes, wide lobes, mixed.
fn param_sets() -> Vec<(&'static str, FiberParams)> {
    vec![
        (
            "fleece",
            FiberParams {
                c_r: Rgb::new(0.04, 0.087, 0.087),
                beta_r_deg: 7.238,
                c_tt: Rgb::new(0.452, 0.725, 0.948),
                beta_tt_deg: 10.0,
                gamma_tt_deg: 25.989,
            },
        ),
        ("narrow", fiber(0.3, 0.5, Rgb::ONE, 2.0, 0.5)),
        ("narrow-tt", fiber(0.05, 2.0, Rgb::new(1.0, 0.5, 0.2), 0.5, 19.823)),
        ("wide", fiber(0.9, 60.0, Rgb::splat(0.6), 45.0, 180.0)),
        ("cotton", fiber(0.04, 1.0, Rgb::splat(0.9), 27.197, 38.269)),
    ]
}

fn tangent() -> DVec3 {
    DVec3::new(0.3, -0.5, 0.81).normalize()
}

/// Gauss–Legendre nodes and weights on panels between `breaks`.
fn panel_nodes(breaks: &[f64]) -> Vec<(f64, f64)> {
    let rule = gauss_legendre_pairs(16);
    let mut nodes = Vec::new();
    for w in breaks.windows(2) {
        let (mid, half) = (0.5 * (w[0] + w[1]), 0.5 * (w[1] - w[0]));
        nodes.extend(rule.iter().map(|&(x, wx)| (mid + half * x, wx * half)));
    }
    nodes
}

/// ∫∫ f(θ, φ) cos θ dθ dφ over the sphere, with panels graded around the lobe centre
/// (θc, widths `wt`) and (φc, width `wp`).
fn sphere_integral(theta_c: f64, wt: &[f64], phi_c: f64, wp: f64, mut f: impl FnMut(f64, f64) -> Rgb) -> Rgb {
    let mut tb: Vec<f64> =
        wt.iter().flat_map(|&w| graded_breaks(-FRAC_PI_2, FRAC_PI_2, theta_c, w)).collect();
    tb.sort_by(f64::total_cmp);
    tb.dedup_by(|a, b| (*a - *b).abs() < 1e-12);
    let theta_nodes = panel_nodes(&tb);
    let phi_nodes = panel_nodes(&graded_breaks(phi_c - PI, phi_c + PI, phi_c, wp));
    let mut sum = Rgb::ZERO;
    for &(th, wth) in &theta_nodes {
        let mut inner = Rgb::ZERO;
        for &(ph, wph) in &phi_nodes {
            inner += f(th, ph) * wph;
        }
        sum += inner * (wth * th.cos());
    }
    sum
}

fn lobe_widths(p: &FiberParams) -> ([f64; 2], f64) {
    ([p.beta_r_deg.to_radians(), p.beta_tt_deg.to_radians()], p.gamma_tt_deg.to_radians())
}

/// The furnace value from the parameters, independent of the implementation.
fn furnace_value(p: &FiberParams, theta_i: f64) -> Rgb {
    let f = p.c_r + (Rgb::ONE - p.c_r) * (1.0 - theta_i.cos()).powi(5);
    f + (Rgb::ONE - f) * p.c_tt
}

fn max_rel(a: Rgb, b: Rgb) -> f64 {
    ((a - b).abs() / b.abs().max(Rgb::splat(1e-300))).max_element()
}

const FURNACE_THETAS_DEG: [f64; 13] =
    [-90.0, -89.9, -80.0, -60.0, -30.0, -5.0, 0.0, 10.0, 45.0, 70.0, 85.0, 89.9, 90.0];
/// Relative tolerance of the furnace: the Gn table's error (≤ 5.3e-8) plus quadrature.
const FURNACE_TOL: f64 = 2e-7;

fn furnace_case(name: &str, p: &FiberParams) {
    let s = FiberScattering::new(p).unwrap();
    let frame = TestFrame::new(tangent());
    let (wt, wp) = lobe_widths(p);
    let mut worst: f64 = 0.0;
    for &ti_deg in &FURNACE_THETAS_DEG {
        for phi_i in [0.4, -2.5] {
            let ti = f64::to_radians(ti_deg);
            let wi = frame.dir(ti, phi_i);
            // ∫ S cos θo dωo, dωo = cos θo dθo dφo.
            let got = sphere_integral(-ti, &wt, phi_i + PI, wp, |to, po| {
                s.eval(frame.axis, wi, frame.dir(to, po)) * to.cos()
            });
            let want = furnace_value(p, ti);
            let err = max_rel(got, want);
            worst = worst.max(err);
            assert!(err < FURNACE_TOL, "{name}: θi = {ti_deg}°, φi = {phi_i}: {got} vs {want} (rel {err:e})");
        }
    }
    println!("furnace {name}: max rel error {worst:.2e}");
}

#[test]
fn furnace_fleece_and_wide() {
    for (name, p) in param_sets().iter().filter(|(n, _)| ["fleece", "wide"].contains(n)) {
        furnace_case(name, p);
    }
}

#[test]
fn furnace_narrow() {
    for (name, p) in param_sets().iter().filter(|(n, _)| ["narrow", "narrow-tt"].contains(n)) {
        furnace_case(name, p);
    }
}

#[test]
fn furnace_cotton_white() {
    // C_TT = 1: the furnace is exactly 1 for every ωi.
    let (name, mut p) = param_sets()[4];
    p.c_tt = Rgb::ONE;
    furnace_case(name, &p);
}

#[test]
fn eval_matches_the_formula_with_directly_integrated_gn() {
    // Catches sign errors the furnace cannot see (Gn is even, so g(θo; +θi) would also pass it).
    let (_, p) = param_sets()[0];
    let s = FiberScattering::new(&p).unwrap();
    let (lam_r, lam_tt) = (0.5 / p.beta_r_deg.to_radians().powi(2), 0.5 / p.beta_tt_deg.to_radians().powi(2));
    let kappa = 1.0 / p.gamma_tt_deg.to_radians().powi(2);
    for (ti, pi, to, po) in
        [(0.3, 0.1, -0.25, 2.0), (-1.2, 0.0, 1.1, 3.0), (0.0, 1.0, 0.05, -2.2), (1.5, 0.0, -1.5, 0.5)]
    {
        let f = furnace_value(&FiberParams { c_tt: Rgb::ZERO, ..p }, ti);
        let m = |lam: f64, beta: f64| {
            (lam / PI).sqrt() * (-lam * (to + ti) * (to + ti)).exp() / gn_direct(-ti, beta.to_radians()).0
        };
        let n_tt =
            (kappa * (po - pi - PI).cos()).exp() / (2.0 * PI * crate::special::i0e(kappa) * kappa.exp());
        let want = f * m(lam_r, p.beta_r_deg) / (2.0 * PI)
            + (Rgb::ONE - f) * p.c_tt * m(lam_tt, p.beta_tt_deg) * n_tt;
        let got = s.eval_angles(ti, pi, to, po);
        assert!(max_rel(got, want) < 1e-7, "{got} vs {want}");
    }
}

#[test]
fn lobes_peak_at_the_specular_cone_and_forward() {
    let s = FiberScattering::new(&fiber(0.0, 3.0, Rgb::ONE, 3.0, 10.0)).unwrap();
    for ti in [-1.0, -0.2, 0.4, 1.3] {
        let at = |to: f64, dphi: f64| s.eval_angles(ti, 0.3, to, 0.3 + dphi).x;
        let peak = at(-ti, PI);
        assert!(peak > at(-ti + 0.02, PI) && peak > at(-ti - 0.02, PI), "θi = {ti}");
        assert!(peak > at(-ti, PI + 0.05) && peak > at(-ti, PI - 0.05), "θi = {ti}");
        // Backward (φo = φi) is much weaker than forward (where F_R, hence the φ-uniform R
        // lobe, is negligible).
        if ti.abs() < 0.5 {
            assert!(at(-ti, 0.0) < 1e-3 * peak, "θi = {ti}: {} vs {peak}", at(-ti, 0.0));
        }
    }
}

/// Sampling weights: E[S cos / pdf] under `sample` equals the deterministic integral, within
/// 5 standard errors (per channel), fixing either side.
#[test]
fn sampling_weights_match_the_integral_both_ways() {
    let frame = TestFrame::new(tangent());
    let n = DVec3::new(0.0, 0.6, 0.8); // only used by Lambert; the fiber ignores it
    let mut rng: Pcg64 = rand::SeedableRng::seed_from_u64(7);
    for (name, p) in param_sets() {
        let s = FiberScattering::new(&p).unwrap();
        let m = Material::from_desc(&MaterialDesc::Fiber(p)).unwrap();
        let (wt, wp) = lobe_widths(&p);
        for (tf, pf) in [(0.2, 0.0), (-0.9, 1.0), (1.45, -2.0)] {
            let fixed = frame.dir(tf, pf);
            for fix_wi in [true, false] {
                let want = if fix_wi {
                    furnace_value(&p, tf)
                } else {
                    sphere_integral(-tf, &wt, pf + PI, wp, |ti, pi| {
                        s.eval(frame.axis, frame.dir(ti, pi), fixed) * ti.cos()
                    })
                };
                let count = 20_000;
                let (mut sum, mut sum2) = (Rgb::ZERO, Rgb::ZERO);
                for _ in 0..count {
                    let u = [rng.random::<f64>(), rng.random::<f64>(), rng.random::<f64>()];
                    let w = if fix_wi {
                        s.sample(frame.axis, fixed, u).map_or(Rgb::ZERO, |wo| {
                            let (to, _) = frame.angles(wo);
                            s.eval(frame.axis, fixed, wo) * to.cos() / s.pdf(frame.axis, fixed, wo)
                        })
                    } else {
                        m.sample(frame.axis, n, fixed, u)
                            .map_or(Rgb::ZERO, |(wi, pdf)| m.eval_cos(frame.axis, n, wi, fixed) / pdf)
                    };
                    assert!(w.is_finite() && w.min_element() >= 0.0);
                    sum += w;
                    sum2 += w * w;
                }
                let mean = sum / f64::from(count);
                let se =
                    ((sum2 / f64::from(count) - mean * mean).max(Rgb::ZERO) / f64::from(count)).powf(0.5);
                let dev = (mean - want).abs();
                assert!(
                    dev.cmple(5.0 * se + want * 1e-9 + Rgb::splat(1e-12)).all(),
                    "{name} θf = {tf} fix_wi = {fix_wi}: mean {mean} ± {se} vs {want}"
                );
            }
        }
    }
}

/// Total number of chi-square tests in this module, for the Šidák correction.
const CHI2_TESTS: usize = 5 * 5 + 3 + 5;
const CHI2_ALPHA: f64 = 0.01;

pub(crate) fn chi2_threshold() -> f64 {
    1.0 - (1.0 - CHI2_ALPHA).powf(1.0 / CHI2_TESTS as f64)
}

/// Chi-square of the fiber sampler for parameter set `set`, five fixed directions (grazing
/// ones included).
fn chi2_fiber_case(set: usize) {
    let frame = TestFrame::new(tangent());
    let alpha = chi2_threshold();
    let mut seed = 100 + 10 * set as u64;
    let (name, p) = param_sets()[set];
    {
        let s = FiberScattering::new(&p).unwrap();
        let (wt, wp) = lobe_widths(&p);
        for tf in [0.0, 0.6, -1.2, f64::to_radians(89.9), f64::to_radians(-89.99)] {
            let pf = 0.7;
            let fixed = frame.dir(tf, pf);
            let theta_edges = lobe_edges(-FRAC_PI_2, FRAC_PI_2, -tf, &wt, 24);
            let phi_edges = lobe_edges(pf, pf + 2.0 * PI, pf + PI, &[wp], 36);
            seed += 1;
            let r = chi2_test(
                frame,
                &theta_edges,
                &phi_edges,
                100_000,
                seed,
                |rng| s.sample(frame.axis, fixed, [rng.random(), rng.random(), rng.random()]),
                |w| s.pdf(frame.axis, fixed, w),
            );
            println!(
                "chi2 {name} θf = {:.2}°: p = {:.4} (X² = {:.1}, dof {})",
                tf.to_degrees(),
                r.p_value,
                r.stat,
                r.dof
            );
            assert!(r.p_value > alpha, "{name} θf = {tf}: {r:?} (threshold {alpha:e})");
            assert!((r.pdf_mass - 1.0).abs() < 1e-4, "{name} θf = {tf}: mass {}", r.pdf_mass);
        }
    }
}

#[test]
fn chi2_fiber_fleece() {
    chi2_fiber_case(0);
}

#[test]
fn chi2_fiber_narrow() {
    chi2_fiber_case(1);
}

#[test]
fn chi2_fiber_narrow_tt() {
    chi2_fiber_case(2);
}

#[test]
fn chi2_fiber_wide() {
    chi2_fiber_case(3);
}

#[test]
fn chi2_fiber_cotton() {
    chi2_fiber_case(4);
}

#[test]
fn chi2_lambert_sampler_against_its_pdf() {
    let n = DVec3::new(-0.2, 0.4, 0.9).normalize();
    let frame = TestFrame::new(n);
    let m = Material::from_desc(&MaterialDesc::Lambert { albedo: Rgb::new(0.8, 0.5, 0.1) }).unwrap();
    let alpha = chi2_threshold();
    for (k, wo) in [n, frame.dir(0.05, 1.0), frame.dir(1.0, -2.0)].into_iter().enumerate() {
        let theta_edges = lobe_edges(-FRAC_PI_2, FRAC_PI_2, 0.0, &[], 32);
        let phi_edges = lobe_edges(0.0, 2.0 * PI, 0.0, &[], 24);
        let r = chi2_test(
            frame,
            &theta_edges,
            &phi_edges,
            100_000,
            500 + k as u64,
            |rng| m.sample(tangent(), n, wo, [rng.random(), rng.random(), rng.random()]).map(|s| s.0),
            |wi| m.pdf(tangent(), n, wo, wi),
        );
        println!("chi2 lambert wo #{k}: p = {:.4} (X² = {:.1}, dof {})", r.p_value, r.stat, r.dof);
        assert!(r.p_value > alpha, "{r:?}");
        assert!((r.pdf_mass - 1.0).abs() < 1e-6, "{}", r.pdf_mass);
    }
}

fn pdf_integrates_to_one(sets: std::ops::Range<usize>) {
    let frame = TestFrame::new(tangent());
    for (name, p) in &param_sets()[sets] {
        let p = *p;
        let s = FiberScattering::new(&p).unwrap();
        let (wt, wp) = lobe_widths(&p);
        for tf in [-FRAC_PI_2, -1.5, -0.7, 0.0, 0.3, 1.2, FRAC_PI_2 - 1e-4, FRAC_PI_2] {
            let pf = -1.1;
            let fixed = frame.dir(tf, pf);
            let mass = sphere_integral(-tf, &wt, pf + PI, wp, |t, ph| {
                Rgb::splat(s.pdf(frame.axis, fixed, frame.dir(t, ph)))
            })
            .x;
            // Directions within 1e-9 of ±t (pdf 0, never sampled) hold < 1e-7 of the mass.
            assert!((mass - 1.0).abs() < 1e-6, "{name} θf = {tf}: {mass}");
        }
    }
}

#[test]
fn pdf_integrates_to_one_fleece_narrow() {
    pdf_integrates_to_one(0..2);
}

#[test]
fn pdf_integrates_to_one_narrow_tt_wide_cotton() {
    pdf_integrates_to_one(2..5);
}

/// Every combination of extreme parameters, directions at and next to the poles (ωi = ±t
/// included), lobes centred at the poles: all values finite and non-negative, samples unit
/// vectors with positive finite pdf and finite weight.
#[test]
fn extreme_parameters_and_directions_stay_finite() {
    let t = tangent();
    let frame = TestFrame::new(t);
    let n = frame.e1;
    let thetas = [-FRAC_PI_2, -FRAC_PI_2 + 1e-12, -1.0, 0.0, 0.3, FRAC_PI_2 - 1e-9, FRAC_PI_2];
    let mut dirs: Vec<DVec3> =
        thetas.iter().flat_map(|&th| [frame.dir(th, 0.0), frame.dir(th, 2.0)]).collect();
    dirs.extend([t, -t]);
    let us = [
        [0.0, 0.0, 0.0],
        [0.5, 0.5, 0.5],
        [1.0 - 1e-16, 1.0 - 1e-16, 1.0 - 1e-16],
        [0.3, 1e-300, 0.999],
        [0.99, 0.7, 0.0],
    ];
    let mut sampled = 0;
    for bits in 0..32u32 {
        let pick = |bit: u32, a: f64, b: f64| if bits >> bit & 1 == 0 { a } else { b };
        let p = FiberParams {
            c_r: Rgb::splat(pick(0, 0.0, 1.0)),
            beta_r_deg: pick(1, 0.5, 60.0),
            c_tt: Rgb::splat(pick(2, 0.0, 1.0)),
            beta_tt_deg: pick(3, 0.5, 60.0),
            gamma_tt_deg: pick(4, 0.5, 180.0),
        };
        let m = Material::from_desc(&MaterialDesc::Fiber(p)).unwrap();
        let Material::Fiber(s) = &m else { unreachable!() };
        for &wi in &dirs {
            for &wo in &dirs {
                let v = s.eval(t, wi, wo);
                assert!(v.is_finite() && v.min_element() >= 0.0, "{p:?} {wi} {wo}: {v}");
                let c = m.eval_cos(t, n, wi, wo);
                assert!(c.is_finite() && c.min_element() >= 0.0, "{p:?}: {c}");
                let pdf = m.pdf(t, n, wo, wi);
                assert!(pdf.is_finite() && pdf >= 0.0, "{p:?} {wi} {wo}: pdf {pdf}");
            }
            for u in us {
                if let Some((d, pdf)) = m.sample(t, n, wi, u) {
                    sampled += 1;
                    assert!(d.is_finite() && (d.length() - 1.0).abs() < 1e-12, "{p:?} {wi} {u:?}: {d}");
                    assert!(pdf.is_finite() && pdf > 0.0);
                    let w = m.eval_cos(t, n, d, wi) / pdf;
                    assert!(w.is_finite() && w.min_element() >= 0.0, "{p:?} {wi} {u:?}: weight {w}");
                }
            }
        }
    }
    assert!(sampled > 1000, "{sampled}");
}

#[test]
fn parameter_validation_names_the_parameter_and_its_range() {
    let (_, good) = param_sets()[0];
    assert!(FiberScattering::new(&good).is_ok());
    let bad: [(&str, FiberParams); 10] = [
        ("c_r", FiberParams { c_r: Rgb::new(0.1, f64::NAN, 0.1), ..good }),
        ("c_r", FiberParams { c_r: Rgb::splat(-0.1), ..good }),
        ("c_tt", FiberParams { c_tt: Rgb::new(0.2, 0.2, 1.5), ..good }),
        ("beta_r_deg", FiberParams { beta_r_deg: f64::NAN, ..good }),
        ("beta_r_deg", FiberParams { beta_r_deg: 0.4, ..good }),
        ("beta_tt_deg", FiberParams { beta_tt_deg: -3.0, ..good }),
        ("beta_tt_deg", FiberParams { beta_tt_deg: 61.0, ..good }),
        ("gamma_tt_deg", FiberParams { gamma_tt_deg: 0.0, ..good }),
        ("gamma_tt_deg", FiberParams { gamma_tt_deg: f64::INFINITY, ..good }),
        ("gamma_tt_deg", FiberParams { gamma_tt_deg: 181.0, ..good }),
    ];
    for (name, p) in bad {
        let err = Material::from_desc(&MaterialDesc::Fiber(p)).unwrap_err();
        let msg = err.to_string();
        assert_eq!(err.name, name, "{msg}");
        let range_ok = match name {
            "c_r" | "c_tt" => msg.contains("[0, 1]"),
            "gamma_tt_deg" => msg.contains("0.5 <= gamma_tt_deg <= 180"),
            _ => msg.contains(&format!("0.5 <= {name} <= 60")),
        };
        assert!(range_ok, "{msg}");
    }
    for albedo in [Rgb::new(0.5, 1.01, 0.5), Rgb::new(f64::NAN, 0.0, 0.0), Rgb::splat(-1e-9)] {
        let err = Material::from_desc(&MaterialDesc::Lambert { albedo }).unwrap_err();
        assert!(err.name == "albedo" && err.to_string().contains("[0, 1]"), "{err}");
    }
}

#[test]
fn material_interface() {
    let (_, p) = param_sets()[0];
    let fib = Material::from_desc(&MaterialDesc::Fiber(p)).unwrap();
    let lam = Material::from_desc(&MaterialDesc::Lambert { albedo: Rgb::new(0.8, 0.5, 0.1) }).unwrap();
    assert!(fib.is_transmissive() && !lam.is_transmissive());
    assert!(max_rel(fib.albedo_hint(), furnace_value(&p, 0.0)) < 1e-15);
    assert_eq!(lam.albedo_hint(), Rgb::new(0.8, 0.5, 0.1));
    let t = tangent();
    let frame = TestFrame::new(t);
    let n = frame.e2;
    let (wi, wo) = (frame.dir(0.4, 1.0), frame.dir(-0.3, 3.0));
    let Material::Fiber(s) = &fib else { unreachable!() };
    // The fiber's cosine is cos θi = |ωi × t|.
    assert!(max_rel(fib.eval_cos(t, n, wi, wo), s.eval(t, wi, wo) * wi.cross(t).length()) < 1e-14);
    // Lambert: albedo/π cos, zero with either direction below n; its sampling weight is the albedo.
    let up = (0.6 * n + 0.8 * frame.e1).normalize();
    let down = (-0.6 * n + 0.8 * frame.e1).normalize();
    assert!(max_rel(lam.eval_cos(t, n, up, n), Rgb::new(0.8, 0.5, 0.1) * 0.6 / PI) < 1e-14);
    assert_eq!(lam.eval_cos(t, n, down, n), Rgb::ZERO);
    assert_eq!(lam.eval_cos(t, n, up, down), Rgb::ZERO);
    assert!(lam.sample(t, n, down, [0.5; 3]).is_none());
    assert!(lam.pdf(t, n, down, up) == 0.0 && lam.pdf(t, n, up, down) == 0.0);
    let mut rng: Pcg64 = rand::SeedableRng::seed_from_u64(3);
    for _ in 0..1000 {
        let (d, pdf) = lam.sample(t, n, up, [rng.random(), rng.random(), rng.random()]).unwrap();
        assert!(max_rel(lam.eval_cos(t, n, d, up) / pdf, Rgb::new(0.8, 0.5, 0.1)) < 1e-12);
    }
    // The fiber's `sample` returns the pdf `pdf` gives.
    for _ in 0..1000 {
        if let Some((d, pdf)) = fib.sample(t, n, wo, [rng.random(), rng.random(), rng.random()]) {
            assert!((pdf / fib.pdf(t, n, wo, d) - 1.0).abs() < 1e-14);
        }
    }
}

/// The von Mises sampler alone, over the κ range it claims (0.1 .. 1e6): 1D chi-square.
#[test]
fn chi2_von_mises_sampler_from_flat_to_extremely_sharp() {
    let rule = gauss_legendre_pairs(8);
    let mut rng: Pcg64 = rand::SeedableRng::seed_from_u64(11);
    for kappa in [0.1, 1.0, 30.0, 1e3, 1e6] {
        let vm = super::sampling::VonMises::new(kappa);
        let half = (8.0 / kappa.sqrt()).min(PI);
        let nb = 64;
        let edges: Vec<f64> = (0..=nb).map(|k| -half + 2.0 * half * f64::from(k) / f64::from(nb)).collect();
        let count = 100_000;
        let mut obs = vec![0.0; nb as usize + 1];
        for _ in 0..count {
            let x = vm.sample(rng.random(), rng.random());
            assert!(x.is_finite() && x.abs() <= PI);
            let i = edges.partition_point(|&e| e <= x);
            obs[if i == 0 || i > nb as usize { nb as usize } else { i - 1 }] += 1.0;
        }
        let mut exp: Vec<f64> = edges
            .windows(2)
            .map(|w| {
                crate::quadrature::integrate_panels(&rule, &[w[0], w[1]], |x| vm.pdf(x)) * f64::from(count)
            })
            .collect();
        let inside: f64 = exp.iter().sum();
        exp.push(f64::from(count) - inside);
        let (mut stat, mut dof, mut po, mut pe) = (0.0, 0usize, 0.0, 0.0);
        for (o, e) in obs.iter().zip(&exp) {
            if *e < 5.0 {
                po += o;
                pe += e;
            } else {
                stat += (o - e) * (o - e) / e;
                dof += 1;
            }
        }
        if po > 0.0 || pe > 0.0 {
            stat += (po - pe) * (po - pe) / f64::max(pe, 1e-300);
            dof += 1;
        }
        let p = crate::test_support::gamma_q(0.5 * (dof - 1) as f64, 0.5 * stat);
        println!("chi2 von Mises κ = {kappa:e}: p = {p:.4} (X² = {stat:.1}, dof {})", dof - 1);
        assert!(p > chi2_threshold(), "κ = {kappa}: p = {p}");
    }
}
