//! `radiant render`: bake (unless the scene has nothing to bake), then render one frame headless
//! through the whole chain from the scene's camera.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use radiant::post::frame::{FrameRenderer, FrameSettings};
use radiant::radiosity::BakeParams;
use radiant::render::GpuContext;
use radiant::render::capture::{write_exr, write_png};
use radiant::render::lighting::DebugView;
use radiant::scene::Builtin;
use serde_json::json;

/// Mitsuba 3 path-traced radiance of the builtin Cornell box from its camera, 128×128, 16 384
/// spp (tools/make_cornell_render_reference.py).
const CORNELL_RENDER_REFERENCE: &[u8] =
    include_bytes!("../assets/reference/cornell_box_mitsuba_128.exr");
use crate::args::{Debug, FormFactors, Solver, Tonemap};
use crate::baking;
use crate::common::load_scene;
use crate::output::{ensure_dir, write_atomic};
use crate::{SceneArgs, SolveArgs};

/// `radiant render`.
#[derive(Args, Debug)]
pub(crate) struct RenderArgs {
    #[command(flatten)]
    pub(crate) scene: SceneArgs,
    /// Output directory.
    #[arg(long, short)]
    pub(crate) out: PathBuf,
    /// Image size, WxH.
    #[arg(long, default_value = "1024x1024")]
    pub(crate) size: String,
    /// Leave SSAO out of frame.png.
    #[arg(long)]
    pub(crate) no_ssao: bool,
    /// Leave bloom out of frame.png.
    #[arg(long)]
    pub(crate) no_bloom: bool,
    /// Apply SSAO and bloom to frame.exr too (by default it is pure radiance).
    #[arg(long)]
    pub(crate) exr_effects: bool,
    /// Tone-map operator.
    #[arg(long, value_enum, default_value_t = Tonemap(FrameSettings::default().tonemapping.operator))]
    pub(crate) tonemap: Tonemap,
    /// Exposure in stops.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub(crate) exposure: f32,
    /// Debug view.
    #[arg(long, value_enum, default_value_t = Debug(FrameSettings::default().debug_view))]
    pub(crate) debug: Debug,
    /// Light-map texels per scene unit (metres for glTF); default: automatic (about 256
    /// texels per triangle, 8 M at most; Sponza gets 18 per metre). Lowered where the charts
    /// would not fit one 8192² page.
    #[arg(long, value_parser = crate::args::parse_texel_density)]
    pub(crate) texel_density: Option<f64>,
    /// Solver for the bake.
    #[arg(long, value_enum, default_value_t = Solver(BakeParams::default().solver))]
    pub(crate) method: Solver,
    /// Form factors for the bake.
    #[arg(long, value_enum, default_value_t = FormFactors(BakeParams::default().form_factors))]
    pub(crate) form_factors: FormFactors,
    /// Checkpoint file: load the bake from it when it matches the scene, and write it after
    /// baking.
    #[arg(long)]
    pub(crate) checkpoint: Option<PathBuf>,
    /// A linear path-traced image of the scene from the same camera (EXR) to report the
    /// frame's error against (the builtin Cornell box has one: Mitsuba 3, 128×128).
    #[arg(long)]
    pub(crate) reference_image: Option<PathBuf>,
    /// A glTF node that moves (repeatable): left out of the bake, drawn lit by an irradiance
    /// volume of probes baked from the solution (as a node whose extras hold
    /// `{"radiant": {"dynamic": true}}`).
    #[arg(long, value_name = "NODE")]
    pub(crate) dynamic: Vec<String>,
    /// Distance between the probes that light dynamic nodes, scene units (default: a
    /// sixteenth of the scene's longest extent, coarser where more than 32 768 probes would be
    /// needed).
    #[arg(long, value_name = "METRES", value_parser = crate::args::parse_spacing)]
    pub(crate) probe_spacing: Option<f64>,
    /// Also time each pass over this many frames (median), into render.json.
    #[arg(long, default_value_t = 0)]
    pub(crate) timings: usize,
    #[command(flatten)]
    pub(crate) light_map: crate::LightMapArgs,
    #[command(flatten)]
    pub(crate) solve: SolveArgs,
    #[command(flatten)]
    pub(crate) hierarchy: crate::HierarchyArgs,
}

fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .with_context(|| format!("--size {s:?} must be WxH, e.g. 1280x720"))?;
    let w: u32 = w
        .trim()
        .parse()
        .with_context(|| format!("--size width {w:?}"))?;
    let h: u32 = h
        .trim()
        .parse()
        .with_context(|| format!("--size height {h:?}"))?;
    anyhow::ensure!(
        (1..=16384).contains(&w) && (1..=16384).contains(&h),
        "--size {w}x{h}: each side must be 1 to 16384"
    );
    Ok((w, h))
}

/// Frame settings from the flags.
fn settings(args: &RenderArgs) -> anyhow::Result<FrameSettings> {
    let mut s = FrameSettings::default();
    s.tonemapping.operator = args.tonemap.0;
    s.tonemapping.exposure = args.exposure;
    s.debug_view = args.debug.0;
    if args.no_ssao {
        s.ssao = None;
    }
    if args.no_bloom {
        s.bloom = None;
    }
    s.validate()?;
    Ok(s)
}

/// Bakes the scene as `bake` would (no bake when nothing emits).
fn bake(
    args: &RenderArgs,
    scene: &radiant::scene::Scene,
    params: &BakeParams,
    source: &str,
) -> anyhow::Result<Option<radiant::radiosity::BakeResult>> {
    // No emitters: nothing to bake, and nothing is allocated for it.
    if scene.has_emitters() {
        let h = &args.hierarchy;
        let clustered = baking::use_clustered(h.hierarchy, scene, params)?;
        let checkpoint = args.checkpoint.as_deref();
        Ok(Some(if clustered {
            baking::bake_clustered(scene, params, h, checkpoint, None)?.0
        } else {
            baking::bake_triangles(scene, params, checkpoint)?
        }))
    } else {
        let dynamic_only = scene.surfaces.iter().any(|s| s.dynamic && s.is_emitter());
        println!(
            "{source}: no emitters{}, so no bake; the frame shows punctual lights and emission",
            if dynamic_only {
                " among the static surfaces (dynamic ones are not baked)"
            } else {
                ""
            }
        );
        Ok(None)
    }
}

/// The path-traced image to compare the frame with (`--reference-image`, or the one shipped
/// with the builtin Cornell box), read and checked before anything is baked: a linear radiance
/// image has finite, non-negative values and some light. None when there is no reference.
fn reference_image(args: &RenderArgs) -> anyhow::Result<Option<radiant::render::capture::Image>> {
    let bytes = match (&args.reference_image, args.scene.builtin) {
        (Some(p), _) => crate::common::read_input(
            p,
            "--reference-image",
            4 << 30, // a float EXR of 16384² RGBA texels
        )?,
        (None, Some(crate::args::BuiltinScene(Builtin::CornellBox))) => {
            CORNELL_RENDER_REFERENCE.to_vec()
        }
        _ => return Ok(None),
    };
    radiant::scene::exr_fits(&bytes, 1 << 28)
        .map_err(|e| anyhow::anyhow!("--reference-image: {e}"))?;
    let reference = radiant::render::capture::read_image(&bytes)
        .map_err(|e| anyhow::anyhow!("--reference-image: {e}"))?;
    let w = reference.width.max(1) as usize;
    if let Some((i, t)) = reference
        .texels
        .iter()
        .enumerate()
        .find(|(_, t)| t[..3].iter().any(|v| !v.is_finite() || *v < 0.0))
    {
        anyhow::bail!(
            "--reference-image: pixel ({}, {}) is {:?}: a linear radiance image has finite, \
             non-negative values",
            i % w,
            i / w,
            &t[..3]
        );
    }
    anyhow::ensure!(
        reference
            .texels
            .iter()
            .any(|t| t[..3].iter().any(|&v| v > 0.0)),
        "--reference-image: the image is black ({}×{}, every pixel 0): nothing to compare the \
         frame with",
        reference.width,
        reference.height
    );
    Ok(Some(reference))
}

/// The frame against a path-traced image from the same camera ([`reference_image`]): radiance,
/// no SSAO, no bloom; the whole image and the surfaces alone. Null when there is no reference.
fn against_reference(
    reference: Option<&radiant::render::capture::Image>,
    gpu: &GpuContext,
    frame: &mut FrameRenderer,
) -> anyhow::Result<serde_json::Value> {
    let Some(reference) = reference else {
        return Ok(serde_json::Value::Null);
    };
    {
        let plain = FrameSettings {
            debug_view: DebugView::Lit,
            ..FrameSettings::MINIMAL
        };
        // 4×4 supersampled and box-filtered, like the path tracer's pixels.
        const SS: u32 = 4;
        let ours = frame
            .capture(gpu, reference.width * SS, reference.height * SS, &plain)?
            .hdr
            .box_downsample(SS);
        // Emitter pixels (and their neighbours) separately: their edges decide most of the
        // difference, and the surfaces are what the bake is about.
        let emissive = frame
            .capture(
                gpu,
                reference.width * SS,
                reference.height * SS,
                &FrameSettings {
                    debug_view: DebugView::Emissive,
                    ..plain
                },
            )?
            .hdr
            .box_downsample(SS);
        let (w, h) = (reference.width as i64, reference.height as i64);
        let lit = |x: i64, y: i64| {
            (0..w).contains(&x)
                && (0..h).contains(&y)
                && emissive.texels[(y * w + x) as usize][..3]
                    .iter()
                    .any(|&v| v > 0.0)
        };
        let mask = |img: &radiant::render::capture::Image| {
            let mut img = img.clone();
            for y in 0..h {
                for x in 0..w {
                    if (-1..=1).any(|dy| (-1..=1).any(|dx| lit(x + dx, y + dy))) {
                        img.texels[(y * w + x) as usize] = [0.0; 4];
                    }
                }
            }
            img
        };
        // Over 4×4 and 8×8 blocks: the frame's error at a scale a player sees, less the
        // reference's noise.
        let compare = |a: &radiant::render::capture::Image, b: &radiant::render::capture::Image| {
            Some([
                radiant::render::capture::compare_images(a, b, 4)?,
                radiant::render::capture::compare_images(a, b, 8)?,
            ])
        };
        let all = compare(&ours, reference);
        let surfaces = compare(&mask(&ours), &mask(reference));
        if let (Some(e), Some(s)) = (all, surfaces) {
            return Ok(describe(e, s, reference, SS));
        }
    }
    Ok(serde_json::Value::Null)
}

/// Prints the two errors against the reference (each over 4×4 and 8×8 blocks) and returns
/// them for `render.json`.
fn describe(
    e: [radiant::render::capture::ImageError; 2],
    s: [radiant::render::capture::ImageError; 2],
    reference: &radiant::render::capture::Image,
    ss: u32,
) -> serde_json::Value {
    println!(
        "against the path-traced reference ({}×{}, same camera; the frame at {} samples per pixel):",
        reference.width,
        reference.height,
        ss * ss
    );
    for (what, [b4, b8]) in [
        ("whole image", e),
        ("surfaces (emitter pixels excluded)", s),
    ] {
        println!(
            "  {what}: L1 {:.2} % per pixel, {:.2} % over 4×4 blocks, {:.2} % over 8×8, mean bias {:+.2} %",
            100.0 * b4.rel_l1,
            100.0 * b4.rel_l1_blocks,
            100.0 * b8.rel_l1_blocks,
            100.0 * b4.mean_bias
        );
    }
    let j = |[b4, b8]: [radiant::render::capture::ImageError; 2]| {
        json!({
            "rel_l1": b4.rel_l1,
            "rel_l1_4x4": b4.rel_l1_blocks,
            "rel_l1_8x8": b8.rel_l1_blocks,
            "mean_bias": b4.mean_bias,
        })
    };
    json!({
        "size": [reference.width, reference.height],
        "supersampling": ss * ss,
        "whole_image": j(e),
        "surfaces": j(s),
    })
}

/// `--timings`: each pass's median time over `frames` frames.
fn pass_timings(
    gpu: &GpuContext,
    frame: &mut FrameRenderer,
    (w, h): (u32, u32),
    frame_settings: &FrameSettings,
    frames: usize,
) -> anyhow::Result<serde_json::Value> {
    {
        let target = radiant::render::util::target_texture(
            &gpu.device,
            "timing_target",
            w,
            h,
            radiant::render::wgpu::TextureFormat::Rgba8UnormSrgb,
        );
        let view = target.create_view(&Default::default());
        let mut runs = Vec::new();
        let mut gpu_clock = false;
        for _ in 0..frames {
            let t = frame.render_timed(
                gpu,
                &view,
                w,
                h,
                radiant::render::wgpu::TextureFormat::Rgba8UnormSrgb,
                frame_settings,
            )?;
            gpu_clock = t.gpu;
            runs.push(t.passes);
        }
        let medians: Vec<(String, f64)> = runs[0]
            .iter()
            .enumerate()
            .map(|(i, (name, _))| {
                let mut v: Vec<f64> = runs.iter().map(|r| r[i].1).collect();
                v.sort_by(f64::total_cmp);
                (name.to_string(), v[v.len() / 2])
            })
            .collect();
        println!(
            "per-pass times, median of {} frames ({}):",
            frames,
            if gpu_clock {
                "GPU timestamps"
            } else {
                "CPU wall time per pass"
            }
        );
        for (name, ms) in &medians {
            println!("  {name:<24} {ms:8.3} ms");
        }
        println!(
            "  {:<24} {:8.3} ms",
            "total",
            medians.iter().map(|m| m.1).sum::<f64>()
        );
        Ok(json!({
            "frames": frames,
            "clock": if gpu_clock { "gpu" } else { "cpu" },
            "median_ms": medians.iter().map(|(n, ms)| json!({"pass": n, "ms": ms})).collect::<Vec<_>>(),
        }))
    }
}

pub fn run(args: &RenderArgs) -> anyhow::Result<()> {
    let (w, h) = parse_size(&args.size)?;
    let frame_settings = settings(args)?;
    args.solve.init_threads()?;
    let params = args.solve.params(args.method.0, args.form_factors.0)?;
    let reference = reference_image(args)?;
    let (mut scene, source) = load_scene(&args.scene)?;
    crate::probes::mark_dynamic(&mut scene, &args.dynamic)?;
    ensure_dir(&args.out)?;
    let start = Instant::now();

    let bake = bake(args, &scene, &params, &source)?;
    let bake_s = start.elapsed().as_secs_f64();
    // The light map the bake would write, composed on the renderer's own atlas.
    let mut render_scene =
        radiant::render::scene::RenderScene::from_scene(&scene, args.texel_density)?;
    let lap = Instant::now();
    if let Some(bake) = &bake {
        radiant::bridge::light_with(&mut render_scene, &scene, |atlas| {
            baking::light_map(&scene, atlas, bake, args.light_map.gather(params.ff.seed))
        });
    }
    let lightmap_s = lap.elapsed().as_secs_f64();
    // Dynamic surfaces: lit by probes from the solution.
    let dynamic = scene.surfaces.iter().filter(|s| s.dynamic).count();
    let probes = match &bake {
        Some(bake) if dynamic > 0 => {
            let lap = Instant::now();
            let (_, volume) = crate::probes::bake_volume(&scene, bake, args.probe_spacing);
            radiant::bridge::light_dynamic(&mut render_scene, &volume);
            let seconds = lap.elapsed().as_secs_f64();
            let spacing = volume.step * bake.mesh.frame.scale;
            println!(
                "{dynamic} dynamic surfaces lit by {} probes ({}×{}×{}, {spacing:.3} apart, {} inside geometry) in {seconds:.2} s",
                volume.probes.len(),
                volume.dims[0],
                volume.dims[1],
                volume.dims[2],
                volume.inside()
            );
            json!({
                "dynamic_surfaces": dynamic,
                "dims": volume.dims,
                "probes": volume.probes.len(),
                "inside": volume.inside(),
                "spacing": spacing,
                "seconds": seconds,
            })
        }
        _ => serde_json::Value::Null,
    };

    let gpu = GpuContext::headless()?;
    let mut frame = FrameRenderer::new(&gpu, &render_scene)?;
    let t = Instant::now();
    let png = frame.capture(&gpu, w, h, &frame_settings)?;
    let frame_ms = t.elapsed().as_secs_f64() * 1e3;
    let graph = frame.report().cloned();
    let exr_settings = if args.exr_effects {
        frame_settings
    } else {
        FrameSettings {
            ssao: None,
            bloom: None,
            ..frame_settings
        }
    };
    let exr = if exr_settings == frame_settings {
        png.hdr.clone()
    } else {
        frame.capture(&gpu, w, h, &exr_settings)?.hdr
    };
    write_png(&args.out.join("frame.png"), &png.ldr)?;
    write_exr(&args.out.join("frame.exr"), &exr)?;

    let against = against_reference(reference.as_ref(), &gpu, &mut frame)?;
    let timings = match args.timings {
        0 => serde_json::Value::Null,
        n => pass_timings(&gpu, &mut frame, (w, h), &frame_settings, n)?,
    };

    let report = json!({
        "scene": source,
        "adapter": format!("{} ({:?})", gpu.info.name, gpu.info.backend),
        "size": [w, h],
        "baked": bake.is_some(),
        "bake_s": bake_s,
        "lightmap_s": lightmap_s,
        "probes": probes,
        "final_gather": args.light_map.gather(params.ff.seed).map(|g| json!({
            "strata": g.strata,
            "stride": g.stride,
            "radius": g.filter_radius,
            "element_passes": g.element_passes,
            "lights_at_hits": g.lights_at_hits,
        })),
        "elements": bake.as_ref().map(|b| b.mesh.element_count()),
        "first_frame_ms": frame_ms,
        "graph": graph.as_ref().map(|g| json!({
            "passes": g.passes,
            "transient_textures": g.virtual_textures,
            "allocations": g.physical_textures.len(),
            "bytes": g.bytes,
        })),
        "exr": if args.exr_effects { "with the frame's effects" } else { "radiance: no SSAO, no bloom" },
        "timings": timings,
        "path_traced_reference": against,
    });
    write_atomic(
        &args.out.join("render.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    println!(
        "{source}: {w}×{h} on {}; wrote {}/frame.png, frame.exr, render.json",
        gpu.info.name,
        args.out.display()
    );
    Ok(())
}
