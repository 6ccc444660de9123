//! The light-map atlas of a scene: one chart per triangle (a `cell × cell` texel square holding
//! the triangle's three corners, inset one texel so bilinear filtering stays inside), a
//! surface's charts one block, blocks packed on shelves. The CLI's light map and the
//! renderer's are this one atlas; `rasterize` fills either, dilating each chart by one texel.

use glam::{DVec3, Vec2};

use crate::Scene;

/// The most texels [`Atlas::new`] gives an atlas: a scene with many triangles gets fewer texels
/// per triangle (down to 4 × 4), not a larger map.
pub const MAX_TEXELS: u64 = 8 << 20;

/// The largest side [`Atlas::new`] makes (the WebGPU minimum of `max_texture_dimension_2d`).
pub const MAX_SIDE: u32 = 8192;

/// A surface's charts in the atlas: cells `(x + k % width, y + k / width)` for its triangle `k`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Block {
    /// First cell, x.
    pub x: u32,
    /// First cell, y.
    pub y: u32,
    /// Cells per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
}

/// Packs one block per surface (`counts[s]` triangles, a near-square block each) on shelves,
/// tallest first; returns the blocks and the atlas size in cells.
pub fn pack_blocks(counts: &[usize]) -> (Vec<Block>, u32, u32) {
    let mut blocks: Vec<Block> = counts
        .iter()
        .map(|&n| {
            let width = ((n as f64).sqrt().ceil() as u32).max(1);
            Block {
                width,
                height: (n as u32).div_ceil(width),
                ..Block::default()
            }
        })
        .collect();
    let total: u64 = blocks
        .iter()
        .map(|b| u64::from(b.width) * u64::from(b.height))
        .sum();
    let widest = blocks.iter().map(|b| b.width).max().unwrap_or(1);
    let side = ((total as f64).sqrt().ceil() as u32).max(widest).max(1);
    let mut order: Vec<usize> = (0..blocks.len()).filter(|&s| counts[s] > 0).collect();
    order.sort_by_key(|&s| (std::cmp::Reverse(blocks[s].height), s));
    let (mut x, mut y, mut shelf) = (0u32, 0u32, 0u32);
    for s in order {
        let b = &mut blocks[s];
        if x + b.width > side {
            (x, y, shelf) = (0, y + shelf, 0);
        }
        (b.x, b.y) = (x, y);
        x += b.width;
        shelf = shelf.max(b.height);
    }
    (blocks, side, (y + shelf).max(1))
}

/// A scene's atlas.
#[derive(Clone, Debug, PartialEq)]
pub struct Atlas {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Texels along a chart's side.
    pub cell: u32,
    /// Per surface, its block.
    pub blocks: Vec<Block>,
    /// Per triangle, the light-map coordinates of its three vertices, in [0, 1].
    pub uv: Vec<[Vec2; 3]>,
}

/// An atlas too large even at 4 texels per chart: its size in texels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TooLarge {
    /// Width it would need.
    pub width: u64,
    /// Height it would need.
    pub height: u64,
}

impl Atlas {
    /// The atlas of `scene` with `cell` texels per chart side (4 to 256), smaller where the
    /// atlas would pass [`MAX_TEXELS`] (not below 4).
    pub fn new(scene: &Scene, cell: u32) -> Result<Atlas, TooLarge> {
        let mut count = vec![0usize; scene.surfaces.len()];
        let mut slot = Vec::with_capacity(scene.triangles.len());
        for t in &scene.triangles {
            let c = count.get_mut(t.surface as usize);
            slot.push(c.as_ref().map_or(0, |c| **c) as u32);
            if let Some(c) = c {
                *c += 1;
            }
        }
        let (blocks, cols, rows) = pack_blocks(&count);
        let cells = u64::from(cols) * u64::from(rows);
        let fit = ((MAX_TEXELS as f64 / cells as f64).sqrt() as u32).min(MAX_SIDE / cols.max(rows));
        let asked = cell.clamp(4, 256);
        let cell = asked.min(fit).max(4);
        let (w, h) = (
            u64::from(cols) * u64::from(cell),
            u64::from(rows) * u64::from(cell),
        );
        if w > u64::from(MAX_SIDE) || h > u64::from(MAX_SIDE) {
            return Err(TooLarge {
                width: w,
                height: h,
            });
        }
        let (w, h) = (w as u32, h as u32);
        let inset = 1.0;
        let span = cell as f32 - 2.0 * inset - 1.0;
        let uv = scene
            .triangles
            .iter()
            .zip(&slot)
            .map(|(t, &k)| {
                let b = blocks.get(t.surface as usize).copied().unwrap_or_default();
                let (cx, cy) = (
                    (b.x + k % b.width.max(1)) * cell,
                    (b.y + k / b.width.max(1)) * cell,
                );
                let corner = |u: f32, v: f32| {
                    Vec2::new(
                        (cx as f32 + inset + 0.5 + u * span) / w as f32,
                        (cy as f32 + inset + 0.5 + v * span) / h as f32,
                    )
                };
                [corner(0.0, 0.0), corner(1.0, 0.0), corner(0.0, 1.0)]
            })
            .collect();
        Ok(Atlas {
            width: w,
            height: h,
            cell,
            blocks,
            uv,
        })
    }

    /// Texels per scene unit along a surface, area-weighted over `scene`'s triangles (each
    /// chart's texels inside its triangle over the triangle's area, square-rooted).
    pub fn texel_density(&self, scene: &Scene) -> f64 {
        let inside = {
            let s = self.cell as f64 - 3.0;
            0.5 * s * s
        };
        let (mut sum, mut area) = (0.0, 0.0);
        for t in &scene.triangles {
            let a = t.area();
            if a > 0.0 && a.is_finite() {
                sum += a * (inside / a).sqrt();
                area += a;
            }
        }
        if area > 0.0 { sum / area } else { 0.0 }
    }

    /// The share of texels inside some chart's triangle.
    pub fn utilisation(&self) -> f64 {
        let per_chart = {
            let s = self.cell as f64 - 3.0;
            0.5 * s * s
        };
        (self.uv.len() as f64 * per_chart / (f64::from(self.width) * f64::from(self.height)))
            .min(1.0)
    }
}

/// Fills `texels` (`width × height`, row-major) chart by chart: `charts` yields each triangle's
/// index, its light-map coordinates and its three positions; every texel of the chart's box and
/// one around it gets `eval(triangle, u, v, position)` at the texel centre's barycentric
/// weights clamped onto the triangle, so the ring around a chart repeats its edge and bilinear
/// filtering never reads outside it.
pub fn rasterize(
    width: u32,
    height: u32,
    texels: &mut [[f32; 3]],
    charts: impl Iterator<Item = (usize, [Vec2; 3], [DVec3; 3])>,
    mut eval: impl FnMut(usize, f32, f32, DVec3) -> [f32; 3],
) {
    if texels.len() as u64 != u64::from(width) * u64::from(height) {
        return;
    }
    let (w, h) = (width as f32, height as f32);
    for (index, uv, p) in charts {
        let uv = uv.map(|c| c * Vec2::new(w, h));
        let lo = uv[0].min(uv[1]).min(uv[2]).floor() - 1.0;
        let hi = uv[0].max(uv[1]).max(uv[2]).ceil() + 1.0;
        let (e1, e2) = (uv[1] - uv[0], uv[2] - uv[0]);
        let det = e1.perp_dot(e2);
        if det.abs() < 1e-12 || !(lo.is_finite() && hi.is_finite()) {
            continue;
        }
        for y in lo.y.max(0.0) as u32..(hi.y.max(0.0) as u32).min(height) {
            for x in lo.x.max(0.0) as u32..(hi.x.max(0.0) as u32).min(width) {
                let q = Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - uv[0];
                // Barycentrics, clamped onto the triangle so the border texels dilate it.
                let u = (q.perp_dot(e2) / det).clamp(0.0, 1.0);
                let v = (e1.perp_dot(q) / det).clamp(0.0, 1.0 - u);
                let (u64_, v64) = (f64::from(u), f64::from(v));
                let pos = p[0] + (p[1] - p[0]) * u64_ + (p[2] - p[0]) * v64;
                texels[(y * width + x) as usize] = eval(index, u, v, pos);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_do_not_overlap_and_fit_the_atlas() {
        let counts = [1usize, 7, 300, 0, 64, 2, 2, 1000, 5];
        let (blocks, w, h) = pack_blocks(&counts);
        let mut used = vec![false; (w * h) as usize];
        for (b, &n) in blocks.iter().zip(&counts) {
            for k in 0..n as u32 {
                let (x, y) = (b.x + k % b.width, b.y + k / b.width);
                assert!(x < w && y < h, "cell ({x}, {y}) outside {w}×{h}");
                let i = (y * w + x) as usize;
                assert!(!used[i], "cell ({x}, {y}) used twice");
                used[i] = true;
            }
        }
        let cells: usize = counts.iter().sum();
        assert!((w * h) as usize <= cells * 2, "{w}×{h} for {cells} cells");
    }

    #[test]
    fn charts_stay_in_their_cells_and_the_unit_square() {
        let scene = crate::builtin("cornell-box").expect("builtin");
        let atlas = Atlas::new(&scene, 16).expect("atlas");
        assert_eq!(atlas.uv.len(), scene.triangles.len());
        let mut cells = std::collections::HashSet::new();
        for uv in &atlas.uv {
            assert!(
                uv.iter()
                    .all(|c| (0.0..=1.0).contains(&c.x) && (0.0..=1.0).contains(&c.y))
            );
            let cell = (
                (uv[0].x * atlas.width as f32 / 16.0) as u32,
                (uv[0].y * atlas.height as f32 / 16.0) as u32,
            );
            for c in uv {
                let here = (
                    (c.x * atlas.width as f32 / 16.0) as u32,
                    (c.y * atlas.height as f32 / 16.0) as u32,
                );
                assert_eq!(here, cell, "a chart leaves its cell");
            }
            assert!(cells.insert(cell), "two charts in cell {cell:?}");
        }
        assert!(atlas.utilisation() > 0.2, "{}", atlas.utilisation());
    }

    #[test]
    fn texel_density_is_texels_inside_a_chart_per_unit_of_length() {
        // One right triangle of legs 2: area 2; 32-texel charts hold 0.5 · 29² texels.
        let mut scene = Scene::default();
        scene.surfaces.push(crate::Surface::default());
        scene.triangles.push(crate::Triangle::new(
            [DVec3::ZERO, DVec3::X * 2.0, DVec3::Y * 2.0],
            0,
        ));
        let atlas = Atlas::new(&scene, 32).expect("atlas");
        let want = (0.5 * 29.0f64 * 29.0 / 2.0).sqrt();
        assert!((atlas.texel_density(&scene) - want).abs() < 1e-9);
        assert!((atlas.utilisation() - 0.5 * 29.0 * 29.0 / (32.0 * 32.0)).abs() < 1e-9);
    }
}
