#!/usr/bin/env python3
"""Writes assets/cornell_box.gltf from Cornell's published data.

Input: cornell_box_scene.json (19 quads in mm, `bitterli` RGB materials, the published camera),
as exported beside the project in ../shared/refs/cornell/. Output: a single-file glTF 2.0 (buffer
as a data URI) in metres, one node per quad named as in the input, two triangles per quad.

Emission uses KHR_materials_emissive_strength: emissiveFactor = L / max(L), strength = max(L), so
the emitted radiance is exactly the published L = (17, 12, 4).

Usage: python3 tools/make_cornell_gltf.py [path/to/cornell_box_scene.json] [out.gltf]
"""
import base64
import json
import math
import struct
import sys
from pathlib import Path

root = Path(__file__).resolve().parent.parent
src = Path(sys.argv[1]) if len(sys.argv) > 1 else root.parent / "shared/refs/cornell/cornell_box_scene.json"
out = Path(sys.argv[2]) if len(sys.argv) > 2 else root / "assets/cornell_box.gltf"
data = json.loads(src.read_text())
mats = data["materials_rgb"]["bitterli"]

material_names = ["white", "red", "green", "light"]
materials = []
for name in material_names:
    if name == "light":
        rho = mats["light_reflectance"]
        radiance = mats["light_radiance"]
        peak = max(radiance)
        materials.append({
            "name": "light",
            "pbrMetallicRoughness": {"baseColorFactor": rho + [1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "emissiveFactor": [c / peak for c in radiance],
            "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": peak}},
        })
    else:
        materials.append({
            "name": name,
            "pbrMetallicRoughness": {"baseColorFactor": mats[name] + [1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
        })

blob = bytearray()
accessors, views, meshes, nodes = [], [], [], []
for quad in data["quads"]:
    verts = [[c / 1000.0 for c in v] for v in quad["vertices_mm"]]
    # Quads are CCW seen from the lit side; glTF front faces are CCW too.
    pos_offset = len(blob)
    for v in verts:
        blob += struct.pack("<3f", *v)
    idx_offset = len(blob)
    for i in (0, 1, 2, 0, 2, 3):
        blob += struct.pack("<H", i)
    while len(blob) % 4:
        blob += b"\0"
    views.append({"buffer": 0, "byteOffset": pos_offset, "byteLength": 48, "target": 34962})
    views.append({"buffer": 0, "byteOffset": idx_offset, "byteLength": 12, "target": 34963})
    lo = [min(v[k] for v in verts) for k in range(3)]
    hi = [max(v[k] for v in verts) for k in range(3)]
    accessors.append({"bufferView": len(views) - 2, "componentType": 5126, "count": 4, "type": "VEC3", "min": lo, "max": hi})
    accessors.append({"bufferView": len(views) - 1, "componentType": 5123, "count": 6, "type": "SCALAR"})
    meshes.append({"name": quad["name"], "primitives": [{
        "attributes": {"POSITION": len(accessors) - 2},
        "indices": len(accessors) - 1,
        "material": material_names.index(quad["material"]),
    }]})
    nodes.append({"name": quad["name"], "mesh": len(meshes) - 1})

cam = data["camera"]
nodes.append({
    "name": "camera",
    "camera": 0,
    "translation": [c / 1000.0 for c in cam["position_mm"]],
    # glTF cameras look down -Z; the published camera looks down +Z with +Y up: turn 180 deg about Y.
    "rotation": [0.0, 1.0, 0.0, 0.0],
})
gltf = {
    "asset": {"version": "2.0", "generator": "radiant tools/make_cornell_gltf.py (Cornell PCG published data, bitterli RGB)"},
    "extensionsUsed": ["KHR_materials_emissive_strength"],
    "scene": 0,
    "scenes": [{"name": "cornell_box", "nodes": list(range(len(nodes)))}],
    "nodes": nodes,
    "meshes": meshes,
    "materials": materials,
    "cameras": [{"name": "cornell_camera", "type": "perspective", "perspective": {
        "yfov": math.radians(cam["fov_deg"]), "aspectRatio": 1.0, "znear": 0.01, "zfar": 100.0}}],
    "accessors": accessors,
    "bufferViews": views,
    "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode()}],
}
out.write_text(json.dumps(gltf, indent=1) + "\n")
print(f"wrote {out} ({len(data['quads'])} quads)")

# The measured spectra, as the side file `radiant bake --spectral` reads (assets/cornell_box_spectra.json).
sp = data["spectra"]
side = {
    "source": "Cornell PCG 'Cornell Box Data': measured reflectances 400-700 nm at 4 nm; the light's relative spectral power at 400/500/600/700 nm. Reflectance of the light: bitterli's 0.78, flat. Emission spectra are relative: a bake scales each to the luminance of the material's RGB emission.",
    "materials": {
        "white": {"reflectance": {"wavelengths_nm": sp["wavelengths_nm"], "values": sp["white"]}},
        "red": {"reflectance": {"wavelengths_nm": sp["wavelengths_nm"], "values": sp["red"]}},
        "green": {"reflectance": {"wavelengths_nm": sp["wavelengths_nm"], "values": sp["green"]}},
        "light": {
            "reflectance": {"wavelengths_nm": [400, 700], "values": [0.78, 0.78]},
            "emission": {"wavelengths_nm": sp["light_wavelengths_nm"], "values": sp["light_relative_spd"]},
        },
    },
}
(root / "assets/cornell_box_spectra.json").write_text(json.dumps(side, indent=1) + "\n")
print("wrote assets/cornell_box_spectra.json")
