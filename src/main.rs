//! The `radiant` command line: bake a scene, or measure error against run time.

mod bake_cmd;
mod converge_cmd;
#[cfg(feature = "render")]
mod gather_cmd;
mod output;
mod plot;
mod reference_cmd;
#[cfg(feature = "render")]
mod render_cmd;
#[cfg(feature = "viewer")]
mod view_cmd;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use radiant::radiosity::{BakeParams, FormFactorKind, SolverKind};

/// Radiosity light baking: diffuse global illumination with honest error reporting.
#[derive(Parser, Debug)]
#[command(name = "radiant", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Bake a scene: light maps, per-surface and per-element radiosity, and a report.
    Bake(BakeArgs),
    /// Run several method × form-factor combinations and plot their error against run time.
    Converge(ConvergeArgs),
    /// Path-trace the scene for reference values with standard errors: per-surface radiosity
    /// (surfaces.csv, which `bake --reference` and `converge --reference` read), points and a
    /// camera image.
    Reference(reference_cmd::ReferenceArgs),
    /// Bake, then render one frame headless (G-buffer, SSAO, lighting, bloom, tone mapping):
    /// frame.png (tone-mapped) and frame.exr (linear radiance).
    #[cfg(feature = "render")]
    Render(render_cmd::RenderArgs),
    /// Open the viewer: the scene through the full render graph while the bake converges,
    /// with the egui inspector (Tab toggles it). Default: the builtin Cornell box.
    #[cfg(feature = "viewer")]
    View(view_cmd::ViewArgs),
}

/// Which scene to load.
#[derive(Args, Debug, Clone)]
pub(crate) struct SceneArgs {
    /// A glTF 2.0 file (.gltf or .glb).
    #[arg(required_unless_present = "builtin", conflicts_with = "builtin")]
    pub(crate) scene: Option<PathBuf>,
    /// A builtin scene instead of a file: cornell-box.
    #[arg(long)]
    pub(crate) builtin: Option<String>,
    /// Sky light, in emissive units: L or R,G,B (uniform radiance), gradient:ZENITH/HORIZON
    /// (each L or R,G,B), FILE.hdr or FILE.exr with an optional @SCALE (equirectangular), or
    /// none. Replaces the glTF scene extras' radiant.sky.
    #[arg(long)]
    pub(crate) sky: Option<String>,
}

/// Settings shared by `bake` and `converge`.
#[derive(Args, Debug, Clone)]
pub(crate) struct SolveArgs {
    /// Target longest edge of a patch, in scene units (default: a quarter of the scene's extent).
    #[arg(long)]
    pub(crate) patch_size: Option<f64>,
    /// Subdivision levels from patches down to elements; each level splits a triangle in 4.
    #[arg(long, default_value_t = 2)]
    pub(crate) element_levels: u8,
    /// Sky light: rays per element, stratified (used only when there is a sky).
    #[arg(long, default_value_t = 64)]
    pub(crate) sky_rays: u32,
    /// Link refinement threshold (smaller: more accurate, slower).
    #[arg(long, default_value_t = 0.02)]
    pub(crate) refinement: f64,
    /// Far-field factor: above the patch level, link coarser sources whose transport is below
    /// this times the refinement threshold.
    #[arg(long, default_value_t = 0.05)]
    pub(crate) far_field: f64,
    /// Estimated relative error at which the solver stops: the relative residual divided by
    /// 1 − ρ̂ (ρ̂: largest reflectance × row sum), so stiff scenes do not stop early.
    #[arg(long, default_value_t = 1e-4)]
    pub(crate) tolerance: f64,
    /// Stop solving after this many seconds, converged or not.
    #[arg(long)]
    pub(crate) time_limit: Option<f64>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub(crate) threads: Option<usize>,
    /// Seed for every random choice.
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
    /// Hemicube resolution (pixels along the top face).
    #[arg(long, default_value_t = 128)]
    pub(crate) hemicube_resolution: u32,
    /// Monte Carlo rays per element.
    #[arg(long, default_value_t = 256)]
    pub(crate) mc_rays: u32,
    /// Largest element count for the direct solver.
    #[arg(long, default_value_t = 4096)]
    pub(crate) max_direct: usize,
}

/// `radiant bake`.
#[derive(Args, Debug)]
pub(crate) struct BakeArgs {
    #[command(flatten)]
    pub(crate) scene: SceneArgs,
    /// Output directory.
    #[arg(long, short)]
    pub(crate) out: PathBuf,
    /// Solver: jacobi, gauss-seidel, southwell (progressive shooting) or direct; or
    /// gpu-hemicube: the GPU gathers on hemicubes at every light-map texel, with no form
    /// factors (Jacobi sweeps, --hemicube-resolution, --texel-density; needs a GPU adapter).
    #[arg(long, default_value = "gauss-seidel")]
    pub(crate) method: String,
    /// Form factors: analytic, hemicube, raycast or montecarlo.
    #[arg(long, default_value = "analytic")]
    pub(crate) form_factors: String,
    /// Per-surface reference CSV to report the error against (default for the builtin Cornell
    /// box: the shipped Mitsuba 3 reference).
    #[arg(long)]
    pub(crate) reference: Option<PathBuf>,
    /// Also solve in wavelength bands with measured spectra (the builtin Cornell box has them;
    /// other scenes need --spectra), compare with the RGB bake in the report, and write the
    /// spectral result as surfaces.csv (the RGB one goes to surfaces_rgb.csv).
    #[arg(long)]
    pub(crate) spectral: bool,
    /// Wavelength bands over 400-700 nm for --spectral (3 to 96). 32 reproduces Mitsuba's
    /// spectral/RGB ratios on the Cornell box within 1.2 %; 16 within 3.9 % (saturated walls).
    #[arg(long, default_value_t = 32)]
    pub(crate) bands: usize,
    /// Spectral materials side file (JSON, see assets/cornell_box_spectra.json) for --spectral.
    #[arg(long)]
    pub(crate) spectra: Option<PathBuf>,
    /// Checkpoint file: resume from it when it matches the scene (no form factors computed),
    /// and write it (atomically) when the bake ends.
    #[arg(long)]
    pub(crate) checkpoint: Option<PathBuf>,
    /// Also write the scene with its light map as binary glTF for other engines: TEXCOORD_1 on
    /// every baked primitive, the light map as an image, named in each primitive's extras
    /// (`lightmap`: texture, texCoord, scale, encoding).
    #[arg(long)]
    pub(crate) export: Option<PathBuf>,
    /// Light-map texels per scene unit (metres for glTF); default: automatic (about 256
    /// texels per triangle, 8 M at most; Sponza gets 18 per metre). Lowered where the charts
    /// would not fit one 8192² page.
    #[arg(long, value_parser = crate::parse_texel_density)]
    pub(crate) texel_density: Option<f64>,
    /// Largest light-map page side in texels (64 to 8192): charts that do not fit one page go
    /// on several (`lightmap.exr` stacks them top to bottom; `--export` writes one image each).
    #[arg(long, default_value_t = radiant::scene::atlas::MAX_SIDE,
          value_parser = clap::value_parser!(u32).range(64..=8192))]
    pub(crate) lightmap_page: u32,
    #[command(flatten)]
    pub(crate) hierarchy: HierarchyArgs,
    #[command(flatten)]
    pub(crate) solve: SolveArgs,
}

/// Which link hierarchy bakes, and its memory budget.
#[derive(Args, Debug, Clone)]
pub(crate) struct HierarchyArgs {
    /// Link hierarchy: `clustered` (volume clusters above triangles, links at any level on both
    /// ends: for levels; checkpoints of version 3), `triangles` (every element gathers from a
    /// per-triangle hierarchy: geometry edits, spectral, every solver and form-factor
    /// method; checkpoints of version 2), or `auto`:
    /// clustered when the scene has more than 4096 triangles or the per-triangle mesh would
    /// have more than 65 536 elements, and no option needs the per-triangle bake.
    #[arg(long, default_value = "auto", value_parser = ["auto", "clustered", "triangles"])]
    pub(crate) hierarchy: String,
    /// Memory budget of a clustered bake, e.g. 4G, 512M or bytes (default: 60 % of the
    /// available memory). Over it the bake coarsens, and refuses with an error in the end.
    #[arg(long, value_parser = parse_size)]
    pub(crate) memory_limit: Option<u64>,
    /// Visibility samples per link of a clustered bake.
    #[arg(long, default_value_t = 4)]
    pub(crate) link_samples: u32,
}

/// `4G`, `512M`, `64K` or a number of bytes.
/// `--texel-density`: a positive, finite number of texels per scene unit.
pub(crate) fn parse_texel_density(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(d) if d.is_finite() && d > 0.0 => Ok(d),
        _ => Err(format!(
            "{s:?} is not a positive number of texels per scene unit"
        )),
    }
}

fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let (num, mul) = match t.char_indices().last() {
        Some((i, c)) if c.is_ascii_alphabetic() => {
            let mul: u64 = match c.to_ascii_uppercase() {
                'K' => 1 << 10,
                'M' => 1 << 20,
                'G' => 1 << 30,
                'T' => 1 << 40,
                _ => return Err(format!("'{s}': use a number with K, M, G or T")),
            };
            (&t[..i], mul)
        }
        _ => (t, 1),
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a size (e.g. 4G, 512M)"))?;
    let bytes = v * mul as f64;
    if !(1.0..1.8e19).contains(&bytes) {
        return Err(format!("'{s}' is not a size between 1 byte and 16 EiB"));
    }
    Ok(bytes as u64)
}

/// `radiant converge`.
#[derive(Args, Debug)]
pub(crate) struct ConvergeArgs {
    #[command(flatten)]
    pub(crate) scene: SceneArgs,
    /// Output directory.
    #[arg(long, short)]
    pub(crate) out: PathBuf,
    /// Solvers to run, comma separated; `gpu-hemicube` adds the GPU gather's curve (against
    /// a per-surface reference).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "jacobi,gauss-seidel,southwell,direct"
    )]
    pub(crate) methods: Vec<String>,
    /// Form-factor methods to run, comma separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "analytic,hemicube,raycast,montecarlo"
    )]
    pub(crate) form_factors: Vec<String>,
    /// `path` (path-trace the scene first with `radiant reference`'s tracer: total error),
    /// `direct` (the direct solve on the same mesh: solver error only) or a per-surface CSV
    /// (total error; `radiant reference` writes one). Default: the shipped Mitsuba 3 reference
    /// for the builtin Cornell box, else `path`.
    #[arg(long)]
    pub(crate) reference: Option<String>,
    /// Target relative standard error of each surface for `--reference path`.
    #[arg(long, default_value_t = 0.005)]
    pub(crate) reference_error: f64,
    /// Time limit in seconds for `--reference path`.
    #[arg(long, default_value_t = 120.0)]
    pub(crate) reference_time: f64,
    /// Link hierarchy to measure: `triangles` (one curve per solver × form-factor method, as
    /// the solve progresses), `clustered` (one curve of clustered bakes at --refinements, each
    /// point a whole bake), or `auto` (as `bake` chooses).
    #[arg(long, default_value = "auto", value_parser = ["auto", "clustered", "triangles"])]
    pub(crate) hierarchy: String,
    /// Refinement thresholds of the clustered curve, coarse to fine.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.32,0.16,0.08,0.04,0.02,0.01"
    )]
    pub(crate) refinements: Vec<f64>,
    /// Memory budget of each clustered bake (as `bake --memory-limit`).
    #[arg(long, value_parser = parse_size)]
    pub(crate) memory_limit: Option<u64>,
    /// Seconds between error samples.
    #[arg(long, default_value_t = 0.01)]
    pub(crate) sample_every: f64,
    #[command(flatten)]
    pub(crate) solve: SolveArgs,
}

impl SolveArgs {
    /// Bake parameters for one solver and form-factor method.
    pub(crate) fn params(
        &self,
        solver: SolverKind,
        ff: FormFactorKind,
    ) -> anyhow::Result<BakeParams> {
        let mut p = BakeParams::default();
        p.mesh.patch_size = match self.patch_size {
            Some(s) if s > 0.0 && s.is_finite() => s,
            Some(s) => anyhow::bail!("--patch-size {s} must be a positive number"),
            None => 0.0,
        };
        p.mesh.element_levels = self.element_levels;
        p.links.refinement = self.refinement;
        anyhow::ensure!(
            self.far_field.is_finite() && self.far_field >= 0.0,
            "--far-field {} must be a number >= 0",
            self.far_field
        );
        p.links.far_field = self.far_field;
        p.form_factors = ff;
        p.ff.seed = self.seed;
        p.ff.hemicube_resolution = self.hemicube_resolution;
        p.ff.monte_carlo_rays = self.mc_rays;
        anyhow::ensure!(
            (1..=65536).contains(&self.sky_rays),
            "--sky-rays {} must be 1 to 65536",
            self.sky_rays
        );
        p.ff.sky_rays = self.sky_rays;
        p.solver = solver;
        p.solver_params.tolerance = self.tolerance;
        p.solver_params.max_direct = self.max_direct;
        if let Some(t) = self.time_limit {
            anyhow::ensure!(
                t > 0.0 && t.is_finite(),
                "--time-limit {t} must be a positive number of seconds"
            );
            p.time_limit = Some(seconds(t)?);
        }
        Ok(p)
    }

    /// Sets the global thread pool.
    pub(crate) fn init_threads(&self) -> anyhow::Result<()> {
        if let Some(n) = self.threads {
            anyhow::ensure!(n > 0, "--threads must be at least 1");
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build_global()?;
        }
        Ok(())
    }
}

/// Starts a bake, resuming from `checkpoint` when it exists and fits the scene, with a
/// progress bar over the form factors; the bar is returned, set to "solving", for the solve.
pub(crate) fn start_bake(
    scene: &radiant::scene::Scene,
    params: &BakeParams,
    checkpoint: Option<&std::path::Path>,
) -> anyhow::Result<(radiant::radiosity::Bake, indicatif::ProgressBar)> {
    let pb = bake_cmd::progress_bar(1, "form factors");
    let resumed = checkpoint.filter(|p| p.exists()).and_then(|path| {
        match radiant::radiosity::Bake::resume(scene, params, path) {
            Ok(b) => {
                println!("resumed from {} (no form factors computed)", path.display());
                Some(b)
            }
            Err(e) => {
                println!("not resuming: {e}; baking from scratch");
                None
            }
        }
    });
    let bake = match resumed {
        Some(b) => b,
        None => radiant::radiosity::Bake::with_progress(scene, params, &|done, total| {
            pb.set_length(total as u64);
            pb.set_position(done as u64);
        })?,
    };
    pb.set_message("solving");
    Ok((bake, pb))
}

/// Seconds as a `Duration`, with a clear error instead of a panic for absurd values.
pub(crate) fn seconds(t: f64) -> anyhow::Result<std::time::Duration> {
    std::time::Duration::try_from_secs_f64(t)
        .map_err(|_| anyhow::anyhow!("{t} seconds is out of range"))
}

/// Parses a solver name.
pub(crate) fn parse_solver(s: &str) -> anyhow::Result<SolverKind> {
    SolverKind::parse(s).ok_or_else(|| {
        anyhow::anyhow!(
            "unknown method '{s}' (jacobi, gauss-seidel, southwell, direct, gpu-hemicube)"
        )
    })
}

/// Parses a form-factor method name.
pub(crate) fn parse_ff(s: &str) -> anyhow::Result<FormFactorKind> {
    FormFactorKind::parse(s).ok_or_else(|| {
        anyhow::anyhow!(
            "unknown form-factor method '{s}' (analytic, hemicube, raycast, montecarlo)"
        )
    })
}

/// Loads the scene named by the arguments, with the sky `--sky` gives.
pub(crate) fn load_scene(args: &SceneArgs) -> anyhow::Result<(radiant::scene::Scene, String)> {
    let (mut scene, name) = match (&args.scene, &args.builtin) {
        (_, Some(name)) => (radiant::scene::builtin(name)?, name.clone()),
        (Some(path), None) => {
            let scene = radiant::scene::load_gltf(path)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
            (scene, path.display().to_string())
        }
        (None, None) => anyhow::bail!("give a scene file or --builtin cornell-box"),
    };
    apply_sky(&mut scene, args.sky.as_deref())?;
    Ok((scene, name))
}

/// Replaces the scene's sky with `--sky` (`none` removes it).
pub(crate) fn apply_sky(
    scene: &mut radiant::scene::Scene,
    sky: Option<&str>,
) -> anyhow::Result<()> {
    match sky.map(str::trim) {
        None => {}
        Some("none") => scene.sky = None,
        Some(spec) => {
            scene.sky = Some(
                radiant::scene::Sky::parse(spec, None)
                    .map_err(|e| anyhow::anyhow!("--sky {spec}: {e}"))?,
            );
        }
    }
    Ok(())
}

/// `radiant` alone: the viewer on the Cornell box, or the headless path without a display.
fn run_no_arguments() -> anyhow::Result<()> {
    #[cfg(feature = "viewer")]
    {
        if radiant_viewer::display_available() {
            let cli = <Cli as clap::Parser>::try_parse_from(["radiant", "view"])?;
            if let Some(Command::View(args)) = cli.command {
                match view_cmd::run(&args) {
                    Err(e)
                        if matches!(
                            e.downcast_ref::<radiant_viewer::ViewerError>(),
                            Some(
                                radiant_viewer::ViewerError::NoDisplay(_)
                                    | radiant_viewer::ViewerError::NoGpu(_)
                            )
                        ) =>
                    {
                        println!("radiant: {e}; running headless instead");
                    }
                    other => return other,
                }
            }
        } else {
            println!(
                "radiant: no display (neither DISPLAY nor WAYLAND_DISPLAY is set): running headless"
            );
        }
    }
    bake_cmd::run_default()
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("RUST_LOG")
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let result = match cli.command {
        Some(Command::Bake(args)) => bake_cmd::run(&args),
        Some(Command::Converge(args)) => converge_cmd::run(&args),
        Some(Command::Reference(args)) => reference_cmd::run(&args),
        #[cfg(feature = "render")]
        Some(Command::Render(args)) => render_cmd::run(&args),
        #[cfg(feature = "viewer")]
        Some(Command::View(args)) => view_cmd::run(&args),
        None => run_no_arguments(),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One clear line, no backtrace.
            let msg = format!("{e:#}").replace('\n', " ");
            eprintln!("error: {msg}");
            ExitCode::FAILURE
        }
    }
}
