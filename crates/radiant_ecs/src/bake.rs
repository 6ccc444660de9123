//! The background, incremental bake.
//!
//! [`RadiosityBake`] (a resource: insert it to bake) holds the settings. Every frame, in
//! `PostUpdate` after transform propagation, two systems run:
//! - [`detect_scene_changes`] notes what changed among static entities and lights;
//! - [`drive_bake`] gathers the static scene when it changed, starts or steers the worker, and
//!   copies the worker's reports into [`BakeStatus`] and its light into [`BakedLighting`].
//!
//! The worker is a task on bevy's `AsyncComputeTaskPool`: it builds the bake (meshing, links,
//! form factors) and solves one sweep (or one shot) per step, so its results do not depend on
//! timing or thread count. The frame never waits for it. Edits are sent to the worker, which
//! keeps the links and warm-starts: materials (`Bake::edit_surfaces`), lights
//! (`Bake::edit_lights`) and moved, added or removed static geometry (`Bake::edit_geometry`, which
//! recomputes only the links the change touches); only a change of the static scene's bounding
//! box bakes again.
//! A bake that converged, or was paused, returns to the world, ready for the next edit or for
//! resuming; an edit that reaches a worker as it stops is applied on the next start.

use std::sync::{Arc, Mutex, mpsc};
use std::time::{Duration, Instant};

use bevy_ecs::prelude::*;
use bevy_tasks::{AsyncComputeTaskPool, Task, TaskPoolBuilder, futures::check_ready};
use radiant_radiosity::metrics::{SurfaceMean, surface_means};
use radiant_radiosity::smooth::{SmoothField, element_emission};
use radiant_radiosity::{Bake, BakeParams, Mesh, Rgb};
use radiant_scene::{Light, Scene, Sky, Surface};

use crate::app::{App, Plugin, PostUpdate};
use crate::scene::{
    GlobalTransform, Material, PunctualLight, Static, TransformSystems, gather_scene,
};

/// Radiosity baking of the world's [`Static`] geometry. Present → the world is baked and
/// rebaked on edits; absent → nothing is baked.
#[derive(Resource, Clone, Debug)]
pub struct RadiosityBake {
    /// Method, form factors, patch size, tolerance (default: `BakeParams::default()`).
    pub params: BakeParams,
    /// Least time between two published light updates before convergence (default: 100 ms).
    pub publish_interval: Duration,
    /// Worker threads for the bake's parallel parts, `None` for all cores (default: `None`).
    /// Results are the same for any count.
    pub threads: Option<usize>,
    /// A checkpoint file: a bake of the same geometry resumes from it without computing form
    /// factors, and it is rewritten (atomically) after each build, on convergence and on pause
    /// (default: none).
    pub checkpoint: Option<std::path::PathBuf>,
}

impl Default for RadiosityBake {
    fn default() -> Self {
        Self {
            params: BakeParams::default(),
            publish_interval: Duration::from_millis(100),
            threads: None,
            checkpoint: None,
        }
    }
}

/// Where the bake is.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BakePhase {
    /// No bake has been asked for (no [`RadiosityBake`], or nothing gathered yet).
    #[default]
    Idle,
    /// The static scene has no emitters and no lights: nothing to bake, nothing allocated.
    NoEmitters,
    /// Meshing, links and form factors.
    Building,
    /// Iterating.
    Solving,
    /// Met the tolerance (or stopped converging; see `warning`).
    Converged,
    /// Paused by [`BakeControl::pause`].
    Paused,
    /// Cancelled by [`BakeControl::cancel`]; the last published light is kept.
    Cancelled,
    /// Failed; see `error`.
    Failed,
}

/// Progress of the bake, for UIs and tests.
#[derive(Resource, Clone, Debug, Default)]
pub struct BakeStatus {
    /// The phase.
    pub phase: BakePhase,
    /// Progress of the phase in [0, 1] (building: elements linked; solving: log-residual
    /// progress toward the tolerance).
    pub progress: f64,
    /// Estimated relative error of the current solution: the residual over `1 − ρ̂`.
    pub estimated_error: f64,
    /// (seconds since this bake started, estimated error) after each step.
    pub history: Vec<(f64, f64)>,
    /// Seconds to the tolerance at the recent rate, when it can be told.
    pub eta_s: Option<f64>,
    /// Sweeps (or shots) of the solver since the bake was built.
    pub iterations: u64,
    /// Sweeps (or shots) since the last material edit: the rebake's work.
    pub iterations_since_edit: u64,
    /// Bakes built from scratch (the first one, a change of the static scene's bounding box, a
    /// rebake).
    pub builds: u64,
    /// Edits applied by warm start (materials, lights, static geometry moved, added or removed).
    pub edits: u64,
    /// Static geometry edits among them (moves, additions, removals).
    pub geometry_edits: u64,
    /// Links recomputed by geometry edits (the rest were kept).
    pub links_recomputed: usize,
    /// True while the published light no longer matches the scene (an edit is being baked).
    pub stale: bool,
    /// Elements and links of the current bake.
    pub elements: usize,
    /// Links of the current bake.
    pub links: usize,
    /// Whether the current bake resumed from the checkpoint (no form factors computed).
    pub resumed: bool,
    /// The error, when `phase` is `Failed`.
    pub error: Option<String>,
    /// A warning (the solver stopped converging), if any.
    pub warning: Option<String>,
}

/// The latest published bake result.
#[derive(Resource, Clone, Debug, Default)]
pub struct BakedLighting {
    /// Increments on every publication.
    pub generation: u64,
    /// The element hierarchy the radiosity refers to.
    pub mesh: Option<Arc<Mesh>>,
    /// Radiosity per element (emissive units).
    pub radiosity: Arc<Vec<Rgb>>,
    /// The light as a smooth field over the elements (`radiant_radiosity::smooth`), for light
    /// maps: incident radiance averaged at element vertices, each element's reflectance.
    pub field: Option<Arc<SmoothField>>,
    /// Area-weighted mean radiosity per static surface, in gather order.
    pub surfaces: Vec<SurfaceMean>,
    /// The estimated error when it was published.
    pub estimated_error: f64,
}

/// Requests to the bake; take effect on the next frame.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct BakeControl {
    paused: bool,
    cancel: bool,
    rebake: bool,
}

impl BakeControl {
    /// Stops solving after the current step; the bake is kept.
    pub fn pause(&mut self) {
        self.paused = true;
    }
    /// Continues a paused bake.
    pub fn resume(&mut self) {
        self.paused = false;
    }
    /// Stops and drops the bake; the last published light stays.
    pub fn cancel(&mut self) {
        self.cancel = true;
    }
    /// Bakes again from scratch (after a cancel, say).
    pub fn rebake(&mut self) {
        self.rebake = true;
    }
    /// Whether pause is requested.
    pub fn is_paused(&self) -> bool {
        self.paused
    }
}

/// The bake's systems.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BakeSystems;

/// Background baking: add it with [`crate::scene::ScenePlugin`] and insert [`RadiosityBake`].
pub struct BakePlugin;

impl Plugin for BakePlugin {
    fn build(&self, app: &mut App) {
        app.init_resource::<BakeStatus>()
            .init_resource::<BakedLighting>()
            .init_resource::<BakeControl>()
            .init_resource::<SceneChanges>()
            .init_resource::<BakeWorker>()
            .configure_sets(PostUpdate, BakeSystems.after(TransformSystems))
            .add_systems(
                PostUpdate,
                (detect_scene_changes, drive_bake)
                    .chain()
                    .in_set(BakeSystems),
            );
    }
}

/// What changed since the last frame.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct SceneChanges {
    /// Static geometry was added, removed, moved or reshaped.
    pub geometry: bool,
    /// Only materials of static surfaces changed.
    pub materials: bool,
    /// Punctual lights were added, removed, moved or changed, or the sky ([`SceneSky`]).
    pub lights: bool,
}

/// Notes changes to static geometry, materials and lights (Bevy change detection).
#[expect(clippy::type_complexity, reason = "change-detection filters")]
pub fn detect_scene_changes(
    geometry: Query<
        (),
        (
            With<Static>,
            Or<(
                Added<Static>,
                Changed<GlobalTransform>,
                Changed<crate::scene::Geometry>,
            )>,
        ),
    >,
    materials: Query<(), (With<Static>, Changed<Material>)>,
    lights: Query<
        (),
        Or<(
            Changed<PunctualLight>,
            (With<PunctualLight>, Changed<GlobalTransform>),
        )>,
    >,
    mut removed_static: RemovedComponents<Static>,
    mut removed_lights: RemovedComponents<PunctualLight>,
    sky: Option<Res<crate::scene::SceneSky>>,
    mut changes: ResMut<SceneChanges>,
) {
    if !geometry.is_empty() || removed_static.read().count() > 0 {
        changes.geometry = true;
    }
    let sky_changed = sky.is_some_and(|s| s.is_changed());
    if !lights.is_empty() || removed_lights.read().count() > 0 || sky_changed {
        changes.lights = true;
    }
    if !materials.is_empty() {
        changes.materials = true;
    }
}

enum Control {
    Pause,
    Cancel,
    Edit(Edit, u64),
}

enum Report {
    Building(usize, usize),
    Built {
        mesh: Arc<Mesh>,
        links: usize,
        resumed: bool,
    },
    Edited,
    Remeshed {
        mesh: Arc<Mesh>,
        links: usize,
        recomputed: usize,
    },
    /// A solver step: its iterations, estimated error and progress, at `t` seconds.
    Step {
        t: f64,
        info: radiant_radiosity::Info,
    },
    Publish {
        radiosity: Vec<Rgb>,
        field: Arc<SmoothField>,
        surfaces: Vec<SurfaceMean>,
        epoch: u64,
        converged: bool,
    },
    Warning(String),
}

enum Outcome {
    Done(Box<Bake>, u64),
    Paused(Box<Bake>, u64),
    Cancelled,
    NeedsRebuild,
    Failed(String),
    /// A level's clustered bake finished at this epoch; it keeps nothing to edit.
    Finished(u64),
    /// A level's clustered bake stopped for a pause; it starts over when resumed.
    PausedLevel,
}

enum Start {
    Build(Arc<Scene>),
    Continue(Box<Bake>, Option<Edit>),
}

/// A change the bake absorbs without starting over: new materials, new lights, and static
/// geometry moved, added or removed (the scene to change to).
struct Edit {
    surfaces: Vec<Surface>,
    /// New punctual lights and sky.
    lights: Option<(Vec<Light>, Option<Sky>)>,
    geometry: Option<Arc<Scene>>,
}

fn apply(
    bake: &mut Bake,
    edit: &Edit,
    tx: &mpsc::Sender<Report>,
) -> Result<(), radiant_radiosity::BakeError> {
    // A geometry edit brings the scene's materials and lights along (and matches surfaces by
    // name, so they must not be renamed under it first).
    if let Some(scene) = &edit.geometry {
        // Lights come with the scene.
        let stats = bake.edit_geometry(scene)?;
        let _ = tx.send(Report::Remeshed {
            mesh: Arc::new(bake.mesh.clone()),
            links: bake.system.links.len(),
            recomputed: stats.recomputed,
        });
    } else {
        if edit.surfaces.len() != bake.surfaces.len() {
            return Err(radiant_radiosity::BakeError::NeedsRebuild);
        }
        bake.edit_surfaces(&edit.surfaces)?;
        if let Some((l, sky)) = &edit.lights {
            bake.edit_lights_and_sky(l, sky.as_ref())?;
        }
    }
    Ok(())
}

/// The worker's handles, and what waits to be done.
#[derive(Resource, Default)]
pub struct BakeWorker {
    task: Option<Task<Outcome>>,
    to_worker: Option<mpsc::Sender<Control>>,
    from_worker: Option<Mutex<mpsc::Receiver<Report>>>,
    idle: Option<(Box<Bake>, u64)>,
    rebuild: Option<Arc<Scene>>,
    edit: Option<Edit>,
    /// Increments on every scene change; publications carry the epoch they match.
    epoch: u64,
    tolerance: f64,
    started: Option<Instant>,
    iterations_at_edit: u64,
    mesh: Option<Arc<Mesh>>,
    pool: Option<(usize, Arc<rayon::ThreadPool>)>,
    cancelled: Option<Arc<std::sync::atomic::AtomicBool>>,
}

impl BakeWorker {
    /// Whether a worker task exists (building or solving).
    pub fn is_running(&self) -> bool {
        self.task.is_some()
    }
    /// Whether a bake (running or idle) holds memory.
    pub fn holds_a_bake(&self) -> bool {
        self.task.is_some() || self.idle.is_some()
    }
}

/// What a worker needs besides its start.
struct WorkerSetup {
    params: BakeParams,
    publish_interval: Duration,
    checkpoint: Option<std::path::PathBuf>,
    epoch: u64,
    /// Set when the world drops this worker: it then writes no checkpoint (a newer bake may).
    cancelled: Arc<std::sync::atomic::AtomicBool>,
}

fn save(bake: &Bake, setup: &WorkerSetup, tx: &mpsc::Sender<Report>) {
    if setup.cancelled.load(std::sync::atomic::Ordering::Relaxed) {
        return;
    }
    if let Some(path) = &setup.checkpoint
        && let Err(e) = bake.write_checkpoint(path)
    {
        let _ = tx.send(Report::Warning(e.to_string()));
    }
}

fn build(scene: &Scene, setup: &WorkerSetup, tx: &mpsc::Sender<Report>) -> Result<Bake, String> {
    if let Some(path) = setup.checkpoint.as_deref().filter(|p| p.exists()) {
        match Bake::resume(scene, &setup.params, path) {
            Ok(b) => return Ok(b),
            Err(e) => tracing::info!("not resuming: {e}"),
        }
    }
    let progress = |d: usize, t: usize| {
        let _ = tx.send(Report::Building(d, t));
    };
    let b = Bake::with_progress(scene, &setup.params, &progress).map_err(|e| e.to_string())?;
    save(&b, setup, tx);
    Ok(b)
}

fn work(
    start: Start,
    setup: WorkerSetup,
    rx: mpsc::Receiver<Control>,
    tx: mpsc::Sender<Report>,
) -> Outcome {
    let send = |r: Report| {
        let _ = tx.send(r);
    };
    let (publish_interval, mut epoch) = (setup.publish_interval, setup.epoch);
    let mut bake = match start {
        Start::Build(scene)
            if radiant_radiosity::cluster::suits(&scene, &setup.params).unwrap_or(false) =>
        {
            return work_clustered(&scene, &setup, rx, &tx);
        }
        Start::Build(scene) => match build(&scene, &setup, &tx) {
            Ok(b) => {
                send(Report::Built {
                    mesh: Arc::new(b.mesh.clone()),
                    links: b.system.links.len(),
                    resumed: b.is_resumed(),
                });
                Box::new(b)
            }
            Err(e) => return Outcome::Failed(e),
        },
        Start::Continue(mut b, edit) => {
            if let Some(edit) = edit {
                match apply(&mut b, &edit, &tx) {
                    Ok(()) => send(Report::Edited),
                    Err(radiant_radiosity::BakeError::NeedsRebuild) => {
                        return Outcome::NeedsRebuild;
                    }
                    Err(e) => return Outcome::Failed(e.to_string()),
                }
            }
            b
        }
    };
    let t0 = Instant::now();
    let mut last_publish: Option<Instant> = None;
    loop {
        while let Ok(c) = rx.try_recv() {
            match c {
                Control::Cancel => return Outcome::Cancelled,
                Control::Pause => {
                    // Apply edits queued behind the pause, so none is lost.
                    while let Ok(c) = rx.try_recv() {
                        match c {
                            Control::Cancel => return Outcome::Cancelled,
                            Control::Pause => {}
                            Control::Edit(edit, e) => match apply(&mut bake, &edit, &tx) {
                                Ok(()) => {
                                    epoch = e;
                                    send(Report::Edited);
                                }
                                Err(radiant_radiosity::BakeError::NeedsRebuild) => {
                                    return Outcome::NeedsRebuild;
                                }
                                Err(err) => return Outcome::Failed(err.to_string()),
                            },
                        }
                    }
                    save(&bake, &setup, &tx);
                    return Outcome::Paused(bake, epoch);
                }
                Control::Edit(edit, e) => match apply(&mut bake, &edit, &tx) {
                    Ok(()) => {
                        epoch = e;
                        send(Report::Edited);
                    }
                    Err(radiant_radiosity::BakeError::NeedsRebuild) => {
                        return Outcome::NeedsRebuild;
                    }
                    Err(err) => return Outcome::Failed(err.to_string()),
                },
            }
        }
        // One sweep (or one shot) per step: the same sequence whatever the timing. The stall
        // rule is the bake's own (an edit's warm start resets it).
        let done = match bake.step(Duration::ZERO) {
            Ok(info) => {
                send(Report::Step {
                    t: t0.elapsed().as_secs_f64(),
                    info,
                });
                info.converged
            }
            Err(e @ radiant_radiosity::SolveError::Stalled { .. }) => {
                send(Report::Warning(e.to_string()));
                true
            }
            Err(e) => return Outcome::Failed(e.to_string()),
        };
        if done {
            // Before the final publication, so whoever sees "converged" finds the checkpoint.
            save(&bake, &setup, &tx);
        }
        if done || last_publish.is_none_or(|t| t.elapsed() >= publish_interval) {
            let radiosity = bake.radiosity();
            let surfaces = surface_means(&bake.surfaces, &bake.mesh, &radiosity);
            let field = SmoothField::new(&bake.mesh, &bake.system, &bake.surfaces, &radiosity);
            send(Report::Publish {
                field: Arc::new(field),
                radiosity,
                surfaces,
                epoch,
                converged: done,
            });
            last_publish = Some(Instant::now());
        }
        if done {
            return Outcome::Done(bake, epoch);
        }
    }
}

/// Why a clustered bake was stopped, strongest last.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum StopReason {
    Edit,
    Pause,
    Cancel,
}

/// A level's bake (more than 4096 triangles or 65 536 per-triangle elements; see
/// `radiant_radiosity::cluster::suits`): the clustered hierarchy, which keeps no links to
/// edit. Its light is published as it converges, as the per-triangle bake's is; an edit, a
/// pause or a cancel stops it (checked while links are refined and after every sweep), and an
/// edit or a resume bakes again from the start. No checkpoint is written.
fn work_clustered(
    scene: &Scene,
    setup: &WorkerSetup,
    rx: mpsc::Receiver<Control>,
    tx: &mpsc::Sender<Report>,
) -> Outcome {
    use radiant_radiosity::cluster::{self, ClusterParams, Phase, Sweep, Watch};
    use std::sync::atomic::{AtomicBool, Ordering};
    let stop = AtomicBool::new(false);
    let reason: Mutex<Option<StopReason>> = Mutex::new(None);
    let rx = Mutex::new(rx);
    let note = |r: StopReason| {
        if let Ok(mut g) = reason.lock() {
            *g = (*g).max(Some(r));
        }
        stop.store(true, Ordering::Relaxed);
    };
    let poll = || {
        if setup.cancelled.load(Ordering::Relaxed) {
            note(StopReason::Cancel);
        }
        if let Ok(rx) = rx.try_lock() {
            while let Ok(c) = rx.try_recv() {
                note(match c {
                    Control::Cancel => StopReason::Cancel,
                    Control::Pause => StopReason::Pause,
                    Control::Edit(..) => StopReason::Edit,
                });
            }
        }
    };
    let progress = |phase: Phase, done: usize, total: usize| {
        if phase == Phase::Links {
            let _ = tx.send(Report::Building(done, total));
        }
        poll();
    };
    let built = |mesh: &Mesh, links: usize| Report::Built {
        mesh: Arc::new(mesh.clone()),
        links,
        resumed: false,
    };
    let t0 = Instant::now();
    let mut sent_built = false;
    let mut last_publish: Option<Instant> = None;
    let mut emission: Option<Vec<Rgb>> = None;
    let mut on_sweep = |s: &Sweep<'_>| {
        if !sent_built {
            let _ = tx.send(built(s.mesh, s.links));
            sent_built = true;
        }
        let _ = tx.send(Report::Step {
            t: t0.elapsed().as_secs_f64(),
            info: s.info,
        });
        if last_publish.is_none_or(|t| t.elapsed() >= setup.publish_interval) {
            let emission =
                emission.get_or_insert_with(|| element_emission(s.mesh, &scene.surfaces));
            let weight: Vec<f64> = s
                .enclosed
                .iter()
                .map(|&d| f64::from(u8::from(!d)))
                .collect();
            let field = SmoothField::from_parts(
                s.mesh,
                s.reflectance,
                emission,
                Some(&weight),
                s.radiosity,
            );
            let _ = tx.send(Report::Publish {
                radiosity: s.radiosity.to_vec(),
                field: Arc::new(field),
                surfaces: surface_means(&scene.surfaces, s.mesh, s.radiosity),
                epoch: setup.epoch,
                converged: false,
            });
            last_publish = Some(Instant::now());
        }
        poll();
    };
    let watch = Watch {
        stop: Some(&stop),
        on_sweep: Some(&mut on_sweep),
    };
    let result = cluster::bake_watched(
        scene,
        &setup.params,
        &ClusterParams::default(),
        &progress,
        watch,
    );
    match result {
        Ok(r) => {
            if !sent_built {
                let _ = tx.send(built(&r.mesh, r.report.links));
            }
            if let Some(w) = r.report.warnings.last() {
                let _ = tx.send(Report::Warning(w.clone()));
            }
            let field = SmoothField::new(&r.mesh, &r.system, &scene.surfaces, &r.radiosity);
            let _ = tx.send(Report::Publish {
                field: Arc::new(field),
                radiosity: r.radiosity,
                surfaces: r.surfaces,
                epoch: setup.epoch,
                converged: true,
            });
            Outcome::Finished(setup.epoch)
        }
        Err(radiant_radiosity::BakeError::Stopped) => match reason.lock().ok().and_then(|g| *g) {
            Some(StopReason::Edit) => Outcome::NeedsRebuild,
            Some(StopReason::Pause) => Outcome::PausedLevel,
            Some(StopReason::Cancel) | None => Outcome::Cancelled,
        },
        Err(e) => Outcome::Failed(e.to_string()),
    }
}

fn thread_pool(worker: &mut BakeWorker, threads: usize) -> Option<Arc<rayon::ThreadPool>> {
    if let Some((n, p)) = &worker.pool
        && *n == threads
    {
        return Some(p.clone());
    }
    match rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("radiant-bake-{i}"))
        .build()
    {
        Ok(p) => {
            let p = Arc::new(p);
            worker.pool = Some((threads, p.clone()));
            Some(p)
        }
        Err(e) => {
            tracing::warn!("bake thread pool: {e}; using the global pool");
            None
        }
    }
}

fn spawn(worker: &mut BakeWorker, settings: &RadiosityBake, start: Start) {
    let (to_worker, rx) = mpsc::channel();
    let (tx, from_worker) = mpsc::channel();
    let setup = WorkerSetup {
        params: settings.params,
        publish_interval: settings.publish_interval,
        checkpoint: settings.checkpoint.clone(),
        epoch: worker.epoch,
        cancelled: Arc::new(std::sync::atomic::AtomicBool::new(false)),
    };
    worker.cancelled = Some(setup.cancelled.clone());
    let tolerance = settings.params.solver_params.tolerance;
    let pool = settings.threads.and_then(|n| thread_pool(worker, n.max(1)));
    // Bevy's async compute pool, if an app set it up; else a small one (the bake's parallel
    // loops run on rayon, not here).
    let task_pool = AsyncComputeTaskPool::get_or_init(|| {
        TaskPoolBuilder::new()
            .num_threads(2)
            .thread_name("radiant-async-compute".into())
            .build()
    });
    let task = task_pool.spawn(async move {
        match pool {
            Some(p) => p.install(move || work(start, setup, rx, tx)),
            None => work(start, setup, rx, tx),
        }
    });
    worker.task = Some(task);
    worker.to_worker = Some(to_worker);
    worker.from_worker = Some(Mutex::new(from_worker));
    worker.tolerance = tolerance;
}

fn drain(world: &mut World) {
    let reports: Vec<Report> = {
        let w = world.resource::<BakeWorker>();
        match &w.from_worker {
            Some(rx) => match rx.lock() {
                Ok(rx) => rx.try_iter().collect(),
                Err(_) => Vec::new(),
            },
            None => Vec::new(),
        }
    };
    for r in reports {
        match r {
            Report::Building(d, t) => {
                let mut s = world.resource_mut::<BakeStatus>();
                s.phase = BakePhase::Building;
                s.progress = if t > 0 { d as f64 / t as f64 } else { 0.0 };
            }
            Report::Built {
                mesh,
                links,
                resumed,
            } => {
                let elements = mesh.element_count();
                let mut w = world.resource_mut::<BakeWorker>();
                w.mesh = Some(mesh);
                w.started = Some(Instant::now());
                w.iterations_at_edit = 0;
                let mut s = world.resource_mut::<BakeStatus>();
                s.phase = BakePhase::Solving;
                s.elements = elements;
                s.links = links;
                s.history.clear();
                s.iterations = 0;
                s.builds += 1;
                s.resumed = resumed;
                s.warning = None;
            }
            Report::Remeshed {
                mesh,
                links,
                recomputed,
            } => {
                let mut w = world.resource_mut::<BakeWorker>();
                w.mesh = Some(mesh);
                let mut s = world.resource_mut::<BakeStatus>();
                s.links = links;
                s.geometry_edits += 1;
                s.links_recomputed += recomputed;
            }
            Report::Edited => {
                let iterations = world.resource::<BakeStatus>().iterations;
                world.resource_mut::<BakeWorker>().iterations_at_edit = iterations;
                let mut s = world.resource_mut::<BakeStatus>();
                s.edits += 1;
                s.iterations_since_edit = 0;
                s.warning = None;
            }
            Report::Step { t, info } => {
                let (tol, at_edit) = {
                    let w = world.resource::<BakeWorker>();
                    (w.tolerance, w.iterations_at_edit)
                };
                let err = info.estimated_error;
                let mut s = world.resource_mut::<BakeStatus>();
                s.phase = BakePhase::Solving;
                s.iterations = info.iterations;
                s.iterations_since_edit = info.iterations.saturating_sub(at_edit);
                s.estimated_error = err;
                s.progress = info.progress;
                s.history.push((t, err));
                s.eta_s = eta(&s.history, tol);
            }
            Report::Publish {
                radiosity,
                field,
                surfaces,
                epoch,
                converged,
            } => {
                let (current, mesh) = {
                    let w = world.resource::<BakeWorker>();
                    (w.epoch, w.mesh.clone())
                };
                let err = world.resource::<BakeStatus>().estimated_error;
                let mut l = world.resource_mut::<BakedLighting>();
                l.generation += 1;
                l.mesh = mesh;
                l.radiosity = Arc::new(radiosity);
                l.field = Some(field);
                l.surfaces = surfaces;
                l.estimated_error = err;
                let mut s = world.resource_mut::<BakeStatus>();
                s.stale = epoch < current;
                if converged && epoch == current {
                    s.phase = BakePhase::Converged;
                    s.progress = 1.0;
                    s.eta_s = Some(0.0);
                }
            }
            Report::Warning(w) => world.resource_mut::<BakeStatus>().warning = Some(w),
        }
    }
}

/// Seconds to reach `tol` at the rate of the last few steps (log-linear convergence).
fn eta(history: &[(f64, f64)], tol: f64) -> Option<f64> {
    let n = history.len();
    if n < 3 {
        return None;
    }
    let (t0, e0) = history[n.saturating_sub(8)];
    let (t1, e1) = history[n - 1];
    if e1 <= tol {
        return Some(0.0);
    }
    let rate = (e0.ln() - e1.ln()) / (t1 - t0).max(1e-9);
    (rate > 0.0 && rate.is_finite()).then(|| (e1.ln() - tol.ln()) / rate)
}

fn cancel_worker(w: &mut BakeWorker) {
    if let Some(tx) = &w.to_worker {
        let _ = tx.send(Control::Cancel);
    }
    if let Some(c) = &w.cancelled {
        c.store(true, std::sync::atomic::Ordering::Relaxed);
    }
}

fn stop(world: &mut World) {
    let mut w = world.resource_mut::<BakeWorker>();
    cancel_worker(&mut w);
    // Dropping the task detaches nothing: the worker sees Cancel at its next step and ends.
    w.task = None;
    w.to_worker = None;
    w.from_worker = None;
    w.idle = None;
    w.rebuild = None;
    w.edit = None;
}

/// Nothing emits: drop any bake and its light.
fn no_emitters(world: &mut World) {
    stop(world);
    let mut s = world.resource_mut::<BakeStatus>();
    s.phase = BakePhase::NoEmitters;
    s.stale = false;
    world.insert_resource(BakedLighting::default());
}

/// A worker that stopped behind the world's epoch missed an edit sent as it was stopping:
/// queue the current scene as an edit, so the next start applies it.
fn requeue_lost_edit(world: &mut World, epoch: u64) {
    let w = world.resource::<BakeWorker>();
    if epoch >= w.epoch || w.edit.is_some() || w.rebuild.is_some() {
        return;
    }
    let scene = gather_scene(world);
    world.resource_mut::<BakeWorker>().edit = Some(Edit {
        surfaces: scene.surfaces.clone(),
        lights: Some((scene.lights.clone(), scene.sky.clone())),
        geometry: Some(Arc::new(scene)),
    });
    world.resource_mut::<BakeStatus>().stale = true;
}

/// Starts, steers and reports on the worker. Exclusive: it gathers the scene when it changed.
pub fn drive_bake(world: &mut World) {
    let Some(settings) = world.get_resource::<RadiosityBake>().cloned() else {
        if world.resource::<BakeWorker>().holds_a_bake() {
            stop(world);
            world.resource_mut::<BakeStatus>().phase = BakePhase::Idle;
        }
        return;
    };
    let changes = std::mem::take(&mut *world.resource_mut::<SceneChanges>());
    drain(world);

    // A finished task hands the bake back.
    let outcome = {
        let mut w = world.resource_mut::<BakeWorker>();
        match w.task.as_mut().and_then(check_ready) {
            Some(o) => {
                w.task = None;
                w.to_worker = None;
                Some(o)
            }
            None => None,
        }
    };
    if let Some(o) = outcome {
        drain(world);
        match o {
            Outcome::Done(bake, epoch) => {
                world.resource_mut::<BakeWorker>().idle = Some((bake, epoch));
                requeue_lost_edit(world, epoch);
            }
            Outcome::Paused(bake, epoch) => {
                world.resource_mut::<BakeWorker>().idle = Some((bake, epoch));
                world.resource_mut::<BakeStatus>().phase = BakePhase::Paused;
                requeue_lost_edit(world, epoch);
            }
            Outcome::Cancelled => {}
            Outcome::Finished(epoch) => {
                // An edit that arrived after the bake's last look: bake the scene as it is now.
                if epoch < world.resource::<BakeWorker>().epoch {
                    let scene = Arc::new(gather_scene(world));
                    world.resource_mut::<BakeWorker>().rebuild = Some(scene);
                }
            }
            Outcome::PausedLevel => {
                let scene = Arc::new(gather_scene(world));
                world.resource_mut::<BakeWorker>().rebuild = Some(scene);
                world.resource_mut::<BakeStatus>().phase = BakePhase::Paused;
            }
            Outcome::NeedsRebuild => {
                let scene = Arc::new(gather_scene(world));
                world.resource_mut::<BakeWorker>().rebuild = Some(scene);
            }
            Outcome::Failed(e) => {
                tracing::error!("bake failed: {e}");
                let mut s = world.resource_mut::<BakeStatus>();
                s.phase = BakePhase::Failed;
                s.error = Some(e);
            }
        }
    }

    // Requests.
    let control = *world.resource::<BakeControl>();
    if control.cancel {
        stop(world);
        world.resource_mut::<BakeControl>().cancel = false;
        world.resource_mut::<BakeStatus>().phase = BakePhase::Cancelled;
        return;
    }
    if control.paused
        && let Some(tx) = &world.resource::<BakeWorker>().to_worker
    {
        let _ = tx.send(Control::Pause);
    }

    // Changes: geometry and lights bake again; materials are edited in place.
    let first = world.resource::<BakeStatus>().phase == BakePhase::Idle;
    if changes.geometry || control.rebake || first {
        world.resource_mut::<BakeControl>().rebake = false;
        let scene = gather_scene(world);
        if scene.triangles.is_empty() && !changes.geometry && first {
            // Nothing spawned yet.
            return;
        }
        if !scene.has_emitters() {
            no_emitters(world);
            return;
        }
        let mut w = world.resource_mut::<BakeWorker>();
        w.epoch += 1;
        let epoch = w.epoch;
        let has_bake = w.task.is_some() || w.idle.is_some();
        if control.rebake || !has_bake || w.rebuild.is_some() {
            w.rebuild = Some(Arc::new(scene));
            w.edit = None;
            w.idle = None;
            cancel_worker(&mut w);
        } else {
            // A rigid move keeps what it does not touch; the worker rebuilds if it is not one.
            let edit = Edit {
                surfaces: scene.surfaces.clone(),
                lights: None,
                geometry: Some(Arc::new(scene)),
            };
            if let Some(tx) = &w.to_worker {
                let _ = tx.send(Control::Edit(edit, epoch));
            } else {
                w.edit = Some(edit);
            }
        }
        world.resource_mut::<BakeStatus>().stale = true;
    } else if changes.materials || changes.lights {
        let scene = gather_scene(world);
        let lights = changes
            .lights
            .then(|| (scene.lights.clone(), scene.sky.clone()));
        if !scene.has_emitters() {
            no_emitters(world);
            return;
        }
        let mut w = world.resource_mut::<BakeWorker>();
        w.epoch += 1;
        let epoch = w.epoch;
        if w.rebuild.is_some() || (w.task.is_none() && w.idle.is_none()) {
            // No bake to edit (none yet, or the scene had no emitters): build one.
            w.rebuild = Some(Arc::new(scene));
        } else {
            // Merge with an edit still waiting: a pending move carries the whole scene.
            let pending = w.edit.take();
            let geometry = pending
                .as_ref()
                .and_then(|e| e.geometry.as_ref())
                .map(|_| Arc::new(scene.clone()));
            let lights = lights.or_else(|| pending.and_then(|e| e.lights));
            let edit = Edit {
                surfaces: scene.surfaces,
                lights,
                geometry,
            };
            if let Some(tx) = &w.to_worker {
                let _ = tx.send(Control::Edit(edit, epoch));
            } else {
                w.edit = Some(edit);
            }
        }
        world.resource_mut::<BakeStatus>().stale = true;
    }

    // Start work when the worker is free.
    if world.resource::<BakeWorker>().task.is_some() || control.paused {
        return;
    }
    let mut w = world.resource_mut::<BakeWorker>();
    if let Some(scene) = w.rebuild.take() {
        w.idle = None;
        spawn(&mut w, &settings, Start::Build(scene));
        let mut s = world.resource_mut::<BakeStatus>();
        s.phase = BakePhase::Building;
        s.progress = 0.0;
        s.error = None;
    } else if let Some((bake, bake_epoch)) = w.idle.take() {
        let edit = w.edit.take();
        let resuming = world.resource::<BakeStatus>().phase == BakePhase::Paused;
        let mut w = world.resource_mut::<BakeWorker>();
        if edit.is_some() || resuming {
            spawn(&mut w, &settings, Start::Continue(bake, edit));
            world.resource_mut::<BakeStatus>().phase = BakePhase::Solving;
        } else {
            w.idle = Some((bake, bake_epoch));
        }
    }
}
