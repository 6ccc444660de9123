//! A minimal app in the shape of `bevy_app`: a world, schedules, plugins with `build` and
//! `finish`, and a headless runner that steps frames deterministically.

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::ScheduleLabel;
use bevy_ecs::system::ScheduleSystem;

/// Runs once, before the first frame.
#[derive(ScheduleLabel, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Startup;
/// Every frame, first.
#[derive(ScheduleLabel, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PreUpdate;
/// Every frame: user systems and edits go here.
#[derive(ScheduleLabel, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Update;
/// Every frame, last: transform propagation, then the bake's systems.
#[derive(ScheduleLabel, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PostUpdate;

/// Frames run so far.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameCount(pub u64);

/// A piece of app setup: resources, systems, other plugins.
pub trait Plugin: Send + Sync + 'static {
    /// Adds what the plugin needs.
    fn build(&self, app: &mut App);
    /// Runs once after every plugin is built, before the first frame.
    fn finish(&self, _app: &mut App) {}
}

/// A world with schedules and plugins.
pub struct App {
    /// The ECS world.
    pub world: World,
    plugins: Vec<Box<dyn Plugin>>,
    finished: bool,
    started: bool,
}

impl Default for App {
    fn default() -> Self {
        Self::new()
    }
}

impl App {
    /// An app with the four schedules and no plugins. It creates no window and no GUI.
    pub fn new() -> Self {
        let mut world = World::new();
        world.add_schedule(Schedule::new(Startup));
        world.add_schedule(Schedule::new(PreUpdate));
        world.add_schedule(Schedule::new(Update));
        world.add_schedule(Schedule::new(PostUpdate));
        world.insert_resource(FrameCount(0));
        Self {
            world,
            plugins: Vec::new(),
            finished: false,
            started: false,
        }
    }

    /// Builds a plugin now and keeps it for [`Plugin::finish`].
    pub fn add_plugins(&mut self, plugin: impl Plugin) -> &mut Self {
        plugin.build(self);
        self.plugins.push(Box::new(plugin));
        self
    }

    /// Adds systems to a schedule.
    pub fn add_systems<M>(
        &mut self,
        schedule: impl ScheduleLabel,
        systems: impl IntoScheduleConfigs<ScheduleSystem, M>,
    ) -> &mut Self {
        self.world
            .resource_mut::<Schedules>()
            .add_systems(schedule, systems);
        self
    }

    /// Orders system sets in a schedule.
    pub fn configure_sets<M>(
        &mut self,
        schedule: impl ScheduleLabel,
        sets: impl IntoScheduleConfigs<bevy_ecs::schedule::InternedSystemSet, M>,
    ) -> &mut Self {
        self.world
            .resource_mut::<Schedules>()
            .configure_sets(schedule, sets);
        self
    }

    /// Inserts a resource.
    pub fn insert_resource<R: Resource>(&mut self, resource: R) -> &mut Self {
        self.world.insert_resource(resource);
        self
    }

    /// Inserts a resource's default unless it exists.
    pub fn init_resource<R: Resource + FromWorld>(&mut self) -> &mut Self {
        self.world.init_resource::<R>();
        self
    }

    /// Calls every plugin's `finish` once (the first [`App::update`] does it too).
    pub fn finish(&mut self) {
        if self.finished {
            return;
        }
        let plugins = std::mem::take(&mut self.plugins);
        for p in &plugins {
            p.finish(self);
        }
        self.plugins = plugins;
        self.finished = true;
    }

    /// Runs one frame: `Startup` the first time, then `PreUpdate`, `Update`, `PostUpdate`.
    pub fn update(&mut self) {
        self.finish();
        if !self.started {
            self.world.run_schedule(Startup);
            self.started = true;
        }
        self.world.run_schedule(PreUpdate);
        self.world.run_schedule(Update);
        self.world.run_schedule(PostUpdate);
        self.world.resource_mut::<FrameCount>().0 += 1;
    }

    /// The headless runner: steps frames until `done` holds or `max_frames` have run, and says
    /// whether `done` held. Background work (the bake) runs on other threads meanwhile;
    /// `frame_pause` between frames stands for a frame's other work.
    pub fn run_until(
        &mut self,
        max_frames: u64,
        frame_pause: std::time::Duration,
        mut done: impl FnMut(&mut World) -> bool,
    ) -> bool {
        for _ in 0..max_frames {
            self.update();
            if done(&mut self.world) {
                return true;
            }
            if !frame_pause.is_zero() {
                std::thread::sleep(frame_pause);
            }
        }
        false
    }
}
