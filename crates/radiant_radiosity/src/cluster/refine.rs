//! Link refinement from the root's link to itself (Hanrahan, Salzman & Aupperle 1991, with the
//! clusters of Smits, Arvo & Greenberg 1994): a link `r ← s` is kept when the radiosity it can
//! bring to `r`, `ρ_r · B̂_s · A_s / (π d²)`, is at most the threshold and the two nodes' bounding
//! spheres are apart; otherwise the larger node is split. Links join nodes at any level on both
//! ends; a node's self-link becomes its children's links among themselves.
//!
//! Form factors: between two triangles (mesh nodes), Lambert's contour integral from the
//! receiver's centroid (or the ray-cast disc sum) times the fraction of clear segments between
//! stratified points on both; with a cluster on either end, the area-averaged form factor is
//! estimated by Monte Carlo over point pairs sampled by area on both nodes, which also samples
//! the visibility through and inside the clusters. Every random choice is seeded by the two
//! nodes' stable ids, so links do not depend on the thread count.

use std::f64::consts::PI;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};

use glam::DVec3;
use radiant_visibility::Visibility;
use rayon::prelude::*;

use super::edit::Before;
use super::record::{Extent, Op, Piece, Pos, Record, Top as Part};
use super::tree::Tree;
use crate::form_factors::{FormFactorKind, analytic::point_to_triangle, sample_triangle};
use crate::mesh::Mesh;
use crate::rng::{Rng, hash};

/// One link: `recv` gathers `ff × B̄(src)`.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Zeroable)]
pub struct Link {
    /// Receiver node.
    pub recv: u32,
    /// Source node.
    pub src: u32,
    /// Form factor (area-averaged over the receiver).
    pub ff: f32,
}

/// What refinement does with one pair.
enum Step {
    /// Nothing flows (facing away, coplanar).
    Cull,
    /// Link them; the estimate of what the link carries, relative to the threshold.
    Link(f64),
    /// Refine these pairs instead (the split recorded as `Op`).
    Split(Op, [(u32, u32); 4], usize),
}

/// Where a pair stands in the refinement an edit keeps ([`Before`]).
#[derive(Clone, Copy, Debug)]
pub(crate) enum Cursor {
    /// The old refinement visited the pair (old node ids) at `pos` of its record: the same
    /// nodes, or for nodes that changed, the old nodes in their place in the tree.
    At {
        /// The pair's op in the old record.
        pos: Pos,
        /// Old receiver.
        r: u32,
        /// Old source.
        s: u32,
    },
    /// Not known yet: looked up when both nodes are old ones.
    Unknown,
    /// Not visited, but the old refinement visited the pair `(r, s)` at `pos`, which holds
    /// this one, and split one of this pair's own nodes there: a pair below may still have been
    /// visited, and is looked up from there.
    Near {
        /// The holding pair's op in the old record.
        pos: Pos,
        /// Old receiver.
        r: u32,
        /// Old source.
        s: u32,
    },
    /// The old refinement stopped above the pair (linked or culled a pair holding it), so it
    /// visited nothing below it either.
    Above,
}

/// What to do with a pair.
enum Visit {
    /// Copy the old record's subtree `[from, to)`.
    Copy(Pos, Pos),
    Cull,
    /// Link, with the old form factor when it holds (0 for a hidden link).
    Link(f64, Option<f32>),
    Split(Op, [(u32, u32); 4], usize, [Cursor; 4]),
}

/// A link with a cluster on one end is also held to a bound: what it could carry with its
/// nodes as close as their bounding spheres allow, `ρ_r B̂_s A_s / (π gap²)` (the kernel
/// `cos·cos / (π d²)` is at most `1 / (π gap²)`), may not pass this many times the threshold.
/// It replaces a rule that split every pair whose spheres were within twice their radii,
/// whatever the pair could carry: on Sponza that rule, not the threshold, decided the links
/// (31.6 M, 56 s of form factors; 18.3 M and 33 s with the bound, and the same error against
/// the path tracer, 4.6 % mean). At 4 times the threshold it made 15 M links, but the
/// tessellated furnace's rows summed to 1.002 instead of 1.000: near cluster links are Monte
/// Carlo estimates.
const NEAR_BOUND: f64 = 1.0;

/// Refinement of one bake's links.
pub(crate) struct Refiner<'a> {
    pub mesh: &'a Mesh,
    pub tree: &'a Tree,
    pub vis: &'a dyn Visibility,
    /// Per node: radiosity estimate relative to the ambient level (mesh nodes: the largest in
    /// the subtree; clusters: the area-weighted mean, so `B̂ A` is the cluster's power).
    pub bhat: &'a [f64],
    /// Per node: the largest reflectance in it.
    pub rho: &'a [f64],
    /// Threshold on `ρ B̂ F`, relative to the ambient level.
    pub eps: f64,
    /// Form factors between triangles.
    pub kind: FormFactorKind,
    /// Visibility samples (point pairs) per link; links above the threshold that could not be
    /// split get [`ABOVE`] times as many.
    pub samples: u32,
    pub seed: u64,
    /// Stop (and report [`Refiner::build`]'s `None`) past this many links.
    pub max_links: u64,
    /// Set from outside to stop early ([`Refiner::build`] then returns `None` too).
    pub stop: Option<&'a AtomicBool>,
    /// The refinement before a geometry edit: what it refined for pairs the edit did not
    /// touch is copied, not refined again.
    pub before: Option<&'a Before<'a>>,
    /// Keep the whole record (for geometry edits), not the links alone.
    pub keep: bool,
    /// Take the form factors from these links instead of computing them (a resumed bake's
    /// refinement made again, for its record).
    pub replay: Option<&'a Replay>,
}

/// A bake's links by receiver, each row sorted by source, for [`Refiner::replay`]: a link the
/// refinement makes takes its form factor from here, and one not here was wholly hidden.
pub(crate) struct Replay {
    row: Vec<u64>,
    links: Vec<(u32, f32)>,
    found: AtomicU64,
}

impl Replay {
    /// From rows by receiver node.
    pub fn new(row: &[u64], src: &[u32], ff: &[f32]) -> Replay {
        let mut links: Vec<(u32, f32)> = src.iter().copied().zip(ff.iter().copied()).collect();
        let mut rows = Vec::with_capacity(row.len());
        let mut rest = &mut links[..];
        for w in row.windows(2) {
            let (a, b) = std::mem::take(&mut rest).split_at_mut((w[1] - w[0]) as usize);
            rows.push(a);
            rest = b;
        }
        rows.into_par_iter()
            .for_each(|r| r.sort_unstable_by_key(|&(s, _)| s));
        Replay {
            row: row.to_vec(),
            links,
            found: AtomicU64::new(0),
        }
    }

    /// The form factor of `r ← s`, `None` when it is not a link (the caller counts the ones
    /// found, into [`Replay::met`]).
    pub fn get(&self, r: u32, s: u32) -> Option<f32> {
        let (Some(&a), Some(&b)) = (self.row.get(r as usize), self.row.get(r as usize + 1)) else {
            return None;
        };
        let row = &self.links[a as usize..b as usize];
        let k = row.binary_search_by_key(&s, |&(x, _)| x).ok()?;
        Some(row[k].1)
    }

    /// Counts `n` links found.
    pub fn met(&self, n: u64) {
        self.found.fetch_add(n, Ordering::Relaxed);
    }

    /// Whether every link was met (once each, as a refinement meets a pair): then the
    /// refinement made again is the one that made them.
    pub fn all_met(&self) -> bool {
        self.found.load(Ordering::Relaxed) == self.links.len() as u64
    }
}

/// A refinement made in parts, not yet put together: the splits above the parts, and the
/// parts with the stretches of the record before an edit that they keep. Its size is known
/// before any of its memory is taken ([`Walk::extent`]).
pub(crate) struct Walk {
    top: Vec<Part>,
    pieces: Vec<Piece>,
    links_only: bool,
    extent: Extent,
}

impl Walk {
    /// The size of the record it makes.
    pub fn extent(&self) -> Extent {
        self.extent
    }

    /// Put together into fresh memory, the stretches copied from `old` (the record before an
    /// edit) with their links mapped; `None` when the memory cannot be had, or stretches are
    /// held without `old`.
    pub fn assemble(
        &self,
        old: Option<(&Record, &(dyn Fn(Link) -> Link + Sync))>,
    ) -> Option<Record> {
        Record::assemble(&self.top, &self.pieces, self.links_only, old)
    }

    /// Put together in the memory of `old`, the record before an edit, which becomes this
    /// record ([`Record::assemble_over`]); `false`, with `old` as it was, when that cannot be
    /// done (then [`Walk::assemble`]).
    pub fn assemble_over(&self, old: &mut Record, remap: &(dyn Fn(Link) -> Link + Sync)) -> bool {
        !self.links_only && Record::assemble_over(&self.top, &self.pieces, old, remap)
    }
}

/// How much of a refinement was computed, and how much kept from the one before an edit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RefineStats {
    /// Links whose form factor was computed (hidden ones too).
    pub computed: u64,
    /// Links kept from before the edit (hidden ones not counted).
    pub kept: u64,
}

/// Counters shared by the parallel parts of one refinement.
struct Shared {
    count: AtomicU64,
    computed: AtomicU64,
    kept: AtomicU64,
    abort: AtomicBool,
}

/// The smallest mean cosine a cluster is credited with towards a source, against dividing by
/// nearly nothing where its triangles barely face it.
pub const KAPPA_MIN: f64 = 0.02;

/// Mean of `max(0, n·ω)` over receiver cluster `r`'s triangles, `ω` towards `s`.
pub fn receiver_kappa(tree: &Tree, r: u32, s: u32) -> f64 {
    let d = (tree.center[s as usize] - tree.center[r as usize]).normalize_or_zero();
    let c = (r - tree.mesh_nodes) as usize;
    super::sh::dot(&tree.normal_sh[c], &super::sh::cosine(d)).max(KAPPA_MIN)
}

/// Links above the threshold that could not be split take this many times the visibility
/// samples. Mostly neighbouring elements at a corner; at four times they cast half of Sponza's
/// rays, at twice the error against the path tracer is the same (4.6 %, −4.3 % bias both).
const ABOVE: u32 = 2;

/// Pairs the parallel refinement starts from, at least.
const FRONTIER: usize = 4096;

impl Refiner<'_> {
    /// All links from the root's self-link as a [`Record`], depth first (so the same for any
    /// number of threads, and for an edit as for a fresh refinement), or `None` when there
    /// would be more than `max_links` or it was stopped. `progress(done, total)` is called as
    /// parts finish.
    pub fn build(&self, progress: &(dyn Fn(usize, usize) + Sync)) -> Option<(Record, RefineStats)> {
        let (walk, stats) = self.walk(progress)?;
        let remap = |l: Link| self.before.map_or(l, |b| b.remap(l));
        let old = self
            .before
            .map(|b| (b.old.record, &remap as &(dyn Fn(Link) -> Link + Sync)));
        Some((walk.assemble(old)?, stats))
    }

    /// [`Refiner::build`] without putting its parts together: see [`Walk`].
    pub fn walk(&self, progress: &(dyn Fn(usize, usize) + Sync)) -> Option<(Walk, RefineStats)> {
        let root = self.tree.root(self.mesh);
        // The top of the recursion, breadth first into at least FRONTIER pieces of work; each
        // level's splits name their children's place in the next level. In an edit, a pair the
        // old refinement visited goes to the parallel part at once (it is mostly copied), and
        // the rest, around what moved, is spread out.
        let mut levels: Vec<Vec<Top>> = vec![vec![Top::Work(usize::MAX)]];
        let start = self.before.map_or(Cursor::Unknown, |b| b.root_cursor());
        let mut frontier = vec![(root, root, start, 0, Sight::UNKNOWN)];
        let mut work: Vec<Work> = Vec::new();
        while !frontier.is_empty() && frontier.len() < FRONTIER {
            let l = levels.len() - 1;
            let mut level = Vec::with_capacity(frontier.len() * 4);
            let mut next = Vec::with_capacity(frontier.len() * 4);
            for &(r, s, cur, slot, sight) in &frontier {
                levels[l][slot] = match self.visit(r, s, cur) {
                    Visit::Split(op, pairs, n, cursors) => {
                        let first = level.len();
                        let sight = self.look(r, s, sight);
                        for k in 0..n {
                            let (r, s) = pairs[k];
                            if self.before.is_some_and(|b| b.same_pair(r, s, cursors[k])) {
                                level.push(Top::Work(work.len()));
                                work.push(Work::Refine(r, s, cursors[k], sight));
                            } else {
                                next.push((r, s, cursors[k], level.len(), sight));
                                level.push(Top::Work(usize::MAX));
                            }
                        }
                        Top::Split(op, first, n)
                    }
                    v => {
                        work.push(Work::Done(r, s, v, sight));
                        Top::Work(work.len() - 1)
                    }
                };
            }
            levels.push(level);
            frontier = next;
        }
        if let Some(last) = levels.last_mut() {
            for &(r, s, cur, slot, sight) in &frontier {
                last[slot] = Top::Work(work.len());
                work.push(Work::Refine(r, s, cur, sight));
            }
        }
        let shared = Shared {
            count: AtomicU64::new(0),
            computed: AtomicU64::new(0),
            kept: AtomicU64::new(0),
            abort: AtomicBool::new(false),
        };
        let done = AtomicUsize::new(0);
        let total = work.len();
        let chunk = (total / (rayon::current_num_threads() * 16)).clamp(1, 64);
        let chunks: Vec<Vec<Piece>> = work
            .par_chunks(chunk)
            .map(|items| {
                let out: Vec<Piece> = items
                    .iter()
                    .map(|w| {
                        let mut rec = self.empty();
                        if !shared.abort.load(Ordering::Relaxed) {
                            self.run(w, &mut rec, &shared);
                        }
                        rec
                    })
                    .collect();
                let d = done.fetch_add(items.len(), Ordering::Relaxed) + items.len();
                progress(d, total);
                out
            })
            .collect();
        let pieces: Vec<Piece> = chunks.into_iter().flatten().collect();
        if shared.abort.load(Ordering::Relaxed) {
            return None;
        }
        let mut top = Vec::with_capacity(levels.iter().map(Vec::len).sum::<usize>() * 2);
        depth_first(&levels, 0, 0, &mut top);
        let stats = RefineStats {
            computed: shared.computed.load(Ordering::Relaxed),
            kept: shared.kept.load(Ordering::Relaxed),
        };
        let extent = Record::extent_of(&top, &pieces, !self.keep)?;
        Some((
            Walk {
                top,
                pieces,
                links_only: !self.keep,
                extent,
            },
            stats,
        ))
    }

    /// An empty piece: whole, or the links alone.
    fn empty(&self) -> Piece {
        Piece::new(if self.keep {
            Record::default()
        } else {
            Record::links_only()
        })
    }

    /// One piece of work into `out`.
    fn run(&self, w: &Work, out: &mut Piece, shared: &Shared) {
        match *w {
            Work::Refine(r, s, cur, sight) => {
                let mut pass = Pass::default();
                self.refine((r, s, sight), cur, out, shared, &mut pass);
                self.count(&mut pass, shared);
            }
            Work::Done(r, s, ref v, sight) => {
                let mut pass = Pass::default();
                self.emit((r, s, sight), v, out, &mut pass);
                self.count(&mut pass, shared);
            }
        }
    }

    /// Counts the pass's links against the budget and the stop flag, and hands its counters
    /// to the shared ones (once in a while, not per link: the two threads' atomic adds to one
    /// cache line took 7 % of the Cornell box's refinement); false once the refinement must
    /// stop.
    fn count(&self, pass: &mut Pass, shared: &Shared) -> bool {
        let links = std::mem::take(&mut pass.since);
        let (computed, kept) = (
            std::mem::take(&mut pass.computed),
            std::mem::take(&mut pass.kept),
        );
        if computed > 0 {
            shared.computed.fetch_add(computed, Ordering::Relaxed);
        }
        if kept > 0 {
            shared.kept.fetch_add(kept, Ordering::Relaxed);
        }
        if let Some(replay) = self.replay {
            replay.met(std::mem::take(&mut pass.found));
        }
        let c = shared.count.fetch_add(links, Ordering::Relaxed) + links;
        if c > self.max_links || self.stop.is_some_and(|f| f.load(Ordering::Relaxed)) {
            shared.abort.store(true, Ordering::Relaxed);
        }
        !shared.abort.load(Ordering::Relaxed)
    }

    /// Refines `r ← s` depth first into `out`; false once the refinement must stop. `sight`:
    /// what the pairs holding it found between them.
    fn refine(
        &self,
        (r, s, sight): (u32, u32, Sight),
        cur: Cursor,
        out: &mut Piece,
        shared: &Shared,
        pass: &mut Pass,
    ) -> bool {
        match self.visit(r, s, cur) {
            Visit::Split(op, pairs, n, cursors) => {
                let start = out.open_split(op, n);
                let sight = self.look(r, s, sight);
                for k in 0..n {
                    let (r, s) = pairs[k];
                    if !self.refine((r, s, sight), cursors[k], out, shared, pass) {
                        return false;
                    }
                }
                out.close_split(start);
            }
            v => self.emit((r, s, sight), &v, out, pass),
        }
        if pass.since >= 1024 {
            return self.count(pass, shared);
        }
        true
    }

    /// Records a visit that is not a split.
    fn emit(&self, (r, s, sight): (u32, u32, Sight), v: &Visit, out: &mut Piece, pass: &mut Pass) {
        match *v {
            Visit::Copy(from, to) => {
                if self.before.is_none() {
                    return;
                }
                out.copy_from(from, to);
                let links = to.links - from.links;
                pass.kept += links;
                pass.since += links;
            }
            Visit::Cull => out.push(Op::Cull, None),
            Visit::Link(err, reuse) => {
                let f = match reuse {
                    Some(f) => {
                        pass.kept += u64::from(f > 0.0);
                        f
                    }
                    None => match self.replay {
                        Some(links) => links.get(r, s).map_or(0.0, |f| {
                            pass.found += 1;
                            f
                        }),
                        None => {
                            pass.computed += 1;
                            self.form_factor(r, s, err, sight, &mut pass.blocker) as f32
                        }
                    },
                };
                if f > 0.0 {
                    out.push(
                        Op::Link,
                        Some(Link {
                            recv: r,
                            src: s,
                            ff: f,
                        }),
                    );
                    pass.since += 1;
                } else {
                    out.push(Op::Zero, None);
                }
            }
            Visit::Split(..) => {}
        }
    }

    /// What to do with `r ← s`: copy what was refined for it before an edit, or decide.
    fn visit(&self, r: u32, s: u32, cur: Cursor) -> Visit {
        let Some(b) = self.before else {
            return match self.step(r, s) {
                Step::Cull => Visit::Cull,
                Step::Link(e) => Visit::Link(e, None),
                Step::Split(op, p, n) => Visit::Split(op, p, n, [Cursor::Unknown; 4]),
            };
        };
        // An old pair followed by position (through nodes that changed) that is not this
        // pair of old nodes: looked up by what they are.
        let cur = match cur {
            Cursor::At { .. } if !b.positions_agree(r, s, cur) => b.lookup(r, s, Cursor::Unknown),
            Cursor::Unknown | Cursor::Near { .. } => b.lookup(r, s, cur),
            c => c,
        };
        if let Cursor::At { pos, .. } = cur
            && b.settled(r)
            && b.settled(s)
            && b.same_pair(r, s, cur)
            && b.clear_of_changes(self.tree, r, s)
        {
            return Visit::Copy(pos, b.old.record.skip(pos));
        }
        match self.step(r, s) {
            Step::Cull => Visit::Cull,
            Step::Link(e) => Visit::Link(e, self.reuse(b, r, s, e, cur)),
            Step::Split(op, p, n) => Visit::Split(op, p, n, b.child_cursors(op, n, cur)),
        }
    }

    /// The old form factor of a link, when it was linked before the edit, with as many
    /// samples, and nothing that moved can cross it.
    fn reuse(&self, b: &Before<'_>, r: u32, s: u32, err: f64, cur: Cursor) -> Option<f32> {
        let Cursor::At { pos, r: ro, s: so } = cur else {
            return None;
        };
        let op = b.old.record.op(pos);
        if !matches!(op, Op::Link | Op::Zero) || !b.same_pair(r, s, cur) {
            return None;
        }
        let old = carry_err(b.old.mesh, b.old.tree, b.old.rho, b.old.bhat, ro, so) / b.old.eps;
        if self.samples_for(err) != self.samples_for(old) {
            return None;
        }
        // The same nodes and samples: the same point pairs, so the form factor is the old one
        // unless one of its segments may meet what moved. The shaft around both nodes says so
        // at once; where it does not, the link's own segments are drawn again (the rays are
        // not cast) and each is held against what moved.
        if !b.clear_of_changes(self.tree, r, s) {
            let changes = b.segments();
            self.form_factor_with(&changes, (r, s, err), Sight::UNKNOWN, &mut { u32::MAX });
            if changes.met() {
                return None;
            }
        }
        Some(match op {
            Op::Link => b.old.record.link(pos).ff,
            _ => 0.0,
        })
    }

    fn splittable(&self, id: u32) -> bool {
        id >= self.tree.mesh_nodes || !self.mesh.nodes[id as usize].is_leaf()
    }

    /// Children of a node (clusters: 2, triangles: 4).
    fn children(&self, id: u32) -> ([u32; 4], usize) {
        if let Some(c) = self.tree.cluster(id) {
            ([c.children[0], c.children[1], 0, 0], 2)
        } else {
            let f = self.mesh.nodes[id as usize].first_child;
            ([f, f + 1, f + 2, f + 3], 4)
        }
    }

    /// The normal of a cluster whose triangles all share it.
    #[inline]
    fn flat(&self, id: u32) -> Option<DVec3> {
        let c = id.checked_sub(self.tree.mesh_nodes)?;
        let cone = self.tree.cone[c as usize];
        (cone.cos >= 1.0 - 1e-9).then_some(cone.axis)
    }

    /// The least `n·x` over cluster `id`'s box.
    fn lowest(&self, id: u32, n: DVec3) -> f64 {
        let c = self
            .tree
            .cluster(id)
            .map_or((DVec3::ZERO, DVec3::ZERO), |c| (c.lo, c.hi));
        let (mid, half) = ((c.0 + c.1) * 0.5, (c.1 - c.0) * 0.5);
        n.dot(mid) - n.abs().dot(half)
    }

    /// How far any part of node `id` lies in front of the plane through `p0` with normal `n`.
    fn front(&self, id: u32, n: DVec3, p0: DVec3) -> f64 {
        if let Some(c) = self.tree.cluster(id) {
            let (mid, half) = ((c.lo + c.hi) * 0.5, (c.hi - c.lo) * 0.5);
            n.dot(mid - p0) + n.abs().dot(half)
        } else {
            self.mesh.nodes[id as usize]
                .v
                .iter()
                .map(|v| n.dot(*v - p0))
                .fold(f64::NEG_INFINITY, f64::max)
        }
    }

    fn step(&self, r: u32, s: u32) -> Step {
        let m = self.tree.mesh_nodes;
        if r == s {
            return match self.tree.cluster(r) {
                Some(c) => {
                    let [a, b] = c.children;
                    Step::Split(Op::SplitSelf, [(a, a), (a, b), (b, a), (b, b)], 4)
                }
                // A triangle does not see itself.
                None => Step::Cull,
            };
        }
        // Facing away: the source's light goes to its front, the receiver takes it on its front.
        let tol = 1e-12;
        if s < m {
            let n = &self.mesh.nodes[s as usize];
            if r < m && self.mesh.nodes[r as usize].root == n.root {
                return Step::Cull;
            }
            if self.front(r, n.normal, n.v[0]) <= tol {
                return Step::Cull;
            }
        }
        if r < m {
            let n = &self.mesh.nodes[r as usize];
            if self.front(s, n.normal, n.v[0]) <= tol {
                return Step::Cull;
            }
        }
        // The same for a flat cluster (its triangles' normals all one): nothing of the other
        // node in front of its rearmost triangle (a wall's pieces among themselves).
        if let Some(n) = self.flat(s)
            && self.front(r, n, n * self.lowest(s, n)) <= tol
        {
            return Step::Cull;
        }
        if let Some(n) = self.flat(r)
            && self.front(s, n, n * self.lowest(r, n)) <= tol
        {
            return Step::Cull;
        }
        let t = self.tree;
        let (rr, rs) = (t.radius[r as usize], t.radius[s as usize]);
        let d2 = (t.center[r as usize] - t.center[s as usize]).length_squared();
        let gap = d2.sqrt() - (rr + rs);
        // What the link may carry at the centres' distance, relative to the threshold.
        let err = carry_err(self.mesh, t, self.rho, self.bhat, r, s);
        // Spheres apart; between two triangles that is enough, with a cluster on an end its
        // bound at the gap must hold too (without the cosines: with them, more near cluster
        // links passed, and the tessellated furnace's rows strayed 0.25 % from 1).
        let carry = self.rho[r as usize] * self.bhat[s as usize] * t.area[s as usize] / PI;
        let apart = gap > 0.0 && (r < m && s < m || carry / (gap * gap) <= NEAR_BOUND * self.eps);
        let (can_r, can_s) = (self.splittable(r), self.splittable(s));
        if (apart && err <= self.eps) || (!can_r && !can_s) {
            return Step::Link(err / self.eps);
        }
        let mut out = [(0, 0); 4];
        if can_r && (!can_s || rr >= rs) {
            let (c, n) = self.children(r);
            for k in 0..n {
                out[k] = (c[k], s);
            }
            Step::Split(Op::SplitRecv, out, n)
        } else {
            let (c, n) = self.children(s);
            for k in 0..n {
                out[k] = (r, c[k]);
            }
            Step::Split(Op::SplitSrc, out, n)
        }
    }

    /// A number for a node that does not depend on the scene's order of surfaces.
    fn stable_id(&self, id: u32) -> u64 {
        match self.tree.cluster(id) {
            Some(c) => {
                let t = self.tree.order[c.first as usize] as usize;
                hash(self.mesh.root_key[t], u64::from(c.end - c.first), 7)
            }
            None => self.mesh.stable_id(id),
        }
    }

    /// A point on node `id` (by area) and the normal there.
    fn sample(&self, id: u32, u: f64, rng: &mut Rng) -> (DVec3, DVec3) {
        let node = match self.tree.cluster(id) {
            Some(c) => {
                let t = self.tree.pick(c, u);
                &self.mesh.nodes[self.mesh.roots[t as usize] as usize]
            }
            None => &self.mesh.nodes[id as usize],
        };
        let (a, b) = if id >= self.tree.mesh_nodes {
            (rng.f64(), rng.f64())
        } else {
            (u, rng.f64())
        };
        (sample_triangle(&node.v, a, b), node.normal)
    }

    /// Visibility samples for a link carrying `err` times the threshold.
    fn samples_for(&self, err: f64) -> u32 {
        if err > 1.0 {
            self.samples.saturating_mul(ABOVE)
        } else {
            (f64::from(self.samples) * err).ceil() as u32
        }
        .clamp(1, self.samples.saturating_mul(ABOVE).max(1))
    }

    /// The form factor of `r ← s`, visibility included; `sight`: what lies between them
    /// ([`Refiner::look`]): where nothing does, no segment between two triangles needs a ray,
    /// and where something does, it is tried first.
    fn form_factor(&self, r: u32, s: u32, err: f64, sight: Sight, blocker: &mut u32) -> f64 {
        self.form_factor_with(self.vis, (r, s, err), sight, blocker)
    }

    /// What lies between mesh nodes `r` and `s`, where a pair of them is split: a pair whose
    /// shaft is clear (Haines & Wallace) has its parts' shafts clear too, and the links below
    /// it need no rays; one that is not names a triangle in it, tried first below. The answer
    /// is the rays' own: a segment the shaft holds clear is clear
    /// (`Visibility::shaft_clear`), so the form factors do not depend on where it was asked
    /// (an edit that copies a link computed without rays gets what a fresh bake computes with
    /// them). Clusters are not looked at.
    fn look(&self, r: u32, s: u32, sight: Sight) -> Sight {
        let m = self.tree.mesh_nodes;
        if sight.clear || r >= m || s >= m {
            return sight;
        }
        let (nr, ns) = (&self.mesh.nodes[r as usize], &self.mesh.nodes[s as usize]);
        let mut witness = sight.witness;
        let clear = (self.vis).shaft_clear(&nr.v, nr.normal, &ns.v, ns.normal, &mut witness);
        Sight { clear, witness }
    }

    /// [`Refiner::form_factor`] with the segments asked of `vis`. `blocker`: a triangle that
    /// blocked a segment of a link refined just before (`u32::MAX`: none), tried first, and
    /// the last blocker this link's segments met.
    fn form_factor_with(
        &self,
        vis: &dyn Visibility,
        (r, s, err): (u32, u32, f64),
        sight: Sight,
        blocker: &mut u32,
    ) -> f64 {
        // Samples by what the link may carry: one where it is far below the threshold, the
        // full count near it, `ABOVE` times that on links above it that could not be split.
        let n = self.samples_for(err);
        let mut rng = Rng::new(hash(self.seed, self.stable_id(r), self.stable_id(s)));
        let m = self.tree.mesh_nodes;
        if r < m && s < m {
            return self.planar((vis, sight, blocker), r, s, n, &mut rng);
        }
        // A cluster link's estimate is its form factor too, not only its visibility: never
        // fewer than half the full count, unless it carries so little that one would do for
        // a triangle pair.
        let n = if n <= 1 {
            1
        } else {
            n.max(self.samples.div_ceil(2))
        };
        let a_s = self.tree.area[s as usize];
        let da = a_s / f64::from(n);
        let mut sum = 0.0;
        // What blocked the last segment is tried first on the next.
        for k in 0..n {
            let u = (f64::from(k) + rng.f64()) / f64::from(n);
            let (x, nx) = self.sample(r, u, &mut rng);
            let v = rng.f64();
            let (p, np) = self.sample(s, v, &mut rng);
            let d = p - x;
            let d2 = d.length_squared();
            let (cr, cs) = (nx.dot(d), -np.dot(d));
            if cr <= 0.0 || cs <= 0.0 || d2 <= 0.0 {
                continue;
            }
            // What blocked the last segment is tried first on the next.
            if vis.segment_clear_hinted(x.as_vec3(), p.as_vec3(), None, blocker) {
                // The disc form (Wallace et al.) keeps a near pair from dominating.
                sum += (cr * cs / d2) / (PI * d2 + da);
            }
        }
        let f = da * sum;
        // No more than the receiver can see of the source's bounding sphere.
        let t = self.tree;
        let dc = (t.center[r as usize] - t.center[s as usize]).length() - t.radius[r as usize];
        let bound = if dc > t.radius[s as usize] {
            (t.radius[s as usize] / dc).powi(2)
        } else {
            1.0
        };
        let f = if f.is_finite() {
            f.clamp(0.0, bound.min(1.0))
        } else {
            0.0
        };
        match self.tree.cluster(r) {
            // A cluster receives by direction: the solve hands each triangle in it
            // `F / κ × max(0, n·ω)`, κ the mean of that cosine over the cluster, so that the
            // cluster as a whole gets `F` (see `solve`).
            Some(_) => f / receiver_kappa(self.tree, r, s),
            None => f,
        }
    }

    /// Two triangles: the unoccluded form factor times the clear fraction of `n` segments
    /// (all of them, without rays, where the shaft between them is clear; where it is not,
    /// the last `blocker` met, or else the shaft's witness, is tried first, then each
    /// segment's blocker on the next).
    fn planar(
        &self,
        (vis, sight, blocker): (&dyn Visibility, Sight, &mut u32),
        r: u32,
        s: u32,
        n: u32,
        rng: &mut Rng,
    ) -> f64 {
        let (nr, ns) = (&self.mesh.nodes[r as usize], &self.mesh.nodes[s as usize]);
        let f0 = match self.kind {
            FormFactorKind::RayCast => {
                let side = f64::from(n).sqrt().ceil() as u32;
                let k = side * side;
                let da = ns.area / f64::from(k);
                let mut f = 0.0;
                for i in 0..k {
                    let (u, v) = (
                        (f64::from(i % side) + rng.f64()) / f64::from(side),
                        (f64::from(i / side) + rng.f64()) / f64::from(side),
                    );
                    let d = sample_triangle(&ns.v, u, v) - nr.centroid;
                    let d2 = d.length_squared();
                    let (cr, cs) = (nr.normal.dot(d), -ns.normal.dot(d));
                    if cr > 0.0 && cs > 0.0 && d2 > 0.0 {
                        f += da * (cr * cs / d2) / (PI * d2 + da);
                    }
                }
                f.clamp(0.0, 1.0)
            }
            _ => point_to_triangle(nr.centroid, nr.normal, &ns.v, ns.normal),
        };
        if f0 <= 0.0 {
            return 0.0;
        }
        // The clear share of the pairs, each weighted by its kernel `cos cos / d²`: the form
        // factor needs the mean of kernel × visibility, not the product of their means. Where
        // the near part of a node is clear and its far part behind clutter (a floor among
        // boxes), the unweighted share undercounted: a room of 25 boxes lost 1 % of its light.
        // What lies on or behind either triangle's plane is left out of the segments' tests,
        // as the shaft leaves it out (`Ends`): otherwise a segment grazing its own end
        // triangle meets it by rounding (in the Cornell box 4 540 of the segments of the links
        // whose shafts are clear, most at the blocks' foot), and a link computed without rays
        // would differ from one computed with them (Sponza had 282 k more links, 1.5 %, once
        // such hits no longer hid them).
        let ends = radiant_visibility::Ends::new(&nr.v, nr.normal, &ns.v, ns.normal);
        let (mut seen, mut valid) = (0.0f64, 0.0f64);
        if *blocker == u32::MAX {
            *blocker = sight.witness;
        }
        for k in 0..n {
            let u = (f64::from(k) + rng.f64()) / f64::from(n);
            let x = sample_triangle(&nr.v, u, rng.f64());
            let p = sample_triangle(&ns.v, rng.f64(), rng.f64());
            let d = p - x;
            let (cr, cs) = (nr.normal.dot(d), -ns.normal.dot(d));
            if cr <= 0.0 || cs <= 0.0 {
                continue;
            }
            let d2 = d.length_squared();
            let w = cr * cs / (d2 * d2);
            if !(w > 0.0 && w.is_finite()) {
                continue;
            }
            valid += w;
            if sight.clear
                || vis.segment_clear_hinted(x.as_vec3(), p.as_vec3(), Some(&ends), blocker)
            {
                seen += w;
            }
        }
        if valid == 0.0 {
            // Every pair grazes: judge by the centroids.
            let clear = vis.segment_clear(nr.centroid.as_vec3(), ns.centroid.as_vec3());
            return if clear { f0 } else { 0.0 };
        }
        f0 * seen / valid
    }
}

/// What `r ← s` may carry at the centres' distance (relative to the ambient level):
/// `ρ_r B̂_s A_s / (π d²)`, `f64::MAX` where that is not finite.
/// What `r ← s` may carry at the centres' distance (relative to the ambient level):
/// `ρ_r B̂_s A_s cos θ_r cos θ_s / (π d²)`, each cosine at the centres (a triangle's; for a
/// cluster the largest its cone of normals allows) widened by the angle the two bounding
/// spheres span, `(r_r + r_s) / d`, and at most 1; `f64::MAX` where that is not finite. Without
/// the cosines the oracle refined grazing pairs as if they faced each other: on the Cornell
/// box the same error (0.63 % mean) took 1.42 M links instead of 0.94 M.
pub(crate) fn carry_err(
    mesh: &Mesh,
    tree: &Tree,
    rho: &[f64],
    bhat: &[f64],
    r: u32,
    s: u32,
) -> f64 {
    let d = tree.center[s as usize] - tree.center[r as usize];
    let d2 = d.length_squared();
    let dist = d2.sqrt();
    let slack = (tree.radius[r as usize] + tree.radius[s as usize]) / dist;
    let cos = |id: u32, dir: DVec3| (tree.max_cos(mesh, id, dir / dist) + slack).clamp(0.0, 1.0);
    let est = rho[r as usize] * bhat[s as usize] * tree.area[s as usize] / PI / d2
        * cos(r, d)
        * cos(s, -d);
    if est.is_finite() { est } else { f64::MAX }
}

/// What a piece of work carries from one link to the next, depth first.
#[derive(Clone, Copy, Debug)]
struct Pass {
    /// Links made since they were last counted against the budget.
    since: u64,
    /// Links computed, links kept from before an edit, and links found in the
    /// [`Replay`], since they were last counted.
    computed: u64,
    kept: u64,
    found: u64,
    /// The last triangle that blocked a segment (`u32::MAX`: none), tried first on the next
    /// link's segments: siblings mostly look past the same wall.
    blocker: u32,
}

impl Default for Pass {
    fn default() -> Pass {
        Pass {
            since: 0,
            computed: 0,
            kept: 0,
            found: 0,
            blocker: u32::MAX,
        }
    }
}

/// A piece of the refinement's parallel part.
enum Work {
    /// Refine the pair depth first.
    Refine(u32, u32, Cursor, Sight),
    /// Decided at the top (not a split); what lies between its nodes.
    Done(u32, u32, Visit, Sight),
}

/// What the pairs holding a pair found between its nodes ([`Refiner::look`]).
#[derive(Clone, Copy, Debug)]
struct Sight {
    /// Nothing at all lies between them.
    clear: bool,
    /// A triangle that lay in the shaft of a pair holding them (`u32::MAX`: none).
    witness: u32,
}

impl Sight {
    const UNKNOWN: Sight = Sight {
        clear: false,
        witness: u32::MAX,
    };
}

/// The top of the recursion: a split whose children are `n` entries of the next level from
/// the one named, or a piece of work.
enum Top {
    Split(Op, usize, usize),
    Work(usize),
}

/// The top's entry `i` of level `l` and what lies below it, depth first, into `out`.
fn depth_first(levels: &[Vec<Top>], l: usize, i: usize, out: &mut Vec<Part>) {
    match levels[l][i] {
        Top::Split(op, first, n) => {
            out.push(Part::Open(op, n));
            for k in 0..n {
                depth_first(levels, l + 1, first + k, out);
            }
            out.push(Part::Close);
        }
        Top::Work(w) => out.push(Part::Piece(w)),
    }
}
