//! The clustered bake as an engine (`cluster::ClusterBake`): version-3 checkpoints (resume
//! without refining, the other hierarchy's files refused with a typed "rebake" error, damaged
//! or foreign files refused), and material and light edits that keep the links.

use radiant_radiosity::checkpoint::CheckpointError;
use radiant_radiosity::cluster::{ClusterBake, ClusterParams, EditPreview, Watch};
use radiant_radiosity::{Bake, BakeError, BakeParams, BakeResult};
use radiant_scene::Scene;

fn params() -> BakeParams {
    let mut p = BakeParams::default();
    p.links.refinement = 0.01;
    p
}

fn fresh(scene: &Scene, p: &BakeParams) -> ClusterBake {
    ClusterBake::new(scene, p, &ClusterParams::default(), &|_, _, _| {}, None).expect("builds")
}

fn run(mut b: ClusterBake) -> BakeResult {
    b.run_to_end(&|_, _, _| {}, &mut Watch::default())
        .expect("solves");
    b.finish()
}

/// Largest relative difference of the surface means (emitters aside).
fn worst(a: &BakeResult, b: &BakeResult) -> f64 {
    let mut w = 0.0f64;
    for (x, y) in a.surfaces.iter().zip(&b.surfaces) {
        assert_eq!(x.name, y.name);
        for c in 0..3 {
            if !x.emitter && x.mean[c] > 0.0 {
                w = w.max((x.mean[c] - y.mean[c]).abs() / x.mean[c]);
            }
        }
    }
    w
}

/// A sun over the box's open side.
fn sun() -> radiant_scene::Light {
    radiant_scene::Light {
        name: "sun".into(),
        kind: radiant_scene::LightKind::Directional,
        position: glam::DVec3::ZERO,
        direction: glam::DVec3::new(0.2, -0.3, 1.0).normalize(),
        intensity: 2.0,
        color: [1.0, 0.9, 0.8],
        range: None,
    }
}

fn temp(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("radiant-{name}-{}.ckpt", std::process::id()))
}

#[test]
fn a_resumed_clustered_bake_refines_nothing_and_ends_where_a_fresh_one_does() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let p = params();
    let path = temp("v3");
    // Written right after the links, before any sweep: what a crash mid-solve leaves.
    let b = fresh(&scene, &p);
    b.write_checkpoint(&path).expect("writes");
    let links = b.links();
    let a = run(b);
    assert!(a.report.converged);

    let r = ClusterBake::resume(&scene, &p, &ClusterParams::default(), &path).expect("resumes");
    assert!(r.is_resumed());
    assert_eq!(r.links(), links);
    let resumed = run(r);
    assert!(resumed.report.converged);
    assert_eq!(resumed.report.links, a.report.links);
    // The same links and the same start: the same sweeps.
    assert_eq!(resumed.radiosity, a.radiosity);

    // Written converged, it resumes converged: two sweeps confirm it.
    let mut b = fresh(&scene, &p);
    b.run_to_end(&|_, _, _| {}, &mut Watch::default())
        .expect("solves");
    b.write_checkpoint(&path).expect("writes");
    let r = ClusterBake::resume(&scene, &p, &ClusterParams::default(), &path).expect("resumes");
    let again = run(r);
    assert!(
        again.report.iterations <= 3,
        "{} sweeps",
        again.report.iterations
    );
    assert!(worst(&a, &again) < 1e-3, "{}", worst(&a, &again));
    let _ = std::fs::remove_file(&path);
}

#[test]
fn checkpoints_of_the_other_hierarchy_other_geometry_or_damaged_are_typed_errors() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let mut p = params();
    p.mesh.patch_size = 0.25;
    let cp = ClusterParams::default();
    let (v2, v3) = (temp("other-v2"), temp("other-v3"));
    // A per-triangle checkpoint (version 2) for a clustered bake, and the reverse.
    let tri = Bake::new(&scene, &p).expect("bake");
    tri.write_checkpoint(&v2).expect("writes v2");
    fresh(&scene, &p).write_checkpoint(&v3).expect("writes v3");
    match ClusterBake::resume(&scene, &p, &cp, &v2) {
        Err(BakeError::CheckpointHierarchy {
            version: 2,
            found: "per-triangle",
            needed: "clustered",
            ..
        }) => {}
        Err(e) => panic!("expected a typed rebake error, got {e}"),
        Ok(_) => panic!("a per-triangle checkpoint resumed a clustered bake"),
    }
    match Bake::resume(&scene, &p, &v3) {
        Err(e @ BakeError::CheckpointHierarchy { version: 4, .. }) => {
            assert!(e.to_string().contains("rebake"), "{e}");
        }
        Err(e) => panic!("expected a typed rebake error, got {e}"),
        Ok(_) => panic!("a clustered checkpoint resumed a per-triangle bake"),
    }
    // Other geometry: the fingerprint says so.
    let mut moved = scene.clone();
    moved.triangles[0].vertices[0].x += 0.01;
    assert!(matches!(
        ClusterBake::resume(&moved, &p, &cp, &v3),
        Err(BakeError::Checkpoint(CheckpointError::OtherScene { expected, found })) if expected != found
    ));
    // Other visibility samples per link: other links.
    let more = ClusterParams { samples: 8, ..cp };
    assert!(matches!(
        ClusterBake::resume(&scene, &p, &more, &v3),
        Err(BakeError::Checkpoint(CheckpointError::OtherScene { .. }))
    ));
    // Written when nothing emitted (materials are not in the fingerprint): no links to
    // resume from, refused rather than solved with none.
    let mut dark = scene.clone();
    dark.surfaces.iter_mut().for_each(|s| s.emission = [0.0; 3]);
    let v3_dark = temp("dark-v3");
    fresh(&dark, &p).write_checkpoint(&v3_dark).expect("writes");
    assert!(matches!(
        ClusterBake::resume(&scene, &p, &cp, &v3_dark),
        Err(BakeError::Checkpoint(CheckpointError::NoLinks))
    ));
    let _ = std::fs::remove_file(&v3_dark);
    // Damaged: every byte flipped in turn (a stride through the file) is refused, never a
    // panic or a huge allocation.
    let good = std::fs::read(&v3).expect("reads");
    for at in (0..good.len()).step_by(good.len() / 97 + 1) {
        let mut bad = good.clone();
        bad[at] ^= 0x5A;
        std::fs::write(&v3, &bad).expect("writes");
        assert!(
            ClusterBake::resume(&scene, &p, &cp, &v3).is_err(),
            "byte {at} flipped was accepted"
        );
    }
    std::fs::write(&v3, &good[..good.len() / 2]).expect("writes");
    assert!(matches!(
        ClusterBake::resume(&scene, &p, &cp, &v3),
        Err(BakeError::Checkpoint(CheckpointError::Damaged { .. }))
    ));
    let _ = std::fs::remove_file(&v2);
    let _ = std::fs::remove_file(&v3);
}

#[test]
fn material_and_light_edits_keep_the_links_and_match_a_fresh_bake() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let p = params();
    let mut b = fresh(&scene, &p);
    b.run_to_end(&|_, _, _| {}, &mut Watch::default())
        .expect("solves");
    let links = b.links();

    // The red wall turned blue: the same links, the light a fresh bake of the edited scene
    // gets (whose links were refined with the new estimates: a few differ).
    let mut edited = scene.clone();
    let red = (edited.surfaces.iter())
        .position(|s| s.name == "left_wall")
        .expect("the red wall");
    edited.surfaces[red].reflectance = [0.1, 0.2, 0.6];
    b.edit_surfaces(&edited.surfaces).expect("edits");
    assert_eq!(b.links(), links);
    let after = run(b);
    assert!(after.report.converged);
    let truth = run(fresh(&edited, &p));
    let w = worst(&truth, &after);
    eprintln!("material edit vs a fresh bake: max {:.3} %", w * 100.0);
    assert!(w < 0.02, "max {:.3} %", w * 100.0);

    // A bad material is refused and changes nothing.
    let mut b = fresh(&scene, &p);
    b.run_to_end(&|_, _, _| {}, &mut Watch::default())
        .expect("solves");
    let unlit = b.radiosity();
    let mut bad = scene.surfaces.clone();
    bad[red].reflectance = [1.5, 0.0, 0.0];
    assert!(matches!(
        b.edit_surfaces(&bad),
        Err(BakeError::InvalidMaterial { .. })
    ));

    // A sun added over the box's open side: its direct light is traced, the links kept.
    let mut lit = scene.clone();
    lit.lights.push(sun());
    b.edit_lights_and_sky(&lit.lights, None).expect("edits");
    assert_eq!(b.links(), links);
    let after = run(b);
    let truth = run(fresh(&lit, &p));
    let gain = (after.radiosity.iter().zip(&unlit))
        .map(|(x, y)| x[0] - y[0])
        .fold(0.0f64, f64::max);
    assert!(gain > 0.05, "the sun reached nothing (largest gain {gain})");
    let w = worst(&truth, &after);
    eprintln!("light edit vs a fresh bake: max {:.3} %", w * 100.0);
    assert!(w < 0.02, "max {:.3} %", w * 100.0);
}

/// The links of two bakes, bit for bit.
fn same_links(a: &ClusterBake, b: &ClusterBake) -> bool {
    let (x, y) = (a.rows(), b.rows());
    x.row == y.row
        && x.src == y.src
        && x.ff
            .iter()
            .map(|f| f.to_bits())
            .eq(y.ff.iter().map(|f| f.to_bits()))
}

/// A level: the box with every triangle split in 16 (608 input triangles), and a sun through
/// the open side so that moving a block changes direct light too; baked clustered and
/// converged.
fn sunlit_level() -> (Scene, BakeParams, ClusterBake) {
    let mut scene = radiant_radiosity::scenes::tessellated(
        &radiant_scene::builtin("cornell-box").expect("builtin"),
        2,
    );
    scene.lights.push(sun());
    let p = params();
    let mut b = fresh(&scene, &p);
    b.run_to_end(&|_, _, _| {}, &mut Watch::default())
        .expect("solves");
    (scene, p, b)
}

#[test]
fn a_geometry_edit_refines_only_what_it_touches_and_equals_a_fresh_bake() {
    let (scene, p, mut b) = sunlit_level();
    let before = b.links();
    let shift = |s: &Scene, name: &str, dx: f64| {
        radiant_radiosity::scenes::translated(s, name, glam::DVec3::new(dx, 0.0, 0.0))
    };
    // Moved by 5 cm, then again by 3 cm, then back: each edit against a fresh bake.
    let mut now = scene.clone();
    for (name, dx) in [
        ("short_block", 0.05),
        ("tall_block", 0.03),
        ("short_block", -0.05),
    ] {
        now = shift(&now, name, dx);
        let e = b.edit_geometry(&now, &|_, _, _| {}, None).expect("edits");
        let f = fresh(&now, &p);
        assert!(
            same_links(&b, &f),
            "{name} moved: links differ from a fresh bake's"
        );
        // Put together over the old record, which the next edit reads as its own.
        assert!(
            e.in_place,
            "{name} moved: the record was assembled beside the old one"
        );
        // Against the form factors a fresh bake computes (hidden links included): measured
        // 46 % for the short block, 53 % for the tall one, most of them the links of the moved
        // block's own triangles (a third of this small level's links) and of the clusters that
        // hold them, the rest links with a segment that meets its old or new place, or whose
        // source's estimate the sun's moved shadow changed.
        let all = f.report().clusters.map_or(0, |c| c.form_factors);
        let share = e.computed as f64 / all as f64;
        eprintln!(
            "{name} by {dx}: {} form factors computed of a fresh bake's {all} ({:.1} %), {} links kept, {} of {} nodes kept, {:.3} s",
            e.computed,
            100.0 * share,
            e.kept,
            e.kept_nodes,
            e.nodes,
            e.seconds
        );
        assert!(e.kept > 0 && share < 0.6, "{share}");
        assert_eq!(e.links, f.links());
        // Warm-started, it ends where a fresh bake of the moved scene does.
        let (mut x, mut y) = (b, f);
        for z in [&mut x, &mut y] {
            z.run_to_end(&|_, _, _| {}, &mut Watch::default())
                .expect("solves");
        }
        let (ra, rb) = (x.radiosity(), y.radiosity());
        let diff = ra
            .iter()
            .zip(&rb)
            .flat_map(|(a, b)| (0..3).map(move |c| (a[c] - b[c]).abs()))
            .fold(0.0, f64::max);
        let peak = rb.iter().flatten().fold(0.0f64, |m, v| m.max(*v));
        assert!(diff <= 2e-3 * peak, "{diff} of {peak}");
        b = x;
    }
    assert!(before > 0);

    // Without the record, an edit refines everything again, to the same links.
    let cp = ClusterParams {
        edits: false,
        ..ClusterParams::default()
    };
    let mut plain = ClusterBake::new(&scene, &p, &cp, &|_, _, _| {}, None).expect("builds");
    let moved = shift(&scene, "short_block", 0.05);
    let e = plain
        .edit_geometry(&moved, &|_, _, _| {}, None)
        .expect("edits");
    assert_eq!(e.kept, 0);
    assert!(same_links(&plain, &fresh(&moved, &p)));

    // A block removed, then put back: links as fresh bakes'.
    let mut gone = scene.clone();
    gone.triangles
        .retain(|t| !gone_name(&scene, t.surface).starts_with("tall_block"));
    let mut b = fresh(&scene, &p);
    b.edit_geometry(&gone, &|_, _, _| {}, None).expect("edits");
    assert!(same_links(&b, &fresh(&gone, &p)));
    b.edit_geometry(&scene, &|_, _, _| {}, None).expect("edits");
    assert!(same_links(&b, &fresh(&scene, &p)));

    // Something that changes the bounding box asks for a rebuild.
    let far = shift(&scene, "short_block", 3.0);
    assert!(matches!(
        b.edit_geometry(&far, &|_, _, _| {}, None),
        Err(BakeError::NeedsRebuild)
    ));
}

#[test]
fn a_geometry_edit_keeps_what_stayed_of_textures_and_enclosure_bit_for_bit() {
    // The tessellated box with a 4 × 4 checker on the floor and the short block, which stands
    // on the floor (the elements under it are enclosed): moved, its own footprints are read
    // again and the floor's kept, the floor's enclosed elements change where it went and came.
    let mut scene = radiant_radiosity::scenes::tessellated(
        &radiant_scene::builtin("cornell-box").expect("builtin"),
        1,
    );
    let mut rgba = Vec::new();
    for y in 0..4 {
        for x in 0..4 {
            let v = if (x + y) % 2 == 0 { 230u8 } else { 40 };
            rgba.extend([v, v, v, 255]);
        }
    }
    scene.images.push(radiant_scene::texture::Image {
        name: "checker".into(),
        width: 4,
        height: 4,
        pixels: rgba.into(),
    });
    for s in scene.surfaces.iter_mut() {
        if s.name == "floor" || s.name.starts_with("short_block") {
            s.base_color_texture = Some(radiant_scene::TextureRef {
                image: 0,
                sampler: Default::default(),
                tex_coord: 0,
                transform: Default::default(),
            });
        }
    }
    for t in &mut scene.triangles {
        t.uv[0] = t
            .vertices
            .map(|v| glam::Vec2::new((3.0 * v.x) as f32, (3.0 * (v.z + v.y)) as f32));
    }
    let p = params();
    let mut b = fresh(&scene, &p);
    let moved = radiant_radiosity::scenes::translated(
        &scene,
        "short_block",
        glam::DVec3::new(0.1, 0.0, 0.05),
    );
    b.edit_geometry(&moved, &|_, _, _| {}, None).expect("edits");
    let f = fresh(&moved, &p);
    assert!(same_links(&b, &f));
    let differ = |x: &[bool], y: &[bool]| x.iter().zip(y).filter(|(a, b)| a != b).count();
    assert_eq!(b.enclosed().len(), f.enclosed().len());
    assert_eq!(differ(b.enclosed(), f.enclosed()), 0, "enclosed elements");
    let under = |b: &ClusterBake| b.enclosed().iter().filter(|&&d| d).count();
    assert!(under(&f) > 0, "the block encloses floor elements");
    // Its edges cover elements in part: their exposure too is a fresh bake's.
    assert!(
        b.exposure() == f.exposure(),
        "exposure differs from a fresh bake's"
    );
    let all = radiant_radiosity::exposure::POINTS as u8;
    let partial = |b: &ClusterBake| b.exposure().iter().filter(|&&l| l > 0 && l < all).count();
    assert!(partial(&f) > 0, "the block covers floor elements in part");
    let same_terms = |b: ClusterBake, f: ClusterBake| {
        let (x, y) = (b.finish().system, f.finish().system);
        assert!(x.rho == y.rho, "reflectance differs from a fresh bake's");
        assert!(x.source == y.source, "sources differ from a fresh bake's");
        assert!(x.weight == y.weight, "weights differ from a fresh bake's");
        x.rho
            .iter()
            .fold((1.0f64, 0.0f64), |(lo, hi), r| (lo.min(r[0]), hi.max(r[0])))
    };
    let (lo, hi) = same_terms(b, f);
    assert!(hi > 1.5 * lo, "the checker shows: {lo} to {hi}");

    // A geometry edit brings its scene's lights along, even when no triangle moved.
    let mut b = fresh(&moved, &p);
    let mut lit = moved.clone();
    lit.lights.push(sun());
    b.edit_geometry(&lit, &|_, _, _| {}, None).expect("edits");
    same_terms(b, fresh(&lit, &p));

    // The floor's texture coordinates shifted by half a square, nothing moved: its
    // footprints are read again.
    let mut b = fresh(&moved, &p);
    let mut shifted = moved.clone();
    let floor = (shifted.surfaces.iter().position(|s| s.name == "floor")).expect("floor") as u32;
    for t in shifted.triangles.iter_mut().filter(|t| t.surface == floor) {
        t.uv[0] = t.uv[0].map(|uv| uv + glam::Vec2::new(0.375, 0.0));
    }
    b.edit_geometry(&shifted, &|_, _, _| {}, None)
        .expect("edits");
    same_terms(b, fresh(&shifted, &p));
}

#[test]
fn a_resumed_bake_edits_from_its_checkpoints_record_or_makes_its_refinement_again() {
    // A bake kept for geometry edits writes its refinement's record into its checkpoint; a
    // one-shot bake's checkpoint holds the links alone, and the first geometry edit after its
    // resume makes the refinement again with the links' form factors (none computed). Either
    // way the edit refines only what it touches, to a fresh bake's links.
    let scene = radiant_radiosity::scenes::tessellated(
        &radiant_scene::builtin("cornell-box").expect("builtin"),
        1,
    );
    let p = params();
    let path = temp("replay");
    let shift = |s: &Scene| {
        radiant_radiosity::scenes::translated(s, "short_block", glam::DVec3::new(0.05, 0.0, 0.0))
    };
    let moved = shift(&scene);
    let cp = ClusterParams::default();
    let f = fresh(&moved, &p);
    let all = f.report().clusters.map_or(0, |c| c.form_factors);

    let one_shot = ClusterParams {
        edits: false,
        ..ClusterParams::default()
    };
    let b = ClusterBake::new(&scene, &p, &one_shot, &|_, _, _| {}, None).expect("builds");
    b.write_checkpoint(&path).expect("writes");
    let small = std::fs::metadata(&path).expect("written").len();
    let mut r = ClusterBake::resume(&scene, &p, &cp, &path).expect("resumes");
    let e = r.edit_geometry(&moved, &|_, _, _| {}, None).expect("edits");
    assert!(same_links(&r, &f));
    assert!(
        e.kept > 0 && e.computed < all / 2,
        "{} of {all}",
        e.computed
    );
    assert!(e.phases.replay > 0.0);
    let first = e.computed;

    fresh(&scene, &p).write_checkpoint(&path).expect("writes");
    assert!(std::fs::metadata(&path).expect("written").len() > small);
    let mut r = ClusterBake::resume(&scene, &p, &cp, &path).expect("resumes");
    let e = r.edit_geometry(&moved, &|_, _, _| {}, None).expect("edits");
    assert!(same_links(&r, &f));
    assert_eq!((e.computed, e.phases.replay), (first, 0.0));
    // Written after that edit, the record is the edited refinement's: moved back after a
    // resume, the links are the first scene's.
    let edited = temp("replay-edited");
    r.write_checkpoint(&edited).expect("writes");
    let mut r = ClusterBake::resume(&moved, &p, &cp, &edited).expect("resumes");
    let e = r.edit_geometry(&scene, &|_, _, _| {}, None).expect("edits");
    assert!(e.kept > 0 && e.phases.replay == 0.0);
    assert!(same_links(&r, &fresh(&scene, &p)));
    let _ = std::fs::remove_file(&edited);

    // Resumed under other materials, the record is not this bake's (its estimates differ),
    // nor is the refinement made again: the edit refines everything, to a fresh bake's links
    // all the same.
    let mut other = scene.clone();
    for s in other.surfaces.iter_mut().filter(|s| s.emission == [0.0; 3]) {
        s.reflectance = s.reflectance.map(|c| 0.3 * c);
    }
    let moved = shift(&other);
    let mut r = ClusterBake::resume(&other, &p, &cp, &path).expect("resumes");
    let e = r.edit_geometry(&moved, &|_, _, _| {}, None).expect("edits");
    assert_eq!(e.kept, 0);
    assert!(same_links(&r, &fresh(&moved, &p)));
    let _ = std::fs::remove_file(&path);
}

fn gone_name(scene: &Scene, surface: u32) -> &str {
    &scene.surfaces[surface as usize].name
}

#[test]
fn a_clustered_results_smooth_field_is_the_bakes_own() {
    // The CLI fills light maps from the result's field (`SmoothField::new` over its system),
    // the ECS from the bake's (`ClusterBake::smooth_field`): the same votes, exposure
    // included (the blocks cover floor elements in part).
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let mut b = fresh(&scene, &params());
    b.run_to_end(&|_, _, _| {}, &mut Watch::default())
        .expect("solves");
    let own = b.smooth_field();
    let all = radiant_radiosity::exposure::POINTS as u8;
    assert!(b.exposure().iter().any(|&l| l > 0 && l < all));
    let result = b.finish();
    let field = radiant_radiosity::smooth::SmoothField::new(
        &result.mesh,
        &result.system,
        &scene.surfaces,
        &result.radiosity,
    );
    let mut worst = 0.0f64;
    for leaf in 0..result.mesh.element_count() as u32 {
        for w in [[1.0, 0.0, 0.0], [0.2, 0.3, 0.5]] {
            let (x, y) = (own.radiosity_in(leaf, w), field.radiosity_in(leaf, w));
            for c in 0..3 {
                worst = worst.max((x[c] - y[c]).abs() / x[c].abs().max(1e-9));
            }
        }
    }
    assert!(worst < 1e-9, "the fields differ by {worst}");
}

#[test]
fn a_geometry_edits_preview_carries_the_light_and_moves_the_shadow_before_refining() {
    // The short block moved 8 cm.
    let (scene, _, mut b) = sunlit_level();
    let old = b.radiosity();
    let moved = radiant_radiosity::scenes::translated(&scene, "short_block", glam::DVec3::X * 0.08);
    let mut preview = None;
    let e = b
        .edit_geometry_previewed(
            &moved,
            &|_, _, _| {},
            None,
            Some(&mut |v: EditPreview| preview = Some(v)),
        )
        .expect("edits");
    let preview = preview.expect("a rigid move has a preview");
    // On the edit's own mesh, before its refinement.
    assert!(std::sync::Arc::ptr_eq(&preview.mesh, &b.shared_mesh()));
    assert!(preview.seconds < e.seconds);
    assert!(preview.retraced > 0 && preview.retraced < old.len() / 2);
    assert!(
        preview
            .radiosity
            .iter()
            .flatten()
            .all(|v| v.is_finite() && *v >= 0.0)
    );
    let start = b.radiosity();
    b.run_to_end(&|_, _, _| {}, &mut Watch::default())
        .expect("solves");
    let now = b.radiosity();
    // A move keeps the elements' order: element i before is element i after.
    assert_eq!(old.len(), now.len());
    let err =
        |x: &[radiant_radiosity::Rgb]| radiant_radiosity::metrics::relative_difference(x, &now);
    let (e_preview, e_old, e_start) = (err(&preview.radiosity), err(&old), err(&start));
    eprintln!(
        "against the converged light: preview {e_preview:.4}, the light before the edit {e_old:.4}, the edit's warm start {e_start:.4}"
    );
    // The moved shadow is most of the change; what is left is bounced light.
    assert!(e_preview < 0.6 * e_old, "{e_preview} against {e_old}");
    assert!(e_preview < e_start, "{e_preview} against {e_start}");

    // A removal is previewed, and so is putting the block back: triangles that were not there,
    // whose light the preview gathers.
    let mut gone = moved.clone();
    gone.triangles
        .retain(|t| !gone_name(&moved, t.surface).starts_with("tall_block"));
    let mut shown = Vec::new();
    b.edit_geometry_previewed(&gone, &|_, _, _| {}, None, Some(&mut |v| shown.push(v)))
        .expect("edits");
    b.run_to_end(&|_, _, _| {}, &mut Watch::default())
        .expect("solves");
    b.edit_geometry_previewed(&moved, &|_, _, _| {}, None, Some(&mut |v| shown.push(v)))
        .expect("edits");
    assert_eq!(shown.len(), 2);
    assert_eq!(shown[0].gathered, 0);
    let start = b.radiosity();
    b.run_to_end(&|_, _, _| {}, &mut Watch::default())
        .expect("solves");
    let now = b.radiosity();
    let back = &shown[1];
    let block: Vec<usize> = (0..now.len())
        .filter(|&i| {
            let root = b.mesh().leaf_node(i as u32).root as usize;
            gone_name(&moved, moved.triangles[root].surface).starts_with("tall_block")
        })
        .collect();
    assert_eq!(back.gathered, block.len());
    let sum = |x: &[radiant_radiosity::Rgb]| -> f64 {
        block.iter().map(|&i| x[i].iter().sum::<f64>()).sum()
    };
    let (got, want, warm) = (sum(&back.radiosity), sum(&now), sum(&start));
    let err =
        |x: &[radiant_radiosity::Rgb]| radiant_radiosity::metrics::relative_difference(x, &now);
    eprintln!(
        "the block put back: its light {got:.4} in the preview, {want:.4} converged, {warm:.4} at the warm start; the level {:.4} against {:.4}",
        err(&back.radiosity),
        err(&start)
    );
    assert!((got - want).abs() < 0.2 * want, "{got} against {want}");
    assert!(err(&back.radiosity) < err(&start));

    // A move that brings a material change along has no preview.
    let mut recoloured =
        radiant_radiosity::scenes::translated(&moved, "short_block", glam::DVec3::X * -0.08);
    recoloured.surfaces[0].reflectance = [0.3; 3];
    let mut none = 0;
    b.edit_geometry_previewed(&recoloured, &|_, _, _| {}, None, Some(&mut |_| none += 1))
        .expect("edits");
    assert_eq!(none, 0);
}
