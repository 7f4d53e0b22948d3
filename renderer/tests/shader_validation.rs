//! Every WGSL file under `shaders/` composes (its `#import`s resolved), parses and validates
//! with naga, without a GPU; every file on disk is one the renderer compiles in; and no pass
//! takes its per-frame parameters in a uniform buffer (see `passes::params_buffer`).

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

/// A file as the renderer compiles it: its `#import`s resolved (`shaders::compose`).
fn composed(file: &Path, root: &Path) -> Result<String, String> {
    let name = file.strip_prefix(root).unwrap().to_string_lossy().replace('\\', "/");
    twill_renderer::shaders::compose(&name).map_err(|e| e.to_string())
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
        let source = match composed(file, &root) {
            Ok(source) => source,
            Err(e) => {
                failures.push(format!("{}: {e}", file.display()));
                continue;
            }
        };
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
    for (name, source) in twill_renderer::shaders::FILES {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shaders").join(name);
        assert_eq!(&std::fs::read_to_string(&path).unwrap(), source, "{name}");
    }
}

#[test]
fn every_file_on_disk_is_compiled_in() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shaders");
    let mut files = Vec::new();
    wgsl_files(&root, &mut files);
    for file in files {
        let name = file.strip_prefix(&root).unwrap().to_string_lossy().replace('\\', "/");
        assert!(
            twill_renderer::shaders::FILES.iter().any(|(n, _)| *n == name),
            "{name} is not in shaders::FILES"
        );
    }
}

/// Lavapipe specializes a shader on the values of its uniform buffers and keeps every variant
/// (`passes::params_buffer`): a pass's parameters, which change from frame to frame or sample
/// to sample, must be in read-only storage buffers. Only the fabric header, fixed while a bake
/// is loaded, is a uniform.
#[test]
fn only_the_fabric_header_is_a_uniform() {
    let mut uniforms = Vec::new();
    for (name, _) in twill_renderer::shaders::FILES {
        let source = twill_renderer::shaders::compose(name).unwrap();
        let module = naga::front::wgsl::parse_str(&source).unwrap();
        for (_, global) in module.global_variables.iter() {
            if global.space == naga::AddressSpace::Uniform {
                let ty = module.types[global.ty].name.clone().unwrap_or_default();
                if ty != "FabricHeader" {
                    uniforms.push(format!("{name}: {} ({ty})", global.name.clone().unwrap_or_default()));
                }
            }
        }
    }
    assert!(uniforms.is_empty(), "per-frame parameters in uniform buffers: {uniforms:?}");
}
