//! Every WGSL function that feeds radiance is compared with its Rust twin on a real Vulkan
//! adapter (lavapipe on machines without a GPU), over grids that include the hard cases.
//! NaN or Inf anywhere fails.
//!
//! Without an adapter these tests fail, unless `TWILL_ALLOW_NO_GPU=1` is set, in which case
//! they print a loud SKIPPED line: skipping is never silent. `scripts/test.sh` installs
//! lavapipe, so CI always runs them.

use glam::DVec3;
use twill_precompute::sg::{
    sg_azimuthal_average, sg_azimuthal_average_f32, sg_mass, sg_mass_f32, sg_upper_fraction,
    sg_upper_fraction_f32,
};
use twill_precompute::shading::multiple::sg_above_horizon;
use twill_precompute::special::{erf, erf_f32, erfc, erfc_f32, i0e, i0e_f32};
use twill_renderer::gpu::Gpu;
use twill_renderer::shaders;

/// Arguments from -lim to lim (uniform), plus the hard cases given.
fn grid(lim: f32, n: usize, hard: &[f32]) -> Vec<f32> {
    let mut xs: Vec<f32> = (0..n).map(|i| -lim + 2.0 * lim * i as f32 / (n - 1) as f32).collect();
    xs.extend_from_slice(hard);
    xs
}

#[test]
fn special_functions_match_their_rust_twins() {
    let Some(gpu) = Gpu::for_test("special_functions_match_their_rust_twins") else { return };
    let hard =
        [0.0, -0.0, 1e-30, -1e-30, 1e-7, 0.4999999, 0.5, 3.75, 3.7500002, 9.0, 9.2, 20.0, 88.0, 1e4, 1e5];
    let xs = grid(12.0, 4001, &hard);
    let inputs: Vec<[f32; 4]> = xs.iter().map(|&x| [x, 0.0, 0.0, 0.0]).collect();
    let out = gpu
        .evaluate(
            shaders::SPECIAL,
            "vec4<f32>(erf_f32(input.x), erfc_f32(input.x), i0e_f32(input.x), 0.0)",
            &inputs,
        )
        .unwrap();
    let (mut worst_erf, mut worst_erfc, mut worst_i0e) = (0.0f64, 0.0f64, 0.0f64);
    for (&x, r) in xs.iter().zip(&out) {
        assert!(r.iter().all(|v| v.is_finite()), "x = {x}: non-finite GPU result {r:?}");
        let xd = f64::from(x);
        // erf: absolute error against the f64 reference (the CPU twin's bound is 3.5e-7).
        let e = (f64::from(r[0]) - erf(xd)).abs();
        assert!(e < 1e-6, "erf({x}): GPU {} CPU twin {} reference {}", r[0], erf_f32(x), erf(xd));
        worst_erf = worst_erf.max(e);
        // erfc: relative error where erfc is a normal f32 (x < 9), absolute elsewhere.
        let reference = erfc(xd);
        let e = if reference > 1e-37 { (f64::from(r[1]) / reference - 1.0).abs() } else { f64::from(r[1]) };
        assert!(e < 2e-5, "erfc({x}): GPU {} CPU twin {} reference {reference}", r[1], erfc_f32(x));
        worst_erfc = worst_erfc.max(e);
        // i0e: relative error.
        let e = (f64::from(r[2]) / i0e(xd) - 1.0).abs();
        assert!(e < 2e-6, "i0e({x}): GPU {} CPU twin {} reference {}", r[2], i0e_f32(x), i0e(xd));
        worst_i0e = worst_i0e.max(e);
    }
    eprintln!(
        "GPU vs f64 reference over {} arguments: erf abs {worst_erf:.2e}, erfc rel {worst_erfc:.2e}, i0e rel {worst_i0e:.2e}",
        xs.len()
    );
}

#[test]
fn sg_functions_match_their_rust_twins_from_1e_minus_4_to_1e5() {
    let Some(gpu) = Gpu::for_test("sg_functions_match_their_rust_twins_from_1e_minus_4_to_1e5") else {
        return;
    };
    let half_pi = std::f32::consts::FRAC_PI_2;
    // Sharpness log-spaced over the whole supported range; angles include aligned directions,
    // grazing ones (exactly ±π/2) and opposite ones.
    let lambdas: Vec<f32> = (0..=36).map(|i| 1e-4_f32 * 10f32.powf(i as f32 / 4.0)).collect();
    let angles = [-half_pi, -1.3, -0.7, -1e-3, 0.0, 1e-6, 0.5, 1.2, 1.5, half_pi];
    let mut inputs = Vec::new();
    for &lambda in &lambdas {
        for &theta in &angles {
            for &theta_xi in &angles {
                inputs.push([theta, theta_xi, lambda, 0.0]);
            }
        }
    }
    let out = gpu
        .evaluate(
            &shaders::shared_library(),
            "vec4<f32>(sg_azimuthal_average_f32(input.x, input.y, input.z), sg_mass_f32(input.z), 0.0, 0.0)",
            &inputs,
        )
        .unwrap();
    let (mut worst_avg, mut worst_mass) = (0.0f64, 0.0f64);
    for (input, r) in inputs.iter().zip(&out) {
        let [theta, theta_xi, lambda, _] = *input;
        assert!(r.iter().all(|v| v.is_finite()), "{input:?}: non-finite GPU result {r:?}");
        let reference = sg_azimuthal_average(f64::from(theta), f64::from(theta_xi), f64::from(lambda));
        // The same conditioning bound as the CPU twin's test (f32 angles, amplified by λ), plus
        // lavapipe's looser exp/sin; absolute below f32's normal range.
        let tolerance = 4e-6 + 4.8e-7 * f64::from(lambda) * f64::from(theta.abs() + theta_xi.abs());
        let error = (f64::from(r[0]) - reference).abs();
        assert!(
            error <= tolerance * reference + f64::from(f32::MIN_POSITIVE),
            "sg_azimuthal_average{input:?}: GPU {} CPU twin {} reference {reference}",
            r[0],
            sg_azimuthal_average_f32(theta, theta_xi, lambda)
        );
        if reference > 1e-30 {
            worst_avg = worst_avg.max(error / reference);
        }
        let mass = sg_mass(f64::from(lambda));
        let e = (f64::from(r[1]) / mass - 1.0).abs();
        assert!(
            e < 2e-6,
            "sg_mass({lambda}): GPU {} CPU twin {} reference {mass}",
            r[1],
            sg_mass_f32(lambda)
        );
        worst_mass = worst_mass.max(e);
    }
    eprintln!(
        "GPU vs f64 reference over {} cases: SG azimuthal average rel {worst_avg:.2e}, SG mass rel {worst_mass:.2e}",
        inputs.len()
    );
}

/// The SG standing for an SG light's part above the horizon (the fiber lobes' shapes): the
/// WGSL twin against the f64 function over the sharpness range, axes from below the horizon to
/// the zenith, on it and within a lobe's width of it, turned in azimuth.
#[test]
fn sg_above_horizon_matches_its_rust_twin_from_1e_minus_4_to_1e5() {
    let Some(gpu) = Gpu::for_test("sg_above_horizon_matches_its_rust_twin_from_1e_minus_4_to_1e5") else {
        return;
    };
    let lambdas: Vec<f32> = (0..=36).map(|i| 1e-4_f32 * 10f32.powf(i as f32 / 4.0)).collect();
    let axis_z = [-1.0_f32, -0.5, -0.03, -1e-3, 0.0, 1e-4, 2e-3, 0.02, 0.1, 0.3, 0.8, 0.999, 1.0];
    let inputs: Vec<[f32; 4]> = lambdas
        .iter()
        .flat_map(|&l| {
            axis_z.iter().map(move |&z| {
                let r = (1.0 - z * z).max(0.0).sqrt();
                [r * 0.8, -r * 0.6, z, l]
            })
        })
        .collect();
    let out = gpu
        .evaluate(&shaders::shared_library(), "sg_above_horizon_f32(input.xyz, input.w)", &inputs)
        .unwrap();
    let (mut worst_angle, mut worst_variance) = (0.0f64, 0.0f64);
    for (input, r) in inputs.iter().zip(&out) {
        assert!(r.iter().all(|v| v.is_finite()) && r[3] > 0.0, "{input:?}: GPU {r:?}");
        let axis = DVec3::new(f64::from(input[0]), f64::from(input[1]), f64::from(input[2]));
        let (ref_axis, ref_sharpness) = sg_above_horizon(axis, f64::from(input[3]));
        let got_axis = DVec3::new(f64::from(r[0]), f64::from(r[1]), f64::from(r[2]));
        let angle = got_axis.angle_between(ref_axis);
        let rel = (f64::from(r[3]) / ref_sharpness - 1.0).abs();
        // A light with less than 1e-6 of its power above the horizon gives the lobes no
        // strength, and its moment is the difference of two nearly equal ones (the whole SG's
        // and its mirror's): finite is all that counts there.
        let share = sg_upper_fraction(axis.z, f64::from(input[3]));
        if share < 1e-6 {
            continue;
        }
        // f32 axes and lavapipe's acos near the plane, and the same difference of moments for
        // lights mostly below it, where the error grows as 1/share (the lobes' radiance, which
        // is proportional to the share, keeps its absolute error). The sharpness is compared as
        // the variance 1/λ it widens the lobes' series by (exp(−k²/2λ)): within 2e-3 relative,
        // or 1e-5 absolute for very sharp lights, whose 1 − R² f32 holds to a few digits only
        // (a change of 3e-3 at most in the 24th term's factor).
        let below = 1.0 + 2e-2 / share;
        let variance_error = (1.0 / f64::from(r[3]) - 1.0 / ref_sharpness).abs();
        assert!(
            angle < 2e-3 * below && variance_error < (1e-5 + 2e-3 / ref_sharpness) * below,
            "sg_above_horizon{input:?}: GPU {r:?}, f64 {ref_axis} {ref_sharpness} (angle {angle:.2e}, sharpness rel {rel:.2e})"
        );
        worst_angle = worst_angle.max(angle);
        worst_variance = worst_variance.max(variance_error);
    }
    eprintln!(
        "GPU vs f64 over {} cases: SG above the horizon, axis {worst_angle:.2e} rad, 1/sharpness {worst_variance:.2e}",
        inputs.len()
    );
}

/// The share of an SG light above the horizon (the transfer's light, `hemisphere_light_sh`):
/// the WGSL twin against the f64 function over the sharpness range, axes from below the
/// horizon to the zenith, on it, and within a lobe's width of it.
#[test]
fn sg_upper_fraction_matches_its_rust_twins_from_1e_minus_4_to_1e5() {
    let Some(gpu) = Gpu::for_test("sg_upper_fraction_matches_its_rust_twins_from_1e_minus_4_to_1e5") else {
        return;
    };
    let lambdas: Vec<f32> = (0..=36).map(|i| 1e-4_f32 * 10f32.powf(i as f32 / 4.0)).collect();
    let axis_z = [-1.0, -0.5, -0.03, -1e-3, 0.0, 1e-4, 2e-3, 0.02, 0.1, 0.3, 0.8, 1.0];
    let inputs: Vec<[f32; 4]> =
        lambdas.iter().flat_map(|&l| axis_z.iter().map(move |&z| [z, l, 0.0, 0.0])).collect();
    let out = gpu
        .evaluate(
            &shaders::shared_library(),
            "vec4<f32>(sg_upper_fraction_f32(input.x, input.y), 0.0, 0.0, 0.0)",
            &inputs,
        )
        .unwrap();
    let mut worst = 0.0f64;
    for (input, r) in inputs.iter().zip(&out) {
        let [z, lambda, _, _] = *input;
        assert!(r[0].is_finite() && (0.0..=1.0).contains(&r[0]), "{input:?}: GPU {}", r[0]);
        let reference = sg_upper_fraction(f64::from(z), f64::from(lambda));
        let error = (f64::from(r[0]) - reference).abs();
        // f32 axes and lavapipe's acos/log: the share moves by λ^½ per unit of z near the plane.
        let tolerance = 2e-4 + 2e-6 * f64::from(lambda).sqrt();
        assert!(
            error <= tolerance,
            "sg_upper_fraction{input:?}: GPU {} CPU twin {} reference {reference}",
            r[0],
            sg_upper_fraction_f32(z, lambda)
        );
        worst = worst.max(error);
    }
    eprintln!("GPU vs f64 reference over {} cases: SG share above the horizon abs {worst:.2e}", inputs.len());
}
