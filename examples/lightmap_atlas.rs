//! The light-map atlas of a scene at several texel densities: generation time, page size,
//! charts and the share of texels inside charts (the UV benchmark of ARCHITECTURE.md).
//!
//! `cargo run --release --example lightmap_atlas -- SCENE.gltf [DENSITY ...]`
//! (no density: the automatic one). Each density is generated `--runs` times (default 3) and
//! the median time printed.

use std::path::PathBuf;

use clap::Parser;
use radiant::scene::atlas::Atlas;

#[derive(Parser)]
struct Args {
    /// The glTF scene.
    scene: PathBuf,
    /// Texels per scene unit; none: the automatic density.
    densities: Vec<f64>,
    /// Runs per density.
    #[arg(long, default_value_t = 3)]
    runs: usize,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let scene = radiant::scene::load_gltf(&args.scene)?;
    let area: f64 = scene.triangles.iter().map(|t| t.area()).sum();
    println!(
        "{}: {} triangles, {} surfaces, {area:.1} square units; {} threads",
        args.scene.display(),
        scene.triangles.len(),
        scene.surfaces.len(),
        rayon::current_num_threads()
    );
    let densities: Vec<Option<f64>> = if args.densities.is_empty() {
        vec![None]
    } else {
        args.densities.iter().map(|&d| Some(d)).collect()
    };
    println!("asked,density,width,height,charts,utilisation,measured_density,median_s");
    for asked in densities {
        let mut times = Vec::new();
        let mut atlas = None;
        for _ in 0..args.runs.max(1) {
            let t = std::time::Instant::now();
            atlas = Some(Atlas::new(&scene, asked)?);
            times.push(t.elapsed().as_secs_f64());
        }
        times.sort_by(f64::total_cmp);
        let a = atlas.expect("one run");
        println!(
            "{},{:.2},{},{},{},{:.4},{:.2},{:.3}",
            asked.map_or("auto".to_string(), |d| d.to_string()),
            a.density,
            a.width,
            a.height,
            a.charts,
            a.utilisation(),
            a.texel_density(&scene),
            times[times.len() / 2]
        );
    }
    Ok(())
}
