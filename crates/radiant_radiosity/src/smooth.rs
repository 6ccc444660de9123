//! A smooth light field over the elements, for light maps and point values: the incident
//! radiance `H = (B − E) / ρ` averaged at the elements' vertices (area-weighted, over elements
//! whose normals agree within 25°, across input triangles and surfaces: light is continuous
//! where a wall's triangles or materials meet, radiosity is not), then interpolated linearly in
//! each element; `B = E + ρ H` with the element's own `ρ` and `E`. Nodal averaging (Cohen &
//! Wallace, *Radiosity and Realistic Image Synthesis*, 1993, ch. 9) on `H`, not on `B`, so a
//! material edge stays sharp while the light across it is smooth.
//!
//! Elements inside closed geometry (weight 0 in [`System::weight`]) and black ones (no `H` to
//! recover) do not vote; a vertex no element votes for takes its element's own value. Where a
//! finer neighbour leaves a T-vertex on a coarse element's edge, the coarse element
//! interpolates between its own corners: the two sides then differ by the field's curvature
//! over the edge, not by a step.

use rustc_hash::FxHashMap;

use glam::DVec3;

use crate::mesh::Mesh;
use crate::system::{Rgb, System};

/// The field: per element its three corners' `H`, and its own `ρ` and `E`.
#[derive(Clone, Debug)]
pub struct SmoothField {
    corners: Vec<[u32; 3]>,
    /// Per element, the weight of its vote (0: it does not vote).
    votes: Vec<f64>,
    nodal: Vec<Rgb>,
    /// Per nodal value: whether any element voted.
    voted: Vec<bool>,
    own: Vec<Rgb>,
    rho: Vec<Rgb>,
    emission: Vec<Rgb>,
}

/// Each element's emission: its surface's (an emissive texture's variation is not seen).
pub fn element_emission(mesh: &Mesh, surfaces: &[radiant_scene::Surface]) -> Vec<Rgb> {
    mesh.leaves
        .iter()
        .map(|&leaf| {
            let root = mesh.nodes[leaf as usize].root as usize;
            mesh.root_surface
                .get(root)
                .and_then(|&s| surfaces.get(s as usize))
                .map_or([0.0; 3], |s| s.emission)
        })
        .collect()
}

/// The field of a clustered bake's light: each element votes by its exposed share
/// ([`crate::exposure::fraction`] of its probes that escaped, `exposure`).
pub fn exposed_field(
    mesh: &Mesh,
    surfaces: &[radiant_scene::Surface],
    rho: &[Rgb],
    exposure: &[u8],
    radiosity: &[Rgb],
) -> SmoothField {
    let emission = element_emission(mesh, surfaces);
    let weight: Vec<f64> = (exposure.iter())
        .map(|&l| crate::exposure::fraction(l))
        .collect();
    SmoothField::from_parts(mesh, rho, &emission, Some(&weight), radiosity)
}

/// Cosine between normals that still share a vertex value.
pub(crate) const SAME_PLANE: f64 = 0.906; // 25°

impl SmoothField {
    /// The field of `radiosity` on `mesh`, with the system's reflectance and weights, and the
    /// emission of each element's surface (an emissive texture's variation within a surface is
    /// not seen: it only moves an emitter's own `H`).
    pub fn new(
        mesh: &Mesh,
        system: &System,
        surfaces: &[radiant_scene::Surface],
        radiosity: &[Rgb],
    ) -> SmoothField {
        let emission = element_emission(mesh, surfaces);
        // `from_parts` weighs each element by its area already: the system's weights are
        // areas (times an exposed share), so it takes their share of the area. Handing it the
        // weights themselves weighed each vote by the area squared, unlike a clustered bake's
        // own field.
        let share: Vec<f64> = (system.weight.iter().zip(&system.area))
            .map(|(&w, &a)| if a > 0.0 { w / a } else { 0.0 })
            .collect();
        Self::from_parts(mesh, &system.rho, &emission, Some(&share), radiosity)
    }

    /// The field from per-element reflectance, emission, weights (`None`: all vote) and
    /// radiosity. Slices shorter than the element count are read as zero (weights as one).
    pub fn from_parts(
        mesh: &Mesh,
        rho: &[Rgb],
        emission: &[Rgb],
        weight: Option<&[f64]>,
        radiosity: &[Rgb],
    ) -> SmoothField {
        let n = mesh.leaves.len();
        let get = |v: &[Rgb], i: usize| v.get(i).copied().unwrap_or([0.0; 3]);
        let rho: Vec<Rgb> = (0..n).map(|i| get(rho, i)).collect();
        let emission: Vec<Rgb> = (0..n).map(|i| get(emission, i)).collect();
        // Each element's own H.
        let own: Vec<Rgb> = (0..n)
            .map(|i| {
                let (b, e, r) = (get(radiosity, i), emission[i], rho[i]);
                std::array::from_fn(|c| {
                    if r[c] > 1e-6 {
                        ((b[c] - e[c]) / r[c]).max(0.0)
                    } else {
                        0.0
                    }
                })
            })
            .collect();
        // Vertices by position (quantised at a 2⁻²⁴ of the scene's extent), then by normal.
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for &leaf in &mesh.leaves {
            for v in mesh.nodes[leaf as usize].v {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        let q = ((hi - lo).max_element().max(1e-12)) / f64::from(1u32 << 24);
        let key = |p: DVec3| {
            let k = ((p - lo) / q).round();
            [k.x as i64, k.y as i64, k.z as i64]
        };
        // Per position, its first vertex; `next` chains the others there, in the order they
        // were made (one per plane the position's elements lie in).
        let mut first: FxHashMap<[i64; 3], u32> = FxHashMap::default();
        first.reserve(n);
        let mut next: Vec<u32> = Vec::with_capacity(n * 2);
        let mut normal: Vec<DVec3> = Vec::with_capacity(n * 2);
        let mut sum: Vec<[f64; 4]> = Vec::with_capacity(n * 2);
        let mut corners = Vec::with_capacity(n);
        let mut vote_weights = Vec::with_capacity(n);
        for (i, &leaf) in mesh.leaves.iter().enumerate() {
            let node = &mesh.nodes[leaf as usize];
            let w = node.area * weight.and_then(|w| w.get(i)).copied().unwrap_or(1.0);
            let votes = w > 0.0 && rho[i].iter().any(|&r| r > 1e-6);
            vote_weights.push(if votes { w } else { 0.0 });
            let mut c = [0u32; 3];
            for (k, p) in node.v.iter().enumerate() {
                let fresh = normal.len() as u32;
                let head = *first.entry(key(*p)).or_insert(fresh);
                let (mut at, mut found) = (head, None);
                while at != fresh {
                    if normal[at as usize].dot(node.normal) >= SAME_PLANE {
                        found = Some(at);
                        break;
                    }
                    if next[at as usize] == u32::MAX {
                        next[at as usize] = fresh;
                    }
                    at = next[at as usize];
                }
                let id = match found {
                    Some(id) => id,
                    None => {
                        normal.push(node.normal);
                        sum.push([0.0; 4]);
                        next.push(u32::MAX);
                        fresh
                    }
                };
                if votes {
                    let s = &mut sum[id as usize];
                    for ch in 0..3 {
                        s[ch] += w * own[i][ch];
                    }
                    s[3] += w;
                }
                c[k] = id;
            }
            corners.push(c);
        }
        let voted: Vec<bool> = sum.iter().map(|s| s[3] > 0.0).collect();
        let nodal = nodal_means(&sum);
        SmoothField {
            corners,
            votes: vote_weights,
            nodal,
            voted,
            own,
            rho,
            emission,
        }
    }

    /// The same field with `h[i]` taken from each element's own `H` (at least 0), averaged at
    /// the same vertices with the same weights: the field of a part of the light (a bake's
    /// light without its punctual lights' direct part, `crate::texel_light`). Without `h` (or
    /// with zeros) the field is the same, bit for bit.
    pub fn minus(&self, h: &[Rgb]) -> SmoothField {
        let own: Vec<Rgb> = self
            .own
            .iter()
            .enumerate()
            .map(|(i, o)| {
                let d = h.get(i).copied().unwrap_or([0.0; 3]);
                std::array::from_fn(|c| (o[c] - d[c]).max(0.0))
            })
            .collect();
        let mut sum = vec![[0.0f64; 4]; self.nodal.len()];
        for (i, c) in self.corners.iter().enumerate() {
            let w = self.votes[i];
            if w > 0.0 {
                for &id in c {
                    let s = &mut sum[id as usize];
                    for ch in 0..3 {
                        s[ch] += w * own[i][ch];
                    }
                    s[3] += w;
                }
            }
        }
        SmoothField {
            corners: self.corners.clone(),
            votes: self.votes.clone(),
            nodal: nodal_means(&sum),
            voted: self.voted.clone(),
            own,
            rho: self.rho.clone(),
            emission: self.emission.clone(),
        }
    }

    /// Element `leaf`'s reflectance.
    pub fn reflectance(&self, leaf: u32) -> Rgb {
        self.rho.get(leaf as usize).copied().unwrap_or([0.0; 3])
    }

    /// `H` in element `leaf` at barycentric weights `w` of its vertices.
    pub fn irradiance_in(&self, leaf: u32, w: [f64; 3]) -> Rgb {
        let i = leaf as usize;
        let Some(c) = self.corners.get(i) else {
            return [0.0; 3];
        };
        let mut h = [0.0; 3];
        for k in 0..3 {
            let id = c[k] as usize;
            let v = if self.voted[id] {
                self.nodal[id]
            } else {
                self.own[i]
            };
            let wk = w[k].clamp(0.0, 1.0);
            for ch in 0..3 {
                h[ch] += wk * v[ch];
            }
        }
        h
    }

    /// Radiosity in element `leaf` at barycentric weights `w`: `E + ρ H`.
    pub fn radiosity_in(&self, leaf: u32, w: [f64; 3]) -> Rgb {
        let h = self.irradiance_in(leaf, w);
        let (r, e) = (self.rho[leaf as usize], self.emission[leaf as usize]);
        std::array::from_fn(|c| e[c] + r[c] * h[c])
    }

    /// `H` on input triangle `root` at barycentric weights `(1 − u − v, u, v)`.
    pub fn irradiance(&self, mesh: &Mesh, root: u32, u: f64, v: f64) -> Rgb {
        let (leaf, w) = mesh.locate_weights(root, u, v);
        self.irradiance_in(leaf, w)
    }

    /// Radiosity on input triangle `root` at barycentric weights `(1 − u − v, u, v)`.
    pub fn radiosity(&self, mesh: &Mesh, root: u32, u: f64, v: f64) -> Rgb {
        let (leaf, w) = mesh.locate_weights(root, u, v);
        self.radiosity_in(leaf, w)
    }

    /// Radiosity at world point `p` on a surface facing `normal` (the element found as
    /// [`crate::metrics::element_at`] finds it), or `None` when no element holds it.
    pub fn radiosity_at(&self, mesh: &Mesh, p: DVec3, normal: DVec3) -> Option<Rgb> {
        let e = crate::metrics::element_at(mesh, p, normal)?;
        let node = mesh.leaf_node(e as u32);
        let q = mesh.frame.to_local(p);
        let [a, b, c] = node.v;
        let n = (b - a).cross(c - a);
        let d = n.length_squared();
        if d <= 0.0 {
            return Some(self.radiosity_in(e as u32, [1.0 / 3.0; 3]));
        }
        let w1 = (q - a).cross(c - a).dot(n) / d;
        let w2 = (b - a).cross(q - a).dot(n) / d;
        Some(self.radiosity_in(e as u32, [1.0 - w1 - w2, w1, w2]))
    }
}

/// Per vertex, the weighted mean of its votes (`[Σ w H, Σ w]`), 0 where none voted.
fn nodal_means(sum: &[[f64; 4]]) -> Vec<Rgb> {
    sum.iter()
        .map(|s| {
            if s[3] > 0.0 {
                [s[0] / s[3], s[1] / s[3], s[2] / s[3]]
            } else {
                [0.0; 3]
            }
        })
        .collect()
}
