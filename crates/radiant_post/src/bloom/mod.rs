//! Bloom: the Jimenez 2014 mip chain (default) or the lecture's bright pass plus repeated
//! separable Gaussian, composited energy-conserving (default) or additive.

use std::sync::Arc;

use radiant_render::graph::{RenderGraph, TextureDesc, TextureHandle};
use radiant_render::util::{
    buffer_entry, fullscreen_pipeline, texture_entry, uniform_entry, view_entry,
};
use radiant_render::{COMMON_WGSL, RenderError};
use wgpu::util::DeviceExt;

use crate::blur::{BlurPipeline, GaussianBlur, blur_1d};

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

/// The bloom pipelines.
pub struct BloomPipeline {
    layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
    down_first: wgpu::RenderPipeline,
    down: wgpu::RenderPipeline,
    up: wgpu::RenderPipeline,
    bright: wgpu::RenderPipeline,
    composite: wgpu::RenderPipeline,
    blur: Arc<BlurPipeline>,
}

impl BloomPipeline {
    /// Compiles the pipelines (all render to Rgba16Float).
    pub fn new(device: &wgpu::Device, blur: Arc<BlurPipeline>) -> Self {
        let float = wgpu::TextureSampleType::Float { filterable: true };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("bloom_layout"),
            entries: &[
                texture_entry(0, float),
                texture_entry(1, float),
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                uniform_entry(3, wgpu::ShaderStages::FRAGMENT),
            ],
        });
        let src = shader_source();
        let make = |label, entry| {
            fullscreen_pipeline(device, label, &src, entry, &layout, BLOOM_FORMAT, None)
        };
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("bloom_sampler"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        Self {
            down_first: make(
                "bloom_downsample_first_pipeline",
                "bloom_downsample_first_fs",
            ),
            down: make("bloom_downsample_pipeline", "bloom_downsample_fs"),
            up: make("bloom_upsample_pipeline", "bloom_upsample_fs"),
            bright: make("bloom_bright_pipeline", "bloom_bright_fs"),
            composite: make("bloom_composite_pipeline", "bloom_composite_fs"),
            layout,
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

#[derive(Clone, Copy)]
enum Stage {
    DownFirst,
    Down,
    Up,
    Bright,
    Composite,
}

/// Adds one bloom pass reading `a` (and `b`) into `out`.
#[expect(
    clippy::too_many_arguments,
    reason = "a pass over explicit graph handles"
)]
fn bloom_stage(
    graph: &mut RenderGraph,
    name: &'static str,
    stage: Stage,
    a: TextureHandle,
    b: Option<TextureHandle>,
    out: TextureHandle,
    uniform: &Arc<wgpu::Buffer>,
    pipeline: &Arc<BloomPipeline>,
) {
    let reads: Vec<TextureHandle> = std::iter::once(a).chain(b).collect();
    let (p, u) = (pipeline.clone(), uniform.clone());
    graph.add_pass(name, &reads, &[out], move |ctx| {
        let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("bloom_bind_group"),
            layout: &p.layout,
            entries: &[
                view_entry(0, ctx.view(a)),
                view_entry(1, ctx.view(b.unwrap_or(a))),
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(&p.sampler),
                },
                buffer_entry(3, &u),
            ],
        });
        let rp = match stage {
            Stage::DownFirst => &p.down_first,
            Stage::Down => &p.down,
            Stage::Up => &p.up,
            Stage::Bright => &p.bright,
            Stage::Composite => &p.composite,
        };
        radiant_render::util::draw_fullscreen(ctx.encoder, name, ctx.view(out), rp, &bind);
    });
}

/// Adds the bloom passes on `hdr`; returns the composited HDR image.
pub fn bloom_pass(
    graph: &mut RenderGraph,
    hdr: TextureHandle,
    settings: &Bloom,
    pipeline: &Arc<BloomPipeline>,
    device: &wgpu::Device,
) -> TextureHandle {
    let d = graph.desc(hdr);
    let half = |k: u32| {
        TextureDesc::new(
            (d.width >> (k + 1)).max(1),
            (d.height >> (k + 1)).max(1),
            BLOOM_FORMAT,
        )
    };
    let uniform = Arc::new(
        device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bloom_settings"),
            contents: bytemuck::cast_slice(&[
                settings.threshold.to_bits(),
                settings.knee.to_bits(),
                settings.intensity.to_bits(),
                settings.scatter.to_bits(),
                u32::from(settings.composite == BloomComposite::Additive),
                0,
                0,
                0,
            ]),
            usage: wgpu::BufferUsages::UNIFORM,
        }),
    );
    let blurred = match settings.method {
        BloomMethod::MipChain => {
            let n = settings.mip_count.clamp(1, MAX_MIPS);
            let mut down = Vec::new();
            for k in 0..n {
                let t = graph.create("bloom_mip", half(k));
                let (stage, src) = if k == 0 {
                    (Stage::DownFirst, hdr)
                } else {
                    (Stage::Down, down[k as usize - 1])
                };
                bloom_stage(
                    graph,
                    DOWN[k as usize],
                    stage,
                    src,
                    None,
                    t,
                    &uniform,
                    pipeline,
                );
                down.push(t);
            }
            let mut wider = down[n as usize - 1];
            for k in (0..n - 1).rev() {
                let t = graph.create("bloom_up", half(k));
                let own = down[k as usize];
                bloom_stage(
                    graph,
                    UP[k as usize],
                    Stage::Up,
                    own,
                    Some(wider),
                    t,
                    &uniform,
                    pipeline,
                );
                wider = t;
            }
            wider
        }
        BloomMethod::Gaussian => {
            let bright = graph.create("bloom_bright", half(0));
            bloom_stage(
                graph,
                "bloom_bright_pass",
                Stage::Bright,
                hdr,
                None,
                bright,
                &uniform,
                pipeline,
            );
            let weights = GaussianBlur {
                sigma: 2.0,
                taps: 9,
                passes: 1,
            }
            .weights();
            let mut cur = bright;
            for r in 0..settings.gaussian_rounds.clamp(1, 8) as usize {
                let h = graph.create("bloom_gaussian_h", half(0));
                blur_1d(
                    graph,
                    GAUSS_H[r],
                    cur,
                    h,
                    &weights,
                    [1, 0],
                    &pipeline.blur,
                    device,
                );
                let v = graph.create("bloom_gaussian_v", half(0));
                blur_1d(
                    graph,
                    GAUSS_V[r],
                    h,
                    v,
                    &weights,
                    [0, 1],
                    &pipeline.blur,
                    device,
                );
                cur = v;
            }
            cur
        }
    };
    let out = graph.create(
        "bloom_composite",
        TextureDesc::new(d.width, d.height, BLOOM_FORMAT),
    );
    bloom_stage(
        graph,
        "bloom_composite_pass",
        Stage::Composite,
        hdr,
        Some(blurred),
        out,
        &uniform,
        pipeline,
    );
    out
}
