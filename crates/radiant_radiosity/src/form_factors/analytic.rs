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
        let gamma = angle(cl, a.dot(b));
        sum += gamma * n.dot(c) / cl;
    }
    let f = -sum / std::f64::consts::TAU;
    if f.is_finite() {
        f.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// `atan2(y, x)` for `y >= 0`, an angle in `[0, π]`, within a few units in the last place of
/// `f64::atan2` (4·10⁻¹⁶ relative at most, measured) and about twice as fast: the contour
/// integral takes one per edge, and libm's `atan2` was a fifth of the per-triangle Cornell
/// bake. The ratio of the smaller to the larger
/// of `|x|` and `y` is brought to `|z| <= tan(π/8)` around `π/4`, where `atan(z) = z P(z²)`
/// with `P` of degree 10 fitted by least squares (`tools/fit_angle.py`: 2·10⁻¹⁶ relative).
/// `y = x = 0` gives 0, a NaN gives NaN.
#[inline]
fn angle(y: f64, x: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};
    const P: [f64; 11] = [
        1.0,
        -0.333_333_333_333_285_8,
        0.199_999_999_988_820_76,
        -0.142_857_141_829_785_65,
        0.111_111_062_559_958_19,
        -0.090_907_747_127_958_27,
        0.076_899_751_285_696_65,
        -0.066_404_108_115_352_68,
        0.056_892_235_017_660_546,
        -0.043_504_452_574_300_106,
        0.021_163_217_481_242_648,
    ];
    const TAN_PI_8: f64 = 0.414_213_562_373_095_03;
    let ax = x.abs();
    let steep = y > ax;
    let (num, den) = if steep { (ax, y) } else { (y, ax) };
    if den == 0.0 {
        return if y.is_nan() {
            y
        } else if x.is_sign_negative() {
            PI
        } else {
            0.0
        };
    }
    // One division: near π/4, atan(n/d) = π/4 + atan((n − d)/(n + d)).
    let (z, base) = if num > TAN_PI_8 * den {
        ((num - den) / (num + den), FRAC_PI_4)
    } else {
        (num / den, 0.0)
    };
    // P(w) by Estrin's scheme: a shorter chain of dependent operations than Horner's.
    let w = z * z;
    let w2 = w * w;
    let w4 = w2 * w2;
    let p01 = P[0] + P[1] * w;
    let p23 = P[2] + P[3] * w;
    let p45 = P[4] + P[5] * w;
    let p67 = P[6] + P[7] * w;
    let p89 = P[8] + P[9] * w;
    let p = (p01 + p23 * w2) + (p45 + p67 * w2) * w4 + (p89 + P[10] * w2) * (w4 * w4);
    let r = base + z * p;
    let r = if steep { FRAC_PI_2 - r } else { r };
    if x < 0.0 { PI - r } else { r }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_is_atan2_within_a_few_ulps() {
        use std::f64::consts::{FRAC_PI_2, PI};
        let mut rng = crate::rng::Rng::new(17);
        let mut worst = 0.0f64;
        for k in 0..200_000 {
            // Magnitudes over twenty decades, and x near 0 and near ±y.
            let scale = 10f64.powf(rng.f64() * 20.0 - 10.0);
            let y = rng.f64() * scale;
            let x = match k % 4 {
                0 => (2.0 * rng.f64() - 1.0) * scale * 1e-9,
                1 => y * (1.0 + (rng.f64() - 0.5) * 1e-9) * if k % 8 == 1 { -1.0 } else { 1.0 },
                _ => (2.0 * rng.f64() - 1.0) * scale,
            };
            let (exact, ours) = (y.atan2(x), angle(y, x));
            assert!(
                (ours - exact).abs() <= 4.0 * f64::EPSILON * exact.abs(),
                "angle({y:e}, {x:e}) = {ours:e}, atan2 {exact:e}"
            );
            if exact != 0.0 {
                worst = worst.max(((ours - exact) / exact).abs());
            }
        }
        assert!(worst > 0.0, "the test compares something");
        assert_eq!(angle(0.0, 0.0), 0.0);
        assert_eq!(angle(0.0, -0.0), PI);
        assert_eq!(angle(0.0, 1.0), 0.0);
        assert_eq!(angle(0.0, -1.0), PI);
        assert_eq!(angle(1.0, 0.0), FRAC_PI_2);
        assert_eq!(angle(f64::INFINITY, 1.0), FRAC_PI_2);
        assert_eq!(angle(1.0, f64::INFINITY), 0.0);
        assert!(angle(f64::NAN, 1.0).is_nan() && angle(1.0, f64::NAN).is_nan());
        assert!(angle(f64::NAN, 0.0).is_nan());
    }

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
