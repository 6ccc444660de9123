//! The GPU half of the gather: buffers, the two light maps, the hemicube atlas, pipelines, and
//! one sweep as one command buffer.

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
use radiant_render::GpuContext;
use radiant_render::capture::{ReadbackError, read_buffer};
use radiant_render::util::{storage_entry, uniform_entry};
use radiant_scene::Scene;
use radiant_scene::atlas::Atlas;
use wgpu::util::DeviceExt;

use crate::{Frame, GatherError};

/// The light maps hold f32 where the adapter filters it, else half floats; what a pixel sees is
/// f32 too. (With half floats a stiff furnace, ρ = 0.9, stalled 0.8 % short of its fixed point:
/// once a sweep's increment fell below half a unit in the last place, nothing changed.)
const MAP_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const MAP_FORMAT_HALF: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
const HEMICUBE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Widest hemicube atlas (pixels); a batch fills it with cells of 3R × R.
const ATLAS_SIDE: u32 = 4096;

/// One receiver, as `gather.wgsl` reads it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct GpuReceiver {
    pub origin: [f32; 4],
    pub t: [f32; 4],
    pub b: [f32; 4],
    pub n: [f32; 4],
    pub direct: [f32; 4],
    pub texel: [u32; 4],
}

/// A surface's mean reflectance and emission.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct GpuMaterial {
    pub reflectance: [f32; 4],
    pub emission: [f32; 4],
}

/// A vertex of a baked triangle (not indexed).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct GpuVertex {
    position: [f32; 3],
    uv: [f32; 2],
    page: u32,
    material: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    atlas: [f32; 2],
    res: u32,
    cols: u32,
    first: u32,
    count: u32,
    near: f32,
    norm: f32,
    sky_kind: u32,
    pad: [u32; 3],
    sky_a: [f32; 4],
    sky_b: [f32; 4],
}

/// The sky the reduction adds where a pixel sees nothing.
#[derive(Clone, Copy, Debug)]
pub(crate) enum SkyUniform {
    None,
    Uniform([f64; 3]),
    Gradient([f64; 3], [f64; 3]),
}

/// What [`Gpu::new`] uploads.
pub(crate) struct Setup<'a> {
    pub resolution: u32,
    pub atlas: &'a Atlas,
    pub receivers: &'a [GpuReceiver],
    pub vertices: &'a [GpuVertex],
    pub materials: &'a [GpuMaterial],
    pub sky: SkyUniform,
    pub near: f32,
}

/// The baked triangles' vertices in the local frame, with their light-map coordinates.
pub(crate) fn vertices(
    scene: &Scene,
    atlas: &Atlas,
    frame: &Frame,
    baked: &[bool],
) -> Vec<GpuVertex> {
    let mut out = Vec::with_capacity(scene.triangles.len() * 3);
    for (i, t) in scene.triangles.iter().enumerate() {
        if !baked[i] {
            continue;
        }
        for k in 0..3 {
            let p: DVec3 = frame.local(t.vertices[k]);
            out.push(GpuVertex {
                position: [p.x as f32, p.y as f32, p.z as f32],
                uv: atlas.uv[i][k].to_array(),
                page: atlas.page[i],
                material: t.surface,
            });
        }
    }
    out
}

struct Batch {
    count: u32,
    render: [wgpu::BindGroup; 2],
    reduce: [wgpu::BindGroup; 2],
}

/// Everything on the GPU.
pub(crate) struct Gpu {
    ctx: GpuContext,
    front: wgpu::RenderPipeline,
    back: wgpu::RenderPipeline,
    reduce: wgpu::ComputePipeline,
    vertices: wgpu::Buffer,
    vertex_count: u32,
    hemicube_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    batches: Vec<Batch>,
    gathered: wgpu::Buffer,
    readback: wgpu::Buffer,
    receivers: usize,
    /// Which light map the next sweep reads (it writes the other).
    parity: usize,
}

/// 1 / the sum of the unnormalised delta form factors `d² / (π q²)` of a hemicube of `res`
/// (the same pixels as `gather.wgsl` and the CPU hemicube), in f64.
fn normalisation(res: u32) -> f64 {
    let d = 2.0 / f64::from(res);
    let c = |i: u32| -1.0 + (f64::from(i) + 0.5) * d;
    let mut total = 0.0;
    for j in 0..res {
        for i in 0..res {
            let q = c(i) * c(i) + c(j) * c(j) + 1.0;
            total += d * d / (std::f64::consts::PI * q * q);
        }
    }
    for j in 0..res / 2 {
        for i in 0..res {
            let z = (f64::from(j) + 0.5) * d;
            let q = c(i) * c(i) + z * z + 1.0;
            total += 4.0 * z * d * d / (std::f64::consts::PI * q * q);
        }
    }
    1.0 / total
}

impl Gpu {
    pub(crate) fn new(ctx: GpuContext, s: &Setup) -> Result<Self, GatherError> {
        let device = &ctx.device;
        let res = s.resolution;
        let limit = device.limits().max_texture_dimension_2d;
        let side = ATLAS_SIDE.min(limit);
        let cols = side / (3 * res);
        let rows_max = side / res;
        if cols == 0 || rows_max == 0 {
            return Err(GatherError::InvalidSetting {
                field: "hemicube resolution",
                value: f64::from(res),
                range: "at most a third of the adapter's largest texture",
            });
        }
        let n = s.receivers.len() as u32;
        let per_batch = (cols * rows_max).min(device.limits().max_compute_workgroups_per_dimension);
        let rows = n.min(per_batch).div_ceil(cols);
        let (atlas_w, atlas_h) = (cols * 3 * res, rows * res);
        let (pages, mw, mh) = (s.atlas.pages.max(1), s.atlas.width, s.atlas.height);
        if pages > device.limits().max_texture_array_layers || mw > limit || mh > limit {
            return Err(GatherError::InvalidSetting {
                field: "light-map page side",
                value: f64::from(mw.max(mh)),
                range: "within the adapter's texture limits",
            });
        }

        let map_format = if ctx.features.contains(wgpu::Features::FLOAT32_FILTERABLE) {
            MAP_FORMAT
        } else {
            MAP_FORMAT_HALF
        };
        let map = |label: &str| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width: mw,
                    height: mh,
                    depth_or_array_layers: pages,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: map_format,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::STORAGE_BINDING,
                view_formats: &[],
            })
        };
        let maps = [map("gather_light_map_a"), map("gather_light_map_b")];
        let array_view = |t: &wgpu::Texture| {
            t.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2Array),
                ..Default::default()
            })
        };
        let map_views = [array_view(&maps[0]), array_view(&maps[1])];
        let target = |label: &str, format, usage| {
            device
                .create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size: wgpu::Extent3d {
                        width: atlas_w,
                        height: atlas_h,
                        depth_or_array_layers: 1,
                    },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                })
                .create_view(&Default::default())
        };
        let hemicube_view = target(
            "gather_hemicubes",
            HEMICUBE_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let depth_view = target(
            "gather_depth",
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("gather_light_map"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });

        let storage = |label: &str, bytes: &[u8]| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytes,
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let receivers = storage("gather_receivers", bytemuck::cast_slice(s.receivers));
        let materials = if s.materials.is_empty() {
            storage("gather_materials", &[0u8; 32])
        } else {
            storage("gather_materials", bytemuck::cast_slice(s.materials))
        };
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("gather_vertices"),
            contents: bytemuck::cast_slice(s.vertices),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let out_bytes = u64::from(n.max(1)) * 16;
        let gathered = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gather_out"),
            size: out_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gather_readback"),
            size: out_bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        let vf = wgpu::ShaderStages::VERTEX | wgpu::ShaderStages::FRAGMENT;
        let render_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gather_render"),
            entries: &[
                uniform_entry(0, vf),
                storage_entry(1, wgpu::ShaderStages::VERTEX),
                storage_entry(2, wgpu::ShaderStages::FRAGMENT),
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 4,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let cs = wgpu::ShaderStages::COMPUTE;
        let reduce_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gather_reduce"),
            entries: &[
                uniform_entry(0, cs),
                storage_entry(1, cs),
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: cs,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 6,
                    visibility: cs,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: false },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 7,
                    visibility: cs,
                    ty: wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format: map_format,
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                    },
                    count: None,
                },
            ],
        });

        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("gather"),
            source: wgpu::ShaderSource::Wgsl(shader(map_format).into()),
        });
        let render_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("gather_render"),
            bind_group_layouts: &[Some(&render_layout)],
            immediate_size: 0,
        });
        let attributes =
            wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x2, 2 => Uint32, 3 => Uint32];
        let raster = |label: &str, fs: &str, cull: wgpu::Face| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(&render_pl),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("hemicube_vs"),
                    compilation_options: Default::default(),
                    buffers: &[Some(wgpu::VertexBufferLayout {
                        array_stride: std::mem::size_of::<GpuVertex>() as u64,
                        step_mode: wgpu::VertexStepMode::Vertex,
                        attributes: &attributes,
                    })],
                },
                primitive: wgpu::PrimitiveState {
                    front_face: wgpu::FrontFace::Ccw,
                    cull_mode: Some(cull),
                    ..Default::default()
                },
                // Reversed depth: nearer is greater. Back faces come second and must be strictly
                // nearer, so a double-sided surface's twin (same depth, facing this way) wins.
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Greater),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(fs),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: HEMICUBE_FORMAT,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let front = raster("gather_front", "front_fs", wgpu::Face::Back);
        let back = raster("gather_back", "back_fs", wgpu::Face::Front);
        let reduce_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("gather_reduce"),
            bind_group_layouts: &[Some(&reduce_layout)],
            immediate_size: 0,
        });
        let reduce = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("gather_reduce"),
            layout: Some(&reduce_pl),
            module: &module,
            entry_point: Some("reduce_cs"),
            compilation_options: Default::default(),
            cache: None,
        });

        let (sky_kind, sky_a, sky_b) = match s.sky {
            SkyUniform::None => (0, [0.0; 3], [0.0; 3]),
            SkyUniform::Uniform(r) => (1, r, [0.0; 3]),
            SkyUniform::Gradient(z, h) => (2, z, h),
        };
        let v4 = |v: [f64; 3]| [v[0] as f32, v[1] as f32, v[2] as f32, 0.0];
        let norm = normalisation(res) as f32;
        let mut batches = Vec::new();
        let mut first = 0u32;
        while first < n {
            let count = (n - first).min(per_batch);
            let params = Params {
                atlas: [atlas_w as f32, atlas_h as f32],
                res,
                cols,
                first,
                count,
                near: s.near,
                norm,
                sky_kind,
                pad: [0; 3],
                sky_a: v4(sky_a),
                sky_b: v4(sky_b),
            };
            let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("gather_params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM,
            });
            let render = |p: usize| {
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("gather_render"),
                    layout: &render_layout,
                    entries: &[
                        entry(0, uniform.as_entire_binding()),
                        entry(1, receivers.as_entire_binding()),
                        entry(2, materials.as_entire_binding()),
                        entry(3, wgpu::BindingResource::TextureView(&map_views[p])),
                        entry(4, wgpu::BindingResource::Sampler(&sampler)),
                    ],
                })
            };
            let reduce = |p: usize| {
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("gather_reduce"),
                    layout: &reduce_layout,
                    entries: &[
                        entry(0, uniform.as_entire_binding()),
                        entry(1, receivers.as_entire_binding()),
                        entry(5, wgpu::BindingResource::TextureView(&hemicube_view)),
                        entry(6, gathered.as_entire_binding()),
                        entry(7, wgpu::BindingResource::TextureView(&map_views[1 - p])),
                    ],
                })
            };
            batches.push(Batch {
                count,
                render: [render(0), render(1)],
                reduce: [reduce(0), reduce(1)],
            });
            first += count;
        }
        ctx.take_errors().map_err(GatherError::Gpu)?;
        Ok(Self {
            front,
            back,
            reduce,
            vertex_count: s.vertices.len() as u32,
            vertices,
            hemicube_view,
            depth_view,
            batches,
            gathered,
            readback,
            receivers: n as usize,
            parity: 0,
            ctx,
        })
    }

    pub(crate) fn batches(&self) -> usize {
        self.batches.len()
    }

    pub(crate) fn adapter(&self) -> String {
        format!("{} ({:?})", self.ctx.info.name, self.ctx.info.backend)
    }

    /// One Jacobi sweep: every batch's hemicubes drawn from the current light map and reduced
    /// into the other; returns the new `H` per receiver.
    pub(crate) fn sweep(&mut self) -> Result<Vec<[f32; 3]>, GatherError> {
        let p = self.parity;
        let device = &self.ctx.device;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("gather_sweep"),
        });
        for batch in &self.batches {
            {
                let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("gather_hemicubes"),
                    color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                        view: &self.hemicube_view,
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                            store: wgpu::StoreOp::Store,
                        },
                    })],
                    depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                        view: &self.depth_view,
                        depth_ops: Some(wgpu::Operations {
                            load: wgpu::LoadOp::Clear(0.0),
                            store: wgpu::StoreOp::Discard,
                        }),
                        stencil_ops: None,
                    }),
                    timestamp_writes: None,
                    occlusion_query_set: None,
                    multiview_mask: None,
                });
                pass.set_bind_group(0, &batch.render[p], &[]);
                pass.set_vertex_buffer(0, self.vertices.slice(..));
                let instances = 0..batch.count * 5;
                pass.set_pipeline(&self.front);
                pass.draw(0..self.vertex_count, instances.clone());
                pass.set_pipeline(&self.back);
                pass.draw(0..self.vertex_count, instances);
            }
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("gather_reduce"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.reduce);
            pass.set_bind_group(0, &batch.reduce[p], &[]);
            pass.dispatch_workgroups(batch.count, 1, 1);
        }
        encoder.copy_buffer_to_buffer(&self.gathered, 0, &self.readback, 0, None);
        self.ctx.queue.submit([encoder.finish()]);
        let bytes = read_buffer(&self.ctx, &self.readback).map_err(GatherError::Gpu)?;
        self.ctx.poll_errors().map_err(GatherError::Gpu)?;
        self.parity = 1 - p;
        let floats: &[f32] = bytemuck::try_cast_slice(&bytes)
            .map_err(|e| GatherError::Gpu(ReadbackError::Layout(e).into()))?;
        Ok(floats
            .chunks_exact(4)
            .take(self.receivers)
            .map(|c| [c[0], c[1], c[2]])
            .collect())
    }
}

/// `gather.wgsl` with the light map's storage format.
fn shader(map_format: wgpu::TextureFormat) -> String {
    let format = if map_format == MAP_FORMAT {
        "rgba32float"
    } else {
        "rgba16float"
    };
    include_str!("gather.wgsl").replace("rgba16float", format)
}

fn entry(binding: u32, resource: wgpu::BindingResource<'_>) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry { binding, resource }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_normalisation_matches_the_analytic_sum() {
        // The unnormalised delta form factors sum to about 1 (exactly in the limit).
        for res in [8, 64, 256] {
            let total = 1.0 / normalisation(res);
            assert!((total - 1.0).abs() < 0.02, "{res}: {total}");
        }
        assert!((1.0 / normalisation(512) - 1.0).abs() < 1e-4);
    }

    #[test]
    fn the_shader_parses_and_validates() {
        for format in [MAP_FORMAT, MAP_FORMAT_HALF] {
            let module = naga::front::wgsl::parse_str(&shader(format)).expect("parse");
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            )
            .validate(&module)
            .expect("valid");
        }
    }
}
