//! `radiant bake`, and the default job when `radiant` runs with no arguments.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use radiant::radiosity::metrics::{self, CORNELL_BOX_REFERENCE};
use radiant::radiosity::{Bake, BakeEvent, lightmap};
use serde_json::json;

use crate::output::{self, ensure_dir, write_atomic};
use crate::{BakeArgs, SceneArgs, load_scene, parse_ff, parse_solver};

/// A per-surface reference and where it came from.
pub type NamedReference = (String, Vec<(String, [f64; 3])>);

/// The reference for a bake: a given CSV, or the shipped one for the builtin Cornell box.
pub fn reference_for(
    scene: &SceneArgs,
    given: Option<&Path>,
) -> anyhow::Result<Option<NamedReference>> {
    if let Some(path) = given {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read reference {}", path.display()))?;
        let rows =
            metrics::parse_reference_csv(&text).with_context(|| format!("{}", path.display()))?;
        return Ok(Some((path.display().to_string(), rows)));
    }
    if scene
        .builtin
        .as_deref()
        .is_some_and(|b| b.starts_with("cornell"))
    {
        let rows = metrics::parse_reference_csv(CORNELL_BOX_REFERENCE)?;
        return Ok(Some((
            "Mitsuba 3 path-traced irradiance meters (assets/reference)".into(),
            rows,
        )));
    }
    Ok(None)
}

/// A progress bar on a terminal; hidden otherwise.
pub fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    if let Ok(style) =
        ProgressStyle::with_template("{spinner} {msg:24} [{bar:32}] {pos}/{len} {elapsed_precise}")
    {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(what.to_string());
    pb
}

pub fn run(args: &BakeArgs) -> anyhow::Result<()> {
    args.solve.init_threads()?;
    let start = Instant::now();
    let solver = parse_solver(&args.method)?;
    let ff = parse_ff(&args.form_factors)?;
    let params = args.solve.params(solver, ff)?;
    let reference = reference_for(&args.scene, args.reference.as_deref())?;
    let (scene, source) = load_scene(&args.scene)?;
    let import_s = start.elapsed().as_secs_f64();
    if let Some((name, rows)) = &reference {
        // Check before baking, not after: a reference for another scene is a mistake.
        let known = scene
            .surfaces
            .iter()
            .any(|s| !s.is_emitter() && rows.iter().any(|(n, _)| *n == s.name));
        anyhow::ensure!(known, "reference {name} names none of the scene's surfaces");
    }
    ensure_dir(&args.out)?;

    let pb = progress_bar(1, "form factors");
    let bake = Bake::with_progress(&scene, &params, &|done, total| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
    })?;
    pb.set_message("solving");
    pb.set_length(1000);
    pb.set_position(0);
    let tol = params.solver_params.tolerance;
    let result = bake.run_to_end(&mut |BakeEvent::Solve(p, t)| {
        // Progress in log-residual, from 1 down to the tolerance.
        let frac = if p.residual > 0.0 {
            (p.residual.ln() / tol.ln()).clamp(0.0, 1.0)
        } else {
            1.0
        };
        pb.set_position((frac * 1000.0) as u64);
        pb.set_message(format!("solving, residual {:.1e}", p.residual));
        tracing::debug!(
            t,
            iterations = p.iterations,
            residual = p.residual,
            "solver step"
        );
    })?;
    pb.finish_and_clear();

    let error = match &reference {
        Some((name, rows)) => Some((
            name.clone(),
            metrics::compare_surfaces(&result.surfaces, rows)?,
        )),
        None => None,
    };
    let out = &args.out;
    write_atomic(
        &out.join("surfaces.csv"),
        output::surfaces_csv(&result.surfaces).as_bytes(),
    )?;
    write_atomic(
        &out.join("patches.csv"),
        output::patches_csv(&scene, &result).as_bytes(),
    )?;
    let map = lightmap::bake_lightmap(&result.mesh, &result.radiosity, args.lightmap_width);
    output::write_lightmaps(out, &map)?;
    let total_s = start.elapsed().as_secs_f64();
    let extra = json!({
        "patch_size": params.mesh.patch_size,
        "element_levels": params.mesh.element_levels,
        "refinement": params.links.refinement,
        "far_field": params.links.far_field,
        "tolerance": params.solver_params.tolerance,
        "seed": params.ff.seed,
        "threads": rayon::current_num_threads(),
        "lightmap": { "width": map.width, "height": map.height },
    });
    let report = output::report_json(
        &source,
        &result.report,
        import_s,
        total_s,
        error.as_ref().map(|(n, e)| (n.as_str(), e)),
        extra,
    );
    write_atomic(
        &out.join("report.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;

    let r = &result.report;
    println!(
        "{source}: {} patches, {} elements, {} links; {} with {} form factors",
        r.patches,
        r.elements,
        r.links,
        r.solver.name(),
        r.form_factors.name()
    );
    println!(
        "time: {:.3} s total (form factors {:.3} s, solve {:.3} s); {} iterations, residual {:.2e}, {}",
        total_s,
        r.times.form_factors,
        r.times.solve,
        r.iterations,
        r.residual,
        if r.converged {
            "converged"
        } else {
            "NOT converged"
        }
    );
    for w in &r.warnings {
        println!("warning: {w}");
    }
    if let Some((name, e)) = &error {
        println!(
            "error against {name}: mean {:.2} %, max {:.2} %, rms {:.2} % (emitters excluded)",
            e.mean_rel * 100.0,
            e.max_rel * 100.0,
            e.rel_rms * 100.0
        );
    }
    println!(
        "wrote {}/{{surfaces.csv, patches.csv, report.json, lightmap.hdr, lightmap.png}}",
        out.display()
    );
    Ok(())
}

/// `radiant` with no arguments: there is no viewer in this build, so run the headless job: bake
/// the Cornell box and plot error against time for the default methods.
pub fn run_default() -> anyhow::Result<()> {
    let out = PathBuf::from("radiant-out");
    println!(
        "radiant: no viewer in this build; baking the builtin Cornell box headless into {}/",
        out.display()
    );
    let parse = |args: &[&str]| -> anyhow::Result<crate::Cli> {
        Ok(<crate::Cli as clap::Parser>::try_parse_from(args)?)
    };
    let cli = parse(&[
        "radiant",
        "bake",
        "--builtin",
        "cornell-box",
        "--out",
        "radiant-out",
    ])?;
    if let Some(crate::Command::Bake(args)) = cli.command {
        run(&args)?;
    }
    let cli = parse(&[
        "radiant",
        "converge",
        "--builtin",
        "cornell-box",
        "--out",
        "radiant-out",
        "--methods",
        "jacobi,gauss-seidel,southwell",
        "--form-factors",
        "analytic",
    ])?;
    if let Some(crate::Command::Converge(args)) = cli.command {
        crate::converge_cmd::run(&args)?;
    }
    Ok(())
}
