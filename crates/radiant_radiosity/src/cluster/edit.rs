//! Geometry edits of a clustered bake: which nodes of the edited scene are the old ones, what
//! moved, and where the old refinement visited a pair of old nodes.
//!
//! A node of the edited scene *is* an old node when it holds the same triangles, unmoved: an
//! input triangle matched by [`RootMatch`] (surface, index in it, exact position), a cluster
//! whose two children are an old cluster's two children. Its box, area, harmonics and ray
//! seeds are then the old ones bit for bit ([`super::tree`] computes them from the children
//! only). It is *settled* when its estimates and every estimate below it are the old ones too:
//! then refinement decides below it exactly as before. A pair of settled nodes whose shaft
//! (the capsule around both bounding spheres) meets nothing that moved keeps everything the old
//! refinement made of it, bit for bit, so the edit copies it from the [`Record`]. A link of old
//! nodes with as many samples keeps its form factor when its shaft is clear, or else when
//! none of its own segments (drawn again, not cast) meets what moved ([`Moved`]); the same
//! holds for an element's enclosure probes.

use std::sync::atomic::{AtomicBool, Ordering};

use glam::{DVec3, Vec3};
use radiant_visibility::{Hit, Visibility};

use super::record::{Op, Pos, Record};
use super::refine::{Cursor, Link};
use super::tree::Tree;
use crate::hierarchy::RootMatch;
use crate::mesh::Mesh;

/// No node.
const NONE: u32 = u32::MAX;

/// Room left around what moved: past the `f32` rounding of the rays' ends and the ray caster's
/// watertight slack (the local frame has unit extent).
const MARGIN: f64 = 1e-5;

/// At most this many spheres stand for what moved.
const SPHERES: usize = 32;

/// The bake before a geometry edit, as the edited refinement reads it.
pub(crate) struct Before<'a> {
    /// The old scene's parts.
    pub old: Old<'a>,
    /// Per new node: the old node it is, or [`NONE`].
    old_of_new: Vec<u32>,
    /// Per old node: the new node it is, or [`NONE`].
    new_of_old: Vec<u32>,
    /// Per new node: an old node whose estimates, and all below it, are the old ones.
    settled: Vec<bool>,
    /// Where the triangles that came and went lie.
    moved: &'a Moved,
}

/// An old link in new node numbers, by `new_of_old` (per old node, the new node).
pub(crate) fn remap(new_of_old: &[u32], l: Link) -> Link {
    Link {
        recv: new_of_old[l.recv as usize],
        src: new_of_old[l.src as usize],
        ff: l.ff,
    }
}

/// Where the triangles that came and went in an edit lie (local frame): at most [`SPHERES`]
/// bounding spheres, and one around them all. What no segment or ray can reach through them is
/// what the edit left as it was.
pub(crate) struct Moved {
    spheres: Vec<(DVec3, f64)>,
    all: (DVec3, f64),
}

impl Moved {
    /// Around `triangles` (those that came, and those that went).
    pub fn new(triangles: &[[DVec3; 3]]) -> Moved {
        let spheres = spheres(triangles);
        let all = around(&spheres);
        Moved { spheres, all }
    }

    /// Whether nothing that moved comes within `wide` (and [`MARGIN`]) of the segment `a b`.
    pub fn clear_of(&self, a: DVec3, b: DVec3, wide: f64) -> bool {
        let clear =
            |&(c, radius): &(DVec3, f64)| distance(c, a, b - a, 1.0) > wide + radius + MARGIN;
        clear(&self.all) || self.spheres.iter().all(clear)
    }

    /// Whether everything that moved lies behind the plane through `p` with unit normal `n`
    /// (beyond [`MARGIN`]): then no ray leaving a point of that plane on its front side can
    /// meet it.
    pub fn behind(&self, p: DVec3, n: DVec3) -> bool {
        let behind = |&(c, radius): &(DVec3, f64)| n.dot(c - p) < -(radius + MARGIN);
        behind(&self.all) || self.spheres.iter().all(behind)
    }

    /// Whether the ray from `o` along `d` (to any distance) may meet what moved.
    pub fn ray_meets(&self, o: DVec3, d: DVec3) -> bool {
        let near =
            |&(c, radius): &(DVec3, f64)| distance(c, o, d, f64::INFINITY) <= radius + MARGIN;
        near(&self.all) && self.spheres.iter().any(near)
    }
}

/// The distance from `c` to the points `o + t d`, `t` in `[0, tmax]`.
fn distance(c: DVec3, o: DVec3, d: DVec3, tmax: f64) -> f64 {
    let len2 = d.length_squared();
    let t = if len2 > 0.0 {
        ((c - o).dot(d) / len2).clamp(0.0, tmax)
    } else {
        0.0
    };
    (o + d * t).distance(c)
}

/// The old bake's parts an edit needs.
pub(crate) struct Old<'a> {
    pub mesh: &'a Mesh,
    pub tree: &'a Tree,
    pub record: &'a Record,
    pub bhat: &'a [f64],
    pub rho: &'a [f64],
    pub eps: f64,
}

/// The edited scene's parts an edit needs.
pub(crate) struct New<'a> {
    pub mesh: &'a Mesh,
    pub tree: &'a Tree,
    pub bhat: &'a [f64],
    pub rho: &'a [f64],
}

impl<'a> Before<'a> {
    /// Matches the edited scene's nodes against the old ones.
    pub fn new(old: Old<'a>, new: New<'_>, matched: &RootMatch, moved: &'a Moved) -> Before<'a> {
        let nm = new.tree.mesh_nodes as usize;
        let mut old_of_new = vec![NONE; new.tree.len()];
        let mut new_of_old = vec![NONE; old.tree.len()];
        for (o, &n) in matched.new_of_old_node.iter().enumerate() {
            if n != NONE {
                old_of_new[n as usize] = o as u32;
                new_of_old[o] = n;
            }
        }
        // Clusters, children first: an old cluster when its children are one's children.
        for c in (0..new.tree.clusters.len()).rev() {
            let [a, b] = new.tree.clusters[c].children;
            let (oa, ob) = (old_of_new[a as usize], old_of_new[b as usize]);
            if oa == NONE || ob == NONE {
                continue;
            }
            let p = old.tree.parent[oa as usize];
            if p == NONE || p != old.tree.parent[ob as usize] {
                continue;
            }
            if old
                .tree
                .cluster(p)
                .is_some_and(|pc| pc.children == [oa, ob])
            {
                old_of_new[nm + c] = p;
                new_of_old[p as usize] = (nm + c) as u32;
            }
        }
        // Settled, children first: mesh nodes (children after parents), then clusters.
        let mut settled = vec![false; new.tree.len()];
        let same = |n: usize| {
            let o = old_of_new[n];
            o != NONE
                && new.bhat[n].to_bits() == old.bhat[o as usize].to_bits()
                && new.rho[n].to_bits() == old.rho[o as usize].to_bits()
        };
        for n in (0..nm).rev() {
            let node = &new.mesh.nodes[n];
            settled[n] = same(n)
                && (node.is_leaf() || (0..4).all(|k| settled[(node.first_child + k) as usize]));
        }
        for c in (0..new.tree.clusters.len()).rev() {
            let n = nm + c;
            let [a, b] = new.tree.clusters[c].children;
            settled[n] = same(n) && settled[a as usize] && settled[b as usize];
        }
        Before {
            old,
            old_of_new,
            new_of_old,
            settled,
            moved,
        }
    }

    /// The root pair's cursor: the old root pair, in its place.
    pub fn root_cursor(&self) -> Cursor {
        if self.old.record.ops.is_empty() {
            return Cursor::Unknown;
        }
        let root = self.old.tree.root(self.old.mesh);
        Cursor::At {
            pos: Pos::default(),
            r: root,
            s: root,
        }
    }

    /// Whether `cur` is the old pair of the same nodes as `r ← s`.
    #[inline]
    pub fn same_pair(&self, r: u32, s: u32, cur: Cursor) -> bool {
        matches!(cur, Cursor::At { r: ro, s: so, .. }
            if self.old_of_new[r as usize] == ro && self.old_of_new[s as usize] == so)
    }

    /// Whether a cursor followed by position agrees with what `r` and `s` are: an old node in
    /// the pair must be the very node the cursor names (a node that changed has no old self,
    /// and takes whatever stood in its place).
    #[inline]
    pub fn positions_agree(&self, r: u32, s: u32, cur: Cursor) -> bool {
        let Cursor::At { r: ro, s: so, .. } = cur else {
            return false;
        };
        let agree = |n: u32, o: u32| {
            let old = self.old_of_new[n as usize];
            old == NONE || old == o
        };
        agree(r, ro) && agree(s, so)
    }

    /// Whether new node `n` is an old one with the old estimates all below it.
    #[inline]
    pub fn settled(&self, n: u32) -> bool {
        self.settled[n as usize]
    }

    /// Whether nothing that moved comes near the shaft of `r ← s` (new nodes, `tree` the new
    /// tree): the capsule around the segment between their centres, as wide as the larger
    /// bounding sphere, holds every segment between points of the two.
    pub fn clear_of_changes(&self, tree: &Tree, r: u32, s: u32) -> bool {
        let (a, b) = (tree.center[r as usize], tree.center[s as usize]);
        let wide = tree.radius[r as usize].max(tree.radius[s as usize]);
        self.moved.clear_of(a, b, wide)
    }

    /// A visibility that casts no ray but notes whether a segment asked of it may meet what
    /// moved (comes within [`MARGIN`] of the spheres around the triangles that came and went).
    pub fn segments(&self) -> Changes<'_> {
        Changes {
            before: self,
            met: AtomicBool::new(false),
        }
    }

    /// An old link in the new numbering (both its nodes are old ones).
    #[inline]
    pub fn remap(&self, l: Link) -> Link {
        remap(&self.new_of_old, l)
    }

    /// Per old node, the new node it is (or [`NONE`]): what [`Before::remap`] reads, kept when
    /// the rest goes.
    pub fn into_new_of_old(self) -> Vec<u32> {
        self.new_of_old
    }

    /// The old children of old node `id` (none for an element).
    fn old_children(&self, id: u32) -> ([u32; 4], usize) {
        match self.old.tree.cluster(id) {
            Some(c) => ([c.children[0], c.children[1], 0, 0], 2),
            None => match self.old.mesh.nodes[id as usize].first_child {
                crate::mesh::NO_CHILD => ([0; 4], 0),
                f => ([f, f + 1, f + 2, f + 3], 4),
            },
        }
    }

    /// The old pairs a split of the old pair `(r, s)` made.
    fn old_pairs(&self, op: Op, r: u32, s: u32) -> [(u32, u32); 4] {
        match op {
            Op::SplitSelf => {
                let (c, _) = self.old_children(r);
                let (a, b) = (c[0], c[1]);
                [(a, a), (a, b), (b, a), (b, b)]
            }
            Op::SplitRecv => {
                let (c, _) = self.old_children(r);
                c.map(|x| (x, s))
            }
            _ => {
                let (c, _) = self.old_children(s);
                c.map(|x| (r, x))
            }
        }
    }

    /// The cursors of the children of a split `op` into `n` pairs, at a pair whose cursor is
    /// `cur`.
    pub fn child_cursors(&self, op: Op, n: usize, cur: Cursor) -> [Cursor; 4] {
        let Cursor::At { pos, r, s } = cur else {
            // Near: the pair that holds this one holds its children too.
            return [cur; 4];
        };
        let old = self.old.record.op(pos);
        if old != op {
            // Split another way: the children may still be found below; linked or culled:
            // nothing below was visited.
            return [if old.is_split() {
                Cursor::Near { pos, r, s }
            } else {
                Cursor::Above
            }; 4];
        }
        // Followed by position, the old node split may have another number of children.
        let split = if op == Op::SplitSrc { s } else { r };
        if self.old_children(split).1 != n && op != Op::SplitSelf {
            return [Cursor::Near { pos, r, s }; 4];
        }
        let pairs = self.old_pairs(op, r, s);
        let mut out = [Cursor::Unknown; 4];
        let mut p = self.old.record.first_child(pos);
        for k in 0..n {
            out[k] = Cursor::At {
                pos: p,
                r: pairs[k].0,
                s: pairs[k].1,
            };
            if k + 1 < n {
                p = self.old.record.skip(p);
            }
        }
        out
    }

    /// Where the old refinement visited the pair of new nodes `r ← s`, when both are old
    /// ones: followed down the old record from the root, or from the pair a [`Cursor::Near`]
    /// names.
    pub fn lookup(&self, r: u32, s: u32, from: Cursor) -> Cursor {
        let (x, y) = (self.old_of_new[r as usize], self.old_of_new[s as usize]);
        if x == NONE || y == NONE || self.old.record.ops.is_empty() {
            return from;
        }
        let (ax, ay) = (self.ancestors(x), self.ancestors(y));
        // Where `a` and `b` stand on the ways up from `x` and `y`.
        let root = self.old.tree.root(self.old.mesh);
        let (mut a, mut b, mut pos) = match from {
            Cursor::Near { pos, r, s } => (r, s, pos),
            _ => (root, root, Pos::default()),
        };
        let (Some(mut ia), Some(mut ib)) = (
            ax.iter().rposition(|&n| n == a),
            ay.iter().rposition(|&n| n == b),
        ) else {
            return Cursor::Unknown;
        };
        // The child of `a` (at `ia` on the way up `anc`) on the way down: its place among
        // `a`'s children.
        let toward = |a: u32, ia: &mut usize, anc: &[u32]| -> Option<usize> {
            let next = *anc.get(ia.checked_sub(1)?)?;
            let (c, n) = self.old_children(a);
            let k = c[..n].iter().position(|&ch| ch == next)?;
            *ia -= 1;
            Some(k)
        };
        loop {
            if a == x && b == y {
                return Cursor::At { pos, r: a, s: b };
            }
            let op = self.old.record.op(pos);
            let k = match op {
                Op::Cull | Op::Link | Op::Zero => return Cursor::Above,
                // The split passed one of the nodes itself: the pair was not visited, but
                // pairs below it may have been.
                Op::SplitSelf if a == x || b == y => return Cursor::Near { pos, r: a, s: b },
                Op::SplitRecv if a == x => return Cursor::Near { pos, r: a, s: b },
                Op::SplitSrc if b == y => return Cursor::Near { pos, r: a, s: b },
                Op::SplitSelf => {
                    let (Some(i), Some(j)) = (toward(a, &mut ia, &ax), toward(b, &mut ib, &ay))
                    else {
                        return Cursor::Unknown;
                    };
                    let (c, _) = self.old_children(a);
                    (a, b) = (c[i], c[j]);
                    2 * i + j
                }
                Op::SplitRecv => {
                    let Some(i) = toward(a, &mut ia, &ax) else {
                        return Cursor::Unknown;
                    };
                    a = self.old_children(a).0[i];
                    i
                }
                Op::SplitSrc => {
                    let Some(j) = toward(b, &mut ib, &ay) else {
                        return Cursor::Unknown;
                    };
                    b = self.old_children(b).0[j];
                    j
                }
            };
            let mut p = self.old.record.first_child(pos);
            for _ in 0..k {
                p = self.old.record.skip(p);
            }
            pos = p;
        }
    }

    /// Old node `x` and its ancestors.
    fn ancestors(&self, x: u32) -> Vec<u32> {
        let mut out = Vec::with_capacity(48);
        let mut n = x;
        while n != NONE {
            out.push(n);
            n = self.old.tree.parent[n as usize];
        }
        out
    }

    /// New nodes that are old ones.
    pub fn kept_nodes(&self) -> usize {
        self.old_of_new.iter().filter(|&&o| o != NONE).count()
    }
}

/// See [`Before::segments`].
pub(crate) struct Changes<'a> {
    before: &'a Before<'a>,
    met: AtomicBool,
}

impl Changes<'_> {
    /// Whether a segment asked of it may meet what moved.
    pub fn met(&self) -> bool {
        self.met.load(Ordering::Relaxed)
    }
}

impl Visibility for Changes<'_> {
    fn segment_clear(&self, a: Vec3, b: Vec3) -> bool {
        if !self.before.moved.clear_of(a.as_dvec3(), b.as_dvec3(), 0.0) {
            self.met.store(true, Ordering::Relaxed);
        }
        // Either answer: the form factor drawn with it is not kept.
        true
    }

    fn closest_hit(&self, _origin: Vec3, _dir: Vec3, _tmax: f32) -> Option<Hit> {
        // Not asked by a form factor; never let it pass for clear.
        self.met.store(true, Ordering::Relaxed);
        None
    }
}

/// A sphere around `spheres` (none: an empty one far away).
fn around(spheres: &[(DVec3, f64)]) -> (DVec3, f64) {
    let (lo, hi) = spheres.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), &(c, r)| (lo.min(c - r), hi.max(c + r)),
    );
    if spheres.is_empty() {
        return (DVec3::splat(1e30), 0.0);
    }
    ((lo + hi) * 0.5, (hi - lo).length() * 0.5)
}

/// At most [`SPHERES`] bounding spheres around `triangles`: split along the longest axis of
/// their centroids until there are that many groups.
fn spheres(triangles: &[[DVec3; 3]]) -> Vec<(DVec3, f64)> {
    let mut groups: Vec<Vec<[DVec3; 3]>> = vec![triangles.to_vec()];
    while groups.len() < SPHERES {
        let Some((i, _)) = groups
            .iter()
            .enumerate()
            .filter(|(_, g)| g.len() > 1)
            .max_by_key(|(_, g)| g.len())
        else {
            break;
        };
        let mut g = groups.swap_remove(i);
        let centroid = |t: &[DVec3; 3]| (t[0] + t[1] + t[2]) / 3.0;
        let (lo, hi) = g.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), t| (lo.min(centroid(t)), hi.max(centroid(t))),
        );
        let axis = (hi - lo).max_position();
        g.sort_by(|a, b| centroid(a)[axis].total_cmp(&centroid(b)[axis]));
        let rest = g.split_off(g.len() / 2);
        groups.push(g);
        groups.push(rest);
    }
    groups
        .iter()
        .filter(|g| !g.is_empty())
        .map(|g| {
            let (lo, hi) = g.iter().flatten().fold(
                (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
                |(lo, hi), v| (lo.min(*v), hi.max(*v)),
            );
            ((lo + hi) * 0.5, (hi - lo).length() * 0.5)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn what_lies_behind_a_plane_no_ray_from_its_front_meets() {
        // A unit triangle moved to 1 below the floor y = 0 (its sphere's radius is 0.71), and
        // one lying on the floor.
        let below = Moved::new(&[[
            DVec3::new(0.0, -1.0, 0.0),
            DVec3::new(1.0, -1.0, 0.0),
            DVec3::new(0.0, -1.0, 1.0),
        ]]);
        let on = Moved::new(&[[DVec3::ZERO, DVec3::X, DVec3::Z]]);
        let (p, up) = (DVec3::new(5.0, 0.0, 5.0), DVec3::Y);
        assert!(below.behind(p, up));
        assert!(!below.behind(p, -up), "in front of a floor facing down");
        assert!(!on.behind(p, up), "touching the plane is not behind it");
        // What behind() settles, ray_meets agrees with: no upward ray from the floor meets it.
        for k in 0..64 {
            let a = f64::from(k) * 0.1;
            let d = DVec3::new(a.cos(), 0.05 + f64::from(k % 7) * 0.1, a.sin());
            assert!(!below.ray_meets(p + up * 1e-5, d), "{d}");
        }
    }
}
