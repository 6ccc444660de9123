//! The G-buffer pass: albedo, octahedral normal, material, baked irradiance, emission and depth.

use std::sync::Arc;

use crate::graph::{RenderGraph, TextureDesc, TextureHandle};
use crate::scene::{GpuScene, InstanceData, Vertex};

/// Albedo, Rgba8Unorm (linear reflectance).
pub const ALBEDO_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
/// World normal, octahedral in Rg16Float.
pub const NORMAL_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rg16Float;
/// Material: roughness, light-map coverage.
pub const MATERIAL_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rg8Unorm;
/// Baked irradiance and emission, linear HDR.
pub const HDR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
/// Depth.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// The shader source (with the shared prelude).
pub fn shader_source() -> String {
    format!("{}{}", crate::COMMON_WGSL, include_str!("gbuffer.wgsl"))
}

/// The G-buffer's textures in a graph.
#[derive(Clone, Copy, Debug)]
pub struct GBuffer {
    /// Linear albedo.
    pub albedo: TextureHandle,
    /// Octahedral world normal.
    pub normal: TextureHandle,
    /// Roughness and light-map coverage.
    pub material: TextureHandle,
    /// Light-map irradiance `H` (reflected radiance = albedo × H).
    pub irradiance: TextureHandle,
    /// Emitted radiance.
    pub emissive: TextureHandle,
    /// Depth, 0 near, 1 far / empty.
    pub depth: TextureHandle,
}

/// The G-buffer pipeline and its bind-group layout.
pub struct GBufferPipeline {
    layout: wgpu::BindGroupLayout,
    material_layout: wgpu::BindGroupLayout,
    pipeline: wgpu::RenderPipeline,
}

impl GBufferPipeline {
    /// Compiles the pipeline.
    pub fn new(device: &wgpu::Device) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("gbuffer_shader"),
            source: wgpu::ShaderSource::Wgsl(shader_source().into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gbuffer_layout"),
            entries: &[
                crate::util::uniform_entry(0, wgpu::ShaderStages::VERTEX_FRAGMENT),
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                crate::util::storage_entry(3, wgpu::ShaderStages::VERTEX),
            ],
        });
        let material_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gbuffer_material_layout"),
            entries: &[
                crate::util::texture_entry(0, wgpu::TextureSampleType::Float { filterable: true }),
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                crate::util::uniform_entry(2, wgpu::ShaderStages::FRAGMENT),
            ],
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("gbuffer_pipeline_layout"),
            bind_group_layouts: &[Some(&layout), Some(&material_layout)],
            immediate_size: 0,
        });
        let attributes = wgpu::vertex_attr_array![
            0 => Float32x3, 1 => Float32x3, 2 => Float32x3, 3 => Float32x3, 4 => Float32x2,
            5 => Float32x2, 13 => Uint32
        ];
        let instance_attributes = wgpu::vertex_attr_array![
            6 => Float32x4, 7 => Float32x4, 8 => Float32x4,
            9 => Float32x4, 10 => Float32x4, 11 => Float32x4, 12 => Uint32x4
        ];
        let target = |format| {
            Some(wgpu::ColorTargetState {
                format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })
        };
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("gbuffer_pipeline"),
            layout: Some(&pl),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("gbuffer_vs"),
                compilation_options: Default::default(),
                buffers: &[
                    Some(wgpu::VertexBufferLayout {
                        array_stride: std::mem::size_of::<Vertex>() as u64,
                        step_mode: wgpu::VertexStepMode::Vertex,
                        attributes: &attributes,
                    }),
                    Some(wgpu::VertexBufferLayout {
                        array_stride: std::mem::size_of::<InstanceData>() as u64,
                        step_mode: wgpu::VertexStepMode::Instance,
                        attributes: &instance_attributes,
                    }),
                ],
            },
            primitive: wgpu::PrimitiveState {
                cull_mode: None,
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("gbuffer_fs"),
                compilation_options: Default::default(),
                targets: &[
                    target(ALBEDO_FORMAT),
                    target(NORMAL_FORMAT),
                    target(MATERIAL_FORMAT),
                    target(HDR_FORMAT),
                    target(HDR_FORMAT),
                ],
            }),
            multiview_mask: None,
            cache: None,
        });
        Self {
            layout,
            material_layout,
            pipeline,
        }
    }
}

/// Adds the G-buffer pass; returns its textures.
pub fn gbuffer_pass(
    graph: &mut RenderGraph,
    width: u32,
    height: u32,
    pipeline: Arc<GBufferPipeline>,
    scene: Arc<GpuScene>,
) -> GBuffer {
    let g = GBuffer {
        albedo: graph.create(
            "gbuffer_albedo",
            TextureDesc::new(width, height, ALBEDO_FORMAT),
        ),
        normal: graph.create(
            "gbuffer_normal",
            TextureDesc::new(width, height, NORMAL_FORMAT),
        ),
        material: graph.create(
            "gbuffer_material",
            TextureDesc::new(width, height, MATERIAL_FORMAT),
        ),
        irradiance: graph.create(
            "gbuffer_irradiance",
            TextureDesc::new(width, height, HDR_FORMAT),
        ),
        emissive: graph.create(
            "gbuffer_emissive",
            TextureDesc::new(width, height, HDR_FORMAT),
        ),
        depth: graph.create(
            "gbuffer_depth",
            TextureDesc::new(width, height, DEPTH_FORMAT),
        ),
    };
    let writes = [
        g.albedo,
        g.normal,
        g.material,
        g.irradiance,
        g.emissive,
        g.depth,
    ];
    graph.add_pass("gbuffer_pass", &[], &writes, move |ctx| {
        let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("gbuffer_bind_group"),
            layout: &pipeline.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: scene.camera.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&scene.lightmap),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(&scene.linear_sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: scene.instance_uvs.as_entire_binding(),
                },
            ],
        });
        let materials: Vec<wgpu::BindGroup> = scene
            .materials
            .iter()
            .map(|m| {
                ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("gbuffer_material"),
                    layout: &pipeline.material_layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: wgpu::BindingResource::TextureView(&m.texture),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: wgpu::BindingResource::Sampler(&m.sampler),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: m.uniform.as_entire_binding(),
                        },
                    ],
                })
            })
            .collect();
        let color = |h| {
            Some(wgpu::RenderPassColorAttachment {
                view: ctx.view(h),
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                    store: wgpu::StoreOp::Store,
                },
            })
        };
        let attachments = [
            color(g.albedo),
            color(g.normal),
            color(g.material),
            color(g.irradiance),
            color(g.emissive),
        ];
        let depth_view = ctx.view(g.depth);
        let mut pass = ctx.encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("gbuffer_pass"),
            color_attachments: &attachments,
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Store,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(&pipeline.pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.set_vertex_buffer(0, scene.vertices.slice(..));
        pass.set_vertex_buffer(1, scene.instances.slice(..));
        for (m, bind) in scene.materials.iter().zip(&materials) {
            pass.set_bind_group(1, bind, &[]);
            pass.draw(m.first..m.first + m.count, m.instances.clone());
        }
    });
    g
}
