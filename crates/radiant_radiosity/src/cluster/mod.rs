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
//! [`ClusterBake`] is the same engine shape as the per-triangle [`crate::Bake`]: built (or
//! resumed from a version-4 (or 3) checkpoint), then stepped one sweep at a time ([`Info`], the
//! stopping rule of [`crate::solve::Stall`]); material and light edits keep its links, and a
//! geometry edit refines only what it touches ([`ClusterBake::edit_geometry`], bit for bit a
//! fresh bake's links). What it does not do (the per-triangle bake does): the hemicube and
//! Monte Carlo form-factor methods (they gather a whole receiver's row at once, which a
//! two-sided hierarchy does not have).

mod bake;
mod edit;
mod preview;
pub mod record;
pub mod refine;
pub mod sh;
pub mod solve;
pub mod transfer;
pub mod tree;

pub use bake::{ClusterBake, EditPhases, GeometryEdit};
pub use preview::EditPreview;
pub use refine::RefineStats;

use std::sync::atomic::{AtomicBool, Ordering};

use radiant_scene::Scene;

use crate::form_factors::FormFactorKind;
use crate::mesh::Mesh;
use crate::params::BakeParams;
use crate::report::BakeResult;
use crate::solve::Info;
use crate::solvers::SolverKind;
use crate::system::Rgb;
use crate::{BakeError, ParameterError};

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
    /// Keep the refinement's record, so that a geometry edit
    /// ([`ClusterBake::edit_geometry`]) refines only what it touches; about a byte per pair
    /// visited and 12 per link. Off, an edit refines everything again (default: true).
    pub edits: bool,
    /// Each element takes its clusters' light by its own visibility ([`transfer`]: a nook
    /// inside a large cluster no longer takes the light its open neighbours see); off, by its
    /// normal alone. Sixteen short probe rays per element (default: true).
    pub transfer: bool,
}

impl Default for ClusterParams {
    fn default() -> Self {
        ClusterParams {
            memory_limit: None,
            coarsen: true,
            samples: 4,
            max_sweeps: 10_000,
            edits: true,
            transfer: true,
        }
    }
}

/// Times the threshold may be raised to fit the memory budget.
pub const COARSEN_STEPS: u32 = 3;

/// What the clustered bake reports beyond [`crate::BakeReport`].
#[derive(Clone, Debug, PartialEq)]
pub struct ClusterReport {
    /// Clusters above the input triangles.
    pub clusters: usize,
    /// Links whose receiver is a cluster.
    pub cluster_receiver_links: usize,
    /// Links whose source is a cluster.
    pub cluster_source_links: usize,
    /// Form factors the last refinement computed (links found wholly hidden included; after a
    /// geometry edit, only those it did not keep).
    pub form_factors: u64,
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
    /// Elements enclosed in part: some of their probe points exposed, some not
    /// ([`crate::exposure`]).
    pub partly_enclosed: usize,
    /// Whether the elements took their clusters' light by their own visibility
    /// ([`transfer`]), not by their normals alone.
    pub transfer: bool,
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
    /// Per element: its exposed probe points, of [`crate::exposure::POINTS`]: `radiosity` is
    /// that of the exposed part ([`crate::metrics::surface_means_exposed`] weighs it).
    pub exposure: &'a [u8],
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

/// Which link hierarchy bakes a scene (the CLI's `--hierarchy`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Hierarchy {
    /// The clustered hierarchy for a level ([`suits`]), else the per-triangle one.
    #[default]
    Auto,
    /// Volume clusters above the triangles, links at any level on both ends; a solver or
    /// form-factor method it does not support is a typed error when the bake is built.
    Clustered,
    /// Every element gathers from a per-triangle hierarchy.
    Triangles,
}

impl Hierarchy {
    /// Whether `scene` bakes with the clustered hierarchy.
    pub fn clustered(self, scene: &Scene, params: &BakeParams) -> Result<bool, BakeError> {
        match self {
            Hierarchy::Auto => suits(scene, params),
            Hierarchy::Clustered => Ok(true),
            Hierarchy::Triangles => Ok(false),
        }
    }
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

/// Bakes `scene` with the clustered hierarchy ([`ClusterBake`] run to the end). `params` gives
/// the meshing (element size = patch size / 2^element levels), the threshold
/// (`links.refinement`), the form-factor method (analytic or ray-cast between triangles), the
/// seed, the tolerance and the time limit. `progress(phase, done, total)` is called as the
/// bake advances, also from worker threads. `watch` sees the solution after every sweep and
/// can stop the bake.
pub fn bake_watched(
    scene: &Scene,
    params: &BakeParams,
    cp: &ClusterParams,
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
    mut watch: Watch<'_>,
) -> Result<BakeResult, BakeError> {
    // Run once to the end: no geometry edit follows, so the refinement's record is not kept.
    let cp = ClusterParams {
        edits: false,
        ..*cp
    };
    let mut bake = ClusterBake::new(scene, params, &cp, progress, watch.stop)?;
    bake.run_to_end(progress, &mut watch)?;
    Ok(bake.finish())
}

fn check(params: &BakeParams, cp: &ClusterParams) -> Result<(), BakeError> {
    params.check()?;
    if !matches!(
        params.form_factors,
        FormFactorKind::Analytic | FormFactorKind::RayCast
    ) {
        return Err(ParameterError::FormFactors {
            method: params.form_factors.name(),
        }
        .into());
    }
    if cp.samples == 0 || cp.samples > 1024 {
        let samples = f64::from(cp.samples);
        return Err(ParameterError::out_of_range("visibility samples", samples, "1..=1024").into());
    }
    if cp.memory_limit == Some(0) {
        return Err(ParameterError::out_of_range("memory limit", 0.0, "(0, inf) bytes").into());
    }
    Ok(())
}
