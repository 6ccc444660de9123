//! A bake's light map on the scene's atlas (`radiant_scene::atlas`: UV charts on one or more
//! pages; the renderer draws the same atlas). Each texel holds the
//! incident radiance `H` at its own point from the smooth field (`crate::smooth`), so a surface
//! of albedo `a` reflects `a · H` (plus its emission); texels around each chart repeat its edge.
//! Triangles left out of the bake (dynamic surfaces) stay 0.

use radiant_scene::Scene;
use radiant_scene::atlas::Atlas;

use crate::mesh::Mesh;
use crate::smooth::SmoothField;

/// A light map: linear RGB `H`, `pages` pages of `width × height` texels, each row-major, one
/// after the other.
#[derive(Clone, Debug, PartialEq)]
pub struct LightMap {
    /// Width of a page in texels.
    pub width: u32,
    /// Height of a page in texels.
    pub height: u32,
    /// Pages.
    pub pages: u32,
    /// Texels (linear RGB incident radiance, emissive units); texels outside charts are 0.
    pub texels: Vec<[f32; 3]>,
}

/// Per scene triangle, the bake's input triangle (the bake meshes the static part only), or
/// `None` for a triangle of a dynamic surface.
pub fn static_roots(scene: &Scene) -> Vec<Option<u32>> {
    let mut next = 0u32;
    scene
        .triangles
        .iter()
        .map(|t| {
            let dynamic = scene
                .surfaces
                .get(t.surface as usize)
                .is_none_or(|s| s.dynamic);
            (!dynamic).then(|| {
                next += 1;
                next - 1
            })
        })
        .collect()
}

/// Fills `atlas` with the bake's `H` from `field` (on `mesh`, the bake of `scene`'s static part).
pub fn bake_lightmap(scene: &Scene, atlas: &Atlas, mesh: &Mesh, field: &SmoothField) -> LightMap {
    let roots = static_roots(scene);
    let texels = atlas.fill(scene, |i, u, v, _| match roots.get(i).copied().flatten() {
        Some(root) if (root as usize) < mesh.roots.len() => field
            .irradiance(mesh, root, f64::from(u), f64::from(v))
            .map(|x| x as f32),
        _ => [0.0; 3],
    });
    LightMap {
        width: atlas.width,
        height: atlas.height,
        pages: atlas.pages,
        texels,
    }
}
