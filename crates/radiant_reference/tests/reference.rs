//! The path tracer against closed forms and against Mitsuba 3.
//!
//! Tolerances come from the standard errors the tracer reports (and Mitsuba's where it gives
//! them), not from guesses: a value is accepted within `K` combined standard errors. Every
//! run is seeded, so each test is the same on every machine.

#![expect(
    clippy::needless_range_loop,
    reason = "RGB channel loops index several arrays at once"
)]

use std::f64::consts::PI;
use std::time::Duration;

use glam::DVec3;
use radiant_radiosity::scenes::{add_surface, box_triangles, furnace, quad};
use radiant_reference::{DARK, Estimate, Params, Point, ReferenceError, Stopped, Tracer};
use radiant_scene::{Light, LightKind, Scene};

fn samples(n: u64) -> Params {
    Params {
        samples: Some(n),
        target_error: None,
        time_limit: None,
        seed: 7,
    }
}

fn quiet(_: &radiant_reference::Progress) {}

/// `|got − want| ≤ k · se` per channel, with a small absolute floor for exact zeros.
fn within(e: &Estimate, want: [f64; 3], k: f64, what: &str) {
    for c in 0..3 {
        let d = (e.mean[c] - want[c]).abs();
        assert!(
            d <= k * e.se[c] + 1e-12,
            "{what}: channel {c}: {} vs {} (se {}, {:.1} se)",
            e.mean[c],
            want[c],
            e.se[c],
            d / e.se[c]
        );
    }
}

#[test]
fn white_furnace_converges_to_e_over_one_minus_rho() {
    for (rho, e) in [(0.5, 1.0), (0.9, 2.0)] {
        let tracer = Tracer::new(&furnace(rho, e)).expect("furnace");
        let (s, run) = tracer.surfaces(&samples(20_000), &quiet).expect("trace");
        let want = e / (1.0 - rho);
        within(
            &s[0].estimate,
            [want; 3],
            4.0,
            &format!("furnace rho {rho}"),
        );
        // The estimate is tight enough to mean something: under 1 %.
        assert!(s[0].estimate.rel_error() < 0.01, "{:?}", s[0].estimate);
        assert_eq!(run.paths, 20_000);
        assert_eq!(run.stopped, Stopped::Samples);
    }
}

#[test]
fn double_sided_walls_reflect_on_the_side_a_ray_meets() {
    // glTF's doubleSided arrives as back-to-back twins: the furnace's walls so, plus an
    // exact duplicate of one wall facing the same way. Nothing may absorb at a tie.
    let mut scene = furnace(0.8, 1.0);
    let tris = scene.triangles.clone();
    for t in &tris {
        scene.triangles.push(t.rewound());
    }
    scene.triangles.push(tris[0]);
    let tracer = Tracer::new(&scene).expect("furnace");
    let (s, _) = tracer.surfaces(&samples(20_000), &quiet).expect("trace");
    // Inside, e/(1 − ρ) = 5 on the 13 inward triangles; the 12 outward ones see nothing and
    // only emit (1). All 25 have the same area.
    within(
        &s[0].estimate,
        [(13.0 * 5.0 + 12.0) / 25.0; 3],
        4.0,
        "double-sided furnace",
    );
}

/// A 4 × 4 floor (ρ 0.5) lit by a 100 cd point light 2 above its centre; with `occluder`, a
/// 1 × 1 upward-facing black square at height 1 above the centre shadows a square of side 2.
fn lit_floor(occluder: bool) -> Scene {
    let mut s = Scene::default();
    let floor = quad(
        DVec3::new(-2.0, 0.0, 2.0),
        DVec3::new(4.0, 0.0, 0.0),
        DVec3::new(0.0, 0.0, -4.0),
    );
    add_surface(&mut s, "floor", [0.5; 3], [0.0; 3], &floor);
    if occluder {
        let sq = quad(
            DVec3::new(-0.5, 1.0, 0.5),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.0, 0.0, -1.0),
        );
        add_surface(&mut s, "occluder", [0.0; 3], [0.0; 3], &sq);
    }
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
fn a_point_light_falls_off_with_the_inverse_square_and_casts_a_shadow() {
    let probe = |x: f64| Point {
        name: format!("x={x}"),
        position: DVec3::new(x, 0.0, 0.0),
        normal: DVec3::Y,
    };
    let xs = [0.0, 0.6, 0.9, 1.5];
    let pts: Vec<Point> = xs.iter().map(|&x| probe(x)).collect();
    for occluder in [false, true] {
        let tracer = Tracer::new(&lit_floor(occluder)).expect("scene");
        let (est, _) = tracer.points(&pts, &samples(256), &quiet).expect("trace");
        for (x, e) in xs.iter().zip(&est) {
            // E = I cos θ / d² = I h / d³, L = ρ E / π; the occluder's shadow is |x| < 1.
            let d = (x * x + 4.0f64).sqrt();
            let shadowed = occluder && *x < 1.0;
            let irr = if shadowed {
                0.0
            } else {
                100.0 * 2.0 / (d * d * d)
            };
            let want = [1.0, 0.5, 0.25].map(|c| 0.5 * irr * c / PI);
            for c in 0..3 {
                // No indirect light reaches the floor: the estimate is exact, not noisy.
                assert!(
                    (e.mean[c] - want[c]).abs() <= 1e-9 * want[c].max(1.0),
                    "occluder {occluder}, x {x}: {:?} vs {want:?}",
                    e.mean
                );
            }
        }
    }
}

/// Mitsuba 3's per-quad irradiance meters (`llvm_ad_rgb`, 2^25 samples): (name, our
/// radiosity = ρ E / π + emission, its standard error ρ σ_E / π).
fn mitsuba_surfaces(scene: &Scene) -> Vec<(String, [f64; 3], [f64; 3])> {
    let text = radiant_radiosity::metrics::CORNELL_BOX_REFERENCE;
    let mut rows = Vec::new();
    for line in text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("quad"))
    {
        let f: Vec<&str> = line.split(',').collect();
        let num = |i: usize| f[i].trim().parse::<f64>().expect("number");
        let s = scene
            .surfaces
            .iter()
            .find(|s| s.name == f[0])
            .expect("surface in the scene");
        let rho = s.reflectance;
        let e = [num(2), num(3), num(4)];
        let se = [num(8), num(9), num(10)];
        rows.push((
            f[0].to_string(),
            [0, 1, 2].map(|c| s.emission[c] + rho[c] * e[c] / PI),
            [0, 1, 2].map(|c| rho[c] * se[c] / PI),
        ));
    }
    rows
}

#[test]
fn cornell_box_surfaces_agree_with_mitsuba_within_their_standard_errors() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let tracer = Tracer::new(&scene).expect("tracer");
    let (ours, run) = tracer.surfaces(&samples(65_536), &quiet).expect("trace");
    let refs = mitsuba_surfaces(&scene);
    let (mut z2, mut count, mut worst) = (0.0, 0, 0.0f64);
    for s in &ours {
        let name = &scene.surfaces[s.surface as usize].name;
        let Some((_, want, se_m)) = refs.iter().find(|(n, _, _)| n == name) else {
            continue;
        };
        if scene.surfaces[s.surface as usize].is_emitter() {
            continue;
        }
        for c in 0..3 {
            let sigma = (s.estimate.se[c].powi(2) + se_m[c].powi(2)).sqrt();
            let z = (s.estimate.mean[c] - want[c]) / sigma;
            println!(
                "{name} {c}: ours {:.5} mitsuba {:.5} z {z:+.2}",
                s.estimate.mean[c], want[c]
            );
            z2 += z * z;
            count += 1;
            worst = worst.max(z.abs());
        }
    }
    let chi = z2 / count as f64;
    println!(
        "{count} values, mean z² {chi:.2}, worst |z| {worst:.2}; {} paths, {} rays in {:.2} s",
        run.paths, run.rays, run.seconds
    );
    assert_eq!(count, 54, "18 surfaces × 3 channels");
    // Unbiased: every value within 3.5 combined standard errors (54 values: at 3.0 one in
    // seven seeds would fail by chance alone), and the mean squared z near 1.
    assert!(worst <= 3.5, "worst |z| {worst}");
    assert!((0.4..=1.8).contains(&chi), "mean z² {chi}");
}

#[test]
fn bad_parameters_are_typed_errors_and_nothing_to_light_gives_zeros() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let tracer = Tracer::new(&scene).expect("tracer");
    let bad = [
        Params {
            samples: Some(0),
            ..samples(1)
        },
        Params {
            target_error: Some(f64::NAN),
            samples: None,
            ..samples(1)
        },
        Params {
            time_limit: Some(Duration::ZERO),
            ..samples(1)
        },
    ];
    for p in bad {
        assert!(matches!(
            tracer.surfaces(&p, &quiet),
            Err(ReferenceError::InvalidParameter { .. })
        ));
    }
    let unbounded = Params {
        samples: None,
        target_error: None,
        time_limit: None,
        seed: 1,
    };
    assert_eq!(
        tracer.surfaces(&unbounded, &quiet).err(),
        Some(ReferenceError::Unbounded)
    );
    assert_eq!(
        Tracer::new(&Scene::default()).err(),
        Some(ReferenceError::EmptyScene)
    );
    let off = Point {
        name: "in the air".into(),
        position: DVec3::new(0.25, 0.25, 0.25),
        normal: DVec3::Y,
    };
    assert!(matches!(
        tracer.points(&[off], &samples(4), &quiet),
        Err(ReferenceError::PointOffSurface { index: 0, .. })
    ));
    // Without emitters: zeros, exactly, and the tracer says there is nothing to light.
    let mut dark = scene.clone();
    for s in &mut dark.surfaces {
        s.emission = [0.0; 3];
    }
    let tracer = Tracer::new(&dark).expect("tracer");
    assert!(!tracer.has_emitters());
    let (s, _) = tracer.surfaces(&samples(64), &quiet).expect("trace");
    assert!(
        s.iter()
            .all(|s| s.estimate.mean == [0.0; 3] && s.estimate.se == [0.0; 3])
    );
}

#[test]
fn one_and_two_threads_give_identical_estimates() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let tracer = Tracer::new(&scene).expect("tracer");
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| {
                let (s, _) = tracer.surfaces(&samples(700), &quiet).expect("surfaces");
                let cam = scene.camera.expect("camera");
                let (img, _) = tracer
                    .image(&cam, 16, 16, &samples(3), &quiet)
                    .expect("image");
                (s, img)
            })
    };
    assert_eq!(run(1), run(2));
}

#[test]
fn a_target_error_stops_the_estimate_when_met() {
    // The furnace, and outside it a square facing away that no light reaches.
    let mut scene = furnace(0.5, 1.0);
    let dark = quad(
        DVec3::new(0.0, 3.0, 0.0),
        DVec3::new(0.0, 0.0, 1.0),
        DVec3::new(1.0, 0.0, 0.0),
    );
    add_surface(&mut scene, "dark", [0.5; 3], [0.0; 3], &dark);
    let tracer = Tracer::new(&scene).expect("scene");
    let p = Params {
        samples: None,
        target_error: Some(0.02),
        time_limit: Some(Duration::from_secs(60)),
        seed: 3,
    };
    let (s, run) = tracer.surfaces(&p, &quiet).expect("trace");
    assert_eq!(run.stopped, Stopped::Target);
    assert!(s[0].estimate.rel_error() <= 0.02);
    assert!(run.rel_error <= 0.02);
    // All-zero paths have no spread, which proves little: at least 4096 before stopping.
    assert_eq!(s[1].estimate.mean, [0.0; 3]);
    assert!(s[1].estimate.samples >= 4096, "{:?}", s[1].estimate);
}

#[test]
fn a_surface_far_darker_than_the_rest_is_held_to_an_absolute_error() {
    // The furnace's six walls as six surfaces (ρ 0.5, emitting 1: radiosity 2), and inside it
    // a square facing up half a millimetre under a black cover facing down: only grazing light
    // through the rim reaches the square, about 10⁻⁴ of the walls'. Its relative error would
    // take far longer to reach the target than the walls'; it is held instead to the target
    // times a thousandth of the median surface's mean.
    let mut scene = Scene::default();
    let walls = box_triangles(DVec3::ZERO, DVec3::ONE, true);
    for (k, face) in walls.chunks(2).enumerate() {
        add_surface(&mut scene, &format!("wall{k}"), [0.5; 3], [1.0; 3], face);
    }
    let dark = quad(
        DVec3::new(0.1, 0.5, 0.1),
        DVec3::new(0.0, 0.0, 0.8),
        DVec3::new(0.8, 0.0, 0.0),
    );
    add_surface(&mut scene, "dark", [0.5; 3], [0.0; 3], &dark);
    let cover = quad(
        DVec3::new(0.1, 0.5005, 0.1),
        DVec3::new(0.8, 0.0, 0.0),
        DVec3::new(0.0, 0.0, 0.8),
    );
    add_surface(&mut scene, "cover", [0.0; 3], [0.0; 3], &cover);
    let tracer = Tracer::new(&scene).expect("scene");
    let t = 0.02;
    let p = Params {
        samples: None,
        target_error: Some(t),
        time_limit: Some(Duration::from_secs(120)),
        seed: 5,
    };
    let (s, run) = tracer.surfaces(&p, &quiet).expect("trace");
    assert_eq!(run.stopped, Stopped::Target, "{run:?}");
    assert!(run.rel_error <= t, "{run:?}");
    let wall = s[0].estimate.magnitude();
    let d = &s[6].estimate;
    // Lit, but far below a thousandth of the walls: its own relative error was not reached,
    // its absolute one was.
    assert!(d.mean[0] > 0.0, "{d:?}");
    assert!(d.magnitude() < DARK * wall, "{d:?} against {wall}");
    assert!(d.rel_error() > t, "{d:?}");
    assert!(d.rel_error_above(DARK * wall) <= t, "{d:?}");
    for w in &s[..6] {
        assert!(w.estimate.rel_error() <= t, "{:?}", w.estimate);
    }
}

#[test]
fn cornell_box_points_agree_with_mitsuba() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let tracer = Tracer::new(&scene).expect("tracer");
    let refs = radiant_radiosity::metrics::parse_point_csv(
        radiant_radiosity::metrics::CORNELL_POINTS_RGB,
        1e-3,
    )
    .expect("points");
    let pts: Vec<Point> = refs
        .iter()
        .map(|r| Point {
            name: r.name.clone(),
            position: r.position,
            normal: r.normal,
        })
        .collect();
    let n = 65_536;
    let (ours, _) = tracer.points(&pts, &samples(n), &quiet).expect("trace");
    // The file gives no standard errors: Mitsuba's radiance meters trace paths much like ours,
    // so take our per-path spread at their 2^20 paths.
    let mitsuba_paths = (1u64 << 20) as f64;
    let (mut z2, mut count, mut worst) = (0.0, 0, 0.0f64);
    for (r, e) in refs.iter().zip(&ours) {
        for c in 0..3 {
            let se_m = e.se[c] * (n as f64 / mitsuba_paths).sqrt();
            let z = (e.mean[c] - r.radiosity[c]) / (e.se[c].powi(2) + se_m.powi(2)).sqrt();
            println!(
                "{} {c}: ours {:.5} mitsuba {:.5} z {z:+.2}",
                r.name, e.mean[c], r.radiosity[c]
            );
            z2 += z * z;
            count += 1;
            worst = worst.max(z.abs());
        }
    }
    let chi = z2 / count as f64;
    println!("{count} values, mean z² {chi:.2}, worst |z| {worst:.2}");
    assert_eq!(count, 72, "24 points × 3 channels");
    assert!(worst <= 3.5, "worst |z| {worst}");
    assert!((0.4..=1.8).contains(&chi), "mean z² {chi}");
}

#[test]
fn cornell_box_image_agrees_with_mitsuba_within_noise() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let tracer = Tracer::new(&scene).expect("tracer");
    let reference = image::load_from_memory(include_bytes!(
        "../../../assets/reference/cornell_box_mitsuba_128.exr"
    ))
    .expect("reference EXR")
    .to_rgb32f();
    let (w, h) = (reference.width(), reference.height());
    let spp = 64;
    let cam = scene.camera.expect("camera");
    let (img, run) = tracer
        .image(&cam, w, h, &samples(spp), &quiet)
        .expect("image");
    // Mitsuba: 16 384 samples per pixel, the same per-path spread as ours assumed.
    let k = (spp as f64 / 16_384.0).sqrt();
    let (mut count, mut sum_ours, mut sum_ref, mut var_sum) = (0, 0.0, 0.0, 0.0);
    let mut flat = 0;
    let mut d2_sum = 0.0;
    for (p, r) in img.pixels.iter().zip(reference.pixels()) {
        for c in 0..3 {
            let want = r.0[c] as f64;
            let sigma2 = p.se[c].powi(2) * (1.0 + k * k);
            sum_ours += p.mean[c];
            sum_ref += want;
            var_sum += sigma2;
            if sigma2 > 0.0 {
                d2_sum += (p.mean[c] - want).powi(2);
                count += 1;
            } else if (p.mean[c] - want).abs() > 1e-6 {
                // Every one of our paths found the same value but Mitsuba's differs: a pixel
                // where most paths find nothing (surfaces facing the open front send most of
                // their bounces out of the box) and all of ours did. Rare, or a bug.
                flat += 1;
            }
        }
    }
    assert!(
        flat <= 16,
        "{flat} pixel channels where all our paths agreed but Mitsuba's differs"
    );
    // Pooled over pixels: Σ (ours − Mitsuba)² against Σ σ². Per-pixel z² would overstate:
    // 64 paths of a skewed distribution often underestimate their own spread.
    let pooled = d2_sum / var_sum;
    let bias = (sum_ours - sum_ref) / var_sum.sqrt();
    println!(
        "{count} pixel channels ({} flat), squared differences / variances {pooled:.3}, image sum ours {sum_ours:.2} Mitsuba {sum_ref:.2} ({bias:+.2} σ); {:.2} s",
        flat, run.seconds
    );
    // Per-pixel differences are what the standard errors say, and the image as a whole is
    // unbiased.
    assert!(
        (0.85..=1.15).contains(&pooled),
        "squared differences / variances {pooled}"
    );
    assert!(bias.abs() <= 4.0, "image sum off by {bias} σ");
}

/// Probes: irradiance at points anywhere, for any normal.
fn probe(name: &str, position: DVec3, normal: DVec3) -> Point {
    Point {
        name: name.into(),
        position,
        normal,
    }
}

#[test]
fn a_probe_in_a_furnace_reads_pi_e_over_one_minus_rho_for_every_normal() {
    let (rho, e) = (0.5, 1.0);
    let scene = furnace(rho, e);
    let tracer = Tracer::new(&scene).expect("furnace");
    // Inside the furnace cube: its centre and a point near a corner, along the six axes and a
    // tilted normal of length 3 (a probe's normal need not be unit).
    let (lo, hi) = scene.triangles.iter().flat_map(|t| t.vertices).fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), v| (lo.min(v), hi.max(v)),
    );
    let normals = [
        DVec3::X,
        DVec3::NEG_X,
        DVec3::Y,
        DVec3::NEG_Y,
        DVec3::Z,
        DVec3::NEG_Z,
        DVec3::new(1.0, 2.0, -2.0),
    ];
    let mut probes = Vec::new();
    for (k, at) in [0.5, 0.1].into_iter().enumerate() {
        for (j, n) in normals.iter().enumerate() {
            probes.push(probe(&format!("{k}/{j}"), lo + (hi - lo) * at, *n));
        }
    }
    let (est, run) = tracer
        .probes(&probes, &samples(8_000), &quiet)
        .expect("trace");
    assert_eq!(run.paths, 8_000 * probes.len() as u64);
    let want = PI * e / (1.0 - rho);
    for (p, e) in probes.iter().zip(&est) {
        within(e, [want; 3], 4.0, &p.name);
        assert!(e.rel_error() < 0.02, "{}: {e:?}", p.name);
    }
}

#[test]
fn a_probe_under_a_point_light_reads_the_inverse_square_and_its_shadow() {
    // Probes 0.5 above the floor, facing up (nothing above but the light): E = I cos θ / d²
    // exactly, no noise; under the occluder (height 1, |x| < 0.5 shadows |x| < 0.75 here) 0.
    let xs = [0.0, 0.5, 1.0, 1.5];
    let probes: Vec<Point> = xs
        .iter()
        .map(|&x| probe(&format!("x={x}"), DVec3::new(x, 0.5, 0.0), DVec3::Y * 2.0))
        .collect();
    for occluder in [false, true] {
        let tracer = Tracer::new(&lit_floor(occluder)).expect("scene");
        let (est, _) = tracer
            .probes(&probes, &samples(256), &quiet)
            .expect("trace");
        for (x, e) in xs.iter().zip(&est) {
            let d = (x * x + 1.5f64 * 1.5).sqrt();
            let shadowed = occluder && *x < 0.75;
            let irr = if shadowed {
                0.0
            } else {
                100.0 * 1.5 / (d * d * d)
            };
            for (c, colour) in [1.0, 0.5, 0.25].into_iter().enumerate() {
                let want = irr * colour;
                assert!(
                    (e.mean[c] - want).abs() <= 1e-9 * want.max(1.0),
                    "occluder {occluder}, x {x}: {:?} vs {irr} × colour",
                    e.mean
                );
            }
        }
    }
}

#[test]
fn bad_probes_are_typed_errors() {
    let tracer = Tracer::new(&lit_floor(false)).expect("scene");
    for (p, what) in [
        (probe("zero", DVec3::Y, DVec3::ZERO), "normal"),
        (
            probe("nan", DVec3::Y, DVec3::new(f64::NAN, 1.0, 0.0)),
            "normal",
        ),
        (
            probe("inf", DVec3::new(f64::INFINITY, 0.0, 0.0), DVec3::Y),
            "position",
        ),
        (
            probe("remote", DVec3::new(1e12, 0.0, 0.0), DVec3::Y),
            "million",
        ),
    ] {
        let e = tracer
            .probes(std::slice::from_ref(&p), &samples(16), &quiet)
            .expect_err(&p.name);
        assert!(
            matches!(&e, ReferenceError::InvalidProbe { index: 0, name, .. } if *name == p.name)
                && e.to_string().contains(what),
            "{e}"
        );
    }
}
