//! Tuning probe: Cornell box error against Mitsuba for given settings.
use radiant_radiosity::*;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let ps: f64 = args.get(1).map(|s| s.parse().unwrap()).unwrap_or(0.05);
    let refine: f64 = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(0.02);
    let ff = args
        .get(3)
        .map(|s| FormFactorKind::parse(s).unwrap())
        .unwrap_or(FormFactorKind::Analytic);
    let solver = args
        .get(4)
        .map(|s| SolverKind::parse(s).unwrap())
        .unwrap_or(SolverKind::GaussSeidel);
    let levels: u8 = args.get(5).map(|s| s.parse().unwrap()).unwrap_or(1);
    let scene = radiant_scene::builtin("cornell-box").unwrap();
    let mut p = BakeParams::default();
    p.mesh.patch_size = ps;
    p.mesh.element_levels = levels;
    p.links.refinement = refine;
    if let Ok(v) = std::env::var("FAR") {
        p.links.far_field = v.parse().unwrap();
    }
    if std::env::var("UNIFORM").is_ok() {
        p.links.hierarchical = false;
    }
    p.form_factors = ff;
    p.solver = solver;
    if std::env::var("DIRECT").is_ok() {
        p.solver = SolverKind::Jacobi;
        let mut b = Bake::new(&scene, &p).unwrap();
        let sys = &b.system;
        let mut nodes = vec![[0.0; 3]; sys.node_area.len()];
        sys.pull(&sys.source, &mut nodes);
        let b1: Vec<Rgb> = (0..sys.len())
            .map(|i| {
                let g = sys.gather(i, &nodes);
                std::array::from_fn(|c| sys.source[i][c] + sys.rho[i][c] * g[c])
            })
            .collect();
        let _ = b.step(std::time::Duration::ZERO);
        let means = metrics::surface_means(&b.surfaces, &b.mesh, &b1);
        let reference =
            metrics::parse_reference_csv(&std::fs::read_to_string("/tmp/direct.csv").unwrap())
                .unwrap();
        let e = metrics::compare_surfaces(&means, &reference).unwrap();
        println!("DIRECT mean_rel {:.4} max_rel {:.4}", e.mean_rel, e.max_rel);
        for s in &means {
            if let Some((_, rf)) = reference.iter().find(|(n, _)| *n == s.name) {
                let rel: Vec<String> = (0..3)
                    .map(|c| format!("{:+.3}", (s.mean[c] - rf[c]) / rf[c] * 100.0))
                    .collect();
                println!(
                    "{:20} {:?} {}",
                    s.name,
                    s.mean.map(|x| (x * 1e4).round() / 1e4),
                    rel.join(" ")
                );
            }
        }
        return;
    }
    let t = std::time::Instant::now();
    let r = Bake::new(&scene, &p)
        .unwrap()
        .run_to_end(&mut |_| {})
        .unwrap();
    let wall = t.elapsed().as_secs_f64();
    let reference = metrics::parse_reference_csv(metrics::CORNELL_BOX_REFERENCE).unwrap();
    let e = metrics::compare_surfaces(&r.surfaces, &reference).unwrap();
    let rep = &r.report;
    println!(
        "patches {} elements {} links {} ({:.1} MB) iters {} conv {} resid {:.2e}",
        rep.patches,
        rep.elements,
        rep.links,
        rep.link_bytes as f64 / 1e6,
        rep.iterations,
        rep.converged,
        rep.residual
    );
    println!(
        "times mesh {:.3} vis {:.3} ff {:.3} solve {:.3} wall {:.3}",
        rep.times.meshing, rep.times.visibility, rep.times.form_factors, rep.times.solve, wall
    );
    println!(
        "mean_rel {:.4} max_rel {:.4} rms {:.4}",
        e.mean_rel, e.max_rel, e.rel_rms
    );
    for s in &r.surfaces {
        if let Some((_, rf)) = reference.iter().find(|(n, _)| *n == s.name) {
            let rel: Vec<String> = (0..3)
                .map(|c| format!("{:+.3}", (s.mean[c] - rf[c]) / rf[c] * 100.0))
                .collect();
            println!(
                "{:20} {:?} {}",
                s.name,
                s.mean.map(|x| (x * 1e4).round() / 1e4),
                rel.join(" ")
            );
        }
    }
}

#[allow(dead_code)]
fn direct_only() {}
