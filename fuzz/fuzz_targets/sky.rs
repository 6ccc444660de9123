//! Sky images and descriptions: the input is decoded as an equirectangular sky image (Radiance
//! `.hdr` or OpenEXR, by content) under a 2²⁰-texel limit; read as text, it is also a `--sky`
//! description and, as JSON, a glTF scene's `radiant.sky` extras. A sky that loads must have
//! finite, non-negative radiance everywhere.
#![no_main]

use glam::DVec3;
use radiant_scene::Sky;

fn check(sky: &Sky) {
    for dir in [
        DVec3::Y,
        DVec3::NEG_Y,
        DVec3::X,
        DVec3::new(0.3, 0.4, -0.866),
    ] {
        let l = sky.radiance(dir);
        assert!(
            l.iter().all(|v| v.is_finite() && *v >= 0.0),
            "radiance {l:?} along {dir}"
        );
    }
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let scale = f64::from(data.first().copied().unwrap_or(1)) / 16.0;
    if let Ok(sky) = Sky::from_image_bytes_within("fuzz.hdr", data, scale, 1 << 20) {
        check(&sky);
    }
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    // Paths are left out: a description naming a file would read the machine's files.
    if text.len() < 256 && !text.contains(".hdr") && !text.contains(".exr") {
        if let Ok(sky) = Sky::parse(text, None) {
            check(&sky);
        }
    }
    if let Ok(value) = serde_json::from_str::<serde_json::Value>(text) {
        let file_named = value.as_object().is_some_and(|o| o.contains_key("image"));
        if !file_named && !text.contains(".hdr") && !text.contains(".exr") {
            if let Ok(Some(sky)) = Sky::from_extras(&value, None) {
                check(&sky);
            }
        }
    }
});
