//! `radiant converge`: error against run time for each method × form-factor combination.

use std::fmt::Write as _;
use std::time::{Duration, Instant};

use radiant::radiosity::metrics::{self, ErrorStats};
use radiant::radiosity::solvers::{Direct, Solver};
use radiant::radiosity::{Bake, FormFactorKind, Rgb, SolveError, SolverKind};

use crate::ConvergeArgs;
use crate::args::{Hierarchy, Method, Reference};
use crate::common::{
    NamedReference, PROGRESS, ProgressLog, load_scene, progress_bar, reference_for,
};
use crate::output::{ensure_dir, write_atomic};
use crate::plot::{Curve, plot_convergence};

/// One row of `convergence.csv`.
struct Row {
    t_s: f64,
    iterations: u64,
    error: ErrorStats,
    residual: f64,
}

pub fn run(args: &ConvergeArgs) -> anyhow::Result<()> {
    args.solve.init_threads()?;
    let (scene, source) = load_scene(&args.scene)?;
    let gpu = args.methods.contains(&Method::GpuHemicube);
    #[cfg(not(feature = "render"))]
    anyhow::ensure!(
        !gpu,
        "gpu-hemicube needs a build with the `render` feature (wgpu)"
    );
    let solvers: Vec<SolverKind> = args.methods.iter().filter_map(|m| m.solver()).collect();
    let ffs: Vec<FormFactorKind> = args.form_factors.iter().map(|f| f.0).collect();
    anyhow::ensure!(
        args.sample_every > 0.0 && args.sample_every.is_finite(),
        "--sample-every must be positive"
    );
    let clustered = match args.hierarchy {
        Hierarchy::Clustered => true,
        Hierarchy::Triangles => false,
        Hierarchy::Auto => radiant::radiosity::cluster::is_level(
            &scene,
            &args
                .solve
                .params(SolverKind::Jacobi, FormFactorKind::Analytic)?,
        )?,
    };
    ensure_dir(&args.out)?;
    let file_ref = choose_reference(args, &scene)?;
    let reference_name = file_ref.as_ref().map_or(
        "direct solve on the same mesh (solver error)".to_string(),
        |(n, _)| n.clone(),
    );
    let time_limit = args.solve.time_limit.unwrap_or(10.0);
    if !args.light_maps.is_empty() {
        return lightmap_curve(args, &scene, &source, file_ref.as_ref());
    }
    if clustered {
        let Some((_, rows)) = &file_ref else {
            anyhow::bail!(
                "a clustered bake has no direct solve to compare with: use --reference path (or a CSV), or --hierarchy triangles"
            );
        };
        return clustered_curves(args, &scene, &source, &ffs, rows, &reference_name);
    }

    let mut csv = String::from(
        "method,form_factors,t_s,iterations,rel_rms_error,max_rel_error,residual,mean_rel_error\n",
    );
    let mut curves = Vec::new();
    for &ff in &ffs {
        for &solver in &solvers {
            let label = format!("{} / {}", solver.name(), ff.name());
            if let Some(rows) = curve(
                args,
                &scene,
                (solver, ff),
                &label,
                file_ref.as_ref(),
                time_limit,
            )? {
                record((solver, ff), label, &rows, &mut csv, &mut curves);
            }
        }
    }
    #[cfg(feature = "render")]
    if gpu {
        gpu_curve(args, &scene, &file_ref, time_limit, &mut csv, &mut curves)?;
    }
    let title = format!("{source}: mean relative error vs time (reference: {reference_name})");
    write_outputs(args, &csv, &curves, &title, &reference_name)
}

/// Writes `convergence.csv` and the plot of `curves`, and says so.
fn write_outputs(
    args: &ConvergeArgs,
    csv: &str,
    curves: &[Curve],
    title: &str,
    reference_name: &str,
) -> anyhow::Result<()> {
    write_atomic(&args.out.join("convergence.csv"), csv.as_bytes())?;
    let png = plot_convergence(curves, title)?;
    write_atomic(&args.out.join("convergence.png"), &png)?;
    println!("reference: {reference_name}");
    println!(
        "wrote {}/convergence.csv and convergence.png",
        args.out.display()
    );
    Ok(())
}

/// Adds one combination's rows to `convergence.csv`, prints its summary and keeps its curve.
fn record(
    (solver, ff): (SolverKind, FormFactorKind),
    label: String,
    rows: &[Row],
    csv: &mut String,
    curves: &mut Vec<Curve>,
) {
    for r in rows {
        let _ = writeln!(
            csv,
            "{},{},{:.6},{},{:.6e},{:.6e},{:.6e},{:.6e}",
            solver.name(),
            ff.name(),
            r.t_s,
            r.iterations,
            r.error.rel_rms,
            r.error.max_rel,
            r.residual,
            r.error.mean_rel
        );
    }
    let Some(last) = rows.last() else {
        return;
    };
    // Time to 1 % mean error, if reached.
    let to_1pct = (rows.iter().find(|r| r.error.mean_rel <= 0.01)).map(|r| r.t_s);
    println!(
        "{label:28} {:>8.3} s  mean {:6.3} %  max {:6.3} %  rms {:6.3} %  residual {:.1e}  1 % at {}",
        last.t_s,
        last.error.mean_rel * 100.0,
        last.error.max_rel * 100.0,
        last.error.rel_rms * 100.0,
        last.residual,
        to_1pct.map_or("never".to_string(), |t| format!("{t:.3} s"))
    );
    curves.push(Curve {
        label,
        points: rows.iter().map(|r| (r.t_s, r.error.mean_rel)).collect(),
    });
}

/// One solver × form-factor curve: the error after each step of about `--sample-every`
/// seconds, against the per-surface reference or (with none) the direct solve on the same
/// mesh, until converged or the time limit. `None`: the combination cannot run here (it says
/// why). The time spent measuring the error is not the method's: it is subtracted.
fn curve(
    args: &ConvergeArgs,
    scene: &radiant::scene::Scene,
    (solver, ff): (SolverKind, FormFactorKind),
    label: &str,
    file_ref: Option<&NamedReference>,
    time_limit: f64,
) -> anyhow::Result<Option<Vec<Row>>> {
    let mut params = args.solve.params(solver, ff)?;
    params.time_limit = Some(crate::common::seconds(time_limit)?);
    let pb = progress_bar(1, label);
    let log = ProgressLog::new();
    let mut bake = match Bake::with_progress(scene, &params, &|d, n| {
        pb.set_length(n as u64);
        pb.set_position(d as u64);
        if log.due() {
            tracing::info!(target: PROGRESS, curve = label, done = d, total = n, "form factors progress");
        }
    }) {
        Ok(b) => b,
        Err(e) => {
            pb.finish_and_clear();
            println!("{label}: skipped: {e}");
            return Ok(None);
        }
    };
    let mut overhead = Duration::ZERO;
    // With `--reference direct`, the direct solve on the same mesh is the reference.
    let direct_ref: Option<Vec<Rgb>> = match file_ref {
        Some(_) => None,
        None => {
            let t = Instant::now();
            let mut d = Direct::new(params.solver_params);
            match d.step(&bake.system, Duration::ZERO) {
                Ok(_) => {}
                Err(e @ SolveError::OutOfMemory { .. }) => {
                    pb.finish_and_clear();
                    println!("{label}: skipped: the direct reference needs it: {e}");
                    return Ok(None);
                }
                Err(e) => return Err(e.into()),
            }
            overhead += t.elapsed();
            Some(d.radiosity(&bake.system))
        }
    };
    // The time limit is the solver's: form factors always finish first.
    let prepared = bake.elapsed() - overhead.as_secs_f64();
    let mut rows = Vec::new();
    loop {
        let p = match bake.step(crate::common::seconds(args.sample_every)?) {
            Ok(p) => p,
            Err(e) => {
                println!("{label}: stopped: {e}");
                break;
            }
        };
        let t = Instant::now();
        let b = bake.radiosity();
        let error = match (&direct_ref, file_ref) {
            (Some(r), _) => metrics::compare_elements(&bake.system.area, &b, r),
            (None, Some((_, rows))) => metrics::compare_surfaces(
                &metrics::surface_means(&bake.surfaces, &bake.mesh, &b),
                rows,
            )?,
            (None, None) => unreachable_reference()?,
        };
        overhead += t.elapsed();
        let t_s = bake.elapsed() - overhead.as_secs_f64();
        rows.push(Row {
            t_s,
            iterations: p.iterations,
            error,
            residual: p.residual,
        });
        pb.set_message(format!("{label}: {:.2} %", error.mean_rel * 100.0));
        if p.converged || t_s - prepared >= time_limit || !p.residual.is_finite() {
            break;
        }
    }
    pb.finish_and_clear();
    Ok(Some(rows))
}

/// The GPU hemicube gather's curve (`gpu-hemicube` in `--methods`): its error after each sweep
/// against the per-surface reference.
#[cfg(feature = "render")]
fn gpu_curve(
    args: &ConvergeArgs,
    scene: &radiant::scene::Scene,
    file_ref: &Option<NamedReference>,
    time_limit: f64,
    csv: &mut String,
    curves: &mut Vec<Curve>,
) -> anyhow::Result<()> {
    let label = "gpu-hemicube / gpu";
    let Some((_, rows)) = file_ref else {
        println!(
            "{label}: skipped: it needs a per-surface reference (--reference path or a CSV); the direct solve is on another mesh"
        );
        return Ok(());
    };
    let samples =
        match crate::gather_cmd::curve(scene, &args.solve, rows, time_limit, args.memory_limit) {
            Ok(s) => s,
            Err(e) => {
                println!("{label}: skipped: {e}");
                return Ok(());
            }
        };
    for s in &samples {
        let e = s.error.unwrap_or_default();
        let _ = writeln!(
            csv,
            "gpu-hemicube,gpu-hemicube,{:.6},{},{:.6e},{:.6e},{:.6e},{:.6e}",
            s.t_s, s.iterations, e.rel_rms, e.max_rel, s.estimate, e.mean_rel
        );
    }
    if let Some(last) = samples.last() {
        let e = last.error.unwrap_or_default();
        let to_1pct = samples
            .iter()
            .find(|s| s.error.is_some_and(|e| e.mean_rel <= 0.01))
            .map_or("never".to_string(), |s| format!("{:.3} s", s.t_s));
        println!(
            "{label:28} {:>8.3} s  mean {:6.3} %  max {:6.3} %  rms {:6.3} %  estimate {:.1e}  1 % at {to_1pct}",
            last.t_s,
            e.mean_rel * 100.0,
            e.max_rel * 100.0,
            e.rel_rms * 100.0,
            last.estimate
        );
        curves.push(Curve {
            label: label.to_string(),
            points: samples
                .iter()
                .map(|s| (s.t_s, s.error.unwrap_or_default().mean_rel))
                .collect(),
        });
    }
    Ok(())
}

fn unreachable_reference() -> anyhow::Result<ErrorStats> {
    anyhow::bail!("internal: no reference chosen")
}

/// The per-surface reference: `direct` gives none (the direct solve is used), `path` traces
/// the scene here, a file is read; by default the reference shipped with a builtin scene,
/// else `path`.
fn choose_reference(
    args: &ConvergeArgs,
    scene: &radiant::scene::Scene,
) -> anyhow::Result<Option<NamedReference>> {
    match &args.reference {
        Some(Reference::Direct) => Ok(None),
        Some(Reference::Path) => path_traced(args, scene).map(Some),
        Some(Reference::File(file)) => reference_for(&args.scene, Some(file)),
        None => match reference_for(&args.scene, None)? {
            Some(r) => Ok(Some(r)),
            None => path_traced(args, scene).map(Some),
        },
    }
}

/// Path-traces the per-surface reference and keeps it in `DIR/reference/surfaces.csv`.
fn path_traced(
    args: &ConvergeArgs,
    scene: &radiant::scene::Scene,
) -> anyhow::Result<NamedReference> {
    let params = crate::reference_cmd::stopping_rules(
        None,
        Some(args.reference_error),
        Some(args.reference_time),
        args.solve.seed,
    )?;
    let tracer = radiant::reference::Tracer::new(&scene.static_part())?;
    anyhow::ensure!(
        tracer.has_emitters(),
        "the scene has no emitters: there is no light to measure an error of"
    );
    let (surfaces, run) = crate::reference_cmd::trace_surfaces(&tracer, &params)?;
    let dir = args.out.join("reference");
    ensure_dir(&dir)?;
    write_atomic(
        &dir.join("surfaces.csv"),
        crate::reference_cmd::surfaces_csv(scene, &surfaces).as_bytes(),
    )?;
    let floor = radiant::reference::mean_rel_error(&surfaces);
    println!(
        "reference: path-traced {} surfaces, {} paths in {:.1} s, standard error {:.2} % (area-weighted), worst {:.2} %: errors below that are noise",
        surfaces.len(),
        run.paths,
        run.seconds,
        100.0 * floor,
        100.0 * run.rel_error
    );
    let rows = surfaces
        .iter()
        .map(|s| {
            (
                scene.surfaces[s.surface as usize].name.clone(),
                s.estimate.mean,
            )
        })
        .collect();
    Ok((
        format!(
            "path-traced here, {} paths, se {:.2} %",
            run.paths,
            100.0 * floor
        ),
        rows,
    ))
}

/// One clustered bake at refinement `r`: its time and error against `reference`, its row in
/// `csv`; `None` when the bake stopped (over the memory limit, say), which it says.
fn clustered_point(
    args: &ConvergeArgs,
    scene: &radiant::scene::Scene,
    ff: FormFactorKind,
    r: f64,
    reference: &[(String, Rgb)],
    csv: &mut String,
) -> anyhow::Result<Option<(f64, metrics::ErrorStats)>> {
    use radiant::radiosity::cluster::{self, ClusterParams};
    let label = format!("clustered / {}", ff.name());
    let mut params = args.solve.params(SolverKind::Jacobi, ff)?;
    params.links.refinement = r;
    let cp = ClusterParams {
        memory_limit: args.memory_limit,
        ..ClusterParams::default()
    };
    let pb = progress_bar(1, &format!("{label}, refinement {r}"));
    let log = ProgressLog::new();
    let t = Instant::now();
    let result = cluster::bake(scene, &params, &cp, &|phase, done, total| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
        if log.due() {
            tracing::info!(target: PROGRESS, curve = label, refinement = r, ?phase, done, total, "clustered bake progress");
        }
    });
    let t_s = t.elapsed().as_secs_f64();
    pb.finish_and_clear();
    let result = match result {
        Ok(x) => x,
        Err(e) => {
            println!("{label}, refinement {r}: stopped: {e}");
            return Ok(None);
        }
    };
    let e = metrics::compare_surfaces(&result.surfaces, reference)?;
    let rep = &result.report;
    let _ = writeln!(
        csv,
        "clustered,{},{r},{t_s:.6},{},{:.6e},{:.6e},{:.6e},{:.6e},{},{}",
        ff.name(),
        rep.iterations,
        e.rel_rms,
        e.max_rel,
        rep.residual,
        e.mean_rel,
        rep.elements,
        rep.links
    );
    println!(
        "{label:24} refinement {r:<6} {t_s:>8.2} s  mean {:6.3} %  max {:6.3} %  rms {:6.3} %  {} elements, {} links",
        e.mean_rel * 100.0,
        e.max_rel * 100.0,
        e.rel_rms * 100.0,
        rep.elements,
        rep.links
    );
    Ok(Some((t_s, e)))
}

/// Clustered bakes at each refinement threshold, coarse to fine: one point per whole bake
/// (links and solve), one curve per form-factor method the clustered bake supports.
fn clustered_curves(
    args: &ConvergeArgs,
    scene: &radiant::scene::Scene,
    source: &str,
    ffs: &[FormFactorKind],
    reference: &[(String, Rgb)],
    reference_name: &str,
) -> anyhow::Result<()> {
    anyhow::ensure!(
        !args.refinements.is_empty() && args.refinements.iter().all(|r| *r > 0.0 && r.is_finite()),
        "--refinements must be positive numbers"
    );
    let mut csv = String::from(
        "method,form_factors,refinement,t_s,iterations,rel_rms_error,max_rel_error,residual,mean_rel_error,elements,links\n",
    );
    let mut curves = Vec::new();
    for &ff in ffs {
        if !matches!(ff, FormFactorKind::Analytic | FormFactorKind::RayCast) {
            println!(
                "clustered / {}: skipped: the clustered bake uses analytic or raycast form factors",
                ff.name()
            );
            continue;
        }
        let label = format!("clustered / {}", ff.name());
        let mut points = Vec::new();
        for &r in &args.refinements {
            let Some((t_s, e)) = clustered_point(args, scene, ff, r, reference, &mut csv)? else {
                break;
            };
            points.push((t_s, e.mean_rel));
        }
        if !points.is_empty() {
            curves.push(Curve { label, points });
        }
    }
    let title = format!("{source}: mean relative error vs bake time (reference: {reference_name})");
    write_outputs(args, &csv, &curves, &title, reference_name)
}

/// `--light-maps`: one bake as `bake` makes it (Jacobi, analytic form factors, the hierarchy
/// `bake` would take), then its light map composed at each setting, timed, and measured over
/// the surfaces (what the renderer shows, `texel_light::shown_surface_means`) against the
/// reference and at the points against theirs: error against time for the light map alone, so
/// that a user picks a final-gather setting from the curve.
fn lightmap_curve(
    args: &ConvergeArgs,
    scene: &radiant::scene::Scene,
    source: &str,
    reference: Option<&NamedReference>,
) -> anyhow::Result<()> {
    use radiant::radiosity::cluster::ClusterParams;
    use radiant::radiosity::texel_light;
    use radiant::scene::atlas::{Atlas, MAX_SIDE};
    anyhow::ensure!(
        args.light_maps.iter().all(|&s| s <= 64),
        "--light-maps: each setting is a number of strata, 0 (the smooth field) to 64"
    );
    let asked = match &args.points {
        Some(p) => Some(crate::points::read(
            scene,
            p,
            args.reference_points.as_deref(),
        )?),
        None => None,
    };
    let params = args
        .solve
        .params(SolverKind::Jacobi, FormFactorKind::Analytic)?;
    let hierarchy = crate::HierarchyArgs {
        hierarchy: args.hierarchy,
        memory_limit: args.memory_limit,
        link_samples: ClusterParams::default().samples,
        push_by_normal: false,
    };
    let t = Instant::now();
    let result = if crate::baking::use_clustered(args.hierarchy, scene, &params)? {
        crate::baking::bake_clustered(scene, &params, &hierarchy, None, None)?.0
    } else {
        crate::baking::bake_triangles(scene, &params, None)?
    };
    let bake_s = t.elapsed().as_secs_f64();
    let atlas = Atlas::paged(scene, None, MAX_SIDE)?;
    println!(
        "baked in {bake_s:.2} s; light map {}×{}×{} texels",
        atlas.width, atlas.height, atlas.pages
    );
    let mut csv = String::from(
        "light_map,strata,stride,radius,element_passes,bake_s,lightmap_s,t_s,surfaces_mean_rel_error,surfaces_max_rel_error,points_median_rel_error,points_mean_rel_error,points_max_rel_error,lights_at_hits\n",
    );
    let (mut by_surfaces, mut by_points, mut by_points_median) =
        (Vec::new(), Vec::new(), Vec::new());
    for &strata in &args.light_maps {
        let g = args.gather.params(strata, params.ff.seed);
        let t = Instant::now();
        let map = match strata {
            0 => texel_light::compose_lightmap(
                scene,
                &atlas,
                &result.mesh,
                &result.system,
                &result.radiosity,
            ),
            _ => texel_light::compose_gathered(
                scene,
                &atlas,
                &result.mesh,
                &result.system,
                &result.radiosity,
                g,
            ),
        };
        let lightmap_s = t.elapsed().as_secs_f64();
        let t_s = bake_s + lightmap_s;
        let surfaces = match reference {
            Some((_, rows)) => {
                let means = texel_light::shown_surface_means(scene, &atlas, &result.mesh, &map)?;
                Some(metrics::compare_surfaces(&means, rows)?)
            }
            None => None,
        };
        let points = match &asked {
            Some(a) => crate::points::measure(a, scene, &atlas, &map)?,
            None => None,
        };
        let name = if strata == 0 { "smooth" } else { "gather" };
        let f = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6e}"));
        let _ = writeln!(
            csv,
            "{name},{strata},{},{},{},{bake_s:.6},{lightmap_s:.6},{t_s:.6},{},{},{},{},{},{}",
            g.stride,
            g.filter_radius,
            g.element_passes,
            f(surfaces.map(|e| e.mean_rel)),
            f(surfaces.map(|e| e.max_rel)),
            f(points.as_ref().map(|c| c.median_rel)),
            f(points.as_ref().map(|c| c.mean_rel)),
            f(points.as_ref().map(|c| c.max_rel)),
            if strata == 0 {
                String::new()
            } else {
                g.lights_at_hits.to_string()
            },
        );
        let pct = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{:.2} %", v * 100.0));
        println!(
            "{name} {strata:>2}: light map {lightmap_s:>7.2} s (bake + map {t_s:>7.2} s); surfaces mean {}; points median {}, mean {}, worst {}",
            pct(surfaces.map(|e| e.mean_rel)),
            pct(points.as_ref().map(|c| c.median_rel)),
            pct(points.as_ref().map(|c| c.mean_rel)),
            pct(points.as_ref().map(|c| c.max_rel)),
        );
        if let Some(e) = surfaces {
            by_surfaces.push((t_s, e.mean_rel));
        }
        if let Some(c) = &points {
            by_points.push((t_s, c.mean_rel));
            by_points_median.push((t_s, c.median_rel));
        }
    }
    write_atomic(&args.out.join("lightmap_convergence.csv"), csv.as_bytes())?;
    let mut curves = Vec::new();
    for (label, points) in [
        ("surfaces (mean)", by_surfaces),
        ("points (mean)", by_points),
        ("points (median)", by_points_median),
    ] {
        if !points.is_empty() {
            curves.push(Curve {
                label: label.to_string(),
                points,
            });
        }
    }
    let title =
        format!("{source}: the light map's error vs bake and light-map time, by final gather");
    write_atomic(
        &args.out.join("lightmap_convergence.png"),
        &plot_convergence(&curves, &title)?,
    )?;
    println!(
        "wrote {}/lightmap_convergence.csv and lightmap_convergence.png",
        args.out.display()
    );
    Ok(())
}
