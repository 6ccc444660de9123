//! Which part of each triangle each light-map texel stands for.
//!
//! A texel is a square of the light map; the part of it inside a triangle's chart footprint is
//! what its value stands for on that triangle. The gather puts a texel's hemicube at the
//! centroid of that part (the centre for a texel the triangle covers whole; a point inside the
//! triangle for one on its edge), and a triangle's mean is its texels' values weighted by the
//! area each covers: the texels tile the footprint, so the weights sum to the footprint's area
//! and a partly covered texel at an edge counts for only what it covers (as lightmapper.h
//! weighs them). Weighting every texel whose centre is inside alike, as before, biased coarse
//! maps towards their edges.

use glam::DVec2;

/// The part of the unit texel square at `(x, y)` inside the triangle `uv` (texel units, either
/// winding): its area and centroid, or `None` when they do not overlap (or the triangle is
/// degenerate).
pub(crate) fn clip_texel(x: f64, y: f64, uv: [DVec2; 3]) -> Option<(f64, DVec2)> {
    let poly = clip_polygon(x, y, uv)?;
    // Shoelace area and centroid.
    let (mut area2, mut c) = (0.0, DVec2::ZERO);
    for i in 0..poly.len() {
        let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
        let cross = p.perp_dot(q);
        area2 += cross;
        c += (p + q) * cross;
    }
    let area = 0.5 * area2;
    (area > 1e-12 && area.is_finite()).then(|| (area, c / (3.0 * area2)))
}

/// The polygon (counter-clockwise) of the part of the unit texel square at `(x, y)` inside the
/// triangle `uv`, or `None` when it has fewer than three corners.
pub(crate) fn clip_polygon(x: f64, y: f64, uv: [DVec2; 3]) -> Option<Vec<DVec2>> {
    let signed = (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]);
    if signed.is_nan() || signed.abs() < 1e-18 {
        return None;
    }
    // Counter-clockwise, so "inside" is left of every edge.
    let tri = if signed > 0.0 {
        uv
    } else {
        [uv[0], uv[2], uv[1]]
    };
    let mut poly: Vec<DVec2> = vec![
        DVec2::new(x, y),
        DVec2::new(x + 1.0, y),
        DVec2::new(x + 1.0, y + 1.0),
        DVec2::new(x, y + 1.0),
    ];
    let mut next = Vec::with_capacity(8);
    for k in 0..3 {
        let (a, b) = (tri[k], tri[(k + 1) % 3]);
        let side = |p: DVec2| (b - a).perp_dot(p - a);
        next.clear();
        for i in 0..poly.len() {
            let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
            let (sp, sq) = (side(p), side(q));
            if sp >= 0.0 {
                next.push(p);
            }
            if (sp >= 0.0) != (sq >= 0.0) {
                let t = sp / (sp - sq);
                next.push(p + (q - p) * t);
            }
        }
        std::mem::swap(&mut poly, &mut next);
        if poly.len() < 3 {
            return None;
        }
    }
    Some(poly)
}

/// Barycentric weights `(u, v)` of the second and third vertex of `uv` at `p`.
pub(crate) fn barycentric(uv: [DVec2; 3], p: DVec2) -> (f64, f64) {
    let (e1, e2, q) = (uv[1] - uv[0], uv[2] - uv[0], p - uv[0]);
    let det = e1.perp_dot(e2);
    (q.perp_dot(e2) / det, e1.perp_dot(q) / det)
}

/// Per triangle, the receivers whose texels overlap its footprint and the area each covers.
pub(crate) struct Coverage {
    /// `entries[start[t]..start[t + 1]]` are triangle `t`'s (receiver, area in texels).
    start: Vec<u32>,
    entries: Vec<(u32, f32)>,
}

impl Coverage {
    /// `uv[t]` the footprint of triangle `t` in texel units on page `page[t]`, `receiver_at`
    /// the receiver of a texel `(page, x, y)`, if any; only triangles `keep` are covered.
    pub(crate) fn new(
        uv: &[[DVec2; 3]],
        page: &[u32],
        keep: &[bool],
        (width, height): (u32, u32),
        receiver_at: impl Fn(u32, u32, u32) -> Option<u32>,
    ) -> Coverage {
        let mut start = Vec::with_capacity(uv.len() + 1);
        let mut entries = Vec::new();
        for (t, tri) in uv.iter().enumerate() {
            start.push(entries.len() as u32);
            if !keep.get(t).copied().unwrap_or(false) {
                continue;
            }
            let lo = tri[0].min(tri[1]).min(tri[2]).floor().max(DVec2::ZERO);
            let hi = tri[0].max(tri[1]).max(tri[2]).ceil();
            if !(lo.is_finite() && hi.is_finite()) {
                continue;
            }
            let (x1, y1) = ((hi.x as u32).min(width), (hi.y as u32).min(height));
            for y in lo.y as u32..y1 {
                for x in lo.x as u32..x1 {
                    let Some((area, _)) = clip_texel(f64::from(x), f64::from(y), *tri) else {
                        continue;
                    };
                    if let Some(r) = receiver_at(page[t], x, y) {
                        entries.push((r, area as f32));
                    }
                }
            }
        }
        start.push(entries.len() as u32);
        Coverage { start, entries }
    }

    /// Triangle `t`'s area-weighted mean of `values` (per receiver), or `None` when no texel
    /// with a receiver covers it.
    pub(crate) fn mean(&self, t: usize, values: &[[f32; 3]]) -> Option<[f64; 3]> {
        let (a, b) = (
            *self.start.get(t)? as usize,
            *self.start.get(t + 1)? as usize,
        );
        let (mut sum, mut weight) = ([0.0f64; 3], 0.0f64);
        for &(r, area) in &self.entries[a..b] {
            let v = values.get(r as usize)?;
            for c in 0..3 {
                sum[c] += f64::from(area) * f64::from(v[c]);
            }
            weight += f64::from(area);
        }
        (weight > 0.0).then(|| sum.map(|s| s / weight))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_texel_inside_is_covered_whole_and_one_outside_not_at_all() {
        let big = [
            DVec2::new(-10.0, -10.0),
            DVec2::new(30.0, -10.0),
            DVec2::new(-10.0, 30.0),
        ];
        let (a, c) = clip_texel(2.0, 3.0, big).expect("inside");
        assert!((a - 1.0).abs() < 1e-12 && (c - DVec2::new(2.5, 3.5)).length() < 1e-12);
        assert!(clip_texel(40.0, 40.0, big).is_none());
        // Either winding.
        let flipped = [big[0], big[2], big[1]];
        assert!((clip_texel(2.0, 3.0, flipped).expect("inside").0 - 1.0).abs() < 1e-12);
    }

    #[test]
    fn a_diagonal_halves_a_texel_and_the_texels_tile_the_triangle() {
        // The lower-left half of the square [0, 4]²: texels on the diagonal are half covered,
        // with their centroid a third of the way in; all of them sum to the area, 8.
        let tri = [
            DVec2::new(0.0, 0.0),
            DVec2::new(4.0, 0.0),
            DVec2::new(0.0, 4.0),
        ];
        let (a, c) = clip_texel(1.0, 2.0, tri).expect("on the diagonal");
        assert!((a - 0.5).abs() < 1e-12, "{a}");
        assert!((c - DVec2::new(1.0 + 1.0 / 3.0, 2.0 + 1.0 / 3.0)).length() < 1e-12);
        let skew = [
            DVec2::new(0.3, 0.7),
            DVec2::new(5.9, 1.2),
            DVec2::new(2.2, 4.6),
        ];
        for t in [tri, skew] {
            let mut total = 0.0;
            for y in 0..6 {
                for x in 0..6 {
                    total += clip_texel(f64::from(x), f64::from(y), t).map_or(0.0, |(a, _)| a);
                }
            }
            let exact = 0.5 * (t[1] - t[0]).perp_dot(t[2] - t[0]).abs();
            assert!((total - exact).abs() < 1e-9, "{total} against {exact}");
        }
    }

    #[test]
    fn a_triangle_mean_weighs_its_texels_by_what_they_cover() {
        // Texel 0 covers the whole of 1 unit, texel 1 half a unit: (1·1 + 0.5·4) / 1.5 = 2.
        let coverage = Coverage {
            start: vec![0, 2, 2],
            entries: vec![(0, 1.0), (1, 0.5)],
        };
        let values = [[1.0; 3], [4.0; 3]];
        assert_eq!(coverage.mean(0, &values), Some([2.0; 3]));
        assert_eq!(coverage.mean(1, &values), None);
    }
}
