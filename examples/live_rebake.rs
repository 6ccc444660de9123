//! The in-editor case, headless: the Cornell box bakes in the background of a bevy_ecs world,
//! then a wall's colour is edited, the block is moved and then removed; each rebake's error timeline is
//! printed, measured against the converged answer, with the main schedule's cost per frame.
//! Given a glTF scene instead, it bakes it with the clustered hierarchy and moves one prop.
//!
//! `cargo run --release --example live_rebake [PATCH_SIZE]`
//! `cargo run --release --example live_rebake SCENE.gltf [PREFIX [DX [REFINEMENT]]]`: the
//! surfaces whose names start with PREFIX moved by DX scene units along x (for Sponza,
//! `../shared/scenes/sponza/Sponza_sun.gltf VaseRound.003 0.2`: a vase moved 20 cm; for the
//! box baked clustered, `assets/cornell_box.gltf short_block 0.05 0.008`). With `--probes`
//! anywhere, the level's world also keeps an irradiance volume (`ProbeVolumeBake`), and the
//! times after the move at which the probes carry the new light are printed.

use std::sync::Arc;
use std::time::{Duration, Instant};

use radiant::ecs::prelude::*;
use radiant::radiosity::{BakeParams, Rgb};

/// Published lights: (seconds since the change, radiosity per element, whether it is a
/// geometry edit's preview).
type Snapshots = Vec<(f64, Arc<Vec<Rgb>>, bool)>;

/// Published probe volumes: (seconds since the change, the light's generation, whether it is
/// the light's preview volume, seconds its sampling took).
type Volumes = Vec<(f64, u64, bool, f64)>;

/// With probes in the world: steps frames until the volume of the current light is the full
/// one, recording each volume published since `t0` into `volumes`.
fn settle_probes(app: &mut App, t0: Instant, volumes: &mut Volumes) {
    if app.world.get_resource::<ProbeVolumeBake>().is_none() {
        return;
    }
    let mut seen = app.world.resource::<BakedProbes>().published;
    loop {
        let p = app.world.resource::<BakedProbes>();
        if p.published != seen {
            seen = p.published;
            volumes.push((
                t0.elapsed().as_secs_f64(),
                p.generation,
                p.preview,
                p.seconds,
            ));
        }
        if p.generation == app.world.resource::<BakedLighting>().generation
            && !p.in_flight
            && !p.preview
        {
            return;
        }
        app.update();
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Steps frames until converged; returns the published snapshots and the duration of every
/// frame in milliseconds.
fn run(app: &mut App, t0: Instant) -> (Snapshots, Vec<f64>) {
    run_with(app, t0, &mut Vec::new())
}

/// [`run`], recording the probe volumes published meanwhile (when the world has probes).
fn run_with(app: &mut App, t0: Instant, volumes: &mut Volumes) -> (Snapshots, Vec<f64>) {
    let mut snaps = Vec::new();
    let mut frames = Vec::new();
    let mut seen = app.world.resource::<BakedLighting>().generation;
    let mut published = app.world.get_resource::<BakedProbes>().map(|p| p.published);
    loop {
        let f = Instant::now();
        app.update();
        frames.push(f.elapsed().as_secs_f64() * 1e3);
        if let Some(p) = app.world.get_resource::<BakedProbes>()
            && Some(p.published) != published
        {
            published = Some(p.published);
            volumes.push((
                t0.elapsed().as_secs_f64(),
                p.generation,
                p.preview,
                p.seconds,
            ));
        }
        let lit = app.world.resource::<BakedLighting>();
        if lit.generation != seen && !app.world.resource::<BakeStatus>().stale {
            seen = lit.generation;
            snaps.push((
                t0.elapsed().as_secs_f64(),
                lit.radiosity.clone(),
                lit.preview,
            ));
        }
        let s = app.world.resource::<BakeStatus>();
        if s.phase == BakePhase::Converged && !s.stale {
            return (snaps, frames);
        }
        assert!(s.phase != BakePhase::Failed, "{:?}", s.error);
        // The rest of a 60 Hz frame.
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn report(what: &str, snaps: &Snapshots, frames: &mut [f64]) {
    let Some((_, last, _)) = snaps.last() else {
        return;
    };
    println!("{what}: error of each published light against the converged one");
    println!("  {:>9}  {:>10}", "t (ms)", "rel. RMS");
    let mut first_1pc = None;
    for (t, b, preview) in snaps {
        let e = radiant::radiosity::metrics::relative_difference(b, last);
        if e < 0.01 && first_1pc.is_none() {
            first_1pc = Some(*t);
        }
        let what = if *preview { "  the edit's preview" } else { "" };
        println!("  {:9.1}  {:10.2e}{what}", t * 1e3, e);
    }
    frames.sort_by(f64::total_cmp);
    println!(
        "  under 1 % after {:.1} ms; converged after {:.1} ms",
        first_1pc.unwrap_or(f64::NAN) * 1e3,
        snaps.last().map_or(f64::NAN, |s| s.0 * 1e3)
    );
    println!(
        "  main schedule per frame: median {:.3} ms, max {:.3} ms over {} frames",
        frames[frames.len() / 2],
        frames[frames.len() - 1],
        frames.len()
    );
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--probes")
        .collect();
    match args.first() {
        Some(path) if path.ends_with(".gltf") || path.ends_with(".glb") => level(path, &args[1..]),
        size => cornell(size),
    }
}

/// A level baked in the world, then one prop moved.
fn level(path: &str, args: &[String]) -> anyhow::Result<()> {
    let prefix = args.first().map_or("VaseRound.003", String::as_str);
    let dx: f64 = args.get(1).map_or(Ok(0.2), |v| v.parse())?;
    let mut params = BakeParams::default();
    if let Some(r) = args.get(2) {
        params.links.refinement = r.parse()?;
    }
    let scene = radiant::scene::load_gltf(std::path::Path::new(path))?;
    let mut app = App::new();
    app.add_plugins(RadiantPlugins)
        .insert_resource(RadiosityBake {
            params,
            hierarchy: radiant::radiosity::cluster::Hierarchy::Clustered,
            ..RadiosityBake::default()
        });
    let probes = std::env::args().any(|a| a == "--probes");
    if probes {
        app.insert_resource(ProbeVolumeBake::default());
    }
    spawn_scene(&mut app.world, &scene);
    // What the frame that takes in an edit pays to gather the world's scene (five times, the
    // median), before the bake starts.
    let mut gathers: Vec<f64> = (0..5)
        .map(|_| {
            let t = Instant::now();
            std::hint::black_box(gather_scene(&mut app.world));
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    gathers.sort_by(f64::total_cmp);
    println!(
        "{path}: the world's scene gathered in {:.1} ms (median of 5; {:.1}-{:.1})",
        gathers[2], gathers[0], gathers[4]
    );
    let t0 = Instant::now();
    let (snaps, mut frames) = run(&mut app, t0);
    let s = app.world.resource::<BakeStatus>().clone();
    println!(
        "{path}: {} elements, {} links; first bake converged in {:.2} s ({} sweeps)",
        s.size.elements,
        s.size.links,
        t0.elapsed().as_secs_f64(),
        s.progress.iterations
    );
    report("first bake", &snaps, &mut frames);
    // The probes of the converged light first, so that the move's are told apart.
    settle_probes(&mut app, Instant::now(), &mut Vec::new());
    let before = app.world.resource::<BakedLighting>().generation;

    let mut q = app.world.query::<(&Name, &mut Transform)>();
    let mut moved = 0;
    for (n, mut t) in q.iter_mut(&mut app.world) {
        if n.as_str().starts_with(prefix) {
            t.translation.x += dx;
            moved += 1;
        }
    }
    anyhow::ensure!(moved > 0, "no surface of {path} is named {prefix}...");
    let t0 = Instant::now();
    let mut volumes = Vec::new();
    let (snaps, mut frames) = run_with(&mut app, t0, &mut volumes);
    settle_probes(&mut app, t0, &mut volumes);
    let s = app.world.resource::<BakeStatus>();
    println!(
        "\n{moved} surfaces named {prefix}... moved {dx} along x: {} form factors computed, {} links, {} builds in all",
        s.counts.links_recomputed, s.size.links, s.counts.builds
    );
    report("move", &snaps, &mut frames);
    if probes {
        println!(
            "probe volumes of the lights published after the move (the light before it: {before}):"
        );
        for (t, generation, preview, seconds) in volumes.iter().filter(|v| v.1 > before) {
            let what = if *preview { "preview" } else { "full" };
            println!(
                "  {:9.1} ms  light {generation}, {what}, sampled in {seconds:.3} s",
                t * 1e3
            );
        }
    }
    Ok(())
}

/// The Cornell box: a wall recoloured, a block moved, then removed.
fn cornell(size: Option<&String>) -> anyhow::Result<()> {
    let mut params = BakeParams::default();
    if let Some(size) = size {
        params.mesh.patch_size = size.parse()?;
    }
    let mut app = App::new();
    app.add_plugins(RadiantPlugins)
        .insert_resource(RadiosityBake {
            params,
            // Publish every step, to draw the timeline; an editor would throttle.
            publish_interval: Duration::ZERO,
            ..RadiosityBake::default()
        });
    let scene = radiant::scene::builtin("cornell-box")?;
    spawn_scene(&mut app.world, &scene);

    let t0 = Instant::now();
    let (snaps, mut frames) = run(&mut app, t0);
    let s = app.world.resource::<BakeStatus>().clone();
    println!(
        "{} elements, {} links; first bake converged in {:.2} s ({} sweeps)",
        s.size.elements,
        s.size.links,
        t0.elapsed().as_secs_f64(),
        s.progress.iterations
    );
    report("first bake", &snaps, &mut frames);

    // Edit a material: links are kept, the solve warm-starts.
    let mut q = app.world.query::<(&Name, &mut Material)>();
    for (n, mut m) in q.iter_mut(&mut app.world) {
        if n.as_str() == "left_wall" {
            m.reflectance = [0.1, 0.2, 0.7];
        }
    }
    let t0 = Instant::now();
    let (snaps, mut frames) = run(&mut app, t0);
    println!(
        "\nleft wall turned blue: {} sweeps after the edit",
        app.world
            .resource::<BakeStatus>()
            .progress
            .iterations_since_edit
    );
    report("material edit", &snaps, &mut frames);

    // Move a block: a rigid move keeps the form factors it does not touch.
    let mut q = app.world.query::<(&Name, &mut Transform)>();
    for (n, mut t) in q.iter_mut(&mut app.world) {
        if n.as_str().starts_with("short_block") {
            t.translation.x += 0.05;
        }
    }
    let t0 = Instant::now();
    let (snaps, mut frames) = run(&mut app, t0);
    let s = app.world.resource::<BakeStatus>();
    println!(
        "\nshort block moved 5 cm: {} of {} links recomputed, {} builds in all",
        s.counts.links_recomputed, s.size.links, s.counts.builds
    );
    report("move", &snaps, &mut frames);

    // Remove the block: its links go, the links its bounds do not reach are kept.
    let recomputed_before = app.world.resource::<BakeStatus>().counts.links_recomputed;
    let block: Vec<Entity> = app
        .world
        .query::<(Entity, &Name)>()
        .iter(&app.world)
        .filter(|(_, n)| n.as_str().starts_with("short_block"))
        .map(|(e, _)| e)
        .collect();
    for e in block {
        app.world.despawn(e);
    }
    let t0 = Instant::now();
    let (snaps, mut frames) = run(&mut app, t0);
    let s = app.world.resource::<BakeStatus>();
    println!(
        "
short block removed: {} of {} links recomputed, {} builds in all",
        s.counts.links_recomputed - recomputed_before,
        s.size.links,
        s.counts.builds
    );
    report("removal", &snaps, &mut frames);
    Ok(())
}
