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
//! over the mesh) are built in the task and kept for the next light of the same mesh.
//! Without [`ProbeVolumeBake`] nothing is sampled and nothing allocated: a scene with nothing
//! that moves does not pay for probes.

use std::sync::Arc;
use std::time::Instant;

use bevy_ecs::prelude::*;
use bevy_tasks::{AsyncComputeTaskPool, Task, futures::check_ready};
use radiant_probes::{ProbeBaker, ProbeParams, ProbeVolume, VolumeParams};

use crate::app::{App, Plugin, PostUpdate};
use crate::bake::{BakePhase, BakeStatus, BakeSystems, BakeWorker, BakedLighting};
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
}

/// Per probe, [`ProbeVolume::h_harmonics`]: nine RGB coefficients and whether it is valid.
pub type Harmonics = Vec<([[f64; 3]; 9], bool)>;

/// Rays over a mesh: the mesh (weakly: it is told apart by its address, which a `Weak` keeps
/// from being reused, and it is freed when the bake drops it) and its BVH.
type Rays = (
    std::sync::Weak<radiant_radiosity::mesh::Mesh>,
    Arc<radiant_visibility::Bvh>,
);

/// What the sampling task returns: the volume, its harmonics, the seconds they took and the
/// rays it sampled with.
type Sampled = (ProbeVolume, Harmonics, f64, Rays);

/// The task sampling a volume, the light generation it samples and whether it is a preview.
#[derive(Resource, Default)]
struct ProbeTask(Option<(u64, bool, Task<Sampled>)>);

/// The rays of the last mesh sampled (its BVH, alpha masks included), kept for the next light
/// of the same mesh: on Sponza (262 k triangles) the BVH takes ~1 s to build, the preview's
/// rays ~0.1 s.
#[derive(Resource, Default)]
struct ProbeRays(Option<Rays>);

/// The world's scene as the probes last gathered it, and the bake's epoch it matches: a
/// solve publishes a light every few sweeps, and each would gather the scene again on the
/// frame (Sponza: its longest frames 180–200 ms with probes against 120–156 ms without).
/// Dropped once the probes have the full volume of a converged light.
#[derive(Resource, Default)]
struct ProbeScene(Option<(u64, Arc<radiant_scene::Scene>)>);

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
            .init_resource::<ProbeScene>()
            .configure_sets(PostUpdate, ProbeSystems.after(BakeSystems))
            .add_systems(PostUpdate, drive_probes.in_set(ProbeSystems));
    }
}

/// Publishes a finished volume, and starts sampling the bake's newest light when none is in
/// flight (see the module).
pub fn drive_probes(world: &mut World) {
    let done = match &mut world.resource_mut::<ProbeTask>().0 {
        Some((_, _, task)) => check_ready(task),
        None => None,
    };
    if let Some((volume, harmonics, seconds, rays)) = done {
        world.resource_mut::<ProbeRays>().0 = Some(rays);
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
            world.resource_mut::<ProbeScene>().0 = None;
        }
    }
    let running = world.resource::<ProbeTask>().0.is_some();
    world.resource_mut::<BakedProbes>().in_flight = running;
    let Some(settings) = world.get_resource::<ProbeVolumeBake>().copied() else {
        return;
    };
    if running {
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
    // The light matches the world's scene now (not stale): the scene its mesh was made from,
    // gathered once per epoch.
    let epoch = world.resource::<BakeWorker>().epoch();
    let scene = match &world.resource::<ProbeScene>().0 {
        Some((e, scene)) if *e == epoch => scene.clone(),
        _ => {
            let scene = Arc::new(gather_scene(world));
            world.resource_mut::<ProbeScene>().0 = Some((epoch, scene.clone()));
            scene
        }
    };
    let volume_params = settings.volume;
    // The last mesh's rays, when this light's mesh is that one; else they are dropped now.
    let kept = match world.resource_mut::<ProbeRays>().0.take() {
        Some((m, bvh)) if std::ptr::eq(m.as_ptr(), Arc::as_ptr(&mesh)) => Some(bvh),
        _ => None,
    };
    let task = AsyncComputeTaskPool::get().spawn(async move {
        let t0 = Instant::now();
        // Built in the task (never on the frame), once per mesh.
        let vis = kept.unwrap_or_else(|| {
            let masks = radiant_radiosity::input::masks(&scene);
            Arc::new(radiant_radiosity::input::visibility(&mesh, masks.as_ref()))
        });
        let baker = ProbeBaker::new(&scene, &mesh, &field, &*vis, probe);
        let volume = ProbeVolume::bake(&baker, &volume_params);
        let harmonics = volume.h_harmonics();
        drop(baker);
        let rays = (Arc::downgrade(&mesh), vis);
        (volume, harmonics, t0.elapsed().as_secs_f64(), rays)
    });
    world.resource_mut::<ProbeTask>().0 = Some((generation, is_preview, task));
    world.resource_mut::<BakedProbes>().in_flight = true;
}
