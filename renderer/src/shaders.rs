//! WGSL sources, compiled into the binary. Shared modules (`shaders/shared/*.wgsl`) hold
//! functions only; a pass's shader is its own file concatenated after the shared modules it
//! uses (WGSL has no includes).

/// `erf_f32`, `erfc_f32`, `i0e_f32`: twins of `twill_precompute::special`.
pub const SPECIAL: &str = include_str!("../../shaders/shared/special.wgsl");

/// Every shared module, with its file name (for validation and error messages).
pub const SHARED: &[(&str, &str)] = &[("shared/special.wgsl", SPECIAL)];
