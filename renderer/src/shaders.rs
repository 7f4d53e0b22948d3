//! WGSL sources, compiled into the binary. Shared modules (`shaders/shared/*.wgsl`) hold
//! functions only; a pass's shader is its own file concatenated after the shared modules it
//! uses (WGSL has no includes).

/// `erf_f32`, `erfc_f32`, `i0e_f32`: twins of `twill_precompute::special`.
pub const SPECIAL: &str = include_str!("../../shaders/shared/special.wgsl");

/// `expm1_f32`, `sg_mass_f32`, `sg_azimuthal_average_f32`: twins of `twill_precompute::special`
/// and `twill_precompute::sg`. Needs [`SPECIAL`] before it.
pub const SG: &str = include_str!("../../shaders/shared/sg.wgsl");

/// The baked fabric's bind group 1 (`FabricHeader`, `ExemplarGpu`, ..., `voxel_segment`):
/// twin of `crate::fabric_data`.
pub const FABRIC_DATA: &str = include_str!("../../shaders/shared/fabric_data.wgsl");

/// Render-time shading from bake data (Γ, SSDF, sum-of-SGs, light SH, IIRTF): twins of
/// `twill_precompute::shading`. Needs every module before it.
pub const SHADING: &str = include_str!("../../shaders/shared/shading.wgsl");

/// Eye rays through the shell into the G-buffer (paper 5.1).
pub const GBUFFER: &str = include_str!("../../shaders/gbuffer.wgsl");
/// Shadow maps and the top-surface position texture.
pub const SHELL_SURFACE: &str = include_str!("../../shaders/shell_surface.wgsl");
/// Shell-space visibility by PCF / PCSS.
pub const VISIBILITY: &str = include_str!("../../shaders/visibility.wgsl");
/// Separable Gaussian blur of the visibility by sigma_glo.
pub const BLUR: &str = include_str!("../../shaders/blur.wgsl");
/// Deferred shading: single and multiple scattering per pixel.
pub const SHADE: &str = include_str!("../../shaders/shade.wgsl");
/// The light arriving in every IIRTF cell, once per frame (flat shells without shadow maps).
pub const TRANSFER: &str = include_str!("../../shaders/transfer.wgsl");
/// Exposure, tone curve and sRGB encoding.
pub const TONEMAP: &str = include_str!("../../shaders/tonemap.wgsl");
/// `sh_eval_f32`, `sh_rotate_f32`, `sh_zonal_rotated_f32`: real spherical harmonics up to order
/// 6, twins of `twill_precompute::sh` (`sh_eval`, `ShRotation`). Needs no other module.
pub const SH: &str = include_str!("../../shaders/shared/sh.wgsl");

/// Every shared module, with its file name (for validation and error messages), in an order
/// where each needs only those before it.
pub const SHARED: &[(&str, &str)] = &[
    ("shared/special.wgsl", SPECIAL),
    ("shared/sg.wgsl", SG),
    ("shared/sh.wgsl", SH),
    ("shared/fabric_data.wgsl", FABRIC_DATA),
    ("shared/shading.wgsl", SHADING),
];

/// The shared modules concatenated in dependency order (what a pass shader is appended to).
#[must_use]
pub fn shared_library() -> String {
    SHARED.iter().map(|(_, source)| *source).collect::<Vec<_>>().join("\n")
}
