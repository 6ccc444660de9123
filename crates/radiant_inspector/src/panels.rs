//! The inspector's panels. Each reads the ECS world and writes it back only when the user
//! changed something, so change detection sees real edits only (and the bake rebakes only
//! what they touched).

use bevy_ecs::prelude::*;
use egui::{Color32, RichText, Ui};
use egui_plot::{Line, Plot, PlotPoints};
use radiant_ecs::bake::{BakeControl, BakeStatus, RadiosityBake};
use radiant_ecs::render::{Bloom, DebugView, GaussianBlur, RenderState, Sobel, Ssao, Tonemapping};
use radiant_ecs::scene::{Material, PunctualLight, SceneCamera, SceneSky, SurfaceOrder};
use radiant_scene::LightKind;

use crate::InspectorState;
use crate::colour::{self, chromaticity, chromaticity_diagram, from_chromaticity};
use crate::inspect::Inspect;

fn warn(ui: &mut Ui, text: impl Into<String>) {
    ui.colored_label(Color32::from_rgb(230, 160, 60), text.into());
}

/// Surfaces in spawn order: (entity, name).
fn surfaces(world: &mut World) -> Vec<(Entity, String)> {
    let mut q = world.query::<(Entity, &SurfaceOrder, Option<&Name>, &Material)>();
    let mut rows: Vec<_> = q
        .iter(world)
        .map(|(e, o, n, _)| {
            (
                *o,
                e,
                n.map_or_else(|| format!("surface {}", o.0), |n| n.as_str().to_owned()),
            )
        })
        .collect();
    rows.sort_by_key(|r| r.0);
    rows.into_iter().map(|(_, e, n)| (e, n)).collect()
}

/// Colour: the selected surface's base colour (reflectance) and emission in linear RGB, sRGB
/// hex and HDR intensity, and the CIE 1931 xy diagram. A click in the diagram sets the base
/// colour's chromaticity at its luminance; outside sRGB the point is ringed and the colour
/// desaturated into the gamut.
pub fn colour_panel(ui: &mut Ui, world: &mut World, state: &mut InspectorState) {
    let list = surfaces(world);
    if list.is_empty() {
        ui.label("No surfaces in the world.");
        return;
    }
    if state
        .surface
        .is_none_or(|s| !list.iter().any(|(e, _)| *e == s))
    {
        state.surface = Some(list[0].0);
        state.hex_base.clear();
        state.hex_emission.clear();
        state.picked_xy = None;
    }
    let Some(selected) = state.surface else {
        return;
    };
    let current = list
        .iter()
        .find(|(e, _)| *e == selected)
        .map_or("", |(_, n)| n.as_str());
    egui::ComboBox::from_label("surface")
        .selected_text(current)
        .show_ui(ui, |ui| {
            for (e, name) in &list {
                if ui.selectable_label(*e == selected, name).clicked() && *e != selected {
                    state.surface = Some(*e);
                    state.hex_base.clear();
                    state.hex_emission.clear();
                    state.picked_xy = None;
                }
            }
        });
    let Some(entity) = state.surface else { return };
    let Some(material) = world.get::<Material>(entity).copied() else {
        return;
    };
    let Material {
        mut reflectance,
        mut emission,
    } = material;
    let mut changed = false;
    ui.label(RichText::new("Base colour (reflectance)").strong());
    changed |= colour::rgb_editor(ui, "hex_base", &mut reflectance, 0.999, &mut state.hex_base);
    ui.label(RichText::new("Emission").strong());
    changed |= colour::hdr_editor(ui, "hex_emission", &mut emission, &mut state.hex_emission);

    let base_xy = chromaticity(reflectance);
    let mut points = vec![("base", base_xy, reflectance)];
    if emission.iter().any(|&e| e > 0.0) {
        let peak = emission.iter().copied().fold(0.0, f64::max);
        points.push((
            "emission",
            chromaticity(emission),
            emission.map(|e| e / peak),
        ));
    }
    if let Some((xy, rgb)) = state.picked_xy {
        points.push(("picked", xy, rgb));
    }
    ui.label("CIE 1931 xy: click to set the base colour's chromaticity");
    if let Some(xy) = chromaticity_diagram(ui, 260.0, &points) {
        let y = colour::luminance_y(reflectance).max(0.05);
        if let Some((rgb, outside)) = from_chromaticity(xy, y) {
            // Below 1 (a reflectance), scaled as a whole so the chromaticity is kept.
            let peak = rgb.iter().copied().fold(0.0, f64::max);
            let k = peak.max(0.999) / 0.999;
            reflectance = rgb.map(|c| c / k);
            state.picked_xy = outside.then_some((xy, reflectance));
            state.hex_base.clear();
            changed = true;
        }
    }
    if let Some((xy, rgb)) = state.picked_xy {
        warn(
            ui,
            format!(
                "picked xy ({:.3}, {:.3}) is outside sRGB: stored as {}",
                xy[0],
                xy[1],
                colour::to_hex(rgb)
            ),
        );
    }
    let edited = Material {
        reflectance,
        emission,
    };
    if changed
        && edited != material
        && let Some(mut m) = world.get_mut::<Material>(entity)
    {
        *m = edited;
    }
}

/// Lights: colour (with a colour-temperature picker), intensity, range and cone angles.
pub fn lights_panel(ui: &mut Ui, world: &mut World, state: &mut InspectorState) {
    let mut q = world.query::<(Entity, &PunctualLight)>();
    let mut lights: Vec<(Entity, radiant_scene::Light)> =
        q.iter(world).map(|(e, l)| (e, l.0.clone())).collect();
    lights.sort_by_key(|(e, _)| *e);
    if lights.is_empty() {
        ui.label("No punctual lights. Emissive surfaces are edited in the Colour panel.");
        return;
    }
    for (entity, original) in lights {
        let mut light = original.clone();
        let mut changed = false;
        egui::CollapsingHeader::new(light.name.clone())
            .id_salt(entity)
            .default_open(true)
            .show(ui, |ui| {
                let radiant_scene::Light {
                    name: _,
                    kind,
                    position: _,
                    direction: _,
                    color,
                    intensity,
                    range,
                } = &mut light;
                let hex = state.hex_lights.entry(entity).or_default();
                changed |=
                    colour::rgb_editor(ui, &format!("hex_light_{entity:?}"), color, 1.0, hex);
                let kelvin = state.kelvin.entry(entity).or_insert(6504.0);
                if let Some(rgb) = colour::kelvin_picker(ui, kelvin) {
                    *color = rgb;
                    hex.clear();
                    changed = true;
                }
                let unit = if matches!(kind, LightKind::Directional) {
                    " lx"
                } else {
                    " cd"
                };
                ui.horizontal(|ui| {
                    let label = ui.label("intensity");
                    let speed = (*intensity * 0.01).max(0.01);
                    let (response, edited) = crate::inspect::drag(ui, intensity, |d| {
                        d.range(0.0..=1e7).speed(speed).suffix(unit)
                    });
                    response.labelled_by(label.id);
                    changed |= edited;
                });
                if !matches!(kind, LightKind::Directional) {
                    ui.horizontal(|ui| {
                        let mut limited = range.is_some();
                        let toggle = ui.checkbox(&mut limited, "range");
                        if toggle.changed() {
                            *range = limited.then_some(10.0);
                            changed = true;
                        }
                        if let Some(r) = range {
                            let (response, edited) = crate::inspect::drag(ui, r, |d| {
                                d.range(1e-3..=1e6).speed(0.05).suffix(" m")
                            });
                            response.labelled_by(toggle.id);
                            changed |= edited;
                        }
                    });
                }
                if let LightKind::Spot {
                    inner_cone_angle,
                    outer_cone_angle,
                } = kind
                {
                    let mut inner = inner_cone_angle.to_degrees();
                    let mut outer = outer_cone_angle.to_degrees();
                    let a = crate::inspect::slider(ui, &mut inner, 0.0..=90.0, "inner cone (°)");
                    let b = crate::inspect::slider(ui, &mut outer, 0.0..=90.0, "outer cone (°)");
                    if a || b {
                        // glTF: 0 ≤ inner < outer ≤ π/2.
                        outer = outer.max(0.1);
                        inner = inner.min(outer - 0.05).max(0.0);
                        *inner_cone_angle = inner.to_radians();
                        *outer_cone_angle = outer.to_radians();
                        changed = true;
                    }
                }
            });
        if changed
            && light != original
            && let Some(mut l) = world.get_mut::<PunctualLight>(entity)
        {
            l.0 = light;
        }
    }
}

/// Brightest sky radiance the editors offer (emissive units).
const SKY_MAX: f64 = 1e4;

/// The sky: none, uniform or a zenith/horizon gradient, edited as HDR colours; an image sky is
/// shown, and can be replaced. An edit re-lights the bake (its links are kept) and the frame.
pub fn sky_panel(ui: &mut Ui, world: &mut World, state: &mut InspectorState) {
    use radiant_scene::Sky;
    let Some(original) = world.get_resource::<SceneSky>().map(|s| s.0.clone()) else {
        ui.label("This world has no sky resource.");
        return;
    };
    let mut sky = original.clone();
    // The kind, switching with the colours carried over.
    let kind = |s: &Option<Sky>| match s {
        None => 0,
        Some(Sky::Uniform { .. }) => 1,
        Some(Sky::Gradient { .. }) => 2,
        Some(Sky::Image(_)) => 3,
    };
    let mut chosen = kind(&sky);
    ui.horizontal(|ui| {
        ui.radio_value(&mut chosen, 0, "none");
        ui.radio_value(&mut chosen, 1, "uniform");
        ui.radio_value(&mut chosen, 2, "gradient");
        if matches!(sky, Some(Sky::Image(_))) {
            ui.radio_value(&mut chosen, 3, "image");
        }
    });
    if chosen != kind(&sky) {
        let (zenith, horizon) = match &sky {
            Some(Sky::Uniform { radiance }) => (*radiance, *radiance),
            Some(Sky::Gradient { zenith, horizon }) => (*zenith, *horizon),
            _ => ([0.4, 0.6, 1.0], [1.0; 3]),
        };
        sky = match chosen {
            1 => Some(Sky::Uniform { radiance: zenith }),
            2 => Some(Sky::Gradient { zenith, horizon }),
            _ => None,
        };
        state.hex_sky = Default::default();
    }
    match &mut sky {
        None => {
            ui.label("No sky: only emitters and punctual lights light the scene.");
        }
        Some(Sky::Uniform { radiance }) => {
            ui.label("radiance (every direction)");
            colour::rgb_editor(ui, "hex_sky_0", radiance, SKY_MAX, &mut state.hex_sky[0]);
        }
        Some(Sky::Gradient { zenith, horizon }) => {
            ui.label("zenith");
            colour::rgb_editor(ui, "hex_sky_0", zenith, SKY_MAX, &mut state.hex_sky[0]);
            ui.label("horizon (and below)");
            colour::rgb_editor(ui, "hex_sky_1", horizon, SKY_MAX, &mut state.hex_sky[1]);
        }
        Some(Sky::Image(img)) => {
            ui.label(format!("{} ({}×{})", img.path, img.width, img.height));
        }
    }
    ui.small("The sky lights the bake with visibility and takes part in every bounce; an edit re-lights it.");
    if sky != original {
        world.resource_mut::<SceneSky>().0 = sky;
    }
}

fn camera_entity(world: &mut World) -> Option<Entity> {
    let mut q = world.query_filtered::<Entity, With<SceneCamera>>();
    q.iter(world).next()
}

/// One optional effect: a toggle that inserts or removes its component (the render graph
/// recompiles without its passes and textures), and its settings when on.
fn effect<C>(ui: &mut Ui, world: &mut World, camera: Entity, name: &str)
where
    C: Component<Mutability = bevy_ecs::component::Mutable> + Inspect + Copy + Default + PartialEq,
{
    let current = world.get::<C>(camera).copied();
    let mut on = current.is_some();
    if ui.checkbox(&mut on, RichText::new(name).strong()).changed() {
        if on {
            world.entity_mut(camera).insert(C::default());
        } else {
            world.entity_mut(camera).remove::<C>();
        }
        return;
    }
    if let Some(before) = current {
        let mut settings = before;
        ui.indent(name, |ui| {
            if settings.inspect(ui)
                && settings != before
                && let Some(mut slot) = world.get_mut::<C>(camera)
            {
                *slot = settings;
            }
        });
    }
}

/// Post-processing: tone mapping, the debug view, and SSAO, bloom, Sobel and blur as
/// toggles with their settings.
pub fn post_panel(ui: &mut Ui, world: &mut World, _state: &mut InspectorState) {
    let Some(camera) = camera_entity(world) else {
        ui.label("No camera in the world.");
        return;
    };
    ui.label(RichText::new("Tone mapping").strong());
    let mut tm = world
        .get::<Tonemapping>(camera)
        .copied()
        .unwrap_or_default();
    if tm.inspect(ui) {
        world.entity_mut(camera).insert(tm);
    }
    let mut view = world.get::<DebugView>(camera).copied().unwrap_or_default();
    if view.inspect(ui) {
        world.entity_mut(camera).insert(view);
    }
    ui.separator();
    effect::<Ssao>(ui, world, camera, "SSAO");
    effect::<Bloom>(ui, world, camera, "bloom");
    effect::<GaussianBlur>(ui, world, camera, "Gaussian blur");
    effect::<Sobel>(ui, world, camera, "Sobel edges");
}

/// Radiosity: method, patch size and budget (a change rebakes); pause, resume, rebake,
/// cancel; progress, ETA and the stale flag; the estimated error against time.
pub fn radiosity_panel(ui: &mut Ui, world: &mut World, _state: &mut InspectorState) {
    let (Some(mut settings), Some(status), Some(control)) = (
        world.get_resource::<RadiosityBake>().cloned(),
        world.get_resource::<BakeStatus>().cloned(),
        world.get_resource::<BakeControl>().copied(),
    ) else {
        ui.label("No bake in this world (add the bake plugin and a RadiosityBake resource).");
        return;
    };
    let before = settings.params;
    if settings.params.inspect(ui) && settings.params != before {
        world.insert_resource(settings);
        world.resource_mut::<BakeControl>().rebake();
    }
    let paused = control.is_paused();
    ui.horizontal(|ui| {
        let mut control = None;
        if paused {
            if ui.button("resume").clicked() {
                control = Some(BakeControl::resume as fn(&mut BakeControl));
            }
        } else if ui.button("pause").clicked() {
            control = Some(BakeControl::pause);
        }
        if ui.button("rebake").clicked() {
            control = Some(BakeControl::rebake);
        }
        if ui.button("cancel").clicked() {
            control = Some(BakeControl::cancel);
        }
        if let Some(f) = control {
            f(&mut world.resource_mut::<BakeControl>());
        }
    });
    ui.label(format!(
        "{}{}",
        status.phase.name(),
        if status.stale {
            " · stale: an edit is being baked"
        } else {
            ""
        }
    ));
    let eta = (status.estimate.eta_s).map_or_else(String::new, |s| format!(", ETA {s:.1} s"));
    ui.add(
        egui::ProgressBar::new(status.progress.fraction.clamp(0.0, 1.0) as f32)
            .text(format!("{:.0} %{eta}", status.progress.fraction * 100.0)),
    );
    ui.label(format!(
        "{} elements, {} links, {} iterations, est. error {:.2e}{}",
        status.size.elements,
        status.size.links,
        status.progress.iterations,
        status.estimate.error,
        if status.size.resumed {
            ", resumed from checkpoint"
        } else {
            ""
        }
    ));
    if let Some(e) = &status.error {
        ui.colored_label(Color32::from_rgb(230, 60, 50), e.to_string());
    }
    if let Some(w) = &status.warning {
        warn(ui, w.to_string());
    }
    let points: Vec<[f64; 2]> = status
        .history
        .iter()
        .filter(|(t, e)| t.is_finite() && *e > 0.0 && e.is_finite())
        .map(|&(t, e)| [t, e.log10()])
        .collect();
    Plot::new("bake_error_vs_time")
        .height(140.0)
        .x_axis_label("seconds")
        .y_axis_label("est. error")
        .y_axis_formatter(|mark, _| format!("1e{:.0}", mark.value))
        .allow_scroll(false)
        .show(ui, |plot| {
            plot.line(Line::new("estimated error", PlotPoints::from(points)));
        });
    probes_section(ui, world);
}

/// The probe grid that lights dynamic meshes, when the world bakes one: its size, and its
/// probes seen from above (x, z), those inside geometry apart.
fn probes_section(ui: &mut Ui, world: &mut World) {
    let Some(probes) = world.get_resource::<radiant_ecs::probes::BakedProbes>() else {
        return;
    };
    let Some(volume) = probes.volume.clone() else {
        if probes.in_flight {
            ui.label("Probes for dynamic meshes: sampling…");
        }
        return;
    };
    let frame = volume.lighting.frame();
    let spacing = volume.step * frame.scale;
    ui.separator();
    ui.label(format!(
        "Probes for dynamic meshes: {} × {} × {} = {}, {spacing:.3} apart, {} inside geometry, \
         sampled in {:.2} s{}",
        volume.dims[0],
        volume.dims[1],
        volume.dims[2],
        volume.probes.len(),
        volume.inside(),
        probes.seconds,
        if probes.in_flight {
            " (newer ones sampling)"
        } else {
            ""
        }
    ));
    let (mut valid, mut inside) = (Vec::new(), Vec::new());
    for p in &volume.probes {
        let w = frame.to_world(p.position);
        if p.inside() {
            inside.push([w.x, w.z]);
        } else {
            valid.push([w.x, w.z]);
        }
    }
    Plot::new("probe_grid")
        .height(140.0)
        .data_aspect(1.0)
        .x_axis_label("x")
        .y_axis_label("z")
        .allow_scroll(false)
        .show(ui, |plot| {
            plot.points(egui_plot::Points::new("probes", PlotPoints::from(valid)).radius(1.5));
            plot.points(
                egui_plot::Points::new("inside geometry", PlotPoints::from(inside))
                    .radius(1.5)
                    .color(Color32::from_rgb(230, 60, 50)),
            );
        });
}

/// Performance: frame time, per-pass times, and the compiled graph's textures.
pub fn performance_panel(ui: &mut Ui, world: &mut World, state: &mut InspectorState) {
    if let Some(ms) = state.median_frame_ms() {
        ui.label(format!(
            "frame: {ms:.2} ms median over {} frames ({:.0} fps)",
            state.frame_ms.len(),
            1000.0 / ms.max(1e-6)
        ));
    } else {
        ui.label("frame: not measured yet");
    }
    let Some(render) = world.get_resource::<RenderState>() else {
        ui.label("No renderer in this world.");
        return;
    };
    if let Some(t) = &render.timings {
        ui.label(
            RichText::new(if t.gpu {
                "GPU time per pass"
            } else {
                "CPU time per pass"
            })
            .strong(),
        );
        egui::Grid::new("pass_timings")
            .striped(true)
            .show(ui, |ui| {
                let mut total = 0.0;
                for (name, ms) in &t.passes {
                    ui.label(*name);
                    ui.label(format!("{ms:.3} ms"));
                    ui.end_row();
                    total += ms;
                }
                ui.label(RichText::new("total").strong());
                ui.label(format!("{total:.3} ms"));
                ui.end_row();
            });
    }
    if let Some(a) = &render.atlas {
        ui.label(format!(
            "light map: {} × {}×{} texels, {} charts, {:.0} % inside charts, {:.1} texels/m",
            a.pages,
            a.width,
            a.height,
            a.charts,
            a.utilisation * 100.0,
            a.texel_density
        ));
    }
    if let Some(g) = render.graph() {
        ui.label(format!(
            "graph: {} passes ({} culled), {} textures in {} allocations, {:.1} MiB",
            g.passes.len(),
            g.culled.len(),
            g.virtual_textures,
            g.physical_textures.len(),
            g.bytes as f64 / (1024.0 * 1024.0)
        ));
    }
    if let Some(e) = &render.error {
        ui.colored_label(Color32::from_rgb(230, 60, 50), e.to_string());
    }
}
