//! The worker: a task that builds a bake (or resumes it from a checkpoint), then steps it one
//! sweep (or one shot) at a time, applying edits as they come and publishing its light.
//!
//! It talks to the world through two channels: [`Control`] in, [`Report`] out. It ends with an
//! [`Outcome`]: the bake handed back (converged or paused), or why there is none.

use std::collections::VecDeque;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::time::{Duration, Instant};

use radiant_radiosity::cluster::{self, ClusterBake, ClusterParams, EditPreview, Phase};
use radiant_radiosity::metrics::{SurfaceMean, surface_means, surface_means_exposed};
use radiant_radiosity::smooth::SmoothField;
use radiant_radiosity::{Bake, BakeError, BakeParams, Info, Mesh, Rgb, SolveError};
use radiant_scene::{Light, Scene, Sky, Surface};

/// A request from the world.
pub(super) enum Control {
    Pause,
    Cancel,
    /// An edit, and the world's epoch once it is applied.
    Edit(Edit, u64),
}

/// What the worker tells the world.
pub(super) enum Report {
    /// Links built for `done` of `total` elements (or clusters).
    Building {
        done: usize,
        total: usize,
    },
    Built {
        elements: usize,
        links: usize,
        resumed: bool,
    },
    /// An edit was applied; a geometry edit recomputed `recomputed` links (`links` now).
    Edited {
        geometry: Option<(usize, usize)>,
    },
    /// A solver step, at `t` seconds since the bake was built; `since_edit` steps since the
    /// last edit.
    Step {
        t: f64,
        info: Info,
        since_edit: u64,
    },
    Publish(Box<Published>),
    Warning(super::BakeWarning),
}

/// A light to publish.
pub(super) struct Published {
    pub mesh: Arc<Mesh>,
    pub radiosity: Vec<Rgb>,
    pub field: Arc<SmoothField>,
    pub surfaces: Vec<SurfaceMean>,
    /// The world's epoch the light matches.
    pub epoch: u64,
    pub converged: bool,
    /// A geometry edit's preview ([`EditPreview`]).
    pub preview: bool,
}

/// How a worker ended.
pub(super) enum Outcome {
    /// Converged, or paused: the bake is handed back for the next edit or the resume.
    Idle {
        held: Box<Held>,
        paused: bool,
    },
    Cancelled,
    /// The change cannot be absorbed (the scene's bounds changed, the surfaces renumbered, a
    /// level's geometry edited while its links were being built): bake the scene again.
    NeedsRebuild,
    Failed(Arc<BakeError>),
}

/// How a worker starts.
pub(super) enum Start {
    Build(Arc<Scene>),
    Continue(Box<Held>, Option<Edit>),
}

/// A change the bake absorbs without starting over: new materials, new lights, and static
/// geometry moved, added or removed (the scene to change to).
pub(super) struct Edit {
    pub surfaces: Vec<Surface>,
    /// New punctual lights and sky.
    pub lights: Option<(Vec<Light>, Option<Sky>)>,
    pub geometry: Option<Arc<Scene>>,
}

/// The bake a worker drives: per-triangle, or clustered for a level (see
/// `radiant_radiosity::cluster::suits`); the links of both follow material, light and geometry
/// edits.
/// Boxed, both: each is over a kilobyte of state besides its buffers.
pub(super) enum Engine {
    Triangles(Box<Bake>),
    Clustered(Box<ClusterBake>),
}

/// A bake between workers, with what its reports need.
pub(super) struct Held {
    engine: Engine,
    /// The mesh the published light refers to.
    mesh: Arc<Mesh>,
    /// The world's epoch the bake matches.
    epoch: u64,
    /// Solver steps when the last edit was applied.
    at_edit: u64,
    built: Instant,
}

/// What a worker needs besides its start.
pub(super) struct Setup {
    pub params: BakeParams,
    pub cluster: ClusterParams,
    pub publish_interval: Duration,
    pub checkpoint: Option<std::path::PathBuf>,
    pub hierarchy: cluster::Hierarchy,
    pub epoch: u64,
    /// Set when the world drops this worker: it then stops and writes no checkpoint (a newer
    /// bake may).
    pub cancelled: Arc<AtomicBool>,
}

/// The worker's end of the control channel. While a bake is built, requests are held for
/// after it, except those that make the build useless (a cancel; a geometry edit of a level),
/// which stop it.
struct Inbox {
    rx: Mutex<mpsc::Receiver<Control>>,
    held: Mutex<VecDeque<Control>>,
    stop: AtomicBool,
}

impl Inbox {
    fn new(rx: mpsc::Receiver<Control>) -> Inbox {
        Inbox {
            rx: Mutex::new(rx),
            held: Mutex::new(VecDeque::new()),
            stop: AtomicBool::new(false),
        }
    }

    /// Holds what arrived during a build; `level`: a geometry edit stops it.
    fn poll_building(&self, level: bool, cancelled: &AtomicBool) {
        let (Ok(rx), Ok(mut held)) = (self.rx.try_lock(), self.held.lock()) else {
            return;
        };
        while let Ok(c) = rx.try_recv() {
            let stops = match &c {
                Control::Cancel => true,
                Control::Edit(edit, _) => level && edit.geometry.is_some(),
                Control::Pause => false,
            };
            if stops {
                self.stop.store(true, Ordering::Relaxed);
            }
            held.push_back(c);
        }
        if cancelled.load(Ordering::Relaxed) {
            self.stop.store(true, Ordering::Relaxed);
        }
    }

    /// The next request: held ones first.
    fn next(&self) -> Option<Control> {
        if let Some(c) = self.held.lock().ok().and_then(|mut h| h.pop_front()) {
            return Some(c);
        }
        self.rx.lock().ok().and_then(|rx| rx.try_recv().ok())
    }

    /// Why a build stopped: a cancel wins over an edit.
    fn stopped_build(&self, cancelled: &AtomicBool) -> Outcome {
        let held = self.held.lock();
        let cancel = held.is_ok_and(|h| h.iter().any(|c| matches!(c, Control::Cancel)));
        if cancel || cancelled.load(Ordering::Relaxed) {
            Outcome::Cancelled
        } else {
            Outcome::NeedsRebuild
        }
    }
}

impl Engine {
    /// Builds the bake of `scene`, or resumes it from the checkpoint when that matches.
    fn build(
        scene: &Scene,
        setup: &Setup,
        inbox: &Inbox,
        tx: &mpsc::Sender<Report>,
    ) -> Result<Engine, BakeError> {
        let level = setup.hierarchy.clustered(scene, &setup.params)?;
        if let Some(path) = setup.checkpoint.as_deref().filter(|p| p.exists()) {
            let resumed = if level {
                ClusterBake::resume(scene, &setup.params, &setup.cluster, path)
                    .map(|b| Engine::Clustered(Box::new(b)))
            } else {
                Bake::resume(scene, &setup.params, path).map(|b| Engine::Triangles(Box::new(b)))
            };
            match resumed {
                Ok(e) => return Ok(e),
                Err(e) => tracing::info!("not resuming: {e}"),
            }
        }
        let progress = |done: usize, total: usize| {
            let _ = tx.send(Report::Building { done, total });
            inbox.poll_building(level, &setup.cancelled);
        };
        if level {
            let progress = |phase: Phase, done: usize, total: usize| {
                if phase == Phase::Links {
                    progress(done, total);
                }
            };
            let (params, cp) = (&setup.params, &setup.cluster);
            ClusterBake::new(scene, params, cp, &progress, Some(&inbox.stop))
                .map(|b| Engine::Clustered(Box::new(b)))
        } else {
            Bake::with_progress(scene, &setup.params, &progress)
                .map(|b| Engine::Triangles(Box::new(b)))
        }
    }

    /// The mesh to publish light on: the clustered bake's own, shared.
    fn shared_mesh(&self) -> Arc<Mesh> {
        match self {
            Engine::Triangles(b) => Arc::new(b.mesh.clone()),
            Engine::Clustered(b) => b.shared_mesh(),
        }
    }

    fn surfaces(&self) -> &[Surface] {
        match self {
            Engine::Triangles(b) => &b.surfaces,
            Engine::Clustered(b) => b.surfaces(),
        }
    }

    fn links(&self) -> usize {
        match self {
            Engine::Triangles(b) => b.system.links.len(),
            Engine::Clustered(b) => b.links(),
        }
    }

    fn is_resumed(&self) -> bool {
        match self {
            Engine::Triangles(b) => b.is_resumed(),
            Engine::Clustered(b) => b.is_resumed(),
        }
    }

    fn iterations(&self) -> u64 {
        match self {
            Engine::Triangles(b) => b.last_info().map_or(0, |i| i.iterations),
            Engine::Clustered(b) => b.last_info().iterations,
        }
    }

    /// One sweep (or one shot): the same sequence whatever the timing. Returns the step's
    /// info and whether the bake is done (converged, or out of sweeps or time).
    fn step(&mut self) -> Result<(Info, bool), SolveError> {
        match self {
            Engine::Triangles(b) => {
                let info = b.step(Duration::ZERO)?;
                Ok((info, info.converged || b.out_of_time()))
            }
            Engine::Clustered(b) => {
                let info = b.step()?;
                Ok((info, info.converged || b.out_of_sweeps()))
            }
        }
    }

    /// Applies `edit`; returns the links a geometry edit recomputed, and the links now. A
    /// level's geometry edit hands `preview` a first look at its light.
    fn apply(
        &mut self,
        edit: &Edit,
        preview: &mut dyn FnMut(EditPreview),
    ) -> Result<Option<(usize, usize)>, BakeError> {
        // A geometry edit brings the scene's materials and lights along (and matches
        // surfaces by name, so they must not be renamed under it first).
        if let Some(scene) = &edit.geometry {
            return match self {
                Engine::Triangles(b) => {
                    let stats = b.edit_geometry(scene)?;
                    Ok(Some((stats.recomputed, b.system.links.len())))
                }
                Engine::Clustered(b) => {
                    let e = b.edit_geometry_previewed(scene, &|_, _, _| {}, None, Some(preview))?;
                    Ok(Some((e.computed as usize, e.links)))
                }
            };
        }
        if edit.surfaces.len() != self.surfaces().len() {
            return Err(BakeError::NeedsRebuild);
        }
        match self {
            Engine::Triangles(b) => {
                b.edit_surfaces(&edit.surfaces)?;
                if let Some((l, sky)) = &edit.lights {
                    b.edit_lights_and_sky(l, sky.as_ref())?;
                }
            }
            Engine::Clustered(b) => {
                b.edit_surfaces(&edit.surfaces)?;
                if let Some((l, sky)) = &edit.lights {
                    b.edit_lights_and_sky(l, sky.as_ref())?;
                }
            }
        }
        Ok(None)
    }

    fn write_checkpoint(&self, path: &Path) -> Result<(), BakeError> {
        match self {
            Engine::Triangles(b) => b.write_checkpoint(path),
            Engine::Clustered(b) => b.write_checkpoint(path),
        }
    }

    fn light(&self) -> (Vec<Rgb>, SmoothField) {
        match self {
            Engine::Triangles(b) => (b.radiosity(), b.smooth_field()),
            Engine::Clustered(b) => (b.radiosity(), b.smooth_field()),
        }
    }

    /// Per-surface means of `radiosity` (from [`Engine::light`]): a clustered bake's counts
    /// each element's exposed share of its area.
    fn surface_means(&self, mesh: &Mesh, radiosity: &[Rgb]) -> Vec<SurfaceMean> {
        match self {
            Engine::Triangles(_) => surface_means(self.surfaces(), mesh, radiosity),
            Engine::Clustered(b) => {
                surface_means_exposed(self.surfaces(), mesh, radiosity, b.exposure())
            }
        }
    }
}

impl Held {
    /// The world's epoch the bake matches.
    pub(super) fn epoch(&self) -> u64 {
        self.epoch
    }
}

/// The worker's loop; runs on a task, inside the bake's thread pool when it has one.
pub(super) fn work(
    start: Start,
    setup: Setup,
    rx: mpsc::Receiver<Control>,
    tx: mpsc::Sender<Report>,
) -> Outcome {
    let inbox = Inbox::new(rx);
    let send = |r: Report| {
        let _ = tx.send(r);
    };
    let mut held = match begin(start, &setup, &inbox, &tx) {
        Ok(held) => held,
        Err(outcome) => return outcome,
    };
    let mut last_publish: Option<Instant> = None;
    loop {
        // Requests, in order; a pause takes effect after the edits queued behind it.
        let mut paused = false;
        while let Some(c) = inbox.next() {
            match c {
                Control::Cancel => return Outcome::Cancelled,
                Control::Pause => paused = true,
                Control::Edit(edit, epoch) => {
                    if let Err(o) = apply(&mut held, &edit, epoch, &tx) {
                        return o;
                    }
                }
            }
        }
        if setup.cancelled.load(Ordering::Relaxed) {
            return Outcome::Cancelled;
        }
        if paused {
            save(&held.engine, &setup, &tx);
            return Outcome::Idle { held, paused: true };
        }
        let done = match held.engine.step() {
            Ok((info, done)) => {
                send(Report::Step {
                    t: held.built.elapsed().as_secs_f64(),
                    info,
                    since_edit: info.iterations.saturating_sub(held.at_edit),
                });
                done
            }
            Err(e @ SolveError::Stalled { .. }) => {
                send(Report::Warning(super::BakeWarning::Stalled(e)));
                true
            }
            Err(e) => return Outcome::Failed(Arc::new(e.into())),
        };
        if done {
            // Before the final publication, so whoever sees "converged" finds the checkpoint.
            save(&held.engine, &setup, &tx);
        }
        if done || last_publish.is_none_or(|t| t.elapsed() >= setup.publish_interval) {
            publish(&held, done, &tx);
            last_publish = Some(Instant::now());
        }
        if done {
            return Outcome::Idle {
                held,
                paused: false,
            };
        }
    }
}

/// Builds the bake (or resumes it from the checkpoint), or takes the held one and applies the
/// edit it waited for.
fn begin(
    start: Start,
    setup: &Setup,
    inbox: &Inbox,
    tx: &mpsc::Sender<Report>,
) -> Result<Box<Held>, Outcome> {
    match start {
        Start::Build(scene) => match Engine::build(&scene, setup, inbox, tx) {
            Ok(engine) => {
                let held = Held {
                    mesh: engine.shared_mesh(),
                    epoch: setup.epoch,
                    at_edit: 0,
                    built: Instant::now(),
                    engine,
                };
                let _ = tx.send(Report::Built {
                    elements: held.mesh.element_count(),
                    links: held.engine.links(),
                    resumed: held.engine.is_resumed(),
                });
                save(&held.engine, setup, tx);
                Ok(Box::new(held))
            }
            Err(BakeError::Stopped) => Err(inbox.stopped_build(&setup.cancelled)),
            Err(e) => Err(Outcome::Failed(Arc::new(e))),
        },
        Start::Continue(mut held, edit) => {
            if let Some(edit) = edit {
                apply(&mut held, &edit, setup.epoch, tx)?;
            }
            Ok(held)
        }
    }
}

/// Applies an edit and reports it; the bake then matches `epoch`.
fn apply(
    held: &mut Held,
    edit: &Edit,
    epoch: u64,
    tx: &mpsc::Sender<Report>,
) -> Result<(), Outcome> {
    // An edit's warm start forgets the last step; the solver's count goes on.
    let before = held.engine.iterations();
    // A level's geometry edit shows a first look at its light before it refines.
    let mut preview = |p: EditPreview| {
        let surfaces = edit.surfaces.as_slice();
        let _ = tx.send(Report::Publish(Box::new(Published {
            field: Arc::new(p.smooth_field(surfaces)),
            surfaces: surface_means_exposed(surfaces, &p.mesh, &p.radiosity, &p.exposure),
            mesh: p.mesh,
            radiosity: p.radiosity,
            epoch,
            converged: false,
            preview: true,
        })));
    };
    match held.engine.apply(edit, &mut preview) {
        Ok(geometry) => {
            if geometry.is_some() {
                held.mesh = held.engine.shared_mesh();
            }
            held.epoch = epoch;
            held.at_edit = before;
            let _ = tx.send(Report::Edited { geometry });
            Ok(())
        }
        Err(BakeError::NeedsRebuild) => Err(Outcome::NeedsRebuild),
        Err(e) => Err(Outcome::Failed(Arc::new(e))),
    }
}

fn publish(held: &Held, converged: bool, tx: &mpsc::Sender<Report>) {
    let (radiosity, field) = held.engine.light();
    let surfaces = held.engine.surface_means(&held.mesh, &radiosity);
    let _ = tx.send(Report::Publish(Box::new(Published {
        mesh: held.mesh.clone(),
        radiosity,
        field: Arc::new(field),
        surfaces,
        epoch: held.epoch,
        converged,
        preview: false,
    })));
}

/// Writes the checkpoint, if one is asked for and the world still wants this bake.
fn save(engine: &Engine, setup: &Setup, tx: &mpsc::Sender<Report>) {
    if setup.cancelled.load(Ordering::Relaxed) {
        return;
    }
    if let Some(path) = &setup.checkpoint
        && let Err(e) = engine.write_checkpoint(path)
    {
        let _ = tx.send(Report::Warning(super::BakeWarning::Checkpoint(Arc::new(e))));
    }
}
