//! The bake file: named arrays, keyed by a content hash of their inputs, checksummed, written
//! atomically, and a cache directory of such files.
//!
//! How it works:
//! - Cache keys are [`ContentHash`]es (BLAKE3) built with a [`Hasher`] that frames every input
//!   unambiguously: integers little-endian, floats by their bits (so -0.0 ≠ 0.0 and NaN
//!   payloads differ), strings and slices length-prefixed, and serde values through their TOML
//!   text (deterministic: fields in declaration order, floats printed round-trip exact). Each
//!   stage hashes its name, a `STAGE_VERSION` constant bumped whenever its code changes
//!   results, and the keys or values of everything it reads; the whole file's key hashes the
//!   stage keys.
//! - Layout, all little-endian:
//!
//!   ```text
//!   0   magic "TWILLBK\0"            8 bytes
//!   8   format version               u32   (FORMAT_VERSION)
//!   12  section count                u32
//!   16  file key                     32 bytes
//!   48  body length                  u64   (bytes after the 96-byte header)
//!   56  reserved                     u64   (0)
//!   64  checksum                     32 bytes: BLAKE3 of bytes 0..64 followed by the body
//!   96  body: the section directory, then every section's data, each padded to 8 bytes
//!   ```
//!
//!   A directory entry is: name length u8, name (UTF-8), element type u8 ([`ElementType`]),
//!   rank u8, section key (32 bytes), the dims (u64 each), the data's offset from the file start
//!   (u64) and its length in bytes (u64).
//! - [`BakeFile::open`] reads the whole file and checks, in order, the magic, the version, the
//!   length (→ [`BakeFileError::Truncated`]), the checksum (any flipped byte, header fields
//!   included, → [`BakeFileError::Corrupt`]), the directory's internal consistency, and finally
//!   the key (→ [`BakeFileError::Stale`]); nothing is returned from a file that fails any check.
//! - [`BakeWriter::write`] goes through [`crate::atomic_file::write_atomically`]: the checksum is
//!   computed in a first pass over the serialized body, the file written in a second, so a big
//!   bake is never copied in memory; a failed write (full disk, unwritable directory) leaves
//!   no file and no temporary behind.
//! - [`Cache`] keeps files named `<key hex>.twillbake` in one directory; [`Cache::load`] deletes
//!   a file that is corrupt, truncated, stale or of another version (logging why) and returns
//!   `None`, so the caller recomputes.

use std::collections::HashSet;
use std::fmt;
use std::fs;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use crate::atomic_file::{temporary_of, write_atomically, writer_is_gone};
use crate::fabric::{Exemplar, Tiling, YarnRole};

/// First bytes of every bake file.
pub const MAGIC: [u8; 8] = *b"TWILLBK\0";
/// The format version this build reads and writes.
pub const FORMAT_VERSION: u32 = 1;
/// Size of the fixed header.
pub const HEADER_LEN: usize = 96;
/// File name extension of cached bakes.
pub const CACHE_EXTENSION: &str = "twillbake";

const CHECKSUM_AT: usize = 64;

/// A 32-byte BLAKE3 content hash: the cache key of a bake or of one stage.
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ContentHash(pub [u8; 32]);

impl ContentHash {
    /// Lower-case hex, 64 characters.
    #[must_use]
    pub fn to_hex(&self) -> String {
        use fmt::Write as _;
        self.0.iter().fold(String::with_capacity(64), |mut s, b| {
            let _ = write!(s, "{b:02x}");
            s
        })
    }
}

impl fmt::Display for ContentHash {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.to_hex())
    }
}

impl fmt::Debug for ContentHash {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "ContentHash({})", self.to_hex())
    }
}

/// Builds a [`ContentHash`] from typed inputs, framed so that different input sequences never
/// produce the same byte stream.
#[derive(Debug, Clone)]
pub struct Hasher(blake3::Hasher);

impl Hasher {
    /// A hasher for one purpose (e.g. `"twill.bake.svf"`): the domain is hashed first.
    #[must_use]
    pub fn new(domain: &str) -> Self {
        let mut h = Self(blake3::Hasher::new());
        h.str(domain);
        h
    }

    fn raw(&mut self, tag: u8, bytes: &[u8]) -> &mut Self {
        self.0.update(&[tag]);
        self.0.update(bytes);
        self
    }

    pub fn u64(&mut self, v: u64) -> &mut Self {
        self.raw(1, &v.to_le_bytes())
    }

    pub fn u32(&mut self, v: u32) -> &mut Self {
        self.raw(2, &v.to_le_bytes())
    }

    pub fn usize(&mut self, v: usize) -> &mut Self {
        self.raw(3, &(v as u64).to_le_bytes())
    }

    pub fn bool(&mut self, v: bool) -> &mut Self {
        self.raw(4, &[u8::from(v)])
    }

    /// By bits.
    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.raw(5, &v.to_bits().to_le_bytes())
    }

    /// By bits.
    pub fn f32(&mut self, v: f32) -> &mut Self {
        self.raw(6, &v.to_bits().to_le_bytes())
    }

    /// Length-prefixed UTF-8.
    pub fn str(&mut self, s: &str) -> &mut Self {
        self.raw(7, &(s.len() as u64).to_le_bytes());
        self.0.update(s.as_bytes());
        self
    }

    /// Length-prefixed raw bytes.
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        self.raw(8, &(b.len() as u64).to_le_bytes());
        self.0.update(b);
        self
    }

    /// Length-prefixed, each by bits.
    pub fn f32s(&mut self, v: &[f32]) -> &mut Self {
        self.raw(9, &(v.len() as u64).to_le_bytes());
        for x in v {
            self.0.update(&x.to_bits().to_le_bytes());
        }
        self
    }

    /// Length-prefixed, each by bits.
    pub fn f64s(&mut self, v: &[f64]) -> &mut Self {
        self.raw(10, &(v.len() as u64).to_le_bytes());
        for x in v {
            self.0.update(&x.to_bits().to_le_bytes());
        }
        self
    }

    /// Another hash (a stage key feeding a later stage or the file key).
    pub fn hash(&mut self, h: &ContentHash) -> &mut Self {
        self.raw(11, &h.0)
    }

    /// A stage's identity: its name and code version.
    pub fn stage(&mut self, name: &str, version: u32) -> &mut Self {
        self.raw(12, &[]);
        self.str(name).u32(version)
    }

    /// A serde value through its TOML text (field order as declared, floats round-trip exact).
    pub fn serde<T: serde::Serialize>(&mut self, value: &T) -> Result<&mut Self, toml::ser::Error> {
        #[derive(serde::Serialize)]
        struct Wrapped<'a, T> {
            value: &'a T,
        }
        let text = toml::to_string(&Wrapped { value })?;
        self.raw(13, &[]);
        Ok(self.str(&text))
    }

    /// Every number that defines an exemplar's geometry, yarns, tiling and blocks.
    pub fn exemplar(&mut self, e: &Exemplar) -> &mut Self {
        self.raw(14, &[]).usize(e.fibers.len());
        for f in &e.fibers {
            self.f32(f.radius).u32(f.yarn).usize(f.points.len());
            for p in &f.points {
                self.f32(p.x).f32(p.y).f32(p.z);
            }
        }
        self.usize(e.yarns.len());
        for y in &e.yarns {
            let role = match y.role {
                YarnRole::Warp => 0,
                YarnRole::Weft => 1,
                YarnRole::Other => 2,
            };
            self.u32(role).u32(y.material);
        }
        match e.tiling {
            Tiling::Periodic { period } => self.u32(0).f32(period.x).f32(period.y),
            Tiling::AsIs => self.u32(1),
        };
        self.u32(e.blocks.nx).u32(e.blocks.ny)
    }

    #[must_use]
    pub fn finish(&self) -> ContentHash {
        ContentHash(*self.0.finalize().as_bytes())
    }
}

/// Element type of a section's array, as stored (one byte).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum ElementType {
    F32 = 1,
    U32 = 2,
    U16 = 3,
    U8 = 4,
    F64 = 5,
}

impl ElementType {
    #[must_use]
    pub fn size(self) -> usize {
        match self {
            Self::F32 | Self::U32 => 4,
            Self::U16 => 2,
            Self::U8 => 1,
            Self::F64 => 8,
        }
    }

    fn from_tag(tag: u8) -> Option<Self> {
        Some(match tag {
            1 => Self::F32,
            2 => Self::U32,
            3 => Self::U16,
            4 => Self::U8,
            5 => Self::F64,
            _ => return None,
        })
    }
}

/// The elements of an array.
#[derive(Debug, Clone, PartialEq)]
pub enum ArrayData {
    F32(Vec<f32>),
    U32(Vec<u32>),
    U16(Vec<u16>),
    U8(Vec<u8>),
    F64(Vec<f64>),
}

impl ArrayData {
    #[must_use]
    pub fn len(&self) -> usize {
        match self {
            Self::F32(v) => v.len(),
            Self::U32(v) => v.len(),
            Self::U16(v) => v.len(),
            Self::U8(v) => v.len(),
            Self::F64(v) => v.len(),
        }
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    #[must_use]
    pub fn element_type(&self) -> ElementType {
        match self {
            Self::F32(_) => ElementType::F32,
            Self::U32(_) => ElementType::U32,
            Self::U16(_) => ElementType::U16,
            Self::U8(_) => ElementType::U8,
            Self::F64(_) => ElementType::F64,
        }
    }

    fn write_le(&self, w: &mut impl Write) -> io::Result<()> {
        // Little-endian hosts write the memory as is; others convert element by element.
        fn put<T: bytemuck::Pod, const N: usize>(
            w: &mut impl Write,
            v: &[T],
            le: impl Fn(&T) -> [u8; N],
        ) -> io::Result<()> {
            if cfg!(target_endian = "little") {
                w.write_all(bytemuck::cast_slice(v))
            } else {
                v.iter().try_for_each(|x| w.write_all(&le(x)))
            }
        }
        match self {
            Self::F32(v) => put(w, v, |x| x.to_le_bytes()),
            Self::U32(v) => put(w, v, |x| x.to_le_bytes()),
            Self::U16(v) => put(w, v, |x| x.to_le_bytes()),
            Self::U8(v) => w.write_all(v),
            Self::F64(v) => put(w, v, |x| x.to_le_bytes()),
        }
    }

    fn read_le(ty: ElementType, bytes: &[u8]) -> Self {
        fn get<const N: usize, T>(bytes: &[u8], from: impl Fn([u8; N]) -> T) -> Vec<T> {
            bytes.chunks_exact(N).map(|c| from(c.try_into().expect("chunks_exact gives N bytes"))).collect()
        }
        match ty {
            ElementType::F32 => Self::F32(get(bytes, f32::from_le_bytes)),
            ElementType::U32 => Self::U32(get(bytes, u32::from_le_bytes)),
            ElementType::U16 => Self::U16(get(bytes, u16::from_le_bytes)),
            ElementType::U8 => Self::U8(bytes.to_vec()),
            ElementType::F64 => Self::F64(get(bytes, f64::from_le_bytes)),
        }
    }
}

/// An n-dimensional array (row-major: the last dim varies fastest).
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    shape: Vec<u64>,
    data: ArrayData,
}

impl Array {
    /// An array of `shape` holding `data`; `None` if the element count does not match or the
    /// rank exceeds 255.
    #[must_use]
    pub fn new(shape: &[usize], data: ArrayData) -> Option<Self> {
        let count = shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))?;
        (count == data.len() && shape.len() <= 255)
            .then(|| Self { shape: shape.iter().map(|&d| d as u64).collect(), data })
    }

    /// A one-dimensional array.
    #[must_use]
    pub fn vector(data: ArrayData) -> Self {
        Self { shape: vec![data.len() as u64], data }
    }

    #[must_use]
    pub fn shape(&self) -> &[u64] {
        &self.shape
    }

    #[must_use]
    pub fn data(&self) -> &ArrayData {
        &self.data
    }

    #[must_use]
    pub fn into_data(self) -> ArrayData {
        self.data
    }

    #[must_use]
    pub fn as_f32(&self) -> Option<&[f32]> {
        if let ArrayData::F32(v) = &self.data { Some(v) } else { None }
    }

    #[must_use]
    pub fn as_u32(&self) -> Option<&[u32]> {
        if let ArrayData::U32(v) = &self.data { Some(v) } else { None }
    }

    #[must_use]
    pub fn as_u16(&self) -> Option<&[u16]> {
        if let ArrayData::U16(v) = &self.data { Some(v) } else { None }
    }

    #[must_use]
    pub fn as_u8(&self) -> Option<&[u8]> {
        if let ArrayData::U8(v) = &self.data { Some(v) } else { None }
    }

    #[must_use]
    pub fn as_f64(&self) -> Option<&[f64]> {
        if let ArrayData::F64(v) = &self.data { Some(v) } else { None }
    }

    fn byte_len(&self) -> u64 {
        (self.data.len() * self.data.element_type().size()) as u64
    }
}

/// One named array of a bake file with the cache key of the stage that produced it.
#[derive(Debug, Clone, PartialEq)]
pub struct Section {
    pub name: String,
    pub key: ContentHash,
    pub array: Array,
}

/// Why a bake file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum BakeFileError {
    #[error("{}: bake file not found", file.display())]
    NotFound { file: PathBuf },
    #[error("{} is corrupt at byte {offset}: {what}", file.display())]
    Corrupt { file: PathBuf, offset: u64, what: String },
    #[error("{} is truncated: expected {expected} bytes, found {got}", file.display())]
    Truncated { file: PathBuf, expected: u64, got: u64 },
    #[error("{} is stale: baked from other inputs (key {found}, wanted {expected})", file.display())]
    Stale { file: PathBuf, found: ContentHash, expected: ContentHash },
    #[error("{} has bake format version {found}; this build reads version {supported}", file.display())]
    VersionMismatch { file: PathBuf, found: u32, supported: u32 },
    #[error("{}: {source}", file.display())]
    Io { file: PathBuf, source: io::Error },
    #[error("cache directory {} cannot be used: {source}", dir.display())]
    CacheDir { dir: PathBuf, source: io::Error },
    #[error("bake section {name:?}: {what}")]
    InvalidSection { name: String, what: String },
}

/// Collects sections and writes them as one bake file. A section is either an [`Array`] held
/// in memory or a byte section [`BakeWriter::streamed_section`] writes on demand (a serialized
/// stage), so a bake is written without an encoded copy of itself in memory.
pub struct BakeWriter<'a> {
    key: ContentHash,
    sections: Vec<PendingSection<'a>>,
}

/// Writes a streamed section's bytes to the sink it is given.
type WriteBytes<'a> = Box<dyn Fn(&mut dyn Write) -> io::Result<()> + 'a>;

/// A section's data as the writer holds it.
enum Payload<'a> {
    Array(Array),
    /// `len` bytes (element type u8), produced by `write` each time the body is written.
    Streamed {
        len: u64,
        write: WriteBytes<'a>,
    },
}

struct PendingSection<'a> {
    name: String,
    key: ContentHash,
    payload: Payload<'a>,
}

impl PendingSection<'_> {
    fn shape(&self) -> Vec<u64> {
        match &self.payload {
            Payload::Array(a) => a.shape.clone(),
            Payload::Streamed { len, .. } => vec![*len],
        }
    }

    fn element_type(&self) -> ElementType {
        match &self.payload {
            Payload::Array(a) => a.data.element_type(),
            Payload::Streamed { .. } => ElementType::U8,
        }
    }

    fn byte_len(&self) -> u64 {
        match &self.payload {
            Payload::Array(a) => a.byte_len(),
            Payload::Streamed { len, .. } => *len,
        }
    }

    /// The data's bytes; a streamed section that writes another length than it announced is
    /// an error (the directory already holds the length).
    fn write_data(&self, w: &mut dyn Write) -> io::Result<()> {
        match &self.payload {
            Payload::Array(a) => a.data.write_le(&mut { w }),
            Payload::Streamed { len, write } => {
                let mut counted = CountingWriter { inner: w, count: 0 };
                write(&mut counted)?;
                if counted.count == *len {
                    Ok(())
                } else {
                    Err(io::Error::other(format!(
                        "section {:?} wrote {} bytes, announced {len}",
                        self.name, counted.count
                    )))
                }
            }
        }
    }
}

impl fmt::Debug for BakeWriter<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let names: Vec<&str> = self.sections.iter().map(|s| s.name.as_str()).collect();
        f.debug_struct("BakeWriter").field("key", &self.key).field("sections", &names).finish()
    }
}

/// A writer that counts what passes through it.
struct CountingWriter<'w> {
    inner: &'w mut dyn Write,
    count: u64,
}

impl Write for CountingWriter<'_> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.count += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

fn pad8(n: u64) -> u64 {
    n.div_ceil(8) * 8
}

impl<'a> BakeWriter<'a> {
    /// A file whose cache key is `key`.
    #[must_use]
    pub fn new(key: ContentHash) -> Self {
        Self { key, sections: Vec::new() }
    }

    /// Adds a section produced by the stage whose cache key is `key`.
    #[must_use]
    pub fn section(mut self, name: &str, key: ContentHash, array: Array) -> Self {
        self.sections.push(PendingSection { name: name.to_owned(), key, payload: Payload::Array(array) });
        self
    }

    /// Adds a byte section of `len` bytes that `write` produces when the file is written (it is
    /// called twice: for the checksum, then for the file). It must write exactly `len` bytes,
    /// the same each time; a different count fails the write.
    #[must_use]
    pub fn streamed_section(
        mut self,
        name: &str,
        key: ContentHash,
        len: u64,
        write: impl Fn(&mut dyn Write) -> io::Result<()> + 'a,
    ) -> Self {
        self.sections.push(PendingSection {
            name: name.to_owned(),
            key,
            payload: Payload::Streamed { len, write: Box::new(write) },
        });
        self
    }

    #[must_use]
    pub fn key(&self) -> ContentHash {
        self.key
    }

    fn validate(&self) -> Result<(), BakeFileError> {
        let mut seen = HashSet::new();
        for s in &self.sections {
            let bad =
                |what: &str| Err(BakeFileError::InvalidSection { name: s.name.clone(), what: what.into() });
            if s.name.is_empty() || s.name.len() > 255 {
                return bad("names must be 1 to 255 bytes long");
            }
            if !seen.insert(s.name.as_str()) {
                return bad("appears twice");
            }
        }
        if self.sections.len() > u32::MAX as usize {
            return Err(BakeFileError::InvalidSection {
                name: String::new(),
                what: "too many sections".into(),
            });
        }
        Ok(())
    }

    fn directory_len(&self) -> u64 {
        self.sections.iter().map(|s| (3 + s.name.len() + 32 + 8 * s.shape().len() + 16) as u64).sum()
    }

    /// The length of what [`Self::write_body`] writes.
    fn body_len(&self) -> u64 {
        let data: u64 = self.sections.iter().map(|s| pad8(s.byte_len())).sum();
        pad8(HEADER_LEN as u64 + self.directory_len()) + data - HEADER_LEN as u64
    }

    /// Everything after the header: directory, then data, each data block padded to 8 bytes.
    fn write_body(&self, w: &mut impl Write) -> io::Result<u64> {
        let mut offset = pad8(HEADER_LEN as u64 + self.directory_len());
        for s in &self.sections {
            let shape = s.shape();
            w.write_all(&[s.name.len() as u8])?;
            w.write_all(s.name.as_bytes())?;
            w.write_all(&[s.element_type() as u8, shape.len() as u8])?;
            w.write_all(&s.key.0)?;
            for d in &shape {
                w.write_all(&d.to_le_bytes())?;
            }
            w.write_all(&offset.to_le_bytes())?;
            w.write_all(&s.byte_len().to_le_bytes())?;
            offset = pad8(offset + s.byte_len());
        }
        let zeros = [0u8; 8];
        let dir_end = HEADER_LEN as u64 + self.directory_len();
        w.write_all(&zeros[..(pad8(dir_end) - dir_end) as usize])?;
        for s in &self.sections {
            s.write_data(w)?;
            let n = s.byte_len();
            w.write_all(&zeros[..(pad8(n) - n) as usize])?;
        }
        Ok(offset - HEADER_LEN as u64)
    }

    fn header_prefix(&self, body_len: u64) -> [u8; CHECKSUM_AT] {
        let mut h = [0u8; CHECKSUM_AT];
        h[0..8].copy_from_slice(&MAGIC);
        h[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
        h[12..16].copy_from_slice(&(self.sections.len() as u32).to_le_bytes());
        h[16..48].copy_from_slice(&self.key.0);
        h[48..56].copy_from_slice(&body_len.to_le_bytes());
        h
    }

    /// Serializes the whole file to `w` (two passes over the data: checksum, then bytes; the
    /// body's length follows from the directory).
    pub fn write_to(&self, w: &mut impl Write) -> Result<(), BakeFileError> {
        self.validate()?;
        let io_err = |source| BakeFileError::Io { file: PathBuf::from("<stream>"), source };
        let prefix = self.header_prefix(self.body_len());
        let mut hasher = blake3::Hasher::new();
        hasher.update(&prefix);
        self.write_body(&mut hasher).map_err(io_err)?;
        (|| {
            w.write_all(&prefix)?;
            w.write_all(hasher.finalize().as_bytes())?;
            self.write_body(w).map(|_| ())
        })()
        .map_err(io_err)
    }

    /// Writes the file atomically (temporary file beside `path`, then rename).
    pub fn write(&self, path: &Path) -> Result<(), BakeFileError> {
        self.validate()?;
        let mut inner: Option<BakeFileError> = None;
        let result = write_atomically(path, |w| {
            self.write_to(w).map_err(|e| match e {
                BakeFileError::Io { source, .. } => source,
                other => {
                    inner = Some(other);
                    io::Error::other("invalid section")
                }
            })
        });
        match (result, inner) {
            (Ok(()), _) => Ok(()),
            (Err(_), Some(e)) => Err(e),
            (Err(source), None) => Err(BakeFileError::Io { file: path.to_owned(), source }),
        }
    }
}

/// A bake file that passed every check.
#[derive(Debug, Clone)]
pub struct BakeFile {
    path: PathBuf,
    key: ContentHash,
    sections: Vec<Section>,
}

fn read_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

fn read_u64(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

/// A cursor over the checked body that reports overruns as corruption.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    file: &'a Path,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], BakeFileError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len()).ok_or_else(|| {
            BakeFileError::Corrupt {
                file: self.file.to_owned(),
                offset: self.at as u64,
                what: format!("{what} runs past the end of the file"),
            }
        })?;
        let out = &self.bytes[self.at..end];
        self.at = end;
        Ok(out)
    }

    fn u8(&mut self, what: &str) -> Result<u8, BakeFileError> {
        Ok(self.take(1, what)?[0])
    }

    fn u64(&mut self, what: &str) -> Result<u64, BakeFileError> {
        Ok(read_u64(self.take(8, what)?, 0))
    }
}

impl BakeFile {
    /// Opens `path` and checks everything, including that its key is `expected_key`.
    pub fn open(path: &Path, expected_key: ContentHash) -> Result<Self, BakeFileError> {
        let file = Self::open_unkeyed(path)?;
        if file.key == expected_key {
            Ok(file)
        } else {
            Err(BakeFileError::Stale { file: path.to_owned(), found: file.key, expected: expected_key })
        }
    }

    /// Opens `path` and checks its integrity (magic, version, length, checksum, directory) but
    /// not its key: for reusing the sections whose own keys still match.
    pub fn open_unkeyed(path: &Path) -> Result<Self, BakeFileError> {
        let bytes = fs::read(path).map_err(|source| {
            if source.kind() == io::ErrorKind::NotFound {
                BakeFileError::NotFound { file: path.to_owned() }
            } else {
                BakeFileError::Io { file: path.to_owned(), source }
            }
        })?;
        Self::parse(path, &bytes)
    }

    /// Checks and decodes file contents; `path` is only used in errors.
    pub fn parse(path: &Path, bytes: &[u8]) -> Result<Self, BakeFileError> {
        let file = path.to_owned();
        let corrupt = |offset: usize, what: String| BakeFileError::Corrupt {
            file: path.to_owned(),
            offset: offset as u64,
            what,
        };
        let got = bytes.len() as u64;
        if bytes.len() < MAGIC.len() {
            return Err(BakeFileError::Truncated { file, expected: HEADER_LEN as u64, got });
        }
        if bytes[..8] != MAGIC {
            return Err(corrupt(0, format!("magic bytes {:02x?} are not {MAGIC:02x?}", &bytes[..8])));
        }
        if bytes.len() < 12 {
            return Err(BakeFileError::Truncated { file, expected: HEADER_LEN as u64, got });
        }
        let version = read_u32(bytes, 8);
        if version != FORMAT_VERSION {
            return Err(BakeFileError::VersionMismatch { file, found: version, supported: FORMAT_VERSION });
        }
        if bytes.len() < HEADER_LEN {
            return Err(BakeFileError::Truncated { file, expected: HEADER_LEN as u64, got });
        }
        let body_len = read_u64(bytes, 48);
        let expected = (HEADER_LEN as u64).saturating_add(body_len);
        if got < expected {
            return Err(BakeFileError::Truncated { file, expected, got });
        }
        if got > expected {
            return Err(corrupt(
                48,
                format!("body length {body_len} leaves {} trailing bytes", got - expected),
            ));
        }
        let mut hasher = blake3::Hasher::new();
        hasher.update(&bytes[..CHECKSUM_AT]);
        hasher.update(&bytes[HEADER_LEN..]);
        if hasher.finalize().as_bytes() != &bytes[CHECKSUM_AT..HEADER_LEN] {
            return Err(corrupt(CHECKSUM_AT, "checksum does not match the contents".into()));
        }
        let reserved = read_u64(bytes, 56);
        if reserved != 0 {
            return Err(corrupt(56, format!("reserved field is {reserved}, not 0")));
        }
        let count = read_u32(bytes, 12) as usize;
        let key = ContentHash(bytes[16..48].try_into().expect("32 bytes"));
        let mut r = Reader { bytes, at: HEADER_LEN, file: path };
        let mut sections = Vec::with_capacity(count.min(1024));
        let mut seen = HashSet::new();
        for index in 0..count {
            let entry_at = r.at;
            let name_len = r.u8("section name length")? as usize;
            let name = std::str::from_utf8(r.take(name_len, "section name")?)
                .map_err(|_| corrupt(entry_at + 1, format!("section {index} name is not UTF-8")))?
                .to_owned();
            let type_at = r.at;
            let tag = r.u8("element type")?;
            let ty = ElementType::from_tag(tag).ok_or_else(|| {
                corrupt(type_at, format!("section {name:?} has unknown element type {tag}"))
            })?;
            let rank = r.u8("rank")? as usize;
            let section_key = ContentHash(r.take(32, "section key")?.try_into().expect("32 bytes"));
            let mut shape = Vec::with_capacity(rank);
            for _ in 0..rank {
                shape.push(r.u64("dimension")?);
            }
            let offset_at = r.at;
            let offset = r.u64("data offset")?;
            let len = r.u64("data length")?;
            let count = shape.iter().try_fold(1u64, |a, &d| a.checked_mul(d));
            let bytes_needed = count.and_then(|c| c.checked_mul(ty.size() as u64));
            if bytes_needed != Some(len) {
                return Err(corrupt(
                    offset_at,
                    format!("section {name:?}: shape {shape:?} of {ty:?} does not fill {len} bytes"),
                ));
            }
            let data = offset
                .checked_add(len)
                .filter(|&end| offset >= HEADER_LEN as u64 && end <= got)
                .map(|end| &bytes[offset as usize..end as usize])
                .ok_or_else(|| {
                    corrupt(
                        offset_at,
                        format!(
                            "section {name:?}: data at {offset}+{len} lies outside the file ({got} bytes)"
                        ),
                    )
                })?;
            if !seen.insert(name.clone()) {
                return Err(corrupt(entry_at, format!("section {name:?} appears twice")));
            }
            let array = Array { shape, data: ArrayData::read_le(ty, data) };
            sections.push(Section { name, key: section_key, array });
        }
        Ok(Self { path: path.to_owned(), key, sections })
    }

    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }

    #[must_use]
    pub fn key(&self) -> ContentHash {
        self.key
    }

    #[must_use]
    pub fn sections(&self) -> &[Section] {
        &self.sections
    }

    /// The section called `name`.
    #[must_use]
    pub fn section(&self, name: &str) -> Option<&Section> {
        self.sections.iter().find(|s| s.name == name)
    }

    /// The section called `name` if the stage that wrote it had cache key `key`.
    #[must_use]
    pub fn section_if_current(&self, name: &str, key: ContentHash) -> Option<&Array> {
        self.section(name).filter(|s| s.key == key).map(|s| &s.array)
    }
}

/// A directory of bake files named by their cache keys, at most [`Cache::limit_bytes`] in all.
///
/// How it works: a load that hits touches the file's modification time, so modification order
/// is use order; after every store the least recently used entries are deleted until the
/// folder fits the limit again (the entry just stored is never deleted, even when it alone is
/// larger). Opening the cache deletes temporary files that a killed writer left behind
/// (`.NAME.PID.tmp` whose process is gone, or older than a day where that cannot be told).
#[derive(Debug, Clone)]
pub struct Cache {
    dir: PathBuf,
    limit_bytes: u64,
}

/// The default size limit of a stage cache: 4 GiB.
pub const DEFAULT_CACHE_LIMIT_BYTES: u64 = 4 << 30;

/// What a cache holds ([`Cache::info`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CacheInfo {
    pub entries: usize,
    pub bytes: u64,
    pub limit_bytes: u64,
}

impl Cache {
    /// Uses `dir` with the default size limit, creating it if missing; fails clearly if it
    /// cannot be created or written.
    pub fn new(dir: &Path) -> Result<Self, BakeFileError> {
        Self::with_limit(dir, DEFAULT_CACHE_LIMIT_BYTES)
    }

    /// [`Cache::new`] holding at most `limit_bytes` of entries.
    pub fn with_limit(dir: &Path, limit_bytes: u64) -> Result<Self, BakeFileError> {
        let cache_err = |source| BakeFileError::CacheDir { dir: dir.to_owned(), source };
        fs::create_dir_all(dir).map_err(cache_err)?;
        // Probe that files can be created here (read-only mounts, permissions).
        let probe = dir.join(format!(".twill-write-probe.{}", std::process::id()));
        fs::write(&probe, b"probe").map_err(cache_err)?;
        let _ = fs::remove_file(&probe);
        let cache = Self { dir: dir.to_owned(), limit_bytes };
        cache.remove_leftover_temporaries();
        Ok(cache)
    }

    #[must_use]
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    #[must_use]
    pub fn limit_bytes(&self) -> u64 {
        self.limit_bytes
    }

    /// `<dir>/<key hex>.twillbake`.
    #[must_use]
    pub fn path_for(&self, key: ContentHash) -> PathBuf {
        self.dir.join(format!("{}.{CACHE_EXTENSION}", key.to_hex()))
    }

    /// The cached bake for `key`, or `None` (recompute) if there is none or it is unusable;
    /// unusable files (corrupt, truncated, stale, other version) are deleted, and why is logged.
    /// A hit counts as a use (for the least-recently-used eviction).
    #[must_use]
    pub fn load(&self, key: ContentHash) -> Option<BakeFile> {
        let path = self.path_for(key);
        match BakeFile::open(&path, key) {
            Ok(file) => {
                let touched = fs::File::options()
                    .append(true)
                    .open(&path)
                    .and_then(|f| f.set_modified(std::time::SystemTime::now()));
                if let Err(e) = touched {
                    log::debug!("{}: could not mark as used: {e}", path.display());
                }
                Some(file)
            }
            Err(BakeFileError::NotFound { .. }) => None,
            Err(e @ BakeFileError::Io { .. }) => {
                log::warn!("{e}; baking again");
                None
            }
            Err(e) => {
                log::warn!("{e}; deleting it and baking again");
                if let Err(rm) = fs::remove_file(&path) {
                    log::warn!("{}: could not delete: {rm}", path.display());
                }
                None
            }
        }
    }

    /// Writes `writer` atomically under its key, then evicts the least recently used entries
    /// beyond the limit; returns the path.
    pub fn store(&self, writer: &BakeWriter) -> Result<PathBuf, BakeFileError> {
        let path = self.path_for(writer.key());
        writer.write(&path)?;
        self.evict_beyond_limit(&path);
        Ok(path)
    }

    /// Entries and their total size.
    #[must_use]
    pub fn info(&self) -> CacheInfo {
        let entries = self.entries();
        CacheInfo {
            entries: entries.len(),
            bytes: entries.iter().map(|e| e.1).sum(),
            limit_bytes: self.limit_bytes,
        }
    }

    /// Deletes every entry; returns how many were deleted.
    pub fn clear(&self) -> Result<usize, BakeFileError> {
        let mut removed = 0;
        for (path, ..) in self.entries() {
            fs::remove_file(&path).map_err(|source| BakeFileError::Io { file: path, source })?;
            removed += 1;
        }
        Ok(removed)
    }

    /// `(path, bytes, last use)` of every entry, least recently used first.
    fn entries(&self) -> Vec<(PathBuf, u64, std::time::SystemTime)> {
        let Ok(dir) = fs::read_dir(&self.dir) else { return Vec::new() };
        let mut entries: Vec<_> = dir
            .filter_map(Result::ok)
            .filter(|e| e.path().extension().is_some_and(|x| x == CACHE_EXTENSION))
            .filter_map(|e| {
                let meta = e.metadata().ok().filter(fs::Metadata::is_file)?;
                Some((e.path(), meta.len(), meta.modified().ok()?))
            })
            .collect();
        entries.sort_by(|a, b| a.2.cmp(&b.2).then_with(|| a.0.cmp(&b.0)));
        entries
    }

    fn evict_beyond_limit(&self, keep: &Path) {
        let entries = self.entries();
        let mut total: u64 = entries.iter().map(|e| e.1).sum();
        for (path, bytes, _) in entries {
            if total <= self.limit_bytes {
                break;
            }
            if path == keep {
                continue;
            }
            match fs::remove_file(&path) {
                Ok(()) => {
                    log::info!("{}: evicted from the stage cache (least recently used)", path.display());
                    total -= bytes;
                }
                Err(e) => log::warn!("{}: could not evict: {e}", path.display()),
            }
        }
    }

    /// Deletes `.NAME.PID.tmp` files of cache entries whose writer is gone (see the type's docs).
    fn remove_leftover_temporaries(&self) {
        let Ok(dir) = fs::read_dir(&self.dir) else { return };
        for entry in dir.filter_map(Result::ok) {
            let file_name = entry.file_name().to_string_lossy().into_owned();
            let Some((name, pid)) = temporary_of(&file_name) else { continue };
            let entry_name = Path::new(name).extension().is_some_and(|x| x == CACHE_EXTENSION);
            if entry_name && writer_is_gone(pid, entry.metadata().and_then(|m| m.modified()).ok()) {
                match fs::remove_file(entry.path()) {
                    Ok(()) => log::info!("{}: removed a killed writer's leftover", entry.path().display()),
                    Err(e) => log::warn!("{}: could not remove: {e}", entry.path().display()),
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(s: &str) -> ContentHash {
        Hasher::new("test").str(s).finish()
    }

    fn sample_writer() -> BakeWriter<'static> {
        BakeWriter::new(key("file"))
            .section(
                "a.f32",
                key("a"),
                Array::new(&[2, 3], ArrayData::F32(vec![1.0, -2.5, f32::MIN_POSITIVE, 0.0, -0.0, 7.0]))
                    .unwrap(),
            )
            .section("b.u32", key("b"), Array::vector(ArrayData::U32(vec![0, 1, u32::MAX])))
            .section("c.u16", key("c"), Array::new(&[1, 1, 3], ArrayData::U16(vec![9, 65535, 2])).unwrap())
            .section("d.u8", key("d"), Array::vector(ArrayData::U8(vec![1, 2, 3, 4, 5])))
            .section(
                "e.f64",
                key("e"),
                Array::new(&[2], ArrayData::F64(vec![std::f64::consts::PI, 1e-300])).unwrap(),
            )
            .section("empty", key("f"), Array::new(&[0, 4], ArrayData::F32(vec![])).unwrap())
    }

    fn bytes_of(w: &BakeWriter) -> Vec<u8> {
        let mut out = Vec::new();
        w.write_to(&mut out).unwrap();
        out
    }

    #[test]
    fn a_streamed_section_is_written_as_the_same_bytes_held_in_memory() {
        let bytes: Vec<u8> = (0..1001_u32).map(|i| (i * 7 % 251) as u8).collect();
        let held = sample_writer().section("s", key("s"), Array::vector(ArrayData::U8(bytes.clone())));
        let streamed = sample_writer().streamed_section("s", key("s"), bytes.len() as u64, |w| {
            // In uneven pieces, as a serializer writes.
            bytes.chunks(13).try_for_each(|c| w.write_all(c))
        });
        assert_eq!(bytes_of(&held), bytes_of(&streamed));
        // A section that writes other than it announced fails the write and leaves nothing.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("short.twillbake");
        let short = sample_writer().streamed_section("s", key("s"), 10, |w| w.write_all(&[1; 9]));
        let error = short.write(&path).unwrap_err();
        assert!(error.to_string().contains("wrote 9 bytes, announced 10"), "{error}");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0, "no file or temporary left behind");
    }

    #[test]
    fn every_element_type_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.twillbake");
        let w = sample_writer();
        w.write(&path).unwrap();
        let f = BakeFile::open(&path, key("file")).unwrap();
        let written: Vec<Section> = w
            .sections
            .iter()
            .map(|s| match &s.payload {
                Payload::Array(array) => Section { name: s.name.clone(), key: s.key, array: array.clone() },
                Payload::Streamed { .. } => unreachable!("the sample has arrays only"),
            })
            .collect();
        assert_eq!(f.sections(), &written[..]);
        assert_eq!(f.section("c.u16").unwrap().array.shape(), &[1, 1, 3]);
        assert_eq!(f.section("b.u32").unwrap().array.as_u32().unwrap(), &[0, 1, u32::MAX]);
        assert_eq!(
            f.section_if_current("a.f32", key("a")).unwrap().as_f32().unwrap()[1].to_bits(),
            (-2.5f32).to_bits()
        );
        assert!(f.section_if_current("a.f32", key("other")).is_none());
        assert!(f.section("missing").is_none());
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1, "no temporary left behind");
        // Data blocks are 8-byte aligned.
        let bytes = fs::read(&path).unwrap();
        assert_eq!(bytes.len() % 8, 0);
        assert_eq!(&bytes[..8], b"TWILLBK\0");
    }

    #[test]
    fn any_flipped_byte_is_detected() {
        let bytes = bytes_of(&sample_writer());
        let path = Path::new("flip.twillbake");
        // Every header byte, then a stride through the body, then the last byte.
        let positions: Vec<usize> =
            (0..HEADER_LEN).chain((HEADER_LEN..bytes.len()).step_by(7)).chain([bytes.len() - 1]).collect();
        for at in positions {
            for bit in [0x01u8, 0x80] {
                let mut b = bytes.clone();
                b[at] ^= bit;
                match BakeFile::parse(path, &b).and_then(|f| {
                    if f.key() == key("file") {
                        Ok(f)
                    } else {
                        Err(BakeFileError::Stale { file: path.into(), found: f.key(), expected: key("file") })
                    }
                }) {
                    Ok(_) => panic!("flip at byte {at} not detected"),
                    Err(
                        BakeFileError::Corrupt { .. }
                        | BakeFileError::VersionMismatch { .. }
                        | BakeFileError::Truncated { .. },
                    ) => {}
                    Err(e) => panic!("flip at byte {at}: unexpected {e}"),
                }
            }
        }
        let mut b = bytes.clone();
        b[200] ^= 1;
        let msg = BakeFile::parse(path, &b).unwrap_err().to_string();
        assert!(msg.contains("flip.twillbake") && msg.contains("checksum"), "{msg}");
        b = bytes.clone();
        b[8] = 7;
        assert!(matches!(
            BakeFile::parse(path, &b),
            Err(BakeFileError::VersionMismatch { found: 7, supported: 1, .. })
        ));
    }

    #[test]
    fn every_truncation_is_detected() {
        let bytes = bytes_of(&sample_writer());
        for len in 0..bytes.len() {
            match BakeFile::parse(Path::new("t"), &bytes[..len]) {
                Err(BakeFileError::Truncated { expected, got, .. }) => {
                    assert_eq!(got, len as u64);
                    assert!(expected > got);
                }
                other => panic!("length {len}: {other:?}"),
            }
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(matches!(
            BakeFile::parse(Path::new("t"), &longer),
            Err(BakeFileError::Corrupt { offset: 48, .. })
        ));
    }

    #[test]
    fn key_mismatch_is_stale_and_missing_is_not_found() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.twillbake");
        sample_writer().write(&path).unwrap();
        let err = BakeFile::open(&path, key("other")).unwrap_err();
        assert!(matches!(err, BakeFileError::Stale { .. }), "{err}");
        assert!(err.to_string().contains("stale"));
        assert!(matches!(
            BakeFile::open(&dir.path().join("nope"), key("x")),
            Err(BakeFileError::NotFound { .. })
        ));
        // Garbage that is not a bake file at all.
        fs::write(&path, b"hello, world, this is not a bake file").unwrap();
        assert!(matches!(BakeFile::open(&path, key("file")), Err(BakeFileError::Corrupt { offset: 0, .. })));
    }

    #[test]
    fn invalid_sections_are_rejected_before_writing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.twillbake");
        let a = Array::vector(ArrayData::U8(vec![1]));
        let w = BakeWriter::new(key("k")).section("s", key("a"), a.clone()).section("s", key("b"), a.clone());
        assert!(matches!(w.write(&path), Err(BakeFileError::InvalidSection { .. })));
        let w = BakeWriter::new(key("k")).section(&"n".repeat(256), key("a"), a);
        assert!(matches!(w.write(&path), Err(BakeFileError::InvalidSection { .. })));
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
        assert!(Array::new(&[2, 2], ArrayData::U8(vec![1, 2, 3])).is_none());
    }

    /// A writer that fails after `left` bytes, like a disk filling up.
    struct FailAfter<'a, W: Write> {
        inner: &'a mut W,
        left: usize,
    }

    impl<W: Write> Write for FailAfter<'_, W> {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            if self.left == 0 {
                return Err(io::Error::new(io::ErrorKind::StorageFull, "no space left on device"));
            }
            let n = buf.len().min(self.left);
            self.left -= n;
            self.inner.write(&buf[..n])
        }
        fn flush(&mut self) -> io::Result<()> {
            self.inner.flush()
        }
    }

    #[test]
    fn a_failed_write_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.twillbake");
        let w = sample_writer();
        let result = write_atomically(&path, |out| {
            w.write_to(&mut FailAfter { inner: out, left: 150 }).map_err(|e| match e {
                BakeFileError::Io { source, .. } => source,
                other => io::Error::other(other.to_string()),
            })
        });
        assert_eq!(result.unwrap_err().kind(), io::ErrorKind::StorageFull);
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
        // An unwritable target directory is a clear error naming the file.
        let err = w.write(Path::new("/nonexistent-twill-dir/x.twillbake")).unwrap_err();
        assert!(err.to_string().contains("/nonexistent-twill-dir/x.twillbake"), "{err}");
    }

    /// Stores beyond the limit evict the least recently used entries (a load counts as a use),
    /// never the one just stored; `info` and `clear` see every entry; a killed writer's
    /// temporary is removed when the cache is opened, a live writer's is not.
    #[test]
    fn cache_evicts_least_recently_used_entries_beyond_its_limit() {
        let dir = tempfile::tempdir().unwrap();
        let writer = |name: &str| {
            BakeWriter::new(key(name)).section("x", key(name), Array::vector(ArrayData::U8(vec![7; 10_000])))
        };
        let one_entry = {
            let probe = Cache::new(&dir.path().join("probe")).unwrap();
            fs::metadata(probe.store(&writer("probe")).unwrap()).unwrap().len()
        };
        let cache = Cache::with_limit(dir.path(), 3 * one_entry).unwrap();
        let at = |seconds: u64| std::time::UNIX_EPOCH + std::time::Duration::from_secs(1_000_000 + seconds);
        let set_used = |name: &str, seconds| {
            let f = fs::File::options().append(true).open(cache.path_for(key(name))).unwrap();
            f.set_modified(at(seconds)).unwrap();
        };
        for (i, name) in ["a", "b", "c"].into_iter().enumerate() {
            cache.store(&writer(name)).unwrap();
            set_used(name, i as u64);
        }
        assert_eq!(cache.info(), CacheInfo { entries: 3, bytes: 3 * one_entry, limit_bytes: 3 * one_entry });
        // Using "a" makes "b" the least recently used: storing "d" evicts "b" only.
        assert!(cache.load(key("a")).is_some());
        cache.store(&writer("d")).unwrap();
        let present = |name: &str| cache.path_for(key(name)).exists();
        assert_eq!(
            ["a", "b", "c", "d"].map(present),
            [true, false, true, true],
            "the least recently used entry goes first"
        );
        // An entry larger than the whole limit is kept (it is what was just baked) alone.
        let small = Cache::with_limit(dir.path(), 1).unwrap();
        let kept = small.store(&writer("e")).unwrap();
        assert!(kept.exists());
        assert_eq!(small.info().entries, 1);
        // Leftover temporaries: a dead writer's goes, a live writer's (ours) stays, others stay.
        let dead = dir.path().join(format!(
            ".{}.{}.tmp",
            cache.path_for(key("f")).file_name().unwrap().to_string_lossy(),
            u32::MAX - 1
        ));
        let live = dir.path().join(format!(
            ".{}.{}.tmp",
            cache.path_for(key("g")).file_name().unwrap().to_string_lossy(),
            std::process::id()
        ));
        let unrelated = dir.path().join("notes.txt");
        for path in [&dead, &live, &unrelated] {
            fs::write(path, b"half").unwrap();
        }
        let reopened = Cache::new(dir.path()).unwrap();
        assert!(!dead.exists() && live.exists() && unrelated.exists());
        assert_eq!(reopened.clear().unwrap(), 1);
        assert_eq!(reopened.info().entries, 0);
        assert!(live.exists() && unrelated.exists(), "clear removes entries only");
    }

    #[test]
    fn cache_recomputes_bad_files_and_rejects_unusable_dirs() {
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::new(&dir.path().join("a/b")).unwrap();
        let w = sample_writer();
        assert!(cache.load(w.key()).is_none());
        let path = cache.store(&w).unwrap();
        assert_eq!(path, cache.path_for(w.key()));
        assert!(path.to_string_lossy().ends_with(&format!("{}.twillbake", w.key().to_hex())));
        assert_eq!(cache.load(w.key()).unwrap().sections().len(), 6);
        // Corrupt it: load says None and deletes it.
        let mut bytes = fs::read(&path).unwrap();
        let n = bytes.len();
        bytes[n - 3] ^= 0x10;
        fs::write(&path, &bytes).unwrap();
        assert!(cache.load(w.key()).is_none());
        assert!(!path.exists());
        // Truncated.
        cache.store(&w).unwrap();
        fs::write(&path, &fs::read(&path).unwrap()[..100]).unwrap();
        assert!(cache.load(w.key()).is_none() && !path.exists());
        // Stale: a file under this key's name holding another key.
        let other = BakeWriter::new(key("other"));
        other.write(&path).unwrap();
        assert!(cache.load(w.key()).is_none() && !path.exists());

        // A directory under a regular file, and one under /proc, cannot be used.
        let file = dir.path().join("plain");
        fs::write(&file, b"x").unwrap();
        let err = Cache::new(&file.join("cache")).unwrap_err();
        assert!(matches!(err, BakeFileError::CacheDir { .. }));
        assert!(err.to_string().contains("plain/cache"), "{err}");
        assert!(matches!(Cache::new(Path::new("/proc/twill-cache")), Err(BakeFileError::CacheDir { .. })));
    }

    /// `bytes` with the header's body length and checksum made to fit its contents.
    fn resealed(mut bytes: Vec<u8>) -> Vec<u8> {
        let body_len = (bytes.len() - HEADER_LEN) as u64;
        bytes[48..56].copy_from_slice(&body_len.to_le_bytes());
        let mut hasher = blake3::Hasher::new();
        hasher.update(&bytes[..CHECKSUM_AT]);
        hasher.update(&bytes[HEADER_LEN..]);
        let checksum = *hasher.finalize().as_bytes();
        bytes[CHECKSUM_AT..HEADER_LEN].copy_from_slice(&checksum);
        bytes
    }

    #[test]
    fn a_section_claiming_a_huge_array_is_refused_before_reading_it() {
        let w =
            BakeWriter::new(key("file")).section("h", key("h"), Array::vector(ArrayData::F32(vec![1.0; 3])));
        let good = bytes_of(&w);
        let path = Path::new("huge.twillbake");
        assert!(BakeFile::parse(path, &resealed(good.clone())).is_ok());
        // The one directory entry: name length, "h", type, rank 1, key, dim, offset, length.
        let dim_at = HEADER_LEN + 1 + 1 + 2 + 32;
        let huge: u64 = 1 << 40;
        let mut bad = good.clone();
        bad[dim_at..dim_at + 8].copy_from_slice(&huge.to_le_bytes());
        bad[dim_at + 16..dim_at + 24].copy_from_slice(&(4 * huge).to_le_bytes());
        let msg = BakeFile::parse(path, &resealed(bad)).unwrap_err().to_string();
        assert!(
            msg.contains("huge.twillbake")
                && msg.contains(&format!("+{}", 4 * huge))
                && msg.contains(&format!("outside the file ({} bytes)", good.len())),
            "{msg}"
        );
        // A shape whose byte size overflows u64 is refused too.
        let mut bad = good;
        bad[dim_at..dim_at + 8].copy_from_slice(&u64::MAX.to_le_bytes());
        let msg = BakeFile::parse(path, &resealed(bad)).unwrap_err().to_string();
        assert!(msg.contains("huge.twillbake") && msg.contains("does not fill"), "{msg}");
    }

    #[test]
    fn hasher_frames_inputs_and_is_deterministic() {
        let a = Hasher::new("d").str("ab").str("c").finish();
        let b = Hasher::new("d").str("a").str("bc").finish();
        assert_ne!(a, b);
        assert_ne!(Hasher::new("d").f64(0.0).finish(), Hasher::new("d").f64(-0.0).finish());
        assert_ne!(Hasher::new("d").u32(1).finish(), Hasher::new("d").f32(f32::from_bits(1)).finish());
        assert_ne!(Hasher::new("d").finish(), Hasher::new("e").finish());
        let s = crate::bake::settings::Quality::Draft.settings();
        let h1 = Hasher::new("d").serde(&s).unwrap().finish();
        let h2 = Hasher::new("d").serde(&s.clone()).unwrap().finish();
        assert_eq!(h1, h2);
        let mut s2 = s;
        s2.sos_sharpness = f64::from_bits(s.sos_sharpness.to_bits() + 1);
        assert_ne!(h1, Hasher::new("d").serde(&s2).unwrap().finish());
        assert_eq!(a.to_hex().len(), 64);
        assert_eq!(format!("{a}"), a.to_hex());
    }
}
