//! A bake: the input (scene → mesh, visibility, per-element terms: [`crate::input`]), the
//! link hierarchy ([`crate::hierarchy`], what a checkpoint stores), and the solve
//! ([`crate::solve`]) in time-budgeted steps, with the residual recorded against time.

use std::time::{Duration, Instant};

use radiant_scene::{Light, Scene, Sky, Surface};

use crate::hierarchy::{self, Hierarchy, Relink, RootMatch};
use crate::input::{self, Lighting};
use crate::links;
use crate::mesh::Mesh;
use crate::metrics::surface_means;
use crate::params::BakeParams;
use crate::report::{BakeReport, BakeResult, PhaseTimes, TimelinePoint};
use crate::solve::{Info, Solve, SolveError};
use crate::solvers::SolverKind;
use crate::system::{Rgb, System};
use crate::{BakeError, ParameterError};

/// Progress callbacks.
#[derive(Debug)]
pub enum BakeEvent<'a> {
    /// A solver step finished, at this many seconds since the bake started.
    Solve(&'a Info, f64),
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
    /// Lights, sky, masks, textures and direct light, kept for edits.
    lighting: Lighting,
    /// The links' bookkeeping: fingerprint, enclosed elements, oracle.
    hierarchy: Hierarchy,
    /// Whether this bake was resumed from a checkpoint.
    resumed: bool,
    has_emitters: bool,
    solve: Solve,
    log: Log,
    /// Scratch space of geometry edits, kept between them.
    scratch: links::Scratch,
}

/// What a bake records as it goes, for its report.
struct Log {
    started: Instant,
    times: PhaseTimes,
    timeline: Vec<TimelinePoint>,
    warnings: Vec<String>,
    last: Option<Info>,
    stalled: Option<SolveError>,
}

const NO_EMITTERS: &str = "no emitters and no lights: nothing to bake, all radiosity is 0";

/// Refuses a mesh too large for the direct solver, before form factors are spent on it.
fn check_direct(params: &BakeParams, mesh: &Mesh) -> Result<(), BakeError> {
    let limit = params.solver_params.max_direct;
    if params.solver == SolverKind::Direct && mesh.element_count() > limit {
        return Err(BakeError::TooLargeForDirect {
            elements: mesh.element_count(),
            limit,
        });
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
            &self.hierarchy,
            self.mesh.nodes.len(),
            &self.system.links,
            &self.radiosity(),
        )
    }

    /// Whether this bake came from a checkpoint.
    pub fn is_resumed(&self) -> bool {
        self.resumed
    }

    /// The links' bookkeeping (fingerprint, enclosed elements, refinement oracle).
    pub fn hierarchy(&self) -> &Hierarchy {
        &self.hierarchy
    }

    /// The input, then the hierarchy (built, or read from `saved`), then the solver.
    fn build(
        scene: &Scene,
        params: &BakeParams,
        progress: &(dyn Fn(usize, usize) + Sync),
        saved: Option<crate::checkpoint::Saved>,
    ) -> Result<Bake, BakeError> {
        let started = Instant::now();
        let scene = input::static_scene(scene);
        let scene = scene.as_ref();
        input::validate(scene)?;
        params.check()?;
        let mut times = PhaseTimes::default();
        let mut t = Instant::now();
        let mut lap = || {
            std::mem::replace(&mut t, Instant::now())
                .elapsed()
                .as_secs_f64()
        };
        if let Some(sv) = &saved {
            sv.fits_scene(hierarchy::fingerprint(scene, params))?;
        }
        let mesh = Mesh::new(scene, &params.mesh)?;
        if let Some(sv) = &saved {
            sv.fits_mesh(&mesh)?;
        }
        check_direct(params, &mesh)?;
        times.meshing = lap();
        let masks = input::masks(scene);
        let bvh = input::visibility(&mesh, masks.as_ref());
        times.visibility = lap();
        let lighting = Lighting::new(scene, &mesh, &bvh, masks, &params.ff);
        let (rho, source) = lighting.terms(&scene.surfaces, &mesh);
        times.direct_light = lap();

        let has_emitters = source.iter().flatten().any(|&v| v > 0.0);
        let mut warnings = scene.warnings();
        if !has_emitters {
            warnings.push(NO_EMITTERS.into());
        }
        if let Some(sv) = &saved
            && has_emitters
            && sv.links.is_empty()
            && mesh.element_count() > 0
        {
            // Written when nothing emitted, so it has no links to resume from.
            return Err(crate::checkpoint::CheckpointError::NoLinks.into());
        }
        let resumed = saved.is_some();
        let (hierarchy, links, saved_b) = match saved {
            Some(sv) => (sv.hierarchy, sv.links, Some(sv.radiosity)),
            None => {
                let n = mesh.element_count();
                let progress = |d| progress(d, n);
                let (h, l) =
                    hierarchy::build(scene, &mesh, &bvh, params, (&rho, &source), &progress);
                (h, l, None)
            }
        };
        times.form_factors = lap();
        let dead_count = hierarchy.dead.iter().filter(|&&d| d).count();
        if dead_count > 0 {
            tracing::debug!("{dead_count} elements lie inside closed geometry");
        }
        let system = System::new(&mesh, rho, source, links, &hierarchy.dead);
        let mut solve = Solve::new(params.solver, &system, params.solver_params);
        if let Some(b) = &saved_b {
            solve.warm_start(&system, b);
        }
        Ok(Bake {
            mesh,
            system,
            params: *params,
            surfaces: scene.surfaces.clone(),
            lighting,
            hierarchy,
            resumed,
            has_emitters,
            solve,
            log: Log {
                started,
                times,
                timeline: Vec::new(),
                warnings,
                last: None,
                stalled: None,
            },
            scratch: links::Scratch::default(),
        })
    }

    /// Runs the solver for about `budget` and records a timeline point. A solve that stalls
    /// or diverges is an error ([`Solve::step`]); after a stall the solution so far is still
    /// there to read.
    pub fn step(&mut self, budget: Duration) -> Result<Info, SolveError> {
        let info = if self.has_emitters {
            self.solve.step(&self.system, budget)?
        } else {
            Info::nothing_to_solve()
        };
        self.log.timeline.push(TimelinePoint {
            t_s: self.elapsed(),
            iterations: info.iterations,
            residual: info.residual,
            unshot_fraction: info.unshot_fraction,
        });
        self.log.last = Some(info);
        Ok(info)
    }

    /// Changes the surfaces' reflectance and emission and continues from the current solution:
    /// the links and form factors are kept (they do not depend on colour), and the solver
    /// warm-starts (Southwell shoots the difference, negative energy included). Returns
    /// [`BakeError::NeedsRebuild`] when the edit turns a bake with no emitters into one with
    /// some: it has no links to keep.
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
        let b = self.radiosity();
        self.system.set_materials(rho, source);
        self.surfaces = surfaces.to_vec();
        self.has_emitters = has_emitters;
        self.solve.warm_start(&self.system, &b);
        self.log.last = None;
        Ok(())
    }

    /// Replaces the punctual lights: their direct light is computed again (shadow rays on the
    /// same geometry), the links are kept, and the solve warm-starts as for
    /// [`Bake::edit_surfaces`]. Lights must be finite, with non-negative intensity.
    pub fn edit_lights(&mut self, lights: &[Light]) -> Result<(), BakeError> {
        let sky = self.lighting.sky.clone();
        self.edit_lights_and_sky(lights, sky.as_ref())
    }

    /// Replaces the punctual lights and the sky (`None`: no sky), as [`Bake::edit_lights`]
    /// does the lights: the sky's light is computed again with its visibility rays, the links
    /// are kept.
    pub fn edit_lights_and_sky(
        &mut self,
        lights: &[Light],
        sky: Option<&Sky>,
    ) -> Result<(), BakeError> {
        input::validate_lights(lights)?;
        let relit = self
            .lighting
            .relit(lights, sky, &self.mesh, &self.params.ff);
        let old = std::mem::replace(&mut self.lighting, relit);
        let surfaces = self.surfaces.clone();
        let result = self.edit_surfaces(&surfaces);
        if result.is_err() {
            self.lighting = old;
        }
        result
    }

    /// Moves, adds or removes static geometry (and takes the scene's materials and lights along)
    /// and keeps what the edit does not touch: the form factors of links whose receiver and
    /// source are on triangles that stayed where they were, and whose shaft misses the bounds of
    /// the triangles that moved, came or went (see [`links::update`]).
    ///
    /// Triangles are matched to the old ones by surface name, their index within the surface
    /// and exact position ([`RootMatch`]); a moved triangle is one that went and one that came.
    /// Matched ones keep their elements' links and radiosity, the others get theirs computed,
    /// and the refinement oracle is recomputed as a fresh bake would (links whose visibility
    /// sample count changes with it are computed again). Visibility rays are seeded by each
    /// node's own triangle ([`Mesh::stable_id`]), so the links equal a fresh bake's bit for bit
    /// (after a resume from a checkpoint written under other materials or lights, a few links
    /// may keep the sample counts of the oracle they were built with).
    ///
    /// Direct light and enclosed elements are computed again, and the solve warm-starts from
    /// the current solution. Returns [`BakeError::NeedsRebuild`] when the scene's bounding box
    /// changed (every local coordinate would), or when nothing emits before or after.
    pub fn edit_geometry(&mut self, scene: &Scene) -> Result<links::UpdateStats, BakeError> {
        let scene = input::static_scene(scene);
        let scene = scene.as_ref();
        input::validate(scene)?;
        if !self.has_emitters || !scene.has_emitters() {
            return Err(BakeError::NeedsRebuild);
        }
        let mesh = Mesh::new(scene, &self.params.mesh)?;
        check_direct(&self.params, &mesh)?;
        if mesh.frame != self.mesh.frame {
            return Err(BakeError::NeedsRebuild);
        }
        let matched = RootMatch::new(&self.mesh, &mesh);
        let unchanged = matched.unchanged()
            && scene.lights == self.lighting.lights
            && scene.sky == self.lighting.sky
            && scene.surfaces == self.surfaces
            && self.lighting.same_textures(scene);
        if unchanged {
            return Ok(links::UpdateStats::default());
        }
        // The current solution, carried over to the elements that stay.
        let b = matched.carry(&self.radiosity());
        let masks = input::masks(scene);
        let bvh = input::visibility(&mesh, masks.as_ref());
        let lighting = Lighting::new(scene, &mesh, &bvh, masks, &self.params.ff);
        let (rho, source) = lighting.terms(&scene.surfaces, &mesh);
        if !source.iter().flatten().any(|&v| v > 0.0) {
            // Lights that reach nothing: a fresh bake would say so and build no links.
            return Err(BakeError::NeedsRebuild);
        }
        let relink = Relink {
            old_mesh: &self.mesh,
            old_links: &self.system.links,
            old: &self.hierarchy,
            scene,
            mesh: &mesh,
            bvh: &bvh,
            rho: &rho,
            source: &source,
            matched: &matched,
            scratch: &self.scratch,
        };
        let (hierarchy, links, stats) = hierarchy::relink(&relink, &self.params);
        self.system = System::new(&mesh, rho, source, links, &hierarchy.dead);
        self.hierarchy = hierarchy;
        self.lighting = lighting;
        self.mesh = mesh;
        self.surfaces = scene.surfaces.clone();
        self.log.warnings = scene.warnings();
        self.log.last = None;
        self.resumed = false;
        self.solve.restart(&self.system, &b);
        Ok(stats)
    }

    /// Seconds since the bake started.
    pub fn elapsed(&self) -> f64 {
        self.log.started.elapsed().as_secs_f64()
    }

    /// The latest step's info.
    pub fn last_info(&self) -> Option<Info> {
        self.log.last
    }

    /// The current radiosity per element.
    pub fn radiosity(&self) -> Vec<Rgb> {
        if self.has_emitters {
            self.solve.radiosity(&self.system)
        } else {
            vec![[0.0; 3]; self.system.len()]
        }
    }

    /// Whether the solve has spent its time limit (`BakeParams::time_limit`).
    pub fn out_of_time(&self) -> bool {
        (self.params.time_limit).is_some_and(|l| self.solve.solving() >= l)
    }

    /// The current light as a smooth field (for light maps).
    pub fn smooth_field(&self) -> crate::smooth::SmoothField {
        let radiosity = self.radiosity();
        crate::smooth::SmoothField::new(&self.mesh, &self.system, &self.surfaces, &radiosity)
    }

    /// Steps until converged or the time limit, calling `on_event` after each step.
    ///
    /// A solve that stops making progress ([`SolveError::Stalled`]: reflectance 1 in a closed
    /// scene, say) ends unconverged, with the stall in the report and a warning, rather than
    /// running forever; one that diverges or is singular is an error.
    pub fn run_to_end(
        mut self,
        on_event: &mut dyn FnMut(BakeEvent),
    ) -> Result<BakeResult, BakeError> {
        loop {
            match self.step(self.params.step_budget) {
                Ok(info) => {
                    on_event(BakeEvent::Solve(&info, self.elapsed()));
                    if info.converged || self.out_of_time() {
                        break;
                    }
                }
                Err(e @ SolveError::Stalled { .. }) => {
                    self.log.warnings.push(e.to_string());
                    self.log.stalled = Some(e);
                    break;
                }
                Err(e) => return Err(e.into()),
            }
        }
        Ok(self.finish())
    }

    /// The report as things stand.
    pub fn report(&self) -> BakeReport {
        let last = self.log.last.unwrap_or(Info {
            iterations: 0,
            residual: f64::INFINITY,
            estimated_error: f64::INFINITY,
            progress: 0.0,
            unshot_fraction: 1.0,
            converged: false,
        });
        let mut times = self.log.times;
        times.solve = self.solve.solving().as_secs_f64();
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
            timeline: self.log.timeline.clone(),
            warnings: self.log.warnings.clone(),
            stalled: self.log.stalled,
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
            hierarchy: self.hierarchy,
        }
    }
}
