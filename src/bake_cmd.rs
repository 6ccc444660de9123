//! `radiant bake`, and the default job when `radiant` runs with no arguments.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use radiant::radiosity::metrics::{
    self, CORNELL_BOX_REFERENCE, CORNELL_POINTS_RGB, CORNELL_POINTS_SPECTRAL,
};
use radiant::radiosity::{BakeEvent, lightmap};
use serde_json::json;

use crate::output::{self, ensure_dir, write_atomic};
use crate::{BakeArgs, SceneArgs, load_scene, parse_ff, parse_solver};

/// A point comparison as JSON: mean, max and each point.
fn points_json(c: &metrics::PointComparison) -> serde_json::Value {
    let points: Vec<serde_json::Value> = c
        .points
        .iter()
        .map(|p| json!({ "point": p.name, "ours": p.ours, "reference": p.reference, "relative_error": p.rel }))
        .collect();
    json!({ "mean_rel": c.mean_rel, "max_rel": c.max_rel, "reference_scale": c.scale, "points": points })
}

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

/// Spectral materials: a side file, or the shipped measured spectra of the builtin Cornell box.
fn spectral_materials(
    scene: &SceneArgs,
    file: Option<&Path>,
) -> anyhow::Result<std::collections::HashMap<String, radiant::radiosity::spectral::SpectralMaterial>>
{
    let text = match file {
        Some(p) => std::fs::read_to_string(p)
            .with_context(|| format!("cannot read spectra {}", p.display()))?,
        None if scene
            .builtin
            .as_deref()
            .is_some_and(|b| b.starts_with("cornell")) =>
        {
            include_str!("../assets/cornell_box_spectra.json").to_string()
        }
        None => anyhow::bail!("--spectral needs --spectra FILE for this scene"),
    };
    let v: serde_json::Value =
        serde_json::from_str(&text).context("spectra file is not valid JSON")?;
    let spectrum = |m: &str,
                    key: &str,
                    s: &serde_json::Value|
     -> anyhow::Result<radiant::color::cie::Spectrum> {
        let nums = |k: &str| -> anyhow::Result<Vec<f64>> {
            s[k].as_array()
                .with_context(|| format!("material '{m}' {key}: no '{k}' array"))?
                .iter()
                .map(|x| {
                    x.as_f64()
                        .with_context(|| format!("material '{m}' {key}: '{k}' has a non-number"))
                })
                .collect()
        };
        radiant::color::cie::Spectrum::new(nums("wavelengths_nm")?, nums("values")?)
            .map_err(|e| anyhow::anyhow!("material '{m}' {key}: {e}"))
    };
    let mut out = std::collections::HashMap::new();
    for (name, m) in v["materials"]
        .as_object()
        .context("spectra file has no 'materials' object")?
    {
        let reflectance = spectrum(name, "reflectance", &m["reflectance"])?;
        let emission = if m.get("emission").is_some() {
            Some(spectrum(name, "emission", &m["emission"])?)
        } else {
            None
        };
        out.insert(
            name.clone(),
            radiant::radiosity::spectral::SpectralMaterial {
                reflectance,
                emission,
            },
        );
    }
    Ok(out)
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
    if args.method == "gpu-hemicube" {
        #[cfg(feature = "render")]
        return crate::gather_cmd::bake(args);
        #[cfg(not(feature = "render"))]
        anyhow::bail!(
            "--method gpu-hemicube needs a build with the `render` feature (wgpu); use jacobi, gauss-seidel, southwell or direct"
        );
    }
    args.solve.init_threads()?;
    let start = Instant::now();
    let solver = parse_solver(&args.method)?;
    let ff = parse_ff(&args.form_factors)?;
    let params = args.solve.params(solver, ff)?;
    let reference = reference_for(&args.scene, args.reference.as_deref())?;
    let (scene, source) = load_scene(&args.scene)?;
    let import_s = start.elapsed().as_secs_f64();
    // Spectral mode solves emission per band; punctual lights have only RGB colours so far.
    anyhow::ensure!(
        !args.spectral || scene.lights.is_empty(),
        "--spectral does not handle punctual lights yet ({} in this scene)",
        scene.lights.len()
    );
    if let Some((name, rows)) = &reference {
        // Check before baking, not after: a reference for another scene is a mistake.
        let known = scene
            .surfaces
            .iter()
            .any(|s| !s.is_emitter() && rows.iter().any(|(n, _)| *n == s.name));
        anyhow::ensure!(known, "reference {name} names none of the scene's surfaces");
    }
    ensure_dir(&args.out)?;
    // The light map's atlas first: a density it cannot use fails before the bake, not after.
    let lap = Instant::now();
    let atlas =
        radiant::scene::atlas::Atlas::paged(&scene, args.texel_density, args.lightmap_page)?;
    let atlas_s = lap.elapsed().as_secs_f64();
    println!(
        "light-map atlas: {} page(s) of {}×{} texels, {} charts, {:.1} texels/unit, {:.1} % inside charts ({:.2} s)",
        atlas.pages,
        atlas.width,
        atlas.height,
        atlas.charts,
        atlas.density,
        atlas.utilisation() * 100.0,
        atlas_s
    );

    let clustered = use_clustered(&args.hierarchy, args.spectral, &scene, &params)?;
    let result = if clustered {
        bake_clustered(&scene, &params, &args.hierarchy, args.checkpoint.as_deref())?
    } else {
        bake_triangles(&scene, &params, args.checkpoint.as_deref())?
    };

    let error = match &reference {
        Some((name, rows)) => Some((
            name.clone(),
            metrics::compare_surfaces(&result.surfaces, rows)?,
        )),
        None => None,
    };
    // The builtin Cornell box also has path-traced radiosity at 24 surface points (RGB and
    // spectral Mitsuba 3 runs): pointwise errors, not just surface means.
    let cornell = args.scene.builtin.as_deref() == Some("cornell-box");
    // Informational: a failure is a warning, not a failed bake.
    let rgb_points = if cornell {
        metrics::parse_point_csv(CORNELL_POINTS_RGB, 1e-3)
            .and_then(|refs| {
                let elements =
                    metrics::compare_points(&result.mesh, &result.radiosity, &refs, None)?;
                // The smooth field the light map is filled from, at the same points.
                let field = radiant::radiosity::smooth::SmoothField::new(
                    &result.mesh,
                    &result.system,
                    &scene.surfaces,
                    &result.radiosity,
                );
                let smooth = metrics::compare_points_with(&refs, None, |r| {
                    field.radiosity_at(&result.mesh, r.position, r.normal)
                })?;
                Ok((elements, smooth))
            })
            .map_err(|e| println!("warning: no point comparison: {e}"))
            .ok()
    } else {
        None
    };
    let out = &args.out;
    let mut result = result;
    let mut spectral_json = serde_json::Value::Null;
    if args.spectral {
        let t = std::time::Instant::now();
        let materials = spectral_materials(&args.scene, args.spectra.as_deref())?;
        let sp = radiant::radiosity::spectral::solve_spectral(
            &result.system,
            &result.mesh,
            &scene.surfaces,
            &materials,
            args.bands,
            params.solver_params.tolerance,
        )?;
        let seconds = t.elapsed().as_secs_f64();
        // The difference from the RGB bake, per surface (relative, per channel).
        let mut diffs = serde_json::Map::new();
        let (mut worst, mut mean, mut area) = (0.0f64, 0.0, 0.0);
        for (s, r) in sp.surfaces.iter().zip(&result.surfaces) {
            if s.emitter {
                continue;
            }
            let d: Vec<f64> = (0..3)
                .map(|c| (s.mean[c] - r.mean[c]) / r.mean[c].abs().max(1e-12))
                .collect();
            worst = d.iter().fold(worst, |m, v| m.max(v.abs()));
            mean += s.area * d.iter().map(|v| v.abs()).sum::<f64>() / 3.0;
            area += s.area;
            diffs.insert(s.name.clone(), json!(d));
        }
        let mean = if area > 0.0 { mean / area } else { 0.0 };
        println!(
            "spectral ({} bands, {seconds:.3} s): differs from the RGB bake by {:.1} % on average, {:.1} % at most",
            sp.bands,
            mean * 100.0,
            worst * 100.0
        );
        if !sp.converged {
            println!("warning: a spectral band stopped converging");
        }
        spectral_json = json!({
            "bands": sp.bands,
            "converged": sp.converged,
            "seconds": seconds,
            "relative_difference_from_rgb": { "mean": mean, "max": worst, "per_surface": diffs },
        });
        if cornell {
            let refs = metrics::parse_point_csv(CORNELL_POINTS_SPECTRAL, 1e-3)?;
            let c =
                metrics::compare_points(&result.mesh, &sp.radiosity, &refs, Some("light_centre"))?;
            println!(
                "spectral vs Mitsuba 3 spectral path tracing at {} surface points: mean {:.2} %, max {:.2} % \
                 (reference scaled to our light's luminance)",
                c.points.len(),
                c.mean_rel * 100.0,
                c.max_rel * 100.0
            );
            spectral_json["vs_path_traced_points"] = points_json(&c);
        }
        write_atomic(
            &out.join("surfaces_rgb.csv"),
            output::surfaces_csv(&result.surfaces).as_bytes(),
        )?;
        result.surfaces = sp.surfaces;
        result.radiosity = sp.radiosity;
    }
    write_atomic(
        &out.join("surfaces.csv"),
        output::surfaces_csv(&result.surfaces).as_bytes(),
    )?;
    write_atomic(
        &out.join("patches.csv"),
        output::patches_csv(&scene, &result).as_bytes(),
    )?;
    // The renderer's atlas, filled from the smooth field.
    let lap = Instant::now();
    let field = radiant::radiosity::smooth::SmoothField::new(
        &result.mesh,
        &result.system,
        &scene.surfaces,
        &result.radiosity,
    );
    let map = lightmap::bake_lightmap(&scene, &atlas, &result.mesh, &field);
    let lightmap_s = lap.elapsed().as_secs_f64();
    let lap = Instant::now();
    output::write_lightmaps(out, &map)?;
    let write_s = lap.elapsed().as_secs_f64();
    let export = match &args.export {
        Some(path) => {
            let lap = Instant::now();
            let r = radiant::scene::gltf_export::export_gltf(
                &scene,
                Some(radiant::scene::gltf_export::LightmapExport {
                    atlas: &atlas,
                    texels: &map.texels,
                }),
                path,
            )?;
            println!(
                "exported {} ({} primitives, light-map textures {:?}, {:.2} MB) in {:.2} s",
                path.display(),
                r.primitives,
                r.lightmap_textures,
                r.bytes as f64 / 1e6,
                lap.elapsed().as_secs_f64()
            );
            json!({
                "path": path.display().to_string(),
                "primitives": r.primitives,
                "lightmap_textures": r.lightmap_textures,
                "lightmap_scale": r.lightmap_scale,
                "bytes": r.bytes,
                "seconds": lap.elapsed().as_secs_f64(),
            })
        }
        None => serde_json::Value::Null,
    };
    let total_s = start.elapsed().as_secs_f64();
    let extra = json!({
        "patch_size": params.mesh.patch_size,
        "element_levels": params.mesh.element_levels,
        "refinement": params.links.refinement,
        "far_field": params.links.far_field,
        "tolerance": params.solver_params.tolerance,
        "seed": params.ff.seed,
        "threads": rayon::current_num_threads(),
        "lightmap": {
            "width": map.width,
            "height": map.height,
            "pages": map.pages,
            "texel_density": atlas.density,
            "texel_density_asked": args.texel_density,
            "charts": atlas.charts,
            "authored": atlas.authored,
            "utilisation": atlas.utilisation(),
            "atlas_seconds": atlas_s,
            "seconds": lightmap_s,
            "write_seconds": write_s,
        },
        "export": export,
    });
    let mut report = output::report_json(
        &source,
        &result.report,
        import_s,
        total_s,
        error.as_ref().map(|(n, e)| (n.as_str(), e)),
        extra,
    );
    if !spectral_json.is_null() {
        report["spectral"] = spectral_json;
    }
    if let Some((c, smooth)) = &rgb_points {
        report["points_vs_path_traced"] = points_json(c);
        report["points_vs_path_traced"]["smooth"] = points_json(smooth);
    }
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
    if let Some((c, smooth)) = &rgb_points {
        println!(
            "RGB bake vs Mitsuba 3 RGB path tracing at {} surface points: mean {:.2} %, max {:.2} % (elements); {:.2} %, {:.2} % (the light map's smooth field)",
            c.points.len(),
            c.mean_rel * 100.0,
            c.max_rel * 100.0,
            smooth.mean_rel * 100.0,
            smooth.max_rel * 100.0
        );
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
        "wrote {}/{{surfaces.csv, patches.csv, report.json, lightmap.exr, lightmap.png}}",
        out.display()
    );
    Ok(())
}

/// `radiant` with no arguments: there is no viewer in this build, so run the headless job: bake
/// the Cornell box and plot error against time for the default methods.
pub fn run_default() -> anyhow::Result<()> {
    let out = PathBuf::from("radiant-out");
    println!(
        "radiant: baking and rendering the builtin Cornell box headless into {}/",
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
    #[cfg(not(feature = "render"))]
    let rendered = false;
    #[cfg(feature = "render")]
    let mut rendered = false;
    #[cfg(feature = "render")]
    {
        let cli = parse(&[
            "radiant",
            "render",
            "--builtin",
            "cornell-box",
            "--out",
            "radiant-out",
            "--size",
            "768x768",
        ])?;
        if let Some(crate::Command::Render(args)) = cli.command {
            // The bake and the plots are written; a machine with no GPU adapter still gets them.
            match crate::render_cmd::run(&args) {
                Ok(()) => rendered = true,
                Err(e) => eprintln!("radiant: no frame rendered: {e:#}"),
            }
        }
    }
    println!(
        "radiant: outputs in {}/: report.json (bake report), surfaces.csv, patches.csv, light maps, \
         convergence.csv and convergence.png (error against time){}",
        out.display(),
        if rendered {
            ", frame.png and frame.exr (the rendered frame)"
        } else {
            ""
        }
    );
    Ok(())
}

/// Whether this bake uses the clustered hierarchy (see `--hierarchy`).
pub(crate) fn use_clustered(
    hierarchy: &crate::HierarchyArgs,
    spectral: bool,
    scene: &radiant::scene::Scene,
    params: &radiant::radiosity::BakeParams,
) -> anyhow::Result<bool> {
    use radiant::radiosity::{FormFactorKind, SolverKind};
    let needs_triangles = [
        (spectral, "--spectral"),
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
    match hierarchy.hierarchy.as_str() {
        "triangles" => Ok(false),
        "clustered" => match needed {
            Some(what) => anyhow::bail!(
                "{what} needs the per-triangle hierarchy: use --hierarchy triangles (or auto)"
            ),
            None => Ok(true),
        },
        _ => {
            if needed.is_some() {
                return Ok(false);
            }
            Ok(radiant::radiosity::cluster::is_level(scene, params)?)
        }
    }
}

/// A bake with the clustered hierarchy, with progress on a terminal and in the log. With a
/// `checkpoint`, it resumes from it when it fits (else says why and bakes afresh), writes it
/// once the links are built (a crash while solving then loses no refinement) and again at the
/// end.
pub(crate) fn bake_clustered(
    scene: &radiant::scene::Scene,
    params: &radiant::radiosity::BakeParams,
    h: &crate::HierarchyArgs,
    checkpoint: Option<&Path>,
) -> anyhow::Result<radiant::radiosity::BakeResult> {
    use radiant::radiosity::cluster::{ClusterBake, ClusterParams, Phase, Watch};
    let cp = ClusterParams {
        memory_limit: h.memory_limit,
        samples: h.link_samples,
        ..ClusterParams::default()
    };
    let pb = progress_bar(1, "links (clustered)");
    let last_log = std::sync::Mutex::new(Instant::now());
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
        if let Ok(mut t) = last_log.lock()
            && t.elapsed().as_secs_f64() >= 5.0
        {
            *t = Instant::now();
            tracing::info!(?phase, done, total, "clustered bake progress");
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
    Ok(result)
}

/// A bake with the per-triangle hierarchy, resuming from and writing `checkpoint`.
pub(crate) fn bake_triangles(
    scene: &radiant::scene::Scene,
    params: &radiant::radiosity::BakeParams,
    checkpoint: Option<&Path>,
) -> anyhow::Result<radiant::radiosity::BakeResult> {
    let (bake, pb) = crate::start_bake(scene, params, checkpoint)?;
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
    if let Some(path) = checkpoint {
        result.write_checkpoint(path)?;
    }
    Ok(result)
}
