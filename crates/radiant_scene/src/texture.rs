//! Textures of the scene model: decoded 8-bit RGBA images, glTF samplers and texture references
//! with `KHR_texture_transform`, and the three ways the bake and the tracer read them:
//!
//! - [`TextureRef::sample_linear`]: one bilinear (or nearest) sample of an sRGB colour texture,
//!   decoded to linear before filtering (the tracer's hit points);
//! - [`Pyramid`]: a linear-light mip chain, for the mean of a texture over a triangle of UV space
//!   ([`Pyramid::footprint_mean`], an element's own reflectance);
//! - [`AlphaMasks`]: whether a hit on an alpha-masked triangle is opaque at its barycentrics.
//!
//! Every sample is finite: wrap modes fold any finite UV into the image, and non-finite UVs read
//! texel (0, 0).

use std::sync::Arc;

use glam::{DVec3, Vec2};

use crate::{AlphaMode, Scene};

/// An image decoded to 8-bit RGBA, row-major from the top-left texel (glTF's UV origin).
#[derive(Clone, PartialEq)]
pub struct Image {
    /// The image's name or URI (for reports).
    pub name: String,
    /// Width in texels (≥ 1).
    pub width: u32,
    /// Height in texels (≥ 1).
    pub height: u32,
    /// `width × height × 4` bytes, RGBA.
    pub pixels: Arc<[u8]>,
}

/// Why an encoded image could not be decoded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ImageError {
    /// The bytes start like neither a PNG nor a JPEG file.
    #[error("neither PNG nor JPEG (declared {})", declared.as_deref().unwrap_or("no MIME type"))]
    NotPngOrJpeg {
        /// The MIME type the glTF declared, if any.
        declared: Option<String>,
    },
    /// Truncated or corrupt data, as the decoder reports it.
    #[error("cannot decode it: {0}")]
    Corrupt(String),
    /// More texels than [`Image::MAX_TEXELS`].
    #[error(
        "{width}×{height} texels is over the limit of 8192×8192; scale it down (e.g. `convert in.png -resize 8192x8192 out.png`)"
    )]
    TooLarge {
        /// Width in texels, from the header.
        width: u32,
        /// Height in texels, from the header.
        height: u32,
    },
}

impl std::fmt::Debug for Image {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Image({:?}, {}×{})", self.name, self.width, self.height)
    }
}

impl Image {
    /// A solid-colour or test image from RGBA bytes; `None` when the size does not match.
    pub fn new(name: &str, width: u32, height: u32, pixels: Vec<u8>) -> Option<Image> {
        (width > 0 && height > 0 && pixels.len() as u64 == u64::from(width) * u64::from(height) * 4)
            .then(|| Image {
                name: name.to_string(),
                width,
                height,
                pixels: pixels.into(),
            })
    }

    /// The most texels an imported image may have: 8192 × 8192 (256 MiB as RGBA8). Larger images
    /// are refused before they are decoded, so a 16k × 16k texture cannot take the memory of a
    /// bake.
    pub const MAX_TEXELS: u64 = 8192 * 8192;

    /// Decodes an encoded PNG or JPEG image to 8-bit RGBA (16-bit channels rounded, grey
    /// replicated). The container is recognised by its first bytes; `declared` is the MIME type
    /// the file gives, and a mismatch is returned as a warning (the image is decoded as what it
    /// is). Images over [`Image::MAX_TEXELS`] are refused from their header, before decoding.
    ///
    /// # Errors
    /// [`ImageError`] when the bytes are neither PNG nor JPEG, are truncated or corrupt, or are too
    /// large.
    pub fn decode(
        name: &str,
        bytes: &[u8],
        declared: Option<&str>,
    ) -> Result<(Image, Option<String>), ImageError> {
        Self::decode_within(name, bytes, declared, Self::MAX_TEXELS)
    }

    /// [`Image::decode`] with at most `max_texels` texels: a larger PNG (not interlaced) is
    /// read row by row and averaged down by the smallest whole factor that fits (colour in
    /// linear light), never held whole, with a warning that says so; a larger JPEG or
    /// interlaced PNG is [`ImageError::TooLarge`].
    pub fn decode_within(
        name: &str,
        bytes: &[u8],
        declared: Option<&str>,
        max_texels: u64,
    ) -> Result<(Image, Option<String>), ImageError> {
        use image::ImageFormat;
        let (format, mime) = if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
            (ImageFormat::Png, "image/png")
        } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
            (ImageFormat::Jpeg, "image/jpeg")
        } else {
            return Err(ImageError::NotPngOrJpeg {
                declared: declared.map(str::to_string),
            });
        };
        let warning = declared.filter(|d| *d != mime).map(|d| {
            format!("image '{name}': declared {d:?} but its bytes are {mime}; decoded as {mime}")
        });
        let reader = || {
            let mut r = image::ImageReader::with_format(std::io::Cursor::new(bytes), format);
            let mut limits = image::Limits::default();
            limits.max_alloc = Some(Self::MAX_TEXELS * 8 + (64 << 20));
            r.limits(limits);
            r
        };
        let corrupt = |e: image::ImageError| ImageError::Corrupt(e.to_string());
        let (width, height) = reader().into_dimensions().map_err(corrupt)?;
        if u64::from(width) * u64::from(height) > max_texels {
            let averaged = match format {
                ImageFormat::Png => png_averaged(name, bytes, max_texels).map_err(|e| {
                    ImageError::Corrupt(format!("{width}×{height} texels read row by row: {e}"))
                })?,
                _ => None,
            };
            if let Some((image, k)) = averaged {
                let side = (max_texels as f64).sqrt().floor() as u64;
                let note = format!(
                    "image '{name}': {width}×{height} texels is over the limit of {side}×{side}; averaged down {k}× to {}×{} as it was read",
                    image.width, image.height
                );
                let warning = Some(match warning {
                    Some(w) => format!("{w}; {note}"),
                    None => note,
                });
                return Ok((image, warning));
            }
            return Err(ImageError::TooLarge { width, height });
        }
        let decoded = reader().decode().map_err(corrupt)?;
        let rgba = decoded.into_rgba8();
        let (width, height) = rgba.dimensions();
        let image = Image::new(name, width, height, rgba.into_raw())
            .ok_or_else(|| ImageError::Corrupt(format!("{width}×{height} texels")))?;
        Ok((image, warning))
    }

    /// The mean linear RGB and alpha of all texels (colour decoded from sRGB).
    pub fn mean_linear(&self) -> [f64; 4] {
        let lut = srgb_lut();
        let mut sum = [0.0f64; 4];
        for px in self.pixels.chunks_exact(4) {
            for c in 0..3 {
                sum[c] += lut[px[c] as usize];
            }
            sum[3] += f64::from(px[3]) / 255.0;
        }
        let n = (self.pixels.len() / 4).max(1) as f64;
        sum.map(|s| s / n)
    }

    #[inline]
    fn texel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = (y as usize * self.width as usize + x as usize) * 4;
        [
            self.pixels[i],
            self.pixels[i + 1],
            self.pixels[i + 2],
            self.pixels[i + 3],
        ]
    }
}

/// How a texture coordinate outside [0, 1] is folded back (glTF sampler wrap modes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Wrap {
    /// Tiles (glTF's default).
    #[default]
    Repeat,
    /// Tiles, mirrored every other tile.
    MirroredRepeat,
    /// Clamps to the edge texel.
    ClampToEdge,
}

impl Wrap {
    /// The texel index of integer texel coordinate `i` in an axis of `n` texels.
    #[inline]
    fn fold(self, i: i64, n: u32) -> u32 {
        let n = i64::from(n);
        let k = match self {
            Wrap::Repeat => i.rem_euclid(n),
            Wrap::ClampToEdge => i.clamp(0, n - 1),
            Wrap::MirroredRepeat => {
                let m = i.rem_euclid(2 * n);
                if m < n { m } else { 2 * n - 1 - m }
            }
        };
        k as u32
    }
}

/// A glTF sampler: wrap modes and whether magnification is nearest (else linear).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Sampler {
    /// Wrap along U.
    pub wrap_s: Wrap,
    /// Wrap along V.
    pub wrap_t: Wrap,
    /// Nearest-texel filtering (glTF `magFilter` NEAREST); linear otherwise.
    pub nearest: bool,
}

/// `KHR_texture_transform`: `uv' = T · R · S · uv`, rotation counter-clockwise in radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UvTransform {
    /// Translation.
    pub offset: [f32; 2],
    /// Rotation in radians.
    pub rotation: f32,
    /// Scale.
    pub scale: [f32; 2],
}

impl Default for UvTransform {
    fn default() -> Self {
        UvTransform {
            offset: [0.0; 2],
            rotation: 0.0,
            scale: [1.0; 2],
        }
    }
}

impl UvTransform {
    /// Applies the transform (the extension's matrix, written out).
    pub fn apply(&self, uv: Vec2) -> Vec2 {
        let (s, c) = self.rotation.sin_cos();
        let (x, y) = (uv.x * self.scale[0], uv.y * self.scale[1]);
        Vec2::new(
            c * x + s * y + self.offset[0],
            -s * x + c * y + self.offset[1],
        )
    }
}

/// A material's use of a texture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into [`Scene::images`].
    pub image: u32,
    /// How it is sampled.
    pub sampler: Sampler,
    /// Which TEXCOORD set it reads (0 or 1).
    pub tex_coord: u8,
    /// `KHR_texture_transform`, identity when absent.
    pub transform: UvTransform,
}

/// sRGB byte → linear, as a table (`f64`, so means are exact to rounding).
/// A PNG averaged down, read row by row (`png`'s streaming reader, 8 bits per channel): each
/// texel the mean of a `k × k` block (colour in linear light, alpha as it is), `k` the
/// smallest that leaves at most `max_texels`. `None` for an interlaced PNG, whose rows do not
/// come in order.
fn png_averaged(
    name: &str,
    bytes: &[u8],
    max_texels: u64,
) -> Result<Option<(Image, u32)>, ImageError> {
    let corrupt = |e: png::DecodingError| ImageError::Corrupt(e.to_string());
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::normalize_to_color8());
    let mut reader = decoder.read_info().map_err(corrupt)?;
    if reader.info().interlaced {
        return Ok(None);
    }
    let (width, height) = reader.info().size();
    let fits =
        |k: u32| u64::from(width.div_ceil(k)) * u64::from(height.div_ceil(k)) <= max_texels.max(1);
    let k = (2..=width.max(height).max(2))
        .find(|&k| fits(k))
        .unwrap_or(width.max(height));
    let (ow, oh) = (width.div_ceil(k), height.div_ceil(k));
    let channels = reader.output_color_type().0.samples();
    let lut = srgb_lut();
    let mut sums = vec![[0.0f64; 5]; ow as usize];
    let mut out = Vec::with_capacity(ow as usize * oh as usize * 4);
    for y in 0..height {
        let row = reader
            .next_row()
            .map_err(corrupt)?
            .ok_or_else(|| ImageError::Corrupt(format!("{name}: rows end at {y} of {height}")))?;
        for (x, px) in row
            .data()
            .chunks_exact(channels)
            .take(width as usize)
            .enumerate()
        {
            let (rgb, a) = match channels {
                1 => ([px[0]; 3], 255),
                2 => ([px[0]; 3], px[1]),
                3 => ([px[0], px[1], px[2]], 255),
                _ => ([px[0], px[1], px[2]], px[3]),
            };
            let s = &mut sums[x / k as usize];
            for c in 0..3 {
                s[c] += lut[rgb[c] as usize];
            }
            s[3] += f64::from(a) / 255.0;
            s[4] += 1.0;
        }
        if (y + 1) % k == 0 || y + 1 == height {
            for s in &mut sums {
                let n = s[4].max(1.0);
                out.extend((0..3).map(|c| radiant_color::linear_to_srgb8(s[c] / n)));
                out.push((s[3] / n * 255.0).round().clamp(0.0, 255.0) as u8);
                *s = [0.0; 5];
            }
        }
    }
    let image = Image::new(name, ow, oh, out)
        .ok_or_else(|| ImageError::Corrupt(format!("{ow}×{oh} texels")))?;
    Ok(Some((image, k)))
}

fn srgb_lut() -> &'static [f64; 256] {
    static LUT: std::sync::OnceLock<[f64; 256]> = std::sync::OnceLock::new();
    LUT.get_or_init(|| std::array::from_fn(|i| radiant_color::srgb_to_linear(i as f64 / 255.0)))
}

/// The four texels and weights of a bilinear (or nearest) lookup at `uv` in a `w × h` image.
#[inline]
fn taps(sampler: Sampler, w: u32, h: u32, uv: Vec2) -> [(u32, u32, f32); 4] {
    let uv = if uv.is_finite() { uv } else { Vec2::ZERO };
    let (x, y) = (uv.x * w as f32 - 0.5, uv.y * h as f32 - 0.5);
    if sampler.nearest {
        let (i, j) = ((x + 0.5).floor() as i64, (y + 0.5).floor() as i64);
        let t = (sampler.wrap_s.fold(i, w), sampler.wrap_t.fold(j, h), 1.0);
        return [t, (t.0, t.1, 0.0), (t.0, t.1, 0.0), (t.0, t.1, 0.0)];
    }
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (i, j) = (x0 as i64, y0 as i64);
    let (i0, i1) = (sampler.wrap_s.fold(i, w), sampler.wrap_s.fold(i + 1, w));
    let (j0, j1) = (sampler.wrap_t.fold(j, h), sampler.wrap_t.fold(j + 1, h));
    [
        (i0, j0, (1.0 - fx) * (1.0 - fy)),
        (i1, j0, fx * (1.0 - fy)),
        (i0, j1, (1.0 - fx) * fy),
        (i1, j1, fx * fy),
    ]
}

impl TextureRef {
    /// The texture coordinate this reference reads from a vertex's two UV sets, transformed.
    pub fn uv(&self, uv: [Vec2; 2]) -> Vec2 {
        self.transform.apply(uv[usize::from(self.tex_coord.min(1))])
    }

    /// Linear RGB and alpha at `uv` (already transformed): colour decoded from sRGB before
    /// filtering, alpha linear. `[1; 4]` when the image index is dangling.
    pub fn sample_linear(&self, images: &[Image], uv: Vec2) -> [f32; 4] {
        let Some(img) = images.get(self.image as usize) else {
            return [1.0; 4];
        };
        let lut = srgb_lut();
        let mut out = [0.0f64; 4];
        for (x, y, w) in taps(self.sampler, img.width, img.height, uv) {
            if w == 0.0 {
                continue;
            }
            let (t, w) = (img.texel(x, y), f64::from(w));
            for c in 0..3 {
                out[c] += w * lut[t[c] as usize];
            }
            out[3] += w * f64::from(t[3]) / 255.0;
        }
        out.map(|v| v as f32)
    }

    /// Alpha at `uv` (already transformed), filtered as the sampler says.
    pub fn sample_alpha(&self, images: &[Image], uv: Vec2) -> f32 {
        let Some(img) = images.get(self.image as usize) else {
            return 1.0;
        };
        taps(self.sampler, img.width, img.height, uv)
            .iter()
            .map(|&(x, y, w)| w * f32::from(img.texel(x, y)[3]) / 255.0)
            .sum()
    }
}

/// A linear-light mip chain of one image, for footprint means. Level 0 is the image itself
/// (decoded on the fly); each further level halves both sides (a box filter in linear light,
/// 16 bits per channel).
pub struct Pyramid {
    image: Image,
    /// Levels 1, 2, …: (width, height, linear RGBA in units of 1/65535).
    levels: Vec<(u32, u32, Vec<[u16; 4]>)>,
}

impl Pyramid {
    /// Builds the chain down to 1 × 1.
    pub fn new(image: &Image) -> Pyramid {
        let lut = srgb_lut();
        let q = |v: f32| (v.clamp(0.0, 1.0) * 65535.0 + 0.5) as u16;
        let mut levels: Vec<(u32, u32, Vec<[u16; 4]>)> = Vec::new();
        let (mut w, mut h) = (image.width, image.height);
        while w > 1 || h > 1 {
            let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
            let prev = levels.last();
            let read = |x: u32, y: u32| -> [f32; 4] {
                match prev {
                    None => {
                        let t = image.texel(x, y);
                        [
                            lut[t[0] as usize] as f32,
                            lut[t[1] as usize] as f32,
                            lut[t[2] as usize] as f32,
                            f32::from(t[3]) / 255.0,
                        ]
                    }
                    Some((pw, _, data)) => {
                        data[(y * pw + x) as usize].map(|v| f32::from(v) / 65535.0)
                    }
                }
            };
            let mut data = Vec::with_capacity((nw * nh) as usize);
            for y in 0..nh {
                for x in 0..nw {
                    let mut sum = [0.0f32; 4];
                    let mut n = 0.0;
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (sx, sy) = (2 * x + dx, 2 * y + dy);
                        if sx < w && sy < h {
                            let t = read(sx, sy);
                            for c in 0..4 {
                                sum[c] += t[c];
                            }
                            n += 1.0;
                        }
                    }
                    data.push(sum.map(|s| q(s / n)));
                }
            }
            levels.push((nw, nh, data));
            (w, h) = (nw, nh);
        }
        Pyramid {
            image: image.clone(),
            levels,
        }
    }

    /// Linear RGBA at `uv` on mip level `level` (0 = the image), bilinear.
    fn sample(&self, sampler: Sampler, uv: Vec2, level: usize) -> [f64; 4] {
        let mut out = [0.0f64; 4];
        if level == 0 || self.levels.is_empty() {
            let lut = srgb_lut();
            let img = &self.image;
            for (x, y, w) in taps(sampler, img.width, img.height, uv) {
                let t = img.texel(x, y);
                let w = f64::from(w);
                for c in 0..3 {
                    out[c] += w * lut[t[c] as usize];
                }
                out[3] += w * f64::from(t[3]) / 255.0;
            }
            return out;
        }
        let (lw, lh, data) = &self.levels[(level - 1).min(self.levels.len() - 1)];
        for (x, y, w) in taps(sampler, *lw, *lh, uv) {
            let t = data[(y * lw + x) as usize];
            for c in 0..4 {
                out[c] += f64::from(w) * f64::from(t[c]) / 65535.0;
            }
        }
        out
    }

    /// The mean linear RGBA of the texture over the UV triangle `uv` (already transformed):
    /// `k²` stratified samples at the centroids of the triangle's regular `k`-subdivision, on the
    /// mip level whose texels are about the samples' spacing.
    pub fn footprint_mean(&self, sampler: Sampler, uv: [Vec2; 3]) -> [f64; 4] {
        const K: u32 = 6;
        let (w, h) = (self.image.width as f32, self.image.height as f32);
        let (a, b, c) = (uv[0], uv[1], uv[2]);
        // Area in texels of level 0, then the level where one sample covers about one texel.
        let texels = 0.5
            * ((b - a) * Vec2::new(w, h))
                .perp_dot((c - a) * Vec2::new(w, h))
                .abs();
        let per_sample = if texels.is_finite() {
            texels / (K * K) as f32
        } else {
            0.0
        };
        let level = if per_sample > 1.0 {
            (0.5 * per_sample.log2()).floor() as usize
        } else {
            0
        };
        let mut sum = [0.0f64; 4];
        let kf = K as f32;
        for i in 0..K {
            for j in 0..K - i {
                // Upright cell (i, j) and, where it exists, the inverted one beside it.
                let mut centroids = vec![Vec2::new(i as f32 + 1.0 / 3.0, j as f32 + 1.0 / 3.0)];
                if i + j + 1 < K {
                    centroids.push(Vec2::new(i as f32 + 2.0 / 3.0, j as f32 + 2.0 / 3.0));
                }
                for p in centroids {
                    let (s, t) = (p.x / kf, p.y / kf);
                    let x = a + (b - a) * s + (c - a) * t;
                    let v = self.sample(sampler, x, level);
                    for ch in 0..4 {
                        sum[ch] += v[ch];
                    }
                }
            }
        }
        sum.map(|s| s / f64::from(K * K))
    }
}

/// One alpha-masked triangle: its mask's texture and UVs, the cutoff and the factor's alpha.
#[derive(Clone, Copy, Debug)]
pub struct MaskedTriangle {
    /// The texture whose alpha masks it; image `u32::MAX` when the triangle is cut wholly
    /// (its `factor` is then below the cutoff) or needs no lookup.
    pub texture: TextureRef,
    /// The texture's (transformed) coordinates at the triangle's corners.
    pub uv: [Vec2; 3],
    /// Alpha below this is cut.
    pub cutoff: f32,
    /// The base colour factor's alpha, which multiplies the texture's.
    pub factor: f32,
}

/// What a masked triangle's texture holds over its UV footprint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Coverage {
    /// Every texel a hit could read is at or above the cutoff.
    Opaque,
    /// Every one is below it.
    Cut,
    /// Both, or too many texels to look at.
    Mixed,
}

impl MaskedTriangle {
    /// Classifies the triangle from the texels under its UV bounding box (one texel more on
    /// each side for bilinear filtering): conservative, as the box holds the triangle. Boxes
    /// over 2²⁰ texels are not looked at (mixed).
    fn coverage(&self, img: &Image) -> Coverage {
        let (w, h) = (img.width as f32, img.height as f32);
        if !self.uv.iter().all(|p| p.is_finite()) {
            return Coverage::Mixed;
        }
        let lo = self.uv.iter().fold(Vec2::INFINITY, |a, &b| a.min(b));
        let hi = self.uv.iter().fold(Vec2::NEG_INFINITY, |a, &b| a.max(b));
        let (x0, x1) = ((lo.x * w).floor() as i64 - 1, (hi.x * w).ceil() as i64 + 1);
        let (y0, y1) = ((lo.y * h).floor() as i64 - 1, (hi.y * h).ceil() as i64 + 1);
        if (x1 - x0 + 1).saturating_mul(y1 - y0 + 1) > 1 << 20 {
            return Coverage::Mixed;
        }
        let (mut opaque, mut cut) = (false, false);
        for y in y0..=y1 {
            let ty = self.texture.sampler.wrap_t.fold(y, img.height);
            for x in x0..=x1 {
                let tx = self.texture.sampler.wrap_s.fold(x, img.width);
                let a = self.factor * f32::from(img.texel(tx, ty)[3]) / 255.0;
                if a >= self.cutoff {
                    opaque = true;
                } else {
                    cut = true;
                }
                if opaque && cut {
                    return Coverage::Mixed;
                }
            }
        }
        if cut { Coverage::Cut } else { Coverage::Opaque }
    }
}

/// The alpha masks of a scene's triangles (`alphaMode` MASK, and BLEND treated as a mask at
/// 0.5): [`AlphaMasks::blocks`] says whether a hit is opaque.
#[derive(Clone, Debug)]
pub struct AlphaMasks {
    /// Triangles of masked surfaces found wholly opaque (kept as ordinary triangles), wholly
    /// cut (never block) and mixed (look up their texture), for reports.
    pub counts: [usize; 3],
    images: Vec<Image>,
    /// Per scene triangle: index into `masked`, or `u32::MAX` for an opaque triangle.
    index: Vec<u32>,
    masked: Vec<MaskedTriangle>,
}

impl AlphaMasks {
    /// The masks of `scene`'s triangles, or `None` when no triangle is masked.
    pub fn new(scene: &Scene) -> Option<AlphaMasks> {
        let cut = |s: &crate::Surface| match s.alpha {
            AlphaMode::Opaque => None,
            AlphaMode::Mask { cutoff } => Some(cutoff as f32),
            AlphaMode::Blend => Some(0.5),
        };
        if !scene.surfaces.iter().any(|s| cut(s).is_some()) {
            return None;
        }
        let mut index = vec![u32::MAX; scene.triangles.len()];
        let mut masked = Vec::new();
        let mut counts = [0usize; 3];
        for (k, t) in scene.triangles.iter().enumerate() {
            let Some(s) = scene.surfaces.get(t.surface as usize) else {
                continue;
            };
            let Some(cutoff) = cut(s) else { continue };
            let factor = s.base_color_alpha as f32;
            let Some(texture) = s.base_color_texture else {
                if factor < cutoff {
                    // A constant alpha below the cutoff: the triangle is not there at all.
                    index[k] = masked.len() as u32;
                    masked.push(MaskedTriangle {
                        texture: TextureRef {
                            image: u32::MAX,
                            sampler: Sampler::default(),
                            tex_coord: 0,
                            transform: UvTransform::default(),
                        },
                        uv: [Vec2::ZERO; 3],
                        cutoff,
                        factor: 0.0,
                    });
                }
                continue;
            };
            let uv = [0, 1, 2].map(|v| texture.uv([t.uv[0][v], t.uv[1][v]]));
            let m = MaskedTriangle {
                texture,
                uv,
                cutoff,
                factor,
            };
            match scene
                .images
                .get(texture.image as usize)
                .map(|img| m.coverage(img))
            {
                // Opaque wherever a hit can land: an ordinary triangle, no texture lookups.
                Some(Coverage::Opaque) => counts[0] += 1,
                Some(Coverage::Cut) => {
                    counts[1] += 1;
                    index[k] = masked.len() as u32;
                    masked.push(MaskedTriangle { factor: 0.0, ..m });
                    // No image index: `blocks` answers from the factor alone.
                    let last = masked.len() - 1;
                    masked[last].texture.image = u32::MAX;
                }
                _ => {
                    counts[2] += 1;
                    index[k] = masked.len() as u32;
                    masked.push(m);
                }
            }
        }
        Some(AlphaMasks {
            counts,
            images: scene.images.clone(),
            index,
            masked,
        })
    }

    /// Scene triangle `triangle`'s mask, `None` when it is opaque.
    pub fn mask(&self, triangle: u32) -> Option<&MaskedTriangle> {
        let &i = self.index.get(triangle as usize)?;
        self.masked.get(i as usize)
    }

    /// The scene's images, which the masks' textures index.
    pub fn images(&self) -> &[Image] {
        &self.images
    }

    /// Whether scene triangle `triangle` has a mask.
    pub fn is_masked(&self, triangle: u32) -> bool {
        self.index
            .get(triangle as usize)
            .is_some_and(|&i| i != u32::MAX)
    }

    /// Whether a hit on scene triangle `triangle` at barycentrics `(u, v)` (weights of vertices
    /// 1 and 2) is opaque. Unmasked triangles always are.
    pub fn blocks(&self, triangle: u32, u: f32, v: f32) -> bool {
        let Some(&i) = self.index.get(triangle as usize) else {
            return true;
        };
        let Some(m) = self.masked.get(i as usize) else {
            return true;
        };
        if m.texture.image == u32::MAX {
            return m.factor >= m.cutoff;
        }
        let uv = m.uv[0] * (1.0 - u - v) + m.uv[1] * u + m.uv[2] * v;
        m.factor * m.texture.sample_alpha(&self.images, uv) >= m.cutoff
    }
}

/// The barycentric weights `(1 − s − t, s, t)` of point `p` in triangle `v` (f64, in its plane).
pub fn barycentric(v: [DVec3; 3], p: DVec3) -> [f64; 3] {
    let (e1, e2, d) = (v[1] - v[0], v[2] - v[0], p - v[0]);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (d1, d2) = (d.dot(e1), d.dot(e2));
    let det = d11 * d22 - d12 * d12;
    if det == 0.0 || !det.is_finite() {
        return [1.0 / 3.0; 3];
    }
    let s = (d22 * d1 - d12 * d2) / det;
    let t = (d11 * d2 - d12 * d1) / det;
    [1.0 - s - t, s, t]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A PNG over the limit is averaged down by the smallest whole factor that fits, each
    /// texel the mean of its block in linear light, with a warning; a JPEG over it is refused.
    #[test]
    fn a_png_over_the_limit_is_averaged_down_row_by_row() {
        let (w, h) = (64u32, 48u32);
        let texel = |x: u32, y: u32| [(x * 4) as u8, (y * 5) as u8, ((x + y) % 256) as u8, 200];
        let rgba: Vec<u8> = (0..h)
            .flat_map(|y| (0..w).flat_map(move |x| texel(x, y)))
            .collect();
        let mut png = std::io::Cursor::new(Vec::new());
        image::RgbaImage::from_raw(w, h, rgba)
            .expect("size")
            .write_to(&mut png, image::ImageFormat::Png)
            .expect("encodes");
        // At most 256 texels: 64/4 × 48/4 = 192 (a factor of 3 leaves 352).
        let (img, warning) =
            Image::decode_within("big", png.get_ref(), Some("image/png"), 256).expect("decodes");
        assert_eq!((img.width, img.height), (16, 12));
        let warning = warning.expect("a warning");
        assert!(
            warning.contains("64×48") && warning.contains("4×"),
            "{warning}"
        );
        let lut = srgb_lut();
        for (ox, oy) in [(0u32, 0u32), (7, 5), (15, 11)] {
            let got = img.texel(ox, oy);
            for c in 0..3 {
                let mean = (0..4)
                    .flat_map(|dy| (0..4).map(move |dx| (dx, dy)))
                    .map(|(dx, dy)| lut[texel(ox * 4 + dx, oy * 4 + dy)[c] as usize])
                    .sum::<f64>()
                    / 16.0;
                assert_eq!(
                    got[c],
                    radiant_color::linear_to_srgb8(mean),
                    "({ox}, {oy}) {c}"
                );
            }
            assert_eq!(got[3], 200);
        }
        let mut jpeg = std::io::Cursor::new(Vec::new());
        image::RgbImage::new(w, h)
            .write_to(&mut jpeg, image::ImageFormat::Jpeg)
            .expect("encodes");
        assert!(matches!(
            Image::decode_within("big", jpeg.get_ref(), None, 256),
            Err(ImageError::TooLarge {
                width: 64,
                height: 48
            })
        ));
    }

    fn checker(n: u32) -> Image {
        let mut px = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let v = if (x + y) % 2 == 0 { 255 } else { 0 };
                px.extend([v, v, v, if x < n / 2 { 255 } else { 0 }]);
            }
        }
        Image::new("checker", n, n, px).expect("size matches")
    }

    #[test]
    fn wrap_modes_fold_indices() {
        assert_eq!(Wrap::Repeat.fold(-1, 4), 3);
        assert_eq!(Wrap::Repeat.fold(9, 4), 1);
        assert_eq!(Wrap::ClampToEdge.fold(-7, 4), 0);
        assert_eq!(Wrap::ClampToEdge.fold(7, 4), 3);
        assert_eq!(Wrap::MirroredRepeat.fold(4, 4), 3);
        assert_eq!(Wrap::MirroredRepeat.fold(-1, 4), 0);
    }

    #[test]
    fn transform_matches_the_extension() {
        let t = UvTransform {
            offset: [0.5, 0.0],
            rotation: std::f32::consts::FRAC_PI_2,
            scale: [2.0, 1.0],
        };
        // S: (1, 0) → (2, 0); R(π/2) as written: (x, y) → (y, −x) → (0, −2); T: (0.5, −2).
        let p = t.apply(Vec2::new(1.0, 0.0));
        assert!((p - Vec2::new(0.5, -2.0)).length() < 1e-6, "{p}");
    }

    #[test]
    fn footprints_average_what_they_cover() {
        let img = checker(2);
        let p = Pyramid::new(&img);
        let tex = Sampler {
            nearest: true,
            ..Sampler::default()
        };
        // A triangle inside the white texel (0, 0) reads white; one across many texels, grey.
        let small = [
            Vec2::new(0.05, 0.05),
            Vec2::new(0.4, 0.05),
            Vec2::new(0.05, 0.4),
        ];
        assert!((p.footprint_mean(tex, small)[0] - 1.0).abs() < 1e-9);
        let big = [
            Vec2::new(0.0, 0.0),
            Vec2::new(40.0, 0.0),
            Vec2::new(0.0, 40.0),
        ];
        let m = p.footprint_mean(Sampler::default(), big);
        assert!((m[0] - 0.5).abs() < 0.02, "{m:?}");
        // Non-finite UVs read a texel, never NaN.
        let nan = [Vec2::NAN; 3];
        assert!(p.footprint_mean(tex, nan).iter().all(|v| v.is_finite()));
    }

    #[test]
    fn barycentric_round_trips() {
        let v = [DVec3::ZERO, DVec3::X * 2.0, DVec3::new(0.0, 3.0, 1.0)];
        let p = v[0] * 0.2 + v[1] * 0.3 + v[2] * 0.5;
        let b = barycentric(v, p);
        assert!(
            (b[0] - 0.2).abs() < 1e-12 && (b[1] - 0.3).abs() < 1e-12,
            "{b:?}"
        );
    }
}
