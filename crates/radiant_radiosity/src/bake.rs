//! A bake: mesh the scene, build visibility, light it directly, build links, then solve in
//! time-budgeted steps while recording the residual against time.

use std::time::{Duration, Instant};

use glam::DVec3;
use radiant_scene::{Light, Scene, Surface};
use radiant_visibility::{Bvh, Visibility};

use crate::form_factors::{self, FfContext, FormFactorKind, FormFactorParams};
use crate::links::{self, LinkParams, Oracle};
use crate::mesh::{Mesh, MeshParams};
use crate::metrics::{SurfaceMean, surface_means};
use crate::solvers::{Progress, Solver, SolverKind, SolverParams, new_solver};
use crate::system::{Rgb, System};
use crate::{BakeError, input};

/// Everything a bake can be told. `Default` gives the settings the accuracy tests hold to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BakeParams {
    /// Meshing (patch size, element levels).
    pub mesh: MeshParams,
    /// The form-factor method (default: analytic).
    pub form_factors: FormFactorKind,
    /// Form-factor parameters (hemicube resolution, ray counts, seed).
    pub ff: FormFactorParams,
    /// Link refinement.
    pub links: LinkParams,
    /// The solver (default: Gauss–Seidel).
    pub solver: SolverKind,
    /// Solver parameters (tolerance etc.).
    pub solver_params: SolverParams,
    /// Stop solving after this long (solve phase only), converged or not (default: none).
    pub time_limit: Option<Duration>,
    /// Length of one solver step between progress reports (default: 25 ms).
    pub step_budget: Duration,
}

impl Default for BakeParams {
    fn default() -> Self {
        BakeParams {
            mesh: MeshParams::default(),
            form_factors: FormFactorKind::Analytic,
            ff: FormFactorParams::default(),
            links: LinkParams::default(),
            solver: SolverKind::GaussSeidel,
            solver_params: SolverParams::default(),
            time_limit: None,
            step_budget: Duration::from_millis(25),
        }
    }
}

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
    /// Warnings (skipped input, no emitters, …).
    pub warnings: Vec<String>,
    /// Whether anything emits.
    pub has_emitters: bool,
    /// The clustered hierarchy's figures, when it made the links ([`crate::cluster`]).
    pub clusters: Option<crate::cluster::ClusterReport>,
}

/// Steps without progress after which [`Bake::run_to_end`] gives up.
pub const STALL_STEPS: u32 = 200;

/// Progress callbacks.
#[derive(Debug)]
pub enum BakeEvent<'a> {
    /// A solver step finished.
    Solve(&'a Progress, f64),
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
    fingerprint: u64,
    dead: Vec<bool>,
    /// The refinement oracle the links were built with, when known.
    oracle: Option<(Vec<f64>, f64)>,
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
            fingerprint: 0,
            dead,
            oracle: None,
        }
    }

    /// Writes the links and the solution to `path` (see [`Bake::write_checkpoint`]).
    pub fn write_checkpoint(&self, path: &std::path::Path) -> Result<(), BakeError> {
        if self.report.clusters.is_some() {
            return Err(BakeError::Checkpoint(
                "bakes of the clustered hierarchy have no checkpoints yet: use --hierarchy triangles".into(),
            ));
        }
        crate::checkpoint::write(
            path,
            self.fingerprint,
            self.mesh.nodes.len(),
            &self.system.links,
            &self.dead,
            &self.radiosity,
            self.oracle.as_ref().map(|(b, e)| (b.as_slice(), *e)),
        )
    }
}

/// A bake in progress.
pub struct Bake {
    /// The element hierarchy.
    pub mesh: Mesh,
    /// The system.
    pub system: System,
    /// The parameters.
    pub params: BakeParams,
    /// The scene's surfaces.
    pub surfaces: Vec<Surface>,
    times: PhaseTimes,
    warnings: Vec<String>,
    has_emitters: bool,
    /// Per element: irradiance from the punctual lights and the sky (shadowed), for material
    /// edits.
    direct: Option<Vec<Rgb>>,
    /// Per element: the textures' footprints, for material edits.
    textures: Option<input::ElementTextures>,
    /// The scene's alpha masks and sky, for light edits.
    masks: Option<std::sync::Arc<radiant_scene::AlphaMasks>>,
    sky: Option<radiant_scene::Sky>,
    /// Elements inside closed geometry.
    dead: Vec<bool>,
    /// Fingerprint of geometry, lights and link parameters (for checkpoints).
    fingerprint: u64,
    /// Whether this bake was resumed from a checkpoint.
    resumed: bool,
    /// The refinement oracle's estimate and threshold the links were built with.
    bhat: Vec<f64>,
    eps: f64,
    /// Whether `bhat` and `eps` are really those (not after a resume from an old checkpoint).
    oracle_known: bool,
    /// Lights of the scene (for geometry edits, which recompute direct light).
    lights: Vec<Light>,
    solver: Box<dyn Solver>,
    started: Instant,
    solving: Duration,
    timeline: Vec<TimelinePoint>,
    last: Option<Progress>,
}

pub(crate) fn validate(scene: &Scene) -> Result<(), BakeError> {
    for s in &scene.surfaces {
        let bad = |what: String| BakeError::InvalidMaterial {
            surface: s.name.clone(),
            what,
        };
        if s.reflectance
            .iter()
            .any(|r| !r.is_finite() || !(0.0..=1.0).contains(r))
        {
            return Err(bad(format!(
                "reflectance {:?} is outside [0, 1]",
                s.reflectance
            )));
        }
        if s.emission.iter().any(|e| !e.is_finite() || *e < 0.0) {
            return Err(bad(format!(
                "emission {:?} is negative or not finite",
                s.emission
            )));
        }
    }
    if scene
        .triangles
        .iter()
        .any(|t| t.surface as usize >= scene.surfaces.len())
    {
        return Err(BakeError::InvalidScene(
            "a triangle names a surface that does not exist".into(),
        ));
    }
    Ok(())
}

impl Bake {
    /// Prepares a bake: everything up to the solve.
    pub fn new(scene: &Scene, params: &BakeParams) -> Result<Bake, BakeError> {
        Self::with_progress(scene, params, &|_, _| {})
    }

    /// As [`Bake::new`], calling `progress(done, total)` while form factors are computed.
    pub fn with_progress(
        scene: &Scene,
        params: &BakeParams,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<Bake, BakeError> {
        Self::build(scene, params, progress, None)
    }

    /// Resumes from a checkpoint written by [`Bake::write_checkpoint`] for the same geometry,
    /// lights and link parameters: no form factors are computed, and the solve continues from
    /// the saved radiosity (with the scene's current materials, as an edit would). A checkpoint
    /// for other geometry, or a damaged one, is a [`BakeError::Checkpoint`].
    pub fn resume(
        scene: &Scene,
        params: &BakeParams,
        path: &std::path::Path,
    ) -> Result<Bake, BakeError> {
        let saved = crate::checkpoint::read(path)?;
        Self::build(scene, params, &|_, _| {}, Some(saved))
    }

    /// Writes the links and the current solution to `path`, atomically.
    pub fn write_checkpoint(&self, path: &std::path::Path) -> Result<(), BakeError> {
        crate::checkpoint::write(
            path,
            self.fingerprint,
            self.mesh.nodes.len(),
            &self.system.links,
            &self.dead,
            &self.radiosity(),
            self.oracle_known
                .then_some((self.bhat.as_slice(), self.eps)),
        )
    }

    /// Whether this bake came from a checkpoint.
    pub fn is_resumed(&self) -> bool {
        self.resumed
    }

    fn build(
        scene: &Scene,
        params: &BakeParams,
        progress: &(dyn Fn(usize, usize) + Sync),
        saved: Option<crate::checkpoint::Saved>,
    ) -> Result<Bake, BakeError> {
        let started = Instant::now();
        // Dynamic surfaces take no part in the bake.
        let static_part;
        let scene = if scene.surfaces.iter().any(|s| s.dynamic) {
            static_part = scene.static_part();
            &static_part
        } else {
            scene
        };
        validate(scene)?;
        let p = &params.solver_params;
        if !(p.tolerance.is_finite() && p.tolerance > 0.0) {
            return Err(BakeError::InvalidParameter(format!(
                "tolerance {} must be positive",
                p.tolerance
            )));
        }
        if !(params.links.far_field.is_finite() && params.links.far_field >= 0.0) {
            return Err(BakeError::InvalidParameter(
                "far field must be a number >= 0".into(),
            ));
        }
        if !(params.links.refinement.is_finite() && params.links.refinement > 0.0) {
            return Err(BakeError::InvalidParameter(
                "refinement must be positive".into(),
            ));
        }
        let mut times = PhaseTimes::default();
        let mut t = Instant::now();
        let mut lap = |slot: &mut f64| {
            *slot = t.elapsed().as_secs_f64();
            t = Instant::now();
        };
        let fingerprint = crate::checkpoint::fingerprint(scene, params);
        if let Some(sv) = &saved
            && sv.fingerprint != fingerprint
        {
            return Err(BakeError::Checkpoint(
                "it was written for other geometry or bake parameters".into(),
            ));
        }
        let mesh = Mesh::new(scene, &params.mesh)?;
        if let Some(sv) = &saved
            && (sv.dead.len() != mesh.element_count() || sv.nodes != mesh.nodes.len())
        {
            return Err(BakeError::Checkpoint(
                "its element hierarchy differs from this scene's".into(),
            ));
        }
        if params.solver == SolverKind::Direct
            && mesh.element_count() > params.solver_params.max_direct
        {
            // Refuse now, before the form factors are spent.
            return Err(BakeError::TooLargeForDirect {
                elements: mesh.element_count(),
                limit: params.solver_params.max_direct,
            });
        }
        lap(&mut times.meshing);
        let masks = input::masks(scene);
        let bvh = input::visibility(&mesh, masks.as_ref());
        lap(&mut times.visibility);

        let n = mesh.element_count();
        let textures = input::element_textures(scene, &mesh);
        let (rho, emission) = input::materials(&scene.surfaces, &mesh, textures.as_ref());
        let direct =
            input::direct_irradiance(&scene.lights, scene.sky.as_ref(), &mesh, &bvh, &params.ff);
        let source = input::sources(&rho, &emission, direct.as_deref());
        lap(&mut times.direct_light);

        let mut warnings = scene.warnings();
        let has_emitters = source.iter().any(|s| s.iter().any(|&v| v > 0.0));
        let (saved_links, saved_b, saved_oracle) = match saved {
            Some(sv) => (Some((sv.links, sv.dead)), Some(sv.radiosity), sv.oracle),
            None => (None, None, None),
        };
        if has_emitters
            && saved_links
                .as_ref()
                .is_some_and(|(l, _)| l.is_empty() && n > 0)
        {
            // Written when nothing emitted, so it has no links to resume from.
            return Err(BakeError::Checkpoint(
                "it was written when nothing emitted and holds no links".into(),
            ));
        }
        let resumed = saved_links.is_some();
        let (links, dead) = if let Some((links, dead)) = saved_links {
            (links, dead)
        } else {
            let dead = if has_emitters {
                enclosed_elements(&mesh, &bvh, params.ff.seed)
            } else {
                vec![false; n]
            };
            (
                Self::links(
                    &mesh,
                    &bvh,
                    params,
                    &rho,
                    &source,
                    has_emitters,
                    progress,
                    &mut warnings,
                ),
                dead,
            )
        };
        lap(&mut times.form_factors);
        let dead_count = dead.iter().filter(|&&d| d).count();
        if dead_count > 0 {
            tracing::debug!("{dead_count} elements lie inside closed geometry");
        }
        // The oracle the links were built with: this scene's, or the one the checkpoint stored
        // (its materials and lights may have differed).
        let oracle_known = !resumed || saved_oracle.is_some();
        let (bhat, eps) = match saved_oracle {
            Some(o) => o,
            None => estimates(&mesh, &rho, &source, params.links.refinement),
        };
        let system = System::new(&mesh, rho, source, links, &dead);
        let mut solver = new_solver(params.solver, &system, params.solver_params);
        if let Some(b) = &saved_b {
            solver.warm_start(&system, b);
        }
        Ok(Bake {
            mesh,
            system,
            params: *params,
            surfaces: scene.surfaces.clone(),
            times,
            warnings,
            has_emitters,
            direct,
            textures,
            masks,
            sky: scene.sky.clone(),
            dead,
            fingerprint,
            resumed,
            bhat,
            eps,
            oracle_known,
            lights: scene.lights.clone(),
            solver,
            started,
            solving: Duration::ZERO,
            timeline: Vec::new(),
            last: None,
        })
    }

    #[expect(clippy::too_many_arguments, reason = "the inputs of the link build")]
    fn links(
        mesh: &Mesh,
        bvh: &Bvh,
        params: &BakeParams,
        rho: &[Rgb],
        source: &[Rgb],
        has_emitters: bool,
        progress: &(dyn Fn(usize, usize) + Sync),
        warnings: &mut Vec<String>,
    ) -> links::Links {
        let n = mesh.element_count();
        if has_emitters {
            let (bhat, eps) = estimates(mesh, rho, source, params.links.refinement);
            let ctx = FfContext {
                mesh,
                vis: bvh,
                params: params.ff,
            };
            let method = form_factors::method(params.form_factors);
            links::build(
                &ctx,
                method,
                Oracle { bhat: &bhat, eps },
                &params.links,
                &|d| progress(d, n),
            )
        } else {
            warnings.push("no emitters and no lights: nothing to bake, all radiosity is 0".into());
            links::Links {
                row: vec![0; n + 1],
                ..Default::default()
            }
        }
    }

    /// Runs the solver for about `budget` and records a timeline point.
    pub fn step(&mut self, budget: Duration) -> Result<Progress, BakeError> {
        let t = Instant::now();
        let p = if self.has_emitters {
            self.solver.step(&self.system, budget)?
        } else {
            Progress {
                iterations: 0,
                residual: 0.0,
                unshot_fraction: 0.0,
                converged: true,
            }
        };
        self.solving += t.elapsed();
        self.timeline.push(TimelinePoint {
            t_s: self.started.elapsed().as_secs_f64(),
            iterations: p.iterations,
            residual: p.residual,
            unshot_fraction: p.unshot_fraction,
        });
        self.last = Some(p);
        Ok(p)
    }

    /// Changes the surfaces' reflectance and emission and continues from the current solution:
    /// the links and form factors are kept (they do not depend on colour), and the solver
    /// warm-starts (Southwell shoots the difference, negative energy included). Returns
    /// [`BakeError::NeedsRebuild`] when the edit turns a bake with no emitters into one with
    /// some: it has no links to keep.
    pub fn edit_surfaces(&mut self, surfaces: &[Surface]) -> Result<(), BakeError> {
        if surfaces.len() != self.surfaces.len() {
            return Err(BakeError::InvalidParameter(format!(
                "an edit must keep the {} surfaces ({} given)",
                self.surfaces.len(),
                surfaces.len()
            )));
        }
        let probe = Scene {
            surfaces: surfaces.to_vec(),
            ..Scene::default()
        };
        validate(&probe)?;
        let (rho, emission) = input::materials(surfaces, &self.mesh, self.textures.as_ref());
        let source = input::sources(&rho, &emission, self.direct.as_deref());
        let has_emitters = source.iter().any(|s| s.iter().any(|&v| v > 0.0));
        if has_emitters && !self.has_emitters {
            return Err(BakeError::NeedsRebuild);
        }
        let b = self.radiosity();
        self.system.set_materials(rho, source);
        self.surfaces = surfaces.to_vec();
        self.has_emitters = has_emitters;
        self.solver.warm_start(&self.system, &b);
        self.last = None;
        Ok(())
    }

    /// Replaces the punctual lights: their direct light is computed again (shadow rays on the
    /// same geometry), the links are kept, and the solve warm-starts as for
    /// [`Bake::edit_surfaces`]. Lights must be finite, with non-negative intensity.
    pub fn edit_lights(&mut self, lights: &[Light]) -> Result<(), BakeError> {
        for l in lights {
            let finite = l.position.is_finite()
                && l.direction.is_finite()
                && l.intensity.is_finite()
                && l.color.iter().all(|c| c.is_finite());
            if !finite || l.intensity < 0.0 || l.color.iter().any(|&c| c < 0.0) {
                return Err(BakeError::InvalidParameter(format!(
                    "light '{}' has a non-finite or negative value",
                    l.name
                )));
            }
        }
        let old = self.direct.take();
        let old_lights = std::mem::replace(&mut self.lights, lights.to_vec());
        if !lights.is_empty() || self.sky.is_some() {
            let bvh = input::visibility(&self.mesh, self.masks.as_ref());
            self.direct = input::direct_irradiance(
                lights,
                self.sky.as_ref(),
                &self.mesh,
                &bvh,
                &self.params.ff,
            );
        }
        let surfaces = self.surfaces.clone();
        let result = self.edit_surfaces(&surfaces);
        if result.is_err() {
            self.direct = old;
            self.lights = old_lights;
        }
        result
    }

    /// Replaces the punctual lights and the sky (`None`: no sky), as [`Bake::edit_lights`]
    /// does the lights: the sky's light is computed again with its visibility rays, the links
    /// are kept.
    pub fn edit_lights_and_sky(
        &mut self,
        lights: &[Light],
        sky: Option<&radiant_scene::Sky>,
    ) -> Result<(), BakeError> {
        let old = std::mem::replace(&mut self.sky, sky.cloned());
        let result = self.edit_lights(lights);
        if result.is_err() {
            self.sky = old;
        }
        result
    }

    /// Moves, adds or removes static geometry (and takes the scene's materials and lights along)
    /// and keeps what the edit does not touch: the form factors of links whose receiver and
    /// source are on triangles that stayed where they were, and whose shaft misses the bounds of
    /// the triangles that moved, came or went (see [`links::update`]).
    ///
    /// Triangles are matched to the old ones by surface name, their index within the surface
    /// and exact position; a moved triangle is one that went and one that came. Matched ones
    /// keep their elements' links and radiosity, the others get theirs computed, and the
    /// refinement oracle is recomputed as a fresh bake would (links whose visibility sample
    /// count changes with it are computed again). Visibility rays are seeded by each node's own
    /// triangle ([`Mesh::stable_id`]), so the links equal a fresh bake's bit for bit (after a
    /// resume from a checkpoint written under other materials or lights, a few links may keep
    /// the sample counts of the oracle they were built with).
    ///
    /// Direct light and enclosed elements are computed again, and the solve warm-starts from
    /// the current solution. Returns [`BakeError::NeedsRebuild`] when the scene's bounding box
    /// changed (every local coordinate would), or when nothing emits before or after.
    pub fn edit_geometry(&mut self, scene: &Scene) -> Result<links::UpdateStats, BakeError> {
        let static_part;
        let scene = if scene.surfaces.iter().any(|s| s.dynamic) {
            static_part = scene.static_part();
            &static_part
        } else {
            scene
        };
        validate(scene)?;
        if !self.has_emitters || !scene.has_emitters() {
            return Err(BakeError::NeedsRebuild);
        }
        let mesh = Mesh::new(scene, &self.params.mesh)?;
        if self.params.solver == SolverKind::Direct
            && mesh.element_count() > self.params.solver_params.max_direct
        {
            return Err(BakeError::TooLargeForDirect {
                elements: mesh.element_count(),
                limit: self.params.solver_params.max_direct,
            });
        }
        self.edit_structure(scene, mesh)
    }

    fn edit_structure(
        &mut self,
        scene: &Scene,
        mesh: Mesh,
    ) -> Result<links::UpdateStats, BakeError> {
        if mesh.frame != self.mesh.frame {
            return Err(BakeError::NeedsRebuild);
        }
        let old = &self.mesh;
        // Old roots by (surface name and index within it, as hashed into the ray seeds; exact
        // local vertices). The names come from each mesh, not from `self.surfaces`.
        let key = |m: &Mesh, r: usize| {
            let v = m.nodes[m.roots[r] as usize].v;
            (
                m.root_key.get(r).copied().unwrap_or(0),
                v.map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]),
            )
        };
        let mut by_key: std::collections::HashMap<_, Vec<usize>> = std::collections::HashMap::new();
        for r in 0..old.roots.len() {
            by_key.entry(key(old, r)).or_default().push(r);
        }
        // The node range of each root: roots are pushed in order, each with its whole subtree.
        let range = |m: &Mesh, r: usize| {
            let lo = m.roots[r] as usize;
            let hi = m.roots.get(r + 1).map_or(m.nodes.len(), |&x| x as usize);
            (lo, hi)
        };
        let mut matched_old = vec![false; old.roots.len()];
        let mut new_of_old_node = vec![u32::MAX; old.nodes.len()];
        let mut old_of_new_leaf = vec![u32::MAX; mesh.element_count()];
        let mut added = vec![true; mesh.roots.len()];
        for r in 0..mesh.roots.len() {
            let Some(o) = by_key
                .get(&key(&mesh, r))
                .and_then(|c| c.iter().copied().find(|&o| !matched_old[o]))
            else {
                continue;
            };
            let ((nlo, nhi), (olo, ohi)) = (range(&mesh, r), range(old, o));
            if nhi - nlo != ohi - olo {
                continue;
            }
            matched_old[o] = true;
            added[r] = false;
            for k in 0..(nhi - nlo) {
                new_of_old_node[olo + k] = (nlo + k) as u32;
            }
            let (nl, ol) = (
                mesh.nodes[mesh.roots[r] as usize].leaf_lo as usize,
                old.nodes[old.roots[o] as usize].leaf_lo as usize,
            );
            let count = (mesh.nodes[mesh.roots[r] as usize].leaf_hi as usize) - nl;
            for k in 0..count {
                old_of_new_leaf[nl + k] = (ol + k) as u32;
            }
        }
        let unchanged = !added.iter().any(|&a| a) && matched_old.iter().all(|&m| m);
        if unchanged && scene.lights == self.lights && scene.surfaces == self.surfaces {
            return Ok(links::UpdateStats::default());
        }
        // What changed occludes differently: the triangles that came and went.
        let mut changed: Vec<[DVec3; 3]> = Vec::new();
        for (r, _) in added.iter().enumerate().filter(|(_, a)| **a) {
            changed.push(mesh.nodes[mesh.roots[r] as usize].v);
        }
        for (o, _) in matched_old.iter().enumerate().filter(|(_, m)| !**m) {
            changed.push(old.nodes[old.roots[o] as usize].v);
        }
        // Monte Carlo rays leave 1e-5 off the receiver (`form_factors::ray_origin`): they stray
        // that far from the exact shaft; the other methods only by rounding.
        let margin = match self.params.form_factors {
            form_factors::FormFactorKind::MonteCarlo => 2e-5,
            _ => links::ChangeSet::ROUNDING,
        };
        let changed = links::ChangeSet::new(&changed, margin);
        // The current solution, carried over to the elements that stay.
        let b_old = self.radiosity();
        let b: Vec<Rgb> = old_of_new_leaf
            .iter()
            .map(|&o| b_old.get(o as usize).copied().unwrap_or([0.0; 3]))
            .collect();
        let masks = input::masks(scene);
        let bvh = input::visibility(&mesh, masks.as_ref());
        let textures = input::element_textures(scene, &mesh);
        let (rho, emission) = input::materials(&scene.surfaces, &mesh, textures.as_ref());
        let direct = input::direct_irradiance(
            &scene.lights,
            scene.sky.as_ref(),
            &mesh,
            &bvh,
            &self.params.ff,
        );
        let source = input::sources(&rho, &emission, direct.as_deref());
        if !source.iter().flatten().any(|&v| v > 0.0) {
            // Lights that reach nothing: a fresh bake would say so and build no links.
            return Err(BakeError::NeedsRebuild);
        }
        // The oracle a fresh bake of this scene would use, so the links match a fresh bake's.
        let (bhat, eps) = estimates(&mesh, &rho, &source, self.params.links.refinement);
        let ctx = FfContext {
            mesh: &mesh,
            vis: &bvh,
            params: self.params.ff,
        };
        let method = form_factors::method(self.params.form_factors);
        // The old oracle in the new numbering: kept links whose sample count changes with the
        // new oracle are computed again (added nodes have no old estimate: recomputed anyway).
        let mut old_bhat = vec![0.0; mesh.nodes.len()];
        for (o, &nn) in new_of_old_node.iter().enumerate() {
            if nn != u32::MAX {
                old_bhat[nn as usize] = self.bhat[o];
            }
        }
        let (new_links, stats) = links::update(
            &ctx,
            method,
            Oracle { bhat: &bhat, eps },
            &self.params.links,
            &self.system.links,
            &links::Change {
                old_of_new_leaf: &old_of_new_leaf,
                new_of_old_node: &new_of_old_node,
                moved_root: &added,
                triangles: &changed,
                old_oracle: self.oracle_known.then_some(Oracle {
                    bhat: &old_bhat,
                    eps: self.eps,
                }),
            },
        );
        let dead = enclosed_elements(&mesh, &bvh, self.params.ff.seed);
        self.system = System::new(&mesh, rho, source, new_links, &dead);
        self.dead = dead;
        self.direct = direct;
        self.textures = textures;
        self.masks = masks;
        self.sky = scene.sky.clone();
        self.bhat = bhat;
        self.eps = eps;
        self.oracle_known = true;
        self.mesh = mesh;
        self.surfaces = scene.surfaces.clone();
        self.lights = scene.lights.clone();
        self.warnings = scene.warnings();
        self.resumed = false;
        self.fingerprint = crate::checkpoint::fingerprint(scene, &self.params);
        self.solver = new_solver(self.params.solver, &self.system, self.params.solver_params);
        self.solver.warm_start(&self.system, &b);
        self.last = None;
        Ok(stats)
    }

    /// Seconds since the bake started.
    pub fn elapsed(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// The latest progress.
    pub fn last_progress(&self) -> Option<Progress> {
        self.last
    }

    /// The current radiosity per element.
    pub fn radiosity(&self) -> Vec<Rgb> {
        if self.has_emitters {
            self.solver.radiosity(&self.system)
        } else {
            vec![[0.0; 3]; self.system.len()]
        }
    }

    /// Steps until converged or the time limit, calling `on_event` after each step.
    ///
    /// A solve that stops making progress (the residual has not fallen by 1 % over
    /// [`STALL_STEPS`] steps: reflectance 1 in a closed scene, say) ends unconverged with a
    /// warning rather than running forever.
    pub fn run_to_end(
        mut self,
        on_event: &mut dyn FnMut(BakeEvent),
    ) -> Result<BakeResult, BakeError> {
        let (mut best, mut since_best) = (f64::INFINITY, 0u32);
        loop {
            let p = self.step(self.params.step_budget)?;
            on_event(BakeEvent::Solve(&p, self.elapsed()));
            let out_of_time = self.params.time_limit.is_some_and(|l| self.solving >= l);
            if p.residual < 0.99 * best {
                (best, since_best) = (p.residual, 0);
            } else {
                since_best += 1;
            }
            if since_best >= STALL_STEPS {
                self.warnings.push(format!(
                    "the solver stopped converging (residual {:.2e}); reflectance 1 in a closed scene?",
                    p.residual
                ));
                break;
            }
            if p.converged || out_of_time || !p.residual.is_finite() {
                break;
            }
        }
        Ok(self.finish())
    }

    /// The report as things stand.
    pub fn report(&self) -> BakeReport {
        let last = self.last.unwrap_or(Progress {
            iterations: 0,
            residual: f64::INFINITY,
            unshot_fraction: 1.0,
            converged: false,
        });
        let mut times = self.times;
        times.solve = self.solving.as_secs_f64();
        BakeReport {
            patches: self.mesh.patch_count,
            elements: self.mesh.element_count(),
            links: self.system.links.len(),
            link_bytes: self.system.links.bytes(),
            solver: self.params.solver,
            form_factors: self.params.form_factors,
            times,
            iterations: last.iterations,
            converged: last.converged,
            residual: last.residual,
            unshot_fraction: last.unshot_fraction,
            timeline: self.timeline.clone(),
            warnings: self.warnings.clone(),
            has_emitters: self.has_emitters,
            clusters: None,
        }
    }

    /// Ends the bake and hands over the results.
    pub fn finish(self) -> BakeResult {
        let radiosity = self.radiosity();
        let report = self.report();
        let surfaces = surface_means(&self.surfaces, &self.mesh, &radiosity);
        BakeResult {
            mesh: self.mesh,
            system: self.system,
            radiosity,
            surfaces,
            report,
            fingerprint: self.fingerprint,
            dead: self.dead,
            oracle: self.oracle_known.then_some((self.bhat, self.eps)),
        }
    }
}

/// Elements whose centroid lies inside closed geometry (the floor under a block): every one of
/// the cosine-distributed probe rays from them hits a back face. Such elements receive nothing and no
/// receiver sees them, so they must not dilute the radiosity of the source nodes they belong to.
pub(crate) fn enclosed_elements(mesh: &Mesh, vis: &dyn Visibility, seed: u64) -> Vec<bool> {
    use rayon::prelude::*;
    const PROBES: u32 = 16;
    (0..mesh.element_count())
        .into_par_iter()
        .map(|leaf| {
            let node = mesh.leaf_node(leaf as u32);
            let (t, b) = crate::form_factors::basis(node.normal);
            let id = mesh.stable_id(mesh.leaves[leaf]);
            let mut rng = crate::rng::Rng::new(crate::rng::hash(seed ^ 0xDEAD, id, 0));
            let mut back = 0;
            for k in 0..PROBES {
                let (u1, u2) = (
                    (f64::from(k % 4) + rng.f64()) / 4.0,
                    (f64::from(k / 4) + rng.f64()) / 4.0,
                );
                let (r, phi) = (u1.sqrt(), std::f64::consts::TAU * u2);
                let dir = t * (r * phi.cos())
                    + b * (r * phi.sin())
                    + node.normal * (1.0 - u1).max(0.0).sqrt();
                if vis
                    .closest_hit(
                        crate::form_factors::ray_origin(node.centroid, node.normal),
                        dir.as_vec3(),
                        f32::INFINITY,
                    )
                    .is_some_and(|h| !h.front)
                {
                    back += 1;
                } else {
                    // One probe that escapes or meets a front face decides it: not enclosed.
                    break;
                }
            }
            back == PROBES
        })
        .collect()
}

/// The refinement oracle: per-node radiosity estimates `B̂` (max channel) relative to the
/// ambient level `B_amb`, and the threshold (`refinement`): a source is split while
/// `F × B̂ > refinement × B_amb`. Relative, a surface that neither emits nor is lit directly
/// has the estimate `ρ` whatever the ambient level, so an edit that changes the ambient level
/// (moving a block changes the total area in the last bits) leaves those estimates, and every
/// refinement decision made with them, exactly as they were.
pub(crate) fn estimates(
    mesh: &Mesh,
    rho: &[Rgb],
    source: &[Rgb],
    refinement: f64,
) -> (Vec<f64>, f64) {
    let max3 = |v: &Rgb| v[0].max(v[1]).max(v[2]);
    let (mut area, mut s_sum, mut r_sum) = (0.0, 0.0, 0.0);
    for (i, &id) in mesh.leaves.iter().enumerate() {
        let a = mesh.nodes[id as usize].area;
        area += a;
        s_sum += a * max3(&source[i]);
        r_sum += a * max3(&rho[i]);
    }
    let rho_mean = (r_sum / area).min(0.99);
    let amb = (s_sum / area / (1.0 - rho_mean)).max(f64::MIN_POSITIVE);
    let mut bhat = vec![0.0; mesh.nodes.len()];
    for n in (0..mesh.nodes.len()).rev() {
        let node = &mesh.nodes[n];
        bhat[n] = if node.is_leaf() {
            let i = node.leaf_lo as usize;
            let s = max3(&source[i]);
            // Zero stays exactly zero; a huge emitter over a tiny ambient stays finite.
            let e = if s > 0.0 {
                (s / amb).min(f64::MAX)
            } else {
                0.0
            };
            e + max3(&rho[i])
        } else {
            (0..4)
                .map(|k| bhat[(node.first_child + k) as usize])
                .fold(0.0, f64::max)
        };
    }
    (bhat, refinement)
}
