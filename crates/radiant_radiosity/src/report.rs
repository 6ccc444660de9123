//! What a bake hands over: its report (phase times, the residual against time, warnings, the
//! clustered hierarchy's figures) and its result.

use crate::BakeError;
use crate::form_factors::FormFactorKind;
use crate::hierarchy::Hierarchy;
use crate::mesh::Mesh;
use crate::metrics::SurfaceMean;
use crate::solve::SolveError;
use crate::solvers::SolverKind;
use crate::system::{Rgb, System};

/// Seconds spent in each phase.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PhaseTimes {
    /// Meshing.
    pub meshing: f64,
    /// BVH build.
    pub visibility: f64,
    /// Direct light from punctual lights.
    pub direct_light: f64,
    /// Link refinement and form factors.
    pub form_factors: f64,
    /// Solving.
    pub solve: f64,
}

/// One point of the convergence timeline.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimelinePoint {
    /// Seconds since the bake started (meshing included).
    pub t_s: f64,
    /// Iterations or shots so far.
    pub iterations: u64,
    /// Relative residual.
    pub residual: f64,
    /// Unshot energy fraction.
    pub unshot_fraction: f64,
}

/// What a bake reports.
#[derive(Clone, Debug, PartialEq)]
pub struct BakeReport {
    /// Patches (nodes at the patch size).
    pub patches: usize,
    /// Elements (leaves).
    pub elements: usize,
    /// Links.
    pub links: usize,
    /// Bytes held by the links.
    pub link_bytes: usize,
    /// The solver.
    pub solver: SolverKind,
    /// The form-factor method.
    pub form_factors: FormFactorKind,
    /// Seconds per phase.
    pub times: PhaseTimes,
    /// Iterations or shots.
    pub iterations: u64,
    /// Whether the tolerance was met.
    pub converged: bool,
    /// Final relative residual.
    pub residual: f64,
    /// Final unshot fraction.
    pub unshot_fraction: f64,
    /// The timeline.
    pub timeline: Vec<TimelinePoint>,
    /// Warnings (skipped input, no emitters, a stall, …).
    pub warnings: Vec<String>,
    /// Why the solve ended unconverged when it gave up by itself ([`SolveError::Stalled`]);
    /// `None` when it converged or ran out of time.
    pub stalled: Option<SolveError>,
    /// Whether anything emits.
    pub has_emitters: bool,
    /// The clustered hierarchy's figures, when it made the links ([`crate::cluster`]).
    pub clusters: Option<crate::cluster::ClusterReport>,
}

/// The outcome of a bake.
pub struct BakeResult {
    /// The element hierarchy.
    pub mesh: Mesh,
    /// The system that was solved.
    pub system: System,
    /// Radiosity per element (emissive units).
    pub radiosity: Vec<Rgb>,
    /// Area-weighted mean radiosity per surface.
    pub surfaces: Vec<SurfaceMean>,
    /// The report.
    pub report: BakeReport,
    /// The links' bookkeeping, for checkpoints.
    pub(crate) hierarchy: Hierarchy,
}

impl BakeResult {
    /// A result made without per-triangle links (the clustered hierarchy): no checkpoint can
    /// be written from it.
    pub(crate) fn from_parts(
        mesh: Mesh,
        system: System,
        radiosity: Vec<Rgb>,
        surfaces: Vec<SurfaceMean>,
        report: BakeReport,
        dead: Vec<bool>,
    ) -> BakeResult {
        BakeResult {
            mesh,
            system,
            radiosity,
            surfaces,
            report,
            hierarchy: Hierarchy {
                fingerprint: 0,
                dead,
                oracle: None,
            },
        }
    }

    /// Writes the links and the solution to `path` (see [`crate::Bake::write_checkpoint`]).
    pub fn write_checkpoint(&self, path: &std::path::Path) -> Result<(), BakeError> {
        if self.report.clusters.is_some() {
            return Err(crate::checkpoint::CheckpointError::ClusteredResult.into());
        }
        crate::checkpoint::write(
            path,
            &self.hierarchy,
            self.mesh.nodes.len(),
            &self.system.links,
            &self.radiosity,
        )
    }
}
