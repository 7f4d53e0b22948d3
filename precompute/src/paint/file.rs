//! The paint file: [`PaintData`] behind a magic, a version and a BLAKE3 checksum.
//!
//! Layout: `TWILLPNT` (8 bytes), the format version (u32, little endian), the body's length
//! (u64), its BLAKE3 hash (32 bytes), then the body: the data as postcard. A file whose magic,
//! version, length or checksum does not match is refused with an error naming it; it is
//! written atomically (temp + rename), so a reader never sees half of one.

use std::path::{Path, PathBuf};

use super::PaintData;
use crate::atomic_file::write_atomically;

const MAGIC: &[u8; 8] = b"TWILLPNT";
/// Bumped whenever [`PaintData`] or its meaning changes.
pub const PAINT_FILE_VERSION: u32 = 3;
const HEADER: usize = 8 + 4 + 8 + 32;

/// Why a paint file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum PaintFileError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a twill paint file (it does not start with `TWILLPNT`)")]
    NotPaint { path: PathBuf },
    #[error("{path}: paint file version {found}; this twill reads version {expected} (precompute it again)")]
    Version { path: PathBuf, found: u32, expected: u32 },
    #[error("{path}: truncated: {have} bytes where the header promises {want}")]
    Truncated { path: PathBuf, have: u64, want: u64 },
    #[error("{path}: checksum mismatch: the file is damaged (precompute it again)")]
    Checksum { path: PathBuf },
    #[error("{path}: {message}")]
    Decode { path: PathBuf, message: String },
}

impl PaintData {
    /// Writes the data to `path` atomically.
    pub fn save(&self, path: &Path) -> Result<(), PaintFileError> {
        let io = |source| PaintFileError::Io { path: path.to_path_buf(), source };
        let body = postcard::to_allocvec(self).map_err(|e| PaintFileError::Decode {
            path: path.to_path_buf(),
            message: format!("cannot encode: {e}"),
        })?;
        write_atomically(path, |w| {
            use std::io::Write;
            w.write_all(MAGIC)?;
            w.write_all(&PAINT_FILE_VERSION.to_le_bytes())?;
            w.write_all(&(body.len() as u64).to_le_bytes())?;
            w.write_all(blake3::hash(&body).as_bytes())?;
            w.write_all(&body)
        })
        .map_err(io)
    }

    /// Reads and checks a paint file.
    pub fn load(path: &Path) -> Result<Self, PaintFileError> {
        let bytes =
            std::fs::read(path).map_err(|source| PaintFileError::Io { path: path.to_path_buf(), source })?;
        Self::from_bytes(&bytes, path)
    }

    /// [`Self::load`] of bytes in memory; `path` names them in errors.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, PaintFileError> {
        let path = path.to_path_buf();
        if bytes.len() < 8 || &bytes[..8] != MAGIC {
            return Err(PaintFileError::NotPaint { path });
        }
        if bytes.len() < HEADER {
            return Err(PaintFileError::Truncated { path, have: bytes.len() as u64, want: HEADER as u64 });
        }
        let found = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
        if found != PAINT_FILE_VERSION {
            return Err(PaintFileError::Version { path, found, expected: PAINT_FILE_VERSION });
        }
        let len = u64::from_le_bytes(bytes[12..20].try_into().expect("8 bytes"));
        let want = (HEADER as u64).saturating_add(len);
        if bytes.len() as u64 != want {
            return Err(PaintFileError::Truncated { path, have: bytes.len() as u64, want });
        }
        let body = &bytes[HEADER..];
        if blake3::hash(body).as_bytes() != &bytes[20..52] {
            return Err(PaintFileError::Checksum { path });
        }
        let data: Self = postcard::from_bytes(body).map_err(|e| PaintFileError::Decode {
            path: path.clone(),
            message: format!("cannot decode: {e}"),
        })?;
        data.check().map_err(|message| PaintFileError::Decode { path, message })?;
        Ok(data)
    }
}
