//! Tiled deferred lighting: punctual lights, light-map irradiance × albedo × AO, emission; the
//! sky where no geometry is.

use std::sync::Arc;

use crate::RenderError;
use crate::context::Requirements;
use crate::gbuffer::{GBuffer, HDR_FORMAT};
use crate::graph::{RenderGraph, TextureDesc, TextureHandle};
use crate::pass::{BindLayout, SimplePass, Slot, UNFILTERABLE};
use crate::scene::GpuScene;

/// The shader source (with the shared prelude).
pub fn shader_source() -> String {
    format!("{}{}", crate::COMMON_WGSL, include_str!("lighting.wgsl"))
}

/// What the lighting pass writes: the lit image, or one input on its own.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "bevy_ecs", derive(bevy_ecs::component::Component))]
pub enum DebugView {
    /// The lit image (default).
    #[default]
    Lit,
    /// G-buffer albedo.
    Albedo,
    /// G-buffer normal, mapped to `n / 2 + 1/2`.
    Normal,
    /// G-buffer material (roughness, light-map coverage).
    Material,
    /// The light-map term only: albedo × H (no AO).
    LightMap,
    /// Emission only.
    Emissive,
    /// Linear view depth over the far plane.
    Depth,
    /// Ambient occlusion only (1 when SSAO is off).
    AmbientOcclusion,
    /// Direct light from the punctual lights only.
    DirectLight,
}

impl DebugView {
    /// Every view, in UI order.
    pub const ALL: [DebugView; 9] = [
        DebugView::Lit,
        DebugView::Albedo,
        DebugView::Normal,
        DebugView::Material,
        DebugView::LightMap,
        DebugView::Emissive,
        DebugView::Depth,
        DebugView::AmbientOcclusion,
        DebugView::DirectLight,
    ];

    fn code(self) -> u32 {
        Self::ALL.iter().position(|&v| v == self).unwrap_or(0) as u32
    }

    /// The view's name, as the CLI spells it.
    pub fn name(self) -> &'static str {
        match self {
            DebugView::Lit => "lit",
            DebugView::Albedo => "albedo",
            DebugView::Normal => "normal",
            DebugView::Material => "material",
            DebugView::LightMap => "lightmap",
            DebugView::Emissive => "emissive",
            DebugView::Depth => "depth",
            DebugView::AmbientOcclusion => "ao",
            DebugView::DirectLight => "direct",
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SettingsUniform {
    debug_view: u32,
    use_ao: u32,
    pad: [u32; 2],
}

/// What the lighting pass needs from the adapter.
pub fn requirements() -> Requirements {
    Requirements {
        storage_formats: vec![HDR_FORMAT],
        ..Default::default()
    }
}

/// The lighting compute pipeline.
pub struct LightingPipeline {
    layout: Arc<BindLayout>,
    pipeline: wgpu::ComputePipeline,
    white: wgpu::TextureView,
    device: wgpu::Device,
}

impl LightingPipeline {
    /// Compiles the pipeline.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("lighting_shader"),
            source: wgpu::ShaderSource::Wgsl(shader_source().into()),
        });
        let tex = Slot::Texture(UNFILTERABLE);
        // Depth bound as unfilterable float, which every backend (GL's GLSL included) loads.
        let depth = Slot::Texture(UNFILTERABLE);
        let layout = Arc::new(BindLayout::new(
            device,
            "lighting",
            wgpu::ShaderStages::COMPUTE,
            &[
                Slot::Uniform,                    // camera
                Slot::Storage,                    // lights
                tex,                              // albedo
                tex,                              // normal
                tex,                              // material
                tex,                              // irradiance
                tex,                              // emissive
                depth,                            // depth
                tex,                              // ambient occlusion
                Slot::StorageTexture(HDR_FORMAT), // lit radiance
                Slot::Uniform,                    // settings
                Slot::Uniform,                    // sky
                tex,                              // sky image
            ],
        ));
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("lighting_pipeline_layout"),
            bind_group_layouts: &[Some(layout.layout())],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("lighting_pipeline"),
            layout: Some(&pl),
            module: &module,
            entry_point: Some("lighting_main"),
            compilation_options: Default::default(),
            cache: None,
        });
        let white = crate::util::sampled_texture(
            device,
            queue,
            "lighting_white",
            (1, 1, 1),
            wgpu::TextureFormat::R8Unorm,
            &[255],
        );
        Self {
            layout,
            pipeline,
            white,
            device: device.clone(),
        }
    }
}

/// Adds the lighting pass; returns the lit HDR radiance (Rgba16Float).
///
/// With `ao` = `None` no AO texture is read (the indirect term is unoccluded).
pub fn lighting_pass(
    graph: &mut RenderGraph,
    (gbuffer, ao): (&GBuffer, Option<TextureHandle>),
    scene: &GpuScene,
    debug_view: DebugView,
    pipeline: &LightingPipeline,
) -> Result<TextureHandle, RenderError> {
    let d = graph.desc(gbuffer.albedo);
    let out = graph.create(
        "lit_radiance",
        TextureDesc::storage(d.width, d.height, HDR_FORMAT),
    );
    let settings = SettingsUniform {
        debug_view: debug_view.code(),
        use_ao: u32::from(ao.is_some()),
        pad: [0; 2],
    };
    let g = *gbuffer;
    let pass = SimplePass::new(graph, "lighting_pass", &pipeline.layout, &pipeline.device)
        .buffer(&scene.camera)
        .buffer(&scene.lights)
        .read(g.albedo)
        .read(g.normal)
        .read(g.material)
        .read(g.irradiance)
        .read(g.emissive)
        .read(g.depth);
    let pass = match ao {
        Some(ao) => pass.read(ao),
        None => pass.view(&pipeline.white),
    };
    pass.write(out)
        .uniform(bytemuck::bytes_of(&settings))
        .buffer(&scene.sky)
        .view(&scene.sky_image)
        .dispatch(
            pipeline.pipeline.clone(),
            [d.width.div_ceil(16), d.height.div_ceil(16), 1],
        )?;
    Ok(out)
}
