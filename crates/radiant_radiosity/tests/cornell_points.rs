//! The Cornell box at default settings against Mitsuba 3 radiance meters at 24 surface points
//! (assets/reference, 2^20 samples each): the RGB bake against the RGB path tracer, and the
//! 32-band spectral solve with the measured spectra against the spectral path tracer. Points
//! are compared with the element that contains them, so the discretisation shows, not only
//! the surface means. Then the spectral effect alone: our spectral/RGB ratio against
//! Mitsuba's, where the discretisation cancels (16 bands: 0.7 % mean, 3.9 % max on the
//! saturated walls; 32 bands: 0.3 %, 1.2 %).

mod common;

use radiant_radiosity::BakeParams;
use radiant_radiosity::metrics::{
    CORNELL_POINTS_RGB, CORNELL_POINTS_SPECTRAL, compare_points, compare_points_with, element_at,
    parse_point_csv,
};
use radiant_radiosity::spectral::solve_spectral;

#[test]
fn cornell_box_matches_path_traced_points_in_rgb_and_spectral() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let r = common::bake(&scene, &BakeParams::default());
    let rgb_refs = parse_point_csv(CORNELL_POINTS_RGB, 1e-3).expect("rgb points");
    assert_eq!(rgb_refs.len(), 24);
    // Every point lies on exactly the surface it names.
    for p in &rgb_refs {
        assert!(
            element_at(&r.mesh, p.position, p.normal).is_some(),
            "{} is on no element",
            p.name
        );
    }
    let rgb = compare_points(&r.mesh, &r.radiosity, &rgb_refs, None).expect("compare");
    let sp = solve_spectral(
        &r.system,
        &r.mesh,
        &scene.surfaces,
        &common::cornell_spectra(),
        32,
        1e-6,
    )
    .expect("spectral");
    let spec_refs = parse_point_csv(CORNELL_POINTS_SPECTRAL, 1e-3).expect("spectral points");
    let spectral =
        compare_points(&r.mesh, &sp.radiosity, &spec_refs, Some("light_centre")).expect("compare");
    for (label, c) in [("RGB", &rgb), ("spectral", &spectral)] {
        eprintln!(
            "{label} vs Mitsuba at {} points: mean {:.2} %, max {:.2} % (scale {:.4})",
            c.points.len(),
            c.mean_rel * 100.0,
            c.max_rel * 100.0,
            c.scale
        );
        for p in &c.points {
            eprintln!("  {:24} {:6.2} %", p.name, p.rel * 100.0);
        }
    }
    assert!(
        rgb.mean_rel <= 0.03,
        "RGB mean {:.2} %",
        rgb.mean_rel * 100.0
    );
    assert!(rgb.max_rel <= 0.10, "RGB max {:.2} %", rgb.max_rel * 100.0);
    assert!(
        spectral.mean_rel <= 0.03,
        "spectral mean {:.2} %",
        spectral.mean_rel * 100.0
    );
    assert!(
        spectral.max_rel <= 0.10,
        "spectral max {:.2} %",
        spectral.max_rel * 100.0
    );
    // Isolate the spectral effect: per point and channel, how much the spectral answer differs
    // from the RGB answer, in our bakes and in Mitsuba's. The discretisation error (the same
    // mesh in both of ours) cancels; what remains is how well we reproduce "spectra do not
    // multiply like RGB triples".
    // Per point, channel errors weighted by the channel's share of the RGB reference: a
    // channel near zero (blue on the green wall) has a ratio of two noisy small numbers.
    let mut worst: f64 = 0.0;
    let mut sum = 0.0;
    for p in &spectral.points {
        let q = rgb
            .points
            .iter()
            .find(|q| q.name == p.name)
            .expect("same points");
        let total: f64 = q.reference.iter().sum();
        let e: f64 = (0..3)
            .map(|c| {
                let ours = p.ours[c] / q.ours[c];
                let theirs = p.reference[c] / q.reference[c];
                (ours - theirs).abs() / theirs * q.reference[c] / total
            })
            .sum();
        eprintln!("  ratio error {:24} {:.2} %", p.name, e * 100.0);
        worst = worst.max(e);
        sum += e;
    }
    let mean = sum / spectral.points.len() as f64;
    eprintln!(
        "spectral/RGB ratio, ours vs Mitsuba's: mean {:.2} %, max {:.2} %",
        mean * 100.0,
        worst * 100.0
    );
    assert!(mean <= 0.01, "ratio mean {:.2} %", mean * 100.0);
    assert!(worst <= 0.02, "ratio max {:.2} %", worst * 100.0);
}

#[test]
fn the_smooth_field_is_closer_to_the_path_tracer_at_the_points_than_the_elements() {
    // Light averaged at element vertices and interpolated (radiosity::smooth) against the same
    // meters: measured 0.63 % mean, 1.78 % max (the elements themselves: 2.11 %, 6.99 %).
    use radiant_radiosity::smooth::SmoothField;
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let r = common::bake(&scene, &BakeParams::default());
    let refs = parse_point_csv(CORNELL_POINTS_RGB, 1e-3).expect("rgb points");
    let field = SmoothField::new(&r.mesh, &r.system, &scene.surfaces, &r.radiosity);
    let smooth = compare_points_with(&refs, None, |p| {
        field.radiosity_at(&r.mesh, p.position, p.normal)
    })
    .expect("compare");
    let (mean, max) = (smooth.mean_rel, smooth.max_rel);
    eprintln!(
        "smooth field at 24 points: mean {:.2} %, max {:.2} %",
        mean * 100.0,
        max * 100.0
    );
    let flat = compare_points(&r.mesh, &r.radiosity, &refs, None).expect("compare");
    assert!(
        mean <= 0.01 && max <= 0.03,
        "mean {:.2} %, max {:.2} %",
        mean * 100.0,
        max * 100.0
    );
    assert!(mean < flat.mean_rel && max < flat.max_rel);
}
