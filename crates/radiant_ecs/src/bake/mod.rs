//! The background, incremental bake.
//!
//! [`RadiosityBake`] (a resource: insert it to bake) holds the settings. Every frame, in
//! `PostUpdate` after transform propagation, two systems run:
//! - [`detect_scene_changes`] notes what changed among static entities and lights;
//! - [`drive_bake`] gathers the static scene when it changed, starts or steers the worker, and
//!   copies the worker's reports into [`BakeStatus`] and its light into [`BakedLighting`].
//!
//! The worker (`worker`) is a task on bevy's `AsyncComputeTaskPool`: it builds the bake
//! (meshing, links, form factors) and solves one sweep (or one shot) per step, so its results
//! do not depend on timing or thread count. The frame never waits for it. Edits are sent to
//! the worker, which keeps the links and warm-starts:
//! - a scene the size of the Cornell box bakes per triangle (`radiant_radiosity::Bake`):
//!   materials, lights and the sky, and moved, added or removed static geometry
//!   (`Bake::edit_geometry`, which recomputes only the links the change touches); a change of
//!   the static scene's bounding box bakes again;
//! - a level (`radiant_radiosity::cluster::suits`), or any scene when
//!   [`RadiosityBake::hierarchy`] asks for it, bakes clustered
//!   (`radiant_radiosity::cluster::ClusterBake`): materials, lights and the sky keep its
//!   links, and a geometry edit refines only what it touches (`ClusterBake::edit_geometry`);
//!   one that arrives while the level's links are being built stops the build, which starts
//!   again on the edited scene.
//!
//! A bake that converged, or was paused, returns to the world, ready for the next edit or for
//! resuming; an edit that reaches a worker as it stops is applied on the next start. The
//! world's side is a small state machine, [`BakeWorker`]: no bake, a bake held idle, or a
//! worker running, and at most one piece of pending work (a rebuild or an edit).

mod worker;

use std::sync::{Arc, Mutex, mpsc};
use std::time::Duration;

use bevy_ecs::prelude::*;
use bevy_tasks::{AsyncComputeTaskPool, Task, TaskPoolBuilder, futures::check_ready};
use radiant_radiosity::cluster::{ClusterParams, Hierarchy};
use radiant_radiosity::metrics::SurfaceMean;
use radiant_radiosity::smooth::SmoothField;
use radiant_radiosity::{BakeError, BakeParams, Mesh, Rgb, SolveError};
use radiant_scene::Scene;

use crate::app::{App, Plugin, PostUpdate};
use crate::scene::{
    GlobalTransform, Material, PunctualLight, Static, TransformSystems, gather_scene,
};
use worker::{Control, Edit, Held, Outcome, Published, Report, Setup, Start};

/// Radiosity baking of the world's [`Static`] geometry. Present → the world is baked and
/// rebaked on edits; absent → nothing is baked.
#[derive(Resource, Clone, Debug)]
pub struct RadiosityBake {
    /// Method, form factors, patch size, tolerance (default: `BakeParams::default()`).
    pub params: BakeParams,
    /// The clustered hierarchy's memory budget, visibility samples and sweeps, for levels
    /// (default: `ClusterParams::default()`).
    pub cluster: ClusterParams,
    /// Least time between two published light updates before convergence (default: 100 ms).
    pub publish_interval: Duration,
    /// Worker threads for the bake's parallel parts, `None` for all cores (default: `None`).
    /// Results are the same for any count.
    pub threads: Option<usize>,
    /// A checkpoint file: a bake of the same geometry resumes from it without computing form
    /// factors (or refining a level's links), and it is rewritten (atomically) after each
    /// build, on convergence and on pause (default: none).
    pub checkpoint: Option<std::path::PathBuf>,
    /// Which link hierarchy bakes (default: `Auto`, the clustered one for a level). An editor
    /// that moves geometry of a small scene often may ask for `Clustered`: its geometry edits
    /// cost what they touch at any size.
    pub hierarchy: Hierarchy,
}

impl Default for RadiosityBake {
    fn default() -> Self {
        Self {
            params: BakeParams::default(),
            cluster: ClusterParams::default(),
            publish_interval: Duration::from_millis(100),
            threads: None,
            checkpoint: None,
            hierarchy: Hierarchy::Auto,
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
    /// Paused by [`BakeControl::pause`] (a pause during a build takes effect when the links
    /// are built).
    Paused,
    /// Cancelled by [`BakeControl::cancel`]; the last published light is kept.
    Cancelled,
    /// Failed; see `error`.
    Failed,
}

impl BakePhase {
    /// What the phase is, in words (the inspector's and the window title's).
    pub fn name(self) -> &'static str {
        match self {
            BakePhase::Idle => "idle",
            BakePhase::NoEmitters => "nothing to bake (no emitters)",
            BakePhase::Building => "building links",
            BakePhase::Solving => "solving",
            BakePhase::Converged => "converged",
            BakePhase::Paused => "paused",
            BakePhase::Cancelled => "cancelled",
            BakePhase::Failed => "failed",
        }
    }
}

/// Progress of the current phase.
#[derive(Clone, Copy, Debug, Default)]
pub struct BakeProgress {
    /// In [0, 1]; building: elements linked; solving: progress in log error toward the
    /// tolerance (`radiant_radiosity::Info::progress`).
    pub fraction: f64,
    /// Sweeps (or shots) of the solver since the bake was built.
    pub iterations: u64,
    /// Sweeps (or shots) since the last edit: the rebake's work.
    pub iterations_since_edit: u64,
}

/// How far the current light is from converged.
#[derive(Clone, Copy, Debug, Default)]
pub struct BakeEstimate {
    /// Estimated relative error (`radiant_radiosity::Info::estimated_error`).
    pub error: f64,
    /// Seconds to the tolerance at the recent rate, when it can be told
    /// (`radiant_radiosity::eta_seconds`).
    pub eta_s: Option<f64>,
}

/// The size of the current bake.
#[derive(Clone, Copy, Debug, Default)]
pub struct BakeSize {
    /// Elements (leaves of the element hierarchy).
    pub elements: usize,
    /// Links.
    pub links: usize,
    /// Whether the bake resumed from the checkpoint (no form factors computed).
    pub resumed: bool,
}

/// What the bake has done since the world started.
#[derive(Clone, Copy, Debug, Default)]
pub struct BakeCounts {
    /// Bakes built from scratch (the first one, a change the bake cannot absorb, a rebake).
    pub builds: u64,
    /// Edits applied by warm start (materials, lights, static geometry moved, added or removed).
    pub edits: u64,
    /// Static geometry edits among them (moves, additions, removals).
    pub geometry_edits: u64,
    /// Links recomputed by geometry edits (the rest were kept).
    pub links_recomputed: usize,
    /// Previews published by geometry edits before their refinement ([`BakedLighting::preview`]).
    pub previews: u64,
}

/// Something the bake went on past.
#[derive(Clone, Debug, thiserror::Error)]
pub enum BakeWarning {
    /// The solver stopped converging; the light is what it reached.
    #[error(transparent)]
    Stalled(SolveError),
    /// The checkpoint could not be written.
    #[error("checkpoint not written: {0}")]
    Checkpoint(Arc<BakeError>),
}

/// The bake's state, for UIs and tests.
#[derive(Resource, Clone, Debug, Default)]
pub struct BakeStatus {
    /// The phase.
    pub phase: BakePhase,
    /// True while the published light no longer matches the scene (an edit is being baked).
    pub stale: bool,
    /// Progress of the phase.
    pub progress: BakeProgress,
    /// The estimated error, and the time to the tolerance.
    pub estimate: BakeEstimate,
    /// (seconds since this bake was built, estimated error) after each step.
    pub history: Vec<(f64, f64)>,
    /// Elements and links.
    pub size: BakeSize,
    /// Builds and edits.
    pub counts: BakeCounts,
    /// The error, when `phase` is `Failed`.
    pub error: Option<Arc<BakeError>>,
    /// A warning, if any.
    pub warning: Option<BakeWarning>,
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
    /// A geometry edit's first look at its light, published before the edit refines its links
    /// (`radiant_radiosity::cluster::EditPreview`: the light carried over, the direct light
    /// traced again where the edit may have changed it); `estimated_error` is the one before
    /// the edit. The edit's sweeps publish the light itself.
    pub preview: bool,
}

/// The world's scene as the bake last gathered it, for other work that follows the bake (the
/// probes): filled at every change the bake absorbs, only while this resource exists, so the
/// scene is not gathered on the frame a second time for the same change.
#[derive(Resource, Clone, Debug, Default)]
pub struct SceneSnapshot {
    /// The bake's epoch ([`BakeWorker::epoch`]) the scene matches.
    pub epoch: u64,
    /// The epoch at which static geometry last changed (or the bake started over): what is
    /// built over the triangles alone (rays) stays valid while it is the same.
    pub geometry_epoch: u64,
    /// The scene at `epoch`; its holder may drop it (to free it) and gather it again.
    pub scene: Option<Arc<Scene>>,
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
    /// Punctual lights were added, removed, moved or changed, or the sky ([`SceneSky`](crate::scene::SceneSky)).
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

/// The world's side of the bake: no bake, a bake held between workers, or a worker running;
/// and the work waiting for the worker to be free.
#[derive(Resource, Default)]
pub struct BakeWorker {
    state: WorkerState,
    pending: Option<Pending>,
    /// Increments on every scene change; publications carry the epoch they match.
    epoch: u64,
    pool: Option<(usize, Arc<rayon::ThreadPool>)>,
}

#[derive(Default)]
enum WorkerState {
    #[default]
    Empty,
    /// Converged or paused, ready for an edit or the resume.
    Idle {
        held: Box<Held>,
        paused: bool,
    },
    Running(Running),
}

/// A worker task and its channels.
struct Running {
    task: Task<Outcome>,
    control: mpsc::Sender<Control>,
    reports: Mutex<mpsc::Receiver<Report>>,
    /// Set to drop the worker: it stops at its next look and writes no checkpoint.
    cancelled: Arc<std::sync::atomic::AtomicBool>,
}

/// Work for the worker once it is free.
enum Pending {
    /// Bake this scene from scratch.
    Rebuild(Arc<Scene>),
    /// Apply this edit to the held bake.
    Edit(Edit),
}

impl BakeWorker {
    /// Increments on every scene change the bake absorbs: a light published at this epoch
    /// matches the world's scene as it is.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }
    /// Whether a worker task exists (building or solving).
    pub fn is_running(&self) -> bool {
        matches!(self.state, WorkerState::Running(_))
    }
    /// Whether a bake (running or idle) holds memory.
    pub fn holds_a_bake(&self) -> bool {
        !matches!(self.state, WorkerState::Empty)
    }

    fn rebuild_pending(&self) -> bool {
        matches!(self.pending, Some(Pending::Rebuild(_)))
    }

    /// Tells a running worker to stop and forget its bake (a newer one is coming).
    fn cancel_running(&self) {
        if let WorkerState::Running(r) = &self.state {
            let _ = r.control.send(Control::Cancel);
            r.cancelled
                .store(true, std::sync::atomic::Ordering::Relaxed);
        }
    }

    /// Drops everything: the worker (it ends at its next look), the held bake, the pending
    /// work.
    fn stop(&mut self) {
        self.cancel_running();
        self.state = WorkerState::Empty;
        self.pending = None;
    }

    /// Sends an edit to the running worker, or keeps it for the next start.
    fn edit(&mut self, edit: Edit) {
        match &self.state {
            WorkerState::Running(r) => {
                let _ = r.control.send(Control::Edit(edit, self.epoch));
            }
            _ => self.pending = Some(Pending::Edit(edit)),
        }
    }

    /// Reports sent so far.
    fn reports(&self) -> Vec<Report> {
        match &self.state {
            WorkerState::Running(r) => r
                .reports
                .lock()
                .map_or_else(|_| Vec::new(), |rx| rx.try_iter().collect::<Vec<Report>>()),
            _ => Vec::new(),
        }
    }

    fn thread_pool(&mut self, threads: usize) -> Option<Arc<rayon::ThreadPool>> {
        if let Some((n, p)) = &self.pool
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
                self.pool = Some((threads, p.clone()));
                Some(p)
            }
            Err(e) => {
                tracing::warn!("bake thread pool: {e}; using the global pool");
                None
            }
        }
    }

    fn spawn(&mut self, settings: &RadiosityBake, start: Start) {
        let (control, rx) = mpsc::channel();
        let (tx, reports) = mpsc::channel();
        let cancelled = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let setup = Setup {
            params: settings.params,
            cluster: settings.cluster,
            publish_interval: settings.publish_interval,
            checkpoint: settings.checkpoint.clone(),
            hierarchy: settings.hierarchy,
            epoch: self.epoch,
            cancelled: cancelled.clone(),
        };
        let pool = settings.threads.and_then(|n| self.thread_pool(n.max(1)));
        // Bevy's async compute pool, if an app set it up; else a small one (the bake's
        // parallel loops run on rayon, not here).
        let task_pool = AsyncComputeTaskPool::get_or_init(|| {
            TaskPoolBuilder::new()
                .num_threads(2)
                .thread_name("radiant-async-compute".into())
                .build()
        });
        let task = task_pool.spawn(async move {
            match pool {
                Some(p) => p.install(move || worker::work(start, setup, rx, tx)),
                None => worker::work(start, setup, rx, tx),
            }
        });
        self.state = WorkerState::Running(Running {
            task,
            control,
            reports: Mutex::new(reports),
            cancelled,
        });
    }
}

/// Copies the worker's reports into [`BakeStatus`] and [`BakedLighting`].
fn drain(world: &mut World) {
    let reports = world.resource::<BakeWorker>().reports();
    if reports.is_empty() {
        return;
    }
    let tolerance = (world.get_resource::<RadiosityBake>())
        .map_or_else(BakeParams::default, |b| b.params)
        .solver_params
        .tolerance;
    let epoch = world.resource::<BakeWorker>().epoch;
    for r in reports {
        let mut s = world.resource_mut::<BakeStatus>();
        match r {
            Report::Building { done, total } => {
                s.phase = BakePhase::Building;
                s.progress.fraction = if total > 0 {
                    done as f64 / total as f64
                } else {
                    0.0
                };
            }
            Report::Built {
                elements,
                links,
                resumed,
            } => {
                s.phase = BakePhase::Solving;
                s.size = BakeSize {
                    elements,
                    links,
                    resumed,
                };
                s.history.clear();
                s.progress = BakeProgress::default();
                s.counts.builds += 1;
                s.warning = None;
            }
            Report::Edited { geometry } => {
                s.counts.edits += 1;
                s.progress.iterations_since_edit = 0;
                s.warning = None;
                if let Some((recomputed, links)) = geometry {
                    s.size.links = links;
                    s.counts.geometry_edits += 1;
                    s.counts.links_recomputed += recomputed;
                }
            }
            Report::Step {
                t,
                info,
                since_edit,
            } => {
                s.phase = BakePhase::Solving;
                s.progress = BakeProgress {
                    fraction: info.progress,
                    iterations: info.iterations,
                    iterations_since_edit: since_edit,
                };
                s.history.push((t, info.estimated_error));
                s.estimate = BakeEstimate {
                    error: info.estimated_error,
                    eta_s: radiant_radiosity::eta_seconds(&s.history, tolerance),
                };
            }
            Report::Publish(p) => publish(world, *p, epoch),
            Report::Warning(w) => s.warning = Some(w),
        }
    }
}

fn publish(world: &mut World, p: Published, current: u64) {
    let error = world.resource::<BakeStatus>().estimate.error;
    let mut l = world.resource_mut::<BakedLighting>();
    l.generation += 1;
    l.mesh = Some(p.mesh);
    l.radiosity = Arc::new(p.radiosity);
    l.field = Some(p.field);
    l.surfaces = p.surfaces;
    l.estimated_error = error;
    l.preview = p.preview;
    let mut s = world.resource_mut::<BakeStatus>();
    s.stale = p.epoch < current;
    if p.preview && !s.stale {
        s.counts.previews += 1;
    }
    if p.converged && p.epoch == current {
        s.phase = BakePhase::Converged;
        s.progress.fraction = 1.0;
        s.estimate.eta_s = Some(0.0);
    }
}

/// Takes a finished worker's outcome: the bake held, or what to do instead.
fn collect(world: &mut World) {
    let outcome = match &mut world.resource_mut::<BakeWorker>().state {
        WorkerState::Running(r) => check_ready(&mut r.task),
        _ => None,
    };
    let Some(outcome) = outcome else {
        return;
    };
    // The last reports, while the channel is still there.
    drain(world);
    world.resource_mut::<BakeWorker>().state = WorkerState::Empty;
    match outcome {
        Outcome::Idle { held, paused } => {
            let epoch = held.epoch();
            world.resource_mut::<BakeWorker>().state = WorkerState::Idle { held, paused };
            if paused {
                world.resource_mut::<BakeStatus>().phase = BakePhase::Paused;
            }
            requeue_lost_edit(world, epoch);
        }
        Outcome::Cancelled => {}
        Outcome::NeedsRebuild => {
            let scene = Arc::new(gather_scene(world));
            world.resource_mut::<BakeWorker>().pending = Some(Pending::Rebuild(scene));
        }
        Outcome::Failed(e) => {
            tracing::error!("bake failed: {e}");
            let mut s = world.resource_mut::<BakeStatus>();
            s.phase = BakePhase::Failed;
            s.error = Some(e);
        }
    }
}

/// Nothing emits: drop any bake and its light.
fn no_emitters(world: &mut World) {
    world.resource_mut::<BakeWorker>().stop();
    let mut s = world.resource_mut::<BakeStatus>();
    s.phase = BakePhase::NoEmitters;
    s.stale = false;
    world.insert_resource(BakedLighting::default());
}

/// A bake handed back behind the world's epoch missed an edit sent as it was stopping:
/// queue the current scene as an edit, so the next start applies it.
fn requeue_lost_edit(world: &mut World, epoch: u64) {
    let w = world.resource::<BakeWorker>();
    if epoch >= w.epoch || w.pending.is_some() {
        return;
    }
    let scene = gather_scene(world);
    world.resource_mut::<BakeWorker>().pending = Some(Pending::Edit(Edit {
        surfaces: scene.surfaces.clone(),
        lights: Some((scene.lights.clone(), scene.sky.clone())),
        geometry: Some(Arc::new(scene)),
    }));
    world.resource_mut::<BakeStatus>().stale = true;
}

/// Turns the frame's changes into pending work or an edit for the running worker. Returns
/// false when there is nothing to bake (no emitters: any bake is dropped).
fn absorb_changes(world: &mut World, changes: SceneChanges, control: BakeControl) -> bool {
    let first = world.resource::<BakeStatus>().phase == BakePhase::Idle;
    let rebuild = changes.geometry || control.rebake || first;
    if !rebuild && !changes.materials && !changes.lights {
        return true;
    }
    world.resource_mut::<BakeControl>().rebake = false;
    let scene = gather_scene(world);
    if rebuild && scene.triangles.is_empty() && !changes.geometry && first {
        // Nothing spawned yet.
        return false;
    }
    if !scene.has_emitters() {
        no_emitters(world);
        return false;
    }
    let scene = Arc::new(scene);
    let mut w = world.resource_mut::<BakeWorker>();
    w.epoch += 1;
    let epoch = w.epoch;
    if control.rebake || !w.holds_a_bake() || w.rebuild_pending() {
        // Nothing to edit, or a rebuild already waits: bake the scene as it is now.
        w.cancel_running();
        w.pending = Some(Pending::Rebuild(scene.clone()));
    } else if changes.geometry {
        // A rigid move keeps what it does not touch; the worker rebuilds if it is not one.
        w.edit(Edit {
            surfaces: scene.surfaces.clone(),
            lights: None,
            geometry: Some(scene.clone()),
        });
    } else {
        // Merge with an edit still waiting: a pending move carries the whole scene.
        let waiting = match w.pending.take() {
            Some(Pending::Edit(e)) => Some(e),
            other => {
                w.pending = other;
                None
            }
        };
        let geometry = (waiting.as_ref())
            .and_then(|e| e.geometry.as_ref())
            .map(|_| scene.clone());
        let lights = (changes.lights)
            .then(|| (scene.lights.clone(), scene.sky.clone()))
            .or_else(|| waiting.and_then(|e| e.lights));
        w.edit(Edit {
            surfaces: scene.surfaces.clone(),
            lights,
            geometry,
        });
    }
    world.resource_mut::<BakeStatus>().stale = true;
    if let Some(mut snapshot) = world.get_resource_mut::<SceneSnapshot>() {
        if rebuild {
            snapshot.geometry_epoch = epoch;
        }
        snapshot.epoch = epoch;
        snapshot.scene = Some(scene);
    }
    true
}

/// Starts the worker on the pending work, or resumes a paused bake, when it is free.
fn start(world: &mut World, settings: &RadiosityBake) {
    let resume = world.resource::<BakeStatus>().phase == BakePhase::Paused;
    let mut w = world.resource_mut::<BakeWorker>();
    if w.is_running() {
        return;
    }
    let state = std::mem::take(&mut w.state);
    let (start, phase) = match (w.pending.take(), state) {
        (Some(Pending::Rebuild(scene)), _) => (Start::Build(scene), BakePhase::Building),
        (Some(Pending::Edit(edit)), WorkerState::Idle { held, .. }) => {
            (Start::Continue(held, Some(edit)), BakePhase::Solving)
        }
        (None, WorkerState::Idle { held, paused }) if paused && resume => {
            (Start::Continue(held, None), BakePhase::Solving)
        }
        (pending, state) => {
            // Nothing to start (an edit with no bake to apply it to waits for a rebake).
            w.state = state;
            w.pending = pending;
            return;
        }
    };
    w.spawn(settings, start);
    let mut s = world.resource_mut::<BakeStatus>();
    s.phase = phase;
    if phase == BakePhase::Building {
        s.progress.fraction = 0.0;
        s.error = None;
    }
}

/// Starts, steers and reports on the worker. Exclusive: it gathers the scene when it changed.
pub fn drive_bake(world: &mut World) {
    let Some(settings) = world.get_resource::<RadiosityBake>().cloned() else {
        if world.resource::<BakeWorker>().holds_a_bake() {
            world.resource_mut::<BakeWorker>().stop();
            world.resource_mut::<BakeStatus>().phase = BakePhase::Idle;
        }
        return;
    };
    let changes = std::mem::take(&mut *world.resource_mut::<SceneChanges>());
    drain(world);
    collect(world);

    let control = *world.resource::<BakeControl>();
    if control.cancel {
        world.resource_mut::<BakeWorker>().stop();
        world.resource_mut::<BakeControl>().cancel = false;
        world.resource_mut::<BakeStatus>().phase = BakePhase::Cancelled;
        return;
    }
    if control.paused
        && let WorkerState::Running(r) = &world.resource::<BakeWorker>().state
    {
        let _ = r.control.send(Control::Pause);
    }
    if !absorb_changes(world, changes, control) || control.paused {
        return;
    }
    start(world, &settings);
}
