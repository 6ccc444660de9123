//! How much of each element lies outside closed geometry: the clustered bake's exposure.
//!
//! A floor element partly under a box has a buried part that sees nothing and that nothing
//! sees. Its form factors, averaged over the whole element, already leave that part out, as
//! receiver and as source; if its radiosity were also the mean over the whole element, the
//! buried part would darken it twice (once as the receiver's mean, once more when that mean is
//! carried through the source's form factors). So the bake solves for the radiosity of the
//! **exposed** part, with each element's exposed share of its area as its weight: the live area
//! that takes a receiver's gather and votes in a source's pull (`cluster::solve`), and that a
//! surface's mean counts (`metrics::surface_means_exposed`). Before this, an element was either
//! enclosed (by its centroid) or not, and the 101 582-triangle room of boxes baked 11.7 % too
//! dark against the path tracer.
//!
//! Each element is probed at [`POINTS`] points, the centroids of the nine triangles of its
//! triangle split in three along each edge. A point is buried when every one of its
//! [`PER_POINT`] cosine-distributed probe rays meets a back face; one that escapes or meets a
//! front face settles it, so an open element costs one ray per point.

use glam::{DVec3, Vec3};
use radiant_visibility::Visibility;

use crate::mesh::Mesh;

/// Probe points per element.
pub const POINTS: usize = 9;
/// Probe rays per point.
pub const PER_POINT: usize = 4;

/// An element's probe rays, origins and directions as cast: point by point, [`PER_POINT`]
/// each.
pub(crate) type Probes = [(Vec3, Vec3); POINTS * PER_POINT];

/// The share of an element's area that is exposed, from its count of exposed points.
#[inline]
pub fn fraction(live: u8) -> f64 {
    f64::from(live.min(POINTS as u8)) / POINTS as f64
}

/// Per element: how many of its [`POINTS`] probe points lie outside closed geometry (0: the
/// element is enclosed).
pub fn exposure(mesh: &Mesh, vis: &dyn Visibility, seed: u64) -> Vec<u8> {
    exposure_keeping(mesh, vis, seed, &|_| None, &|_, _| None)
}

/// [`exposure`], where an edit's element that stayed may keep its old answer without its
/// probe rays being cast: `settled(element)` answers before its probes are made (everything
/// that moved lies behind it), `kept(element, probes)` when nothing that moved can reach them.
pub(crate) fn exposure_keeping(
    mesh: &Mesh,
    vis: &dyn Visibility,
    seed: u64,
    settled: &(dyn Fn(usize) -> Option<u8> + Sync),
    kept: &(dyn Fn(usize, &Probes) -> Option<u8> + Sync),
) -> Vec<u8> {
    use rayon::prelude::*;
    (0..mesh.element_count())
        .into_par_iter()
        .map(|leaf| {
            if let Some(live) = settled(leaf) {
                return live;
            }
            let node = mesh.leaf_node(leaf as u32);
            let id = mesh.stable_id(mesh.leaves[leaf]);
            let mut rng = crate::rng::Rng::new(crate::rng::hash(seed ^ 0xE7905, id, 0));
            let points = points(&node.v, &mut rng);
            let (t, b) = crate::form_factors::basis(node.normal);
            let probes: Probes = std::array::from_fn(|k| {
                let origin = crate::form_factors::ray_origin(points[k / PER_POINT], node.normal);
                let dir = cosine_probe((t, b, node.normal), k % PER_POINT, 2, &mut rng);
                (origin, dir)
            });
            if let Some(live) = kept(leaf, &probes) {
                return live;
            }
            probes
                .chunks_exact(PER_POINT)
                .filter(|rays| {
                    !rays.iter().all(|&(o, d)| {
                        vis.closest_hit(o, d, f32::INFINITY)
                            .is_some_and(|h| !h.front)
                    })
                })
                .count() as u8
        })
        .collect()
}

/// One uniformly random point in each of the nine triangles that splitting `v`'s edges in
/// three makes (six upright, three upside down): stratified, so each ninth of the area is
/// counted once, and unbiased whatever pattern covers the element. The ninths' centroids, a
/// regular set, aliased with regular geometry: on the rooms of `tools/make_rooms.py` they lie
/// on the boxes' lattice, between the boxes, and the 1 M room's floor counted 8 % of itself
/// buried where 25 % is.
pub(crate) fn points(v: &[DVec3; 3], rng: &mut crate::rng::Rng) -> [DVec3; POINTS] {
    // Each ninth by its corners, in barycentric thirds along v1 − v0 and v2 − v0.
    const UP: [(f64, f64); 6] = [(0., 0.), (1., 0.), (2., 0.), (0., 1.), (1., 1.), (0., 2.)];
    const DOWN: [(f64, f64); 3] = [(0., 0.), (1., 0.), (0., 1.)];
    std::array::from_fn(|k| {
        let corners = match k {
            0..6 => {
                let (i, j) = UP[k];
                [(i, j), (i + 1.0, j), (i, j + 1.0)]
            }
            _ => {
                let (i, j) = DOWN[k - 6];
                [(i + 1.0, j), (i, j + 1.0), (i + 1.0, j + 1.0)]
            }
        };
        // Uniform in the ninth: √u₁ folds the square onto the triangle.
        let (s, u2) = (rng.f64().sqrt(), rng.f64());
        let w = [1.0 - s, s * (1.0 - u2), s * u2];
        let (a, b) = (0..3).fold((0.0, 0.0), |(a, b), c| {
            (a + w[c] * corners[c].0, b + w[c] * corners[c].1)
        });
        v[0] + (v[1] - v[0]) * (a / 3.0) + (v[2] - v[0]) * (b / 3.0)
    })
}

/// Probe `k` of `side²` about `normal` (with its tangents `t`, `b`): cosine-distributed,
/// stratified on a `side × side` grid and jittered by `rng`.
pub(crate) fn cosine_probe(
    (t, b, normal): (DVec3, DVec3, DVec3),
    k: usize,
    side: usize,
    rng: &mut crate::rng::Rng,
) -> Vec3 {
    let s = side as f64;
    let (u1, u2) = (
        ((k % side) as f64 + rng.f64()) / s,
        ((k / side) as f64 + rng.f64()) / s,
    );
    let (r, phi) = (u1.sqrt(), std::f64::consts::TAU * u2);
    let dir = t * (r * phi.cos()) + b * (r * phi.sin()) + normal * (1.0 - u1).max(0.0).sqrt();
    dir.as_vec3()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_point_lies_in_its_own_ninth_of_the_element() {
        let v = [DVec3::ZERO, DVec3::X * 3.0, DVec3::Y * 3.0];
        let mut rng = crate::rng::Rng::new(5);
        let mut mean = DVec3::ZERO;
        for _ in 0..2000 {
            let p = points(&v, &mut rng);
            // The unit cells of the 3 × 3 split: upright ones first, then upside down.
            for (k, q) in p.iter().enumerate() {
                let (i, j) = (q.x.floor(), q.y.floor());
                let (fx, fy) = (q.x - i, q.y - j);
                let upright = fx + fy < 1.0;
                assert!(q.x > 0.0 && q.y > 0.0 && q.x + q.y < 3.0, "{q}");
                assert_eq!(upright, k < 6, "point {k} at {q}");
                mean += *q;
            }
            // No two share a ninth.
            let cells: std::collections::HashSet<_> = p
                .iter()
                .map(|q| {
                    (
                        q.x.floor() as i32,
                        q.y.floor() as i32,
                        q.x.fract() + q.y.fract() < 1.0,
                    )
                })
                .collect();
            assert_eq!(cells.len(), POINTS);
        }
        // Uniform over the element: their mean is its centroid.
        let mean = mean / (2000.0 * POINTS as f64);
        assert!((mean - DVec3::new(1.0, 1.0, 0.0)).length() < 0.01, "{mean}");
        assert_eq!(fraction(0), 0.0);
        assert_eq!(fraction(POINTS as u8), 1.0);
    }

    /// A 4 × 4 m floor (surface 0) in 1 m elements under closed geometry `cover`: the mesh
    /// and each element's exposure.
    fn floor_under(cover: &[[DVec3; 3]]) -> (Mesh, Vec<u8>) {
        let mut scene = radiant_scene::Scene::default();
        let floor = crate::scenes::quad(DVec3::ZERO, DVec3::Z * 4.0, DVec3::X * 4.0);
        crate::scenes::add_surface(&mut scene, "floor", [0.5; 3], [0.0; 3], &floor);
        crate::scenes::add_surface(&mut scene, "cover", [0.5; 3], [0.0; 3], cover);
        let params = crate::mesh::MeshParams {
            patch_size: 10.0,
            element_levels: 2,
            ..Default::default()
        };
        let mesh = Mesh::new(&scene, &params).expect("mesh");
        let bvh = crate::input::visibility(&mesh, None);
        let live = exposure(&mesh, &bvh, 7);
        (mesh, live)
    }

    #[test]
    fn a_box_on_a_floor_covers_the_share_of_its_elements_it_stands_on() {
        // A 4 × 4 m floor in 1 m elements under a closed box over x < 1.5: the elements at
        // x < 1 are enclosed, those at x > 2 open, those across x = 1.5 half covered.
        let block = crate::scenes::box_triangles(DVec3::ZERO, DVec3::new(1.5, 1.0, 4.0), false);
        let (mesh, live) = floor_under(&block);
        let (mut area, mut open, mut partial) = (0.0, 0.0, 0);
        for (i, &l) in live.iter().enumerate() {
            let node = mesh.leaf_node(i as u32);
            if mesh.root_surface[node.root as usize] != 0 {
                continue;
            }
            // In the mesh's frame: back to metres along x.
            let xs = node.v.map(|p| mesh.frame.to_world(p).x);
            let (lo, hi) = (
                xs.iter().copied().fold(f64::MAX, f64::min),
                xs.iter().copied().fold(f64::MIN, f64::max),
            );
            if hi <= 1.0 + 1e-9 {
                assert_eq!(l, 0, "an element under the box at x {lo}..{hi}");
            } else if lo >= 1.5 - 1e-9 {
                assert_eq!(usize::from(l), POINTS, "an open element at x {lo}..{hi}");
            } else {
                assert!(l > 0 && usize::from(l) < POINTS, "{l} at x {lo}..{hi}");
                partial += 1;
            }
            area += node.area;
            open += node.area * fraction(l);
        }
        assert!(partial > 0, "elements across the box's edge");
        // The open share of the floor: 2.5 of 4 m.
        let share = open / area;
        assert!((share - 0.625).abs() < 0.02, "{share}");
    }

    #[test]
    fn a_grid_of_small_boxes_covers_its_share_of_large_elements() {
        // The rooms of `tools/make_rooms.py` in small: a 4 × 4 m floor in 1 m elements under
        // a regular grid of closed boxes, each half its cell's side (a quarter of the floor
        // under them), 36 cells a side so that the cell divides the elements' ninths. A
        // regular set of probe points on that lattice lies in the gaps between the boxes (the
        // 1 M room's floor counted 8 % buried where 25 % is); one random point in each ninth
        // of an element does not.
        let (k, cell) = (36, 4.0 / 36.0);
        let mut boxes = Vec::new();
        for i in 0..k {
            for j in 0..k {
                let lo = DVec3::new(f64::from(i) + 0.25, 0.0, f64::from(j) + 0.25) * cell;
                boxes.extend(crate::scenes::box_triangles(
                    lo,
                    lo + DVec3::splat(0.5 * cell),
                    false,
                ));
            }
        }
        let (mesh, live) = floor_under(&boxes);
        let (mut area, mut open) = (0.0, 0.0);
        for (i, &l) in live.iter().enumerate() {
            let node = mesh.leaf_node(i as u32);
            if mesh.root_surface[node.root as usize] == 0 {
                area += node.area;
                open += node.area * fraction(l);
            }
        }
        let share = open / area;
        assert!(
            (share - 0.75).abs() < 0.04,
            "open share {share}, a quarter is buried"
        );
    }
}
