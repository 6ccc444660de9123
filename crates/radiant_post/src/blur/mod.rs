//! Separable Gaussian blur as a post node (sigma, taps, passes).

use radiant_render::graph::{RenderGraph, TextureDesc, TextureHandle};
use radiant_render::pass::{FullscreenEffect, Slot, UNFILTERABLE};
use radiant_render::{COMMON_WGSL, RenderError};

/// The shader source (with the shared prelude).
pub fn shader_source() -> String {
    format!("{COMMON_WGSL}{}", include_str!("blur.wgsl"))
}

/// The most taps a 1D kernel may have.
pub const MAX_TAPS: u32 = 63;

/// A separable Gaussian blur of the final image. Present → on.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "bevy_ecs", derive(bevy_ecs::component::Component))]
pub struct GaussianBlur {
    /// Standard deviation in pixels; range (0, 32] (default: 2).
    pub sigma: f32,
    /// Taps of the 1D kernel, odd; range 1..=63 (default: 9).
    pub taps: u32,
    /// Horizontal + vertical rounds; range 1..=8 (default: 1). `k` rounds equal one blur of
    /// sigma `σ√k` (for kernels wide enough not to truncate).
    pub passes: u32,
}

impl Default for GaussianBlur {
    fn default() -> Self {
        Self {
            sigma: 2.0,
            taps: 9,
            passes: 1,
        }
    }
}

impl GaussianBlur {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), RenderError> {
        let bad = |field, value: f64, range| {
            Err(RenderError::InvalidSetting {
                field,
                value,
                range,
            })
        };
        if !(self.sigma.is_finite() && self.sigma > 0.0 && self.sigma <= 32.0) {
            return bad("blur.sigma", self.sigma.into(), "(0, 32]");
        }
        if self.taps.is_multiple_of(2) || !(1..=MAX_TAPS).contains(&self.taps) {
            return bad("blur.taps", self.taps.into(), "odd, 1..=63");
        }
        if !(1..=8).contains(&self.passes) {
            return bad("blur.passes", self.passes.into(), "1..=8");
        }
        Ok(())
    }

    /// The normalised 1D weights for offsets `0..=radius` (the kernel is symmetric): sampled
    /// Gaussian, accumulated in f64, summing to 1 over `-radius..=radius`.
    pub fn weights(&self) -> Vec<f32> {
        let r = (self.taps.clamp(1, MAX_TAPS) / 2) as i32;
        let s = f64::from(self.sigma.max(1e-3));
        let raw: Vec<f64> = (0..=r)
            .map(|i| (-f64::from(i * i) / (2.0 * s * s)).exp())
            .collect();
        let total = raw[0] + 2.0 * raw[1..].iter().sum::<f64>();
        raw.iter().map(|w| (w / total) as f32).collect()
    }
}

/// The blur pipelines (one per format).
pub struct BlurPipeline(FullscreenEffect);

impl BlurPipeline {
    /// Declares the bindings; pipelines compile on first use per format.
    pub fn new(device: &wgpu::Device) -> Self {
        Self(FullscreenEffect::new(
            device,
            "blur",
            shader_source(),
            &[Slot::Texture(UNFILTERABLE), Slot::Uniform],
        ))
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BlurUniform {
    weights: [f32; 64],
    params: [i32; 4],
}

const NAMES_H: [&str; 8] = [
    "blur_h_pass_0",
    "blur_h_pass_1",
    "blur_h_pass_2",
    "blur_h_pass_3",
    "blur_h_pass_4",
    "blur_h_pass_5",
    "blur_h_pass_6",
    "blur_h_pass_7",
];
const NAMES_V: [&str; 8] = [
    "blur_v_pass_0",
    "blur_v_pass_1",
    "blur_v_pass_2",
    "blur_v_pass_3",
    "blur_v_pass_4",
    "blur_v_pass_5",
    "blur_v_pass_6",
    "blur_v_pass_7",
];

/// One 1D blur pass from `input` into `output` along `dir`.
pub fn blur_1d_pass(
    graph: &mut RenderGraph,
    name: &'static str,
    (input, output): (TextureHandle, TextureHandle),
    weights: &[f32],
    dir: [i32; 2],
    pipeline: &BlurPipeline,
) -> Result<(), RenderError> {
    let mut w = [0.0f32; 64];
    let n = weights.len().min(64);
    w[..n].copy_from_slice(&weights[..n]);
    let uniform = BlurUniform {
        weights: w,
        params: [n as i32 - 1, dir[0], dir[1], 0],
    };
    pipeline
        .0
        .pass(graph, name)
        .read(input)
        .uniform(bytemuck::bytes_of(&uniform))
        .draw("blur_fs", output)
}

/// Adds the blur passes; writes into `output` if given, else a new texture like `input`.
pub fn blur_pass(
    graph: &mut RenderGraph,
    input: TextureHandle,
    settings: &GaussianBlur,
    output: Option<TextureHandle>,
    pipeline: &BlurPipeline,
) -> Result<TextureHandle, RenderError> {
    let desc = graph.desc(input);
    let scratch = TextureDesc::new(desc.width, desc.height, desc.format);
    let weights = settings.weights();
    let passes = settings.passes.clamp(1, 8) as usize;
    let mut current = input;
    for round in 0..passes {
        let h = graph.create("blur_h", scratch);
        blur_1d_pass(
            graph,
            NAMES_H[round],
            (current, h),
            &weights,
            [1, 0],
            pipeline,
        )?;
        let last = round + 1 == passes;
        let v = match output {
            Some(o) if last => o,
            _ => graph.create("blur_v", scratch),
        };
        blur_1d_pass(graph, NAMES_V[round], (h, v), &weights, [0, 1], pipeline)?;
        current = v;
    }
    Ok(current)
}
