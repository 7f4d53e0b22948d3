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
//! - [`hemisphere_light_sh`]: the light as the transfer takes it. The IIRTF counts light from
//!   the upper hemisphere only (`bake::iirtf::LightDomain`), so as a function of the light's
//!   direction its matrix is the projection of a function cut to zero at the horizon, and
//!   evaluated at a light's direction that truncated projection rings there: a raking light
//!   met a transfer far below zero (order 4, a light 11° above the horizon: −90% of the path
//!   tracer before the clamp at zero, docs/BENCHMARKS.md). Light from below never reaches it,
//!   so what counts is the expansion's values above the horizon: the light's SH of its part
//!   above the horizon are turned by [`UpperHemisphereFit`] into the weights that evaluate the
//!   least-squares fit of the transfer over the upper hemisphere (`crate::upper_fit`), exact
//!   for polynomial transfers of the order, scaled by the light's share above the horizon
//!   ([`sg_upper_fraction`] for an SG). Broad SG lobes (λ < 4) keep their plain SH, which
//!   average the ringing away ([`upper_fit_share`] blends the two up to λ = 40). Below SH
//!   order 4 ([`UPPER_FIT_MIN_ORDER`]) the light keeps its plain SH.
//! - The renderer sums `V̄_glo · hemisphere_light_sh(light)` over lights (V̄_glo the light's
//!   blurred global visibility) into one `c_light` per segment.
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
//! - [`lobe_scattering`]: a bake with fiber lobes (`BakeSettings::fiber_lobes`) holds the
//!   light of the cells whose forward light is too sharp for the SH as two lobes instead of
//!   their matrices: the forward chains and the light reflected at least once, each a strength
//!   over light directions (SH at `LOBE_SH_ORDER`) and a shape in the fiber frame
//!   ([`FiberLobe`]). Per light, each is scattered toward ωo by the shaded fiber in closed
//!   form ([`lobe_quadrature`]; docs/MATH.md, "Fiber lobes").

use std::f64::consts::PI;

use glam::DVec3;

use super::gamma::{LobeAngles, lobe_quadrature};
use super::{SegmentShading, ShadingError};
use crate::Rgb;
use crate::bake::cs_table::{CsTable, OmegaOSpace};
use crate::bake::iirtf::{
    CellTransfer, LOBE_AZIMUTH_TERMS, LOBE_AZIMUTH_TOTALS, LOBE_CHANNEL_SHAPE_LEN, LOBE_FOURIER_TERMS,
    LOBE_LONGITUDINAL_AT, LOBE_LONGITUDINAL_TOTALS, LOBE_SH_ORDER, LOBE_SHAPE_LEN, elevation_hats,
    fiber_elevation, longitudinal_hats, toward_up,
};
use crate::bake::pipeline::Baked;
use crate::bake::tables::CgTable;
use crate::pathtrace::Light;
use crate::sg::{sg_mean_resultant, sg_upper_fraction, sg_upper_moment};
use crate::sh::{ShEulerRotation, sh_count, sh_eval};
use crate::upper_fit::{UPPER_FIT_MIN_ORDER, UpperHemisphereFit};

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

/// The light's SH as the transfer takes it ([`multiple_scattering`], [`lobe_scattering`]): the
/// light's SH ([`light_sh`]) turned by [`UpperHemisphereFit`] into the weights that evaluate
/// the transfer's least-squares fit over the upper hemisphere, scaled by the light's share
/// above the horizon (1 or 0 for a directional light, [`sg_upper_fraction`] for an SG), and
/// blended with the plain SH by [`upper_fit_share`]: broad SG lobes average the plain
/// projection's ringing away, and their part below the horizon, which the transfer drops,
/// would meet the fit's polynomial continued below it. Below [`UPPER_FIT_MIN_ORDER`] the plain
/// SH.
///
/// # Panics
/// As [`light_sh`], and for an order above `upper_fit::UPPER_FIT_MAX_ORDER`.
#[must_use]
pub fn hemisphere_light_sh(light: &Light, order: usize, cg: &CgTable) -> Vec<Rgb> {
    if order < UPPER_FIT_MIN_ORDER {
        return light_sh(light, order, cg);
    }
    let (share, upper) = match *light {
        Light::Directional { to_light, .. } => {
            if to_light.z <= 0.0 {
                return vec![Rgb::ZERO; sh_count(order)];
            }
            (1.0, 1.0)
        }
        Light::Sg { axis, sharpness, .. } => {
            (upper_fit_share(sharpness), sg_upper_fraction(axis.z, sharpness))
        }
    };
    let mut c = light_sh(light, order, cg);
    if share > 0.0 {
        let mut fitted = c.clone();
        UpperHemisphereFit::of_order(order).apply(&mut fitted);
        for (c, f) in c.iter_mut().zip(fitted) {
            *c += (f * upper - *c) * share;
        }
    }
    c
}

/// How much of an SG light of sharpness λ takes the upper-hemisphere fit in
/// [`hemisphere_light_sh`]: none below λ = 4, all above λ = 40, a smoothstep in ln λ between.
#[must_use]
pub fn upper_fit_share(sharpness: f64) -> f64 {
    let t = ((sharpness.max(1e-30) / 4.0).ln() / 10f64.ln()).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The light SH the transfer takes in `baked` (bands `0..=` its order): the sum over `lights`
/// of `V̄ · hemisphere_light_sh(light)`, V̄ each light's blurred global visibility (lights with
/// V̄ = 0 skipped).
pub fn transfer_light_sh<'a>(baked: &Baked, lights: impl IntoIterator<Item = (&'a Light, f64)>) -> Vec<Rgb> {
    let order = baked.transfer.iirtf.sh_order;
    let mut c_light = vec![Rgb::ZERO; sh_count(order)];
    for (light, v_blurred) in lights {
        if v_blurred != 0.0 {
            for (sum, c) in c_light.iter_mut().zip(hemisphere_light_sh(light, order, &baked.cg)) {
                *sum += c * v_blurred;
            }
        }
    }
    c_light
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
    let cs = seg.cs_table(baked)?;
    if let Some(own) = segment_transfer(baked, segment) {
        return Ok(multiple_scattering_in_cell(cs, own, seg.tangent, wo, c_light));
    }
    let grid = &baked.transfer.cells;
    let cells = &baked.transfer.iirtf.cells;
    let own_cell = &cells[grid.cell_of_segment(segment) as usize];
    let around = position
        .map(|p| grid.interpolation(baked.transfer_point(segment as usize, p)))
        .filter(|w| w.iter().any(|e| e.1 > 0.0));
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

/// The transfer `segment` is shaded with instead of the cells around it: its segment cell's
/// (`bake::cells`), where the bake has one for it (`BakeSettings::segment_transfer_paths`, a
/// segment an eye sees). Where the segment's lattice cell keeps no fiber lobes that carry light
/// ([`CellTransfer::keeps_lobe_light`]) the segment cell holds all of the segment's light and
/// the segment takes no lobes; where it keeps them, the segment cell holds the light reflected
/// at least once (`iirtf::MatrixLight::Reflected`, baked only where the fabric's reflected
/// light fits matrices, `iirtf::reflected_light_fits_matrices`) and the forward chains come
/// from the lattice cells' forward lobes ([`lobe_scattering`]).
#[must_use]
pub fn segment_transfer(baked: &Baked, segment: u32) -> Option<&CellTransfer> {
    let grid = &baked.transfer.cells;
    let transfer = baked.transfer.iirtf.cells.get(grid.segment_cell(segment)? as usize)?;
    (transfer.paths > 0).then_some(transfer)
}

/// Which of the lattice cells' fiber lobes shade `segment` ([`lobe_scattering`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LobesTaken {
    /// Both, from the cells around the point (a segment without a transfer of its own).
    Both,
    /// The forward lobes alone (a segment whose own transfer holds its reflected light), from
    /// the cells around the point that keep lobes, their weights renormalized: the cells
    /// without lobes hold their forward chains in matrices the segment does not read.
    ForwardOnly,
}

impl LobesTaken {
    fn of(baked: &Baked, segment: u32) -> Option<Self> {
        if segment_transfer(baked, segment).is_none() {
            return Some(Self::Both);
        }
        let grid = &baked.transfer.cells;
        let own = baked.transfer.iirtf.cells.get(grid.cell_of_segment(segment) as usize)?;
        own.keeps_lobe_light().then_some(Self::ForwardOnly)
    }
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

/// Below this `1 − (ξ·t)²` (the light within about 13° of the fiber's axis) a lobe's
/// azimuthal terms fade linearly to zero ([`FiberLobe::angles`]): a light along the fiber
/// has no azimuth about it, and the model stays continuous where φ' stops being defined.
pub const AZIMUTH_FADE_ACROSS: f64 = 0.05;

/// One fiber lobe (`CellTransfer::forward` and `forward_shape`, or `reflected` and
/// `reflected_shape`) summed over the cells around a point with their interpolation weights.
/// A shape's node sums and node totals are sums over the same connections, so each node's
/// weighted sums over its weighted total are the interpolated lobe's means at that node. Each
/// colour channel has its own shape, and is shaded with it ([`lobe_scattering`]).
#[derive(Debug, Clone, PartialEq)]
pub struct FiberLobe {
    /// SH over light directions at [`LOBE_SH_ORDER`], RGB.
    pub strength: Vec<Rgb>,
    /// [`LOBE_SHAPE_LEN`] sums (`CellTransfer::forward_shape`'s layout: a
    /// [`LOBE_CHANNEL_SHAPE_LEN`] shape per colour channel).
    pub shape: Vec<f64>,
}

impl Default for FiberLobe {
    fn default() -> Self {
        Self { strength: vec![Rgb::ZERO; sh_count(LOBE_SH_ORDER)], shape: vec![0.0; LOBE_SHAPE_LEN] }
    }
}

impl FiberLobe {
    /// Adds `weight ×` a cell's lobe.
    pub fn add(&mut self, strength: &[[f32; 3]], shape: &[f32], weight: f64) {
        for (sum, f) in self.strength.iter_mut().zip(strength) {
            *sum += glam::Vec3::from(*f).as_dvec3() * weight;
        }
        for (sum, v) in self.shape.iter_mut().zip(shape) {
            *sum += f64::from(*v) * weight;
        }
    }

    /// `s = Σ_j strength_j c_j` per channel for a light's SH `c` at [`LOBE_SH_ORDER`]
    /// ([`light_sh`]: a directional light of irradiance E gives E F(ω_d)), signed as the SH
    /// transfer's samples are: only a pixel's mean is clamped at zero (`shading::render`).
    /// The strength is an order-6 expansion estimated from each cell's paths, and where a
    /// light's true strength is small its noise is as often below zero as above: clamped here,
    /// every cell's noise added light. On the silk satin at draft (96 paths per cell) that
    /// held multiple scattering's median over the 100 configurations of `twill accuracy` at
    /// +5.7% (+0.4% at 960 paths), its worst configuration +75% (CPU method); signed, −1.7%
    /// and +30% (docs/BENCHMARKS.md, "The lobes' strength, signed").
    #[must_use]
    pub fn strength_for(&self, c_light: &[Rgb]) -> Rgb {
        self.strength.iter().zip(c_light).map(|(f, c)| *f * *c).sum::<Rgb>()
    }

    /// The azimuthal means `[E cos Δφ, E sin Δφ (toward up), …]` of colour channel `channel`
    /// for a light at elevation `z` about the fiber ([`fiber_elevation`]):
    /// each elevation node's sums over its total, interpolated between the two nodes around
    /// `z` ([`elevation_hats`]); a node without weight counts as uniform (means 0).
    #[must_use]
    pub fn azimuth_means(&self, channel: usize, z: f64) -> Vec<f64> {
        self.node_means(channel, elevation_hats(z), LOBE_AZIMUTH_TOTALS, 0, 2 * LOBE_AZIMUTH_TERMS)
    }

    /// The longitudinal means `[E cos Δθ, E sin Δθ, …]` of colour channel `channel` for a light
    /// of `ω0·t = along` at the fiber: as [`Self::azimuth_means`], over the nodes of the light's angle to the fiber
    /// ([`longitudinal_hats`]).
    #[must_use]
    pub fn longitudinal_means(&self, channel: usize, along: f64) -> Vec<f64> {
        self.node_means(
            channel,
            longitudinal_hats(along),
            LOBE_LONGITUDINAL_TOTALS,
            LOBE_LONGITUDINAL_AT,
            2 * LOBE_FOURIER_TERMS,
        )
    }

    /// Each of the two nodes `hats` its `terms` sums (from `sums_at`, node after node, in
    /// `channel`'s shape) over its total (at `totals_at`), weighted by its hat; a node without
    /// weight counts as uniform.
    fn node_means(
        &self,
        channel: usize,
        hats: [(usize, f64); 2],
        totals_at: usize,
        sums_at: usize,
        terms: usize,
    ) -> Vec<f64> {
        let mut out = vec![0.0; terms];
        let shape = &self.shape[channel * LOBE_CHANNEL_SHAPE_LEN..(channel + 1) * LOBE_CHANNEL_SHAPE_LEN];
        for (node, hat) in hats {
            let total = shape[totals_at + node];
            if total > 0.0 && hat > 0.0 {
                let sums = &shape[sums_at + node * terms..sums_at + (node + 1) * terms];
                for (o, v) in out.iter_mut().zip(sums) {
                    *o += hat * v / total;
                }
            }
        }
        out
    }

    /// Where colour channel `channel` of the lobe's light arrives from for `light` at a fiber of
    /// unit tangent `t`: the axis
    /// ξ its angles are measured from (the light's direction) and their densities
    /// ([`LobeAngles`], both series smoothed by [`LobeAngles::from_means`]), or `None` for a
    /// lobe without light in that channel. The longitudinal means are taken per light angle to the fiber
    /// ([`Self::longitudinal_means`]), the azimuthal ones per light elevation about the fiber
    /// ([`Self::azimuth_means`] of [`fiber_elevation`]). The azimuth's odd terms were kept in the sense toward the
    /// fabric's top ([`toward_up`]), so they turn with `toward_up(t, ξ)` here; all of its terms
    /// fade out within [`AZIMUTH_FADE_ACROSS`] of a light along the fiber. An SG light of sharpness λ widens
    /// both densities by its own spread, exactly for a von Mises–like lobe: its longitudinal
    /// variance 1/λ multiplies the longitudinal terms by `exp(−k²/2λ)`, and its azimuthal
    /// concentration about t, `κ_l = λ (1 − (ξ·t)²)`, multiplies the azimuthal ones by
    /// `I_k(κ_l)/I_0(κ_l)`.
    #[must_use]
    pub fn angles(&self, light: &Light, t: DVec3, channel: usize) -> Option<(DVec3, LobeAngles)> {
        let total = self.strength[0][channel];
        if total.is_nan() || total <= 0.0 {
            return None;
        }
        let (axis, sharpness) = match *light {
            Light::Directional { to_light, .. } => (to_light, None),
            Light::Sg { axis, sharpness, .. } => {
                let (axis, sharpness) = sg_above_horizon(axis, sharpness);
                (axis, Some(sharpness))
            }
        };
        let across = (1.0 - axis.dot(t).powi(2)).max(0.0);
        let longitudinal = self.longitudinal_means(channel, axis.dot(t));
        let means = self.azimuth_means(channel, fiber_elevation(t, axis));
        let fade = (across / AZIMUTH_FADE_ACROSS).min(1.0);
        let odd = toward_up(t, axis);
        let azimuth: Vec<f64> =
            means.chunks_exact(2).flat_map(|pair| [pair[0] * fade, pair[1] * fade * odd]).collect();
        let LobeAngles { mut fourier, mut azimuth } = LobeAngles::from_means(&longitudinal, &azimuth);
        if let Some(sharpness) = sharpness {
            for (k, term) in fourier.chunks_exact_mut(2).enumerate() {
                let damping = (-((k + 1) as f64).powi(2) / (2.0 * sharpness)).exp();
                term[0] *= damping;
                term[1] *= damping;
            }
            let mut ratios = [0.0; LOBE_AZIMUTH_TERMS];
            crate::special::bessel_i_ratios(sharpness * across, &mut ratios);
            for (term, rho) in azimuth.chunks_exact_mut(2).zip(ratios) {
                term[0] *= rho;
                term[1] *= rho;
            }
        }
        debug_assert_eq!(fourier.len(), 2 * LOBE_FOURIER_TERMS);
        Some((axis, LobeAngles { fourier, azimuth }))
    }
}

/// The SG that stands for the part of an SG light (unit `axis`, `sharpness`) above the
/// fabric's horizon, as `(axis, sharpness)`: its axis the mean direction of that part
/// ([`sg_upper_moment`]), its sharpness the von Mises–Fisher one of the same mean resultant
/// length R ([`vmf_sharpness`]). Light from below the horizon never reaches the transfer, so a
/// broad SG low in the sky reaches the fibers from higher up than its axis, and narrower than
/// itself: its forward chains fan out about that higher direction (a backlit eye near the
/// horizon sees less of them). A light wholly above the horizon keeps its axis and sharpness.
/// A light with less than [`ABOVE_HORIZON_SHARES`]`.0` of its power above the horizon keeps
/// both too, and between the two shares the SG moves to the one above by a smoothstep in the
/// share: such a light's lobes hold next to nothing (its strength is the share's), and below
/// the horizon its moment is the difference of two nearly equal ones (the whole SG's and its
/// mirror's), which f32 (the WGSL twin) cannot take. Twin: `sg_above_horizon_f32`
/// (`shaders/shared/sg.wgsl`).
#[must_use]
pub fn sg_above_horizon(axis: DVec3, sharpness: f64) -> (DVec3, f64) {
    let (share, moment) = sg_upper_moment(axis, sharpness);
    let (lo, hi) = ABOVE_HORIZON_SHARES;
    let x = ((share - lo) / (hi - lo)).clamp(0.0, 1.0);
    let weight = x * x * (3.0 - 2.0 * x);
    let length = moment.length();
    if weight == 0.0 || length < 1e-12 {
        return (axis, sharpness);
    }
    let (above, above_sharpness) = (moment / length, vmf_sharpness(length / share));
    ((axis + weight * (above - axis)).normalize(), sharpness + weight * (above_sharpness - sharpness))
}

/// The shares of an SG light's power above the horizon between which [`sg_above_horizon`]
/// moves from the light's own SG to the one above the horizon.
pub const ABOVE_HORIZON_SHARES: (f64, f64) = (1e-3, 1e-2);

/// The sharpness λ of the von Mises–Fisher density with mean resultant length `r`
/// (the inverse of [`sg_mean_resultant`]): Banerjee et al.'s `R (3 − R²) / (1 − R²)` (about
/// λ + ½ for sharp lobes), then, below λ = 100, three Newton steps on `A(λ) = R` (within
/// 1e-9 after them). `r` is clamped to [1e-9, 1 − 1e-12].
#[must_use]
pub fn vmf_sharpness(r: f64) -> f64 {
    let r = r.clamp(1e-9, 1.0 - 1e-12);
    let mut lambda = r * (3.0 - r * r) / (1.0 - r * r);
    if lambda < VMF_NEWTON_BELOW {
        for _ in 0..3 {
            lambda = (lambda + (r - sg_mean_resultant(lambda)) / sg_mean_resultant_slope(lambda)).max(1e-9);
        }
    }
    lambda
}

/// Below this first guess [`vmf_sharpness`] refines it (above, the guess is within ½%, and the
/// f32 twin's `1 − A(λ)` has too few digits for Newton).
pub const VMF_NEWTON_BELOW: f64 = 100.0;

/// `A′(λ) = 1/λ² − 1/sinh² λ`, by its series `1/3 − λ²/15 + 2λ⁴/189` below λ = 0.05.
fn sg_mean_resultant_slope(lambda: f64) -> f64 {
    if lambda < 0.05 {
        let l2 = lambda * lambda;
        1.0 / 3.0 - l2 / 15.0 + 2.0 * l2 * l2 / 189.0
    } else {
        // 1/sinh² λ = 4 e^{−2λ} / expm1(−2λ)².
        let e = (-2.0 * lambda).exp_m1();
        1.0 / (lambda * lambda) - 4.0 * (-2.0 * lambda).exp() / (e * e)
    }
}

/// The fiber lobes (`BakeSettings::fiber_lobes`) of `segment` of `baked` at `position` (as
/// [`multiple_scattering`]: `None` the segment's own cell, else interpolated between cells),
/// seen from unit `wo`, under `lights` given as `(light, V̄_glo)`: per light and lobe
/// ([`FiberLobe`]: forward chains, then reflected light), `s · V̄_glo · ∫ L S cos θi dωi` with s
/// the lobe's strength for the light and L its unit shape ([`FiberLobe::angles`],
/// [`lobe_quadrature`]), per colour channel with that channel's shape. Zero where no cell around the point holds lobes.
pub fn lobe_scattering(
    baked: &Baked,
    segment: u32,
    position: Option<DVec3>,
    wo: DVec3,
    lights: &[(Light, f64)],
) -> Result<Rgb, ShadingError> {
    let Some(seg) = SegmentShading::of(baked, segment)? else {
        return Ok(Rgb::ZERO);
    };
    let Some((forward, reflected)) = lobes_around(baked, segment, position) else {
        return Ok(Rgb::ZERO);
    };
    let mut out = Rgb::ZERO;
    for (light, v_blurred) in lights {
        if *v_blurred == 0.0 {
            continue;
        }
        let c = hemisphere_light_sh(light, LOBE_SH_ORDER, &baked.cg);
        for lobe in [&forward, &reflected] {
            let strength = lobe.strength_for(&c);
            if strength == Rgb::ZERO {
                continue;
            }
            for channel in 0..3 {
                if strength[channel] == 0.0 {
                    continue;
                }
                if let Some((axis, angles)) = lobe.angles(light, seg.tangent, channel) {
                    let scattered = lobe_quadrature(&seg.fiber, &baked.gn, seg.tangent, axis, &angles, wo);
                    out[channel] += strength[channel] * scattered[channel] * *v_blurred;
                }
            }
        }
    }
    Ok(out)
}

/// The fiber lobes that shade `segment` of `baked` at `position` ([`lobe_scattering`]): the
/// forward and the reflected [`FiberLobe`] summed over the cells around the point with their
/// interpolation weights (`None` for `position`: the segment's own cell). The reflected lobe is
/// empty where the segment's own transfer holds its reflected light ([`LobesTaken`]). `None`
/// where no cell around the point holds lobes.
#[must_use]
fn lobes_around(baked: &Baked, segment: u32, position: Option<DVec3>) -> Option<(FiberLobe, FiberLobe)> {
    let cells = &baked.transfer.iirtf.cells;
    let taken = LobesTaken::of(baked, segment)?;
    let grid = &baked.transfer.cells;
    let own = (grid.cell_of_segment(segment), 1.0);
    let around = position
        .map(|p| grid.interpolation(baked.transfer_point(segment as usize, p)))
        .filter(|w| w.iter().any(|e| e.1 > 0.0));
    let mut around = around.map_or_else(|| vec![own], |a| a.to_vec());
    around.retain(|&(cell, weight)| weight > 0.0 && cells[cell as usize].has_lobes());
    let lobed: f64 = around.iter().map(|e| e.1).sum();
    if lobed <= 0.0 {
        return None;
    }
    let scale = if taken == LobesTaken::ForwardOnly { 1.0 / lobed } else { 1.0 };
    let (mut forward, mut reflected) = (FiberLobe::default(), FiberLobe::default());
    for (cell, weight) in around {
        let cell = &cells[cell as usize];
        forward.add(&cell.forward, &cell.forward_shape, weight * scale);
        if taken == LobesTaken::Both {
            reflected.add(&cell.reflected, &cell.reflected_shape, weight);
        }
    }
    Some((forward, reflected))
}
