//! The inspector's panels driven headlessly with egui_kittest: a widget is moved the way a user
//! moves it (mouse drags and clicks, typed text), and the ECS value must change; every panel
//! is also compared with a snapshot image rendered by egui-wgpu on the test adapter (lavapipe
//! in CI).
//!
//! Snapshot threshold: egui_kittest's per-pixel YIQ distance 0.6 (its default), with at most
//! 16 pixels over it: lavapipe renders these panels bit-identically from run to run, so the
//! allowance only absorbs font rasterisation changes across Mesa versions. Regenerate with
//! `UPDATE_SNAPSHOTS=1 cargo test -p radiant_inspector`.

use bevy_ecs::prelude::*;
use egui_kittest::kittest::Queryable;
use egui_kittest::{Harness, SnapshotOptions};
use glam::DVec3;
use radiant_ecs::bake::{BakeControl, BakePhase, BakeStatus, RadiosityBake};
use radiant_ecs::prelude::{App, RadiantPlugins, spawn_scene};
use radiant_ecs::render::{Bloom, RenderState, Ssao, Tonemapping};
use radiant_ecs::scene::{Material, PunctualLight, SceneCamera, Transform};
use radiant_inspector::{InspectorState, Tab, tab_ui};
use radiant_radiosity::SolverKind;

struct State {
    world: World,
    inspector: InspectorState,
}

/// The Cornell box in a world with the bake's resources (the bake itself never runs: no
/// update is stepped, so the panels are deterministic), a spot light, and the default effects
/// on the camera.
fn world() -> World {
    let mut app = App::new();
    app.add_plugins(RadiantPlugins)
        .insert_resource(RadiosityBake::default())
        .init_resource::<RenderState>();
    let scene = radiant_scene::builtin("cornell-box").expect("builtin scene");
    spawn_scene(&mut app.world, &scene);
    app.world.spawn((
        Name::new("spot"),
        Transform::IDENTITY,
        PunctualLight(radiant_scene::Light {
            name: "spot".into(),
            kind: radiant_scene::LightKind::Spot {
                inner_cone_angle: 0.3,
                outer_cone_angle: 0.6,
            },
            position: DVec3::new(0.28, 0.5, 0.28),
            direction: DVec3::NEG_Y,
            color: [1.0, 0.9, 0.8],
            intensity: 2.0,
            range: Some(3.0),
        }),
    ));
    let cam = camera(&mut app.world);
    app.world
        .entity_mut(cam)
        .insert((Bloom::default(), Ssao::default(), Tonemapping::default()));
    app.world
}

fn camera(world: &mut World) -> Entity {
    let mut q = world.query_filtered::<Entity, With<SceneCamera>>();
    q.iter(world).next().expect("the Cornell box has a camera")
}

fn harness(tab: Tab) -> Harness<'static, State> {
    let state = State {
        world: world(),
        inspector: InspectorState {
            tab,
            ..Default::default()
        },
    };
    Harness::builder().with_size([440.0, 620.0]).build_ui_state(
        |ui, s: &mut State| tab_ui(ui, &mut s.world, &mut s.inspector),
        state,
    )
}

fn snapshot(h: &mut Harness<'_, State>, name: &str) {
    h.snapshot_options(
        name,
        &SnapshotOptions::new().threshold(0.6).max_failed_pixels(16),
    );
}

/// Clicks into the `nth` text field labelled "sRGB", selects all and types `text`, like a
/// user would.
fn type_hex(h: &mut Harness<'_, State>, nth: usize, text: &str) {
    let field = |h: &Harness<'_, State>| {
        h.get_all_by_role_and_label(egui::accesskit::Role::TextInput, "sRGB")
            .nth(nth)
            .expect("an sRGB hex field")
            .rect()
    };
    let r = field(h);
    h.hover_at(r.center());
    h.drag_at(r.center());
    h.drop_at(r.center());
    h.run();
    h.key_combination_modifiers(egui::Modifiers::COMMAND, &[egui::Key::A]);
    h.run();
    h.get_all_by_role_and_label(egui::accesskit::Role::TextInput, "sRGB")
        .nth(nth)
        .expect("an sRGB hex field")
        .type_text(text);
    h.run();
}

/// Drags the handle of the slider labelled `label` by `dx` points, like a mouse would.
fn drag_slider(h: &mut Harness<'_, State>, label: &str, dx: f32) {
    let rect = h
        .get_by_role_and_label(egui::accesskit::Role::Slider, label)
        .rect();
    let start = egui::pos2(rect.center().x, rect.center().y);
    h.hover_at(start);
    h.run();
    h.drag_at(start);
    h.run();
    h.hover_at(start + egui::vec2(dx, 0.0));
    h.run();
    h.drop_at(start + egui::vec2(dx, 0.0));
    h.run();
}

#[test]
fn colour_panel_edits_the_material() {
    let mut h = harness(Tab::Colour);
    h.run();
    snapshot(&mut h, "colour_panel");
    let entity = h.state().inspector.surface.expect("a surface is selected");
    let before = *h.state().world.get::<Material>(entity).expect("material");

    // Type a new sRGB hex code into the base colour's field (the first "sRGB" text input).
    let hex = radiant_inspector::colour::to_hex(before.reflectance);
    let field = h
        .get_all_by_role_and_label(egui::accesskit::Role::TextInput, "sRGB")
        .next()
        .expect("hex field");
    assert_eq!(field.value().as_deref(), Some(hex.as_str()));
    type_hex(&mut h, 0, "#336699");
    let after = *h.state().world.get::<Material>(entity).expect("material");
    let want = radiant_inspector::colour::from_hex("#336699").expect("hex");
    for c in 0..3 {
        assert!(
            (after.reflectance[c] - want[c]).abs() < 1e-9,
            "{:?} vs {want:?}",
            after.reflectance
        );
    }
    assert_eq!(after.emission, before.emission, "emission untouched");
}

#[test]
fn chromaticity_click_outside_srgb_is_ringed_and_mapped() {
    let mut h = harness(Tab::Colour);
    h.run();
    let entity = h.state().inspector.surface.expect("selected");
    // The diagram is the last 260-point square; click near 520 nm green, outside sRGB.
    let label = h.get_by_label("CIE 1931 xy: click to set the base colour's chromaticity");
    let top = label.rect().bottom() + 4.0;
    let left = label.rect().left();
    // Inside the diagram's frame (24 px left margin, 6 px top, 20 px bottom): x = 0.08, y = 0.80.
    let frame_w = 260.0 - 30.0;
    let frame_h = 260.0 - 26.0;
    let p = egui::pos2(
        left + 24.0 + 0.08 / 0.8 * frame_w,
        top + 6.0 + (1.0 - 0.80 / 0.9) * frame_h,
    );
    h.hover_at(p);
    h.run();
    h.drag_at(p);
    h.run();
    h.drop_at(p);
    h.run();
    let (xy, rgb) = h.state().inspector.picked_xy.expect("picked outside sRGB");
    assert!(!radiant_inspector::colour::in_srgb_gamut(xy), "{xy:?}");
    let m = *h.state().world.get::<Material>(entity).expect("material");
    assert_eq!(m.reflectance, rgb);
    assert!(m.reflectance[1] > m.reflectance[0] && m.reflectance[1] > m.reflectance[2]);
    snapshot(&mut h, "colour_panel_out_of_gamut");
}

#[test]
fn lights_panel_edits_colour_temperature_and_cones() {
    let mut h = harness(Tab::Lights);
    h.run();
    snapshot(&mut h, "lights_panel");
    h.get_by_label("tungsten").click();
    h.run();
    let light = {
        let w = &mut h.state_mut().world;
        let mut q = w.query::<&PunctualLight>();
        q.iter(w).next().expect("light").0.clone()
    };
    let (_, want) = radiant_color::cie::blackbody_color(2856.0).expect("colour");
    assert_eq!(light.color, want);
    drag_slider(&mut h, "outer cone (°)", 40.0);
    let w = &mut h.state_mut().world;
    let mut q = w.query::<&PunctualLight>();
    let l = q.iter(w).next().expect("light").0.clone();
    let radiant_scene::LightKind::Spot {
        inner_cone_angle,
        outer_cone_angle,
    } = l.kind
    else {
        panic!("still a spot light");
    };
    assert!(outer_cone_angle > 0.6 + 1e-3, "{outer_cone_angle}");
    assert!(inner_cone_angle < outer_cone_angle);
}

#[test]
fn sky_panel_switches_kinds_and_edits_the_sky_resource() {
    use radiant_ecs::scene::SceneSky;
    use radiant_scene::Sky;
    let mut h = harness(Tab::Sky);
    h.run();
    assert_eq!(h.state().world.resource::<SceneSky>().0, None);
    h.get_by_label("uniform").click();
    h.run();
    assert_eq!(
        h.state().world.resource::<SceneSky>().0,
        Some(Sky::Uniform {
            radiance: [0.4, 0.6, 1.0]
        })
    );
    // Uniform to gradient keeps the colour at both ends.
    h.get_by_label("gradient").click();
    h.run();
    snapshot(&mut h, "sky_panel");
    assert_eq!(
        h.state().world.resource::<SceneSky>().0,
        Some(Sky::Gradient {
            zenith: [0.4, 0.6, 1.0],
            horizon: [0.4, 0.6, 1.0]
        })
    );
    // The horizon's sRGB hex field, typed as a user would.
    type_hex(&mut h, 1, "#ffffff");
    let Some(Sky::Gradient { zenith, horizon }) = h.state().world.resource::<SceneSky>().0.clone()
    else {
        panic!("still a gradient");
    };
    assert_eq!(zenith, [0.4, 0.6, 1.0]);
    assert!(
        horizon.iter().all(|&c| (c - 1.0).abs() < 1e-9),
        "{horizon:?}"
    );
    h.get_by_label("none").click();
    h.run();
    assert_eq!(h.state().world.resource::<SceneSky>().0, None);
}

#[test]
fn post_panel_slider_and_toggles_write_components() {
    let mut h = harness(Tab::Post);
    h.run();
    snapshot(&mut h, "post_panel");
    let cam = camera(&mut h.state_mut().world);
    let ev0 = h
        .state()
        .world
        .get::<Tonemapping>(cam)
        .expect("tm")
        .exposure;
    drag_slider(&mut h, "exposure (EV)", 60.0);
    let ev1 = h
        .state()
        .world
        .get::<Tonemapping>(cam)
        .expect("tm")
        .exposure;
    assert!(ev1 > ev0 + 0.1, "exposure {ev0} → {ev1}");

    // Toggling bloom off removes the component (the graph then culls its passes).
    h.get_by_label("bloom").click();
    h.run();
    assert!(h.state().world.get::<Bloom>(cam).is_none());
    h.get_by_label("bloom").click();
    h.run();
    assert!(h.state().world.get::<Bloom>(cam).is_some());
    // And Sobel on.
    h.get_by_label("Sobel edges").click();
    h.run();
    assert!(
        h.state()
            .world
            .get::<radiant_ecs::render::Sobel>(cam)
            .is_some()
    );
}

#[test]
fn radiosity_panel_controls_the_bake() {
    let mut h = harness(Tab::Radiosity);
    {
        let mut s = h.state_mut().world.resource_mut::<BakeStatus>();
        s.phase = BakePhase::Solving;
        s.progress.fraction = 0.42;
        s.estimate.eta_s = Some(1.5);
        s.size.elements = 15488;
        s.size.links = 6_100_000;
        s.progress.iterations = 12;
        s.estimate.error = 3.2e-3;
        s.stale = true;
        s.history = (0..40)
            .map(|i| (f64::from(i) * 0.05, 0.5 * 0.8f64.powi(i)))
            .collect();
    }
    h.run();
    snapshot(&mut h, "radiosity_panel");
    h.get_by_label("pause").click();
    h.run();
    assert!(h.state().world.resource::<BakeControl>().is_paused());
    h.get_by_label("resume").click();
    h.run();
    assert!(!h.state().world.resource::<BakeControl>().is_paused());

    // Choosing another solver writes the settings.
    h.get_by_label("solver").click();
    h.run();
    h.get_by_label("southwell").click();
    h.run();
    assert_eq!(
        h.state().world.resource::<RadiosityBake>().params.solver,
        SolverKind::Southwell
    );
}

/// With probes for dynamic meshes in the world, the radiosity tab shows their grid.
#[test]
fn radiosity_panel_shows_the_probe_grid() {
    use radiant_probes::{ProbeParams, ProbeVolume, Solved, VolumeParams};
    let scene = radiant_scene::builtin("cornell-box").expect("builtin scene");
    let mut params = radiant_radiosity::BakeParams::default();
    params.mesh.patch_size = 0.3;
    let result = radiant_radiosity::Bake::new(&scene, &params)
        .expect("bake")
        .run_to_end(&mut |_| {})
        .expect("solve");
    let solved = Solved::new(&scene, &result);
    let probe = ProbeParams {
        strata: 4,
        ..ProbeParams::default()
    };
    let volume = ProbeVolume::bake(
        &solved.baker(&scene, &result.mesh, probe),
        &VolumeParams {
            spacing: Some(0.12),
            ..VolumeParams::default()
        },
    );
    let count = volume.probes.len();
    let mut h = harness(Tab::Radiosity);
    h.state_mut()
        .world
        .insert_resource(radiant_ecs::probes::BakedProbes {
            generation: 1,
            volume: Some(std::sync::Arc::new(volume)),
            seconds: 0.5,
            published: 1,
            ..Default::default()
        });
    h.run();
    let label = format!("= {count},");
    assert!(
        h.query_by_label_contains("Probes for dynamic meshes")
            .is_some()
            && h.query_by_label_contains(&label).is_some(),
        "no probe grid of {count} probes in the panel"
    );
}

#[test]
fn performance_panel_shows_timings() {
    let mut h = harness(Tab::Performance);
    for ms in [16.0, 17.0, 15.0] {
        h.state_mut().inspector.record_frame(ms);
    }
    h.state_mut().world.resource_mut::<RenderState>().timings =
        Some(radiant_render::graph::PassTimings {
            passes: vec![("gbuffer_pass", 1.25), ("lighting_pass", 2.5)],
            gpu: true,
        });
    h.run();
    h.get_by_label_contains("frame: 16.00 ms median over 3 frames");
    h.get_by_label("3.750 ms");
    snapshot(&mut h, "performance_panel");
    h.state_mut().world.resource_mut::<RenderState>().atlas =
        Some(radiant_ecs::render::AtlasReport {
            width: 224,
            height: 224,
            pages: 1,
            charts: 41,
            utilisation: 0.32,
            texel_density: 123.4,
        });
    h.run();
    h.get_by_label_contains(
        "light map: 1 × 224×224 texels, 41 charts, 32 % inside charts, 123.4 texels/m",
    );
}

#[test]
fn looking_at_a_panel_writes_nothing() {
    // Values a widget cannot show in its range (glTF's default white reflectance 1.0, a time
    // budget over the slider's hour) must not be clamped and written back just by being shown:
    // that would rebake every frame.
    for tab in Tab::ALL {
        let mut h = harness(tab);
        {
            let w = &mut h.state_mut().world;
            let mut q = w.query::<&mut Material>();
            for mut m in q.iter_mut(w) {
                m.reflectance = [1.0; 3];
            }
            w.resource_mut::<RadiosityBake>().params.time_limit =
                Some(std::time::Duration::from_secs(4000));
            w.clear_trackers();
        }
        h.run_steps(5);
        let w = &mut h.state_mut().world;
        let changed_materials = w.query_filtered::<(), Changed<Material>>().iter(w).count();
        let changed_lights = w
            .query_filtered::<(), Changed<PunctualLight>>()
            .iter(w)
            .count();
        let changed_camera = w
            .query_filtered::<(), Or<(
                Changed<Tonemapping>,
                Changed<Bloom>,
                Changed<Ssao>,
                Changed<radiant_ecs::render::DebugView>,
            )>>()
            .iter(w)
            .count();
        assert_eq!(
            (changed_materials, changed_lights, changed_camera),
            (0, 0, 0),
            "{tab:?} wrote without input"
        );
        assert!(
            !w.is_resource_changed::<RadiosityBake>(),
            "{tab:?} rewrote the bake settings"
        );
        assert!(
            !w.is_resource_changed::<radiant_ecs::scene::SceneSky>(),
            "{tab:?} rewrote the sky"
        );
        assert!(!w.resource::<BakeControl>().is_paused());
    }
}
