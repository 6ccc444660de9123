//! The bake against the in-project path tracer on scenes with no published reference: a
//! sunlit room under a skylight, where most of the light is indirect.

use glam::DVec3;
use radiant::radiosity::cluster::{self, ClusterParams};
use radiant::radiosity::scenes::{add_surface, quad};
use radiant::radiosity::{Bake, BakeParams, BakeResult};
use radiant::reference::{Params, SurfaceEstimate, Tracer};
use radiant::scene::{Light, LightKind, Scene};

/// A 10 × 4 × 10 room (inward faces, ρ 0.7) whose ceiling has a 4 × 4 skylight in its middle,
/// lit by a sun through it.
fn skylit_room() -> Scene {
    let mut s = Scene::default();
    let (w, h) = (10.0, 4.0);
    let rho = [0.7, 0.6, 0.5];
    let y = DVec3::Y * h;
    let (x, z) = (DVec3::X * w, DVec3::Z * w);
    add_surface(&mut s, "floor", rho, [0.0; 3], &quad(DVec3::ZERO, z, x));
    add_surface(&mut s, "wall_x0", rho, [0.0; 3], &quad(DVec3::ZERO, y, z));
    add_surface(&mut s, "wall_x1", rho, [0.0; 3], &quad(x, z, y));
    add_surface(&mut s, "wall_z0", rho, [0.0; 3], &quad(DVec3::ZERO, x, y));
    add_surface(&mut s, "wall_z1", rho, [0.0; 3], &quad(z, y, x));
    // The ceiling: four quads around the hole [3, 7]², facing down.
    let c = |a: f64, b: f64| DVec3::new(a, h, b);
    let mut ceiling = Vec::new();
    for (o, u, v) in [
        (c(0.0, 0.0), DVec3::X * 10.0, DVec3::Z * 3.0),
        (c(0.0, 7.0), DVec3::X * 10.0, DVec3::Z * 3.0),
        (c(0.0, 3.0), DVec3::X * 3.0, DVec3::Z * 4.0),
        (c(7.0, 3.0), DVec3::X * 3.0, DVec3::Z * 4.0),
    ] {
        ceiling.extend(quad(o, u, v));
    }
    add_surface(&mut s, "ceiling", rho, [0.0; 3], &ceiling);
    s.lights.push(Light {
        name: "sun".into(),
        kind: LightKind::Directional,
        position: DVec3::ZERO,
        direction: DVec3::new(0.3, -1.0, 0.2).normalize(),
        color: [1.0; 3],
        intensity: 10.0,
        range: None,
    });
    s
}

/// The path tracer's per-surface estimate, `samples` paths each, seed 1.
fn traced(scene: &Scene, samples: u64) -> Vec<SurfaceEstimate> {
    let tracer = Tracer::new(scene).expect("tracer");
    let p = Params {
        samples: Some(samples),
        target_error: None,
        time_limit: None,
        seed: 1,
    };
    tracer.surfaces(&p, &|_| {}).expect("trace").0
}

/// Per surface the tracer estimated that does not emit: its name, the reference's mean and
/// relative standard error (first channel), and each bake's offset from it, relative.
fn offsets(
    scene: &Scene,
    reference: &[SurfaceEstimate],
    bakes: &[&BakeResult],
) -> Vec<(String, f64, f64, Vec<f64>)> {
    reference
        .iter()
        .map(|r| (&scene.surfaces[r.surface as usize], r))
        .filter(|(s, _)| !s.is_emitter())
        .map(|(s, r)| {
            let m = r.estimate.mean[0];
            let d = bakes.iter().map(|res| {
                let b = (res.surfaces.iter())
                    .find(|x| x.name == s.name)
                    .expect("surface")
                    .mean[0];
                (b - m) / m
            });
            (s.name.clone(), m, r.estimate.se[0] / m, d.collect())
        })
        .collect()
}

/// The path tracer's per-surface estimate (`samples` paths each, seed 1), and the
/// per-triangle and clustered bakes at default settings.
fn reference_and_bakes(
    scene: &Scene,
    samples: u64,
) -> (Vec<SurfaceEstimate>, BakeResult, BakeResult) {
    let reference = traced(scene, samples);
    let params = BakeParams::default();
    let tri = Bake::new(scene, &params)
        .expect("bake")
        .run_to_end(&mut |_| {})
        .expect("solve");
    let clu =
        cluster::bake(scene, &params, &ClusterParams::default(), &|_, _, _| {}).expect("clustered");
    (reference, tri, clu)
}

#[test]
fn a_skylit_room_bakes_as_the_path_tracer_sees_it() {
    // Split in 16 per triangle, so that the clustered bake links clusters, not just
    // triangles.
    let scene = radiant::radiosity::scenes::tessellated(&skylit_room(), 2);
    let (reference, tri, clu) = reference_and_bakes(&scene, 32_768);
    for r in &reference {
        let name = &scene.surfaces[r.surface as usize].name;
        let get = |res: &BakeResult| {
            res.surfaces
                .iter()
                .find(|s| &s.name == name)
                .expect("surface")
                .mean
        };
        let (t, c) = (get(&tri), get(&clu));
        let m = r.estimate.mean;
        for ch in 0..3 {
            let se = r.estimate.se[ch] / m[ch];
            let (dt, dc) = ((t[ch] - m[ch]) / m[ch], (c[ch] - m[ch]) / m[ch]);
            println!(
                "{name:8} {ch}: ref {:.5} (se {:.2} %)  triangles {:+.2} %  clustered {:+.2} %",
                m[ch],
                100.0 * se,
                100.0 * dt,
                100.0 * dc
            );
            // The bake's own discretisation (3 %) plus four standard errors of the reference.
            let tol = 0.03 + 4.0 * se;
            assert!(
                dt.abs() <= tol,
                "{name} {ch}: per-triangle bake off by {dt}"
            );
            assert!(dc.abs() <= tol, "{name} {ch}: clustered bake off by {dc}");
        }
    }
    assert!(
        clu.report
            .clusters
            .as_ref()
            .is_some_and(|c| c.cluster_receiver_links + c.cluster_source_links > 0),
        "the clustered bake must link clusters here"
    );
}

#[test]
fn a_room_of_boxes_bakes_as_the_path_tracer_sees_it() {
    // 25 boxes on the floor of a closed room lit by a ceiling panel (1 214 triangles): most of
    // the light is indirect and much of the floor near a box.
    let scene = radiant::radiosity::scenes::room_with_boxes(5, 1);
    let (reference, tri, clu) = reference_and_bakes(&scene, 65_536);
    for (name, m, se, d) in offsets(&scene, &reference, &[&tri, &clu]) {
        let (dt, dc) = (d[0], d[1]);
        println!(
            "{name}: ref {m:.5} (se {:.2} %), triangles {:+.2} %, clustered {:+.2} %",
            100.0 * se,
            100.0 * dt,
            100.0 * dc
        );
        // Measured: per-triangle +2.5 % (room) and within 2.7 % (boxes); clustered +1.1 %
        // and within 4 % (−1.3 % for the room before elements enclosed in part were counted
        // by their exposure; −7.3 % before the push took enclosed area into account and
        // planar visibility was weighted by the kernel).
        assert!(
            dt.abs() <= 0.02 + 3.0 * se,
            "{name}: per-triangle off by {dt}"
        );
        assert!(dc.abs() <= 0.04 + 3.0 * se, "{name}: clustered off by {dc}");
    }
}

#[test]
fn a_floor_under_boxes_smaller_than_its_elements_bakes_as_the_path_tracer_sees_it() {
    // 256 boxes of 0.6 m on the floor of the 20 m room (3 086 triangles), each smaller than
    // the floor's elements: most floor elements near a box are covered in part. Counted whole,
    // such an element diluted its light twice, as receiver and as source: the room baked
    // 12.0 % too dark. With each element's exposure (`radiosity::exposure`) it bakes within
    // 3 % (measured: room −2.4 %, boxes +0.3 %).
    let mut scene = radiant::radiosity::scenes::room_with_boxes(16, 0);
    // The boxes as one surface, so that the path tracer's estimate of them is one number.
    let boxes = (scene.surfaces.iter())
        .position(|s| s.name.starts_with("box_"))
        .expect("boxes") as u32;
    for t in &mut scene.triangles {
        if scene.surfaces[t.surface as usize].name.starts_with("box_") {
            t.surface = boxes;
        }
    }
    let reference = traced(&scene, 262_144);
    let clu = cluster::bake(
        &scene,
        &BakeParams::default(),
        &ClusterParams::default(),
        &|_, _, _| {},
    )
    .expect("clustered");
    for (name, m, se, d) in offsets(&scene, &reference, &[&clu]) {
        let d = d[0];
        println!(
            "{name}: ref {m:.5} (se {:.2} %), clustered {:+.2} %",
            100.0 * se,
            100.0 * d
        );
        assert!(d.abs() <= 0.03 + 3.0 * se, "{name}: clustered off by {d}");
    }
    let partial = (clu.system.weight.iter().zip(&clu.system.area))
        .filter(|(w, a)| **w > 0.0 && **w < 0.99 * **a)
        .count();
    assert!(partial > 100, "{partial} elements covered in part");
    let report = clu.report.clusters.as_ref().expect("a clustered report");
    assert_eq!(report.partly_enclosed, partial, "the report counts them");
}
