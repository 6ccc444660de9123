//! The light-map atlas of a scene. Where every triangle has an authored TEXCOORD_1 inside the
//! unit square and no two triangles overlap in it, those coordinates are used unchanged, on a
//! square map of as many texels as the generated layout would have. Otherwise the atlas is
//! generated: one chart per triangle (a `cell × cell` texel square holding the triangle's three
//! corners, inset one texel so bilinear filtering stays inside), a surface's charts one block,
//! blocks packed on shelves. The CLI's light map and the renderer's are this one atlas;
//! `rasterize` fills either, dilating each chart by one texel where no other chart is.

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
    /// Texels along a chart's side (generated atlases; the generated layout's for authored).
    pub cell: u32,
    /// Per surface, its block (generated atlases; empty blocks for authored ones).
    pub blocks: Vec<Block>,
    /// Per triangle, the light-map coordinates of its three vertices, in [0, 1].
    pub uv: Vec<[Vec2; 3]>,
    /// Whether `uv` is the scene's own TEXCOORD_1.
    pub authored: bool,
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
    /// The atlas of `scene`: its authored TEXCOORD_1 where usable (see the module), else
    /// generated with `cell` texels per chart side (4 to 256), smaller where the atlas would
    /// pass [`MAX_TEXELS`] (not below 4).
    pub fn new(scene: &Scene, cell: u32) -> Result<Atlas, TooLarge> {
        let generated = Self::generated(scene, cell)?;
        Ok(Self::authored(scene, &generated).unwrap_or(generated))
    }

    /// The scene's own TEXCOORD_1, if every triangle has one in the unit square and no texel
    /// centre of a `side²` map lies inside two triangles.
    fn authored(scene: &Scene, generated: &Atlas) -> Option<Atlas> {
        let has = |t: &crate::Triangle| {
            scene
                .surfaces
                .get(t.surface as usize)
                .is_some_and(|s| s.tex_coords >= 2)
                && t.uv[1].iter().all(|c| {
                    c.is_finite() && (0.0..=1.0).contains(&c.x) && (0.0..=1.0).contains(&c.y)
                })
        };
        if scene.triangles.is_empty() || !scene.triangles.iter().all(has) {
            return None;
        }
        let texels = f64::from(generated.width) * f64::from(generated.height);
        let side = ((texels.sqrt().ceil() as u32).div_ceil(4) * 4).clamp(64, MAX_SIDE);
        let mut owner = vec![u32::MAX; side as usize * side as usize];
        let mut overlap = false;
        for_inside_texels(
            side,
            side,
            scene.triangles.iter().map(|t| t.uv[1]),
            |i, x, y| {
                let o = &mut owner[(y * side + x) as usize];
                if *o != u32::MAX && *o != i as u32 {
                    overlap = true;
                }
                *o = i as u32;
            },
        );
        if overlap {
            return None;
        }
        Some(Atlas {
            width: side,
            height: side,
            cell: generated.cell,
            blocks: vec![Block::default(); scene.surfaces.len()],
            uv: scene.triangles.iter().map(|t| t.uv[1]).collect(),
            authored: true,
        })
    }

    fn generated(scene: &Scene, cell: u32) -> Result<Atlas, TooLarge> {
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
            authored: false,
        })
    }

    /// Texels per scene unit along a surface, area-weighted over `scene`'s triangles (each
    /// triangle's texels over its area, square-rooted).
    pub fn texel_density(&self, scene: &Scene) -> f64 {
        let texels = f64::from(self.width) * f64::from(self.height);
        let (mut sum, mut area) = (0.0, 0.0);
        for (t, uv) in scene.triangles.iter().zip(&self.uv) {
            let a = t.area();
            let inside = uv_area(uv) * texels;
            if a > 0.0 && a.is_finite() {
                sum += a * (inside / a).sqrt();
                area += a;
            }
        }
        if area > 0.0 { sum / area } else { 0.0 }
    }

    /// The light map of `scene` on this atlas: every chart's texels (and a one-texel ring where
    /// no chart is, see [`rasterize`]) get `eval(triangle, u, v, position)`; the rest are 0.
    pub fn fill(
        &self,
        scene: &Scene,
        eval: impl FnMut(usize, f32, f32, DVec3) -> [f32; 3],
    ) -> Vec<[f32; 3]> {
        let mut texels = vec![[0.0f32; 3]; self.width as usize * self.height as usize];
        let charts = scene
            .triangles
            .iter()
            .zip(&self.uv)
            .enumerate()
            .map(|(i, (t, uv))| (i, *uv, t.vertices));
        rasterize(self.width, self.height, &mut texels, charts, eval);
        texels
    }

    /// The share of texels inside some triangle (charts do not overlap).
    pub fn utilisation(&self) -> f64 {
        self.uv.iter().map(uv_area).sum::<f64>().min(1.0)
    }
}

/// A chart's area in the unit square.
fn uv_area(uv: &[Vec2; 3]) -> f64 {
    0.5 * f64::from((uv[1] - uv[0]).perp_dot(uv[2] - uv[0]).abs())
}

/// Calls `f(chart, x, y)` for every texel whose centre lies strictly inside a chart (by a
/// thousandth of its barycentric range: a texel on an edge two charts share is neither's).
fn for_inside_texels(
    width: u32,
    height: u32,
    charts: impl Iterator<Item = [Vec2; 3]>,
    mut f: impl FnMut(usize, u32, u32),
) {
    let size = Vec2::new(width as f32, height as f32);
    for (index, uv) in charts.enumerate() {
        let uv = uv.map(|c| c * size);
        let (e1, e2) = (uv[1] - uv[0], uv[2] - uv[0]);
        let det = e1.perp_dot(e2);
        let (lo, hi) = (uv[0].min(uv[1]).min(uv[2]), uv[0].max(uv[1]).max(uv[2]));
        if det.abs() < 1e-12 || !(lo.is_finite() && hi.is_finite()) {
            continue;
        }
        let eps = -1e-3;
        let x0 = (lo.x - 0.5).floor().max(0.0) as u32;
        let y0 = (lo.y - 0.5).floor().max(0.0) as u32;
        let x1 = ((hi.x + 0.5).ceil().max(0.0) as u32).min(width);
        let y1 = ((hi.y + 0.5).ceil().max(0.0) as u32).min(height);
        for y in y0..y1 {
            for x in x0..x1 {
                let q = Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - uv[0];
                let u = q.perp_dot(e2) / det;
                let v = e1.perp_dot(q) / det;
                if u >= -eps && v >= -eps && u + v <= 1.0 + eps {
                    f(index, x, y);
                }
            }
        }
    }
}

/// Fills `texels` (`width × height`, row-major): `charts` yields each triangle's index, its
/// light-map coordinates and its three positions. First every texel whose centre is inside a
/// chart gets `eval(triangle, u, v, position)` at its barycentric weights; then each chart's
/// box and one texel around it, where no chart is, gets the value at the weights clamped onto
/// the triangle, so bilinear filtering never reads unfilled texels and a chart's ring never
/// overwrites a neighbouring chart.
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
    let charts: Vec<(usize, [Vec2; 3], [DVec3; 3])> = charts.collect();
    let mut covered = vec![false; texels.len()];
    let (w, h) = (width as f32, height as f32);
    for pass in 0..2 {
        for &(index, uv, p) in &charts {
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
                    let i = (y * width + x) as usize;
                    let q = Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - uv[0];
                    let (u, v) = (q.perp_dot(e2) / det, e1.perp_dot(q) / det);
                    let eps = 1e-4;
                    let inside = u >= -eps && v >= -eps && u + v <= 1.0 + eps;
                    if (pass == 0) != inside || (pass == 1 && covered[i]) {
                        continue;
                    }
                    // Barycentrics, clamped onto the triangle for the ring around it.
                    let u = u.clamp(0.0, 1.0);
                    let v = v.clamp(0.0, 1.0 - u);
                    let pos = p[0] + (p[1] - p[0]) * f64::from(u) + (p[2] - p[0]) * f64::from(v);
                    texels[i] = eval(index, u, v, pos);
                    covered[i] = true;
                }
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
    fn authored_texcoord_1_is_used_unchanged_unless_triangles_overlap_in_it() {
        let mut scene = Scene::default();
        scene.surfaces.push(crate::Surface {
            tex_coords: 2,
            ..Default::default()
        });
        // Two triangles of a quad, side by side in their own UV1, sharing an edge.
        let mut a = crate::Triangle::new([DVec3::ZERO, DVec3::X, DVec3::Y], 0);
        let mut b = crate::Triangle::new([DVec3::X, DVec3::X + DVec3::Y, DVec3::Y], 0);
        a.uv[1] = [
            Vec2::new(0.1, 0.1),
            Vec2::new(0.9, 0.1),
            Vec2::new(0.1, 0.9),
        ];
        b.uv[1] = [
            Vec2::new(0.9, 0.1),
            Vec2::new(0.9, 0.9),
            Vec2::new(0.1, 0.9),
        ];
        scene.triangles = vec![a, b];
        let atlas = Atlas::new(&scene, 32).expect("atlas");
        assert!(atlas.authored);
        assert_eq!(atlas.uv, vec![a.uv[1], b.uv[1]]);
        // Filled, each texel inside a chart holds its own triangle; the ring of one chart does
        // not overwrite the other.
        let texels = atlas.fill(&scene, |i, _, _, _| [i as f32 + 1.0; 3]);
        let side = atlas.width as f32;
        let at = |u: f32, v: f32| {
            texels[((v * side) as u32 * atlas.width + (u * side) as u32) as usize][0]
        };
        assert_eq!(at(0.3, 0.3), 1.0);
        assert_eq!(at(0.7, 0.7), 2.0);
        assert_eq!(at(0.02, 0.02), 0.0, "far outside every chart");
        // The same UV1 on both triangles overlaps: the atlas is generated instead.
        scene.triangles[1].uv[1] = a.uv[1];
        let generated = Atlas::new(&scene, 32).expect("atlas");
        assert!(!generated.authored);
        // Without a second UV set on every surface, too.
        scene.triangles[1].uv[1] = b.uv[1];
        scene.surfaces[0].tex_coords = 1;
        assert!(!Atlas::new(&scene, 32).expect("atlas").authored);
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
