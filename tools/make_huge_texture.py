#!/usr/bin/env python3
"""A scene whose base-colour texture is too large to hold: a 1 m floor textured with a
SIDE x SIDE RGB PNG (default 16384, a smooth gradient, written row by row with zlib so this
script needs little memory), lit by an emitting panel above it. For measuring that such a
texture bakes within the memory budget (`radiant bake DIR/huge_texture.gltf`: averaged down
to 8192 x 8192 with one warning). Standard library only.

    python3 tools/make_huge_texture.py DIR [SIDE]
"""

import base64
import json
import struct
import sys
import zlib
from pathlib import Path


def chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def write_png(path, side):
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", side, side, 8, 2, 0, 0, 0)))
        z = zlib.compressobj(6)
        data = bytearray()
        # A gradient: red across, green down, blue constant.
        reds = bytes((x * 255) // max(side - 1, 1) for x in range(side))
        pixels = bytearray(side * 3)
        pixels[0::3] = reds
        pixels[2::3] = b"\x80" * side
        for y in range(side):
            pixels[1::3] = bytes([(y * 255) // max(side - 1, 1)]) * side
            row = b"\0" + bytes(pixels)
            data += z.compress(row)
            if len(data) > 1 << 22:
                f.write(chunk(b"IDAT", bytes(data)))
                data = bytearray()
        data += z.flush()
        f.write(chunk(b"IDAT", bytes(data)))
        f.write(chunk(b"IEND", b""))


def main(argv):
    if len(argv) < 2:
        sys.exit(__doc__)
    out = Path(argv[1])
    side = int(argv[2]) if len(argv) > 2 else 16384
    out.mkdir(parents=True, exist_ok=True)
    write_png(out / "huge.png", side)
    # Floor (facing up, with UVs) and a panel 0.6 m above it (facing down), u16 indices.
    floor = [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)]
    panel = [(0.3, 0.6, 0.3), (0.3, 0.6, 0.7), (0.7, 0.6, 0.7), (0.7, 0.6, 0.3)]
    uv = [(0, 0), (1, 0), (1, 1), (0, 1)]
    blob = bytearray()
    for p in floor + panel:
        blob += struct.pack("<3f", *p)
    uv_at = len(blob)
    for t in uv:
        blob += struct.pack("<2f", *t)
    idx_at = len(blob)
    blob += struct.pack("<6H", 0, 2, 1, 0, 3, 2)
    doc = {
        "asset": {"version": "2.0", "generator": "tools/make_huge_texture.py"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"name": "floor", "mesh": 0}, {"name": "panel", "mesh": 1}],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 2}, "indices": 3, "material": 0}]},
            {"primitives": [{"attributes": {"POSITION": 1}, "indices": 3, "material": 1}]},
        ],
        "materials": [
            {"name": "huge", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0}},
            {"name": "lamp", "emissiveFactor": [1, 1, 1], "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1]}},
        ],
        "textures": [{"source": 0}],
        "images": [{"uri": "huge.png"}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 0, 1]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0.3, 0.6, 0.3], "max": [0.7, 0.6, 0.7]},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 48},
            {"buffer": 0, "byteOffset": uv_at, "byteLength": 32},
            {"buffer": 0, "byteOffset": idx_at, "byteLength": 12},
        ],
        "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode()}],
    }
    (out / "huge_texture.gltf").write_text(json.dumps(doc, indent=1))
    print(f"wrote {out}/huge_texture.gltf and huge.png ({side} x {side})")


if __name__ == "__main__":
    main(sys.argv)
