//! The GPU half of the gather: buffers, the two radiosity maps, the hemicube atlases,
//! pipelines, and one sweep as one command buffer.
//!
//! A hemicube pixel holds what it sees (light-map coordinates and page), not a colour, so a
//! receiver's hemicube, which does not change between sweeps, is drawn once and kept: each
//! later sweep is only the reduction (one compute pass per batch), which looks the current
//! radiosity map up. Batches whose ids do not fit [`Setup::keep_bytes`] are drawn again every
//! sweep into one shared atlas.

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
use radiant_render::GpuContext;
use radiant_render::capture::{ReadbackError, read_buffer};
use radiant_render::util::{storage_entry, storage_rw_entry, uniform_entry};
use std::collections::HashMap;

use radiant_scene::atlas::Atlas;
use radiant_scene::{AlphaMasks, Scene};
use wgpu::util::DeviceExt;

use crate::{Frame, GatherError};

/// The radiosity maps hold f32 where the adapter filters it, else half floats. (With half
/// floats a stiff furnace, ρ = 0.9, stalled 0.8 % short of its fixed point: once a sweep's
/// increment fell below half a unit in the last place, nothing changed.)
const MAP_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const MAP_FORMAT_HALF: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
/// What a hemicube pixel sees (`gather.wgsl`): x the light-map coordinates (two unorm16: steps
/// of 1/8 texel on the largest page, 8192), y the page + 1; y = 0 nothing (the sky), all ones a
/// back face.
const ID_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rg32Uint;
/// Bytes of one hemicube pixel's id.
pub(crate) const ID_BYTES: u64 = 8;
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
    /// Its surface's mean reflectance, and the emission it shows in the hemicubes.
    pub reflectance: [f32; 4],
    pub emission: [f32; 4],
}

/// A vertex of a baked triangle.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct GpuVertex {
    position: [f32; 3],
    uv: [f32; 2],
    page: u32,
    /// The alpha mask's texture coordinates, and the mask ([`NO_MASK`]: opaque).
    tex: [f32; 2],
    mask: u32,
}

/// The mask value of a vertex whose triangle is opaque (no alpha lookup).
const NO_MASK: u32 = u32::MAX;

/// An alpha mask as `gather.wgsl` reads it: its image in [`Masks::images`], the sampler
/// (wrap along U in bits 0–1, along V in 2–3: 0 repeat, 1 mirrored, 2 clamp; bit 4 nearest),
/// the cutoff and the base colour factor's alpha.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuMask {
    image: u32,
    sampler: u32,
    cutoff: f32,
    factor: f32,
}

/// The alpha masks of the drawn triangles: masks, their images (byte offset into `alpha`,
/// width, height) and the images' alpha bytes, four to a word.
#[derive(Default)]
pub(crate) struct Masks {
    masks: Vec<GpuMask>,
    images: Vec<[u32; 4]>,
    alpha: Vec<u8>,
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
    sky_kind: u32,
    pad: [u32; 4],
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
    /// Three per triangle, into `vertices`.
    pub indices: &'a [u32],
    /// The alpha masks the vertices name.
    pub masks: &'a Masks,
    pub sky: SkyUniform,
    pub near: f32,
    /// At most this many bytes of hemicube ids kept between sweeps.
    pub keep_bytes: u64,
}

/// The baked triangles' vertices in the local frame, with their light-map coordinates.
///
/// Indexed: corners with the same position, light-map coordinates and page are one vertex, so
/// a CPU rasteriser's vertex cache shades a shared corner once per face instead of once per
/// triangle (every hemicube face runs the vertex stage over the whole scene).
pub(crate) fn vertices(
    scene: &Scene,
    atlas: &Atlas,
    frame: &Frame,
    baked: &[bool],
    alpha: Option<&AlphaMasks>,
) -> (Vec<GpuVertex>, Vec<u32>, Masks) {
    use radiant_scene::texture::Wrap;
    let mut out = Vec::with_capacity(scene.triangles.len() * 3);
    let mut indices = Vec::with_capacity(scene.triangles.len() * 3);
    let mut seen: HashMap<[u32; 9], u32> = HashMap::new();
    let mut masks = Masks::default();
    let mut mask_of: HashMap<[u32; 4], u32> = HashMap::new();
    let mut image_of: HashMap<u32, u32> = HashMap::new();
    'triangles: for (i, t) in scene.triangles.iter().enumerate() {
        if !baked[i] {
            continue;
        }
        // Its mask: none (opaque), cut wholly (not drawn), or a texture's alpha.
        let (mask, tex) = match alpha.and_then(|a| Some((a, a.mask(i as u32)?))) {
            None => (NO_MASK, [glam::Vec2::ZERO; 3]),
            Some((a, m)) => 'mask: {
                let Some(img) = a.images().get(m.texture.image as usize) else {
                    if m.factor < m.cutoff {
                        continue 'triangles;
                    }
                    break 'mask (NO_MASK, [glam::Vec2::ZERO; 3]);
                };
                let image = *image_of.entry(m.texture.image).or_insert_with(|| {
                    masks
                        .images
                        .push([masks.alpha.len() as u32, img.width, img.height, 0]);
                    masks.alpha.extend(img.pixels.chunks_exact(4).map(|p| p[3]));
                    (masks.images.len() - 1) as u32
                });
                let wrap = |w: Wrap| match w {
                    Wrap::Repeat => 0,
                    Wrap::MirroredRepeat => 1,
                    Wrap::ClampToEdge => 2,
                };
                let sm = m.texture.sampler;
                let sampler =
                    wrap(sm.wrap_s) | (wrap(sm.wrap_t) << 2) | (u32::from(sm.nearest) << 4);
                let key = [image, sampler, m.cutoff.to_bits(), m.factor.to_bits()];
                let mask = *mask_of.entry(key).or_insert_with(|| {
                    masks.masks.push(GpuMask {
                        image,
                        sampler,
                        cutoff: m.cutoff,
                        factor: m.factor,
                    });
                    (masks.masks.len() - 1) as u32
                });
                (mask, m.uv)
            }
        };
        for (k, corner) in tex.iter().enumerate() {
            let p: DVec3 = frame.local(t.vertices[k]);
            let v = GpuVertex {
                position: [p.x as f32, p.y as f32, p.z as f32],
                uv: atlas.uv[i][k].to_array(),
                page: atlas.page[i],
                tex: corner.to_array(),
                mask,
            };
            let key = [
                v.position[0].to_bits(),
                v.position[1].to_bits(),
                v.position[2].to_bits(),
                v.uv[0].to_bits(),
                v.uv[1].to_bits(),
                v.page,
                v.tex[0].to_bits(),
                v.tex[1].to_bits(),
                v.mask,
            ];
            let index = *seen.entry(key).or_insert_with(|| {
                out.push(v);
                (out.len() - 1) as u32
            });
            indices.push(index);
        }
    }
    (out, indices, masks)
}

struct Batch {
    count: u32,
    /// Its cells' extent in pixels.
    size: [u32; 2],
    /// Its hemicubes' ids (its own texture when kept, else the shared one) and a depth buffer
    /// of the same size.
    ids: wgpu::TextureView,
    depth: wgpu::TextureView,
    /// Drawn once and kept, or drawn every sweep.
    kept: bool,
    /// Whether its kept ids are drawn.
    drawn: bool,
    render: wgpu::BindGroup,
    reduce: [wgpu::BindGroup; 2],
}

/// Everything on the GPU.
pub(crate) struct Gpu {
    ctx: GpuContext,
    ids: wgpu::RenderPipeline,
    reduce: wgpu::ComputePipeline,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    index_count: u32,
    batches: Vec<Batch>,
    gathered: wgpu::Buffer,
    /// The sweep's step weight ω (`gather.wgsl`'s `Sweep`).
    sweep_uniform: wgpu::Buffer,
    readback: wgpu::Buffer,
    receivers: usize,
    /// Which radiosity map the next sweep reads (it writes the other).
    parity: usize,
}

/// The unnormalised delta form factors `d² / (π q²)` (times the height on a side face) of the
/// pixels of a hemicube cell of `res` (3R × R: the top face, then the side faces two by two, as
/// `gather.wgsl` lays them out and as the CPU hemicube weighs them), in f64.
fn delta_form_factors(res: u32) -> Vec<f64> {
    let d = 2.0 / f64::from(res);
    let c = |i: u32| -1.0 + (f64::from(i) + 0.5) * d;
    let half = res / 2;
    let mut out = Vec::with_capacity(3 * res as usize * res as usize);
    for py in 0..res {
        for px in 0..3 * res {
            let x = c(px % res);
            let w = if px < res {
                let y = c(py);
                let q = x * x + y * y + 1.0;
                1.0 / (q * q)
            } else {
                let z = 1.0 - (f64::from(py % half) + 0.5) * d;
                let q = x * x + z * z + 1.0;
                z / (q * q)
            };
            out.push(w * d * d / std::f64::consts::PI);
        }
    }
    out
}

/// The multiplier buffer: [`delta_form_factors`] scaled to sum to exactly 1.
fn multipliers(res: u32) -> Vec<f32> {
    let w = delta_form_factors(res);
    let total: f64 = w.iter().sum();
    w.iter().map(|v| (v / total) as f32).collect()
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
        let atlas_w = cols * 3 * res;
        let (pages, mw, mh) = (s.atlas.pages.max(1), s.atlas.width, s.atlas.height);
        if pages > device.limits().max_texture_array_layers {
            return Err(GatherError::InvalidSetting {
                field: "light-map pages",
                value: f64::from(pages),
                range: "at most the adapter's texture array layers",
            });
        }
        if mw > limit || mh > limit {
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
        let target = |label: &str, format, usage, height: u32| {
            device
                .create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size: wgpu::Extent3d {
                        width: atlas_w,
                        height,
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
        // Batches in order, each kept with its own ids if they fit what is left of
        // `keep_bytes` (the batch's whole atlas counts, empty cells too); the rest are drawn
        // every sweep into one shared atlas (not counted, nor are the depth buffers).
        let counts: Vec<u32> = (0..n)
            .step_by(per_batch as usize)
            .map(|first| (n - first).min(per_batch))
            .collect();
        let height = |count: u32| count.div_ceil(cols) * res;
        let mut kept_bytes = 0u64;
        let kept: Vec<bool> = counts
            .iter()
            .map(|&count| {
                let bytes = u64::from(atlas_w) * u64::from(height(count)) * ID_BYTES;
                let keep = kept_bytes + bytes <= s.keep_bytes;
                if keep {
                    kept_bytes += bytes;
                }
                keep
            })
            .collect();
        let ids_usage =
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
        let shared = counts
            .iter()
            .zip(&kept)
            .filter(|(_, k)| !**k)
            .map(|(&count, _)| height(count))
            .max()
            .map(|h| (h, target("gather_hemicubes", ID_FORMAT, ids_usage, h)));
        // One depth buffer per atlas height.
        let mut depths: Vec<(u32, wgpu::TextureView)> = Vec::new();
        let mut depth = |h: u32| {
            if let Some((_, v)) = depths.iter().find(|(dh, _)| *dh == h) {
                return v.clone();
            }
            let v = target(
                "gather_depth",
                DEPTH_FORMAT,
                wgpu::TextureUsages::RENDER_ATTACHMENT,
                h,
            );
            depths.push((h, v.clone()));
            v
        };
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("gather_light_map"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });

        // A storage buffer, never empty (a binding needs bytes).
        let storage = |label: &str, bytes: &[u8]| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: if bytes.is_empty() { &[0u8; 16] } else { bytes },
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let receivers = storage("gather_receivers", bytemuck::cast_slice(s.receivers));
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("gather_vertices"),
            contents: bytemuck::cast_slice(s.vertices),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let mask_infos = storage("gather_masks", bytemuck::cast_slice(&s.masks.masks));
        let mask_images = storage("gather_mask_images", bytemuck::cast_slice(&s.masks.images));
        let mut alpha_words = vec![0u32; s.masks.alpha.len().div_ceil(4)];
        for (k, &a) in s.masks.alpha.iter().enumerate() {
            alpha_words[k / 4] |= u32::from(a) << (8 * (k % 4));
        }
        let mask_alpha = storage("gather_mask_alpha", bytemuck::cast_slice(&alpha_words));
        let indices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("gather_indices"),
            contents: bytemuck::cast_slice(s.indices),
            usage: wgpu::BufferUsages::INDEX,
        });
        let out_bytes = u64::from(n.max(1)) * 16;
        let gathered = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gather_out"),
            size: out_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        // H two sweeps back, for the accelerated step.
        let older = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gather_older"),
            size: out_bytes,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let sweep_uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gather_sweep"),
            size: 16,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gather_readback"),
            size: out_bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        let vs = wgpu::ShaderStages::VERTEX;
        let fs = wgpu::ShaderStages::FRAGMENT;
        let render_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gather_render"),
            entries: &[
                uniform_entry(0, vs),
                storage_entry(1, vs),
                storage_entry(11, fs),
                storage_entry(12, fs),
                storage_entry(13, fs),
            ],
        });
        let cs = wgpu::ShaderStages::COMPUTE;
        let reduce_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gather_reduce"),
            entries: &[
                uniform_entry(0, cs),
                storage_entry(1, cs),
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: cs,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 4,
                    visibility: cs,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: cs,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                storage_rw_entry(6, cs),
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
                storage_entry(8, cs),
                storage_rw_entry(9, cs),
                uniform_entry(10, cs),
            ],
        });

        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("gather"),
            source: wgpu::ShaderSource::Wgsl(
                shader(map_format, reduce_group(ctx.info.device_type)).into(),
            ),
        });
        let render_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("gather_render"),
            bind_group_layouts: &[Some(&render_layout)],
            immediate_size: 0,
        });
        let attributes = wgpu::vertex_attr_array![
            0 => Float32x3, 1 => Float32x2, 2 => Uint32, 3 => Float32x2, 4 => Uint32
        ];
        let raster = |label: &str, fs: &str| {
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
                    cull_mode: None,
                    ..Default::default()
                },
                // Reversed depth: nearer is greater. Front and back faces in one pass, both sides
                // drawn (`id_fs` sets a back face a little farther).
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
                        format: ID_FORMAT,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let ids = if s.masks.masks.is_empty() {
            raster("gather_ids", "id_fs")
        } else {
            raster("gather_ids", "id_masked_fs")
        };
        let reduce_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("gather_reduce"),
            bind_group_layouts: &[Some(&reduce_layout)],
            immediate_size: 0,
        });
        let compute = |label: &str, entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: Some(&reduce_pl),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let reduce = compute("gather_reduce", "reduce_cs");
        let seed = compute("gather_seed", "seed_cs");

        let (sky_kind, sky_a, sky_b) = match s.sky {
            SkyUniform::None => (0, [0.0; 3], [0.0; 3]),
            SkyUniform::Uniform(r) => (1, r, [0.0; 3]),
            SkyUniform::Gradient(z, h) => (2, z, h),
        };
        let v4 = |v: [f64; 3]| [v[0] as f32, v[1] as f32, v[2] as f32, 0.0];
        let weights = storage(
            "gather_multipliers",
            bytemuck::cast_slice(&multipliers(res)),
        );
        let mut batches = Vec::new();
        let mut first = 0u32;
        for (&count, &kept) in counts.iter().zip(&kept) {
            let (h, ids) = match (&shared, kept) {
                (Some((h, ids)), false) => (*h, ids.clone()),
                _ => (
                    height(count),
                    target("gather_hemicubes_kept", ID_FORMAT, ids_usage, height(count)),
                ),
            };
            // The batch's own size even in the shared atlas (drawn through a viewport of that
            // size), so a batch rasterises the same, kept or not.
            let params = Params {
                atlas: [atlas_w as f32, height(count) as f32],
                res,
                cols,
                first,
                count,
                near: s.near,
                sky_kind,
                pad: [0; 4],
                sky_a: v4(sky_a),
                sky_b: v4(sky_b),
            };
            let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("gather_params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM,
            });
            let render = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("gather_render"),
                layout: &render_layout,
                entries: &[
                    entry(0, uniform.as_entire_binding()),
                    entry(1, receivers.as_entire_binding()),
                    entry(11, mask_infos.as_entire_binding()),
                    entry(12, mask_images.as_entire_binding()),
                    entry(13, mask_alpha.as_entire_binding()),
                ],
            });
            let reduce = |p: usize| {
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("gather_reduce"),
                    layout: &reduce_layout,
                    entries: &[
                        entry(0, uniform.as_entire_binding()),
                        entry(1, receivers.as_entire_binding()),
                        entry(3, wgpu::BindingResource::TextureView(&map_views[p])),
                        entry(4, wgpu::BindingResource::Sampler(&sampler)),
                        entry(5, wgpu::BindingResource::TextureView(&ids)),
                        entry(6, gathered.as_entire_binding()),
                        entry(7, wgpu::BindingResource::TextureView(&map_views[1 - p])),
                        entry(8, weights.as_entire_binding()),
                        entry(9, older.as_entire_binding()),
                        entry(10, sweep_uniform.as_entire_binding()),
                    ],
                })
            };
            batches.push(Batch {
                count,
                size: [atlas_w, height(count)],
                depth: depth(h),
                reduce: [reduce(0), reduce(1)],
                ids,
                kept,
                drawn: false,
                render,
            });
            first += count;
        }
        // The first sweep reads map 0: seed it with what the emitters show.
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("gather_seed"),
        });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("gather_seed"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&seed);
            for batch in &batches {
                pass.set_bind_group(0, &batch.reduce[1], &[]);
                pass.dispatch_workgroups(batch.count.div_ceil(64), 1, 1);
            }
        }
        ctx.queue.submit([encoder.finish()]);
        ctx.take_errors().map_err(GatherError::Gpu)?;
        Ok(Self {
            ids,
            reduce,
            index_count: s.indices.len() as u32,
            indices,
            vertices,
            batches,
            gathered,
            sweep_uniform,
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

    /// Triangles drawn on every hemicube face.
    pub(crate) fn triangles(&self) -> usize {
        self.index_count as usize / 3
    }

    /// Batches whose hemicube ids are kept between sweeps.
    pub(crate) fn kept_batches(&self) -> usize {
        self.batches.iter().filter(|b| b.kept).count()
    }

    /// One sweep: every batch's hemicubes (drawn now unless kept from an earlier sweep)
    /// reduced with the current radiosity map into the other; returns the new `H` per receiver.
    /// `omega` weighs the step: `H ← ω J(H) + (1 − ω) H_older` (`J` the Jacobi sweep, `H_older`
    /// the sweep before last); 1 is the plain Jacobi sweep. `on_drawn(k, n)` hears when the
    /// k-th of the n batches this sweep draws is drawn (each then goes to the GPU on its own).
    pub(crate) fn sweep(
        &mut self,
        omega: f32,
        on_drawn: &mut dyn FnMut(usize, usize),
    ) -> Result<Vec<[f32; 3]>, GatherError> {
        let p = self.parity;
        let device = &self.ctx.device;
        let to_draw = self.batches.iter().filter(|b| !(b.kept && b.drawn)).count();
        let mut drawn = 0;
        self.ctx.queue.write_buffer(
            &self.sweep_uniform,
            0,
            bytemuck::bytes_of(&[omega, 0.0, 0.0, 0.0]),
        );
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("gather_sweep"),
        });
        for batch in &self.batches {
            let draws = !(batch.kept && batch.drawn);
            if draws {
                let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("gather_hemicubes"),
                    color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                        view: &batch.ids,
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                            store: wgpu::StoreOp::Store,
                        },
                    })],
                    depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                        view: &batch.depth,
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
                pass.set_viewport(
                    0.0,
                    0.0,
                    batch.size[0] as f32,
                    batch.size[1] as f32,
                    0.0,
                    1.0,
                );
                pass.set_bind_group(0, &batch.render, &[]);
                pass.set_vertex_buffer(0, self.vertices.slice(..));
                pass.set_index_buffer(self.indices.slice(..), wgpu::IndexFormat::Uint32);
                pass.set_pipeline(&self.ids);
                pass.draw_indexed(0..self.index_count, 0, 0..batch.count * 5);
            }
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("gather_reduce"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.reduce);
            pass.set_bind_group(0, &batch.reduce[p], &[]);
            pass.dispatch_workgroups(batch.count, 1, 1);
            drop(pass);
            if draws {
                // A drawing batch is the long part of a sweep: say when each is done.
                let done = std::mem::replace(
                    &mut encoder,
                    device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                        label: Some("gather_sweep"),
                    }),
                );
                self.ctx.queue.submit([done.finish()]);
                let _ = device.poll(wgpu::PollType::wait_indefinitely());
                drawn += 1;
                on_drawn(drawn, to_draw);
            }
        }
        encoder.copy_buffer_to_buffer(&self.gathered, 0, &self.readback, 0, None);
        self.ctx.queue.submit([encoder.finish()]);
        let bytes = read_buffer(&self.ctx, &self.readback).map_err(GatherError::Gpu)?;
        self.ctx.poll_errors().map_err(GatherError::Gpu)?;
        for batch in &mut self.batches {
            batch.drawn = batch.kept;
        }
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

/// Invocations reducing one receiver: a CPU rasteriser runs a workgroup's invocations as SIMD
/// rows and pays for every barrier, so it gets one row; a GPU gets two or more waves.
fn reduce_group(device: wgpu::DeviceType) -> u32 {
    if device == wgpu::DeviceType::Cpu {
        8
    } else {
        64
    }
}

/// `gather.wgsl` with the radiosity maps' storage format and the reduction's workgroup size.
fn shader(map_format: wgpu::TextureFormat, group: u32) -> String {
    let format = if map_format == MAP_FORMAT {
        "rgba32float"
    } else {
        "rgba16float"
    };
    include_str!("gather.wgsl")
        .replace("rgba16float", format)
        .replace(
            "const GROUP: u32 = 8u;",
            &format!("const GROUP: u32 = {group}u;"),
        )
        .replace("@workgroup_size(8)", &format!("@workgroup_size({group})"))
}

fn entry(binding: u32, resource: wgpu::BindingResource<'_>) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry { binding, resource }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_delta_form_factors_sum_to_the_hemisphere() {
        // The unnormalised delta form factors sum to about 1 (exactly in the limit); the
        // multipliers to 1, and the top face's centre weighs the most.
        for res in [8, 64, 256] {
            let total: f64 = delta_form_factors(res).iter().sum();
            assert!((total - 1.0).abs() < 0.02, "{res}: {total}");
            let m = multipliers(res);
            assert_eq!(m.len(), 3 * res as usize * res as usize);
            let sum: f64 = m.iter().map(|&v| f64::from(v)).sum();
            assert!((sum - 1.0).abs() < 1e-5, "{res}: {sum}");
            let centre = (res / 2 * 3 * res + res / 2) as usize;
            assert!(m.iter().all(|&v| v > 0.0 && v <= m[centre]));
        }
        let total: f64 = delta_form_factors(512).iter().sum();
        assert!((total - 1.0).abs() < 1e-4);
    }

    #[test]
    fn the_shader_parses_and_validates() {
        for (format, group) in [(MAP_FORMAT, 8), (MAP_FORMAT_HALF, 64)] {
            let source = shader(format, group);
            // Both substitutions took: the reduction's array and its workgroup agree.
            assert!(source.contains(&format!("@workgroup_size({group})")));
            assert!(source.contains(&format!("const GROUP: u32 = {group}u;")));
            let module = naga::front::wgsl::parse_str(&source).expect("parse");
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            )
            .validate(&module)
            .expect("valid");
        }
    }
}
