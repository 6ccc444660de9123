//! Shared helpers for the GPU tests: the adapter, uploads, node runs, and small scenes.
#![allow(dead_code)]

use glam::{DVec3, Vec3};
use radiant_render::GpuContext;
use radiant_render::capture::{Image, read_texture};
use radiant_render::graph::{RenderGraph, TextureDesc, TextureHandle, TexturePool};
use radiant_render::scene::{CameraView, RenderScene, Vertex};

/// The GPU, or a failure that says how to get one. Never a silent pass.
pub fn gpu() -> GpuContext {
    GpuContext::headless().unwrap_or_else(|e| {
        panic!("GPU tests need an adapter: {e}. Run tools/test.sh, which installs lavapipe.")
    })
}

/// Uploads RGBA f32 texels into a texture of `format` (Rgba32Float or Rgba16Float).
pub fn upload(
    gpu: &GpuContext,
    width: u32,
    height: u32,
    format: wgpu::TextureFormat,
    texels: &[[f32; 4]],
) -> wgpu::Texture {
    let bytes: Vec<u8> = match format {
        wgpu::TextureFormat::Rgba32Float => bytemuck::cast_slice(texels).to_vec(),
        wgpu::TextureFormat::Rgba16Float => texels
            .iter()
            .flatten()
            .flat_map(|&x| f32_to_f16(x).to_le_bytes())
            .collect(),
        other => panic!("upload: unsupported {other:?}"),
    };
    let tex = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("test_input"),
        size: wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let bpp = bytes.len() as u32 / (width * height);
    gpu.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture: &tex,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        &bytes,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(width * bpp),
            rows_per_image: Some(height),
        },
        wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
    );
    tex
}

fn f32_to_f16(x: f32) -> u16 {
    // Exact for the values the tests use (small integers, halves, powers of two).
    let bits = x.to_bits();
    let sign = ((bits >> 16) & 0x8000) as u16;
    if x == 0.0 {
        return sign;
    }
    let e = ((bits >> 23) & 0xff) as i32 - 127 + 15;
    let m = (bits & 0x7f_ffff) >> 13;
    assert!(
        (1..31).contains(&e),
        "value {x} out of the test's f16 range"
    );
    sign | ((e as u16) << 10) | m as u16
}

/// Imports `input`, lets `build` add passes that return an output, exports it, runs the graph
/// and reads the output back.
pub fn run_node(
    gpu: &GpuContext,
    input: &wgpu::Texture,
    build: impl FnOnce(&mut RenderGraph, TextureHandle) -> TextureHandle,
) -> Image {
    let mut g = RenderGraph::new();
    let desc = TextureDesc {
        width: input.width(),
        height: input.height(),
        format: input.format(),
        usage: input.usage(),
    };
    let h = g.import("test_input", desc);
    let out = build(&mut g, h);
    g.export(out);
    let mut pool = TexturePool::new();
    let compiled = g
        .compile()
        .expect("graph compiles")
        .realize(&gpu.device, &mut pool);
    let view = input.create_view(&Default::default());
    compiled.execute(gpu, &[&view]).expect("executes");
    gpu.take_errors().expect("no GPU errors");
    read_texture(gpu, compiled.texture(out).expect("exported")).expect("readback")
}

/// A quad with corners `p0`, `p0 + u`, `p0 + u + v`, `p0 + v` (counter-clockwise seen from
/// the side its normal points to), texture coordinates (0, 0) to (1, 1) along `u` and `v`.
pub fn quad(vertices: &mut Vec<Vertex>, p0: Vec3, u: Vec3, v: Vec3, albedo: [f32; 3]) {
    let n = u.cross(v).normalize().to_array();
    let corners = [p0, p0 + u, p0 + u + v, p0 + v];
    let uvs = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    for k in [0, 1, 2, 0, 2, 3] {
        vertices.push(Vertex {
            position: corners[k].to_array(),
            normal: n,
            albedo,
            emissive: [0.0; 3],
            lightmap_uv: [0.5, 0.5],
            uv: uvs[k],
            lightmap_page: 0,
        });
    }
}

/// A scene from vertices, seen by a camera at `eye` looking at `at`, with a constant light map
/// of `h` (so the light-map term is `albedo × h`).
pub fn scene(vertices: Vec<Vertex>, eye: Vec3, at: Vec3, h: f32) -> RenderScene {
    RenderScene {
        origin: DVec3::ZERO,
        indices: (0..vertices.len() as u32).collect(),
        vertices,
        textures: Vec::new(),
        materials: Vec::new(),
        draws: Vec::new(),
        instances: Vec::new(),
        instance_uvs: Vec::new(),
        sky: None,
        atlas: None,
        lights: Vec::new(),
        camera: CameraView {
            position: eye.as_dvec3(),
            forward: (at - eye).normalize(),
            up: Vec3::Y,
            yfov: 0.9,
            near: 0.05,
            far: 20.0,
        },
        lightmap: Some(radiant_render::scene::LightMap {
            width: 1,
            height: 1,
            pages: 1,
            texels: vec![[h; 3]],
        }),
        probes: None,
    }
}

/// The world position seen at the centre of pixel (x, y), by intersecting the camera ray with
/// the plane `dot(n, p) = d`.
pub fn pixel_on_plane(
    cam: &CameraView,
    width: u32,
    height: u32,
    x: u32,
    y: u32,
    n: Vec3,
    d: f32,
) -> Vec3 {
    let view = cam.view(DVec3::ZERO);
    let proj = cam.projection(width as f32 / height as f32);
    let inv = (proj * view).inverse();
    let ndc_x = (x as f32 + 0.5) / width as f32 * 2.0 - 1.0;
    let ndc_y = 1.0 - (y as f32 + 0.5) / height as f32 * 2.0;
    let a = inv.project_point3(Vec3::new(ndc_x, ndc_y, 0.0));
    let b = inv.project_point3(Vec3::new(ndc_x, ndc_y, 1.0));
    let dir = b - a;
    let t = (d - n.dot(a)) / n.dot(dir);
    a + dir * t
}

/// Mean structural similarity (Wang et al. 2004) of two equal-size luminance images in [0, 1],
/// over 8×8 windows with stride 4.
pub fn ssim(a: &[f64], b: &[f64], width: usize, height: usize) -> f64 {
    let (c1, c2) = ((0.01f64).powi(2), (0.03f64).powi(2));
    let mut total = 0.0;
    let mut n = 0.0;
    for y0 in (0..height.saturating_sub(7)).step_by(4) {
        for x0 in (0..width.saturating_sub(7)).step_by(4) {
            let (mut ma, mut mb) = (0.0, 0.0);
            for y in y0..y0 + 8 {
                for x in x0..x0 + 8 {
                    ma += a[y * width + x];
                    mb += b[y * width + x];
                }
            }
            ma /= 64.0;
            mb /= 64.0;
            let (mut va, mut vb, mut cov) = (0.0, 0.0, 0.0);
            for y in y0..y0 + 8 {
                for x in x0..x0 + 8 {
                    let (da, db) = (a[y * width + x] - ma, b[y * width + x] - mb);
                    va += da * da;
                    vb += db * db;
                    cov += da * db;
                }
            }
            va /= 63.0;
            vb /= 63.0;
            cov /= 63.0;
            total += ((2.0 * ma * mb + c1) * (2.0 * cov + c2))
                / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            n += 1.0;
        }
    }
    total / n
}
