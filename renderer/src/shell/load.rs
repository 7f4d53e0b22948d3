//! Loading base meshes from OBJ (via `tobj`) and glTF 2.0 (`.gltf`/`.glb`, via `gltf`).
//!
//! Both loaders merge everything in the file into one [`BaseMesh`]:
//! - OBJ: every object/group; polygons are fan-triangulated; a vertex is one (v, vt, vn) combination,
//!   so UV seams and hard normal edges split vertices (and become shell borders). Positions are
//!   taken as centimetres. Materials are ignored (no `.mtl` is read). A part without `vn` gets
//!   area-weighted normals; a part without `vt` is an error.
//! - glTF: every triangle primitive of every mesh instance in the default scene (or the first scene;
//!   every mesh once, untransformed, when there is none), with node transforms applied. glTF's unit
//!   is the metre, so positions are multiplied by 100 to get centimetres. `TEXCOORD_0` is used; its
//!   v axis points down in glTF, so v is flipped (v ← 1 − v) into the OBJ convention. Buffers may be
//!   GLB binary chunks, base64 `data:` URIs or regular files relative to the `.gltf` (at most the
//!   buffer's declared byteLength is read). Points and lines are rejected.
//!
//! Neither parser is trusted not to panic on hostile input: each runs under `catch_unwind`, and a
//! panic becomes [`ShellError::Parse`].

use std::collections::HashMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use glam::{Mat3, Mat4, Vec2, Vec3};
use gltf::mesh::Mode;

use super::mesh::area_weighted_normals;
use super::{BaseMesh, ShellError};

/// glTF positions are metres; base meshes are centimetres.
const CM_PER_METRE: f32 = 100.0;
/// Deepest glTF node hierarchy followed.
const MAX_NODE_DEPTH: usize = 256;

impl BaseMesh {
    /// Loads a mesh file, choosing the parser by extension: `.obj`, `.gltf` or `.glb`
    /// (case-insensitive). All meshes/primitives in the file are merged. The result is not yet
    /// validated; [`Shell::build`](super::Shell::build) validates it (or call
    /// [`BaseMesh::validate_and_repair`]).
    pub fn load(path: &Path) -> Result<BaseMesh, ShellError> {
        let file = path.display().to_string();
        let extension = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        if !matches!(extension.as_str(), "obj" | "gltf" | "glb") {
            return Err(ShellError::UnsupportedFormat { file, extension });
        }
        let bytes = std::fs::read(path)
            .map_err(|e| ShellError::Read { file: file.clone(), message: e.to_string() })?;
        if extension == "obj" {
            Self::parse_obj(&bytes, &file)
        } else {
            Self::parse_gltf(&bytes, &file, path.parent())
        }
    }

    /// Parses OBJ text; `source` names it in messages.
    pub fn parse_obj(bytes: &[u8], source: &str) -> Result<BaseMesh, ShellError> {
        let options = tobj::LoadOptions {
            single_index: true,
            triangulate: true,
            ignore_points: true,
            ignore_lines: true,
        };
        let parse_error = |line, message| ShellError::Parse { file: source.to_owned(), line, message };
        let parsed = catch_unwind(AssertUnwindSafe(|| {
            let mut reader = bytes;
            tobj::load_obj_buf(&mut reader, &options, |_| Ok((Vec::new(), HashMap::new())))
        }));
        let models = match parsed {
            Ok(Ok((models, _materials))) => models,
            Ok(Err(error)) => {
                return Err(parse_error(locate_obj_error(bytes, error), format!("OBJ parser: {error}")));
            }
            Err(_) => return Err(parse_error(None, "the OBJ parser panicked on this input".to_owned())),
        };

        let mut mesh = empty(source);
        for (index, model) in models.iter().enumerate() {
            let part = || {
                if model.name.is_empty() || model.name == "unnamed_object" {
                    format!("OBJ object {index}")
                } else {
                    format!("OBJ object {index} ({:?})", model.name)
                }
            };
            let m = &model.mesh;
            let count = m.positions.len() / 3;
            if m.indices.is_empty() {
                continue;
            }
            if m.texcoords.is_empty() {
                return Err(ShellError::MissingUvs { file: source.to_owned(), part: part() });
            }
            if m.texcoords.len() != 2 * count {
                return Err(ShellError::MissingUvs {
                    file: source.to_owned(),
                    part: format!(
                        "{} ({} of {} vertices have no vt)",
                        part(),
                        count.saturating_sub(m.texcoords.len() / 2),
                        count
                    ),
                });
            }
            let positions: Vec<Vec3> = m.positions.chunks_exact(3).map(Vec3::from_slice).collect();
            let uvs = m.texcoords.chunks_exact(2).map(Vec2::from_slice);
            if !m.indices.len().is_multiple_of(3) {
                return Err(parse_error(None, format!("{} has a face that is not a triangle", part())));
            }
            let triangles: Vec<[u32; 3]> = m.indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
            let normals = if m.normals.len() == 3 * count {
                m.normals.chunks_exact(3).map(Vec3::from_slice).collect()
            } else {
                // tobj checked the indices, so the area-weighted normals can index safely.
                if triangles.iter().flatten().any(|&i| i as usize >= count) {
                    return Err(parse_error(None, format!("{} has a face index out of range", part())));
                }
                area_weighted_normals(&positions, triangles.iter().copied())
            };
            append(&mut mesh, positions, normals, uvs, triangles);
        }
        if mesh.triangles.is_empty() {
            return Err(ShellError::NoTriangles {
                file: source.to_owned(),
                detail: "the OBJ has no faces".to_owned(),
            });
        }
        Ok(mesh)
    }

    /// Parses glTF JSON or GLB bytes; `base_dir` resolves external buffer files (none when `None`).
    pub fn parse_gltf(bytes: &[u8], source: &str, base_dir: Option<&Path>) -> Result<BaseMesh, ShellError> {
        match catch_unwind(AssertUnwindSafe(|| parse_gltf_inner(bytes, source, base_dir))) {
            Ok(result) => result,
            Err(_) => Err(ShellError::Parse {
                file: source.to_owned(),
                line: None,
                message: "the glTF reader panicked on this input".to_owned(),
            }),
        }
    }
}

fn empty(source: &str) -> BaseMesh {
    BaseMesh {
        positions: Vec::new(),
        normals: Vec::new(),
        uvs: Vec::new(),
        triangles: Vec::new(),
        source: source.to_owned(),
    }
}

fn append(
    mesh: &mut BaseMesh,
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    uvs: impl Iterator<Item = Vec2>,
    triangles: Vec<[u32; 3]>,
) {
    let offset = mesh.positions.len() as u32;
    mesh.positions.extend(positions);
    mesh.normals.extend(normals);
    mesh.uvs.extend(uvs);
    mesh.triangles.extend(triangles.into_iter().map(|t| t.map(|i| i.saturating_add(offset))));
}

/// Best-effort line number for a tobj error: tobj does not report one, so the text is scanned for
/// the first line of the kind the error is about that is malformed.
fn locate_obj_error(bytes: &[u8], error: tobj::LoadError) -> Option<usize> {
    use tobj::LoadError as E;
    let text = String::from_utf8_lossy(bytes);
    let (mut positions, mut texcoords, mut normals) = (0usize, 0usize, 0usize);
    let numbers_ok = |fields: &[&str], min: usize, max: usize| {
        (min..=max).contains(&fields.len()) && fields.iter().all(|f| f.parse::<f32>().is_ok())
    };
    let index_ok = |field: &str, count: usize| {
        if field.is_empty() {
            return true;
        }
        match field.parse::<i64>() {
            Ok(i) if i > 0 => (i as usize) <= count,
            Ok(i) if i < 0 => i.unsigned_abs() as usize <= count,
            _ => false,
        }
    };
    for (number, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        let keyword = words.next().unwrap_or("");
        let fields: Vec<&str> = words.collect();
        let bad = match keyword {
            "v" => {
                positions += 1;
                matches!(error, E::PositionParseError | E::ColorParseError) && !numbers_ok(&fields, 3, 7)
            }
            "vt" => {
                texcoords += 1;
                matches!(error, E::TexcoordParseError) && !numbers_ok(&fields, 1, 3)
            }
            "vn" => {
                normals += 1;
                matches!(error, E::NormalParseError) && !numbers_ok(&fields, 3, 3)
            }
            "f" => {
                let face_error = matches!(
                    error,
                    E::FaceParseError
                        | E::InvalidPolygon
                        | E::FaceVertexOutOfBounds
                        | E::FaceTexCoordOutOfBounds
                        | E::FaceNormalOutOfBounds
                );
                face_error
                    && (fields.len() < 3
                        || fields.iter().any(|corner| {
                            let parts: Vec<&str> = corner.split('/').collect();
                            parts.len() > 3
                                || parts[0].is_empty()
                                || !index_ok(parts[0], positions)
                                || !parts.get(1).is_none_or(|p| index_ok(p, texcoords))
                                || !parts.get(2).is_none_or(|p| index_ok(p, normals))
                        }))
            }
            _ => false,
        };
        if bad {
            return Some(number + 1);
        }
    }
    None
}

fn parse_gltf_inner(bytes: &[u8], source: &str, base_dir: Option<&Path>) -> Result<BaseMesh, ShellError> {
    let parse_error = |message: String| ShellError::Parse { file: source.to_owned(), line: None, message };
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice(bytes).map_err(|e| parse_error(format!("glTF parser: {e}")))?;

    let mut buffers = Vec::new();
    for buffer in document.buffers() {
        let data = match buffer.source() {
            gltf::buffer::Source::Bin => blob.clone().ok_or_else(|| {
                parse_error(format!("buffer {} refers to a missing GLB BIN chunk", buffer.index()))
            })?,
            gltf::buffer::Source::Uri(uri) => load_uri(uri, base_dir, buffer.length())
                .map_err(|e| parse_error(format!("buffer {} ({}): {e}", buffer.index(), shorten(uri))))?,
        };
        if data.len() < buffer.length() {
            return Err(parse_error(format!(
                "buffer {} has {} bytes but declares byteLength {}",
                buffer.index(),
                data.len(),
                buffer.length()
            )));
        }
        buffers.push(data);
    }

    // (mesh, transform) pairs to merge.
    let mut instances: Vec<(gltf::Mesh, Mat4)> = Vec::new();
    if let Some(scene) = document.default_scene().or_else(|| document.scenes().next()) {
        let mut stack: Vec<(gltf::Node, Mat4, usize)> =
            scene.nodes().map(|n| (n, Mat4::IDENTITY, 0)).collect();
        let mut visited = vec![false; document.nodes().len()];
        while let Some((node, parent, depth)) = stack.pop() {
            if depth > MAX_NODE_DEPTH || visited.get(node.index()).copied().unwrap_or(true) {
                continue; // a cycle or an absurd depth: the file is invalid, skip the repeat
            }
            visited[node.index()] = true;
            let transform = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
            if let Some(mesh) = node.mesh() {
                instances.push((mesh, transform));
            }
            stack.extend(node.children().map(|child| (child, transform, depth + 1)));
        }
    } else {
        instances.extend(document.meshes().map(|m| (m, Mat4::IDENTITY)));
    }

    let mut mesh = empty(source);
    for (gltf_mesh, transform) in instances {
        let to_cm = Mat4::from_scale(Vec3::splat(CM_PER_METRE)) * transform;
        let normal_matrix = Mat3::from_mat4(transform).inverse().transpose();
        let mirrored = Mat3::from_mat4(transform).determinant() < 0.0;
        for primitive in gltf_mesh.primitives() {
            let (m, p) = (gltf_mesh.index(), primitive.index());
            let place = format!("mesh {m} primitive {p}");
            let mode = primitive.mode();
            if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
                return Err(ShellError::UnsupportedPrimitive {
                    file: source.to_owned(),
                    mesh: m,
                    primitive: p,
                    mode: format!("{mode:?}"),
                });
            }
            check_accessors(&primitive).map_err(|e| parse_error(format!("{place}: {e}")))?;
            let reader = primitive.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
            let positions: Vec<Vec3> = reader
                .read_positions()
                .ok_or_else(|| parse_error(format!("{place}: POSITION data lies outside its buffer")))?
                .map(|p| to_cm.transform_point3(Vec3::from(p)))
                .collect();
            let count = positions.len();
            if primitive.get(&gltf::Semantic::TexCoords(0)).is_none() {
                return Err(ShellError::MissingUvs {
                    file: source.to_owned(),
                    part: format!("glTF {place}"),
                });
            }
            let uvs: Vec<Vec2> = reader
                .read_tex_coords(0)
                .ok_or_else(|| parse_error(format!("{place}: TEXCOORD_0 data lies outside its buffer")))?
                .into_f32()
                .map(|[u, v]| Vec2::new(u, 1.0 - v))
                .collect();
            let indices: Vec<u32> = match reader.read_indices() {
                Some(indices) => indices.into_u32().collect(),
                None if primitive.indices().is_some() => {
                    return Err(parse_error(format!("{place}: index data lies outside its buffer")));
                }
                None => (0..count as u32).collect(),
            };
            if uvs.len() != count {
                return Err(parse_error(format!(
                    "{place}: TEXCOORD_0 has {} entries, POSITION {count}",
                    uvs.len()
                )));
            }
            if let Some(&bad) = indices.iter().find(|&&i| i as usize >= count) {
                return Err(parse_error(format!("{place}: index {bad} is out of range 0..{count}")));
            }
            let mut triangles = assemble(mode, &indices).ok_or_else(|| {
                parse_error(format!("{place}: {} indices do not form whole triangles", indices.len()))
            })?;
            if mirrored {
                for t in &mut triangles {
                    t.swap(1, 2);
                }
            }
            let normals: Vec<Vec3> = match reader.read_normals() {
                Some(normals) => {
                    normals.map(|n| (normal_matrix * Vec3::from(n)).normalize_or_zero()).collect()
                }
                None if primitive.get(&gltf::Semantic::Normals).is_some() => {
                    return Err(parse_error(format!("{place}: NORMAL data lies outside its buffer")));
                }
                None => area_weighted_normals(&positions, triangles.iter().copied()),
            };
            if normals.len() != count {
                return Err(parse_error(format!(
                    "{place}: NORMAL has {} entries, POSITION {count}",
                    normals.len()
                )));
            }
            append(&mut mesh, positions, normals, uvs.into_iter(), triangles);
        }
    }
    if mesh.triangles.is_empty() {
        return Err(ShellError::NoTriangles {
            file: source.to_owned(),
            detail: "the glTF has no triangle primitives in its scene".to_owned(),
        });
    }
    Ok(mesh)
}

/// Rejects accessor layouts the `gltf` reader would assert on (a zero count, a stride shorter than
/// the element, the wrong element type), so they become errors instead of panics.
fn check_accessors(primitive: &gltf::Primitive) -> Result<(), String> {
    use gltf::accessor::{DataType, Dimensions};
    let check = |name: &str, accessor: gltf::Accessor, dims: &[Dimensions], types: &[DataType]| {
        if accessor.count() == 0 {
            return Err(format!("{name} accessor {} is empty", accessor.index()));
        }
        if !dims.contains(&accessor.dimensions()) || !types.contains(&accessor.data_type()) {
            return Err(format!(
                "{name} accessor {} has type {:?} {:?}, expected one of {dims:?} of {types:?}",
                accessor.index(),
                accessor.dimensions(),
                accessor.data_type()
            ));
        }
        if accessor.sparse().is_some_and(|s| s.count() == 0) {
            return Err(format!("{name} accessor {} has an empty sparse block", accessor.index()));
        }
        if let Some(view) = accessor.view()
            && view.stride().is_some_and(|stride| stride < accessor.size())
        {
            return Err(format!(
                "{name} accessor {} has a byteStride shorter than its element",
                accessor.index()
            ));
        }
        Ok(())
    };
    let position = primitive.get(&gltf::Semantic::Positions).ok_or("it has no POSITION attribute")?;
    check("POSITION", position, &[Dimensions::Vec3], &[DataType::F32])?;
    if let Some(normal) = primitive.get(&gltf::Semantic::Normals) {
        check("NORMAL", normal, &[Dimensions::Vec3], &[DataType::F32])?;
    }
    if let Some(uv) = primitive.get(&gltf::Semantic::TexCoords(0)) {
        check("TEXCOORD_0", uv, &[Dimensions::Vec2], &[DataType::F32, DataType::U8, DataType::U16])?;
    }
    if let Some(indices) = primitive.indices() {
        check("indices", indices, &[Dimensions::Scalar], &[DataType::U8, DataType::U16, DataType::U32])?;
    }
    Ok(())
}

/// Triangles from a primitive's indices, `None` if they do not form whole triangles.
fn assemble(mode: Mode, indices: &[u32]) -> Option<Vec<[u32; 3]>> {
    match mode {
        Mode::Triangles => indices
            .len()
            .is_multiple_of(3)
            .then(|| indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect()),
        Mode::TriangleStrip if indices.len() >= 3 => Some(
            indices
                .windows(3)
                .enumerate()
                .map(|(k, w)| if k % 2 == 0 { [w[0], w[1], w[2]] } else { [w[1], w[0], w[2]] })
                .collect(),
        ),
        Mode::TriangleFan if indices.len() >= 3 => {
            Some(indices[1..].windows(2).map(|w| [indices[0], w[0], w[1]]).collect())
        }
        _ => None,
    }
}

/// The bytes behind a buffer URI: a base64 `data:` URI or a file relative to `base_dir`, of
/// which at most `declared` bytes (the buffer's byteLength) are read. Absolute paths and files
/// that are not regular files (devices, pipes, folders) are refused.
fn load_uri(uri: &str, base_dir: Option<&Path>, declared: usize) -> Result<Vec<u8>, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, payload) = rest.split_once(";base64,").ok_or("only base64 data URIs are supported")?;
        return decode_base64(payload);
    }
    if uri.contains("://") {
        return Err("only data: URIs and relative file paths are supported".to_owned());
    }
    let base_dir = base_dir.ok_or("an external buffer file needs the .gltf's folder")?;
    let relative = percent_decode(uri)?;
    if Path::new(&relative).has_root() {
        return Err(format!("{relative:?} is an absolute path; buffer files are relative to the .gltf"));
    }
    let path = base_dir.join(relative);
    let cannot_read = |e: std::io::Error| format!("cannot read {}: {e}", path.display());
    let file = std::fs::File::open(&path).map_err(cannot_read)?;
    let metadata = file.metadata().map_err(cannot_read)?;
    if !metadata.is_file() {
        return Err(format!("{} is not a regular file", path.display()));
    }
    // Only the declared bytes are read; a shorter file is reported by the caller.
    let length = metadata.len().min(declared as u64);
    let mut data = Vec::with_capacity(length as usize);
    std::io::Read::read_to_end(&mut std::io::Read::take(file, length), &mut data).map_err(cannot_read)?;
    Ok(data)
}

fn shorten(uri: &str) -> String {
    if uri.len() > 48 { format!("{}...", uri.chars().take(45).collect::<String>()) } else { uri.to_owned() }
}

/// Standard base64 (RFC 4648, `+/`, optional `=` padding, whitespace ignored).
fn decode_base64(text: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(text.len() * 3 / 4);
    let (mut bits, mut bit_count) = (0u32, 0u32);
    let mut padding = false;
    for (position, byte) in text.bytes().enumerate() {
        let value = match byte {
            b'A'..=b'Z' => byte - b'A',
            b'a'..=b'z' => byte - b'a' + 26,
            b'0'..=b'9' => byte - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            b'=' => {
                padding = true;
                continue;
            }
            b' ' | b'\n' | b'\r' | b'\t' => continue,
            _ => return Err(format!("invalid base64 character {:?} at offset {position}", byte as char)),
        };
        if padding {
            return Err(format!("base64 data continues after '=' padding at offset {position}"));
        }
        bits = (bits << 6) | u32::from(value);
        bit_count += 6;
        if bit_count >= 8 {
            bit_count -= 8;
            out.push((bits >> bit_count) as u8);
            bits &= (1 << bit_count) - 1;
        }
    }
    Ok(out)
}

fn percent_decode(uri: &str) -> Result<String, String> {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = uri.get(i + 1..i + 3).ok_or_else(|| format!("bad percent escape in {uri:?}"))?;
            out.push(u8::from_str_radix(hex, 16).map_err(|_| format!("bad percent escape in {uri:?}"))?);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    String::from_utf8(out).map_err(|_| format!("URI {uri:?} is not UTF-8 after percent-decoding"))
}
