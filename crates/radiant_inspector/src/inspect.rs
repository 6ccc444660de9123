//! Settings that draw themselves. Each `inspect` destructures every field of its type
//! (`let Self { a, b, .. }` is never used), so a new field breaks the build until it is shown
//! or explicitly left out here.

use egui::{ComboBox, DragValue, Slider, Ui};
use radiant_color::Tonemap;
use radiant_post::bloom::{Bloom, BloomComposite, BloomMethod};
use radiant_post::blur::GaussianBlur;
use radiant_post::sobel::{EdgeSource, Sobel};
use radiant_post::tonemapping::Tonemapping;
use radiant_radiosity::{FormFactorKind, SolverKind};
use radiant_render::lighting::DebugView;
use radiant_render::ssao::Ssao;

/// A settings type that draws its own editor. Returns whether anything changed.
pub trait Inspect {
    /// Draws every field; `true` when the user changed one.
    fn inspect(&mut self, ui: &mut Ui) -> bool;
}

fn combo<T: PartialEq + Copy>(
    ui: &mut Ui,
    label: &str,
    value: &mut T,
    options: &[T],
    name: impl Fn(T) -> &'static str,
) -> bool {
    let before = *value;
    ComboBox::from_label(label)
        .selected_text(name(*value))
        .show_ui(ui, |ui| {
            for &o in options {
                ui.selectable_value(value, o, name(o));
            }
        });
    *value != before
}

impl Inspect for Tonemapping {
    fn inspect(&mut self, ui: &mut Ui) -> bool {
        let Self { operator, exposure } = self;
        let mut changed = combo(ui, "operator", operator, &Tonemap::ALL, |t| t.name());
        changed |= ui
            .add(Slider::new(exposure, -8.0..=8.0).text("exposure (EV)"))
            .changed();
        changed
    }
}

impl Inspect for Bloom {
    fn inspect(&mut self, ui: &mut Ui) -> bool {
        let Self {
            method,
            composite,
            intensity,
            threshold,
            knee,
            mip_count,
            scatter,
            gaussian_rounds,
        } = self;
        let mut c = combo(
            ui,
            "method",
            method,
            &[BloomMethod::MipChain, BloomMethod::Gaussian],
            |m| match m {
                BloomMethod::MipChain => "mip chain (Jimenez)",
                BloomMethod::Gaussian => "bright pass + Gaussian",
            },
        );
        c |= combo(
            ui,
            "composite",
            composite,
            &[BloomComposite::EnergyConserving, BloomComposite::Additive],
            |m| match m {
                BloomComposite::EnergyConserving => "energy-conserving",
                BloomComposite::Additive => "additive",
            },
        );
        c |= ui
            .add(Slider::new(intensity, 0.0..=1.0).text("intensity"))
            .changed();
        c |= ui
            .add(Slider::new(threshold, 0.0..=16.0).text("threshold"))
            .changed();
        c |= ui.add(Slider::new(knee, 0.0..=1.0).text("knee")).changed();
        c |= ui
            .add(Slider::new(mip_count, 1..=8).text("mip levels"))
            .changed();
        c |= ui
            .add(Slider::new(scatter, 0.0..=1.0).text("scatter"))
            .changed();
        c |= ui
            .add(Slider::new(gaussian_rounds, 1..=16).text("Gaussian rounds"))
            .changed();
        c
    }
}

impl Inspect for Ssao {
    fn inspect(&mut self, ui: &mut Ui) -> bool {
        let Self {
            radius,
            bias,
            intensity,
            samples,
        } = self;
        let mut c = ui
            .add(Slider::new(radius, 0.01..=2.0).text("radius (m)"))
            .changed();
        c |= ui
            .add(Slider::new(bias, 0.0..=0.1).text("bias (m)"))
            .changed();
        c |= ui
            .add(Slider::new(intensity, 0.0..=4.0).text("intensity"))
            .changed();
        c |= ui
            .add(Slider::new(samples, 1..=64).text("samples"))
            .changed();
        c
    }
}

impl Inspect for Sobel {
    fn inspect(&mut self, ui: &mut Ui) -> bool {
        let Self {
            threshold,
            source,
            edge_color,
        } = self;
        let mut c = combo(
            ui,
            "edges of",
            source,
            &[EdgeSource::Color, EdgeSource::Depth, EdgeSource::Normal],
            |s| match s {
                EdgeSource::Color => "colour",
                EdgeSource::Depth => "depth",
                EdgeSource::Normal => "normal",
            },
        );
        c |= ui
            .add(Slider::new(threshold, 0.0..=4.0).text("threshold"))
            .changed();
        ui.horizontal(|ui| {
            c |= ui.color_edit_button_rgb(edge_color).changed();
            ui.label("edge colour");
        });
        c
    }
}

impl Inspect for GaussianBlur {
    fn inspect(&mut self, ui: &mut Ui) -> bool {
        let Self {
            sigma,
            taps,
            passes,
        } = self;
        let mut c = ui
            .add(Slider::new(sigma, 0.1..=16.0).text("sigma (px)"))
            .changed();
        c |= ui.add(Slider::new(taps, 1..=63).text("taps")).changed();
        c |= ui.add(Slider::new(passes, 1..=8).text("passes")).changed();
        c
    }
}

impl Inspect for DebugView {
    fn inspect(&mut self, ui: &mut Ui) -> bool {
        combo(ui, "debug view", self, &DEBUG_VIEWS, debug_view_name)
    }
}

/// Every debug view, in menu order.
pub const DEBUG_VIEWS: [DebugView; 9] = [
    DebugView::Lit,
    DebugView::Albedo,
    DebugView::Normal,
    DebugView::Material,
    DebugView::LightMap,
    DebugView::Emissive,
    DebugView::Depth,
    DebugView::AmbientOcclusion,
    DebugView::DirectLight,
];

/// The menu name of a debug view.
pub fn debug_view_name(v: DebugView) -> &'static str {
    match v {
        DebugView::Lit => "lit",
        DebugView::Albedo => "albedo",
        DebugView::Normal => "normal",
        DebugView::Material => "material",
        DebugView::LightMap => "light map",
        DebugView::Emissive => "emissive",
        DebugView::Depth => "depth",
        DebugView::AmbientOcclusion => "ambient occlusion",
        DebugView::DirectLight => "direct light",
    }
}

/// The bake's settings as the inspector edits them: method, form factors, patch size and time
/// budget. Everything else in `BakeParams` keeps its value.
impl Inspect for radiant_radiosity::BakeParams {
    fn inspect(&mut self, ui: &mut Ui) -> bool {
        let Self {
            mesh,
            form_factors,
            ff: _,
            links: _,
            solver,
            solver_params: _,
            time_limit,
            step_budget: _,
        } = self;
        let mut c = combo(ui, "solver", solver, &SolverKind::ALL, |s| s.name());
        c |= combo(
            ui,
            "form factors",
            form_factors,
            &FormFactorKind::ALL,
            |f| f.name(),
        );
        ui.horizontal(|ui| {
            let mut auto = mesh.patch_size <= 0.0;
            let toggle = ui.checkbox(&mut auto, "auto patch size");
            if toggle.changed() {
                mesh.patch_size = if auto { 0.0 } else { 0.25 };
                c = true;
            }
            if !auto {
                c |= ui
                    .add(
                        DragValue::new(&mut mesh.patch_size)
                            .range(1e-3..=1e3)
                            .speed(0.005)
                            .suffix(" m"),
                    )
                    .labelled_by(toggle.id)
                    .changed();
            }
        });
        ui.horizontal(|ui| {
            let mut limited = time_limit.is_some();
            let toggle = ui.checkbox(&mut limited, "time budget");
            if toggle.changed() {
                *time_limit = limited.then(|| std::time::Duration::from_secs(10));
                c = true;
            }
            if let Some(t) = time_limit {
                let mut s = t.as_secs_f64();
                if ui
                    .add(
                        DragValue::new(&mut s)
                            .range(0.05..=3600.0)
                            .speed(0.1)
                            .suffix(" s"),
                    )
                    .labelled_by(toggle.id)
                    .changed()
                {
                    *t = std::time::Duration::from_secs_f64(s);
                    c = true;
                }
            }
        });
        c
    }
}
