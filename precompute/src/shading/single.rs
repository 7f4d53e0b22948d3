//! Single scattering per light (paper 5.2), for one segment seen from ωo.
//!
//! Local visibility is that of the visibility image of the point along the segment whose piece
//! holds the shaded position (`Baked::visibility_image`; the midpoint's without a position).
//!
//! - Directional light (to-light ω_d, irradiance E):
//!   `V_glo · V_k(ω_d) · S(ω_d, ωo) cos θ_d · E`, `V_k` the image's pixel when the bake kept
//!   the binary images, else the hard step of the PCA SSDF (`VisibilityData::visible`).
//! - Normalized SG light (axis ξ, sharpness λ, intensity I; radiance `I G(ω; ξ, λ)/M(λ)`):
//!   `V_glo · I/M(λ) · [w_sos · SOS + w_ssdf · ½ erfc(−sqrt(λ/2) d_k(ξ)) Γ(ξ, λ, ωo)]`, `d_k`
//!   the PCA SSDF with the kept binary image's sign (`VisibilityData::distance`), with
//!   `(w_sos, w_ssdf) = sg_path_weights(λ)` and SOS the sum-of-SGs path
//!   ([`super::visibility`]); a path whose weight is 0 is not evaluated.
//!
//! `V_glo ∈ [0, 1]` is the light's global (macro-scale) visibility at the point, from shadow
//! maps or shadow rays; it multiplies everything. Products with RGB are per channel.

use glam::DVec3;

use super::bcsdf::{FiberConstants, fiber_eval_cos};
use super::gamma::gamma;
use super::visibility::{erf_soft_visibility, sg_path_weights, sum_of_sg_path};
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
    if v_glo == 0.0 || !visibility.visible(image, to_light) {
        return Rgb::ZERO;
    }
    fiber_eval_cos(fiber, gn, t, to_light, wo) * irradiance * v_glo
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
        let path = sum_of_sg_path(
            fiber,
            gn,
            t,
            wo,
            &sos.axes(image),
            sos.weights(image),
            sos.sharpness,
            axis,
            sharpness,
        );
        integral += path * w_sos;
    }
    if w_ssdf > 0.0 {
        let soft = erf_soft_visibility(visibility.distance(image, axis), sharpness);
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
