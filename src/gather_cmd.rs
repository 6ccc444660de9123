//! `--method gpu-hemicube`: the GPU hemicube gather (`radiant_gather`) for `bake` and
//! `converge`. Built with the `render` feature; without it the method is refused by name.

use std::time::Instant;

use radiant::radiosity::metrics::{self, ErrorStats};
use serde_json::json;

use crate::args::Method;
use crate::common::{load_scene, reference_for};
use crate::output::{self, ensure_dir, write_atomic};
use crate::{BakeArgs, SolveArgs};

/// The method's name on the command line.
const GPU_HEMICUBE: &str = Method::GPU_HEMICUBE;

/// One sweep of a gather, for `convergence.csv` and `report.json`.
pub struct Sample {
    /// Seconds since the gather began (setup included, error measurement excluded).
    pub t_s: f64,
    /// Sweeps so far.
    pub iterations: u32,
    /// Estimated remaining relative change.
    pub estimate: f64,
    /// Error against the reference, when there is one.
    pub error: Option<ErrorStats>,
}

/// The gather's parameters from the shared solve options.
/// `memory_limit` (`--memory-limit`, a budget of host memory) can only lower what the gather
/// keeps between sweeps: at most half of it, and never more than the default (kept hemicubes
/// live in GPU memory, which a host budget does not size).
fn params(
    solve: &SolveArgs,
    texel_density: Option<f64>,
    page: u32,
    memory_limit: Option<u64>,
) -> radiant::gather::GatherParams {
    let defaults = radiant::gather::GatherParams::default();
    radiant::gather::GatherParams {
        resolution: solve.hemicube_resolution.unwrap_or(defaults.resolution),
        texel_density,
        page_side: page,
        tolerance: solve.tolerance.unwrap_or(defaults.tolerance),
        keep_bytes: memory_limit.map_or(defaults.keep_bytes, |l| (l / 2).min(defaults.keep_bytes)),
        ..defaults
    }
}

/// Gathers until converged or past `time_limit` (seconds of sweeps), measuring the error
/// against `reference` after each sweep (not counted in the time).
pub fn run_gather(
    scene: &radiant::scene::Scene,
    params: &radiant::gather::GatherParams,
    reference: Option<&[(String, [f64; 3])]>,
    time_limit: Option<f64>,
    mut on_sample: impl FnMut(&Sample),
) -> anyhow::Result<(radiant::gather::GpuGather, Vec<Sample>, bool)> {
    let start = Instant::now();
    let mut g = radiant::gather::GpuGather::new(scene, params)?;
    let line = format!(
        "{GPU_HEMICUBE}: {} receivers, {} batch(es) of hemicubes ({} kept between sweeps), {} triangles on each of their faces; set up in {:.2} s",
        g.receivers(),
        g.batches(),
        g.kept_batches(),
        g.drawn_triangles(),
        start.elapsed().as_secs_f64()
    );
    tracing::info!("{line}");
    eprintln!("{line}");
    let mut overhead = 0.0;
    let mut samples = Vec::new();
    let mut converged = false;
    loop {
        let s = g.step_with(|k, n| {
            let line = format!(
                "{GPU_HEMICUBE}: drew batch {k} of {n} at {:.2} s",
                start.elapsed().as_secs_f64()
            );
            tracing::info!("{line}");
            eprintln!("{line}");
        })?;
        let t_s = start.elapsed().as_secs_f64() - overhead;
        let lap = Instant::now();
        let error = reference
            .map(|r| metrics::compare_surfaces(&g.surface_means(), r))
            .transpose()?;
        overhead += lap.elapsed().as_secs_f64();
        let sample = Sample {
            t_s,
            iterations: s.iterations,
            estimate: s.estimate,
            error,
        };
        on_sample(&sample);
        samples.push(sample);
        if s.converged {
            converged = s.estimate <= params.tolerance;
            break;
        }
        if time_limit.is_some_and(|l| t_s - g.setup_seconds() >= l) {
            break;
        }
    }
    Ok((g, samples, converged))
}

/// `radiant bake --method gpu-hemicube`.
pub fn bake(args: &BakeArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    for (given, what) in [
        (args.spectral, "--spectral"),
        (args.checkpoint.is_some(), "--checkpoint"),
        (args.export.is_some(), "--export"),
    ] {
        anyhow::ensure!(
            !given,
            "{what} is not available with --method {GPU_HEMICUBE} (use a CPU method)"
        );
    }
    args.solve.init_threads()?;
    let reference = reference_for(&args.scene, args.reference.as_deref())?;
    let (scene, source) = load_scene(&args.scene)?;
    ensure_dir(&args.out)?;
    let params = params(
        &args.solve,
        args.texel_density,
        args.lightmap_page,
        args.hierarchy.memory_limit,
    );
    let rows = reference.as_ref().map(|(_, r)| r.as_slice());
    let (g, samples, converged) = run_gather(&scene, &params, rows, args.solve.time_limit, |s| {
        let error = s.error.map_or(String::new(), |e| {
            format!(", {:.2} % mean error", e.mean_rel * 100.0)
        });
        let line = format!(
            "{GPU_HEMICUBE}: sweep {} at {:.2} s, estimated change {:.1e}{error}",
            s.iterations, s.t_s, s.estimate
        );
        tracing::info!("{line}");
        eprintln!("{line}");
    })?;
    let solve_s = start.elapsed().as_secs_f64();
    let surfaces = g.surface_means();
    write_atomic(
        &args.out.join("surfaces.csv"),
        output::surfaces_csv(&surfaces).as_bytes(),
    )?;
    let map = g.lightmap();
    output::write_lightmaps(&args.out, &map)?;
    let mut report = json!({
        "scene": source,
        "method": GPU_HEMICUBE,
        "adapter": g.adapter(),
        "receivers": g.receivers(),
        "batches": g.batches(),
        "batches_drawn_once": g.kept_batches(),
        "keep_bytes": params.keep_bytes,
        "hemicube_resolution": params.resolution,
        "converged": converged,
        "iterations": g.iterations(),
        "tolerance": params.tolerance,
        "lightmap": {
            "width": map.width,
            "height": map.height,
            "pages": map.pages,
            "texel_density": g.atlas().density,
        },
        "seconds": { "setup": g.setup_seconds(), "total": solve_s },
        "timeline": samples.iter().map(|s| json!({
            "t_s": s.t_s,
            "iterations": s.iterations,
            "estimate": s.estimate,
            "mean_rel_error": s.error.map(|e| e.mean_rel),
        })).collect::<Vec<_>>(),
    });
    let mut summary = String::new();
    if let Some((name, rows)) = &reference {
        let e = metrics::compare_surfaces(&surfaces, rows)?;
        report["error_vs_reference"] = json!({
            "reference": name,
            "mean_rel": e.mean_rel,
            "max_rel": e.max_rel,
            "rel_rms": e.rel_rms,
        });
        summary = format!(
            ", {:.2} % mean / {:.2} % max from {name}",
            e.mean_rel * 100.0,
            e.max_rel * 100.0
        );
    }
    write_atomic(
        &args.out.join("report.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    println!(
        "{GPU_HEMICUBE} on {}: {} receivers, {} sweeps in {:.2} s ({}){summary}",
        g.adapter(),
        g.receivers(),
        g.iterations(),
        solve_s,
        if converged {
            "converged"
        } else {
            "not converged"
        }
    );
    println!("wrote {}", args.out.display());
    Ok(())
}

/// The gather's curve for `converge`, against a per-surface reference.
pub fn curve(
    scene: &radiant::scene::Scene,
    solve: &SolveArgs,
    reference: &[(String, [f64; 3])],
    time_limit: f64,
    memory_limit: Option<u64>,
) -> anyhow::Result<Vec<Sample>> {
    let params = params(solve, None, 2048, memory_limit);
    let (_, samples, _) = run_gather(scene, &params, Some(reference), Some(time_limit), |_| {})?;
    Ok(samples)
}
