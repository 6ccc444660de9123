//! Sobel edge detection as a post node, on colour, depth or normals.

use radiant_render::graph::{RenderGraph, TextureDesc, TextureHandle};
use radiant_render::pass::{FullscreenEffect, Slot, UNFILTERABLE};
use radiant_render::{COMMON_WGSL, RenderError};

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

/// The Sobel pipelines: one effect per source, as each entry point binds its own textures
/// (the colour at 0, the normal at 1, the depth at 2, the settings at 3).
pub struct SobelPipeline {
    color: FullscreenEffect,
    depth: FullscreenEffect,
    normal: FullscreenEffect,
}

impl SobelPipeline {
    /// Declares the bindings; pipelines compile on first use per format.
    pub fn new(device: &wgpu::Device) -> Self {
        let (tex, no) = (Slot::Texture(UNFILTERABLE), Slot::Unused);
        // Depth bound as unfilterable float, which every backend (GL's GLSL included) loads.
        let depth = Slot::Texture(UNFILTERABLE);
        let make =
            |label, slots: &[Slot]| FullscreenEffect::new(device, label, shader_source(), slots);
        Self {
            color: make("sobel_color", &[tex, no, no, Slot::Uniform]),
            depth: make("sobel_depth", &[tex, no, depth, Slot::Uniform]),
            normal: make("sobel_normal", &[tex, tex, no, Slot::Uniform]),
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
    pipeline: &SobelPipeline,
) -> Result<TextureHandle, RenderError> {
    let desc = graph.desc(inputs.color);
    let out = output.unwrap_or_else(|| {
        graph.create(
            "sobel_out",
            TextureDesc::new(desc.width, desc.height, desc.format),
        )
    });
    let missing = |input| RenderError::MissingInput {
        pass: "sobel_pass",
        input,
    };
    let (effect, entry, aux) = match settings.source {
        EdgeSource::Color => (&pipeline.color, "sobel_color_fs", None),
        EdgeSource::Depth => (
            &pipeline.depth,
            "sobel_depth_fs",
            Some(inputs.depth.ok_or(missing("depth"))?),
        ),
        EdgeSource::Normal => (
            &pipeline.normal,
            "sobel_normal_fs",
            Some(inputs.normal.ok_or(missing("normal"))?),
        ),
    };
    let c = settings.edge_color;
    let uniform = [
        c[0],
        c[1],
        c[2],
        1.0,
        settings.threshold,
        inputs.near_far[0],
        inputs.near_far[1],
        0.0,
    ];
    let mut pass = effect.pass(graph, "sobel_pass").read(inputs.color);
    if let Some(aux) = aux {
        pass = pass.read(aux);
    }
    pass.uniform(bytemuck::cast_slice(&uniform))
        .draw(entry, out)?;
    Ok(out)
}
