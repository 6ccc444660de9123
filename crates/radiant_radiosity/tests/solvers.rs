//! Solvers: the lecture's two-patch example, the furnace, and agreement with the direct solve.

mod common;

use std::time::Duration;

use radiant_radiosity::scenes::furnace;
use radiant_radiosity::solvers::{
    Direct, GaussSeidel, Jacobi, Solver, SolverParams, Southwell, new_solver,
};
use radiant_radiosity::{BakeParams, FormFactorKind, SolverKind, System, metrics};

fn two_patches() -> System {
    // The lecture's example: rho = 0.5, E = (0, 0.8), F01 = F10 = 0.183 (equal areas).
    System::from_matrix(
        vec![1.0, 1.0],
        vec![[0.5; 3]; 2],
        vec![[0.0; 3], [0.8; 3]],
        &[vec![0.0, 0.183], vec![0.183, 0.0]],
    )
}

#[test]
fn lecture_two_patch_jacobi_iterates_and_fixed_point() {
    let sys = two_patches();
    let params = SolverParams {
        tolerance: 1e-12,
        ..Default::default()
    };
    let mut j = Jacobi::new(&sys, params);
    // The lecture's table, to its three decimals: (0, 0.8), (0.073, 0.8), (0.073, 0.807), (0.074, 0.807).
    let table = [[0.0, 0.8], [0.073, 0.8], [0.073, 0.807], [0.074, 0.807]];
    let mut b = j.radiosity(&sys);
    for (k, want) in table.iter().enumerate() {
        if k > 0 {
            j.step(&sys, Duration::ZERO).expect("step");
            b = j.radiosity(&sys);
        }
        for p in 0..2 {
            assert!(
                (b[p][0] - want[p]).abs() < 1.5e-3,
                "iterate {k}: {:?} vs {want:?}",
                [b[0][0], b[1][0]]
            );
        }
    }
    // The fixed point: B1 = 0.8 / (1 - 0.0915^2), B0 = 0.0915 B1.
    let b1 = 0.8 / (1.0 - 0.0915f64 * 0.0915);
    let b0 = 0.0915 * b1;
    assert!((b0 - 0.0738).abs() < 5e-5 && (b1 - 0.8068).abs() < 5e-5);
    for kind in SolverKind::ALL {
        let mut s = new_solver(kind, &sys, params);
        let mut p = s.step(&sys, Duration::from_secs(5)).expect("solve");
        while !p.converged {
            p = s.step(&sys, Duration::from_secs(5)).expect("solve");
        }
        let b = s.radiosity(&sys);
        assert!(
            (b[0][0] - b0).abs() < 1e-9 && (b[1][0] - b1).abs() < 1e-9,
            "{kind:?}: {:?}",
            b
        );
    }
}

#[test]
fn southwell_shoots_unshot_radiosity_not_total() {
    // After the first shot from patch 1 (the emitter), patch 0 holds rho F dB = 0.5 * 0.183 * 0.8
    // and patch 1 has no unshot energy left; shooting B instead of dB, or scaling by an area
    // ratio, would give other numbers (the lecture's pseudo-code does both).
    let sys = System::from_matrix(
        vec![1.0, 4.0],
        vec![[0.5; 3]; 2],
        vec![[0.0; 3], [0.8; 3]],
        &[vec![0.0, 0.4], vec![0.1, 0.0]],
    );
    let params = SolverParams {
        overshoot: false,
        ambient: false,
        tolerance: 1e-12,
        ..Default::default()
    };
    let mut s = Southwell::new(&sys, params);
    // A zero budget runs one shot.
    let p = s.step(&sys, Duration::ZERO).expect("shot");
    assert_eq!(p.iterations, 1);
    let b = s.radiosity(&sys);
    // Form factors are stored in f32.
    assert!((b[0][0] - 0.5 * 0.4 * 0.8).abs() < 1e-8, "{b:?}");
    assert!((b[1][0] - 0.8).abs() < 1e-15);
    // Energy is conserved: the power received equals the power shot times what the receiver
    // keeps: A0 * dB0 = rho * A1 F10 * dB1 (reciprocity: A0 F01 = A1 F10 = 0.4).
    let mut d = Direct::new(params);
    d.step(&sys, Duration::ZERO).expect("direct");
    let mut p = s.step(&sys, Duration::from_secs(1)).expect("solve");
    while !p.converged {
        p = s.step(&sys, Duration::from_secs(1)).expect("solve");
    }
    let (x, y) = (s.radiosity(&sys), d.radiosity(&sys));
    for i in 0..2 {
        assert!((x[i][0] - y[i][0]).abs() < 1e-10, "{x:?} vs {y:?}");
    }
}

#[test]
fn furnace_holds_for_stiff_reflectance() {
    // A closed box, uniform emission and reflectance: B = E / (1 - rho) exactly. A row-sum
    // error of 1e-3 would halve the answer at rho = 0.999.
    for rho in [0.5, 0.9, 0.99, 0.999] {
        let exact = 1.0 / (1.0 - rho);
        for (ff, solver) in [
            (FormFactorKind::Analytic, SolverKind::Direct),
            (FormFactorKind::Analytic, SolverKind::GaussSeidel),
            (FormFactorKind::Analytic, SolverKind::Southwell),
            (FormFactorKind::Analytic, SolverKind::Jacobi),
            (FormFactorKind::MonteCarlo, SolverKind::GaussSeidel),
            (FormFactorKind::Hemicube, SolverKind::GaussSeidel),
        ] {
            let mut p = BakeParams::default();
            p.mesh.patch_size = 0.5;
            p.mesh.element_levels = 1;
            p.form_factors = ff;
            p.ff.hemicube_resolution = 32;
            p.ff.monte_carlo_rays = 64;
            p.solver = solver;
            p.solver_params.tolerance = 1e-6;
            p.step_budget = Duration::from_millis(200);
            let r = common::bake(&furnace(rho, 1.0), &p);
            assert!(
                r.report.converged,
                "{ff:?} {solver:?} rho {rho}: not converged"
            );
            for (i, b) in r.radiosity.iter().enumerate() {
                for c in b {
                    assert!(c.is_finite(), "NaN");
                    assert!(
                        (c - exact).abs() <= 1e-5 * exact,
                        "{ff:?} {solver:?} rho {rho}: element {i} has {c}, exact {exact}"
                    );
                }
            }
        }
    }
}

#[test]
fn iterative_solvers_agree_with_the_direct_solve() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let mut p = BakeParams::default();
    p.mesh.patch_size = 0.3;
    p.mesh.element_levels = 2;
    let bake = radiant_radiosity::Bake::new(&scene, &p).expect("bake");
    let sys = &bake.system;
    assert!(
        sys.len() > 500 && sys.len() < 4096,
        "{} elements",
        sys.len()
    );
    let params = SolverParams {
        tolerance: 1e-7,
        ..Default::default()
    };
    let mut d = Direct::new(params);
    d.step(sys, Duration::ZERO).expect("direct");
    let reference = d.radiosity(sys);
    let solvers: Vec<Box<dyn Solver>> = vec![
        Box::new(Jacobi::new(sys, params)),
        Box::new(GaussSeidel::new(sys, params)),
        Box::new(Southwell::new(
            sys,
            SolverParams {
                ambient: false,
                ..params
            },
        )),
        Box::new(Southwell::new(sys, params)),
    ];
    for mut s in solvers {
        let mut p = s.step(sys, Duration::from_secs(10)).expect("step");
        while !p.converged {
            p = s.step(sys, Duration::from_secs(10)).expect("step");
        }
        let e = metrics::compare_elements(&sys.area, &s.radiosity(sys), &reference);
        assert!(
            e.rel_rms < 1e-6 && e.max_rel < 1e-5,
            "{:?}: {e:?}",
            s.kind()
        );
    }
}

#[test]
fn no_emitters_bakes_nothing() {
    let mut scene = radiant_scene::builtin("cornell-box").expect("builtin");
    for s in &mut scene.surfaces {
        s.emission = [0.0; 3];
    }
    let mut p = BakeParams::default();
    p.mesh.patch_size = 0.3;
    let r = common::bake(&scene, &p);
    assert!(!r.report.has_emitters);
    assert_eq!(r.report.links, 0, "no form factors are computed");
    assert!(r.radiosity.iter().all(|b| *b == [0.0; 3]));
    assert!(r.report.warnings.iter().any(|w| w.contains("no emitters")));
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let mut results = Vec::new();
    for threads in [1, 2] {
        for ff in [FormFactorKind::Analytic, FormFactorKind::MonteCarlo] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            let mut p = BakeParams::default();
            p.mesh.patch_size = 0.3;
            p.form_factors = ff;
            p.solver = SolverKind::Jacobi;
            let r = pool.install(|| common::bake(&scene, &p));
            results.push(((ff, threads), r.radiosity));
        }
    }
    for ff in [FormFactorKind::Analytic, FormFactorKind::MonteCarlo] {
        let a = &results.iter().find(|r| r.0 == (ff, 1)).expect("1 thread").1;
        let b = &results
            .iter()
            .find(|r| r.0 == (ff, 2))
            .expect("2 threads")
            .1;
        assert_eq!(a, b, "{ff:?}: 1 and 2 threads differ");
    }
}
