//! Stiff and extreme cases: shared edges, areas spanning 10^12, emitters from 1e-3 to 1e6,
//! extreme scales and far-off origins, bad materials. Nothing panics, nothing is NaN.

mod common;

use glam::DVec3;
use radiant_radiosity::scenes::{add_surface, box_triangles, quad};
use radiant_radiosity::{
    Bake, BakeError, BakeParams, FormFactorKind, SolveError, SolverKind, SolverParams,
};
use radiant_scene::Scene;

fn all_finite(r: &radiant_radiosity::BakeResult) {
    assert!(
        r.radiosity
            .iter()
            .flatten()
            .all(|v| v.is_finite() && *v >= 0.0),
        "NaN, infinite or negative radiosity"
    );
    assert!(
        r.system
            .links
            .ff
            .iter()
            .all(|f| f.is_finite() && *f >= 0.0 && *f <= 1.0),
        "a form factor outside [0, 1]"
    );
}

#[test]
fn edge_sharing_patches_give_bounded_form_factors() {
    // A folded strip: every pair of neighbours shares an edge, at 90, 45 and 135 degrees.
    let mut s = Scene::default();
    let o = DVec3::ZERO;
    add_surface(
        &mut s,
        "floor",
        [0.8; 3],
        [0.0; 3],
        &quad(o, DVec3::X, DVec3::Y),
    );
    add_surface(
        &mut s,
        "wall",
        [0.8; 3],
        [1.0; 3],
        &quad(o, DVec3::Y, DVec3::Z),
    );
    add_surface(
        &mut s,
        "slant",
        [0.8; 3],
        [0.5; 3],
        &quad(DVec3::X, DVec3::Y, DVec3::new(-0.7, 0.0, 0.7)),
    );
    add_surface(
        &mut s,
        "wide",
        [0.8; 3],
        [0.0; 3],
        &quad(DVec3::Y, DVec3::X, DVec3::new(0.0, 0.7, 0.7)),
    );
    for ff in FormFactorKind::ALL {
        let mut p = BakeParams::default();
        p.mesh.patch_size = 0.25;
        p.form_factors = ff;
        p.ff.hemicube_resolution = 32;
        let r = common::bake(&s, &p);
        all_finite(&r);
        for i in 0..r.system.len() {
            let sum = r.system.links.row_sum(i);
            assert!(sum <= 1.0 + 1e-3, "{ff:?}: row {i} sums to {sum}");
        }
    }
}

#[test]
fn areas_spanning_ten_to_the_twelve() {
    // A 1000 x 1000 emitting floor and a 1e-3 x 1e-3 reflector facing it at height 1: the
    // reflector sees almost only the floor, so its radiosity is rho * F * 1 with F the point
    // form factor to a 1000 x 1000 square at distance 1 (a hair under 1).
    let mut s = Scene::default();
    let big = 1000.0;
    add_surface(
        &mut s,
        "floor",
        [0.5; 3],
        [1.0; 3],
        &quad(
            DVec3::new(-big / 2.0, -big / 2.0, 0.0),
            DVec3::X * big,
            DVec3::Y * big,
        ),
    );
    let e = 1e-3;
    add_surface(
        &mut s,
        "speck",
        [0.25; 3],
        [0.0; 3],
        &quad(
            DVec3::new(-e / 2.0, -e / 2.0, 1.0),
            DVec3::Y * e,
            DVec3::X * e,
        ),
    );
    let areas: Vec<f64> = s.triangles.iter().map(|t| t.area()).collect();
    let ratio = areas.iter().cloned().fold(0.0, f64::max)
        / areas.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(ratio >= 1e12, "area ratio {ratio:e}");
    // Point to a square of half-side h at distance 1 (Howell B-3, four corners).
    let h: f64 = big / 2.0;
    let x = h;
    let corner = 1.0 / (2.0 * std::f64::consts::PI)
        * 2.0
        * (x / (1.0 + x * x).sqrt() * (x / (1.0 + x * x).sqrt()).atan());
    let f = 4.0 * corner;
    for solver in [
        SolverKind::Direct,
        SolverKind::GaussSeidel,
        SolverKind::Southwell,
    ] {
        let p = BakeParams {
            solver,
            solver_params: SolverParams {
                tolerance: 1e-8,
                ..Default::default()
            },
            ..Default::default()
        };
        let r = common::bake(&s, &p);
        all_finite(&r);
        let speck = common::surface(&r, "speck").mean[0];
        let want = 0.25 * f;
        assert!(
            (speck - want).abs() < 1e-6,
            "{solver:?}: speck {speck} vs {want}"
        );
        let floor = common::surface(&r, "floor").mean[0];
        assert!((floor - 1.0).abs() < 1e-9, "{solver:?}: floor {floor}");
    }
}

#[test]
fn emitters_from_one_thousandth_to_a_million_superpose() {
    // Two emitters nine orders of magnitude apart in a box: with uniform links (independent of
    // the emission) the solution is linear in the emission, so both-on equals the sum of
    // each-alone, and the dim emitter is not lost in rounding.
    let make = |dim: f64, bright: f64| {
        let mut s = Scene::default();
        add_surface(
            &mut s,
            "box",
            [0.7; 3],
            [0.0; 3],
            &box_triangles(DVec3::ZERO, DVec3::ONE, true),
        );
        add_surface(
            &mut s,
            "dim",
            [0.5; 3],
            [dim; 3],
            &quad(DVec3::new(0.1, 0.1, 0.01), DVec3::X * 0.2, DVec3::Y * 0.2),
        );
        add_surface(
            &mut s,
            "bright",
            [0.5; 3],
            [bright; 3],
            &quad(DVec3::new(0.6, 0.6, 0.99), DVec3::Y * 0.2, DVec3::X * 0.2),
        );
        s
    };
    let mut p = BakeParams::default();
    p.mesh.patch_size = 0.5;
    p.mesh.element_levels = 1;
    p.links.hierarchical = false;
    p.solver = SolverKind::Direct;
    let both = common::bake(&make(1e-3, 1e6), &p);
    let dim = common::bake(&make(1e-3, 0.0), &p);
    let bright = common::bake(&make(0.0, 1e6), &p);
    all_finite(&both);
    for i in 0..both.radiosity.len() {
        let sum = dim.radiosity[i][0] + bright.radiosity[i][0];
        let got = both.radiosity[i][0];
        assert!(
            (got - sum).abs() <= 1e-9 * sum.max(1e-300),
            "element {i}: {got} vs {sum}"
        );
    }
    assert!(common::surface(&both, "dim").mean[0] >= 1e-3);
    // The iterative solvers agree too, at the bright scale.
    for solver in [
        SolverKind::GaussSeidel,
        SolverKind::Southwell,
        SolverKind::Jacobi,
    ] {
        p.solver = solver;
        p.solver_params.tolerance = 1e-8;
        let r = common::bake(&make(1e-3, 1e6), &p);
        all_finite(&r);
        let e = radiant_radiosity::metrics::compare_elements(
            &r.system.area,
            &r.radiosity,
            &both.radiosity,
        );
        assert!(e.rel_rms < 1e-6, "{solver:?}: {e:?}");
    }
}

#[test]
fn cornell_box_is_the_same_at_any_scale_and_place() {
    // Positions far from the origin are rounded (by ~1e-7 of the box) before the bake sees them,
    // and a visibility ray that grazes an edge can flip with them: the tolerance is 1e-3.
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let mut p = BakeParams::default();
    p.mesh.patch_size = 0.3;
    // Solved far below the comparison's 1e-3: the solver stops at step boundaries set by wall
    // time, so at the default tolerance two bakes of one system can differ by more than 1e-3
    // on a dark face when the machine is loaded (seen once in a loaded test run: 0.16 %).
    p.solver_params.tolerance = 1e-8;
    let base = common::bake(&scene, &p);
    for (scale, offset) in [
        (1e-4, DVec3::new(1e5, -2e5, 3e5)),
        (1e4, DVec3::new(-3e7, 1e7, 5e6)),
        (1.0, DVec3::splat(1e6)),
    ] {
        let moved = scene.transformed(scale, offset);
        let mut q = p;
        q.mesh.patch_size = p.mesh.patch_size * scale;
        let r = common::bake(&moved, &q);
        all_finite(&r);
        for (a, b) in base.surfaces.iter().zip(&r.surfaces) {
            assert_eq!(a.name, b.name);
            assert!(
                (b.area / (scale * scale) - a.area).abs() < 1e-5 * a.area,
                "area of {}",
                a.name
            );
            for c in 0..3 {
                let rel = (a.mean[c] - b.mean[c]).abs() / a.mean[c].abs().max(1e-12);
                assert!(
                    rel < 1e-3,
                    "scale {scale:e}, offset {offset}: {} channel {c}: {} vs {}",
                    a.name,
                    a.mean[c],
                    b.mean[c]
                );
            }
        }
    }
}

#[test]
fn bad_materials_and_parameters_are_typed_errors() {
    let mut s = Scene::default();
    add_surface(
        &mut s,
        "q",
        [1.5, 0.5, 0.5],
        [0.0; 3],
        &quad(DVec3::ZERO, DVec3::X, DVec3::Y),
    );
    assert!(matches!(
        Bake::new(&s, &BakeParams::default()),
        Err(BakeError::InvalidMaterial { .. })
    ));
    s.surfaces[0].reflectance = [f64::NAN; 3];
    assert!(matches!(
        Bake::new(&s, &BakeParams::default()),
        Err(BakeError::InvalidMaterial { .. })
    ));
    s.surfaces[0].reflectance = [0.5; 3];
    s.surfaces[0].emission = [-1.0, 0.0, 0.0];
    assert!(matches!(
        Bake::new(&s, &BakeParams::default()),
        Err(BakeError::InvalidMaterial { .. })
    ));
    s.surfaces[0].emission = [1.0; 3];
    let mut p = BakeParams::default();
    p.solver_params.tolerance = f64::NAN;
    assert!(matches!(
        Bake::new(&s, &p),
        Err(BakeError::InvalidParameter(_))
    ));
    assert!(matches!(
        Bake::new(&Scene::default(), &BakeParams::default()),
        Err(BakeError::InvalidScene(_))
    ));
    // Reflectance 1 in a closed box: the direct solve reports a singular system, never NaN.
    let mut closed = Scene::default();
    add_surface(
        &mut closed,
        "walls",
        [1.0; 3],
        [1.0; 3],
        &box_triangles(DVec3::ZERO, DVec3::ONE, true),
    );
    let mut p = BakeParams::default();
    p.mesh.patch_size = 0.5;
    p.mesh.element_levels = 0;
    p.solver = SolverKind::Direct;
    match Bake::new(&closed, &p)
        .expect("prepares")
        .run_to_end(&mut |_| {})
    {
        Err(BakeError::Solve(SolveError::Singular)) => {}
        Ok(r) => panic!("expected a singular system, got {:?}", &r.radiosity[..2]),
        Err(e) => panic!("expected a singular system, got {e}"),
    }
    // Iteratively it does not converge, and says so without producing NaN.
    p.solver = SolverKind::GaussSeidel;
    p.time_limit = Some(std::time::Duration::from_millis(200));
    let r = common::bake(&closed, &p);
    assert!(!r.report.converged);
    assert!(r.radiosity.iter().flatten().all(|v| v.is_finite()));
}

#[test]
fn bad_input_errors_carry_the_numbers() {
    use radiant_radiosity::metrics::{ReferenceFileError, parse_reference_csv};
    use radiant_radiosity::{MaterialError, ParameterError, SceneError};
    let mut s = Scene::default();
    let floor = quad(DVec3::ZERO, DVec3::X, DVec3::Z);
    add_surface(&mut s, "floor", [0.5; 3], [1.0; 3], &floor);
    let mut p = BakeParams::default();
    p.links.refinement = -2.0;
    match Bake::new(&s, &p) {
        Err(BakeError::InvalidParameter(ParameterError::OutOfRange { name, value, .. })) => {
            assert_eq!((name, value), ("refinement", -2.0));
        }
        other => panic!("expected an out-of-range refinement, got {:?}", other.err()),
    }
    s.surfaces[0].reflectance = [1.5, 0.5, 0.5];
    assert!(matches!(
        Bake::new(&s, &BakeParams::default()),
        Err(BakeError::InvalidMaterial {
            what: MaterialError::Reflectance([1.5, 0.5, 0.5]),
            ..
        })
    ));
    s.surfaces[0].reflectance = [0.5; 3];
    s.triangles[1].surface = 7;
    assert_eq!(
        Bake::new(&s, &BakeParams::default())
            .err()
            .map(|e| e.to_string()),
        Some(
            BakeError::from(SceneError::UnknownSurface {
                triangle: 1,
                surface: 7,
                surfaces: 1,
            })
            .to_string()
        )
    );
    let csv = "surface,area,b_r,b_g,b_b\nfloor,1,0.5,0.5,0.5\nwall,1,0.5,x,0.5\n";
    assert!(matches!(
        parse_reference_csv(csv),
        Err(BakeError::Reference(ReferenceFileError::BadNumber {
            row: 3,
            column: 4
        }))
    ));
}
