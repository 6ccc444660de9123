//! The `radiant` command line: bake a scene, or measure error against run time.

mod args;
mod bake_cmd;
mod baking;
mod common;
mod converge_cmd;
#[cfg(feature = "render")]
mod gather_cmd;
mod output;
mod plot;
mod points;
mod probes;
mod reference_cmd;
#[cfg(feature = "render")]
mod render_cmd;
#[cfg(feature = "viewer")]
mod view_cmd;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use radiant::radiosity::cluster::ClusterParams;
use radiant::radiosity::final_gather::GatherParams;
use radiant::radiosity::{
    BakeParams, FormFactorKind, FormFactorParams, LinkParams, MeshParams, SolverKind, SolverParams,
};

use args::{FormFactors, Hierarchy, Method, Reference};

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
    /// A builtin scene instead of a file.
    #[arg(long, value_enum)]
    pub(crate) builtin: Option<args::BuiltinScene>,
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
    #[arg(long, default_value_t = MeshParams::default().element_levels)]
    pub(crate) element_levels: u8,
    /// Sky light: rays per element, stratified (used only when there is a sky).
    #[arg(long, default_value_t = FormFactorParams::default().sky_rays)]
    pub(crate) sky_rays: u32,
    /// Link refinement threshold (smaller: more accurate, slower).
    #[arg(long, default_value_t = LinkParams::default().refinement)]
    pub(crate) refinement: f64,
    /// Far-field factor: above the patch level, link coarser sources whose transport is below
    /// this times the refinement threshold.
    #[arg(long, default_value_t = LinkParams::default().far_field)]
    pub(crate) far_field: f64,
    /// Estimated relative error at which the solver stops: the relative residual divided by
    /// 1 − ρ̂ (ρ̂: largest reflectance × row sum), so stiff scenes do not stop early. Default
    /// 1e-4; 1e-3 for --method gpu-hemicube, whose estimate is the light map's remaining
    /// relative change (its texels' error is larger than that).
    #[arg(long)]
    pub(crate) tolerance: Option<f64>,
    /// Stop solving after this many seconds, converged or not.
    #[arg(long)]
    pub(crate) time_limit: Option<f64>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub(crate) threads: Option<usize>,
    /// Seed for every random choice.
    #[arg(long, default_value_t = FormFactorParams::default().seed)]
    pub(crate) seed: u64,
    /// Hemicube resolution (pixels along the top face). Default: 128 for the hemicube form
    /// factors, 16 for --method gpu-hemicube (whose error comes more from the texels' size).
    #[arg(long)]
    pub(crate) hemicube_resolution: Option<u32>,
    /// Monte Carlo rays per element.
    #[arg(long, default_value_t = FormFactorParams::default().monte_carlo_rays)]
    pub(crate) mc_rays: u32,
    /// Largest element count for the direct solver.
    #[arg(long, default_value_t = SolverParams::default().max_direct)]
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
    #[arg(long, value_enum, default_value_t = Method::Solver(BakeParams::default().solver))]
    pub(crate) method: Method,
    /// Form factors.
    #[arg(long, value_enum, default_value_t = FormFactors(BakeParams::default().form_factors))]
    pub(crate) form_factors: FormFactors,
    /// Per-surface reference CSV to report the error against (default for a builtin scene:
    /// the reference shipped with it; the Cornell box's is Mitsuba 3's).
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
    /// Surface points (the CSV `radiant reference --points` reads: name, x,y,z in scene units or
    /// x_mm,y_mm,z_mm, nx,ny,nz): writes points.csv with what the renderer shows there, the
    /// light map H as the GPU samples it and L = albedo × H + emission.
    #[arg(long, value_name = "FILE.csv")]
    pub(crate) points: Option<PathBuf>,
    /// A points.csv written by `radiant reference --points` (or Mitsuba's point meters) to
    /// measure --points against, by point name: median, mean and worst relative error and the
    /// bias in report.json and the summary.
    #[arg(long, value_name = "REF.csv", requires = "points")]
    pub(crate) reference_points: Option<PathBuf>,
    /// Probe points (`name,x,y,z,nx,ny,nz`, scene units: a point anywhere and a normal): bakes
    /// an irradiance volume with the level and writes probes.csv, `name,E_r,E_g,E_b`, what a
    /// dynamic mesh there would receive from it (the layout `radiant reference --probes`
    /// writes).
    #[arg(long, value_name = "FILE.csv")]
    pub(crate) probes: Option<PathBuf>,
    /// A probes.csv written by `radiant reference --probes` to measure --probes against, by
    /// name: median, mean and worst relative error in report.json and the summary.
    #[arg(long, value_name = "REF.csv", requires = "probes")]
    pub(crate) reference_probes: Option<PathBuf>,
    /// Distance between the volume's probes, scene units (default: a sixteenth of the scene's
    /// longest extent, coarser where more than 32 768 probes would be needed).
    #[arg(long, value_name = "METRES", requires = "probes", value_parser = crate::args::parse_spacing)]
    pub(crate) probe_spacing: Option<f64>,
    /// Light-map texels per scene unit (metres for glTF); default: automatic (about 256
    /// texels per triangle, 8 M at most; Sponza gets 18 per metre). Lowered where the charts
    /// would not fit one 8192² page.
    #[arg(long, value_parser = crate::args::parse_texel_density)]
    pub(crate) texel_density: Option<f64>,
    /// Largest light-map page side in texels (64 to 8192): charts that do not fit one page go
    /// on several (`lightmap.exr` stacks them top to bottom; `--export` writes one image each).
    #[arg(long, default_value_t = radiant::scene::atlas::MAX_SIDE,
          value_parser = clap::value_parser!(u32).range(64..=8192))]
    pub(crate) lightmap_page: u32,
    #[command(flatten)]
    pub(crate) light_map: LightMapArgs,
    #[command(flatten)]
    pub(crate) hierarchy: HierarchyArgs,
    #[command(flatten)]
    pub(crate) solve: SolveArgs,
}

/// How the light map is composed from the solution (`bake`, `render`).
#[derive(Args, Debug, Clone, Copy)]
pub(crate) struct LightMapArgs {
    /// Final gather: the light map's light other than the punctual lights' direct part is
    /// gathered at every texel with STRATA² rays into the solution (and 16 points on the
    /// emitters), instead of interpolated from the elements; 0: interpolated (fastest).
    #[arg(long, value_name = "STRATA", default_value_t = 0,
          value_parser = clap::value_parser!(u32).range(0..=64))]
    pub(crate) final_gather: u32,
    #[command(flatten)]
    pub(crate) gather: GatherArgs,
}

impl LightMapArgs {
    /// The final gather's parameters, seeded by `seed`; `None` without a final gather.
    pub(crate) fn gather(&self, seed: u64) -> Option<GatherParams> {
        match self.final_gather {
            0 => None,
            strata => Some(self.gather.params(strata, seed)),
        }
    }
}

/// How a final gather samples (`bake --final-gather`, `converge --light-maps`).
#[derive(Args, Debug, Clone, Copy)]
pub(crate) struct GatherArgs {
    /// With a final gather: rays are shot at every N-th texel along each axis, then on finer
    /// lattices down to every second texel where none of those stands for them (near walls
    /// and contacts, small charts; Ward's irradiance caching), and each texel takes the mean
    /// of those within --gather-radius (at least N) on its surface (1: at every texel).
    #[arg(long, value_name = "N", default_value_t = GatherParams::default().stride,
          value_parser = clap::value_parser!(u32).range(1..=16))]
    pub(crate) gather_stride: u32,
    /// With a final gather: the radius, in texels, of the window whose gathered rays a texel
    /// averages (at least the stride).
    #[arg(long, value_name = "TEXELS", default_value_t = GatherParams::default().filter_radius,
          value_parser = clap::value_parser!(u32).range(0..=16))]
    pub(crate) gather_radius: u32,
    /// With a final gather: passes of a gather at the elements first (each element's light
    /// from rays at its own points into the last pass's solution), which the texels then
    /// gather from (0: the solve's light).
    #[arg(long, value_name = "N", default_value_t = 0,
          value_parser = clap::value_parser!(u32).range(0..=8))]
    pub(crate) gather_passes: u32,
    /// With a final gather: where a ray meets a surface, read the punctual lights' light
    /// there from the elements (their mean, smeared across shadow edges) instead of a shadow
    /// ray from the point met (the default; one more ray where a light faces the point).
    #[arg(long)]
    pub(crate) gather_lights_from_elements: bool,
}

impl GatherArgs {
    /// The gather's parameters at `strata` (`strata²` rays per gathered texel), seeded by
    /// `seed`.
    pub(crate) fn params(&self, strata: u32, seed: u64) -> GatherParams {
        GatherParams {
            strata,
            seed,
            stride: self.gather_stride,
            filter_radius: self.gather_radius.max(self.gather_stride),
            element_passes: self.gather_passes,
            lights_at_hits: !self.gather_lights_from_elements,
            ..GatherParams::default()
        }
    }
}

/// Which link hierarchy bakes, and its memory budget.
#[derive(Args, Debug, Clone)]
pub(crate) struct HierarchyArgs {
    /// Link hierarchy: `clustered` (volume clusters above triangles, links at any level on both
    /// ends: for levels, and for an editor's geometry edits at any size; checkpoints of
    /// version 4), `triangles` (every element gathers from a per-triangle hierarchy: every
    /// solver and form-factor method; checkpoints of version 2), or `auto`:
    /// clustered when the scene has more than 4096 triangles or the per-triangle mesh would
    /// have more than 65 536 elements, and no option needs the per-triangle bake.
    #[arg(long, value_enum, default_value_t = Hierarchy::Auto)]
    pub(crate) hierarchy: Hierarchy,
    /// Memory budget of a clustered bake, e.g. 4G, 512M or bytes (default: 60 % of the
    /// available memory). Over it the bake coarsens, and refuses with an error in the end.
    /// With --method gpu-hemicube it can only lower the hemicubes drawn once and kept between
    /// sweeps (GPU memory, 1 GiB by default): at most half of it; the others are drawn again
    /// every sweep.
    #[arg(long, value_parser = args::parse_size)]
    pub(crate) memory_limit: Option<u64>,
    /// Visibility samples per link of a clustered bake.
    #[arg(long, default_value_t = ClusterParams::default().samples)]
    pub(crate) link_samples: u32,
    /// A clustered bake's cluster receivers hand their light to the elements under them by
    /// the elements' normals alone, not by each one's own visibility (16 short probe rays an
    /// element saved; a nook inside a large cluster then takes its open neighbours' light).
    #[arg(long)]
    pub(crate) push_by_normal: bool,
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
    #[arg(long, value_enum, value_delimiter = ',',
          default_values_t = SolverKind::ALL.map(Method::Solver))]
    pub(crate) methods: Vec<Method>,
    /// Form-factor methods to run, comma separated.
    #[arg(long, value_enum, value_delimiter = ',',
          default_values_t = FormFactorKind::ALL.map(FormFactors))]
    pub(crate) form_factors: Vec<FormFactors>,
    /// `path` (path-trace the scene first with `radiant reference`'s tracer: total error),
    /// `direct` (the direct solve on the same mesh: solver error only) or a per-surface CSV
    /// (total error; `radiant reference` writes one). Default: the shipped Mitsuba 3 reference
    /// for the builtin Cornell box, else `path`.
    #[arg(long, value_parser = args::parse_reference)]
    pub(crate) reference: Option<Reference>,
    /// Target relative standard error of each surface for `--reference path`.
    #[arg(long, default_value_t = 0.005)]
    pub(crate) reference_error: f64,
    /// Time limit in seconds for `--reference path`.
    #[arg(long, default_value_t = 120.0)]
    pub(crate) reference_time: f64,
    /// Link hierarchy to measure: `triangles` (one curve per solver × form-factor method, as
    /// the solve progresses), `clustered` (one curve of clustered bakes at --refinements, each
    /// point a whole bake), or `auto` (as `bake` chooses).
    #[arg(long, value_enum, default_value_t = Hierarchy::Auto)]
    pub(crate) hierarchy: Hierarchy,
    /// Refinement thresholds of the clustered curve, coarse to fine.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.32,0.16,0.08,0.04,0.02,0.01"
    )]
    pub(crate) refinements: Vec<f64>,
    /// Memory budget of each clustered bake, and a bound on the GPU gather's kept hemicubes
    /// (as `bake --memory-limit`).
    #[arg(long, value_parser = args::parse_size)]
    pub(crate) memory_limit: Option<u64>,
    /// Seconds between error samples.
    #[arg(long, default_value_t = 0.01)]
    pub(crate) sample_every: f64,
    /// Light maps to measure instead of solvers: one bake (as `bake` does it), then its light
    /// map composed at each of these final-gather settings (STRATA, as `bake --final-gather`;
    /// 0: the smooth field), each measured over the surfaces against the reference and at
    /// --points against --reference-points: lightmap_convergence.csv and .png.
    #[arg(long, value_delimiter = ',', value_name = "STRATA,...")]
    pub(crate) light_maps: Vec<u32>,
    /// With --light-maps: surface points (as `bake --points`).
    #[arg(long, value_name = "FILE.csv", requires = "light_maps")]
    pub(crate) points: Option<PathBuf>,
    /// With --light-maps and --points: the path-traced values there (as `bake
    /// --reference-points`).
    #[arg(long, value_name = "REF.csv", requires = "points")]
    pub(crate) reference_points: Option<PathBuf>,
    #[command(flatten)]
    pub(crate) gather: GatherArgs,
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
        if let Some(r) = self.hemicube_resolution {
            p.ff.hemicube_resolution = r;
        }
        p.ff.monte_carlo_rays = self.mc_rays;
        anyhow::ensure!(
            (1..=65536).contains(&self.sky_rays),
            "--sky-rays {} must be 1 to 65536",
            self.sky_rays
        );
        p.ff.sky_rays = self.sky_rays;
        p.solver = solver;
        if let Some(t) = self.tolerance {
            p.solver_params.tolerance = t;
        }
        p.solver_params.max_direct = self.max_direct;
        if let Some(t) = self.time_limit {
            anyhow::ensure!(
                t > 0.0 && t.is_finite(),
                "--time-limit {t} must be a positive number of seconds"
            );
            p.time_limit = Some(common::seconds(t)?);
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

/// Mesa's drivers (lavapipe, llvmpipe) print "error: XDG_RUNTIME_DIR is invalid or not set" on
/// every device they open where the variable is missing, as on a headless machine, a container
/// or CI. Before anything else runs, point it at a private directory of this user's (mode 0700,
/// as the XDG spec asks; one per user, kept between runs) so that nothing but Radiant's own
/// lines reach standard error.
#[cfg(unix)]
fn quiet_mesa() {
    use std::os::unix::fs::{MetadataExt as _, PermissionsExt as _};
    let valid =
        std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| std::path::Path::new(&d).is_dir());
    if valid {
        return;
    }
    let uid = std::fs::metadata("/proc/self").map_or(0, |m| m.uid());
    let dir = std::env::temp_dir().join(format!("radiant-runtime-{uid}"));
    let ours = std::fs::create_dir_all(&dir)
        .and_then(|()| std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700)))
        .is_ok();
    if ours {
        // SAFETY: the first statement of `main`, before any other thread exists, so nothing
        // reads the environment while it changes.
        #[allow(unsafe_code)]
        unsafe {
            std::env::set_var("XDG_RUNTIME_DIR", &dir);
        }
    }
}

#[cfg(not(unix))]
fn quiet_mesa() {}

fn main() -> ExitCode {
    quiet_mesa();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        // Help and version go to stdout as clap writes them.
        Err(e) if !e.use_stderr() => e.exit(),
        Err(e) => {
            // As every other error: one line (clap's own spans several).
            let text = e.render().to_string();
            let parts: Vec<&str> = (text.lines().map(str::trim))
                .filter(|l| !l.is_empty())
                .collect();
            let line = parts.join(" ");
            eprintln!("error: {}", line.strip_prefix("error: ").unwrap_or(&line));
            return ExitCode::FAILURE;
        }
    };
    // Where standard error is not a terminal the progress bars are hidden: the log says how
    // far a long phase is instead, without colour codes.
    let stderr_is_terminal = std::io::IsTerminal::is_terminal(&std::io::stderr());
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("RUST_LOG").unwrap_or_else(|_| {
                tracing_subscriber::EnvFilter::new(common::default_log_filter(stderr_is_terminal))
            }),
        )
        .with_ansi(stderr_is_terminal)
        .with_writer(std::io::stderr)
        .init();
    let progress_seconds = std::env::var("RADIANT_PROGRESS_SECONDS").ok();
    if let Some(problem) = common::progress_seconds_problem(progress_seconds.as_deref()) {
        tracing::warn!("{problem}");
    }
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
