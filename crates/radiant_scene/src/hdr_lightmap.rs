//! Full-range light maps for other engines: one page of linear RGB `H` as KTX2 (RGBA16F,
//! zstd-supercompressed, the way Bevy loads light maps) and as OpenEXR (32-bit float RGB).
//!
//! Written with well-kept crates where one does the job: `ktx2` for the KTX2 header, level
//! index and data format descriptor (its `Header::as_bytes`, `LevelIndex::as_bytes` and
//! `dfd::Basic::from_format`), `ruzstd` for the zstd frame, `half` for f16 texels and `image`
//! for the EXR. What no crate does, laying the sections out one after the other with their
//! offsets, is written here (about twenty lines): `ktx2` reads containers but does not
//! assemble one.
//!
//! Texels are row-major from the top row, as glTF reads TEXCOORD_1 (KTX2's default
//! orientation, right and down); alpha is 1.

use ktx2::{Format, Header, Index, LevelIndex, SupercompressionScheme};

use crate::SceneError;

fn err(what: impl Into<String>) -> SceneError {
    SceneError::Export(what.into())
}

/// `width × height` texels of linear RGB as a KTX2 file: `R16G16B16A16_SFLOAT`, one level,
/// zstd-supercompressed. Values past the f16 range (65504) are clamped to it, non-finite
/// ones written as 0.
pub fn ktx2_rgba16f(width: u32, height: u32, texels: &[[f32; 3]]) -> Result<Vec<u8>, SceneError> {
    if texels.len() as u64 != u64::from(width) * u64::from(height) || width == 0 || height == 0 {
        return Err(err(format!(
            "a {width}×{height} KTX2 light map of {} texels",
            texels.len()
        )));
    }
    let mut raw = Vec::with_capacity(texels.len() * 8);
    for t in texels {
        for x in [t[0], t[1], t[2], 1.0] {
            let x = if x.is_finite() {
                x.clamp(-65504.0, 65504.0)
            } else {
                0.0
            };
            raw.extend_from_slice(&half::f16::from_f32(x).to_le_bytes());
        }
    }
    let packed =
        ruzstd::encoding::compress_to_vec(&raw[..], ruzstd::encoding::CompressionLevel::Fastest);
    let (basic, type_size) = ktx2::dfd::Basic::from_format(Format::R16G16B16A16_SFLOAT)
        .map_err(|e| err(format!("KTX2 data format descriptor: {e:?}")))?;
    let block = ktx2::dfd::Block::Basic(basic).to_vec();
    // The DFD section is its total size, then its blocks.
    let mut dfd = ((block.len() + 4) as u32).to_le_bytes().to_vec();
    dfd.extend_from_slice(&block);
    let dfd_offset = Header::LENGTH + LevelIndex::LENGTH;
    let level_offset = dfd_offset + dfd.len();
    let header = Header {
        format: Some(Format::R16G16B16A16_SFLOAT),
        type_size,
        pixel_width: width,
        pixel_height: height,
        pixel_depth: 0,
        layer_count: 0,
        face_count: 1,
        level_count: 1,
        supercompression_scheme: Some(SupercompressionScheme::Zstandard),
        index: Index {
            dfd_byte_offset: dfd_offset as u32,
            dfd_byte_length: dfd.len() as u32,
            kvd_byte_offset: 0,
            kvd_byte_length: 0,
            sgd_byte_offset: 0,
            sgd_byte_length: 0,
        },
    };
    let level = LevelIndex {
        byte_offset: level_offset as u64,
        byte_length: packed.len() as u64,
        uncompressed_byte_length: raw.len() as u64,
    };
    let mut out = Vec::with_capacity(level_offset + packed.len());
    out.extend_from_slice(&header.as_bytes());
    out.extend_from_slice(&level.as_bytes());
    out.extend_from_slice(&dfd);
    out.extend_from_slice(&packed);
    Ok(out)
}

/// `width × height` texels of linear RGB as an OpenEXR file (32-bit float RGB).
pub fn exr_rgb32f(width: u32, height: u32, texels: &[[f32; 3]]) -> Result<Vec<u8>, SceneError> {
    if texels.len() as u64 != u64::from(width) * u64::from(height) || width == 0 || height == 0 {
        return Err(err(format!(
            "a {width}×{height} EXR light map of {} texels",
            texels.len()
        )));
    }
    let flat: Vec<f32> = texels
        .iter()
        .flatten()
        .map(|&x| if x.is_finite() { x } else { 0.0 })
        .collect();
    let image = image::Rgb32FImage::from_raw(width, height, flat)
        .ok_or_else(|| err("EXR light map: size does not match its texels"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    image
        .write_to(&mut out, image::ImageFormat::OpenExr)
        .map_err(|e| err(format!("EXR light map: {e}")))?;
    Ok(out.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A page with a 10⁶ range of light, decoded as a loader would: the `ktx2` crate's
    /// reader, `ruzstd`'s decoder, `half`; `image` for the EXR.
    #[test]
    fn a_page_round_trips_through_ktx2_and_exr() {
        let (w, h) = (37u32, 11u32);
        let texels: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let x = 10f32.powf(-3.0 + 6.0 * i as f32 / (w * h) as f32);
                [x, 0.5 * x, 0.25 * x]
            })
            .collect();
        let file = ktx2_rgba16f(w, h, &texels).expect("writes");
        let reader = ktx2::Reader::new(&file[..]).expect("a valid KTX2 file");
        let header = reader.header();
        assert_eq!(header.format, Some(Format::R16G16B16A16_SFLOAT));
        assert_eq!(
            header.supercompression_scheme,
            Some(SupercompressionScheme::Zstandard)
        );
        assert_eq!((header.pixel_width, header.pixel_height), (w, h));
        let level = reader.levels().next().expect("one level");
        let mut raw = Vec::new();
        std::io::Read::read_to_end(
            &mut ruzstd::decoding::StreamingDecoder::new(level.data).expect("a zstd frame"),
            &mut raw,
        )
        .expect("decodes");
        assert_eq!(raw.len() as u64, level.uncompressed_byte_length);
        for (k, t) in texels.iter().enumerate() {
            for (c, want) in [t[0], t[1], t[2], 1.0].into_iter().enumerate() {
                let at = (k * 4 + c) * 2;
                let v = half::f16::from_le_bytes([raw[at], raw[at + 1]]).to_f32();
                // f16 keeps 11 significant bits: 0.05 % relative; below 6·10⁻⁵ it is
                // subnormal, 6·10⁻⁸ absolute.
                assert!(
                    (v - want).abs() <= 5e-4 * want + 6e-8,
                    "texel {k} channel {c}: {v} vs {want}"
                );
            }
        }
        let exr = exr_rgb32f(w, h, &texels).expect("writes");
        let back = image::load_from_memory_with_format(&exr, image::ImageFormat::OpenExr)
            .expect("decodes")
            .to_rgb32f();
        assert_eq!((back.width(), back.height()), (w, h));
        for (t, p) in texels.iter().zip(back.pixels()) {
            assert_eq!(*t, p.0);
        }
    }

    #[test]
    fn a_size_that_does_not_match_the_texels_is_a_typed_error() {
        assert!(matches!(
            ktx2_rgba16f(2, 2, &[[0.0; 3]; 3]),
            Err(SceneError::Export(_))
        ));
        assert!(matches!(exr_rgb32f(0, 0, &[]), Err(SceneError::Export(_))));
    }
}
