//! Bloom: the Jimenez 2014 mip chain (default) or the lecture's bright pass plus repeated
//! separable Gaussian, composited energy-conserving (default) or additive.

use std::sync::Arc;

use radiant_render::graph::{RenderGraph, TextureDesc, TextureHandle};
use radiant_render::pass::{FullscreenEffect, Slot};
use radiant_render::{COMMON_WGSL, RenderError};
use wgpu::util::DeviceExt;

use crate::blur::{BlurPipeline, GaussianBlur, blur_1d_pass};

/// The shader source (with the shared prelude).
pub fn shader_source() -> String {
    format!("{COMMON_WGSL}{}", include_str!("bloom.wgsl"))
}

/// The bloom buffers' format.
pub const BLOOM_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
/// The most mip levels.
pub const MAX_MIPS: u32 = 8;

/// How the blur is built.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BloomMethod {
    /// 13-tap downsample / tent upsample mip chain (Jimenez 2014) (default).
    #[default]
    MipChain,
    /// The lecture's: half-resolution bright pass, then `gaussian_rounds` of a separable 9-tap
    /// Gaussian.
    Gaussian,
}

/// How the blurred light returns to the image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BloomComposite {
    /// Replace the above-threshold part of each pixel by its blurred version: no energy is
    /// added (default).
    #[default]
    EnergyConserving,
    /// Add the blurred part on top (the lecture's version; brightens the image).
    Additive,
}

/// Bloom. Present → on; absent → its passes and textures are culled.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "bevy_ecs", derive(bevy_ecs::component::Component))]
pub struct Bloom {
    /// Mip chain or the lecture's Gaussian (default: mip chain).
    pub method: BloomMethod,
    /// Energy-conserving or additive (default: energy-conserving).
    pub composite: BloomComposite,
    /// Fraction of the thresholded light that is spread; range [0, 1] (default: 0.15).
    pub intensity: f32,
    /// Radiance (max channel of the HDR image, before exposure: tone mapping applies that
    /// afterwards) where bloom starts; 0 blooms everything; range [0, ∞) (default: 1).
    pub threshold: f32,
    /// Softness of the threshold as a fraction of it; range [0, 1] (default: 0.5).
    pub knee: f32,
    /// Mip levels of the chain, each half the previous; range 1..=8 (default: 6).
    pub mip_count: u32,
    /// How much of the wider levels passes to the finer ones when upsampling; range [0, 1]
    /// (default: 0.7).
    pub scatter: f32,
    /// Rounds of the 9-tap Gaussian for [`BloomMethod::Gaussian`]; range 1..=8 (default: 3).
    pub gaussian_rounds: u32,
}

impl Default for Bloom {
    fn default() -> Self {
        Self::NATURAL
    }
}

impl Bloom {
    /// The default: Jimenez's mip chain, energy-conserving, a soft knee at 1.
    pub const NATURAL: Bloom = Bloom {
        method: BloomMethod::MipChain,
        composite: BloomComposite::EnergyConserving,
        intensity: 0.15,
        threshold: 1.0,
        knee: 0.5,
        mip_count: 6,
        scatter: 0.7,
        gaussian_rounds: 3,
    };

    /// The lecture's version: bright pass, repeated 9-tap Gaussian, additive.
    pub const LECTURE: Bloom = Bloom {
        method: BloomMethod::Gaussian,
        composite: BloomComposite::Additive,
        intensity: 0.5,
        threshold: 1.0,
        knee: 0.0,
        mip_count: 1,
        scatter: 0.7,
        gaussian_rounds: 3,
    };

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), RenderError> {
        let bad = |field, value: f64, range| {
            Err(RenderError::InvalidSetting {
                field,
                value,
                range,
            })
        };
        let unit = |x: f32| x.is_finite() && (0.0..=1.0).contains(&x);
        if !unit(self.intensity) {
            return bad("bloom.intensity", self.intensity.into(), "[0, 1]");
        }
        if !(self.threshold.is_finite() && self.threshold >= 0.0) {
            return bad("bloom.threshold", self.threshold.into(), "[0, inf)");
        }
        if !unit(self.knee) {
            return bad("bloom.knee", self.knee.into(), "[0, 1]");
        }
        if !unit(self.scatter) {
            return bad("bloom.scatter", self.scatter.into(), "[0, 1]");
        }
        if !(1..=MAX_MIPS).contains(&self.mip_count) {
            return bad("bloom.mip_count", self.mip_count.into(), "1..=8");
        }
        if !(1..=8).contains(&self.gaussian_rounds) {
            return bad(
                "bloom.gaussian_rounds",
                self.gaussian_rounds.into(),
                "1..=8",
            );
        }
        Ok(())
    }
}

/// The bloom pipelines: one effect whose entry points are the stages, all writing
/// [`BLOOM_FORMAT`], and the blur for the lecture's method.
pub struct BloomPipeline {
    effect: FullscreenEffect,
    sampler: wgpu::Sampler,
    blur: Arc<BlurPipeline>,
}

impl BloomPipeline {
    /// Declares the bindings (two textures, a bilinear sampler, the settings).
    pub fn new(device: &wgpu::Device, blur: Arc<BlurPipeline>) -> Self {
        let float = Slot::Texture(wgpu::TextureSampleType::Float { filterable: true });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("bloom_sampler"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let filtering = Slot::Sampler(wgpu::SamplerBindingType::Filtering);
        Self {
            effect: FullscreenEffect::new(
                device,
                "bloom",
                shader_source(),
                &[float, float, filtering, Slot::Uniform],
            ),
            sampler,
            blur,
        }
    }
}

const DOWN: [&str; 8] = [
    "bloom_downsample_0",
    "bloom_downsample_1",
    "bloom_downsample_2",
    "bloom_downsample_3",
    "bloom_downsample_4",
    "bloom_downsample_5",
    "bloom_downsample_6",
    "bloom_downsample_7",
];
const UP: [&str; 8] = [
    "bloom_upsample_0",
    "bloom_upsample_1",
    "bloom_upsample_2",
    "bloom_upsample_3",
    "bloom_upsample_4",
    "bloom_upsample_5",
    "bloom_upsample_6",
    "bloom_upsample_7",
];
const GAUSS_H: [&str; 8] = [
    "bloom_gaussian_h_0",
    "bloom_gaussian_h_1",
    "bloom_gaussian_h_2",
    "bloom_gaussian_h_3",
    "bloom_gaussian_h_4",
    "bloom_gaussian_h_5",
    "bloom_gaussian_h_6",
    "bloom_gaussian_h_7",
];
const GAUSS_V: [&str; 8] = [
    "bloom_gaussian_v_0",
    "bloom_gaussian_v_1",
    "bloom_gaussian_v_2",
    "bloom_gaussian_v_3",
    "bloom_gaussian_v_4",
    "bloom_gaussian_v_5",
    "bloom_gaussian_v_6",
    "bloom_gaussian_v_7",
];

/// One bloom frame's passes: the pipeline, the shared settings and the half-size description.
struct Stages<'a> {
    pipeline: &'a BloomPipeline,
    uniform: wgpu::Buffer,
    full: TextureDesc,
}

impl Stages<'_> {
    /// `(width, height) >> (k + 1)` in the bloom format.
    fn half(&self, k: u32) -> TextureDesc {
        TextureDesc::new(
            (self.full.width >> (k + 1)).max(1),
            (self.full.height >> (k + 1)).max(1),
            BLOOM_FORMAT,
        )
    }

    /// Pass `name` of fragment entry `entry` reading `a` (and `b`) into a new texture `texture`.
    fn stage_pass(
        &self,
        graph: &mut RenderGraph,
        (name, entry, texture): (&'static str, &'static str, &'static str),
        (a, b): (TextureHandle, Option<TextureHandle>),
        out: TextureDesc,
    ) -> Result<TextureHandle, RenderError> {
        let t = graph.create(texture, out);
        self.pipeline
            .effect
            .pass(graph, name)
            .read(a)
            .read(b.unwrap_or(a))
            .sampler(&self.pipeline.sampler)
            .buffer(&self.uniform)
            .draw(entry, t)?;
        Ok(t)
    }

    /// Jimenez's chain: `n` 13-tap downsamples, then tent upsamples back to half size.
    fn mip_chain_pass(
        &self,
        graph: &mut RenderGraph,
        hdr: TextureHandle,
        n: u32,
    ) -> Result<TextureHandle, RenderError> {
        let mut down: Vec<TextureHandle> = Vec::new();
        for k in 0..n {
            let (entry, src) = match down.last() {
                None => ("bloom_downsample_first_fs", hdr),
                Some(&prev) => ("bloom_downsample_fs", prev),
            };
            let name = (DOWN[k as usize], entry, "bloom_mip");
            let t = self.stage_pass(graph, name, (src, None), self.half(k))?;
            down.push(t);
        }
        let mut wider = down[n as usize - 1];
        for k in (0..n - 1).rev() {
            let own = down[k as usize];
            let name = (UP[k as usize], "bloom_upsample_fs", "bloom_up");
            wider = self.stage_pass(graph, name, (own, Some(wider)), self.half(k))?;
        }
        Ok(wider)
    }

    /// The lecture's: a half-size bright pass, then `rounds` of a separable 9-tap Gaussian.
    fn gaussian_pass(
        &self,
        graph: &mut RenderGraph,
        hdr: TextureHandle,
        rounds: usize,
    ) -> Result<TextureHandle, RenderError> {
        let half = self.half(0);
        let name = ("bloom_bright_pass", "bloom_bright_fs", "bloom_bright");
        let mut cur = self.stage_pass(graph, name, (hdr, None), half)?;
        let weights = GaussianBlur {
            sigma: 2.0,
            taps: 9,
            passes: 1,
        }
        .weights();
        let blur = &self.pipeline.blur;
        for r in 0..rounds {
            let h = graph.create("bloom_gaussian_h", half);
            blur_1d_pass(graph, GAUSS_H[r], (cur, h), &weights, [1, 0], blur)?;
            let v = graph.create("bloom_gaussian_v", half);
            blur_1d_pass(graph, GAUSS_V[r], (h, v), &weights, [0, 1], blur)?;
            cur = v;
        }
        Ok(cur)
    }
}

/// Adds the bloom passes on `hdr`; returns the composited HDR image.
pub fn bloom_pass(
    graph: &mut RenderGraph,
    hdr: TextureHandle,
    settings: &Bloom,
    pipeline: &BloomPipeline,
) -> Result<TextureHandle, RenderError> {
    let uniform = [
        settings.threshold.to_bits(),
        settings.knee.to_bits(),
        settings.intensity.to_bits(),
        settings.scatter.to_bits(),
        u32::from(settings.composite == BloomComposite::Additive),
        0,
        0,
        0,
    ];
    let uniform = pipeline
        .effect
        .device()
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bloom_settings"),
            contents: bytemuck::cast_slice(&uniform),
            usage: wgpu::BufferUsages::UNIFORM,
        });
    let full = graph.desc(hdr);
    let stages = Stages {
        pipeline,
        uniform,
        full,
    };
    let blurred = match settings.method {
        BloomMethod::MipChain => {
            stages.mip_chain_pass(graph, hdr, settings.mip_count.clamp(1, MAX_MIPS))?
        }
        BloomMethod::Gaussian => {
            stages.gaussian_pass(graph, hdr, settings.gaussian_rounds.clamp(1, 8) as usize)?
        }
    };
    let out = TextureDesc::new(full.width, full.height, BLOOM_FORMAT);
    let name = (
        "bloom_composite_pass",
        "bloom_composite_fs",
        "bloom_composite",
    );
    stages.stage_pass(graph, name, (hdr, Some(blurred)), out)
}
