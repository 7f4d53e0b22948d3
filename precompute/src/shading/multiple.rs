//! Multiple scattering at render time (paper 5.3): `C_S[θo] · (R_ωo · A_C · c_light)`.
//!
//! How it works:
//! - [`light_sh`]: the light's radiance distribution in real SH (`sh.rs` basis, fabric space),
//!   bands `0..=order`. A directional light of irradiance E toward ω_d is `E δ(ω − ω_d)`, so
//!   `c_j = E Y_j(ω_d)`. A normalized SG light (axis ξ, sharpness λ, intensity I) is
//!   `c_lm = I · z_l(λ) · sqrt(4π/(2l+1)) · Y_lm(ξ)` with `z_l(λ)` the zonal coefficients of
//!   the normalized SG from `CgTable::lookup` (linear in ln λ between its samples, limits
//!   outside): the addition theorem rotates the zonal vector about +z to ξ exactly (equal to
//!   `ShRotation` of the zonal vector, tested).
//! - The renderer sums `V̄_glo · light_sh(light)` over lights (V̄_glo the light's blurred global
//!   visibility) into one `c_light` per segment.
//! - [`multiple_scattering_in_cell`]: `c_T = A_C c_light` **per channel**:
//!   `c_T[j1].ch = Σ_j0 A[j1·n + j0].ch · c_light[j0].ch` (the IIRTF's RGB entry multiplies the
//!   same channel of the light; `bake::iirtf` stores `matrix[j1 · n + j0] = a_C[j0, j1]`). Then
//!   each channel of c_T is rotated into the ωo-space of `bake::cs_table::OmegaOSpace::new(t,
//!   ωo)` with `ShEulerRotation::new(order, &world_to_local)` (three turns about z around two
//!   constant quarter turns about x, the GPU's algorithm) and dotted with the same channel of
//!   `CsTable::lookup(θo)` (linear in θo between its rows). A cell that holds no segment has a
//!   zero matrix (no paths were traced) and gives zero.
//! - [`multiple_scattering`] looks up the segment's tangent and material in a bake, and its
//!   transfer: given the shaded point, `c_T` is interpolated between the cells whose centres
//!   surround it (`CellGrid::interpolation`: trilinear, empty cells left out), so transfer
//!   varies smoothly through the fabric; without a point it is the constant of the segment's
//!   own cell (`CellGrid::cell_of_segment`), the paper's choice, which shows each cell as a
//!   flat block.
//! - [`forward_scattering`]: a bake with forward lobes (`BakeSettings::forward_lobe`) holds the
//!   forward-scattered light of the cells whose lobe is too sharp for the SH outside their
//!   matrices; it is added per light as an SG about the light's direction through Γ by
//!   quadrature (docs/MATH.md, "Forward lobes").

use std::f64::consts::PI;

use glam::DVec3;

use super::gamma::gamma_quadrature;
use super::{SegmentShading, ShadingError};
use crate::Rgb;
use crate::bake::cs_table::{CsTable, OmegaOSpace};
use crate::bake::iirtf::CellTransfer;
use crate::bake::pipeline::Baked;
use crate::bake::tables::CgTable;
use crate::pathtrace::Light;
use crate::sg::sg_mass;
use crate::sh::{ShEulerRotation, sh_count, sh_eval};

/// The SH coefficients (bands `0..=order`, fabric space) of a light's radiance; see the module
/// docs.
///
/// # Panics
/// If `order` is above `cg.order()` for an SG light.
#[must_use]
pub fn light_sh(light: &Light, order: usize, cg: &CgTable) -> Vec<Rgb> {
    let n = sh_count(order);
    let mut basis = vec![0.0; n];
    match *light {
        Light::Directional { to_light, irradiance } => {
            sh_eval(order, to_light, &mut basis);
            basis.iter().map(|&y| irradiance * y).collect()
        }
        Light::Sg { axis, sharpness, intensity } => {
            assert!(order <= cg.order(), "light_sh: order {order} is above the C_G table's {}", cg.order());
            sh_eval(order, axis, &mut basis);
            let zonal = cg.lookup(sharpness);
            let mut out = vec![Rgb::ZERO; n];
            for (l, z) in zonal.iter().enumerate().take(order + 1) {
                let scale = z * (4.0 * PI / (2 * l + 1) as f64).sqrt();
                for j in l * l..(l + 1) * (l + 1) {
                    out[j] = intensity * (scale * basis[j]);
                }
            }
            out
        }
    }
}

/// `C_S[θo] · (R_ωo · A_C · c_light)` per channel for a segment of unit tangent `t` in the
/// cell whose transfer is `transfer`, seen from unit `wo`; `cs` is the segment's material's
/// table. `c_light` holds `(L+1)²` coefficients, L = `cs.sh_order()`.
///
/// # Panics
/// If `c_light` or the transfer matrix do not match the table's SH order.
#[must_use]
pub fn multiple_scattering_in_cell(
    cs: &CsTable,
    transfer: &CellTransfer,
    t: DVec3,
    wo: DVec3,
    c_light: &[Rgb],
) -> Rgb {
    let n = sh_count(cs.sh_order());
    assert_eq!(c_light.len(), n, "multiple_scattering: c_light must have {n} coefficients");
    if transfer.paths == 0 {
        return Rgb::ZERO;
    }
    let mut transferred = vec![Rgb::ZERO; n];
    add_transferred(transfer, c_light, 1.0, &mut transferred);
    scatter_transferred(cs, &transferred, t, wo)
}

/// Adds `weight · A_C c_light` (per channel) to `sum`.
///
/// # Panics
/// If the transfer matrix does not match `c_light`'s length.
pub fn add_transferred(transfer: &CellTransfer, c_light: &[Rgb], weight: f64, sum: &mut [Rgb]) {
    let n = c_light.len();
    if transfer.is_empty() {
        return;
    }
    assert_eq!(transfer.matrix.len(), n * n, "multiple_scattering: transfer matrix order mismatch");
    for (j1, out) in sum.iter_mut().enumerate() {
        let value: Rgb = transfer.row(j1, n).zip(c_light).map(|(a, c)| a * *c).sum();
        *out += value * weight;
    }
}

/// `C_S[θo] · (R_ωo c_T)` per channel: the incoming radiance `transferred` (SH, fabric space)
/// scattered toward unit `wo` by a fiber of unit tangent `t` whose material's table is `cs`.
#[must_use]
pub fn scatter_transferred(cs: &CsTable, transferred: &[Rgb], t: DVec3, wo: DVec3) -> Rgb {
    let order = cs.sh_order();
    let n = sh_count(order);
    let space = OmegaOSpace::new(t, wo);
    let rotation = ShEulerRotation::new(order, &space.world_to_local);
    let c_s = cs.lookup(space.theta_o);
    let mut local = vec![0.0; n];
    let mut out = Rgb::ZERO;
    for ch in 0..3 {
        for (l, c) in local.iter_mut().zip(transferred) {
            *l = c[ch];
        }
        rotation.apply_in_place(&mut local);
        out[ch] = local.iter().zip(&c_s).map(|(x, s)| x * s[ch]).sum();
    }
    out
}

/// Multiple scattering of `segment` of `baked` at `position` (the shaded point in the
/// exemplar's coordinates; `None`: the segment's own cell, constant per cell) seen from unit
/// `wo` (fabric space) under the summed, visibility-scaled light SH `c_light`; see the module
/// docs. Zero-length segments give zero.
pub fn multiple_scattering(
    baked: &Baked,
    segment: u32,
    position: Option<DVec3>,
    wo: DVec3,
    c_light: &[Rgb],
) -> Result<Rgb, ShadingError> {
    let order = baked.transfer.iirtf.sh_order;
    let expected = sh_count(order);
    if c_light.len() != expected {
        return Err(ShadingError::ShLength { got: c_light.len(), expected, order });
    }
    let Some(seg) = SegmentShading::of(baked, segment)? else {
        return Ok(Rgb::ZERO);
    };
    let material = seg.fiber.material;
    let Some(Some(cs)) = baked.cs_tables.get(material) else {
        return Err(ShadingError::MissingCsTable { material });
    };
    let grid = &baked.transfer.cells;
    let cells = &baked.transfer.iirtf.cells;
    let own_cell = &cells[grid.cell_of_segment(segment) as usize];
    let around = position.map(|p| grid.interpolation(p)).filter(|w| w.iter().any(|e| e.1 > 0.0));
    let Some(around) = around else {
        return Ok(multiple_scattering_in_cell(cs, own_cell, seg.tangent, wo, c_light));
    };
    let mut transferred = vec![Rgb::ZERO; expected];
    for (cell, weight) in around {
        if weight > 0.0 {
            add_transferred(&cells[cell as usize], c_light, weight, &mut transferred);
        }
    }
    Ok(scatter_transferred(cs, &transferred, seg.tangent, wo))
}

/// The largest mean cosine a forward lobe is given (λ about 500): beyond it the paths' estimate
/// says "a delta", which a few hundred paths cannot tell from "very narrow".
pub const MAX_FORWARD_MEAN_COSINE: f64 = 0.999;

/// The sharpness of the SG a cell's forward-scattered light is shaded as, from its
/// `forward[0]` and `forward_cosine` (summed over channels): the mean cosine
/// `μ = Σ cosine / (√(4π) Σ forward[0])`, clamped to [0, [`MAX_FORWARD_MEAN_COSINE`]], to the
/// von Mises–Fisher concentration by Banerjee et al.'s estimate `μ(3 − μ²)/(1 − μ²)` (an SG
/// `exp(λ(ω·ξ − 1))` is a vMF lobe of concentration λ). No forward light gives 0.
#[must_use]
pub fn forward_sharpness(forward0: Rgb, forward_cosine: Rgb) -> f64 {
    let strength = forward0.element_sum() * (4.0 * PI).sqrt();
    if strength.is_nan() || strength <= 0.0 {
        return 0.0;
    }
    let mu = (forward_cosine.element_sum() / strength).clamp(0.0, MAX_FORWARD_MEAN_COSINE);
    mu * (3.0 - mu * mu) / (1.0 - mu * mu)
}

/// Forward-scattered light (`BakeSettings::forward_lobe`) of `segment` of `baked` at `position`
/// (as [`multiple_scattering`]: `None` the segment's own cell, else interpolated between cells)
/// seen from unit `wo`, under `lights` given as `(light, V̄_glo)`. Per light: the strength
/// `s = Σ_j F_j c_j` (per channel, clamped at zero; `c` the light's SH, [`light_sh`], so a
/// directional light of irradiance E gives `E F(ω_d)`) arrives as a normalized SG about the
/// light's axis, of the cell's sharpness λ_C ([`forward_sharpness`]; an SG light of sharpness
/// λ_l widens it to `λ_C λ_l / (λ_C + λ_l)`, the product of two vMF convolutions' usual
/// approximation), and is scattered toward ωo: `s · V̄_glo · Γ(axis, λ, ωo) / M(λ)`, Γ by
/// quadrature ([`gamma_quadrature`]: the lobes are broad, λ about 0.5–30, where the
/// closed form is off by up to 70%). Zero where no cell around the point holds a lobe.
pub fn forward_scattering(
    baked: &Baked,
    segment: u32,
    position: Option<DVec3>,
    wo: DVec3,
    lights: &[(Light, f64)],
) -> Result<Rgb, ShadingError> {
    let order = baked.transfer.iirtf.sh_order;
    let n = sh_count(order);
    let cells = &baked.transfer.iirtf.cells;
    let Some(seg) = SegmentShading::of(baked, segment)? else {
        return Ok(Rgb::ZERO);
    };
    let grid = &baked.transfer.cells;
    let own = (grid.cell_of_segment(segment), 1.0);
    let around = position.map(|p| grid.interpolation(p)).filter(|w| w.iter().any(|e| e.1 > 0.0));
    let mut forward = vec![Rgb::ZERO; n];
    let mut cosine = Rgb::ZERO;
    for (cell, weight) in around.map_or_else(|| vec![own], |a| a.to_vec()) {
        let cell = &cells[cell as usize];
        if weight > 0.0 && cell.has_forward_lobe() {
            for (sum, f) in forward.iter_mut().zip(&cell.forward) {
                *sum += glam::Vec3::from(*f).as_dvec3() * weight;
            }
            cosine += glam::Vec3::from(cell.forward_cosine).as_dvec3() * weight;
        }
    }
    if forward[0] == Rgb::ZERO {
        return Ok(Rgb::ZERO); // No cell around the point holds a lobe.
    }
    let lambda_cell = forward_sharpness(forward[0], cosine);
    let mut out = Rgb::ZERO;
    for (light, v_blurred) in lights {
        if *v_blurred == 0.0 {
            continue;
        }
        let c = light_sh(light, order, &baked.cg);
        let strength: Rgb = forward.iter().zip(&c).map(|(f, c)| *f * *c).sum::<Rgb>().max(Rgb::ZERO);
        if strength == Rgb::ZERO {
            continue;
        }
        let (axis, lambda) = match *light {
            Light::Directional { to_light, .. } => (to_light, lambda_cell),
            Light::Sg { axis, sharpness, .. } => {
                (axis, lambda_cell * sharpness / (lambda_cell + sharpness).max(f64::MIN_POSITIVE))
            }
        };
        let scattered =
            gamma_quadrature(&seg.fiber, &baked.gn, seg.tangent, axis, lambda, wo) / sg_mass(lambda);
        out += strength * scattered * *v_blurred;
    }
    Ok(out)
}
