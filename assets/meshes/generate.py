#!/usr/bin/env python3
"""Regenerates the small test meshes in this folder (run from anywhere; writes next to itself).

bent_sheet.obj     two OBJ objects: a 4x3-quad sheet bent over a cylinder (vt, vn, quads) and a
                   2x1-quad strip without normals; 28 triangles after triangulation. Units: cm.
wave_patch.gltf    one mesh, two primitives: a 3x3-quad wave (NORMAL, TEXCOORD_0, u16 indices) and a
                   single quad without normals (u8 indices); 20 triangles. Units: metres (glTF),
                   node translation + uniform scale 2; UVs in glTF's v-down convention.
wave_patch.glb     the same as a binary glTF.
The bad_*.obj/gltf files are hand-written invalid inputs for the error tests.
"""
import base64, json, math, os, struct

HERE = os.path.dirname(os.path.abspath(__file__))


def bent_sheet():
    radius, nx, ny, w, h = 10.0, 4, 3, 8.0, 6.0
    lines = ["# bent sheet: 4x3 quads over a cylinder of radius 10 cm, plus a flat strip", "mtllib missing.mtl",
             "o sheet"]
    for j in range(ny + 1):
        for i in range(nx + 1):
            x, y = -w / 2 + w * i / nx, -h / 2 + h * j / ny
            z = math.sqrt(radius * radius - x * x) - radius
            lines.append(f"v {x:.6f} {y:.6f} {z:.6f}")
            lines.append(f"vt {i / nx:.6f} {j / ny:.6f}")
            lines.append(f"vn {x / radius:.6f} 0 {(z + radius) / radius:.6f}")
    for j in range(ny):
        for i in range(nx):
            a = j * (nx + 1) + i + 1
            b, c, d = a + 1, a + nx + 2, a + nx + 1
            lines.append(f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c} {d}/{d}/{d}")
    lines.append("o strip")
    base = (nx + 1) * (ny + 1)
    for j in range(2):
        for i in range(3):
            lines.append(f"v {20 + 2.0 * i:.1f} {2.0 * j:.1f} 0")
            lines.append(f"vt {0.5 * i:.2f} {0.5 * j:.2f}")
    for i in range(2):
        a = base + i + 1
        b, c, d = a + 1, a + 4, a + 3
        lines.append(f"f {a}/{a} {b}/{b} {c}/{c} {d}/{d}")
    with open(os.path.join(HERE, "bent_sheet.obj"), "w") as f:
        f.write("\n".join(lines) + "\n")


def wave_patch():
    n, size = 3, 0.06
    pos, nrm, uv, idx = [], [], [], []
    for j in range(n + 1):
        for i in range(n + 1):
            x, y = size * i / n - size / 2, size * j / n - size / 2
            k = 2 * math.pi / size
            z = 0.004 * math.sin(k * x)
            dz = 0.004 * k * math.cos(k * x)
            l = math.sqrt(1 + dz * dz)
            pos += [x, y, z]
            nrm += [-dz / l, 0.0, 1 / l]
            uv += [i / n, 1 - j / n]  # glTF: v points down
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            b, c, d = a + 1, a + n + 2, a + n + 1
            idx += [a, b, c, a, c, d]
    quad_pos = [0.05, 0, 0, 0.07, 0, 0, 0.07, 0.02, 0, 0.05, 0.02, 0]
    quad_uv = [0, 1, 1, 1, 1, 0, 0, 0]
    quad_idx = [0, 1, 2, 0, 2, 3]

    chunks, views, accessors = [], [], []

    def add(data, fmt, count, comp, typ, target, minmax=None):
        raw = struct.pack("<" + fmt * len(data), *data)
        while len(raw) % 4:
            raw += b"\0"
        offset = sum(len(c) for c in chunks)
        chunks.append(raw)
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(raw), "target": target})
        acc = {"bufferView": len(views) - 1, "componentType": comp, "count": count, "type": typ}
        if minmax:
            acc["min"], acc["max"] = minmax
        accessors.append(acc)
        return len(accessors) - 1

    def bounds(p):
        return [[min(p[k::3]) for k in range(3)], [max(p[k::3]) for k in range(3)]]

    a_pos = add(pos, "f", len(pos) // 3, 5126, "VEC3", 34962, bounds(pos))
    a_nrm = add(nrm, "f", len(nrm) // 3, 5126, "VEC3", 34962)
    a_uv = add(uv, "f", len(uv) // 2, 5126, "VEC2", 34962)
    a_idx = add(idx, "H", len(idx), 5123, "SCALAR", 34963)
    q_pos = add(quad_pos, "f", 4, 5126, "VEC3", 34962, bounds(quad_pos))
    q_uv = add(quad_uv, "f", 4, 5126, "VEC2", 34962)
    q_idx = add(quad_idx, "B", 6, 5121, "SCALAR", 34963)
    blob = b"".join(chunks)
    doc = {
        "asset": {"version": "2.0", "generator": "twill assets/meshes/generate.py"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "root", "translation": [0, 0, 0.01], "children": [1]},
                  {"name": "patch", "mesh": 0, "scale": [2, 2, 2]}],
        "meshes": [{"name": "wave", "primitives": [
            {"attributes": {"POSITION": a_pos, "NORMAL": a_nrm, "TEXCOORD_0": a_uv}, "indices": a_idx},
            {"attributes": {"POSITION": q_pos, "TEXCOORD_0": q_uv}, "indices": q_idx}]}],
        "accessors": accessors,
        "bufferViews": views,
    }
    text_doc = dict(doc, buffers=[{"byteLength": len(blob),
                                   "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}])
    with open(os.path.join(HERE, "wave_patch.gltf"), "w") as f:
        json.dump(text_doc, f, indent=1)
        f.write("\n")
    glb_doc = dict(doc, buffers=[{"byteLength": len(blob)}])
    js = json.dumps(glb_doc, separators=(",", ":")).encode()
    while len(js) % 4:
        js += b" "
    body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(blob), 0x004E4942) + blob
    with open(os.path.join(HERE, "wave_patch.glb"), "wb") as f:
        f.write(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)


if __name__ == "__main__":
    bent_sheet()
    wave_patch()
