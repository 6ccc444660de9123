//! Materials as the renderer draws them: base-colour textures (sRGB, a full mip chain made on
//! upload, anisotropic filtering, glTF wrap modes), alpha-mask cut-offs and double-sided faces,
//! and one indexed draw per material.
//!
//! A texture is uploaded once and kept in a [`TextureCache`] for as long as the scene uses its
//! pixels: a new light map re-uploads the scene, not its textures.

use std::collections::HashMap;
use std::sync::Arc;

use radiant_scene::texture::{Sampler, Wrap};
use wgpu::util::DeviceExt;

/// An RGBA8 texture, colour sRGB-encoded, alpha linear; row-major from the top-left texel.
#[derive(Clone, PartialEq)]
pub struct RenderTexture {
    /// For labels and reports.
    pub name: String,
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// `width × height × 4` bytes. Shared with the scene's image: the cache keys on it.
    pub pixels: Arc<[u8]>,
}

impl std::fmt::Debug for RenderTexture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "RenderTexture({:?}, {}×{})",
            self.name, self.width, self.height
        )
    }
}

/// How one group of triangles is shaded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderMaterial {
    /// The base-colour texture (index into `RenderScene::textures`), multiplied with the
    /// vertex albedo; `None` for a plain colour.
    pub texture: Option<u32>,
    /// Wrap modes and magnification filter of the texture.
    pub sampler: Sampler,
    /// The base colour factor's alpha, multiplied with the texture's.
    pub alpha_factor: f32,
    /// Fragments whose alpha is below this are discarded (glTF MASK); `None`: opaque.
    pub alpha_cutoff: Option<f32>,
    /// Back faces are discarded: the scene draws the back as a separate, rewound twin
    /// (glTF `doubleSided`, as the importer makes it) with its own light.
    pub cull_back: bool,
}

impl Default for RenderMaterial {
    fn default() -> Self {
        RenderMaterial {
            texture: None,
            sampler: Sampler::default(),
            alpha_factor: 1.0,
            alpha_cutoff: None,
            cull_back: false,
        }
    }
}

/// A run of `count` indices from `first`, drawn with one material, once per instance in
/// `first_instance..first_instance + instance_count` (of `RenderScene::instances`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DrawRange {
    /// Index into `RenderScene::materials`.
    pub material: u32,
    /// First index.
    pub first: u32,
    /// Number of indices.
    pub count: u32,
    /// First instance.
    pub first_instance: u32,
    /// Number of instances.
    pub instance_count: u32,
}

impl DrawRange {
    /// Indices `first..first + count` with `material`, drawn once (instance 0, the identity).
    pub fn new(material: u32, first: u32, count: u32) -> DrawRange {
        DrawRange {
            material,
            first,
            count,
            first_instance: 0,
            instance_count: 1,
        }
    }
}

/// A material's constants as the G-buffer shader sees them.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct MaterialUniform {
    /// Discard below this alpha (−1: never).
    pub alpha_cutoff: f32,
    /// Factor alpha.
    pub alpha_factor: f32,
    /// 1: discard back faces.
    pub cull_back: u32,
    pad: u32,
}

/// A draw on the GPU: its material's texture, sampler and constants, its vertex range (in the
/// uploaded vertex buffer) and its instances.
pub struct GpuMaterial {
    /// The base-colour texture (1 × 1 white without one).
    pub texture: wgpu::TextureView,
    /// Its sampler.
    pub sampler: wgpu::Sampler,
    /// The material's uniform buffer (`MaterialUniform`).
    pub uniform: wgpu::Buffer,
    /// First vertex.
    pub first: u32,
    /// Number of vertices.
    pub count: u32,
    /// Instances.
    pub instances: std::ops::Range<u32>,
}

/// One uploaded texture.
struct Cached {
    /// Held so the address the cache keys on stays this buffer's.
    _pixels: Arc<[u8]>,
    view: wgpu::TextureView,
    /// Used by the latest upload.
    used: bool,
}

/// Uploaded textures, keyed by their pixel buffer; survives scene uploads.
#[derive(Default)]
pub struct TextureCache {
    textures: HashMap<(usize, usize), Cached>,
    white: Option<wgpu::TextureView>,
    samplers: HashMap<(u8, u8, bool), wgpu::Sampler>,
    uploads: usize,
}

impl TextureCache {
    /// An empty cache.
    pub fn new() -> Self {
        Self::default()
    }

    /// How many textures were uploaded so far (a cached one is not counted again).
    pub fn uploads(&self) -> usize {
        self.uploads
    }

    /// How many textures it holds.
    pub fn len(&self) -> usize {
        self.textures.len()
    }

    /// Whether it holds none.
    pub fn is_empty(&self) -> bool {
        self.textures.is_empty()
    }

    fn white(&mut self, device: &wgpu::Device, queue: &wgpu::Queue) -> wgpu::TextureView {
        self.white
            .get_or_insert_with(|| {
                crate::util::sampled_texture(device, queue, "white", (1, 1, 1), SRGB, &[255; 4])
            })
            .clone()
    }

    fn texture(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        t: &RenderTexture,
    ) -> wgpu::TextureView {
        let key = (t.pixels.as_ptr() as usize, t.pixels.len());
        if let Some(entry) = self.textures.get_mut(&key) {
            entry.used = true;
            return entry.view.clone();
        }
        let max = device.limits().max_texture_dimension_2d;
        let levels = mip_chain(t.width, t.height, &t.pixels);
        // Levels larger than the adapter allows are dropped (the image is drawn from the first
        // that fits).
        let first = levels
            .iter()
            .position(|(w, h, _)| *w <= max && *h <= max)
            .unwrap_or(levels.len() - 1);
        let (w, h) = (levels[first].0, levels[first].1);
        let data: Vec<u8> = levels[first..]
            .iter()
            .flat_map(|l| l.2.iter().copied())
            .collect();
        let mips = (levels.len() - first) as u32;
        let view = crate::util::sampled_texture(device, queue, &t.name, (w, h, mips), SRGB, &data);
        self.uploads += 1;
        self.textures.insert(
            key,
            Cached {
                _pixels: t.pixels.clone(),
                view: view.clone(),
                used: true,
            },
        );
        view
    }

    fn sampler(&mut self, device: &wgpu::Device, s: Sampler) -> wgpu::Sampler {
        let code = |w: Wrap| match w {
            Wrap::Repeat => 0u8,
            Wrap::MirroredRepeat => 1,
            Wrap::ClampToEdge => 2,
        };
        let mode = |w: Wrap| match w {
            Wrap::Repeat => wgpu::AddressMode::Repeat,
            Wrap::MirroredRepeat => wgpu::AddressMode::MirrorRepeat,
            Wrap::ClampToEdge => wgpu::AddressMode::ClampToEdge,
        };
        self.samplers
            .entry((code(s.wrap_s), code(s.wrap_t), s.nearest))
            .or_insert_with(|| {
                device.create_sampler(&wgpu::SamplerDescriptor {
                    label: Some("material_sampler"),
                    address_mode_u: mode(s.wrap_s),
                    address_mode_v: mode(s.wrap_t),
                    mag_filter: if s.nearest {
                        wgpu::FilterMode::Nearest
                    } else {
                        wgpu::FilterMode::Linear
                    },
                    min_filter: wgpu::FilterMode::Linear,
                    mipmap_filter: wgpu::MipmapFilterMode::Linear,
                    // Anisotropy needs every filter linear; adapters without it clamp to 1.
                    anisotropy_clamp: if s.nearest { 1 } else { 16 },
                    ..Default::default()
                })
            })
            .clone()
    }

    /// Uploads what `materials` need (cached textures are reused) and drops textures no
    /// material uses any more.
    pub(crate) fn upload(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        textures: &[RenderTexture],
        materials: &[RenderMaterial],
        draws: &[DrawRange],
    ) -> Vec<GpuMaterial> {
        for e in self.textures.values_mut() {
            e.used = false;
        }
        let mut out = Vec::with_capacity(draws.len());
        for d in draws {
            let m = materials
                .get(d.material as usize)
                .copied()
                .unwrap_or_default();
            let texture = match m.texture.and_then(|i| textures.get(i as usize)) {
                Some(t) => self.texture(device, queue, t),
                None => self.white(device, queue),
            };
            let uniform = MaterialUniform {
                alpha_cutoff: m.alpha_cutoff.unwrap_or(-1.0),
                alpha_factor: m.alpha_factor,
                cull_back: u32::from(m.cull_back),
                pad: 0,
            };
            out.push(GpuMaterial {
                texture,
                sampler: self.sampler(device, m.sampler),
                uniform: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("material_uniform"),
                    contents: bytemuck::bytes_of(&uniform),
                    usage: wgpu::BufferUsages::UNIFORM,
                }),
                first: d.first,
                count: d.count,
                instances: d.first_instance..d.first_instance + d.instance_count,
            });
        }
        self.textures.retain(|_, e| e.used);
        out
    }
}

/// Colour textures: 8-bit sRGB, decoded to linear by the sampler.
const SRGB: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;

/// The full mip chain of an sRGB RGBA8 image, down to 1 × 1: each level a 2 × 2 box filter of
/// the one above in linear light (alpha averaged as is). Odd sides repeat their last texel.
pub fn mip_chain(width: u32, height: u32, pixels: &[u8]) -> Vec<(u32, u32, Vec<u8>)> {
    static DECODE: std::sync::OnceLock<[f32; 256]> = std::sync::OnceLock::new();
    static ENCODE: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    const STEPS: usize = 16384;
    let decode = DECODE.get_or_init(|| {
        std::array::from_fn(|i| radiant_color::srgb_to_linear(i as f64 / 255.0) as f32)
    });
    let encode = ENCODE.get_or_init(|| {
        (0..=STEPS)
            .map(|i| radiant_color::linear_to_srgb8(i as f64 / STEPS as f64))
            .collect()
    });
    let (width, height) = (width.max(1), height.max(1));
    let mut level = pixels.to_vec();
    level.resize((width * height * 4) as usize, 255);
    let mut out = vec![(width, height, level)];
    loop {
        let (w, h, src) = out.last().expect("level 0");
        let (w, h) = (*w as usize, *h as usize);
        if w == 1 && h == 1 {
            return out;
        }
        let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
        let mut dst = vec![0u8; nw * nh * 4];
        for y in 0..nh {
            for x in 0..nw {
                let mut sum = [0.0f32; 4];
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (sx, sy) = ((2 * x + dx).min(w - 1), (2 * y + dy).min(h - 1));
                    let p = &src[(sy * w + sx) * 4..][..4];
                    for c in 0..3 {
                        sum[c] += decode[p[c] as usize];
                    }
                    sum[3] += f32::from(p[3]);
                }
                let d = &mut dst[(y * nw + x) * 4..][..4];
                for c in 0..3 {
                    d[c] = encode[((sum[c] * 0.25 * STEPS as f32 + 0.5) as usize).min(STEPS)];
                }
                d[3] = (sum[3] * 0.25 + 0.5) as u8;
            }
        }
        out.push((nw as u32, nh as u32, dst));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mips_average_in_linear_light_down_to_one_texel() {
        // A 4 × 2 image: black and white columns, alpha 0 and 255.
        let mut px = Vec::new();
        for _y in 0..2 {
            for x in 0..4 {
                let v = if x % 2 == 0 { 0 } else { 255 };
                px.extend([v, v, v, v]);
            }
        }
        let chain = mip_chain(4, 2, &px);
        let sizes: Vec<(u32, u32)> = chain.iter().map(|l| (l.0, l.1)).collect();
        assert_eq!(sizes, vec![(4, 2), (2, 1), (1, 1)]);
        // Linear 0.5 is sRGB 188, not 128.
        let last = &chain[2].2;
        assert_eq!(last[0], radiant_color::linear_to_srgb8(0.5));
        assert!((i32::from(last[3]) - 128).abs() <= 1, "alpha {}", last[3]);
    }
}
