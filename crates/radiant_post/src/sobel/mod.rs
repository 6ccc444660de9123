//! Sobel edge detection as a post node, on colour, depth or normals.

use std::sync::Arc;

use radiant_render::graph::{RenderGraph, TextureDesc, TextureHandle};
use radiant_render::util::{
    PipelinesByFormat, buffer_entry, fullscreen_pipeline, texture_entry, uniform_entry, view_entry,
};
use radiant_render::{COMMON_WGSL, RenderError};
use wgpu::util::DeviceExt;

/// The shader source (with the shared prelude).
pub fn shader_source() -> String {
    format!("{COMMON_WGSL}{}", include_str!("sobel.wgsl"))
}

/// Which signal the edges are found in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum EdgeSource {
    /// Luminance of the input image (default).
    #[default]
    Color,
    /// Linear depth, relative to the centre pixel's distance.
    Depth,
    /// The G-buffer normal.
    Normal,
}

/// Sobel edge overlay. Present → on.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "bevy_ecs", derive(bevy_ecs::component::Component))]
pub struct Sobel {
    /// Gradient magnitude above which a pixel is an edge; a unit step has magnitude 1; range
    /// (0, ∞) (default: 0.2).
    pub threshold: f32,
    /// What to differentiate (default: colour).
    pub source: EdgeSource,
    /// Colour of edge pixels, display-linear (default: black).
    pub edge_color: [f32; 3],
}

impl Default for Sobel {
    fn default() -> Self {
        Self {
            threshold: 0.2,
            source: EdgeSource::Color,
            edge_color: [0.0; 3],
        }
    }
}

impl Sobel {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), RenderError> {
        if !(self.threshold.is_finite() && self.threshold > 0.0) {
            return Err(RenderError::InvalidSetting {
                field: "sobel.threshold",
                value: self.threshold.into(),
                range: "(0, inf)",
            });
        }
        if self.edge_color.iter().any(|c| !c.is_finite()) {
            return Err(RenderError::InvalidSetting {
                field: "sobel.edge_color",
                value: f64::NAN,
                range: "finite",
            });
        }
        Ok(())
    }
}

/// The Sobel pipelines (per source and format).
pub struct SobelPipeline {
    layouts: [wgpu::BindGroupLayout; 3],
    pipelines: [PipelinesByFormat; 3],
}

impl SobelPipeline {
    /// Creates the layouts.
    pub fn new(device: &wgpu::Device) -> Self {
        let float = wgpu::TextureSampleType::Float { filterable: false };
        let make = |label, extra: Option<wgpu::BindGroupLayoutEntry>| {
            let mut entries = vec![
                texture_entry(0, float),
                uniform_entry(3, wgpu::ShaderStages::FRAGMENT),
            ];
            entries.extend(extra);
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &entries,
            })
        };
        Self {
            layouts: [
                make("sobel_color_layout", None),
                make(
                    "sobel_depth_layout",
                    Some(texture_entry(2, wgpu::TextureSampleType::Depth)),
                ),
                make("sobel_normal_layout", Some(texture_entry(1, float))),
            ],
            pipelines: Default::default(),
        }
    }
}

/// Which auxiliary texture the Sobel reads for a source.
#[derive(Clone, Copy, Debug)]
pub struct SobelInputs {
    /// The image to overlay (and differentiate, for [`EdgeSource::Color`]).
    pub color: TextureHandle,
    /// The G-buffer depth, for [`EdgeSource::Depth`].
    pub depth: Option<TextureHandle>,
    /// The G-buffer normal, for [`EdgeSource::Normal`].
    pub normal: Option<TextureHandle>,
    /// Camera near and far planes, to linearise depth.
    pub near_far: [f32; 2],
}

/// Adds the Sobel pass; writes `output` if given, else a new texture like the colour input.
pub fn sobel_pass(
    graph: &mut RenderGraph,
    inputs: SobelInputs,
    settings: &Sobel,
    output: Option<TextureHandle>,
    pipeline: &Arc<SobelPipeline>,
    device: &wgpu::Device,
) -> Result<TextureHandle, RenderError> {
    let desc = graph.desc(inputs.color);
    let out = output.unwrap_or_else(|| {
        graph.create(
            "sobel_out",
            TextureDesc::new(desc.width, desc.height, desc.format),
        )
    });
    let (index, entry, aux) = match settings.source {
        EdgeSource::Color => (0, "sobel_color_fs", None),
        EdgeSource::Depth => (1, "sobel_depth_fs", inputs.depth.map(|h| (2, h))),
        EdgeSource::Normal => (2, "sobel_normal_fs", inputs.normal.map(|h| (1, h))),
    };
    if index != 0 && aux.is_none() {
        return Err(RenderError::Graph(format!(
            "Sobel on {:?} needs that G-buffer texture",
            settings.source
        )));
    }
    let format = graph.desc(out).format;
    let layout = &pipeline.layouts[index];
    let rp = pipeline.pipelines[index].get(format, || {
        fullscreen_pipeline(
            device,
            "sobel_pipeline",
            &shader_source(),
            entry,
            layout,
            format,
            None,
        )
    });
    let c = settings.edge_color;
    let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("sobel_settings"),
        contents: bytemuck::cast_slice(&[
            c[0],
            c[1],
            c[2],
            1.0,
            settings.threshold,
            inputs.near_far[0],
            inputs.near_far[1],
            0.0,
        ]),
        usage: wgpu::BufferUsages::UNIFORM,
    });
    let mut reads = vec![inputs.color];
    reads.extend(aux.map(|(_, h)| h));
    let p = pipeline.clone();
    let color = inputs.color;
    graph.add_pass("sobel_pass", &reads, &[out], move |ctx| {
        let mut entries = vec![view_entry(0, ctx.view(color)), buffer_entry(3, &uniform)];
        if let Some((b, h)) = aux {
            entries.push(view_entry(b, ctx.view(h)));
        }
        let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("sobel_bind_group"),
            layout: &p.layouts[index],
            entries: &entries,
        });
        radiant_render::util::draw_fullscreen(ctx.encoder, "sobel_pass", ctx.view(out), &rp, &bind);
    });
    Ok(out)
}
