//! Tone mapping with exposure, into an sRGB (display-encoded) target.

use radiant_color::Tonemap;
use radiant_render::graph::{RenderGraph, TextureHandle};
use radiant_render::pass::{FullscreenEffect, Slot, UNFILTERABLE};
use radiant_render::{COMMON_WGSL, RenderError};

/// The shader source (with the shared prelude).
pub fn shader_source() -> String {
    format!("{COMMON_WGSL}{}", include_str!("tonemapping.wgsl"))
}

/// Tone mapping: always on (the target is 8-bit); `Tonemap::Clamp` is "none".
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "bevy_ecs", derive(bevy_ecs::component::Component))]
pub struct Tonemapping {
    /// The operator (default: ACES fitted).
    pub operator: Tonemap,
    /// Exposure in stops: radiance is multiplied by `2^exposure` first; range [-20, 20]
    /// (default: 0).
    pub exposure: f32,
}

impl Default for Tonemapping {
    fn default() -> Self {
        Self {
            operator: Tonemap::AcesFitted,
            exposure: 0.0,
        }
    }
}

impl Tonemapping {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), RenderError> {
        if !(self.exposure.is_finite() && (-20.0..=20.0).contains(&self.exposure)) {
            return Err(RenderError::InvalidSetting {
                field: "tonemapping.exposure",
                value: self.exposure.into(),
                range: "[-20, 20]",
            });
        }
        if let Tonemap::ExtendedReinhard { white } = self.operator
            && !(white.is_finite() && white > 0.0)
        {
            return Err(RenderError::InvalidSetting {
                field: "tonemapping.white",
                value: white,
                range: "(0, inf)",
            });
        }
        Ok(())
    }

    fn uniform(&self) -> [f32; 4] {
        let (op, white) = match self.operator {
            Tonemap::Clamp => (0, 1.0),
            Tonemap::Reinhard => (1, 1.0),
            Tonemap::ExtendedReinhard { white } => (2, white as f32),
            Tonemap::AcesFitted => (3, 1.0),
            Tonemap::AgX => (4, 1.0),
            Tonemap::PbrNeutral => (5, 1.0),
        };
        [f32::from_bits(op), self.exposure.exp2(), white, 0.0]
    }
}

/// The tone-mapping pipelines (one per target format).
pub struct TonemappingPipeline(FullscreenEffect);

impl TonemappingPipeline {
    /// Declares the bindings; pipelines compile on first use per format.
    pub fn new(device: &wgpu::Device) -> Self {
        Self(FullscreenEffect::new(
            device,
            "tonemapping",
            shader_source(),
            &[Slot::Texture(UNFILTERABLE), Slot::Uniform],
        ))
    }
}

/// Adds the tone-mapping pass from `hdr` into `target` (an sRGB format encodes on store);
/// returns `target`.
pub fn tonemapping_pass(
    graph: &mut RenderGraph,
    hdr: TextureHandle,
    target: TextureHandle,
    settings: &Tonemapping,
    pipeline: &TonemappingPipeline,
) -> Result<TextureHandle, RenderError> {
    pipeline
        .0
        .pass(graph, "tonemapping_pass")
        .read(hdr)
        .uniform(bytemuck::cast_slice(&settings.uniform()))
        .draw("tonemapping_fs", target)?;
    Ok(target)
}
