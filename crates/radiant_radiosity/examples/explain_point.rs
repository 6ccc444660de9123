//! Where the clustered bake's light at a point comes from: the element under the point, the
//! links of it and of every node above it (the light each pushes to the element, by level),
//! and cosine-weighted rays from the point itself into the same solution, each credited to the
//! link whose source holds what it met. Where a link pushes much more than the point's rays
//! find behind it, the element's light is not the point's: the link's receiver is a cluster
//! whose parts see the source and this one does not, or the element reaches past a wall.
//!
//! `cargo run --release -p radiant_radiosity --example explain_point -- SCENE.gltf X Y Z NX NY NZ
//! [CHECKPOINT]` (world units; the normal of the surface at the point). With CHECKPOINT (written
//! by `radiant bake --checkpoint`, default settings) the links are read from it instead of
//! refined again. The figures are red-channel irradiance `H` (emissive units); the pushed light
//! is approximate for cluster sources (their mean radiosity instead of their directional one)
//! and leaves out the solve's live-area corrections, so the levels' sum is not exactly the
//! element's own `H`, which is printed beside it.

use std::collections::{BTreeMap, HashMap};

use glam::DVec3;
use radiant_radiosity::BakeParams;
use radiant_radiosity::cluster::{ClusterBake, ClusterParams, Watch, sh};
use radiant_radiosity::mesh::Mesh;
use radiant_radiosity::rng::Rng;
use radiant_visibility::Visibility;

/// Rays from the point.
const RAYS: u32 = 40_000;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: explain_point SCENE.gltf X Y Z NX NY NZ [CHECKPOINT]";
    let num = |i: usize| -> Result<f64, String> {
        args.get(i)
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| usage.to_string())
    };
    let path = args.first().ok_or(usage)?;
    let world = DVec3::new(num(1)?, num(2)?, num(3)?);
    let normal = DVec3::new(num(4)?, num(5)?, num(6)?).normalize_or_zero();
    if !world.is_finite() || normal == DVec3::ZERO {
        return Err("the point must be finite and the normal finite and not zero".into());
    }
    let scene = radiant_scene::load_gltf(std::path::Path::new(path))?;
    let (params, cp) = (BakeParams::default(), ClusterParams::default());
    let mut bake = match args.get(7) {
        Some(c) => ClusterBake::resume(&scene, &params, &cp, std::path::Path::new(c))?,
        None => ClusterBake::new(&scene, &params, &cp, &|_, _, _| {}, None)?,
    };
    bake.run_to_end(&|_, _, _| {}, &mut Watch::default())?;
    let mesh = bake.mesh();
    let tree = bake.tree();
    let scale = mesh.frame.scale;
    let p = mesh.frame.to_local(world);
    let masks = radiant_radiosity::input::masks(&scene);
    let bvh = radiant_radiosity::input::visibility(mesh, masks.as_ref());
    let (rho, source) = bake.terms();
    let b = bake.radiosity();
    let exposure = bake.exposure();

    let leaf = nearest_element(mesh, p, normal).ok_or("no element faces that way")?;
    let node = mesh.leaf_node(leaf);
    let surface = |root: u32| {
        let t = &scene.triangles[root as usize];
        scene.surfaces[t.surface as usize].name.clone()
    };
    let own_h = (b[leaf as usize][0] - source[leaf as usize][0]) / rho[leaf as usize][0];
    println!(
        "element {leaf} of `{}`: {:.4} m², bounding radius {:.3} m, {} of {} probe points exposed, \
         its H {own_h:.4e}",
        surface(node.root),
        node.area * scale * scale,
        (0..3)
            .map(|k| (node.v[k] - node.centroid).length())
            .fold(0.0, f64::max)
            * scale,
        exposure[leaf as usize],
        radiant_radiosity::exposure::POINTS,
    );

    // The element's node and every node above it; each link of theirs with the light it
    // pushes to the element.
    let above = ancestors(mesh, tree, mesh.leaves[leaf as usize]);
    let rows = bake.rows();
    let mean_b = |id: u32| source_mean(mesh, tree, &b, exposure, id);
    struct Pushed {
        level: usize,
        src: u32,
        light: f64,
    }
    let mut links = Vec::new();
    for (level, &r) in above.iter().enumerate() {
        for k in rows.row[r as usize]..rows.row[r as usize + 1] {
            let src = rows.src[k as usize];
            let f = f64::from(rows.ff[k as usize]);
            let light = if r >= tree.mesh_nodes {
                // A cluster hands each triangle under it its light by the triangle's normal.
                let d = (tree.center[src as usize] - tree.center[r as usize]).normalize_or_zero();
                f * mean_b(src) * sh::dot(&sh::basis(d), &sh::cosine(node.normal))
            } else {
                f * mean_b(src)
            };
            links.push(Pushed { level, src, light });
        }
    }

    // Rays from the point, credited to the link whose source holds what they met.
    let by_source: HashMap<u32, usize> =
        links.iter().enumerate().map(|(i, l)| (l.src, i)).collect();
    let mut found = vec![0.0; links.len()];
    let (mut unlinked, mut unlinked_h, mut total) = (0u32, 0.0, 0.0);
    let mut rng = Rng::new(1);
    let origin = p + normal * 1e-5;
    for _ in 0..RAYS {
        let d = cosine_direction(normal, &mut rng);
        let Some(h) = bvh.closest_hit(origin.as_vec3(), d.as_vec3(), f32::INFINITY) else {
            continue;
        };
        if !h.front {
            continue;
        }
        let at = mesh.locate(h.triangle, f64::from(h.u), f64::from(h.v));
        let value = b[at as usize][0] / f64::from(RAYS);
        total += value;
        match ancestors(mesh, tree, mesh.leaves[at as usize])
            .iter()
            .find_map(|a| by_source.get(a))
        {
            Some(&i) => found[i] += value,
            None => {
                unlinked += 1;
                unlinked_h += value;
            }
        }
    }
    println!(
        "rays from the point into the solution: H {total:.4e}; {unlinked} of {RAYS} met a surface \
         no link reaches ({unlinked_h:.4e} of it)"
    );
    // The same rays from the element's ninths: where it lies inside other geometry, most of
    // their rays meet back faces.
    for (k, q) in ninths(&node.v).into_iter().enumerate() {
        let o = q + node.normal * 1e-5;
        let (mut h_sum, mut back) = (0.0, 0u32);
        let n = RAYS / 10;
        for _ in 0..n {
            let d = cosine_direction(node.normal, &mut rng);
            match bvh.closest_hit(o.as_vec3(), d.as_vec3(), f32::INFINITY) {
                Some(h) if h.front => {
                    let at = mesh.locate(h.triangle, f64::from(h.u), f64::from(h.v));
                    h_sum += b[at as usize][0];
                }
                Some(_) => back += 1,
                None => {}
            }
        }
        println!(
            "  ninth {k} of the element, {:.3} m from the point: rays' H {:.3e}, {:.0} % back faces",
            (q - p).length() * scale,
            h_sum / f64::from(n),
            100.0 * f64::from(back) / f64::from(n)
        );
    }
    let mut levels: BTreeMap<usize, (f64, f64, usize)> = BTreeMap::new();
    for (l, f) in links.iter().zip(&found) {
        let e = levels.entry(l.level).or_default();
        e.0 += l.light;
        e.1 += f;
        e.2 += 1;
    }
    println!("level  receiver  radius (m)  links  pushed H    rays' H");
    for (level, (pushed, rays, n)) in &levels {
        let r = above[*level];
        let kind = if r >= tree.mesh_nodes {
            "cluster"
        } else {
            "triangle"
        };
        let radius = tree.radius[r as usize] * scale;
        println!("{level:5}  {kind:8}  {radius:10.3}  {n:5}  {pushed:.3e}  {rays:.3e}");
    }
    let mut excess: Vec<usize> = (0..links.len()).collect();
    excess.sort_by(|&a, &c| {
        let ea = links[a].light - found[a];
        (links[c].light - found[c]).total_cmp(&ea)
    });
    println!("the links that push the most more than the rays find:");
    for &i in excess.iter().take(10) {
        let l = &links[i];
        let s = l.src as usize;
        println!(
            "  level {} source {} ({}, {:.3} m², {:.2} m away): pushed {:.3e}, rays {:.3e}",
            l.level,
            l.src,
            if l.src >= tree.mesh_nodes {
                "cluster"
            } else {
                "triangle"
            },
            tree.area[s] * scale * scale,
            (tree.center[s] - p).length() * scale,
            l.light,
            found[i]
        );
    }
    Ok(())
}

/// The element facing along `normal` (within 25°) whose triangle holds `p` or lies nearest it.
fn nearest_element(mesh: &Mesh, p: DVec3, normal: DVec3) -> Option<u32> {
    let mut best: Option<(f64, u32)> = None;
    for leaf in 0..mesh.element_count() as u32 {
        let n = mesh.leaf_node(leaf);
        if n.normal.dot(normal) < 0.9 {
            continue;
        }
        let h = n.normal.dot(p - n.v[0]);
        let q = p - n.normal * h;
        let inside = (0..3).all(|i| {
            let (a, b) = (n.v[i], n.v[(i + 1) % 3]);
            (b - a).cross(q - a).dot(n.normal) >= 0.0
        });
        let d = if inside {
            h.abs()
        } else {
            (p - n.centroid).length() + 1.0
        };
        if best.is_none_or(|(bd, _)| d < bd) {
            best = Some((d, leaf));
        }
    }
    best.map(|(_, l)| l)
}

/// Node `id` and every node above it, mesh nodes then clusters.
fn ancestors(mesh: &Mesh, tree: &radiant_radiosity::cluster::tree::Tree, id: u32) -> Vec<u32> {
    let mut out = vec![id];
    let mut id = id;
    loop {
        let up = match mesh.nodes.get(id as usize) {
            Some(n) if n.parent != u32::MAX => n.parent,
            _ => tree.parent[id as usize],
        };
        if up == u32::MAX {
            return out;
        }
        out.push(up);
        id = up;
    }
}

/// The red radiosity of node `id` averaged over its exposed area.
fn source_mean(
    mesh: &Mesh,
    tree: &radiant_radiosity::cluster::tree::Tree,
    b: &[radiant_radiosity::Rgb],
    exposure: &[u8],
    id: u32,
) -> f64 {
    let roots: Vec<u32> = match tree.cluster(id) {
        Some(c) => (c.first..c.end)
            .map(|k| mesh.roots[tree.order[k as usize] as usize])
            .collect(),
        None => vec![id],
    };
    let (mut sum, mut area) = (0.0, 0.0);
    for r in roots {
        let n = &mesh.nodes[r as usize];
        for leaf in n.leaf_lo..n.leaf_hi {
            let a = mesh.leaf_node(leaf).area
                * radiant_radiosity::exposure::fraction(exposure[leaf as usize]);
            sum += a * b[leaf as usize][0];
            area += a;
        }
    }
    if area > 0.0 { sum / area } else { 0.0 }
}

/// The centroids of the nine triangles that splitting `v`'s edges in three makes.
fn ninths(v: &[DVec3; 3]) -> Vec<DVec3> {
    let at = |i: u32, j: u32| {
        v[0] + (v[1] - v[0]) * (f64::from(i) / 3.0) + (v[2] - v[0]) * (f64::from(j) / 3.0)
    };
    let mut out = Vec::with_capacity(9);
    for i in 0..3 {
        for j in 0..3 - i {
            out.push((at(i, j) + at(i + 1, j) + at(i, j + 1)) / 3.0);
            if i + j < 2 {
                out.push((at(i + 1, j) + at(i, j + 1) + at(i + 1, j + 1)) / 3.0);
            }
        }
    }
    out
}

/// A cosine-distributed direction about unit `n`.
fn cosine_direction(n: DVec3, rng: &mut Rng) -> DVec3 {
    let (t, b) = n.any_orthonormal_pair();
    let (u, v) = (rng.f64(), rng.f64());
    let (r, phi) = (u.sqrt(), std::f64::consts::TAU * v);
    t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u).sqrt()
}
