//! Tone mapping with exposure, into an sRGB (display-encoded) target.

use std::sync::Arc;

use radiant_color::Tonemap;
use radiant_render::graph::{RenderGraph, TextureHandle};
use radiant_render::util::{
    PipelinesByFormat, buffer_entry, fullscreen_pipeline, texture_entry, uniform_entry, view_entry,
};
use radiant_render::{COMMON_WGSL, RenderError};
use wgpu::util::DeviceExt;

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
pub struct TonemappingPipeline {
    layout: wgpu::BindGroupLayout,
    pipelines: PipelinesByFormat,
}

impl TonemappingPipeline {
    /// Creates the layout; pipelines compile on first use per format.
    pub fn new(device: &wgpu::Device) -> Self {
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("tonemapping_layout"),
            entries: &[
                texture_entry(0, wgpu::TextureSampleType::Float { filterable: false }),
                uniform_entry(1, wgpu::ShaderStages::FRAGMENT),
            ],
        });
        Self {
            layout,
            pipelines: PipelinesByFormat::default(),
        }
    }
}

/// Adds the tone-mapping pass from `hdr` into `target` (an sRGB format encodes on store).
pub fn tonemapping_pass(
    graph: &mut RenderGraph,
    hdr: TextureHandle,
    target: TextureHandle,
    settings: &Tonemapping,
    pipeline: &Arc<TonemappingPipeline>,
    device: &wgpu::Device,
) {
    let format = graph.desc(target).format;
    let layout = &pipeline.layout;
    let rp = pipeline.pipelines.get(format, || {
        fullscreen_pipeline(
            device,
            "tonemapping_pipeline",
            &shader_source(),
            "tonemapping_fs",
            layout,
            format,
            None,
        )
    });
    let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("tonemapping_settings"),
        contents: bytemuck::cast_slice(&settings.uniform()),
        usage: wgpu::BufferUsages::UNIFORM,
    });
    let p = pipeline.clone();
    graph.add_pass("tonemapping_pass", &[hdr], &[target], move |ctx| {
        let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("tonemapping_bind_group"),
            layout: &p.layout,
            entries: &[view_entry(0, ctx.view(hdr)), buffer_entry(1, &uniform)],
        });
        radiant_render::util::draw_fullscreen(
            ctx.encoder,
            "tonemapping_pass",
            ctx.view(target),
            &rp,
            &bind,
        );
    });
}
