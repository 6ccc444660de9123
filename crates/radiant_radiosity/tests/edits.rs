//! Live edits: changing materials keeps the links and warm-starts the solve, reaching the same
//! answer as a cold solve of the edited system with less work, for every iterative solver.

use radiant_radiosity::{Bake, BakeError, BakeParams, SolverKind};
use radiant_scene::Scene;

fn params(solver: SolverKind) -> BakeParams {
    let mut p = BakeParams::default();
    p.mesh.patch_size = 0.3;
    p.solver = solver;
    p.solver_params.tolerance = 1e-6;
    p
}

/// The in-editor case: one wall's colour changes. With `brighter_light`, the light's
/// emission also grows by half (a global change).
fn edited(scene: &Scene, brighter_light: bool) -> Scene {
    let mut s = scene.clone();
    for surf in &mut s.surfaces {
        if surf.name == "left_wall" {
            surf.reflectance = [0.1, 0.2, 0.7];
        }
        if brighter_light && surf.is_emitter() {
            surf.emission = surf.emission.map(|e| e * 1.5);
        }
    }
    assert_ne!(&s.surfaces, &scene.surfaces, "the edit changed nothing");
    s
}

/// Steps until converged; returns the solver's iteration count (sweeps or shots, cumulative
/// over the bake's life).
/// The largest channel difference between `got` and `reference`, and `reference`'s peak.
fn worst_and_peak(got: &[[f64; 3]], reference: &[[f64; 3]]) -> (f64, f64) {
    let peak = reference
        .iter()
        .flatten()
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let worst = got
        .iter()
        .flatten()
        .zip(reference.iter().flatten())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    (worst, peak)
}

fn solve(bake: &mut Bake) -> u64 {
    for _ in 0..100_000 {
        let p = bake
            // A zero budget is one sweep (or one shot) per step: exact counts.
            .step(std::time::Duration::ZERO)
            .expect("step");
        if p.converged {
            return p.iterations;
        }
    }
    panic!("did not converge");
}

#[test]
fn a_material_edit_warm_starts_to_the_cold_answer_with_less_work() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let target = edited(&scene, false);
    for solver in [
        SolverKind::GaussSeidel,
        SolverKind::Jacobi,
        SolverKind::Southwell,
    ] {
        let p = params(solver);
        // Warm: converge on the original, then edit.
        let mut warm = Bake::new(&scene, &p).expect("bake");
        let iters_before_edit = solve(&mut warm);
        warm.edit_surfaces(&target.surfaces).expect("edit");
        let warm_work = solve(&mut warm) - iters_before_edit;
        // Cold: the same links, edited before any solving.
        let mut cold = Bake::new(&scene, &p).expect("bake");
        cold.edit_surfaces(&target.surfaces).expect("edit");
        let cold_work = solve(&mut cold);
        let (bw, bc) = (warm.radiosity(), cold.radiosity());
        let (worst, peak) = worst_and_peak(&bw, &bc);
        assert!(
            worst <= 1e-4 * peak,
            "{solver:?}: warm and cold differ by {worst} (peak {peak})"
        );
        assert!(
            warm_work < cold_work,
            "{solver:?}: warm start took {warm_work} iterations, cold {cold_work}"
        );
        eprintln!(
            "{solver:?}: original {iters_before_edit}, after edit {warm_work} (cold {cold_work})"
        );
    }
}

#[test]
fn an_edited_bake_matches_a_fresh_bake_of_the_edited_scene() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let target = edited(&scene, true);
    let p = params(SolverKind::Southwell);
    let mut warm = Bake::new(&scene, &p).expect("bake");
    solve(&mut warm);
    warm.edit_surfaces(&target.surfaces).expect("edit");
    solve(&mut warm);
    let warm = warm.finish();
    let fresh = Bake::new(&target, &p)
        .expect("bake")
        .run_to_end(&mut |_| {})
        .expect("fresh");
    // The fresh bake refines its links for the new materials, so they differ a little: both
    // are within the discretisation error of each other.
    for (a, b) in warm.surfaces.iter().zip(&fresh.surfaces) {
        for c in 0..3 {
            let d = (a.mean[c] - b.mean[c]).abs() / b.mean[c].abs().max(1e-3);
            assert!(d < 0.02, "{}: {:?} vs {:?}", a.name, a.mean, b.mean);
        }
    }
}

#[test]
fn edits_that_need_new_links_or_break_materials_are_typed_errors() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let mut dark = scene.clone();
    for s in &mut dark.surfaces {
        s.emission = [0.0; 3];
    }
    let p = params(SolverKind::GaussSeidel);
    let mut bake = Bake::new(&dark, &p).expect("bake");
    assert!(matches!(
        bake.edit_surfaces(&scene.surfaces),
        Err(BakeError::NeedsRebuild)
    ));
    let mut bake = Bake::new(&scene, &p).expect("bake");
    let mut bad = scene.surfaces.clone();
    bad[0].reflectance = [f64::NAN, 0.5, 0.5];
    assert!(matches!(
        bake.edit_surfaces(&bad),
        Err(BakeError::InvalidMaterial { .. })
    ));
    assert!(matches!(
        bake.edit_surfaces(&scene.surfaces[1..]),
        Err(BakeError::InvalidParameter(_))
    ));
    let bad_light = radiant_scene::Light {
        name: "bad".into(),
        kind: radiant_scene::LightKind::Point,
        position: glam::DVec3::new(f64::NAN, 0.0, 0.0),
        direction: glam::DVec3::NEG_Y,
        color: [1.0; 3],
        intensity: 1.0,
        range: None,
    };
    assert!(matches!(
        bake.edit_lights(&[bad_light]),
        Err(BakeError::InvalidParameter(_))
    ));
    // Removing every emitter is fine: the answer becomes zero.
    bake.edit_surfaces(&dark.surfaces).expect("edit");
    bake.step(std::time::Duration::from_millis(50))
        .expect("step");
    assert!(bake.radiosity().iter().flatten().all(|&v| v == 0.0));
}

#[test]
fn a_checkpoint_resumes_without_form_factors_and_refuses_other_scenes() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let p = params(SolverKind::GaussSeidel);
    let dir = std::env::temp_dir().join(format!("radiant-ckpt-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let path = dir.join("bake.ckpt");
    let mut bake = Bake::new(&scene, &p).expect("bake");
    let iterations = solve(&mut bake);
    assert!(iterations > 3);
    bake.write_checkpoint(&path).expect("write");
    let t = std::time::Instant::now();
    let mut resumed = Bake::resume(&scene, &p, &path).expect("resume");
    let resume_s = t.elapsed().as_secs_f64();
    assert!(resumed.is_resumed());
    assert_eq!(resumed.system.links.len(), bake.system.links.len());
    assert!(
        resumed.report().times.form_factors < 0.5 * bake.report().times.form_factors,
        "resuming computed form factors again"
    );
    // Already converged: the first step confirms it.
    let p1 = resumed.step(std::time::Duration::ZERO).expect("step");
    assert!(p1.converged, "resumed bake not converged: {p1:?}");
    let (a, b) = (bake.radiosity(), resumed.radiosity());
    let (worst, peak) = worst_and_peak(&b, &a);
    assert!(worst <= 2e-6 * peak, "resumed differs by {worst}");
    eprintln!("resume took {resume_s:.3} s");

    // Other geometry: refused.
    let mut other = scene.clone();
    other.triangles[0].vertices[0].x += 0.01;
    assert!(matches!(
        Bake::resume(&other, &p, &path),
        Err(BakeError::Checkpoint(_))
    ));
    // Other colours: resumed, as an edit. The checkpoint holds the refinement oracle its links
    // were built with, so a geometry edit after it keeps their structure where that oracle
    // still holds and gives exactly a fresh bake's links.
    let recoloured = edited(&scene, false);
    let mut resumed = Bake::resume(&recoloured, &p, &path).expect("resume recoloured");
    let moved = moved_block(&recoloured, 0.03);
    let stats = resumed
        .edit_geometry(&moved)
        .expect("a move after a resume");
    let fresh = Bake::new(&moved, &p).expect("bake");
    let (lk, fk) = (&resumed.system.links, &fresh.system.links);
    assert!(lk.row == fk.row && lk.src == fk.src && lk.ff == fk.ff);
    assert!(lk.hidden_row == fk.hidden_row && lk.hidden_src == fk.hidden_src);
    assert!(stats.rows_walked * 10 < fresh.system.len(), "{stats:?}");
    // A checkpoint of a dark scene has no links: not resumed once something emits.
    let mut dark = scene.clone();
    for s in &mut dark.surfaces {
        s.emission = [0.0; 3];
    }
    let dark_path = dir.join("dark.ckpt");
    Bake::new(&dark, &p)
        .expect("bake")
        .write_checkpoint(&dark_path)
        .expect("write");
    assert!(matches!(
        Bake::resume(&scene, &p, &dark_path),
        Err(BakeError::Checkpoint(_))
    ));
    // Damaged or truncated files: typed errors, never a panic.
    let bytes = std::fs::read(&path).expect("read");
    let mut flipped = bytes.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x40;
    for (name, data) in [
        ("flipped", flipped),
        ("truncated", bytes[..bytes.len() / 3].to_vec()),
        ("empty", Vec::new()),
    ] {
        let bad = dir.join(name);
        std::fs::write(&bad, data).expect("write");
        assert!(
            matches!(
                Bake::resume(&scene, &p, &bad),
                Err(BakeError::Checkpoint(_))
            ),
            "{name}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The builtin box with the short block moved by `dx` metres along x.
fn moved_block(scene: &Scene, dx: f64) -> Scene {
    radiant_radiosity::scenes::translated(scene, "short_block", glam::DVec3::X * dx)
}

#[test]
fn moving_a_block_keeps_untouched_form_factors_and_matches_a_fresh_bake() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let moved = moved_block(&scene, 0.04);
    for ff in [
        radiant_radiosity::FormFactorKind::Analytic,
        radiant_radiosity::FormFactorKind::RayCast,
    ] {
        let mut p = params(SolverKind::GaussSeidel);
        p.form_factors = ff;
        let mut bake = Bake::new(&scene, &p).expect("bake");
        solve(&mut bake);
        let t = std::time::Instant::now();
        let stats = bake.edit_geometry(&moved).expect("a rigid move");
        let update_s = t.elapsed().as_secs_f64();
        solve(&mut bake);
        let fresh = Bake::new(&moved, &p)
            .expect("bake")
            .run_to_end(&mut |_| {})
            .expect("fresh");
        // Same links as a fresh bake: every kept form factor is what it would compute.
        assert_eq!(bake.system.links.row, fresh.system.links.row, "{ff:?}");
        assert_eq!(bake.system.links.src, fresh.system.links.src, "{ff:?}");
        assert_eq!(bake.system.links.ff, fresh.system.links.ff, "{ff:?}");
        assert_eq!(
            bake.system.links.hidden_row, fresh.system.links.hidden_row,
            "{ff:?}"
        );
        assert_eq!(
            bake.system.links.hidden_src, fresh.system.links.hidden_src,
            "{ff:?}"
        );
        // Receivers that stayed kept their rows' structure: only the block's own elements
        // walked the whole hierarchy again.
        let n = bake.system.len();
        assert!(
            stats.rows_walked * 10 < n,
            "{ff:?}: {} of {n} rows walked again",
            stats.rows_walked
        );
        let (a, b) = (bake.radiosity(), &fresh.radiosity);
        let (worst, peak) = worst_and_peak(&a, b);
        assert!(worst <= 1e-4 * peak, "{ff:?}: differs by {worst}");
        let share = stats.recomputed as f64 / (stats.recomputed + stats.kept) as f64;
        assert!(share < 0.9, "{ff:?}: recomputed {share:.2} of the links");
        eprintln!(
            "{ff:?}: recomputed {} of {} links ({:.0} %), update {update_s:.3} s",
            stats.recomputed,
            stats.recomputed + stats.kept,
            100.0 * share
        );
    }
    // An edit that changes the scene's bounding box changes every local coordinate: refused,
    // the caller bakes again.
    let mut p = params(SolverKind::GaussSeidel);
    p.form_factors = radiant_radiosity::FormFactorKind::Analytic;
    let mut bake = Bake::new(&scene, &p).expect("bake");
    let wider = radiant_radiosity::scenes::translated(&scene, "left_wall", glam::DVec3::X * 0.1);
    assert!(matches!(
        bake.edit_geometry(&wider),
        Err(BakeError::NeedsRebuild)
    ));
}

/// The scene without the surfaces whose names start with `prefix`.
fn without(scene: &Scene, prefix: &str) -> Scene {
    let mut s = scene.clone();
    let keep: Vec<bool> = s
        .surfaces
        .iter()
        .map(|x| !x.name.starts_with(prefix))
        .collect();
    let mut new_index = vec![u32::MAX; keep.len()];
    let mut next = 0;
    for (i, k) in keep.iter().enumerate() {
        if *k {
            new_index[i] = next;
            next += 1;
        }
    }
    s.surfaces.retain(|x| !x.name.starts_with(prefix));
    s.triangles.retain(|t| keep[t.surface as usize]);
    for t in &mut s.triangles {
        t.surface = new_index[t.surface as usize];
    }
    s
}

#[test]
fn removing_and_adding_a_block_keeps_untouched_form_factors_and_matches_a_fresh_bake() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let no_block = without(&scene, "short_block");
    assert!(no_block.surfaces.len() < scene.surfaces.len());
    let p = params(SolverKind::GaussSeidel);
    // Remove the short block, then put it back.
    for (from, to, what) in [(&scene, &no_block, "remove"), (&no_block, &scene, "add")] {
        let mut bake = Bake::new(from, &p).expect("bake");
        solve(&mut bake);
        let t = std::time::Instant::now();
        let stats = bake.edit_geometry(to).expect("a structural edit");
        let update_s = t.elapsed().as_secs_f64();
        let sweeps = solve(&mut bake);
        let fresh = Bake::new(to, &p)
            .expect("bake")
            .run_to_end(&mut |_| {})
            .expect("fresh");
        // The same links as a fresh bake, bit for bit: visibility rays are seeded by each
        // node's own triangle, not by numbers the edit shifts (compared without printing half
        // a million offsets).
        let (lk, fk) = (&bake.system.links, &fresh.system.links);
        let (l, f) = (lk.len(), fk.len());
        assert!(lk.row == fk.row, "{what}: rows differ ({l} vs {f} links)");
        assert!(lk.src == fk.src, "{what}: link sources differ");
        assert!(lk.ff == fk.ff, "{what}: form factors differ");
        assert!(
            lk.hidden_row == fk.hidden_row && lk.hidden_src == fk.hidden_src,
            "{what}: fully occluded links differ"
        );
        // Only added receivers walk the whole hierarchy again.
        let n = bake.system.len();
        assert!(
            stats.rows_walked * 10 < n,
            "{what}: {} of {n} rows walked again",
            stats.rows_walked
        );
        let (a, b) = (bake.radiosity(), &fresh.radiosity);
        let (worst, peak) = worst_and_peak(&a, b);
        assert!(
            worst <= 1e-4 * peak,
            "{what}: differs by {:.2e} of the peak",
            worst / peak
        );
        let share = stats.recomputed as f64 / (stats.recomputed + stats.kept) as f64;
        assert!(stats.kept > 0, "{what}: nothing kept");
        assert!(share < 0.9, "{what}: recomputed {share:.2} of the links");
        eprintln!(
            "{what} the short block: recomputed {} of {} links ({:.0} %), update {update_s:.3} s, \
             {sweeps} sweeps after; {l} links as fresh ({f}), answer within {:.1e} of the peak",
            stats.recomputed,
            stats.recomputed + stats.kept,
            100.0 * share,
            worst / peak
        );
    }
}

#[test]
fn an_edit_of_texture_coordinates_alone_reads_the_footprints_again() {
    // The floor under a 4 × 4 checker; its texture coordinates shifted by half a square, no
    // triangle moved: the edited bake's reflectance is a fresh bake's.
    let mut scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let mut rgba = Vec::new();
    for y in 0..4 {
        for x in 0..4 {
            let v = if (x + y) % 2 == 0 { 230u8 } else { 40 };
            rgba.extend([v, v, v, 255]);
        }
    }
    scene.images.push(radiant_scene::Image {
        name: "checker".into(),
        width: 4,
        height: 4,
        pixels: rgba.into(),
    });
    let floor = (scene.surfaces.iter().position(|s| s.name == "floor")).expect("floor") as u32;
    scene.surfaces[floor as usize].base_color_texture = Some(radiant_scene::TextureRef {
        image: 0,
        sampler: Default::default(),
        tex_coord: 0,
        transform: Default::default(),
    });
    for t in scene.triangles.iter_mut().filter(|t| t.surface == floor) {
        t.uv[0] = t
            .vertices
            .map(|v| glam::Vec2::new((3.0 * v.x) as f32, (3.0 * v.z) as f32));
    }
    let mut shifted = scene.clone();
    for t in shifted.triangles.iter_mut().filter(|t| t.surface == floor) {
        t.uv[0] = t.uv[0].map(|uv| uv + glam::Vec2::new(0.375, 0.0));
    }
    let p = params(SolverKind::GaussSeidel);
    let mut bake = Bake::new(&scene, &p).expect("bake");
    bake.edit_geometry(&shifted).expect("edits");
    let fresh = Bake::new(&shifted, &p).expect("bake").finish();
    let before = Bake::new(&scene, &p).expect("bake").finish();
    assert!(
        before.system.rho != fresh.system.rho,
        "the shift changes the floor"
    );
    assert!(bake.finish().system.rho == fresh.system.rho);
}
