//! Single scattering per light (paper 5.2), for one segment seen from ωo.
//!
//! Local visibility is that of the visibility image of the point along the segment whose piece
//! holds the shaded position (`Baked::visibility_image`; the midpoint's without a position).
//!
//! - Directional light (to-light ω_d, irradiance E):
//!   `V_glo · V_k(ω_d) · S(ω_d, ωo) cos θ_d · E`, `V_k` the kept binary image's visible
//!   fraction toward ω_d (bilinear), else the hard step `H(d_k(ω_d))` of the PCA SSDF
//!   (`VisibilityData::visibility`).
//! - Normalized SG light (axis ξ, sharpness λ, intensity I; radiance `I G(ω; ξ, λ)/M(λ)`):
//!   `V_glo · I/M(λ) · [w_sos · SOS + w_ssdf · V_k(ξ, λ) Γ(ξ, λ, ωo)]` (SOS at the SGs'
//!   centroids and Fibonacci axes by `sos_centroid_share`), `V_k(ξ, λ)` the kept
//!   binary image's visible fraction toward ξ, else `½ erfc(−sqrt(λ/2) d_k(ξ))`
//!   (`VisibilityData::soft_visibility`), with
//!   `(w_sos, w_ssdf) = sg_path_weights(λ)` and SOS the sum-of-SGs path
//!   ([`super::visibility`]); a path whose weight is 0 is not evaluated.
//!
//! `V_glo ∈ [0, 1]` is the light's global (macro-scale) visibility at the point, from shadow
//! maps or shadow rays; it multiplies everything. Products with RGB are per channel.

use glam::DVec3;

use super::bcsdf::{FiberConstants, fiber_eval_cos};
use super::gamma::gamma;
use super::visibility::{sg_path_weights, sos_centroid_share, sum_of_sg_path};
use super::{SegmentShading, ShadingError};
use crate::Rgb;
use crate::bake::pipeline::{Baked, VisibilityData};
use crate::bake::tables::GnTable;
use crate::pathtrace::Light;
use crate::sg::sg_mass;

/// Directional-light single scattering of a segment (unit tangent `t`) with visibility image
/// `image` (`Baked::visibility_image`), see the module docs.
#[must_use]
pub fn single_scattering_directional(
    fiber: &FiberConstants,
    gn: &GnTable,
    visibility: &VisibilityData,
    image: usize,
    t: DVec3,
    wo: DVec3,
    to_light: DVec3,
    irradiance: Rgb,
    v_glo: f64,
) -> Rgb {
    let local = visibility.visibility(image, to_light);
    if local == 0.0 || v_glo == 0.0 {
        return Rgb::ZERO;
    }
    fiber_eval_cos(fiber, gn, t, to_light, wo) * irradiance * (v_glo * local)
}

/// SG-light single scattering of a segment (unit tangent `t`) with visibility image `image`
/// (`Baked::visibility_image`), see the module docs.
#[must_use]
pub fn single_scattering_sg(
    fiber: &FiberConstants,
    gn: &GnTable,
    visibility: &VisibilityData,
    image: usize,
    t: DVec3,
    wo: DVec3,
    axis: DVec3,
    sharpness: f64,
    intensity: Rgb,
    v_glo: f64,
) -> Rgb {
    if v_glo == 0.0 {
        return Rgb::ZERO;
    }
    let (w_sos, w_ssdf) = sg_path_weights(sharpness);
    let mut integral = Rgb::ZERO;
    if w_sos > 0.0 {
        let sos = &visibility.sum_of_sg;
        let centroid_share = sos_centroid_share(sharpness, sos.count);
        for (share, at_centroids) in [(centroid_share, true), (1.0 - centroid_share, false)] {
            if share > 0.0 {
                let axes = if at_centroids { sos.axes(image) } else { sos.fibonacci_axes(image) };
                let path = sum_of_sg_path(
                    fiber,
                    gn,
                    t,
                    wo,
                    &axes,
                    sos.weights(image),
                    sos.sharpness,
                    axis,
                    sharpness,
                );
                integral += path * (w_sos * share);
            }
        }
    }
    if w_ssdf > 0.0 {
        let soft = visibility.soft_visibility(image, axis, sharpness);
        if soft > 0.0 {
            integral += gamma(fiber, gn, t, axis, sharpness, wo) * (w_ssdf * soft);
        }
    }
    integral * intensity * (v_glo / sg_mass(sharpness))
}

/// Single scattering of `light` at `segment` of `baked` at `position` (exemplar coordinates;
/// `None`: with the midpoint's visibility), seen from unit `wo` (fabric space), with the
/// light's global visibility `v_glo`. Zero-length segments give zero.
pub fn single_scattering(
    baked: &Baked,
    segment: u32,
    position: Option<DVec3>,
    wo: DVec3,
    light: &Light,
    v_glo: f64,
) -> Result<Rgb, ShadingError> {
    let Some(seg) = SegmentShading::of(baked, segment)? else {
        return Ok(Rgb::ZERO);
    };
    let k = baked.visibility_image(segment as usize, seg.tangent, position);
    let (vis, gn, t) = (&baked.visibility, &baked.gn, seg.tangent);
    Ok(match *light {
        Light::Directional { to_light, irradiance } => {
            single_scattering_directional(&seg.fiber, gn, vis, k, t, wo, to_light, irradiance, v_glo)
        }
        Light::Sg { axis, sharpness, intensity } => {
            single_scattering_sg(&seg.fiber, gn, vis, k, t, wo, axis, sharpness, intensity, v_glo)
        }
    })
}
