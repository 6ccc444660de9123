#!/usr/bin/env python3
"""Per-surface error of a bake against the Mitsuba reference, as Radiant computes it.

Reproduces `radiant_radiosity::metrics::compare_surfaces` (and its `stats`) and
`parse_reference_csv`: over the non-emitting surfaces that the reference has, area-weighted,

    mean_rel = sum_s A_s mean_c |B_sc - R_sc| / max(R_sc, f) / sum_s A_s
    max_rel  = max_{s,c} |B_sc - R_sc| / max(R_sc, f)
    rel_rms  = sqrt(sum_s A_s sum_c (B_sc - R_sc)^2 / sum_s A_s sum_c R_sc^2)

with f = max(1e-3 * (area-weighted mean of R over the surfaces and channels), 1e-12), A_s the
bake's surface area, B in emissive units (a surface shows E + rho H), and R the reference: a
Mitsuba irradiance-meter CSV (first column `quad`) whose B_r,B_g,B_b columns (exitance) are
divided by pi, or Radiant's own `surface,area,b_r,b_g,b_b` layout, taken as it is.

The reference file is the one `CORNELL_BOX_REFERENCE` in crates/radiant_radiosity/src/metrics.rs
includes (its include_str! path is read from that source), unless --reference names another.

Input CSV (a file or stdin, '-'): a header with a name column (`name`, `surface` or `quad`),
the radiosity (`r,g,b` or `b_r,b_g,b_b`), optionally `area_m2` (else `area`, else the
reference's `area_mm2` / 1e6) and `emitter` (0/1; else a surface named `light` is the emitter).

Usage: surface_error.py [BAKE_CSV|-] [--reference CSV]
"""
import argparse
import math
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
METRICS = ROOT / "crates/radiant_radiosity/src/metrics.rs"


def reference_path():
    """The file CORNELL_BOX_REFERENCE includes, resolved as include_str! does."""
    src = METRICS.read_text()
    m = re.search(r'pub const CORNELL_BOX_REFERENCE:\s*&str\s*=\s*include_str!\(\s*"([^"]+)"\s*\)', src)
    if not m:
        sys.exit(f"cannot find CORNELL_BOX_REFERENCE's include_str! in {METRICS}")
    return (METRICS.parent / m.group(1)).resolve()


def csv_lines(text):
    """Header fields and data rows; blank lines and '#' comments skipped (as csv_lines)."""
    lines = [l.strip() for l in text.splitlines()]
    lines = [l for l in lines if l and not l.startswith("#")]
    if not lines:
        sys.exit("empty CSV")
    header = [h.strip() for h in lines[0].split(",")]
    rows = [[f.strip() for f in l.split(",")] for l in lines[1:]]
    return header, rows


def parse_reference(text):
    """parse_reference_csv: {name: (rgb, area_mm2 or None)}."""
    header, rows = csv_lines(text)
    low = [h.lower() for h in header]
    try:
        cols = [low.index("b_r"), low.index("b_g"), low.index("b_b")]
    except ValueError:
        sys.exit("reference header needs b_r,b_g,b_b (ours) or B_r,B_g,B_b (Mitsuba)")
    scale = 1.0 / math.pi if header[0] == "quad" else 1.0
    area_col = low.index("area_mm2") if "area_mm2" in low else None
    out = {}
    for row in rows:
        rgb = [float(row[c]) * scale for c in cols]
        out[row[0]] = (rgb, float(row[area_col]) if area_col is not None else None)
    return out


def parse_bake(text, reference):
    header, rows = csv_lines(text)
    low = [h.lower() for h in header]
    name = next(low.index(n) for n in ("name", "surface", "quad") if n in low)
    if all(c in low for c in ("r", "g", "b")):
        cols = [low.index(c) for c in ("r", "g", "b")]
    else:
        cols = [low.index(c) for c in ("b_r", "b_g", "b_b")]
    area_m2 = low.index("area_m2") if "area_m2" in low else None
    area = low.index("area") if "area" in low else None
    emit = low.index("emitter") if "emitter" in low else None
    out = []
    for row in rows:
        n = row[name]
        if area_m2 is not None:
            a = float(row[area_m2])
        elif area is not None:
            a = float(row[area])
        elif n in reference and reference[n][1] is not None:
            a = reference[n][1] / 1e6
        else:
            sys.exit(f"no area for surface {n}")
        e = row[emit] not in ("0", "false") if emit is not None else n == "light"
        out.append((n, a, [float(row[c]) for c in cols], e))
    return out


def compare_surfaces(got, reference):
    """compare_surfaces + stats: (rel_rms, mean_rel, max_rel, per-surface rows)."""
    pairs = [(n, a, b, reference[n][0]) for (n, a, b, e) in got if not e and n in reference]
    if not pairs:
        sys.exit("no surface of the bake is in the reference")
    area = sum(p[1] for p in pairs)
    mean_r = sum(a * sum(r) / 3.0 for (_, a, _, r) in pairs) / max(area, sys.float_info.min)
    floor = max(1e-3 * mean_r, 1e-12)
    tot_a = num = den = mean = mx = 0.0
    rows = []
    for n, a, b, r in pairs:
        tot_a += a
        m = 0.0
        rel = []
        for c in range(3):
            d = b[c] - r[c]
            num += a * d * d
            den += a * r[c] * r[c]
            x = abs(d) / max(abs(r[c]), floor)
            rel.append(d / max(abs(r[c]), floor))
            m += x / 3.0
            mx = max(mx, x)
        mean += a * m
        rows.append((n, a, b, r, rel))
    rel_rms = math.sqrt(num / den) if den > 0 else 0.0
    mean_rel = mean / tot_a if tot_a > 0 else 0.0
    return rel_rms, mean_rel, mx, rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bake", nargs="?", default="-")
    ap.add_argument("--reference", type=Path, default=None)
    args = ap.parse_args()
    ref_path = args.reference or reference_path()
    reference = parse_reference(ref_path.read_text())
    text = sys.stdin.read() if args.bake == "-" else Path(args.bake).read_text()
    got = parse_bake(text, reference)
    rel_rms, mean_rel, max_rel, rows = compare_surfaces(got, reference)
    print(f"reference: {ref_path.relative_to(ROOT) if ref_path.is_relative_to(ROOT) else ref_path}")
    print(f"{'surface':<18} {'area m2':>8}  {'bake r,g,b':>26}  {'reference r,g,b':>26}  relative error r,g,b")
    for n, a, b, r, rel in rows:
        print(f"{n:<18} {a:8.5f}  {b[0]:8.5f},{b[1]:8.5f},{b[2]:8.5f}  {r[0]:8.5f},{r[1]:8.5f},{r[2]:8.5f}  "
              + ", ".join(f"{100 * x:+6.2f}%" for x in rel))
    print(f"surfaces vs reference: mean_rel {100 * mean_rel:.2f} %, max_rel {100 * max_rel:.2f} %, "
          f"rel_rms {100 * rel_rms:.2f} % ({len(rows)} surfaces)")


if __name__ == "__main__":
    main()
