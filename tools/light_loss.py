#!/usr/bin/env python3
"""Where the light is lost: the solution, its light map and the path tracer, surface by surface.

For one scene, side by side per surface (area-weighted means of the outgoing radiance, the
mean of the three channels):

- `elements`: the solution's elements (`patches.csv`, area-weighted: their radiosity as solved);
- `solution`: the bake's `surfaces.csv` (a clustered bake counts each element's buried part
  dark, as a path tracer that samples the whole surface sees it);
- `light map`: `lightmap_surfaces.csv`, what the renderer shows (the light map sampled as the
  GPU samples it, times the albedo, plus emission) averaged over the same surface;
- `path tracer`: `radiant reference`'s `surfaces.csv` (with its standard error).

Each column but the last is given as its signed deviation from the path tracer. The solution
dark while the light map agrees with it: light is lost in the solve (links, visibility, the
oracle, the stopping rule). The solution right and the light map not: it is lost in the
reconstruction into texels.

    target/release/radiant reference SCENE --out REF --target-error 0.003
    target/release/radiant bake SCENE --out BAKE --reference REF/surfaces.csv
    python3 tools/light_loss.py BAKE REF/surfaces.csv [--top 12] [--markdown]

The last row sums up every surface listed and not (emitters excluded): the area-weighted
mean of |deviation| and the bias (area-weighted signed deviation), the measure of `bake
--reference`'s `mean` (which takes the mean over channels of each channel's |deviation|).

Standard library only.
"""
import argparse
import csv
import math
import sys
from pathlib import Path


def read_rows(path):
    """Rows of a CSV as dicts, '#' comments and blank lines skipped."""
    with open(path, newline="") as f:
        lines = [l for l in f if l.strip() and not l.lstrip().startswith("#")]
    return list(csv.DictReader(lines))


def rgb(row, prefix="b_"):
    return [float(row[prefix + c]) for c in "rgb"]


def surface_table(path):
    """surface -> (area, [r, g, b], [se_r, se_g, se_b] or None)."""
    out = {}
    for row in read_rows(path):
        name = row.get("surface") or row.get("name")
        se = [float(row["se_" + c]) for c in "rgb"] if "se_r" in row else None
        out[name] = (float(row["area"]), rgb(row), se)
    return out


def element_means(path):
    """surface -> (area, mean radiosity, emitting) from patches.csv."""
    acc = {}
    for row in read_rows(path):
        a = float(row["area"])
        s = acc.setdefault(row["surface"], [0.0, [0.0, 0.0, 0.0], False])
        s[0] += a
        for c, v in enumerate(rgb(row)):
            s[1][c] += a * v
        s[2] = s[2] or any(float(row["e_" + c]) > 0 for c in "rgb")
    return {k: (a, [v / a for v in m], e) for k, (a, m, e) in acc.items() if a > 0}


def grey(v):
    return sum(v) / 3.0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bake", help="the bake's --out directory")
    ap.add_argument("reference", help="radiant reference's surfaces.csv")
    ap.add_argument("--top", type=int, default=12, help="surfaces listed, the largest first (default 12)")
    ap.add_argument("--markdown", action="store_true", help="a Markdown table")
    a = ap.parse_args()
    bake = Path(a.bake)
    for f in ("surfaces.csv", "lightmap_surfaces.csv", "patches.csv"):
        if not (bake / f).is_file():
            sys.exit(f"{bake / f}: missing (bake with a radiant that writes it)")
    solution = surface_table(bake / "surfaces.csv")
    shown = surface_table(bake / "lightmap_surfaces.csv")
    elements = element_means(bake / "patches.csv")
    ref = surface_table(a.reference)
    names = [n for n in ref if n in solution and n in shown and n in elements and not elements[n][2]]
    if not names:
        sys.exit("the reference names none of the bake's non-emitting surfaces")
    missing = [n for n in solution if n not in ref and not elements.get(n, (0, 0, True))[2]]
    names.sort(key=lambda n: -solution[n][0])

    def dev(v, r):
        g = grey(r)
        return grey(v) / g - 1.0 if g > 0 else math.nan

    rows, tot = [], {"area": 0.0, "elements": [0.0, 0.0], "solution": [0.0, 0.0], "light map": [0.0, 0.0]}
    for n in names:
        area, r, se = ref[n][0], ref[n][1], ref[n][2]
        area = solution[n][0]
        d = {"elements": dev(elements[n][1], r), "solution": dev(solution[n][1], r),
             "light map": dev(shown[n][1], r)}
        rel_se = grey(se) / grey(r) if se and grey(r) > 0 else math.nan
        rows.append((n, area, grey(r), rel_se, d))
        if all(math.isfinite(v) for v in d.values()):
            tot["area"] += area
            for k in ("elements", "solution", "light map"):
                tot[k][0] += area * abs(d[k])
                tot[k][1] += area * d[k]

    pct = lambda x: "n/a" if not math.isfinite(x) else f"{100 * x:+.1f} %"
    head = ["surface", "area", "path tracer (± se)", "elements", "solution", "light map"]
    body = []
    for n, area, r, rel_se, d in rows[: a.top]:
        ref = f"{r:.4g} (± {100 * rel_se:.1f} %)" if math.isfinite(rel_se) else f"{r:.4g}"
        body.append([n, f"{area:.4g}", ref, pct(d["elements"]),
                     pct(d["solution"]), pct(d["light map"])])
    if len(rows) > a.top:
        rest = rows[a.top:]
        ra = sum(r[1] for r in rest)
        body.append([f"({len(rest)} more)", f"{ra:.4g}", "", "", "", ""])
    A = tot["area"]
    if A > 0:
        mean = lambda k: f"{100 * tot[k][0] / A:.1f} % (bias {100 * tot[k][1] / A:+.1f} %)"
        body.append(["all: mean of abs. deviation", f"{A:.4g}", "", mean("elements"), mean("solution"),
                     mean("light map")])
    if a.markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "|".join(["---"] + ["---:"] * (len(head) - 1)) + "|")
        for b in body:
            print("| " + " | ".join(b) + " |")
    else:
        widths = [max(len(x[i]) for x in [head] + body) for i in range(len(head))]
        for b in [head] + body:
            print("  ".join(x.ljust(w) if i == 0 else x.rjust(w) for i, (x, w) in enumerate(zip(b, widths))))
    if missing:
        print(f"# {len(missing)} surfaces of the bake are not in the reference: {', '.join(missing[:5])}"
              + (" …" if len(missing) > 5 else ""), file=sys.stderr)


if __name__ == "__main__":
    main()
