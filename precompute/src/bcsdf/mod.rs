//! Fiber scattering (in progress: the model itself lands with the BCSDF work).

use crate::Rgb;

/// Parameters of the two-lobe R + TT fiber scattering model (Khungurn et al. 2015, as
/// reconstructed in `docs/MATH.md`), as a user writes them: angles in degrees.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FiberParams {
    /// Reflectance at normal incidence of the R lobe (Schlick F0), per channel in [0, 1].
    pub c_r: Rgb,
    /// Longitudinal width of the R lobe, degrees.
    pub beta_r_deg: f64,
    /// Transmission colour of the TT lobe, per channel in [0, 1].
    pub c_tt: Rgb,
    /// Longitudinal width of the TT lobe, degrees.
    pub beta_tt_deg: f64,
    /// Azimuthal width of the TT lobe, degrees.
    pub gamma_tt_deg: f64,
}

/// A fiber material as a scene file names it.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "model", rename_all = "lowercase", deny_unknown_fields)]
pub enum MaterialDesc {
    /// The R + TT fiber scattering model.
    Fiber(FiberParams),
    /// A Lambertian fiber surface shaded with the exact cylinder hit normal (for checking light
    /// transport against independent renderers).
    Lambert { albedo: Rgb },
}
