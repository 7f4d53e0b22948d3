//! twill-renderer: turning radiance into pictures.
//!
//! For now this crate holds [`export`]: tone mapping and the PNG/EXR writers used by every
//! command that produces an image. The wgpu pipeline (shell-mapped volume ray casting, SG single
//! scattering, SH multiple scattering, PCSS) joins it as one module per pass.

pub mod export;
