#!/usr/bin/env python3
"""Points where a player looks in a room of `tools/make_rooms.py` (k x k boxes in the 20 m
room): floor points 2, 5, 15 and 50 cm in front of three boxes' feet (classes `contact`, and
`open` for 50 cm) and points on those boxes' sides 3 cm (`contact`), 30 and 60 cm (`side`)
above the floor. For `radiant reference --points` and `radiant bake --points`, then
`tools/points_by_class.py`. Standard library only.

    python3 tools/make_rooms.py 8 1 DIR/r8.gltf
    python3 tools/room_points.py 8 > DIR/points.csv
"""
import sys

k = int(sys.argv[1]) if len(sys.argv) > 1 else 8
cell = 20.0 / k
rows = ["name,x,y,z,nx,ny,nz,class"]
for i, j in [(1, 1), (k // 2 - 1, k - 3), (k - 2, 2)]:
    lx, lz = (i + 0.25) * cell, (j + 0.25) * cell
    z = lz + 0.24 * cell
    for d in (0.02, 0.05, 0.15, 0.5):
        cls = "contact" if d < 0.2 else "open"
        rows.append(f"floor_{i}{j}_d{round(d * 100):02d},{lx - d:.4f},0,{z:.4f},0,1,0,{cls}")
    for y in (0.03, 0.3, 0.6):
        cls = "contact" if y < 0.1 else "side"
        rows.append(f"side_{i}{j}_y{round(y * 100):02d},{lx:.4f},{y},{z:.4f},-1,0,0,{cls}")
print("\n".join(rows))
