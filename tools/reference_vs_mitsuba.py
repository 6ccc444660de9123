"""Path-tracing throughput: `radiant reference` against Mitsuba 3 on the same scene and camera.

Renders one camera image of WxH pixels at N samples per pixel with Mitsuba 3 (`scalar_rgb`, and
`llvm_ad_rgb` when it works here) and with our CPU path tracer, and prints paths per second per
core = W*H*spp / seconds / threads for each, as a table (and a CSV with --csv).

Both sides trace the same thing: unbounded depth (Mitsuba `path`, max_depth -1, its default
Russian roulette from depth 5), Lambertian BSDFs with flat (face) normals, an independent
sampler, a box pixel filter, THREADS worker threads (2 by default). Mitsuba's timing is the wall
clock of `mi.render` only; scene loading (glTF conversion + `mi.load_dict`, BVH included) is
reported separately. Each variant first renders once untimed (the LLVM variant JIT-compiles its
kernel then; that first time is reported as `first_s`), then --repeats timed renders with fresh
seeds, of which the fastest is reported. `cpu` is process CPU time over wall time during the
timed render, to check that the thread count took (about 2.0 for 2 threads; less when other
work shares the cores, then `paths_per_cpu_s` is the better guide, though it reads 10-20 % high
when the threads take turns on a core, as measured on a 2-vCPU VM). Each Mitsuba
variant runs in its own subprocess of this script: a broken LLVM aborts the process, not the
benchmark. Mitsuba's pip wheels intersect with Embree in both variants.

Scenes:
  cornell  the Cornell box of ../shared/refs/mitsuba/cornell_mitsuba.py (bitterli RGB materials,
           published camera; our side: --builtin cornell-box). Default 128x128.
  sponza   ../shared/scenes/sponza/Sponza_sun.gltf, converted here to a Mitsuba scene (Mitsuba
           reads no glTF): see `gltf_scene_dict` for what is kept. Default 320x180. (Check of the
           converter: assets/cornell_box.gltf through it renders the same mean radiance as the
           `cornell` scene, to 0.3 %.)

Our side runs `RADIANT reference SCENE --out TMP --image WxH --samples N --threads T
--no-surfaces` and reads TMP/report.json, key "image": {"paths", "seconds", "threads"}. If the
binary or the subcommand is missing or fails, it says so and reports Mitsuba alone.

  pip install mitsuba numpy
  apt-get install libllvm19        # for llvm_ad_rgb: Dr.Jit 1.5 aborts on LLVM 15 ("Cannot select
                                   # fminimum"); DRJIT_LIBLLVM_PATH=/path/libLLVM.so picks one
  python tools/reference_vs_mitsuba.py cornell [--spp 64] [--image 128x128] [--threads 2]
  python tools/reference_vs_mitsuba.py sponza --spp 16 --save /tmp --csv /tmp/sponza.csv
  options: --variants scalar_rgb,llvm_ad_rgb  --radiant PATH | --no-radiant  --repeats K
           --gltf FILE (another glTF for the sponza path)  --camera NAME (glTF camera node)
"""
import argparse
import base64
import csv
import json
import math
import os
import resource
import struct
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SHARED = os.path.normpath(os.path.join(ROOT, "..", "shared"))
SPONZA = os.path.join(SHARED, "scenes", "sponza", "Sponza_sun.gltf")
DEFAULT_IMAGE = {"cornell": (128, 128), "sponza": (320, 180)}
VARIANTS = ("scalar_rgb", "llvm_ad_rgb")


# ----------------------------------------------------------------------------------------------
# glTF -> Mitsuba (numpy only; mirrors what crates/radiant_scene/src/gltf_import.rs keeps)
# ----------------------------------------------------------------------------------------------

COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def load_gltf(path):
    """The JSON document and its buffers (external files, data URIs or the GLB binary chunk)."""
    with open(path, "rb") as f:
        raw = f.read()
    glb_bin = None
    if raw[:4] == b"glTF":
        n, _ = struct.unpack_from("<II", raw, 12)
        doc = json.loads(raw[20:20 + n])
        off = 20 + n
        if off + 8 <= len(raw):
            m, _ = struct.unpack_from("<II", raw, off)
            glb_bin = raw[off + 8:off + 8 + m]
    else:
        doc = json.loads(raw)
    base = os.path.dirname(os.path.abspath(path))
    buffers = []
    for b in doc.get("buffers", []):
        uri = b.get("uri")
        if uri is None:
            buffers.append(glb_bin)
        elif uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            with open(os.path.join(base, uri), "rb") as f:
                buffers.append(f.read())
    return doc, buffers, base


def accessor(doc, buffers, index):
    """Accessor `index` as an (count, width) array, honouring byteStride (sparse: not supported)."""
    a = doc["accessors"][index]
    if "sparse" in a:
        raise ValueError(f"accessor {index}: sparse accessors are not supported")
    dtype = np.dtype(COMPONENT[a["componentType"]]).newbyteorder("<")
    width, count = WIDTH[a["type"]], a["count"]
    if "bufferView" not in a:
        return np.zeros((count, width), dtype)
    view = doc["bufferViews"][a["bufferView"]]
    data = buffers[view["buffer"]]
    offset = view.get("byteOffset", 0) + a.get("byteOffset", 0)
    stride = view.get("byteStride") or dtype.itemsize * width
    out = np.ndarray((count, width), dtype, data, offset, (stride, dtype.itemsize))
    return np.array(out)  # copy: contiguous and detached from the buffer


def node_matrix(node):
    """Local 4x4 transform of a glTF node: `matrix` (column-major) or T * R * S."""
    if "matrix" in node:
        return np.array(node["matrix"], float).reshape(4, 4).T
    x, y, z, w = node.get("rotation", (0.0, 0.0, 0.0, 1.0))
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = r * np.array(node.get("scale", (1.0, 1.0, 1.0)), float)
    m[:3, 3] = node.get("translation", (0.0, 0.0, 0.0))
    return m


def walk(doc):
    """(node index, world matrix) in depth-first pre-order from the default scene's roots."""
    nodes = doc.get("nodes", [])
    scenes = doc.get("scenes", [])
    if scenes:
        roots = scenes[doc.get("scene", 0)].get("nodes", [])
    else:
        children = {c for n in nodes for c in n.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in children]
    stack = [(i, np.eye(4)) for i in reversed(roots)]
    while stack:
        i, parent = stack.pop()
        world = parent @ node_matrix(nodes[i])
        yield i, world
        stack.extend((c, world) for c in reversed(nodes[i].get("children", [])))


def srgb_to_linear(c):
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def texture_mean(mi, doc, base, tex_index):
    """Mean linear RGB of an 8-bit RGB(A) base-colour texture (alpha ignored, as our importer
    does), or None for other formats and embedded images (then the factor alone is used)."""
    image = doc["images"][doc["textures"][tex_index]["source"]]
    uri = image.get("uri")
    if uri is None or uri.startswith("data:"):
        return None
    bmp = mi.Bitmap(os.path.join(base, uri))
    px = np.array(bmp)
    if px.dtype != np.uint8 or px.ndim != 3 or px.shape[2] not in (3, 4):
        return None
    lut = srgb_to_linear(np.arange(256) / 255.0)
    return lut[px[..., :3]].reshape(-1, 3).mean(0)


def material(mi, doc, base, index, cache):
    """(reflectance rgb, emitted radiance rgb, double-sided) of material `index` (None: default)."""
    if index in cache:
        return cache[index]
    m = doc["materials"][index] if index is not None else {}
    pbr = m.get("pbrMetallicRoughness", {})
    rho = np.array(pbr.get("baseColorFactor", (1.0, 1.0, 1.0, 1.0))[:3], float)
    if "baseColorTexture" in pbr:
        mean = texture_mean(mi, doc, base, pbr["baseColorTexture"]["index"])
        if mean is not None:
            rho = rho * mean  # our importer's reflectance: factor x texture mean (linear)
    strength = m.get("extensions", {}).get("KHR_materials_emissive_strength", {}).get("emissiveStrength", 1.0)
    emission = np.array(m.get("emissiveFactor", (0.0, 0.0, 0.0)), float) * strength
    cache[index] = (rho, emission, bool(m.get("doubleSided", False)))
    return cache[index]


def triangles(prim, idx):
    mode = prim.get("mode", 4)
    if mode == 4:
        return idx[: len(idx) // 3 * 3].reshape(-1, 3)
    if mode == 5:  # strip: odd triangles swap their first two vertices to keep the winding
        t = np.stack([idx[:-2], idx[1:-1], idx[2:]], 1)
        t[1::2, :2] = t[1::2, 1::-1]
        return t
    if mode == 6:  # fan
        return np.stack([np.full(len(idx) - 2, idx[0]), idx[1:-1], idx[2:]], 1)
    return np.zeros((0, 3), np.uint32)  # points and lines do not reflect light


def pick_camera(doc, cameras, name):
    """The camera node named `name`, else the first one met in node order."""
    if not cameras:
        raise ValueError("the glTF has no perspective camera")
    if name is None:
        return cameras[0]
    for c in cameras:
        if doc["nodes"][c[0]].get("name") == name:
            return c
    raise ValueError(f"no camera node named {name!r}: " + ", ".join(doc["nodes"][c[0]].get("name", "?") for c in cameras))


def gltf_scene_dict(mi, path, width, height, spp, camera_name=None):
    """A Mitsuba scene dict for a glTF file, as our tracer sees it:

    - every triangle primitive of every node instance, positions baked into world space (winding
      flipped under mirroring transforms), one `mi.Mesh` per material, flat face normals
      (no vertex normals or UVs: our tracer shades with geometric normals);
    - reflectance = baseColorFactor x the base-colour texture's mean linear colour, as our
      importer computes it (no texture lookups, metallic/roughness/normal maps and alpha masks
      ignored: everything is an opaque Lambertian `diffuse`);
    - one-sided surfaces (Mitsuba's `diffuse` is black from behind). doubleSided materials get
      Mitsuba's `twosided`, the equivalent of the flipped duplicate triangle our importer adds;
      their emission stays one-sided (Mitsuba's `area` emitter is);
    - emissiveFactor x KHR_materials_emissive_strength as an `area` emitter (radiance);
    - KHR_lights_punctual: directional -> `directional` (irradiance = intensity [lux] x colour,
      direction = the node's -Z), point -> `point` (intensity [cd] x colour), spot -> `spot`
      (Mitsuba's falloff between the cones differs from glTF's); `range` is ignored;
    - the first camera in node order (or `camera_name`): `perspective`, vertical fov = yfov,
      aspect from the image; glTF cameras look down -Z, Mitsuba's down +Z, hence the look_at.
    """
    doc, buffers, base = load_gltf(path)
    nodes = doc.get("nodes", [])
    groups = {}  # material index -> (list of vertex arrays, list of face arrays, vertex count)
    cameras, lights, cache = [], [], {}
    for ni, world in walk(doc):
        node = nodes[ni]
        if "mesh" in node:
            flip = np.linalg.det(world[:3, :3]) < 0
            for prim in doc["meshes"][node["mesh"]]["primitives"]:
                pos = accessor(doc, buffers, prim["attributes"]["POSITION"]).astype(np.float64)
                pos = pos @ world[:3, :3].T + world[:3, 3]
                idx = (accessor(doc, buffers, prim["indices"])[:, 0].astype(np.uint32)
                       if "indices" in prim else np.arange(len(pos), dtype=np.uint32))
                tri = triangles(prim, idx)
                if flip:
                    tri = tri[:, ::-1]
                if len(tri) == 0:
                    continue
                g = groups.setdefault(prim.get("material"), ([], [], [0]))
                g[0].append(pos)
                g[1].append(tri + g[2][0])
                g[2][0] += len(pos)
        if "camera" in node and doc["cameras"][node["camera"]].get("type") == "perspective":
            cameras.append((ni, world))
        light = node.get("extensions", {}).get("KHR_lights_punctual")
        if light is not None:
            lights.append((doc["extensions"]["KHR_lights_punctual"]["lights"][light["light"]], world))

    d = {"type": "scene", "integrator": {"type": "path", "max_depth": -1}}
    for mat, (verts, faces, _) in groups.items():
        rho, emission, double_sided = material(mi, doc, base, mat, cache)
        bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": rho.tolist()}}
        if double_sided:
            bsdf = {"type": "twosided", "material": bsdf}
        props = mi.Properties()
        props["bsdf"] = mi.load_dict(bsdf)
        if emission.max() > 0:
            props["emitter"] = mi.load_dict({"type": "area", "radiance": {"type": "rgb", "value": emission.tolist()}})
        v = np.concatenate(verts).astype(np.float32)
        f = np.concatenate(faces).astype(np.uint32)
        mesh = mi.Mesh(f"material{mat}", len(v), len(f), props=props, has_vertex_normals=False, has_vertex_texcoords=False)
        params = mi.traverse(mesh)
        params["vertex_positions"] = type(params["vertex_positions"])(v.ravel())
        params["faces"] = type(params["faces"])(f.ravel())
        params.update()
        d[f"mesh_{mat}"] = mesh

    for li, (light, world) in enumerate(lights):
        rgb = (np.array(light.get("color", (1.0, 1.0, 1.0)), float) * light.get("intensity", 1.0)).tolist()
        origin = world[:3, 3]
        forward = world[:3, :3] @ np.array([0.0, 0.0, -1.0])
        forward /= np.linalg.norm(forward)
        kind = light["type"]
        if kind == "directional":
            d[f"light_{li}"] = {"type": "directional", "direction": forward.tolist(), "irradiance": {"type": "rgb", "value": rgb}}
        elif kind == "point":
            d[f"light_{li}"] = {"type": "point", "position": origin.tolist(), "intensity": {"type": "rgb", "value": rgb}}
        elif kind == "spot":
            spot = light.get("spot", {})
            up = world[:3, :3] @ np.array([0.0, 1.0, 0.0])
            d[f"light_{li}"] = {"type": "spot", "intensity": {"type": "rgb", "value": rgb},
                                "cutoff_angle": math.degrees(spot.get("outerConeAngle", math.pi / 4)),
                                "beam_width": math.degrees(spot.get("innerConeAngle", 0.0)),
                                "to_world": mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=(origin + forward).tolist(), up=up.tolist())}

    ni, world = pick_camera(doc, cameras, camera_name)
    persp = doc["cameras"][nodes[ni]["camera"]]["perspective"]
    origin = world[:3, 3]
    forward = world[:3, :3] @ np.array([0.0, 0.0, -1.0])
    up = world[:3, :3] @ np.array([0.0, 1.0, 0.0])
    d["camera"] = {"type": "perspective", "fov": math.degrees(persp["yfov"]), "fov_axis": "y",
                   "to_world": mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=(origin + forward).tolist(), up=up.tolist()),
                   "sampler": {"type": "independent", "sample_count": spp},
                   "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}, "pixel_format": "rgb"}}
    n_tri = sum(len(f) for g in groups.values() for f in g[1])
    info = {"triangles": n_tri, "meshes": len(groups), "lights": len(lights), "camera": nodes[ni].get("name", f"node{ni}")}
    return d, info


def cornell_scene_dict(mi, width, height, spp, mesh_dir):
    sys.path.insert(0, os.path.join(SHARED, "refs", "mitsuba"))
    sys.dont_write_bytecode = True
    import cornell_mitsuba as cm
    s = cm.load_json()
    cm.MESH_DIR = mesh_dir  # its OBJs, not into ../shared
    cm.write_quad_objs(s)
    d = cm.scene_dict(s, "bitterli", width, spp)
    d["camera"]["film"]["width"], d["camera"]["film"]["height"] = width, height
    return d, {"triangles": 2 * len(s["quads"]), "camera": "published"}


# ----------------------------------------------------------------------------------------------
# Mitsuba worker (one variant, in its own process)
# ----------------------------------------------------------------------------------------------

def cpu_seconds():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def mitsuba_worker(job):
    import drjit as dr
    import mitsuba as mi
    mi.set_variant(job["variant"])
    mi.set_log_level(mi.LogLevel.Warn)
    dr.set_thread_count(job["threads"])  # the nanothread pool that scalar and LLVM variants render on
    w, h, spp = job["width"], job["height"], job["spp"]
    with tempfile.TemporaryDirectory(prefix="radiant-cornell-") as mesh_dir:
        t0 = time.perf_counter()
        if job["scene"] == "cornell":
            d, info = cornell_scene_dict(mi, w, h, spp, mesh_dir)
        else:
            d, info = gltf_scene_dict(mi, job["gltf"], w, h, spp, job["camera"])
        t1 = time.perf_counter()
        scene = mi.load_dict(d)
        t2 = time.perf_counter()
    np.array(mi.render(scene, spp=spp, seed=0))
    first = time.perf_counter() - t2
    best, img = None, None
    for r in range(job["repeats"]):
        c0, t = cpu_seconds(), time.perf_counter()
        img = mi.render(scene, spp=spp, seed=1 + r)
        arr = np.array(img)
        dt, dc = time.perf_counter() - t, cpu_seconds() - c0
        if best is None or dt < best[0]:
            best = (dt, dc / dt)
    if job.get("save"):
        stem = os.path.join(job["save"], f"mitsuba_{job['scene']}_{job['variant']}")
        mi.util.write_bitmap(stem + ".exr", img)
        lum = float((arr[..., :3] @ np.array([0.2126, 0.7152, 0.0722])).mean())
        mi.util.write_bitmap(stem + ".png", mi.Bitmap(arr[..., :3] * (0.18 / max(lum, 1e-12))))  # mean -> 18 % grey
        info["image"] = stem + ".exr"
    info.update(convert_s=t1 - t0, load_dict_s=t2 - t1, mean_rgb=arr[..., :3].reshape(-1, 3).mean(0).tolist())
    if job["variant"].startswith("llvm"):
        info["llvm"] = ".".join(map(str, dr.detail.llvm_version()))
    return {"renderer": f"mitsuba {mi.__version__}", "variant": job["variant"], "paths": w * h * spp,
            "load_s": t2 - t0, "first_s": first, "seconds": best[0], "threads": job["threads"], "cpu": best[1], "info": info}


def run_mitsuba(args, variant):
    job = {"variant": variant, "scene": args.scene, "width": args.width, "height": args.height, "spp": args.spp,
           "threads": args.threads, "repeats": args.repeats, "gltf": args.gltf, "camera": args.camera, "save": args.save}
    p = subprocess.run([sys.executable, os.path.abspath(__file__), "--worker", json.dumps(job)],
                       capture_output=True, text=True)
    lines = [l for l in p.stdout.splitlines() if l.startswith("{")]
    if p.returncode != 0 or not lines:
        tail = "\n    ".join((p.stderr or p.stdout).strip().splitlines()[-6:])
        print(f"mitsuba {variant}: failed (exit {p.returncode}):\n    {tail}", flush=True)
        return None
    return json.loads(lines[-1])


# ----------------------------------------------------------------------------------------------
# Our tracer
# ----------------------------------------------------------------------------------------------

def run_radiant(args):
    exe = args.radiant
    if not (os.path.isfile(exe) and os.access(exe, os.X_OK)):
        print(f"radiant: no executable at {exe}; Mitsuba only", flush=True)
        return None
    scene = ["--builtin", "cornell-box"] if args.scene == "cornell" else [args.gltf]
    best = None
    with tempfile.TemporaryDirectory(prefix="radiant-reference-") as out:
        cmd = [exe, "reference", *scene, "--out", out, "--image", f"{args.width}x{args.height}",
               "--samples", str(args.spp), "--threads", str(args.threads), "--no-surfaces"]
        for _ in range(args.repeats):
            t = time.perf_counter()
            p = subprocess.run(cmd, capture_output=True, text=True)
            wall = time.perf_counter() - t
            try:
                with open(os.path.join(out, "report.json")) as f:
                    img = json.load(f)["image"]
                row = {"renderer": "radiant", "variant": "reference", "paths": int(img["paths"]),
                       "seconds": float(img["seconds"]), "threads": int(img["threads"]), "process_s": wall}
            except (OSError, ValueError, KeyError, TypeError) as e:
                tail = "\n    ".join((p.stderr or p.stdout).strip().splitlines()[-6:])
                print(f"radiant: `{' '.join(cmd)}` failed (exit {p.returncode}, {type(e).__name__}: {e}):\n    {tail}", flush=True)
                return None
            if best is None or row["seconds"] < best["seconds"]:
                best = row
    return best


# ----------------------------------------------------------------------------------------------

COLUMNS = ["scene", "renderer", "variant", "width", "height", "spp", "threads", "paths", "load_s", "first_s", "seconds", "cpu",
           "paths_per_s_per_core", "paths_per_cpu_s"]


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "--worker":
        print(json.dumps(mitsuba_worker(json.loads(sys.argv[2]))), flush=True)
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="see the module docstring for what each side traces")
    ap.add_argument("scene", choices=["cornell", "sponza"])
    ap.add_argument("--image", help="WxH (default 128x128 for cornell, 320x180 for sponza)")
    ap.add_argument("--spp", type=int, default=64, help="samples per pixel (default 64)")
    ap.add_argument("--threads", type=int, default=2, help="render threads for both renderers (default 2)")
    ap.add_argument("--repeats", type=int, default=1, help="timed renders per renderer; the fastest is reported (default 1)")
    ap.add_argument("--variants", default=",".join(VARIANTS), help="Mitsuba variants (default scalar_rgb,llvm_ad_rgb)")
    ap.add_argument("--radiant", default=os.path.join(ROOT, "target", "release", "radiant"), help="our binary (default target/release/radiant)")
    ap.add_argument("--no-radiant", action="store_true", help="Mitsuba only")
    ap.add_argument("--gltf", default=SPONZA, help="glTF scene for `sponza` (default ../shared/scenes/sponza/Sponza_sun.gltf)")
    ap.add_argument("--camera", help="glTF camera node name (default: the first camera node in node order)")
    ap.add_argument("--save", metavar="DIR", help="write Mitsuba's images to DIR/mitsuba_<scene>_<variant>.exr/.png")
    ap.add_argument("--csv", metavar="FILE", help="also write the table as CSV")
    args = ap.parse_args()
    if args.image:
        args.width, args.height = (int(x) for x in args.image.lower().split("x"))
    else:
        args.width, args.height = DEFAULT_IMAGE[args.scene]
    args.gltf = os.path.abspath(args.gltf)
    if args.save:
        args.save = os.path.abspath(args.save)
        os.makedirs(args.save, exist_ok=True)

    rows = []
    for variant in [v.strip() for v in args.variants.split(",") if v.strip()]:
        r = run_mitsuba(args, variant)
        if r:
            i = r.pop("info")
            extra = f", LLVM {i['llvm']}" if "llvm" in i else ""
            print(f"mitsuba {variant}: load {r['load_s']:.2f} s (convert {i['convert_s']:.2f} + load_dict {i['load_dict_s']:.2f}), "
                  f"first render {r['first_s']:.2f} s, timed {r['seconds']:.2f} s, cpu {r['cpu']:.2f}{extra}; "
                  f"{i['triangles']} triangles, camera {i['camera']}, mean rgb {np.round(i['mean_rgb'], 4).tolist()}"
                  + (f", image {i['image']}" if "image" in i else ""), flush=True)
            rows.append(r)
    if not args.no_radiant:
        r = run_radiant(args)
        if r:
            print(f"radiant reference: {r['seconds']:.2f} s traced, {r.pop('process_s'):.2f} s whole process", flush=True)
            rows.append(r)

    for r in rows:
        r.update(scene=args.scene, width=args.width, height=args.height, spp=args.spp)
        r["paths_per_s_per_core"] = r["paths"] / r["seconds"] / r["threads"]
        if r.get("cpu"):  # less sensitive to other load on the machine than the per-core figure
            r["paths_per_cpu_s"] = r["paths"] / (r["seconds"] * r["cpu"])
    fmt = {"load_s": "{:.2f}", "first_s": "{:.2f}", "seconds": "{:.3f}", "cpu": "{:.2f}", "paths_per_s_per_core": "{:.0f}", "paths_per_cpu_s": "{:.0f}"}
    cells = [[fmt.get(c, "{}").format(r[c]) if r.get(c) is not None else "" for c in COLUMNS] for r in rows]
    widths = [max([len(c)] + [len(row[k]) for row in cells]) for k, c in enumerate(COLUMNS)]
    print()
    for row in [COLUMNS] + cells:
        print("  ".join(v.rjust(wd) for v, wd in zip(row, widths)))
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(COLUMNS)
            w.writerows(cells)
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
