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
    let on = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| compose_gathered(&scene, &atlas, &r.mesh, &r.system, &r.radiosity, params))
    };
    let (one, two) = (on(1), on(2));
    assert!(one.texels.iter().flatten().all(|c| c.is_finite()));
    assert!(
        one.texels == two.texels,
        "the gather depends on the thread count"
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
