#!/usr/bin/env python3
"""Writes the corpus of bad (and a few valid) glTF inputs in tests/bad_inputs/.

The starting point is a tiny valid glTF: one node "quad" with a mesh of two triangles (4 float3
positions, 6 u16 indices) and a grey material, its buffer embedded as a base64 data URI so each
case is one self-contained file. Each case breaks one thing; tests/bad_inputs.rs checks that each
gives its typed `SceneError` and that none panics.

Usage: python3 tools/make_bad_inputs.py [out_dir]
"""
import base64
import copy
import json
import math
import struct
import sys
from pathlib import Path

root = Path(__file__).resolve().parent.parent
out = Path(sys.argv[1]) if len(sys.argv) > 1 else root / "tests/bad_inputs"

QUAD = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.0, 1.0, 0.0), (0.0, 1.0, 0.0)]
QUAD_INDICES = [0, 1, 2, 0, 2, 3]


def blob_of(positions, indices):
    """Positions as float3 (48 bytes for 4 vertices), then u16 indices, padded to 4 bytes."""
    blob = bytearray()
    for p in positions:
        blob += struct.pack("<3f", *p)
    for i in indices:
        blob += struct.pack("<H", i)
    while len(blob) % 4:
        blob += b"\0"
    return bytes(blob)


def data_uri(blob):
    return "data:application/octet-stream;base64," + base64.b64encode(blob).decode("ascii")


def document(positions=QUAD, indices=QUAD_INDICES, lo=(0.0, 0.0, 0.0), hi=(1.0, 1.0, 0.0)):
    """The valid base document. `lo`/`hi` are given, not computed, so that NaN/Inf data can keep
    finite JSON bounds."""
    blob = blob_of(positions, indices)
    pos_len = 12 * len(positions)
    return {
        "asset": {"version": "2.0", "generator": "tools/make_bad_inputs.py"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "quad", "mesh": 0}],
        "meshes": [{"name": "quad", "primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{
            "name": "grey",
            "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
        }],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(positions), "type": "VEC3", "min": list(lo), "max": list(hi)},
            {"bufferView": 1, "componentType": 5123, "count": len(indices), "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": pos_len, "target": 34962},
            {"buffer": 0, "byteOffset": pos_len, "byteLength": 2 * len(indices), "target": 34963},
        ],
        "buffers": [{"byteLength": len(blob), "uri": data_uri(blob)}],
    }


def to_json(doc):
    # allow_nan=False: the JSON itself must stay valid JSON; bad floats go in the binary data.
    return json.dumps(doc, indent=1, allow_nan=False).encode("utf-8") + b"\n"


def to_glb(doc):
    """GLB: the buffer moves into the BIN chunk (buffer 0 without a URI)."""
    doc = copy.deepcopy(doc)
    uri = doc["buffers"][0].pop("uri")
    blob = base64.b64decode(uri.split(",", 1)[1])
    js = json.dumps(doc, separators=(",", ":"), allow_nan=False).encode("utf-8")
    while len(js) % 4:
        js += b" "
    while len(blob) % 4:
        blob += b"\0"
    length = 12 + 8 + len(js) + 8 + len(blob)
    return (struct.pack("<4sII", b"glTF", 2, length)
            + struct.pack("<I4s", len(js), b"JSON") + js
            + struct.pack("<I4s", len(blob), b"BIN\0") + blob)


cases = {}


def case(name, data):
    cases[name] = data if isinstance(data, bytes) else to_json(data)


def mutated(fn, **kwargs):
    doc = document(**kwargs)
    fn(doc)
    return doc


# Valid files.
case("ok_no_emitters.gltf", document())
valid_glb = to_glb(document())
case("ok_quad.glb", valid_glb)
# Two collinear (zero-area) triangles: loads, with both counted as degenerate.
case("degenerate_only.gltf", document(
    positions=[(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (2.0, 0.0, 0.0), (3.0, 0.0, 0.0)],
    indices=[0, 1, 2, 1, 2, 3], hi=(3.0, 0.0, 0.0)))

# Not glTF at all.
case("empty.gltf", b"")
case("whitespace.gltf", b"  \n\t\r\n   \n")
case("not_gltf.gltf", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x01\x00\x00\x00\x01\x08\x02\x00\x00\x00")
valid_json = to_json(document())
case("truncated_json.gltf", valid_json[: len(valid_json) // 2])

# Broken GLB containers.
case("truncated.glb", valid_glb[: len(valid_glb) // 2])
case("bad_magic.glb", b"glTX" + valid_glb[4:])
# Declared total length 0, less than the 12-byte header itself.
case("glb_length_below_header.glb", valid_glb[:8] + struct.pack("<I", 0) + valid_glb[12:])

# Buffers.
case("missing_buffer.gltf", mutated(lambda d: d["buffers"][0].update(uri="does_not_exist.bin")))
case("short_buffer.gltf", mutated(lambda d: d["buffers"][0].update(byteLength=d["buffers"][0]["byteLength"] + 16)))
# Sparse accessors (core glTF 2.0): one that moves vertex 2 to (1, 2, 0), read right, and one
# whose index names a vertex the accessor does not have.
def sparse(index, value):
    def apply(d):
        blob = bytearray(base64.b64decode(d["buffers"][0]["uri"].split(",", 1)[1]))
        at = len(blob)
        blob += struct.pack("<H", index) + b"\0\0" + struct.pack("<3f", *value)
        d["buffers"][0] = {"byteLength": len(blob), "uri": data_uri(bytes(blob))}
        d["bufferViews"] += [{"buffer": 0, "byteOffset": at, "byteLength": 2},
                             {"buffer": 0, "byteOffset": at + 4, "byteLength": 12}]
        d["accessors"][0]["sparse"] = {"count": 1, "indices": {"bufferView": 2, "componentType": 5123},
                                       "values": {"bufferView": 3}}
        d["accessors"][0]["max"] = [1.0, 2.0, 0.0]
    return apply


case("ok_sparse_positions.gltf", mutated(sparse(2, (1.0, 2.0, 0.0))))
case("sparse_index_out_of_range.gltf", mutated(sparse(9, (1.0, 2.0, 0.0))))
# Compressed geometry marked required (Draco, meshopt), which Radiant does not decode.
def required(ext):
    def apply(d):
        d["extensionsUsed"] = [ext]
        d["extensionsRequired"] = [ext]
    return apply


case("draco_required.gltf", mutated(required("KHR_draco_mesh_compression")))
case("meshopt_required.gltf", mutated(required("EXT_meshopt_compression")))
# A buffer that names a device: read without end unless refused.
case("buffer_is_a_device.gltf", mutated(lambda d: d["buffers"][0].update(uri="/dev/zero")))
# A relative URI whose percent-decoding is not UTF-8.
case("bad_percent_uri.gltf", mutated(lambda d: d["buffers"][0].update(uri="%FF%FE.bin")))

# Dangling indices and out-of-bounds accessors.
case("dangling_accessor.gltf", mutated(lambda d: d["meshes"][0]["primitives"][0]["attributes"].update(POSITION=99)))
case("dangling_buffer_view.gltf", mutated(lambda d: d["accessors"][0].update(bufferView=99)))
case("accessor_out_of_bounds.gltf", mutated(lambda d: d["accessors"][0].update(count=5)))
case("zero_count_accessor.gltf", mutated(lambda d: d["accessors"][1].update(count=0)))
# byteStride 4 for float3 positions (12 bytes each).
case("stride_too_small.gltf", mutated(lambda d: d["bufferViews"][0].update(byteStride=4)))
# POSITION must be VEC3 FLOAT; this one is VEC3 UNSIGNED_SHORT (fits in its view).
case("position_not_vec3_float.gltf", mutated(lambda d: d["accessors"][0].update(componentType=5123)))
# Indices must be unsigned integers; these are FLOAT (3 of them fit the 12-byte view).
case("float_indices.gltf", mutated(lambda d: d["accessors"][1].update(componentType=5126, count=3)))
# A sparse accessor whose one substitution puts vertex 0 back where it was: loads as the quad.
case("sparse_accessor.gltf", mutated(lambda d: d["accessors"][0].update(sparse={
    "count": 1,
    "indices": {"bufferView": 1, "componentType": 5123},
    "values": {"bufferView": 0},
})))


def image_view_out_of_bounds(d):
    # A base-colour texture whose image lies in a buffer view past the end of the buffer.
    d["bufferViews"].append({"buffer": 0, "byteOffset": 40, "byteLength": 64})
    d["images"] = [{"bufferView": 2, "mimeType": "image/png"}]
    d["textures"] = [{"source": 0}]
    d["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = {"index": 0}


case("image_view_out_of_bounds.gltf", mutated(image_view_out_of_bounds))


def image_source(**image):
    # A base-colour image whose source glTF 2.0 forbids (found by fuzzing: the gltf crate
    # unwrapped the missing MIME type of a buffer-view image and panicked).
    def apply(d):
        image_view_out_of_bounds(d)
        d["bufferViews"][2] = {"buffer": 0, "byteOffset": 0, "byteLength": 8}
        d["images"] = [image]
    return apply


case("image_view_without_mime.gltf", mutated(image_source(bufferView=2)))


def texcoords(component_type, kind, attribute="TEXCOORD_0"):
    # Found by fuzzing: texture coordinates of UNSIGNED_INT reached `unreachable!` in the gltf
    # crate's reader. The quad's positions serve as the attribute's bytes.
    def apply(d):
        d["accessors"].append({"bufferView": 0, "componentType": component_type, "count": 4, "type": kind})
        d["meshes"][0]["primitives"][0]["attributes"][attribute] = len(d["accessors"]) - 1
    return apply


case("texcoord_u32.gltf", mutated(texcoords(5125, "VEC2")))
case("texcoord_vec3.gltf", mutated(texcoords(5126, "VEC3")))
case("normal_u8.gltf", mutated(texcoords(5121, "VEC3", "NORMAL")))
case("image_without_source.gltf", mutated(image_source(name="nothing")))
case("image_uri_and_view.gltf", mutated(image_source(bufferView=2, mimeType="image/png", uri="t.png")))


def png_1x1(rgba):
    """A valid 1 x 1 RGBA PNG."""
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", 1, 1, 8, 6, 0, 0, 0)
    raw = b"\0" + bytes(rgba)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def textured(uri):
    def apply(d):
        d["images"] = [{"uri": uri}]
        d["textures"] = [{"source": 0}]
        d["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = {"index": 0}
    return apply


PNG_URI = "data:image/png;base64," + base64.b64encode(png_1x1([200, 100, 50, 255])).decode("ascii")
# Textures: a missing file, bytes that are no image, and a texture on a primitive without UVs.
case("texture_missing_file.gltf", mutated(textured("does_not_exist.png")))
case("texture_undecodable.gltf", mutated(textured("data:image/png;base64," + base64.b64encode(b"not a png at all").decode("ascii"))))
case("texture_without_texcoord.gltf", mutated(textured(PNG_URI)))
# A sky with negative radiance in the scene's extras.
case("sky_negative.gltf", mutated(lambda d: d["scenes"][0].update(extras={"radiant": {"sky": {"radiance": [1.0, -1.0, 1.0]}}})))

# Geometry.
case("index_out_of_range.gltf", document(indices=[0, 1, 2, 0, 2, 7]))
case("nan_position.gltf", document(positions=[QUAD[0], (math.nan, 0.0, 0.0), QUAD[2], QUAD[3]]))
case("inf_position.gltf", document(positions=[QUAD[0], QUAD[1], (1.0, math.inf, 0.0), QUAD[3]]))
case("cyclic_nodes.gltf", mutated(lambda d: d["nodes"][0].update(children=[0])))

# Materials.
def pbr(d):
    return d["materials"][0]["pbrMetallicRoughness"]


case("reflectance_above_one.gltf", mutated(lambda d: pbr(d).update(baseColorFactor=[1.5, 0.5, 0.5, 1.0])))
case("reflectance_negative.gltf", mutated(lambda d: pbr(d).update(baseColorFactor=[0.5, -0.25, 0.5, 1.0])))
case("negative_emission.gltf", mutated(lambda d: d["materials"][0].update(emissiveFactor=[-1.0, 0.5, 0.5])))


def negative_emissive_strength(d):
    d["extensionsUsed"] = ["KHR_materials_emissive_strength"]
    d["materials"][0]["emissiveFactor"] = [1.0, 1.0, 1.0]
    d["materials"][0]["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": -2.0}}


case("negative_emissive_strength.gltf", mutated(negative_emissive_strength))


# Lights.
def light_negative_intensity(d):
    d["extensionsUsed"] = ["KHR_lights_punctual"]
    d["extensions"] = {"KHR_lights_punctual": {"lights": [{"name": "bulb", "type": "point", "intensity": -5.0}]}}
    d["nodes"].append({"name": "bulb", "translation": [0.5, 0.5, 1.0], "extensions": {"KHR_lights_punctual": {"light": 0}}})
    d["scenes"][0]["nodes"].append(1)


case("light_negative_intensity.gltf", mutated(light_negative_intensity))

out.mkdir(parents=True, exist_ok=True)
for name, data in sorted(cases.items()):
    (out / name).write_bytes(data)
print(f"wrote {len(cases)} files to {out}")
