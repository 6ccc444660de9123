//! Offscreen capture: read a texture back (rows padded to 256 bytes on the GPU side), and write
//! PNG (tone-mapped, 8-bit sRGB) or EXR (linear, 32-bit float).

use std::path::Path;

use crate::{GpuContext, RenderError};

/// A texture read back to the CPU, as RGBA f32 per texel (stored values: no sRGB decoding).
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Row-major, top row first.
    pub texels: Vec<[f32; 4]>,
}

impl Image {
    fn size_error(&self) -> RenderError {
        RenderError::ImageSize {
            width: self.width,
            height: self.height,
            texels: self.texels.len(),
        }
    }

    /// The texel at (x, y).
    pub fn at(&self, x: u32, y: u32) -> [f32; 4] {
        self.texels[(y * self.width + x) as usize]
    }

    /// Quantises stored [0, 1] values to 8 bits per channel (for textures that hold encoded
    /// sRGB already, such as the tone-mapped target).
    pub fn to_rgba8(&self) -> Vec<u8> {
        self.texels
            .iter()
            .flat_map(|t| t.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8))
            .collect()
    }
}

/// Why a texture or buffer could not be read back.
#[derive(Debug, thiserror::Error)]
pub enum ReadbackError {
    /// Waiting for the device failed.
    #[error("waiting for the GPU: {0}")]
    Poll(wgpu::PollError),
    /// Mapping the buffer failed.
    #[error("mapping the buffer: {0}")]
    Map(wgpu::BufferAsyncError),
    /// The mapped range could not be read.
    #[error("reading the mapped range: {0}")]
    Range(wgpu::MapRangeError),
    /// The bytes read back are not the expected texel or value layout.
    #[error("the bytes read back do not cast to the expected values: {0:?}")]
    Layout(bytemuck::PodCastError),
    /// The map callback never ran.
    #[error("the map callback was dropped")]
    Disconnected,
    /// A texel format readback does not decode.
    #[error("cannot read back {0:?}")]
    Format(wgpu::TextureFormat),
}

/// Waits for a mappable buffer and copies its contents out.
pub fn read_buffer(gpu: &GpuContext, buffer: &wgpu::Buffer) -> Result<Vec<u8>, RenderError> {
    let slice = buffer.slice(..);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    gpu.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(ReadbackError::Poll)?;
    rx.recv()
        .map_err(|_| ReadbackError::Disconnected)?
        .map_err(ReadbackError::Map)?;
    let data = slice
        .get_mapped_range()
        .map_err(ReadbackError::Range)?
        .to_vec();
    buffer.unmap();
    Ok(data)
}

/// Bytes per texel of the formats capture understands.
fn texel_bytes(format: wgpu::TextureFormat) -> Option<u32> {
    use wgpu::TextureFormat as F;
    Some(match format {
        F::Rgba8Unorm | F::Rgba8UnormSrgb | F::Bgra8Unorm | F::Bgra8UnormSrgb => 4,
        F::R8Unorm => 1,
        F::R16Float => 2,
        F::R32Float | F::Depth32Float => 4,
        F::Rg16Float => 4,
        F::Rgba16Float => 8,
        F::Rgba32Float => 16,
        _ => return None,
    })
}

/// IEEE 754 binary16 → f32.
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exp = i32::from((h >> 10) & 0x1f);
    let frac = f32::from(h & 0x3ff);
    match exp {
        0 => sign * frac * (2.0f32).powi(-24),
        31 if frac == 0.0 => sign * f32::INFINITY,
        31 => f32::NAN,
        _ => sign * (1.0 + frac / 1024.0) * (2.0f32).powi(exp - 15),
    }
}

/// Copies a whole 2D texture (mip 0) to the CPU.
pub fn read_texture(gpu: &GpuContext, texture: &wgpu::Texture) -> Result<Image, RenderError> {
    let (w, h, format) = (texture.width(), texture.height(), texture.format());
    let bpp = texel_bytes(format).ok_or(ReadbackError::Format(format))?;
    let unpadded = w * bpp;
    let padded =
        unpadded.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("capture_readback"),
        size: u64::from(padded) * u64::from(h),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = gpu
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("capture"),
        });
    encoder.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded),
                rows_per_image: Some(h),
            },
        },
        wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
    );
    gpu.queue.submit([encoder.finish()]);
    let raw = read_buffer(gpu, &buffer)?;
    gpu.take_errors()?;
    let mut texels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        let row = &raw[(y * padded) as usize..(y * padded + unpadded) as usize];
        for px in row.chunks_exact(bpp as usize) {
            texels.push(decode(format, px));
        }
    }
    Ok(Image {
        width: w,
        height: h,
        texels,
    })
}

fn decode(format: wgpu::TextureFormat, px: &[u8]) -> [f32; 4] {
    use wgpu::TextureFormat as F;
    let f16 = |i: usize| f16_to_f32(u16::from_le_bytes([px[2 * i], px[2 * i + 1]]));
    let f32_ =
        |i: usize| f32::from_le_bytes([px[4 * i], px[4 * i + 1], px[4 * i + 2], px[4 * i + 3]]);
    let u8_ = |i: usize| f32::from(px[i]) / 255.0;
    match format {
        F::Rgba8Unorm | F::Rgba8UnormSrgb => [u8_(0), u8_(1), u8_(2), u8_(3)],
        F::Bgra8Unorm | F::Bgra8UnormSrgb => [u8_(2), u8_(1), u8_(0), u8_(3)],
        F::R8Unorm => [u8_(0), 0.0, 0.0, 1.0],
        F::R16Float => [f16(0), 0.0, 0.0, 1.0],
        F::Rg16Float => [f16(0), f16(1), 0.0, 1.0],
        F::R32Float | F::Depth32Float => [f32_(0), 0.0, 0.0, 1.0],
        F::Rgba16Float => [f16(0), f16(1), f16(2), f16(3)],
        _ => [f32_(0), f32_(1), f32_(2), f32_(3)],
    }
}

fn write_atomically(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), RenderError>,
) -> Result<(), RenderError> {
    let tmp = path.with_extension(format!(
        "{}.tmp",
        path.extension().and_then(|e| e.to_str()).unwrap_or("out")
    ));
    write(&tmp)?;
    std::fs::rename(&tmp, path)?;
    Ok(())
}

/// Writes an 8-bit PNG of an image whose stored values are display-encoded (the tone-mapped
/// target), alpha forced opaque.
pub fn write_png(path: &Path, img: &Image) -> Result<(), RenderError> {
    let mut rgba = img.to_rgba8();
    for px in rgba.chunks_exact_mut(4) {
        px[3] = 255;
    }
    let buf = image::RgbaImage::from_raw(img.width, img.height, rgba).ok_or(img.size_error())?;
    write_atomically(path, |tmp| {
        buf.save_with_format(tmp, image::ImageFormat::Png)
            .map_err(RenderError::Image)
    })
}

/// Writes a linear 32-bit float OpenEXR of an HDR image (alpha forced to 1).
pub fn write_exr(path: &Path, img: &Image) -> Result<(), RenderError> {
    let data: Vec<f32> = img
        .texels
        .iter()
        .flat_map(|t| [t[0], t[1], t[2], 1.0])
        .collect();
    let buf = image::Rgba32FImage::from_raw(img.width, img.height, data).ok_or(img.size_error())?;
    write_atomically(path, |tmp| {
        buf.save_with_format(tmp, image::ImageFormat::OpenExr)
            .map_err(RenderError::Image)
    })
}

/// Reads an image file (EXR, HDR, PNG) as linear RGBA f32 as stored.
pub fn read_image(bytes: &[u8]) -> Result<Image, RenderError> {
    let img = image::load_from_memory(bytes)
        .map_err(RenderError::Image)?
        .to_rgba32f();
    Ok(Image {
        width: img.width(),
        height: img.height(),
        texels: img.pixels().map(|p| p.0).collect(),
    })
}

impl Image {
    /// Averages `factor × factor` tiles: the box pixel filter of a path tracer, from an image
    /// rendered `factor` times larger (supersampling; the renderer itself does not antialias).
    pub fn box_downsample(&self, factor: u32) -> Image {
        let f = factor.max(1);
        let (w, h) = (self.width / f, self.height / f);
        let mut texels = vec![[0.0f32; 4]; (w * h) as usize];
        let norm = 1.0 / f64::from(f * f);
        for y in 0..h {
            for x in 0..w {
                let mut acc = [0.0f64; 4];
                for j in 0..f {
                    for i in 0..f {
                        let t = self.at(x * f + i, y * f + j);
                        for c in 0..4 {
                            acc[c] += f64::from(t[c]);
                        }
                    }
                }
                texels[(y * w + x) as usize] = acc.map(|v| (v * norm) as f32);
            }
        }
        Image {
            width: w,
            height: h,
            texels,
        }
    }
}

/// How far an image is from a reference of the same size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageError {
    /// Σ|a − b| / Σ|b| over pixels and RGB channels.
    pub rel_l1: f64,
    /// The same after averaging both over `block × block` tiles (less sensitive to noise in
    /// the reference and to edge aliasing).
    pub rel_l1_blocks: f64,
    /// Relative difference of the image means (RGB summed).
    pub mean_bias: f64,
}

/// Compares linear images; `None` when the sizes differ or the reference has no light (every
/// RGB value 0, or a value not finite: no relative error is defined). Accumulates in f64.
pub fn compare_images(a: &Image, reference: &Image, block: u32) -> Option<ImageError> {
    if (a.width, a.height) != (reference.width, reference.height) || a.texels.is_empty() {
        return None;
    }
    let light: f64 = reference
        .texels
        .iter()
        .flat_map(|t| &t[..3])
        .map(|&v| f64::from(v).abs())
        .sum();
    if !(light.is_finite() && light > 0.0) {
        return None;
    }
    let l1 = |x: &[[f64; 3]], y: &[[f64; 3]]| {
        let (mut num, mut den) = (0.0, 0.0);
        for (p, q) in x.iter().zip(y) {
            for c in 0..3 {
                num += (p[c] - q[c]).abs();
                den += q[c].abs();
            }
        }
        num / den.max(1e-300)
    };
    let rgb = |img: &Image| -> Vec<[f64; 3]> {
        img.texels
            .iter()
            .map(|t| [f64::from(t[0]), f64::from(t[1]), f64::from(t[2])])
            .collect()
    };
    let (x, y) = (rgb(a), rgb(reference));
    let blocks = |v: &[[f64; 3]]| -> Vec<[f64; 3]> {
        // A block larger than the image is the whole image.
        let b = block.clamp(1, a.width.min(a.height));
        let (bw, bh) = (a.width / b, a.height / b);
        let mut out = vec![[0.0; 3]; (bw * bh) as usize];
        for j in 0..bh * b {
            for i in 0..bw * b {
                let o = &mut out[((j / b) * bw + i / b) as usize];
                let p = v[(j * a.width + i) as usize];
                for c in 0..3 {
                    o[c] += p[c];
                }
            }
        }
        out
    };
    let sum = |v: &[[f64; 3]]| v.iter().flatten().sum::<f64>();
    Some(ImageError {
        rel_l1: l1(&x, &y),
        rel_l1_blocks: l1(&blocks(&x), &blocks(&y)),
        mean_bias: (sum(&x) - sum(&y)) / sum(&y).max(1e-300),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_floats_decode() {
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x7bff), 65504.0);
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
        assert!(f16_to_f32(0x7e00).is_nan());
        assert_eq!(f16_to_f32(0x7c00), f32::INFINITY);
    }

    #[test]
    fn image_comparison_measures_what_it_says() {
        let img = |v: f32| Image {
            width: 4,
            height: 4,
            texels: vec![[v, v, v, 1.0]; 16],
        };
        let e = compare_images(&img(1.1), &img(1.0), 2).expect("same size");
        assert!((e.rel_l1 - 0.1).abs() < 1e-6 && (e.mean_bias - 0.1).abs() < 1e-6);
        // A checkerboard error cancels in 2×2 blocks.
        let mut checker = img(1.0);
        for (k, t) in checker.texels.iter_mut().enumerate() {
            let d = if (k % 4 + k / 4) % 2 == 0 { 0.2 } else { -0.2 };
            *t = [1.0 + d; 4];
        }
        let e = compare_images(&checker, &img(1.0), 2).expect("same size");
        assert!((e.rel_l1 - 0.2).abs() < 1e-6 && e.rel_l1_blocks < 1e-6);
        let small = Image {
            width: 2,
            height: 2,
            texels: vec![[1.0; 4]; 4],
        };
        assert!(compare_images(&small, &img(1.0), 2).is_none());
        // No light in the reference: no relative error (not a huge or NaN one).
        assert!(compare_images(&img(1.0), &img(0.0), 2).is_none());
        assert!(compare_images(&img(1.0), &img(f32::NAN), 2).is_none());
        let e = compare_images(&img(1.1), &img(1.0), 64).expect("same size");
        assert!((e.rel_l1_blocks - 0.1).abs() < 1e-6, "{e:?}");
    }
}
