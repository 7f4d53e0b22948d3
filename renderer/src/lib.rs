//! twill-renderer: turning radiance into pictures.
//!
//! [`export`] holds tone mapping and the PNG/EXR writers used by every command that produces
//! an image. [`gpu`] opens a headless wgpu device (a GPU, or lavapipe without one) and runs
//! compute kernels; [`shaders`] holds the WGSL sources. The wgpu pipeline (shell-mapped volume
//! ray casting, SG single scattering, SH multiple scattering, PCSS) joins it as one module per
//! pass.

pub mod export;
pub mod fabric_data;
pub mod frame;
pub mod gpu;
pub mod headless;
pub mod plan;
pub mod shaders;
pub mod shell;
