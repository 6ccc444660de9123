//! The node hierarchy of the clustered bake: volume clusters (a binary tree of bounding boxes
//! over the input triangles) above each input triangle's quadtree ([`Mesh`]).
//!
//! Every node has one id: mesh nodes keep theirs (`0..M`), clusters follow (`M..M + C`). The
//! cluster tree is built by median splits along the longest axis of the triangles' centroids,
//! in preorder, so a parent's id is always below its children's, among clusters as among mesh
//! nodes: one forward pass over the ids pushes down, one backward pass pulls up.
//!
//! A cluster depends only on the triangles it holds: its split, its order of triangles, its
//! box, area and harmonics are computed from its children, never from its place in the whole.
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
            parent: Vec::new(),
            center: Vec::new(),
            radius: Vec::new(),
            area: Vec::new(),
            normal_sh: Vec::new(),
        };
        if k > 1 {
            tree.split(mesh, &centroids, &mut order, 0);
        }
        tree.order = order;
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
        tree
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

    /// The input triangle whose share of cluster `c`'s area holds `u` in `[0, 1)`: found by
    /// going down the children by their areas, so it depends on the cluster only.
    #[inline]
    pub fn pick(&self, mesh: &Mesh, c: &Cluster, u: f64) -> u32 {
        let (mut c, mut u) = (c, u);
        loop {
            let [a, b] = c.children;
            let (wa, wb) = (self.area[a as usize], self.area[b as usize]);
            let x = u * (wa + wb);
            let (next, v) = if x < wa || wb <= 0.0 {
                (a, if wa > 0.0 { x / wa } else { 0.0 })
            } else {
                (b, (x - wa) / wb)
            };
            u = v.clamp(0.0, 1.0);
            match self.cluster(next) {
                Some(cl) => c = cl,
                None => return mesh.nodes[next as usize].root,
            }
        }
    }
}
