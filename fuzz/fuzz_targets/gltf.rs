//! glTF and GLB base meshes: the input is a document (glTF JSON or GLB), optionally followed by
//! the separator `\n#buffer#\n` and the contents of an external buffer file, which is written to
//! `buffer.bin` in a private temporary folder that is given to `BaseMesh::parse_gltf` as the
//! document's folder (so `"uri": "buffer.bin"` reads it). Loaded meshes then go through the
//! validation and repairs every loaded mesh goes through.
//!
//! The OBJ and glTF parsers (tobj, gltf) panic on some inputs; the loaders catch those panics and
//! report a parse error (see renderer/src/shell/load.rs). libFuzzer's panic hook would abort on
//! them even so, so this target replaces it with a silent one: a panic that escapes the loader
//! still ends the run as a crash (libfuzzer-sys aborts on it), one the loader catches does not.
#![no_main]

use std::path::PathBuf;
use std::sync::{Once, OnceLock};

use libfuzzer_sys::fuzz_target;
use twill_renderer::shell::BaseMesh;

const SEPARATOR: &[u8] = b"\n#buffer#\n";

/// A folder of this process's own under the system's temporary folder.
fn folder() -> &'static PathBuf {
    static FOLDER: OnceLock<PathBuf> = OnceLock::new();
    FOLDER.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("twill-fuzz-gltf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("create the fuzz folder");
        dir
    })
}

fuzz_target!(|data: &[u8]| {
    static QUIET: Once = Once::new();
    QUIET.call_once(|| std::panic::set_hook(Box::new(|_| {})));
    let (document, buffer) = match data.windows(SEPARATOR.len()).position(|w| w == SEPARATOR) {
        Some(at) => (&data[..at], Some(&data[at + SEPARATOR.len()..])),
        None => (data, None),
    };
    let dir = folder();
    let buffer_path = dir.join("buffer.bin");
    match buffer {
        Some(bytes) => std::fs::write(&buffer_path, bytes).expect("write the buffer file"),
        None => {
            let _ = std::fs::remove_file(&buffer_path);
        }
    }
    if let Ok(mut mesh) = BaseMesh::parse_gltf(document, "fuzz/mesh.gltf", Some(dir)) {
        let _ = mesh.validate_and_repair();
    }
});
