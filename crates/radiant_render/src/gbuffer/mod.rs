//! The G-buffer pass: albedo, octahedral normal, material, baked irradiance, emission and depth.

use std::sync::Arc;

use crate::graph::{RenderGraph, TextureDesc, TextureHandle};
use crate::pass::{Bind, BindLayout, Slot};
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
    layout: Arc<BindLayout>,
    material_layout: Arc<BindLayout>,
    pipeline: wgpu::RenderPipeline,
}

impl GBufferPipeline {
    /// Compiles the pipeline.
    pub fn new(device: &wgpu::Device) -> Self {
        let filterable = wgpu::TextureSampleType::Float { filterable: true };
        let filtering = Slot::Sampler(wgpu::SamplerBindingType::Filtering);
        let stages = wgpu::ShaderStages::VERTEX_FRAGMENT;
        let layout = Arc::new(BindLayout::new(
            device,
            "gbuffer",
            stages,
            // Camera, light-map pages, their sampler, per-instance light-map placement, the
            // probe grid and its probes (for dynamic surfaces).
            &[
                Slot::Uniform,
                Slot::TextureArray(filterable),
                filtering,
                Slot::Storage,
                Slot::Uniform,
                Slot::Storage,
            ],
        ));
        let material_layout = Arc::new(BindLayout::new(
            device,
            "gbuffer_material",
            stages,
            // Base-colour texture, its sampler, the material's factors.
            &[Slot::Texture(filterable), filtering, Slot::Uniform],
        ));
        let pipeline = draw_pipeline(device, &layout, &material_layout);
        Self {
            layout,
            material_layout,
            pipeline,
        }
    }
}

/// The G-buffer's render pipeline: vertex and instance buffers in, five colour targets and
/// depth out, no culling (back faces are handled in the shader).
fn draw_pipeline(
    device: &wgpu::Device,
    layout: &BindLayout,
    material_layout: &BindLayout,
) -> wgpu::RenderPipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("gbuffer_shader"),
        source: wgpu::ShaderSource::Wgsl(shader_source().into()),
    });
    let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("gbuffer_pipeline_layout"),
        bind_group_layouts: &[Some(layout.layout()), Some(material_layout.layout())],
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
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
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
    })
}

/// The G-buffer's textures of a `width` × `height` frame.
fn gbuffer_textures(graph: &mut RenderGraph, width: u32, height: u32) -> GBuffer {
    let mut create = |name, format| graph.create(name, TextureDesc::new(width, height, format));
    GBuffer {
        albedo: create("gbuffer_albedo", ALBEDO_FORMAT),
        normal: create("gbuffer_normal", NORMAL_FORMAT),
        material: create("gbuffer_material", MATERIAL_FORMAT),
        irradiance: create("gbuffer_irradiance", HDR_FORMAT),
        emissive: create("gbuffer_emissive", HDR_FORMAT),
        depth: create("gbuffer_depth", DEPTH_FORMAT),
    }
}

/// Adds the G-buffer pass; returns its textures.
pub fn gbuffer_pass(
    graph: &mut RenderGraph,
    (width, height): (u32, u32),
    scene: &Arc<GpuScene>,
    pipeline: &GBufferPipeline,
) -> Result<GBuffer, crate::RenderError> {
    let g = gbuffer_textures(graph, width, height);
    let mut pass = graph.add_pass("gbuffer_pass");
    let colors = [g.albedo, g.normal, g.material, g.irradiance, g.emissive].map(|h| pass.write(h));
    let depth = pass.write(g.depth);
    let frame = pipeline.layout.bind(
        &mut pass,
        vec![
            Bind::Buffer(scene.camera.clone()),
            Bind::View(scene.lightmap.clone()),
            Bind::Sampler(scene.linear_sampler.clone()),
            Bind::Buffer(scene.instance_uvs.clone()),
            Bind::Buffer(scene.probe_grid.clone()),
            Bind::Buffer(scene.probes.clone()),
        ],
    )?;
    let materials = scene
        .materials
        .iter()
        .map(|m| {
            pipeline.material_layout.bind(
                &mut pass,
                vec![
                    Bind::View(m.texture.clone()),
                    Bind::Sampler(m.sampler.clone()),
                    Bind::Buffer(m.uniform.clone()),
                ],
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    let (scene, rp) = (scene.clone(), pipeline.pipeline.clone());
    pass.render(move |ctx| {
        let frame = frame.create(ctx)?;
        let materials = materials
            .iter()
            .map(|m| m.create(ctx))
            .collect::<Result<Vec<_>, _>>()?;
        let mut attachments = Vec::with_capacity(colors.len());
        for c in colors {
            attachments.push(Some(wgpu::RenderPassColorAttachment {
                view: ctx.view(c)?,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                    store: wgpu::StoreOp::Store,
                },
            }));
        }
        let mut rpass = ctx.encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("gbuffer_pass"),
            color_attachments: &attachments,
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: ctx.view(depth)?,
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
        rpass.set_pipeline(&rp);
        rpass.set_bind_group(0, &frame, &[]);
        rpass.set_vertex_buffer(0, scene.vertices.slice(..));
        rpass.set_vertex_buffer(1, scene.instances.slice(..));
        for (m, bind) in scene.materials.iter().zip(&materials) {
            rpass.set_bind_group(1, bind, &[]);
            rpass.draw(m.first..m.first + m.count, m.instances.clone());
        }
        Ok(())
    });
    Ok(g)
}
