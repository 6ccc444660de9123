#!/usr/bin/env python3
"""The light map against the path tracer at classed surface points.

Reads the points file (with a `class` column, as `examples/sun_points.rs` writes it), the
`points.csv` of `radiant bake --points` (columns L_r, L_g, L_b) and the `points.csv` of
`radiant reference --points` (L_r, L_g, L_b and their standard errors se_r, se_g, se_b), and
prints per class: the count, the median and worst relative error sum|L - ref| / sum ref, and
the median and largest ratio sum L / sum ref. Standard library only.

    python3 tools/points_by_class.py POINTS.csv BAKE/points.csv REF/points.csv
"""

import csv
import statistics
import sys


def rows(path):
    with open(path, newline="") as f:
        lines = [line for line in f if line.strip() and not line.startswith("#")]
    return list(csv.DictReader(lines))


def name_of(row):
    return row.get("name") or row.get("point")


def main(argv):
    if len(argv) != 4:
        sys.exit(__doc__)
    classes = {name_of(r): r.get("class", "all") for r in rows(argv[1])}
    ours = {name_of(r): [float(r[c]) for c in ("L_r", "L_g", "L_b")] for r in rows(argv[2])}
    ref = {}
    for r in rows(argv[3]):
        ref[name_of(r)] = (
            [float(r[c]) for c in ("L_r", "L_g", "L_b")],
            [float(r.get(c, 0.0)) for c in ("se_r", "se_g", "se_b")],
        )
    by_class = {}
    for name, cls in classes.items():
        if name not in ours or name not in ref:
            sys.exit(f"point {name} is missing from a points.csv")
        (theirs, se), mine = ref[name], ours[name]
        total = sum(theirs)
        if total <= 0.0:
            continue
        err = sum(abs(a - b) for a, b in zip(mine, theirs)) / total
        ratio = sum(mine) / total
        noise = sum(se) / total
        by_class.setdefault(cls, []).append((err, ratio, noise, name))
    print(f"{'class':10} {'n':>3} {'median err':>10} {'worst err':>10} {'median ratio':>12} "
          f"{'max ratio':>9} {'min ratio':>9} {'ref se':>7}  worst point")
    for cls in sorted(by_class):
        v = by_class[cls]
        errs = [e for e, _, _, _ in v]
        ratios = [r for _, r, _, _ in v]
        worst = max(v)
        print(f"{cls:10} {len(v):3} {100 * statistics.median(errs):9.2f}% {100 * max(errs):9.2f}% "
              f"{statistics.median(ratios):12.3f} {max(ratios):9.3f} {min(ratios):9.3f} "
              f"{100 * statistics.median(n for _, _, n, _ in v):6.2f}%  {worst[3]}")


if __name__ == "__main__":
    main(sys.argv)
