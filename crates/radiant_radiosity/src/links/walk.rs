//! The refinement walk of one receiver over the source hierarchy, shared by a fresh build and
//! an update.

use super::{LinkParams, Oracle};
use crate::form_factors::{Row, analytic::point_to_triangle};
use crate::mesh::Mesh;

/// Visibility samples of a link that carries `transport`: one per `eps`, at most
/// `params.max_samples`.
pub(super) fn samples_for(transport: f64, eps: f64, params: &LinkParams) -> u8 {
    let want = (transport / eps).ceil();
    if want.is_finite() {
        want.clamp(1.0, f64::from(params.max_samples.max(1))) as u8
    } else {
        1
    }
}

/// One receiver's refined row: source nodes (in order of their first leaf), their unoccluded
/// form factors and visibility sample counts.
#[derive(Default)]
pub(super) struct Walked {
    pub(super) src: Vec<u32>,
    pub(super) f: Vec<f64>,
    pub(super) samples: Vec<u8>,
}

impl Walked {
    pub(super) fn clear(&mut self) {
        self.src.clear();
        self.f.clear();
        self.samples.clear();
    }
    pub(super) fn push(&mut self, s: u32, f: f64, samples: u8) {
        self.src.push(s);
        self.f.push(f);
        self.samples.push(samples);
    }
    pub(super) fn as_row(&self, leaf: u32) -> Row<'_> {
        Row {
            leaf,
            sources: &self.src,
            unoccluded: &self.f,
            samples: &self.samples,
        }
    }
}

/// Refines receiver `leaf` against the subtrees of `roots` (root nodes, in order), appending
/// to `out`.
pub(super) fn refine(
    mesh: &Mesh,
    leaf: u32,
    roots: &[u32],
    oracle: Oracle,
    params: &LinkParams,
    stack: &mut Vec<u32>,
    out: &mut Walked,
) {
    let r = mesh.leaf_node(leaf);
    let (x, n) = (r.centroid, r.normal);
    stack.clear();
    stack.extend(roots.iter().rev().copied());
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
        if split {
            for k in (0..4).rev() {
                stack.push(node.first_child + k);
            }
        } else {
            out.push(s, f, samples_for(t, oracle.eps, params));
        }
    }
}
