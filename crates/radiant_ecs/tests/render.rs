//! The render extraction on a real adapter (lavapipe in CI): effect components decide the
//! frame's passes, and the bake's light reaches the frame. With no adapter these tests fail with
//! the install hint.
#![cfg(feature = "render")]

use std::time::Duration;

use radiant_ecs::prelude::*;
use radiant_radiosity::BakeParams;

fn app(bake: bool) -> App {
    radiant_render::GpuContext::headless().unwrap_or_else(|e| {
        panic!("GPU tests need an adapter: {e}. Run tools/test.sh, which installs lavapipe.")
    });
    let mut app = App::new();
    app.add_plugins(RadiantPlugins)
        .add_plugins(RenderPlugin)
        .insert_resource(RenderSettings {
            size: (64, 64),
            texel_density: Some(40.0),
            capture: true,
            ..RenderSettings::default()
        });
    if bake {
        let mut params = BakeParams::default();
        params.mesh.patch_size = 0.3;
        app.insert_resource(RadiosityBake {
            params,
            ..RadiosityBake::default()
        });
    }
    spawn_scene(
        &mut app.world,
        &radiant_scene::builtin("cornell-box").expect("builtin"),
    );
    app
}

fn camera(app: &mut App) -> Entity {
    app.world
        .query_filtered::<Entity, With<SceneCamera>>()
        .iter(&app.world)
        .next()
        .expect("a camera")
}

fn passes(app: &App) -> Vec<&'static str> {
    let state = app.world.resource::<RenderState>();
    assert!(state.error.is_none(), "{:?}", state.error);
    state.graph().expect("a frame was drawn").passes.clone()
}

#[test]
fn effect_components_decide_the_frames_passes() {
    let mut app = app(false);
    app.update();
    assert_eq!(
        passes(&app),
        vec!["gbuffer_pass", "lighting_pass", "tonemapping_pass"]
    );
    let cam = camera(&mut app);
    app.world
        .entity_mut(cam)
        .insert((Bloom::default(), Ssao::default()));
    app.update();
    let p = passes(&app);
    assert!(
        p.contains(&"ssao_pass") && p.contains(&"bloom_composite_pass"),
        "{p:?}"
    );
    app.world.entity_mut(cam).remove::<Bloom>();
    app.update();
    let p = passes(&app);
    assert!(
        p.contains(&"ssao_pass") && !p.iter().any(|n| n.starts_with("bloom")),
        "{p:?}"
    );
    app.world.entity_mut(cam).insert(Sobel::default());
    app.update();
    assert!(passes(&app).contains(&"sobel_pass"));
}

#[test]
fn the_baked_light_reaches_the_frame() {
    let mut app = app(true);
    let mean = |app: &App| {
        let img = app
            .world
            .resource::<LastFrame>()
            .hdr
            .clone()
            .expect("captured");
        img.texels
            .iter()
            .map(|t| f64::from(t[0] + t[1] + t[2]))
            .sum::<f64>()
            / img.texels.len() as f64
    };
    let cam = camera(&mut app);
    app.world.entity_mut(cam).insert(DebugView::LightMap);
    // The first frame starts the bake; nothing is published yet, so the light map is black.
    app.update();
    let before = mean(&app);
    let t = std::time::Instant::now();
    app.run_until(u64::MAX, Duration::from_millis(1), |w| {
        (w.resource::<BakeStatus>().phase == BakePhase::Converged
            && !w.resource::<BakeStatus>().stale)
            || t.elapsed() > Duration::from_secs(60)
    });
    app.update();
    let after = mean(&app);
    let state = app.world.resource::<RenderState>();
    assert!(state.uploads >= 2, "{} light maps uploaded", state.uploads);
    assert!(before < 1e-6, "light map before the bake: {before}");
    assert!(after > 0.05, "light map after the bake: {after}");
}

#[test]
fn extraction_uploads_only_what_changed() {
    let mut app = app(false);
    app.update();
    let uploads = |app: &App| app.world.resource::<RenderState>().uploads;
    assert_eq!(uploads(&app), 1);
    // The inspector's figures of the uploaded light map's atlas.
    let atlas = app.world.resource::<RenderState>().atlas.expect("an atlas");
    assert!(
        atlas.width > 0 && atlas.charts > 0 && atlas.utilisation > 0.0 && atlas.texel_density > 0.0
    );
    let first = app
        .world
        .resource::<LastFrame>()
        .ldr
        .clone()
        .expect("frame");
    // Steady frames and a camera move upload nothing; the move still changes the image.
    app.update();
    let cam = camera(&mut app);
    app.world
        .get_mut::<SceneCamera>(cam)
        .expect("camera")
        .0
        .position
        .x += 0.05;
    app.update();
    assert_eq!(uploads(&app), 1, "a camera move re-uploaded the scene");
    let moved = app
        .world
        .resource::<LastFrame>()
        .ldr
        .clone()
        .expect("frame");
    assert_ne!(
        first.texels, moved.texels,
        "the camera move did not reach the frame"
    );
    // A material edit and a despawned surface upload the scene again.
    let mut q = app.world.query::<(Entity, &radiant_ecs::scene::Material)>();
    let (wall, _) = q.iter(&app.world).next().expect("a surface");
    app.world
        .get_mut::<radiant_ecs::scene::Material>(wall)
        .expect("material")
        .reflectance = [0.1, 0.2, 0.3];
    app.update();
    assert_eq!(uploads(&app), 2);
    app.world.despawn(wall);
    app.update();
    assert_eq!(uploads(&app), 3);
    app.update();
    assert_eq!(uploads(&app), 3);
    // A new sky is uploaded too.
    app.world.resource_mut::<radiant_ecs::scene::SceneSky>().0 =
        Some(radiant_scene::Sky::Uniform {
            radiance: [0.0, 0.0, 4.0],
        });
    app.update();
    assert_eq!(uploads(&app), 4);
    let error = &app.world.resource::<RenderState>().error;
    assert!(error.is_none(), "{error:?}");
}

#[test]
fn an_empty_world_renders_nothing_and_reports_no_error() {
    radiant_render::GpuContext::headless().unwrap_or_else(|e| {
        panic!("GPU tests need an adapter: {e}. Run tools/test.sh, which installs lavapipe.")
    });
    let mut app = App::new();
    app.add_plugins(RadiantPlugins).add_plugins(RenderPlugin);
    for _ in 0..3 {
        app.update();
    }
    let state = app.world.resource::<RenderState>();
    assert_eq!((state.frames, state.uploads), (0, 0));
    assert!(state.error.is_none(), "{:?}", state.error);
}
