//! Image export: linear HDR EXR and tone-mapped sRGB PNG, both written atomically.
//!
//! EXR files hold the linear, scene-referred radiance as 32-bit floats (RGB), untouched. PNG
//! files are display-referred: radiance is scaled by `2^exposure`, passed through a tone curve
//! ([`ToneCurve`]), encoded with the sRGB transfer function and quantized to 8 bits. The format is
//! chosen from the file extension.

use std::io;
use std::path::{Path, PathBuf};

use twill_precompute::Rgb;
use twill_precompute::atomic_file::write_atomically;
use twill_precompute::image::Image;

/// Errors writing an image; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("{path}: unsupported image extension (expected .png or .exr)")]
    UnsupportedExtension { path: PathBuf },
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: io::Error },
    #[error("{path}: image has non-finite pixels (first at x={x}, y={y}); refusing to write it")]
    NonFinite { path: PathBuf, x: usize, y: usize },
}

/// How radiance maps to display values before sRGB encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ToneCurve {
    /// Clamp to [0, 1]: values stay proportional to radiance (best for comparing images).
    Clamp,
    /// Narkowicz's fit of the ACES filmic curve: highlights roll off instead of clipping.
    #[default]
    Filmic,
}

/// Display settings for PNG output.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Display {
    /// Exposure in stops: radiance is multiplied by `2^exposure`.
    pub exposure: f64,
    pub curve: ToneCurve,
}

impl Default for Display {
    fn default() -> Self {
        Self { exposure: 0.0, curve: ToneCurve::Filmic }
    }
}

/// Writes `image` as `.exr` (linear) or `.png` (tone-mapped), chosen by extension.
pub fn write_image(path: &Path, image: &Image, display: Display) -> Result<(), ExportError> {
    if let Some(i) = image.pixels.iter().position(|p| !p.is_finite()) {
        return Err(ExportError::NonFinite { path: path.into(), x: i % image.width, y: i / image.width });
    }
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let io_err = |source| ExportError::Io { path: path.into(), source };
    match ext.as_deref() {
        Some("png") => write_png(path, image, display).map_err(io_err),
        Some("exr") => write_exr(path, image).map_err(io_err),
        _ => Err(ExportError::UnsupportedExtension { path: path.into() }),
    }
}

/// Writes an already tone-mapped RGBA8 image (the GPU's display image) as an RGB PNG,
/// atomically.
pub fn write_display_png(path: &Path, width: u32, height: u32, rgba: &[[u8; 4]]) -> Result<(), ExportError> {
    let bytes: Vec<u8> = rgba.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
    write_rgb8_png(path, width, height, &bytes)
        .map_err(|source| ExportError::Io { path: path.into(), source })
}

/// Maps linear radiance to an 8-bit sRGB value per channel.
#[must_use]
pub fn display_srgb8(radiance: Rgb, display: Display) -> [u8; 3] {
    let scaled = radiance * display.exposure.exp2();
    let mapped = match display.curve {
        ToneCurve::Clamp => scaled,
        ToneCurve::Filmic => {
            let x = scaled.max(Rgb::ZERO);
            (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)
        }
    };
    mapped.to_array().map(|c| (srgb_encode(c.clamp(0.0, 1.0)) * 255.0 + 0.5) as u8)
}

/// The sRGB transfer function (IEC 61966-2-1) for a value in [0, 1].
#[must_use]
pub fn srgb_encode(linear: f64) -> f64 {
    if linear <= 0.003_130_8 { 12.92 * linear } else { 1.055 * linear.powf(1.0 / 2.4) - 0.055 }
}

fn write_png(path: &Path, image: &Image, display: Display) -> io::Result<()> {
    let mut bytes = Vec::with_capacity(image.pixels.len() * 3);
    for &p in &image.pixels {
        bytes.extend_from_slice(&display_srgb8(p, display));
    }
    write_rgb8_png(path, image.width as u32, image.height as u32, &bytes)
}

/// Writes 8-bit sRGB RGB bytes (row-major, top row first) as a PNG, atomically.
pub fn write_rgb8_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> io::Result<()> {
    write_atomically(path, |w| encode_rgb8_png(w, width, height, rgb))
}

/// Encodes 8-bit sRGB RGB bytes (row-major, top row first) as a PNG into `w`.
pub fn encode_rgb8_png<W: io::Write>(w: W, width: u32, height: u32, rgb: &[u8]) -> io::Result<()> {
    let mut encoder = png::Encoder::new(w, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
    let mut writer = encoder.write_header().map_err(io::Error::other)?;
    writer.write_image_data(rgb).map_err(io::Error::other)?;
    writer.finish().map_err(io::Error::other)
}

fn write_exr(path: &Path, image: &Image) -> io::Result<()> {
    use exr::prelude::{Image as ExrImage, SpecificChannels, Vec2, WritableImage};
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let p = image.get(x, y);
        (p.x as f32, p.y as f32, p.z as f32)
    });
    let exr_image = ExrImage::from_channels((image.width, image.height), channels);
    write_atomically(path, |w| exr_image.write().to_buffered(w).map_err(io::Error::other))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gradient() -> Image {
        let mut image = Image::new(4, 2);
        for (i, p) in image.pixels.iter_mut().enumerate() {
            *p = Rgb::new(i as f64 * 0.25, 0.5, 2.0);
        }
        image
    }

    #[test]
    #[allow(clippy::float_cmp)] // f32 values must round-trip bit for bit
    fn exr_round_trips_linear_values() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.exr");
        let image = gradient();
        write_image(&path, &image, Display::default()).unwrap();
        let read = exr::prelude::read_first_rgba_layer_from_file(
            &path,
            |size, _| vec![[0.0f32; 3]; size.width() * size.height()],
            |pixels: &mut Vec<[f32; 3]>, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                pixels[pos.y() * 4 + pos.x()] = [r, g, b];
            },
        )
        .unwrap();
        let pixels = read.layer_data.channel_data.pixels;
        for (i, p) in image.pixels.iter().enumerate() {
            assert_eq!(pixels[i], [p.x as f32, p.y as f32, p.z as f32]);
        }
    }

    #[test]
    fn png_is_written_with_the_right_size_and_srgb_values() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.png");
        let display = Display { exposure: 0.0, curve: ToneCurve::Clamp };
        write_image(&path, &gradient(), display).unwrap();
        let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (4, 2));
        // Pixel 2: r = 0.5 linear -> 188 in sRGB; b = 2.0 clamps to 255.
        assert_eq!(&buf[6..9], &[188, 188, 255]);
    }

    #[test]
    fn bad_extension_and_non_finite_pixels_are_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let err = write_image(&dir.path().join("x.jpg"), &gradient(), Display::default()).unwrap_err();
        assert!(err.to_string().contains("x.jpg"), "{err}");
        let mut image = gradient();
        image.set(1, 1, Rgb::new(f64::NAN, 0.0, 0.0));
        let err = write_image(&dir.path().join("y.png"), &image, Display::default()).unwrap_err();
        assert!(err.to_string().contains("x=1, y=1"), "{err}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn filmic_curve_is_monotone_and_bounded() {
        let display = Display::default();
        let mut last = 0;
        for i in 0..200 {
            let v = display_srgb8(Rgb::splat(f64::from(i) * 0.1), display)[0];
            assert!(v >= last);
            last = v;
        }
        assert!(last >= 250);
    }
}
