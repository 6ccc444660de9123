//! Tiled deferred lighting: punctual lights, light-map irradiance × albedo × AO, emission; the
//! sky where no geometry is.

use std::sync::Arc;

use wgpu::util::DeviceExt;

use crate::context::Requirements;
use crate::gbuffer::{GBuffer, HDR_FORMAT};
use crate::graph::{RenderGraph, TextureDesc, TextureHandle};
use crate::scene::GpuScene;
use crate::util::{storage_entry, texture_entry, uniform_entry};

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
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    white: wgpu::TextureView,
}

impl LightingPipeline {
    /// Compiles the pipeline.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("lighting_shader"),
            source: wgpu::ShaderSource::Wgsl(shader_source().into()),
        });
        let float = wgpu::TextureSampleType::Float { filterable: false };
        let mut entries = vec![
            uniform_entry(0, wgpu::ShaderStages::COMPUTE),
            storage_entry(1, wgpu::ShaderStages::COMPUTE),
        ];
        for b in 2..=6 {
            entries.push(texture_entry(b, float));
        }
        entries.push(texture_entry(7, wgpu::TextureSampleType::Depth));
        entries.push(texture_entry(8, float));
        entries.push(wgpu::BindGroupLayoutEntry {
            binding: 9,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::StorageTexture {
                access: wgpu::StorageTextureAccess::WriteOnly,
                format: HDR_FORMAT,
                view_dimension: wgpu::TextureViewDimension::D2,
            },
            count: None,
        });
        entries.push(uniform_entry(10, wgpu::ShaderStages::COMPUTE));
        entries.push(uniform_entry(11, wgpu::ShaderStages::COMPUTE));
        entries.push(texture_entry(12, float));
        for e in &mut entries {
            e.visibility = wgpu::ShaderStages::COMPUTE;
        }
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("lighting_layout"),
            entries: &entries,
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("lighting_pipeline_layout"),
            bind_group_layouts: &[Some(&layout)],
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
        }
    }
}

/// Adds the lighting pass; returns the lit HDR radiance (Rgba16Float).
///
/// With `ao` = `None` no AO texture is read (the indirect term is unoccluded).
pub fn lighting_pass(
    graph: &mut RenderGraph,
    gbuffer: &GBuffer,
    ao: Option<TextureHandle>,
    debug_view: DebugView,
    pipeline: Arc<LightingPipeline>,
    scene: Arc<GpuScene>,
    device: &wgpu::Device,
) -> TextureHandle {
    let d = graph.desc(gbuffer.albedo);
    let out = graph.create(
        "lit_radiance",
        TextureDesc::storage(d.width, d.height, HDR_FORMAT),
    );
    let settings = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("lighting_settings"),
        contents: bytemuck::bytes_of(&SettingsUniform {
            debug_view: debug_view.code(),
            use_ao: u32::from(ao.is_some()),
            pad: [0; 2],
        }),
        usage: wgpu::BufferUsages::UNIFORM,
    });
    let g = *gbuffer;
    let mut reads = vec![
        g.albedo,
        g.normal,
        g.material,
        g.irradiance,
        g.emissive,
        g.depth,
    ];
    reads.extend(ao);
    graph.add_pass("lighting_pass", &reads, &[out], move |ctx| {
        fn view(b: u32, v: &wgpu::TextureView) -> wgpu::BindGroupEntry<'_> {
            wgpu::BindGroupEntry {
                binding: b,
                resource: wgpu::BindingResource::TextureView(v),
            }
        }
        let ao_view = ao.map_or(&pipeline.white, |h| ctx.view(h));
        let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("lighting_bind_group"),
            layout: &pipeline.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: scene.camera.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: scene.lights.as_entire_binding(),
                },
                view(2, ctx.view(g.albedo)),
                view(3, ctx.view(g.normal)),
                view(4, ctx.view(g.material)),
                view(5, ctx.view(g.irradiance)),
                view(6, ctx.view(g.emissive)),
                view(7, ctx.view(g.depth)),
                view(8, ao_view),
                view(9, ctx.view(out)),
                wgpu::BindGroupEntry {
                    binding: 10,
                    resource: settings.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 11,
                    resource: scene.sky.as_entire_binding(),
                },
                view(12, &scene.sky_image),
            ],
        });
        let mut pass = ctx
            .encoder
            .begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("lighting_pass"),
                timestamp_writes: None,
            });
        pass.set_pipeline(&pipeline.pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups(d.width.div_ceil(16), d.height.div_ceil(16), 1);
    });
    out
}
