//! Light maps: every input triangle gets a square chart of `2^depth` texels a side (its elements'
//! resolution), of which it uses the lower-left half; charts are packed in shelves with a one
//! texel gutter. Each texel holds the radiosity at its centre, interpolated linearly between the
//! element-grid vertices (vertex values are the means of the elements around them), so the map
//! is smooth inside a chart (the element values themselves are in `patches.csv`).

use crate::mesh::Mesh;
use crate::system::Rgb;

/// A light map: linear RGB radiosity, row-major, `width × height`.
#[derive(Clone, Debug, PartialEq)]
pub struct LightMap {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Texels (linear RGB radiosity, emissive units); unused texels are 0.
    pub texels: Vec<[f32; 3]>,
    /// Per input triangle: chart origin (texels) and size.
    pub charts: Vec<(u32, u32, u32)>,
}

/// Bakes the element radiosity into a light map at most `max_width` texels wide.
pub fn bake_lightmap(mesh: &Mesh, b: &[Rgb], max_width: u32) -> LightMap {
    let sizes: Vec<u32> = mesh
        .roots
        .iter()
        .map(|&r| {
            let n = &mesh.nodes[r as usize];
            let depth = mesh.nodes[mesh.leaves[n.leaf_lo as usize] as usize].depth;
            1u32 << depth.min(12)
        })
        .collect();
    let widest = sizes.iter().copied().max().unwrap_or(1) + 2;
    let width = max_width.max(widest);
    let (mut x, mut y, mut shelf) = (0u32, 0u32, 0u32);
    let mut charts = Vec::with_capacity(sizes.len());
    // Tallest first keeps shelves tight.
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(sizes[i]));
    let mut placed = vec![(0, 0, 0); sizes.len()];
    for &i in &order {
        let s = sizes[i] + 2;
        if x + s > width {
            x = 0;
            y += shelf;
            shelf = 0;
        }
        placed[i] = (x + 1, y + 1, sizes[i]);
        x += s;
        shelf = shelf.max(s);
    }
    charts.extend(placed);
    let height = (y + shelf).max(1);
    let mut texels = vec![[0.0f32; 3]; (width * height) as usize];
    for (root, &(cx, cy, n)) in charts.iter().enumerate() {
        let verts = vertex_values(mesh, root as u32, n, b);
        let stride = n as usize + 1;
        for j in 0..n {
            for i in 0..n - j {
                // Texel centre in lattice units; u along vertex 1, v along vertex 2.
                let (u, v) = (i as f64 + 0.5, j as f64 + 0.5);
                let (su, sv) = (u.floor() as usize, v.floor() as usize);
                let (fu, fv) = (u - su as f64, v - sv as f64);
                // Interpolate in the lattice cell's triangle that holds the point.
                let val = |a: usize, bb: usize| verts[bb * stride + a];
                let c: Rgb = if fu + fv <= 1.0 || su + sv + 1 >= n as usize {
                    let (p0, p1, p2) = (val(su, sv), val(su + 1, sv), val(su, sv + 1));
                    std::array::from_fn(|k| p0[k] * (1.0 - fu - fv) + p1[k] * fu + p2[k] * fv)
                } else {
                    let (p0, p1, p2) = (val(su + 1, sv + 1), val(su, sv + 1), val(su + 1, sv));
                    let (gu, gv) = (1.0 - fu, 1.0 - fv);
                    std::array::from_fn(|k| p0[k] * (1.0 - gu - gv) + p1[k] * gu + p2[k] * gv)
                };
                texels[((cy + j) * width + cx + i) as usize] = c.map(|x| x as f32);
            }
        }
    }
    LightMap {
        width,
        height,
        texels,
        charts,
    }
}

/// Radiosity at the `(n+1)(n+2)/2` lattice vertices of an input triangle split `n` ways per
/// edge: the area-weighted mean of the elements that touch each vertex.
fn vertex_values(mesh: &Mesh, root: u32, n: u32, b: &[Rgb]) -> Vec<Rgb> {
    let stride = n as usize + 1;
    let mut acc = vec![([0.0; 3], 0.0); stride * stride];
    let r = &mesh.nodes[mesh.roots[root as usize] as usize];
    let (e1, e2) = (r.v[1] - r.v[0], r.v[2] - r.v[0]);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let det = d11 * d22 - d12 * d12;
    for leaf in r.leaf_lo..r.leaf_hi {
        let node = mesh.leaf_node(leaf);
        for v in node.v {
            let p = v - r.v[0];
            let (p1, p2) = (p.dot(e1), p.dot(e2));
            let u = ((d22 * p1 - d12 * p2) / det * f64::from(n))
                .round()
                .clamp(0.0, f64::from(n)) as usize;
            let w = ((d11 * p2 - d12 * p1) / det * f64::from(n))
                .round()
                .clamp(0.0, f64::from(n)) as usize;
            let slot = &mut acc[w * stride + u];
            for c in 0..3 {
                slot.0[c] += node.area * b[leaf as usize][c];
            }
            slot.1 += node.area;
        }
    }
    acc.into_iter()
        .map(|(s, a)| if a > 0.0 { s.map(|x| x / a) } else { [0.0; 3] })
        .collect()
}
