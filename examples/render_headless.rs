//! Renders the Cornell box (or a glTF) offscreen through the whole frame — G-buffer, SSAO,
//! tiled lighting, bloom, tone mapping — with no window, and writes `frame.png` (tone-mapped,
//! 8-bit sRGB) and `frame.exr` (linear radiance before tone mapping).
//!
//! The light map comes from a radiosity bake of the scene (or `--synthetic` for a fast,
//! shadowless stand-in). `--timings N` measures each pass over N frames; `--memory` prints the
//! graph's texture memory with and without each effect.
//!
//! `cargo run --release --example render_headless -- --out DIR [--size 1280x720]`

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Parser;
use radiant::color::Tonemap;
use radiant::post::bloom::Bloom;
use radiant::post::blur::GaussianBlur;
use radiant::post::frame::{FrameRenderer, FrameSettings};
use radiant::post::sobel::Sobel;
use radiant::radiosity::{Bake, BakeParams};
use radiant::render::GpuContext;
use radiant::render::capture::{write_exr, write_png};
use radiant::render::lighting::DebugView;
use radiant::render::scene::RenderScene;

#[derive(Parser)]
struct Args {
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
    /// A glTF scene (default: the builtin Cornell box).
    scene: Option<PathBuf>,
    /// Image size, WxH.
    #[arg(long, default_value = "1280x720")]
    size: String,
    /// Light-map texels per scene unit (default: automatic).
    #[arg(long)]
    texel_density: Option<f64>,
    /// Use a shadowless synthetic light map instead of baking.
    #[arg(long)]
    synthetic: bool,
    /// Turn SSAO off.
    #[arg(long)]
    no_ssao: bool,
    /// Turn bloom off.
    #[arg(long)]
    no_bloom: bool,
    /// The lecture's bloom (bright pass + repeated Gaussian, additive).
    #[arg(long)]
    lecture_bloom: bool,
    /// Sobel edge overlay.
    #[arg(long)]
    sobel: bool,
    /// Gaussian blur of the final image.
    #[arg(long)]
    blur: bool,
    /// Tone-map operator: clamp, reinhard, reinhard-extended, aces, agx, pbr-neutral.
    #[arg(long, default_value = "aces")]
    tonemap: String,
    /// Exposure, stops.
    #[arg(long, default_value_t = 0.0)]
    exposure: f32,
    /// Debug view: lit, albedo, normal, material, lightmap, emissive, depth, ao, direct.
    #[arg(long, default_value = "lit")]
    debug: String,
    /// Measure per-pass times over this many frames and print the medians.
    #[arg(long, default_value_t = 0)]
    timings: usize,
    /// Print the graph's texture memory with and without each effect.
    #[arg(long)]
    memory: bool,
    /// With `--synthetic`: draw every triangle on its own (no instances), to compare.
    #[arg(long)]
    flatten: bool,
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "warn,radiant=info".into()),
        )
        .init();
    let args = Args::parse();
    let (w, h) = args
        .size
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
        .context("--size must be WxH, e.g. 1280x720")?;
    let Some(operator) = Tonemap::from_name(&args.tonemap) else {
        bail!("unknown --tonemap {:?}", args.tonemap);
    };
    let Some(debug_view) = DebugView::ALL.into_iter().find(|v| v.name() == args.debug) else {
        bail!("unknown --debug {:?}", args.debug);
    };
    let scene = match &args.scene {
        Some(p) => radiant::scene::load_gltf(p)?,
        None => radiant::scene::builtin("cornell-box")?,
    };
    let render_scene = if args.synthetic {
        let mut rs = if args.flatten {
            RenderScene::from_scene_flattened(&scene, args.texel_density)?
        } else {
            RenderScene::from_scene(&scene, args.texel_density)?
        };
        rs.fill_synthetic_lightmap(0.02);
        rs
    } else if !scene.has_emitters() {
        // Nothing to bake: direct light and emission only.
        radiant::bridge::render_scene(&scene, None, args.texel_density)?
    } else {
        let t = std::time::Instant::now();
        let bake = Bake::new(&scene, &BakeParams::default())?.run_to_end(&mut |_| {})?;
        println!(
            "baked {} elements in {:.2} s",
            bake.mesh.element_count(),
            t.elapsed().as_secs_f64()
        );
        radiant::bridge::render_scene(&scene, Some(&bake), args.texel_density)?
    };

    let gpu = GpuContext::headless()?;
    println!("adapter: {} ({:?})", gpu.info.name, gpu.info.backend);
    let mut frame = FrameRenderer::new(&gpu, &render_scene)?;
    let (vertices, draws) = frame.scene_size();
    println!(
        "scene: {} triangles, {vertices} vertices uploaded in {draws} draws ({} instances)",
        render_scene.vertices.len() / 3,
        render_scene.instances.len().saturating_sub(1)
    );
    let mut settings = FrameSettings::default();
    settings.tonemapping.operator = operator;
    settings.tonemapping.exposure = args.exposure;
    settings.debug_view = debug_view;
    if args.no_ssao {
        settings.ssao = None;
    }
    if args.no_bloom {
        settings.bloom = None;
    } else if args.lecture_bloom {
        settings.bloom = Some(Bloom::LECTURE);
    }
    if args.sobel {
        settings.sobel = Some(Sobel::default());
    }
    if args.blur {
        settings.blur = Some(GaussianBlur::default());
    }

    let t = std::time::Instant::now();
    let capture = frame.capture(&gpu, w, h, &settings)?;
    println!(
        "frame {w}×{h} in {:.1} ms (first, compiling)",
        t.elapsed().as_secs_f64() * 1e3
    );
    std::fs::create_dir_all(&args.out)?;
    write_png(&args.out.join("frame.png"), &capture.ldr)?;
    write_exr(&args.out.join("frame.exr"), &capture.hdr)?;
    if let Some(r) = frame.report() {
        print!("{r}");
    }
    println!("wrote {}/frame.png and frame.exr", args.out.display());

    if args.timings > 0 {
        let target = radiant::render::util::target_texture(
            &gpu.device,
            "timing_target",
            w,
            h,
            wgpu_format(),
        );
        let view = target.create_view(&Default::default());
        let format = wgpu_format();
        let mut runs: Vec<Vec<(&'static str, f64)>> = Vec::new();
        let mut gpu_times = false;
        for _ in 0..args.timings {
            let t = frame.render_timed(&gpu, &view, w, h, format, &settings)?;
            gpu_times = t.gpu;
            runs.push(t.passes);
        }
        println!(
            "per-pass times at {w}×{h}, median of {} frames ({}):",
            args.timings,
            if gpu_times {
                "GPU timestamps"
            } else {
                "CPU wall time per pass, submitted alone"
            }
        );
        let mut total = 0.0;
        for (i, (name, _)) in runs[0].iter().enumerate() {
            let mut v: Vec<f64> = runs.iter().map(|r| r[i].1).collect();
            v.sort_by(f64::total_cmp);
            let m = v[v.len() / 2];
            total += m;
            println!("  {name:<24} {m:9.3} ms");
        }
        println!("  {:<24} {total:9.3} ms", "total");
    }

    if args.memory {
        let full = FrameSettings {
            sobel: Some(Sobel::default()),
            blur: Some(GaussianBlur::default()),
            ..FrameSettings::default()
        };
        let variants: [(&str, FrameSettings); 6] = [
            ("everything", full),
            ("default (SSAO + bloom)", FrameSettings::default()),
            (
                "no SSAO",
                FrameSettings {
                    ssao: None,
                    ..FrameSettings::default()
                },
            ),
            (
                "no bloom",
                FrameSettings {
                    bloom: None,
                    ..FrameSettings::default()
                },
            ),
            (
                "lecture bloom",
                FrameSettings {
                    bloom: Some(Bloom::LECTURE),
                    ..FrameSettings::default()
                },
            ),
            ("minimal", FrameSettings::MINIMAL),
        ];
        println!("graph texture memory at {w}×{h}:");
        for (name, s) in variants {
            let (graph, _) = frame.build_graph(w, h, wgpu_format(), &s)?;
            let r = graph.compile()?.report();
            println!(
                "  {name:<24} {:2} passes, {:2} textures in {:2} allocations, {:7.2} MiB",
                r.passes.len(),
                r.virtual_textures,
                r.physical_textures.len(),
                r.bytes as f64 / 1048576.0
            );
        }
    }
    Ok(())
}

fn wgpu_format() -> radiant::render::wgpu::TextureFormat {
    radiant::render::wgpu::TextureFormat::Rgba8UnormSrgb
}
