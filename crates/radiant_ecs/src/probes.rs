//! Irradiance probes for what moves, kept up to date with the background bake.
//!
//! Insert [`ProbeVolumeBake`] (with [`crate::bake::RadiosityBake`]) and every light the bake
//! publishes for the current scene (a geometry edit's first look at its light included, not a
//! stale one) is sampled
//! into an irradiance volume ([`radiant_probes::ProbeVolume`]) by a task on bevy's
//! `AsyncComputeTaskPool`; [`BakedProbes`] holds the latest. The frame never waits: a volume
//! in flight is picked up by a later frame, and a light published meanwhile is sampled next.
//! Each new light gets a preview volume first (a sixteenth of the rays, within the light map's
//! edit budget on the Cornell box:
//! [`ProbeVolumeBake::preview_strata`]), so moved geometry relights the probes soon, then the
//! full volume for the same light replaces it ([`BakedProbes::preview`] tells which is shown;
//! an edit's first look gets the preview alone: its solved light follows). The rays (a BVH
//! over the scene's triangles) are made in a task of their own as soon as the bake takes in
//! a geometry change, from the scene it gathered ([`SceneSnapshot`]): a moved prop is patched
//! into the last BVH built ([`SceneRays`]), so the rays are ready when the edit's first light
//! comes; they are kept while the geometry stays.
//! Without [`ProbeVolumeBake`] nothing is sampled and nothing allocated: a scene with nothing
//! that moves does not pay for probes.

use std::sync::Arc;
use std::time::Instant;

use bevy_ecs::prelude::*;
use bevy_tasks::{AsyncComputeTaskPool, Task, futures::check_ready};
use radiant_probes::{ProbeBaker, ProbeParams, ProbeVolume, VolumeParams};
use radiant_radiosity::input::SceneRays;

use crate::app::{App, Plugin, PostUpdate};
use crate::bake::{BakePhase, BakeStatus, BakeSystems, BakeWorker, BakedLighting, SceneSnapshot};
use crate::scene::gather_scene;

/// Probes for the world's dynamic meshes. Present → a volume follows the bake's light; absent
/// → none is made.
#[derive(Resource, Clone, Copy, Debug)]
pub struct ProbeVolumeBake {
    /// The grid (default: a sixteenth of the scene's longest extent apart).
    pub volume: VolumeParams,
    /// Each probe's rays.
    pub probe: ProbeParams,
    /// For each new light, first a preview volume with this many strata per probe (fewer rays,
    /// published sooner), then the full one (`None`: the full one alone). Default
    /// [`ProbeVolumeBake::PREVIEW_STRATA`].
    pub preview_strata: Option<u32>,
}

impl ProbeVolumeBake {
    /// The preview's strata: 8 (128 rays a probe against 2048). On the Cornell box (4913
    /// probes, release, 2 cores) the preview took 0.14 s against 1.24 s for the full volume, and
    /// read 2.0 % mean, 6.3 % worst from it beside the short block (12 strata: 0.26 s, 0.4 %
    /// and 1.2 %).
    pub const PREVIEW_STRATA: u32 = 8;
}

impl Default for ProbeVolumeBake {
    fn default() -> Self {
        ProbeVolumeBake {
            volume: VolumeParams::default(),
            probe: ProbeParams::default(),
            preview_strata: Some(Self::PREVIEW_STRATA),
        }
    }
}

/// The latest irradiance volume.
#[derive(Resource, Clone, Debug, Default)]
pub struct BakedProbes {
    /// The [`BakedLighting::generation`] it was sampled from (0: none yet).
    pub generation: u64,
    /// The volume: read it with [`ProbeVolume::irradiance_world`].
    pub volume: Option<Arc<ProbeVolume>>,
    /// Its probes' whole light as one function of the normal each, as the renderer draws
    /// dynamic surfaces with it ([`ProbeVolume::h_harmonics`], made with the volume).
    pub harmonics: Option<Arc<Harmonics>>,
    /// Seconds its sampling took (off the frame).
    pub seconds: f64,
    /// A newer volume is being sampled.
    pub in_flight: bool,
    /// The volume is the preview of its light (fewer rays); the full one follows.
    pub preview: bool,
    /// Volumes published so far.
    pub published: u64,
    /// Rays (a BVH over the scene's triangles) built so far: for the first scene and for each
    /// change of static geometry that could not be patched in; none for a material or light
    /// edit.
    pub rays_built: u64,
    /// Changes of static geometry patched into the last rays built (a prop moved: only its
    /// triangles get a BVH, [`SceneRays::patched`]).
    pub rays_patched: u64,
}

/// Per probe, [`ProbeVolume::h_harmonics`]: nine RGB coefficients and whether it is valid.
pub type Harmonics = Vec<([[f64; 3]; 9], bool)>;

/// The [`SceneSnapshot::geometry_epoch`] rays were made for, and the rays over the scene's
/// triangles (alpha masks included; `None`: the scene had none to build, as the bake says
/// too).
type Rays = (u64, Option<Arc<radiant_radiosity::input::Rays>>);

/// What a rays task returns: the rays, the last BVH built (the one it was given, or the
/// scene's own), and whether it built that one (else it patched the one it was given).
type MadeRays = (
    Option<radiant_radiosity::input::Rays>,
    Option<Arc<SceneRays>>,
    bool,
);

/// What the sampling task returns: the volume, its harmonics and the seconds they took.
type Sampled = (ProbeVolume, Harmonics, f64);

/// The task sampling a volume, the light generation it samples and whether it is a preview.
#[derive(Resource, Default)]
struct ProbeTask(Option<(u64, bool, Task<Sampled>)>);

/// The rays of the scene's geometry, kept while it stays, the last BVH built
/// ([`SceneRays`]: a moved prop is patched into it, on Sponza in milliseconds where the whole
/// BVH takes ~0.5 s), and the task making them for a newer geometry.
#[derive(Resource, Default)]
struct ProbeRays {
    rays: Option<Rays>,
    built: Option<Arc<SceneRays>>,
    building: Option<(u64, Task<MadeRays>)>,
}

/// System set of [`drive_probes`], after the bake's.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub struct ProbeSystems;

/// Keeps [`BakedProbes`] up to date: add it with [`crate::bake::BakePlugin`] and insert
/// [`ProbeVolumeBake`].
pub struct ProbePlugin;

impl Plugin for ProbePlugin {
    fn build(&self, app: &mut App) {
        app.init_resource::<BakedProbes>()
            .init_resource::<ProbeTask>()
            .init_resource::<ProbeRays>()
            .init_resource::<SceneSnapshot>()
            .configure_sets(PostUpdate, ProbeSystems.after(BakeSystems))
            .add_systems(PostUpdate, drive_probes.in_set(ProbeSystems));
    }
}

/// Publishes a finished volume, builds the rays of a new geometry as soon as the bake takes it
/// in, and starts sampling the bake's newest light when none is in flight (see the module).
pub fn drive_probes(world: &mut World) {
    let done = match &mut world.resource_mut::<ProbeTask>().0 {
        Some((_, _, task)) => check_ready(task),
        None => None,
    };
    if let Some((volume, harmonics, seconds)) = done {
        let (generation, preview) = world
            .resource_mut::<ProbeTask>()
            .0
            .take()
            .map_or((0, false), |(g, p, _)| (g, p));
        let mut p = world.resource_mut::<BakedProbes>();
        p.generation = generation;
        p.volume = Some(Arc::new(volume));
        p.harmonics = Some(Arc::new(harmonics));
        p.seconds = seconds;
        p.preview = preview;
        p.published += 1;
        // The full volume of a converged light: no more lights come until the scene changes.
        let settled = !preview
            && generation == world.resource::<BakedLighting>().generation
            && world.resource::<BakeStatus>().phase == BakePhase::Converged;
        if settled {
            world.resource_mut::<SceneSnapshot>().scene = None;
        }
    }
    let built = match &mut world.resource_mut::<ProbeRays>().building {
        Some((_, task)) => check_ready(task),
        None => None,
    };
    if let Some((rays, last, was_built)) = built {
        let mut r = world.resource_mut::<ProbeRays>();
        let geometry = r.building.take().map_or(0, |(g, _)| g);
        let made = rays.is_some();
        r.rays = Some((geometry, rays.map(Arc::new)));
        r.built = last;
        let mut p = world.resource_mut::<BakedProbes>();
        if was_built {
            p.rays_built += 1;
        } else if made {
            p.rays_patched += 1;
        }
    }
    let running = world.resource::<ProbeTask>().0.is_some();
    world.resource_mut::<BakedProbes>().in_flight = running;
    let Some(settings) = world.get_resource::<ProbeVolumeBake>().copied() else {
        // No probes: nothing of theirs is held.
        world.resource_mut::<SceneSnapshot>().scene = None;
        *world.resource_mut::<ProbeRays>() = ProbeRays::default();
        return;
    };
    let geometry = world.resource::<SceneSnapshot>().geometry_epoch;
    if !rays_ready(world, geometry) || running {
        return;
    }
    let lighting = world.resource::<BakedLighting>();
    let (generation, preview) = (lighting.generation, lighting.preview);
    let (Some(mesh), Some(field)) = (lighting.mesh.clone(), lighting.field.clone()) else {
        return;
    };
    if world.resource::<BakeStatus>().stale {
        return;
    }
    let published = world.resource::<BakedProbes>();
    // A new light: its preview first (when asked); a geometry edit's first look at its light
    // (`BakedLighting::preview`) too, so the probes relight as soon as the light maps do;
    // the light of a preview volume, when it is not an edit's preview: the full volume.
    let preview_probe = match settings.preview_strata {
        Some(strata) if strata < settings.probe.strata => ProbeParams {
            strata: strata.max(1),
            ..settings.probe
        },
        _ => settings.probe,
    };
    let probe = if generation > published.generation {
        preview_probe
    } else if generation == published.generation && published.preview && !preview {
        settings.probe
    } else {
        return;
    };
    let is_preview = probe.strata < settings.probe.strata;
    // The light matches the world's scene now (not stale): the scene the bake gathered for
    // this epoch, or gathered again when it was dropped.
    let Some((_, Some(vis))) = world.resource::<ProbeRays>().rays.clone() else {
        return;
    };
    let scene = current_scene(world);
    let volume_params = settings.volume;
    let task = AsyncComputeTaskPool::get().spawn(async move {
        let t0 = Instant::now();
        let baker = ProbeBaker::new(&scene, &mesh, &field, &*vis, probe);
        let volume = ProbeVolume::bake(&baker, &volume_params);
        let harmonics = volume.h_harmonics();
        (volume, harmonics, t0.elapsed().as_secs_f64())
    });
    world.resource_mut::<ProbeTask>().0 = Some((generation, is_preview, task));
    world.resource_mut::<BakedProbes>().in_flight = true;
}

/// The world's scene at the bake's epoch: the bake's snapshot, or gathered (once) when it was
/// dropped.
fn current_scene(world: &mut World) -> Arc<radiant_scene::Scene> {
    let epoch = world.resource::<BakeWorker>().epoch();
    let snapshot = world.resource::<SceneSnapshot>();
    match &snapshot.scene {
        Some(scene) if snapshot.epoch == epoch => scene.clone(),
        _ => {
            let scene = Arc::new(gather_scene(world));
            let mut snapshot = world.resource_mut::<SceneSnapshot>();
            snapshot.epoch = epoch;
            snapshot.scene = Some(scene.clone());
            scene
        }
    }
}

/// Whether the rays of `geometry` (a [`SceneSnapshot::geometry_epoch`]) are made; if not,
/// starts making them in a task (one at a time), from the scene the bake took in, before its
/// light comes: on Sponza the light of a moved vase is previewed 0.4–0.9 s after the move, its
/// rays patched in milliseconds (a whole BVH: ~0.5 s). A material's alpha mode changed alone
/// keeps the rays (masks are read when they are built).
fn rays_ready(world: &mut World, geometry: u64) -> bool {
    let r = world.resource::<ProbeRays>();
    if r.rays.as_ref().is_some_and(|(g, _)| *g == geometry) {
        return true;
    }
    // Nothing taken in yet, or a build under way (of this geometry, or of an older one whose
    // end starts this one's).
    if geometry == 0 || r.building.is_some() {
        return false;
    }
    let scene = current_scene(world);
    let mut r = world.resource_mut::<ProbeRays>();
    r.rays = None;
    // The last BVH goes to the task, and comes back with its rays or a new one.
    let last = r.built.take();
    let task = AsyncComputeTaskPool::get().spawn(async move {
        if let Some(rays) = last.as_ref().and_then(|l| l.patched(&scene)) {
            return (Some(rays), last, false);
        }
        // The old BVH goes first: no two BVHs of a level at once (a volume still sampling
        // with it keeps it until it ends).
        drop(last);
        match SceneRays::new(&scene) {
            Ok(built) => (Some(built.rays()), Some(Arc::new(built)), true),
            Err(e) => {
                tracing::warn!("probes: no rays over the scene: {e}");
                (None, None, false)
            }
        }
    });
    r.building = Some((geometry, task));
    false
}
