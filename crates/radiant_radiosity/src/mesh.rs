//! Meshing: each input triangle becomes the root of a quadtree of similar triangles (midpoint
//! subdivision). *Patches* are the nodes whose longest edge first fits the patch size; *elements*
//! are the leaves, `element_levels` below the patches. Leaves are numbered depth-first, so every
//! node covers a contiguous range of leaves.
//!
//! Everything is stored in a local frame: world positions minus the scene's bounding-box centre,
//! divided by its largest extent. Form factors are scale-invariant, so this loses nothing, and it
//! keeps a scene far from the origin or at an extreme scale exact in `f64` and usable in `f32`.

use glam::{DVec3, Vec3};
use radiant_scene::Scene;

use crate::{BakeError, ParameterError, SceneError};

/// Marks a leaf in [`Node::first_child`].
pub const NO_CHILD: u32 = u32::MAX;

/// The map from world to local coordinates: `local = (world - center) / scale`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// Centre of the scene's bounding box (world units).
    pub center: DVec3,
    /// Largest extent of the bounding box (world units); positive.
    pub scale: f64,
}

impl Frame {
    /// The frame every mesh of `scene` is made in: the centre and largest extent of its
    /// bounding box. A typed error for a scene without triangles, of zero extent or with a
    /// vertex that is not finite.
    pub fn of(scene: &Scene) -> Result<Frame, BakeError> {
        frame_of(scene)
    }
    /// World → local.
    pub fn to_local(&self, p: DVec3) -> DVec3 {
        (p - self.center) / self.scale
    }
    /// Local → world.
    pub fn to_world(&self, p: DVec3) -> DVec3 {
        p * self.scale + self.center
    }
}

/// A triangle of the hierarchy.
#[derive(Clone, Copy, Debug)]
pub struct Node {
    /// Vertices in the local frame, counter-clockwise seen from the front.
    pub v: [DVec3; 3],
    /// Centroid (local frame).
    pub centroid: DVec3,
    /// Unit front normal.
    pub normal: DVec3,
    /// Area in local units (world area = `area * scale²`).
    pub area: f64,
    /// Index of the first of four consecutive children, or [`NO_CHILD`].
    pub first_child: u32,
    /// Parent node, or `u32::MAX` for roots.
    pub parent: u32,
    /// First leaf (element) under this node.
    pub leaf_lo: u32,
    /// One past the last leaf under this node.
    pub leaf_hi: u32,
    /// Index of the input triangle this node subdivides.
    pub root: u32,
    /// Depth below the root.
    pub depth: u8,
}

impl Node {
    /// Whether this node is an element (has no children).
    pub fn is_leaf(&self) -> bool {
        self.first_child == NO_CHILD
    }
}

/// Meshing parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshParams {
    /// Target longest edge of a patch, in scene (world) units; 0 picks a quarter of the
    /// scene's extent (default: 0).
    pub patch_size: f64,
    /// Levels of subdivision from patches down to elements; each level splits a triangle in 4
    /// (default: 2).
    pub element_levels: u8,
    /// Refuse meshes with more elements than this (default: 4 000 000).
    pub max_elements: usize,
}

impl Default for MeshParams {
    fn default() -> Self {
        MeshParams {
            patch_size: 0.0,
            element_levels: 2,
            max_elements: 4_000_000,
        }
    }
}

/// The element hierarchy of a scene.
#[derive(Clone, Debug)]
pub struct Mesh {
    /// World ↔ local map.
    pub frame: Frame,
    /// All nodes; children come after their parent.
    pub nodes: Vec<Node>,
    /// Root node of each input triangle.
    pub roots: Vec<u32>,
    /// Leaf index → node index.
    pub leaves: Vec<u32>,
    /// Surface index of each input triangle.
    pub root_surface: Vec<u32>,
    /// Depth of patches under each root.
    pub patch_depth: Vec<u8>,
    /// Number of patches.
    pub patch_count: usize,
    /// Per input triangle: a hash of its surface's name and its index among that surface's
    /// triangles (see [`Mesh::stable_id`]).
    pub root_key: Vec<u64>,
}

/// See [`Mesh::root_key`].
fn root_keys(scene: &Scene) -> Vec<u64> {
    let mut seen = vec![0u64; scene.surfaces.len()];
    scene
        .triangles
        .iter()
        .map(|t| {
            let name = scene
                .surfaces
                .get(t.surface as usize)
                .map_or("", |s| s.name.as_str());
            // FNV-1a of the name, then the triangle's index within its surface.
            let h = name.bytes().fold(0xCBF2_9CE4_8422_2325u64, |h, b| {
                (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3)
            });
            let k = seen.get_mut(t.surface as usize).map_or(0, |c| {
                *c += 1;
                *c - 1
            });
            crate::rng::hash(h, k, 2)
        })
        .collect()
}

impl Mesh {
    /// Meshes the scene. `params.patch_size == 0` picks a quarter of the scene's extent.
    pub fn new(scene: &Scene, params: &MeshParams) -> Result<Mesh, BakeError> {
        let frame = frame_of(scene)?;
        let patch_size = if params.patch_size > 0.0 && params.patch_size.is_finite() {
            params.patch_size / frame.scale
        } else if params.patch_size == 0.0 {
            0.25
        } else {
            return Err(
                ParameterError::out_of_range("patch size", params.patch_size, "(0, inf)").into(),
            );
        };
        // Plan depths first, so the element budget is checked before allocating.
        let mut plan = Vec::with_capacity(scene.triangles.len());
        let mut total: usize = 0;
        for t in &scene.triangles {
            let v = t.vertices.map(|p| frame.to_local(p));
            let longest = (v[1] - v[0])
                .length()
                .max((v[2] - v[1]).length())
                .max((v[0] - v[2]).length());
            let mut pd = 0u8;
            while longest / f64::from(1u32 << pd) > patch_size && pd < 14 {
                pd += 1;
            }
            let ld = pd.saturating_add(params.element_levels).min(15);
            total = total.saturating_add(1usize << (2 * ld as usize));
            plan.push((v, pd, ld));
        }
        if total > params.max_elements {
            return Err(BakeError::TooManyElements {
                elements: total,
                limit: params.max_elements,
            });
        }
        let mut mesh = Mesh {
            frame,
            nodes: Vec::with_capacity(total * 4 / 3 + plan.len()),
            roots: Vec::with_capacity(plan.len()),
            leaves: Vec::with_capacity(total),
            root_surface: scene.triangles.iter().map(|t| t.surface).collect(),
            root_key: root_keys(scene),
            patch_depth: plan.iter().map(|p| p.1).collect(),
            patch_count: plan.iter().map(|p| 1usize << (2 * p.1 as usize)).sum(),
        };
        for (r, (v, _, ld)) in plan.into_iter().enumerate() {
            let id = mesh.push(v, u32::MAX, r as u32, 0);
            mesh.roots.push(id);
            mesh.subdivide(id, ld);
        }
        Ok(mesh)
    }

    /// Elements [`Mesh::new`] would make, counted without meshing (saturating).
    pub fn count_elements(scene: &Scene, params: &MeshParams) -> Result<u64, BakeError> {
        let frame = frame_of(scene)?;
        let patch = if params.patch_size > 0.0 && params.patch_size.is_finite() {
            params.patch_size / frame.scale
        } else {
            0.25
        };
        let mut total = 0u64;
        for t in &scene.triangles {
            let v = t.vertices.map(|p| frame.to_local(p));
            let longest = (v[1] - v[0])
                .length()
                .max((v[2] - v[1]).length())
                .max((v[0] - v[2]).length());
            let mut pd = 0u8;
            while longest / f64::from(1u32 << pd) > patch && pd < 14 {
                pd += 1;
            }
            let ld = pd.saturating_add(params.element_levels).min(15);
            total = total.saturating_add(1u64 << (2 * u64::from(ld)));
        }
        Ok(total)
    }

    /// Meshes the scene to fit its geometry, for the clustered hierarchy
    /// ([`crate::cluster`]): each input triangle is subdivided until its longest edge fits the
    /// element size, `params.patch_size / 2^element_levels` (world units; patch size 0: a
    /// quarter of the scene's extent), so a triangle already that small stays one element and a
    /// large one gets as many as its size needs; no fixed count per triangle. The element
    /// count is known before anything is allocated: `reserve(bytes)` is asked for the nodes'
    /// memory first and may refuse it (the memory budget).
    pub fn adaptive(
        scene: &Scene,
        params: &MeshParams,
        reserve: &mut dyn FnMut(u64) -> Result<(), BakeError>,
    ) -> Result<Mesh, BakeError> {
        let frame = frame_of(scene)?;
        let patch = if params.patch_size == 0.0 {
            0.25
        } else if params.patch_size > 0.0 && params.patch_size.is_finite() {
            params.patch_size / frame.scale
        } else {
            return Err(
                ParameterError::out_of_range("patch size", params.patch_size, "(0, inf)").into(),
            );
        };
        let element_size = patch / f64::from(1u32 << params.element_levels.min(16));
        let mut plan = Vec::with_capacity(scene.triangles.len());
        let (mut leaves, mut nodes) = (0u64, 0u64);
        for t in &scene.triangles {
            let v = t.vertices.map(|p| frame.to_local(p));
            let longest = (v[1] - v[0])
                .length()
                .max((v[2] - v[1]).length())
                .max((v[0] - v[2]).length());
            let mut d = 0u8;
            while longest / f64::from(1u32 << d) > element_size && d < 12 {
                d += 1;
            }
            leaves += 1u64 << (2 * u64::from(d));
            nodes += ((1u64 << (2 * u64::from(d) + 2)) - 1) / 3;
            plan.push((v, d));
        }
        if nodes >= u64::from(u32::MAX) {
            return Err(BakeError::OutOfMemory {
                what: "mesh nodes",
                needed: nodes.saturating_mul(std::mem::size_of::<Node>() as u64),
                limit: u64::from(u32::MAX),
            });
        }
        reserve(nodes * (std::mem::size_of::<Node>() as u64 + 4) + leaves * 4)?;
        let mut mesh = Mesh {
            frame,
            nodes: Vec::new(),
            roots: Vec::new(),
            leaves: Vec::new(),
            root_surface: scene.triangles.iter().map(|t| t.surface).collect(),
            root_key: root_keys(scene),
            patch_depth: plan.iter().map(|p| p.1).collect(),
            patch_count: leaves as usize,
        };
        let oom = |what| BakeError::OutOfMemory {
            what,
            needed: nodes * std::mem::size_of::<Node>() as u64,
            limit: 0,
        };
        mesh.nodes
            .try_reserve_exact(nodes as usize)
            .map_err(|_| oom("mesh nodes"))?;
        mesh.leaves
            .try_reserve_exact(leaves as usize)
            .map_err(|_| oom("mesh leaves"))?;
        mesh.roots
            .try_reserve_exact(plan.len())
            .map_err(|_| oom("mesh roots"))?;
        for (r, (v, d)) in plan.into_iter().enumerate() {
            let id = mesh.push(v, u32::MAX, r as u32, 0);
            mesh.roots.push(id);
            mesh.subdivide(id, d);
        }
        Ok(mesh)
    }

    fn push(&mut self, v: [DVec3; 3], parent: u32, root: u32, depth: u8) -> u32 {
        let c = (v[1] - v[0]).cross(v[2] - v[0]);
        let len = c.length();
        self.nodes.push(Node {
            v,
            centroid: (v[0] + v[1] + v[2]) / 3.0,
            normal: if len > 0.0 { c / len } else { DVec3::Z },
            area: 0.5 * len,
            first_child: NO_CHILD,
            parent,
            leaf_lo: 0,
            leaf_hi: 0,
            root,
            depth,
        });
        (self.nodes.len() - 1) as u32
    }

    fn subdivide(&mut self, id: u32, leaf_depth: u8) {
        let node = self.nodes[id as usize];
        let lo = self.leaves.len() as u32;
        if node.depth >= leaf_depth {
            self.leaves.push(id);
        } else {
            let [a, b, c] = node.v;
            let (ab, bc, ca) = ((a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5);
            let kids = [[a, ab, ca], [ab, b, bc], [ca, bc, c], [bc, ca, ab]];
            let first = self.nodes.len() as u32;
            for k in kids {
                self.push(k, id, node.root, node.depth + 1);
            }
            self.nodes[id as usize].first_child = first;
            for k in 0..4 {
                self.subdivide(first + k, leaf_depth);
            }
        }
        let n = &mut self.nodes[id as usize];
        n.leaf_lo = lo;
        n.leaf_hi = self.leaves.len() as u32;
    }

    /// A number for `node` that depends on its surface's name, its input triangle's place among
    /// that surface's triangles and its place in the triangle's subtree, not on the order of the
    /// scene's surfaces nor on where the scene sits: random sequences seeded by it (visibility
    /// rays) stay the same when other surfaces are added or removed, or the scene is scaled or
    /// moved, so an edited bake keeps exactly the estimates a fresh bake would make.
    pub fn stable_id(&self, node: u32) -> u64 {
        let Some(n) = self.nodes.get(node as usize) else {
            return u64::from(node);
        };
        let root_id = self.roots.get(n.root as usize).copied().unwrap_or(0);
        let key = self.root_key.get(n.root as usize).copied().unwrap_or(0);
        crate::rng::hash(key, u64::from(node.wrapping_sub(root_id)), 1)
    }

    /// Number of elements (leaves).
    pub fn element_count(&self) -> usize {
        self.leaves.len()
    }

    /// The leaf node of element `leaf`.
    pub fn leaf_node(&self, leaf: u32) -> &Node {
        &self.nodes[self.leaves[leaf as usize] as usize]
    }

    /// The element of input triangle `root` that contains the point with barycentric weights
    /// `(1 - u - v, u, v)` on the input triangle.
    pub fn locate(&self, root: u32, u: f64, v: f64) -> u32 {
        self.locate_weights(root, u, v).0
    }

    /// [`Mesh::locate`], with the point's barycentric weights of the element's own vertices.
    pub fn locate_weights(&self, root: u32, u: f64, v: f64) -> (u32, [f64; 3]) {
        let mut id = self.roots[root as usize];
        let (mut b0, mut b1, mut b2) = (1.0 - u - v, u, v);
        loop {
            let n = &self.nodes[id as usize];
            if n.is_leaf() {
                return (n.leaf_lo, [b0, b1, b2]);
            }
            // Children: 0 at vertex 0, 1 at vertex 1, 2 at vertex 2, 3 in the middle (its
            // vertices the midpoints of the opposite edges).
            let k = if b0 >= 0.5 {
                (b0, b1, b2) = (2.0 * b0 - 1.0, 2.0 * b1, 2.0 * b2);
                0
            } else if b1 >= 0.5 {
                (b0, b1, b2) = (2.0 * b0, 2.0 * b1 - 1.0, 2.0 * b2);
                1
            } else if b2 >= 0.5 {
                (b0, b1, b2) = (2.0 * b0, 2.0 * b1, 2.0 * b2 - 1.0);
                2
            } else {
                (b0, b1, b2) = (1.0 - 2.0 * b0, 1.0 - 2.0 * b1, 1.0 - 2.0 * b2);
                3
            };
            id = n.first_child + k;
        }
    }

    /// The input triangles in the local frame as `f32`, for the BVH.
    pub fn root_triangles_f32(&self) -> Vec<[Vec3; 3]> {
        self.roots
            .iter()
            .map(|&r| self.nodes[r as usize].v.map(|p| p.as_vec3()))
            .collect()
    }
}

fn frame_of(scene: &Scene) -> Result<Frame, BakeError> {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for (triangle, t) in scene.triangles.iter().enumerate() {
        for v in t.vertices {
            if !v.is_finite() {
                return Err(SceneError::NonFiniteVertex { triangle }.into());
            }
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    if scene.triangles.is_empty() {
        return Err(SceneError::NoTriangles.into());
    }
    let scale = (hi - lo).max_element();
    if !(scale > 0.0 && scale.is_finite()) {
        return Err(SceneError::ZeroExtent.into());
    }
    Ok(Frame {
        center: (lo + hi) * 0.5,
        scale,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leaves_tile_each_root_and_locate_finds_them() {
        let scene = radiant_scene::builtin("cornell-box").expect("builtin");
        let mesh = Mesh::new(
            &scene,
            &MeshParams {
                patch_size: 0.2,
                ..Default::default()
            },
        )
        .expect("mesh");
        for &r in &mesh.roots {
            let root = mesh.nodes[r as usize];
            let sum: f64 = (root.leaf_lo..root.leaf_hi)
                .map(|l| mesh.leaf_node(l).area)
                .sum();
            assert!((sum - root.area).abs() < 1e-12 * root.area.max(1.0));
        }
        // Every leaf's centroid locates to itself.
        for (leaf, &id) in mesh.leaves.iter().enumerate() {
            let n = mesh.nodes[id as usize];
            let root = mesh.nodes[mesh.roots[n.root as usize] as usize];
            // Barycentrics of the centroid on the root triangle.
            let (e1, e2, p) = (
                root.v[1] - root.v[0],
                root.v[2] - root.v[0],
                n.centroid - root.v[0],
            );
            let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
            let (p1, p2) = (p.dot(e1), p.dot(e2));
            let det = d11 * d22 - d12 * d12;
            let u = (d22 * p1 - d12 * p2) / det;
            let v = (d11 * p2 - d12 * p1) / det;
            assert_eq!(mesh.locate(n.root, u, v), leaf as u32);
        }
    }

    #[test]
    fn bad_patch_size_and_budget_are_errors() {
        let scene = radiant_scene::builtin("cornell-box").expect("builtin");
        assert!(matches!(
            Mesh::new(
                &scene,
                &MeshParams {
                    patch_size: -1.0,
                    ..Default::default()
                }
            ),
            Err(BakeError::InvalidParameter(_))
        ));
        assert!(matches!(
            Mesh::new(
                &scene,
                &MeshParams {
                    patch_size: 1e-4,
                    max_elements: 1000,
                    ..Default::default()
                }
            ),
            Err(BakeError::TooManyElements { .. })
        ));
    }
}
