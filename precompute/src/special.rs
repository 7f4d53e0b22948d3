//! TEMPORARY stand-in for the special functions (replaced at merge by the real module).
//!
//! Only here so the BCSDF slice compiles and tests: series / continued fractions, f64-accurate
//! enough for the tests (relative error ~1e-15 .. 1e-13).

use std::f64::consts::PI;

/// Exponentially scaled modified Bessel function of the first kind, `e^{-|x|} I0(x)`.
#[must_use]
pub fn i0e(x: f64) -> f64 {
    let x = x.abs();
    if x < 30.0 {
        // Power series, all terms positive.
        let q = 0.25 * x * x;
        let mut term = 1.0;
        let mut sum = 1.0;
        let mut k = 1.0;
        while term > sum * 1e-17 {
            term *= q / (k * k);
            sum += term;
            k += 1.0;
        }
        sum * (-x).exp()
    } else {
        // Asymptotic expansion.
        let mut term = 1.0;
        let mut sum = 1.0;
        for k in 1..40 {
            let k = f64::from(k);
            let next = term * (2.0 * k - 1.0) * (2.0 * k - 1.0) / (8.0 * k * x);
            if next.abs() < 1e-17 * sum || next.abs() > term.abs() {
                break;
            }
            term = next;
            sum += term;
        }
        sum / (2.0 * PI * x).sqrt()
    }
}

/// Error function.
#[must_use]
pub fn erf(x: f64) -> f64 {
    if x.abs() < 2.0 { erf_series(x) } else { x.signum() * (1.0 - erfc_cf(x.abs())) }
}

/// Complementary error function `1 - erf(x)`, accurate in the right tail.
#[must_use]
pub fn erfc(x: f64) -> f64 {
    if x >= 2.0 {
        erfc_cf(x)
    } else if x <= -2.0 {
        2.0 - erfc_cf(-x)
    } else {
        1.0 - erf_series(x)
    }
}

fn erf_series(x: f64) -> f64 {
    // erf x = 2/sqrt(pi) e^{-x^2} sum 2^n x^{2n+1} / (1*3*...*(2n+1)), all terms positive.
    let x2 = x * x;
    let mut term = x;
    let mut sum = x;
    let mut n = 0.0;
    while term.abs() > sum.abs() * 1e-17 {
        n += 1.0;
        term *= 2.0 * x2 / (2.0 * n + 1.0);
        sum += term;
    }
    2.0 / PI.sqrt() * (-x2).exp() * sum
}

fn erfc_cf(x: f64) -> f64 {
    // Continued fraction erfc x = e^{-x^2}/sqrt(pi) * 1/(x + 1/2/(x + 1/(x + 3/2/(x + ...)))),
    // evaluated backwards with a fixed depth ample for x >= 2.
    if x > 27.0 {
        return 0.0;
    }
    let mut f = x;
    for k in (1..200).rev() {
        f = x + f64::from(k) * 0.5 / f;
    }
    (-x * x).exp() / PI.sqrt() / f
}
