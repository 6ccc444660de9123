//! Radiant on `bevy_ecs`: scenes as entities, a background bake that follows edits, and a
//! headless app for tests and tools.
//!
//! ```no_run
//! use radiant_ecs::prelude::*;
//!
//! let mut app = App::new();
//! app.add_plugins(RadiantPlugins).insert_resource(RadiosityBake::default());
//! let scene = radiant_scene::builtin("cornell-box").expect("builtin");
//! spawn_scene(&mut app.world, &scene);
//! // Step frames; the bake runs in the background and the frame never waits for it.
//! app.run_until(100_000, std::time::Duration::from_millis(1), |w| {
//!     w.resource::<BakeStatus>().phase == BakePhase::Converged
//! });
//! println!("{:?}", app.world.resource::<BakedLighting>().surfaces);
//! ```
//!
//! A headless app creates no window and no GUI; with no static emitter and no light, no bake
//! is scheduled and nothing is allocated for one.

pub mod app;
pub mod bake;
pub mod probes;
#[cfg(feature = "render")]
pub mod render;
pub mod scene;

use app::{App, Plugin};

/// The scene, bake and probe plugins.
pub struct RadiantPlugins;

impl Plugin for RadiantPlugins {
    fn build(&self, app: &mut App) {
        app.add_plugins(scene::ScenePlugin)
            .add_plugins(bake::BakePlugin)
            .add_plugins(probes::ProbePlugin);
    }
}

/// Everything a user of the crate needs.
pub mod prelude {
    pub use crate::RadiantPlugins;
    pub use crate::app::{App, FrameCount, Plugin, PostUpdate, PreUpdate, Startup, Update};
    pub use crate::bake::{
        BakeControl, BakePhase, BakePlugin, BakeStatus, BakeSystems, BakeWorker, BakedLighting,
        RadiosityBake, SceneSnapshot,
    };
    pub use crate::probes::{BakedProbes, ProbePlugin, ProbeSystems, ProbeVolumeBake};
    #[cfg(feature = "render")]
    pub use crate::render::{
        Bloom, DebugView, GaussianBlur, Gpu, LastFrame, RenderPlugin, RenderSettings, RenderState,
        RenderSystems, Sobel, Ssao, Tonemapping,
    };
    pub use crate::scene::{
        Geometry, GlobalTransform, Material, MaterialTextures, PunctualLight, SceneCamera,
        SceneImages, ScenePlugin, SceneSky, Static, SurfaceOrder, Transform, TransformSystems,
        gather_scene, move_dynamic, spawn_scene,
    };
    pub use bevy_ecs::prelude::*;
}
