//! Clustered hierarchical radiosity for real levels: links at any level on both ends, starting
//! from the root's link to itself, in memory that is a budget.
//!
//! 1. **Meshing fits the geometry** ([`Mesh::adaptive`]): an input triangle is subdivided only
//!    until its longest edge fits the element size; small triangles stay whole.
//! 2. **Volume clusters** ([`tree`]) over the input triangles, a binary tree of bounding boxes
//!    (Sillion 1995; Smits, Arvo & Greenberg 1994). Volume clusters, not face clusters
//!    (Willmott et al. 1999): real levels are triangle soups with T-vertices, slivers and
//!    interpenetrating props, which have no clean face adjacency to merge along; a volume
//!    tree needs none.
//! 3. **Refinement** ([`refine`]) from the root's self-link, splitting the larger node while a
//!    link could carry more than the threshold (`ρ B̂ A / (π d²)`, relative to the ambient
//!    level) or its bounding spheres are too close; visibility for links with a cluster on an
//!    end is sampled by segments between points chosen by area inside both nodes, which sees
//!    through the gaps between a cluster's triangles; leaves keep the contour integral.
//! 4. **Solve** ([`solve`]): Jacobi sweeps of gather and push-pull.
//!
//! **Memory is a budget**: the mesh's size is computed before it is allocated and the links
//! are counted while refinement runs. A mesh over the budget is a typed
//! [`BakeError::OutOfMemory`] at once; links over it stop the refinement, which starts again
//! with a threshold four times larger (coarser, reported), at most [`COARSEN_STEPS`] times,
//! and then refuses with the same typed error. Large buffers are reserved with
//! `try_reserve`, so an allocator's refusal is that error too, never an abort.
//!
//! What it does not do yet (the per-triangle [`crate::Bake`] does): geometry and light edits,
//! checkpoints, the spectral solve, the hemicube and Monte Carlo form-factor methods (they
//! gather a whole receiver's row at once, which a two-sided hierarchy does not have).

pub mod refine;
pub mod sh;
pub mod solve;
pub mod tree;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use radiant_scene::Scene;
use radiant_visibility::Bvh;

use crate::BakeError;
use crate::form_factors::FormFactorKind;
use crate::mesh::Mesh;
use crate::metrics::surface_means;
use crate::params::BakeParams;
use crate::report::{BakeReport, BakeResult, PhaseTimes, TimelinePoint};
use crate::solve::{Info, SolveError, Stall};
use crate::solvers::SolverKind;
use crate::system::{Rgb, System};

/// Settings of the clustered hierarchy that the per-triangle bake does not have.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClusterParams {
    /// Bytes the bake may use for its mesh, links and buffers; `None`: 60 % of the memory
    /// available when the bake starts (`MemAvailable`), or 4 GiB where that is unknown.
    pub memory_limit: Option<u64>,
    /// Over the budget, coarsen (raise the threshold 4×, up to [`COARSEN_STEPS`] times)
    /// instead of refusing at once (default: true).
    pub coarsen: bool,
    /// Visibility samples (point pairs) per link (default: 4).
    pub samples: u32,
    /// Most Jacobi sweeps (default: 10 000).
    pub max_sweeps: u32,
}

impl Default for ClusterParams {
    fn default() -> Self {
        ClusterParams {
            memory_limit: None,
            coarsen: true,
            samples: 4,
            max_sweeps: 10_000,
        }
    }
}

/// Times the threshold may be raised to fit the memory budget.
pub const COARSEN_STEPS: u32 = 3;

/// What the clustered bake reports beyond [`BakeReport`].
#[derive(Clone, Debug, PartialEq)]
pub struct ClusterReport {
    /// Clusters above the input triangles.
    pub clusters: usize,
    /// Links whose receiver is a cluster.
    pub cluster_receiver_links: usize,
    /// Links whose source is a cluster.
    pub cluster_source_links: usize,
    /// The threshold asked for (relative to the ambient level).
    pub refinement_asked: f64,
    /// The threshold used: larger when the budget made the bake coarsen.
    pub refinement_used: f64,
    /// The memory budget in bytes.
    pub memory_limit: u64,
    /// Bytes of mesh, tree, links and solver buffers, as counted by the bake.
    pub memory_estimate: u64,
    /// Elements found inside closed geometry.
    pub enclosed: usize,
}

/// The memory budget: bytes handed out against a limit.
#[derive(Clone, Copy, Debug)]
pub struct Budget {
    /// The limit in bytes.
    pub limit: u64,
    /// Bytes reserved so far.
    pub used: u64,
}

impl Budget {
    /// A budget of `limit` bytes, or the default (see [`ClusterParams::memory_limit`]).
    pub fn new(limit: Option<u64>) -> Budget {
        Budget {
            limit: limit.unwrap_or_else(default_memory_limit),
            used: 0,
        }
    }

    /// Takes `bytes` for `what`, or says it does not fit.
    pub fn reserve(&mut self, what: &'static str, bytes: u64) -> Result<(), BakeError> {
        let used = self.used.saturating_add(bytes);
        if used > self.limit {
            return Err(BakeError::OutOfMemory {
                what,
                needed: used,
                limit: self.limit,
            });
        }
        self.used = used;
        Ok(())
    }

    /// Bytes left.
    pub fn left(&self) -> u64 {
        self.limit.saturating_sub(self.used)
    }
}

/// 60 % of `MemAvailable` (Linux), else 4 GiB.
pub fn default_memory_limit() -> u64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("MemAvailable:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse::<u64>().ok())
        })
        .map_or(4 << 30, |kib| kib * 1024 / 10 * 6)
}

/// Phases reported to the progress callback.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Refining links: `(parts done, parts)`.
    Links,
    /// Solving: `(sweeps, most sweeps)`.
    Solve,
}

/// The state of a clustered bake after one sweep, for [`Watch::on_sweep`].
pub struct Sweep<'a> {
    /// The element hierarchy.
    pub mesh: &'a Mesh,
    /// Radiosity per element after the sweep.
    pub radiosity: &'a [Rgb],
    /// Reflectance per element.
    pub reflectance: &'a [Rgb],
    /// Per element: inside closed geometry (seen by nothing).
    pub enclosed: &'a [bool],
    /// Sweeps so far, the estimated relative error of `radiosity` (the bake's residual) and
    /// the progress toward the tolerance.
    pub info: Info,
    /// Links.
    pub links: usize,
    /// Seconds since the bake started.
    pub seconds: f64,
}

/// Hooks into a running clustered bake: a live view of its solution, and a way to stop it.
#[derive(Default)]
pub struct Watch<'a> {
    /// Set to stop the bake: checked while links are refined and between sweeps; the bake
    /// then returns [`BakeError::Stopped`].
    pub stop: Option<&'a AtomicBool>,
    /// Called after every sweep (from the thread that called [`bake_watched`]).
    pub on_sweep: Option<&'a mut dyn FnMut(&Sweep<'_>)>,
}

impl Watch<'_> {
    fn stopped(&self) -> bool {
        self.stop.is_some_and(|f| f.load(Ordering::Relaxed))
    }
}

/// `--hierarchy auto`'s rule: a scene with more than 4096 triangles, or whose per-triangle mesh
/// would have more than 65 536 elements, is a level and bakes clustered, when `params` are
/// ones the clustered hierarchy supports (Jacobi or Gauss–Seidel, analytic or ray-cast form
/// factors; it solves with Jacobi sweeps either way).
pub fn suits(scene: &Scene, params: &BakeParams) -> Result<bool, BakeError> {
    let supported = matches!(params.solver, SolverKind::GaussSeidel | SolverKind::Jacobi)
        && matches!(
            params.form_factors,
            FormFactorKind::Analytic | FormFactorKind::RayCast
        );
    Ok(supported && is_level(scene, params)?)
}

/// The size half of [`suits`]: more than 4096 triangles, or more than 65 536 elements in the
/// per-triangle mesh.
pub fn is_level(scene: &Scene, params: &BakeParams) -> Result<bool, BakeError> {
    Ok(scene.triangles.len() > 4096 || Mesh::count_elements(scene, &params.mesh)? > 65_536)
}

/// Bakes `scene` with the clustered hierarchy (see [`bake_watched`]).
pub fn bake(
    scene: &Scene,
    params: &BakeParams,
    cp: &ClusterParams,
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
) -> Result<BakeResult, BakeError> {
    bake_watched(scene, params, cp, progress, Watch::default())
}

/// Bakes `scene` with the clustered hierarchy. `params` gives the meshing (element size =
/// patch size / 2^element levels), the threshold (`links.refinement`), the form-factor method
/// (analytic or ray-cast between triangles), the seed, the tolerance and the time limit.
/// `progress(phase, done, total)` is called as the bake advances, also from worker threads.
/// `watch` sees the solution after every sweep and can stop the bake.
pub fn bake_watched(
    scene: &Scene,
    params: &BakeParams,
    cp: &ClusterParams,
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
    mut watch: Watch<'_>,
) -> Result<BakeResult, BakeError> {
    let started = Instant::now();
    let scene = crate::input::static_scene(scene);
    let scene = scene.as_ref();
    crate::input::validate(scene)?;
    check(params, cp)?;
    let mut times = PhaseTimes::default();
    let mut budget = Budget::new(cp.memory_limit);
    let mut lap = Instant::now();
    let mesh = Mesh::adaptive(scene, &params.mesh, &mut |b| budget.reserve("the mesh", b))?;
    let n = mesh.element_count();
    // Per element: reflectance, source, area, solution twice; per node: tree geometry and
    // three solver buffers.
    let nodes = (mesh.nodes.len() + mesh.roots.len()) as u64;
    budget.reserve("the element buffers", n as u64 * (24 * 4 + 16))?;
    budget.reserve("the cluster tree", nodes * (24 * 5 + 8 * 4))?;
    // Per cluster: its normals' harmonics, and two harmonics buffers of the solve.
    budget.reserve(
        "the cluster buffers",
        mesh.roots.len() as u64 * (72 + 2 * 216),
    )?;
    budget.reserve("the ray-tracing BVH", mesh.roots.len() as u64 * 160)?;
    times.meshing = lap.elapsed().as_secs_f64();
    lap = Instant::now();
    let masks = crate::input::masks(scene);
    let bvh = crate::input::visibility(&mesh, masks.as_ref());
    let tree = tree::Tree::new(&mesh);
    times.visibility = lap.elapsed().as_secs_f64();
    tracing::info!(
        elements = n,
        triangles = mesh.roots.len(),
        clusters = tree.clusters.len(),
        "clustered bake: meshed"
    );

    lap = Instant::now();
    let (rho, source) = crate::input::Lighting::new(scene, &mesh, &bvh, masks, &params.ff)
        .terms(&scene.surfaces, &mesh);
    times.direct_light = lap.elapsed().as_secs_f64();
    let mut warnings = scene.warnings();
    let has_emitters = source.iter().any(|s| s.iter().any(|&v| v > 0.0));
    lap = Instant::now();
    let dead = if has_emitters {
        crate::hierarchy::enclosed_elements(&mesh, &bvh, params.ff.seed)
    } else {
        warnings.push("no emitters and no lights: nothing to bake, all radiosity is 0".into());
        vec![false; n]
    };
    let enclosed = dead.iter().filter(|&&d| d).count();
    let (parts, eps_used) = if has_emitters {
        links(
            &mesh,
            &tree,
            &bvh,
            params,
            cp,
            &rho,
            &source,
            &mut budget,
            &mut warnings,
            progress,
            watch.stop,
        )?
    } else {
        (Vec::new(), params.links.refinement)
    };
    let sys = solve::HierSystem::new(&mesh, &tree, parts, rho, source, dead)?;
    times.form_factors = lap.elapsed().as_secs_f64();
    tracing::info!(
        links = sys.links(),
        seconds = times.form_factors,
        "clustered bake: links"
    );

    // Solve.
    lap = Instant::now();
    let mut b = sys.source.clone();
    let mut timeline = Vec::new();
    let (mut info, mut stalled) = (Info::nothing_to_solve(), None);
    info.converged = !has_emitters;
    let mut stall = Stall::default();
    let mut last_update = f64::NAN;
    let tol = params.solver_params.tolerance;
    while has_emitters && info.iterations < u64::from(cp.max_sweeps) {
        let nb = sys.sweep(&b);
        let diff: Vec<Rgb> = nb
            .iter()
            .zip(&b)
            .map(|(x, y)| std::array::from_fn(|c| x[c] - y[c]))
            .collect();
        // Relative to the bounced light (b − source), not to b: in a sunlit level the direct
        // light dominates ‖b‖, and a change measured against it stopped Sponza after 4
        // sweeps while its shade was still filling in (now 7).
        let bounced: Vec<Rgb> = nb
            .iter()
            .zip(&sys.source)
            .map(|(x, s)| std::array::from_fn(|c| x[c] - s[c]))
            .collect();
        let (dn, bn) = (sys.norm(&diff), sys.norm(&bounced));
        b = nb;
        let iterations = info.iterations + 1;
        let update = if bn > 0.0 { dn / bn } else { 0.0 };
        // The error after a sweep is about update × q / (1 − q), q the observed contraction.
        let q = if last_update > 0.0 {
            (update / last_update).clamp(0.0, 0.9999)
        } else {
            0.5
        };
        last_update = update;
        let residual = update * q / (1.0 - q);
        // The residual is already an error estimate: contraction 0 keeps it as it is.
        let converged = residual <= tol && iterations >= 2;
        info = Info::from_residual(iterations, residual, 0.0, 0.0, tol, converged);
        if !residual.is_finite() {
            return Err(SolveError::Diverged {
                residual,
                iterations,
            }
            .into());
        }
        timeline.push(TimelinePoint {
            t_s: started.elapsed().as_secs_f64(),
            iterations,
            residual,
            unshot_fraction: 0.0,
        });
        progress(Phase::Solve, iterations as usize, cp.max_sweeps as usize);
        if let Some(f) = watch.on_sweep.as_mut() {
            f(&Sweep {
                mesh: &mesh,
                radiosity: &b,
                reflectance: &sys.rho,
                enclosed: sys.enclosed(),
                info,
                links: sys.links(),
                seconds: started.elapsed().as_secs_f64(),
            });
        }
        if watch.stopped() {
            return Err(BakeError::Stopped);
        }
        if converged {
            break;
        }
        if let Err(e) = stall.observe(residual, iterations) {
            warnings.push(e.to_string());
            stalled = Some(e);
            break;
        }
        if params
            .time_limit
            .is_some_and(|l| lap.elapsed() >= l.max(Duration::ZERO))
        {
            break;
        }
    }
    times.solve = lap.elapsed().as_secs_f64();
    tracing::info!(
        iterations = info.iterations,
        residual = info.residual,
        converged = info.converged,
        "clustered bake: solved"
    );

    let (cluster_receiver_links, cluster_source_links) = sys.cluster_links();
    let report = BakeReport {
        patches: n,
        elements: n,
        links: sys.links(),
        link_bytes: sys.link_bytes(),
        solver: SolverKind::Jacobi,
        form_factors: params.form_factors,
        times,
        iterations: info.iterations,
        converged: info.converged,
        residual: info.residual,
        unshot_fraction: 0.0,
        timeline,
        warnings,
        stalled,
        has_emitters,
        clusters: Some(ClusterReport {
            clusters: tree.clusters.len(),
            cluster_receiver_links,
            cluster_source_links,
            refinement_asked: params.links.refinement,
            refinement_used: eps_used,
            memory_limit: budget.limit,
            memory_estimate: budget.used,
            enclosed,
        }),
    };
    let surfaces = surface_means(&scene.surfaces, &mesh, &b);
    let (rho, source, dead) = sys.into_parts();
    let system = System::new(
        &mesh,
        rho,
        source,
        crate::links::Links {
            row: vec![0; n + 1],
            ..Default::default()
        },
        &dead,
    );
    Ok(BakeResult::from_parts(
        mesh, system, b, surfaces, report, dead,
    ))
}

fn check(params: &BakeParams, cp: &ClusterParams) -> Result<(), BakeError> {
    let bad = |s: String| Err(BakeError::InvalidParameter(s));
    params.check()?;
    if !matches!(
        params.form_factors,
        FormFactorKind::Analytic | FormFactorKind::RayCast
    ) {
        return bad(format!(
            "the clustered hierarchy computes form factors analytic or ray-cast, not {}: use --hierarchy triangles for it",
            params.form_factors.name()
        ));
    }
    if cp.samples == 0 || cp.samples > 1024 {
        return bad(format!(
            "{} visibility samples per link: use 1 to 1024",
            cp.samples
        ));
    }
    if cp.memory_limit == Some(0) {
        return bad("a memory limit of 0 bytes".into());
    }
    Ok(())
}

/// Refines the links within the budget, coarsening if allowed; returns them with the
/// threshold used.
#[expect(clippy::too_many_arguments, reason = "the inputs of the link build")]
fn links(
    mesh: &Mesh,
    tree: &tree::Tree,
    bvh: &Bvh,
    params: &BakeParams,
    cp: &ClusterParams,
    rho: &[Rgb],
    source: &[Rgb],
    budget: &mut Budget,
    warnings: &mut Vec<String>,
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
    stop: Option<&AtomicBool>,
) -> Result<(Vec<Vec<refine::Link>>, f64), BakeError> {
    let max3 = |v: &Rgb| v[0].max(v[1]).max(v[2]);
    let bmesh = crate::hierarchy::Estimates::new(mesh, rho, source, 1.0).bhat;
    let m = mesh.nodes.len();
    let total = tree.len();
    // Clusters: area-weighted means (B̂ A is the cluster's power); mesh nodes keep their max.
    let mut bhat = bmesh;
    bhat.resize(total, 0.0);
    let mut rmax: Vec<f64> = vec![0.0; total];
    for (i, &id) in mesh.leaves.iter().enumerate() {
        rmax[id as usize] = max3(&rho[i]);
    }
    for nd in (0..m).rev() {
        let node = &mesh.nodes[nd];
        if !node.is_leaf() {
            rmax[nd] = (0..4)
                .map(|k| rmax[(node.first_child + k) as usize])
                .fold(0.0, f64::max);
        }
    }
    for c in (0..tree.clusters.len()).rev() {
        let cl = &tree.clusters[c];
        let [a, b] = cl.children.map(|x| x as usize);
        let id = m + c;
        let (wa, wb) = (tree.area[a], tree.area[b]);
        bhat[id] = if wa + wb > 0.0 {
            (wa * bhat[a] + wb * bhat[b]) / (wa + wb)
        } else {
            0.0
        };
        rmax[id] = rmax[a].max(rmax[b]);
    }
    let asked = params.links.refinement;
    let mut eps = asked;
    for attempt in 0..=COARSEN_STEPS {
        let max_links = budget.left() / solve::LINK_BYTES;
        let r = refine::Refiner {
            mesh,
            tree,
            vis: bvh,
            bhat: &bhat,
            rho: &rmax,
            eps,
            kind: params.form_factors,
            samples: cp.samples,
            seed: params.ff.seed,
            max_links,
            stop,
        };
        let t = Instant::now();
        if let Some(parts) = r.build(&|d, n| progress(Phase::Links, d, n)) {
            let count: u64 = parts.iter().map(|p| p.len() as u64).sum();
            budget.reserve("the links", count * solve::LINK_BYTES)?;
            if attempt > 0 {
                warnings.push(format!(
                    "the memory limit of {} MiB made the bake coarser: refinement {eps} instead of {asked}",
                    budget.limit >> 20
                ));
            }
            return Ok((parts, eps));
        }
        if stop.is_some_and(|f| f.load(Ordering::Relaxed)) {
            return Err(BakeError::Stopped);
        }
        tracing::warn!(
            refinement = eps,
            seconds = t.elapsed().as_secs_f64(),
            max_links,
            "links exceed the memory limit"
        );
        if !cp.coarsen {
            break;
        }
        eps *= 4.0;
    }
    Err(BakeError::OutOfMemory {
        what: "the links",
        needed: budget.used + budget.left() + 1,
        limit: budget.limit,
    })
}
