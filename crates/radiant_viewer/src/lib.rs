//! The Radiant viewer: a winit window showing a scene through the full render graph while the
//! bake converges in the background, with the egui inspector drawn as the graph's last pass.
//!
//! - Left drag orbits, right drag looks around, the wheel zooms, WASD and Q/E fly.
//! - `Tab` (or `F1`) shows and hides the inspector; hidden, its pass and texture leave the graph.
//! - Minimised or occluded (where the platform reports it: X11, Windows, macOS; Wayland does
//!   not tell), nothing is rendered; the bake goes on.
//! - Closing pauses the bake, which writes its checkpoint: the next start resumes from it.
//!
//! [`display_available`] tells whether a window can be opened at all; the `radiant` binary
//! falls back to a headless bake and render when it cannot.

pub mod camera;

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bevy_ecs::prelude::*;
use egui_wgpu::ScreenDescriptor;
use glam::DVec3;
use radiant_ecs::bake::{BakeControl, BakePhase, BakeStatus, RadiosityBake};
use radiant_ecs::prelude::{App, RadiantPlugins, spawn_scene};
use radiant_ecs::render::{
    Bloom, Gpu, RenderPlugin, RenderSettings, RenderState, Ssao, Tonemapping,
    apply_pending_overlay, render_to, set_overlay,
};
use radiant_ecs::scene::SceneCamera;
use radiant_inspector::InspectorState;
use radiant_post::overlay::Overlay;
use radiant_render::{GpuContext, RenderError, wgpu};
use radiant_scene::Scene;
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

use crate::camera::OrbitCamera;

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
    pub bake_phase: String,
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

/// egui drawn as the render graph's last pass (see `radiant_post::overlay`).
struct EguiOverlay {
    frame: Mutex<EguiFrame>,
}

struct EguiFrame {
    renderer: egui_wgpu::Renderer,
    jobs: Vec<egui::ClippedPrimitive>,
    textures: egui::TexturesDelta,
    to_free: Vec<egui::TextureId>,
    pixels_per_point: f32,
}

impl EguiOverlay {
    fn lock(&self) -> std::sync::MutexGuard<'_, EguiFrame> {
        match self.frame.lock() {
            Ok(g) => g,
            Err(poisoned) => poisoned.into_inner(),
        }
    }
}

impl Overlay for EguiOverlay {
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        (width, height): (u32, u32),
    ) {
        let mut f = self.lock();
        let f = &mut *f;
        for id in f.to_free.drain(..) {
            f.renderer.free_texture(&id);
        }
        let mut delta = std::mem::take(&mut f.textures);
        for (id, images) in &delta.set {
            for image in images {
                f.renderer.update_texture(device, queue, *id, image);
            }
        }
        f.to_free = delta.free.iter().copied().collect();
        delta.clear();
        let screen = ScreenDescriptor {
            size_in_pixels: [width, height],
            pixels_per_point: f.pixels_per_point,
        };
        let extra = f
            .renderer
            .update_buffers(device, queue, encoder, &f.jobs, &screen);
        if !extra.is_empty() {
            queue.submit(extra);
        }
    }

    fn draw(&self, pass: &mut wgpu::RenderPass<'static>, (width, height): (u32, u32)) {
        let f = self.lock();
        let screen = ScreenDescriptor {
            size_in_pixels: [width, height],
            pixels_per_point: f.pixels_per_point,
        };
        f.renderer.render(pass, &f.jobs, &screen);
    }
}

struct Running {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    app: App,
    egui_ctx: egui::Context,
    egui_state: egui_winit::State,
    overlay: Arc<EguiOverlay>,
    inspector: InspectorState,
    show_inspector: bool,
    camera: OrbitCamera,
    camera_entity: Option<Entity>,
    drag: Option<MouseButton>,
    cursor: Option<(f64, f64)>,
    keys: std::collections::HashSet<KeyCode>,
    minimised: bool,
    reconfigure: bool,
    last_frame: Instant,
    last_title: Instant,
    frames: u64,
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
        let caps = surface.get_capabilities(&gpu.adapter);
        // egui blends correctly only into a linear-format target, the 3D frame wants sRGB:
        // configure the linear format and view it as sRGB when the inspector is hidden.
        let preferred = caps
            .formats
            .first()
            .copied()
            .ok_or(RenderError::NoSurfaceFormat)?;
        let linear = preferred.remove_srgb_suffix();
        let view_formats_ok = gpu
            .adapter
            .get_downlevel_capabilities()
            .flags
            .contains(wgpu::DownlevelFlags::SURFACE_VIEW_FORMATS);
        let format = if view_formats_ok && caps.formats.contains(&linear) {
            linear
        } else {
            preferred
        };
        let srgb = format.add_srgb_suffix();
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            format,
            width: size.width.max(1),
            height: size.height.max(1),
            present_mode: wgpu::PresentMode::AutoVsync,
            desired_maximum_frame_latency: 2,
            alpha_mode: caps
                .alpha_modes
                .first()
                .copied()
                .unwrap_or(wgpu::CompositeAlphaMode::Auto),
            view_formats: if srgb != format { vec![srgb] } else { vec![] },
            color_space: Default::default(),
        };
        surface.configure(&gpu.device, &config);
        gpu.take_errors()?;
        tracing::info!(
            "window {}×{} on {} ({:?}), surface {:?}",
            config.width,
            config.height,
            gpu.info.name,
            gpu.info.backend,
            format
        );

        let renderer = egui_wgpu::Renderer::new(&gpu.device, format, Default::default());
        let egui_ctx = egui::Context::default();
        let egui_state = egui_winit::State::new(
            egui_ctx.clone(),
            egui::ViewportId::ROOT,
            &window,
            Some(window.scale_factor() as f32),
            None,
            Some(gpu.device.limits().max_texture_dimension_2d as usize),
        );
        let overlay = Arc::new(EguiOverlay {
            frame: Mutex::new(EguiFrame {
                renderer,
                jobs: Vec::new(),
                textures: Default::default(),
                to_free: Vec::new(),
                pixels_per_point: window.scale_factor() as f32,
            }),
        });

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
        let scene = &self.options.scene;
        spawn_scene(&mut app.world, scene);
        app.finish();
        let mut q = app.world.query_filtered::<Entity, With<SceneCamera>>();
        let mut camera_entity = q.iter(&app.world).next();
        if camera_entity.is_none() {
            // A scene without a camera gets one looking at it, so the controls work.
            let orbit = initial_camera(&mut app.world, None, scene);
            camera_entity = Some(
                app.world
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
            app.world.entity_mut(e).insert((
                Bloom::default(),
                Ssao::default(),
                Tonemapping::default(),
            ));
        }
        let camera = initial_camera(&mut app.world, camera_entity, scene);
        if self.options.inspector {
            set_overlay(&mut app.world, Some(overlay.clone() as Arc<dyn Overlay>));
        }
        Ok(Running {
            window,
            surface,
            config,
            app,
            egui_ctx,
            egui_state,
            overlay,
            inspector: InspectorState::default(),
            show_inspector: self.options.inspector,
            camera,
            camera_entity,
            drag: None,
            cursor: None,
            keys: Default::default(),
            minimised: false,
            reconfigure: false,
            last_frame: Instant::now(),
            last_title: Instant::now(),
            frames: 0,
        })
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
        let status = r.app.world.resource::<BakeStatus>().clone();
        self.report.frames = r.frames;
        self.report.median_frame_ms = r.inspector.median_frame_ms();
        self.report.pass_ms = r
            .app
            .world
            .resource::<RenderState>()
            .timings
            .as_ref()
            .map(|t| t.passes.clone())
            .unwrap_or_default();
        self.report.bake_phase = format!("{:?}", status.phase);
        self.report.checkpoint = r
            .app
            .world
            .get_resource::<RadiosityBake>()
            .and_then(|b| b.checkpoint.clone())
            .filter(|p| p.exists());
    }
}

/// The orbit camera that reproduces the scene camera, orbiting the scene's centre.
fn initial_camera(world: &mut World, camera: Option<Entity>, scene: &Scene) -> OrbitCamera {
    let (lo, hi) = scene.triangles.iter().flat_map(|t| t.vertices).fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(p), hi.max(p)),
    );
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

    fn fly(&mut self, dt: f64) {
        let k = |code: KeyCode| f64::from(u8::from(self.keys.contains(&code)));
        let right = k(KeyCode::KeyD) - k(KeyCode::KeyA);
        let up = k(KeyCode::KeyE) - k(KeyCode::KeyQ);
        let forward = k(KeyCode::KeyW) - k(KeyCode::KeyS);
        if right != 0.0 || up != 0.0 || forward != 0.0 {
            let speed = 0.8 * dt;
            self.camera.fly(right * speed, up * speed, forward * speed);
        }
    }

    fn resize(&mut self, width: u32, height: u32) {
        self.minimised = width == 0 || height == 0;
        if self.minimised {
            return;
        }
        self.config.width = width;
        self.config.height = height;
        let gpu = &self.app.world.resource::<Gpu>().0;
        self.surface.configure(&gpu.device, &self.config);
    }

    fn set_inspector(&mut self, on: bool) {
        self.show_inspector = on;
        let overlay = on.then(|| self.overlay.clone() as Arc<dyn Overlay>);
        set_overlay(&mut self.app.world, overlay);
    }

    /// One frame: ECS update (the bake's progress, edits, light-map uploads), the inspector,
    /// the render graph into the surface, present.
    fn redraw(&mut self) -> Result<bool, RenderError> {
        let now = Instant::now();
        let dt = now.duration_since(self.last_frame).as_secs_f64().min(0.1);
        self.fly(dt);
        self.write_camera();
        self.app.update();
        apply_pending_overlay(&mut self.app.world);

        if self.show_inspector {
            let input = self.egui_state.take_egui_input(&self.window);
            let world = &mut self.app.world;
            let inspector = &mut self.inspector;
            let output = self.egui_ctx.run_ui(input, |ui| {
                egui::Panel::right("radiant_inspector")
                    .default_size(320.0)
                    .show(ui, |ui| {
                        radiant_inspector::inspector_ui(ui, world, inspector)
                    });
            });
            self.egui_state
                .handle_platform_output(&self.window, output.platform_output);
            let jobs = self
                .egui_ctx
                .tessellate(output.shapes, output.pixels_per_point);
            let mut f = self.overlay.lock();
            f.jobs = jobs;
            f.textures.append(output.textures_delta);
            f.pixels_per_point = output.pixels_per_point;
        }

        let frame = {
            let gpu = &self.app.world.resource::<Gpu>().0;
            match self.surface.get_current_texture() {
                wgpu::CurrentSurfaceTexture::Success(t) => t,
                wgpu::CurrentSurfaceTexture::Suboptimal(t) => {
                    // Reconfigure after presenting: not while this texture is held.
                    self.reconfigure = true;
                    t
                }
                wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => {
                    return Ok(false);
                }
                wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                    self.surface.configure(&gpu.device, &self.config);
                    return Ok(false);
                }
                wgpu::CurrentSurfaceTexture::Validation => {
                    gpu.take_errors()?;
                    return Ok(false);
                }
            }
        };
        // With the inspector, the overlay pass encodes into the linear format egui wants;
        // without, the frame goes straight into an sRGB view.
        let format = if self.show_inspector {
            self.config.format
        } else {
            self.config.format.add_srgb_suffix()
        };
        let view = frame.texture.create_view(&wgpu::TextureViewDescriptor {
            format: Some(format),
            ..Default::default()
        });
        // Per-pass times now and then: measuring waits for the GPU.
        let timed = self.frames % 60 == 1;
        match render_to(
            &mut self.app.world,
            &view,
            (self.config.width, self.config.height),
            format,
            timed,
        ) {
            Ok(()) => {}
            Err(e @ RenderError::InvalidSetting { .. }) => {
                // A setting the renderer refuses: say so in the inspector, keep the window.
                tracing::warn!("frame skipped: {e}");
                self.app.world.resource_mut::<RenderState>().error = Some(e.to_string());
                return Ok(false);
            }
            Err(e) => return Err(e),
        }
        let gpu = &self.app.world.resource::<Gpu>().0;
        // No wait for the GPU here (the timed frames wait anyway); errors of this frame show
        // up in a later one.
        gpu.poll_errors()?;
        gpu.queue.present(frame);
        if std::mem::take(&mut self.reconfigure) {
            self.surface.configure(&gpu.device, &self.config);
        }
        self.frames += 1;
        let ms = now.duration_since(self.last_frame).as_secs_f64() * 1e3;
        if self.frames > 1 {
            self.inspector.record_frame(ms);
        }
        self.last_frame = now;
        if self.frames == 1 {
            tracing::info!("first frame presented");
            eprintln!("radiant viewer: first frame presented");
        }
        if now.duration_since(self.last_title) > Duration::from_millis(500) {
            self.last_title = now;
            let s = self.app.world.resource::<BakeStatus>();
            self.window.set_title(&format!(
                "Radiant: {:?} {:.0} %{}",
                s.phase,
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
        let consumed = r.show_inspector && r.egui_state.on_window_event(&r.window, &event).consumed;
        match event {
            WindowEvent::CloseRequested => {
                self.close();
                event_loop.exit();
            }
            WindowEvent::Resized(size) => r.resize(size.width, size.height),
            WindowEvent::Occluded(occluded) => r.minimised = occluded,
            WindowEvent::RedrawRequested => {
                if r.minimised {
                    return;
                }
                match r.redraw() {
                    Ok(_) => {}
                    Err(e) => {
                        self.close();
                        self.fail(event_loop, e.into());
                        return;
                    }
                }
                let done = self
                    .options
                    .exit_after_frames
                    .is_some_and(|n| r.frames >= n);
                if done {
                    self.close();
                    event_loop.exit();
                }
            }
            WindowEvent::Focused(false) => {
                // Releases that happen elsewhere never arrive: forget what is held.
                r.keys.clear();
                r.drag = None;
            }
            WindowEvent::KeyboardInput { event, .. } => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    match event.state {
                        ElementState::Pressed if consumed => {}
                        ElementState::Pressed => {
                            if matches!(code, KeyCode::Tab | KeyCode::F1) && !event.repeat {
                                let on = !r.show_inspector;
                                r.set_inspector(on);
                            }
                            if code == KeyCode::Escape {
                                self.close();
                                event_loop.exit();
                                return;
                            }
                            r.keys.insert(code);
                        }
                        ElementState::Released => {
                            r.keys.remove(&code);
                        }
                    }
                }
            }
            WindowEvent::MouseInput { state, button, .. } => {
                if state == ElementState::Pressed && !consumed {
                    r.drag = Some(button);
                } else if state == ElementState::Released {
                    r.drag = None;
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                let p = (position.x, position.y);
                if let (Some(button), Some(last)) = (r.drag, r.cursor) {
                    let (dx, dy) = (p.0 - last.0, p.1 - last.1);
                    match button {
                        MouseButton::Left => r.camera.orbit(dx, dy),
                        MouseButton::Right => r.camera.look(dx, dy),
                        _ => {}
                    }
                }
                r.cursor = Some(p);
            }
            WindowEvent::MouseWheel { delta, .. } if !consumed => {
                let steps = match delta {
                    MouseScrollDelta::LineDelta(_, y) => f64::from(y),
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                r.camera.zoom(steps);
            }
            _ => {}
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
