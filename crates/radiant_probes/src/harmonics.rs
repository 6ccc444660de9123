//! Real spherical harmonics of order 4 (25 per channel), which a probe holds its reflected
//! light in, and the clamped cosine's bands that turn them into irradiance (Ramamoorthi and
//! Hanrahan 2001: `E(n) = Σ_lm Â_l L_lm Y_lm(n)`, `Â = π, 2π/3, π/4, 0, −π/24`).
//!
//! Why order 4 and not 2: order 2 keeps the irradiance within a few per cent of the light's
//! *mean*, so a normal that faces a nearly black part of the sphere (the Cornell box's open
//! front, seen from inside) reads the truncation's ringing as light: +14 % at a probe facing
//! it (irradiance 0.023 against 0.2–15 for the other axes). The next nonzero band (`Â_4`)
//! carries most of what order 2 leaves out (`Â_6 = π/64` is the next).
//!
//! The basis is made by the associated Legendre recurrence (Green, "Spherical Harmonic
//! Lighting: The Gritty Details", 2003) in Cartesian form rather than written out, and
//! tested orthonormal.

use std::f64::consts::PI;
use std::sync::LazyLock;

use glam::DVec3;

/// The highest band.
pub const ORDER: usize = 4;
/// Coefficients per channel, `(ORDER + 1)²`.
pub const COUNT: usize = (ORDER + 1) * (ORDER + 1);

/// Harmonics of one channel.
pub type Coeffs = [f64; COUNT];

/// The clamped cosine's band weights `Â_l` (`E = Σ Â_l L_lm Y_lm`).
const BANDS: [f64; ORDER + 1] = [PI, 2.0 * PI / 3.0, PI / 4.0, 0.0, -PI / 24.0];

/// `K_l^m` (times √2 for `m > 0`), the basis's normalisation, by `[l][m]`.
static NORM: LazyLock<[[f64; ORDER + 1]; ORDER + 1]> = LazyLock::new(|| {
    let factorial = |n: usize| -> f64 { (1..=n).map(|k| k as f64).product() };
    std::array::from_fn(|l| {
        std::array::from_fn(|m| {
            if m > l {
                return 0.0;
            }
            let k = ((2 * l + 1) as f64 / (4.0 * PI) * factorial(l - m) / factorial(l + m)).sqrt();
            if m > 0 {
                std::f64::consts::SQRT_2 * k
            } else {
                k
            }
        })
    })
});

/// The basis at unit direction `d`, index `l (l + 1) + m`: `K_l^m P_l^m(z)` times `cos mφ`
/// (`m > 0`) or `sin |m|φ` (`m < 0`), with the Condon–Shortley phase. Without trigonometry:
/// `sin^m θ (cos mφ + i sin mφ) = (x + i y)^m`, and `P_l^m(z) / sin^m θ` follows the
/// associated Legendre recurrence in `l`.
pub fn basis(d: DVec3) -> Coeffs {
    let (x, y, z) = (d.x, d.y, d.z);
    let norm = &*NORM;
    let mut out = [0.0; COUNT];
    // (x + i y)^m.
    let (mut c, mut s) = (1.0, 0.0);
    // P_m^m / sin^m θ = (−1)^m (2m − 1)!!.
    let mut pmm = 1.0;
    for m in 0..=ORDER {
        if m > 0 {
            (c, s) = (c * x - s * y, c * y + s * x);
            pmm *= -((2 * m - 1) as f64);
        }
        let (mut p2, mut p1) = (0.0, pmm);
        for (l, norm) in norm.iter().enumerate().skip(m) {
            let p = match l - m {
                0 => pmm,
                1 => z * (2 * m + 1) as f64 * pmm,
                _ => ((2 * l - 1) as f64 * z * p1 - (l + m - 1) as f64 * p2) / (l - m) as f64,
            };
            if l > m {
                (p2, p1) = (p1, p);
            }
            let centre = l * (l + 1);
            let k = norm[m] * p;
            if m == 0 {
                out[centre] = k;
            } else {
                out[centre + m] = k * c;
                out[centre - m] = k * s;
            }
        }
    }
    out
}

/// The irradiance `E(n) = Σ Â_l L_lm Y_lm(n)` of radiance harmonics `l`.
pub fn irradiance(l: &Coeffs, n: DVec3) -> f64 {
    let y = basis(n);
    let mut e = 0.0;
    for (band, weight) in BANDS.iter().enumerate() {
        for k in band * band..(band + 1) * (band + 1) {
            e += weight * l[k] * y[k];
        }
    }
    e
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points of a spherical Fibonacci lattice, each of solid angle `4π / n`.
    fn sphere(n: usize) -> impl Iterator<Item = DVec3> {
        (0..n).map(move |i| crate::volume::fibonacci(i, n))
    }

    #[test]
    fn the_basis_is_orthonormal() {
        let n = 40_000;
        let mut gram = [[0.0; COUNT]; COUNT];
        for d in sphere(n) {
            let y = basis(d);
            for i in 0..COUNT {
                for j in 0..COUNT {
                    gram[i][j] += y[i] * y[j] * 4.0 * PI / n as f64;
                }
            }
        }
        for (i, row) in gram.iter().enumerate() {
            for (j, &g) in row.iter().enumerate() {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((g - want).abs() < 2e-3, "<Y{i}, Y{j}> = {g}");
            }
        }
    }

    /// Bands 0 to 2 are the order-2 basis the clustered bake uses, up to the sign convention.
    #[test]
    fn its_first_bands_are_the_usual_ones() {
        for d in sphere(50) {
            let (a, b) = (basis(d), radiant_radiosity::cluster::sh::basis(d));
            for k in 0..9 {
                assert!((a[k].abs() - b[k].abs()).abs() < 1e-12, "{k} at {d}");
            }
        }
    }

    /// A cap of unit radiance, half-angle 60°, around +z: `E(+z) = π sin² 60°`, and a normal
    /// facing away sees none of it (`E(−z) = 0`). Order 4 holds the dark side far better than
    /// order 2 (its bands alone).
    #[test]
    fn a_dark_side_rings_less_at_order_four() {
        let n = 200_000;
        let mut l = [0.0; COUNT];
        for d in sphere(n) {
            if d.z >= 0.5 {
                let y = basis(d);
                for k in 0..COUNT {
                    l[k] += y[k] * 4.0 * PI / n as f64;
                }
            }
        }
        let top = irradiance(&l, DVec3::Z);
        assert!((top - PI * 0.75).abs() < 0.02 * PI, "{top}");
        let mut two = l;
        two[9..].fill(0.0);
        let (dark4, dark2) = (irradiance(&l, DVec3::NEG_Z), irradiance(&two, DVec3::NEG_Z));
        assert!(
            dark4.abs() < 0.5 * dark2.abs(),
            "order 4 {dark4}, order 2 {dark2}"
        );
        assert!(dark4.abs() < 0.01 * PI, "{dark4}");
    }
}
