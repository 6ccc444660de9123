//! The CSV inputs: `--points` (positions and normals, in scene units or millimetres),
//! `--reference-points` (a path tracer's or Mitsuba's radiance per point) and `--reference`
//! (radiosity per surface). What parses must be finite, with unit normals.
#![no_main]

use radiant_radiosity::metrics;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(points) = metrics::parse_point_positions(text, 1e-3) {
        for p in &points {
            assert!(p.position.is_finite() && p.normal.is_finite(), "{p:?}");
            assert!(
                (p.normal.length() - 1.0).abs() < 1e-9,
                "normal {}",
                p.normal
            );
        }
    }
    if let Ok(points) = metrics::parse_point_csv(text, 1e-3) {
        for p in &points {
            assert!(p.position.is_finite() && p.normal.is_finite(), "{p:?}");
            assert!(p.radiosity.iter().all(|v| v.is_finite()), "{p:?}");
        }
    }
    if let Ok(rows) = metrics::parse_reference_csv(text) {
        for (name, b) in &rows {
            assert!(b.iter().all(|v| v.is_finite()), "{name}: {b:?}");
        }
    }
});
