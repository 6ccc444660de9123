//! Screen-space ambient occlusion: a hemisphere kernel, per-pixel rotation, range check, and a
//! 4×4 blur. It darkens only the indirect (light-map) term of the lighting.

use std::sync::Arc;

use wgpu::util::DeviceExt;

use crate::gbuffer::GBuffer;
use crate::graph::{RenderGraph, TextureDesc, TextureHandle};
use crate::scene::GpuScene;
use crate::util::{fullscreen_pipeline, texture_entry, uniform_entry};

/// The AO format.
pub const AO_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R8Unorm;
/// The largest kernel.
pub const MAX_SAMPLES: u32 = 64;

/// The SSAO shader source (with the shared prelude).
pub fn shader_source() -> String {
    format!("{}{}", crate::COMMON_WGSL, include_str!("ssao.wgsl"))
}

/// The SSAO blur shader source (with the shared prelude).
pub fn blur_shader_source() -> String {
    format!("{}{}", crate::COMMON_WGSL, include_str!("ssao_blur.wgsl"))
}

/// Screen-space ambient occlusion. Present → the passes run; absent → they are culled and the
/// lighting reads no AO.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "bevy_ecs", derive(bevy_ecs::component::Component))]
pub struct Ssao {
    /// Radius of the sampling hemisphere, in metres of view space; range (0, ∞)
    /// (default: 0.1, a fifth of the Cornell box's wall).
    pub radius: f32,
    /// Depth bias against self-occlusion, metres; range [0, radius) (default: 0.005).
    pub bias: f32,
    /// Exponent on the unoccluded fraction; 1 is physical-ish, higher darkens; range (0, 8]
    /// (default: 1).
    pub intensity: f32,
    /// Kernel samples per pixel; range 1..=64 (default: 16).
    pub samples: u32,
}

impl Default for Ssao {
    fn default() -> Self {
        Self {
            radius: 0.1,
            bias: 0.005,
            intensity: 1.0,
            samples: 16,
        }
    }
}

impl Ssao {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), crate::RenderError> {
        let bad = |field: &'static str, value: f64, range: &'static str| {
            Err(crate::RenderError::InvalidSetting {
                field,
                value,
                range,
            })
        };
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return bad("ssao.radius", self.radius.into(), "(0, inf)");
        }
        if !(self.bias.is_finite() && self.bias >= 0.0 && self.bias < self.radius) {
            return bad("ssao.bias", self.bias.into(), "[0, radius)");
        }
        if !(self.intensity.is_finite() && self.intensity > 0.0 && self.intensity <= 8.0) {
            return bad("ssao.intensity", self.intensity.into(), "(0, 8]");
        }
        if !(1..=MAX_SAMPLES).contains(&self.samples) {
            return bad("ssao.samples", self.samples.into(), "1..=64");
        }
        Ok(())
    }

    /// The hemisphere kernel: `samples` points with z ≥ 0, denser near the centre, from a fixed
    /// seed (the same image on every run).
    pub fn kernel(&self) -> Vec<[f32; 4]> {
        let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
        let mut next = || {
            // SplitMix64.
            state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
        };
        let n = self.samples.clamp(1, MAX_SAMPLES);
        (0..n)
            .map(|i| {
                let v = loop {
                    let v = glam::Vec3::new(next() * 2.0 - 1.0, next() * 2.0 - 1.0, next());
                    let l = v.length();
                    if l > 1e-3 && l <= 1.0 {
                        break v / l;
                    }
                };
                let s = i as f32 / n as f32;
                let v = v * next() * (0.1 + 0.9 * s * s);
                [v.x, v.y, v.z, 0.0]
            })
            .collect()
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SsaoUniform {
    kernel: [[f32; 4]; 64],
    params: [f32; 4],
}

/// The SSAO and blur pipelines.
pub struct SsaoPipeline {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::RenderPipeline,
    blur_layout: wgpu::BindGroupLayout,
    blur: wgpu::RenderPipeline,
}

impl SsaoPipeline {
    /// Compiles the pipelines.
    pub fn new(device: &wgpu::Device) -> Self {
        let float = wgpu::TextureSampleType::Float { filterable: false };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("ssao_layout"),
            entries: &[
                uniform_entry(0, wgpu::ShaderStages::FRAGMENT),
                texture_entry(1, wgpu::TextureSampleType::Depth),
                texture_entry(2, float),
                uniform_entry(3, wgpu::ShaderStages::FRAGMENT),
            ],
        });
        let blur_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("ssao_blur_layout"),
            entries: &[texture_entry(0, float)],
        });
        let pipeline = fullscreen_pipeline(
            device,
            "ssao_pipeline",
            &shader_source(),
            "ssao_fs",
            &layout,
            AO_FORMAT,
            None,
        );
        let blur = fullscreen_pipeline(
            device,
            "ssao_blur_pipeline",
            &blur_shader_source(),
            "ssao_blur_fs",
            &blur_layout,
            AO_FORMAT,
            None,
        );
        Self {
            layout,
            pipeline,
            blur_layout,
            blur,
        }
    }
}

/// Adds the SSAO and blur passes; returns the blurred AO (R8Unorm, 1 = unoccluded).
pub fn ssao_pass(
    graph: &mut RenderGraph,
    gbuffer: &GBuffer,
    settings: &Ssao,
    pipeline: Arc<SsaoPipeline>,
    scene: Arc<GpuScene>,
    device: &wgpu::Device,
) -> TextureHandle {
    let d = graph.desc(gbuffer.depth);
    let raw = graph.create("ssao_raw", TextureDesc::new(d.width, d.height, AO_FORMAT));
    let out = graph.create("ssao", TextureDesc::new(d.width, d.height, AO_FORMAT));
    let mut kernel = [[0.0f32; 4]; 64];
    for (k, v) in kernel.iter_mut().zip(settings.kernel()) {
        *k = v;
    }
    let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("ssao_settings"),
        contents: bytemuck::bytes_of(&SsaoUniform {
            kernel,
            params: [
                settings.radius,
                settings.bias,
                settings.intensity,
                settings.samples.clamp(1, MAX_SAMPLES) as f32,
            ],
        }),
        usage: wgpu::BufferUsages::UNIFORM,
    });
    let (depth, normal) = (gbuffer.depth, gbuffer.normal);
    let p = pipeline.clone();
    graph.add_pass("ssao_pass", &[depth, normal], &[raw], move |ctx| {
        let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("ssao_bind_group"),
            layout: &p.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: scene.camera.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(ctx.view(depth)),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(ctx.view(normal)),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: uniform.as_entire_binding(),
                },
            ],
        });
        crate::util::draw_fullscreen(ctx.encoder, "ssao_pass", ctx.view(raw), &p.pipeline, &bind);
    });
    graph.add_pass("ssao_blur_pass", &[raw], &[out], move |ctx| {
        let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("ssao_blur_bind_group"),
            layout: &pipeline.blur_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::TextureView(ctx.view(raw)),
            }],
        });
        crate::util::draw_fullscreen(
            ctx.encoder,
            "ssao_blur_pass",
            ctx.view(out),
            &pipeline.blur,
            &bind,
        );
    });
    out
}
