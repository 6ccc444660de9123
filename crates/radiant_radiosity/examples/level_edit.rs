//! A geometry edit of a level without the ECS: bake a glTF level clustered, move the surfaces
//! whose names start with a prefix, and time the edit and each sweep after it, with the error
//! of the light against where it converges (relative RMS over elements).
//!
//! `cargo run --release -p radiant_radiosity --example level_edit -- SCENE.gltf PREFIX DX DY DZ
//! [REFINEMENT]` (default: `../shared/scenes/sponza/Sponza_sun.gltf VaseRound.003 0.2 0 0`, a
//! vase moved 20 cm, at the default refinement). `LEVEL_EDIT_CHECKPOINT=FILE` resumes from FILE
//! (written by the first such run) instead of baking.

use std::time::Instant;

use radiant_radiosity::BakeParams;
use radiant_radiosity::cluster::{ClusterBake, ClusterParams, Watch};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args
        .first()
        .cloned()
        .unwrap_or_else(|| "../shared/scenes/sponza/Sponza_sun.gltf".into());
    let prefix = args
        .get(1)
        .cloned()
        .unwrap_or_else(|| "VaseRound.003".into());
    let num = |i: usize, d: f64| args.get(i).and_then(|v| v.parse().ok()).unwrap_or(d);
    let offset = glam::DVec3::new(num(2, 0.2), num(3, 0.0), num(4, 0.0));
    let scene = radiant_scene::load_gltf(std::path::Path::new(&path)).map_err(|e| {
        format!("{path}: {e} (Sponza lives in ../shared/scenes/sponza beside the checkout)")
    })?;
    let moved = radiant_radiosity::scenes::translated(&scene, &prefix, offset);
    let count = |s: &radiant_scene::Scene| {
        s.triangles
            .iter()
            .filter(|t| s.surfaces[t.surface as usize].name.starts_with(&prefix))
            .count()
    };
    println!(
        "{path}: {} triangles, {} of them `{prefix}*`",
        scene.triangles.len(),
        count(&scene)
    );
    let mut params = BakeParams::default();
    params.links.refinement = num(5, params.links.refinement);
    let cp = ClusterParams::default();
    let t = Instant::now();
    // With LEVEL_EDIT_CHECKPOINT=FILE: resumed from FILE when it fits (the edit then makes
    // the refinement again first), else baked and written there.
    let checkpoint = std::env::var_os("LEVEL_EDIT_CHECKPOINT").map(std::path::PathBuf::from);
    let mut bake = match checkpoint.as_deref().filter(|c| c.exists()) {
        Some(c) => ClusterBake::resume(&scene, &params, &cp, c)?,
        None => {
            let b = ClusterBake::new(&scene, &params, &cp, &|_, _, _| {}, None)?;
            if let Some(c) = &checkpoint {
                let t = Instant::now();
                b.write_checkpoint(c)?;
                println!(
                    "checkpoint written in {:.2} s: {:.0} MB",
                    t.elapsed().as_secs_f64(),
                    std::fs::metadata(c)?.len() as f64 / 1e6
                );
            }
            b
        }
    };
    println!(
        "built in {:.2} s: {} links",
        t.elapsed().as_secs_f64(),
        bake.links()
    );
    bake.run_to_end(&|_, _, _| {}, &mut Watch::default())?;
    println!("converged at {:.2} s", t.elapsed().as_secs_f64());

    let t = Instant::now();
    let mut preview = None;
    let e = bake.edit_geometry_previewed(
        &moved,
        &|_, _, _| {},
        None,
        Some(&mut |p: radiant_radiosity::cluster::EditPreview| preview = Some(p)),
    )?;
    let edited = t.elapsed().as_secs_f64();
    match &preview {
        Some(p) => {
            let t = Instant::now();
            let field = p.smooth_field(bake.surfaces());
            println!(
                "preview after {:.3} s: direct light traced again for {} elements, light gathered for {} new ones; its smooth field in {:.3} s more",
                p.seconds,
                p.retraced,
                p.gathered,
                t.elapsed().as_secs_f64(),
            );
            drop(field);
        }
        None => println!("no preview"),
    }
    println!(
        "edit: {:.3} s, {} form factors computed, {} links kept, {} of {} nodes kept",
        e.seconds, e.computed, e.kept, e.kept_nodes, e.nodes
    );
    let p = e.phases;
    println!(
        "  replay {:.3} s, meshing {:.3} s, preview {:.3} s, BVH and tree {:.3} s, direct light {:.3} s, matching {:.3} s, refinement {:.3} s, assembly {:.3} s ({}), rows {:.3} s",
        p.replay,
        p.meshing,
        p.preview,
        p.visibility,
        p.direct_light,
        p.matching,
        p.refinement,
        p.assembly,
        if e.in_place {
            "in place"
        } else {
            "beside the old record"
        },
        p.rows
    );
    println!("the edit returned after {edited:.3} s");
    if std::env::var_os("LEVEL_EDIT_QUIT").is_some() {
        return Ok(());
    }
    // Each sweep's light, then the converged one to measure them against.
    let mut lights = preview
        .map(|p| (p.seconds - edited, p.radiosity))
        .into_iter()
        .collect::<Vec<_>>();
    lights.push((0.0, bake.radiosity()));
    let t = Instant::now();
    loop {
        let info = bake.step()?;
        lights.push((t.elapsed().as_secs_f64(), bake.radiosity()));
        if info.converged || lights.len() > 200 {
            break;
        }
    }
    let last = lights.last().map(|l| l.1.clone()).unwrap_or_default();
    // Where the first light's error lies: on the moved surfaces, or on the others within a
    // metre of where they moved, or further off (shares of the squared difference).
    if let Some((_, first)) = lights.first() {
        let mesh = bake.mesh();
        let moved_at = |leaf: usize| {
            let root = mesh.leaf_node(leaf as u32).root as usize;
            let s = moved.triangles[root].surface as usize;
            moved.surfaces[s].name.starts_with(&prefix)
        };
        let (mut lo, mut hi) = (glam::DVec3::INFINITY, glam::DVec3::NEG_INFINITY);
        for leaf in (0..mesh.element_count()).filter(|&l| moved_at(l)) {
            let c = mesh.frame.to_world(mesh.leaf_node(leaf as u32).centroid);
            (lo, hi) = (lo.min(c), hi.max(c));
        }
        let mut share = [0.0f64; 3];
        for (leaf, (x, y)) in first.iter().zip(&last).enumerate() {
            let d: f64 = (0..3).map(|c| (x[c] - y[c]).powi(2)).sum();
            let c = mesh.frame.to_world(mesh.leaf_node(leaf as u32).centroid);
            let near = c.clamp(lo - offset.abs(), hi + offset.abs()).distance(c) < 1.0;
            share[if moved_at(leaf) {
                0
            } else if near {
                1
            } else {
                2
            }] += d;
        }
        let all = share.iter().sum::<f64>().max(1e-300);
        println!(
            "the first light's squared error: {:.0} % on the moved surfaces, {:.0} % within a metre of them, {:.0} % further off",
            100.0 * share[0] / all,
            100.0 * share[1] / all,
            100.0 * share[2] / all
        );
    }
    println!("seconds since the edit began, and the light's error against the converged one:");
    let mut within = None;
    for (s, b) in &lights {
        let err = radiant_radiosity::metrics::relative_difference(b, &last);
        println!("  {:>8.3} s  {:.4} %", edited + s, 100.0 * err);
        if err < 0.01 && within.is_none() {
            within = Some(edited + s);
        }
    }
    if let Some(w) = within {
        println!("within 1 % of its converged light {w:.3} s after the edit began");
    }
    let t = Instant::now();
    let fresh = ClusterBake::new(&moved, &params, &cp, &|_, _, _| {}, None)?;
    let (a, b) = (bake.rows(), fresh.rows());
    let same = a.row == b.row && a.src == b.src;
    let differ =
        a.ff.iter()
            .zip(b.ff)
            .filter(|(x, y)| x.to_bits() != y.to_bits())
            .count();
    println!(
        "a fresh bake of the moved scene: links in {:.2} s, {} form factors computed; the edit's links {}",
        t.elapsed().as_secs_f64(),
        fresh.report().clusters.map_or(0, |c| c.form_factors),
        if same && differ == 0 {
            "are the same, bit for bit".to_string()
        } else if same {
            format!("have the same structure, {differ} form factors differ")
        } else {
            format!(
                "differ in structure ({} against {} links)",
                a.src.len(),
                b.src.len()
            )
        }
    );
    Ok(())
}
