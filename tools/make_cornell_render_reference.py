"""Path-traced reference image of the builtin Cornell box, from its published camera, for
`radiant render`'s comparison (assets/reference/cornell_box_mitsuba_128.exr).

Uses the shared Mitsuba 3 scene (../shared/refs/mitsuba/cornell_mitsuba.py: Cornell's geometry,
bitterli RGB materials, the published camera). Renders CHUNKS independent 1024-spp images with
distinct seeds, averages them in float64 (the film accumulates in float32, so calls stay small),
and writes the mean as linear radiance plus a JSON with the per-pixel standard error.

  pip install mitsuba numpy
  python tools/make_cornell_render_reference.py [--res 128] [--chunks 16]
"""
import argparse, json, os, sys, tempfile, time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SHARED = os.path.join(ROOT, "..", "shared", "refs", "mitsuba")
sys.path.insert(0, SHARED)
sys.dont_write_bytecode = True

import mitsuba as mi  # noqa: E402

mi.set_variant("scalar_rgb")
import cornell_mitsuba as cm  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--chunks", type=int, default=16)
    ap.add_argument("--spp", type=int, default=1024, help="samples per chunk")
    a = ap.parse_args()
    S = cm.load_json()
    # Meshes go to a scratch directory, not into ../shared.
    cm.MESH_DIR = tempfile.mkdtemp(prefix="radiant-cornell-")
    cm.write_quad_objs(S)
    scene = mi.load_dict(cm.scene_dict(S, "bitterli", a.res, a.spp))
    t0 = time.time()
    imgs = []
    for k in range(a.chunks):
        img = np.array(mi.render(scene, spp=a.spp, seed=1 + k), dtype=np.float64)[:, :, :3]
        imgs.append(img)
        print(f"chunk {k + 1}/{a.chunks}: {time.time() - t0:.0f} s", flush=True)
    stack = np.stack(imgs)
    mean = stack.mean(0)
    stderr = stack.std(0, ddof=1) / np.sqrt(a.chunks)
    out = os.path.join(ROOT, "assets", "reference", f"cornell_box_mitsuba_{a.res}.exr")
    mi.util.write_bitmap(out, mi.Bitmap(mean.astype(np.float32)))
    total = a.spp * a.chunks
    rel = float(stderr.sum() / mean.sum())
    meta = {
        "renderer": f"Mitsuba {mi.__version__} scalar_rgb, path tracer, unlimited depth",
        "scene": "Cornell PCG box, bitterli RGB materials, published camera (../shared/refs)",
        "resolution": [a.res, a.res],
        "spp": total,
        "chunks": a.chunks,
        "seconds": round(time.time() - t0, 1),
        "relative_stderr_l1": rel,
        "units": "radiance, the same units as glTF emissive (the light emits 17, 12, 4)",
    }
    with open(out.replace(".exr", ".json"), "w") as f:
        json.dump(meta, f, indent=2)
    print(json.dumps(meta, indent=2))


if __name__ == "__main__":
    main()
