//! Hot paths: the analytic kernel, form factors per method (a whole link build on the Cornell
//! box), one solver step of each iterative solver, and a geometry edit (the short block moved
//! 5 cm and back) on the default Cornell bake.
use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, Throughput};
use glam::DVec3;
use radiant_radiosity::form_factors::analytic::point_to_triangle;
use radiant_radiosity::solvers::{GaussSeidel, Jacobi, Solver, SolverParams, Southwell};
use radiant_radiosity::{Bake, BakeParams, FormFactorKind};

fn kernel(c: &mut Criterion) {
    let tri = [
        DVec3::new(0.0, 0.0, 1.0),
        DVec3::new(0.0, 1.0, 1.0),
        DVec3::new(1.0, 0.0, 1.0),
    ];
    let n = -DVec3::Z;
    let points: Vec<DVec3> = (0..1024)
        .map(|k| {
            DVec3::new(
                (k % 32) as f64 / 16.0 - 0.5,
                (k / 32) as f64 / 16.0 - 0.5,
                0.0,
            )
        })
        .collect();
    let mut g = c.benchmark_group("analytic_kernel");
    g.throughput(Throughput::Elements(points.len() as u64));
    g.bench_function("point_to_triangle_x1024", |b| {
        b.iter(|| {
            points
                .iter()
                .map(|&x| point_to_triangle(black_box(x), DVec3::Z, &tri, n))
                .sum::<f64>()
        })
    });
    g.finish();
}

fn cornell(patch: f64, levels: u8, ff: FormFactorKind) -> BakeParams {
    let mut p = BakeParams::default();
    p.mesh.patch_size = patch;
    p.mesh.element_levels = levels;
    p.form_factors = ff;
    p
}

fn form_factors(c: &mut Criterion) {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let mut g = c.benchmark_group("cornell_links_patch0.3");
    g.sample_size(10).measurement_time(Duration::from_secs(4));
    for ff in FormFactorKind::ALL {
        let p = cornell(0.3, 1, ff);
        let links = Bake::new(&scene, &p).expect("bake").system.links.len();
        g.throughput(Throughput::Elements(links as u64));
        g.bench_function(ff.name(), |b| {
            b.iter(|| {
                Bake::new(black_box(&scene), &p)
                    .expect("bake")
                    .system
                    .links
                    .len()
            })
        });
    }
    g.finish();
}

fn solvers(c: &mut Criterion) {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let bake = Bake::new(&scene, &BakeParams::default()).expect("bake");
    let sys = &bake.system;
    let params = SolverParams {
        tolerance: 1e-30,
        ..Default::default()
    };
    let mut g = c.benchmark_group("cornell_default_solver_step");
    g.sample_size(10).measurement_time(Duration::from_secs(3));
    g.throughput(Throughput::Elements(sys.links.len() as u64));
    g.bench_function("jacobi_sweep", |b| {
        let mut s = Jacobi::new(sys, params);
        b.iter(|| s.step(sys, Duration::ZERO).expect("step"))
    });
    g.bench_function("gauss_seidel_sweep", |b| {
        let mut s = GaussSeidel::new(sys, params);
        b.iter(|| s.step(sys, Duration::ZERO).expect("step"))
    });
    g.bench_function("southwell_shot", |b| {
        let mut s = Southwell::new(sys, params);
        b.iter(|| s.step(sys, Duration::ZERO).expect("step"))
    });
    g.finish();
}

fn edits(c: &mut Criterion) {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let moved = radiant_radiosity::scenes::translated(&scene, "short_block", DVec3::X * 0.05);
    let mut bake = Bake::new(&scene, &BakeParams::default()).expect("bake");
    let mut g = c.benchmark_group("cornell_default_edit");
    g.sample_size(10).measurement_time(Duration::from_secs(8));
    g.throughput(Throughput::Elements(bake.system.links.len() as u64));
    let mut there = false;
    g.bench_function("move_short_block_5cm", |b| {
        b.iter(|| {
            there = !there;
            bake.edit_geometry(if there { &moved } else { &scene })
                .expect("a rigid move")
                .recomputed
        })
    });
    g.finish();
}

#[allow(
    missing_docs,
    reason = "criterion_group! generates an undocumented function"
)]
mod group {
    use super::*;
    criterion::criterion_group!(benches, kernel, form_factors, solvers, edits);
}
criterion::criterion_main!(group::benches);
