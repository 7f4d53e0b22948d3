//! Patterned cloth (paper section 6.4): which exemplar each block of a large fabric uses.
//!
//! How it works: a [`PatternMap`] is a `width × height` grid of exemplar indices, one per block,
//! tiled over the whole cloth (`exemplar_at` wraps both coordinates). Block `(bx, by)` covers
//! the block-sized rectangle `bx` steps along +x and `by` along +y. Maps are written like
//! pictures seen from +z with +y up: the FIRST row (of a text list or a PNG) is the TOP one,
//! `by = height - 1`, and the first column is `bx = 0`.
//! - From text rows: each character is an exemplar index, `0`–`9` then `a`–`z` (10–35).
//! - From a PNG: the distinct gray levels, sorted ascending, become indices 0, 1, 2, …
//!   (so a black-and-white image maps black to 0 and white to 1). Gray and gray+alpha images
//!   of any bit depth are read (alpha ignored); palette and RGB(A) images are accepted only if
//!   every pixel is gray (R = G = B); otherwise the error names the file, the pixel and its
//!   value.
//! - A map wider or taller than [`MAX_PATTERN_SIDE`] blocks is refused before its blocks are
//!   allocated: from text, after counting the rows and the first row's length; from a PNG, from
//!   the size in its header, before any pixel is decoded.

use std::io::Cursor;
use std::path::{Path, PathBuf};

/// Largest side, in blocks, of a pattern map (a PNG's side in pixels): larger maps are refused
/// before their blocks are allocated.
pub const MAX_PATTERN_SIDE: usize = 4096;

/// Why a pattern could not be read.
#[derive(Debug, thiserror::Error)]
pub enum PatternError {
    #[error("pattern has no blocks")]
    Empty,
    #[error("pattern row {row}, column {column}: {found:?} is not an exemplar index (0-9, a-z)")]
    BadChar { row: usize, column: usize, found: char },
    #[error("pattern row {row} has {got} blocks; the first row has {expected}")]
    Ragged { row: usize, expected: usize, got: usize },
    #[error("{}: {source}", file.display())]
    Io { file: PathBuf, source: std::io::Error },
    #[error("{}: not a readable PNG: {source}", file.display())]
    Png { file: PathBuf, source: png::DecodingError },
    #[error("{}: pixel ({x}, {y}) is not gray: {value:?}; pattern images must be grayscale", file.display())]
    NotGray { file: PathBuf, x: u32, y: u32, value: Vec<u16> },
    #[error(
        "{}: the image is {width} x {height} pixels; a pattern map has at most \
         {MAX_PATTERN_SIDE} x {MAX_PATTERN_SIDE} blocks (one per pixel)",
        file.display()
    )]
    PngTooLarge { file: PathBuf, width: u32, height: u32 },
    #[error(
        "pattern is {width} x {height} blocks; a pattern map has at most \
         {MAX_PATTERN_SIDE} x {MAX_PATTERN_SIDE}"
    )]
    RowsTooLarge { width: usize, height: usize },
    #[error(
        "{}: the PLTE chunk is {len} bytes; a palette is 1 to 256 entries of 3 bytes (3 to 768 bytes)",
        file.display()
    )]
    Palette { file: PathBuf, len: usize },
    #[error("{}: unsupported PNG color type {found}", file.display())]
    ColorType { file: PathBuf, found: String },
}

/// Exemplar index of every block of a patterned cloth.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct PatternMap {
    pub width: u32,
    pub height: u32,
    /// Row-major by block y (`by * width + bx`), `by = 0` being the BOTTOM row.
    pub exemplar_of_block: Vec<u16>,
}

impl PatternMap {
    /// Every block uses `exemplar`.
    #[must_use]
    pub fn uniform(exemplar: u16) -> Self {
        Self { width: 1, height: 1, exemplar_of_block: vec![exemplar] }
    }

    /// From text rows, top row first (`["0011", "0110"]`); surrounding whitespace is ignored.
    pub fn from_rows<S: AsRef<str>>(rows: &[S]) -> Result<Self, PatternError> {
        let rows: Vec<&str> = rows.iter().map(|r| r.as_ref().trim()).collect();
        let width = rows.first().map_or(0, |r| r.chars().count());
        if width == 0 {
            return Err(PatternError::Empty);
        }
        let height = rows.len();
        if width > MAX_PATTERN_SIDE || height > MAX_PATTERN_SIDE {
            return Err(PatternError::RowsTooLarge { width, height });
        }
        for (row, text) in rows.iter().enumerate() {
            let got = text.chars().count();
            if got != width {
                return Err(PatternError::Ragged { row, expected: width, got });
            }
        }
        let mut out = vec![0u16; width * height];
        for (row, text) in rows.iter().enumerate() {
            let by = height - 1 - row;
            for (column, c) in text.chars().enumerate() {
                let index = c.to_digit(36).ok_or(PatternError::BadChar { row, column, found: c })?;
                out[by * width + column] = index as u16;
            }
        }
        Ok(Self { width: width as u32, height: height as u32, exemplar_of_block: out })
    }

    /// From a grayscale PNG file. Returns the map and the gray level of each exemplar index (in
    /// the image's bit depth).
    pub fn from_png(path: &Path) -> Result<(Self, Vec<u16>), PatternError> {
        let bytes =
            std::fs::read(path).map_err(|source| PatternError::Io { file: path.to_owned(), source })?;
        Self::from_png_bytes(&bytes, path)
    }

    /// From the bytes of a grayscale PNG; `path` names the file in errors. An image wider or
    /// taller than [`MAX_PATTERN_SIDE`] is refused from its header, before any pixel is decoded.
    pub fn from_png_bytes(bytes: &[u8], path: &Path) -> Result<(Self, Vec<u16>), PatternError> {
        let png_err = |source| PatternError::Png { file: path.to_owned(), source };
        let mut decoder = png::Decoder::new(Cursor::new(bytes));
        decoder.set_transformations(png::Transformations::EXPAND);
        let mut reader = decoder.read_info().map_err(png_err)?;
        let (width, height) = (reader.info().width, reader.info().height);
        if width as usize > MAX_PATTERN_SIDE || height as usize > MAX_PATTERN_SIDE {
            return Err(PatternError::PngTooLarge { file: path.to_owned(), width, height });
        }
        // png 0.18 panics expanding a palette that is not whole RGB entries: refuse it here.
        if let Some(palette) = &reader.info().palette
            && (palette.is_empty() || !palette.len().is_multiple_of(3) || palette.len() > 3 * 256)
        {
            return Err(PatternError::Palette { file: path.to_owned(), len: palette.len() });
        }
        let size = reader.output_buffer_size().ok_or_else(|| PatternError::ColorType {
            file: path.to_owned(),
            found: "image too large".into(),
        })?;
        let mut buf = vec![0u8; size];
        let info = reader.next_frame(&mut buf).map_err(png_err)?;
        let (w, h) = (info.width, info.height);
        if w == 0 || h == 0 {
            return Err(PatternError::Empty);
        }
        let channels = match info.color_type {
            png::ColorType::Grayscale => 1,
            png::ColorType::GrayscaleAlpha => 2,
            png::ColorType::Rgb => 3,
            png::ColorType::Rgba => 4,
            png::ColorType::Indexed => {
                return Err(PatternError::ColorType { file: path.to_owned(), found: "indexed".into() });
            }
        };
        let wide = info.bit_depth == png::BitDepth::Sixteen;
        let sample_bytes = if wide { 2 } else { 1 };
        let mut gray = Vec::with_capacity(w as usize * h as usize);
        for y in 0..h {
            let line = &buf[y as usize * info.line_size..][..info.line_size];
            for x in 0..w {
                let px = &line[x as usize * channels * sample_bytes..][..channels * sample_bytes];
                let sample = |c: usize| {
                    if wide { u16::from_be_bytes([px[2 * c], px[2 * c + 1]]) } else { u16::from(px[c]) }
                };
                if channels >= 3 && (sample(0) != sample(1) || sample(1) != sample(2)) {
                    return Err(PatternError::NotGray {
                        file: path.to_owned(),
                        x,
                        y,
                        value: (0..channels).map(sample).collect(),
                    });
                }
                gray.push(sample(0));
            }
        }
        Ok(Self::from_gray_levels(w, h, &gray))
    }

    /// From gray levels in picture order (top row first): distinct levels, ascending, become
    /// indices 0, 1, …; also returns those levels.
    #[must_use]
    pub fn from_gray_levels(width: u32, height: u32, gray: &[u16]) -> (Self, Vec<u16>) {
        let mut levels = gray.to_vec();
        levels.sort_unstable();
        levels.dedup();
        let (w, h) = (width as usize, height as usize);
        let mut out = vec![0u16; w * h];
        for (i, g) in gray.iter().enumerate().take(w * h) {
            let (row, column) = (i / w, i % w);
            let index = levels.binary_search(g).unwrap_or(0);
            out[(h - 1 - row) * w + column] = index as u16;
        }
        (Self { width, height, exemplar_of_block: out }, levels)
    }

    /// The exemplar of block `(block_x, block_y)`; the map repeats in both directions.
    #[must_use]
    pub fn exemplar_at(&self, block_x: i64, block_y: i64) -> u16 {
        let bx = block_x.rem_euclid(i64::from(self.width)) as usize;
        let by = block_y.rem_euclid(i64::from(self.height)) as usize;
        self.exemplar_of_block[by * self.width as usize + bx]
    }

    /// Number of exemplars the map refers to (largest index + 1).
    #[must_use]
    pub fn exemplar_count(&self) -> usize {
        self.exemplar_of_block.iter().max().map_or(0, |&m| usize::from(m) + 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_png(path: &Path, w: u32, h: u32, color: png::ColorType, depth: png::BitDepth, data: &[u8]) {
        let file = std::fs::File::create(path).unwrap();
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
        enc.set_color(color);
        enc.set_depth(depth);
        let mut writer = enc.write_header().unwrap();
        writer.write_image_data(data).unwrap();
    }

    #[test]
    fn rows_map_top_row_to_highest_y_and_wrap() {
        let m = PatternMap::from_rows(&["0011", "0110"]).unwrap();
        assert_eq!((m.width, m.height), (4, 2));
        // Bottom row (by = 0) is "0110".
        assert_eq!((0..4).map(|x| m.exemplar_at(x, 0)).collect::<Vec<_>>(), [0, 1, 1, 0]);
        assert_eq!((0..4).map(|x| m.exemplar_at(x, 1)).collect::<Vec<_>>(), [0, 0, 1, 1]);
        assert_eq!(m.exemplar_at(-1, -1), 1);
        assert_eq!(m.exemplar_at(6, 3), 1);
        assert_eq!(m.exemplar_at(4 * 1000 + 3, 2 * 77), 0);
        assert_eq!(m.exemplar_count(), 2);
        assert_eq!(PatternMap::from_rows(&["az"]).unwrap().exemplar_of_block, [10, 35]);
        assert_eq!(PatternMap::uniform(3).exemplar_at(-5, 9), 3);
    }

    #[test]
    fn bad_rows_are_rejected_with_their_place() {
        let e = PatternMap::from_rows(&["01", "0-"]).unwrap_err();
        assert!(matches!(e, PatternError::BadChar { row: 1, column: 1, found: '-' }), "{e}");
        let e = PatternMap::from_rows(&["01", "011"]).unwrap_err();
        assert!(matches!(e, PatternError::Ragged { row: 1, expected: 2, got: 3 }));
        assert!(matches!(PatternMap::from_rows::<&str>(&[]), Err(PatternError::Empty)));
        assert!(matches!(PatternMap::from_rows(&[""]), Err(PatternError::Empty)));
    }

    #[test]
    fn png_gray_levels_become_ascending_indices() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.png");
        // 3x2, top row 200 10 200, bottom row 90 10 10.
        write_png(&p, 3, 2, png::ColorType::Grayscale, png::BitDepth::Eight, &[200, 10, 200, 90, 10, 10]);
        let (m, levels) = PatternMap::from_png(&p).unwrap();
        assert_eq!(levels, [10, 90, 200]);
        assert_eq!(m.exemplar_of_block, [1, 0, 0, 2, 0, 2]);
        // 16-bit gray and gray RGB read the same way.
        let p16 = dir.path().join("g16.png");
        let data16: Vec<u8> =
            [200u16 * 257, 10, 200 * 257, 90, 10, 10].iter().flat_map(|v| v.to_be_bytes()).collect();
        write_png(&p16, 3, 2, png::ColorType::Grayscale, png::BitDepth::Sixteen, &data16);
        assert_eq!(PatternMap::from_png(&p16).unwrap().0, m);
        let prgb = dir.path().join("rgb.png");
        let rgb: Vec<u8> = [200u8, 10, 200, 90, 10, 10].iter().flat_map(|&v| [v, v, v]).collect();
        write_png(&prgb, 3, 2, png::ColorType::Rgb, png::BitDepth::Eight, &rgb);
        assert_eq!(PatternMap::from_png(&prgb).unwrap().0, m);
        // 1-bit black and white.
        let p1 = dir.path().join("bw.png");
        write_png(&p1, 8, 1, png::ColorType::Grayscale, png::BitDepth::One, &[0b1010_0000]);
        let (m1, l1) = PatternMap::from_png(&p1).unwrap();
        assert_eq!(l1, [0, 255]);
        assert_eq!(m1.exemplar_of_block, [1, 0, 1, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn bad_pngs_are_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.png");
        write_png(&p, 2, 1, png::ColorType::Rgb, png::BitDepth::Eight, &[5, 5, 5, 1, 2, 3]);
        let e = PatternMap::from_png(&p).unwrap_err();
        assert!(matches!(e, PatternError::NotGray { x: 1, y: 0, .. }), "{e}");
        assert!(e.to_string().contains("c.png") && e.to_string().contains("[1, 2, 3]"), "{e}");
        // Truncated at every length: an error naming the file, never a panic.
        let good = dir.path().join("g.png");
        write_png(&good, 4, 4, png::ColorType::Grayscale, png::BitDepth::Eight, &[7; 16]);
        let bytes = std::fs::read(&good).unwrap();
        let cut = dir.path().join("cut.png");
        // (Only the 12-byte IEND chunk may go missing: the pixels are all there.)
        for len in 0..bytes.len() {
            std::fs::write(&cut, &bytes[..len]).unwrap();
            match PatternMap::from_png(&cut) {
                Err(e) => assert!(e.to_string().contains("cut.png"), "{len}: {e}"),
                Ok((m, levels)) => {
                    assert!(len >= bytes.len() - 12, "truncated to {len} bytes yet read");
                    assert_eq!((m.exemplar_of_block, levels), (vec![0; 16], vec![7]));
                }
            }
        }
        let e = PatternMap::from_png(&dir.path().join("missing.png")).unwrap_err();
        assert!(matches!(e, PatternError::Io { .. }) && e.to_string().contains("missing.png"));
    }

    /// Found by the `png_pattern` fuzz target
    /// (fuzz/corpus/png_pattern/regression-palette-not-whole-entries.png): a 2 x 1 indexed image
    /// whose PLTE chunk is 7 bytes made the png crate panic while expanding the palette.
    #[test]
    fn fuzz_regression_a_palette_of_partial_entries_is_refused() {
        const INPUT: [u8; 87] = [
            0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44, 0x52,
            0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x01, 0x08, 0x03, 0x00, 0x00, 0x00, 0xc3, 0xfc, 0x8f,
            0xb8, 0x00, 0x00, 0x00, 0x07, 0x50, 0x4c, 0x54, 0x45, 0x00, 0x00, 0x00, 0xff, 0xff, 0xff, 0xa5,
            0x8c, 0x79, 0xcf, 0x1c, 0x00, 0x00, 0x0b, 0x3f, 0x49, 0x44, 0x41, 0x54, 0x78, 0x9c, 0x63, 0x60,
            0x60, 0x04, 0x00, 0x00, 0x04, 0x00, 0x02, 0xbf, 0x7a, 0x3f, 0x4a, 0x00, 0x00, 0x00, 0x00, 0x49,
            0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82,
        ];
        let e = PatternMap::from_png_bytes(&INPUT, Path::new("pal.png")).unwrap_err();
        assert!(matches!(e, PatternError::Palette { len: 7, .. }), "{e}");
        assert!(e.to_string().starts_with("pal.png: the PLTE chunk is 7 bytes"), "{e}");
    }

    #[test]
    fn huge_maps_are_refused_before_allocating() {
        // A PNG claiming 1e6 x 1e6 pixels (a terabyte decoded) with a few bytes of pixel data.
        let mut bytes = Vec::new();
        let mut enc = png::Encoder::new(&mut bytes, 1_000_000, 1_000_000);
        enc.set_color(png::ColorType::Grayscale);
        let mut writer = enc.write_header().unwrap();
        writer.write_chunk(png::chunk::IDAT, &[0x78, 0x9c, 0x03, 0x00]).unwrap();
        drop(writer);
        assert!(bytes.len() < 100, "{} bytes", bytes.len());
        let e = PatternMap::from_png_bytes(&bytes, Path::new("huge.png")).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("huge.png")
                && msg.contains("1000000 x 1000000")
                && msg.contains("at most 4096 x 4096"),
            "{msg}"
        );
        // Text rows: too many, or too long, before the blocks are allocated.
        let tall = vec!["0"; MAX_PATTERN_SIDE + 1];
        let e = PatternMap::from_rows(&tall).unwrap_err();
        assert!(matches!(e, PatternError::RowsTooLarge { width: 1, height: 4097 }), "{e}");
        let wide = ["0".repeat(MAX_PATTERN_SIDE + 1)];
        assert!(PatternMap::from_rows(&wide).unwrap_err().to_string().contains("4097 x 1 blocks"));
        // A long first row over many short ones is ragged, found before allocating their product.
        let mut ragged = vec![String::new(); 4000];
        ragged[0] = "0".repeat(4000);
        let e = PatternMap::from_rows(&ragged).unwrap_err();
        assert!(matches!(e, PatternError::Ragged { row: 1, expected: 4000, got: 0 }), "{e}");
        // The largest allowed map still reads.
        let side = ["0".repeat(MAX_PATTERN_SIDE)];
        assert_eq!(PatternMap::from_rows(&side).unwrap().width as usize, MAX_PATTERN_SIDE);
    }
}
