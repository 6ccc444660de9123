//! Screen-space ambient occlusion: a hemisphere kernel, per-pixel rotation, range check, and a
//! 4×4 blur. It darkens only the indirect (light-map) term of the lighting.

use crate::RenderError;
use crate::gbuffer::GBuffer;
use crate::graph::{RenderGraph, TextureDesc, TextureHandle};
use crate::pass::{FullscreenEffect, Slot, UNFILTERABLE};
use crate::scene::GpuScene;

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
    ssao: FullscreenEffect,
    blur: FullscreenEffect,
}

impl SsaoPipeline {
    /// Declares the bindings; the pipelines compile on first use.
    pub fn new(device: &wgpu::Device) -> Self {
        // Depth bound as unfilterable float, which every backend (GL's GLSL included) loads.
        let depth = Slot::Texture(UNFILTERABLE);
        let tex = Slot::Texture(UNFILTERABLE);
        Self {
            ssao: FullscreenEffect::new(
                device,
                "ssao",
                shader_source(),
                &[Slot::Uniform, depth, tex, Slot::Uniform],
            ),
            blur: FullscreenEffect::new(device, "ssao_blur", blur_shader_source(), &[tex]),
        }
    }
}

/// Adds the SSAO and blur passes; returns the blurred AO (R8Unorm, 1 = unoccluded).
pub fn ssao_pass(
    graph: &mut RenderGraph,
    gbuffer: &GBuffer,
    scene: &GpuScene,
    settings: &Ssao,
    pipeline: &SsaoPipeline,
) -> Result<TextureHandle, RenderError> {
    let d = graph.desc(gbuffer.depth);
    let raw = graph.create("ssao_raw", TextureDesc::new(d.width, d.height, AO_FORMAT));
    let out = graph.create("ssao", TextureDesc::new(d.width, d.height, AO_FORMAT));
    let mut kernel = [[0.0f32; 4]; 64];
    for (k, v) in kernel.iter_mut().zip(settings.kernel()) {
        *k = v;
    }
    let uniform = SsaoUniform {
        kernel,
        params: [
            settings.radius,
            settings.bias,
            settings.intensity,
            settings.samples.clamp(1, MAX_SAMPLES) as f32,
        ],
    };
    pipeline
        .ssao
        .pass(graph, "ssao_pass")
        .buffer(&scene.camera)
        .read(gbuffer.depth)
        .read(gbuffer.normal)
        .uniform(bytemuck::bytes_of(&uniform))
        .draw("ssao_fs", raw)?;
    pipeline
        .blur
        .pass(graph, "ssao_blur_pass")
        .read(raw)
        .draw("ssao_blur_fs", out)?;
    Ok(out)
}
