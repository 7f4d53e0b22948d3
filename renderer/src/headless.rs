//! Rendering a scene without a window: the glue `twill render`, the tests and the benchmarks
//! share.
//!
//! How it works: [`shell_for_scene`] turns the scene's `[mesh]` section into a shell whose
//! depth spans the baked fabric's slab (the flat swatch of `[swatch]` when no mesh is given,
//! placed so that world and flat-fabric coordinates coincide, as in the path tracer);
//! [`frame_settings`] reads the scene's `[render]` and `[gpu]` sections; [`SceneRenderer`] opens
//! a headless device, uploads the bake and the shell, and renders frames.

use std::path::Path;

use twill_precompute::bake::pattern::PatternMap;
use twill_precompute::bake::pipeline::Baked;
use twill_precompute::scene::{MeshSection, Scene};

use crate::fabric_data::{FabricData, FabricDataError};
use crate::frame::{Frame, FrameSettings, RenderError, Renderer};
use crate::gpu::{Gpu, GpuError};
use crate::plan::Components;
use crate::shell::fibers::{FiberMapError, map_fabric};
use crate::shell::{BaseMesh, Shell, ShellError, ShellSpec};
use twill_precompute::raycast::pattern::PatternedFibers;
use twill_precompute::raycast::{Extent, FiberScene};
use twill_precompute::scene::GROUND_GAP_CM;

/// Why a scene could not be rendered headless.
#[derive(Debug, thiserror::Error)]
pub enum HeadlessError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error(transparent)]
    Fabric(#[from] FabricDataError),
    #[error(transparent)]
    Shell(#[from] ShellError),
    #[error(transparent)]
    Render(#[from] RenderError),
    #[error("[mesh]: the fabric on the mesh: {0}")]
    FiberMap(#[from] FiberMapError),
    #[error("[mesh]: the fabric on the mesh: {0}")]
    Fibers(#[from] twill_precompute::raycast::SceneError),
}

/// The shell of a scene's `[mesh]` (default: the flat swatch) around a fabric slab.
pub fn shell_for_scene(scene: &Scene, z_range: [f32; 2]) -> Result<Shell, ShellError> {
    shell_for_mesh(&scene.mesh, scene.swatch.size_cm, &scene.base_dir, z_range)
}

/// Puts the scene's path tracer on its `[mesh]`, when it has one: the fabric's fibers (every
/// exemplar of patterned cloth, block by block) carried through the shell the GPU renders
/// (`shell::fibers`, grown around the fibers' own slab) replace the flat swatch in
/// `scene.path_scene`, and the ground plane, if any, goes under the lowest of them. Returns
/// whether it did (a scene without `[mesh]` is the flat swatch, as the path tracer has it).
///
/// # Errors
/// A mesh that does not load or grow a shell, or that covers more fabric than the path tracer
/// takes ([`crate::shell::fibers::MAX_MAPPED_SEGMENTS`]).
pub fn trace_on_mesh(scene: &mut Scene) -> Result<bool, HeadlessError> {
    if !scene.mesh.names_a_surface() {
        return Ok(false);
    }
    let path_scene = &scene.path_scene;
    let (z0, z1) =
        path_scene.pattern.as_ref().map_or_else(|| path_scene.fibers.slab(), PatternedFibers::slab);
    let shell = shell_for_scene(scene, [z0, z1])?;
    let on_mesh = map_fabric(&shell, [z0, z1], scene.exemplars(), &scene.pattern_map())?;
    let fibers = FiberScene::new(&on_mesh, Extent::Unbounded)?;
    scene.path_scene.ground_z = scene.swatch.ground.then(|| f64::from(fibers.slab().0) - GROUND_GAP_CM);
    scene.path_scene.fibers = fibers;
    scene.path_scene.pattern = None;
    Ok(true)
}

/// The shell of a `[mesh]` section around a fabric slab; `swatch_cm` is the default size of a
/// built-in surface and `base_dir` resolves a relative mesh path.
pub fn shell_for_mesh(
    m: &MeshSection,
    swatch_cm: [f64; 2],
    base_dir: &Path,
    z_range: [f32; 2],
) -> Result<Shell, ShellError> {
    let size = m.size_cm.unwrap_or(swatch_cm);
    let size = [size[0] as f32, size[1] as f32];
    let mut mesh = match (&m.builtin, &m.path) {
        (_, Some(path)) => BaseMesh::load(&resolve(base_dir, path))?,
        (Some(name), None) => BaseMesh::builtin(name, size)?,
        (None, None) => BaseMesh::builtin("swatch", size)?,
    };
    mesh.validate_and_repair()?;
    let scale = m.thickness_scale as f32;
    let w_range = [z_range[0] * scale, z_range[1] * scale];
    let spec = ShellSpec::new(w_range, m.cm_per_uv as f32);
    Shell::build(&mesh, &spec)
}

/// Uploads `exemplars` (in pattern order) and the shell of the `[mesh]` section `mesh` around
/// them (see [`shell_for_mesh`] for `swatch_cm` and `base_dir`), and builds the renderer.
pub fn renderer_on_mesh(
    gpu: &Gpu,
    exemplars: &[&Baked],
    pattern: &PatternMap,
    mesh: &MeshSection,
    swatch_cm: [f64; 2],
    base_dir: &Path,
) -> Result<Renderer, HeadlessError> {
    let fabric = FabricData::upload(&gpu.device, &gpu.queue, exemplars, pattern)?;
    let shell = shell_for_mesh(mesh, swatch_cm, base_dir, fabric.arrays.header.z_range)?;
    Ok(Renderer::new(gpu, fabric, &shell)?)
}

fn resolve(base: &Path, path: &Path) -> std::path::PathBuf {
    if path.is_absolute() { path.to_path_buf() } else { base.join(path) }
}

/// Frame settings from a scene's `[render]` and `[gpu]` sections.
#[must_use]
pub fn frame_settings(scene: &Scene, components: Components) -> FrameSettings {
    FrameSettings {
        width: scene.render.width as u32,
        height: scene.render.height as u32,
        spp: scene.render.spp,
        exposure: scene.render.exposure,
        filmic: true,
        components,
        gpu: scene.gpu,
        frame_transfer: true,
    }
}

/// A device with a scene's bake and shell uploaded.
pub struct SceneRenderer {
    pub gpu: Gpu,
    pub renderer: Renderer,
}

impl SceneRenderer {
    /// Opens a headless device and uploads `exemplars` (in pattern order) and the scene's shell.
    pub fn new(scene: &Scene, exemplars: &[&Baked], pattern: &PatternMap) -> Result<Self, HeadlessError> {
        let gpu = Gpu::headless()?;
        Self::with_gpu(gpu, scene, exemplars, pattern)
    }

    /// As [`SceneRenderer::new`] on a device already open.
    pub fn with_gpu(
        gpu: Gpu,
        scene: &Scene,
        exemplars: &[&Baked],
        pattern: &PatternMap,
    ) -> Result<Self, HeadlessError> {
        let renderer =
            renderer_on_mesh(&gpu, exemplars, pattern, &scene.mesh, scene.swatch.size_cm, &scene.base_dir)?;
        Ok(Self { gpu, renderer })
    }

    /// Renders the scene's camera and lights.
    pub fn render(&mut self, scene: &Scene, settings: &FrameSettings) -> Result<Frame, HeadlessError> {
        Ok(self.renderer.render(&scene.camera, &scene.path_scene.lights, settings)?)
    }
}
