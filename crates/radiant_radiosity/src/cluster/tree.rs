//! The node hierarchy of the clustered bake: volume clusters (a binary tree of bounding boxes
//! over the input triangles) above each input triangle's quadtree ([`Mesh`]).
//!
//! Every node has one id: mesh nodes keep theirs (`0..M`), clusters follow (`M..M + C`). The
//! cluster tree is built by median splits along the longest axis of the triangles' centroids,
//! in preorder, so a parent's id is always below its children's, among clusters as among mesh
//! nodes: one forward pass over the ids pushes down, one backward pass pulls up.
//!
//! A cluster depends only on the triangles it holds: its split, its order of triangles, its
//! box, area and harmonics are computed from its children, never from its place in the whole
//! (points are sampled on it by exact whole-number sums of its triangles' areas).
//! So after a geometry edit, a cluster of the same triangles is the same cluster bit for bit,
//! and what was refined for it can be kept ([`super::refine`]).

use glam::DVec3;

use crate::mesh::Mesh;

/// A volume cluster: the input triangles `order[first..end]`.
#[derive(Clone, Copy, Debug)]
pub struct Cluster {
    /// Bounding box (local frame), lower corner.
    pub lo: DVec3,
    /// Bounding box, upper corner.
    pub hi: DVec3,
    /// Total area of its triangles (local units).
    pub area: f64,
    /// The two children (node ids: clusters or input triangles' root nodes).
    pub children: [u32; 2],
    /// First index into [`Tree::order`].
    pub first: u32,
    /// One past the last index into [`Tree::order`].
    pub end: u32,
}

/// Per-node geometry, for every id (mesh nodes, then clusters).
#[derive(Clone, Debug)]
pub struct Tree {
    /// Number of mesh nodes (the first cluster's id).
    pub mesh_nodes: u32,
    /// The clusters; `clusters[0]` is the root when there are any.
    pub clusters: Vec<Cluster>,
    /// Input triangles in cluster order: each cluster covers a contiguous range.
    pub order: Vec<u32>,
    /// Prefix sums of the triangles' areas in `order` (length `order.len() + 1`), in units
    /// of 2⁻⁵² of the local frame: whole numbers, so the sums over a cluster's range are exact
    /// and depend on its triangles only (sampling a point on a cluster by area).
    pub cdf: Vec<u128>,
    /// Parent of every node (`u32::MAX` for the root).
    pub parent: Vec<u32>,
    /// Centre of every node's bounding sphere.
    pub center: Vec<DVec3>,
    /// Radius of every node's bounding sphere.
    pub radius: Vec<f64>,
    /// Area of every node (local units).
    pub area: Vec<f64>,
    /// Per cluster: the area-weighted mean of its triangles' normals in spherical harmonics
    /// ([`super::sh`]), so `sh::dot(normal_sh, sh::cosine(d))` is the mean of `max(0, n·d)`.
    pub normal_sh: Vec<[f64; 9]>,
    /// Per cluster: a cone holding all its triangles' normals, from its children's.
    pub cone: Vec<Cone>,
}

/// A cone of directions: its unit axis and the cosine and sine of its half-angle (a half-angle
/// of π or more: every direction).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cone {
    /// Unit axis.
    pub axis: DVec3,
    /// Cosine of the half-angle.
    pub cos: f64,
    /// Sine of the half-angle.
    pub sin: f64,
}

impl Cone {
    /// Every direction.
    pub const ALL: Cone = Cone {
        axis: DVec3::Z,
        cos: -1.0,
        sin: 0.0,
    };

    /// One direction.
    pub fn of(n: DVec3) -> Cone {
        Cone {
            axis: n,
            cos: 1.0,
            sin: 0.0,
        }
    }

    /// The largest cosine between a direction of the cone and the unit direction `d`.
    #[inline]
    pub fn max_cos(&self, d: DVec3) -> f64 {
        if self.cos <= -1.0 {
            return 1.0;
        }
        let c = self.axis.dot(d).clamp(-1.0, 1.0);
        if c >= self.cos {
            return 1.0;
        }
        // cos(α − θ) with α the angle to the axis, θ the half-angle (α > θ here).
        c * self.cos + (1.0 - c * c).max(0.0).sqrt() * self.sin
    }

    /// The smallest cone holding both (a little wider, against rounding).
    pub fn merge(a: Cone, b: Cone) -> Cone {
        if a.cos <= -1.0 || b.cos <= -1.0 {
            return Cone::ALL;
        }
        let (ta, tb) = (a.cos.clamp(-1.0, 1.0).acos(), b.cos.clamp(-1.0, 1.0).acos());
        let phi = a.axis.dot(b.axis).clamp(-1.0, 1.0).acos();
        if phi + tb <= ta {
            return a;
        }
        if phi + ta <= tb {
            return b;
        }
        let theta = (phi + ta + tb) / 2.0 + 1e-9;
        if theta >= std::f64::consts::PI {
            return Cone::ALL;
        }
        // The new axis: from a's axis towards b's by theta − ta.
        let perp = (b.axis - a.axis * a.axis.dot(b.axis)).normalize_or_zero();
        if perp == DVec3::ZERO {
            return Cone::ALL;
        }
        let turn = theta - ta;
        let axis = (a.axis * turn.cos() + perp * turn.sin()).normalize();
        Cone {
            axis,
            cos: theta.cos(),
            sin: theta.sin(),
        }
    }
}

impl Tree {
    /// Builds the clusters over `mesh`'s input triangles.
    pub fn new(mesh: &Mesh) -> Tree {
        let m = mesh.nodes.len() as u32;
        let k = mesh.roots.len();
        let mut order: Vec<u32> = (0..k as u32).collect();
        let centroids: Vec<DVec3> = mesh
            .roots
            .iter()
            .map(|&r| mesh.nodes[r as usize].centroid)
            .collect();
        let mut tree = Tree {
            mesh_nodes: m,
            clusters: Vec::with_capacity(k.saturating_sub(1)),
            order: Vec::new(),
            cdf: Vec::new(),
            parent: Vec::new(),
            center: Vec::new(),
            radius: Vec::new(),
            area: Vec::new(),
            normal_sh: Vec::new(),
            cone: Vec::new(),
        };
        if k > 1 {
            tree.split(mesh, &centroids, &mut order, 0);
        }
        tree.order = order;
        let mut cdf = Vec::with_capacity(k + 1);
        let mut acc = 0u128;
        cdf.push(acc);
        for &t in &tree.order {
            acc += fixed(mesh.nodes[mesh.roots[t as usize] as usize].area);
            cdf.push(acc);
        }
        tree.cdf = cdf;
        let total = m as usize + tree.clusters.len();
        tree.parent = vec![u32::MAX; total];
        tree.center = Vec::with_capacity(total);
        tree.radius = Vec::with_capacity(total);
        tree.area = Vec::with_capacity(total);
        for (i, n) in mesh.nodes.iter().enumerate() {
            tree.parent[i] = n.parent;
            tree.center.push(n.centroid);
            tree.radius.push(
                n.v.iter()
                    .map(|v| (*v - n.centroid).length())
                    .fold(0.0, f64::max),
            );
            tree.area.push(n.area);
        }
        for (c, cl) in tree.clusters.iter().enumerate() {
            for ch in cl.children {
                tree.parent[ch as usize] = m + c as u32;
            }
            tree.center.push((cl.lo + cl.hi) * 0.5);
            tree.radius.push((cl.hi - cl.lo).length() * 0.5);
            tree.area.push(cl.area);
        }
        tree.normal_sh = vec![[0.0; 9]; tree.clusters.len()];
        for c in (0..tree.clusters.len()).rev() {
            let mut acc = [0.0; 9];
            let mut w = 0.0;
            for ch in tree.clusters[c].children {
                let a = tree.area[ch as usize];
                let y = match ch.checked_sub(m) {
                    Some(cc) => tree.normal_sh[cc as usize],
                    None => super::sh::basis(mesh.nodes[ch as usize].normal),
                };
                for k in 0..9 {
                    acc[k] += a * y[k];
                }
                w += a;
            }
            tree.normal_sh[c] = if w > 0.0 { acc.map(|v| v / w) } else { acc };
        }
        tree.cone = vec![Cone::ALL; tree.clusters.len()];
        for c in (0..tree.clusters.len()).rev() {
            let [a, b] = tree.clusters[c].children.map(|ch| match ch.checked_sub(m) {
                Some(cc) => tree.cone[cc as usize],
                None => Cone::of(mesh.nodes[ch as usize].normal),
            });
            tree.cone[c] = Cone::merge(a, b);
        }
        tree
    }

    /// The largest cosine between the unit direction `d` and a normal of node `id` (a
    /// triangle's own; a cluster's, bounded by its cone).
    #[inline]
    pub fn max_cos(&self, mesh: &Mesh, id: u32, d: DVec3) -> f64 {
        match id.checked_sub(self.mesh_nodes) {
            Some(c) => self.cone[c as usize].max_cos(d),
            None => mesh.nodes[id as usize].normal.dot(d),
        }
    }

    /// Clusters `items` (input triangles, a slice of the final order starting at `first`) and
    /// returns the id of the node that holds them.
    fn split(&mut self, mesh: &Mesh, centroids: &[DVec3], items: &mut [u32], first: u32) -> u32 {
        if items.len() == 1 {
            return mesh.roots[items[0] as usize];
        }
        let id = self.clusters.len();
        self.clusters.push(Cluster {
            lo: DVec3::ZERO,
            hi: DVec3::ZERO,
            area: 0.0,
            children: [0; 2],
            first,
            end: first + items.len() as u32,
        });
        let (mut clo, mut chi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for &t in items.iter() {
            clo = clo.min(centroids[t as usize]);
            chi = chi.max(centroids[t as usize]);
        }
        let ext = chi - clo;
        let axis = if ext.x >= ext.y && ext.x >= ext.z {
            0
        } else if ext.y >= ext.z {
            1
        } else {
            2
        };
        let mid = items.len() / 2;
        // Ties broken by index, so the tree does not depend on the selection's internals.
        items.select_nth_unstable_by(mid, |&a, &b| {
            centroids[a as usize][axis]
                .total_cmp(&centroids[b as usize][axis])
                .then(a.cmp(&b))
        });
        let (left, right) = items.split_at_mut(mid);
        let a = self.split(mesh, centroids, left, first);
        let b = self.split(mesh, centroids, right, first + mid as u32);
        // From the children, so that the cluster's numbers depend on its triangles only.
        let ((alo, ahi, aa), (blo, bhi, ba)) = (self.bounds(mesh, a), self.bounds(mesh, b));
        let c = &mut self.clusters[id];
        c.lo = alo.min(blo);
        c.hi = ahi.max(bhi);
        c.area = aa + ba;
        c.children = [a, b];
        self.mesh_nodes + id as u32
    }

    /// Box and area of a node while the tree is built (clusters below it are done).
    fn bounds(&self, mesh: &Mesh, id: u32) -> (DVec3, DVec3, f64) {
        match id.checked_sub(self.mesh_nodes) {
            Some(c) => {
                let c = &self.clusters[c as usize];
                (c.lo, c.hi, c.area)
            }
            None => {
                let n = &mesh.nodes[id as usize];
                let lo = n.v[0].min(n.v[1]).min(n.v[2]);
                let hi = n.v[0].max(n.v[1]).max(n.v[2]);
                (lo, hi, n.area)
            }
        }
    }

    /// The root node: the first cluster, or the only triangle.
    pub fn root(&self, mesh: &Mesh) -> u32 {
        if self.clusters.is_empty() {
            mesh.roots.first().copied().unwrap_or(0)
        } else {
            self.mesh_nodes
        }
    }

    /// The cluster of a node id, if it is one.
    #[inline]
    pub fn cluster(&self, id: u32) -> Option<&Cluster> {
        id.checked_sub(self.mesh_nodes)
            .and_then(|c| self.clusters.get(c as usize))
    }

    /// Number of node ids.
    pub fn len(&self) -> usize {
        self.parent.len()
    }

    /// Whether there are no nodes.
    pub fn is_empty(&self) -> bool {
        self.parent.is_empty()
    }

    /// The input triangle whose share of cluster `c`'s area holds `u` in `[0, 1)`, by a binary
    /// search of the exact prefix sums: it depends on the cluster only. A cluster of triangles
    /// too small to count is sampled evenly.
    #[inline]
    pub fn pick(&self, c: &Cluster, u: f64) -> u32 {
        let (first, end) = (c.first as usize, c.end as usize);
        let (a, b) = (self.cdf[first], self.cdf[end]);
        if b == a {
            let k = ((u * (end - first) as f64) as usize).min(end - first - 1);
            return self.order[first + k];
        }
        // u in 2⁻⁵³ steps, times the cluster's area: exact in 128 bits.
        let x = a + (((b - a) * (u.clamp(0.0, 1.0) * (1u64 << 53) as f64) as u128) >> 53);
        let k = self.cdf[first + 1..=end].partition_point(|&v| v <= x);
        self.order[(first + k).min(end - 1)]
    }
}

/// An area (local units, at most a few) as a whole number of 2⁻⁵² steps.
fn fixed(area: f64) -> u128 {
    if area.is_finite() && area > 0.0 {
        (area * (1u64 << 52) as f64).round() as u128
    } else {
        0
    }
}
