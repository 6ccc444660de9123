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

#[allow(clippy::too_many_arguments)]
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
    let max_samples = f64::from(params.max_samples.max(1));
    let samples_for = |transport: f64, eps: f64| -> u8 {
        let want = (transport / eps).ceil();
        if want.is_finite() {
            want.clamp(1.0, max_samples) as u8
        } else {
            1
        }
    };
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
        let nsamples = samples_for(t, oracle.eps);
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
