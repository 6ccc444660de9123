//! Colour for Radiant: CIE 1931 colorimetry ([`cie`]), linear ↔ sRGB transfer functions and the
//! tone-map operators' CPU reference.
//!
//! Radiosity is solved in linear RGB (Rec. 709 primaries). Images that people look at are
//! tone-mapped and then encoded with the sRGB transfer function (IEC 61966-2-1).
//!
//! ```
//! use radiant_color::{linear_to_srgb, srgb_to_linear, Tonemap};
//! let v = 0.5_f64;
//! assert!((srgb_to_linear(linear_to_srgb(v)) - v).abs() < 1e-12);
//! let display = Tonemap::Reinhard.apply([4.0, 1.0, 0.0]);
//! assert!(display[0] < 1.0);
//! ```

pub mod cie;
mod tonemap;

pub use tonemap::Tonemap;

/// sRGB electro-optical transfer: encoded value in [0, 1] → linear value (IEC 61966-2-1).
///
/// Values outside [0, 1] are extended symmetrically, so the function is invertible everywhere.
pub fn srgb_to_linear(encoded: f64) -> f64 {
    let a = encoded.abs();
    let l = if a <= 0.04045 {
        a / 12.92
    } else {
        ((a + 0.055) / 1.055).powf(2.4)
    };
    l.copysign(encoded)
}

/// sRGB inverse transfer: linear value → encoded value (IEC 61966-2-1).
pub fn linear_to_srgb(linear: f64) -> f64 {
    let a = linear.abs();
    let e = if a <= 0.003_130_8 {
        a * 12.92
    } else {
        1.055 * a.powf(1.0 / 2.4) - 0.055
    };
    e.copysign(linear)
}

/// Linear → 8-bit sRGB with rounding; inputs are clamped to [0, 1] first (display encoding).
pub fn linear_to_srgb8(linear: f64) -> u8 {
    let e = linear_to_srgb(if linear.is_nan() {
        0.0
    } else {
        linear.clamp(0.0, 1.0)
    });
    (e * 255.0).round().clamp(0.0, 255.0) as u8
}

/// Relative luminance of a linear Rec. 709 colour (Y of CIE XYZ).
pub fn luminance(rgb: [f64; 3]) -> f64 {
    0.212_639 * rgb[0] + 0.715_169 * rgb[1] + 0.072_192 * rgb[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_test_vectors() {
        // IEC 61966-2-1 breakpoints and well-known values.
        assert!((linear_to_srgb(0.0031308) - 0.040_449_936).abs() < 1e-6);
        assert!((srgb_to_linear(0.04045) - 0.003_130_804).abs() < 1e-8);
        assert!((linear_to_srgb(1.0) - 1.0).abs() < 1e-12);
        assert!((srgb_to_linear(0.5) - 0.214_041_14).abs() < 1e-7);
        assert_eq!(linear_to_srgb8(0.5), 188);
    }

    #[test]
    fn round_trip_and_monotone() {
        let mut last = -1.0;
        for i in 0..=1000 {
            let v = i as f64 / 1000.0;
            let e = linear_to_srgb(v);
            assert!(e > last);
            last = e;
            assert!((srgb_to_linear(e) - v).abs() < 1e-12);
        }
    }

    #[test]
    fn tonemaps_are_bounded_and_finite() {
        for op in [Tonemap::Clamp, Tonemap::Reinhard, Tonemap::AcesFitted] {
            for x in [
                0.0,
                1e-6,
                0.18,
                1.0,
                10.0,
                1e9,
                f64::INFINITY,
                f64::NAN,
                -1.0,
            ] {
                let y = op.apply([x; 3]);
                assert!(
                    y.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)),
                    "{op:?} {x}"
                );
            }
        }
    }
}
