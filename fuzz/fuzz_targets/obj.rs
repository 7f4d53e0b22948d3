//! OBJ base meshes: `BaseMesh::parse_obj` on any bytes, then the validation and repairs every
//! loaded mesh goes through.
//!
//! The OBJ and glTF parsers (tobj, gltf) panic on some inputs; the loaders catch those panics and
//! report a parse error (see renderer/src/shell/load.rs). libFuzzer's panic hook would abort on
//! them even so, so this target replaces it with a silent one: a panic that escapes the loader
//! still ends the run as a crash (libfuzzer-sys aborts on it), one the loader catches does not.
#![no_main]

use std::sync::Once;

use libfuzzer_sys::fuzz_target;
use twill_renderer::shell::BaseMesh;

fuzz_target!(|data: &[u8]| {
    static QUIET: Once = Once::new();
    QUIET.call_once(|| std::panic::set_hook(Box::new(|_| {})));
    if let Ok(mut mesh) = BaseMesh::parse_obj(data, "fuzz/mesh.obj") {
        let _ = mesh.validate_and_repair();
    }
});
