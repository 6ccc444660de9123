//! Real spherical harmonics to band 2: how a cluster's contents face, and the directional light
//! a cluster receives (Ramamoorthi & Hanrahan 2001: the clamped cosine needs nine
//! coefficients). With them a cluster's received light reaches each triangle in it by the
//! triangle's own orientation, and a cluster shines towards a receiver with the radiosity of
//! the parts that face it, not its mean.

use glam::DVec3;

/// The clamped cosine's coefficients per band, times `Y`'s normalisation: `∫ Y_lm(ω)
/// max(0, n·ω) dω = A_l Y_lm(n)`.
const A: [f64; 9] = [
    std::f64::consts::PI,
    2.0 * std::f64::consts::PI / 3.0,
    2.0 * std::f64::consts::PI / 3.0,
    2.0 * std::f64::consts::PI / 3.0,
    std::f64::consts::PI / 4.0,
    std::f64::consts::PI / 4.0,
    std::f64::consts::PI / 4.0,
    std::f64::consts::PI / 4.0,
    std::f64::consts::PI / 4.0,
];

/// The nine basis functions at the unit vector `d`.
#[inline]
pub fn basis(d: DVec3) -> [f64; 9] {
    let (x, y, z) = (d.x, d.y, d.z);
    [
        0.282_094_791_773_878_1,
        0.488_602_511_902_919_9 * y,
        0.488_602_511_902_919_9 * z,
        0.488_602_511_902_919_9 * x,
        1.092_548_430_592_079_2 * x * y,
        1.092_548_430_592_079_2 * y * z,
        0.315_391_565_252_52 * (3.0 * z * z - 1.0),
        1.092_548_430_592_079_2 * x * z,
        0.546_274_215_296_039_6 * (x * x - y * y),
    ]
}

/// The basis at `d`, convolved with the clamped cosine: `dot(coeffs, cosine(d))` is the mean of
/// `max(0, n·d)` over the normals whose distribution `coeffs` holds.
#[inline]
pub fn cosine(d: DVec3) -> [f64; 9] {
    let y = basis(d);
    std::array::from_fn(|k| A[k] * y[k])
}

/// `Σ a_k b_k`.
#[inline]
pub fn dot(a: &[f64; 9], b: &[f64; 9]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_normal_gives_its_clamped_cosine() {
        let n = DVec3::new(0.3, -0.4, 0.866).normalize();
        let coeffs = basis(n);
        for d in [
            n,
            DVec3::X,
            DVec3::Y,
            DVec3::Z,
            -n,
            DVec3::new(1.0, 1.0, 0.0).normalize(),
        ] {
            let exact = n.dot(d).max(0.0);
            let approx = dot(&coeffs, &cosine(d));
            // Band 2 keeps the clamped cosine within about 0.1 everywhere.
            assert!((approx - exact).abs() < 0.11, "{d}: {approx} vs {exact}");
        }
        // Energy: the mean over the sphere of the approximation is exactly 1/4 (the cosine's).
        let mut rng = crate::rng::Rng::new(3);
        let mut sum = 0.0;
        let k = 200_000;
        for _ in 0..k {
            let z = 2.0 * rng.f64() - 1.0;
            let phi = std::f64::consts::TAU * rng.f64();
            let r = (1.0 - z * z).max(0.0).sqrt();
            let d = DVec3::new(r * phi.cos(), r * phi.sin(), z);
            sum += dot(&coeffs, &cosine(d));
        }
        assert!((sum / f64::from(k) - 0.25).abs() < 0.005);
    }
}
