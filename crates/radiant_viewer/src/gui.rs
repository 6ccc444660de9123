//! The inspector's GUI: egui's context and winit state, the inspector's own state, and egui
//! drawn as the render graph's last pass (see `radiant_post::overlay`).

use std::sync::{Arc, Mutex};

use bevy_ecs::world::World;
use egui_wgpu::ScreenDescriptor;
use radiant_ecs::render::set_overlay;
use radiant_inspector::InspectorState;
use radiant_post::overlay::Overlay;
use radiant_render::wgpu;
use winit::event::WindowEvent;
use winit::window::Window;

/// The inspector: shown or not, and what it draws with.
pub(crate) struct Gui {
    ctx: egui::Context,
    state: egui_winit::State,
    overlay: Arc<EguiOverlay>,
    /// The inspector's state (frame times, panels).
    pub(crate) inspector: InspectorState,
    shown: bool,
}

impl Gui {
    /// egui for `window`, drawing into `format`.
    pub(crate) fn new(window: &Window, device: &wgpu::Device, format: wgpu::TextureFormat) -> Self {
        let renderer = egui_wgpu::Renderer::new(device, format, Default::default());
        let ctx = egui::Context::default();
        let state = egui_winit::State::new(
            ctx.clone(),
            egui::ViewportId::ROOT,
            window,
            Some(window.scale_factor() as f32),
            None,
            Some(device.limits().max_texture_dimension_2d as usize),
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
        Self {
            ctx,
            state,
            overlay,
            inspector: InspectorState::default(),
            shown: false,
        }
    }

    /// Whether the inspector is shown.
    pub(crate) fn shown(&self) -> bool {
        self.shown
    }

    /// Shows or hides the inspector: hidden, its pass and texture leave the graph.
    pub(crate) fn show(&mut self, world: &mut World, on: bool) {
        self.shown = on;
        let overlay = on.then(|| self.overlay.clone() as Arc<dyn Overlay>);
        set_overlay(world, overlay);
    }

    /// Lets egui see `event`; true when the inspector took it.
    pub(crate) fn on_event(&mut self, window: &Window, event: &WindowEvent) -> bool {
        self.shown && self.state.on_window_event(window, event).consumed
    }

    /// Runs the inspector's UI on `world` and hands what it drew to the overlay pass.
    pub(crate) fn run(&mut self, window: &Window, world: &mut World) {
        if !self.shown {
            return;
        }
        let input = self.state.take_egui_input(window);
        let inspector = &mut self.inspector;
        let output = self.ctx.run_ui(input, |ui| {
            egui::Panel::right("radiant_inspector")
                .default_size(320.0)
                .show(ui, |ui| {
                    radiant_inspector::inspector_ui(ui, world, inspector)
                });
        });
        self.state
            .handle_platform_output(window, output.platform_output);
        let jobs = self.ctx.tessellate(output.shapes, output.pixels_per_point);
        let mut f = self.overlay.lock();
        f.jobs = jobs;
        f.textures.append(output.textures_delta);
        f.pixels_per_point = output.pixels_per_point;
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
