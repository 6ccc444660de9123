//! The bake as the commands run it: which hierarchy, with progress on a terminal and in the
//! log, resuming from and writing checkpoints.

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use radiant::radiosity::spectral::{SpectralMaterial, SpectralResult};

use radiant::radiosity::{BakeEvent, BakeParams, BakeResult};
use radiant::scene::Scene;

use crate::args::Hierarchy;
use crate::common::{PROGRESS, ProgressLog, progress_bar};

/// Whether this bake uses the clustered hierarchy (see `--hierarchy`).
pub(crate) fn use_clustered(
    hierarchy: Hierarchy,
    scene: &Scene,
    params: &BakeParams,
) -> anyhow::Result<bool> {
    use radiant::radiosity::{FormFactorKind, SolverKind};
    let needs_triangles = [
        (
            !matches!(params.solver, SolverKind::GaussSeidel | SolverKind::Jacobi),
            "--method southwell or direct",
        ),
        (
            !matches!(
                params.form_factors,
                FormFactorKind::Analytic | FormFactorKind::RayCast
            ),
            "--form-factors hemicube or montecarlo",
        ),
    ];
    let needed = needs_triangles
        .iter()
        .find(|(on, _)| *on)
        .map(|(_, what)| *what);
    match hierarchy {
        Hierarchy::Triangles => Ok(false),
        Hierarchy::Clustered => match needed {
            Some(what) => anyhow::bail!(
                "{what} needs the per-triangle hierarchy: use --hierarchy triangles (or auto)"
            ),
            None => Ok(true),
        },
        Hierarchy::Auto => {
            if needed.is_some() {
                return Ok(false);
            }
            Ok(radiant::radiosity::cluster::is_level(scene, params)?)
        }
    }
}

/// A spectral solve asked of a clustered bake: materials by name and bands.
pub(crate) type SpectralAsk<'a> = (&'a HashMap<String, SpectralMaterial>, usize);

/// A bake with the clustered hierarchy, with progress on a terminal and in the log. With a
/// `checkpoint`, it resumes from it when it fits (else says why and bakes afresh), writes it
/// once the links are built (a crash while solving then loses no refinement) and again at the
/// end. With `spectral`, its links are solved again in bands before they are let go; that
/// result comes back with the seconds it took.
pub(crate) fn bake_clustered(
    scene: &Scene,
    params: &BakeParams,
    h: &crate::HierarchyArgs,
    checkpoint: Option<&Path>,
    spectral: Option<SpectralAsk<'_>>,
) -> anyhow::Result<(BakeResult, Option<(SpectralResult, f64)>)> {
    use radiant::radiosity::cluster::{ClusterBake, ClusterParams, Phase, Watch};
    let cp = ClusterParams {
        memory_limit: h.memory_limit,
        samples: h.link_samples,
        transfer: !h.push_by_normal,
        // A one-shot bake: no geometry edits follow, so the refinement's record is not kept.
        edits: false,
        ..ClusterParams::default()
    };
    let pb = progress_bar(1, "links (clustered)");
    let log = ProgressLog::new();
    let progress = |phase: Phase, done: usize, total: usize| {
        match phase {
            Phase::Links => {
                pb.set_length(total as u64);
                pb.set_position(done as u64);
            }
            Phase::Solve => {
                pb.set_message(format!("solving, sweep {done}"));
            }
        }
        // Also in the log, every few seconds, for runs without a terminal.
        if log.due() {
            tracing::info!(target: PROGRESS, ?phase, done, total, "clustered bake progress");
        }
    };
    let resumed = checkpoint.filter(|p| p.exists()).and_then(|path| {
        match ClusterBake::resume(scene, params, &cp, path) {
            Ok(b) => {
                println!("resumed from {} (no links refined)", path.display());
                Some(b)
            }
            Err(e) => {
                println!("not resuming: {e}; baking from scratch");
                None
            }
        }
    });
    let mut bake = match resumed {
        Some(b) => b,
        None => {
            let b = ClusterBake::new(scene, params, &cp, &progress, None)?;
            if let Some(path) = checkpoint {
                b.write_checkpoint(path)?;
            }
            b
        }
    };
    bake.run_to_end(&progress, &mut Watch::default())?;
    if let Some(path) = checkpoint {
        bake.write_checkpoint(path)?;
    }
    let spectral = match spectral {
        Some((materials, bands)) => {
            pb.set_message(format!("spectral solve, {bands} bands"));
            let t = Instant::now();
            let tolerance = params.solver_params.tolerance;
            let sp = bake.solve_spectral(materials, bands, tolerance)?;
            Some((sp, t.elapsed().as_secs_f64()))
        }
        None => None,
    };
    let result = bake.finish();
    pb.finish_and_clear();
    if let Some(c) = &result.report.clusters {
        println!(
            "clustered hierarchy: {} elements, {} clusters, {} links ({:.1} per element), memory {} of {} MiB",
            result.report.elements,
            c.clusters,
            result.report.links,
            result.report.links as f64 / result.report.elements.max(1) as f64,
            c.memory_estimate >> 20,
            c.memory_limit >> 20
        );
    }
    Ok((result, spectral))
}

/// A bake with the per-triangle hierarchy, resuming from and writing `checkpoint`.
pub(crate) fn bake_triangles(
    scene: &Scene,
    params: &BakeParams,
    checkpoint: Option<&Path>,
) -> anyhow::Result<BakeResult> {
    let (bake, pb) = start_bake(scene, params, checkpoint)?;
    pb.set_length(1000);
    pb.set_position(0);
    let log = ProgressLog::new();
    let result = bake.run_to_end(&mut |BakeEvent::Solve(p, t)| {
        // The solve's own progress: in log error, from 1 down to the tolerance.
        pb.set_position((p.progress * 1000.0) as u64);
        pb.set_message(format!("solving, residual {:.1e}", p.residual));
        if log.due() {
            tracing::info!(
                target: PROGRESS,
                iterations = p.iterations,
                residual = p.residual,
                progress = p.progress,
                "solve progress"
            );
        }
        tracing::debug!(
            t,
            iterations = p.iterations,
            residual = p.residual,
            "solver step"
        );
    })?;
    pb.finish_and_clear();
    if let Some(path) = checkpoint {
        result.write_checkpoint(path)?;
    }
    Ok(result)
}

/// Starts a bake, resuming from `checkpoint` when it exists and fits the scene, with a
/// progress bar over the form factors; the bar is returned, set to "solving", for the solve.
pub(crate) fn start_bake(
    scene: &Scene,
    params: &BakeParams,
    checkpoint: Option<&Path>,
) -> anyhow::Result<(radiant::radiosity::Bake, indicatif::ProgressBar)> {
    let pb = progress_bar(1, "form factors");
    let log = ProgressLog::new();
    let resumed = checkpoint.filter(|p| p.exists()).and_then(|path| {
        match radiant::radiosity::Bake::resume(scene, params, path) {
            Ok(b) => {
                println!("resumed from {} (no form factors computed)", path.display());
                Some(b)
            }
            Err(e) => {
                println!("not resuming: {e}; baking from scratch");
                None
            }
        }
    });
    let bake = match resumed {
        Some(b) => b,
        None => radiant::radiosity::Bake::with_progress(scene, params, &|done, total| {
            pb.set_length(total as u64);
            pb.set_position(done as u64);
            if log.due() {
                tracing::info!(target: PROGRESS, done, total, "form factors progress");
            }
        })?,
    };
    pb.set_message("solving");
    Ok((bake, pb))
}

/// The light map of `result` on `atlas`: the punctual lights' direct light per texel, the rest
/// from the smooth field, or gathered per texel with `gather` (a final gather: a progress bar,
/// and the progress in the log every few seconds for runs without a terminal).
pub(crate) fn light_map(
    scene: &Scene,
    atlas: &radiant::scene::atlas::Atlas,
    result: &BakeResult,
    gather: Option<radiant::radiosity::final_gather::GatherParams>,
) -> radiant::radiosity::lightmap::LightMap {
    use radiant::radiosity::texel_light;
    let Some(gather) = gather else {
        return texel_light::compose_lightmap(
            scene,
            atlas,
            &result.mesh,
            &result.system,
            &result.radiosity,
        );
    };
    let pb = progress_bar(1, "light map (final gather)");
    let log = ProgressLog::new();
    let progress = |done: usize, total: usize| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
        if log.due() {
            tracing::info!(target: PROGRESS, done, total, "final gather progress (rows)");
        }
    };
    let map = texel_light::compose_gathered_with_progress(
        scene,
        atlas,
        &result.mesh,
        &result.system,
        &result.radiosity,
        gather,
        &progress,
    );
    pb.finish_and_clear();
    map
}
