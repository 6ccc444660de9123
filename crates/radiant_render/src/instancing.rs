//! Drawing a level's repeated meshes once: surfaces that are copies of another under an affine
//! transform (glTF instances, which the scene model flattens for the bake) are found by their
//! geometry, and drawn as instances of one copy's vertices.
//!
//! A surface is an instance of a prototype when it has the prototype's material, triangle
//! count and texture coordinates, and one affine map with a positive determinant takes every
//! prototype vertex onto the surface's within a millionth of its size (and its normals onto
//! the surface's). The map is found from the first triangle and the vertex furthest from its
//! plane (for flat surfaces, a similarity is assumed), then checked on every vertex, so a
//! false match is impossible and a missed one only costs memory: it is drawn flattened.
//!
//! Light maps stay per instance: every surface has its own charts in the atlas, so a copy's
//! light-map coordinates are its own (`RenderScene::instance_uvs`, in the prototype's vertex
//! order); the vertex shader reads them by vertex index from a storage buffer.

use std::collections::HashMap;

use glam::{DAffine3, DMat3, DVec3};
use radiant_scene::Scene;

/// One drawn copy as the G-buffer's vertex shader reads it (112 bytes): rows of the
/// origin-relative model matrix, rows of its normal matrix, and where its light-map
/// coordinates are.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct InstanceData {
    /// Rows of the 3 × 4 model matrix (prototype vertex → this copy, origin-relative).
    pub model: [[f32; 4]; 3],
    /// Rows of the normal matrix (inverse transpose of the model's 3 × 3), w unused.
    pub normal: [[f32; 4]; 3],
    /// Light-map coordinates: `[base, first, own, 0]`. With `own` = 1 the vertex at index `i`
    /// of a draw starting at vertex `first` takes `RenderScene::instance_uvs[base + i - first]`;
    /// with 0, the vertex's own (`first` is set by the upload, which knows where draws start).
    pub lightmap: [u32; 4],
}

impl InstanceData {
    /// The identity: vertices drawn where they are.
    pub const IDENTITY: InstanceData = InstanceData {
        model: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ],
        normal: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ],
        lightmap: [0; 4],
    };

    /// A copy placed by `m` (origin-relative: prototype position → copy position), its light-map
    /// coordinates at `base` of `RenderScene::instance_uvs`.
    pub fn new(m: DAffine3, base: u32) -> InstanceData {
        let a = m.matrix3;
        let n = a.inverse().transpose();
        let t = m.translation;
        let row = |k: usize, mat: DMat3, w: f64| {
            let r = mat.row(k);
            [r.x as f32, r.y as f32, r.z as f32, w as f32]
        };
        InstanceData {
            model: [row(0, a, t.x), row(1, a, t.y), row(2, a, t.z)],
            normal: [row(0, n, 0.0), row(1, n, 0.0), row(2, n, 0.0)],
            lightmap: [base, 0, 1, 0],
        }
    }
}

/// For every surface: `Some((prototype, map))` when it is a copy of an earlier surface (the
/// map takes the prototype's world positions to its own), `None` for a prototype or a surface
/// drawn on its own. `triangles[s]` lists surface `s`'s triangles in scene order;
/// `material[s]` is its renderer material.
pub fn find_instances(
    scene: &Scene,
    triangles: &[Vec<u32>],
    material: &[u32],
) -> Vec<Option<(u32, DAffine3)>> {
    let mut out = vec![None; triangles.len()];
    // Candidates share the material, the triangle count and the colours.
    let mut groups: HashMap<(u32, usize, [u64; 6]), Vec<u32>> = HashMap::new();
    for (s, tris) in triangles.iter().enumerate() {
        if tris.is_empty() {
            continue;
        }
        let surface = &scene.surfaces[s];
        let colours: Vec<u64> = surface
            .reflectance
            .iter()
            .chain(&surface.emission)
            .map(|x| x.to_bits())
            .collect();
        let key = (material[s], tris.len(), std::array::from_fn(|i| colours[i]));
        let protos = groups.entry(key).or_default();
        let found = protos
            .iter()
            .find_map(|&p| affine_between(scene, &triangles[p as usize], tris).map(|m| (p, m)));
        match found {
            Some(hit) => out[s] = Some(hit),
            None => protos.push(s as u32),
        }
    }
    out
}

/// The affine map taking surface `p`'s triangles onto `q`'s, vertex for vertex, if there is
/// one (positive determinant; every vertex within a millionth of `q`'s size; normals and
/// texture coordinates matching).
fn affine_between(scene: &Scene, p: &[u32], q: &[u32]) -> Option<DAffine3> {
    let tri = |i: u32| &scene.triangles[i as usize];
    let (tp, tq) = (tri(p[0]), tri(q[0]));
    let [p0, p1, p2] = tp.vertices;
    let [q0, q1, q2] = tq.vertices;
    let (np, nq) = ((p1 - p0).cross(p2 - p0), (q1 - q0).cross(q2 - q0));
    if np.length_squared() <= 0.0 || nq.length_squared() <= 0.0 {
        return None;
    }
    // A fourth point off the first triangle's plane: the farthest vertex, or for a flat
    // surface the normal scaled like a length (exact for similarities).
    let unit = np.normalize();
    let mut far = (0.0f64, p0, q0);
    for (&i, &j) in p.iter().zip(q) {
        for (a, b) in tri(i).vertices.iter().zip(tri(j).vertices) {
            let d = (*a - p0).dot(unit).abs();
            if d > far.0 {
                far = (d, *a, b);
            }
        }
    }
    let size_p = (p1 - p0).length().max((p2 - p0).length());
    let (p3, q3) = if far.0 > 1e-6 * size_p {
        (far.1, far.2)
    } else {
        (
            p0 + unit * np.length().sqrt(),
            q0 + nq.normalize() * nq.length().sqrt(),
        )
    };
    let pm = DMat3::from_cols(p1 - p0, p2 - p0, p3 - p0);
    let det = pm.determinant();
    if !det.is_finite() || det.abs() <= 1e-12 * size_p.powi(3) {
        return None;
    }
    let a = DMat3::from_cols(q1 - q0, q2 - q0, q3 - q0) * pm.inverse();
    if !a.is_finite() || a.determinant() <= 0.0 {
        return None;
    }
    let m = DAffine3::from_mat3_translation(a, q0 - a * p0);
    let normals = a.inverse().transpose();
    // Every vertex, normal and texture coordinate must agree.
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for &j in q {
        for v in tri(j).vertices {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    let tol = 1e-6 * (hi - lo).length() + 1e-9;
    for (&i, &j) in p.iter().zip(q) {
        let (a_t, b_t) = (tri(i), tri(j));
        if a_t.uv != b_t.uv {
            return None;
        }
        for k in 0..3 {
            if (m.transform_point3(a_t.vertices[k]) - b_t.vertices[k]).length() > tol {
                return None;
            }
            let n = (normals * a_t.normals[k].as_dvec3()).normalize_or_zero();
            if (n - b_t.normals[k].as_dvec3()).length() > 1e-3 {
                return None;
            }
        }
    }
    Some(m)
}
