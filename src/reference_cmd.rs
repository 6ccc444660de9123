//! `radiant reference`: path-traced truth for any scene, with standard errors.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use radiant::reference::{
    Estimate, ImageEstimate, Params, Point, Progress, Run, SurfaceEstimate, Tracer,
};
use radiant::scene::Scene;
use serde_json::{Value, json};

use crate::SceneArgs;
use crate::common::{PROGRESS, ProgressLog, load_scene, progress_bar};
use crate::output::{csv_name, ensure_dir, exr_bytes, preview_png, write_atomic};

/// `radiant reference`.
#[derive(Args, Debug)]
pub(crate) struct ReferenceArgs {
    #[command(flatten)]
    pub(crate) scene: SceneArgs,
    /// Output directory: surfaces.csv, points.csv, probes.csv, image.exr (+ image.png),
    /// report.json.
    #[arg(long, short)]
    pub(crate) out: PathBuf,
    /// Paths per surface, point and pixel. Alone, exactly that many (bit-identical on any
    /// thread count); with --target-error or --time-limit, at most that many.
    #[arg(long)]
    pub(crate) samples: Option<u64>,
    /// Target relative standard error of each surface and point (one darker than a thousandth
    /// of the median one is held to that absolute error), and of the image as a whole
    /// (Σ se / Σ mean). Default 0.005 when neither --samples nor --time-limit is given.
    #[arg(long)]
    pub(crate) target_error: Option<f64>,
    /// Seconds per estimate (surfaces, points, image), whatever the error reached. Default 600
    /// when neither --samples nor --time-limit is given.
    #[arg(long)]
    pub(crate) time_limit: Option<f64>,
    /// Seed for every random choice.
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub(crate) threads: Option<usize>,
    /// Points to estimate radiosity at: a CSV with `point,x,y,z,nx,ny,nz` (scene units) or
    /// the shipped Mitsuba layout `point,x_mm,y_mm,z_mm,nx,ny,nz,...` (millimetres, for a
    /// scene in metres). Written to points.csv.
    #[arg(long)]
    pub(crate) points: Option<PathBuf>,
    /// Probes to estimate irradiance at: a CSV with `name,x,y,z,nx,ny,nz` (scene units; a point
    /// anywhere, in free space or on a surface, and the normal of the hemisphere it gathers
    /// over, any length but zero). Written to probes.csv: `name,E_r,E_g,E_b` (W/m² in the
    /// scene's emission units, cosine-weighted over the hemisphere) and standard errors.
    #[arg(long)]
    pub(crate) probes: Option<PathBuf>,
    /// Also render the scene's camera at this size, e.g. 640x360: image.exr (linear radiance,
    /// what `radiant render --reference-image` compares with) and image.png.
    #[arg(long)]
    pub(crate) image: Option<String>,
    /// Skip the per-surface estimate (for an image or points only).
    #[arg(long)]
    pub(crate) no_surfaces: bool,
}

impl ReferenceArgs {
    /// The stopping rules, with the defaults filled in.
    pub(crate) fn params(&self) -> anyhow::Result<Params> {
        stopping_rules(self.samples, self.target_error, self.time_limit, self.seed)
    }
}

/// Stopping rules from the command line: with none given, 0.5 % or 600 s.
pub(crate) fn stopping_rules(
    samples: Option<u64>,
    target_error: Option<f64>,
    time_limit: Option<f64>,
    seed: u64,
) -> anyhow::Result<Params> {
    let none = samples.is_none() && target_error.is_none() && time_limit.is_none();
    let time_limit = match (time_limit, none) {
        (Some(t), _) => {
            anyhow::ensure!(
                t > 0.0 && t.is_finite(),
                "--time-limit {t} must be a positive number of seconds"
            );
            Some(crate::common::seconds(t)?)
        }
        (None, true) => Some(std::time::Duration::from_secs(600)),
        (None, false) => None,
    };
    let p = Params {
        samples,
        target_error: if none { Some(0.005) } else { target_error },
        time_limit,
        seed,
    };
    p.validate()?;
    Ok(p)
}

/// `WxH`.
fn parse_image_size(s: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X', '×'])
        .ok_or_else(|| anyhow::anyhow!("--image {s}: use WIDTHxHEIGHT, e.g. 640x360"))?;
    let parse = |v: &str| -> anyhow::Result<u32> {
        let n: u32 = v
            .trim()
            .parse()
            .map_err(|_| anyhow::anyhow!("--image {s}: '{v}' is not a whole number"))?;
        anyhow::ensure!(
            (1..=16_384).contains(&n),
            "--image {s}: each side 1 to 16384"
        );
        Ok(n)
    };
    Ok((parse(w)?, parse(h)?))
}

/// Reads a points CSV in scene units (`x,y,z`) or the Mitsuba layout in millimetres, as
/// `radiant bake --points` reads it (`metrics::parse_point_positions`).
fn read_points(path: &Path, flag: &str) -> anyhow::Result<Vec<Point>> {
    let text = crate::common::read_text(path, flag)?;
    let specs = radiant::radiosity::metrics::parse_point_positions(&text, 1e-3)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(specs
        .into_iter()
        .map(|p| Point {
            name: p.name,
            position: p.position,
            normal: p.normal,
        })
        .collect())
}

/// A progress callback that drives a bar (with ETA) and logs every few seconds.
pub(crate) fn progress_reporter(what: &str) -> (indicatif::ProgressBar, impl Fn(&Progress) + Sync) {
    let pb = progress_bar(1000, what);
    let bar = pb.clone();
    let log = ProgressLog::new();
    let f = move |p: &Progress| {
        bar.set_position((p.fraction * 1000.0) as u64);
        let eta = p
            .eta_seconds
            .map_or(String::new(), |s| format!(", about {s:.0} s left"));
        bar.set_message(format!("{}: {:.2} % se{eta}", p.what, 100.0 * p.rel_error));
        if log.due() {
            tracing::info!(
                target: PROGRESS,
                what = p.what,
                paths = p.paths,
                rel_error = p.rel_error,
                eta_s = p.eta_seconds,
                "reference progress"
            );
        }
    };
    (pb, f)
}

fn run_json(r: &Run) -> Value {
    json!({
        "paths": r.paths,
        "rays": r.rays,
        "seconds": r.seconds,
        "threads": r.threads,
        "paths_per_second": r.paths as f64 / r.seconds.max(1e-9),
        "paths_per_second_per_thread": r.paths as f64 / r.seconds.max(1e-9) / r.threads.max(1) as f64,
        "stopped_by": r.stopped.name(),
        "rel_error": if r.rel_error.is_finite() { json!(r.rel_error) } else { Value::Null },
    })
}

/// `surfaces.csv` with standard errors: the bake's columns, then `se_r,se_g,se_b,samples`.
pub(crate) fn surfaces_csv(scene: &Scene, surfaces: &[SurfaceEstimate]) -> String {
    let mut s = String::from("surface,area,b_r,b_g,b_b,se_r,se_g,se_b,samples\n");
    for e in surfaces {
        let m = &e.estimate;
        let _ = writeln!(
            s,
            "{},{:.9e},{:.9e},{:.9e},{:.9e},{:.4e},{:.4e},{:.4e},{}",
            csv_name(&scene.surfaces[e.surface as usize].name),
            e.area,
            m.mean[0],
            m.mean[1],
            m.mean[2],
            m.se[0],
            m.se[1],
            m.se[2],
            m.samples
        );
    }
    s
}

fn points_csv(points: &[Point], est: &[Estimate]) -> String {
    let mut s = String::from("point,x,y,z,nx,ny,nz,L_r,L_g,L_b,se_r,se_g,se_b,samples\n");
    for (p, e) in points.iter().zip(est) {
        let _ = writeln!(
            s,
            "{},{:.9e},{:.9e},{:.9e},{:.6},{:.6},{:.6},{:.9e},{:.9e},{:.9e},{:.4e},{:.4e},{:.4e},{}",
            csv_name(&p.name),
            p.position.x,
            p.position.y,
            p.position.z,
            p.normal.x,
            p.normal.y,
            p.normal.z,
            e.mean[0],
            e.mean[1],
            e.mean[2],
            e.se[0],
            e.se[1],
            e.se[2],
            e.samples
        );
    }
    s
}

/// `probes.csv`: irradiance per probe with its standard errors, in the order given.
fn probes_csv(probes: &[Point], est: &[Estimate]) -> String {
    let mut s = String::from("name,E_r,E_g,E_b,se_r,se_g,se_b,samples\n");
    for (p, e) in probes.iter().zip(est) {
        let _ = writeln!(
            s,
            "{},{:.9e},{:.9e},{:.9e},{:.4e},{:.4e},{:.4e},{}",
            csv_name(&p.name),
            e.mean[0],
            e.mean[1],
            e.mean[2],
            e.se[0],
            e.se[1],
            e.se[2],
            e.samples
        );
    }
    s
}

/// The per-surface estimate, with a progress bar.
pub(crate) fn trace_surfaces(
    tracer: &Tracer,
    params: &Params,
) -> anyhow::Result<(Vec<SurfaceEstimate>, Run)> {
    let (pb, progress) = progress_reporter("surfaces");
    let out = tracer.surfaces(params, &progress);
    pb.finish_and_clear();
    Ok(out?)
}

pub fn run(args: &ReferenceArgs) -> anyhow::Result<()> {
    if let Some(n) = args.threads {
        anyhow::ensure!(n > 0, "--threads must be at least 1");
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()?;
    }
    let params = args.params()?;
    let image_size = args.image.as_deref().map(parse_image_size).transpose()?;
    let points = (args.points.as_deref())
        .map(|p| read_points(p, "--points"))
        .transpose()?;
    let probes = (args.probes.as_deref())
        .map(|p| read_points(p, "--probes"))
        .transpose()?;
    anyhow::ensure!(
        !args.no_surfaces || image_size.is_some() || points.is_some() || probes.is_some(),
        "--no-surfaces leaves nothing to do: add --image, --points or --probes"
    );
    let (scene, source) = load_scene(&args.scene)?;
    ensure_dir(&args.out)?;
    let t0 = Instant::now();
    let tracer = Tracer::new(&scene.static_part())?;
    let setup = t0.elapsed().as_secs_f64();
    let mut warnings = scene.warnings();
    if !tracer.has_emitters() {
        let w = "the scene has no emitters: every estimate is zero".to_string();
        println!("warning: {w}");
        warnings.push(w);
    }
    println!(
        "reference for {source}: {} triangles, BVH in {setup:.2} s, {} threads",
        scene.triangles.len(),
        rayon::current_num_threads()
    );
    let mut report = json!({
        "scene": source,
        "seed": params.seed,
        "samples": params.samples,
        "target_error": params.target_error,
        "time_limit_s": params.time_limit.map(|t| t.as_secs_f64()),
        "setup_seconds": setup,
        "units": "outgoing radiance, glTF emissive units (emission + rho E / pi)",
    });

    if !args.no_surfaces {
        let (surfaces, r) = trace_surfaces(&tracer, &params)?;
        write_atomic(
            &args.out.join("surfaces.csv"),
            surfaces_csv(&scene, &surfaces).as_bytes(),
        )?;
        let mean_rel = radiant::reference::mean_rel_error(&surfaces);
        println!(
            "surfaces: {} surfaces, {} paths in {:.2} s ({:.0} paths/s), worst se {:.3} %, area-weighted {:.3} % (stopped by {})",
            surfaces.len(),
            r.paths,
            r.seconds,
            r.paths as f64 / r.seconds.max(1e-9),
            100.0 * r.rel_error,
            100.0 * mean_rel,
            r.stopped.name()
        );
        let mut j = run_json(&r);
        j["mean_rel_error"] = json!(mean_rel);
        j["count"] = json!(surfaces.len());
        report["surfaces"] = j;
    }
    if let Some(points) = &points {
        let (pb, progress) = progress_reporter("points");
        let result = tracer.points(points, &params, &progress);
        pb.finish_and_clear();
        let (est, r) = result?;
        write_atomic(
            &args.out.join("points.csv"),
            points_csv(points, &est).as_bytes(),
        )?;
        println!(
            "points: {} points, {} paths in {:.2} s, worst se {:.3} % (stopped by {})",
            points.len(),
            r.paths,
            r.seconds,
            100.0 * r.rel_error,
            r.stopped.name()
        );
        let mut j = run_json(&r);
        j["count"] = json!(points.len());
        report["points"] = j;
    }
    if let Some(probes) = &probes {
        let (pb, progress) = progress_reporter("probes");
        let result = tracer.probes(probes, &params, &progress);
        pb.finish_and_clear();
        let (est, r) = result?;
        write_atomic(
            &args.out.join("probes.csv"),
            probes_csv(probes, &est).as_bytes(),
        )?;
        println!(
            "probes: {} probes, {} paths in {:.2} s, worst se {:.3} % (stopped by {})",
            probes.len(),
            r.paths,
            r.seconds,
            100.0 * r.rel_error,
            r.stopped.name()
        );
        let mut j = run_json(&r);
        j["count"] = json!(probes.len());
        j["units"] = json!("irradiance E, W/m² in the scene's emission units");
        report["probes"] = j;
    }
    if let Some((w, h)) = image_size {
        let camera = scene
            .camera
            .ok_or(radiant::reference::ReferenceError::NoCamera)?;
        let (pb, progress) = progress_reporter("image");
        let result = tracer.image(&camera, w, h, &params, &progress);
        pb.finish_and_clear();
        let (img, r) = result?;
        write_image(&args.out, &img)?;
        println!(
            "image: {w}×{h}, {} paths in {:.2} s ({:.0} paths/s), se {:.3} % of the mean (stopped by {})",
            r.paths,
            r.seconds,
            r.paths as f64 / r.seconds.max(1e-9),
            100.0 * r.rel_error,
            r.stopped.name()
        );
        let mut j = run_json(&r);
        j["size"] = json!([w, h]);
        j["samples_per_pixel"] = json!(r.paths / (w as u64 * h as u64));
        report["image"] = j;
    }
    report["warnings"] = json!(warnings);
    write_atomic(
        &args.out.join("report.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// image.exr (mean radiance), image_se.exr (its standard error) and image.png (a preview).
fn write_image(dir: &Path, img: &ImageEstimate) -> anyhow::Result<()> {
    let f = |v: f64| v as f32;
    let mean: Vec<[f32; 3]> = img.pixels.iter().map(|p| p.mean.map(f)).collect();
    let se: Vec<[f32; 3]> = img.pixels.iter().map(|p| p.se.map(f)).collect();
    write_atomic(
        &dir.join("image.exr"),
        &exr_bytes(img.width, img.height, &mean)?,
    )?;
    write_atomic(
        &dir.join("image_se.exr"),
        &exr_bytes(img.width, img.height, &se)?,
    )?;
    write_atomic(
        &dir.join("image.png"),
        &preview_png(img.width, img.height, &mean)?,
    )
}
