#!/usr/bin/env python3
"""Writes the fuzz targets' seed inputs into fuzz/seeds/<target>/ (see tools/fuzz.sh).

Small, valid examples of each input, so the fuzzer starts from inside each format rather than
from nothing: glTF with external files, PNG and JPEG in several colour types, Radiance .hdr
(flat and run-length) and OpenEXR (several compressions), sky descriptions, the CSV layouts.
The bad-input corpus (tests/bad_inputs/) is a second seed directory for the glTF target and is
not copied. With `--radiant PATH` (a built `radiant` binary), it also bakes the little glTF
seed with both hierarchies and keeps their checkpoints, less the checksum the fuzz target
appends.

Needs: pip install pillow OpenEXR numpy
"""
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile

import numpy as np
import OpenEXR
from PIL import Image

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
SEEDS = os.path.join(ROOT, "fuzz", "seeds")


def out(target, name, data):
    d = os.path.join(SEEDS, target)
    os.makedirs(d, exist_ok=True)
    mode = "w" if isinstance(data, str) else "wb"
    with open(os.path.join(d, name), mode) as f:
        f.write(data)


def png(name, img, **kw):
    path = os.path.join(SEEDS, "texture", name)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    img.save(path, **kw)


def textures():
    rgba = np.zeros((4, 4, 4), np.uint8)
    rgba[::2, ::2] = (255, 255, 255, 255)
    rgba[1::2, 1::2] = (255, 255, 255, 128)
    rgba[..., 3] = np.maximum(rgba[..., 3], 64)
    png("checker_4x4.png", Image.fromarray(rgba, "RGBA"))
    grey = (np.arange(64).reshape(8, 8) * 4).astype(np.uint8)
    png("grey_8x8.png", Image.fromarray(grey, "L"))
    png("palette_4x4.png", Image.fromarray(rgba[..., :3], "RGB").convert("P"))
    png("grey16_4x4.png", Image.fromarray(grey[:4, :4].astype(np.uint16) * 257))
    # Over the 1024-texel limit the target also decodes under: averaged down as it is read.
    big = np.indices((40, 40)).sum(axis=0).astype(np.uint8) * 3
    png("gradient_40x40.png", Image.fromarray(np.stack([big, big, big], -1), "RGB"))
    rgb = Image.fromarray(rgba[..., :3], "RGB").resize((8, 8))
    png("baseline_8x8.jpg", rgb, format="JPEG", quality=90)
    png("progressive_8x8.jpg", rgb, format="JPEG", quality=90, progressive=True)
    png("grey_8x8.jpg", Image.fromarray(grey, "L"), format="JPEG")


def hdr_flat(w, h):
    head = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode()
    px = bytearray()
    for y in range(h):
        for x in range(w):
            px += bytes((128 + 8 * x % 128, 64 + 16 * y % 128, 200, 129))
    return head + bytes(px)


def hdr_rle(w, h):
    """New-style run-length scanlines (2, 2, width), literal runs only."""
    head = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode()
    body = bytearray()
    for y in range(h):
        body += bytes((2, 2, w >> 8, w & 255))
        for c in range(4):
            values = [(x * 16 + y * 8 + c * 32) % 256 if c < 3 else 128 for x in range(w)]
            body += bytes((w,)) + bytes(values)
    return head + bytes(body)


def exr(name, compression, half):
    h, w = 4, 8
    rgb = (np.indices((h, w)).sum(axis=0) / 10.0).astype(np.float16 if half else np.float32)
    channels = {"RGB": np.stack([rgb, rgb * 0.5, rgb * 0.25], -1)}
    header = {"compression": compression, "type": OpenEXR.scanlineimage}
    path = os.path.join(SEEDS, "sky", name)
    with OpenEXR.File(header, channels) as f:
        f.write(path)


def skies():
    out("sky", "flat_8x4.hdr", hdr_flat(8, 4))
    out("sky", "rle_16x4.hdr", hdr_rle(16, 4))
    exr("none_float.exr", OpenEXR.NO_COMPRESSION, False)
    exr("zip_half.exr", OpenEXR.ZIP_COMPRESSION, True)
    exr("piz_half.exr", OpenEXR.PIZ_COMPRESSION, True)
    exr("rle_float.exr", OpenEXR.RLE_COMPRESSION, False)
    for i, text in enumerate(["1", "0.1, 0.2,0.3", "gradient:1,2,3/0.5", "gradient:1/0"]):
        out("sky", f"spec_{i}.txt", text)
    for i, value in enumerate([
        {"radiance": [1, 2, 3]},
        {"zenith": [1, 1, 1], "horizon": [0, 0.5, 0]},
        "gradient:2/1",
        "none",
    ]):
        out("sky", f"extras_{i}.json", json.dumps(value))


def csvs():
    for name in ["cornell_points_rgb_mitsuba.csv", "cornell_box_mitsuba_irradiance.csv"]:
        shutil.copy(os.path.join(ROOT, "assets", "reference", name), os.path.join(SEEDS, "csv", name))
    out("csv", "positions.csv", "name,x,y,z,nx,ny,nz,class\nfloor,1.0,0.0,-2.5,0,1,0,sunlit\nwall,0,1e-3,2,-1,0,0.5,contact\n")
    out("csv", "reference_points.csv",
        "point,x,y,z,nx,ny,nz,L_r,L_g,L_b,se_r,se_g,se_b,samples\n"
        "a,1.0e0,2.5e-1,3.0e0,0.000000,1.000000,0.000000,1.2e-1,1.1e-1,9.0e-2,1.0e-3,1.0e-3,1.0e-3,4096\n")
    out("csv", "surfaces.csv",
        "surface,area,b_r,b_g,b_b,se_r,se_g,se_b,samples\nfloor,1.0e0,5.0e-1,4.0e-1,3.0e-1,1e-3,1e-3,1e-3,100\n"
        "\"ceiling, west\",2.0e0,1.0e-1,1.0e-1,1.0e-1,1e-3,1e-3,1e-3,100\n")


def gltf():
    # b.bin: a quad's positions (4 × vec3), texture coordinates (4 × vec2), indices (6 × u16).
    pos = [(0, 0, 0), (1, 0, 0), (1, 0, -1), (0, 0, -1)]
    uv = [(0, 0), (1, 0), (1, 1), (0, 1)]
    data = b"".join(struct.pack("<3f", *p) for p in pos)
    data += b"".join(struct.pack("<2f", *t) for t in uv)
    data += struct.pack("<6H", 0, 1, 2, 0, 2, 3)
    out("gltf", "b.bin", data)
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1], "extras": {"radiant": {"sky": "gradient:1/0.2"}}}],
        "nodes": [
            {"mesh": 0, "translation": [0, 0, 0]},
            {"mesh": 0, "rotation": [1, 0, 0, 0], "translation": [0, 2, 0], "scale": [1, 1, 1]},
        ],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "TEXCOORD_0": 1},
            "indices": 2,
            "material": 0,
        }]}],
        "materials": [{
            "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.7, 0.6, 1], "baseColorTexture": {"index": 0}},
            "emissiveFactor": [0.1, 0.1, 0.1],
        }],
        "textures": [{"source": 0, "sampler": 0}],
        "samplers": [{"wrapS": 33648, "wrapT": 33071, "magFilter": 9728}],
        "images": [{"uri": "t.png"}],
        "buffers": [{"uri": "b.bin", "byteLength": len(data)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 32},
            {"buffer": 0, "byteOffset": 80, "byteLength": 12},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, -1], "max": [1, 0, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"},
        ],
    }
    out("gltf", "external.gltf", json.dumps(doc, indent=1))


def checkpoints(radiant):
    with tempfile.TemporaryDirectory() as tmp:
        for name in ["external.gltf", "b.bin"]:
            shutil.copy(os.path.join(SEEDS, "gltf", name), tmp)
        shutil.copy(os.path.join(SEEDS, "texture", "checker_4x4.png"), os.path.join(tmp, "t.png"))
        for hierarchy, patch, levels in [("triangles", 2, 1), ("clustered", 2, 1), ("clustered", 1, 2)]:
            ckpt = os.path.join(tmp, "c.ckpt")
            subprocess.run(
                [radiant, "bake", os.path.join(tmp, "external.gltf"), "--out", os.path.join(tmp, "out"),
                 "--hierarchy", hierarchy, "--patch-size", str(patch), "--element-levels", str(levels),
                 "--checkpoint", ckpt],
                check=True, capture_output=True)
            with open(ckpt, "rb") as f:
                out("checkpoint", f"{hierarchy}_{patch}_{levels}.bin", f.read()[:-8])
            os.remove(ckpt)


if __name__ == "__main__":
    textures()
    skies()
    csvs()
    gltf()
    if "--radiant" in sys.argv:
        checkpoints(sys.argv[sys.argv.index("--radiant") + 1])
    print(f"seeds written under {os.path.relpath(SEEDS)}", file=sys.stderr)
