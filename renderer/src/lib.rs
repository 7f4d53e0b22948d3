//! twill-renderer: the GPU renderer (paper section 5) and turning radiance into pictures.
//!
//! [`frame`] runs a frame's passes (shadow maps, visibility, blur, eye rays into a G-buffer,
//! deferred shading, tone map) as [`plan`] derives them from the scene, over the bake uploaded
//! by [`fabric_data`] and the tetrahedral shell of [`shell`]; the WGSL is in [`shaders`].
//! [`gpu`] opens a headless wgpu device (a GPU, or lavapipe without one), [`headless`] is the
//! glue for rendering a scene file without a window, [`export`] holds tone mapping and the
//! PNG/EXR writers, and [`accuracy`] measures the method against the path tracer (Fig. 13 and
//! the speed-up at equal error).

pub mod accuracy;
pub mod export;
pub mod fabric_data;
pub mod frame;
pub mod gpu;
pub mod headless;
pub mod passes;
pub mod plan;
pub mod shaders;
pub mod shell;
