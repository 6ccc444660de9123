//! How each element takes a cluster's light: its clamped cosine times its own visibility, as
//! harmonics (Sloan, Kautz & Snyder 2002, shadowed diffuse transfer).
//!
//! A cluster receiver gathers its light by direction ([`super::solve`]) and hands it to the
//! triangles under it. By the triangle's normal alone, a triangle in a nook under a wall took
//! the same share of a far source's light as one in the open beside it: Sponza's
//! `shadowed_09`, an element inside a cluster of 2.7 m whose parts see the atrium's sunlit
//! floor, took 4.3·10⁻³ from links its own rays find 2.7·10⁻⁵ behind (`examples/explain_point`).
//! So each element's share is `max(0, n·ω) V(ω)` instead of `max(0, n·ω)`, `V` its visibility:
//! the cosine's harmonics less those of the directions a probe ray finds closed. The solve
//! divides a cluster's light by the mean of these shares over its live elements towards the
//! source, so the light is moved between them, never made or lost.
//!
//! A probe ray is closed where it meets a surface before it leaves the bounding sphere of the
//! cluster above the element's triangle that is at most [`REACH`] times the element's size:
//! what lies inside it shades its parts differently, while a link's source lies outside the
//! receiver's sphere (links join nodes whose spheres are apart), so a ray that meets the source
//! itself is not counted closed at the levels that link.

use glam::DVec3;
use radiant_visibility::Visibility;
use rayon::prelude::*;

use super::sh;
use super::tree::Tree;
use crate::mesh::Mesh;
use crate::rng::{Rng, hash};

/// Probe rays per element: a `SIDE × SIDE` stratified cosine-weighted set.
pub const SIDE: usize = 4;

/// The sphere a probe ray must leave to count open: the largest cluster's above the element's
/// triangle whose radius is at most this many times the element's.
pub const REACH: f64 = 4.0;

/// Where an element's probe rays go: the sphere they must leave, and each ray's origin (on the
/// element) and unit direction.
pub(crate) struct Probes {
    /// Centre and radius (`None`: no cluster above the element's triangle is small enough;
    /// the element takes its clusters' light by its normal).
    pub sphere: Option<(DVec3, f64)>,
    /// Origins and directions.
    pub rays: [(DVec3, DVec3); SIDE * SIDE],
}

/// Per element, the harmonics of `max(0, n·ω) V(ω)` (see the module); `seed` seeds the rays.
pub fn transfer(mesh: &Mesh, tree: &Tree, vis: &dyn Visibility, seed: u64) -> Vec<[f32; 9]> {
    transfer_keeping(mesh, tree, vis, seed, &|_, _| None)
}

/// [`transfer`], where an element may keep an answer given before without its rays being
/// cast: `kept(element, probes)` (an edit's element that stayed, whose rays nothing that moved
/// can reach).
pub(crate) fn transfer_keeping(
    mesh: &Mesh,
    tree: &Tree,
    vis: &dyn Visibility,
    seed: u64,
    kept: &(dyn Fn(usize, &Probes) -> Option<[f32; 9]> + Sync),
) -> Vec<[f32; 9]> {
    (0..mesh.element_count())
        .into_par_iter()
        .with_min_len(256)
        .map(|leaf| {
            let node = mesh.leaf_node(leaf as u32);
            let probes = probes(mesh, tree, leaf, seed);
            if let Some(t) = kept(leaf, &probes) {
                return t;
            }
            let mut g = sh::cosine(node.normal);
            let Some((centre, r)) = probes.sphere else {
                return g.map(|v| v as f32);
            };
            // Cosine-weighted: each ray stands for π / rays of the cosine's integral.
            let w = std::f64::consts::PI / probes.rays.len() as f64;
            for &(x, d) in &probes.rays {
                let exit = exit_distance(x, d, centre, r);
                if exit <= 0.0 {
                    continue;
                }
                let origin = crate::form_factors::ray_origin(x, node.normal);
                if !vis.segment_clear(origin, (x + d * exit).as_vec3()) {
                    let y = sh::basis(d);
                    for j in 0..9 {
                        g[j] -= w * y[j];
                    }
                }
            }
            g.map(|v| v as f32)
        })
        .collect()
}

/// Element `leaf`'s [`Probes`]: points uniform on it, directions stratified by the cosine,
/// from a generator seeded by `seed` and the element's stable id.
pub(crate) fn probes(mesh: &Mesh, tree: &Tree, leaf: usize, seed: u64) -> Probes {
    let node = mesh.leaf_node(leaf as u32);
    let radius = (node.v.iter())
        .map(|v| (*v - node.centroid).length())
        .fold(0.0, f64::max);
    // The largest cluster above the triangle within REACH of the element's size.
    let mut sphere = None;
    let mut id = tree.parent[mesh.roots[node.root as usize] as usize];
    while id != u32::MAX && tree.radius[id as usize] <= REACH * radius {
        sphere = Some((tree.center[id as usize], tree.radius[id as usize]));
        id = tree.parent[id as usize];
    }
    let mut rng = Rng::new(hash(
        seed ^ 0x7472_616e,
        mesh.stable_id(mesh.leaves[leaf]),
        0,
    ));
    let (t, b) = crate::form_factors::basis(node.normal);
    let rays = std::array::from_fn(|k| {
        let (s, u) = (rng.f64().sqrt(), rng.f64());
        let x = node.v[0] * (1.0 - s) + node.v[1] * (s * (1.0 - u)) + node.v[2] * (s * u);
        let d = crate::exposure::cosine_probe((t, b, node.normal), k, SIDE, &mut rng);
        (x, d.as_dvec3())
    });
    Probes { sphere, rays }
}

/// How far a ray from `x` along unit `d` goes before it leaves the sphere (`centre`, `r`); 0
/// where it starts outside and never enters.
fn exit_distance(x: DVec3, d: DVec3, centre: DVec3, r: f64) -> f64 {
    let o = x - centre;
    let b = o.dot(d);
    let c = o.length_squared() - r * r;
    let disc = b * b - c;
    if disc <= 0.0 {
        return 0.0;
    }
    (-b + disc.sqrt()).max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::MeshParams;
    use crate::scenes::{add_surface, quad};

    /// A 1 m floor of two triangles, each split in four elements (a cluster above them within
    /// [`REACH`] of their size), and with `roof` a second one facing it `gap` above.
    fn floor(roof: Option<f64>) -> (Mesh, Tree) {
        let mut scene = radiant_scene::Scene::default();
        let floor = quad(DVec3::ZERO, DVec3::Z, DVec3::X);
        add_surface(&mut scene, "floor", [0.5; 3], [0.0; 3], &floor);
        if let Some(gap) = roof {
            let roof = quad(DVec3::Y * gap, DVec3::X, DVec3::Z);
            add_surface(&mut scene, "roof", [0.5; 3], [1.0; 3], &roof);
        }
        let params = MeshParams {
            patch_size: 1.0,
            element_levels: 0,
            ..Default::default()
        };
        let mesh = Mesh::new(&scene, &params).expect("mesh");
        let tree = Tree::new(&mesh);
        (mesh, tree)
    }

    fn floor_transfers(roof: Option<f64>) -> (Mesh, Vec<[f32; 9]>) {
        let (mesh, tree) = floor(roof);
        let bvh = crate::input::visibility(&mesh, None);
        let t = transfer(&mesh, &tree, &bvh, 1);
        (mesh, t)
    }

    #[test]
    fn an_open_element_takes_its_cosine_and_a_covered_one_almost_nothing() {
        let (mesh, open) = floor_transfers(None);
        let (covered_mesh, covered) = floor_transfers(Some(0.01));
        let mut checked = 0;
        for (leaf, t) in open.iter().enumerate() {
            let n = mesh.leaf_node(leaf as u32).normal;
            let cosine = sh::cosine(n).map(|v| v as f32);
            assert_eq!(*t, cosine, "element {leaf}");
        }
        for (leaf, t) in covered.iter().enumerate() {
            let node = covered_mesh.leaf_node(leaf as u32);
            if node.normal.y < 0.5 {
                continue;
            }
            // Towards its normal the cosine is 1; under a roof 1 cm above, every probe is
            // closed: what is left is the sixteen rays' noise about the cosine's harmonics.
            let y = sh::basis(node.normal);
            let t = t.map(f64::from);
            let along = sh::dot(&t, &y);
            assert!(along.abs() < 0.25, "element {leaf}: {along}");
            checked += 1;
        }
        assert!(checked >= 8, "{checked} floor elements checked");
    }

    #[test]
    fn a_ray_leaves_a_sphere_where_it_should() {
        let d = exit_distance(DVec3::ZERO, DVec3::X, DVec3::ZERO, 2.0);
        assert!((d - 2.0).abs() < 1e-12);
        let d = exit_distance(DVec3::new(-3.0, 0.0, 0.0), DVec3::X, DVec3::ZERO, 1.0);
        assert!((d - 4.0).abs() < 1e-12);
        assert_eq!(
            exit_distance(DVec3::new(3.0, 0.0, 0.0), DVec3::X, DVec3::ZERO, 1.0),
            0.0
        );
    }
}
