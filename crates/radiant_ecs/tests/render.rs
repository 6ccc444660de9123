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

/// A world's frame shows the light map the bake writes: a black box on a floor under a low
/// sun, with elements as coarse as a level's (half a metre), casts a shadow as sharp as the
/// texels once the light map's basis is made: at once (a small map), or in the background
/// (`basis_at_once: 0`), the frames drawing the elements' light until then.
#[test]
fn the_worlds_frame_shows_a_sharp_sun_shadow_whatever_the_elements() {
    for at_once in [radiant_ecs::render::BASIS_AT_ONCE, 0] {
        sharp_sun_shadow(at_once);
    }
}

fn sharp_sun_shadow(at_once: u64) {
    use glam::DVec3;
    use radiant_radiosity::scenes::{add_surface, box_triangles, quad};
    use radiant_scene::{Camera, Light, LightKind, Scene};
    radiant_render::GpuContext::headless().unwrap_or_else(|e| {
        panic!("GPU tests need an adapter: {e}. Run tools/test.sh, which installs lavapipe.")
    });
    let rho = 153.0 / 255.0; // stored exactly by the 8-bit G-buffer
    let mut scene = Scene::default();
    let floor = quad(
        DVec3::new(-1.0, 0.0, 1.0),
        DVec3::X * 2.0,
        DVec3::NEG_Z * 2.0,
    );
    add_surface(&mut scene, "floor", [rho; 3], [0.0; 3], &floor);
    let (lo, hi) = (DVec3::new(-0.3, 0.0, -0.3), DVec3::new(0.3, 0.4, 0.3));
    add_surface(
        &mut scene,
        "box",
        [0.0; 3],
        [0.0; 3],
        &box_triangles(lo, hi, false),
    );
    let direction = DVec3::new(1.0, -2.0, 0.0).normalize();
    scene.lights.push(Light {
        name: "sun".into(),
        kind: LightKind::Directional,
        position: DVec3::ZERO,
        direction,
        color: [1.0; 3],
        intensity: std::f64::consts::PI / -direction.y,
        range: None,
    });
    let (height, tan) = (3.0, 0.3f64.tan());
    scene.camera = Some(Camera {
        position: DVec3::new(0.0, height, 0.0),
        forward: DVec3::NEG_Y,
        up: DVec3::NEG_Z,
        yfov: 0.6,
    });
    let n = 129;
    let mut app = App::new();
    app.add_plugins(RadiantPlugins)
        .add_plugins(RenderPlugin)
        .insert_resource(RenderSettings {
            size: (n, n),
            texel_density: Some(64.0),
            capture: true,
            basis_at_once: at_once,
            ..RenderSettings::default()
        });
    let mut params = BakeParams::default();
    params.mesh.patch_size = 0.5;
    params.mesh.element_levels = 0;
    app.insert_resource(RadiosityBake {
        params,
        ..RadiosityBake::default()
    });
    spawn_scene(&mut app.world, &scene);
    let t = std::time::Instant::now();
    app.run_until(u64::MAX, Duration::from_millis(1), |w| {
        (w.resource::<BakeStatus>().phase == BakePhase::Converged
            && !w.resource::<BakeStatus>().stale
            && w.resource::<RenderState>().light_map_per_texel())
            || t.elapsed() > Duration::from_secs(60)
    });
    app.update();
    assert!(
        app.world.resource::<RenderState>().light_map_per_texel(),
        "at once up to {at_once} texels: no per-texel light map after {:?}",
        t.elapsed()
    );
    let img = app
        .world
        .resource::<LastFrame>()
        .hdr
        .clone()
        .expect("captured");
    let (mut lit, mut shade, mut wrong) = (0, 0, Vec::new());
    for j in 0..n {
        for i in 0..n {
            let ndc = |k: u32| (f64::from(k) + 0.5) / f64::from(n) * 2.0 - 1.0;
            let (x, z) = (ndc(i) * tan * height, ndc(j) * tan * height);
            // Off the box's footprint by more than its top's overhang, inside the floor, and
            // two texels or more from the shadow's edge (x = 0.5).
            let off_box = (lo.x - x).max(x - hi.x).max((lo.z - z).max(z - hi.z));
            let off_shadow = (lo.x - x)
                .max(x - (hi.x + 0.2))
                .max((lo.z - z).max(z - hi.z));
            if off_box < 0.075 || x.abs() > 0.95 || z.abs() > 0.95 || off_shadow.abs() < 0.03 {
                continue;
            }
            let got = f64::from(img.texels[(j * n + i) as usize][0]);
            let ok = if off_shadow > 0.0 {
                lit += 1;
                (got - rho).abs() <= 0.03 * rho
            } else {
                shade += 1;
                got <= 0.03 * rho
            };
            if !ok {
                wrong.push((x, z, got));
            }
        }
    }
    assert!(
        lit > 5000 && shade > 150,
        "{lit} lit, {shade} shaded pixels"
    );
    assert!(
        wrong.is_empty(),
        "{} of {} floor pixels wrong: {:?}",
        wrong.len(),
        lit + shade,
        &wrong[..wrong.len().min(6)]
    );
}

/// A mesh without [`Static`] is dynamic: left out of the bake, and drawn lit by the probes
/// that follow it once they are published (black in the light map before: no chart).
#[test]
fn a_dynamic_mesh_is_lit_by_the_probes_once_they_follow_the_bake() {
    let mut app = app(true);
    app.insert_resource(ProbeVolumeBake::default());
    let block: Vec<Entity> = app
        .world
        .query::<(Entity, &Name)>()
        .iter(&app.world)
        .filter(|(_, n)| n.as_str().starts_with("tall_block"))
        .map(|(e, _)| e)
        .collect();
    assert_eq!(block.len(), 5);
    for e in block {
        app.world.entity_mut(e).remove::<Static>();
    }
    let cam = camera(&mut app);
    app.world.entity_mut(cam).insert(DebugView::LightMap);
    let t = std::time::Instant::now();
    app.run_until(u64::MAX, Duration::from_millis(1), |w| {
        let p = w.resource::<BakedProbes>();
        (w.resource::<BakeStatus>().phase == BakePhase::Converged
            && !w.resource::<BakeStatus>().stale
            && p.generation == w.resource::<BakedLighting>().generation
            && !p.in_flight)
            || t.elapsed() > Duration::from_secs(90)
    });
    assert!(
        app.world.resource::<BakedProbes>().harmonics.is_some(),
        "no probes in 90 s"
    );
    app.update();
    let frame = |app: &App| {
        app.world
            .resource::<LastFrame>()
            .hdr
            .clone()
            .expect("captured")
    };
    let img = frame(&app);
    // The block's front face, mid-height (the builtin camera at 64 × 64).
    for (x, y) in [(24u32, 42u32), (20, 36), (28, 48)] {
        let px = img.texels[(y * img.width + x) as usize];
        assert!(
            px[..3].iter().all(|&v| v > 0.005),
            "({x}, {y}) not lit by the probes: {px:?}"
        );
    }
    // Moved as a game moves it: drawn where it went, with no rebake and no new atlas.
    let generation = app.world.resource::<BakedLighting>().generation;
    let atlases = app.world.resource::<RenderState>().atlases;
    assert_eq!(
        move_dynamic(&mut app.world, glam::DVec3::new(0.15, 0.0, 0.0)),
        5
    );
    app.update();
    app.update();
    let moved = frame(&app);
    let changed = img
        .texels
        .iter()
        .zip(&moved.texels)
        .filter(|(a, b)| (a[0] - b[0]).abs() > 1e-3)
        .count();
    assert!(changed > 100, "{changed} pixels changed");
    let status = app.world.resource::<BakeStatus>();
    assert!(status.phase == BakePhase::Converged && !status.stale);
    assert_eq!(
        app.world.resource::<BakedLighting>().generation,
        generation,
        "a dynamic mesh's move is not a rebake"
    );
    assert_eq!(
        app.world.resource::<RenderState>().atlases,
        atlases,
        "a dynamic mesh's move keeps the atlas"
    );
}
