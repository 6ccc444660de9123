//! Settings that draw themselves. Each `inspect` destructures every field of its type
//! (`let Self { a, b, .. }` is never used), so a new field breaks the build until it is shown
//! or explicitly left out here.

use egui::{ComboBox, DragValue, Slider, SliderClamping, Ui, emath::Numeric};
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

/// A slider that clamps only what the user enters, never the value it is shown (so showing a
/// value outside the range writes nothing back), and reports a change only when the value
/// differs.
pub(crate) fn slider<N: Numeric>(
    ui: &mut Ui,
    value: &mut N,
    range: std::ops::RangeInclusive<N>,
    text: &str,
) -> bool {
    let before = *value;
    ui.add(
        Slider::new(value, range)
            .clamping(SliderClamping::Edits)
            .text(text),
    );
    value.to_f64() != before.to_f64()
}

/// A drag value with the same rules as [`slider`]: `configure` sets its range, speed and text.
/// Returns the response (to label it) and whether the value changed.
pub(crate) fn drag<N: Numeric>(
    ui: &mut Ui,
    value: &mut N,
    configure: impl for<'a> FnOnce(DragValue<'a>) -> DragValue<'a>,
) -> (egui::Response, bool) {
    let before = value.to_f64();
    let response = ui.add(configure(DragValue::new(value)).clamp_existing_to_range(false));
    let changed = value.to_f64() != before;
    (response, changed)
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
        changed |= slider(ui, exposure, -8.0..=8.0, "exposure (EV)");
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
        c |= slider(ui, intensity, 0.0..=1.0, "intensity");
        c |= slider(ui, threshold, 0.0..=16.0, "threshold");
        c |= slider(ui, knee, 0.0..=1.0, "knee");
        c |= slider(ui, mip_count, 1..=8, "mip levels");
        c |= slider(ui, scatter, 0.0..=1.0, "scatter");
        c |= slider(ui, gaussian_rounds, 1..=8, "Gaussian rounds");
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
        // Validation: radius > 0, 0 ≤ bias < radius, intensity in (0, 8], 1..=64 samples.
        let mut c = slider(ui, radius, 0.01..=2.0, "radius (m)");
        c |= slider(ui, bias, 0.0..=0.1, "bias (m)");
        c |= slider(ui, intensity, 0.05..=8.0, "intensity");
        c |= slider(ui, samples, 1..=64, "samples");
        if c && *bias >= *radius {
            *bias = *radius * 0.5;
        }
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
        c |= slider(ui, threshold, 0.01..=4.0, "threshold");
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
        let mut c = slider(ui, sigma, 0.1..=16.0, "sigma (px)");
        if slider(ui, taps, 1..=63, "taps (odd)") {
            // Validation wants an odd count: round an even one up.
            *taps |= 1;
            c = true;
        }
        c |= slider(ui, passes, 1..=8, "passes");
        c
    }
}

impl Inspect for DebugView {
    fn inspect(&mut self, ui: &mut Ui) -> bool {
        combo(ui, "debug view", self, &DebugView::ALL, debug_view_name)
    }
}

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
                let (response, changed) = drag(ui, &mut mesh.patch_size, |d| {
                    d.range(1e-3..=1e3).speed(0.005).suffix(" m")
                });
                response.labelled_by(toggle.id);
                c |= changed;
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
                let (response, changed) = drag(ui, &mut s, |d| {
                    d.range(0.05..=3600.0).speed(0.1).suffix(" s")
                });
                response.labelled_by(toggle.id);
                if changed && s.is_finite() && s > 0.0 {
                    *t = std::time::Duration::from_secs_f64(s);
                    c = true;
                }
            }
        });
        c
    }
}
