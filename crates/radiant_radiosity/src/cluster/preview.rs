//! A quick look at a geometry edit's light, before the edit's refinement.
//!
//! A geometry edit of a level ([`super::ClusterBake::edit_geometry_previewed`]) refines again
//! what the change touches, bit for bit a fresh bake's links: seconds on Sponza. An editor
//! wants to see the moved prop's shadow at once. So, as soon as the edited scene is meshed,
//! the edit can hand out a preview on the new mesh:
//!
//! - every element takes the converged light of the element it was before the edit: the same
//!   element if its triangle stayed, the same place on the triangle if the triangle moved
//!   rigidly (same surface, same index in it, the same subdivision);
//! - the direct light (punctual lights, sky) of the elements it may have changed for is traced
//!   again, against the bake's own BVH with the moved triangles taken out at their old places
//!   and put back at their new ones ([`radiant_visibility::Patched`]): no BVH is built. Its
//!   change, reflected once (`ρ ΔE / π`), is added to the carried light;
//! - an element of a triangle that was not there (or whose subdivision changed) has no light to
//!   carry: it takes its emission, its direct light, and the light its hemisphere meets in the
//!   preview ([`FRESH_RAYS`] cosine-weighted rays, one bounce), with reflectance from its
//!   texture footprint as a fresh bake reads it (new triangles block rays unmasked).
//!
//! What changed is the moved triangles' old and new bounding box. An element's direct light
//! may have changed when it moved, or when its shadow segment towards a punctual light crosses
//! that box; for the sky, when the element lies within twice the box's diagonal of it (an
//! object subtends little sky further off; the sweeps after the edit correct the rest). What a
//! preview leaves out is the change in bounced light: the light the moved prop blocks or sends
//! between other surfaces, and its own bounced light at the new place.
//!
//! There is no preview when materials, lights or the sky change with the geometry: then the
//! edit's first sweep is the first light.

use std::collections::HashMap;
use std::sync::Arc;

use glam::DVec3;
use radiant_scene::{AlphaMasks, Scene, Surface};
use radiant_visibility::{Bvh, Patched, Visibility};
use rayon::prelude::*;

use crate::FormFactorParams;
use crate::hierarchy::RootMatch;
use crate::mesh::Mesh;
use crate::smooth::SmoothField;
use crate::system::Rgb;

/// The light right after a geometry edit is meshed, before its links are refined (see the
/// module's documentation).
#[derive(Clone, Debug)]
pub struct EditPreview {
    /// The edited scene's mesh: the one the edit's light will be on.
    pub mesh: Arc<Mesh>,
    /// Per element of `mesh`: the carried light with the change in direct light.
    pub radiosity: Vec<Rgb>,
    /// Per element: reflectance.
    pub rho: Vec<Rgb>,
    /// Per element: its exposure before the edit (the probes that escaped, of
    /// [`crate::exposure::POINTS`]; all of them for an element of a new triangle).
    pub exposure: Vec<u8>,
    /// Elements whose direct light was traced again.
    pub retraced: usize,
    /// Elements of new triangles, whose light was gathered (64 cosine-weighted rays each).
    pub gathered: usize,
    /// Seconds from the edit's start to the preview.
    pub seconds: f64,
}

impl EditPreview {
    /// The preview's light as a smooth field, as [`super::ClusterBake::smooth_field`] makes
    /// the bake's.
    pub fn smooth_field(&self, surfaces: &[Surface]) -> SmoothField {
        let (rho, live) = (&self.rho, &self.exposure);
        crate::smooth::exposed_field(&self.mesh, surfaces, rho, live, &self.radiosity)
    }
}

/// The converged bake before the edit: what the preview carries.
pub(super) struct Before<'a> {
    pub mesh: &'a Mesh,
    /// Built over `mesh`'s input triangles, in order ([`crate::input::visibility`]).
    pub bvh: &'a Bvh,
    pub masks: Option<&'a Arc<AlphaMasks>>,
    /// Per element: direct irradiance (`None`: no lights and no sky).
    pub direct: Option<&'a [Rgb]>,
    pub rho: &'a [Rgb],
    /// Per element: the texture footprints (`None`: no textures).
    pub textures: Option<&'a crate::input::ElementTextures>,
    pub b: &'a [Rgb],
    pub exposure: &'a [u8],
}

/// The edited scene (its lights and sky light it) and the tracing parameters.
pub(super) struct Lit<'a> {
    pub scene: &'a Scene,
    pub params: &'a FormFactorParams,
}

/// The preview of `mesh` (matched against the old one by `matched`), or `None` where the
/// edit is not one a preview can follow (see the module's documentation).
pub(super) fn preview(
    old: &Before,
    (mesh, matched): (&Arc<Mesh>, &RootMatch),
    lit: &Lit,
    started: std::time::Instant,
) -> Option<EditPreview> {
    let (of, came) = counterparts(old.mesh, mesh, matched)?;
    let fresh: Vec<u32> = (0..of.len() as u32)
        .filter(|&i| of[i as usize] == u32::MAX)
        .collect();
    let carried = |v: &[Rgb], i: usize, none: Rgb| v.get(of[i] as usize).copied().unwrap_or(none);
    // New elements' materials read as a fresh bake reads them (only when there are any).
    let (fresh_rho, emission) = if fresh.is_empty() {
        (Vec::new(), Vec::new())
    } else {
        fresh_materials(old, lit.scene, mesh, &of)
    };
    let or_zero = |v: &[Rgb], i: usize| v.get(i).copied().unwrap_or([0.0; 3]);
    let rho: Vec<Rgb> = (0..of.len())
        .map(|i| carried(old.rho, i, or_zero(&fresh_rho, i)))
        .collect();
    let mut b: Vec<Rgb> = (0..of.len())
        .map(|i| carried(old.b, i, or_zero(&emission, i)))
        .collect();
    let exposure: Vec<u8> = (0..of.len())
        .map(|i| old.exposure.get(of[i] as usize).copied())
        .map(|e| e.unwrap_or(crate::exposure::POINTS as u8))
        .collect();
    let vis = patched(old, mesh, matched, &came);
    let mut retraced = 0;
    if let Some(direct) = old.direct {
        let (affected, now) = retrace(old, (mesh, matched), lit, &vis);
        for (&leaf, e) in affected.iter().zip(&now) {
            let leaf = leaf as usize;
            let was = carried(direct, leaf, [0.0; 3]);
            for c in 0..3 {
                let change = rho[leaf][c] * (e[c] - was[c]) / std::f64::consts::PI;
                let v = b[leaf][c] + change;
                b[leaf][c] = if v.is_finite() { v.max(0.0) } else { 0.0 };
            }
        }
        retraced = affected.len();
    }
    let gathered = gather(
        &Traced {
            old,
            mesh,
            matched,
            vis: &vis,
            came: &came,
        },
        &fresh,
        &b,
        lit.params.seed,
    );
    for (&leaf, h) in fresh.iter().zip(&gathered) {
        let leaf = leaf as usize;
        for c in 0..3 {
            let v = b[leaf][c] + rho[leaf][c] * h[c];
            b[leaf][c] = if v.is_finite() { v.max(0.0) } else { 0.0 };
        }
    }
    Some(EditPreview {
        mesh: Arc::clone(mesh),
        radiosity: b,
        rho,
        exposure,
        retraced,
        gathered: fresh.len(),
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// Reflectance and emission per element of the edited mesh, as a fresh bake reads them: the
/// texture footprints of the elements with a counterpart `of` are the old ones, the others'
/// are read.
fn fresh_materials(old: &Before, scene: &Scene, mesh: &Mesh, of: &[u32]) -> (Vec<Rgb>, Vec<Rgb>) {
    let kept = |leaf: usize| -> Option<(Rgb, Rgb)> {
        let t = old.textures?;
        let o = *of.get(leaf)? as usize;
        Some((*t.reflectance.get(o)?, *t.emission.get(o)?))
    };
    let textures = crate::input::element_textures_keeping(scene, mesh, &kept);
    crate::input::materials(&scene.surfaces, mesh, textures.as_ref())
}

/// Rays per element of a new triangle in the preview's gather.
const FRESH_RAYS: u32 = 64;

/// What the preview traces against: the old scene patched to the edited one.
struct Traced<'a> {
    old: &'a Before<'a>,
    mesh: &'a Mesh,
    matched: &'a RootMatch,
    vis: &'a Patched<&'a Bvh>,
    came: &'a [(u32, u32)],
}

impl Traced<'_> {
    /// The element of the edited mesh a ray from `origin` along `dir` meets on its front.
    fn hit(&self, origin: DVec3, dir: DVec3) -> Option<u32> {
        let h = (self.vis)
            .closest_hit(origin.as_vec3(), dir.as_vec3(), f32::INFINITY)
            .filter(|h| h.front)?;
        let old_roots = &self.old.mesh.roots;
        let root = match (h.triangle as usize).checked_sub(old_roots.len()) {
            Some(k) => self.came[k].0,
            None => {
                let node = self.matched.new_of_old_node[old_roots[h.triangle as usize] as usize];
                self.mesh.nodes[node as usize].root
            }
        };
        Some(self.mesh.locate(root, f64::from(h.u), f64::from(h.v)))
    }
}

/// Per element of `leaves`: the light `b` its hemisphere meets (irradiance over π, to be
/// multiplied by reflectance), by [`FRESH_RAYS`] cosine-weighted rays seeded by its stable id.
fn gather(t: &Traced, leaves: &[u32], b: &[Rgb], seed: u64) -> Vec<Rgb> {
    (leaves.par_iter())
        .with_min_len(16)
        .map(|&leaf| {
            let node = t.mesh.leaf_node(leaf);
            let id = t.mesh.stable_id(t.mesh.leaves[leaf as usize]);
            let mut rng = crate::rng::Rng::new(crate::rng::hash(seed, id, 0x9A7));
            let (tn, bn) = node.normal.any_orthonormal_pair();
            let origin = node.centroid + node.normal * 1e-5;
            let mut sum = DVec3::ZERO;
            for _ in 0..FRESH_RAYS {
                let (u1, u2) = (rng.f64(), rng.f64());
                let (r, phi) = (u1.sqrt(), std::f64::consts::TAU * u2);
                let dir =
                    tn * (r * phi.cos()) + bn * (r * phi.sin()) + node.normal * (1.0 - u1).sqrt();
                if let Some(hit) = t.hit(origin, dir) {
                    sum += DVec3::from(b[hit as usize]);
                }
            }
            (sum / f64::from(FRESH_RAYS)).to_array()
        })
        .collect()
}

/// Each triangle that came: its root in the new mesh, and the one it was in the old
/// (`u32::MAX`: none).
type Moves = Vec<(u32, u32)>;

/// The elements whose direct light may have changed, and their direct irradiance now.
fn retrace(
    old: &Before,
    (mesh, matched): (&Mesh, &RootMatch),
    lit: &Lit,
    vis: &Patched<&Bvh>,
) -> (Vec<u32>, Vec<Rgb>) {
    let (lo, hi) = changed_bounds(&matched.changed_triangles(old.mesh, mesh));
    let moved = |leaf: u32| matched.added[mesh.leaf_node(leaf).root as usize];
    let affected: Vec<u32> = (0..mesh.element_count() as u32)
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&leaf| moved(leaf) || may_change(mesh, leaf, lit, (lo, hi)))
        .collect();
    let now = crate::input::direct_irradiance_of(
        &lit.scene.lights,
        lit.scene.sky.as_ref(),
        mesh,
        vis,
        lit.params,
        &affected,
    );
    (affected, now)
}

/// Per new element, the old element it carries the light of (`u32::MAX`: none): the same one
/// where its triangle stayed; for a triangle that moved, the one at the same place on the
/// triangle it was (same root key, same subdivision). And each triangle that came, with the
/// one it was (`u32::MAX`: none). `None` for a mesh that does not come from `matched`.
fn counterparts(old: &Mesh, new: &Mesh, matched: &RootMatch) -> Option<(Vec<u32>, Moves)> {
    let mut of = matched.old_of_new_leaf.clone();
    let mut went: HashMap<u64, Vec<usize>> = HashMap::new();
    for (o, _) in matched.kept.iter().enumerate().filter(|(_, k)| !**k).rev() {
        went.entry(*old.root_key.get(o)?).or_default().push(o);
    }
    let span = |m: &Mesh, r: usize| {
        let node = &m.nodes[m.roots[r] as usize];
        (node.leaf_lo as usize, node.leaf_hi as usize)
    };
    let mut came = Vec::new();
    for (r, _) in matched.added.iter().enumerate().filter(|(_, a)| **a) {
        let key = new.root_key.get(r)?;
        let Some(o) = went.get_mut(key).and_then(Vec::pop) else {
            came.push((r as u32, u32::MAX));
            continue;
        };
        came.push((r as u32, o as u32));
        let ((nlo, nhi), (olo, ohi)) = (span(new, r), span(old, o));
        if nhi - nlo == ohi - olo && new.patch_depth.get(r) == old.patch_depth.get(o) {
            for k in 0..(nhi - nlo) {
                of[nlo + k] = (olo + k) as u32;
            }
        }
    }
    (of.len() == new.element_count()).then_some((of, came))
}

/// The bounding box of `tris` (local frame), grown by a hair.
fn changed_bounds(tris: &[[DVec3; 3]]) -> (DVec3, DVec3) {
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for p in tris.iter().flatten() {
        (lo, hi) = (lo.min(*p), hi.max(*p));
    }
    (lo - 1e-4, hi + 1e-4)
}

/// Whether element `leaf`'s direct light may change when what lies in `[lo, hi]` changes: its
/// shadow segment to a punctual light crosses the box, or, under a sky, it lies within twice
/// the box's diagonal of it.
fn may_change(mesh: &Mesh, leaf: u32, lit: &Lit, (lo, hi): (DVec3, DVec3)) -> bool {
    if lo.x > hi.x {
        return false;
    }
    let x = mesh.leaf_node(leaf).centroid;
    // The lights' shadow rays, from the element's own points (`lights::shadow_points`).
    let points =
        (!lit.scene.lights.is_empty()).then(|| crate::lights::shadow_points(mesh, leaf as usize));
    let crosses = points.iter().flatten().any(|&p| {
        lit.scene.lights.iter().any(|light| {
            let target = match light.kind {
                radiant_scene::LightKind::Directional => p - light.direction * 4.0,
                _ => mesh.frame.to_local(light.position),
            };
            segment_meets_box(p, target, lo, hi)
        })
    });
    let near = lit.scene.sky.as_ref().is_some_and(|s| !s.is_dark()) && {
        let reach = 2.0 * (hi - lo).length();
        x.clamp(lo, hi).distance(x) <= reach
    };
    crosses || near
}

/// Whether the segment `a`–`b` meets the box `[lo, hi]` (slab test).
fn segment_meets_box(a: DVec3, b: DVec3, lo: DVec3, hi: DVec3) -> bool {
    let d = b - a;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for k in 0..3 {
        if d[k].abs() < 1e-300 {
            if a[k] < lo[k] || a[k] > hi[k] {
                return false;
            }
            continue;
        }
        let (ta, tb) = ((lo[k] - a[k]) / d[k], (hi[k] - a[k]) / d[k]);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
        if t0 > t1 {
            return false;
        }
    }
    true
}

/// The old BVH without the triangles that went, with those that came; `came` pairs each new
/// root with the old one it was, whose alpha mask it keeps (one that was not there is opaque).
fn patched<'a>(
    old: &'a Before,
    mesh: &Mesh,
    matched: &RootMatch,
    came: &[(u32, u32)],
) -> Patched<&'a Bvh> {
    let removed: Vec<bool> = matched.kept.iter().map(|k| !k).collect();
    let tris: Vec<[glam::Vec3; 3]> = (came.iter())
        .map(|&(r, _)| {
            mesh.nodes[mesh.roots[r as usize] as usize]
                .v
                .map(|p| p.as_vec3())
        })
        .collect();
    let added = match old.masks {
        Some(masks) => {
            let was: Arc<Vec<u32>> = Arc::new(came.iter().map(|&(_, o)| o).collect());
            let (marks, masks, was2) = (Arc::clone(masks), Arc::clone(masks), Arc::clone(&was));
            Bvh::with_filter(
                &tris,
                move |i| was[i as usize] != u32::MAX && marks.is_masked(was[i as usize]),
                Arc::new(move |i: u32, u: f32, v: f32| masks.blocks(was2[i as usize], u, v)),
            )
        }
        None => Bvh::new(&tris),
    };
    Patched::new(old.bvh, removed, added)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::MeshParams;
    use radiant_scene::Light;

    /// The tessellated box under a sun and a point light, meshed, with its BVH and direct light.
    fn lit_box(scene: &radiant_scene::Scene) -> (Mesh, Bvh, Vec<Rgb>) {
        let mesh = Mesh::adaptive(scene, &MeshParams::default(), &mut |_| Ok(())).expect("meshes");
        let bvh = crate::input::visibility(&mesh, None);
        let ff = FormFactorParams::default();
        let direct =
            crate::input::direct_irradiance(&scene.lights, None, &mesh, &bvh, &ff).expect("lit");
        (mesh, bvh, direct)
    }

    #[test]
    fn the_retraced_direct_light_is_a_fresh_bakes_and_the_rest_did_not_change() {
        let mut scene =
            crate::scenes::tessellated(&radiant_scene::builtin("cornell-box").expect("builtin"), 2);
        let light = |kind, position: DVec3, direction: DVec3| Light {
            name: "light".into(),
            kind,
            position,
            direction: direction.normalize(),
            intensity: 2.0,
            color: [1.0, 0.9, 0.8],
            range: None,
        };
        scene.lights.push(light(
            radiant_scene::LightKind::Directional,
            DVec3::ZERO,
            DVec3::new(0.2, -0.3, 1.0),
        ));
        scene.lights.push(light(
            radiant_scene::LightKind::Point,
            DVec3::new(0.3, 0.45, 0.2),
            DVec3::NEG_Y,
        ));
        let (old_mesh, old_bvh, old_direct) = lit_box(&scene);
        for (name, dx) in [("short_block", 0.08), ("tall_block", -0.05)] {
            let moved = crate::scenes::translated(&scene, name, DVec3::X * dx);
            let (mesh, _, fresh) = lit_box(&moved);
            let matched = RootMatch::new(&old_mesh, &mesh);
            let (of, came) = counterparts(&old_mesh, &mesh, &matched).expect("a rigid move");
            assert!(!came.is_empty());
            let n = old_mesh.element_count();
            let zero = vec![[0.0; 3]; n];
            let before = Before {
                mesh: &old_mesh,
                bvh: &old_bvh,
                masks: None,
                direct: Some(&old_direct),
                rho: &zero,
                textures: None,
                b: &zero,
                exposure: &[],
            };
            let ff = FormFactorParams::default();
            let lit = Lit {
                scene: &moved,
                params: &ff,
            };
            let vis = patched(&before, &mesh, &matched, &came);
            let (affected, now) = retrace(&before, (&mesh, &matched), &lit, &vis);
            // Traced against the old BVH patched: what a BVH of the moved scene gives.
            for (&leaf, e) in affected.iter().zip(&now) {
                assert_eq!(*e, fresh[leaf as usize], "{name}: element {leaf}");
            }
            // Everything else kept its direct light.
            let mut was = vec![false; n];
            for &leaf in &affected {
                was[leaf as usize] = true;
            }
            let changed = (0..n)
                .filter(|&i| fresh[i] != old_direct[of[i] as usize])
                .count();
            for i in (0..n).filter(|&i| !was[i]) {
                assert_eq!(fresh[i], old_direct[of[i] as usize], "{name}: element {i}");
            }
            // The move changed some direct light, and the retrace is local.
            assert!(
                changed > 10 && affected.len() < n / 3,
                "{name}: {changed} changed, {} retraced of {n}",
                affected.len()
            );
        }
    }

    #[test]
    fn segments_meet_boxes_as_a_slab_test_says() {
        let (lo, hi) = (DVec3::splat(-1.0), DVec3::splat(1.0));
        let seg =
            |a: [f64; 3], b: [f64; 3]| segment_meets_box(DVec3::from(a), DVec3::from(b), lo, hi);
        assert!(seg([-2.0, 0.0, 0.0], [2.0, 0.0, 0.0]));
        assert!(seg([0.0, 0.0, 0.0], [0.1, 0.1, 0.1]));
        assert!(!seg([-2.0, 1.5, 0.0], [2.0, 1.5, 0.0]));
        assert!(!seg([2.0, 2.0, 2.0], [3.0, 3.0, 3.0]));
        // Stops short of the box.
        assert!(!seg([-3.0, 0.0, 0.0], [-1.5, 0.0, 0.0]));
        // Diagonal through a corner's neighbourhood, missing it.
        assert!(!seg([1.5, -1.0, 0.0], [3.0, 1.0, 0.0]));
        assert!(seg([0.5, -3.0, 0.0], [0.5, 3.0, 0.0]));
    }
}
