//! Reading and writing fiber files: Mitsuba's curve text format and Cem Yuksel's cyHair `.hair`.
//!
//! How it works:
//!
//! - **Mitsuba curves** (text): one control point per line, `x y z radius` or `x y z` (then the
//!   caller's default radius applies), a blank line between fibers, `#` starting a comment.
//!   Our [`Fiber`] has one radius, so a fiber's radius is the mean of its points' radii.
//! - **cyHair** (binary, little-endian): a 128-byte header (`"HAIR"`, hair count u32, point count
//!   u32, array bits u32 — bit 0 segments, 1 points, 2 thickness, 3 transparency, 4 colour —,
//!   default segments u32, default thickness f32, default transparency f32, default colour
//!   3 x f32, 88 info bytes), then the present arrays in that order: segments (u16 per hair =
//!   points - 1), points (3 x f32 per point), thickness (f32 per point), transparency (f32 per
//!   point), colour (3 x f32 per point). Thickness is read as a *diameter*: that is how widely
//!   used importers treat it (Unreal's groom importer stores it as the strand `Width`, pbrt's
//!   `cyhair2pbrt` writes it as the curve `width`), so radius = thickness / 2, averaged per fiber.
//!   Transparency and colour are skipped on reading and not written.
//!
//! Readers never panic: every malformed input becomes a [`FiberIoError`] naming the file and the
//! line (text) or byte offset (binary) with the offending value. Writers write a temporary file in
//! the target's directory and rename it over the target, so a crash never leaves half a file.

use std::io::Write;
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::{BlockGrid, Exemplar, Fiber, Tiling, Yarn, YarnRole};

/// A fiber file that could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum FiberIoError {
    #[error("{}: {source}", file.display())]
    Io { file: PathBuf, source: std::io::Error },
    #[error("{}:{line}: {message}", file.display())]
    Text { file: PathBuf, line: usize, message: String },
    #[error("{} at byte {offset}: {message}", file.display())]
    Binary { file: PathBuf, offset: usize, message: String },
    #[error("{}: {message}", file.display())]
    Invalid { file: PathBuf, message: String },
}

/// Fiber file formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FiberFormat {
    /// Mitsuba curve text.
    Mitsuba,
    /// cyHair binary.
    Hair,
}

impl FiberFormat {
    /// `.hair` is cyHair, anything else Mitsuba text.
    #[must_use]
    pub fn from_path(path: &Path) -> Self {
        match path.extension().and_then(|e| e.to_str()) {
            Some(e) if e.eq_ignore_ascii_case("hair") => FiberFormat::Hair,
            _ => FiberFormat::Mitsuba,
        }
    }
}

/// Reads fibers in `format` (by extension when `None`). `default_radius` applies to Mitsuba points
/// without a radius; every fiber gets yarn 0.
pub fn read_fibers(
    path: &Path,
    format: Option<FiberFormat>,
    default_radius: Option<f32>,
) -> Result<Vec<Fiber>, FiberIoError> {
    let bytes = std::fs::read(path).map_err(|source| FiberIoError::Io { file: path.to_owned(), source })?;
    match format.unwrap_or_else(|| FiberFormat::from_path(path)) {
        FiberFormat::Mitsuba => {
            let text = std::str::from_utf8(&bytes).map_err(|e| FiberIoError::Binary {
                file: path.to_owned(),
                offset: e.valid_up_to(),
                message: "not UTF-8 text (is this a .hair file? give format = \"hair\")".into(),
            })?;
            parse_mitsuba(text, path, default_radius)
        }
        FiberFormat::Hair => parse_hair(&bytes, path),
    }
}

/// Writes fibers in `format` (by extension when `None`), atomically.
pub fn write_fibers(path: &Path, fibers: &[Fiber], format: Option<FiberFormat>) -> Result<(), FiberIoError> {
    let bytes = match format.unwrap_or_else(|| FiberFormat::from_path(path)) {
        FiberFormat::Mitsuba => format_mitsuba(fibers).into_bytes(),
        FiberFormat::Hair => {
            encode_hair(fibers).map_err(|message| FiberIoError::Invalid { file: path.to_owned(), message })?
        }
    };
    write_atomically(path, &bytes)
}

/// An exemplar of imported fibers: one yarn (role Other, material 0).
#[must_use]
pub fn exemplar_from_fibers(fibers: Vec<Fiber>, tiling: Tiling, blocks: BlockGrid) -> Exemplar {
    let fibers = fibers.into_iter().map(|f| Fiber { yarn: 0, ..f }).collect();
    Exemplar { fibers, yarns: vec![Yarn { role: YarnRole::Other, material: 0 }], tiling, blocks }
}

fn check_point(p: Vec3, radius: f32) -> Result<(), String> {
    if !p.is_finite() {
        return Err(format!("point ({}, {}, {}) is not finite", p.x, p.y, p.z));
    }
    if !(radius.is_finite() && radius > 0.0) {
        return Err(format!("radius {radius} must be finite and > 0"));
    }
    Ok(())
}

/// Parses Mitsuba curve text; `file` only names the source in errors.
pub fn parse_mitsuba(
    text: &str,
    file: &Path,
    default_radius: Option<f32>,
) -> Result<Vec<Fiber>, FiberIoError> {
    let err = |line: usize, message: String| FiberIoError::Text { file: file.to_owned(), line, message };
    let mut fibers = Vec::new();
    let mut points: Vec<Vec3> = Vec::new();
    let mut radius_sum = 0.0f64;
    let mut start_line = 1;
    let mut finish =
        |points: &mut Vec<Vec3>, radius_sum: &mut f64, line: usize| -> Result<(), FiberIoError> {
            match points.len() {
                0 => {}
                1 => return Err(err(line, "fiber has 1 point, at least 2 are needed".into())),
                n => {
                    let radius = (*radius_sum / n as f64) as f32;
                    fibers.push(Fiber { points: std::mem::take(points), radius, yarn: 0 });
                }
            }
            *radius_sum = 0.0;
            Ok(())
        };
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            // A comment-only line does not end a fiber; a blank one does.
            if raw.trim().is_empty() {
                finish(&mut points, &mut radius_sum, start_line)?;
            }
            continue;
        }
        if points.is_empty() {
            start_line = line;
        }
        let mut values = [0.0f32; 4];
        let mut count = 0;
        for word in content.split_whitespace() {
            if count == 4 {
                return Err(err(line, format!("expected `x y z [radius]`, found extra value `{word}`")));
            }
            values[count] =
                word.parse::<f32>().map_err(|_| err(line, format!("`{word}` is not a number")))?;
            count += 1;
        }
        let radius = match count {
            3 => default_radius.ok_or_else(|| {
                err(
                    line,
                    "point has no radius and no default radius was given (`x y z radius` expected)".into(),
                )
            })?,
            4 => values[3],
            _ => return Err(err(line, format!("expected `x y z [radius]`, found {count} values"))),
        };
        let p = Vec3::new(values[0], values[1], values[2]);
        check_point(p, radius).map_err(|m| err(line, m))?;
        points.push(p);
        radius_sum += f64::from(radius);
    }
    finish(&mut points, &mut radius_sum, start_line)?;
    Ok(fibers)
}

/// Formats fibers as Mitsuba curve text (`x y z radius`, blank line between fibers).
#[must_use]
pub fn format_mitsuba(fibers: &[Fiber]) -> String {
    use std::fmt::Write as _;
    let mut out = String::from("# twill fibers: x y z radius (cm), one fiber per block\n");
    for (k, fiber) in fibers.iter().enumerate() {
        if k > 0 {
            out.push('\n');
        }
        for p in &fiber.points {
            // `{}` prints the shortest string that reads back to the same f32.
            let _ = writeln!(out, "{} {} {} {}", p.x, p.y, p.z, fiber.radius);
        }
    }
    out
}

const HAIR_HEADER_SIZE: usize = 128;
const BIT_SEGMENTS: u32 = 1;
const BIT_POINTS: u32 = 2;
const BIT_THICKNESS: u32 = 4;
const BIT_TRANSPARENCY: u32 = 8;
const BIT_COLORS: u32 = 16;

/// Little-endian cursor that reports truncation with its offset.
struct Reader<'a> {
    bytes: &'a [u8],
    offset: usize,
    file: &'a Path,
}

impl Reader<'_> {
    fn error(&self, offset: usize, message: String) -> FiberIoError {
        FiberIoError::Binary { file: self.file.to_owned(), offset, message }
    }

    fn take<const N: usize>(&mut self, what: &str) -> Result<[u8; N], FiberIoError> {
        let end = self.offset.checked_add(N).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return Err(self.error(
                self.offset,
                format!("file ends while reading {what} ({} bytes total)", self.bytes.len()),
            ));
        };
        let mut out = [0u8; N];
        out.copy_from_slice(&self.bytes[self.offset..end]);
        self.offset = end;
        Ok(out)
    }

    fn u32(&mut self, what: &str) -> Result<u32, FiberIoError> {
        self.take::<4>(what).map(u32::from_le_bytes)
    }

    fn f32(&mut self, what: &str) -> Result<f32, FiberIoError> {
        self.take::<4>(what).map(f32::from_le_bytes)
    }

    fn u16(&mut self, what: &str) -> Result<u16, FiberIoError> {
        self.take::<2>(what).map(u16::from_le_bytes)
    }
}

/// Parses a cyHair file's bytes; `file` only names the source in errors.
pub fn parse_hair(bytes: &[u8], file: &Path) -> Result<Vec<Fiber>, FiberIoError> {
    let mut r = Reader { bytes, offset: 0, file };
    let signature = r.take::<4>("the signature")?;
    if &signature != b"HAIR" {
        return Err(r.error(0, format!("signature {signature:?} is not \"HAIR\"")));
    }
    let hair_count = r.u32("the hair count")? as usize;
    let point_count = r.u32("the point count")? as usize;
    let arrays = r.u32("the array bits")?;
    let default_segments = r.u32("the default segment count")?;
    let default_thickness = r.f32("the default thickness")?;
    r.offset = HAIR_HEADER_SIZE.min(bytes.len());
    if bytes.len() < HAIR_HEADER_SIZE {
        return Err(r.error(bytes.len(), format!("file ends inside the {HAIR_HEADER_SIZE}-byte header")));
    }
    if arrays & BIT_POINTS == 0 {
        return Err(r.error(12, format!("array bits {arrays:#x} say the file has no points array")));
    }
    // Bound the counts by what the file can hold before allocating anything: every point takes
    // 12 bytes of the points array, every hair 2 bytes of the segments array (when present) and
    // at least 2 points.
    let body = bytes.len() - HAIR_HEADER_SIZE;
    let max_points = body / 12;
    if point_count > max_points {
        return Err(r.error(
            8,
            format!(
                "point count {point_count} is more than the {body} bytes after the header can hold \
                 (at most {max_points} points of 12 bytes)"
            ),
        ));
    }
    let max_hairs = if arrays & BIT_SEGMENTS == 0 { max_points / 2 } else { body / 26 };
    if hair_count > max_hairs {
        return Err(r.error(
            4,
            format!(
                "hair count {hair_count} is more than the {body} bytes after the header can hold \
                 (at most {max_hairs} hairs of 2 or more points)"
            ),
        ));
    }
    let mut segments = Vec::with_capacity(hair_count);
    if arrays & BIT_SEGMENTS == 0 {
        segments.resize(hair_count, default_segments as usize);
    } else {
        for _ in 0..hair_count {
            segments.push(r.u16("the segments array")? as usize);
        }
    }
    let total: usize = segments.iter().map(|s| s + 1).sum();
    if total != point_count {
        return Err(r.error(
            8,
            format!("point count {point_count} disagrees with the segments, which add up to {total} points"),
        ));
    }
    let points_at = r.offset;
    let mut points = Vec::with_capacity(point_count);
    for _ in 0..point_count {
        let at = r.offset;
        let p = Vec3::new(r.f32("the points array")?, r.f32("the points array")?, r.f32("the points array")?);
        if !p.is_finite() {
            return Err(r.error(at, format!("point ({}, {}, {}) is not finite", p.x, p.y, p.z)));
        }
        points.push(p);
    }
    // A thickness is a diameter: half of it, the radius, must still be > 0 (half the smallest
    // positive f32 rounds to 0).
    let usable = |t: f32| t.is_finite() && 0.5 * t > 0.0;
    let mut radii = Vec::with_capacity(point_count);
    if arrays & BIT_THICKNESS == 0 {
        if !usable(default_thickness) {
            return Err(r.error(
                24,
                format!(
                    "default thickness {default_thickness:?} must be finite and > {:?} (no thickness array)",
                    f32::from_bits(1)
                ),
            ));
        }
        radii.resize(point_count, 0.5 * default_thickness);
    } else {
        for _ in 0..point_count {
            let at = r.offset;
            let t = r.f32("the thickness array")?;
            if !usable(t) {
                return Err(
                    r.error(at, format!("thickness {t:?} must be finite and > {:?}", f32::from_bits(1)))
                );
            }
            radii.push(0.5 * t);
        }
    }
    let mut optional_len = 0usize;
    if arrays & BIT_TRANSPARENCY != 0 {
        optional_len += 4 * point_count;
    }
    if arrays & BIT_COLORS != 0 {
        optional_len += 12 * point_count;
    }
    if bytes.len() < r.offset + optional_len {
        return Err(r.error(bytes.len(), "file ends inside the transparency or colour array".into()));
    }
    let mut fibers = Vec::with_capacity(hair_count);
    let mut first = 0;
    for (hair, &n) in segments.iter().enumerate() {
        if n == 0 {
            return Err(r.error(points_at, format!("hair {hair} has 1 point, at least 2 are needed")));
        }
        let range = first..first + n + 1;
        let radius = radii[range.clone()].iter().map(|&r| f64::from(r)).sum::<f64>() / (n + 1) as f64;
        fibers.push(Fiber { points: points[range].to_vec(), radius: radius as f32, yarn: 0 });
        first += n + 1;
    }
    Ok(fibers)
}

/// Encodes fibers as cyHair bytes (segments, points and thickness arrays).
pub fn encode_hair(fibers: &[Fiber]) -> Result<Vec<u8>, String> {
    let mut segments = Vec::with_capacity(fibers.len());
    for (k, f) in fibers.iter().enumerate() {
        match u16::try_from(f.points.len().saturating_sub(1)) {
            Ok(n) if n >= 1 => segments.push(n),
            _ => return Err(format!("fiber {k} has {} points; cyHair needs 2 to 65536", f.points.len())),
        }
    }
    let point_count: usize = fibers.iter().map(|f| f.points.len()).sum();
    let (Ok(hairs), Ok(points)) = (u32::try_from(fibers.len()), u32::try_from(point_count)) else {
        return Err("too many fibers or points for cyHair's 32-bit counts".into());
    };
    let mut out = Vec::with_capacity(HAIR_HEADER_SIZE + 2 * fibers.len() + 16 * point_count);
    out.extend_from_slice(b"HAIR");
    out.extend_from_slice(&hairs.to_le_bytes());
    out.extend_from_slice(&points.to_le_bytes());
    out.extend_from_slice(&(BIT_SEGMENTS | BIT_POINTS | BIT_THICKNESS).to_le_bytes());
    let default_thickness = fibers.first().map_or(0.001, |f| 2.0 * f.radius);
    out.extend_from_slice(&1u32.to_le_bytes()); // default segments (unused: array present)
    out.extend_from_slice(&default_thickness.to_le_bytes());
    out.extend_from_slice(&1.0f32.to_le_bytes()); // default transparency
    for c in [1.0f32; 3] {
        out.extend_from_slice(&c.to_le_bytes());
    }
    let mut info = [0u8; 88];
    let text = b"twill fibers, cm; thickness = diameter";
    info[..text.len()].copy_from_slice(text);
    out.extend_from_slice(&info);
    debug_assert_eq!(out.len(), HAIR_HEADER_SIZE);
    for s in segments {
        out.extend_from_slice(&s.to_le_bytes());
    }
    for p in fibers.iter().flat_map(|f| &f.points) {
        for c in p.to_array() {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    for f in fibers {
        for _ in &f.points {
            out.extend_from_slice(&(2.0 * f.radius).to_le_bytes());
        }
    }
    Ok(out)
}

/// Writes `bytes` to `path` atomically (see [`crate::atomic_file`]).
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), FiberIoError> {
    crate::atomic_file::write_atomically(path, |w| w.write_all(bytes))
        .map_err(|source| FiberIoError::Io { file: path.to_owned(), source })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn sample_fibers() -> Vec<Fiber> {
        vec![
            Fiber {
                points: vec![Vec3::ZERO, Vec3::new(0.1, 0.2, -0.3), Vec3::new(1e-7, 3.5, 1.0)],
                radius: 0.0005,
                yarn: 0,
            },
            Fiber { points: vec![Vec3::splat(-1.25), Vec3::new(0.3, 0.1, 0.7)], radius: 0.0012, yarn: 0 },
        ]
    }

    #[test]
    fn mitsuba_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("fibers.txt");
        write_fibers(&path, &sample_fibers(), None).unwrap();
        assert_eq!(read_fibers(&path, None, None).unwrap(), sample_fibers());
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 1, "no temporary file left behind: {names:?}");
    }

    #[test]
    fn hair_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("fibers.hair");
        write_fibers(&path, &sample_fibers(), None).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[..4], b"HAIR");
        assert_eq!(bytes.len(), 128 + 2 * 2 + 5 * 12 + 5 * 4);
        assert_eq!(read_fibers(&path, None, None).unwrap(), sample_fibers());
    }

    #[test]
    fn mitsuba_accepts_comments_and_default_radius() {
        let text =
            "# header\n0 0 0\n1 0 0 # trailing\n# still the same fiber\n2 0 0\n\n\n0 1 0 0.5\n0 2 0 0.7\n";
        let f = parse_mitsuba(text, Path::new("a.txt"), Some(0.25)).unwrap();
        assert_eq!(f.len(), 2);
        assert_eq!(f[0].points.len(), 3);
        assert!((f[0].radius - 0.25).abs() < 1e-7);
        assert!((f[1].radius - 0.6).abs() < 1e-6);
    }

    #[test]
    fn mitsuba_errors_name_file_line_and_value() {
        let cases = [
            ("0 0 0 1\n0 x 0 1\n", "a.txt:2", "`x`"),
            ("0 0 0 1\n0 0 0 -1\n", "a.txt:2", "-1"),
            ("0 0 0 1\nNaN 0 0 1\n", "a.txt:2", "NaN"),
            ("0 0 0 1\n\n0 0 0 1\n1 1 1 1\n", "a.txt:1", "1 point"),
            ("0 0 0 1\n0 0\n", "a.txt:2", "2 values"),
            ("0 0 0 1 5\n", "a.txt:1", "`5`"),
            ("0 0 0\n1 1 1\n", "a.txt:1", "no radius"),
        ];
        for (text, place, value) in cases {
            let msg = parse_mitsuba(text, Path::new("a.txt"), None).unwrap_err().to_string();
            assert!(msg.contains(place) && msg.contains(value), "{text:?}: {msg}");
        }
    }

    #[test]
    fn hair_errors_name_offset_and_value() {
        let good = encode_hair(&sample_fibers()).unwrap();
        let p = Path::new("b.hair");
        let mut bad = good.clone();
        bad[4..8].copy_from_slice(&3u32.to_le_bytes());
        let msg = parse_hair(&bad, p).unwrap_err().to_string();
        assert!(msg.contains("b.hair at byte 8") && msg.contains("point count 5 disagrees"), "{msg}");
        let mut bad = good.clone();
        bad[8..12].copy_from_slice(&6u32.to_le_bytes());
        assert!(parse_hair(&bad, p).unwrap_err().to_string().contains("point count 6"));
        let mut bad = good.clone();
        let thickness_at = 128 + 4 + 60;
        bad[thickness_at..thickness_at + 4].copy_from_slice(&(-2.0f32).to_le_bytes());
        let msg = parse_hair(&bad, p).unwrap_err().to_string();
        assert!(msg.contains(&format!("byte {thickness_at}")) && msg.contains("-2"), "{msg}");
        let mut bad = good.clone();
        bad[128..130].copy_from_slice(&0u16.to_le_bytes());
        bad[130..132].copy_from_slice(&3u16.to_le_bytes());
        assert!(parse_hair(&bad, p).unwrap_err().to_string().contains("1 point"));
        let mut bad = good;
        bad[0] = b'X';
        assert!(parse_hair(&bad, p).unwrap_err().to_string().contains("signature"));
    }

    #[test]
    fn hair_headers_claiming_huge_counts_are_refused_before_allocating() {
        let p = Path::new("huge.hair");
        // A bare header (plus one point's worth of bytes) claiming a billion points.
        let mut header = encode_hair(&[]).unwrap();
        header.extend_from_slice(&[0; 12]);
        let mut bad = header.clone();
        bad[8..12].copy_from_slice(&1_000_000_000u32.to_le_bytes());
        let msg = parse_hair(&bad, p).unwrap_err().to_string();
        assert!(
            msg.contains("huge.hair at byte 8")
                && msg.contains("point count 1000000000")
                && msg.contains("at most 1 points"),
            "{msg}"
        );
        let mut bad = header;
        bad[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
        let msg = parse_hair(&bad, p).unwrap_err().to_string();
        assert!(
            msg.contains("huge.hair at byte 4")
                && msg.contains("hair count 4294967295")
                && msg.contains("at most 0 hairs"),
            "{msg}"
        );
    }

    /// Found by the `hair` fuzz target (fuzz/corpus/hair/regression-subnormal-thickness.hair):
    /// a thickness of the smallest positive f32 was accepted, but its radius, half of it, is 0.
    #[test]
    fn fuzz_regression_a_thickness_whose_half_is_zero_is_refused() {
        let p = Path::new("thin.hair");
        let tiny = f32::from_bits(1);
        // The minimized input: no segments or thickness arrays, default thickness `tiny`.
        let mut bytes = encode_hair(&sample_fibers()).unwrap();
        bytes[12..16].copy_from_slice(&BIT_POINTS.to_le_bytes());
        bytes[16..20].copy_from_slice(&2u32.to_le_bytes());
        bytes[20..24].copy_from_slice(&tiny.to_le_bytes());
        bytes.truncate(HAIR_HEADER_SIZE);
        bytes[4..8].copy_from_slice(&1u32.to_le_bytes());
        bytes[8..12].copy_from_slice(&3u32.to_le_bytes());
        bytes.extend(std::iter::repeat_n(0u8, 36));
        let msg = parse_hair(&bytes, p).unwrap_err().to_string();
        assert!(msg.contains("thin.hair at byte 24") && msg.contains("default thickness 1e-45"), "{msg}");
        // The same in the thickness array.
        let mut bytes = encode_hair(&sample_fibers()).unwrap();
        let thickness_at = 128 + 4 + 60 + 4;
        bytes[thickness_at..thickness_at + 4].copy_from_slice(&tiny.to_le_bytes());
        let msg = parse_hair(&bytes, p).unwrap_err().to_string();
        assert!(msg.contains(&format!("byte {thickness_at}")) && msg.contains("thickness 1e-45"), "{msg}");
        // Twice that is the thinnest fiber read, and it writes back.
        bytes[thickness_at..thickness_at + 4].copy_from_slice(&(2.0 * tiny).to_le_bytes());
        let fibers = parse_hair(&bytes, p).unwrap();
        assert_eq!(parse_hair(&encode_hair(&fibers).unwrap(), p).unwrap(), fibers);
    }

    #[test]
    fn truncations_and_random_bytes_never_panic() {
        let p = Path::new("fuzz");
        let good = encode_hair(&sample_fibers()).unwrap();
        for len in 0..good.len() {
            assert!(parse_hair(&good[..len], p).is_err(), "truncated to {len} bytes parsed");
        }
        let text = format_mitsuba(&sample_fibers());
        for len in 0..text.len() {
            let _ = parse_mitsuba(&text[..len], p, None);
        }
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        for _ in 0..2000 {
            let mut bytes = good.clone();
            for _ in 0..rng.random_range(1..8) {
                let i = rng.random_range(0..bytes.len());
                bytes[i] = rng.random();
            }
            let _ = parse_hair(&bytes, p);
            let noise: Vec<u8> = (0..rng.random_range(0..300)).map(|_| rng.random()).collect();
            let _ = parse_hair(&noise, p);
            let _ = parse_mitsuba(&String::from_utf8_lossy(&noise), p, Some(0.1));
        }
    }

    #[test]
    fn exemplar_from_fibers_has_one_other_yarn() {
        let ex = exemplar_from_fibers(sample_fibers(), Tiling::AsIs, BlockGrid { nx: 1, ny: 1 });
        assert_eq!(ex.yarns, vec![Yarn { role: YarnRole::Other, material: 0 }]);
        assert_eq!(ex.segment_count(), 3);
    }
}
