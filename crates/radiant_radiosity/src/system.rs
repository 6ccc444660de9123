//! The discrete radiosity system over elements:
//! `B_i = S_i + ρ_i Σ_links F_is B̄_s`, with `B̄_s` the area-weighted mean of `B` over the
//! elements under source node `s` (elements inside closed geometry weigh 0), and `S_i` emission plus direct light from punctual lights.

use crate::links::Links;
use crate::mesh::Mesh;

/// RGB in `f64`.
pub type Rgb = [f64; 3];

/// Everything a solver needs, owned, so a solver can run on another thread.
#[derive(Clone, Debug)]
pub struct System {
    /// Element areas (local units).
    pub area: Vec<f64>,
    /// Element weight in source means: its area, or 0 for an element inside closed geometry
    /// (under a block standing on the floor, say), which no receiver can see.
    pub weight: Vec<f64>,
    /// Node weights: sums of their elements' weights.
    pub node_weight: Vec<f64>,
    /// Element reflectance.
    pub rho: Vec<Rgb>,
    /// Element source term: emission plus `ρ E_direct / π`.
    pub source: Vec<Rgb>,
    /// Node areas.
    pub node_area: Vec<f64>,
    /// Node parents (`u32::MAX` for roots).
    pub node_parent: Vec<u32>,
    /// Node first child (`u32::MAX` for leaves).
    pub node_first_child: Vec<u32>,
    /// Node first element.
    pub node_leaf_lo: Vec<u32>,
    /// Node one-past-last element.
    pub node_leaf_hi: Vec<u32>,
    /// Element → node.
    pub leaf_node: Vec<u32>,
    /// Node range `[lo, hi)` of each input triangle's tree.
    pub root_nodes: Vec<(u32, u32)>,
    /// Input triangle of each element.
    pub leaf_root: Vec<u32>,
    /// The links.
    pub links: Links,
    contraction: f64,
}

impl System {
    /// Assembles the system from the mesh, per-element reflectance and source, and links.
    pub fn new(
        mesh: &Mesh,
        rho: Vec<Rgb>,
        source: Vec<Rgb>,
        links: Links,
        dead: &[bool],
    ) -> System {
        let share: Vec<f64> = dead.iter().map(|&d| if d { 0.0 } else { 1.0 }).collect();
        Self::exposed(mesh, rho, source, links, &share)
    }

    /// [`System::new`] with each element's exposed share of its area (0: enclosed) as its
    /// weight: a clustered bake's exposure ([`crate::exposure`]).
    pub fn exposed(
        mesh: &Mesh,
        rho: Vec<Rgb>,
        source: Vec<Rgb>,
        links: Links,
        share: &[f64],
    ) -> System {
        let weight: Vec<f64> = mesh
            .leaves
            .iter()
            .zip(share)
            .map(|(&n, &s)| mesh.nodes[n as usize].area * s)
            .collect();
        let mut node_weight = vec![0.0; mesh.nodes.len()];
        for (i, n) in mesh.nodes.iter().enumerate().rev() {
            node_weight[i] = if n.is_leaf() {
                weight[n.leaf_lo as usize]
            } else {
                (0..4)
                    .map(|k| node_weight[(n.first_child + k) as usize])
                    .sum()
            };
        }
        let mut root_nodes = Vec::with_capacity(mesh.roots.len());
        for (k, &r) in mesh.roots.iter().enumerate() {
            let end = mesh
                .roots
                .get(k + 1)
                .copied()
                .unwrap_or(mesh.nodes.len() as u32);
            root_nodes.push((r, end));
        }
        let mut sys = System {
            contraction: 0.0,
            area: mesh
                .leaves
                .iter()
                .map(|&n| mesh.nodes[n as usize].area)
                .collect(),
            weight,
            node_weight,
            rho,
            source,
            node_area: mesh.nodes.iter().map(|n| n.area).collect(),
            node_parent: mesh.nodes.iter().map(|n| n.parent).collect(),
            node_first_child: mesh.nodes.iter().map(|n| n.first_child).collect(),
            node_leaf_lo: mesh.nodes.iter().map(|n| n.leaf_lo).collect(),
            node_leaf_hi: mesh.nodes.iter().map(|n| n.leaf_hi).collect(),
            leaf_node: mesh.leaves.clone(),
            root_nodes,
            leaf_root: mesh
                .leaves
                .iter()
                .map(|&n| mesh.nodes[n as usize].root)
                .collect(),
            links,
        };
        sys.contraction = sys.compute_contraction();
        sys
    }

    /// A system given by an explicit form-factor matrix `f[i][j]` (gathering: `B_i = S_i +
    /// ρ_i Σ_j f[i][j] B_j`), every element its own source node. For textbook examples and tests.
    pub fn from_matrix(area: Vec<f64>, rho: Vec<Rgb>, source: Vec<Rgb>, f: &[Vec<f64>]) -> System {
        let n = area.len();
        let mut links = Links {
            row: vec![0],
            ..Links::default()
        };
        for row in f {
            for (j, &v) in row.iter().enumerate() {
                if v != 0.0 {
                    links.src.push(j as u32);
                    links.ff.push(v as f32);
                }
            }
            links.row.push(links.src.len());
        }
        let ids: Vec<u32> = (0..n as u32).collect();
        let mut sys = System {
            contraction: 0.0,
            weight: area.clone(),
            node_weight: area.clone(),
            node_area: area.clone(),
            area,
            rho,
            source,
            node_parent: vec![u32::MAX; n],
            node_first_child: vec![u32::MAX; n],
            node_leaf_lo: ids.clone(),
            node_leaf_hi: ids.iter().map(|i| i + 1).collect(),
            leaf_node: ids.clone(),
            root_nodes: ids.iter().map(|&i| (i, i + 1)).collect(),
            leaf_root: ids,
            links,
        };
        sys.contraction = sys.compute_contraction();
        sys
    }

    /// An upper bound on the spectral radius of `diag(ρ) K`: the largest `ρ × row sum`. The
    /// error of an iterate is at most its residual divided by `1 −` this.
    pub fn contraction(&self) -> f64 {
        self.contraction
    }

    fn compute_contraction(&self) -> f64 {
        (0..self.len())
            .map(|i| {
                let r = self.rho[i][0].max(self.rho[i][1]).max(self.rho[i][2]);
                r * self.links.row_sum(i)
            })
            .fold(0.0, f64::max)
    }

    /// The same links with other reflectance and source terms (another wavelength band, an
    /// edited material): form factors do not depend on colour.
    pub fn with_materials(&self, rho: Vec<Rgb>, source: Vec<Rgb>) -> System {
        let mut sys = System {
            rho,
            source,
            ..self.clone()
        };
        sys.contraction = sys.compute_contraction();
        sys
    }

    /// Replaces reflectance and source terms in place, keeping the links (no copy of them).
    pub fn set_materials(&mut self, rho: Vec<Rgb>, source: Vec<Rgb>) {
        self.rho = rho;
        self.source = source;
        self.contraction = self.compute_contraction();
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.area.len()
    }

    /// Whether there are no elements.
    pub fn is_empty(&self) -> bool {
        self.area.is_empty()
    }

    /// Weighted node means of per-element values (see [`Self::weight`]), for nodes `[lo, hi)` (a whole tree or
    /// the whole array). Children come after parents, so one reverse sweep suffices.
    pub fn pull_range(&self, leaf_values: &[Rgb], node_values: &mut [Rgb], lo: u32, hi: u32) {
        for n in (lo..hi).rev() {
            let n = n as usize;
            let fc = self.node_first_child[n];
            node_values[n] = if fc == u32::MAX {
                // An element inside closed geometry is seen by nobody: it adds nothing.
                if self.node_weight[n] > 0.0 {
                    leaf_values[self.node_leaf_lo[n] as usize]
                } else {
                    [0.0; 3]
                }
            } else {
                let mut acc = [0.0; 3];
                for k in 0..4 {
                    let c = (fc + k) as usize;
                    let a = self.node_weight[c];
                    for ch in 0..3 {
                        acc[ch] += a * node_values[c][ch];
                    }
                }
                let w = self.node_weight[n];
                let inv = if w > 0.0 { 1.0 / w } else { 0.0 };
                acc.map(|v| v * inv)
            };
        }
    }

    /// [`Self::pull_range`] over all nodes.
    pub fn pull(&self, leaf_values: &[Rgb], node_values: &mut [Rgb]) {
        self.pull_range(leaf_values, node_values, 0, self.node_area.len() as u32);
    }

    /// `Σ F B̄_s` over element `i`'s links.
    #[inline]
    pub fn gather(&self, i: usize, node_values: &[Rgb]) -> Rgb {
        let (lo, hi) = (self.links.row[i], self.links.row[i + 1]);
        let mut g = [0.0; 3];
        for k in lo..hi {
            let f = f64::from(self.links.ff[k]);
            let b = &node_values[self.links.src[k] as usize];
            g[0] += f * b[0];
            g[1] += f * b[1];
            g[2] += f * b[2];
        }
        g
    }

    /// The residual `S + ρ K B - B` per element.
    pub fn residual(&self, b: &[Rgb]) -> Vec<Rgb> {
        let mut nodes = vec![[0.0; 3]; self.node_area.len()];
        self.pull(b, &mut nodes);
        (0..self.len())
            .map(|i| {
                let g = self.gather(i, &nodes);
                std::array::from_fn(|c| self.source[i][c] + self.rho[i][c] * g[c] - b[i][c])
            })
            .collect()
    }

    /// Area-weighted L2 norm over all channels.
    pub fn norm(&self, v: &[Rgb]) -> f64 {
        v.iter()
            .zip(&self.area)
            .map(|(x, a)| a * (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]))
            .sum::<f64>()
            .sqrt()
    }

    /// Relative residual `‖S + ρKB − B‖ / ‖B‖` (area-weighted L2); 0 when both are 0.
    pub fn relative_residual(&self, b: &[Rgb]) -> f64 {
        let r = self.norm(&self.residual(b));
        let d = self.norm(b);
        if d > 0.0 {
            r / d
        } else if r > 0.0 {
            f64::INFINITY
        } else {
            0.0
        }
    }

    /// Total source power (area × sum of channels), the scale for unshot fractions.
    pub fn source_power(&self) -> f64 {
        self.source
            .iter()
            .zip(&self.area)
            .map(|(s, a)| a * (s[0].abs() + s[1].abs() + s[2].abs()))
            .sum()
    }
}
