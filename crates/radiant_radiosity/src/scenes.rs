//! Small scenes built in code, for tests, benchmarks and stress cases.

use glam::DVec3;
use radiant_scene::{Scene, Surface, Triangle};

/// The 12 triangles of an axis-aligned box, facing inward (`inward`) or outward.
pub fn box_triangles(lo: DVec3, hi: DVec3, inward: bool) -> Vec<[DVec3; 3]> {
    let c = |i: usize| {
        DVec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    };
    // Each face as a quad, counter-clockwise seen from outside.
    let faces = [
        [0, 4, 6, 2],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 2, 3, 1],
        [4, 5, 7, 6],
    ];
    let mut out = Vec::new();
    for f in faces {
        let q = f.map(c);
        let (t1, t2) = ([q[0], q[1], q[2]], [q[0], q[2], q[3]]);
        for t in [t1, t2] {
            out.push(if inward { [t[0], t[2], t[1]] } else { t });
        }
    }
    out
}

/// A quad `origin + s·u + t·v`, `s, t ∈ [0, 1]`, front side along `u × v`.
pub fn quad(origin: DVec3, u: DVec3, v: DVec3) -> [[DVec3; 3]; 2] {
    let p = [origin, origin + u, origin + u + v, origin + v];
    [[p[0], p[1], p[2]], [p[0], p[2], p[3]]]
}

/// Adds a surface with the given triangles to a scene.
pub fn add_surface(
    scene: &mut Scene,
    name: &str,
    rho: [f64; 3],
    emission: [f64; 3],
    tris: &[[DVec3; 3]],
) -> u32 {
    let id = scene.surfaces.len() as u32;
    scene.surfaces.push(Surface {
        name: name.into(),
        material: name.into(),
        reflectance: rho,
        emission,
        ..Surface::default()
    });
    scene
        .triangles
        .extend(tris.iter().map(|&vertices| Triangle::new(vertices, id)));
    id
}

/// `scene` with the triangles of every surface whose name starts with `prefix` moved by
/// `offset` (a rigid move, as an editor makes one).
pub fn translated(scene: &Scene, prefix: &str, offset: DVec3) -> Scene {
    let mut s = scene.clone();
    for t in &mut s.triangles {
        if s.surfaces[t.surface as usize].name.starts_with(prefix) {
            for v in &mut t.vertices {
                *v += offset;
            }
        }
    }
    s
}

/// The furnace: a closed unit cube, every wall with reflectance `rho` and emission `e`.
/// The exact radiosity is `e / (1 − ρ)` everywhere.
pub fn furnace(rho: f64, e: f64) -> Scene {
    let mut s = Scene::default();
    add_surface(
        &mut s,
        "walls",
        [rho; 3],
        [e; 3],
        &box_triangles(DVec3::ZERO, DVec3::ONE, true),
    );
    s
}

/// `scene` with every triangle split into `4^levels` (midpoint subdivision): the same surfaces
/// as many small input triangles, as a modelling tool's fine tessellation gives them.
pub fn tessellated(scene: &Scene, levels: u32) -> Scene {
    let mut s = scene.clone();
    for _ in 0..levels {
        s.triangles = s
            .triangles
            .iter()
            .flat_map(|t| {
                // Corners of the four children as (corner, corner) pairs of the parent: a
                // corner is its own pair, an edge midpoint the mean of its two ends.
                const KIDS: [[(usize, usize); 3]; 4] = [
                    [(0, 0), (0, 1), (2, 0)],
                    [(0, 1), (1, 1), (1, 2)],
                    [(2, 0), (1, 2), (2, 2)],
                    [(1, 2), (2, 0), (0, 1)],
                ];
                KIDS.map(|kid| Triangle {
                    vertices: kid.map(|(i, j)| (t.vertices[i] + t.vertices[j]) * 0.5),
                    surface: t.surface,
                    normals: kid.map(|(i, j)| (t.normals[i] + t.normals[j]).normalize_or_zero()),
                    uv: t.uv.map(|uv| kid.map(|(i, j)| (uv[i] + uv[j]) * 0.5)),
                })
            })
            .collect();
    }
    s
}

/// A room for scaling runs: a closed 20 × 4 × 20 box (reflectance 0.6) with an emitting
/// ceiling panel and a `k × k` grid of boxes on the floor (reflectance 0.5), each box's
/// faces split into `4^split` triangles. Input triangles: `12 + 2 + 12 k² 4^split`.
/// `tools/make_rooms.py` writes the same room as glTF.
pub fn room_with_boxes(k: u32, split: u32) -> Scene {
    room(k, split, 20.0, 1)
}

/// A room that grows with its boxes, as a level grows at a fixed level of detail: every cell
/// is 2.5 m (the cell of [`room_with_boxes`] at `k = 8`), the room is `2.5 k` m square, and the
/// ceiling has one panel for each tile of about 20 m (`n = max(1, (k + 4) / 8)` panels a
/// side), so boxes, triangles and light per square metre stay as they are. Input triangles:
/// `12 + 2 n² + 12 k² 4^split`. `tools/make_rooms.py --grow` writes the same room as glTF.
pub fn grown_room_with_boxes(k: u32, split: u32) -> Scene {
    let panels = (k.saturating_add(4) / 8).max(1);
    room(k, split, 2.5 * f64::from(k.max(1)), panels)
}

fn room(k: u32, split: u32, w: f64, panels: u32) -> Scene {
    let mut s = Scene::default();
    let h = 4.0;
    add_surface(
        &mut s,
        "room",
        [0.6; 3],
        [0.0; 3],
        &box_triangles(DVec3::ZERO, DVec3::new(w, h, w), true),
    );
    let tile = w / f64::from(panels);
    let mut light = Vec::new();
    for a in 0..panels {
        for b in 0..panels {
            light.extend(quad(
                DVec3::new(
                    (f64::from(a) + 0.4) * tile,
                    h - 1e-3,
                    (f64::from(b) + 0.4) * tile,
                ),
                DVec3::new(tile * 0.2, 0.0, 0.0),
                DVec3::new(0.0, 0.0, tile * 0.2),
            ));
        }
    }
    add_surface(&mut s, "light", [0.0; 3], [5.0; 3], &light);
    let mut boxes = Scene::default();
    let cell = w / f64::from(k.max(1));
    for i in 0..k {
        for j in 0..k {
            let lo = DVec3::new(
                (f64::from(i) + 0.25) * cell,
                0.0,
                (f64::from(j) + 0.25) * cell,
            );
            let size = DVec3::new(cell * 0.5, (cell * 0.5).min(h * 0.5), cell * 0.5);
            add_surface(
                &mut boxes,
                &format!("box_{i}_{j}"),
                [0.5; 3],
                [0.0; 3],
                &box_triangles(lo, lo + size, false),
            );
        }
    }
    let boxes = tessellated(&boxes, split);
    let base = s.surfaces.len() as u32;
    s.surfaces.extend(boxes.surfaces);
    s.triangles.extend(boxes.triangles.into_iter().map(|mut t| {
        t.surface += base;
        t
    }));
    s
}
