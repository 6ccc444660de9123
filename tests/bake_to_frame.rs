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
    let rs = radiant::bridge::render_scene(&scene, Some(&bake), None).expect("render scene");
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

/// A black box standing on a floor under a low sun, drawn from above: the frame shows the
/// light map the bake writes (the sun per texel), so the box's shadow on the floor is sharp
/// where the geometry puts it, however coarse the elements (half a metre, as a level's).
#[test]
fn a_box_casts_a_sharp_sun_shadow_in_the_frame_whatever_the_elements() {
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
    let (lo, hi) = (DVec3::new(-0.3, 0.0, -0.3), DVec3::new(0.3, 0.4, 0.3));
    let cube = radiant::radiosity::scenes::box_triangles(lo, hi, false);
    add_surface(&mut scene, "box", [0.0; 3], [0.0; 3], &cube);
    // Down and towards +x, 2 : 1: the top's edge at x = 0.3 shades the floor to x = 0.5. Its
    // illuminance on the floor is π, so the lit floor has H = 1.
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
    let mut params = BakeParams::default();
    params.mesh.patch_size = 0.5;
    params.mesh.element_levels = 0;
    let bake = Bake::new(&scene, &params)
        .expect("bake")
        .run_to_end(&mut |_| {})
        .expect("solve");
    let rs = radiant::bridge::render_scene(&scene, Some(&bake), Some(64.0)).expect("render scene");
    let mut frame = FrameRenderer::new(&gpu, &rs).expect("renderer");
    let n = 129;
    let c = frame
        .capture(&gpu, n, n, &FrameSettings::MINIMAL)
        .expect("capture");
    let (mut lit, mut shade, mut wrong) = (0, 0, Vec::new());
    for j in 0..n {
        for i in 0..n {
            let ndc = |k: u32| (f64::from(k) + 0.5) / f64::from(n) * 2.0 - 1.0;
            let (x, z) = (ndc(i) * tan * height, ndc(j) * tan * height);
            // Off the box's footprint by more than its top's overhang in perspective (4.3 cm),
            // inside the floor, and two texels (3 cm) or more from the shadow's edge.
            let off_box = (lo.x - x).max(x - hi.x).max((lo.z - z).max(z - hi.z));
            let off_shadow = (lo.x - x)
                .max(x - (hi.x + 0.2))
                .max((lo.z - z).max(z - hi.z));
            if off_box < 0.075 || x.abs() > 0.95 || z.abs() > 0.95 || off_shadow.abs() < 0.03 {
                continue;
            }
            let got = f64::from(c.hdr.at(i, j)[0]);
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
        "{lit} lit and {shade} shaded pixels checked"
    );
    assert!(
        wrong.is_empty(),
        "{} of {} floor pixels wrong: {:?}",
        wrong.len(),
        lit + shade,
        &wrong[..wrong.len().min(6)]
    );
}

/// The light map's `H` at `uv`, bilinear as the renderer samples it (clamped at the edges).
fn sample(lm: &radiant::render::scene::LightMap, uv: [f32; 2]) -> [f64; 3] {
    let (w, h) = (lm.width as f32, lm.height as f32);
    let (x, y) = (uv[0] * w - 0.5, uv[1] * h - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (f64::from(x - x0), f64::from(y - y0));
    let at = |i: f32, j: f32| {
        let (i, j) = (
            (i as i64).clamp(0, lm.width as i64 - 1),
            (j as i64).clamp(0, lm.height as i64 - 1),
        );
        lm.texels[(j * i64::from(lm.width) + i) as usize].map(f64::from)
    };
    let (a, b, c, d) = (
        at(x0, y0),
        at(x0 + 1.0, y0),
        at(x0, y0 + 1.0),
        at(x0 + 1.0, y0 + 1.0),
    );
    std::array::from_fn(|k| {
        (a[k] * (1.0 - fx) + b[k] * fx) * (1.0 - fy) + (c[k] * (1.0 - fx) + d[k] * fx) * fy
    })
}

#[test]
fn cornell_light_map_texels_match_mitsuba_and_agree_across_shared_edges() {
    use radiant::radiosity::metrics::{CORNELL_POINTS_RGB, compare_points_with, parse_point_csv};
    let scene = radiant::scene::builtin("cornell-box").expect("builtin");
    let bake = Bake::new(&scene, &BakeParams::default())
        .expect("bake")
        .run_to_end(&mut |_| {})
        .expect("solve");
    let rs = radiant::bridge::render_scene(&scene, Some(&bake), None).expect("render scene");
    let lm = rs.lightmap.as_ref().expect("a light map");
    // The CLI's light map is the same atlas (`radiant bake` writes it as lightmap.exr).
    let atlas = radiant::scene::atlas::Atlas::new(&scene, None).expect("atlas");
    assert_eq!((atlas.width, atlas.height), (lm.width, lm.height));
    for (t, uv) in atlas.uv.iter().enumerate() {
        for (k, c) in uv.iter().enumerate() {
            assert_eq!(c.to_array(), rs.vertices[t * 3 + k].lightmap_uv);
        }
    }
    let vert = |t: usize, k: usize| &rs.vertices[t * 3 + k];
    let pos = |t: usize, k: usize| rs.origin + glam::Vec3::from(vert(t, k).position).as_dvec3();
    // At the 24 path-traced points: the texel value as the renderer reads it (albedo × H + E).
    let refs = parse_point_csv(CORNELL_POINTS_RGB, 1e-3).expect("points");
    let c = compare_points_with(&refs, None, |p| {
        let (t, w) = (0..scene.triangles.len()).find_map(|t| {
            let tri = &scene.triangles[t];
            let n = tri.cross().normalize();
            if n.dot(p.normal) < 0.99 || (p.position - tri.vertices[0]).dot(n).abs() > 5e-3 {
                return None;
            }
            let w = radiant::scene::texture::barycentric(tri.vertices, p.position);
            w.iter().all(|&x| x >= -1e-9).then_some((t, w))
        })?;
        let uv: [f32; 2] = std::array::from_fn(|a| {
            (0..3)
                .map(|k| w[k] as f32 * vert(t, k).lightmap_uv[a])
                .sum()
        });
        let hh = sample(lm, uv);
        let v = vert(t, 0);
        Some(std::array::from_fn(|c| {
            let albedo = (f64::from(v.albedo[c]) * 255.0).round() / 255.0;
            f64::from(v.emissive[c]) + albedo * hh[c]
        }))
    })
    .expect("every point on a triangle");
    let (mean, max) = (c.mean_rel, c.max_rel);
    eprintln!(
        "light-map texels at the 24 points: mean {:.2} %, max {:.2} %",
        mean * 100.0,
        max * 100.0
    );
    assert!(
        mean <= 0.02 && max <= 0.05,
        "mean {:.2} %, max {:.2} %",
        mean * 100.0,
        max * 100.0
    );
    // Seams: two triangles of one surface that share an edge read the same light along it.
    let (mut worst, mut edges) = (0.0f64, 0);
    let n = scene.triangles.len();
    for a in 0..n {
        for b in a + 1..n {
            if scene.triangles[a].surface != scene.triangles[b].surface {
                continue;
            }
            let shared: Vec<(usize, usize)> = (0..3)
                .flat_map(|i| (0..3).map(move |j| (i, j)))
                .filter(|&(i, j)| (pos(a, i) - pos(b, j)).length() < 1e-6)
                .collect();
            if shared.len() != 2 {
                continue;
            }
            edges += 1;
            for t in [0.1f32, 0.3, 0.5, 0.7, 0.9] {
                let on = |tri: usize, k0: usize, k1: usize| -> [f32; 2] {
                    let (u0, u1) = (vert(tri, k0).lightmap_uv, vert(tri, k1).lightmap_uv);
                    [u0[0] + (u1[0] - u0[0]) * t, u0[1] + (u1[1] - u0[1]) * t]
                };
                let ha = sample(lm, on(a, shared[0].0, shared[1].0));
                let hb = sample(lm, on(b, shared[0].1, shared[1].1));
                let scale = ha
                    .iter()
                    .chain(&hb)
                    .fold(0.0f64, |m, x| m.max(x.abs()))
                    .max(1e-3);
                let d = (0..3).map(|c| (ha[c] - hb[c]).abs()).fold(0.0, f64::max) / scale;
                worst = worst.max(d);
            }
        }
    }
    eprintln!(
        "{edges} shared edges, worst difference across them {:.2} %",
        worst * 100.0
    );
    assert!(edges >= 10, "{edges} shared edges");
    assert!(
        worst <= 0.01,
        "texels differ by {:.2} % across a shared edge",
        worst * 100.0
    );
}
