"""Writes the scaling rooms as glTF: a closed 20 x 4 x 20 m room (reflectance 0.6) with an
emitting ceiling panel and a k x k grid of boxes on the floor (reflectance 0.5), each box face
split into 4^split triangles. Input triangles: 12 + 2 + 12 k^2 4^split.

With --grow the room grows with its boxes instead: every cell is 2.5 m (the 20 m room's at
k = 8), the room is 2.5 k m square, and the ceiling has one panel per tile of about 20 m
(n x n panels), so the boxes, their triangles and the light per square metre stay as they
are while the level gets larger. Bake such a room with `--patch-size 5`, the 20 m room's
default patch size (a quarter of its extent), so that its elements stay as they are too.
Input triangles: 12 + 2 n^2 + 12 k^2 4^split with n = max(1, (k + 4) // 8).

The same rooms as `radiant_radiosity::scenes::room_with_boxes` and `grown_room_with_boxes`,
for the CLI, so that a scaling run is measured as a user would run it:

  python3 tools/make_rooms.py 72 2 /tmp/rooms/room_1m.gltf      # 995 342 triangles
  ulimit -v 16000000; /usr/bin/time -v target/release/radiant bake /tmp/rooms/room_1m.gltf --out /tmp/r1m

  python3 tools/make_rooms.py --table /tmp/rooms                # the four rooms of the table:
                                                                # about 1 k, 10 k, 100 k, 1 M
  python3 tools/make_rooms.py --table /tmp/rooms --grow         # the same boxes, rooms that grow
  target/release/radiant bake /tmp/rooms/room_grow_k72_s2.gltf --patch-size 5 --out /tmp/g1m

The table's smallest rooms (about 1 k triangles) are under the 4 096 triangles from which
`radiant bake` takes the clustered hierarchy by itself: add `--hierarchy clustered` to bake
them as the larger ones are.

With --faces the same geometry is written with the room's and the boxes' faces as surfaces of
their own (floor, ceiling, walls; box_tops, box_sides, box_bottoms), so that `surfaces.csv`,
`lightmap_surfaces.csv` and `radiant reference` tell them apart (`tools/light_loss.py`).

Standard library only. Positions are float32 in one .bin beside the .gltf.
"""
import argparse
import json
import struct
import sys
from pathlib import Path

W, H = 20.0, 4.0
# A cell of the grown rooms: the 20 m room's at k = 8.
GROW_CELL = W / 8
TABLE = [(5, 1), (8, 2), (23, 2), (72, 2)]


# The faces of box(), in its order: x low, x high, y low (bottom), y high (top), z low, z high.
FACE_KINDS = ["side", "side", "bottom", "top", "side", "side"]


def box(lo, hi, inward):
    """The 12 triangles of an axis-aligned box, counter-clockwise seen from outside (or inside),
    each with its face's kind (FACE_KINDS)."""
    def c(i):
        return (hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 4 else lo[2])
    faces = [[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [2, 6, 7, 3], [0, 2, 3, 1], [4, 5, 7, 6]]
    out = []
    for kind, f in zip(FACE_KINDS, faces):
        q = [c(i) for i in f]
        for t in ([q[0], q[1], q[2]], [q[0], q[2], q[3]]):
            out.append((kind, [t[0], t[2], t[1]] if inward else t))
    return out


def split(tris, levels):
    for _ in range(levels):
        nxt = []
        for a, b, c in tris:
            ab = tuple((x + y) / 2 for x, y in zip(a, b))
            bc = tuple((x + y) / 2 for x, y in zip(b, c))
            ca = tuple((x + y) / 2 for x, y in zip(c, a))
            nxt += [[a, ab, ca], [ab, b, bc], [ca, bc, c], [bc, ca, ab]]
        tris = nxt
    return tris


ROOM_FACES = {"bottom": "floor", "top": "ceiling", "side": "walls"}


def room(k, levels, grow=False, faces=False):
    """The room's parts: name -> triangles; with faces, a part per kind of face."""
    width = GROW_CELL * max(k, 1) if grow else W
    panels = max(1, (k + 4) // 8) if grow else 1
    walls = box((0, 0, 0), (width, H, width), True)
    if faces:
        parts = {name: [t for kind, t in walls if kind == face] for face, name in ROOM_FACES.items()}
    else:
        parts = {"room": [t for _, t in walls]}
    tile, y = width / panels, H - 1e-3
    parts["light"] = []
    for a in range(panels):
        for b in range(panels):
            x0, x1 = (a + 0.4) * tile, (a + 0.6) * tile
            z0, z1 = (b + 0.4) * tile, (b + 0.6) * tile
            # The panel faces down.
            p = [(x0, y, z0), (x1, y, z0), (x1, y, z1), (x0, y, z1)]
            parts["light"] += [[p[0], p[1], p[2]], [p[0], p[2], p[3]]]
    cell = width / max(k, 1)
    boxes = []
    for i in range(k):
        for j in range(k):
            lo = ((i + 0.25) * cell, 0.0, (j + 0.25) * cell)
            size = (cell * 0.5, min(cell * 0.5, H * 0.5), cell * 0.5)
            boxes += box(lo, tuple(a + b for a, b in zip(lo, size)), False)
    if faces:
        for kind in ("top", "side", "bottom"):
            parts[f"box_{kind}s"] = split([t for f, t in boxes if f == kind], levels)
    else:
        parts["boxes"] = split([t for _, t in boxes], levels)
    return parts


def material_of(part):
    """The material key of a part: the room's faces are the room's, the boxes' the boxes'."""
    if part in ROOM_FACES.values():
        return "room"
    return "boxes" if part.startswith("box") else part


def write(parts, path):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    materials = {
        "room": {"name": "room", "pbrMetallicRoughness": {"baseColorFactor": [0.6, 0.6, 0.6, 1], "metallicFactor": 0}},
        "light": {"name": "light", "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0},
                  "emissiveFactor": [1, 1, 1], "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 5.0}}},
        "boxes": {"name": "boxes", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0}},
    }
    blob = bytearray()
    doc = {"asset": {"version": "2.0", "generator": "radiant tools/make_rooms.py"},
           "extensionsUsed": ["KHR_materials_emissive_strength"],
           "scenes": [{"nodes": []}], "scene": 0, "nodes": [], "meshes": [], "materials": [],
           "accessors": [], "bufferViews": [], "buffers": []}
    for name, tris in parts.items():
        start = len(blob)
        lo = [min(v[a] for t in tris for v in t) for a in range(3)]
        hi = [max(v[a] for t in tris for v in t) for a in range(3)]
        for t in tris:
            for v in t:
                blob += struct.pack("<3f", *v)
        n = len(doc["nodes"])
        doc["bufferViews"].append({"buffer": 0, "byteOffset": start, "byteLength": len(blob) - start})
        doc["accessors"].append({"bufferView": n, "componentType": 5126, "count": 3 * len(tris),
                                 "type": "VEC3", "min": lo, "max": hi})
        doc["materials"].append(materials[material_of(name)])
        doc["meshes"].append({"name": name, "primitives": [{"attributes": {"POSITION": n}, "material": n}]})
        doc["nodes"].append({"name": name, "mesh": n})
        doc["scenes"][0]["nodes"].append(n)
    bin_path = path.with_suffix(".bin")
    bin_path.write_bytes(bytes(blob))
    doc["buffers"].append({"uri": bin_path.name, "byteLength": len(blob)})
    path.write_text(json.dumps(doc))
    return sum(len(t) for t in parts.values())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("k", nargs="?", type=int, help="boxes per side")
    ap.add_argument("split", nargs="?", type=int, help="levels of 4-way splitting of each box face")
    ap.add_argument("out", nargs="?", help="output .gltf")
    ap.add_argument("--table", metavar="DIR", help="write the table's rooms into DIR")
    ap.add_argument("--faces", action="store_true",
                    help="the room's and the boxes' faces as surfaces of their own")
    ap.add_argument("--grow", action="store_true",
                    help="rooms grow with their boxes (2.5 m cells, a panel per 20 m tile)")
    a = ap.parse_args()
    jobs = []
    stem = "room_grow" if a.grow else "room"
    if a.table:
        jobs = [(k, s, Path(a.table) / f"{stem}_k{k}_s{s}.gltf") for k, s in TABLE]
    elif a.k is not None and a.split is not None and a.out:
        jobs = [(a.k, a.split, Path(a.out))]
    else:
        ap.error("give K SPLIT OUT, or --table DIR")
    for k, s, out in jobs:
        if k < 0 or s < 0 or s > 6:
            sys.exit(f"k {k} and split {s}: k >= 0, 0 <= split <= 6")
        n = write(room(k, s, a.grow, a.faces), out)
        print(f"{out}: {n} triangles")


if __name__ == "__main__":
    main()
