//! Texture decoding: the input is an image file's bytes (PNG or JPEG, recognised by content)
//! with a declared MIME type chosen by its length. Decoded under two texel limits, so both the
//! whole decode and the row-by-row averaging of oversized PNGs are reached; a decoded image is
//! filtered into its footprint pyramid, whose means must be finite and within [0, 1].
#![no_main]

use glam::Vec2;
use radiant_scene::texture::{Pyramid, Sampler};

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let declared = [None, Some("image/png"), Some("image/jpeg")][data.len() % 3];
    for limit in [1 << 16, 1 << 10] {
        let Ok((image, _warning)) =
            radiant_scene::Image::decode_within("fuzz", data, declared, limit)
        else {
            continue;
        };
        assert!(u64::from(image.width) * u64::from(image.height) <= limit);
        let pyramid = Pyramid::new(&image);
        let uv = [
            Vec2::new(0.1, 0.2),
            Vec2::new(0.9, 0.3),
            Vec2::new(0.4, 2.5),
        ];
        let mean = pyramid.footprint_mean(Sampler::default(), uv);
        assert!(
            mean.iter()
                .all(|m| m.is_finite() && (-1e-6..=1.0 + 1e-6).contains(m)),
            "footprint mean {mean:?}"
        );
    }
});
