//! The GPU hemicube gather on the builtin Cornell box: receivers, sweeps, time, and the error
//! against Mitsuba after each sweep (surface means), then at the 24 Mitsuba points.
//!
//! `cargo run --release -p radiant_gather --example gather_cornell -- [RES] [TEXELS_PER_M]`
//! (`POINTS=1`: each point; `SURFACES=1`: each surface's mean as CSV; `KEEP_BYTES=0`: draw the
//! hemicubes again every sweep).

use std::time::Instant;

use radiant_gather::{GatherParams, GpuGather};
use radiant_radiosity::metrics;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let res = args
        .first()
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(GatherParams::default().resolution);
    let density = args.get(1).map(|s| s.parse::<f64>()).transpose()?;
    let scene = radiant_scene::builtin("cornell-box")?;
    let reference = metrics::parse_reference_csv(metrics::CORNELL_BOX_REFERENCE)?;
    let start = Instant::now();
    let mut g = GpuGather::new(
        &scene,
        &GatherParams {
            resolution: res,
            texel_density: density,
            keep_bytes: match std::env::var("KEEP_BYTES") {
                Ok(v) => v.parse()?,
                Err(_) => GatherParams::default().keep_bytes,
            },
            ..GatherParams::default()
        },
    )?;
    println!(
        "{} receivers at {:.1} texels/m, {} batch(es) ({} drawn once), setup {:.2} s on {}",
        g.receivers(),
        g.atlas().density,
        g.batches(),
        g.kept_batches(),
        g.setup_seconds(),
        g.adapter()
    );
    loop {
        let s = g.step()?;
        let e = metrics::compare_surfaces(&g.surface_means(), &reference)?;
        println!(
            "sweep {:3}  {:7.3} s  change {:.2e}  estimate {:.2e}  vs Mitsuba mean {:.3} %  max {:.3} %",
            s.iterations,
            start.elapsed().as_secs_f64(),
            s.change,
            s.estimate,
            e.mean_rel * 100.0,
            e.max_rel * 100.0
        );
        if s.converged {
            break;
        }
    }
    {
        let refs = metrics::parse_point_csv(metrics::CORNELL_POINTS_RGB, 1e-3)?;
        let c = metrics::compare_points_with(&refs, None, |r| {
            g.radiosity_at(&scene, r.position, r.normal)
        })?;
        println!(
            "texels at the {} Mitsuba points: mean {:.2} %, max {:.2} %",
            c.points.len(),
            c.mean_rel * 100.0,
            c.max_rel * 100.0
        );
        if std::env::var_os("POINTS").is_some() {
            for p in &c.points {
                println!("  {:28} {:+.2} %", p.name, p.rel * 100.0);
            }
        }
    }
    if std::env::var_os("SURFACES").is_some() {
        for s in g.surface_means() {
            println!("{},{},{},{}", s.name, s.mean[0], s.mean[1], s.mean[2]);
        }
    }
    Ok(())
}
