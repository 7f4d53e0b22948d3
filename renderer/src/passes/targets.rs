//! The textures and buffers a frame of one size renders into and reads back from: the
//! G-buffer (world position, ids, depth), the accumulation buffer the shading pass adds
//! radiance to, the tone-mapped display image, and the readback buffers of the last two.
//!
//! How it works: the renderer keeps one [`FrameTargets`] and makes a new one only when the
//! frame's size changes, so progressive batches and camera moves allocate nothing. A frame that
//! starts a picture clears the accumulation; the readback buffers are unmapped after each read.

use super::{readback_buffer, texture_2d, view};

/// A frame's render targets (cheap to clone: handles).
#[derive(Clone)]
pub struct FrameTargets {
    pub size: (u32, u32),
    pub position: wgpu::Texture,
    pub ids: wgpu::Texture,
    pub depth: wgpu::Texture,
    /// Tone-mapped sRGB, RGBA8 (storage for the tone map, sampled by a window, copied for export).
    pub display: wgpu::Texture,
    /// Views of the G-buffer textures and the display image, made once with them: the passes
    /// bind these every sample instead of making views of their own.
    pub views: TargetViews,
    /// Radiance summed over the samples so far, one `vec4<f32>` per pixel.
    pub accumulation: wgpu::Buffer,
    pub radiance_readback: wgpu::Buffer,
    pub display_readback: wgpu::Buffer,
}

/// The views every frame binds (cheap to clone: handles).
#[derive(Clone)]
pub struct TargetViews {
    pub position: wgpu::TextureView,
    pub ids: wgpu::TextureView,
    pub depth: wgpu::TextureView,
    pub display: wgpu::TextureView,
}

/// Bytes per row of the display image's readback (rows padded to wgpu's copy alignment).
#[must_use]
pub fn display_row_bytes(width: u32) -> u32 {
    (width * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
}

impl FrameTargets {
    /// Targets for a `width` × `height` frame.
    #[must_use]
    pub fn new(device: &wgpu::Device, width: u32, height: u32) -> Self {
        let target = |label: &str, format: wgpu::TextureFormat, usage: wgpu::TextureUsages| {
            texture_2d(device, label, [width, height, 1], format, usage)
        };
        let attach = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
        let pixels = u64::from(width) * u64::from(height);
        let position = target("twill.gbuffer.position", wgpu::TextureFormat::Rgba32Float, attach);
        let ids = target("twill.gbuffer.ids", wgpu::TextureFormat::Rgba32Uint, attach);
        let depth = target(
            "twill.gbuffer.depth",
            wgpu::TextureFormat::Depth32Float,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let display = target(
            "twill.display",
            wgpu::TextureFormat::Rgba8Unorm,
            wgpu::TextureUsages::STORAGE_BINDING
                | wgpu::TextureUsages::COPY_SRC
                | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let views = TargetViews {
            position: view(&position),
            ids: view(&ids),
            depth: view(&depth),
            display: view(&display),
        };
        Self {
            size: (width, height),
            position,
            ids,
            depth,
            display,
            views,
            accumulation: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("twill.accumulation"),
                size: pixels * 16,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            radiance_readback: readback_buffer(device, "twill.readback.radiance", pixels * 16),
            display_readback: readback_buffer(
                device,
                "twill.readback.display",
                u64::from(display_row_bytes(width)) * u64::from(height),
            ),
        }
    }

    /// Pixels in the frame.
    #[must_use]
    pub fn pixels(&self) -> u64 {
        u64::from(self.size.0) * u64::from(self.size.1)
    }

    /// Records copies of the accumulation and the display image into the readback buffers.
    pub fn encode_readback(&self, encoder: &mut wgpu::CommandEncoder, radiance: bool) {
        let (width, height) = self.size;
        if radiance {
            encoder.copy_buffer_to_buffer(
                &self.accumulation,
                0,
                &self.radiance_readback,
                0,
                self.pixels() * 16,
            );
        }
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &self.display,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &self.display_readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(display_row_bytes(width)),
                    rows_per_image: Some(height),
                },
            },
            wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
        );
    }
}
