//! The clustered bake as an engine: built (or resumed), stepped a sweep at a time, edited, and
//! finished into a [`BakeResult`].

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use radiant_scene::{Light, Scene, Sky, Surface};
use radiant_visibility::{Bvh, Visibility};

use super::edit::{self, Before, Moved, New, Old};
use super::preview::{self, EditPreview};
use super::record::Record;
use super::refine::{Link, RefineStats, Walk};
use super::solve::{HierSystem, LINK_BYTES, SweepScratch, Sweeping};
use super::tree::Tree;
use super::{
    Budget, COARSEN_STEPS, ClusterParams, ClusterReport, Phase, Sweep, Watch, check, refine,
};
use crate::checkpoint::CheckpointError;
use crate::hierarchy::RootMatch;
use crate::input::{self, Lighting};
use crate::mesh::Mesh;
use crate::metrics::surface_means_exposed;
use crate::params::BakeParams;
use crate::report::{BakeReport, BakeResult, PhaseTimes, TimelinePoint};
use crate::rng::Fnv;
use crate::smooth::SmoothField;
use crate::solve::{Info, SolveError};
use crate::solvers::SolverKind;
use crate::system::{Rgb, System};
use crate::{BakeError, ParameterError};

/// A clustered bake in progress: the mesh, the cluster tree and the links at every level, and
/// the Jacobi sweeps over them.
pub struct ClusterBake {
    mesh: Arc<Mesh>,
    /// The ray tracer over `mesh`, kept for an edit's preview ([`ClusterParams::edits`]).
    bvh: Option<Arc<Bvh>>,
    tree: Tree,
    sys: HierSystem,
    surfaces: Vec<Surface>,
    lighting: Lighting,
    params: BakeParams,
    cp: ClusterParams,
    /// The fingerprint of geometry and link parameters, for checkpoints.
    fingerprint: u64,
    /// The threshold the links were built with.
    refinement_used: f64,
    /// The estimates the links were refined with.
    oracle: Oracle,
    /// The refinement, kept for geometry edits ([`ClusterParams::edits`]; not after a resume).
    record: Option<Record>,
    /// What the last refinement computed and kept.
    refined: RefineStats,
    budget: Budget,
    has_emitters: bool,
    resumed: bool,
    b: Vec<Rgb>,
    sweeps: Sweeps,
    started: Instant,
    times: PhaseTimes,
    warnings: Vec<String>,
}

/// Where the sweeps stand.
struct Sweeps {
    info: Info,
    /// The stopping measure and the stall rule (afresh since the start or an edit).
    rule: Sweeping,
    /// Sweeps since the start or the last edit.
    since_start: u64,
    stalled: Option<SolveError>,
    timeline: Vec<TimelinePoint>,
    solving: Duration,
    /// The sweeps' buffers, kept from one to the next until the solve converges.
    scratch: SweepScratch,
}

impl Sweeps {
    fn new(has_emitters: bool) -> Sweeps {
        let mut info = Info::nothing_to_solve();
        info.converged = !has_emitters;
        Sweeps {
            info,
            rule: Sweeping::default(),
            since_start: 0,
            stalled: None,
            timeline: Vec::new(),
            solving: Duration::ZERO,
            scratch: SweepScratch::default(),
        }
    }
}

/// What a geometry edit of a clustered bake did ([`ClusterBake::edit_geometry`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GeometryEdit {
    /// Links whose form factor was computed (wholly hidden ones included).
    pub computed: u64,
    /// Links kept from before the edit.
    pub kept: u64,
    /// Links after the edit.
    pub links: usize,
    /// Nodes (triangles, their subdivisions and clusters) that are old ones.
    pub kept_nodes: usize,
    /// Nodes after the edit.
    pub nodes: usize,
    /// Seconds the edit took, the solve not included.
    pub seconds: f64,
    /// Where they went.
    pub phases: EditPhases,
    /// The new refinement's record was put together in the old record's memory, not in fresh
    /// memory beside it (see [`ClusterBake::edit_geometry`]).
    pub in_place: bool,
}

/// Seconds of a geometry edit's phases.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EditPhases {
    /// The edited scene meshed and its nodes matched to the old ones.
    pub meshing: f64,
    /// The preview made and handed out ([`ClusterBake::edit_geometry_previewed`]).
    pub preview: f64,
    /// Its BVH and cluster tree.
    pub visibility: f64,
    /// Direct light, sources and enclosed elements.
    pub direct_light: f64,
    /// The old refinement's nodes matched and what changed bounded.
    pub matching: f64,
    /// A resumed bake's refinement made again for its record, before its first edit.
    pub replay: f64,
    /// The refinement, copied where nothing changed.
    pub refinement: f64,
    /// Its record put together.
    pub assembly: f64,
    /// The solver's rows.
    pub rows: f64,
}

/// The record a checkpoint holds, its links found again in the checkpoint's rows: `None`
/// (noted in the log) unless its links are the rows' links, each met once, or over `budget`.
fn saved_record(
    mesh: &Mesh,
    tree: &Tree,
    rows: &super::solve::Rows,
    (ops, sized): (Vec<u8>, Vec<super::record::Extent>),
    budget: &mut Budget,
) -> Option<Record> {
    let children = |id: u32| match tree.cluster(id) {
        Some(c) => ([c.children[0], c.children[1], 0, 0], 2),
        None => match mesh.nodes.get(id as usize).map(|n| n.first_child) {
            Some(f) if f != crate::mesh::NO_CHILD => ([f, f + 1, f + 2, f + 3], 4),
            _ => ([0; 4], 0),
        },
    };
    let replay = refine::Replay::new(&rows.row, &rows.src, &rows.ff);
    let rebuilt = Record::rebuilt(ops, sized, tree.root(mesh), children, |r, s| {
        replay.get(r, s).map_or(0.0, |f| {
            replay.met(1);
            f
        })
    });
    let whole = rebuilt
        .as_ref()
        .is_some_and(|r| r.links.len() == rows.src.len() && replay.all_met());
    let fits = whole
        && rebuilt.as_ref().is_some_and(|r| {
            (budget.reserve(
                "the refinement's record",
                r.bytes() - r.links.len() as u64 * 12,
            ))
            .is_ok()
        });
    if !fits {
        tracing::info!(
            whole,
            "clustered bake: the checkpoint's record is not kept; a geometry edit makes the refinement again"
        );
    }
    rebuilt.filter(|_| fits)
}

/// A visibility for a refinement that casts no ray ([`refine::Replay`]): never asked.
struct NoRays;

impl Visibility for NoRays {
    fn segment_clear(&self, _: glam::Vec3, _: glam::Vec3) -> bool {
        false
    }

    fn closest_hit(&self, _: glam::Vec3, _: glam::Vec3, _: f32) -> Option<radiant_visibility::Hit> {
        None
    }
}

/// The fingerprint of what clustered links depend on: the per-triangle bake's, and the
/// visibility samples per link.
fn fingerprint(scene: &Scene, params: &BakeParams, cp: &ClusterParams) -> u64 {
    let mut h = Fnv(crate::hierarchy::fingerprint(scene, params));
    h.bytes(b"clustered");
    h.bytes(&cp.samples.to_le_bytes());
    h.0
}

/// Reserves the buffers of a mesh's bake from the budget, before they are allocated.
fn reserve_buffers(mesh: &Mesh, budget: &mut Budget) -> Result<(), BakeError> {
    let n = mesh.element_count() as u64;
    // Per element: reflectance, source, area, solution twice; per node: tree geometry and
    // three solver buffers.
    let nodes = (mesh.nodes.len() + mesh.roots.len()) as u64;
    budget.reserve("the element buffers", n * (24 * 4 + 16))?;
    budget.reserve("the cluster tree", nodes * (24 * 5 + 8 * 4))?;
    // Per cluster: its normals' harmonics (the tree's, and the solve's copy and exposed
    // parts'), and two harmonics buffers of the solve.
    budget.reserve(
        "the cluster buffers",
        mesh.roots.len() as u64 * (3 * 72 + 2 * 216),
    )?;
    budget.reserve("the ray-tracing BVH", mesh.roots.len() as u64 * 160)?;
    // Per element its transfer and cluster, per cluster their mean (`transfer`).
    budget.reserve(
        "the elements' transfers",
        n * 40 + mesh.roots.len() as u64 * 72,
    )?;
    // Kept for edits: direct light and the textures' footprints.
    budget.reserve("the lighting kept for edits", n * 24 * 3)
}

impl ClusterBake {
    /// Prepares a bake: mesh, clusters, direct light and links within the memory budget.
    /// `progress` is called while links are refined; `stop` is polled then (the bake returns
    /// [`BakeError::Stopped`]).
    pub fn new(
        scene: &Scene,
        params: &BakeParams,
        cp: &ClusterParams,
        progress: &(dyn Fn(Phase, usize, usize) + Sync),
        stop: Option<&AtomicBool>,
    ) -> Result<ClusterBake, BakeError> {
        Self::build(scene, params, cp, progress, stop, None)
    }

    /// Resumes from a checkpoint written by [`ClusterBake::write_checkpoint`] for the same
    /// geometry and link parameters: no links are refined, and the sweeps continue from the
    /// saved radiosity under the scene's current materials and lights. A per-triangle
    /// checkpoint is [`BakeError::CheckpointHierarchy`]; one for other geometry, or a damaged
    /// one, [`BakeError::Checkpoint`].
    pub fn resume(
        scene: &Scene,
        params: &BakeParams,
        cp: &ClusterParams,
        path: &Path,
    ) -> Result<ClusterBake, BakeError> {
        let saved = crate::checkpoint::read_clustered(path)?;
        Self::build(scene, params, cp, &|_, _, _| {}, None, Some(saved))
    }

    fn build(
        scene: &Scene,
        params: &BakeParams,
        cp: &ClusterParams,
        progress: &(dyn Fn(Phase, usize, usize) + Sync),
        stop: Option<&AtomicBool>,
        saved: Option<crate::checkpoint::SavedClustered>,
    ) -> Result<ClusterBake, BakeError> {
        let started = Instant::now();
        let scene = input::static_scene(scene);
        let scene = scene.as_ref();
        input::validate(scene)?;
        check(params, cp)?;
        let fingerprint = fingerprint(scene, params, cp);
        if let Some(s) = saved.as_ref().filter(|s| s.fingerprint != fingerprint) {
            return Err(CheckpointError::OtherScene {
                expected: fingerprint,
                found: s.fingerprint,
            }
            .into());
        }
        let mut times = PhaseTimes::default();
        let mut budget = Budget::new(cp.memory_limit);
        let mut t = Instant::now();
        let mut lap = || {
            std::mem::replace(&mut t, Instant::now())
                .elapsed()
                .as_secs_f64()
        };
        let mesh = Mesh::adaptive(scene, &params.mesh, &mut |b| budget.reserve("the mesh", b))?;
        reserve_buffers(&mesh, &mut budget)?;
        times.meshing = lap();
        let masks = input::masks(scene);
        let bvh = input::visibility(&mesh, masks.as_ref());
        let tree = Tree::new(&mesh);
        times.visibility = lap();
        tracing::info!(
            elements = mesh.element_count(),
            triangles = mesh.roots.len(),
            clusters = tree.clusters.len(),
            "clustered bake: meshed"
        );
        let lighting = Lighting::new(scene, &mesh, &bvh, masks, &params.ff);
        let (rho, source) = lighting.terms(&scene.surfaces, &mesh);
        times.direct_light = lap();
        let mut warnings = scene.warnings();
        let has_emitters = source.iter().flatten().any(|&v| v > 0.0);
        let n = mesh.element_count();
        let resumed = saved.is_some();
        let oracle = Oracle::new(&mesh, &tree, &rho, &source);
        let mut refined = RefineStats::default();
        let (sys, refinement_used, b, record) = match saved {
            Some(mut sv) => {
                if sv.live.len() != n || sv.nodes != tree.len() {
                    return Err(CheckpointError::OtherMesh {
                        elements: n,
                        nodes: tree.len(),
                        found_elements: sv.live.len(),
                        found_nodes: sv.nodes,
                    }
                    .into());
                }
                if has_emitters && sv.rows.src.is_empty() && n > 0 {
                    // Written when nothing emitted, so it has no links to resume from.
                    return Err(CheckpointError::NoLinks.into());
                }
                budget.reserve("the links", sv.rows.src.len() as u64 * LINK_BYTES)?;
                // Kept when refined with the estimates this resume has (not when the materials
                // changed since), and its links are the checkpoint's.
                let record = match sv.record.take() {
                    Some((hash, ops, sized)) if cp.edits && hash == oracle.hash() => {
                        saved_record(&mesh, &tree, &sv.rows, (ops, sized), &mut budget)
                    }
                    _ => None,
                };
                // Room for an edit's rows to be built in these (see HierSystem::new_in).
                let room = sv.rows.src.len() / 64;
                let _ =
                    (sv.rows.src.try_reserve_exact(room)).and(sv.rows.ff.try_reserve_exact(room));
                let sys = HierSystem::from_rows(&mesh, &tree, sv.rows, rho, source, sv.live);
                (sys, sv.refinement, Some(sv.radiosity), record)
            }
            None if has_emitters => {
                let live = crate::exposure::exposure(&mesh, &bvh, params.ff.seed);
                let inputs = (&mesh, &tree, &bvh as &dyn Visibility, &oracle);
                let (walk, eps, stats) = refine_within_budget(
                    inputs,
                    params,
                    cp,
                    &mut budget,
                    &mut warnings,
                    progress,
                    stop,
                    None,
                )?;
                let record = walk.assemble(None).ok_or(BakeError::OutOfMemory {
                    what: "the refinement's record",
                    needed: Record::bytes_of(walk.extent()),
                    limit: budget.limit,
                })?;
                drop(walk);
                let sys = HierSystem::new(&mesh, &tree, &record.links, rho, source, live)?;
                refined = stats;
                (sys, eps, None, cp.edits.then_some(record))
            }
            None => {
                warnings
                    .push("no emitters and no lights: nothing to bake, all radiosity is 0".into());
                let all = vec![crate::exposure::POINTS as u8; n];
                let sys = HierSystem::new(&mesh, &tree, &[], rho, source, all)?;
                (sys, params.links.refinement, None, None)
            }
        };
        let mut sys = sys;
        if has_emitters && cp.transfer {
            sys.set_transfer(super::transfer::transfer(
                &mesh,
                &tree,
                &bvh,
                params.ff.seed,
            ));
        }
        times.form_factors = lap();
        tracing::info!(
            links = sys.links(),
            seconds = times.form_factors,
            resumed,
            "clustered bake: links"
        );
        let b = b.unwrap_or_else(|| sys.source.clone());
        Ok(ClusterBake {
            mesh: Arc::new(mesh),
            bvh: (cp.edits && has_emitters).then(|| Arc::new(bvh)),
            tree,
            sys,
            surfaces: scene.surfaces.clone(),
            lighting,
            params: *params,
            cp: *cp,
            fingerprint,
            refinement_used,
            oracle,
            record,
            refined,
            budget,
            has_emitters,
            resumed,
            b,
            sweeps: Sweeps::new(has_emitters),
            started,
            times,
            warnings,
        })
    }

    /// One Jacobi sweep of gather and push-pull, carried on where its contraction has settled
    /// ([`Sweeping`]). The estimated error is the sweep's update times `q / (1 − q)`, `q` the
    /// observed contraction (at least that of the last extrapolation), relative to the bounced
    /// light (`b − source`: in a sunlit level the direct light dominates `‖b‖`, and a change
    /// measured against it stopped Sponza after 4 sweeps while its shade was still filling
    /// in). A solve that stalls or diverges is an error.
    pub fn step(&mut self) -> Result<Info, SolveError> {
        if !self.has_emitters {
            return Ok(Info::nothing_to_solve());
        }
        let t = Instant::now();
        let s = &mut self.sweeps;
        let mut nb = self
            .sys
            .sweep_in(&self.b, &self.sys.rho, &self.sys.source, &mut s.scratch);
        let residual = s.rule.residual(&self.sys, &nb, &self.b, &self.sys.source);
        s.since_start += 1;
        let iterations = s.info.iterations + 1;
        let tol = self.params.solver_params.tolerance;
        let converged = residual <= tol && s.since_start >= 2;
        if !converged && residual.is_finite() {
            s.rule.extrapolate(&mut nb, &self.b);
        }
        self.b = nb;
        if converged {
            // Nothing sweeps until the next change: the buffers go.
            s.scratch = SweepScratch::default();
        }
        // The residual is already an error estimate: contraction 0 keeps it as it is.
        s.info = Info::from_residual(iterations, residual, 0.0, 0.0, tol, converged);
        s.solving += t.elapsed();
        if !residual.is_finite() {
            return Err(SolveError::Diverged {
                residual,
                iterations,
            });
        }
        s.timeline.push(TimelinePoint {
            t_s: self.started.elapsed().as_secs_f64(),
            iterations,
            residual,
            unshot_fraction: 0.0,
        });
        if !converged {
            s.rule.stall.observe(residual, iterations)?;
        }
        Ok(s.info)
    }

    /// Sweeps until converged, the time limit or [`ClusterParams::max_sweeps`], showing each
    /// sweep to `watch` and `progress`. A stall ends it unconverged (with a warning and
    /// `report.stalled`); a stop from `watch` is [`BakeError::Stopped`].
    pub fn run_to_end(
        &mut self,
        progress: &(dyn Fn(Phase, usize, usize) + Sync),
        watch: &mut Watch<'_>,
    ) -> Result<(), BakeError> {
        let max = u64::from(self.cp.max_sweeps);
        while self.has_emitters && !self.out_of_sweeps() {
            let info = match self.step() {
                Ok(info) => info,
                Err(e @ SolveError::Stalled { .. }) => {
                    self.warnings.push(e.to_string());
                    self.sweeps.stalled = Some(e);
                    break;
                }
                Err(e) => return Err(e.into()),
            };
            progress(Phase::Solve, info.iterations as usize, max as usize);
            if let Some(f) = watch.on_sweep.as_mut() {
                f(&self.sweep_view());
            }
            if watch.stopped() {
                return Err(BakeError::Stopped);
            }
            if info.converged || self.out_of_sweeps() {
                break;
            }
        }
        tracing::info!(
            iterations = self.sweeps.info.iterations,
            residual = self.sweeps.info.residual,
            converged = self.sweeps.info.converged,
            "clustered bake: solved"
        );
        Ok(())
    }

    /// Whether the sweeps have run out: [`ClusterParams::max_sweeps`] done, or the solve's time
    /// limit (`BakeParams::time_limit`) spent.
    pub fn out_of_sweeps(&self) -> bool {
        let s = &self.sweeps;
        s.info.iterations >= u64::from(self.cp.max_sweeps)
            || (self.params.time_limit).is_some_and(|l| s.solving >= l)
    }

    /// The current light as a smooth field (for light maps): each element votes by its exposed
    /// area, enclosed elements not at all.
    pub fn smooth_field(&self) -> SmoothField {
        let (rho, live) = (&self.sys.rho, self.sys.exposure());
        crate::smooth::exposed_field(&self.mesh, &self.surfaces, rho, live, &self.radiosity())
    }

    /// The bake as [`Watch::on_sweep`] sees it.
    pub fn sweep_view(&self) -> Sweep<'_> {
        Sweep {
            mesh: &self.mesh,
            radiosity: &self.b,
            reflectance: &self.sys.rho,
            enclosed: self.sys.enclosed(),
            exposure: self.sys.exposure(),
            info: self.sweeps.info,
            links: self.sys.links(),
            seconds: self.started.elapsed().as_secs_f64(),
        }
    }

    /// The element hierarchy.
    pub fn mesh(&self) -> &Mesh {
        &self.mesh
    }

    /// The mesh, shared: what a published light refers to, without a copy.
    pub fn shared_mesh(&self) -> Arc<Mesh> {
        Arc::clone(&self.mesh)
    }

    /// The cluster tree above the mesh's input triangles.
    pub fn tree(&self) -> &Tree {
        &self.tree
    }

    /// Per element: its reflectance and its source term (emission and the lights' direct
    /// light, times the reflectance), as the solve takes them.
    pub fn terms(&self) -> (Vec<Rgb>, Vec<Rgb>) {
        self.lighting.terms(&self.surfaces, &self.mesh)
    }

    /// The scene's surfaces as the bake has them.
    pub fn surfaces(&self) -> &[Surface] {
        &self.surfaces
    }

    /// The current radiosity per element.
    pub fn radiosity(&self) -> Vec<Rgb> {
        if self.has_emitters {
            self.b.clone()
        } else {
            vec![[0.0; 3]; self.b.len()]
        }
    }

    /// The latest sweep's info.
    pub fn last_info(&self) -> Info {
        self.sweeps.info
    }

    /// Whether this bake came from a checkpoint.
    pub fn is_resumed(&self) -> bool {
        self.resumed
    }

    /// Links.
    pub fn links(&self) -> usize {
        self.sys.links()
    }

    /// The links in rows by receiver node (mesh nodes, then clusters).
    pub fn rows(&self) -> super::solve::RowsRef<'_> {
        self.sys.rows()
    }

    /// Per element: inside closed geometry (it receives nothing and is seen by nothing).
    pub fn enclosed(&self) -> &[bool] {
        &self.sys.dead
    }

    /// Per element: how many of its probe points are exposed, of [`crate::exposure::POINTS`].
    /// Its radiosity is that of its exposed part; [`crate::exposure::fraction`] of its area
    /// counts in a surface's mean ([`crate::metrics::surface_means_exposed`]).
    pub fn exposure(&self) -> &[u8] {
        self.sys.exposure()
    }

    /// Changes the surfaces' reflectance and emission and continues from the current
    /// solution: the links are kept (they do not depend on colour; refinement used the old
    /// estimates, as the per-triangle bake's edits do). Returns [`BakeError::NeedsRebuild`]
    /// when the edit turns a bake with no emitters into one with some: it has no links.
    pub fn edit_surfaces(&mut self, surfaces: &[Surface]) -> Result<(), BakeError> {
        if surfaces.len() != self.surfaces.len() {
            return Err(ParameterError::SurfaceCount {
                expected: self.surfaces.len(),
                given: surfaces.len(),
            }
            .into());
        }
        input::validate_surfaces(surfaces)?;
        let (rho, source) = self.lighting.terms(surfaces, &self.mesh);
        let has_emitters = source.iter().flatten().any(|&v| v > 0.0);
        if has_emitters && !self.has_emitters {
            return Err(BakeError::NeedsRebuild);
        }
        self.sys.rho = rho;
        self.sys.source = source;
        self.surfaces = surfaces.to_vec();
        self.has_emitters = has_emitters;
        let s = &mut self.sweeps;
        (s.rule, s.since_start, s.stalled) = (Sweeping::default(), 0, None);
        s.info.converged = !has_emitters;
        Ok(())
    }

    /// Replaces the punctual lights and the sky (`None`: no sky): their direct light is traced
    /// again, the links are kept, and the sweeps continue as after [`Self::edit_surfaces`].
    pub fn edit_lights_and_sky(
        &mut self,
        lights: &[Light],
        sky: Option<&Sky>,
    ) -> Result<(), BakeError> {
        input::validate_lights(lights)?;
        let relit = (self.lighting).relit(lights, sky, &self.mesh, &self.params.ff);
        let old = std::mem::replace(&mut self.lighting, relit);
        let surfaces = self.surfaces.clone();
        let result = self.edit_surfaces(&surfaces);
        if result.is_err() {
            self.lighting = old;
        }
        result
    }

    /// Moves, adds or removes static geometry (the scene's materials and lights come along) and
    /// refines only what the edit touches. Triangles are matched to the old ones by surface
    /// name, index within the surface and exact position ([`RootMatch`]); a cluster of the same
    /// triangles is the same cluster. The refinement is walked again from the root's
    /// self-link beside the old one's record: a pair of old nodes whose estimates below them
    /// are unchanged and whose shaft meets nothing that moved keeps all that was refined of
    /// it; other links are computed, but an old link's form factor is kept where its nodes and
    /// sample count are the old ones and its shaft is clear. Visibility rays are seeded by the
    /// nodes' own triangles, so the links equal a fresh bake's bit for bit. Direct light and
    /// enclosed elements are computed again; the sweeps warm-start from the current light,
    /// carried to the triangles that stayed. The new record is put together in the old one's
    /// memory, what it keeps moved into place ([`GeometryEdit::in_place`]); only where that
    /// cannot be done is it written beside it, the old record then counted in the memory
    /// budget too.
    ///
    /// [`BakeError::NeedsRebuild`] when the scene's bounding box changed (every local
    /// coordinate would), when nothing emits before or after, or when the surfaces were
    /// renumbered. Without the record (a resumed bake, or [`ClusterParams::edits`] off) every
    /// link is refined again, to the same result.
    pub fn edit_geometry(
        &mut self,
        scene: &Scene,
        progress: &(dyn Fn(Phase, usize, usize) + Sync),
        stop: Option<&AtomicBool>,
    ) -> Result<GeometryEdit, BakeError> {
        self.edit_geometry_previewed(scene, progress, stop, None)
    }

    /// [`ClusterBake::edit_geometry`], which hands `preview` a first look at the edited light
    /// as soon as the edited scene is meshed, before the refinement ([`EditPreview`]: the
    /// carried light with the direct light traced again where it may have changed, new
    /// triangles' light gathered). No preview when materials, lights or the sky change with
    /// the edit, or when the bake keeps no ray tracer ([`ClusterParams::edits`] off, or after
    /// an edit that failed).
    pub fn edit_geometry_previewed(
        &mut self,
        scene: &Scene,
        progress: &(dyn Fn(Phase, usize, usize) + Sync),
        stop: Option<&AtomicBool>,
        preview: Option<&mut dyn FnMut(EditPreview)>,
    ) -> Result<GeometryEdit, BakeError> {
        let started = Instant::now();
        let mut phases = EditPhases::default();
        let mut t = Instant::now();
        let mut lap = || {
            std::mem::replace(&mut t, Instant::now())
                .elapsed()
                .as_secs_f64()
        };
        let scene = input::static_scene(scene);
        let scene = scene.as_ref();
        input::validate(scene)?;
        if !self.has_emitters || !scene.has_emitters() {
            return Err(BakeError::NeedsRebuild);
        }
        let mut budget = Budget::new(Some(self.budget.limit));
        let mesh = Arc::new(Mesh::adaptive(scene, &self.params.mesh, &mut |b| {
            budget.reserve("the mesh", b)
        })?);
        if mesh.frame != self.mesh.frame {
            return Err(BakeError::NeedsRebuild);
        }
        reserve_buffers(&mesh, &mut budget)?;
        let matched = RootMatch::new(&self.mesh, &mesh);
        if matched.unchanged()
            && scene.surfaces == self.surfaces
            && scene.lights == self.lighting.lights
            && scene.sky == self.lighting.sky
            && self.lighting.same_textures(scene)
        {
            return Ok(GeometryEdit {
                links: self.sys.links(),
                ..GeometryEdit::default()
            });
        }
        phases.meshing = lap();
        // The old ray tracer serves the preview only: it goes before the new one is built.
        let old_bvh = self.bvh.take();
        if let (Some(show), Some(bvh)) = (preview, old_bvh.as_deref())
            && scene.surfaces == self.surfaces
            && scene.lights == self.lighting.lights
            && scene.sky == self.lighting.sky
        {
            let before = preview::Before {
                mesh: &self.mesh,
                bvh,
                masks: self.lighting.masks.as_ref(),
                direct: self.lighting.direct.as_deref(),
                rho: &self.sys.rho,
                textures: self.lighting.textures.as_ref(),
                b: &self.b,
                exposure: self.sys.exposure(),
            };
            let lit = preview::Lit {
                scene,
                params: &self.params.ff,
            };
            if let Some(p) = preview::preview(&before, (&mesh, &matched), &lit, started) {
                tracing::info!(
                    seconds = p.seconds,
                    retraced = p.retraced,
                    gathered = p.gathered,
                    "clustered bake: geometry edit previewed"
                );
                show(p);
            }
            phases.preview = lap();
        }
        drop(old_bvh);
        if self.record.is_none() && self.cp.edits {
            self.record = self.replayed_record();
            phases.replay = lap();
        }
        let masks = input::masks(scene);
        let bvh = input::visibility(&mesh, masks.as_ref());
        let tree = Tree::new(&mesh);
        phases.visibility = lap();
        let lighting = Lighting::edited(
            scene,
            (&mesh, &matched.old_of_new_leaf),
            &bvh,
            masks,
            &self.params.ff,
            (&self.lighting, &self.mesh),
        );
        let (rho, source) = lighting.terms(&scene.surfaces, &mesh);
        if !source.iter().flatten().any(|&v| v > 0.0) {
            // Lights that reach nothing: a fresh bake would say so and build no links.
            return Err(BakeError::NeedsRebuild);
        }
        let moved = Moved::new(&matched.changed_triangles(&self.mesh, &mesh));
        // An element that stayed keeps its answer when what moved lies behind it, or else
        // unless one of its probes may meet what moved.
        let old_live = self.sys.exposure();
        let old_of = |leaf: usize| -> Option<u8> {
            let o = *matched.old_of_new_leaf.get(leaf)?;
            old_live.get(o as usize).copied()
        };
        let live = crate::exposure::exposure_keeping(
            &mesh,
            &bvh,
            self.params.ff.seed,
            &|leaf| {
                let node = mesh.leaf_node(leaf as u32);
                moved
                    .behind(node.v[0], node.normal)
                    .then(|| old_of(leaf))
                    .flatten()
            },
            &|leaf, probes| {
                let clear = probes
                    .iter()
                    .all(|&(p, d)| !moved.ray_meets(p.as_dvec3(), d.as_dvec3()));
                clear.then(|| old_of(leaf)).flatten()
            },
        );
        // The same for the elements' transfers: kept where the element stayed, under the same
        // sphere, and none of its rays may meet what moved.
        let transfer = self.cp.transfer.then(|| {
            let old = self.sys.transfers();
            let seed = self.params.ff.seed;
            super::transfer::transfer_keeping(&mesh, &tree, &bvh, seed, &|leaf, probes| {
                let o = *matched.old_of_new_leaf.get(leaf)?;
                let t = *old?.get(o as usize)?;
                let before = super::transfer::probes(&self.mesh, &self.tree, o as usize, seed);
                let clear = (probes.rays.iter()).all(|&(x, d)| !moved.ray_meets(x, d));
                (before.sphere == probes.sphere && clear).then_some(t)
            })
        });
        let oracle = Oracle::new(&mesh, &tree, &rho, &source);
        phases.direct_light = lap();
        let before = self.record.as_ref().map(|record| {
            Before::new(
                Old {
                    mesh: &self.mesh,
                    tree: &self.tree,
                    record,
                    bhat: &self.oracle.bhat,
                    rho: &self.oracle.rmax,
                    eps: self.refinement_used,
                },
                New {
                    mesh: &mesh,
                    tree: &tree,
                    bhat: &oracle.bhat,
                    rho: &oracle.rmax,
                },
                &matched,
                &moved,
            )
        });
        let kept_nodes = before.as_ref().map_or(0, Before::kept_nodes);
        phases.matching = lap();
        let mut warnings = scene.warnings();
        let inputs = (&*mesh, &tree, &bvh as &dyn Visibility, &oracle);
        let (walk, eps, stats) = refine_within_budget(
            inputs,
            &self.params,
            &self.cp,
            &mut budget,
            &mut warnings,
            progress,
            stop,
            before.as_ref(),
        )?;
        phases.refinement = lap();
        // Put together in the old record's memory (the edit's record is mostly the old one),
        // or, when that cannot be done, into fresh memory beside it.
        let new_of_old = before.map(Before::into_new_of_old);
        let remap = |l: Link| match &new_of_old {
            Some(map) => edit::remap(map, l),
            None => l,
        };
        let over = match self.record.as_mut() {
            Some(old) => walk.assemble_over(old, &remap),
            None => false,
        };
        let record = if over {
            // Spent: an edit that fails from here on leaves the bake without a record, and the
            // next edit makes the refinement again first.
            self.record.take()
        } else {
            let old = self.record.as_ref();
            budget.reserve(
                "the refinement's record before the edit",
                old.map_or(0, Record::bytes),
            )?;
            walk.assemble(old.map(|r| (r, &remap as &(dyn Fn(Link) -> Link + Sync))))
        };
        let record = record.ok_or(BakeError::OutOfMemory {
            what: "the refinement's record",
            needed: Record::bytes_of(walk.extent()),
            limit: budget.limit,
        })?;
        drop(walk);
        phases.assembly = lap();
        let terms = (rho, source, live);
        let mut sys = HierSystem::new_in(&mesh, &tree, &record.links, terms, Some(&mut self.sys))?;
        if let Some(t) = transfer {
            sys.set_transfer(t);
        }
        phases.rows = lap();
        // The current light, carried to the elements that stayed; the others start from their
        // sources.
        let mut b = matched.carry(&self.b);
        for (i, &o) in matched.old_of_new_leaf.iter().enumerate() {
            if o == u32::MAX {
                b[i] = sys.source[i];
            }
        }
        let nodes = tree.len();
        self.fingerprint = fingerprint(scene, &self.params, &self.cp);
        self.mesh = mesh;
        self.bvh = self.cp.edits.then(|| Arc::new(bvh));
        self.tree = tree;
        self.sys = sys;
        self.surfaces = scene.surfaces.clone();
        self.lighting = lighting;
        self.refinement_used = eps;
        self.oracle = oracle;
        self.record = self.cp.edits.then_some(record);
        self.refined = stats;
        self.budget = budget;
        self.resumed = false;
        self.b = b;
        self.warnings = warnings;
        let s = &mut self.sweeps;
        (s.rule, s.since_start, s.stalled) = (Sweeping::default(), 0, None);
        s.info.converged = false;
        tracing::info!(
            computed = stats.computed,
            kept = stats.kept,
            links = self.sys.links(),
            seconds = started.elapsed().as_secs_f64(),
            meshing = phases.meshing,
            visibility = phases.visibility,
            direct_light = phases.direct_light,
            matching = phases.matching,
            replay = phases.replay,
            refinement = phases.refinement,
            assembly = phases.assembly,
            rows = phases.rows,
            in_place = over,
            "clustered bake: geometry edit"
        );
        Ok(GeometryEdit {
            computed: stats.computed,
            kept: stats.kept,
            links: self.sys.links(),
            kept_nodes,
            nodes,
            seconds: started.elapsed().as_secs_f64(),
            phases,
            in_place: over,
        })
    }

    /// The record of the refinement that made the links of a bake resumed from a checkpoint
    /// (which holds the links, not the record): the refinement made again from the
    /// checkpoint's threshold, its form factors taken from the links instead of computed.
    /// `None` (and a note in the log) when that refinement does not meet every link, as when
    /// the materials changed between the bake and the resume, or over the memory budget:
    /// the edit then refines everything.
    fn replayed_record(&mut self) -> Option<Record> {
        if !self.has_emitters {
            return None;
        }
        let t = Instant::now();
        let rows = self.sys.rows();
        let replay = refine::Replay::new(rows.row, rows.src, rows.ff);
        let r = refine::Refiner {
            mesh: &self.mesh,
            tree: &self.tree,
            vis: &NoRays,
            bhat: &self.oracle.bhat,
            rho: &self.oracle.rmax,
            eps: self.refinement_used,
            kind: self.params.form_factors,
            samples: self.cp.samples,
            seed: self.params.ff.seed,
            max_links: u64::MAX,
            stop: None,
            before: None,
            keep: true,
            replay: Some(&replay),
        };
        let (record, _) = r.build(&|_, _| {})?;
        let same = replay.all_met() && record.links.len() == rows.src.len();
        let fits = same
            && (self.budget)
                .reserve(
                    "the refinement's record",
                    record.bytes() - record.links.len() as u64 * 12,
                )
                .is_ok();
        tracing::info!(
            same,
            fits,
            seconds = t.elapsed().as_secs_f64(),
            "clustered bake: the resumed refinement made again for a geometry edit"
        );
        (same && fits).then_some(record)
    }

    /// The links solved again in `bands` wavelength bands with spectral materials (by
    /// material name, as [`crate::spectral::solve_spectral`]: reflectance spectra, emission
    /// spectra scaled to the RGB emission's luminance; punctual lights and the sky, RGB only,
    /// do not light it), by the bake's sweeps and stopping rule at `tolerance`.
    pub fn solve_spectral(
        &self,
        materials: &std::collections::HashMap<String, crate::spectral::SpectralMaterial>,
        bands: usize,
        tolerance: f64,
    ) -> Result<crate::spectral::SpectralResult, BakeError> {
        let max = self.cp.max_sweeps;
        let mut result = crate::spectral::solve_in_bands(
            &self.mesh,
            &self.surfaces,
            materials,
            bands,
            |rho, source| Ok(self.sys.solve_with(&rho, &source, tolerance, max)?),
        )?;
        // The radiosity is that of each element's exposed part.
        result.surfaces = surface_means_exposed(
            &self.surfaces,
            &self.mesh,
            &result.radiosity,
            self.sys.exposure(),
        );
        Ok(result)
    }

    /// Writes the links and the current solution to `path` (version 4), atomically.
    pub fn write_checkpoint(&self, path: &Path) -> Result<(), BakeError> {
        crate::checkpoint::write_clustered(
            path,
            self.fingerprint,
            self.refinement_used,
            self.sys.rows(),
            (self.sys.exposure(), &self.radiosity()),
            (self.record.as_ref()).map(|r| (self.oracle.hash(), &r.ops[..], &r.sized[..])),
        )
    }

    /// The report as things stand.
    pub fn report(&self) -> BakeReport {
        let n = self.mesh.element_count();
        let info = self.sweeps.info;
        let (cluster_receiver_links, cluster_source_links) = self.sys.cluster_links();
        let mut times = self.times;
        times.solve = self.sweeps.solving.as_secs_f64();
        BakeReport {
            patches: n,
            elements: n,
            links: self.sys.links(),
            link_bytes: self.sys.link_bytes(),
            solver: SolverKind::Jacobi,
            form_factors: self.params.form_factors,
            times,
            iterations: info.iterations,
            converged: info.converged,
            residual: info.residual,
            unshot_fraction: 0.0,
            timeline: self.sweeps.timeline.clone(),
            warnings: self.warnings.clone(),
            stalled: self.sweeps.stalled,
            has_emitters: self.has_emitters,
            clusters: Some(ClusterReport {
                clusters: self.tree.clusters.len(),
                cluster_receiver_links,
                cluster_source_links,
                form_factors: self.refined.computed,
                refinement_asked: self.params.links.refinement,
                refinement_used: self.refinement_used,
                memory_limit: self.budget.limit,
                memory_estimate: self.budget.used,
                enclosed: self.sys.enclosed().iter().filter(|&&d| d).count(),
                partly_enclosed: (self.sys.exposure().iter())
                    .filter(|&&l| l > 0 && usize::from(l) < crate::exposure::POINTS)
                    .count(),
                transfer: self.sys.transfers().is_some(),
            }),
        }
    }

    /// Ends the bake and hands over the results (without the links: a checkpoint is written
    /// from the bake, [`Self::write_checkpoint`]).
    pub fn finish(self) -> BakeResult {
        let report = self.report();
        let b = self.radiosity();
        let n = b.len();
        let surfaces = surface_means_exposed(&self.surfaces, &self.mesh, &b, self.sys.exposure());
        let (rho, source, live) = self.sys.into_parts();
        let links = crate::links::Links {
            row: vec![0; n + 1],
            ..Default::default()
        };
        let share: Vec<f64> = live.iter().map(|&l| crate::exposure::fraction(l)).collect();
        let system = System::exposed(&self.mesh, rho, source, links, &share);
        let dead = live.iter().map(|&l| l == 0).collect();
        BakeResult::from_parts(
            Arc::unwrap_or_clone(self.mesh),
            system,
            b,
            surfaces,
            report,
            dead,
        )
    }
}

/// The estimates refinement reads, per node (mesh nodes, then clusters): `B̂` relative to the
/// ambient level (mesh nodes: the largest in the subtree; clusters: the area-weighted mean, so
/// `B̂ A` is the cluster's power) and the largest reflectance.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Oracle {
    pub bhat: Vec<f64>,
    pub rmax: Vec<f64>,
}

impl Oracle {
    /// A hash of every estimate, bit for bit: a record refined with other estimates is not
    /// this one's.
    fn hash(&self) -> u64 {
        let mut h = Fnv::new();
        for v in self.bhat.iter().chain(&self.rmax) {
            h.bytes(&v.to_bits().to_le_bytes());
        }
        h.0
    }

    fn new(mesh: &Mesh, tree: &Tree, rho: &[Rgb], source: &[Rgb]) -> Oracle {
        let max3 = |v: &Rgb| v[0].max(v[1]).max(v[2]);
        let bmesh = crate::hierarchy::Estimates::new(mesh, rho, source, 1.0).bhat;
        let m = mesh.nodes.len();
        let total = tree.len();
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
        Oracle { bhat, rmax }
    }
}

/// Refines the links within the budget, coarsening if allowed; returns them with the
/// threshold used. `before`: the refinement before a geometry edit, whose untouched parts are
/// kept (used only at its own threshold).
#[allow(clippy::too_many_arguments)]
fn refine_within_budget(
    (mesh, tree, vis, oracle): (&Mesh, &Tree, &dyn Visibility, &Oracle),
    params: &BakeParams,
    cp: &ClusterParams,
    budget: &mut Budget,
    warnings: &mut Vec<String>,
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
    stop: Option<&AtomicBool>,
    before: Option<&Before<'_>>,
) -> Result<(Walk, f64, RefineStats), BakeError> {
    let asked = params.links.refinement;
    let mut eps = asked;
    for attempt in 0..=COARSEN_STEPS {
        // Room for the links and, at about a byte each, the pairs the record keeps.
        let max_links = budget.left() / (LINK_BYTES + 8);
        let r = refine::Refiner {
            mesh,
            tree,
            vis,
            bhat: &oracle.bhat,
            rho: &oracle.rmax,
            eps,
            kind: params.form_factors,
            samples: cp.samples,
            seed: params.ff.seed,
            max_links,
            stop,
            before: before.filter(|b| b.old.eps == eps),
            keep: cp.edits,
            replay: None,
        };
        let t = Instant::now();
        if let Some((walk, stats)) = r.walk(&|d, n| progress(Phase::Links, d, n)) {
            let e = walk.extent();
            budget.reserve("the links", e.links * LINK_BYTES)?;
            budget.reserve(
                "the refinement's record",
                Record::bytes_of(e) - e.links * std::mem::size_of::<Link>() as u64,
            )?;
            if attempt > 0 {
                warnings.push(format!(
                    "the memory limit of {} MiB made the bake coarser: refinement {eps} instead of {asked}",
                    budget.limit >> 20
                ));
            }
            return Ok((walk, eps, stats));
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

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DVec3, Vec3};
    use radiant_visibility::{Ends, Hit};
    use std::sync::atomic::AtomicU64;

    /// The BVH, counting the segments cast and the shafts found clear; with `shafts` off it
    /// keeps its shaft test and its blocker hints to itself, so that every link casts its
    /// rays and every ray traverses the BVH.
    struct Counted<'a> {
        bvh: &'a Bvh,
        shafts: bool,
        segments: AtomicU64,
        clear: AtomicU64,
    }

    impl Visibility for Counted<'_> {
        fn segment_clear(&self, a: Vec3, b: Vec3) -> bool {
            self.segments.fetch_add(1, Ordering::Relaxed);
            self.bvh.segment_clear(a, b)
        }
        fn segment_clear_between(&self, a: Vec3, b: Vec3, ends: &Ends) -> bool {
            self.segments.fetch_add(1, Ordering::Relaxed);
            self.bvh.segment_clear_between(a, b, ends)
        }
        fn segment_clear_hinted(
            &self,
            a: Vec3,
            b: Vec3,
            ends: Option<&Ends>,
            blocker: &mut u32,
        ) -> bool {
            self.segments.fetch_add(1, Ordering::Relaxed);
            match ends {
                _ if self.shafts => self.bvh.segment_clear_hinted(a, b, ends, blocker),
                Some(e) => self.bvh.segment_clear_between(a, b, e),
                None => self.bvh.segment_clear(a, b),
            }
        }
        fn closest_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
            self.bvh.closest_hit(origin, dir, tmax)
        }
        fn shaft_clear(
            &self,
            a: &[DVec3; 3],
            na: DVec3,
            b: &[DVec3; 3],
            nb: DVec3,
            witness: &mut u32,
        ) -> bool {
            let clear = self.shafts && self.bvh.shaft_clear(a, na, b, nb, witness);
            self.clear.fetch_add(u64::from(clear), Ordering::Relaxed);
            clear
        }
    }

    #[test]
    fn extrapolated_sweeps_end_nearer_the_answer_in_fewer_sweeps() {
        // The Cornell box clustered: sweeps with Aitken's extrapolation and without, to the
        // default tolerance, against the same links swept to 10⁻¹⁰. With it: fewer sweeps, an
        // answer at least as near, and an estimate still as near the error left.
        let scene = radiant_scene::builtin("cornell-box").expect("builtin");
        let params = BakeParams::default();
        let cp = ClusterParams::default();
        let mut tight = ClusterBake::new(&scene, &params, &cp, &|_, _, _| {}, None).expect("bake");
        tight.params.solver_params.tolerance = 1e-10;
        tight.sweeps.rule.extrapolation = false;
        while !tight.step().expect("sweeps").converged {}
        let exact = tight.radiosity();
        let sweep = |extrapolation: bool| {
            let mut b = ClusterBake::new(&scene, &params, &cp, &|_, _, _| {}, None).expect("bake");
            b.sweeps.rule.extrapolation = extrapolation;
            let info = loop {
                let info = b.step().expect("sweeps");
                if info.converged {
                    break info;
                }
            };
            let got = b.radiosity();
            let err = b.sys.norm(
                &(got.iter().zip(&exact))
                    .map(|(x, y)| std::array::from_fn(|c| x[c] - y[c]))
                    .collect::<Vec<Rgb>>(),
            );
            let bounced = b.sys.norm(
                &(exact.iter().zip(&b.sys.source))
                    .map(|(x, y)| std::array::from_fn(|c| x[c] - y[c]))
                    .collect::<Vec<Rgb>>(),
            );
            (info.iterations, err / bounced, info.residual)
        };
        let (plain, with) = (sweep(false), sweep(true));
        eprintln!("without: {plain:?}; with: {with:?}");
        assert!(with.0 + 2 <= plain.0, "sweeps: {with:?} against {plain:?}");
        assert!(with.1 <= plain.1, "error: {with:?} against {plain:?}");
        // The estimate is the error along the slowest mode: near the error left, not a strict
        // bound (without extrapolation 8.91e-5 against an estimate of 8.89e-5).
        for (_, err, estimate) in [plain, with] {
            assert!(
                err <= 1.1 * estimate,
                "error {err} above its estimate {estimate}"
            );
        }
    }

    #[test]
    fn links_below_a_clear_shaft_are_the_links_their_rays_give() {
        // The Cornell box: the links refined with shafts (no rays below a clear one) and
        // blocker hints (a segment tries first what blocked the last) and with every ray cast
        // through the whole BVH are the same, form factors bit for bit, and the shafts spared
        // rays.
        let scene = radiant_scene::builtin("cornell-box").expect("builtin");
        let params = BakeParams::default();
        let mesh = Mesh::adaptive(&scene, &params.mesh, &mut |_| Ok(())).expect("meshes");
        let bvh = input::visibility(&mesh, None);
        let tree = Tree::new(&mesh);
        let (rho, source) =
            Lighting::new(&scene, &mesh, &bvh, None, &params.ff).terms(&scene.surfaces, &mesh);
        let oracle = Oracle::new(&mesh, &tree, &rho, &source);
        let links = |vis: &Counted| {
            let r = super::super::refine::Refiner {
                mesh: &mesh,
                tree: &tree,
                vis,
                bhat: &oracle.bhat,
                rho: &oracle.rmax,
                eps: 0.03,
                kind: params.form_factors,
                samples: ClusterParams::default().samples,
                seed: params.ff.seed,
                max_links: u64::MAX,
                stop: None,
                before: None,
                keep: false,
                replay: None,
            };
            let (record, _) = r.build(&|_, _| {}).expect("refines");
            record.links
        };
        let counted = |shafts| Counted {
            bvh: &bvh,
            shafts,
            segments: AtomicU64::new(0),
            clear: AtomicU64::new(0),
        };
        let (with, without) = (counted(true), counted(false));
        let (a, b) = (links(&with), links(&without));
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(&b) {
            assert_eq!((x.recv, x.src), (y.recv, y.src));
            assert_eq!(x.ff.to_bits(), y.ff.to_bits(), "{x:?} against {y:?}");
        }
        let (cast, all) = (
            with.segments.load(Ordering::Relaxed),
            without.segments.load(Ordering::Relaxed),
        );
        eprintln!(
            "{} links; {cast} segments cast with shafts ({} clear), {all} without",
            a.len(),
            with.clear.load(Ordering::Relaxed)
        );
        assert!(with.clear.load(Ordering::Relaxed) > 100);
        assert!(cast * 10 < all * 9, "{cast} of {all}");
    }
}
