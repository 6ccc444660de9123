//! Form factors against closed forms from Howell's catalogue (computed here, not typed in),
//! for each method with its stated tolerance; reciprocity; row sums in closed enclosures.

mod common;

use std::f64::consts::PI;

use common::{form_factor, rect_z};
use glam::DVec3;
use radiant_radiosity::scenes::{box_triangles, furnace, quad};
use radiant_radiosity::{Bake, BakeParams, FormFactorKind};

/// Howell C-11: identical, parallel, directly opposed rectangles `a × b` at distance `c`.
fn parallel_rectangles(a: f64, b: f64, c: f64) -> f64 {
    let (x, y) = (a / c, b / c);
    let (x2, y2) = (x * x, y * y);
    2.0 / (PI * x * y)
        * ((((1.0 + x2) * (1.0 + y2)) / (1.0 + x2 + y2)).sqrt().ln()
            + x * (1.0 + y2).sqrt() * (x / (1.0 + y2).sqrt()).atan()
            + y * (1.0 + x2).sqrt() * (y / (1.0 + x2).sqrt()).atan()
            - x * x.atan()
            - y * y.atan())
}

/// Howell C-14: from a `w × l` rectangle to a perpendicular `h × l` one sharing the edge `l`.
fn perpendicular_rectangles(w: f64, h: f64, l: f64) -> f64 {
    let (w, h) = (w / l, h / l);
    let (w2, h2) = (w * w, h * h);
    let a = (1.0 + w2) * (1.0 + h2) / (1.0 + w2 + h2);
    let b = (w2 * (1.0 + w2 + h2) / ((1.0 + w2) * (w2 + h2))).powf(w2);
    let c = (h2 * (1.0 + h2 + w2) / ((1.0 + h2) * (h2 + w2))).powf(h2);
    1.0 / (PI * w)
        * (w * (1.0 / w).atan() + h * (1.0 / h).atan()
            - (h2 + w2).sqrt() * (1.0 / (h2 + w2).sqrt()).atan()
            + 0.25 * (a * b * c).ln())
}

/// Howell C-41: coaxial parallel discs, radius `ri` to radius `rj` at distance `d`.
fn coaxial_discs(ri: f64, rj: f64, d: f64) -> f64 {
    let (ri, rj) = (ri / d, rj / d);
    let x = 1.0 + (1.0 + rj * rj) / (ri * ri);
    0.5 * (x - (x * x - 4.0 * (rj / ri).powi(2)).sqrt())
}

/// A regular `n`-gon of the disc's area, at height `z`, facing up or down, as a triangle fan.
fn disc(r: f64, z: f64, up: bool, n: usize) -> Vec<[DVec3; 3]> {
    // Same area as the disc: r_poly² n sin(2π/n) / 2 = π r².
    let rp = r * (2.0 * PI / (n as f64 * (2.0 * PI / n as f64).sin())).sqrt();
    let p = |k: usize| {
        let t = 2.0 * PI * k as f64 / n as f64;
        DVec3::new(rp * t.cos(), rp * t.sin(), z)
    };
    let c = DVec3::new(0.0, 0.0, z);
    (0..n)
        .map(|k| {
            if up {
                [c, p(k), p(k + 1)]
            } else {
                [c, p(k + 1), p(k)]
            }
        })
        .collect()
}

/// (method, relative tolerance, element levels): analytic is exact per point (midpoint rule
/// over receivers); the hemicube (128 pixels) aliases and the ray-cast method approximates each
/// sample by a disc; Monte Carlo (1024 rays per element, some 500 elements) is held to about
/// 3 sigma of its noise.
const METHODS: [(FormFactorKind, f64, u8); 4] = [
    (FormFactorKind::Analytic, 0.003, 2),
    (FormFactorKind::Hemicube, 0.015, 1),
    (FormFactorKind::RayCast, 0.02, 1),
    (FormFactorKind::MonteCarlo, 0.015, 1),
];

#[test]
fn parallel_rectangles_match_howell() {
    let (a, b, c) = (1.0, 2.0, 1.0);
    let exact = parallel_rectangles(a, b, c);
    for (m, tol, levels) in METHODS {
        let got = form_factor(
            &rect_z(a, b, 0.0, true),
            &rect_z(a, b, c, false),
            m,
            0.5,
            levels,
        );
        assert!(
            (got - exact).abs() <= tol * exact,
            "{m:?}: {got} vs Howell C-11 {exact} (tolerance {tol})"
        );
    }
}

#[test]
fn perpendicular_rectangles_sharing_an_edge_match_howell() {
    let (w, h, l) = (1.0, 0.5, 2.0);
    // Floor w × l in z = 0 facing up, wall h × l in x = 0 facing +x, sharing the edge on the y axis.
    let floor = quad(
        DVec3::ZERO,
        DVec3::new(w, 0.0, 0.0),
        DVec3::new(0.0, l, 0.0),
    )
    .to_vec();
    let wall = quad(
        DVec3::ZERO,
        DVec3::new(0.0, l, 0.0),
        DVec3::new(0.0, 0.0, h),
    )
    .to_vec();
    let exact = perpendicular_rectangles(w, h, l);
    for (m, tol, levels) in METHODS {
        let got = form_factor(&floor, &wall, m, 0.5, levels);
        assert!(got.is_finite() && got <= 1.0);
        // The shared edge makes the receiver's midpoint rule converge slowly: 1.5 × the tolerance.
        assert!(
            (got - exact).abs() <= 1.5 * tol * exact,
            "{m:?}: {got} vs Howell C-14 {exact}"
        );
    }
}

#[test]
fn coaxial_discs_match_howell() {
    let (ri, rj, d) = (0.5, 1.0, 1.0);
    let exact = coaxial_discs(ri, rj, d);
    for (m, tol, levels) in METHODS {
        let got = form_factor(
            &disc(ri, 0.0, true, 64),
            &disc(rj, d, false, 64),
            m,
            0.5,
            levels,
        );
        // The 64-gon of equal area differs from the disc by well under 0.1 %.
        assert!(
            (got - exact).abs() <= (tol + 1e-3) * exact,
            "{m:?}: {got} vs Howell C-41 {exact}"
        );
    }
}

#[test]
fn small_element_to_rectangle_matches_howell() {
    // Howell B-3 with a receiver much smaller than the distance: element at a corner.
    let (a, b, c) = (2.0f64, 1.0f64, 1.5f64);
    let (x, y) = (a / c, b / c);
    let exact = 1.0 / (2.0 * PI)
        * (x / (1.0 + x * x).sqrt() * (y / (1.0 + x * x).sqrt()).atan()
            + y / (1.0 + y * y).sqrt() * (x / (1.0 + y * y).sqrt()).atan());
    let e = 1e-3;
    let recv = quad(
        DVec3::new(-e / 2.0, -e / 2.0, 0.0),
        DVec3::new(e, 0.0, 0.0),
        DVec3::new(0.0, e, 0.0),
    )
    .to_vec();
    let src = rect_z(a, b, c, false);
    let got = form_factor(&recv, &src, FormFactorKind::Analytic, 10.0, 0);
    assert!(
        (got - exact).abs() < 1e-6 * exact.max(1.0) + 2e-3 * exact,
        "{got} vs {exact}"
    );
}

#[test]
fn reciprocity_holds() {
    let (a, b, c) = (1.0, 2.0, 1.0);
    // Unequal areas: a 1 × 2 rectangle below a 0.5 × 0.5 one.
    let big = rect_z(a, b, 0.0, true);
    let small: Vec<[DVec3; 3]> = rect_z(0.5, 0.5, c, false)
        .into_iter()
        .map(|t| t.map(|p| p + DVec3::new(0.25, 0.75, 0.0)))
        .collect();
    let (a_big, a_small) = (a * b, 0.25);
    for (m, tol, levels) in METHODS {
        let f_bs = form_factor(&big, &small, m, 0.5, levels);
        let f_sb = form_factor(&small, &big, m, 0.5, levels);
        let (l, r) = (a_big * f_bs, a_small * f_sb);
        assert!(
            (l - r).abs() <= 2.0 * tol * l,
            "{m:?}: A_big F = {l}, A_small F = {r}"
        );
    }
}

#[test]
fn rows_sum_to_one_in_a_closed_box() {
    // Every element of a closed box sees the whole box: rows sum to 1 for the methods that are
    // exact in that sense, and within the method's error for the ray-cast method.
    for (m, tol) in [
        (FormFactorKind::Analytic, 1e-6),
        (FormFactorKind::Hemicube, 1e-6),
        (FormFactorKind::MonteCarlo, 1e-6),
        (FormFactorKind::RayCast, 0.05),
    ] {
        let scene = furnace(0.5, 1.0);
        let mut p = BakeParams::default();
        p.mesh.patch_size = 0.5;
        p.mesh.element_levels = 1;
        p.form_factors = m;
        p.ff.hemicube_resolution = 64;
        let bake = Bake::new(&scene, &p).expect("bake");
        for i in 0..bake.system.len() {
            let s = bake.system.links.row_sum(i);
            assert!((s - 1.0).abs() <= tol, "{m:?}: row {i} sums to {s}");
        }
    }
    // A box with an inner box: still closed, rows still sum to 1 (occlusion moves energy, it
    // does not lose it).
    let mut scene = furnace(0.5, 1.0);
    radiant_radiosity::scenes::add_surface(
        &mut scene,
        "block",
        [0.5; 3],
        [0.0; 3],
        &box_triangles(DVec3::splat(0.3), DVec3::splat(0.6), false),
    );
    let mut p = BakeParams::default();
    p.mesh.patch_size = 0.25;
    p.form_factors = FormFactorKind::MonteCarlo;
    let bake = Bake::new(&scene, &p).expect("bake");
    for i in 0..bake.system.len() {
        let s = bake.system.links.row_sum(i);
        assert!((s - 1.0).abs() <= 1e-6, "row {i} sums to {s}");
    }
}
