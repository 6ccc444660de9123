//! Links after a geometry edit: what the edit does not touch is kept.

use rayon::prelude::*;

use super::shaft::{ChangeSet, SeenFrom};
use super::walk::{Walked, refine, samples_for};
use super::{CHUNK, Chunk, LinkParams, Links, Oracle, assemble};
use crate::form_factors::{FfContext, FormFactorMethod, analytic::point_to_triangle};
use crate::mesh::Mesh;
use glam::DVec3;

/// What [`update`] recomputed and kept.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UpdateStats {
    /// Links whose form factor was computed again.
    pub recomputed: usize,
    /// Links whose form factor was kept.
    pub kept: usize,
    /// Receivers whose refinement was walked again in full (the others kept their rows'
    /// structure and walked only the changed roots).
    pub rows_walked: usize,
}

/// Merges two runs sorted by `key` into `out`.
fn merge_by<T: Copy, K: Ord>(a: &[T], b: &[T], key: impl Fn(&T) -> K, out: &mut Vec<T>) {
    let (mut i, mut j) = (0, 0);
    while i < a.len() || j < b.len() {
        if j >= b.len() || (i < a.len() && key(&a[i]) <= key(&b[j])) {
            out.push(a[i]);
            i += 1;
        } else {
            out.push(b[j]);
            j += 1;
        }
    }
}

/// Old receiver `o`'s row (`old` numbering) in the new numbering, fully occluded links
/// included with value 0, sorted by the sources' first leaf (`leaf_lo`, new numbering). Links
/// to nodes that are gone are dropped.
fn old_row(
    old: &Links,
    o: usize,
    new_of_old_node: &[u32],
    leaf_lo: &[u32],
    visible: &mut Vec<(u32, f32)>,
    occluded: &mut Vec<(u32, f32)>,
    out: &mut Vec<(u32, f32)>,
) {
    visible.clear();
    occluded.clear();
    let map = |s: u32, f: f32| {
        let s = new_of_old_node[s as usize];
        (s != u32::MAX).then_some((s, f))
    };
    visible.extend((old.row[o]..old.row[o + 1]).filter_map(|k| map(old.src[k], old.ff[k])));
    if old.hidden_known() {
        occluded.extend(
            (old.hidden_row[o]..old.hidden_row[o + 1]).filter_map(|k| map(old.hidden_src[k], 0.0)),
        );
    }
    let key = |&(s, _): &(u32, f32)| leaf_lo[s as usize];
    // Renumbering usually keeps the order (roots stay in scene order): merge the two runs.
    if visible.is_sorted_by_key(key) && occluded.is_sorted_by_key(key) {
        merge_by(visible, occluded, key, out);
    } else {
        out.extend_from_slice(visible);
        out.extend_from_slice(occluded);
        out.sort_unstable_by_key(key);
    }
}

/// What an edit changed, for [`update`].
pub struct Change<'a> {
    /// Per new element: the old element it is (`u32::MAX`: new).
    pub old_of_new_leaf: &'a [u32],
    /// Per old node: the new node it is (`u32::MAX`: gone).
    pub new_of_old_node: &'a [u32],
    /// Per root (input triangle): new or moved. Every link from or to it is computed again.
    pub moved_root: &'a [bool],
    /// The triangles that went or came: a kept link whose shaft may cross one is computed again.
    pub triangles: &'a ChangeSet,
    /// The oracle the old links were built with, in the new node numbering (nodes that are new
    /// have 0), when it is known. Without it every row is walked again in full.
    pub old_oracle: Option<Oracle<'a>>,
}

/// A link of a row being updated.
#[derive(Clone, Copy)]
struct Cand {
    src: u32,
    /// Unoccluded form factor; NaN until needed, for links kept from the old row.
    f: f64,
    samples: u8,
    /// The kept value (0 for a fully occluded link), or none.
    value: Option<f32>,
    need: bool,
}

/// Updates links after an edit (`old`: the old links, in the old numbering), keeping the
/// value of every link whose receiver and source did not move and whose shaft cannot cross a
/// triangle that went or came. The result equals a fresh [`build`](super::build()) with `oracle`.
///
/// A receiver that did not move keeps its old row's structure for the roots whose oracle
/// estimates did not change (when the old oracle and the old fully occluded links are known
/// and the threshold is the same), and walks only the other roots: an edit costs what it
/// touches, not a walk of the whole hierarchy. Otherwise the row is refined again in full, and
/// old values are taken for links that match (a link whose sample count changes is computed
/// again). Per-link methods (analytic, ray-cast) recompute only the links that need it; the
/// others recompute the whole row when any of its links does.
pub fn update(
    ctx: &FfContext,
    method: &dyn FormFactorMethod,
    oracle: Oracle,
    params: &LinkParams,
    old: &Links,
    change: &Change,
    scratch: &Scratch,
) -> (Links, UpdateStats) {
    use crate::form_factors::FormFactorKind;
    let mesh = ctx.mesh;
    let n = mesh.element_count();
    let per_link = matches!(
        method.kind(),
        FormFactorKind::Analytic | FormFactorKind::RayCast
    );
    let leaf_lo: Vec<u32> = mesh.nodes.iter().map(|n| n.leaf_lo).collect();
    // Roots whose links can be kept as they were: not moved, same estimates on every node.
    let node_range = |r: usize| {
        let lo = mesh.roots[r] as usize;
        let hi = mesh
            .roots
            .get(r + 1)
            .map_or(mesh.nodes.len(), |&x| x as usize);
        lo..hi
    };
    let fast = old.hidden_known()
        && change
            .old_oracle
            .is_some_and(|o| o.eps.to_bits() == oracle.eps.to_bits());
    let clean: Vec<bool> = (0..mesh.roots.len())
        .map(|r| {
            fast && !change.moved_root[r]
                && change.old_oracle.is_some_and(|o| {
                    node_range(r).all(|k| o.bhat[k].to_bits() == oracle.bhat[k].to_bits())
                })
        })
        .collect();
    let dirty_roots: Vec<u32> = (0..mesh.roots.len())
        .filter(|&r| !clean[r])
        .map(|r| mesh.roots[r])
        .collect();
    let rows = RowUpdate {
        ctx,
        method,
        oracle,
        params,
        old,
        change,
        per_link,
        fast,
        clean: &clean,
        dirty_roots: &dirty_roots,
        leaf_lo: &leaf_lo,
    };
    let chunks: Vec<(Chunk, UpdateStats)> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map_init(
            || scratch.lease(),
            |lease, c| {
                let scratch = &mut lease.scratch;
                let (first, last) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
                let mut chunk = Chunk::default();
                let mut stats = UpdateStats::default();
                for leaf in first..last {
                    rows.update_row(leaf, scratch, &mut stats);
                    chunk.push_row(
                        scratch
                            .cands
                            .iter()
                            .map(|c| (c.src, c.value.unwrap_or(0.0))),
                    );
                }
                (chunk, stats)
            },
        )
        .collect();
    let mut stats = UpdateStats::default();
    let chunks = chunks
        .into_iter()
        .map(|(chunk, s)| {
            stats.recomputed += s.recomputed;
            stats.kept += s.kept;
            stats.rows_walked += s.rows_walked;
            chunk
        })
        .collect();
    (assemble(n, chunks), stats)
}

/// What every row of one [`update`] shares.
struct RowUpdate<'a> {
    ctx: &'a FfContext<'a>,
    method: &'a dyn FormFactorMethod,
    oracle: Oracle<'a>,
    params: &'a LinkParams,
    old: &'a Links,
    change: &'a Change<'a>,
    /// Whether the method computes links one by one (else a row is computed whole).
    per_link: bool,
    /// Whether rows of receivers that stayed may keep their structure on clean roots.
    fast: bool,
    /// Per root: its links can be kept as they were.
    clean: &'a [bool],
    /// The root nodes that are not clean, in order.
    dirty_roots: &'a [u32],
    /// Per node: its first leaf (the order of a row).
    leaf_lo: &'a [u32],
}

impl RowUpdate<'_> {
    /// One receiver's row, left in `scratch.cands`.
    fn update_row(&self, leaf: usize, scratch: &mut UpdateScratch, stats: &mut UpdateStats) {
        let RowUpdate {
            ctx,
            method,
            oracle,
            params,
            old,
            change,
            per_link,
            fast,
            clean,
            dirty_roots,
            leaf_lo,
        } = *self;
        let mesh = ctx.mesh;
        let UpdateScratch {
            stack,
            walked,
            old_row: row_old,
            visible,
            occluded,
            cands,
            spare,
            kept,
            sub,
            sub_k,
            out,
            seen,
            memo,
            stamp,
        } = scratch;
        let r = mesh.leaf_node(leaf as u32);
        let receiver_moved = change.moved_root[r.root as usize];
        row_old.clear();
        let o = change.old_of_new_leaf[leaf];
        if o != u32::MAX {
            old_row(
                old,
                o as usize,
                change.new_of_old_node,
                leaf_lo,
                visible,
                occluded,
                row_old,
            );
        }
        cands.clear();
        walked.clear();
        // Rows that keep their structure on clean roots walk only the others.
        let keep = fast && !receiver_moved && o != u32::MAX;
        if !keep {
            stats.rows_walked += 1;
        }
        let roots = if keep { dirty_roots } else { &mesh.roots };
        refine(mesh, leaf as u32, roots, oracle, params, stack, walked);
        // Old values of walked links by merge on first leaf (both rows are sorted by it).
        let mut at = 0;
        for k in 0..walked.src.len() {
            let s = walked.src[k];
            while at < row_old.len() && leaf_lo[row_old[at].0 as usize] < leaf_lo[s as usize] {
                at += 1;
            }
            let mut c = new_cand(walked, k);
            if at < row_old.len() && row_old[at].0 == s {
                c.value = Some(row_old[at].1);
            }
            let resampled = change.old_oracle.is_some_and(|o| {
                samples_for(walked.f[k] * o.bhat[s as usize], o.eps, params) != walked.samples[k]
            });
            c.need = receiver_moved
                || change.moved_root[mesh.nodes[s as usize].root as usize]
                || c.value.is_none()
                || resampled;
            cands.push(c);
        }
        if keep {
            // The clean roots' links as they were, merged in (disjoint nodes: distinct first leaves).
            kept.clear();
            kept.extend(
                row_old
                    .iter()
                    .filter(|(s, _)| clean[mesh.nodes[*s as usize].root as usize])
                    .map(|&(s, v)| Cand {
                        src: s,
                        f: f64::NAN,
                        samples: 0,
                        value: Some(v),
                        need: false,
                    }),
            );
            std::mem::swap(cands, spare);
            cands.clear();
            merge_by(spare, kept, |c| leaf_lo[c.src as usize], cands);
        }
        // Kept links whose shaft may cross the change, culled down the hierarchy: a node's shaft
        // lies inside its parent's.
        if !change.triangles.is_empty() {
            if memo.len() < mesh.nodes.len() {
                memo.resize(mesh.nodes.len(), (0, 0));
            }
            *stamp += 1;
            let mut q = ShaftQuery {
                mesh,
                change: change.triangles,
                x: r.centroid,
                leaf: leaf as u32,
                stamp: *stamp,
                memo,
                seen,
            };
            for c in cands.iter_mut().filter(|c| !c.need) {
                c.need = q.link_meets(c.src);
            }
        }
        if !per_link && cands.iter().any(|c| c.need) {
            cands.iter_mut().for_each(|c| c.need = true);
        }
        sub.clear();
        sub_k.clear();
        for (k, c) in cands.iter_mut().enumerate() {
            if c.need {
                if c.f.is_nan() {
                    // A kept link computed again: its oracle values, as the walk gives them.
                    let node = &mesh.nodes[c.src as usize];
                    c.f = point_to_triangle(r.centroid, r.normal, &node.v, node.normal);
                    c.samples = samples_for(c.f * oracle.bhat[c.src as usize], oracle.eps, params);
                }
                sub.push(c.src, c.f, c.samples);
                sub_k.push(k);
            }
        }
        if !sub.src.is_empty() {
            out.clear();
            out.resize(sub.src.len(), 0.0f32);
            method.compute(ctx, &sub.as_row(leaf as u32), out);
            for (j, &k) in sub_k.iter().enumerate() {
                cands[k].value = Some(out[j]);
            }
        }
        stats.recomputed += sub.src.len();
        stats.kept += cands.len() - sub.src.len();
    }
}

/// Scratch space of [`update`]: one set of buffers per parallel job, lent out while it runs
/// and kept for the next update, so that the per-node shaft memo is allocated once per thread,
/// not per job or per edit. Keep one per bake and pass it to every update.
#[derive(Default)]
pub struct Scratch {
    pool: std::sync::Mutex<Vec<UpdateScratch>>,
}

impl Scratch {
    fn lease(&self) -> Lease<'_> {
        let scratch = self.pool.lock().ok().and_then(|mut p| p.pop());
        Lease {
            pool: self,
            scratch: scratch.unwrap_or_default(),
        }
    }
}

/// Buffers lent out by a [`Scratch`], given back when dropped.
struct Lease<'a> {
    pool: &'a Scratch,
    scratch: UpdateScratch,
}

impl Drop for Lease<'_> {
    fn drop(&mut self) {
        if let Ok(mut p) = self.pool.pool.lock() {
            p.push(std::mem::take(&mut self.scratch));
        }
    }
}

/// One job's buffers.
#[derive(Default)]
struct UpdateScratch {
    stack: Vec<u32>,
    walked: Walked,
    old_row: Vec<(u32, f32)>,
    /// Scratch of [`old_row`]: the visible and the fully occluded run.
    visible: Vec<(u32, f32)>,
    occluded: Vec<(u32, f32)>,
    cands: Vec<Cand>,
    /// The walked links while the kept ones are merged in.
    spare: Vec<Cand>,
    kept: Vec<Cand>,
    sub: Walked,
    sub_k: Vec<usize>,
    out: Vec<f32>,
    /// The changed triangles seen from the current receiver.
    seen: SeenFrom,
    /// Per node: the stamp of the receiver it was last tested for, and the change groups its
    /// shaft may cross.
    memo: Vec<(u64, u64)>,
    /// The last stamp used in `memo` (one per receiver tested, never reused).
    stamp: u64,
}

/// What the shaft tests of one receiver share: its point and number, the memo's stamp, the
/// per-node memo and the changed triangles seen from it.
struct ShaftQuery<'a> {
    mesh: &'a Mesh,
    change: &'a ChangeSet,
    x: DVec3,
    leaf: u32,
    stamp: u64,
    memo: &'a mut [(u64, u64)],
    seen: &'a mut SeenFrom,
}

impl ShaftQuery<'_> {
    /// Whether the shaft to link source `s` may cross the change: the groups its parent's
    /// shaft may cross are found first (memoised), since a child's triangle lies inside its
    /// parent's, and only those are tested.
    fn link_meets(&mut self, s: u32) -> bool {
        let node = &self.mesh.nodes[s as usize];
        let within = if node.parent == u32::MAX {
            self.change.all()
        } else {
            self.groups_met(node.parent)
        };
        within != 0
            && self
                .change
                .meets(self.leaf, self.x, &node.v, within, true, self.seen)
                != 0
    }

    /// The change groups the shaft to node `s` may cross, memoised.
    fn groups_met(&mut self, s: u32) -> u64 {
        if self.memo[s as usize].0 == self.stamp {
            return self.memo[s as usize].1;
        }
        let node = &self.mesh.nodes[s as usize];
        let within = if node.parent == u32::MAX {
            self.change.all()
        } else {
            self.groups_met(node.parent)
        };
        let hit = if within == 0 {
            0
        } else {
            self.change
                .meets(self.leaf, self.x, &node.v, within, false, self.seen)
        };
        self.memo[s as usize] = (self.stamp, hit);
        hit
    }
}

/// A freshly walked link: computed.
fn new_cand(w: &Walked, k: usize) -> Cand {
    Cand {
        src: w.src[k],
        f: w.f[k],
        samples: w.samples[k],
        value: None,
        need: true,
    }
}
