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

use super::tree::Tree;
use crate::form_factors::{FormFactorKind, analytic::point_to_triangle, sample_triangle};
use crate::mesh::Mesh;
use crate::rng::{Rng, hash};

/// One link: `recv` gathers `ff × B̄(src)`.
#[derive(Clone, Copy, Debug, PartialEq)]
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
    /// Refine these pairs instead.
    Split([(u32, u32); 4], usize),
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
    /// All links from the root's self-link, in a fixed order (independent of threads), or
    /// `None` when there would be more than `max_links`. `progress(done, total)` is called as
    /// parts finish.
    pub fn build(&self, progress: &(dyn Fn(usize, usize) + Sync)) -> Option<Vec<Vec<Link>>> {
        let root = self.tree.root(self.mesh);
        let mut frontier = vec![(root, root)];
        let mut first = Vec::new();
        while frontier.len() < FRONTIER {
            let mut next = Vec::with_capacity(frontier.len() * 4);
            let mut split = false;
            for &(r, s) in &frontier {
                match self.step(r, s) {
                    Step::Cull => {}
                    Step::Link(e) => self.link(r, s, e, &mut first),
                    Step::Split(p, n) => {
                        next.extend_from_slice(&p[..n]);
                        split = true;
                    }
                }
            }
            frontier = next;
            if !split {
                break;
            }
        }
        let count = AtomicU64::new(first.len() as u64);
        let abort = AtomicBool::new(false);
        let done = AtomicUsize::new(0);
        let total = frontier.len();
        let chunk = (total / (rayon::current_num_threads() * 16)).clamp(1, 64);
        let mut parts: Vec<Vec<Link>> = frontier
            .par_chunks(chunk)
            .map(|pairs| {
                let mut out = Vec::new();
                for &(r, s) in pairs {
                    if self.stop.is_some_and(|f| f.load(Ordering::Relaxed)) {
                        abort.store(true, Ordering::Relaxed);
                        break;
                    }
                    if !self.run(r, s, &mut out, &count, &abort) {
                        break;
                    }
                }
                let d = done.fetch_add(pairs.len(), Ordering::Relaxed) + pairs.len();
                progress(d, total);
                out
            })
            .collect();
        if abort.load(Ordering::Relaxed) {
            return None;
        }
        parts.insert(0, first);
        Some(parts)
    }

    /// Refines `r ← s` depth-first into `out`; false when the link budget ran out.
    fn run(
        &self,
        r: u32,
        s: u32,
        out: &mut Vec<Link>,
        count: &AtomicU64,
        abort: &AtomicBool,
    ) -> bool {
        let mut stack = vec![(r, s)];
        let mut since = 0u64;
        while let Some((r, s)) = stack.pop() {
            match self.step(r, s) {
                Step::Cull => {}
                Step::Link(e) => {
                    let before = out.len();
                    self.link(r, s, e, out);
                    since += (out.len() - before) as u64;
                    if since >= 1024 {
                        let c = count.fetch_add(since, Ordering::Relaxed) + since;
                        since = 0;
                        if c > self.max_links {
                            abort.store(true, Ordering::Relaxed);
                        }
                        if abort.load(Ordering::Relaxed) {
                            return false;
                        }
                    }
                }
                Step::Split(p, n) => stack.extend(p[..n].iter().rev()),
            }
        }
        count.fetch_add(since, Ordering::Relaxed);
        true
    }

    fn link(&self, r: u32, s: u32, err: f64, out: &mut Vec<Link>) {
        let f = self.form_factor(r, s, err);
        if f > 0.0 {
            out.push(Link {
                recv: r,
                src: s,
                ff: f as f32,
            });
        }
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
                    Step::Split([(a, a), (a, b), (b, a), (b, b)], 4)
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
        let t = self.tree;
        let (rr, rs) = (t.radius[r as usize], t.radius[s as usize]);
        let d2 = (t.center[r as usize] - t.center[s as usize]).length_squared();
        let gap = d2.sqrt() - (rr + rs);
        // What the link may carry at the centres' distance, relative to the threshold.
        let carry = self.rho[r as usize] * self.bhat[s as usize] * t.area[s as usize] / PI;
        let est = carry / d2;
        let err = if est.is_finite() { est } else { f64::MAX };
        // Spheres apart; between two triangles that is enough, with a cluster on an end its
        // bound at the gap must hold too.
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
            Step::Split(out, n)
        } else {
            let (c, n) = self.children(s);
            for k in 0..n {
                out[k] = (r, c[k]);
            }
            Step::Split(out, n)
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
                let t = self.tree.pick(self.mesh, c, u);
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

    /// The form factor of `r ← s`, visibility included.
    fn form_factor(&self, r: u32, s: u32, err: f64) -> f64 {
        // Samples by what the link may carry: one where it is far below the threshold, the
        // full count near it, `ABOVE` times that on links above it that could not be split.
        let n = if err > 1.0 {
            self.samples.saturating_mul(ABOVE)
        } else {
            (f64::from(self.samples) * err).ceil() as u32
        }
        .clamp(1, self.samples.saturating_mul(ABOVE).max(1));
        let mut rng = Rng::new(hash(self.seed, self.stable_id(r), self.stable_id(s)));
        let m = self.tree.mesh_nodes;
        if r < m && s < m {
            return self.planar(r, s, n, &mut rng);
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
            if self.vis.segment_clear(x.as_vec3(), p.as_vec3()) {
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

    /// Two triangles: the unoccluded form factor times the clear fraction of `n` segments.
    fn planar(&self, r: u32, s: u32, n: u32, rng: &mut Rng) -> f64 {
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
        let (mut clear, mut valid) = (0.0f64, 0.0f64);
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
            if self.vis.segment_clear(x.as_vec3(), p.as_vec3()) {
                clear += w;
            }
        }
        if valid == 0.0 {
            // Every pair grazes: judge by the centroids.
            let clear = self
                .vis
                .segment_clear(nr.centroid.as_vec3(), ns.centroid.as_vec3());
            return if clear { f0 } else { 0.0 };
        }
        f0 * clear / valid
    }
}
