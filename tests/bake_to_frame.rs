//! A bake drawn by the renderer: the frame's radiance equals the baked radiosity, and punctual
//! lights (baked with their shadows) are not added a second time. Runs on the test command's
//! GPU adapter (lavapipe in CI).
#![cfg(feature = "render")]

use glam::DVec3;
use radiant::post::frame::{FrameRenderer, FrameSettings};
use radiant::radiosity::scenes::{add_surface, quad};
use radiant::radiosity::{Bake, BakeParams};
use radiant::render::GpuContext;
use radiant::scene::{Camera, Light, LightKind, Scene};

#[test]
fn a_lamp_over_a_floor_is_drawn_once() {
    let gpu = GpuContext::headless().unwrap_or_else(|e| {
        panic!("GPU tests need an adapter: {e}. Run tools/test.sh, which installs lavapipe.")
    });
    let rho = 153.0 / 255.0; // stored exactly by the 8-bit G-buffer
    let mut scene = Scene::default();
    let floor = quad(
        DVec3::new(-1.0, 0.0, 1.0),
        DVec3::new(2.0, 0.0, 0.0),
        DVec3::new(0.0, 0.0, -2.0),
    );
    add_surface(&mut scene, "floor", [rho; 3], [0.0; 3], &floor);
    scene.lights.push(Light {
        name: "lamp".into(),
        kind: LightKind::Point,
        position: DVec3::new(0.0, 1.0, 0.0),
        direction: DVec3::NEG_Y,
        color: [1.0; 3],
        intensity: 2.0,
        range: None,
    });
    scene.camera = Some(Camera {
        position: DVec3::new(0.0, 2.0, 0.0),
        forward: DVec3::NEG_Y,
        up: DVec3::NEG_Z,
        yfov: 0.6,
    });
    let mut params = BakeParams::default();
    params.mesh.patch_size = 0.25;
    let bake = Bake::new(&scene, &params)
        .expect("bake")
        .run_to_end(&mut |_| {})
        .expect("solve");
    let rs = radiant::bridge::render_scene(&scene, Some(&bake), 64).expect("render scene");
    assert!(rs.lights.is_empty(), "the baked lamp would be drawn twice");
    let mut frame = FrameRenderer::new(&gpu, &rs).expect("renderer");
    let c = frame
        .capture(&gpu, 65, 65, &FrameSettings::MINIMAL)
        .expect("capture");
    // Straight below the lamp: B = ρ E / π with E = I / d².
    let want = rho * 2.0 / std::f64::consts::PI;
    let got = f64::from(c.hdr.at(32, 32)[0]);
    assert!(
        (got - want).abs() < 0.03 * want,
        "radiance under the lamp {got}, bake says {want}"
    );
}
