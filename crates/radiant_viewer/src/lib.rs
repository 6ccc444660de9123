//! The Radiant viewer: a winit window showing a scene through the full render graph while the
//! bake converges in the background, with the egui inspector drawn as the graph's last pass.
//!
//! - Left drag orbits, right drag looks around, the wheel zooms, WASD and Q/E fly.
//! - The arrow keys and Page Up/Down move the scene's dynamic meshes (glTF nodes marked
//!   `{"radiant": {"dynamic": true}}`), lit by the probes that follow the bake; the inspector's
//!   radiosity tab shows the probe grid.
//! - `Tab` (or `F1`) shows and hides the inspector; hidden, its pass and texture leave the graph.
//! - Minimised or occluded (where the platform reports it: X11, Windows, macOS; Wayland does
//!   not tell), nothing is rendered; the bake goes on.
//! - Closing pauses the bake, which writes its checkpoint: the next start resumes from it.
//!
//! [`display_available`] tells whether a window can be opened at all; the `radiant` binary
//! falls back to a headless bake and render when it cannot.

pub mod camera;
mod gui;
mod input;
mod surface;
mod timing;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use bevy_ecs::prelude::*;
use glam::DVec3;
use radiant_ecs::bake::{BakeControl, BakePhase, BakeStatus, RadiosityBake};
use radiant_ecs::prelude::{App, RadiantPlugins, spawn_scene};
use radiant_ecs::render::{
    Bloom, Gpu, RenderPlugin, RenderSettings, RenderState, Ssao, Tonemapping,
    apply_pending_overlay, render_to,
};
use radiant_ecs::scene::SceneCamera;
use radiant_render::{GpuContext, RenderError, wgpu};
use radiant_scene::Scene;
use winit::application::ApplicationHandler;
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::window::{Window, WindowId};

use crate::camera::OrbitCamera;
use crate::gui::Gui;
use crate::input::{Action, Input};
use crate::surface::SurfaceState;
use crate::timing::FrameTimer;

/// What can stop the viewer.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// No display server to open a window on, or the event loop could not start.
    #[error("cannot open a window: {0}")]
    NoDisplay(String),
    /// The window opened but no GPU adapter can draw into it (nothing was shown).
    #[error("no GPU can draw into the window: {0}")]
    NoGpu(RenderError),
    /// The GPU failed while drawing.
    #[error(transparent)]
    Render(#[from] RenderError),
}

/// Whether a display server is reachable by its environment variables (X11 `DISPLAY` or
/// Wayland `WAYLAND_DISPLAY`); on other platforms, true.
pub fn display_available() -> bool {
    if cfg!(any(
        target_os = "linux",
        target_os = "freebsd",
        target_os = "openbsd"
    )) {
        ["DISPLAY", "WAYLAND_DISPLAY"]
            .iter()
            .any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()))
    } else {
        true
    }
}

/// How to run the viewer.
#[derive(Clone, Debug)]
pub struct ViewerOptions {
    /// The scene shown and baked.
    pub scene: Scene,
    /// Window title.
    pub title: String,
    /// Initial inner size in logical pixels (default 1280 × 720).
    pub size: (u32, u32),
    /// The bake's settings. Its `checkpoint` should be set, so closing keeps the bake.
    pub bake: RadiosityBake,
    /// Exit after this many presented frames (tests and screenshots); `None` runs until closed.
    pub exit_after_frames: Option<u64>,
    /// Show the inspector at start (default: true).
    pub inspector: bool,
    /// Light-map texels per scene unit (default `None`: automatic).
    pub texel_density: Option<f64>,
}

impl ViewerOptions {
    /// Defaults for `scene`.
    pub fn new(scene: Scene) -> Self {
        Self {
            scene,
            title: "Radiant".into(),
            size: (1280, 720),
            bake: RadiosityBake::default(),
            exit_after_frames: None,
            inspector: true,
            texel_density: None,
        }
    }
}

/// A summary of the session, returned when the window closes.
#[derive(Clone, Debug, Default)]
pub struct ViewerReport {
    /// Frames presented.
    pub frames: u64,
    /// Median time between presented frames, milliseconds.
    pub median_frame_ms: Option<f64>,
    /// The last measured per-pass times (GPU timestamps where available).
    pub pass_ms: Vec<(&'static str, f64)>,
    /// Where the bake stood at exit.
    pub bake_phase: BakePhase,
    /// The checkpoint written, if any.
    pub checkpoint: Option<PathBuf>,
}

/// Opens the window and runs until it is closed (or `exit_after_frames`).
pub fn run(options: ViewerOptions) -> Result<ViewerReport, ViewerError> {
    if !display_available() {
        return Err(ViewerError::NoDisplay(
            "neither DISPLAY nor WAYLAND_DISPLAY is set".into(),
        ));
    }
    let event_loop = EventLoop::new().map_err(|e| ViewerError::NoDisplay(e.to_string()))?;
    let mut viewer = Viewer {
        options,
        state: None,
        error: None,
        report: ViewerReport::default(),
    };
    event_loop
        .run_app(&mut viewer)
        .map_err(|e| ViewerError::NoDisplay(e.to_string()))?;
    match viewer.error {
        Some(e) => Err(e),
        None => Ok(viewer.report),
    }
}

/// A window being shown: the parts wgpu's example framework keeps apart (surface, frame
/// timing, input), the GUI, the ECS app, and the camera.
struct Running {
    window: Arc<Window>,
    surface: SurfaceState,
    app: App,
    gui: Gui,
    camera: OrbitCamera,
    camera_entity: Option<Entity>,
    input: Input,
    timer: FrameTimer,
    minimised: bool,
    /// How fast the arrow keys move dynamic meshes: a tenth of the scene's size a second.
    move_speed: f64,
}

struct Viewer {
    options: ViewerOptions,
    state: Option<Running>,
    error: Option<ViewerError>,
    report: ViewerReport,
}

impl Viewer {
    fn fail(&mut self, event_loop: &ActiveEventLoop, e: ViewerError) {
        tracing::error!("{e}");
        self.error = Some(e);
        event_loop.exit();
    }

    fn start(&mut self, event_loop: &ActiveEventLoop) -> Result<Running, ViewerError> {
        let (w, h) = self.options.size;
        let attrs = Window::default_attributes()
            .with_title(self.options.title.clone())
            .with_inner_size(winit::dpi::LogicalSize::new(w, h));
        let window = Arc::new(
            event_loop
                .create_window(attrs)
                .map_err(|e| ViewerError::NoDisplay(e.to_string()))?,
        );
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_with_display_handle_from_env(
                Box::new(event_loop.owned_display_handle()),
            ));
        let surface = instance
            .create_surface(window.clone())
            .map_err(RenderError::Surface)?;
        let gpu = pollster::block_on(GpuContext::from_instance(instance, Some(&surface)))?;
        let size = window.inner_size();
        let surface = SurfaceState::new(&gpu, surface, (size.width, size.height))?;
        let (width, height) = surface.size();
        tracing::info!(
            "window {width}×{height} on {} ({:?}), surface {:?}",
            gpu.info.name,
            gpu.info.backend,
            surface.format()
        );
        let mut gui = Gui::new(&window, &gpu.device, surface.format());
        let mut app = self.app(gpu);
        let (camera, camera_entity) = viewer_camera(&mut app.world, &self.options.scene);
        gui.show(&mut app.world, self.options.inspector);
        Ok(Running {
            window,
            surface,
            app,
            gui,
            camera,
            camera_entity,
            input: Input::default(),
            timer: FrameTimer::new(),
            minimised: false,
            move_speed: 0.1 * scene_extent(&self.options.scene),
        })
    }

    /// The ECS app: Radiant's plugins and the renderer on `gpu`, the scene spawned, the bake
    /// set up.
    fn app(&self, gpu: GpuContext) -> App {
        let mut app = App::new();
        app.add_plugins(RadiantPlugins)
            .add_plugins(RenderPlugin)
            .insert_resource(Gpu(gpu))
            .insert_resource(RenderSettings {
                texel_density: self.options.texel_density,
                offscreen: false,
                ..RenderSettings::default()
            })
            .insert_resource(self.options.bake.clone());
        // Probes only where something moves.
        if self.options.scene.surfaces.iter().any(|s| s.dynamic) {
            app.insert_resource(radiant_ecs::probes::ProbeVolumeBake::default());
        }
        spawn_scene(&mut app.world, &self.options.scene);
        app.finish();
        app
    }

    /// Pauses the bake so that it writes its checkpoint, waiting at most a few seconds.
    fn close(&mut self) {
        let Some(r) = self.state.as_mut() else {
            return;
        };
        let solving = |w: &World| {
            matches!(
                w.resource::<BakeStatus>().phase,
                BakePhase::Solving | BakePhase::Building
            )
        };
        if solving(&r.app.world) {
            r.app.world.resource_mut::<BakeControl>().pause();
            let deadline = Instant::now() + Duration::from_secs(5);
            while solving(&r.app.world) && Instant::now() < deadline {
                r.app.update();
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        let world = &r.app.world;
        self.report = ViewerReport {
            frames: r.timer.frames(),
            median_frame_ms: r.gui.inspector.median_frame_ms(),
            pass_ms: world
                .resource::<RenderState>()
                .timings
                .as_ref()
                .map(|t| t.passes.clone())
                .unwrap_or_default(),
            bake_phase: world.resource::<BakeStatus>().phase,
            checkpoint: world
                .get_resource::<RadiosityBake>()
                .and_then(|b| b.checkpoint.clone())
                .filter(|p| p.exists()),
        };
    }
}

/// The camera the viewer moves: the scene's, or one spawned looking at the scene; with the
/// default effects on it.
fn viewer_camera(world: &mut World, scene: &Scene) -> (OrbitCamera, Option<Entity>) {
    let mut q = world.query_filtered::<Entity, With<SceneCamera>>();
    let mut camera_entity = q.iter(world).next();
    if camera_entity.is_none() {
        // A scene without a camera gets one looking at it, so the controls work.
        let orbit = initial_camera(world, None, scene);
        camera_entity = Some(
            world
                .spawn((
                    Name::new("viewer camera"),
                    radiant_ecs::scene::Transform::IDENTITY,
                    SceneCamera(radiant_scene::Camera {
                        position: orbit.position(),
                        forward: orbit.forward(),
                        up: orbit.up,
                        yfov: 0.7,
                    }),
                ))
                .id(),
        );
    }
    if let Some(e) = camera_entity {
        world
            .entity_mut(e)
            .insert((Bloom::default(), Ssao::default(), Tonemapping::default()));
    }
    (initial_camera(world, camera_entity, scene), camera_entity)
}

/// The scene's bounding box (infinite corners without triangles).
fn bounds(scene: &Scene) -> (DVec3, DVec3) {
    scene.triangles.iter().flat_map(|t| t.vertices).fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(p), hi.max(p)),
    )
}

/// The length of the scene's bounding box's diagonal (1 when it has none).
fn scene_extent(scene: &Scene) -> f64 {
    let (lo, hi) = bounds(scene);
    let d = (hi - lo).length();
    if d.is_finite() && d > 0.0 { d } else { 1.0 }
}

/// The orbit camera that reproduces the scene camera, orbiting the scene's centre.
fn initial_camera(world: &mut World, camera: Option<Entity>, scene: &Scene) -> OrbitCamera {
    let (lo, hi) = bounds(scene);
    let centre = if lo.is_finite() && hi.is_finite() {
        (lo + hi) * 0.5
    } else {
        DVec3::ZERO
    };
    let cam = camera
        .and_then(|e| world.get::<SceneCamera>(e))
        .map(|c| c.0);
    match cam {
        Some(c) => {
            let d = (centre - c.position).dot(c.forward).max(1e-3);
            OrbitCamera::looking(c.position, c.forward, c.up, d)
        }
        None => {
            let extent = (hi - lo).length().max(1.0);
            OrbitCamera::looking(
                centre + DVec3::Z * extent * 1.5,
                -DVec3::Z,
                DVec3::Y,
                extent * 1.5,
            )
        }
    }
}

impl Running {
    fn write_camera(&mut self) {
        let Some(e) = self.camera_entity else { return };
        let Some(mut c) = self.app.world.get_mut::<SceneCamera>(e) else {
            return;
        };
        let new = radiant_scene::Camera {
            position: self.camera.position(),
            forward: self.camera.forward(),
            up: self.camera.up,
            yfov: c.0.yfov,
        };
        if c.0 != new {
            c.0 = new;
        }
    }

    fn resize(&mut self, width: u32, height: u32) {
        self.minimised = width == 0 || height == 0;
        let gpu = &self.app.world.resource::<Gpu>().0;
        self.surface.resize(gpu, width, height);
    }

    /// One frame: ECS update (the bake's progress, edits, light-map uploads), the inspector,
    /// the render graph into the surface, present. False when no frame was presented.
    fn redraw(&mut self) -> Result<bool, RenderError> {
        let now = Instant::now();
        let dt = self.timer.dt(now);
        self.input.fly(dt, &mut self.camera);
        if let Some(d) = self.input.nudge(dt, self.move_speed) {
            radiant_ecs::scene::move_dynamic(&mut self.app.world, d);
        }
        self.write_camera();
        self.app.update();
        apply_pending_overlay(&mut self.app.world);
        self.gui.run(&self.window, &mut self.app.world);
        let Some(frame) = self.surface.acquire(&self.app.world.resource::<Gpu>().0)? else {
            return Ok(false);
        };
        // With the inspector, the overlay pass encodes into the linear format egui wants;
        // without, the frame goes straight into an sRGB view.
        let (view, format) = self.surface.view(&frame, self.gui.shown());
        // Per-pass times now and then: measuring waits for the GPU.
        let timed = self.timer.frames() % 60 == 1;
        let world = &mut self.app.world;
        match render_to(world, &view, self.surface.size(), format, timed) {
            Ok(()) => {}
            Err(e @ RenderError::InvalidSetting { .. }) => {
                // A setting the renderer refuses: say so in the inspector, keep the window.
                tracing::warn!("frame skipped: {e}");
                world.resource_mut::<RenderState>().error = Some(Arc::new(e));
                return Ok(false);
            }
            Err(e) => return Err(e),
        }
        let gpu = &self.app.world.resource::<Gpu>().0;
        // No wait for the GPU here (the timed frames wait anyway); errors of this frame show
        // up in a later one.
        gpu.poll_errors()?;
        self.surface.present(gpu, frame);
        if let Some(ms) = self.timer.presented(now) {
            self.gui.inspector.record_frame(ms);
        } else {
            tracing::info!("first frame presented");
            eprintln!("radiant viewer: first frame presented");
        }
        if self.timer.title_due(now) {
            let s = self.app.world.resource::<BakeStatus>();
            self.window.set_title(&format!(
                "Radiant: {} {:.0} %{}",
                s.phase.name(),
                s.progress.fraction * 100.0,
                if s.stale { " (stale)" } else { "" }
            ));
        }
        Ok(true)
    }
}

impl ApplicationHandler for Viewer {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.state.is_some() {
            return;
        }
        match self.start(event_loop).map_err(|e| match e {
            ViewerError::Render(r) => ViewerError::NoGpu(r),
            other => other,
        }) {
            Ok(r) => {
                r.window.request_redraw();
                self.state = Some(r);
            }
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let Some(r) = self.state.as_mut() else {
            return;
        };
        let consumed = r.gui.on_event(&r.window, &event);
        match event {
            WindowEvent::CloseRequested => {
                self.close();
                event_loop.exit();
                return;
            }
            WindowEvent::Resized(size) => r.resize(size.width, size.height),
            WindowEvent::Occluded(occluded) => r.minimised = occluded,
            WindowEvent::RedrawRequested if !r.minimised => {
                if let Err(e) = r.redraw() {
                    self.close();
                    self.fail(event_loop, e.into());
                    return;
                }
                let done = self
                    .options
                    .exit_after_frames
                    .is_some_and(|n| r.timer.frames() >= n);
                if done {
                    self.close();
                    event_loop.exit();
                }
                return;
            }
            _ => {}
        }
        match r.input.on_event(&event, consumed, &mut r.camera) {
            Some(Action::ToggleInspector) => {
                let on = !r.gui.shown();
                r.gui.show(&mut r.app.world, on);
            }
            Some(Action::Close) => {
                self.close();
                event_loop.exit();
            }
            None => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        let Some(r) = self.state.as_mut() else {
            return;
        };
        if r.minimised {
            // No frames; keep the ECS ticking slowly so the bake's progress is collected.
            r.app.update();
            event_loop.set_control_flow(ControlFlow::WaitUntil(
                Instant::now() + Duration::from_millis(100),
            ));
        } else {
            event_loop.set_control_flow(ControlFlow::Poll);
            r.window.request_redraw();
        }
    }
}
