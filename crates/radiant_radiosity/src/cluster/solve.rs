//! The solve over links at every level: one sweep pulls radiosity up (area-weighted means,
//! elements inside closed geometry weighing 0), gathers `Σ F B̄_s` at every receiver node,
//! pushes the gathered light down to the elements and sets `B = S + ρ G` there (Jacobi, as
//! Hanrahan et al.'s "gather, push-pull"). All sums in `f64`.
//!
//! Clusters are directional on both ends ([`super::sh`]): a cluster source shines towards a
//! receiver with the radiosity of its parts weighted by how much they face it (pulled up as
//! harmonics of radiosity × normal); a cluster receiver gathers its light as harmonics of the
//! incoming directions, and each triangle under it takes that light by its own normal. A closed
//! box of one cluster thus lights its inner faces, not its outside.

use rayon::prelude::*;

use glam::DVec3;

use super::refine::{KAPPA_MIN, Link};
use super::sh;
use super::tree::Tree;
use crate::BakeError;
use crate::exposure;
use crate::mesh::Mesh;
use crate::solve::{SolveError, Stall};
use crate::system::Rgb;

/// Links in compressed rows by receiver node, with the tree's up and down passes.
pub struct HierSystem {
    /// Number of mesh nodes (ids below are mesh nodes, the rest clusters).
    mesh_nodes: u32,
    /// Row `n` is `src[row[n]..row[n + 1]]`, over every node id.
    row: Vec<u64>,
    /// Source node of each link.
    src: Vec<u32>,
    /// Form factor of each link.
    ff: Vec<f32>,
    /// Parent of every node (`u32::MAX` for the root).
    parent: Vec<u32>,
    /// Weight of every node: the exposed area of its elements (outside closed geometry).
    weight: Vec<f64>,
    /// Per node: its whole area over its live (exposed) area; 1 where nothing is enclosed (or
    /// nothing lives).
    dilution: Vec<f64>,
    /// Per element: what its gather is scaled by so that an element enclosed in part gathers
    /// at most [`GATHER_AT_MOST`] hemispheres (1 elsewhere). Measured at the first sweep, not
    /// when the system is made: a bake still holds its refinement's record then, and this
    /// sweep's temporaries on top of it raised the 1 M-triangle room's peak by 0.4 GB.
    cap: std::sync::OnceLock<Vec<f64>>,
    /// Children of every cluster.
    cluster_children: Vec<[u32; 2]>,
    /// Mesh: first child of each node (`u32::MAX` for elements).
    first_child: Vec<u32>,
    /// Mesh: element → node.
    leaf_node: Vec<u32>,
    /// Mesh: node → its element, for leaves.
    node_leaf: Vec<u32>,
    /// Element areas.
    pub area: Vec<f64>,
    /// Element reflectance.
    pub rho: Vec<Rgb>,
    /// Element source term (emission plus direct light).
    pub source: Vec<Rgb>,
    /// Per element: its exposed probe points, of [`exposure::POINTS`].
    pub(crate) live: Vec<u8>,
    /// Elements inside closed geometry (no exposed point).
    pub(crate) dead: Vec<bool>,
    /// Centre of every node (directions between clusters).
    center: Vec<DVec3>,
    /// Mesh: unit normal of every node.
    normal: Vec<DVec3>,
    /// Per cluster: harmonics of its normals, by area (the tree's: what the refinement
    /// divided a cluster receiver's form factors by).
    normal_sh: Vec<[f64; 9]>,
    /// Per cluster: harmonics of its normals by exposed area ([`HierSystem::weight`]); the
    /// tree's where nothing below it is enclosed. See [`HierSystem::live_harmonics`].
    live_sh: Vec<[f64; 9]>,
    /// How the elements take their clusters' light by their own visibility
    /// ([`super::transfer`]); `None`: by their normals alone.
    transfer: Option<Transfer>,
}

/// [`HierSystem::set_transfer`]'s harmonics.
#[derive(Clone, Debug)]
struct Transfer {
    /// Per element, `max(0, n·ω) V(ω)` as harmonics.
    element: Vec<[f32; 9]>,
    /// Per element, the cluster above its input triangle (`u32::MAX`: none).
    cluster: Vec<u32>,
    /// Per cluster, its live elements' transfers by live area: the mean share its light is
    /// divided by, towards a direction.
    mean: Vec<[f64; 9]>,
}

/// The buffers a sweep works in ([`HierSystem::sweep_in`]): per node its pulled radiosity and
/// gathered light, per cluster its pulled and gathered harmonics. A loop of sweeps keeps them:
/// made afresh every sweep they were a third of the solve's time on this machine, the kernel
/// zeroing their pages (Sponza's are about 160 MB).
#[derive(Debug, Default)]
pub struct SweepScratch {
    nodes: Vec<Rgb>,
    directional: Vec<Sh3>,
    gathered: Vec<Rgb>,
    cluster_gathered: Vec<Sh3>,
}

/// Links in compressed rows by receiver node: row `n` is `src[row[n]..row[n + 1]]` with form
/// factors `ff`, over every node id (mesh nodes, then clusters).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rows {
    /// Row offsets, one more than nodes.
    pub row: Vec<u64>,
    /// Source node of each link.
    pub src: Vec<u32>,
    /// Form factor of each link.
    pub ff: Vec<f32>,
}

/// [`Rows`], borrowed.
#[derive(Clone, Copy, Debug)]
pub struct RowsRef<'a> {
    /// Row offsets.
    pub row: &'a [u64],
    /// Sources.
    pub src: &'a [u32],
    /// Form factors.
    pub ff: &'a [f32],
}

/// The stopping measure of clustered sweeps: a sweep's update relative to the bounced light
/// (`b − source`: in a sunlit level the direct light dominates `‖b‖`, and a change measured
/// against it stopped Sponza after 4 sweeps while its shade was still filling in), times
/// `q / (1 − q)`, `q` the observed contraction; with the stall rule.
///
/// Where the contraction has settled (two sweeps in a row within 1 % of each other, below
/// [`Sweeping::MAX_Q`]), the error left is mostly along one mode that shrinks by `q` a sweep,
/// and the sweep's update is carried on to where that mode ends: `b += q / (1 − q) (b − b_before)`
/// (Aitken's extrapolation; [`Sweeping::extrapolate`]). From then on the estimate keeps that
/// `q` as its least contraction: the update that follows no longer shows it, but what is left
/// of the mode still shrinks that slowly.
#[derive(Clone, Copy, Debug)]
pub struct Sweeping {
    /// The last sweep's update (NaN before the first).
    last_update: f64,
    /// The contraction the last sweep observed (NaN before the second).
    last_q: f64,
    /// The least contraction the estimate uses: that of the last extrapolation (0 before).
    held_q: f64,
    /// Sweeps since the last extrapolation, or since the start.
    since: u32,
    /// The factor the next [`Sweeping::extrapolate`] applies (0: none).
    factor: f64,
    /// Whether to extrapolate at all.
    pub extrapolation: bool,
    /// The stall rule.
    pub stall: Stall,
}

impl Default for Sweeping {
    fn default() -> Self {
        Sweeping {
            last_update: f64::NAN,
            last_q: f64::NAN,
            held_q: 0.0,
            since: 0,
            factor: 0.0,
            extrapolation: true,
            stall: Stall::default(),
        }
    }
}

impl Sweeping {
    /// Contractions above this are not extrapolated (reflectance near 1: the factor
    /// `q / (1 − q)` would multiply any error in `q`).
    pub const MAX_Q: f64 = 0.9;

    /// The estimated error after a sweep from `b` to `nb`.
    pub fn residual(&mut self, sys: &HierSystem, nb: &[Rgb], b: &[Rgb], source: &[Rgb]) -> f64 {
        let diff: Vec<Rgb> = (nb.iter().zip(b))
            .map(|(x, y)| std::array::from_fn(|c| x[c] - y[c]))
            .collect();
        let bounced: Vec<Rgb> = (nb.iter().zip(source))
            .map(|(x, s)| std::array::from_fn(|c| x[c] - s[c]))
            .collect();
        let (dn, bn) = (sys.norm(&diff), sys.norm(&bounced));
        let update = if bn > 0.0 { dn / bn } else { 0.0 };
        let observed = if self.last_update > 0.0 {
            (update / self.last_update).clamp(0.0, 0.9999)
        } else {
            f64::NAN
        };
        self.since += 1;
        let settled = (observed - self.last_q).abs() <= 0.01 * observed;
        self.factor = if self.extrapolation && settled && observed <= Self::MAX_Q && self.since >= 3
        {
            observed / (1.0 - observed)
        } else {
            0.0
        };
        self.last_q = observed;
        self.last_update = update;
        let q = if observed.is_nan() { 0.5 } else { observed }.max(self.held_q);
        update * q / (1.0 - q)
    }

    /// Carries the sweep from `b` to `nb` on as [`Sweeping::residual`] decided, in `nb`
    /// (radiosity kept at least 0); whether it did.
    pub fn extrapolate(&mut self, nb: &mut [Rgb], b: &[Rgb]) -> bool {
        if self.factor <= 0.0 || nb.len() != b.len() {
            return false;
        }
        let f = self.factor;
        nb.par_iter_mut().zip(b).for_each(|(x, y)| {
            for c in 0..3 {
                x[c] = (x[c] + f * (x[c] - y[c])).max(0.0);
            }
        });
        self.held_q = self.held_q.max(f / (1.0 + f));
        // The updates that follow measure what is left after it, not the mode's contraction.
        (self.since, self.last_q, self.last_update, self.factor) = (0, f64::NAN, f64::NAN, 0.0);
        true
    }
}

/// Per channel, nine harmonics coefficients.
type Sh3 = [[f64; 9]; 3];

/// The most hemispheres an element enclosed in part may gather from ([`HierSystem::cap`]).
/// Not 1: sampled form factors scatter about the true sum on every element, whole ones too
/// (in the 101 582-triangle room of boxes, whose sums are 1, a tenth of whole elements gather
/// more than 1.11-1.13 and a tenth of the elements enclosed in part more than 1.44), and
/// cutting only the upper side darkens: that room baked 5.2 % too dark against the path tracer
/// with a bound of 1, 2.0 % with 1.25, 1.2 % with 1.5 and 1.1 % with 2. Sponza, whose solve
/// diverges without a bound (sums up to 15), converges in 8 sweeps with 1.5.
pub(crate) const GATHER_AT_MOST: f64 = 1.5;

/// Bytes a link costs while links are built and then held (the refinement's record, then the
/// rows).
pub const LINK_BYTES: u64 = (std::mem::size_of::<Link>() + 4 + 4) as u64;

impl HierSystem {
    /// Assembles the rows from the refinement's links, in their order within each row.
    pub fn new(
        mesh: &Mesh,
        tree: &Tree,
        links: &[Link],
        rho: Vec<Rgb>,
        source: Vec<Rgb>,
        live: Vec<u8>,
    ) -> Result<HierSystem, BakeError> {
        Self::new_in(mesh, tree, links, (rho, source, live), None)
    }

    /// [`HierSystem::new`], the rows written into `old`'s (an edit's system before it, whose
    /// rows are no longer needed) when they are large enough: memory already in hand, where
    /// fresh pages cost the kernel's zeroing (0.5 s for Sponza's 18 M links on this machine).
    /// `old` keeps its rows when this fails. New rows get 1/64 more room than they need, so
    /// that the next edit's fit.
    pub(crate) fn new_in(
        mesh: &Mesh,
        tree: &Tree,
        links: &[Link],
        (rho, source, live): (Vec<Rgb>, Vec<Rgb>, Vec<u8>),
        old: Option<&mut HierSystem>,
    ) -> Result<HierSystem, BakeError> {
        let nodes = tree.len();
        let total = links.len();
        let oom = |what| BakeError::OutOfMemory {
            what,
            needed: total as u64 * 8,
            limit: 0,
        };
        let mut row = vec![0u64; nodes + 1];
        for l in links {
            row[l.recv as usize + 1] += 1;
        }
        for i in 0..nodes {
            row[i + 1] += row[i];
        }
        let mut fill = row.clone();
        let (mut src, mut ff) = match old {
            Some(o) if o.src.capacity() >= total && o.ff.capacity() >= total => {
                (std::mem::take(&mut o.src), std::mem::take(&mut o.ff))
            }
            _ => {
                let room = total + total / 64;
                let (mut src, mut ff): (Vec<u32>, Vec<f32>) = (Vec::new(), Vec::new());
                src.try_reserve_exact(room).map_err(|_| oom("links"))?;
                ff.try_reserve_exact(room).map_err(|_| oom("links"))?;
                (src, ff)
            }
        };
        src.clear();
        src.resize(total, 0);
        ff.clear();
        ff.resize(total, 0.0);
        for l in links {
            let k = fill[l.recv as usize] as usize;
            fill[l.recv as usize] += 1;
            src[k] = l.src;
            ff[k] = l.ff;
        }
        drop(fill);
        Ok(Self::from_rows(
            mesh,
            tree,
            Rows { row, src, ff },
            rho,
            source,
            live,
        ))
    }

    /// A system over links already in rows (a checkpoint's), which must fit `tree`: one row
    /// per node, sources below its node count.
    pub fn from_rows(
        mesh: &Mesh,
        tree: &Tree,
        rows: Rows,
        rho: Vec<Rgb>,
        source: Vec<Rgb>,
        live: Vec<u8>,
    ) -> HierSystem {
        let nodes = tree.len();
        let Rows { row, src, ff } = rows;
        let area: Vec<f64> = mesh
            .leaves
            .iter()
            .map(|&n| mesh.nodes[n as usize].area)
            .collect();
        let mut node_leaf = vec![u32::MAX; mesh.nodes.len()];
        for (i, &n) in mesh.leaves.iter().enumerate() {
            node_leaf[n as usize] = i as u32;
        }
        let mut sys = HierSystem {
            mesh_nodes: tree.mesh_nodes,
            row,
            src,
            ff,
            parent: tree.parent.clone(),
            weight: vec![0.0; nodes],
            dilution: vec![1.0; nodes],
            cap: std::sync::OnceLock::new(),
            cluster_children: tree.clusters.iter().map(|c| c.children).collect(),
            first_child: mesh.nodes.iter().map(|n| n.first_child).collect(),
            leaf_node: mesh.leaves.clone(),
            node_leaf,
            area,
            rho,
            source,
            dead: live.iter().map(|&l| l == 0).collect(),
            live,
            center: tree.center.clone(),
            normal: mesh.nodes.iter().map(|n| n.normal).collect(),
            normal_sh: tree.normal_sh.clone(),
            live_sh: Vec::new(),
            transfer: None,
        };
        let mut w = vec![0.0; nodes];
        let mut full = vec![0.0; nodes];
        for (i, &n) in sys.leaf_node.iter().enumerate() {
            w[n as usize] = sys.area[i] * exposure::fraction(sys.live[i]);
            full[n as usize] = sys.area[i];
        }
        // Children after parents among mesh nodes and among clusters, and every cluster above
        // the mesh roots: mesh nodes backwards, then clusters backwards.
        let m = tree.mesh_nodes as usize;
        for n in (0..m).rev().chain((m..nodes).rev()) {
            if let Some(c) = sys.cluster(n) {
                w[n] = w[c[0] as usize] + w[c[1] as usize];
                full[n] = full[c[0] as usize] + full[c[1] as usize];
            } else if sys.first_child[n] != u32::MAX {
                let f = sys.first_child[n] as usize;
                w[n] = w[f] + w[f + 1] + w[f + 2] + w[f + 3];
                full[n] = full[f] + full[f + 1] + full[f + 2] + full[f + 3];
            }
        }
        sys.dilution = w
            .iter()
            .zip(&full)
            .map(|(&live, &all)| if live > 0.0 { all / live } else { 1.0 })
            .collect();
        sys.weight = w;
        sys.live_sh = sys.live_harmonics();
        sys
    }

    /// Per element, the transfers [`HierSystem::set_transfer`] set.
    pub(crate) fn transfers(&self) -> Option<&[[f32; 9]]> {
        self.transfer.as_ref().map(|t| &t.element[..])
    }

    /// Hands each cluster's light to the elements under it by their own visibility
    /// ([`super::transfer`]), `element` per element, instead of by their normals alone.
    /// `element` holds one transfer per element ([`super::transfer::transfer`] of the same
    /// mesh); a list of another length is ignored (the push stays by the normals).
    pub(crate) fn set_transfer(&mut self, element: Vec<[f32; 9]>) {
        if element.len() != self.leaf_node.len() {
            return;
        }
        let m = self.mesh_nodes as usize;
        let clusters = self.row.len() - 1 - m;
        let mut sum = vec![[0.0f64; 9]; clusters];
        let mut weight = vec![0.0f64; clusters];
        let cluster: Vec<u32> = (self.leaf_node.iter())
            .map(|&n| {
                let mut id = n;
                while (id as usize) < m {
                    id = self.parent[id as usize];
                    if id == u32::MAX {
                        return u32::MAX;
                    }
                }
                id
            })
            .collect();
        for (i, &c) in cluster.iter().enumerate() {
            let w = self.weight[self.leaf_node[i] as usize];
            if c == u32::MAX || w <= 0.0 {
                continue;
            }
            let c = c as usize - m;
            for j in 0..9 {
                sum[c][j] += w * f64::from(element[i][j]);
            }
            weight[c] += w;
        }
        // Children after parents: backwards, each into its parent.
        for c in (0..clusters).rev() {
            let p = self.parent[m + c];
            if p != u32::MAX {
                let (p, s, w) = (p as usize - m, sum[c], weight[c]);
                for j in 0..9 {
                    sum[p][j] += s[j];
                }
                weight[p] += w;
            }
        }
        let mean = sum
            .iter()
            .zip(&weight)
            .map(|(s, &w)| if w > 0.0 { s.map(|v| v / w) } else { [0.0; 9] })
            .collect();
        self.transfer = Some(Transfer {
            element,
            cluster,
            mean,
        });
    }

    /// Per cluster, the harmonics of its normals weighted by exposed area. A cluster shines
    /// and receives with its exposed parts: as a source, its radiosity towards a receiver is
    /// the mean over its exposed parts weighted by how much they face it; as a receiver, its
    /// exposed parts share what it gathered by how much they face the source. Both divide by
    /// the exposed parts' mean cosine, not the whole cluster's: with the whole's, a cluster
    /// holding enclosed faces that face the other end passed on less than it took, and one
    /// whose enclosed faces face away more (a furnace with two touching boxes: B 12 % above
    /// `E / (1 − ρ)` at ρ 0.9). Where nothing below a cluster is enclosed the tree's own
    /// harmonics are kept, bit for bit.
    fn live_harmonics(&self) -> Vec<[f64; 9]> {
        let m = self.mesh_nodes as usize;
        let mut out = self.normal_sh.clone();
        for c in (0..out.len()).rev() {
            let w = self.weight[m + c];
            if self.dilution[m + c] == 1.0 || w <= 0.0 {
                continue;
            }
            let mut acc = [0.0; 9];
            for ch in self.cluster_children[c] {
                let (ch, wc) = (ch as usize, self.weight[ch as usize]);
                if wc <= 0.0 {
                    continue;
                }
                let y = if ch >= m {
                    out[ch - m]
                } else {
                    sh::basis(self.normal[ch])
                };
                for j in 0..9 {
                    acc[j] += wc * y[j];
                }
            }
            out[c] = acc.map(|v| v / w);
        }
        out
    }

    /// Per element, [`HierSystem::cap`]. A receiver enclosed in part gathers per unit of its
    /// exposed area, from form factors sampled over its whole area; with few samples (a link
    /// that carries little gets one) that may claim many hemispheres, by as much as the
    /// dilution (up to 9), and such elements facing each other feed each other without bound:
    /// Sponza's solve diverged. So for elements enclosed in part, the gather of uniform unit
    /// radiosity (the sum of form factors the element takes, pushes and directions included)
    /// is measured once, and the element's gather scaled to at most [`GATHER_AT_MOST`].
    ///
    /// With transfers ([`HierSystem::set_transfer`]) every live element is measured so: a
    /// cluster whose elements nearly all face away from a source divides its light by a small
    /// mean, and an element's noise above it would take more than the cluster gathered.
    fn caps(&self, scratch: &mut SweepScratch) -> Vec<f64> {
        let elements = self.area.len();
        let all = self.transfer.is_some();
        let partial =
            |i: usize| self.live[i] > 0 && (all || usize::from(self.live[i]) < exposure::POINTS);
        let mut cap = vec![1.0; elements];
        if !(0..elements).any(partial) {
            return cap;
        }
        let (ones, zero) = (vec![[1.0; 3]; elements], vec![[0.0; 3]; elements]);
        let whole = self.gather(&ones, &ones, &zero, &cap, scratch);
        for (i, t) in whole.iter().enumerate() {
            let t = t[0].max(t[1]).max(t[2]);
            if partial(i) && t > GATHER_AT_MOST {
                cap[i] = GATHER_AT_MOST / t;
            }
        }
        cap
    }

    /// The links in rows by receiver node.
    pub fn rows(&self) -> RowsRef<'_> {
        RowsRef {
            row: &self.row,
            src: &self.src,
            ff: &self.ff,
        }
    }

    fn cluster(&self, n: usize) -> Option<[u32; 2]> {
        n.checked_sub(self.mesh_nodes as usize)
            .map(|c| self.cluster_children[c])
    }

    /// Per element: inside closed geometry.
    pub fn enclosed(&self) -> &[bool] {
        &self.dead
    }

    /// Per element: its exposed probe points, of [`exposure::POINTS`] ([`exposure::fraction`]
    /// makes it a share of the area).
    pub fn exposure(&self) -> &[u8] {
        &self.live
    }

    /// Number of links.
    pub fn links(&self) -> usize {
        self.src.len()
    }

    /// Links whose receiver is a cluster, and whose source is.
    pub fn cluster_links(&self) -> (usize, usize) {
        let m = self.mesh_nodes as usize;
        let recv = (self.row[self.row.len() - 1] - self.row[m]) as usize;
        let src = self.src.iter().filter(|&&s| s >= self.mesh_nodes).count();
        (recv, src)
    }

    /// Bytes held by the links.
    pub fn link_bytes(&self) -> usize {
        self.src.len() * 8 + self.row.len() * 8
    }

    /// Sum of the form factors of node `n`'s row and of its ancestors' rows: the fraction of
    /// the hemisphere an element under `n` gathers from (1 in a closed scene).
    pub fn row_sum_to_root(&self, n: u32) -> f64 {
        let mut sum = 0.0;
        let mut n = n;
        while n != u32::MAX {
            let (lo, hi) = (
                self.row[n as usize] as usize,
                self.row[n as usize + 1] as usize,
            );
            sum += self.ff[lo..hi].iter().map(|&f| f64::from(f)).sum::<f64>();
            n = self.parent[n as usize];
        }
        sum
    }

    /// The node of element `i`.
    pub fn leaf_node(&self, i: usize) -> u32 {
        self.leaf_node[i]
    }

    /// Area-weighted means of `b` at every node.
    fn pull(&self, b: &[Rgb], nodes: &mut [Rgb]) {
        let m = self.mesh_nodes as usize;
        for n in (0..m).rev().chain((m..nodes.len()).rev()) {
            let w = self.weight[n];
            nodes[n] = if w <= 0.0 {
                [0.0; 3]
            } else if let Some(c) = self.cluster(n) {
                let (a, b2) = (c[0] as usize, c[1] as usize);
                let (wa, wb) = (self.weight[a], self.weight[b2]);
                std::array::from_fn(|k| (wa * nodes[a][k] + wb * nodes[b2][k]) / w)
            } else if self.first_child[n] != u32::MAX {
                let f = self.first_child[n] as usize;
                let mut acc = [0.0; 3];
                for c in f..f + 4 {
                    for k in 0..3 {
                        acc[k] += self.weight[c] * nodes[c][k];
                    }
                }
                acc.map(|v| v / w)
            } else {
                b[self.node_leaf[n] as usize]
            };
        }
    }

    /// Per cluster: weighted means of radiosity × the harmonics of the normal.
    fn pull_directional(&self, nb: &[Rgb], p: &mut Vec<Sh3>) {
        let m = self.mesh_nodes as usize;
        p.clear();
        p.resize(self.cluster_children.len(), [[0.0; 9]; 3]);
        for c in (0..p.len()).rev() {
            let w = self.weight[m + c];
            if w <= 0.0 {
                continue;
            }
            let mut acc = [[0.0; 9]; 3];
            for ch in self.cluster_children[c] {
                let (ch, wc) = (ch as usize, self.weight[ch as usize]);
                if wc <= 0.0 {
                    continue;
                }
                if ch >= m {
                    for k in 0..3 {
                        for j in 0..9 {
                            acc[k][j] += wc * p[ch - m][k][j];
                        }
                    }
                } else {
                    let y = sh::basis(self.normal[ch]);
                    for k in 0..3 {
                        for j in 0..9 {
                            acc[k][j] += wc * nb[ch][k] * y[j];
                        }
                    }
                }
            }
            p[c] = acc.map(|a| a.map(|v| v / w));
        }
    }

    /// What source `s` sends towards receiver `r`: its mean, or for a cluster the mean of its
    /// parts weighted by how much they face `r`.
    #[inline]
    fn value(&self, r: usize, s: usize, nb: &[Rgb], p: &[Sh3]) -> Rgb {
        let m = self.mesh_nodes as usize;
        if s < m {
            return nb[s];
        }
        let d = (self.center[r] - self.center[s]).normalize_or_zero();
        let cy = sh::cosine(d);
        let den = sh::dot(&self.live_sh[s - m], &cy).max(KAPPA_MIN);
        let ps = &p[s - m];
        std::array::from_fn(|k| (sh::dot(&ps[k], &cy) / den).max(0.0))
    }

    /// One Jacobi sweep from `b`; returns the new radiosity.
    pub fn sweep(&self, b: &[Rgb]) -> Vec<Rgb> {
        self.sweep_with(b, &self.rho, &self.source)
    }

    /// One Jacobi sweep from `b` under other reflectances and sources (per element: a spectral
    /// solve's bands).
    pub fn sweep_with(&self, b: &[Rgb], rho: &[Rgb], source: &[Rgb]) -> Vec<Rgb> {
        self.sweep_in(b, rho, source, &mut SweepScratch::default())
    }

    /// [`HierSystem::sweep_with`] working in `scratch`, which a caller that sweeps in a loop
    /// keeps from one sweep to the next.
    pub fn sweep_in(
        &self,
        b: &[Rgb],
        rho: &[Rgb],
        source: &[Rgb],
        scratch: &mut SweepScratch,
    ) -> Vec<Rgb> {
        let cap = self.cap.get_or_init(|| self.caps(scratch));
        self.gather(b, rho, source, cap, scratch)
    }

    /// [`HierSystem::sweep_with`] with each element's gather scaled by `cap`.
    fn gather(
        &self,
        b: &[Rgb],
        rho: &[Rgb],
        source: &[Rgb],
        cap: &[f64],
        scratch: &mut SweepScratch,
    ) -> Vec<Rgb> {
        let nodes = self.row.len() - 1;
        let m = self.mesh_nodes as usize;
        let SweepScratch {
            nodes: nb,
            directional: p,
            gathered: g,
            cluster_gathered: shr,
        } = scratch;
        nb.clear();
        nb.resize(nodes, [0.0; 3]);
        self.pull(b, nb);
        self.pull_directional(nb, p);
        let (nb, p) = (&*nb, &*p);
        g.clear();
        g.resize(m, [0.0; 3]);
        g.par_iter_mut()
            .enumerate()
            .with_min_len(1024)
            .for_each(|(n, out)| {
                let (lo, hi) = (self.row[n] as usize, self.row[n + 1] as usize);
                let mut acc = [0.0; 3];
                for k in lo..hi {
                    let f = f64::from(self.ff[k]);
                    let v = self.value(n, self.src[k] as usize, nb, p);
                    acc[0] += f * v[0];
                    acc[1] += f * v[1];
                    acc[2] += f * v[2];
                }
                *out = acc;
            });
        // Cluster receivers gather by direction.
        shr.clear();
        shr.resize(nodes - m, [[0.0; 9]; 3]);
        shr.par_iter_mut()
            .enumerate()
            .with_min_len(256)
            .for_each(|(i, out)| {
                let n = m + i;
                let (lo, hi) = (self.row[n] as usize, self.row[n + 1] as usize);
                let mut acc = [[0.0; 9]; 3];
                // The refinement divided each form factor by the mean cosine of the whole
                // area towards the source; its exposed parts share it (`live_harmonics`).
                let diluted = self.dilution[n] != 1.0;
                for k in lo..hi {
                    let s = self.src[k] as usize;
                    let mut f = f64::from(self.ff[k]);
                    let v = self.value(n, s, nb, p);
                    let d = (self.center[s] - self.center[n]).normalize_or_zero();
                    if let Some(t) = &self.transfer {
                        // Shared by the live elements' transfers towards the source.
                        let all = sh::dot(&self.normal_sh[n - m], &sh::cosine(d)).max(KAPPA_MIN);
                        f *= all / sh::dot(&t.mean[n - m], &sh::basis(d)).max(KAPPA_MIN);
                    } else if diluted {
                        let cy = sh::cosine(d);
                        let all = sh::dot(&self.normal_sh[n - m], &cy).max(KAPPA_MIN);
                        f *= all / sh::dot(&self.live_sh[n - m], &cy).max(KAPPA_MIN);
                    }
                    let y = sh::basis(d);
                    for c in 0..3 {
                        let fv = f * v[c];
                        for j in 0..9 {
                            acc[c][j] += fv * y[j];
                        }
                    }
                }
                *out = acc;
            });
        // A receiver's form factors are averages over its whole area, enclosed parts (which
        // see nothing) included; its live parts, which take the push, get what it gathered
        // per unit of live area: elements enclosed in part too (`crate::exposure`). Without
        // this the 1 214-triangle room of boxes baked 6.1 % too dark against the path tracer
        // instead of 3.6 % (whole elements enclosed or not); the 101 582-triangle one 11.7 %
        // instead of 1.2 % (elements enclosed in part).
        for n in 0..m {
            let d = self.dilution[n];
            if d != 1.0 {
                for v in &mut g[n] {
                    *v *= d;
                }
            }
        }
        for (c, acc) in shr.iter_mut().enumerate() {
            let d = self.dilution[m + c];
            if d != 1.0 {
                for ch in acc.iter_mut() {
                    for v in ch.iter_mut() {
                        *v *= d;
                    }
                }
            }
        }
        // Push down: clusters (preorder) first, then mesh nodes (parents before children); a
        // triangle under a cluster takes the cluster's light by its normal.
        for c in 0..shr.len() {
            let parent = self.parent[m + c];
            if parent != u32::MAX {
                let up = shr[parent as usize - m];
                for k in 0..3 {
                    for j in 0..9 {
                        shr[c][k][j] += up[k][j];
                    }
                }
            }
        }
        for n in 0..m {
            let parent = self.parent[n];
            if parent == u32::MAX {
                continue;
            }
            let up = if parent as usize >= m {
                if self.transfer.is_some() {
                    // Each element takes it by its own transfer, below.
                    continue;
                }
                let cy = sh::cosine(self.normal[n]);
                let s = &shr[parent as usize - m];
                std::array::from_fn(|k| sh::dot(&s[k], &cy).max(0.0))
            } else {
                g[parent as usize]
            };
            for k in 0..3 {
                g[n][k] += up[k];
            }
        }
        (0..b.len())
            .map(|i| {
                if self.dead[i] {
                    return [0.0; 3];
                }
                let mut gi = g[self.leaf_node[i] as usize];
                if let Some(t) = &self.transfer
                    && let Some(c) = (t.cluster[i] as usize).checked_sub(m)
                    && c < shr.len()
                {
                    let y = t.element[i].map(f64::from);
                    for k in 0..3 {
                        gi[k] += sh::dot(&shr[c][k], &y).max(0.0);
                    }
                }
                let cap = cap.get(i).copied().unwrap_or(1.0);
                std::array::from_fn(|k| source[i][k] + rho[i][k] * (gi[k] * cap))
            })
            .collect()
    }

    /// Sweeps from the sources under other reflectances and sources until the update, by the
    /// clustered bake's rule ([`Sweeping`]), falls to `tolerance`: the radiosity and whether
    /// it converged (false: stalled, or `max_sweeps` run).
    pub fn solve_with(
        &self,
        rho: &[Rgb],
        source: &[Rgb],
        tolerance: f64,
        max_sweeps: u32,
    ) -> Result<(Vec<Rgb>, bool), SolveError> {
        let mut b = source.to_vec();
        let mut rule = Sweeping::default();
        let mut scratch = SweepScratch::default();
        for it in 1..=u64::from(max_sweeps) {
            let mut nb = self.sweep_in(&b, rho, source, &mut scratch);
            let residual = rule.residual(self, &nb, &b, source);
            if residual > tolerance {
                rule.extrapolate(&mut nb, &b);
            }
            b = nb;
            if residual <= tolerance && it >= 2 {
                return Ok((b, true));
            }
            match rule.stall.observe(residual, it) {
                Ok(()) => {}
                Err(SolveError::Stalled { .. }) => return Ok((b, false)),
                Err(e) => return Err(e),
            }
        }
        Ok((b, false))
    }

    /// Area-weighted L2 norm over all channels.
    pub fn norm(&self, v: &[Rgb]) -> f64 {
        v.iter()
            .zip(&self.area)
            .map(|(x, a)| a * (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]))
            .sum::<f64>()
            .sqrt()
    }

    /// Consumes the system, handing back reflectance, sources and the exposure.
    pub fn into_parts(self) -> (Vec<Rgb>, Vec<Rgb>, Vec<u8>) {
        (self.rho, self.source, self.live)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::MeshParams;
    use crate::scenes::{add_surface, quad};

    /// Two unit quads facing each other `gap` apart (`a` below, `b` above), with reflectance
    /// `rho` and `a`'s emission `e`, meshed `levels` below one patch each.
    fn facing_quads(gap: f64, rho: [f64; 2], e: f64, levels: u8) -> Mesh {
        let mut scene = radiant_scene::Scene::default();
        let a = quad(DVec3::ZERO, DVec3::Z, DVec3::X);
        let b = quad(DVec3::Y * gap, DVec3::X, DVec3::Z);
        add_surface(&mut scene, "a", [rho[0]; 3], [e; 3], &a);
        add_surface(&mut scene, "b", [rho[1]; 3], [0.0; 3], &b);
        let params = MeshParams {
            patch_size: 10.0,
            element_levels: levels,
            ..Default::default()
        };
        Mesh::new(&scene, &params).expect("mesh")
    }

    #[test]
    fn a_sweep_in_kept_buffers_is_a_fresh_sweep_bit_for_bit() {
        // Two facing quads linked every element to every element, at two mesh resolutions:
        // the buffers kept from sweeps of the finer system hold stale, larger contents when
        // the coarser one sweeps in them.
        let system = |levels: u8| {
            let mesh = facing_quads(0.5, [0.7, 0.5], 1.0, levels);
            let tree = Tree::new(&mesh);
            let n = mesh.element_count();
            let root = |i: usize| mesh.leaf_node(i as u32).root;
            let mut links = Vec::new();
            for r in 0..n {
                for s in (0..n).filter(|&s| root(s) / 2 != root(r) / 2) {
                    links.push(Link {
                        recv: mesh.leaves[r],
                        src: mesh.leaves[s],
                        ff: 0.3 / n as f32,
                    });
                }
            }
            // A cluster receiver too: the root cluster, from one element.
            let top = tree.root(&mesh);
            links.push(Link {
                recv: top,
                src: mesh.leaves[0],
                ff: 0.01,
            });
            let source: Vec<Rgb> = (0..n)
                .map(|i| if root(i) < 2 { [1.0; 3] } else { [0.0; 3] })
                .collect();
            let live = vec![9; n];
            HierSystem::new(&mesh, &tree, &links, vec![[0.6; 3]; n], source, live).expect("system")
        };
        let (fine, coarse) = (system(2), system(1));
        let mut kept = SweepScratch::default();
        let mut x = fine.source.clone();
        for _ in 0..3 {
            x = fine.sweep_in(&x, &fine.rho, &fine.source, &mut kept);
        }
        let (mut y, mut z) = (coarse.source.clone(), coarse.source.clone());
        for _ in 0..3 {
            y = coarse.sweep_in(&y, &coarse.rho, &coarse.source, &mut kept);
            z = coarse.sweep(&z);
        }
        let bits = |v: &[Rgb]| v.iter().flatten().map(|f| f.to_bits()).collect::<Vec<_>>();
        assert!(y.iter().flatten().any(|&v| v > 0.0));
        assert_eq!(bits(&y), bits(&z));
    }

    #[test]
    fn an_element_enclosed_in_part_gathers_no_more_than_the_bound() {
        // Two facing quads; `a` is enclosed but for a ninth, and its links claim four
        // hemispheres (the scatter of a few samples): per unit of exposed area, 36. With
        // ρ 0.9 the loop a → b → a would gain 14.6 a sweep and diverge.
        let mesh = facing_quads(0.1, [0.9, 0.9], 0.0, 0);
        let tree = Tree::new(&mesh);
        let on = |i: usize, s: u32| mesh.root_surface[mesh.leaf_node(i as u32).root as usize] == s;
        let n = mesh.element_count();
        let (of_a, of_b): (Vec<usize>, Vec<usize>) = (0..n).partition(|&i| on(i, 0));
        // Every element of `to` from every element of `from`, the form factors summing to
        // `sum` per receiver.
        let all_from = |to: &[usize], from: &[usize], sum: f32| {
            let ff = sum / from.len() as f32;
            let leaf = |i: usize| mesh.leaves[i];
            (to.iter())
                .flat_map(move |&r| (from.iter()).map(move |&s| (r, s)))
                .map(|(r, s)| Link {
                    recv: leaf(r),
                    src: leaf(s),
                    ff,
                })
                .collect::<Vec<_>>()
        };
        let mut links = all_from(&of_a, &of_b, 4.0);
        links.extend(all_from(&of_b, &of_a, 0.5));
        let live: Vec<u8> = (0..n).map(|i| if on(i, 0) { 1 } else { 9 }).collect();
        let rho = vec![[0.9; 3]; n];
        let source: Vec<Rgb> = (0..n)
            .map(|i| if on(i, 0) { [1.0; 3] } else { [0.0; 3] })
            .collect();
        let sys = HierSystem::new(&mesh, &tree, &links, rho, source, live).expect("system");
        let (ones, zero) = (vec![[1.0; 3]; n], vec![[0.0; 3]; n]);
        let whole = sys.sweep_with(&ones, &ones, &zero);
        for &i in &of_a {
            assert!(
                (whole[i][0] - GATHER_AT_MOST).abs() < 1e-9,
                "{:?}",
                whole[i]
            );
        }
        for &i in &of_b {
            assert!(
                (whole[i][0] - 0.5).abs() < 1e-6,
                "b is not enclosed: {:?}",
                whole[i]
            );
        }
        // The solve converges: a gains at most 0.9 × 1.5 × 0.9 × 0.5 = 0.61 a round.
        let mut x = sys.source.clone();
        let mut change = f64::MAX;
        for _ in 0..200 {
            let y = sys.sweep(&x);
            change = (y.iter().zip(&x))
                .map(|(p, q)| (p[0] - q[0]).abs())
                .fold(0.0, f64::max);
            x = y;
        }
        assert!(
            x.iter().flatten().all(|v| v.is_finite() && *v < 10.0),
            "{x:?}"
        );
        assert!(change < 1e-12, "{change}");
    }
}
