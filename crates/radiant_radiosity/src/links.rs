//! Links: which source nodes each element gathers from, and their form factors.
//!
//! Each receiver element, sampled at its centroid, walks the source hierarchy top-down (the
//! source side of Hanrahan, Salzman & Aupperle 1991): a source node is split into its four
//! children while its estimated transport `F × B̂` exceeds `refinement × B_ambient`, otherwise it
//! becomes a link. `F` is the exact unoccluded point-to-polygon value, so the links of a receiver
//! tile everything it sees and, unoccluded, sum to exactly 1 in a closed scene (the furnace
//! holds). The chosen [`FormFactorMethod`] then computes each link's value, occlusion included.
//!
//! With `hierarchical = false` every element links to every patch it sees (Cohen et al.'s
//! patch–element substructuring): the classic O(elements × patches) baseline.

use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use crate::form_factors::{FfContext, FormFactorMethod, Row, analytic::point_to_triangle};
use crate::mesh::Mesh;
use glam::DVec3;

/// Refinement parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkParams {
    /// Below the patch level, split a source while `F × B̂ > refinement × B_ambient`, with `B̂`
    /// its estimated radiosity (default: 0.02). Smaller is more accurate and slower.
    pub refinement: f64,
    /// Adaptive source hierarchy (true) or every element to every patch (false).
    pub hierarchical: bool,
    /// Above the patch level, split unless `F × B̂` is below `far_field × refinement ×
    /// B_ambient` (default: 0.05).
    pub far_field: f64,
    /// Most visibility samples on one link (default: 16).
    pub max_samples: u8,
}

impl Default for LinkParams {
    fn default() -> Self {
        LinkParams {
            refinement: 0.02,
            hierarchical: true,
            far_field: 0.05,
            max_samples: 16,
        }
    }
}

/// Links in compressed rows: receiver element `i` gathers from `src[row[i]..row[i+1]]`.
#[derive(Clone, Debug, Default)]
pub struct Links {
    /// Row offsets, one per element plus one.
    pub row: Vec<usize>,
    /// Source node of each link.
    pub src: Vec<u32>,
    /// Form factor of each link.
    pub ff: Vec<f32>,
}

impl Links {
    /// Number of links.
    pub fn len(&self) -> usize {
        self.src.len()
    }
    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.src.is_empty()
    }
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.row.len() * 8 + self.src.len() * 4 + self.ff.len() * 4
    }
    /// Sum of the form factors of element `i`'s row.
    pub fn row_sum(&self, i: usize) -> f64 {
        self.ff[self.row[i]..self.row[i + 1]]
            .iter()
            .map(|&f| f64::from(f))
            .sum()
    }
}

/// The refinement oracle: split a source node while `F × bhat[node] > eps` (or, above the patch
/// level, while it exceeds `far_field × eps`).
#[derive(Clone, Copy, Debug)]
pub struct Oracle<'a> {
    /// A-priori radiosity estimate per node (max channel).
    pub bhat: &'a [f64],
    /// Absolute threshold on `F × B̂`.
    pub eps: f64,
}

/// Builds all links; `progress(done)` is called with the elements done so far.
pub fn build(
    ctx: &FfContext,
    method: &dyn FormFactorMethod,
    oracle: Oracle,
    params: &LinkParams,
    progress: &(dyn Fn(usize) + Sync),
) -> Links {
    let mesh = ctx.mesh;
    let n = mesh.element_count();
    let done = AtomicUsize::new(0);
    const CHUNK: usize = 64;
    let chunks: Vec<(Vec<u32>, Vec<u32>, Vec<f32>)> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let (lo, hi) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
            let mut counts = Vec::with_capacity(hi - lo);
            let mut src = Vec::new();
            let mut ff = Vec::new();
            let mut stack = Vec::new();
            let (mut row_src, mut row_f, mut row_s) = (Vec::new(), Vec::new(), Vec::new());
            let mut out = Vec::new();
            for leaf in lo..hi {
                row_src.clear();
                row_f.clear();
                row_s.clear();
                refine(
                    mesh,
                    leaf as u32,
                    oracle,
                    params,
                    &mut stack,
                    &mut row_src,
                    &mut row_f,
                    &mut row_s,
                );
                out.clear();
                out.resize(row_src.len(), 0.0f32);
                let row = Row {
                    leaf: leaf as u32,
                    sources: &row_src,
                    unoccluded: &row_f,
                    samples: &row_s,
                };
                method.compute(ctx, &row, &mut out);
                // Drop links that carry nothing (fully occluded).
                let before = src.len();
                for (k, &f) in out.iter().enumerate() {
                    if f > 0.0 {
                        src.push(row_src[k]);
                        ff.push(f);
                    }
                }
                counts.push((src.len() - before) as u32);
            }
            let d = done.fetch_add(hi - lo, Ordering::Relaxed) + (hi - lo);
            progress(d);
            (counts, src, ff)
        })
        .collect();
    assemble(n, chunks)
}

/// Concatenates per-chunk rows (link counts per element, sources, form factors) into links.
fn assemble(n: usize, chunks: Vec<(Vec<u32>, Vec<u32>, Vec<f32>)>) -> Links {
    let total: usize = chunks.iter().map(|c| c.1.len()).sum();
    let mut links = Links {
        row: Vec::with_capacity(n + 1),
        src: Vec::with_capacity(total),
        ff: Vec::with_capacity(total),
    };
    links.row.push(0);
    for (counts, src, ff) in chunks {
        let mut at = links.src.len();
        for c in counts {
            at += c as usize;
            links.row.push(at);
        }
        links.src.extend(src);
        links.ff.extend(ff);
    }
    links
}

/// Visibility samples of a link that carries `transport`: one per `eps`, at most
/// `params.max_samples`.
fn samples_for(transport: f64, eps: f64, params: &LinkParams) -> u8 {
    let want = (transport / eps).ceil();
    if want.is_finite() {
        want.clamp(1.0, f64::from(params.max_samples.max(1))) as u8
    } else {
        1
    }
}

#[expect(
    clippy::too_many_arguments,
    reason = "the row being refined and its scratch"
)]
fn refine(
    mesh: &Mesh,
    leaf: u32,
    oracle: Oracle,
    params: &LinkParams,
    stack: &mut Vec<u32>,
    src: &mut Vec<u32>,
    fs: &mut Vec<f64>,
    samples: &mut Vec<u8>,
) {
    let r = mesh.leaf_node(leaf);
    let (x, n) = (r.centroid, r.normal);
    stack.clear();
    stack.extend(mesh.roots.iter().rev().copied());
    while let Some(s) = stack.pop() {
        let node = &mesh.nodes[s as usize];
        if node.root == r.root {
            continue; // a planar triangle does not see itself
        }
        let f = point_to_triangle(x, n, &node.v, node.normal);
        if f <= 0.0 {
            continue;
        }
        let t = f * oracle.bhat[s as usize];
        let above_patch = node.depth < mesh.patch_depth[node.root as usize];
        let split = !node.is_leaf()
            && if params.hierarchical {
                // Sources are never coarser than patches unless they carry next to nothing;
                // below patches they are split while the transport is large.
                (above_patch && t > oracle.eps * params.far_field) || t > oracle.eps
            } else {
                above_patch
            };
        let nsamples = samples_for(t, oracle.eps, params);
        if split {
            for k in (0..4).rev() {
                stack.push(node.first_child + k);
            }
        } else {
            src.push(s);
            fs.push(f);
            samples.push(nsamples);
        }
    }
}

/// What [`update`] recomputed and kept.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UpdateStats {
    /// Links whose form factor was computed again.
    pub recomputed: usize,
    /// Links whose form factor was kept.
    pub kept: usize,
}

/// Whether the tetrahedron `t` (a receiver point and a source triangle: the volume the
/// visibility rays of a link sweep) overlaps the box `[lo, hi]`, by separating axes.
pub fn shaft_hits_box(t: &[DVec3; 4], lo: DVec3, hi: DVec3) -> bool {
    let centre = (lo + hi) * 0.5;
    let half = (hi - lo) * 0.5;
    let overlaps = |axis: DVec3| -> bool {
        if axis.length_squared() < 1e-24 {
            return true;
        }
        let r = half.x * axis.x.abs() + half.y * axis.y.abs() + half.z * axis.z.abs();
        let c = centre.dot(axis);
        let (mut mn, mut mx) = (f64::INFINITY, f64::NEG_INFINITY);
        for p in t {
            let d = p.dot(axis);
            mn = mn.min(d);
            mx = mx.max(d);
        }
        mx >= c - r && mn <= c + r
    };
    let box_axes = [DVec3::X, DVec3::Y, DVec3::Z];
    if !box_axes.iter().all(|&a| overlaps(a)) {
        return false;
    }
    const FACES: [[usize; 3]; 4] = [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]];
    for f in FACES {
        if !overlaps((t[f[1]] - t[f[0]]).cross(t[f[2]] - t[f[0]])) {
            return false;
        }
    }
    const EDGES: [[usize; 2]; 6] = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];
    for e in EDGES {
        let d = t[e[1]] - t[e[0]];
        for a in box_axes {
            if !overlaps(d.cross(a)) {
                return false;
            }
        }
    }
    true
}

/// Updates links after some input triangles moved rigidly (`moved_root`), keeping the form
/// factor of every link whose receiver and source did not move and whose shaft misses
/// `moved_box` (the moved geometry's bounds before and after, local frame). Rows are refined
/// again with the same oracle, so unmoved pairs keep their structure; links missing from the
/// old row (fully occluded then) are computed again, as is everything touching moved geometry.
/// Per-link methods (analytic, ray-cast) recompute only those links; the others recompute the
/// whole row when any of its links needs it. With `old_oracle` (the oracle the old links were
/// built with, in the new node numbering), a kept link whose visibility sample count would
/// differ under the new oracle is computed again too, so the result equals a fresh build.
#[expect(clippy::too_many_arguments, reason = "the inputs of a link update")]
pub fn update(
    ctx: &FfContext,
    method: &dyn FormFactorMethod,
    oracle: Oracle,
    old_oracle: Option<Oracle>,
    params: &LinkParams,
    old: &Links,
    moved_root: &[bool],
    moved_box: (DVec3, DVec3),
) -> (Links, UpdateStats) {
    use crate::form_factors::FormFactorKind;
    let mesh = ctx.mesh;
    let n = mesh.element_count();
    let per_link = matches!(
        method.kind(),
        FormFactorKind::Analytic | FormFactorKind::RayCast
    );
    // Padded past the f32 rounding of the visibility rays; an empty box (nothing moved)
    // meets no shaft.
    let any_box = moved_box.0.cmple(moved_box.1).all();
    let (lo, hi) = (
        moved_box.0 - DVec3::splat(1e-6),
        moved_box.1 + DVec3::splat(1e-6),
    );
    const CHUNK: usize = 64;
    type Chunk = (Vec<u32>, Vec<u32>, Vec<f32>, UpdateStats);
    let chunks: Vec<Chunk> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let (first, last) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
            let mut counts = Vec::with_capacity(last - first);
            let (mut src, mut ff) = (Vec::new(), Vec::new());
            let mut stats = UpdateStats::default();
            let mut stack = Vec::new();
            let (mut row_src, mut row_f, mut row_s) = (Vec::new(), Vec::new(), Vec::new());
            let (mut sub_src, mut sub_f, mut sub_s, mut sub_k) =
                (Vec::new(), Vec::new(), Vec::new(), Vec::new());
            let mut out = Vec::new();
            for leaf in first..last {
                row_src.clear();
                row_f.clear();
                row_s.clear();
                refine(
                    mesh,
                    leaf as u32,
                    oracle,
                    params,
                    &mut stack,
                    &mut row_src,
                    &mut row_f,
                    &mut row_s,
                );
                let r = mesh.leaf_node(leaf as u32);
                let receiver_moved = moved_root[r.root as usize];
                // Old values by merge on first leaf (both rows are sorted by it).
                let (olo, ohi) = (old.row[leaf], old.row[leaf + 1]);
                let mut o = olo;
                let mut values = vec![None::<f32>; row_src.len()];
                let mut need = vec![receiver_moved; row_src.len()];
                for (k, &s) in row_src.iter().enumerate() {
                    let node = &mesh.nodes[s as usize];
                    while o < ohi && mesh.nodes[old.src[o] as usize].leaf_lo < node.leaf_lo {
                        o += 1;
                    }
                    if o < ohi && old.src[o] == s {
                        values[k] = Some(old.ff[o]);
                    }
                    if !need[k] {
                        let resampled = old_oracle.is_some_and(|o| {
                            samples_for(row_f[k] * o.bhat[s as usize], o.eps, params) != row_s[k]
                        });
                        need[k] = moved_root[node.root as usize]
                            || values[k].is_none()
                            || resampled
                            || (any_box
                                && shaft_hits_box(
                                    &[r.centroid, node.v[0], node.v[1], node.v[2]],
                                    lo,
                                    hi,
                                ));
                    }
                }
                if !per_link && need.iter().any(|&x| x) {
                    need.iter_mut().for_each(|x| *x = true);
                }
                sub_src.clear();
                sub_f.clear();
                sub_s.clear();
                sub_k.clear();
                for k in 0..row_src.len() {
                    if need[k] {
                        sub_src.push(row_src[k]);
                        sub_f.push(row_f[k]);
                        sub_s.push(row_s[k]);
                        sub_k.push(k);
                    }
                }
                if !sub_src.is_empty() {
                    out.clear();
                    out.resize(sub_src.len(), 0.0f32);
                    let row = Row {
                        leaf: leaf as u32,
                        sources: &sub_src,
                        unoccluded: &sub_f,
                        samples: &sub_s,
                    };
                    method.compute(ctx, &row, &mut out);
                    for (j, &k) in sub_k.iter().enumerate() {
                        values[k] = Some(out[j]);
                    }
                }
                stats.recomputed += sub_src.len();
                stats.kept += row_src.len() - sub_src.len();
                let before = src.len();
                for (k, v) in values.iter().enumerate() {
                    if let Some(f) = *v
                        && f > 0.0
                    {
                        src.push(row_src[k]);
                        ff.push(f);
                    }
                }
                counts.push((src.len() - before) as u32);
            }
            (counts, src, ff, stats)
        })
        .collect();
    let mut stats = UpdateStats::default();
    let rows = chunks
        .into_iter()
        .map(|(counts, src, ff, s)| {
            stats.recomputed += s.recomputed;
            stats.kept += s.kept;
            (counts, src, ff)
        })
        .collect();
    (assemble(n, rows), stats)
}

#[cfg(test)]
mod shaft_tests {
    use super::*;

    #[test]
    fn shaft_box_overlap() {
        let t = [
            DVec3::ZERO,
            DVec3::new(0.0, 0.0, 10.0),
            DVec3::new(1.0, 0.0, 10.0),
            DVec3::new(0.0, 1.0, 10.0),
        ];
        // A box on the shaft's axis.
        assert!(shaft_hits_box(
            &t,
            DVec3::splat(0.05),
            DVec3::new(0.1, 0.1, 5.0)
        ));
        // Beside it, where only the bounding boxes overlap.
        assert!(!shaft_hits_box(
            &t,
            DVec3::new(0.8, 0.8, 0.5),
            DVec3::new(1.0, 1.0, 1.0)
        ));
        // Far away.
        assert!(!shaft_hits_box(&t, DVec3::splat(20.0), DVec3::splat(21.0)));
    }
}
