//! Bakes the builtin Cornell box with the library API (no CLI, no GPU, no window), prints the
//! per-surface radiosity and the error against the shipped Mitsuba 3 reference.
//!
//! `cargo run --release --example headless_bake [PATCH_SIZE]`

use radiant::radiosity::metrics::{CORNELL_BOX_REFERENCE, compare_surfaces, parse_reference_csv};
use radiant::radiosity::{Bake, BakeEvent, BakeParams, SolverKind};

fn main() -> anyhow::Result<()> {
    let scene = radiant::scene::builtin("cornell-box")?;
    let mut params = BakeParams::default();
    if let Some(size) = std::env::args().nth(1) {
        params.mesh.patch_size = size.parse()?;
    }
    params.solver = SolverKind::Southwell;

    // Everything up to the solve: meshing, visibility, links and form factors.
    let bake = Bake::new(&scene, &params)?;
    println!(
        "{} elements, {} links",
        bake.mesh.element_count(),
        bake.system.links.len()
    );
    // The solve runs in time-budgeted steps; each step reports its progress.
    let result = bake.run_to_end(&mut |BakeEvent::Solve(p, t)| {
        println!(
            "  {t:7.3} s  {:6} shots  unshot {:.2e}",
            p.iterations, p.unshot_fraction
        );
    })?;
    for s in &result.surfaces {
        println!(
            "{:20} B = ({:.4}, {:.4}, {:.4})",
            s.name, s.mean[0], s.mean[1], s.mean[2]
        );
    }
    let reference = parse_reference_csv(CORNELL_BOX_REFERENCE)?;
    let e = compare_surfaces(&result.surfaces, &reference)?;
    println!(
        "against Mitsuba 3: mean {:.2} %, max {:.2} %",
        e.mean_rel * 100.0,
        e.max_rel * 100.0
    );
    Ok(())
}
