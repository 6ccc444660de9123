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

impl LightMap {
    /// `H` at light-map coordinates `uv` (in [0, 1], texel `(x, y)` centred at
    /// `((x + ½)/width, (y + ½)/height)`) on `page`, filtered as the renderer's sampler filters
    /// it: bilinear between the four nearest texel centres, clamped to the page's edge. Black
    /// for a page the map lacks or coordinates that are not finite.
    pub fn sample(&self, page: u32, uv: [f64; 2]) -> [f64; 3] {
        let (w, h) = (self.width as usize, self.height as usize);
        if page >= self.pages || w == 0 || h == 0 || !uv.iter().all(|c| c.is_finite()) {
            return [0.0; 3];
        }
        let base = page as usize * w * h;
        let axis = |c: f64, n: usize| {
            let x = (c * n as f64 - 0.5).clamp(-1.0, n as f64);
            let x0 = x.floor();
            let i = |k: f64| (k.max(0.0) as usize).min(n - 1);
            (i(x0), i(x0 + 1.0), x - x0)
        };
        let (x0, x1, fx) = axis(uv[0], w);
        let (y0, y1, fy) = axis(uv[1], h);
        let mut out = [0.0; 3];
        for (x, y, weight) in [
            (x0, y0, (1.0 - fx) * (1.0 - fy)),
            (x1, y0, fx * (1.0 - fy)),
            (x0, y1, (1.0 - fx) * fy),
            (x1, y1, fx * fy),
        ] {
            let t = self
                .texels
                .get(base + y * w + x)
                .copied()
                .unwrap_or_default();
            for c in 0..3 {
                out[c] += weight * f64::from(t[c]);
            }
        }
        out
    }
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
