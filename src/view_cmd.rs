//! `radiant view`: the window (feature `viewer`).

use std::path::PathBuf;

use clap::Args;

use radiant::radiosity::BakeParams;

use crate::SolveArgs;
use crate::args::{BuiltinScene, FormFactors, Solver};

/// `radiant view`.
#[derive(Args, Debug)]
pub(crate) struct ViewArgs {
    /// A glTF 2.0 file (.gltf or .glb); default: the builtin Cornell box.
    #[arg(conflicts_with = "builtin")]
    pub(crate) scene: Option<PathBuf>,
    /// A builtin scene instead of a file.
    #[arg(long, value_enum)]
    pub(crate) builtin: Option<BuiltinScene>,
    /// Sky light, as for `bake --sky`.
    #[arg(long)]
    pub(crate) sky: Option<String>,
    /// Window size in logical pixels, WIDTHxHEIGHT.
    #[arg(long, default_value = "1280x720")]
    pub(crate) size: String,
    /// Start with the inspector hidden (Tab or F1 toggles it).
    #[arg(long)]
    pub(crate) no_inspector: bool,
    /// Exit after this many frames (for scripted runs and screenshots).
    #[arg(long)]
    pub(crate) frames: Option<u64>,
    /// The bake's checkpoint: resumed from when it fits the scene, written on close.
    #[arg(long, default_value = "radiant-out/viewer.checkpoint")]
    pub(crate) checkpoint: PathBuf,
    /// Solver.
    #[arg(long, value_enum, default_value_t = Solver(BakeParams::default().solver))]
    pub(crate) method: Solver,
    /// Form factors.
    #[arg(long, value_enum, default_value_t = FormFactors(BakeParams::default().form_factors))]
    pub(crate) form_factors: FormFactors,
    /// Light-map texels per scene unit (metres for glTF); default: automatic (about 256
    /// texels per triangle, 8 M at most; Sponza gets 18 per metre). Lowered where the charts
    /// would not fit one 8192² page.
    #[arg(long, value_parser = crate::args::parse_texel_density)]
    pub(crate) texel_density: Option<f64>,
    /// A glTF node that moves (repeatable; as a node whose extras hold `{"radiant":
    /// {"dynamic": true}}`): left out of the bake, lit by probes, moved with the arrow keys and
    /// Page Up/Down.
    #[arg(long, value_name = "NODE")]
    pub(crate) dynamic: Vec<String>,
    #[command(flatten)]
    pub(crate) hierarchy: crate::HierarchyArgs,
    #[command(flatten)]
    pub(crate) solve: SolveArgs,
}

fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| anyhow::anyhow!("--size {s}: expected WIDTHxHEIGHT"))?;
    let (w, h): (u32, u32) = (w.trim().parse()?, h.trim().parse()?);
    anyhow::ensure!(
        (1..=16384).contains(&w) && (1..=16384).contains(&h),
        "--size {s}: each side must be 1 to 16384"
    );
    Ok((w, h))
}

/// Opens the viewer. `Err` with a [`radiant_viewer::ViewerError::NoDisplay`] inside when no
/// window can be opened (the caller may fall back to the headless path).
pub(crate) fn run(args: &ViewArgs) -> anyhow::Result<()> {
    let (mut scene, name) = match (&args.scene, &args.builtin) {
        (Some(path), None) => (
            radiant::scene::load_gltf(path)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?,
            path.display().to_string(),
        ),
        (_, builtin) => {
            let b = builtin.map_or(radiant::scene::Builtin::CornellBox, |b| b.0);
            (b.scene()?, b.name().to_string())
        }
    };
    crate::common::apply_sky(&mut scene, args.sky.as_deref())?;
    crate::probes::mark_dynamic(&mut scene, &args.dynamic)?;
    let params = args.solve.params(args.method.0, args.form_factors.0)?;
    args.solve.init_threads()?;
    if let Some(dir) = args
        .checkpoint
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
    {
        std::fs::create_dir_all(dir)?;
    }
    let mut options = radiant_viewer::ViewerOptions::new(scene);
    options.title = format!("Radiant: {name}");
    options.size = parse_size(&args.size)?;
    options.inspector = !args.no_inspector;
    options.exit_after_frames = args.frames;
    options.texel_density = args.texel_density;
    let h = &args.hierarchy;
    options.bake = radiant::ecs::bake::RadiosityBake {
        params,
        checkpoint: Some(args.checkpoint.clone()),
        threads: args.solve.threads,
        hierarchy: h.hierarchy.into(),
        // The viewer edits: the refinement's record is kept (ClusterParams::edits).
        cluster: radiant::radiosity::cluster::ClusterParams {
            memory_limit: h.memory_limit,
            samples: h.link_samples,
            transfer: !h.push_by_normal,
            ..Default::default()
        },
        ..Default::default()
    };
    let report = radiant_viewer::run(options)?;
    println!(
        "radiant viewer: {} frames, median {} ms per frame; bake {:?}{}",
        report.frames,
        report
            .median_frame_ms
            .map_or_else(|| "n/a".into(), |m| format!("{m:.1}")),
        report.bake_phase,
        report
            .checkpoint
            .map_or_else(String::new, |p| format!(", checkpoint {}", p.display()))
    );
    if !report.pass_ms.is_empty() {
        let passes: Vec<String> = report
            .pass_ms
            .iter()
            .map(|(n, ms)| format!("{n} {ms:.2}"))
            .collect();
        println!("pass times (ms): {}", passes.join(", "));
    }
    Ok(())
}
