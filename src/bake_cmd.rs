//! `radiant bake`, and the default job when `radiant` runs with no arguments.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use radiant::radiosity::metrics::{self, ErrorStats, PointComparison, ShippedReferences};
use radiant::radiosity::smooth::SmoothField;
use radiant::radiosity::{BakeParams, BakeResult, SolverKind, lightmap};
use radiant::scene::Scene;
use radiant::scene::atlas::Atlas;
use serde_json::json;

use crate::BakeArgs;
use crate::args::Method;
use crate::baking::{bake_clustered, bake_triangles, use_clustered};
use crate::common::{NamedReference, load_scene, reference_for};
use crate::output::{self, ensure_dir, write_atomic};

/// A point comparison as JSON: mean, max and each point.
fn points_json(c: &metrics::PointComparison) -> serde_json::Value {
    let points: Vec<serde_json::Value> = c
        .points
        .iter()
        .map(|p| json!({ "point": p.name, "ours": p.ours, "reference": p.reference, "relative_error": p.rel }))
        .collect();
    json!({ "mean_rel": c.mean_rel, "max_rel": c.max_rel, "reference_scale": c.scale, "points": points })
}

/// Spectral materials: a side file, or the measured spectra shipped with a builtin scene.
fn spectral_materials(
    shipped: Option<ShippedReferences>,
    file: Option<&Path>,
) -> anyhow::Result<std::collections::HashMap<String, radiant::radiosity::spectral::SpectralMaterial>>
{
    let text = match (file, shipped) {
        (Some(p), _) => crate::common::read_text(p, "spectra")?,
        (None, Some(s)) => s.spectra.to_string(),
        (None, None) => anyhow::bail!("--spectral needs --spectra FILE for this scene"),
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

/// What a bake works on: the scene, its parameters, the reference it is measured against and
/// its light map's atlas.
struct Job {
    scene: Scene,
    source: String,
    params: BakeParams,
    reference: Option<NamedReference>,
    shipped: Option<ShippedReferences>,
    atlas: Atlas,
    /// `--points` (located) and `--reference-points`.
    points: Option<crate::points::AskedPoints>,
    /// `--probes` and `--reference-probes`.
    probes: Option<crate::probes::AskedProbes>,
    start: Instant,
    import_s: f64,
    atlas_s: f64,
}

/// The per-surface error, named by its reference.
type NamedError = (String, ErrorStats);

/// Point comparisons against path tracing: of the elements, and of the light map's field.
type Points = (PointComparison, PointComparison);

/// What the light map's fill and the export took and wrote.
struct Written {
    map: lightmap::LightMap,
    lightmap_s: f64,
    write_s: f64,
    export: serde_json::Value,
}

pub fn run(args: &BakeArgs) -> anyhow::Result<()> {
    let solver = match args.method {
        Method::Solver(s) => s,
        #[cfg(feature = "render")]
        Method::GpuHemicube => {
            anyhow::ensure!(
                args.points.is_none(),
                "--points is not available with --method gpu-hemicube yet; bake with jacobi or gauss-seidel"
            );
            anyhow::ensure!(
                args.probes.is_none(),
                "--probes is not available with --method gpu-hemicube yet; bake with jacobi or gauss-seidel"
            );
            return crate::gather_cmd::bake(args);
        }
        #[cfg(not(feature = "render"))]
        Method::GpuHemicube => anyhow::bail!(
            "--method gpu-hemicube needs a build with the `render` feature (wgpu); use jacobi, gauss-seidel, southwell or direct"
        ),
    };
    args.solve.init_threads()?;
    if let Some(p) = &args.checkpoint
        && std::fs::metadata(p).is_ok_and(|m| !m.is_file())
    {
        anyhow::bail!(
            "--checkpoint {}: not a regular file (a checkpoint is read from and written to a file)",
            p.display()
        );
    }
    let job = prepare(args, solver)?;
    let clustered = use_clustered(args.hierarchy.hierarchy, &job.scene, &job.params)?;
    // Read before the bake, so that a bad spectra file fails at once.
    let materials = match args.spectral {
        true => Some(spectral_materials(job.shipped, args.spectra.as_deref())?),
        false => None,
    };
    let (mut result, solved) = if clustered {
        bake_clustered(
            &job.scene,
            &job.params,
            &args.hierarchy,
            args.checkpoint.as_deref(),
            materials.as_ref().map(|m| (m, args.bands)),
        )?
    } else {
        let r = bake_triangles(&job.scene, &job.params, args.checkpoint.as_deref())?;
        (r, None)
    };
    let error = match &job.reference {
        Some((name, rows)) => Some((
            name.clone(),
            metrics::compare_surfaces(&result.surfaces, rows)?,
        )),
        None => None,
    };
    let points = job.shipped.and_then(|s| rgb_points(&job.scene, &result, s));
    let spectral = match &materials {
        Some(m) => spectral(args, &job, &mut result, m, solved)?,
        None => serde_json::Value::Null,
    };
    // Measured before the light map, so that its rays and field are gone while the map's are
    // made: the probes then add nothing to the bake's peak memory (Sponza: +56 to +101 MB
    // after it); `probes.csv` is written after the map, which a failed write cannot cost.
    let probes = job
        .probes
        .as_ref()
        .map(|p| crate::probes::measure(p, &job.scene, &result, args.probe_spacing));
    let written = write_outputs(args, &job, &result)?;
    if let Some(p) = &probes {
        p.write(&args.out)?;
    }
    let probes = probes.map(|p| (p.json, p.summary));
    // Only where it is measured: on Sponza it takes 7 s.
    let shown = match job.reference {
        Some(_) => Some(shown_surfaces(args, &job, &result, &written.map)?),
        None => None,
    };
    let asked = match &job.points {
        Some(p) => Some(crate::points::write(
            p,
            &job.scene,
            &job.atlas,
            &written.map,
            &args.out,
        )?),
        None => None,
    };
    let total_s = job.start.elapsed().as_secs_f64();
    let mut report = report_json(args, &job, &result, &written, error.as_ref(), total_s);
    if let Some(shown) = &shown {
        report["parameters"]["lightmap"]["surfaces_seconds"] = json!(shown.seconds);
        report["reference"]["lightmap_error"] = output::error_json(&shown.error);
    }
    if let Some(p) = &asked {
        report["points"] = p.json().clone();
    }
    if !spectral.is_null() {
        report["spectral"] = spectral;
    }
    if let Some((json, _)) = &probes {
        report["probes"] = json.clone();
    }
    if let Some((c, smooth)) = &points {
        report["points_vs_path_traced"] = points_json(c);
        report["points_vs_path_traced"]["smooth"] = points_json(smooth);
    }
    write_atomic(
        &args.out.join("report.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    print_summary(
        args,
        &job,
        &result,
        total_s,
        points.as_ref(),
        error.as_ref(),
    );
    if let (Some((name, _)), Some(ShownSurfaces { error: e, .. })) = (&error, &shown) {
        println!(
            "the light map against {name}: mean {:.2} %, max {:.2} %, rms {:.2} % (its means over the same surfaces, in lightmap_surfaces.csv)",
            e.mean_rel * 100.0,
            e.max_rel * 100.0,
            e.rel_rms * 100.0
        );
    }
    if let Some(p) = &asked {
        println!("wrote {}/points.csv", args.out.display());
        if let Some(line) = p.summary() {
            println!("{line}");
        }
    }
    if let Some((_, line)) = &probes {
        println!("{line}");
    }
    Ok(())
}

/// Reads the scene and its reference, checks what can be checked before baking, and lays out
/// the light map's atlas (a density it cannot use fails before the bake, not after).
fn prepare(args: &BakeArgs, solver: SolverKind) -> anyhow::Result<Job> {
    let start = Instant::now();
    let params = args.solve.params(solver, args.form_factors.0)?;
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
    let points = match &args.points {
        Some(p) => Some(crate::points::read(
            &scene,
            p,
            args.reference_points.as_deref(),
        )?),
        None => None,
    };
    let probes = match &args.probes {
        Some(p) => Some(crate::probes::read(p, args.reference_probes.as_deref())?),
        None => None,
    };
    ensure_dir(&args.out)?;
    let lap = Instant::now();
    let atlas = Atlas::paged(&scene, args.texel_density, args.lightmap_page)?;
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
    Ok(Job {
        scene,
        source,
        params,
        reference,
        shipped: args.scene.shipped(),
        atlas,
        points,
        probes,
        start,
        import_s,
        atlas_s,
    })
}

/// The bake against path-traced radiosity at the surface points shipped with a builtin
/// scene: pointwise errors, not just surface means. Informational: a failure is a warning.
fn rgb_points(scene: &Scene, result: &BakeResult, shipped: ShippedReferences) -> Option<Points> {
    metrics::parse_point_csv(shipped.points_rgb, 1e-3)
        .and_then(|refs| {
            let elements = metrics::compare_points(&result.mesh, &result.radiosity, &refs, None)?;
            // The smooth field the light map is filled from, at the same points.
            let field = SmoothField::new(
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
}

/// Solves again in wavelength bands (unless the clustered bake already did: `solved`),
/// reports how far that is from the RGB bake (and from spectral path tracing, where the scene
/// ships points), writes the RGB surfaces to `surfaces_rgb.csv` and puts the spectral answer
/// in `result`. Returns the report's part.
fn spectral(
    args: &BakeArgs,
    job: &Job,
    result: &mut BakeResult,
    materials: &std::collections::HashMap<String, radiant::radiosity::spectral::SpectralMaterial>,
    solved: Option<(radiant::radiosity::spectral::SpectralResult, f64)>,
) -> anyhow::Result<serde_json::Value> {
    let (sp, seconds) = match solved {
        Some(s) => s,
        None => {
            let t = Instant::now();
            let sp = radiant::radiosity::spectral::solve_spectral(
                &result.system,
                &result.mesh,
                &job.scene.surfaces,
                materials,
                args.bands,
                job.params.solver_params.tolerance,
            )?;
            (sp, t.elapsed().as_secs_f64())
        }
    };
    let d = metrics::surface_difference(&sp.surfaces, &result.surfaces);
    println!(
        "spectral ({} bands, {seconds:.3} s): differs from the RGB bake by {:.1} % on average, {:.1} % at most",
        sp.bands,
        d.mean * 100.0,
        d.max * 100.0
    );
    if !sp.converged {
        println!("warning: a spectral band stopped converging");
    }
    let per_surface: serde_json::Map<String, serde_json::Value> = (d.per_surface.iter())
        .map(|(n, v)| (n.clone(), json!(v)))
        .collect();
    let mut out = json!({
        "bands": sp.bands,
        "converged": sp.converged,
        "seconds": seconds,
        "relative_difference_from_rgb": { "mean": d.mean, "max": d.max, "per_surface": per_surface },
    });
    if let Some(shipped) = job.shipped {
        let refs = metrics::parse_point_csv(shipped.points_spectral, 1e-3)?;
        let c = metrics::compare_points(&result.mesh, &sp.radiosity, &refs, Some("light_centre"))?;
        println!(
            "spectral vs Mitsuba 3 spectral path tracing at {} surface points: mean {:.2} %, max {:.2} % \
             (reference scaled to our light's luminance)",
            c.points.len(),
            c.mean_rel * 100.0,
            c.max_rel * 100.0
        );
        out["vs_path_traced_points"] = points_json(&c);
    }
    write_atomic(
        &args.out.join("surfaces_rgb.csv"),
        output::surfaces_csv(&result.surfaces).as_bytes(),
    )?;
    result.surfaces = sp.surfaces;
    result.radiosity = sp.radiosity;
    Ok(out)
}

/// Writes the surfaces, the patches and the light map (filled from the smooth field), and
/// the glTF export when asked for.
fn write_outputs(args: &BakeArgs, job: &Job, result: &BakeResult) -> anyhow::Result<Written> {
    let out = &args.out;
    // The tables are written on a thread of their own while the light map is filled and
    // encoded: on the Cornell box the outputs took 0.15 s one after the other.
    let (tables, light) = std::thread::scope(|scope| {
        let tables = scope.spawn(|| -> anyhow::Result<()> {
            write_atomic(
                &out.join("surfaces.csv"),
                output::surfaces_csv(&result.surfaces).as_bytes(),
            )?;
            write_atomic(
                &out.join("patches.csv"),
                output::patches_csv(&job.scene, result).as_bytes(),
            )
        });
        let lap = Instant::now();
        let map = crate::baking::light_map(
            &job.scene,
            &job.atlas,
            result,
            args.light_map.gather(job.params.ff.seed),
        );
        let lightmap_s = lap.elapsed().as_secs_f64();
        let lap = Instant::now();
        let light = output::write_lightmaps(out, &map)
            .map(|()| (map, lightmap_s, lap.elapsed().as_secs_f64()));
        (tables.join(), light)
    });
    tables.map_err(|_| anyhow::anyhow!("writing surfaces.csv and patches.csv panicked"))??;
    let (map, lightmap_s, write_s) = light?;
    let export = match &args.export {
        Some(path) => export(job, &map, path)?,
        None => serde_json::Value::Null,
    };
    Ok(Written {
        map,
        lightmap_s,
        write_s,
        export,
    })
}

/// The light map's means over the surfaces and their error against the reference.
struct ShownSurfaces {
    seconds: f64,
    error: ErrorStats,
}

/// Writes `lightmap_surfaces.csv`: the mean over each surface of what the renderer shows (the
/// light map times the albedo, plus emission), the columns of `surfaces.csv`, so that the
/// solution, its light map and a path tracer compare surface by surface
/// (`tools/light_loss.py`), and measures it against the reference as the solution is measured.
fn shown_surfaces(
    args: &BakeArgs,
    job: &Job,
    result: &BakeResult,
    map: &lightmap::LightMap,
) -> anyhow::Result<ShownSurfaces> {
    let lap = Instant::now();
    let means = radiant::radiosity::texel_light::shown_surface_means(
        &job.scene,
        &job.atlas,
        &result.mesh,
        map,
    )?;
    let Some((_, rows)) = &job.reference else {
        anyhow::bail!("the light map's surface means are measured against a reference");
    };
    let error = metrics::compare_surfaces(&means, rows)?;
    write_atomic(
        &args.out.join("lightmap_surfaces.csv"),
        output::surfaces_csv(&means).as_bytes(),
    )?;
    Ok(ShownSurfaces {
        seconds: lap.elapsed().as_secs_f64(),
        error,
    })
}

/// `--export`: the scene with its light map as binary glTF.
fn export(job: &Job, map: &lightmap::LightMap, path: &Path) -> anyhow::Result<serde_json::Value> {
    use radiant::scene::gltf_export::{LightmapExport, export_gltf};
    let lap = Instant::now();
    let lightmap = LightmapExport {
        atlas: &job.atlas,
        texels: &map.texels,
    };
    let r = export_gltf(&job.scene, Some(lightmap), path)?;
    println!(
        "exported {} ({} primitives, light-map textures {:?}, {:.2} MB) in {:.2} s; the light map in full range beside it: {}",
        path.display(),
        r.primitives,
        r.lightmap_textures,
        r.bytes as f64 / 1e6,
        lap.elapsed().as_secs_f64(),
        r.hdr_files
            .iter()
            .zip(&r.hdr_bytes)
            .map(|(f, b)| format!(
                "{} ({:.2} MB)",
                f.file_name()
                    .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
                *b as f64 / 1e6
            ))
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(json!({
        "path": path.display().to_string(),
        "primitives": r.primitives,
        "lightmap_textures": r.lightmap_textures,
        "lightmap_scale": r.lightmap_scale,
        "hdr_files": r.hdr_files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>(),
        "hdr_bytes": r.hdr_bytes,
        "bytes": r.bytes,
        "seconds": lap.elapsed().as_secs_f64(),
    }))
}

/// `report.json`: the bake's report, its parameters, the light map and the error.
fn report_json(
    args: &BakeArgs,
    job: &Job,
    result: &BakeResult,
    w: &Written,
    error: Option<&NamedError>,
    total_s: f64,
) -> serde_json::Value {
    let (params, atlas) = (&job.params, &job.atlas);
    let extra = json!({
        "patch_size": params.mesh.patch_size,
        "element_levels": params.mesh.element_levels,
        "refinement": params.links.refinement,
        "far_field": params.links.far_field,
        "tolerance": params.solver_params.tolerance,
        "seed": params.ff.seed,
        "threads": rayon::current_num_threads(),
        "lightmap": {
            "width": w.map.width,
            "height": w.map.height,
            "pages": w.map.pages,
            "texel_density": atlas.density,
            "texel_density_asked": args.texel_density,
            "charts": atlas.charts,
            "authored": atlas.authored,
            "utilisation": atlas.utilisation(),
            "atlas_seconds": job.atlas_s,
            "seconds": w.lightmap_s,
            "final_gather": args.light_map.gather(params.ff.seed).map(|g| json!({
                "strata": g.strata,
                "rays_per_gather": g.strata * g.strata,
                "stride": g.stride,
                "radius": g.filter_radius,
                "element_passes": g.element_passes,
                "lights_at_hits": g.lights_at_hits,
                "emitter_samples": g.emitter_samples,
            })),
            "write_seconds": w.write_s,
        },
        "export": w.export,
    });
    output::report_json(
        &job.source,
        &result.report,
        job.import_s,
        total_s,
        error.map(|(n, e)| (n.as_str(), e)),
        extra,
    )
}

/// The bake's figures on the terminal.
fn print_summary(
    args: &BakeArgs,
    job: &Job,
    result: &BakeResult,
    total_s: f64,
    points: Option<&Points>,
    error: Option<&NamedError>,
) {
    let r = &result.report;
    println!(
        "{}: {} patches, {} elements, {} links; {} with {} form factors",
        job.source,
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
    if let Some((c, smooth)) = points {
        println!(
            "RGB bake vs Mitsuba 3 RGB path tracing at {} surface points: mean {:.2} %, max {:.2} % (elements); {:.2} %, {:.2} % (the light map's smooth field)",
            c.points.len(),
            c.mean_rel * 100.0,
            c.max_rel * 100.0,
            smooth.mean_rel * 100.0,
            smooth.max_rel * 100.0
        );
    }
    if let Some((name, e)) = error {
        println!(
            "error against {name}: mean {:.2} %, max {:.2} %, rms {:.2} % (emitters excluded)",
            e.mean_rel * 100.0,
            e.max_rel * 100.0,
            e.rel_rms * 100.0
        );
    }
    println!(
        "wrote {}/{{surfaces.csv, patches.csv, report.json, lightmap.exr, lightmap.png}}",
        args.out.display()
    );
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
