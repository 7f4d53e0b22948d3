//! WGSL sources, compiled into the binary. Shared modules (`shaders/shared/*.wgsl`) hold
//! functions only; a pass's shader is its own file concatenated after the shared modules it
//! uses (WGSL has no includes).

/// `erf_f32`, `erfc_f32`, `i0e_f32`: twins of `twill_precompute::special`.
pub const SPECIAL: &str = include_str!("../../shaders/shared/special.wgsl");

/// `expm1_f32`, `sg_mass_f32`, `sg_azimuthal_average_f32`: twins of `twill_precompute::special`
/// and `twill_precompute::sg`. Needs [`SPECIAL`] before it.
pub const SG: &str = include_str!("../../shaders/shared/sg.wgsl");

/// `sh_eval_f32`, `sh_rotate_f32`, `sh_zonal_rotated_f32`: real spherical harmonics up to order
/// 6, twins of `twill_precompute::sh` (`sh_eval`, `ShRotation`). Needs no other module.
pub const SH: &str = include_str!("../../shaders/shared/sh.wgsl");

/// Every shared module, with its file name (for validation and error messages), in an order
/// where each needs only those before it.
pub const SHARED: &[(&str, &str)] =
    &[("shared/special.wgsl", SPECIAL), ("shared/sg.wgsl", SG), ("shared/sh.wgsl", SH)];

/// The shared modules concatenated in dependency order (what a pass shader is appended to).
#[must_use]
pub fn shared_library() -> String {
    SHARED.iter().map(|(_, source)| *source).collect::<Vec<_>>().join("\n")
}
