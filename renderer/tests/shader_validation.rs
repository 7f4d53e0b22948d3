//! Every WGSL file under `shaders/` parses and validates with naga, without a GPU.

use std::path::{Path, PathBuf};

fn wgsl_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            wgsl_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "wgsl") {
            out.push(path);
        }
    }
}

/// Shared modules may call functions of the modules before them (WGSL has no includes), so
/// each file is validated after everything `shaders::SHARED` lists before it.
fn with_prerequisites(file: &Path, source: &str) -> String {
    let name = file.to_string_lossy().replace('\\', "/");
    let mut text = String::new();
    for (shared, shared_source) in twill_renderer::shaders::SHARED {
        if name.ends_with(shared) {
            break;
        }
        text.push_str(shared_source);
        text.push('\n');
    }
    text.push_str(source);
    text
}

#[test]
fn every_wgsl_file_validates() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shaders");
    let mut files = Vec::new();
    wgsl_files(&root, &mut files);
    files.sort();
    assert!(!files.is_empty(), "no WGSL files found under {}", root.display());
    let mut failures = Vec::new();
    for file in &files {
        let source = with_prerequisites(file, &std::fs::read_to_string(file).unwrap());
        let module = match naga::front::wgsl::parse_str(&source) {
            Ok(m) => m,
            Err(e) => {
                failures.push(format!("{}:\n{}", file.display(), e.emit_to_string(&source)));
                continue;
            }
        };
        let mut validator = naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        );
        if let Err(e) = validator.validate(&module) {
            failures.push(format!("{}:\n{}", file.display(), e.emit_to_string(&source)));
        }
    }
    assert!(failures.is_empty(), "{} WGSL file(s) failed:\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn compiled_in_sources_are_the_files_on_disk() {
    for (name, source) in twill_renderer::shaders::SHARED {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shaders").join(name);
        assert_eq!(&std::fs::read_to_string(&path).unwrap(), source, "{name}");
    }
}
