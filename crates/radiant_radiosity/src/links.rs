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
///
/// Links found fully occluded carry nothing and are left out of the rows the solver reads; they
/// are kept apart (`hidden_*`), so that an edit knows each row's whole refinement without walking
/// the hierarchy again.
#[derive(Clone, Debug, Default)]
pub struct Links {
    /// Row offsets, one per element plus one.
    pub row: Vec<usize>,
    /// Source node of each link.
    pub src: Vec<u32>,
    /// Form factor of each link.
    pub ff: Vec<f32>,
    /// Row offsets of the fully occluded links, one per element plus one; empty when unknown
    /// (links from another source, such as a version-1 checkpoint).
    pub hidden_row: Vec<usize>,
    /// Source node of each fully occluded link.
    pub hidden_src: Vec<u32>,
}

impl Links {
    /// Number of links that carry light.
    pub fn len(&self) -> usize {
        self.src.len()
    }
    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.src.is_empty()
    }
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        (self.row.len() + self.hidden_row.len()) * 8
            + (self.src.len() + self.hidden_src.len()) * 4
            + self.ff.len() * 4
    }
    /// Sum of the form factors of element `i`'s row.
    pub fn row_sum(&self, i: usize) -> f64 {
        self.ff[self.row[i]..self.row[i + 1]]
            .iter()
            .map(|&f| f64::from(f))
            .sum()
    }
    /// Whether the fully occluded links are known (see [`Links::hidden_row`]).
    pub fn hidden_known(&self) -> bool {
        self.hidden_row.len() == self.row.len()
    }
}

/// The refinement oracle: split a source node while `F × bhat[node] > eps` (or, above the patch
/// level, while it exceeds `far_field × eps`).
#[derive(Clone, Copy, Debug)]
pub struct Oracle<'a> {
    /// A-priori radiosity estimate per node (max channel).
    pub bhat: &'a [f64],
    /// Threshold on `F × B̂`.
    pub eps: f64,
}

/// The rows of a range of receivers, before they are joined.
#[derive(Default)]
struct Chunk {
    /// Links per receiver that carry light, and fully occluded ones.
    counts: Vec<(u32, u32)>,
    src: Vec<u32>,
    ff: Vec<f32>,
    hidden: Vec<u32>,
}

impl Chunk {
    /// Ends a receiver's row: `values` by source, in order; zero ones are kept apart.
    fn push_row(&mut self, values: impl Iterator<Item = (u32, f32)>) {
        let (s0, h0) = (self.src.len(), self.hidden.len());
        for (s, f) in values {
            if f > 0.0 {
                self.src.push(s);
                self.ff.push(f);
            } else {
                self.hidden.push(s);
            }
        }
        self.counts.push((
            (self.src.len() - s0) as u32,
            (self.hidden.len() - h0) as u32,
        ));
    }
}

/// Receivers per parallel task.
const CHUNK: usize = 64;

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
    let chunks: Vec<Chunk> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let (lo, hi) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
            let mut chunk = Chunk::default();
            let mut stack = Vec::new();
            let mut row = Walked::default();
            let mut out = Vec::new();
            for leaf in lo..hi {
                row.clear();
                refine(
                    mesh,
                    leaf as u32,
                    &mesh.roots,
                    oracle,
                    params,
                    &mut stack,
                    &mut row,
                );
                out.clear();
                out.resize(row.src.len(), 0.0f32);
                method.compute(ctx, &row.as_row(leaf as u32), &mut out);
                chunk.push_row(row.src.iter().copied().zip(out.iter().copied()));
            }
            let d = done.fetch_add(hi - lo, Ordering::Relaxed) + (hi - lo);
            progress(d);
            chunk
        })
        .collect();
    assemble(n, chunks)
}

/// Concatenates per-chunk rows into links.
fn assemble(n: usize, chunks: Vec<Chunk>) -> Links {
    let total: usize = chunks.iter().map(|c| c.src.len()).sum();
    let hidden: usize = chunks.iter().map(|c| c.hidden.len()).sum();
    let mut links = Links {
        row: Vec::with_capacity(n + 1),
        src: Vec::with_capacity(total),
        ff: Vec::with_capacity(total),
        hidden_row: Vec::with_capacity(n + 1),
        hidden_src: Vec::with_capacity(hidden),
    };
    links.row.push(0);
    links.hidden_row.push(0);
    for c in chunks {
        let (mut at, mut hat) = (links.src.len(), links.hidden_src.len());
        for (k, h) in c.counts {
            at += k as usize;
            hat += h as usize;
            links.row.push(at);
            links.hidden_row.push(hat);
        }
        links.src.extend(c.src);
        links.ff.extend(c.ff);
        links.hidden_src.extend(c.hidden);
    }
    links
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

/// One receiver's refined row: source nodes (in order of their first leaf), their unoccluded
/// form factors and visibility sample counts.
#[derive(Default)]
struct Walked {
    src: Vec<u32>,
    f: Vec<f64>,
    samples: Vec<u8>,
}

impl Walked {
    fn clear(&mut self) {
        self.src.clear();
        self.f.clear();
        self.samples.clear();
    }
    fn push(&mut self, s: u32, f: f64, samples: u8) {
        self.src.push(s);
        self.f.push(f);
        self.samples.push(samples);
    }
    fn as_row(&self, leaf: u32) -> Row<'_> {
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
fn refine(
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
        let (mn, mx) = extent(t, axis);
        mx >= c - r && mn <= c + r
    };
    let box_axes = [DVec3::X, DVec3::Y, DVec3::Z];
    if !box_axes.iter().all(|&a| overlaps(a)) {
        return false;
    }
    if !TET_FACES.iter().all(|f| overlaps(face_normal(t, f))) {
        return false;
    }
    for e in TET_EDGES {
        let d = t[e[1]] - t[e[0]];
        for a in box_axes {
            if !overlaps(d.cross(a)) {
                return false;
            }
        }
    }
    true
}

const TET_FACES: [[usize; 3]; 4] = [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]];
const TET_EDGES: [[usize; 2]; 6] = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];

fn face_normal(t: &[DVec3; 4], f: &[usize; 3]) -> DVec3 {
    (t[f[1]] - t[f[0]]).cross(t[f[2]] - t[f[0]])
}

/// The interval of `points` projected on `axis`.
#[inline]
fn extent(points: &[DVec3], axis: DVec3) -> (f64, f64) {
    points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(mn, mx), p| {
            let d = p.dot(axis);
            (mn.min(d), mx.max(d))
        })
}

/// A triangle seen from a point: its vertices relative to the point, the unit normals of the
/// planes through the point and each edge (towards the triangle; zero when seen edge-on), its
/// own plane (unit normal, pointing away from the point, and offset), its bounding radius and a
/// lower bound on its distance from the point.
#[derive(Clone, Copy, Debug)]
pub struct Pyramid {
    v: [DVec3; 3],
    edge: [DVec3; 3],
    normal: DVec3,
    offset: f64,
    radius: f64,
    near: f64,
}

impl Pyramid {
    /// Triangle `tri` seen from `x`.
    pub fn new(x: DVec3, tri: &[DVec3; 3]) -> Pyramid {
        let v = [tri[0] - x, tri[1] - x, tri[2] - x];
        // The unit normal of `a × b`, none when the two are (nearly) parallel: rounding would
        // give it an arbitrary direction.
        let unit = |a: DVec3, b: DVec3| {
            let n = a.cross(b);
            let l2 = n.length_squared();
            if l2 > 1e-24 * a.length_squared() * b.length_squared() && l2.is_finite() {
                n / l2.sqrt()
            } else {
                DVec3::ZERO
            }
        };
        let edge = std::array::from_fn(|k| {
            let (a, b, c) = (v[k], v[(k + 1) % 3], v[(k + 2) % 3]);
            let n = unit(a, b);
            // Towards the third vertex; none when the point is in the triangle's plane.
            let side = n.dot(c);
            if side > 0.0 {
                n
            } else if side < 0.0 {
                -n
            } else {
                DVec3::ZERO
            }
        });
        let mut normal = unit(v[1] - v[0], v[2] - v[0]);
        let mut offset = normal.dot(v[0]);
        // The point (the origin) on the negative side; in the plane: no depth test.
        if offset < 0.0 {
            normal = -normal;
            offset = -offset;
        } else if offset == 0.0 || !offset.is_finite() {
            normal = DVec3::ZERO;
            offset = 0.0;
        }
        let centre = (v[0] + v[1] + v[2]) / 3.0;
        let radius = v.iter().map(|p| p.distance(centre)).fold(0.0, f64::max);
        Pyramid {
            v,
            edge,
            normal,
            offset,
            radius,
            near: (centre.length() - radius).max(0.0),
        }
    }

    /// Whether rays from the point to `self` (the source) may cross `other`: false only when a
    /// plane separates them with room to spare. Seen from the point, two triangles overlap
    /// unless an edge plane of one separates them; and a ray crosses `other` only if the
    /// source is not wholly in front of `other`'s plane and `other` not wholly beyond the
    /// source's. `margin` is how far the rays may stray from the exact shaft (their origin's
    /// offset and rounding); a ray caster also sees `other` a little past its edges
    /// ([`Pyramid::slack`]). Both must be seen from the same point.
    pub fn shaft_may_cross(&self, other: &Pyramid, margin: f64) -> bool {
        !(other.keeps_clear_of(&self.v, margin) || self.shaft_clears(other, margin))
    }

    /// How far past this triangle a ray may still hit it: `margin`, and the ray caster's
    /// watertight slack of 1e-6 of the triangle's heights (`radiant_visibility`), doubled.
    fn slack(&self, margin: f64) -> f64 {
        margin + 2e-6 * 2.0 * self.radius
    }

    /// Whether this (changed) triangle's edge planes keep rays from the point to the triangle
    /// `src` (vertices relative to the point) clear of it, or `src` lies wholly in front of it.
    /// Needs nothing of `src` but its vertices. An edge plane passes through the point, so a
    /// source vertex `d` below it is only `d × near / far` below it where the rays pass this
    /// triangle: the room asked for is scaled up by that ratio.
    fn keeps_clear_of(&self, src: &[DVec3; 3], margin: f64) -> bool {
        let slack = self.slack(margin);
        let far = src.iter().map(|p| p.length()).fold(0.0, f64::max);
        let edges = self.near > 0.0
            && far.is_finite()
            && self
                .edge
                .iter()
                .any(|&n| below(n, 0.0, src, slack * far / self.near));
        edges || (self.offset > margin && below(self.normal, self.offset, src, margin))
    }

    /// Whether this (source) triangle's edge planes keep `other` clear of the rays to it, or
    /// `other` lies wholly beyond it.
    fn shaft_clears(&self, other: &Pyramid, margin: f64) -> bool {
        let slack = other.slack(margin);
        self.edge.iter().any(|&n| below(n, 0.0, &other.v, slack))
            || (self.normal != DVec3::ZERO
                && other
                    .v
                    .iter()
                    .all(|p| self.normal.dot(*p) - self.offset > slack))
    }
}

/// Whether all of `q` lies below the plane `n·p = d` by more than `pad` (never for a zero `n`).
#[inline]
fn below(n: DVec3, d: f64, q: &[DVec3; 3], pad: f64) -> bool {
    n != DVec3::ZERO && q.iter().all(|p| n.dot(*p) - d < -pad)
}

/// The triangles an edit took away or put in (local frame): the shafts they may cut. They are
/// kept in at most 64 groups (one triangle each when there are that few), so that a shaft's
/// answer is a bit mask and a child's shaft is tested only against the groups its parent's met.
pub struct ChangeSet {
    groups: Vec<Group>,
    count: usize,
    /// How far the rays of a link may stray from its exact shaft.
    margin: f64,
}

/// Consecutive changed triangles (from `first` in the set) and their padded bounds.
struct Group {
    lo: DVec3,
    hi: DVec3,
    first: usize,
    triangles: Vec<([DVec3; 3], DVec3, DVec3)>,
}

/// Changed triangles seen from a receiver (stamped with it), computed when first needed.
#[derive(Default)]
pub struct SeenFrom {
    seen: Vec<(u32, Pyramid)>,
}

impl ChangeSet {
    /// Past the `f32` rounding of the visibility rays' ends (the local frame has unit extent).
    pub const ROUNDING: f64 = 1e-6;

    /// The change made of `triangles`, for rays that stray at most `margin` from the exact
    /// shaft between a receiver's centroid and a source (at least [`ChangeSet::ROUNDING`]).
    pub fn new(triangles: &[[DVec3; 3]], margin: f64) -> ChangeSet {
        let margin = margin.max(Self::ROUNDING);
        let per_group = triangles.len().div_ceil(64).max(1);
        let groups = triangles
            .chunks(per_group)
            .enumerate()
            .map(|(g, chunk)| {
                let triangles: Vec<_> = chunk
                    .iter()
                    .map(|v| {
                        // Padded by the most a ray may stray and the ray caster's slack.
                        let size = (v[1] - v[0]).length() + (v[2] - v[0]).length();
                        let pad = DVec3::splat(margin + 4e-6 * size);
                        (
                            *v,
                            v[0].min(v[1]).min(v[2]) - pad,
                            v[0].max(v[1]).max(v[2]) + pad,
                        )
                    })
                    .collect();
                let lo = triangles.iter().fold(DVec3::INFINITY, |a, t| a.min(t.1));
                let hi = triangles
                    .iter()
                    .fold(DVec3::NEG_INFINITY, |a, t| a.max(t.2));
                Group {
                    lo,
                    hi,
                    first: g * per_group,
                    triangles,
                }
            })
            .collect();
        ChangeSet {
            groups,
            count: triangles.len(),
            margin,
        }
    }

    /// Whether nothing changed.
    pub fn is_empty(&self) -> bool {
        self.groups.is_empty()
    }

    /// Every group's bit.
    pub fn all(&self) -> u64 {
        if self.groups.len() >= 64 {
            u64::MAX
        } else {
            (1u64 << self.groups.len()) - 1
        }
    }

    /// The groups among `within` whose triangles the shaft from receiver `leaf`'s point `x` to
    /// the triangle `tri` may cross (with `first_only`, at most the first such group).
    pub fn meets(
        &self,
        leaf: u32,
        x: DVec3,
        tri: &[DVec3; 3],
        within: u64,
        first_only: bool,
        cache: &mut SeenFrom,
    ) -> u64 {
        if cache.seen.len() != self.count {
            // Entries are stamped with their receiver: stale ones are recomputed.
            cache.seen.clear();
            cache.seen.resize(
                self.count,
                (u32::MAX, Pyramid::new(DVec3::ZERO, &[DVec3::X; 3])),
            );
        }
        let t = [x, tri[0], tri[1], tri[2]];
        let (tlo, thi) = (
            t[0].min(t[1]).min(t[2].min(t[3])),
            t[0].max(t[1]).max(t[2].max(t[3])),
        );
        let overlap = |lo: DVec3, hi: DVec3| tlo.cmple(hi).all() && lo.cmple(thi).all();
        let rel = [tri[0] - x, tri[1] - x, tri[2] - x];
        let mut source = None;
        let mut hit = 0;
        let mut rest = within;
        while rest != 0 {
            let k = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            let Some(g) = self.groups.get(k) else {
                break;
            };
            if !overlap(g.lo, g.hi) || (g.triangles.len() > 1 && !shaft_hits_box(&t, g.lo, g.hi)) {
                continue;
            }
            for (j, (other, lo, hi)) in g.triangles.iter().enumerate() {
                if !overlap(*lo, *hi) {
                    continue;
                }
                let slot = &mut cache.seen[g.first + j];
                if slot.0 != leaf {
                    *slot = (leaf, Pyramid::new(x, other));
                }
                // The changed triangle's own planes first: they need nothing of the source but
                // its vertices (and usually settle it).
                if slot.1.keeps_clear_of(&rel, self.margin) {
                    continue;
                }
                let src = source.get_or_insert_with(|| Pyramid::new(x, tri));
                if !src.shaft_clears(&slot.1, self.margin) {
                    hit |= 1 << k;
                    break;
                }
            }
            if first_only && hit != 0 {
                break;
            }
        }
        hit
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
/// triangle that went or came. The result equals a fresh [`build`] with `oracle`.
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
        generation: UPDATES.fetch_add(1, Ordering::Relaxed) + 1,
    };
    let chunks: Vec<(Chunk, UpdateStats)> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map_init(UpdateScratch::default, |scratch, c| {
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
        })
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
    /// This update's number, for the shaft memo's stamps.
    generation: u64,
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
            generation,
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
            NODE_MEMO.with_borrow_mut(|memo| {
                if memo.len() < mesh.nodes.len() {
                    memo.resize(mesh.nodes.len(), (0, 0));
                }
                let mut q = ShaftQuery {
                    mesh,
                    change: change.triangles,
                    x: r.centroid,
                    leaf: leaf as u32,
                    stamp: (generation << 32) | leaf as u64,
                    memo,
                    seen,
                };
                for c in cands.iter_mut().filter(|c| !c.need) {
                    c.need = q.link_meets(c.src);
                }
            });
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

/// Per-thread scratch of [`update`].
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
}

thread_local! {
    /// Per node: the stamp (update number and receiver) it was last tested for, and the change
    /// groups its shaft may cross. Per thread and kept across updates, so it is allocated once,
    /// not for every parallel job.
    static NODE_MEMO: std::cell::RefCell<Vec<(u64, u64)>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Numbers the updates, for [`NODE_MEMO`]'s stamps.
static UPDATES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

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

#[cfg(test)]
mod shaft_tests {
    use super::*;
    use crate::rng::Rng;

    /// Whether the segment `a`–`b` crosses the triangle `t` (Möller–Trumbore, in f64).
    fn segment_hits(a: DVec3, b: DVec3, t: &[DVec3; 3]) -> bool {
        let d = b - a;
        let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-14 {
            return false;
        }
        let s = a - t[0];
        let u = s.dot(p) / det;
        let q = s.cross(e1);
        let v = d.dot(q) / det;
        let w = e2.dot(q) / det;
        u >= 0.0 && v >= 0.0 && u + v <= 1.0 && (0.0..=1.0).contains(&w)
    }

    fn point(rng: &mut Rng) -> DVec3 {
        DVec3::new(rng.f64(), rng.f64(), rng.f64())
    }

    #[test]
    fn a_shaft_that_crosses_a_triangle_is_never_culled() {
        let mut rng = Rng::new(11);
        let (mut crossing, mut culled) = (0, 0);
        for _ in 0..20_000 {
            let x = point(&mut rng);
            let src = [point(&mut rng), point(&mut rng), point(&mut rng)];
            let other = [point(&mut rng), point(&mut rng), point(&mut rng)];
            let may = Pyramid::new(x, &src).shaft_may_cross(&Pyramid::new(x, &other), 0.0);
            let set = ChangeSet::new(&[other], 0.0);
            let met = set.meets(0, x, &src, set.all(), false, &mut SeenFrom::default()) != 0;
            // Segments from the point to points of the source.
            let hits = (0..64).any(|_| {
                let (r1, r2) = (rng.f64(), rng.f64());
                let p = crate::form_factors::sample_triangle(&src, r1, r2);
                segment_hits(x, p, &other)
            });
            if hits {
                crossing += 1;
                assert!(
                    may && met,
                    "a crossing shaft was culled: {x} {src:?} {other:?}"
                );
            } else if !may {
                culled += 1;
            }
        }
        // The test means something: both cases occur, and most shafts that miss are culled.
        assert!(crossing > 1000 && culled > 5000, "{crossing} {culled}");
    }

    #[test]
    fn a_shaft_beside_or_in_front_of_a_triangle_is_culled() {
        let x = DVec3::ZERO;
        let src = [
            DVec3::new(-1.0, -1.0, 10.0),
            DVec3::new(1.0, -1.0, 10.0),
            DVec3::new(0.0, 1.0, 10.0),
        ];
        let s = Pyramid::new(x, &src);
        let on_axis = [
            DVec3::new(-0.1, -0.1, 5.0),
            DVec3::new(0.1, -0.1, 5.0),
            DVec3::new(0.0, 0.1, 5.0),
        ];
        assert!(s.shaft_may_cross(&Pyramid::new(x, &on_axis), 1e-6));
        let beside = on_axis.map(|p| p + DVec3::new(3.0, 0.0, 0.0));
        assert!(!s.shaft_may_cross(&Pyramid::new(x, &beside), 1e-6));
        let behind = on_axis.map(|p| p + DVec3::new(0.0, 0.0, 10.0));
        assert!(!s.shaft_may_cross(&Pyramid::new(x, &behind), 1e-6));
    }

    /// A source edge that grazes a changed triangle seen from close by: the ray caster's
    /// slack past the triangle's edges must keep this shaft (it once did not).
    #[test]
    fn a_grazing_shaft_near_the_receiver_is_kept() {
        let x = DVec3::ZERO;
        let changed = [
            DVec3::new(0.01, -0.05, 0.0),
            DVec3::new(0.01, 0.05, 0.0),
            DVec3::new(0.01, 0.0, -0.1),
        ];
        let src = [
            DVec3::new(0.5, -0.1, 2e-6),
            DVec3::new(0.5, 0.1, 2e-6),
            DVec3::new(0.5, 0.0, 0.1),
        ];
        let set = ChangeSet::new(&[changed], 0.0);
        assert_ne!(
            set.meets(0, x, &src, set.all(), false, &mut SeenFrom::default()),
            0
        );
        // Farther off, with room to spare, the same shaft is culled.
        let lifted = src.map(|p| p + DVec3::new(0.0, 0.0, 0.01));
        assert_eq!(
            set.meets(1, x, &lifted, set.all(), false, &mut SeenFrom::default()),
            0
        );
    }

    #[test]
    fn many_changed_triangles_are_grouped_and_still_found() {
        // 200 small triangles along a line: more than one per group.
        let tris: Vec<[DVec3; 3]> = (0..200)
            .map(|k| {
                let c = DVec3::new(k as f64 * 0.01, 0.5, 0.5);
                [
                    c,
                    c + DVec3::new(0.004, 0.0, 0.0),
                    c + DVec3::new(0.0, 0.004, 0.0),
                ]
            })
            .collect();
        let set = ChangeSet::new(&tris, 0.0);
        assert_eq!(set.all().count_ones(), 50); // four triangles a group
        let mut seen = SeenFrom::default();
        // A shaft through the 150th triangle's interior, and one far from all of them.
        let target = tris[150][0] + DVec3::new(0.001, 0.001, 0.0);
        let x = target - DVec3::new(0.0, 0.0, 0.4);
        let far = target + DVec3::new(0.0, 0.0, 0.4);
        let src = [
            far,
            far + DVec3::new(0.001, 0.0, 0.0),
            far + DVec3::new(0.0, 0.001, 0.0),
        ];
        assert_ne!(set.meets(1, x, &src, set.all(), false, &mut seen), 0);
        let away = src.map(|p| p + DVec3::new(0.0, 5.0, 0.0));
        assert_eq!(set.meets(1, x, &away, set.all(), false, &mut seen), 0);
    }

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
