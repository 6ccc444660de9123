//! Probes from the solution against closed forms and against the path tracer.

use std::f64::consts::PI;

use glam::DVec3;
use radiant_probes::{ProbeParams, Solved};
use radiant_radiosity::scenes::{add_surface, furnace, quad};
use radiant_radiosity::{Bake, BakeParams, BakeResult};
use radiant_reference::{Params, Point, Tracer};
use radiant_scene::{Light, LightKind, Scene};

fn bake(scene: &Scene, patch: f64) -> BakeResult {
    let mut p = BakeParams::default();
    p.mesh.patch_size = patch;
    Bake::new(scene, &p)
        .expect("bake prepares")
        .run_to_end(&mut |_| {})
        .expect("bake runs")
}

/// The mean and worst of `Σ|got − truth| / Σ truth` over RGB, each pair printed.
fn errors(probes: &[Point], got: &[[f64; 3]], truth: &[radiant_reference::Estimate]) -> (f64, f64) {
    let (mut sum, mut worst) = (0.0, 0.0f64);
    for ((p, got), t) in probes.iter().zip(got).zip(truth) {
        let err =
            (0..3).map(|c| (got[c] - t.mean[c]).abs()).sum::<f64>() / t.mean.iter().sum::<f64>();
        eprintln!(
            "{}: {:.4} vs {:.4} (se {:.2} %): {:.2} %",
            p.name,
            got.iter().sum::<f64>(),
            t.mean.iter().sum::<f64>(),
            100.0 * t.rel_error(),
            100.0 * err
        );
        sum += err;
        worst = worst.max(err);
    }
    let mean = sum / probes.len() as f64;
    eprintln!("mean {:.2} %, worst {:.2} %", 100.0 * mean, 100.0 * worst);
    (mean, worst)
}

const AXES: [DVec3; 6] = [
    DVec3::X,
    DVec3::NEG_X,
    DVec3::Y,
    DVec3::NEG_Y,
    DVec3::Z,
    DVec3::NEG_Z,
];

#[test]
fn a_furnace_probe_reads_e_over_one_minus_rho_for_every_normal() {
    let (rho, e) = (0.5, 1.0);
    let scene = furnace(rho, e);
    let result = bake(&scene, 0.5);
    let solved = Solved::new(&scene, &result);
    let baker = solved.baker(&scene, &result.mesh, ProbeParams::default());
    let (lo, hi) = scene.triangles.iter().flat_map(|t| t.vertices).fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), v| (lo.min(v), hi.max(v)),
    );
    for (k, at) in [0.5, 0.2].into_iter().enumerate() {
        let probe = baker.bake_world(lo + (hi - lo) * at, k as u64);
        assert!(!probe.inside());
        for n in AXES.into_iter().chain([DVec3::new(0.36, 0.48, 0.8)]) {
            let e_got = baker.irradiance(&probe, n);
            let want = PI * e / (1.0 - rho);
            for c in 0..3 {
                assert!(
                    (e_got[c] - want).abs() < 0.01 * want,
                    "at {at}, normal {n}: {e_got:?} vs {want}"
                );
            }
        }
    }
}

/// A black 4 × 4 floor, a 100 cd point light 2 above its centre, and a black occluder
/// (1 × 1, facing up) at height 1.
fn lit_floor() -> Scene {
    let mut s = Scene::default();
    let floor = quad(
        DVec3::new(-2.0, 0.0, 2.0),
        DVec3::new(4.0, 0.0, 0.0),
        DVec3::new(0.0, 0.0, -4.0),
    );
    add_surface(&mut s, "floor", [0.0; 3], [0.0; 3], &floor);
    let sq = quad(
        DVec3::new(-0.5, 1.0, 0.5),
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.0, 0.0, -1.0),
    );
    add_surface(&mut s, "occluder", [0.0; 3], [0.0; 3], &sq);
    s.lights.push(Light {
        name: "bulb".into(),
        kind: LightKind::Point,
        position: DVec3::new(0.0, 2.0, 0.0),
        direction: DVec3::NEG_Y,
        color: [1.0, 0.5, 0.25],
        intensity: 100.0,
        range: None,
    });
    s
}

#[test]
fn a_point_lights_irradiance_is_exact_for_any_normal_and_shadowed() {
    let scene = lit_floor();
    let result = bake(&scene, 1.0);
    let solved = Solved::new(&scene, &result);
    let baker = solved.baker(&scene, &result.mesh, ProbeParams::default());
    // Height 0.5: the occluder (|x| < 0.5 at height 1) shadows |x| < 0.75.
    for (k, x) in [0.0, 0.5, 1.0, 1.5].into_iter().enumerate() {
        let p = DVec3::new(x, 0.5, 0.0);
        let probe = baker.bake_world(p, k as u64);
        let to = DVec3::new(0.0, 2.0, 0.0) - p;
        let d = to.length();
        for n in AXES.into_iter().chain([to / d, DVec3::new(0.6, 0.8, 0.0)]) {
            let cos = n.dot(to / d).max(0.0);
            let lit = if x < 0.75 { 0.0 } else { 1.0 };
            let want = 100.0 * cos / (d * d) * lit;
            let got = baker.irradiance(&probe, n);
            for (c, colour) in [1.0, 0.5, 0.25].into_iter().enumerate() {
                assert!(
                    (got[c] - want * colour).abs() < 1e-9 * want.max(1.0),
                    "x {x}, normal {n}: {got:?} vs {want} × colour"
                );
            }
        }
    }
}

#[test]
fn a_probe_inside_a_box_knows_it() {
    let scene = radiant_scene::builtin("cornell-box").expect("box");
    let result = bake(&scene, 0.3);
    let solved = Solved::new(&scene, &result);
    let baker = solved.baker(&scene, &result.mesh, ProbeParams::default());
    // Inside the tall block, and in the open beside it.
    let inside = baker.bake_world(DVec3::new(0.37, 0.2, 0.35), 0);
    assert!(inside.inside(), "{}", inside.backfaces);
    let open = baker.bake_world(DVec3::new(0.278, 0.3, 0.15), 1);
    assert!(
        !open.inside() && open.backfaces == 0.0,
        "{}",
        open.backfaces
    );
}

/// The Cornell box's probes in free space against the path tracer, for the six axis normals:
/// the benchmark's measure on fewer points, so that it runs in seconds.
#[test]
fn cornell_box_probes_agree_with_the_path_tracer() {
    let scene = radiant_scene::builtin("cornell-box").expect("box");
    let result = bake(&scene, 0.1);
    let solved = Solved::new(&scene, &result);
    let baker = solved.baker(&scene, &result.mesh, ProbeParams::default());
    let places = [
        DVec3::new(0.278, 0.3, 0.28),
        DVec3::new(0.1, 0.45, 0.1),
        DVec3::new(0.45, 0.1, 0.1),
        DVec3::new(0.15, 0.2, 0.45),
    ];
    let mut probes = Vec::new();
    for (i, p) in places.iter().enumerate() {
        for (j, n) in AXES.iter().enumerate() {
            probes.push(Point {
                name: format!("{i}/{j}"),
                position: *p,
                normal: *n,
            });
        }
    }
    let tracer = Tracer::new(&scene).expect("tracer");
    let params = Params {
        samples: Some(16_384),
        target_error: None,
        time_limit: None,
        seed: 3,
    };
    let (truth, _) = tracer.probes(&probes, &params, &|_| {}).expect("trace");
    let got: Vec<[f64; 3]> = places
        .iter()
        .enumerate()
        .flat_map(|(i, p)| {
            let probe = baker.bake_world(*p, i as u64);
            AXES.map(|n| baker.irradiance(&probe, n))
        })
        .collect();
    let (mean, worst) = errors(&probes, &got, &truth);
    // Measured: 0.76 % mean, 4.8 % worst against 2^16 paths with order-4 harmonics (order 2:
    // 0.76 % and 3.4 %; the path tracer's own noise adds up to 3.4 % at the darkest, facing
    // the box's open side, here).
    assert!(mean < 0.02 && worst < 0.08, "mean {mean}, worst {worst}");
}

/// The irradiance volume over the box, read at free-space points between its probes, against
/// the path tracer (the benchmark's measure on fewer points).
#[test]
fn cornell_box_volume_agrees_with_the_path_tracer_between_its_probes() {
    use radiant_probes::{ProbeVolume, VolumeParams};
    let scene = radiant_scene::builtin("cornell-box").expect("box");
    let result = bake(&scene, 0.1);
    let solved = Solved::new(&scene, &result);
    let baker = solved.baker(&scene, &result.mesh, ProbeParams::default());
    let t0 = std::time::Instant::now();
    let volume = ProbeVolume::bake(&baker, &VolumeParams::default());
    eprintln!(
        "{:?} probes ({} inside) in {:.2} s",
        volume.dims,
        volume.inside(),
        t0.elapsed().as_secs_f64()
    );
    // Seeded points in the box's free space, above the blocks.
    let mut rng = radiant_radiosity::rng::Rng::new(11);
    let places: Vec<DVec3> = (0..8)
        .map(|_| {
            DVec3::new(
                0.05 + 0.45 * rng.f64(),
                0.36 + 0.15 * rng.f64(),
                0.05 + 0.45 * rng.f64(),
            )
        })
        .collect();
    let probes: Vec<Point> = places
        .iter()
        .enumerate()
        .flat_map(|(i, p)| {
            AXES.iter().enumerate().map(move |(j, n)| Point {
                name: format!("{i}/{j}"),
                position: *p,
                normal: *n,
            })
        })
        .collect();
    let tracer = Tracer::new(&scene).expect("tracer");
    let params = Params {
        samples: Some(16_384),
        target_error: None,
        time_limit: None,
        seed: 5,
    };
    let (truth, _) = tracer.probes(&probes, &params, &|_| {}).expect("trace");
    let got: Vec<[f64; 3]> = probes
        .iter()
        .map(|p| volume.irradiance_world(p.position, p.normal, Some(&solved.vis)))
        .collect();
    let (mean, worst) = errors(&probes, &got, &truth);
    // Measured: 0.82 % mean, 3.8 % worst with order-4 harmonics and the tricubic blend (order
    // 2 and trilinear: 1.19 %, 3.8 %).
    assert!(mean < 0.025 && worst < 0.08, "mean {mean}, worst {worst}");
}

/// A probe inside the tall block would read black; left out of the interpolation (as inside,
/// and as hidden from the point), it does not darken a point just above the block's top (its
/// cell's lower probes are inside; blended in, 11 % darker facing up). The
/// points lie 5 cm or more inside the top's edges: nearer, the cell's probes beside the block
/// see the floor below, and the blend is darker facing down (20 % at 1.5 cm).
#[test]
fn probes_inside_geometry_do_not_darken_what_stands_beside_them() {
    use radiant_probes::{ProbeVolume, VolumeParams};
    let scene = radiant_scene::builtin("cornell-box").expect("box");
    let result = bake(&scene, 0.1);
    let solved = Solved::new(&scene, &result);
    let baker = solved.baker(&scene, &result.mesh, ProbeParams::default());
    let volume = ProbeVolume::bake(&baker, &VolumeParams::default());
    assert!(volume.inside() > 0);
    let step = volume.step * result.mesh.frame.scale;
    for (k, p) in [
        DVec3::new(0.37, 0.33 + 0.3 * step, 0.35),
        DVec3::new(0.40, 0.33 + 0.5 * step, 0.38),
    ]
    .into_iter()
    .enumerate()
    {
        let exact = baker.bake_world(p, 100 + k as u64);
        for n in [DVec3::Y, DVec3::NEG_Y, DVec3::X] {
            let want = baker.irradiance(&exact, n);
            let got = volume.irradiance_world(p, n, Some(&solved.vis));
            let err =
                (0..3).map(|c| (got[c] - want[c]).abs()).sum::<f64>() / want.iter().sum::<f64>();
            assert!(err < 0.1, "{p}, normal {n}: {got:?} vs {want:?}");
        }
    }
}

/// Facing the Cornell box's open front from a few centimetres inside it, the irradiance grows
/// about as the square of the depth: a trilinear blend of the probes lies above it, the
/// volume's tricubic blend does not. Measured against probes baked at the points themselves
/// with four times the rays: trilinear +7 to +18 % (mean +11.7 %), tricubic −3.9 to +6.6 %
/// (mean of the errors' sizes 2.6 %; the rest is the probes' rays in a nearly dark direction).
#[test]
fn the_volume_follows_light_that_grows_convexly_between_its_probes() {
    use radiant_probes::{ProbeVolume, VolumeParams};
    let scene = radiant_scene::builtin("cornell-box").expect("box");
    let result = bake(&scene, 0.1);
    let solved = Solved::new(&scene, &result);
    let baker = solved.baker(&scene, &result.mesh, ProbeParams::default());
    let fine = solved.baker(
        &scene,
        &result.mesh,
        ProbeParams {
            strata: 64,
            ..ProbeParams::default()
        },
    );
    let volume = ProbeVolume::bake(&baker, &VolumeParams::default());
    let (mut worst, mut sum, mut count) = (0.0f64, 0.0, 0.0);
    for (k, (x, y)) in [(0.48, 0.21), (0.28, 0.30), (0.15, 0.26), (0.40, 0.40)]
        .into_iter()
        .enumerate()
    {
        for (j, z) in [0.04, 0.05].into_iter().enumerate() {
            let p = DVec3::new(x, y, z);
            let exact = fine.bake_world(p, 200 + 2 * k as u64 + j as u64);
            let want = fine.irradiance(&exact, DVec3::NEG_Z);
            let got = volume.irradiance_world(p, DVec3::NEG_Z, Some(&solved.vis));
            let err = (0..3).map(|c| got[c] - want[c]).sum::<f64>() / want.iter().sum::<f64>();
            eprintln!("{p}: {got:?} vs {want:?}: {:+.2} %", 100.0 * err);
            worst = worst.max(err.abs());
            sum += err.abs();
            count += 1.0;
        }
    }
    let mean = sum / count;
    assert!(mean < 0.05 && worst < 0.09, "mean {mean}, worst {worst}");
    // A point or normal that is not finite reads nothing, not NaN.
    for (p, n) in [(DVec3::NAN, DVec3::Y), (DVec3::splat(0.2), DVec3::INFINITY)] {
        assert_eq!(volume.irradiance_world(p, n, Some(&solved.vis)), [0.0; 3]);
    }
}

/// A 10 cm wall across the floor, a point light on one side only: the probes on the dark side,
/// and the volume read just behind the wall, get under 1 % of the light across from them.
#[test]
fn light_does_not_leak_through_a_thin_wall() {
    use radiant_probes::{ProbeVolume, VolumeParams};
    let mut scene = Scene::default();
    let floor = quad(
        DVec3::new(-2.0, 0.0, 1.0),
        DVec3::new(4.0, 0.0, 0.0),
        DVec3::new(0.0, 0.0, -2.0),
    );
    add_surface(&mut scene, "floor", [0.6; 3], [0.0; 3], &floor);
    // The wall: a closed box x ∈ [0.07, 0.17], y ∈ [0, 1.5], z ∈ [−1, 1], faces outward: between
    // the probes at x = 0 and 0.25 (a sixteenth of the 4 m floor apart), so that a point 2 cm
    // behind it shares its cell with the lit side's probes.
    let (lo, hi) = (DVec3::new(0.07, 0.0, -1.0), DVec3::new(0.17, 1.5, 1.0));
    let wall = radiant_radiosity::scenes::box_triangles(lo, hi, false);
    add_surface(&mut scene, "wall", [0.6; 3], [0.0; 3], &wall);
    scene.lights.push(Light {
        name: "bulb".into(),
        kind: LightKind::Point,
        position: DVec3::new(1.2, 1.0, 0.0),
        direction: DVec3::NEG_Y,
        color: [1.0; 3],
        intensity: 50.0,
        range: None,
    });
    let result = bake(&scene, 0.5);
    let solved = Solved::new(&scene, &result);
    let baker = solved.baker(&scene, &result.mesh, ProbeParams::default());
    let volume = ProbeVolume::bake(&baker, &VolumeParams::default());
    let frame = result.mesh.frame;
    let (mut dark, mut lit) = (0.0f64, 0.0f64);
    for p in &volume.probes {
        let x = frame.center + p.position * frame.scale;
        if p.inside() || x.y < 0.05 || x.y > 1.4 || x.z.abs() > 0.9 {
            continue;
        }
        let e: f64 = [DVec3::Y, DVec3::NEG_Y, DVec3::X, DVec3::NEG_X]
            .iter()
            .map(|&n| baker.irradiance(p, n).iter().sum::<f64>())
            .sum();
        if x.x < 0.07 {
            dark = dark.max(e);
        } else if x.x > 0.17 {
            lit = lit.max(e);
        }
    }
    assert!(lit > 0.0 && dark < 0.01 * lit, "dark {dark}, lit {lit}");
    // Read 2 cm from either face, for normals toward the wall, away from it, up and down.
    for y in [0.3, 0.7, 1.1] {
        for z in [-0.5, 0.0, 0.4] {
            for n in [DVec3::X, DVec3::NEG_X, DVec3::Y, DVec3::NEG_Y] {
                let behind = volume.irradiance_world(DVec3::new(0.05, y, z), n, Some(&solved.vis));
                let front = volume.irradiance_world(DVec3::new(0.19, y, z), -n, Some(&solved.vis));
                let (b, f) = (behind.iter().sum::<f64>(), front.iter().sum::<f64>());
                assert!(
                    b <= 0.01 * f.max(1e-3),
                    "({y}, {z}) normal {n}: {b} behind, {f} in front"
                );
            }
        }
    }
}

/// What a renderer evaluates per probe (`ProbeVolume::h_harmonics`: the whole `H(n)` of a
/// probe as order-2 harmonics) against the probe's own exact evaluation, over many normals:
/// close on the whole, as order 2 allows for the panel's lobe (kept exact in the probe).
#[test]
fn a_probes_harmonics_hold_its_whole_light_for_a_renderer() {
    use radiant_probes::{ProbeVolume, VolumeParams};
    let scene = radiant_scene::builtin("cornell-box").expect("box");
    let result = bake(&scene, 0.1);
    let solved = Solved::new(&scene, &result);
    let baker = solved.baker(&scene, &result.mesh, ProbeParams::default());
    let volume = ProbeVolume::bake(
        &baker,
        &VolumeParams {
            spacing: Some(0.12),
            ..VolumeParams::default()
        },
    );
    let harmonics = volume.h_harmonics();
    assert_eq!(harmonics.len(), volume.probes.len());
    let mut rng = radiant_radiosity::rng::Rng::new(3);
    let (mut diff, mut total, mut worst) = (0.0f64, 0.0f64, 0.0f64);
    let mut valid = 0;
    for (p, (c, ok)) in volume.probes.iter().zip(&harmonics) {
        assert_eq!(*ok, !p.inside());
        if !ok {
            assert!(c.iter().flatten().all(|&v| v == 0.0));
            continue;
        }
        valid += 1;
        let lights: Vec<f64> = p.lights.iter().map(|&v| f64::from(v)).collect();
        let emitters: Vec<f64> = p.emitters.iter().map(|&v| f64::from(v)).collect();
        let (mut d, mut t) = (0.0, 0.0);
        for _ in 0..32 {
            let z = 2.0 * rng.f64() - 1.0;
            let phi = 2.0 * PI * rng.f64();
            let r = (1.0 - z * z).sqrt();
            let n = DVec3::new(r * phi.cos(), r * phi.sin(), z);
            let exact = volume
                .lighting
                .evaluate(p.position, n, &p.sh, &lights, &emitters);
            let y = radiant_radiosity::cluster::sh::basis(n);
            for ch in 0..3 {
                let got: f64 = (0..9).map(|k| c[k][ch] * y[k]).sum::<f64>().max(0.0);
                d += (got - exact[ch]).abs();
                t += exact[ch];
            }
        }
        diff += d;
        total += t;
        worst = worst.max(d / t.max(1e-12));
    }
    let mean = diff / total;
    eprintln!("{valid} valid probes: mean {mean:.4}, worst probe {worst:.4}");
    assert!(valid > 100, "{valid}");
    // Measured: 5.30 % mean, 11.8 % at the worst probe; 5.28 % with 4× the projection's
    // normals, the same with 32×: order 2's truncation of the panel's lobe, not the quadrature.
    assert!(
        mean < 0.07 && worst < 0.2,
        "mean {mean}, worst probe {worst}"
    );
}
