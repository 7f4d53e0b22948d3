//! Tests of the shell map: geometry invariants on every builtin and asset mesh, the swatch identity,
//! loaders, every documented error, and robustness against mangled files.
//!
//! The mangling tests make the OBJ/glTF parsers panic on some inputs; those panics are caught
//! inside the loaders (and reported as parse errors), but the default panic hook still prints them.
#![allow(clippy::float_cmp)] // exact equality is the point: w is exactly 0 or 1, the swatch maps exactly.

use std::collections::{HashMap, HashSet};
use std::path::PathBuf;

use glam::{DVec3, Vec2, Vec3};

use super::tetra::{det6, split_side_quad};
use super::*;

fn asset(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/meshes").join(name)
}

/// Every mesh the geometry tests run on, with a spec that suits it.
fn test_shells() -> Vec<(String, Shell)> {
    let cases = [
        (BaseMesh::builtin("swatch", [4.0, 3.0]).unwrap(), ShellSpec::new([-0.05, 0.05], 1.0)),
        (BaseMesh::builtin("drape", [20.0, 20.0]).unwrap(), ShellSpec::new([0.0, 0.1], 1.0)),
        (BaseMesh::builtin("cushion", [30.0, 20.0]).unwrap(), ShellSpec::new([-0.1, 0.2], 1.0)),
        (BaseMesh::load(&asset("bent_sheet.obj")).unwrap(), ShellSpec::outward(0.1, 8.0)),
        (BaseMesh::load(&asset("wave_patch.gltf")).unwrap(), ShellSpec::outward(0.1, 12.0)),
    ];
    cases
        .into_iter()
        .map(|(mesh, spec)| {
            let shell = Shell::build(&mesh, &spec).unwrap_or_else(|e| panic!("{e}"));
            (mesh.source, shell)
        })
        .collect()
}

fn world(v: &ShellVertex) -> DVec3 {
    v.position.as_dvec3()
}

fn uvw(v: &ShellVertex) -> DVec3 {
    v.uvw.as_dvec3()
}

fn volume(t: &[ShellVertex; 4], space: fn(&ShellVertex) -> DVec3) -> f64 {
    det6(space(&t[0]), space(&t[1]), space(&t[2]), space(&t[3])) / 6.0
}

/// Signed volume enclosed by outward triangles (divergence theorem).
fn enclosed_volume(triangles: &[[DVec3; 3]]) -> f64 {
    triangles.iter().map(|[a, b, c]| a.dot(b.cross(*c))).sum::<f64>() / 6.0
}

/// Canonical key of an oriented triangle: rotated so the smallest index comes first.
fn oriented(t: [u32; 3]) -> [u32; 3] {
    let k = (0..3).min_by_key(|&k| t[k]).unwrap();
    [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
}

fn vertex_ids(shell: &Shell) -> HashMap<[u32; 6], u32> {
    let key = |v: &ShellVertex| {
        let (p, q) = (v.position.to_array(), v.uvw.to_array());
        [p[0], p[1], p[2], q[0], q[1], q[2]].map(f32::to_bits)
    };
    let ids: HashMap<_, _> = shell.vertices.iter().enumerate().map(|(i, v)| (key(v), i as u32)).collect();
    assert_eq!(ids.len(), shell.vertices.len(), "shell vertices must be distinct");
    ids
}

fn ids_of<const N: usize>(ids: &HashMap<[u32; 6], u32>, t: &[ShellVertex; N]) -> [u32; N] {
    t.map(|v| {
        let (p, q) = (v.position.to_array(), v.uvw.to_array());
        ids[&[p[0], p[1], p[2], q[0], q[1], q[2]].map(f32::to_bits)]
    })
}

#[test]
fn every_tetrahedron_is_positive_in_world_and_uvw() {
    for (name, shell) in test_shells() {
        assert_eq!(shell.tetrahedra.len(), 3 * shell.top_triangles.len(), "{name}");
        for (i, t) in shell.tetrahedra.iter().enumerate() {
            assert!(volume(t, world) > 0.0, "{name}: tetra {i} world volume {}", volume(t, world));
            assert!(volume(t, uvw) > 0.0, "{name}: tetra {i} uvw volume {}", volume(t, uvw));
        }
    }
}

#[test]
fn three_tetrahedra_fill_their_prism() {
    for (name, shell) in test_shells() {
        let n = (shell.vertices.len() / 2) as u32;
        let at = |i: u32| shell.vertices[i as usize];
        let ids = vertex_ids(&shell);
        for (k, tets) in shell.tetra_indices.chunks_exact(3).enumerate() {
            // The prism's boundary: bottom, top, and the three side quads cut as the rule says.
            let [ta, tb, tc] = ids_of(&ids, &shell.top_triangles[k]);
            let [a, b, c] = [ta - n, tb - n, tc - n];
            let mut faces = vec![[a, c, b], [ta, tb, tc]];
            for (x, y) in [(a, b), (b, c), (c, a)] {
                faces.extend(split_side_quad(x, y, n));
            }
            for space in [world as fn(&ShellVertex) -> DVec3, uvw] {
                let boundary: Vec<[DVec3; 3]> = faces.iter().map(|f| f.map(|i| space(&at(i)))).collect();
                let prism = enclosed_volume(&boundary);
                let sum: f64 = tets.iter().map(|t| volume(&t.map(at), space)).sum();
                assert!(
                    (prism - sum).abs() <= 1e-9 * prism.abs().max(1e-12),
                    "{name}: prism {k}: {prism} vs {sum}"
                );
            }
        }
    }
}

#[test]
fn uvw_volume_equals_uv_area_times_unit_depth() {
    for (name, shell) in test_shells() {
        let uv_area: f64 = shell
            .top_triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|v| v.uvw.truncate().as_dvec2());
                (b - a).perp_dot(c - a) / 2.0
            })
            .sum();
        let uvw_volume: f64 = shell.tetrahedra.iter().map(|t| volume(t, uvw)).sum();
        assert!((uvw_volume - uv_area).abs() <= 1e-9 * uv_area, "{name}: {uvw_volume} vs {uv_area}");
    }
}

#[test]
fn internal_faces_pair_up_and_boundary_is_top_bottom_and_border() {
    for (name, shell) in test_shells() {
        let ids = vertex_ids(&shell);
        let n = (shell.vertices.len() / 2) as u32;
        let mut faces: HashMap<[u32; 3], Vec<[u32; 3]>> = HashMap::new();
        for (t, tet) in shell.tetrahedra.iter().enumerate() {
            let [a, b, c, d] = ids_of(&ids, tet);
            assert_eq!(
                [a, b, c, d],
                shell.tetra_indices[t],
                "{name}: indexed and unrolled tetrahedra differ"
            );
            for face in [[a, c, b], [a, b, d], [a, d, c], [b, c, d]] {
                let mut key = face;
                key.sort_unstable();
                faces.entry(key).or_default().push(oriented(face));
            }
        }
        let mut boundary = HashSet::new();
        for (key, uses) in &faces {
            match uses.as_slice() {
                [one] => {
                    boundary.insert(*one);
                }
                [x, y] => assert_eq!(*x, oriented([y[0], y[2], y[1]]), "{name}: face {key:?} not opposite"),
                more => panic!("{name}: face {key:?} used {} times", more.len()),
            }
        }
        let surface: Vec<[u32; 3]> = [&shell.top_triangles, &shell.bottom_triangles, &shell.side_triangles]
            .into_iter()
            .flatten()
            .map(|t| oriented(ids_of(&ids, t)))
            .collect();
        assert_eq!(surface.len(), boundary.len(), "{name}");
        assert_eq!(surface.iter().copied().collect::<HashSet<_>>(), boundary, "{name}: boundary != surfaces");

        // Top faces are all at w = 1, bottom at w = 0, sides only over boundary edges of the base.
        assert!(shell.top_triangles.iter().flatten().all(|v| v.uvw.z == 1.0));
        assert!(shell.bottom_triangles.iter().flatten().all(|v| v.uvw.z == 0.0));
        let mut base_edges: HashMap<[u32; 2], usize> = HashMap::new();
        for t in &shell.top_triangles {
            let [a, b, c] = ids_of(&ids, t).map(|i| i - n);
            for (x, y) in [(a, b), (b, c), (c, a)] {
                *base_edges.entry([x.min(y), x.max(y)]).or_default() += 1;
            }
        }
        for t in &shell.side_triangles {
            let mut base: Vec<u32> = ids_of(&ids, t).iter().map(|i| i % n).collect();
            base.sort_unstable();
            base.dedup();
            assert_eq!(base.len(), 2, "{name}: side triangle spans {base:?}");
            assert_eq!(base_edges[&[base[0], base[1]]], 1, "{name}: side over an interior edge");
        }
    }
}

#[test]
fn tetra_neighbors_share_a_face_both_ways_and_leave_only_the_surface_open() {
    for (name, shell) in test_shells() {
        let neighbors = shell.tetra_neighbors();
        let mut open = 0;
        for (t, (tet, across)) in shell.tetra_indices.iter().zip(&neighbors).enumerate() {
            for (k, &u) in across.iter().enumerate() {
                if u == NO_NEIGHBOR {
                    open += 1;
                    continue;
                }
                let other = shell.tetra_indices[u as usize];
                let shared: Vec<u32> = tet.iter().copied().filter(|v| other.contains(v)).collect();
                assert_eq!(shared.len(), 3, "{name}: tetrahedra {t} and {u} share {shared:?}");
                assert!(!shared.contains(&tet[k]), "{name}: face {k} of {t} is not opposite corner {k}");
                assert!(
                    neighbors[u as usize].contains(&(t as u32)),
                    "{name}: {u} does not point back to {t}"
                );
            }
        }
        let surface = shell.top_triangles.len() + shell.bottom_triangles.len() + shell.side_triangles.len();
        assert_eq!(open, surface, "{name}: open faces are the surface triangles");
    }
}

#[test]
fn surfaces_face_outward() {
    for (name, shell) in test_shells() {
        // The closed surface encloses exactly the tetrahedra's volume, with the right sign.
        let surface: Vec<[DVec3; 3]> = [&shell.top_triangles, &shell.bottom_triangles, &shell.side_triangles]
            .into_iter()
            .flatten()
            .map(|t| t.map(|v| world(&v)))
            .collect();
        let enclosed = enclosed_volume(&surface);
        let volume = shell.volume_cm3();
        assert!(volume > 0.0 && (enclosed - volume).abs() <= 1e-6 * volume, "{name}: {enclosed} vs {volume}");
        // Top triangles are counter-clockwise seen from the side their vertex normals point to.
        for t in &shell.top_triangles {
            let [a, b, c] = t.map(|v| world(&v));
            let bottom: Vec<DVec3> = shell
                .vertices
                .iter()
                .filter(|v| v.uvw.z == 0.0 && v.uvw.truncate() == t[0].uvw.truncate())
                .map(world)
                .collect();
            assert!((b - a).cross(c - a).dot(a - bottom[0]) > 0.0, "{name}");
        }
    }
}

#[test]
fn tetra_affine_round_trips_and_maps_vertices() {
    for (name, shell) in test_shells() {
        for (i, t) in shell.tetrahedra.iter().enumerate() {
            let (to_uvw, to_world) = Shell::tetra_affine(t);
            assert!(to_uvw.is_finite() && to_world.is_finite(), "{name}: tetra {i}");
            let scale = t.iter().map(|v| v.position.abs().max_element()).fold(1.0, f32::max);
            let uv_scale = t.iter().map(|v| v.uvw.abs().max_element()).fold(1.0, f32::max);
            for v in t {
                let uvw = to_uvw.transform_point3(v.position);
                assert!(
                    (uvw - v.uvw).abs().max_element() <= 1e-5 * uv_scale,
                    "{name}: {i}: {uvw} vs {}",
                    v.uvw
                );
                let back = to_world.transform_point3(v.uvw);
                assert!((back - v.position).abs().max_element() <= 1e-5 * scale, "{name}: {i}: {back}");
            }
            for weights in [[0.25f32; 4], [0.7, 0.1, 0.1, 0.1], [0.05, 0.15, 0.3, 0.5]] {
                let p: Vec3 = t.iter().zip(weights).map(|(v, w)| v.position * w).sum();
                let expected: Vec3 = t.iter().zip(weights).map(|(v, w)| v.uvw * w).sum();
                let q = to_uvw.transform_point3(p);
                assert!(
                    (q - expected).abs().max_element() <= 1e-5 * uv_scale,
                    "{name}: {i}: {q} vs {expected}"
                );
                let back = to_world.transform_point3(q);
                assert!((back - p).abs().max_element() <= 1e-5 * scale, "{name}: {i}: {back} vs {p}");
            }
        }
    }
}

#[test]
fn flat_swatch_maps_world_to_fabric_identically() {
    let (w0, w1) = (-0.04, 0.06);
    let mesh = BaseMesh::builtin("swatch", [5.0, 3.0]).unwrap();
    let shell = Shell::build(&mesh, &ShellSpec::new([w0, w1], 1.0)).unwrap();
    assert_eq!(shell.tetrahedra.len(), 8 * 8 * 2 * 3);
    for v in shell.tetrahedra.iter().flatten().chain(&shell.vertices) {
        let z = if v.uvw.z == 0.0 { w0 } else { w1 };
        assert!(v.uvw.z == 0.0 || v.uvw.z == 1.0);
        assert_eq!(v.position, Vec3::new(v.uvw.x, v.uvw.y, z));
    }
    assert!(shell.is_flat);
    assert_eq!(shell.flat_normal, Some(Vec3::Z));
    assert_eq!((shell.bounds_min, shell.bounds_max), (Vec3::new(-2.5, -1.5, w0), Vec3::new(2.5, 1.5, w1)));
    assert_eq!((shell.uv_min, shell.uv_max), (Vec2::new(-2.5, -1.5), Vec2::new(2.5, 1.5)));
    // The affine map of every tetrahedron is then the identity on (x, y) and z -> w.
    for t in &shell.tetrahedra {
        let (to_uvw, _) = Shell::tetra_affine(t);
        let p = Vec3::new(0.3, -0.2, 0.01);
        let expected = Vec3::new(0.3, -0.2, (0.01 - w0) / (w1 - w0));
        assert!((to_uvw.transform_point3(p) - expected).abs().max_element() < 1e-5);
    }
    assert!((shell.volume_cm3() - 5.0 * 3.0 * 0.1).abs() < 1e-5);
}

#[test]
fn curved_builtins_are_not_flat() {
    for name in ["drape", "cushion"] {
        let mesh = BaseMesh::builtin(name, [20.0, 16.0]).unwrap();
        assert_eq!(mesh.triangles.len(), 64 * 64 * 2, "{name}");
        let shell = Shell::build(&mesh, &ShellSpec::outward(0.1, 1.0)).unwrap();
        assert!(!shell.is_flat && shell.flat_normal.is_none(), "{name}");
        assert_eq!(shell.tetrahedra.len(), 64 * 64 * 2 * 3);
        assert!(shell.repairs.is_clean(), "{name}: {}", shell.repairs);
    }
}

#[test]
fn curved_builtin_uvs_are_close_to_arc_length() {
    for name in ["drape", "cushion"] {
        let mesh = BaseMesh::builtin(name, [20.0, 20.0]).unwrap();
        let mut worst = 0.0f64;
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|i| i as usize);
            for (x, y) in [(a, b), (b, c), (c, a)] {
                let world = f64::from((mesh.positions[x] - mesh.positions[y]).length());
                let uv = f64::from((mesh.uvs[x] - mesh.uvs[y]).length());
                worst = worst.max((uv / world - 1.0).abs());
            }
        }
        assert!(worst < 0.12, "{name}: an edge is stretched by {worst}");
        // UVs are centred: the centre vertex sits at (0, 0).
        let centre = mesh.positions.iter().position(|p| p.x == 0.0 && p.y == 0.0).unwrap();
        assert_eq!(mesh.uvs[centre], Vec2::ZERO);
    }
}

#[test]
fn no_non_finite_values_anywhere() {
    for (name, shell) in test_shells() {
        let all = shell
            .tetrahedra
            .iter()
            .flatten()
            .chain(shell.top_triangles.iter().flatten())
            .chain(shell.bottom_triangles.iter().flatten())
            .chain(shell.side_triangles.iter().flatten())
            .chain(&shell.vertices);
        for v in all {
            assert!(v.position.is_finite() && v.uvw.is_finite(), "{name}: {v:?}");
        }
        assert!(shell.bounds_min.is_finite() && shell.bounds_max.is_finite());
        assert!(shell.uv_min.is_finite() && shell.uv_max.is_finite());
    }
}

#[test]
fn builtin_names_and_sizes() {
    for &name in BaseMesh::BUILTIN_NAMES {
        let mesh = BaseMesh::builtin(name, [10.0, 6.0]).unwrap();
        assert_eq!(mesh.source, format!("builtin:{name}"));
        let (lo, hi) = mesh.bounds().unwrap();
        assert_eq!((lo.x, hi.x, lo.y, hi.y), (-5.0, 5.0, -3.0, 3.0), "{name}");
    }
    let error = BaseMesh::builtin("sofa", [1.0, 1.0]).unwrap_err();
    assert!(matches!(error, ShellError::UnknownBuiltin { .. }));
    assert!(error.to_string().contains("swatch, drape, cushion"), "{error}");
    for size in [[0.0, 1.0], [f32::NAN, 1.0], [1.0, f32::INFINITY], [-1.0, 1.0], [1.0, 1e9]] {
        let error = BaseMesh::builtin("swatch", size).unwrap_err();
        assert!(matches!(error, ShellError::BuiltinSize { .. }), "{size:?}: {error}");
        assert!(error.to_string().contains("builtin:swatch"), "{error}");
    }
}

#[test]
fn obj_asset_loads_and_merges_objects() {
    let mesh = BaseMesh::load(&asset("bent_sheet.obj")).unwrap();
    assert_eq!(mesh.triangles.len(), 4 * 3 * 2 + 2 * 2);
    assert_eq!(mesh.positions.len(), 20 + 6);
    assert_eq!((mesh.normals.len(), mesh.uvs.len()), (26, 26));
    // The strip has no vn: its normals were computed (+z); the sheet's come from the file.
    assert!(mesh.normals[20..].iter().all(|n| (*n - Vec3::Z).length() < 1e-6));
    assert!((mesh.normals[0] - Vec3::new(-0.4, 0.0, 0.916515)).length() < 1e-5);
    assert!(mesh.source.ends_with("bent_sheet.obj"));
    let mut repaired = mesh.clone();
    assert!(repaired.validate_and_repair().unwrap().is_clean());
    let shell = Shell::build(&mesh, &ShellSpec::outward(0.2, 8.0)).unwrap();
    assert_eq!(shell.tetrahedra.len(), 28 * 3);
    assert!(!shell.is_flat);
}

#[test]
fn gltf_and_glb_assets_load_in_centimetres_with_flipped_v() {
    let gltf = BaseMesh::load(&asset("wave_patch.gltf")).unwrap();
    let glb = BaseMesh::load(&asset("wave_patch.glb")).unwrap();
    assert_eq!(gltf.triangles.len(), 3 * 3 * 2 + 2);
    assert_eq!(gltf.positions.len(), 16 + 4);
    assert_eq!((gltf.positions.clone(), gltf.uvs.clone()), (glb.positions, glb.uvs));
    assert_eq!((gltf.normals.clone(), gltf.triangles.clone()), (glb.normals, glb.triangles));
    // 0.06 m patch scaled by 2, translated 0.01 m up; the quad spans 0.05..0.07 m, also scaled by 2.
    let (lo, hi) = gltf.bounds().unwrap();
    assert!((lo.x + 6.0).abs() < 1e-4 && (hi.x - 14.0).abs() < 1e-4, "{lo} {hi}");
    assert!((gltf.positions[16].z - 1.0).abs() < 1e-5);
    // v is flipped to point up: the first row (y = -3 cm) has v = 0.
    assert_eq!(gltf.uvs[0], Vec2::new(0.0, 0.0));
    assert_eq!(gltf.uvs[15], Vec2::new(1.0, 1.0));
    let shell = Shell::build(&gltf, &ShellSpec::outward(0.1, 12.0)).unwrap();
    assert_eq!(shell.tetrahedra.len(), 20 * 3);
}

/// The GLB asset split into a glTF document whose buffer is the file `uri`, and that buffer.
fn gltf_with_buffer_file(uri: &str) -> (String, Vec<u8>) {
    let glb = std::fs::read(asset("wave_patch.glb")).unwrap();
    let u32_at = |at: usize| u32::from_le_bytes(glb[at..at + 4].try_into().unwrap()) as usize;
    let json_len = u32_at(12);
    let json = std::str::from_utf8(&glb[20..20 + json_len]).unwrap().trim_end().to_owned();
    let bin_len = u32_at(20 + json_len);
    let bin = glb[28 + json_len..28 + json_len + bin_len].to_vec();
    let with_uri = json.replacen("{\"byteLength\"", &format!("{{\"uri\":{uri:?},\"byteLength\""), 1);
    assert_ne!(with_uri, json);
    (with_uri, bin)
}

#[test]
fn external_buffer_files_are_read_relative_to_the_gltf_and_only_as_declared() {
    let dir = tempfile::tempdir().unwrap();
    let glb = BaseMesh::load(&asset("wave_patch.glb")).unwrap();
    let (document, mut bin) = gltf_with_buffer_file("buffer%20file.bin");
    // Bytes past the declared byteLength are not read.
    bin.extend_from_slice(&[0xff; 64]);
    std::fs::write(dir.path().join("buffer file.bin"), &bin).unwrap();
    let mesh = BaseMesh::parse_gltf(document.as_bytes(), "ext.gltf", Some(dir.path())).unwrap();
    assert_eq!((mesh.positions, mesh.triangles), (glb.positions, glb.triangles));
    // Absolute paths, folders and devices are refused, naming the buffer and the path.
    std::fs::create_dir(dir.path().join("folder")).unwrap();
    for (uri, expected) in [
        ("/dev/zero", "\"/dev/zero\" is an absolute path"),
        ("folder", "folder is not a regular file"),
        ("missing.bin", "cannot read"),
    ] {
        let (document, _) = gltf_with_buffer_file(uri);
        let (error, text) =
            error_text(BaseMesh::parse_gltf(document.as_bytes(), "ext.gltf", Some(dir.path())));
        assert!(matches!(error, ShellError::Parse { .. }), "{text}");
        assert!(text.contains("ext.gltf") && text.contains("buffer 0") && text.contains(expected), "{text}");
    }
}

fn error_text<T>(result: Result<T, ShellError>) -> (ShellError, String) {
    let Err(error) = result else { panic!("expected an error, got Ok") };
    let text = error.to_string();
    (error, text)
}

fn build(mesh: &BaseMesh, spec: &ShellSpec) -> Result<Shell, ShellError> {
    Shell::build(mesh, spec)
}

#[test]
fn missing_uvs_name_the_file() {
    let (error, text) = error_text(BaseMesh::load(&asset("bad_no_uvs.obj")));
    assert!(matches!(error, ShellError::MissingUvs { .. }), "{text}");
    assert!(text.contains("bad_no_uvs.obj") && text.contains("no texture coordinates"), "{text}");

    let gltf = std::fs::read_to_string(asset("wave_patch.gltf")).unwrap();
    let no_uv = gltf.replacen("\"NORMAL\": 1,\n      \"TEXCOORD_0\": 2", "\"NORMAL\": 1", 1);
    assert_ne!(no_uv, gltf);
    let (error, text) = error_text(BaseMesh::parse_gltf(no_uv.as_bytes(), "patch.gltf", None));
    assert!(matches!(error, ShellError::MissingUvs { .. }), "{text}");
    assert!(text.contains("patch.gltf") && text.contains("mesh 0 primitive 0"), "{text}");

    let mut mesh = BaseMesh::builtin("swatch", [1.0, 1.0]).unwrap();
    mesh.uvs.clear();
    let (error, text) = error_text(build(&mesh, &ShellSpec::outward(0.1, 1.0)));
    assert!(matches!(error, ShellError::MissingUvs { .. }) && text.contains("builtin:swatch"), "{text}");
}

#[test]
fn unreadable_and_unparsable_files_name_file_and_parser_message() {
    let (error, text) = error_text(BaseMesh::load(&asset("does_not_exist.obj")));
    assert!(matches!(error, ShellError::Read { .. }) && text.contains("does_not_exist.obj"), "{text}");
    let (error, text) = error_text(BaseMesh::load(&asset("mesh.stl")));
    assert!(matches!(error, ShellError::UnsupportedFormat { .. }) && text.contains("mesh.stl"), "{text}");
    let (error, text) = error_text(BaseMesh::load(&asset("bad_truncated.gltf")));
    assert!(matches!(error, ShellError::Parse { .. }), "{text}");
    assert!(text.contains("bad_truncated.gltf") && text.contains("glTF parser"), "{text}");
    let (error, text) = error_text(BaseMesh::load(&asset("bad_face_index.obj")));
    assert!(matches!(error, ShellError::Parse { line: Some(11), .. }), "{text}");
    assert!(text.contains("bad_face_index.obj:11") && text.contains("OBJ parser"), "{text}");
    let (error, text) = error_text(BaseMesh::parse_obj(b"v 0 0 0\nv 1 zero 0\n", "typo.obj"));
    assert!(
        matches!(error, ShellError::Parse { line: Some(2), .. }) && text.contains("typo.obj:2"),
        "{text}"
    );
    let (error, text) = error_text(BaseMesh::parse_gltf(b"glTF\x02\0\0\0", "short.glb", None));
    assert!(matches!(error, ShellError::Parse { .. }) && text.contains("short.glb"), "{text}");
}

#[test]
fn non_finite_positions_and_uvs_are_errors() {
    let mesh = BaseMesh::load(&asset("bad_nan_position.obj")).unwrap();
    let (error, text) = error_text(build(&mesh, &ShellSpec::outward(0.1, 1.0)));
    assert!(matches!(error, ShellError::NonFinite { vertex: 2, attribute: "position", .. }), "{text}");
    assert!(text.contains("bad_nan_position.obj") && text.contains("vertex 2"), "{text}");

    let mut mesh = BaseMesh::builtin("swatch", [1.0, 1.0]).unwrap();
    mesh.uvs[5].y = f32::INFINITY;
    let (error, text) = error_text(mesh.clone().validate_and_repair());
    assert!(matches!(error, ShellError::NonFinite { vertex: 5, attribute: "UV", .. }), "{text}");
}

#[test]
fn indices_out_of_range_are_errors() {
    let mut mesh = BaseMesh::builtin("swatch", [1.0, 1.0]).unwrap();
    mesh.triangles[3][2] = 1000;
    let before = mesh.clone();
    let (error, text) = error_text(mesh.validate_and_repair());
    assert!(
        matches!(error, ShellError::IndexOutOfRange { triangle: 3, corner: 2, index: 1000, .. }),
        "{text}"
    );
    assert!(text.contains("builtin:swatch") && text.contains("0..81"), "{text}");
    assert_eq!(mesh, before, "a failed repair leaves the mesh unchanged");
}

#[test]
fn degenerate_and_duplicate_triangles_are_dropped_and_counted() {
    let mut mesh = BaseMesh::builtin("swatch", [2.0, 2.0]).unwrap();
    let clean_count = mesh.triangles.len();
    mesh.triangles.push([0, 1, 2]); // collinear along the bottom row: zero world area
    mesh.triangles.push([3, 3, 12]); // repeated vertex
    mesh.triangles.push(mesh.triangles[5]); // duplicate
    let [a, b, c] = mesh.triangles[7];
    mesh.triangles.push([a, c, b]); // duplicate with the opposite winding
    let extra = mesh.positions.len() as u32;
    mesh.positions.extend([Vec3::new(5.0, 5.0, 0.0), Vec3::new(6.0, 5.0, 0.0), Vec3::new(5.0, 6.0, 0.0)]);
    mesh.normals.extend([Vec3::Z; 3]);
    mesh.uvs.extend([Vec2::new(5.0, 5.0), Vec2::new(6.0, 6.0), Vec2::new(7.0, 7.0)]); // zero UV area
    mesh.triangles.push([extra, extra + 1, extra + 2]);
    mesh.normals[4] = Vec3::new(f32::NAN, 0.0, 1.0); // unusable normal: replaced
    let shell = build(&mesh, &ShellSpec::outward(0.1, 1.0)).unwrap();
    assert_eq!(shell.tetrahedra.len(), clean_count * 3);
    let report = shell.repairs.clone();
    assert_eq!(report.degenerate_world_dropped, 2);
    assert_eq!(report.duplicates_dropped, 2);
    assert_eq!(report.degenerate_uv_dropped, 1);
    assert_eq!(report.unreferenced_vertices_removed, 3);
    assert_eq!(report.normals_replaced, 1);
    assert_eq!(report.dropped_triangles, (clean_count..clean_count + 5).collect::<Vec<_>>());
    assert!(report.to_string().contains("dropped 2 zero-area triangles"), "{report}");
    let mut repaired = mesh.clone();
    assert_eq!(repaired.validate_and_repair().unwrap(), report);
    assert_eq!(repaired.triangles.len(), clean_count);
    assert_eq!(repaired.normals[4], Vec3::Z);

    let mut all_bad = mesh.clone();
    all_bad.triangles = vec![[0, 1, 2], [0, 0, 1]];
    let (error, text) = error_text(all_bad.validate_and_repair());
    assert!(matches!(error, ShellError::NoTriangles { .. }) && text.contains("all 2 triangles"), "{text}");
}

#[test]
fn non_manifold_edges_and_flipped_neighbours_are_errors() {
    let mesh = BaseMesh::load(&asset("bad_non_manifold.obj")).unwrap();
    let (error, text) = error_text(build(&mesh, &ShellSpec::outward(0.1, 1.0)));
    assert!(
        matches!(&error, ShellError::NonManifoldEdge { edge: [0, 1], triangles, .. } if triangles.len() == 3)
    );
    assert!(text.contains("bad_non_manifold.obj") && text.contains("vertices 0 and 1"), "{text}");

    let mut mesh = BaseMesh::builtin("swatch", [1.0, 1.0]).unwrap();
    let [a, b, c] = mesh.triangles[1];
    mesh.triangles[1] = [a, c, b];
    let (error, text) = error_text(mesh.validate_and_repair());
    assert!(matches!(error, ShellError::InconsistentWinding { triangles: [0, 1], .. }), "{text}");
    assert!(text.contains("triangles 0 and 1"), "{text}");
}

#[test]
fn mirrored_uvs_are_errors() {
    let mut mesh = BaseMesh::builtin("swatch", [1.0, 1.0]).unwrap();
    for uv in &mut mesh.uvs {
        uv.y = -uv.y;
    }
    let (error, text) = error_text(build(&mesh, &ShellSpec::outward(0.1, 1.0)));
    assert!(matches!(error, ShellError::MirroredUv { triangle: 0, mirrored_count: 128, .. }), "{text}");
    assert!(text.contains("builtin:swatch") && text.contains("mirrored"), "{text}");
}

#[test]
fn inverted_shells_name_the_triangle() {
    let mut mesh = BaseMesh::builtin("swatch", [1.0, 1.0]).unwrap();
    mesh.normals[40] = -Vec3::Z; // the centre vertex's normal flipped: its prisms turn inside out
    let (error, text) = error_text(build(&mesh, &ShellSpec::outward(0.1, 1.0)));
    let ShellError::InvertedPrism { triangle, vertices, .. } = error else { panic!("{text}") };
    assert!(vertices.contains(&40), "{text}");
    assert!(text.contains(&format!("triangle {triangle} ")) && text.contains("builtin:swatch"), "{text}");

    // A shell thicker than the folds' curvature radius folds over.
    let drape = BaseMesh::builtin("drape", [20.0, 20.0]).unwrap();
    let (error, text) = error_text(build(&drape, &ShellSpec::outward(6.0, 1.0)));
    assert!(matches!(error, ShellError::InvertedPrism { .. }), "{text}");
}

type IsExpected = fn(&ShellError) -> bool;

#[test]
fn spec_values_out_of_range_are_errors() {
    let mesh = BaseMesh::builtin("swatch", [4.0, 3.0]).unwrap(); // diagonal 5 cm
    let cases: Vec<(ShellSpec, IsExpected, &str)> = vec![
        (ShellSpec::outward(3.0, 1.0), |e| matches!(e, ShellError::Thickness { .. }), "2.5]"),
        (ShellSpec::outward(1e-7, 1.0), |e| matches!(e, ShellError::Thickness { .. }), "[0.00002, 2.5]"),
        (ShellSpec::outward(0.0, 1.0), |e| matches!(e, ShellError::WRange { .. }), "greater than"),
        (ShellSpec::new([0.2, 0.1], 1.0), |e| matches!(e, ShellError::WRange { .. }), "greater than"),
        (ShellSpec::new([f32::NAN, 0.1], 1.0), |e| matches!(e, ShellError::WRange { .. }), "finite"),
        (ShellSpec::new([2.4, 2.6], 1.0), |e| matches!(e, ShellError::WRange { .. }), "offset"),
        (
            ShellSpec { thickness_cm: 0.2, cm_per_uv: 1.0, w_range_cm: [0.0, 0.1] },
            |e| matches!(e, ShellError::ThicknessMismatch { .. }),
            "spans 0.1 cm",
        ),
        (ShellSpec::outward(0.1, 0.0), |e| matches!(e, ShellError::CmPerUv { .. }), "cm_per_uv = 0"),
        (ShellSpec::outward(0.1, -2.0), |e| matches!(e, ShellError::CmPerUv { .. }), "cm_per_uv = -2"),
        (ShellSpec::outward(0.1, f32::NAN), |e| matches!(e, ShellError::CmPerUv { .. }), "NaN"),
        (ShellSpec::outward(0.1, f32::MAX), |e| matches!(e, ShellError::CmPerUv { .. }), "finite"),
    ];
    for (spec, is_expected, fragment) in cases {
        let (error, text) = error_text(build(&mesh, &spec));
        assert!(is_expected(&error), "{spec:?}: {text}");
        assert!(text.contains("builtin:swatch") && text.contains(fragment), "{spec:?}: {text}");
    }

    // Thin relative to the distance from the origin: f32 cannot resolve it.
    let mut far = mesh.clone();
    for p in &mut far.positions {
        *p += Vec3::new(5e5, 0.0, 0.0);
    }
    let (error, text) = error_text(build(&far, &ShellSpec::outward(1.0, 1.0)));
    assert!(matches!(error, ShellError::Thickness { .. }) && text.contains("largest |coordinate|"), "{text}");
}

#[test]
fn absurd_mesh_sizes_are_errors() {
    let mesh = BaseMesh::builtin("swatch", [1.0, 1.0]).unwrap();
    for (factor, expect_far) in [(1e-5, false), (2e5, false), (1e7, true)] {
        let mut scaled = mesh.clone();
        for p in &mut scaled.positions {
            *p *= factor;
        }
        let (error, text) = error_text(scaled.validate_and_repair());
        if expect_far {
            assert!(matches!(error, ShellError::FarFromOrigin { .. }), "{text}");
        } else {
            assert!(matches!(error, ShellError::MeshSize { .. }), "{text}");
            assert!(text.contains("[1e-4, 1e5] cm"), "{text}");
        }
    }
    let mut mismatched = mesh.clone();
    mismatched.normals.pop();
    let (error, text) = error_text(mismatched.validate_and_repair());
    assert!(matches!(
        error,
        ShellError::AttributeCount { attribute: "normals", count: 80, expected: 81, .. }
    ));
    assert!(text.contains("builtin:swatch"), "{text}");
    let empty = BaseMesh { triangles: Vec::new(), ..mesh };
    assert!(matches!(empty.clone().validate_and_repair(), Err(ShellError::NoTriangles { .. })));
}

#[test]
fn gltf_point_and_line_primitives_are_rejected() {
    let gltf = std::fs::read_to_string(asset("wave_patch.gltf")).unwrap();
    let lines = gltf.replacen("\"indices\": 3\n", "\"indices\": 3,\n \"mode\": 1\n", 1);
    assert_ne!(lines, gltf);
    let (error, text) = error_text(BaseMesh::parse_gltf(lines.as_bytes(), "lines.gltf", None));
    assert!(matches!(error, ShellError::UnsupportedPrimitive { mesh: 0, primitive: 0, .. }), "{text}");
    assert!(text.contains("lines.gltf") && text.contains("Lines"), "{text}");
}

/// A tiny deterministic generator for the mangling tests.
struct Lcg(u64);

impl Lcg {
    fn below(&mut self, n: usize) -> usize {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 33) as usize) % n.max(1)
    }
}

/// Parses and shells `bytes`; whatever happens must be an `Ok` or an error naming the source.
fn survive(bytes: &[u8], source: &str, parse: fn(&[u8], &str) -> Result<BaseMesh, ShellError>) -> bool {
    let result = parse(bytes, source).and_then(|mesh| Shell::build(&mesh, &ShellSpec::outward(0.05, 4.0)));
    if let Err(error) = &result {
        assert!(error.file().is_none_or(|f| f == source), "{error}");
        assert!(error.to_string().contains(source), "{error}");
    }
    result.is_ok()
}

fn mangled(original: &[u8], rng: &mut Lcg) -> Vec<u8> {
    const TOKENS: &[&[u8]] = &[
        b"0",
        b"9",
        b"-",
        b"/",
        b" ",
        b"\n",
        b"f",
        b"v",
        b"vt",
        b"vn",
        b".",
        b"e",
        b"nan",
        b"inf",
        b"-1",
        b"99999999999999999999",
        b"4294967296",
        b"1e39",
        b"\0",
        b"\xff",
        b"//",
        b"{",
        b"]",
        b"\"",
        b":",
    ];
    let mut bytes = original.to_vec();
    for _ in 0..=rng.below(4) {
        let at = rng.below(bytes.len() + 1);
        let token = TOKENS[rng.below(TOKENS.len())];
        match rng.below(3) {
            0 => {
                bytes.splice(at..at, token.iter().copied());
            }
            1 => {
                let end = (at + 1 + rng.below(6)).min(bytes.len());
                bytes.splice(at..end, token.iter().copied());
            }
            _ => {
                let end = (at + rng.below(12)).min(bytes.len());
                bytes.drain(at..end);
            }
        }
    }
    bytes
}

#[test]
fn truncated_and_mutated_obj_never_panics() {
    let original = std::fs::read(asset("bent_sheet.obj")).unwrap();
    let parse: fn(&[u8], &str) -> Result<BaseMesh, ShellError> = BaseMesh::parse_obj;
    assert!(survive(&original, "fuzz.obj", parse));
    for end in 0..original.len() {
        survive(&original[..end], "fuzz.obj", parse);
    }
    let mut rng = Lcg(7);
    let mut ok = 0;
    for _ in 0..3000 {
        ok += usize::from(survive(&mangled(&original, &mut rng), "fuzz.obj", parse));
    }
    assert!(ok > 0 && ok < 3000, "{ok} of 3000 mangled OBJ files shelled");
}

#[test]
fn truncated_and_mutated_gltf_never_panics() {
    let parse: fn(&[u8], &str) -> Result<BaseMesh, ShellError> = |b, s| BaseMesh::parse_gltf(b, s, None);
    for name in ["wave_patch.gltf", "wave_patch.glb"] {
        let original = std::fs::read(asset(name)).unwrap();
        assert!(survive(&original, "fuzz.gltf", parse));
        for end in (0..original.len()).step_by(5) {
            survive(&original[..end], "fuzz.gltf", parse);
        }
        let mut rng = Lcg(11);
        for _ in 0..1500 {
            survive(&mangled(&original, &mut rng), "fuzz.gltf", parse);
        }
    }
    // Accessor layouts the gltf reader would assert on become errors.
    let gltf = std::fs::read_to_string(asset("wave_patch.gltf")).unwrap();
    let empty = gltf.replacen("\"count\": 16", "\"count\": 0", 1);
    assert_ne!(empty, gltf);
    assert!(!survive(empty.as_bytes(), "fuzz.gltf", parse));
}

#[test]
fn curved_builtins_take_shells_a_tenth_of_their_size_thick() {
    // Documented limit: about 0.1 x the shorter side (the tightest concave curvature radius).
    for name in ["drape", "cushion"] {
        for size in [[20.0, 20.0], [30.0, 20.0], [20.0, 30.0]] {
            let mesh = BaseMesh::builtin(name, size).unwrap();
            let shell = Shell::build(&mesh, &ShellSpec::outward(0.1 * 20.0, 1.0));
            assert!(shell.is_ok(), "{name} {size:?}: {}", shell.err().unwrap());
        }
    }
}
