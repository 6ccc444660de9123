//! Ray visibility for radiosity: closest-hit and segment (shadow) queries over a triangle soup.
//!
//! [`Bvh`] builds an `obvhs` BVH; [`BruteForce`] tests every triangle and is the reference the
//! BVH is tested against. Both intersect triangles from either side, because a ray that hits the
//! back of a wall is blocked just the same. Coordinates are `f32`: callers put the scene into a
//! local frame of about unit size first (the radiosity crate does), so far-off origins and
//! extreme scales lose no precision here.
//!
//! ```
//! use glam::Vec3;
//! use radiant_visibility::{Bvh, Visibility};
//! let floor = [[Vec3::new(-1., 0., -1.), Vec3::new(1., 0., -1.), Vec3::new(0., 0., 1.)]];
//! let bvh = Bvh::new(&floor);
//! assert!(!bvh.segment_clear(Vec3::new(0., 1., 0.), Vec3::new(0., -1., 0.)));
//! let hit = bvh.closest_hit(Vec3::new(0., 1., 0.), Vec3::NEG_Y, f32::INFINITY).unwrap();
//! assert_eq!(hit.triangle, 0);
//! assert!((hit.t - 1.0).abs() < 1e-6);
//! ```

use std::borrow::Borrow;
use std::sync::Arc;
use std::time::Duration;

use glam::{DVec3, Vec3, Vec3A};
use obvhs::{BvhBuildParams, cwbvh::CwBvh, ray::Ray};

mod shaft;
pub use shaft::{Ends, Shaft};

/// Fraction of a segment's length cut from each end, so that the surfaces at its end points do
/// not block it.
pub const SEGMENT_EPSILON: f32 = 1e-4;

/// A ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Index of the triangle, in the order given to the constructor.
    pub triangle: u32,
    /// Distance along the ray, in units of the direction's length.
    pub t: f32,
    /// Barycentric weight of vertex 1.
    pub u: f32,
    /// Barycentric weight of vertex 2 (vertex 0 has `1 - u - v`).
    pub v: f32,
    /// Whether the ray hit the triangle's front (counter-clockwise) side.
    pub front: bool,
}

/// Visibility queries over a fixed set of triangles.
pub trait Visibility: Send + Sync {
    /// Whether the segment from `a` to `b` is unblocked, ignoring [`SEGMENT_EPSILON`] at each end.
    fn segment_clear(&self, a: Vec3, b: Vec3) -> bool;
    /// [`Visibility::segment_clear`] for a segment between two triangles, leaving out the
    /// triangles that lie on or behind either one's plane ([`Ends`]): the segment can meet them
    /// only by rounding, grazing that plane. [`Visibility::shaft_clear`] leaves them out too,
    /// so that where a shaft is clear its segments are, whether asked or not. This default
    /// leaves nothing out.
    fn segment_clear_between(&self, a: Vec3, b: Vec3, ends: &Ends) -> bool {
        let _ = ends;
        self.segment_clear(a, b)
    }
    /// [`Visibility::segment_clear_between`] (with `ends`) or [`Visibility::segment_clear`]
    /// (without), trying first the triangle `blocker` names (this visibility's own number, as
    /// [`Visibility::shaft_clear`]'s witness; `u32::MAX`: none), which blocked a segment near
    /// this one; a segment found blocked names its blocker there. The answer is the one
    /// without the hint: only which triangle is tried first changes. This default ignores it.
    fn segment_clear_hinted(
        &self,
        a: Vec3,
        b: Vec3,
        ends: Option<&Ends>,
        blocker: &mut u32,
    ) -> bool {
        let _ = blocker;
        match ends {
            Some(e) => self.segment_clear_between(a, b, e),
            None => self.segment_clear(a, b),
        }
    }
    /// The closest hit of the ray `origin + t * dir` for `t` in `(tmin, tmax]`, tmin a tiny
    /// relative offset.
    fn closest_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit>;
    /// Whether no triangle at all lies in the shaft of the segments from triangle `a`, leaving
    /// it along `na`, to triangle `b`, reaching it against `nb` ([`Shaft`]): then every such
    /// segment is clear ([`Visibility::segment_clear_between`]), and so is every segment
    /// between parts of the two. Conservative: `false` when unsure, and always in this
    /// default. `witness` names a triangle that may lie in it (`u32::MAX`: none known), tried
    /// first; a shaft found not clear names one there, for the shafts of the parts after it.
    fn shaft_clear(
        &self,
        a: &[DVec3; 3],
        na: DVec3,
        b: &[DVec3; 3],
        nb: DVec3,
        witness: &mut u32,
    ) -> bool {
        let _ = (a, na, b, nb, witness);
        false
    }
}

/// Decides whether a hit counts. Alpha masks implement it: a ray passes a masked triangle
/// where its texture's alpha is cut.
pub trait HitFilter: Send + Sync {
    /// Whether a hit on `triangle` (the constructor's index) at barycentrics `(u, v)` (weights of
    /// vertices 1 and 2) blocks the ray.
    fn blocks(&self, triangle: u32, u: f32, v: f32) -> bool;
}

impl<F: Fn(u32, f32, f32) -> bool + Send + Sync> HitFilter for F {
    fn blocks(&self, triangle: u32, u: f32, v: f32) -> bool {
        self(triangle, u, v)
    }
}

/// No blocker to try first ([`Visibility::segment_clear_hinted`]).
const NO_HINT: u32 = u32::MAX;

/// Rays within this angle (radians) of a triangle's plane do not meet it ([`Tri::edge_on`]).
const EDGE_ON: f32 = 1e-5;

/// How far each triangle's box in the BVH reaches past the triangle: relative to its largest
/// extent, and absolute (local units). The barycentric slack of [`Tri::intersect`] counts hits
/// up to a millionth of an edge outside a triangle; a box as tight as the triangle, quantised
/// differently in another BVH, would hold those hits in one BVH and not in the other.
const BOX_SLACK: (f32, f32) = (1e-5, 1e-7);

#[derive(Clone, Copy, Debug)]
struct Tri {
    v0: Vec3A,
    e1: Vec3A,
    e2: Vec3A,
}

impl Tri {
    fn new(t: &[Vec3; 3]) -> Self {
        let v0 = Vec3A::from(t[0]);
        Tri {
            v0,
            e1: Vec3A::from(t[1]) - v0,
            e2: Vec3A::from(t[2]) - v0,
        }
    }

    /// Its vertices, in `f64`.
    fn vertices(&self) -> [DVec3; 3] {
        let v0 = DVec3::from(Vec3::from(self.v0));
        [
            v0,
            v0 + DVec3::from(Vec3::from(self.e1)),
            v0 + DVec3::from(Vec3::from(self.e2)),
        ]
    }

    /// How far past its edges [`Tri::intersect`] may count a hit (its box's [`BOX_SLACK`]).
    fn slack(&self) -> f64 {
        let ext = self
            .e1
            .abs()
            .max(self.e2.abs())
            .max((self.e1 - self.e2).abs());
        f64::from(ext.max_element() * BOX_SLACK.0 + BOX_SLACK.1)
    }

    /// Möller–Trumbore, two-sided. Returns (t, u, v, front) for `t` in `[tmin, tmax]`.
    #[inline(always)]
    fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<(f32, f32, f32, bool)> {
        let p = d.cross(self.e2);
        let det = self.e1.dot(p);
        if det.abs() < f32::MIN_POSITIVE || !det.is_finite() {
            return None;
        }
        let inv = 1.0 / det;
        let s = o - self.v0;
        // A hair of slack on the barycentric tests makes neighbouring triangles watertight: a
        // ray through a shared edge must not slip between them by rounding.
        const SLACK: f32 = 1e-6;
        let u = s.dot(p) * inv;
        if !(-SLACK..=1.0 + SLACK).contains(&u) {
            return None;
        }
        let q = s.cross(self.e1);
        let v = d.dot(q) * inv;
        if v < -SLACK || u + v > 1.0 + SLACK {
            return None;
        }
        let t = self.e2.dot(q) * inv;
        if t < tmin || t > tmax || self.edge_on(d, det) {
            return None;
        }
        // det = -d·N: positive when the ray meets the front (counter-clockwise) side.
        Some((t, u, v, det > 0.0))
    }

    /// Whether the ray along `d` lies in the triangle's plane, within [`EDGE_ON`] radians
    /// (`det = -d·N`). Such a ray meets the triangle by rounding alone, and whether the
    /// triangle is tested at all depends on which of a BVH's quantised boxes hold it: a BVH
    /// built over other triangles beside it would answer otherwise (a geometry edit that keeps
    /// form factors computed with the old BVH would then differ from a fresh bake). Seen
    /// edge-on, a triangle blocks nothing.
    #[inline]
    fn edge_on(&self, d: Vec3A, det: f32) -> bool {
        let n = self.e1.cross(self.e2);
        det * det <= EDGE_ON * EDGE_ON * d.length_squared() * n.length_squared()
    }
}

/// `d` with every `-0.0` made `+0.0`. The CWBVH's node test takes a component's sign from
/// `d < 0` but its inverse from the sign bit, so a `-0.0` (as in `-0.0 - 0.0`) would flip that
/// axis's slab and miss every node.
fn positive_zeros(d: Vec3) -> Vec3A {
    Vec3A::from(d) + Vec3A::ZERO
}

/// How far behind its origin (in units of its direction) a [`Visibility::closest_hit`] ray
/// starts its traversal. obvhs 0.4's wide-BVH node test clamps each child box's entry to
/// `t = 1e-4`, whatever the ray's own `tmin`: a box wholly nearer than that is skipped, and with
/// it a triangle the ray meets. A light panel 1 mm under a ceiling, alone in its box, was missed
/// by 60 % of the rays cast from the ceiling behind it (the path tracer then saw the floor
/// through it); started this far back, every box in front of the origin lies past the clamp.
/// Segments need nothing: they ignore [`SEGMENT_EPSILON`] = 1e-4 at their start anyway.
const TRAVERSAL_BACK: f32 = 2e-4;

fn ray_tmin(dir: Vec3) -> f32 {
    // A tiny offset relative to the direction's length.
    1e-6 / dir.length().max(f32::MIN_POSITIVE) * 1e-1
}

/// Tests every triangle; O(n) per query. The reference for [`Bvh`].
#[derive(Clone, Debug)]
pub struct BruteForce {
    tris: Vec<Tri>,
}

impl BruteForce {
    /// Takes the triangles' vertices.
    pub fn new(triangles: &[[Vec3; 3]]) -> Self {
        BruteForce {
            tris: triangles.iter().map(Tri::new).collect(),
        }
    }
}

impl Visibility for BruteForce {
    fn segment_clear(&self, a: Vec3, b: Vec3) -> bool {
        let (o, d) = (Vec3A::from(a), Vec3A::from(b - a));
        !self.tris.iter().any(|t| {
            t.intersect(o, d, SEGMENT_EPSILON, 1.0 - SEGMENT_EPSILON)
                .is_some()
        })
    }

    fn segment_clear_between(&self, a: Vec3, b: Vec3, ends: &Ends) -> bool {
        let (o, d) = (Vec3A::from(a), Vec3A::from(b - a));
        !self.tris.iter().any(|t| {
            t.intersect(o, d, SEGMENT_EPSILON, 1.0 - SEGMENT_EPSILON)
                .is_some()
                && !ends.leave_out(&t.vertices())
        })
    }

    fn closest_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        let (o, d) = (Vec3A::from(origin), Vec3A::from(dir));
        let tmin = ray_tmin(dir);
        let mut best: Option<Hit> = None;
        for (i, tri) in self.tris.iter().enumerate() {
            let limit = best.map_or(tmax, |b| b.t);
            if let Some((t, u, v, front)) = tri.intersect(o, d, tmin, limit) {
                best = Some(Hit {
                    triangle: i as u32,
                    t,
                    u,
                    v,
                    front,
                });
            }
        }
        best
    }
}

/// A BVH over the triangles, built with `obvhs`: PLOC (medium preset), then collapsed into its
/// compressed 8-wide layout (CWBVH, Ylitie et al. 2017), whose traversal tests eight children
/// per node at once.
pub struct Bvh {
    bvh: CwBvh,
    /// Triangles in BVH order.
    tris: Vec<Tri>,
    /// BVH order → caller's index.
    ids: Vec<u32>,
    /// The hit filter and, in BVH order, which triangles it is asked about.
    filter: Option<(Arc<dyn HitFilter>, Vec<bool>)>,
}

impl Bvh {
    /// Builds the BVH. An empty input gives a BVH that never hits.
    pub fn new(triangles: &[[Vec3; 3]]) -> Self {
        Self::build(triangles)
    }

    /// Builds the BVH with a hit filter, asked only about the triangles `filtered` marks (by
    /// the caller's index): every other hit blocks as usual, at no extra cost.
    pub fn with_filter(
        triangles: &[[Vec3; 3]],
        filtered: impl Fn(u32) -> bool,
        filter: Arc<dyn HitFilter>,
    ) -> Self {
        let mut bvh = Self::build(triangles);
        let marks: Vec<bool> = bvh.ids.iter().map(|&i| filtered(i)).collect();
        if marks.iter().any(|&m| m) {
            bvh.filter = Some((filter, marks));
        }
        bvh
    }

    /// Whether the hit on BVH-order triangle `id` at `(u, v)` counts.
    #[inline(always)]
    fn counts(&self, id: usize, u: f32, v: f32) -> bool {
        match &self.filter {
            Some((f, marks)) if marks[id] => f.blocks(self.ids[id], u, v),
            _ => true,
        }
    }

    fn build(triangles: &[[Vec3; 3]]) -> Self {
        if triangles.is_empty() {
            return Bvh {
                bvh: CwBvh::default(),
                tris: Vec::new(),
                ids: Vec::new(),
                filter: None,
            };
        }
        // Each triangle's box, grown by the slack its hits may reach past it, so that whether a
        // hit counts depends on the triangle alone, not on the BVH around it.
        let boxes: Vec<obvhs::aabb::Aabb> = triangles
            .iter()
            .map(|t| {
                let (lo, hi) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
                let grow = (hi - lo).max_element() * BOX_SLACK.0 + BOX_SLACK.1;
                obvhs::aabb::Aabb::new(Vec3A::from(lo) - grow, Vec3A::from(hi) + grow)
            })
            .collect();
        let bvh = obvhs::cwbvh::builder::build_cwbvh(
            &boxes,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        let ids = bvh.primitive_indices.clone();
        let tris = ids
            .iter()
            .map(|&i| Tri::new(&triangles[i as usize]))
            .collect();
        Bvh {
            bvh,
            tris,
            ids,
            filter: None,
        }
    }
}

impl Bvh {
    /// [`Visibility::segment_clear_hinted`], where the triangles `removed` marks (by the
    /// caller's index) are not there.
    fn segment_clear_without(
        &self,
        a: Vec3,
        b: Vec3,
        removed: Option<&[bool]>,
        ends: Option<&Ends>,
        blocker: &mut u32,
    ) -> bool {
        if self.tris.is_empty() {
            return true;
        }
        let gone = |id: usize| {
            removed.is_some_and(|r| r.get(self.ids[id] as usize) == Some(&true))
                || ends.is_some_and(|e| e.leave_out(&self.tris[id].vertices()))
        };
        let (o, d) = (Vec3A::from(a), positive_zeros(b - a));
        let ray = Ray::new(o, d, SEGMENT_EPSILON, 1.0 - SEGMENT_EPSILON);
        // Whether triangle `id` blocks the ray: the traversal's own test, so that the hint
        // answers as the traversal would. The traversal counts a hit only before `tmax`, not
        // at it (on Sponza one segment in some 60 million met a triangle exactly there).
        let blocks = |r: &Ray, id: usize| match self.tris[id].intersect(
            r.origin,
            r.direction,
            r.tmin,
            r.tmax,
        ) {
            Some((t, u, v, _)) if t < r.tmax && !gone(id) && self.counts(id, u, v) => Some(t),
            _ => None,
        };
        if (*blocker as usize) < self.tris.len() && blocks(&ray, *blocker as usize).is_some() {
            return false;
        }
        let mut found = None;
        let clear = self
            .bvh
            .ray_traverse_miss(ray, |r, id| match blocks(r, id) {
                Some(t) => {
                    found = Some(id);
                    t
                }
                None => f32::INFINITY,
            });
        if let Some(id) = found.filter(|_| !clear) {
            *blocker = id as u32;
        }
        clear
    }

    /// [`Visibility::closest_hit`], where the triangles `removed` marks are not there.
    fn closest_hit_without(
        &self,
        origin: Vec3,
        dir: Vec3,
        tmax: f32,
        removed: Option<&[bool]>,
    ) -> Option<Hit> {
        if self.tris.is_empty() {
            return None;
        }
        let gone = |id: usize| removed.is_some_and(|r| r.get(self.ids[id] as usize) == Some(&true));
        let (o, d) = (Vec3A::from(origin), positive_zeros(dir));
        let tmin = ray_tmin(dir);
        // The traversal starts `TRAVERSAL_BACK` behind the origin (see there); the triangles
        // are tested from the origin itself, and the traversal is handed their distances from
        // its own start.
        let ray = Ray::new(o - d * TRAVERSAL_BACK, d, tmin, tmax + TRAVERSAL_BACK);
        let mut hit = obvhs::ray::RayHit::none();
        let mut best: Option<(f32, f32, f32, bool, usize)> = None;
        self.bvh.ray_traverse(ray, &mut hit, |r, id| {
            match self.tris[id].intersect(o, d, tmin, r.tmax - TRAVERSAL_BACK) {
                Some((t, u, v, front)) if !gone(id) && self.counts(id, u, v) => {
                    if best.is_none_or(|b| t < b.0) {
                        best = Some((t, u, v, front, id));
                    }
                    t + TRAVERSAL_BACK
                }
                _ => f32::INFINITY,
            }
        });
        best.map(|(t, u, v, front, id)| Hit {
            triangle: self.ids[id],
            t,
            u,
            v,
            front,
        })
    }
}

impl Visibility for Bvh {
    fn segment_clear(&self, a: Vec3, b: Vec3) -> bool {
        self.segment_clear_without(a, b, None, None, &mut { NO_HINT })
    }

    fn segment_clear_between(&self, a: Vec3, b: Vec3, ends: &Ends) -> bool {
        self.segment_clear_without(a, b, None, Some(ends), &mut { NO_HINT })
    }

    fn segment_clear_hinted(
        &self,
        a: Vec3,
        b: Vec3,
        ends: Option<&Ends>,
        blocker: &mut u32,
    ) -> bool {
        self.segment_clear_without(a, b, None, ends, blocker)
    }

    fn shaft_clear(
        &self,
        a: &[DVec3; 3],
        na: DVec3,
        b: &[DVec3; 3],
        nb: DVec3,
        witness: &mut u32,
    ) -> bool {
        if self.tris.is_empty() {
            return true;
        }
        let Some(mut shaft) = Shaft::new(a, na, b, nb) else {
            return false;
        };
        // What blocked the shaft holding this one mostly blocks this one too: tried against
        // the shaft without its sides, which is quicker to make, and answers for it if it may
        // lie there.
        if *witness != u32::MAX
            && (self.tris.get(*witness as usize))
                .is_none_or(|t| !shaft.misses_triangle(&t.vertices(), t.slack()))
        {
            return false;
        }
        shaft.add_sides();
        let meets = |id: u32| {
            (self.tris.get(id as usize))
                .is_none_or(|t| !shaft.misses_triangle(&t.vertices(), t.slack()))
        };
        // Depth first through the wide BVH: every child box the shaft may meet, and in the
        // leaves every triangle; the first triangle that may block answers.
        let nodes = &self.bvh.nodes;
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let Some(node) = nodes.get(i as usize) else {
                return false;
            };
            for child in 0..8 {
                if node.is_child_empty(child) {
                    continue;
                }
                let bx = node.child_aabb(child);
                if shaft.misses_box(bx.min, bx.max) {
                    continue;
                }
                if !node.is_leaf(child) {
                    stack.push(node.child_node_index(child));
                    continue;
                }
                let (first, count) = node.child_primitives(child);
                for id in first..first + count {
                    if meets(id) {
                        *witness = id;
                        return false;
                    }
                }
            }
        }
        true
    }

    fn closest_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        self.closest_hit_without(origin, dir, tmax, None)
    }
}

/// A BVH seen with some of its triangles taken away and others added, without building it
/// again: what a quick look at an edit traces against while the edited scene's own BVH is
/// still to be built. The base is held as `B`: borrowed (`&Bvh`) or shared (`Arc<Bvh>`, for a
/// task that outlives the caller). Hits on the added triangles carry the index
/// `base count + i`, or the index [`Patched::renumbered`] gives them.
pub struct Patched<B> {
    base: B,
    /// By the base's (the caller's) index: the triangles taken away.
    removed: Vec<bool>,
    added: Bvh,
    /// The index a hit on added triangle `i` carries, when renumbered.
    added_ids: Option<Vec<u32>>,
}

impl<B: Borrow<Bvh>> Patched<B> {
    /// `base` without the triangles `removed` marks (by the index given to its constructor),
    /// with `added`.
    pub fn new(base: B, removed: Vec<bool>, added: Bvh) -> Self {
        Patched {
            base,
            removed,
            added,
            added_ids: None,
        }
    }

    /// Hits on added triangle `i` carry `ids[i]` (an index of the edited scene, say, where the
    /// base's triangles keep theirs); `ids` has one entry per added triangle.
    pub fn renumbered(mut self, ids: Vec<u32>) -> Self {
        self.added_ids = Some(ids);
        self
    }
}

impl<B: Borrow<Bvh> + Send + Sync> Visibility for Patched<B> {
    fn segment_clear(&self, a: Vec3, b: Vec3) -> bool {
        self.added.segment_clear(a, b)
            && (self.base.borrow())
                .segment_clear_without(a, b, Some(&self.removed), None, &mut { NO_HINT })
    }

    fn segment_clear_between(&self, a: Vec3, b: Vec3, ends: &Ends) -> bool {
        self.added.segment_clear_between(a, b, ends)
            && (self.base.borrow()).segment_clear_without(
                a,
                b,
                Some(&self.removed),
                Some(ends),
                &mut { NO_HINT },
            )
    }

    fn closest_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        let base = self.base.borrow();
        let near = self.added.closest_hit(origin, dir, tmax).map(|mut h| {
            h.triangle = match &self.added_ids {
                Some(ids) => ids[h.triangle as usize],
                None => h.triangle + base.ids.len() as u32,
            };
            h
        });
        let limit = near.map_or(tmax, |h| h.t);
        base.closest_hit_without(origin, dir, limit, Some(&self.removed))
            .or(near)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seeded xorshift generator, so the test is the same on every run.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f32 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 40) as f32 / (1u64 << 24) as f32
        }
        fn v(&mut self) -> Vec3 {
            Vec3::new(self.next(), self.next(), self.next()) * 2.0 - 1.0
        }
    }

    fn soup(rng: &mut Rng, n: usize) -> Vec<[Vec3; 3]> {
        (0..n)
            .map(|_| {
                let c = rng.v();
                [c + rng.v() * 0.2, c + rng.v() * 0.2, c + rng.v() * 0.2]
            })
            .collect()
    }

    #[test]
    fn bvh_agrees_with_brute_force() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        let tris = soup(&mut rng, 500);
        let (bvh, brute) = (Bvh::new(&tris), BruteForce::new(&tris));
        let mut hits = 0;
        for _ in 0..5000 {
            let (a, b) = (rng.v() * 1.5, rng.v() * 1.5);
            assert_eq!(
                bvh.segment_clear(a, b),
                brute.segment_clear(a, b),
                "segment {a} {b}"
            );
            let (h1, h2) = (
                bvh.closest_hit(a, b - a, f32::INFINITY),
                brute.closest_hit(a, b - a, f32::INFINITY),
            );
            match (h1, h2) {
                (Some(x), Some(y)) => {
                    hits += 1;
                    assert!((x.t - y.t).abs() < 1e-5, "{x:?} {y:?}");
                    if x.triangle != y.triangle {
                        // Only ties may differ.
                        assert!((x.t - y.t).abs() < 1e-6);
                    }
                }
                (None, None) => {}
                other => panic!("bvh and brute force disagree: {other:?}"),
            }
        }
        assert!(hits > 1000, "the test must exercise hits ({hits})");
    }

    #[test]
    fn a_blocker_hint_does_not_change_the_answer() {
        // Random segments through a soup, with and without the triangle ends left out, each
        // asked with the blocker the last one found (the refinement's use), with a wrong hint
        // (a triangle far off) and with an index out of range: always the unhinted answer, and
        // a blocked segment names a triangle that blocks it.
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        let tris = soup(&mut rng, 80);
        let bvh = Bvh::new(&tris);
        let ends = Ends::new(
            &tris[0].map(DVec3::from),
            DVec3::Z,
            &tris[1].map(DVec3::from),
            -DVec3::Z,
        );
        let (mut carried, mut blocked, mut hinted_hits) = (u32::MAX, 0, 0);
        for k in 0..20_000 {
            let p = |rng: &mut Rng| Vec3::new(rng.next(), rng.next(), rng.next()) * 4.0 - 2.0;
            let (a, b) = (p(&mut rng), p(&mut rng));
            let e = (k % 2 == 0).then_some(&ends);
            let plain = match e {
                Some(e) => bvh.segment_clear_between(a, b, e),
                None => bvh.segment_clear(a, b),
            };
            let before = carried;
            let hinted = bvh.segment_clear_hinted(a, b, e, &mut carried);
            assert_eq!(hinted, plain, "segment {a} -> {b} with hint {before}");
            if !plain {
                blocked += 1;
                hinted_hits += u32::from(carried == before);
                let mut again = carried;
                assert!(!bvh.segment_clear_hinted(a, b, e, &mut again), "{carried}");
            }
            for mut wrong in [k % 80, u32::MAX - 1] {
                assert_eq!(bvh.segment_clear_hinted(a, b, e, &mut wrong), plain);
            }
        }
        assert!(blocked > 1000, "{blocked}");
        assert!(hinted_hits > 0, "the carried blocker never answered");
    }

    #[test]
    fn a_clear_shaft_has_no_blocked_segment() {
        // Random pairs among a soup's triangles (as the radiosity asks: both are in the BVH),
        // each seen from its front towards the other. Wherever the shaft is called clear,
        // every segment that counts (leaving `a` along `na`, reaching `b` against `nb`) must be
        // clear by brute force; and some shafts must be clear, some not.
        let mut rng = Rng(0x2545_F491_4F6C_DD1D);
        let tris = soup(&mut rng, 60);
        let (bvh, brute) = (Bvh::new(&tris), BruteForce::new(&tris));
        let d = |t: &[Vec3; 3]| t.map(DVec3::from);
        let (mut clear, mut blocked, mut segments) = (0, 0, 0);
        let mut witness = u32::MAX;
        for _ in 0..3000 {
            let i = (rng.next() * tris.len() as f32) as usize % tris.len();
            let j = (rng.next() * tris.len() as f32) as usize % tris.len();
            if i == j {
                continue;
            }
            let (a, b) = (d(&tris[i]), d(&tris[j]));
            let c = |t: &[DVec3; 3]| (t[0] + t[1] + t[2]) / 3.0;
            let n = |t: &[DVec3; 3], towards: DVec3| {
                let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
                if n.dot(towards - c(t)) >= 0.0 { n } else { -n }
            };
            let (na, nb) = (n(&a, c(&b)), n(&b, c(&a)));
            // The witness carries over from pair to pair: a hint, right or wrong.
            if !bvh.shaft_clear(&a, na, &b, nb, &mut witness) {
                blocked += 1;
                continue;
            }
            clear += 1;
            let point = |t: &[DVec3; 3], rng: &mut Rng| {
                let (mut u, mut v) = (f64::from(rng.next()), f64::from(rng.next()));
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v
            };
            for _ in 0..200 {
                let (x, p) = (point(&a, &mut rng), point(&b, &mut rng));
                // Not grazing either end's plane (see `Shaft`): a segment within a few
                // degrees of it may meet its own end triangle by rounding.
                let dir = (p - x).normalize();
                if na.dot(dir) <= 0.05 || nb.dot(dir) >= -0.05 {
                    continue;
                }
                segments += 1;
                assert!(
                    brute.segment_clear(x.as_vec3(), p.as_vec3()),
                    "a clear shaft {i} -> {j} holds a blocked segment {x} -> {p}"
                );
            }
        }
        assert!(
            clear > 100 && blocked > 100,
            "{clear} clear, {blocked} blocked"
        );
        assert!(segments > 10_000, "{segments}");
        // Two facing walls of an empty room are clear; a wall between them is not.
        let wall = |x: f32| {
            [
                Vec3::new(x, 0.0, 0.0),
                Vec3::new(x, 1.0, 0.0),
                Vec3::new(x, 0.0, 1.0),
            ]
        };
        let (l, r) = (wall(0.0), wall(1.0));
        let room = Bvh::new(&[l, r]);
        let (walls, facing) = ((d(&l), DVec3::X), (d(&r), DVec3::NEG_X));
        let clear = |vis: &dyn Visibility, witness: &mut u32| {
            vis.shaft_clear(&walls.0, walls.1, &facing.0, facing.1, witness)
        };
        assert!(clear(&room, &mut u32::MAX.clone()));
        // Parted by a third wall, which it names as the witness.
        let parted = Bvh::new(&[l, r, wall(0.5)]);
        let mut w = u32::MAX;
        assert!(!clear(&parted, &mut w));
        assert_eq!(parted.ids[w as usize], 2);
        // A wrong witness does not make a clear shaft blocked.
        assert!(clear(&room, &mut 0));
        // The default (brute force) never says clear.
        assert!(!clear(&BruteForce::new(&[l, r]), &mut u32::MAX.clone()));
    }

    #[test]
    fn a_triangle_just_in_front_of_the_origin_is_hit() {
        // A 0.4-wide panel 5e-5 under a 2-wide ceiling, above floors of 0 to 4 096 tiles: the
        // panel's box lies wholly within t = 1e-4 of rays cast down from the ceiling above it.
        // Before the traversal started behind the origin, such rays could miss the panel and
        // meet the floor, depending on how the BVH grouped it (60 % of them in a room of boxes).
        let quad = |y: f32, x0: f32, z0: f32, w: f32| -> [[Vec3; 3]; 2] {
            let p = [
                Vec3::new(x0, y, z0),
                Vec3::new(x0 + w, y, z0),
                Vec3::new(x0 + w, y, z0 + w),
                Vec3::new(x0, y, z0 + w),
            ];
            [[p[0], p[1], p[2]], [p[0], p[2], p[3]]]
        };
        let mut rng = Rng(0x2545_F491_4F6C_DD1D);
        for tiles in [0usize, 4, 16, 64] {
            let mut tris: Vec<[Vec3; 3]> = Vec::new();
            tris.extend(quad(1.0, -1.0, -1.0, 2.0));
            let panel = tris.len() as u32;
            tris.extend(quad(1.0 - 5e-5, -0.2, -0.2, 0.4));
            let w = 2.0 / tiles.max(1) as f32;
            for i in 0..tiles {
                for j in 0..tiles {
                    let (x, z) = (-1.0 + i as f32 * w, -1.0 + j as f32 * w);
                    tris.extend(quad(0.0, x, z, w));
                }
            }
            let (bvh, brute) = (Bvh::new(&tris), BruteForce::new(&tris));
            for _ in 0..2000 {
                let o = Vec3::new(
                    rng.next() * 0.36 - 0.18,
                    1.0 - 1e-6,
                    rng.next() * 0.36 - 0.18,
                );
                let d = Vec3::new(rng.next() - 0.5, -1.0, rng.next() - 0.5).normalize();
                let b = brute.closest_hit(o, d, f32::INFINITY).expect("a hit");
                assert!(b.triangle >= panel && b.triangle < panel + 2, "{b:?}");
                let a = bvh.closest_hit(o, d, f32::INFINITY);
                assert_eq!(
                    a.map(|a| (a.triangle, a.front)),
                    Some((b.triangle, b.front)),
                    "{tiles}² tiles, ray {o} {d}"
                );
                assert!((a.map_or(0.0, |a| a.t) - b.t).abs() <= 1e-7);
            }
        }
    }

    #[test]
    fn both_sides_block_and_ends_do_not() {
        let tri = [[
            Vec3::new(-1., 0., -1.),
            Vec3::new(1., 0., -1.),
            Vec3::new(0., 0., 1.),
        ]];
        for vis in [&Bvh::new(&tri) as &dyn Visibility, &BruteForce::new(&tri)] {
            assert!(!vis.segment_clear(Vec3::Y, -Vec3::Y));
            assert!(!vis.segment_clear(-Vec3::Y, Vec3::Y));
            // A segment that starts or ends on the triangle is not blocked by it.
            assert!(vis.segment_clear(Vec3::ZERO, Vec3::Y));
            assert!(vis.segment_clear(Vec3::Y, Vec3::ZERO));
            // The triangle's front normal is -y.
            let front = vis.closest_hit(-Vec3::Y, Vec3::Y, 10.0).expect("hit");
            let back = vis.closest_hit(Vec3::Y, -Vec3::Y, 10.0).expect("hit");
            assert!(front.front && !back.front);
        }
    }

    #[test]
    fn axis_aligned_segments_with_negative_zeros_are_blocked() {
        // Floors of 1 to 40 triangles; the segment's direction is (-0, -2, -0).
        for n in [1usize, 2, 9, 40] {
            let tris: Vec<[Vec3; 3]> = (0..n)
                .map(|i| {
                    let x = i as f32 * 2.0;
                    [
                        Vec3::new(x - 1., 0., -1.),
                        Vec3::new(x + 1., 0., -1.),
                        Vec3::new(x, 0., 1.),
                    ]
                })
                .collect();
            let bvh = Bvh::new(&tris);
            assert!(!bvh.segment_clear(Vec3::Y, -Vec3::Y), "{n} triangles");
            assert!(
                bvh.closest_hit(Vec3::Y, -Vec3::Y, 10.0).is_some(),
                "{n} triangles"
            );
        }
    }

    #[test]
    fn a_patched_bvh_is_a_bvh_built_again() {
        let mut rng = Rng(0x2545_F491_4F6C_DD1D);
        let tris = soup(&mut rng, 400);
        let added = soup(&mut rng, 40);
        // Every third triangle taken away.
        let removed: Vec<bool> = (0..tris.len()).map(|i| i % 3 == 0).collect();
        let after: Vec<[Vec3; 3]> = (tris.iter().enumerate())
            .filter(|(i, _)| !removed[*i])
            .map(|(_, t)| *t)
            .chain(added.iter().copied())
            .collect();
        let base = Bvh::new(&tris);
        let patched = Patched::new(&base, removed.clone(), Bvh::new(&added));
        let brute = BruteForce::new(&after);
        // The same, shared and renumbered: added triangle i is 1000 + i.
        let shared = Patched::new(
            std::sync::Arc::new(Bvh::new(&tris)),
            removed.clone(),
            Bvh::new(&added),
        )
        .renumbered((0..added.len() as u32).map(|i| 1000 + i).collect());
        let (mut blocked, mut changed) = (0, 0);
        for _ in 0..4000 {
            let (a, b) = (rng.v() * 1.5, rng.v() * 1.5);
            let clear = patched.segment_clear(a, b);
            assert_eq!(clear, brute.segment_clear(a, b), "segment {a} {b}");
            blocked += usize::from(!clear);
            changed += usize::from(clear != base.segment_clear(a, b));
            let (h1, h2) = (
                patched.closest_hit(a, b - a, f32::INFINITY),
                brute.closest_hit(a, b - a, f32::INFINITY),
            );
            match (h1, h2) {
                (Some(x), Some(y)) => assert!((x.t - y.t).abs() < 1e-5, "{x:?} {y:?}"),
                (None, None) => {}
                other => panic!("patched and brute force disagree: {other:?}"),
            }
            let h3 = shared.closest_hit(a, b - a, f32::INFINITY);
            assert_eq!(h1.map(|h| h.t.to_bits()), h3.map(|h| h.t.to_bits()));
            if let (Some(x), Some(y)) = (h1, h3) {
                // The base's triangles keep their index, the added ones get theirs.
                let n = tris.len() as u32;
                let want = if x.triangle >= n {
                    x.triangle - n + 1000
                } else {
                    x.triangle
                };
                assert_eq!(y.triangle, want);
                assert!(x.triangle >= n || !removed[x.triangle as usize]);
            }
        }
        // Both what was taken away and what was added must have mattered.
        assert!(
            blocked > 500 && changed > 100,
            "{blocked} blocked, {changed} changed"
        );
    }

    #[test]
    fn answers_do_not_depend_on_the_triangles_around() {
        // A floor of small triangles and walls across it, all turned off the axes (so that
        // segments in the floor's plane meet it by rounding); segments in that plane.
        let turn = glam::Quat::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
        let mut tris = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                let (x, z) = (i as f32 * 0.1, j as f32 * 0.1);
                let p = |a: f32, b: f32| Vec3::new(x + a, 0.1, z + b);
                tris.push([p(0., 0.), p(0.1, 0.), p(0., 0.1)]);
                tris.push([p(0.1, 0.), p(0.1, 0.1), p(0., 0.1)]);
            }
        }
        for k in 0..5 {
            let x = 0.3 + 0.4 * k as f32;
            tris.push([
                Vec3::new(x, 0.1, 0.),
                Vec3::new(x, 0.5, 0.),
                Vec3::new(x, 0.1, 2.),
            ]);
        }
        // The same triangles among others far off: a BVH of another shape around them.
        let tris: Vec<[Vec3; 3]> = tris.iter().map(|t| t.map(|p| turn * p)).collect();
        let mut rng = Rng(0x1234_5678_9ABC_DEF1);
        let mut more = tris.clone();
        more.extend(
            soup(&mut rng, 3000)
                .into_iter()
                .map(|t| t.map(|p| p + Vec3::splat(5.0))),
        );
        let (a, b) = (Bvh::new(&tris), Bvh::new(&more));
        let brute = BruteForce::new(&tris);
        let (mut blocked, mut total) = (0, 0);
        for _ in 0..20_000 {
            let (x0, z0, x1, z1) = (
                rng.next() * 2.0,
                rng.next() * 2.0,
                rng.next() * 2.0,
                rng.next() * 2.0,
            );
            // In the floor's plane, and a hair above it.
            for y in [0.1f32, 0.1 + 1e-7] {
                let (p, q) = (turn * Vec3::new(x0, y, z0), turn * Vec3::new(x1, y, z1));
                let clear = a.segment_clear(p, q);
                assert_eq!(clear, b.segment_clear(p, q), "{p} {q}");
                assert_eq!(clear, brute.segment_clear(p, q), "{p} {q}");
                blocked += usize::from(!clear);
                total += 1;
            }
        }
        // The walls block; the floor, edge-on, does not.
        assert!(blocked > 1000 && blocked < total, "{blocked} of {total}");
    }

    #[test]
    fn empty_scene_never_hits() {
        let bvh = Bvh::new(&[]);
        assert!(bvh.segment_clear(Vec3::ZERO, Vec3::ONE));
        assert!(bvh.closest_hit(Vec3::ZERO, Vec3::ONE, 1.0).is_none());
    }

    #[test]
    fn a_filter_lets_rays_through_where_it_says() {
        // Two stacked floors; the upper one (index 0) is cut where u > v (barycentrics).
        let upper = [
            Vec3::new(-1., 1., -1.),
            Vec3::new(1., 1., -1.),
            Vec3::new(0., 1., 1.),
        ];
        let lower = [
            Vec3::new(-1., 0., -1.),
            Vec3::new(1., 0., -1.),
            Vec3::new(0., 0., 1.),
        ];
        let bvh = Bvh::with_filter(
            &[upper, lower],
            |t| t == 0,
            Arc::new(|_t: u32, u: f32, v: f32| u <= v),
        );
        let down = Vec3::NEG_Y;
        // x > 0 is towards vertex 1 (u large): cut, so the lower floor is hit.
        let cut = bvh.closest_hit(Vec3::new(0.5, 2., -0.5), down, f32::INFINITY);
        assert_eq!(cut.map(|h| h.triangle), Some(1));
        let kept = bvh.closest_hit(Vec3::new(-0.3, 2., 0.2), down, f32::INFINITY);
        assert_eq!(kept.map(|h| h.triangle), Some(0));
        assert!(!bvh.segment_clear(Vec3::new(0.5, 2., -0.5), Vec3::new(0.5, -1., -0.5)));
        assert!(bvh.segment_clear(Vec3::new(0.5, 2., -0.5), Vec3::new(0.5, 0.5, -0.5)));
        assert!(!bvh.segment_clear(Vec3::new(-0.3, 2., 0.2), Vec3::new(-0.3, 0.5, 0.2)));
    }
}
