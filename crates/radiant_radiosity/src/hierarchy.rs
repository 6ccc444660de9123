//! The per-triangle bake's link hierarchy: the links of a mesh (held by the [`System`] that is
//! solved), the enclosed elements and the refinement oracle they were built with, and the
//! fingerprint of what they depend on. This is what a checkpoint stores besides the solution,
//! and what a geometry edit updates ([`relink`]).
//!
//! [`System`]: crate::System

use glam::DVec3;
use radiant_scene::Scene;
use radiant_visibility::{Bvh, Visibility};
use rayon::prelude::*;

use crate::form_factors::{self, FfContext, FormFactorKind};
use crate::links::{self, Links, Oracle};
use crate::mesh::Mesh;
use crate::params::BakeParams;
use crate::system::Rgb;

/// The refinement oracle a hierarchy was built with: per-node estimates `B̂` and the threshold
/// (see [`Estimates::new`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Estimates {
    /// Per node.
    pub bhat: Vec<f64>,
    /// The threshold.
    pub eps: f64,
}

impl Estimates {
    /// Per-node radiosity estimates `B̂` (max channel) relative to the ambient level `B_amb`,
    /// with the threshold `refinement`: a source is split while `F × B̂ > refinement × B_amb`.
    /// Relative, a surface that neither emits nor is lit directly has the estimate `ρ`
    /// whatever the ambient level, so an edit that changes the ambient level (moving a block
    /// changes the total area in the last bits) leaves those estimates, and every refinement
    /// decision made with them, exactly as they were.
    pub fn new(mesh: &Mesh, rho: &[Rgb], source: &[Rgb], refinement: f64) -> Estimates {
        let max3 = |v: &Rgb| v[0].max(v[1]).max(v[2]);
        let (mut area, mut s_sum, mut r_sum) = (0.0, 0.0, 0.0);
        for (i, &id) in mesh.leaves.iter().enumerate() {
            let a = mesh.nodes[id as usize].area;
            area += a;
            s_sum += a * max3(&source[i]);
            r_sum += a * max3(&rho[i]);
        }
        let rho_mean = (r_sum / area).min(0.99);
        let amb = quantized((s_sum / area / (1.0 - rho_mean)).max(f64::MIN_POSITIVE));
        let mut bhat = vec![0.0; mesh.nodes.len()];
        for n in (0..mesh.nodes.len()).rev() {
            let node = &mesh.nodes[n];
            bhat[n] = if node.is_leaf() {
                let i = node.leaf_lo as usize;
                let s = max3(&source[i]);
                // Zero stays exactly zero; a huge emitter over a tiny ambient stays finite.
                let e = if s > 0.0 {
                    (s / amb).min(f64::MAX)
                } else {
                    0.0
                };
                e + max3(&rho[i])
            } else {
                (0..4)
                    .map(|k| bhat[(node.first_child + k) as usize])
                    .fold(0.0, f64::max)
            };
        }
        Estimates {
            bhat,
            eps: refinement,
        }
    }

    /// As the link walk reads it.
    pub fn oracle(&self) -> Oracle<'_> {
        Oracle {
            bhat: &self.bhat,
            eps: self.eps,
        }
    }
}

/// `x` rounded to the nearest of the steps `2^(k/16)`: the ambient level the estimates are held
/// relative to. A small edit (a prop moved, its shadow with it) moves the ambient level in the
/// last digits; rounded, it stays the same, and so does every estimate of a surface whose own
/// light did not change: the edit can keep all that was refined with them. The threshold moves
/// by at most 2.2 % for it.
fn quantized(x: f64) -> f64 {
    let q = (x.log2() * 16.0).round() / 16.0;
    let y = q.exp2();
    if y.is_finite() && y > 0.0 { y } else { x }
}

/// Everything about a bake's links besides the links themselves.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Hierarchy {
    /// The fingerprint of the geometry and parameters the links were built for
    /// ([`fingerprint`]).
    pub fingerprint: u64,
    /// Per element: inside closed geometry ([`enclosed_elements`]).
    pub dead: Vec<bool>,
    /// The oracle the links were built with; `None` after a resume from a checkpoint that did
    /// not store it (edits then walk every row again).
    pub oracle: Option<Estimates>,
}

/// The fingerprint of what links depend on: geometry and the mesh, link and form-factor
/// parameters. Lights and materials are not in it: resuming computes direct light again and
/// takes the scene's materials, as edits do.
pub fn fingerprint(scene: &Scene, params: &BakeParams) -> u64 {
    let mut h = crate::rng::Fnv::new();
    h.bytes(
        format!(
            "{:?}|{:?}|{:?}|{:?}",
            params.mesh, params.links, params.form_factors, params.ff
        )
        .as_bytes(),
    );
    for t in &scene.triangles {
        for v in t.vertices {
            h.f64(v.x);
            h.f64(v.y);
            h.f64(v.z);
        }
        h.bytes(&t.surface.to_le_bytes());
    }
    h.0
}

/// Builds a fresh hierarchy: enclosed elements, the oracle, and the links refined with it,
/// calling `progress(done)` as receivers are linked. A scene where nothing emits gets no links.
pub fn build(
    scene: &Scene,
    mesh: &Mesh,
    bvh: &Bvh,
    params: &BakeParams,
    (rho, source): (&[Rgb], &[Rgb]),
    progress: &(dyn Fn(usize) + Sync),
) -> (Hierarchy, Links) {
    let n = mesh.element_count();
    let estimates = Estimates::new(mesh, rho, source, params.links.refinement);
    let has_emitters = source.iter().flatten().any(|&v| v > 0.0);
    let (dead, links) = if has_emitters {
        let ctx = FfContext {
            mesh,
            vis: bvh,
            params: params.ff,
        };
        let links = links::build(
            &ctx,
            form_factors::method(params.form_factors),
            estimates.oracle(),
            &params.links,
            progress,
        );
        (enclosed_elements(mesh, bvh, params.ff.seed), links)
    } else {
        let links = Links {
            row: vec![0; n + 1],
            ..Default::default()
        };
        (vec![false; n], links)
    };
    let hierarchy = Hierarchy {
        fingerprint: fingerprint(scene, params),
        dead,
        oracle: Some(estimates),
    };
    (hierarchy, links)
}

/// Elements whose centroid lies inside closed geometry (the floor under a block): every one of
/// the cosine-distributed probe rays from them hits a back face. Such elements receive nothing and no
/// receiver sees them, so they must not dilute the radiosity of the source nodes they belong to.
/// (The clustered bake measures how much of each element is exposed instead:
/// [`crate::exposure`].)
pub fn enclosed_elements(mesh: &Mesh, vis: &dyn Visibility, seed: u64) -> Vec<bool> {
    (0..mesh.element_count())
        .into_par_iter()
        .map(|leaf| {
            let node = mesh.leaf_node(leaf as u32);
            let id = mesh.stable_id(mesh.leaves[leaf]);
            let mut rng = crate::rng::Rng::new(crate::rng::hash(seed ^ 0xDEAD, id, 0));
            let origin = crate::form_factors::ray_origin(node.centroid, node.normal);
            let (t, b) = crate::form_factors::basis(node.normal);
            // One probe that escapes or meets a front face decides it: not enclosed.
            (0..PROBES).all(|k| {
                let dir = crate::exposure::cosine_probe((t, b, node.normal), k, 4, &mut rng);
                vis.closest_hit(origin, dir, f32::INFINITY)
                    .is_some_and(|h| !h.front)
            })
        })
        .collect()
}

/// Probe rays per element of [`enclosed_elements`].
const PROBES: usize = 16;

/// How an edited mesh's input triangles match the old ones: by surface name and index within
/// it (as hashed into the ray seeds) and exact local vertices. A moved triangle is one that
/// went and one that came.
pub struct RootMatch {
    /// Per old node: its number in the new mesh (`u32::MAX`: gone).
    pub new_of_old_node: Vec<u32>,
    /// Per new element: its number in the old mesh (`u32::MAX`: new).
    pub old_of_new_leaf: Vec<u32>,
    /// Per new root: it came (or moved) with the edit.
    pub added: Vec<bool>,
    /// Per old root: it stayed.
    pub kept: Vec<bool>,
}

impl RootMatch {
    /// Matches `new` against `old`.
    pub fn new(old: &Mesh, new: &Mesh) -> RootMatch {
        // Names come from each mesh (its root keys), not from the scene's surfaces.
        let key = |m: &Mesh, r: usize| {
            let v = m.nodes[m.roots[r] as usize].v;
            (
                m.root_key.get(r).copied().unwrap_or(0),
                v.map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]),
            )
        };
        // Each key's digest, in parallel; per digest, its first old root, `next` chaining the
        // others with the same digest in order (the same key twice, or a collision).
        let digests = |m: &Mesh| -> Vec<u64> {
            use std::hash::{Hash, Hasher};
            (0..m.roots.len())
                .into_par_iter()
                .with_min_len(4096)
                .map(|r| {
                    let mut h = rustc_hash::FxHasher::default();
                    key(m, r).hash(&mut h);
                    h.finish()
                })
                .collect()
        };
        let (old_digest, new_digest) = (digests(old), digests(new));
        let mut first: rustc_hash::FxHashMap<u64, u32> = rustc_hash::FxHashMap::default();
        first.reserve(old.roots.len());
        let mut next = vec![u32::MAX; old.roots.len()];
        for (r, &d) in old_digest.iter().enumerate() {
            match first.entry(d) {
                std::collections::hash_map::Entry::Vacant(v) => {
                    v.insert(r as u32);
                }
                std::collections::hash_map::Entry::Occupied(o) => {
                    let mut at = *o.get() as usize;
                    while next[at] != u32::MAX {
                        at = next[at] as usize;
                    }
                    next[at] = r as u32;
                }
            }
        }
        let mut m = RootMatch {
            new_of_old_node: vec![u32::MAX; old.nodes.len()],
            old_of_new_leaf: vec![u32::MAX; new.element_count()],
            added: vec![true; new.roots.len()],
            kept: vec![false; old.roots.len()],
        };
        for r in 0..new.roots.len() {
            let Some(o) = first.get(&new_digest[r]).and_then(|&o| {
                std::iter::successors(Some(o), |&o| {
                    Some(next[o as usize]).filter(|&n| n != u32::MAX)
                })
                .map(|o| o as usize)
                .find(|&o| !m.kept[o] && key(old, o) == key(new, r))
            }) else {
                continue;
            };
            let ((nlo, nhi), (olo, ohi)) = (root_nodes(new, r), root_nodes(old, o));
            if nhi - nlo != ohi - olo {
                continue;
            }
            m.kept[o] = true;
            m.added[r] = false;
            for k in 0..(nhi - nlo) {
                m.new_of_old_node[olo + k] = (nlo + k) as u32;
            }
            let (nl, ol) = (
                new.nodes[new.roots[r] as usize].leaf_lo as usize,
                old.nodes[old.roots[o] as usize].leaf_lo as usize,
            );
            let count = (new.nodes[new.roots[r] as usize].leaf_hi as usize) - nl;
            for k in 0..count {
                m.old_of_new_leaf[nl + k] = (ol + k) as u32;
            }
        }
        m
    }

    /// Whether every triangle stayed and none came.
    pub fn unchanged(&self) -> bool {
        !self.added.iter().any(|&a| a) && self.kept.iter().all(|&k| k)
    }

    /// The triangles that came and went: what occludes differently after the edit.
    pub fn changed_triangles(&self, old: &Mesh, new: &Mesh) -> Vec<[DVec3; 3]> {
        let came = (self.added.iter().enumerate())
            .filter(|(_, a)| **a)
            .map(|(r, _)| new.nodes[new.roots[r] as usize].v);
        let went = (self.kept.iter().enumerate())
            .filter(|(_, k)| !**k)
            .map(|(o, _)| old.nodes[old.roots[o] as usize].v);
        came.chain(went).collect()
    }

    /// `values` per old element, carried over to the new elements that stayed (0 elsewhere).
    pub fn carry(&self, values: &[Rgb]) -> Vec<Rgb> {
        self.old_of_new_leaf
            .iter()
            .map(|&o| values.get(o as usize).copied().unwrap_or([0.0; 3]))
            .collect()
    }
}

/// The node range of root `r`: roots are pushed in order, each with its whole subtree.
fn root_nodes(m: &Mesh, r: usize) -> (usize, usize) {
    let lo = m.roots[r] as usize;
    let hi = m.roots.get(r + 1).map_or(m.nodes.len(), |&x| x as usize);
    (lo, hi)
}

/// The old hierarchy and what it is to be updated for: the inputs of [`relink`].
pub struct Relink<'a> {
    /// The mesh before the edit.
    pub old_mesh: &'a Mesh,
    /// Its links.
    pub old_links: &'a Links,
    /// Its hierarchy.
    pub old: &'a Hierarchy,
    /// The edited scene.
    pub scene: &'a Scene,
    /// Its mesh and visibility.
    pub mesh: &'a Mesh,
    /// Its ray tracer.
    pub bvh: &'a Bvh,
    /// Its reflectance and sources per element.
    pub rho: &'a [Rgb],
    /// The sources.
    pub source: &'a [Rgb],
    /// How its triangles match the old ones.
    pub matched: &'a RootMatch,
    /// Scratch space kept between edits.
    pub scratch: &'a links::Scratch,
}

/// Updates the hierarchy for an edited scene, keeping what the edit does not touch (see
/// [`links::update`]): with the oracle a fresh bake of the scene would use, so the links
/// match a fresh bake's.
pub fn relink(r: &Relink, params: &BakeParams) -> (Hierarchy, Links, links::UpdateStats) {
    // Monte Carlo rays leave 1e-5 off the receiver (`form_factors::ray_origin`): they stray
    // that far from the exact shaft; the other methods only by rounding.
    let margin = match params.form_factors {
        FormFactorKind::MonteCarlo => 2e-5,
        _ => links::ChangeSet::ROUNDING,
    };
    let changed = links::ChangeSet::new(&r.matched.changed_triangles(r.old_mesh, r.mesh), margin);
    let estimates = Estimates::new(r.mesh, r.rho, r.source, params.links.refinement);
    let ctx = FfContext {
        mesh: r.mesh,
        vis: r.bvh,
        params: params.ff,
    };
    // The old oracle in the new numbering: kept links whose sample count changes with the
    // new oracle are computed again (added nodes have no old estimate: recomputed anyway).
    let old_oracle = r.old.oracle.as_ref().map(|o| {
        let mut bhat = vec![0.0; r.mesh.nodes.len()];
        for (k, &nn) in r.matched.new_of_old_node.iter().enumerate() {
            if nn != u32::MAX {
                bhat[nn as usize] = o.bhat[k];
            }
        }
        Estimates { bhat, eps: o.eps }
    });
    let (links, stats) = links::update(
        &ctx,
        form_factors::method(params.form_factors),
        estimates.oracle(),
        &params.links,
        r.old_links,
        &links::Change {
            old_of_new_leaf: &r.matched.old_of_new_leaf,
            new_of_old_node: &r.matched.new_of_old_node,
            moved_root: &r.matched.added,
            triangles: &changed,
            old_oracle: old_oracle.as_ref().map(Estimates::oracle),
        },
        r.scratch,
    );
    let hierarchy = Hierarchy {
        fingerprint: fingerprint(r.scene, params),
        dead: enclosed_elements(r.mesh, r.bvh, params.ff.seed),
        oracle: Some(estimates),
    };
    (hierarchy, links, stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::MeshParams;
    use crate::scenes::add_surface;

    fn mesh(scene: &Scene) -> Mesh {
        Mesh::adaptive(scene, &MeshParams::default(), &mut |_| Ok(())).expect("meshes")
    }

    #[test]
    fn roots_match_by_name_index_and_place_twins_in_order() {
        let t = |x: f64| {
            [
                DVec3::new(x, 0., 0.),
                DVec3::new(x + 1., 0., 0.),
                DVec3::new(x, 1., 0.),
            ]
        };
        // Two surfaces named alike, each with the same triangle first: twins by key.
        let mut old = Scene::default();
        add_surface(&mut old, "a", [0.5; 3], [0.0; 3], &[t(0.0), t(2.0)]);
        add_surface(&mut old, "a", [0.5; 3], [0.0; 3], &[t(0.0)]);
        add_surface(&mut old, "b", [0.5; 3], [1.0; 3], &[t(4.0), t(6.0)]);
        let m = RootMatch::new(&mesh(&old), &mesh(&old));
        assert!(m.unchanged());
        // Each twin matched once, in order: the elements map onto themselves.
        assert!(
            m.old_of_new_leaf
                .iter()
                .enumerate()
                .all(|(i, &o)| o == i as u32)
        );
        // One triangle of "b" moved (the bounding box the same): it went and came.
        let mut new = old.clone();
        new.triangles[3].vertices = t(6.0);
        new.triangles[4].vertices = t(4.0);
        let (a, b) = (mesh(&old), mesh(&new));
        let m = RootMatch::new(&a, &b);
        assert_eq!(m.added, [false, false, false, true, true]);
        assert_eq!(m.kept, [true, true, true, false, false]);
        let (lo, hi) = (
            a.nodes[a.roots[3] as usize].leaf_lo,
            b.nodes[b.roots[3] as usize].leaf_lo,
        );
        assert_eq!(lo, hi);
        assert_eq!(m.old_of_new_leaf[lo as usize], u32::MAX);
        assert_eq!(m.changed_triangles(&a, &b).len(), 4);
    }
}
