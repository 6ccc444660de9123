//! egui panels over Radiant's ECS world: colours, lights, the sky, post-processing, the bake
//! and performance.
//!
//! The inspector holds no copy of the scene. Every frame it reads the world, and it writes a
//! component or resource back only when the user changed it, so Bevy's change detection does
//! the rest: a material edit warm-starts the bake, an effect toggle recompiles the render graph
//! without that effect's passes and textures.
//!
//! ```no_run
//! use radiant_inspector::{InspectorState, inspector_ui};
//! # fn frame(ctx: &egui::Context, input: egui::RawInput, world: &mut bevy_ecs::world::World) {
//! let mut state = InspectorState::default();
//! let output = ctx.run_ui(input, |ui| {
//!     egui::Panel::right("inspector").show(ui, |ui| inspector_ui(ui, world, &mut state));
//! });
//! # }
//! ```
//!
//! Nothing here opens a window: tests drive the panels headlessly with `egui_kittest`, and the
//! viewer (`radiant_viewer`) draws them as the last pass of the render graph.

pub mod colour;
pub mod inspect;
pub mod panels;

use std::collections::{HashMap, VecDeque};

use bevy_ecs::entity::Entity;
use bevy_ecs::world::World;

pub use inspect::Inspect;

/// The inspector's tabs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Tab {
    /// Materials: base colour, emission, chromaticity.
    #[default]
    Colour,
    /// Punctual lights.
    Lights,
    /// The sky.
    Sky,
    /// Tone mapping, debug view and effects.
    Post,
    /// The bake.
    Radiosity,
    /// Frame and pass times, graph memory.
    Performance,
}

impl Tab {
    /// Every tab, in display order.
    pub const ALL: [Tab; 6] = [
        Tab::Colour,
        Tab::Lights,
        Tab::Sky,
        Tab::Post,
        Tab::Radiosity,
        Tab::Performance,
    ];

    /// The tab's title.
    pub fn title(self) -> &'static str {
        match self {
            Tab::Colour => "Colour",
            Tab::Lights => "Lights",
            Tab::Sky => "Sky",
            Tab::Post => "Post",
            Tab::Radiosity => "Radiosity",
            Tab::Performance => "Performance",
        }
    }
}

/// What the inspector remembers between frames (selection, text being typed, frame times).
/// It never holds scene data.
#[derive(Clone, Debug, Default)]
pub struct InspectorState {
    /// The tab shown.
    pub tab: Tab,
    /// The surface the Colour tab edits.
    pub surface: Option<Entity>,
    /// Text of the base colour's hex field.
    pub hex_base: String,
    /// Text of the emission's hex field.
    pub hex_emission: String,
    /// Text of each light's hex field.
    pub hex_lights: HashMap<Entity, String>,
    /// Text of the sky's hex fields (uniform or zenith, horizon).
    pub hex_sky: [String; 2],
    /// Each light's colour temperature in the picker, kelvin.
    pub kelvin: HashMap<Entity, f64>,
    /// A chromaticity picked outside sRGB, and the colour it was mapped to.
    pub picked_xy: Option<([f64; 2], [f64; 3])>,
    /// Recent frame times, milliseconds (the caller records them).
    pub frame_ms: VecDeque<f64>,
}

impl InspectorState {
    /// Frames kept for the frame-time median.
    pub const FRAME_WINDOW: usize = 120;

    /// Records one frame's time.
    pub fn record_frame(&mut self, ms: f64) {
        if ms.is_finite() && ms >= 0.0 {
            if self.frame_ms.len() == Self::FRAME_WINDOW {
                self.frame_ms.pop_front();
            }
            self.frame_ms.push_back(ms);
        }
    }

    /// The median of the recorded frame times.
    pub fn median_frame_ms(&self) -> Option<f64> {
        let mut v: Vec<f64> = self.frame_ms.iter().copied().collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        Some(v[v.len() / 2])
    }
}

/// Draws the tab bar and the current tab.
pub fn inspector_ui(ui: &mut egui::Ui, world: &mut World, state: &mut InspectorState) {
    ui.horizontal_wrapped(|ui| {
        for tab in Tab::ALL {
            ui.selectable_value(&mut state.tab, tab, tab.title());
        }
    });
    ui.separator();
    egui::ScrollArea::vertical().show(ui, |ui| tab_ui(ui, world, state));
}

/// Draws one tab's panel (without the tab bar).
pub fn tab_ui(ui: &mut egui::Ui, world: &mut World, state: &mut InspectorState) {
    match state.tab {
        Tab::Colour => panels::colour_panel(ui, world, state),
        Tab::Lights => panels::lights_panel(ui, world, state),
        Tab::Sky => panels::sky_panel(ui, world, state),
        Tab::Post => panels::post_panel(ui, world, state),
        Tab::Radiosity => panels::radiosity_panel(ui, world, state),
        Tab::Performance => panels::performance_panel(ui, world, state),
    }
}
