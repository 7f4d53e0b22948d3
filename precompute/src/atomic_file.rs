//! Atomic file writes: write to a temporary file beside the target, flush and sync it, then
//! rename it over the target. A reader never sees a half-written file, and a failed or
//! interrupted write leaves the previous file (or none) and no temporary behind. A process
//! killed mid-write cannot remove its temporary; the next write of the same file does
//! ([`remove_dead_writers_temporaries`]).

use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// Writes `path` atomically with `write`, which receives a buffered writer (seekable, so
/// formats that patch headers after the fact work too).
pub fn write_atomically<F>(path: &Path, write: F) -> io::Result<()>
where
    F: FnOnce(&mut BufWriter<File>) -> io::Result<()>,
{
    remove_dead_writers_temporaries(path);
    let temp = temp_path_for(path);
    let result = (|| {
        let mut writer = BufWriter::new(File::create(&temp)?);
        write(&mut writer)?;
        writer.flush()?;
        let file = writer.into_inner().map_err(io::IntoInnerError::into_error)?;
        file.sync_all()?;
        fs::rename(&temp, path)
    })();
    if result.is_err() {
        // Best effort: the temporary may not exist if creating it was what failed.
        let _ = fs::remove_file(&temp);
    }
    result
}

/// A temporary name in the same directory (so the final rename never crosses file systems).
fn temp_path_for(path: &Path) -> PathBuf {
    let name = path.file_name().map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// The writer's process id of a temporary named `.NAME.PID.tmp`, and NAME; `None` for any
/// other file name.
#[must_use]
pub fn temporary_of(file_name: &str) -> Option<(&str, u32)> {
    let inner = file_name.strip_prefix('.')?.strip_suffix(".tmp")?;
    let (name, pid) = inner.rsplit_once('.')?;
    Some((name, pid.parse().ok()?))
}

/// Whether the writer of a temporary (process `pid`, last modified `modified`) is gone: its
/// process no longer exists where `/proc` tells, else the file is more than a day old.
#[must_use]
pub fn writer_is_gone(pid: u32, modified: Option<std::time::SystemTime>) -> bool {
    if Path::new("/proc/self").exists() {
        return pid != std::process::id() && !Path::new(&format!("/proc/{pid}")).exists();
    }
    modified.and_then(|t| t.elapsed().ok()).is_some_and(|age| age.as_secs() > 24 * 3600)
}

/// Deletes the temporaries of `path` (`.NAME.PID.tmp` beside it) whose writer is gone.
pub fn remove_dead_writers_temporaries(path: &Path) {
    let (Some(dir), Some(target)) = (path.parent(), path.file_name()) else { return };
    let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
    let Ok(entries) = fs::read_dir(dir) else { return };
    let target = target.to_string_lossy();
    for entry in entries.filter_map(Result::ok) {
        let file_name = entry.file_name().to_string_lossy().into_owned();
        let Some((name, pid)) = temporary_of(&file_name) else { continue };
        if name == target && writer_is_gone(pid, entry.metadata().and_then(|m| m.modified()).ok()) {
            let _ = fs::remove_file(entry.path());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A killed writer's temporary of the same file is removed by the next write; a live
    /// writer's (this process) and another file's stay.
    #[test]
    fn the_next_write_removes_a_killed_writers_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.bin");
        let dead = dir.path().join(format!(".a.bin.{}.tmp", u32::MAX - 1));
        let other = dir.path().join(format!(".b.bin.{}.tmp", u32::MAX - 1));
        for p in [&dead, &other] {
            fs::write(p, b"half").unwrap();
        }
        assert_eq!(temporary_of(&format!(".a.bin.{}.tmp", u32::MAX - 1)), Some(("a.bin", u32::MAX - 1)));
        assert_eq!(temporary_of("a.bin"), None);
        write_atomically(&path, |w| w.write_all(b"whole")).unwrap();
        assert!(!dead.exists() && other.exists());
        assert_eq!(fs::read(&path).unwrap(), b"whole");
    }

    #[test]
    fn a_failed_write_leaves_the_old_file_and_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_atomically(&path, |w| w.write_all(b"first")).unwrap();
        let err = write_atomically(&path, |w| {
            w.write_all(b"partial")?;
            Err(io::Error::other("disk full"))
        });
        assert!(err.is_err());
        assert_eq!(fs::read(&path).unwrap(), b"first");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn an_unwritable_directory_is_an_error_not_a_panic() {
        let path = Path::new("/nonexistent-dir-for-twill-tests/x.bin");
        assert!(write_atomically(path, |w| w.write_all(b"x")).is_err());
    }
}
