//! The shell on the GPU: the tetrahedra the eye rays walk and the shading reads, and the
//! top and bottom surfaces the shadow-map and top-surface passes rasterize.
//!
//! How it works: [`ShellGpu::upload`] turns a [`Shell`] into storage buffers. Each tetrahedron
//! becomes a [`TetraGpu`]: the rows of its world → (u, v, w) affine map, its four face planes
//! in (u, v, w) (inside where `n · x + d ≥ 0`, plane k opposite corner k) and the tetrahedron
//! across each face. The faces with no neighbour are the shell's surface, listed as
//! `tetrahedron * 4 + k` for the G-buffer to rasterize. When every tetrahedron has the same
//! linear map (the flat swatch) it is kept as [`ShellGpu::uniform_frame`]: then the lights' SH
//! is the same at every pixel and the cell-transfer pass can run once per frame.

use glam::{DVec3, Vec3};

use crate::fabric_data::make_buffer;
use crate::shell::{NO_NEIGHBOR, Shell, ShellVertex};

/// Twin of `TetraGpu` in shaders/shared/shell.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TetraGpu {
    pub uvw_from_world: [[f32; 4]; 3],
    pub planes: [[f32; 4]; 4],
    /// The tetrahedron across the face opposite each corner ([`NO_NEIGHBOR`] on the shell's
    /// surface).
    pub neighbors: [u32; 4],
}

/// Twin of `SurfaceVertex` in shaders/shared/shell.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SurfaceVertexGpu {
    pub position: [f32; 4],
    pub uvw: [f32; 4],
}

/// The shell on the GPU.
pub struct ShellGpu {
    pub tetra_corners: wgpu::Buffer,
    pub tetras: wgpu::Buffer,
    /// The shell's surface faces, `tetrahedron * 4 + k` for the face opposite corner `k`: what
    /// the G-buffer pass rasterizes.
    pub surface_faces: wgpu::Buffer,
    pub surface_face_count: u32,
    /// The rows of the world → uvw map's linear part when every tetrahedron has the same one
    /// (within [`UNIFORM_FRAME_TOLERANCE`]): the flat swatch.
    pub uniform_frame: Option<[[f32; 4]; 3]>,
    pub surface_vertices: wgpu::Buffer,
    /// Top-surface vertices come first in `surface_vertices`.
    pub top_vertex_count: u32,
    pub surface_vertex_count: u32,
    /// (u_min, v_min, u_max - u_min, v_max - v_min), cm.
    pub uv_rect: [f32; 4],
    pub bounds: (Vec3, Vec3),
    pub flat_normal: Option<Vec3>,
}

/// (world → uvw rows, face planes in uvw, neighbours) of one tetrahedron.
#[must_use]
pub fn tetra_gpu(corners: &[ShellVertex; 4], neighbors: [u32; 4]) -> TetraGpu {
    let (uvw_from_world, _) = Shell::tetra_affine(corners);
    let rows = [uvw_from_world.row(0), uvw_from_world.row(1), uvw_from_world.row(2)];
    let uvw: Vec<DVec3> = corners.iter().map(|c| c.uvw.as_dvec3()).collect();
    let mut planes = [[0.0_f32; 4]; 4];
    for (i, plane) in planes.iter_mut().enumerate() {
        let others: Vec<DVec3> = (0..4).filter(|&k| k != i).map(|k| uvw[k]).collect();
        let mut n = (others[1] - others[0]).cross(others[2] - others[0]);
        if n.dot(uvw[i] - others[0]) < 0.0 {
            n = -n;
        }
        let scale = 1.0 / n.length().max(1e-30);
        let n = n * scale;
        *plane = [n.x as f32, n.y as f32, n.z as f32, (-n.dot(others[0])) as f32];
    }
    TetraGpu { uvw_from_world: rows.map(|r| r.to_array()), planes, neighbors }
}

/// Largest difference, relative to the row's length, between two tetrahedra's linear maps that
/// still counts as one frame (f32 rounding of maps computed per tetrahedron: ~1e-7).
pub const UNIFORM_FRAME_TOLERANCE: f32 = 1e-5;

/// The linear part of the world → uvw map shared by every tetrahedron, if they share one.
fn uniform_frame(tetras: &[TetraGpu]) -> Option<[[f32; 4]; 3]> {
    let first = tetras.first()?;
    let rows = first.uvw_from_world.map(|r| Vec3::new(r[0], r[1], r[2]));
    let same = tetras.iter().all(|t| {
        (0..3).all(|i| {
            let row = Vec3::new(t.uvw_from_world[i][0], t.uvw_from_world[i][1], t.uvw_from_world[i][2]);
            (row - rows[i]).length() <= UNIFORM_FRAME_TOLERANCE * rows[i].length()
        })
    });
    same.then(|| rows.map(|r| r.extend(0.0).to_array()))
}

impl ShellGpu {
    /// Uploads `shell`.
    #[must_use]
    pub fn upload(device: &wgpu::Device, queue: &wgpu::Queue, shell: &Shell) -> Self {
        let corners: Vec<[f32; 4]> = shell
            .tetrahedra
            .iter()
            .flat_map(|t| t.iter().map(|v| v.position.extend(1.0).to_array()))
            .collect();
        let neighbors = shell.tetra_neighbors();
        let tetras: Vec<TetraGpu> = shell
            .tetrahedra
            .iter()
            .zip(&neighbors)
            .map(|(corners, &across)| tetra_gpu(corners, across))
            .collect();
        let surface_faces: Vec<u32> = neighbors
            .iter()
            .enumerate()
            .flat_map(|(t, across)| {
                (0..4_u32).filter(|&k| across[k as usize] == NO_NEIGHBOR).map(move |k| t as u32 * 4 + k)
            })
            .collect();
        let vertex = |v: &ShellVertex| SurfaceVertexGpu {
            position: v.position.extend(1.0).to_array(),
            uvw: v.uvw.extend(0.0).to_array(),
        };
        let mut surface: Vec<SurfaceVertexGpu> = shell.top_triangles.iter().flatten().map(vertex).collect();
        let top_vertex_count = surface.len() as u32;
        surface.extend(shell.bottom_triangles.iter().flatten().map(vertex));
        let storage =
            |label: &str, bytes: &[u8]| make_buffer(device, queue, label, bytes, wgpu::BufferUsages::STORAGE);
        let uv_size = (shell.uv_max - shell.uv_min).max(glam::Vec2::splat(1e-6));
        Self {
            tetra_corners: storage("twill.shell.tetra_corners", bytemuck::cast_slice(&corners)),
            tetras: storage("twill.shell.tetras", bytemuck::cast_slice(&tetras)),
            surface_faces: storage("twill.shell.surface_faces", bytemuck::cast_slice(&surface_faces)),
            surface_face_count: surface_faces.len() as u32,
            uniform_frame: uniform_frame(&tetras),
            surface_vertices: storage("twill.shell.surface_vertices", bytemuck::cast_slice(&surface)),
            top_vertex_count,
            surface_vertex_count: surface.len() as u32,
            uv_rect: [shell.uv_min.x, shell.uv_min.y, uv_size.x, uv_size.y],
            bounds: (shell.bounds_min, shell.bounds_max),
            flat_normal: if shell.is_flat { shell.flat_normal } else { None },
        }
    }

    /// Bytes of GPU memory the shell holds.
    #[must_use]
    pub fn bytes(&self) -> u64 {
        self.tetra_corners.size()
            + self.tetras.size()
            + self.surface_faces.size()
            + self.surface_vertices.size()
    }
}
