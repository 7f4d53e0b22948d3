#!/usr/bin/env python3
"""Writes the seed corpus of every fuzz target into fuzz/corpus/ (run from anywhere; rerun after
changing it). Seeds are small valid (and a few nearly valid) inputs: the project's assets and
test fixtures, and files built here in each format. See docs/FUZZING.md."""

import base64
import json
import pathlib
import shutil
import struct
import zlib

ROOT = pathlib.Path(__file__).resolve().parent.parent
CORPUS = ROOT / "fuzz" / "corpus"


def put(target, name, data):
    d = CORPUS / target
    d.mkdir(parents=True, exist_ok=True)
    (d / name).write_bytes(data.encode() if isinstance(data, str) else data)


def copy(target, src):
    put(target, src.name, src.read_bytes())


# Scene TOML: the assets and a procedural and an imported fabric.
for p in sorted((ROOT / "assets" / "scenes").glob("*.toml")):
    copy("scene_toml", p)
CAMERA = '[camera]\nprojection = "perspective"\neye = [0, 0, 3]\ntarget = [0, 0, 0]\nup = [0, 1, 0]\n'
LIGHT = '[[lights]]\ntype = "directional"\ndirection = [0, 0, 1]\nirradiance = [1, 1, 1]\n'
put("scene_toml", "spec_rows.toml",
    '[fabric.spec]\nrows = ["X..", ".X.", "..X"]\nspacing_warp = 0.1\ncrimp = 0.0123\nseed = 3\n'
    'warp = { width = 0.03, height = 0.015 }\n[materials]\n'
    'warp = { model = "lambert", albedo = [0.1, 0.2, 0.3] }\n'
    'weft = { model = "fiber", c_r = [0.04, 0.04, 0.04], beta_r_deg = 5.0, c_tt = [0.8, 0.3, 0.2], '
    'beta_tt_deg = 10.0, gamma_tt_deg = 25.0 }\n[pattern]\n'
    'weaves = [{ rows = ["X.", ".X"] }, { wif = "w.wif" }, { weave = "satin_4_1" }]\npng = "maps/m.png"\n'
    '[mesh]\npath = "cloth.obj"\nsize_cm = [3, 4]\n' + CAMERA + LIGHT +
    '[[lights]]\ntype = "sg"\naxis = [0.1, 0.2, 0.3]\nsharpness = 1e-4\nintensity = [1e300, 5e-324, 0.3]\n'
    '[render]\nseed = 9007199254740993\nexposure = -1.25\n[gpu]\nvolume_samples = 32\n')
put("scene_toml", "imported.toml",
    '[fabric]\nfile = "fibers/silk.txt"\nformat = "mitsuba"\ntiling = { period = [0.2, 0.2] }\n'
    'radius = 0.0005\n' + CAMERA + LIGHT)

# Mitsuba curve text.
put("mitsuba", "two_fibers.txt",
    "# x y z radius\n0 0 0 0.001\n0.1 0.2 -0.3 0.001\n1e-7 3.5 1 0.001\n\n-1.25 -1.25 -1.25 0.0012\n"
    "0.3 0.1 0.7 0.0012\n")
put("mitsuba", "no_radius.txt", "# header\n0 0 0\n1 0 0 # trailing\n# same fiber\n2 0 0\n\n\n0 1 0 0.5\n0 2 0 0.7\n")


# cyHair, as encode_hair writes it (segments, points, thickness), and variants.
def hair(fibers, arrays=0b111, default_segments=1, default_thickness=0.002, extra=b""):
    points = sum(len(f) for f, _ in fibers)
    out = b"HAIR" + struct.pack("<IIII", len(fibers), points, arrays, default_segments)
    out += struct.pack("<f", default_thickness) + struct.pack("<f", 1.0) + struct.pack("<3f", 1, 1, 1)
    out += b"twill fuzz seed".ljust(88, b"\0")
    if arrays & 1:
        out += b"".join(struct.pack("<H", len(f) - 1) for f, _ in fibers)
    out += b"".join(struct.pack("<3f", *p) for f, _ in fibers for p in f)
    if arrays & 4:
        out += b"".join(struct.pack("<f", 2 * r) for f, r in fibers for _ in f)
    return out + extra


FIBERS = [([(0, 0, 0), (0.1, 0.2, -0.3), (1e-7, 3.5, 1)], 0.0005), ([(-1.25, -1.25, -1.25), (0.3, 0.1, 0.7)], 0.0012)]
put("hair", "two_fibers.hair", hair(FIBERS))
put("hair", "no_segments_array.hair", hair([(f[:2], r) for f, r in FIBERS], arrays=0b110))
put("hair", "default_thickness.hair", hair(FIBERS, arrays=0b011))
n = sum(len(f) for f, _ in FIBERS)
put("hair", "with_colours.hair", hair(FIBERS, arrays=0b11111, extra=b"\0" * (16 * n)))

# WIF: the asset, and a lift plan with a sinking shed.
copy("wif", ROOT / "assets" / "weaves" / "twill_2_2.wif")
put("wif", "liftplan.wif",
    "[WIF]\nVersion=1.1\n[CONTENTS]\nWEAVING=true\nWARP=true\nWEFT=true\nTHREADING=true\nLIFTPLAN=true\n"
    "[WEAVING]\nShafts=2\nRising Shed=no\n[WARP]\nThreads=4\n[WEFT]\nThreads=2\n"
    "[THREADING]\n1=1\n2=2\n3=1\n4=2\n[LIFTPLAN]\n1=1\n2=2\n")


# PNG pattern maps.
def chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png(w, h, depth, color, rows, plte=None):
    raw = b"".join(b"\0" + r for r in rows)
    out = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, color, 0, 0, 0))
    if plte:
        out += chunk(b"PLTE", plte)
    return out + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


put("png_pattern", "gray8.png", png(3, 2, 8, 0, [bytes([200, 10, 200]), bytes([90, 10, 10])]))
put("png_pattern", "gray16.png", png(3, 2, 16, 0, [struct.pack(">3H", 51400, 10, 51400), struct.pack(">3H", 90, 10, 10)]))
put("png_pattern", "rgb.png", png(2, 1, 8, 2, [bytes([5, 5, 5, 7, 7, 7])]))
put("png_pattern", "not_gray.png", png(2, 1, 8, 2, [bytes([5, 5, 5, 1, 2, 3])]))
put("png_pattern", "bw1.png", png(8, 1, 1, 0, [bytes([0b10100000])]))
put("png_pattern", "gray_alpha.png", png(2, 2, 8, 4, [bytes([0, 255, 9, 255]), bytes([9, 0, 0, 0])]))
put("png_pattern", "palette.png", png(2, 1, 8, 3, [bytes([0, 1])], plte=bytes([0, 0, 0, 255, 255, 255])))


# Bake files (the fuzz target rewrites the body length and checksum, so they are zero here).
def bake(sections):
    def pad8(n):
        return (n + 7) // 8 * 8
    directory_len = sum(3 + len(name) + 32 + 8 * len(shape) + 16 for name, _, shape, _ in sections)
    offset = pad8(96 + directory_len)
    directory, data = b"", b""
    for name, tag, shape, payload in sections:
        directory += bytes([len(name)]) + name + bytes([tag, len(shape)]) + bytes(range(32))
        directory += b"".join(struct.pack("<Q", d) for d in shape)
        directory += struct.pack("<QQ", offset, len(payload))
        data += payload.ljust(pad8(len(payload)), b"\0")
        offset = pad8(offset + len(payload))
    body = directory.ljust(pad8(96 + directory_len) - 96, b"\0") + data
    header = b"TWILLBK\0" + struct.pack("<II", 1, len(sections)) + bytes(range(100, 132))
    header += struct.pack("<QQ", len(body), 0) + b"\0" * 32
    return header + body


put("bake_file", "sections.twillbake", bake([
    (b"svf", 1, [2, 3], struct.pack("<6f", *range(6))),
    (b"ids", 2, [4], struct.pack("<4I", 1, 2, 3, 4)),
    (b"small", 3, [3], struct.pack("<3H", 7, 8, 9)),
    (b"bytes", 4, [5], b"abcde"),
    (b"wide", 5, [1, 1, 2], struct.pack("<2d", 0.5, -1)),
]))
put("bake_file", "empty.twillbake", bake([]))
put("bake_file", "scalar.twillbake", bake([(b"s", 1, [], struct.pack("<f", 1.5))]))

# OBJ: the asset meshes.
for p in sorted((ROOT / "assets" / "meshes").glob("*.obj")):
    copy("obj", p)
put("obj", "quad_no_normals.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n")

# glTF: the asset meshes, and the glTF with its buffer as an external file (after the separator).
for p in sorted((ROOT / "assets" / "meshes").glob("*.gl*")):
    copy("gltf", p)
doc = json.loads((ROOT / "assets" / "meshes" / "wave_patch.gltf").read_text())
buffer = doc["buffers"][0]
data = base64.b64decode(buffer["uri"].split(";base64,", 1)[1])
buffer["uri"] = "buffer.bin"
put("gltf", "external_buffer.gltf", json.dumps(doc).encode() + b"\n#buffer#\n" + data)
