//! The final gather (`radiosity::final_gather`, `texel_light::compose_gathered`): a furnace
//! gives its closed form at every texel, the Cornell box its path-traced light, and the same
//! bytes on any thread count.

mod common;

use glam::DVec3;
use radiant_radiosity::BakeParams;
use radiant_radiosity::final_gather::GatherParams;
use radiant_radiosity::lightmap::LightMap;
use radiant_radiosity::metrics::{self, PointSpec};
use radiant_radiosity::points::{locate_all, shown_at};
use radiant_radiosity::scenes::{add_surface, box_triangles};
use radiant_radiosity::texel_light::compose_gathered;
use radiant_scene::Scene;
use radiant_scene::atlas::Atlas;

/// Every filled texel's `H` (all channels).
fn filled(scene: &Scene, atlas: &Atlas, map: &LightMap) -> Vec<[f32; 3]> {
    let size = (atlas.width * atlas.height) as usize;
    let mut out = Vec::new();
    for page in 0..atlas.pages {
        for (k, o) in atlas.owners(scene, page).iter().enumerate() {
            if o.triangle != u32::MAX {
                out.push(map.texels[page as usize * size + k]);
            }
        }
    }
    out
}

#[test]
fn a_furnace_gathers_its_closed_form_at_every_texel() {
    // A closed cube that emits 1 and reflects 0.5 everywhere: B = 1 / (1 − 0.5) = 2, and every
    // point receives H = B = 2: 1 from the emitters (exact form factors, nothing in the way)
    // and 1 reflected (the rays' part: B − E of whatever they meet).
    let mut scene = Scene::default();
    let walls = box_triangles(DVec3::ZERO, DVec3::ONE, true);
    add_surface(&mut scene, "furnace", [0.5; 3], [1.0; 3], &walls);
    let r = common::bake(&scene, &BakeParams::default());
    let atlas = Atlas::new(&scene, Some(32.0)).expect("atlas");
    // The furnace's solution is the fixed point of a gather at the elements: passes of it
    // leave every element at B = 2.
    let vis = radiant_radiosity::input::visibility(&r.mesh, None);
    let passes = radiant_radiosity::final_gather::regather_elements(
        &scene,
        &r.mesh,
        &r.system,
        &r.radiosity,
        &vis,
        GatherParams {
            strata: 4,
            ..GatherParams::default()
        },
        2,
    );
    for b in &passes {
        for &c in b {
            assert!((c - 2.0).abs() < 0.02, "B {c} after two passes, not 2");
        }
    }
    for analytic_emitters in [64, 0] {
        let mean_tolerance = if analytic_emitters == 0 { 0.1 } else { 0.02 };
        // Exact form factors, then points sampled on the emitters by power: unbiased, but a
        // texel by an edge sees the next wall's light through few samples (one came to 3.6,
        // and the mean over texels 1.9 % short): only the mean is held, to 5 %.
        let (params, tolerance) = match analytic_emitters {
            0 => (
                GatherParams {
                    strata: 4,
                    emitter_samples: 64,
                    analytic_emitters,
                    ..GatherParams::default()
                },
                f32::INFINITY,
            ),
            _ => (
                GatherParams {
                    strata: 4,
                    ..GatherParams::default()
                },
                0.02,
            ),
        };
        let map = compose_gathered(&scene, &atlas, &r.mesh, &r.system, &r.radiosity, params);
        let texels = filled(&scene, &atlas, &map);
        assert!(texels.len() > 1000);
        let mut mean = 0.0;
        for h in &texels {
            for &c in h {
                assert!(c.is_finite() && (c - 2.0).abs() < tolerance, "H {c}, not 2");
                mean += f64::from(c);
            }
        }
        mean /= 3.0 * texels.len() as f64;
        assert!((mean - 2.0).abs() < mean_tolerance, "mean H {mean}, not 2");
    }
}

#[test]
fn the_cornell_box_gathers_mitsubas_light_at_its_points() {
    // The 24 shipped Mitsuba 3 radiance meters (2^20 samples each): what the renderer shows
    // there (`L = ρ H + E`, `H` sampled as the GPU samples it) within 1 % on average, as the
    // issue asks. Measured (release, the defaults' stride 2 and radius 2): the smooth field
    // 0.65 % mean, 1.75 % worst; the gather at 8 strata 1.47 % and 5.9 %, at 12 0.95 % and
    // 5.8 % (noise at a corner of the ceiling), at 16 0.39 % and 1.09 %.
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let r = common::bake(&scene, &BakeParams::default());
    let atlas = Atlas::new(&scene, None).expect("atlas");
    let params = GatherParams {
        strata: 16,
        ..GatherParams::default()
    };
    let map = compose_gathered(&scene, &atlas, &r.mesh, &r.system, &r.radiosity, params);
    let refs = metrics::parse_point_csv(metrics::CORNELL_POINTS_RGB, 1e-3).expect("shipped");
    let specs: Vec<PointSpec> = refs
        .iter()
        .map(|p| PointSpec {
            name: p.name.clone(),
            position: p.position,
            normal: p.normal,
        })
        .collect();
    let located = locate_all(&scene, &specs).expect("every meter on a surface");
    let shown = shown_at(&scene, &atlas, &map, &located).expect("on the atlas");
    let errors: Vec<(String, f64)> = refs
        .iter()
        .zip(&shown)
        .map(|(p, s)| {
            let (ours, theirs): (f64, f64) = (s.l.iter().sum(), p.radiosity.iter().sum());
            (p.name.clone(), (ours - theirs).abs() / theirs)
        })
        .collect();
    let mean = errors.iter().map(|e| e.1).sum::<f64>() / errors.len() as f64;
    let worst = errors
        .iter()
        .cloned()
        .fold((String::new(), 0.0), |a, b| if b.1 > a.1 { b } else { a });
    assert!(mean < 0.01, "mean {:.2} % (worst {worst:?})", mean * 100.0);
    assert!(worst.1 < 0.03, "worst {worst:?}");
}

#[test]
fn a_gather_is_the_same_on_one_and_two_threads() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let r = common::bake(&scene, &BakeParams::default());
    let atlas = Atlas::new(&scene, Some(64.0)).expect("atlas");
    let params = GatherParams {
        strata: 3,
        ..GatherParams::default()
    };
    let on = |threads: usize, params: GatherParams| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| compose_gathered(&scene, &atlas, &r.mesh, &r.system, &r.radiosity, params))
    };
    let (one, two) = (on(1, params), on(2, params));
    assert!(one.texels.iter().flatten().all(|c| c.is_finite()));
    assert!(
        one.texels == two.texels,
        "the gather depends on the thread count"
    );
    // Finer lattices where the coarsest does not stand for a texel: the same bytes too.
    let coarse = GatherParams {
        stride: 8,
        ..params
    };
    assert!(
        on(1, coarse) == on(2, coarse),
        "the lattices depend on the thread count"
    );
    // Another seed draws other rays: the seed is used.
    let other = compose_gathered(
        &scene,
        &atlas,
        &r.mesh,
        &r.system,
        &r.radiosity,
        GatherParams { seed: 2, ..params },
    );
    assert!(other.texels != one.texels);
}

/// A room lit by a ceiling panel, with a box standing on its floor or lifted 1 mm: the floor
/// farther than 2 cm from the box's foot gets the same light either way (within 1 % in bands
/// of distance, 5 % at any texel: the rays' noise), as a path tracer would give (1 mm lets
/// almost nothing under the box). The smooth field of the elements, which spans the foot, is
/// printed beside it.
#[test]
fn a_box_standing_or_lifted_a_millimetre_lights_the_floor_the_same() {
    use radiant_radiosity::scenes::quad;
    use radiant_radiosity::texel_light::compose_lightmap;
    use radiant_scene::atlas::texel_position;
    let (lo, hi) = (DVec3::new(0.8, 0.0, 0.8), DVec3::new(1.2, 0.4, 1.2));
    let room = |lift: f64| {
        let mut scene = Scene::default();
        let floor = quad(DVec3::ZERO, DVec3::Z * 2.0, DVec3::X * 2.0);
        add_surface(&mut scene, "floor", [0.6; 3], [0.0; 3], &floor);
        let mut walls = box_triangles(DVec3::ZERO, DVec3::new(2.0, 1.5, 2.0), true);
        // The room's own floor is the surface above.
        walls.retain(|t| t.iter().any(|v| v.y > 0.0));
        add_surface(&mut scene, "walls", [0.5; 3], [0.0; 3], &walls);
        let panel = quad(DVec3::new(0.7, 1.499, 0.7), DVec3::X * 0.6, DVec3::Z * 0.6);
        add_surface(&mut scene, "panel", [0.0; 3], [4.0; 3], &panel);
        let up = DVec3::Y * lift;
        add_surface(
            &mut scene,
            "box",
            [0.5; 3],
            [0.0; 3],
            &box_triangles(lo + up, hi + up, false),
        );
        scene
    };
    // `stride`: the gather's coarsest lattice (8: finer lattices where the coarse one does
    // not stand for a texel, as by the box); `None`: the smooth field.
    let floor_light = |scene: &Scene, stride: Option<u32>| -> Vec<(f64, f32)> {
        let r = common::bake(scene, &BakeParams::default());
        let atlas = Atlas::new(scene, Some(64.0)).expect("atlas");
        let map = if let Some(stride) = stride {
            let params = GatherParams {
                strata: 8,
                stride,
                ..GatherParams::default()
            };
            compose_gathered(scene, &atlas, &r.mesh, &r.system, &r.radiosity, params)
        } else {
            compose_lightmap(scene, &atlas, &r.mesh, &r.system, &r.radiosity)
        };
        let size = (atlas.width * atlas.height) as usize;
        let mut out = Vec::new();
        for page in 0..atlas.pages {
            for (k, o) in atlas.owners(scene, page).iter().enumerate() {
                let Some(t) = scene.triangles.get(o.triangle as usize) else {
                    continue;
                };
                if scene.surfaces[t.surface as usize].name != "floor" {
                    continue;
                }
                let p = texel_position(t.vertices, o.u, o.v);
                // Distance to the box's foot (0 inside it).
                let d = (DVec3::new(lo.x - p.x, 0.0, lo.z - p.z).max(DVec3::ZERO)
                    + DVec3::new(p.x - hi.x, 0.0, p.z - hi.z).max(DVec3::ZERO))
                .length();
                let inside = p.x > lo.x && p.x < hi.x && p.z > lo.z && p.z < hi.z;
                if !inside {
                    out.push((d, map.texels[page as usize * size + k][1]));
                }
            }
        }
        out
    };
    for stride in [None, Some(2), Some(8)] {
        let gathered = stride.is_some();
        let (standing, lifted) = (
            floor_light(&room(0.0), stride),
            floor_light(&room(1e-3), stride),
        );
        assert_eq!(standing.len(), lifted.len());
        let mut worst = (0.0f64, 0.0f64);
        for (s, l) in standing.iter().zip(&lifted) {
            assert!((s.0 - l.0).abs() < 1e-9);
            if s.0 > 0.02 {
                let rel = f64::from((s.1 - l.1).abs() / l.1.max(1e-6));
                if rel > worst.0 {
                    worst = (rel, s.0);
                }
            }
        }
        let mut bands = Vec::new();
        for (a, b) in [
            (0.02, 0.05),
            (0.05, 0.1),
            (0.1, 0.2),
            (0.2, 0.5),
            (0.5, 2.0),
        ] {
            let mean = |v: &[(f64, f32)]| {
                let x: Vec<f64> = (v.iter())
                    .filter(|t| t.0 > a && t.0 <= b)
                    .map(|t| f64::from(t.1))
                    .collect();
                x.iter().sum::<f64>() / x.len() as f64
            };
            bands.push((a, b, mean(&standing) / mean(&lifted) - 1.0));
        }
        eprintln!("{bands:?}");
        eprintln!(
            "{}: worst {:.2} % at {:.3} m from the foot",
            stride.map_or("smooth field".into(), |s| format!("gathered, stride {s}")),
            worst.0 * 100.0,
            worst.1
        );
        // Measured: the smooth field +8.7 % at 2-5 cm, 19 % at worst; the gather within
        // 0.4 % in every band, 3.2 % at worst (the rays' noise: the two rooms average other
        // texels near the box).
        if gathered {
            for &(a, b, d) in &bands {
                assert!(
                    d.abs() < 0.01,
                    "{a}-{b} m from the foot: {:+.2} %",
                    d * 100.0
                );
            }
            assert!(
                worst.0 < 0.05,
                "{:.2} % at {:.3} m",
                worst.0 * 100.0,
                worst.1
            );
        }
    }
}
