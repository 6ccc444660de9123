//! Point-to-polygon form factors by Lambert's contour integral (Hottel & Sarofim; Baum, Rushmeier
//! & Winget 1989): exact for an unoccluded polygon seen from a differential area.
//!
//! `F(dA -> P) = -1/(2π) Σ_k γ_k n·(r_k × r_{k+1}) / |r_k × r_{k+1}|`, with `r_k` the vertices
//! relative to the point, `γ_k` the angle between consecutive ones, for a polygon that is
//! counter-clockwise seen from its front. The polygon is first clipped to the half-space above the
//! point's tangent plane, so a polygon that crosses that plane (an adjacent wall seen from a floor
//! element, say) gets the right value. The result lies in `[0, 1]` by construction; it is clamped
//! against rounding, and a point on a polygon edge (where the integrand is undefined) drops that
//! edge's term, which is bounded.

use glam::DVec3;

/// Form factor from a differential area at `x` with unit normal `n` to the front of the triangle
/// `tri` (unit front normal `tri_n`). Zero when the point is behind or in the triangle's plane.
#[inline]
pub fn point_to_triangle(x: DVec3, n: DVec3, tri: &[DVec3; 3], tri_n: DVec3) -> f64 {
    // One-sided: only the front emits.
    if (x - tri[0]).dot(tri_n) <= 0.0 {
        return 0.0;
    }
    let r = [tri[0] - x, tri[1] - x, tri[2] - x];
    let h = [n.dot(r[0]), n.dot(r[1]), n.dot(r[2])];
    if h[0] >= 0.0 && h[1] >= 0.0 && h[2] >= 0.0 {
        return contour(n, &r);
    }
    if h[0] <= 0.0 && h[1] <= 0.0 && h[2] <= 0.0 {
        return 0.0;
    }
    // Sutherland–Hodgman against the tangent plane: at most 4 vertices.
    let mut out = [DVec3::ZERO; 4];
    let mut m = 0;
    for k in 0..3 {
        let (a, b) = (k, (k + 1) % 3);
        if h[a] >= 0.0 {
            out[m] = r[a];
            m += 1;
        }
        if (h[a] > 0.0 && h[b] < 0.0) || (h[a] < 0.0 && h[b] > 0.0) {
            let t = h[a] / (h[a] - h[b]);
            let p = r[a] + (r[b] - r[a]) * t;
            // Exactly on the plane, against rounding.
            out[m] = p - n * n.dot(p);
            m += 1;
        }
    }
    if m < 3 { 0.0 } else { contour(n, &out[..m]) }
}

#[inline]
fn contour(n: DVec3, r: &[DVec3]) -> f64 {
    let mut sum = 0.0;
    for k in 0..r.len() {
        let (a, b) = (r[k], r[(k + 1) % r.len()]);
        let c = a.cross(b);
        let cl2 = c.length_squared();
        // Compared squared: no square roots for the test (this is the hottest loop).
        if cl2.is_nan() || cl2 <= 1e-28 * a.length_squared() * b.length_squared() {
            // Parallel: zero angle (outside the edge) or the point on the edge. Either way the
            // term is bounded; drop it.
            continue;
        }
        let cl = cl2.sqrt();
        let gamma = cl.atan2(a.dot(b));
        sum += gamma * n.dot(c) / cl;
    }
    let f = -sum / std::f64::consts::TAU;
    if f.is_finite() {
        f.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(a: f64, z: f64) -> [[DVec3; 3]; 2] {
        // Facing down (-z), counter-clockwise seen from below.
        let p = [
            DVec3::new(-a, -a, z),
            DVec3::new(-a, a, z),
            DVec3::new(a, a, z),
            DVec3::new(a, -a, z),
        ];
        [[p[0], p[1], p[2]], [p[0], p[2], p[3]]]
    }

    #[test]
    fn small_patch_matches_the_differential_kernel() {
        let a = 1e-3;
        let f: f64 = square(a, 1.0)
            .iter()
            .map(|t| point_to_triangle(DVec3::ZERO, DVec3::Z, t, -DVec3::Z))
            .sum();
        let expect = 4.0 * a * a / std::f64::consts::PI;
        assert!((f - expect).abs() < 1e-5 * expect, "{f} vs {expect}");
    }

    #[test]
    fn element_to_parallel_rectangle_at_corner() {
        // Howell B-3: element parallel to a rectangle a x b at distance c, normal through a corner.
        let (a, b, c) = (2.0f64, 1.0f64, 1.5f64);
        let (x, y) = (a / c, b / c);
        let expect = 1.0 / std::f64::consts::TAU
            * (x / (1.0 + x * x).sqrt() * (y / (1.0 + x * x).sqrt()).atan()
                + y / (1.0 + y * y).sqrt() * (x / (1.0 + y * y).sqrt()).atan());
        let p = [
            DVec3::new(0., 0., c),
            DVec3::new(0., b, c),
            DVec3::new(a, b, c),
            DVec3::new(a, 0., c),
        ];
        let f = point_to_triangle(DVec3::ZERO, DVec3::Z, &[p[0], p[1], p[2]], -DVec3::Z)
            + point_to_triangle(DVec3::ZERO, DVec3::Z, &[p[0], p[2], p[3]], -DVec3::Z);
        assert!((f - expect).abs() < 1e-12, "{f} vs {expect}");
    }

    #[test]
    fn closed_cube_sums_to_one_from_any_interior_point() {
        let cube = crate::testing::unit_cube_inward();
        for x in [
            DVec3::new(0.5, 0.5, 1e-9),
            DVec3::new(0.01, 0.99, 1e-12),
            DVec3::new(0.3, 0.2, 0.0),
        ] {
            let n = DVec3::Z;
            let s: f64 = cube
                .iter()
                .map(|t| {
                    let tn = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
                    point_to_triangle(x, n, t, tn)
                })
                .sum();
            assert!((s - 1.0).abs() < 1e-12, "row sum {s} at {x}");
        }
    }

    #[test]
    fn shared_edge_and_behind_are_finite() {
        // Perpendicular wall sharing the receiver's edge, point on the edge itself.
        let wall = [
            DVec3::new(0., 0., 0.),
            DVec3::new(0., 0., 1.),
            DVec3::new(0., 1., 1.),
        ];
        let wn = (wall[1] - wall[0]).cross(wall[2] - wall[0]).normalize();
        for x in [
            DVec3::new(0.0, 0.5, 0.0),
            DVec3::new(1e-300, 0.5, 0.0),
            DVec3::new(-1.0, 0.5, 0.0),
        ] {
            let f = point_to_triangle(x, DVec3::Z, &wall, wn);
            assert!(f.is_finite() && (0.0..=1.0).contains(&f), "{f}");
        }
        // Seen from behind: zero.
        assert_eq!(
            point_to_triangle(DVec3::new(1.0, 0.5, 0.5), -DVec3::X, &wall, wn),
            0.0
        );
        assert!(point_to_triangle(DVec3::new(-1.0, 0.5, 0.5), DVec3::X, &wall, wn) > 0.0);
    }
}
