//! A reference for Radiant's bakes: a progressive CPU path tracer over the same scene model.
//!
//! It estimates the quantities a bake produces, each with its standard error, so that a bake's
//! total error (meshing, clustering and solver together) can be measured on any scene:
//! - [`Tracer::surfaces`]: per-surface mean radiosity (the bake's `surfaces.csv`);
//! - [`Tracer::points`]: radiosity at given surface points;
//! - [`Tracer::image`]: the radiance seen by a pinhole camera.
//!
//! Units are the bake's: glTF emissive units, outgoing radiance `L_e + ρ E / π`. Materials are
//! one-sided and diffuse; punctual lights follow KHR_lights_punctual as the bake reads them
//! (candela and lux, glTF's range and cone falloff). Sky light is not in the scene model yet;
//! a ray that leaves the scene finds nothing.
//!
//! Estimation is progressive ([`Params`]): rounds of sample chunks run in parallel on rayon's
//! pool until a sample count, a target relative standard error or a time limit. A given
//! sample count gives bit-identical results on any number of threads; a target or a time
//! limit stops after a number of samples that depends on the machine, and the [`Run`] says
//! how many, so that the run can be repeated exactly.
//!
//! ```
//! use radiant_reference::{Params, Tracer};
//! let scene = radiant_scene::builtin("cornell-box").unwrap();
//! let tracer = Tracer::new(&scene).unwrap();
//! let params = Params { samples: Some(64), target_error: None, ..Params::default() };
//! let (surfaces, run) = tracer.surfaces(&params, &|_| {}).unwrap();
//! assert_eq!(surfaces.len(), 19);
//! assert_eq!(run.paths, 19 * 64);
//! ```

#![expect(
    clippy::needless_range_loop,
    reason = "RGB channel loops index several arrays at once; iterators would hide that"
)]

mod progressive;
mod rng;
mod tracer;

use std::time::Duration;

use glam::DVec3;
use radiant_scene::Camera;

pub use tracer::Tracer;

use progressive::{Job, Rule};
use tracer::Cdf;

/// Errors of the reference. None of them panics; each names what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReferenceError {
    /// A parameter out of its range (zero samples, a NaN target, a zero time limit).
    #[error("invalid parameter {name}: {value}")]
    InvalidParameter {
        /// The parameter.
        name: &'static str,
        /// Its value and what it must be.
        value: String,
    },
    /// Nothing would ever stop the estimate: no sample count, target or time limit.
    #[error("no stopping rule: give a sample count, a target error or a time limit")]
    Unbounded,
    /// The scene has no triangles.
    #[error("the scene has no triangles")]
    EmptyScene,
    /// The scene has a non-finite or out-of-range value.
    #[error("invalid scene: {0}")]
    InvalidScene(String),
    /// A requested point is not on a front-facing surface.
    #[error("point {index} ('{name}') is not on a front-facing surface")]
    PointOffSurface {
        /// Index in the list given.
        index: usize,
        /// Its name.
        name: String,
    },
    /// A probe with a non-finite position, or a normal that is zero or not finite.
    #[error("probe {index} ('{name}'): {what}")]
    InvalidProbe {
        /// Index in the list given.
        index: usize,
        /// Its name.
        name: String,
        /// What is wrong.
        what: &'static str,
    },
    /// An image needs a camera.
    #[error("the scene has no camera")]
    NoCamera,
    /// A sample was NaN or infinite (a bug; reported rather than averaged in).
    #[error("a {what} sample of item {item} is not finite")]
    NonFinite {
        /// Surfaces, points or pixels.
        what: &'static str,
        /// The item.
        item: usize,
    },
}

/// When an estimate stops: whichever given rule is met first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    /// Samples (paths) per item: per surface, point or pixel.
    pub samples: Option<u64>,
    /// Target relative standard error: `‖se‖ / ‖mean‖` over RGB per surface or point (after
    /// at least 4096 paths each), where `‖mean‖` counts as at least [`DARK`] times the median
    /// item's (so a surface a thousand times darker than most, the ceiling behind a light
    /// panel, is held to the absolute error of one a thousandth as bright as they are, and does
    /// not chase its relative error to the time limit; the median, so that one bright lamp
    /// does not loosen the rest); over an image, `Σ se / Σ mean` over all pixels and channels.
    pub target_error: Option<f64>,
    /// Wall-clock limit.
    pub time_limit: Option<Duration>,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for Params {
    /// 0.5 % target error, no sample cap, no time limit, seed 1.
    fn default() -> Self {
        Params {
            samples: None,
            target_error: Some(0.005),
            time_limit: None,
            seed: 1,
        }
    }
}

impl Params {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ReferenceError> {
        if self.samples == Some(0) {
            return Err(ReferenceError::InvalidParameter {
                name: "samples",
                value: "0 (must be at least 1)".into(),
            });
        }
        if let Some(t) = self.target_error
            && !(t > 0.0 && t.is_finite())
        {
            return Err(ReferenceError::InvalidParameter {
                name: "target_error",
                value: format!("{t} (must be a positive number)"),
            });
        }
        if self.time_limit.is_some_and(|t| t.is_zero()) {
            return Err(ReferenceError::InvalidParameter {
                name: "time_limit",
                value: "0 s (must be positive)".into(),
            });
        }
        if self.samples.is_none() && self.target_error.is_none() && self.time_limit.is_none() {
            return Err(ReferenceError::Unbounded);
        }
        Ok(())
    }
}

/// An estimated RGB quantity with its standard error.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Estimate {
    /// The mean.
    pub mean: [f64; 3],
    /// The standard error of the mean, per channel.
    pub se: [f64; 3],
    /// Samples averaged.
    pub samples: u64,
}

/// A surface or point darker than this fraction of the median one is held to the target
/// error of a mean this bright ([`Params::target_error`]).
pub const DARK: f64 = 1e-3;

impl Estimate {
    /// `‖se‖ / ‖mean‖` over RGB: 0 when every sample was zero, infinite with one sample.
    pub fn rel_error(&self) -> f64 {
        self.rel_error_above(0.0)
    }

    /// `‖se‖ / max(‖mean‖, floor)` over RGB: 0 when every sample was zero, infinite with one
    /// sample of a mean below a zero floor.
    pub fn rel_error_above(&self, floor: f64) -> f64 {
        let (se, mean) = (norm(&self.se), norm(&self.mean).max(floor));
        if se == 0.0 {
            0.0
        } else if mean > 0.0 {
            se / mean
        } else {
            f64::INFINITY
        }
    }

    /// `‖mean‖` over RGB.
    pub fn magnitude(&self) -> f64 {
        norm(&self.mean)
    }
}

fn norm(v: &[f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Why an estimate stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stopped {
    /// Every item has its samples.
    Samples,
    /// The target error is met.
    Target,
    /// The time limit passed.
    TimeLimit,
}

impl Stopped {
    /// A short name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Stopped::Samples => "samples",
            Stopped::Target => "target error",
            Stopped::TimeLimit => "time limit",
        }
    }
}

/// What an estimate cost.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Run {
    /// Paths traced (samples over all items).
    pub paths: u64,
    /// Rays cast: bounces and shadow rays.
    pub rays: u64,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// Worker threads.
    pub threads: usize,
    /// Which rule stopped it.
    pub stopped: Stopped,
    /// The worst item's relative standard error as the target error measures it (per-item
    /// rules: [`Estimate::rel_error_above`] with [`DARK`] times the median item's mean) or
    /// the image's aggregate one.
    pub rel_error: f64,
}

/// Progress, reported after each round.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Progress {
    /// `"surfaces"`, `"points"` or `"pixels"`.
    pub what: &'static str,
    /// Paths so far.
    pub paths: u64,
    /// Seconds so far.
    pub seconds: f64,
    /// As [`Run::rel_error`], so far.
    pub rel_error: f64,
    /// Estimated fraction done, by the first stopping rule to be met.
    pub fraction: f64,
    /// Estimated seconds left.
    pub eta_seconds: Option<f64>,
}

/// One surface's estimate.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceEstimate {
    /// Index into the scene's surfaces.
    pub surface: u32,
    /// Its area, scene units².
    pub area: f64,
    /// Mean outgoing radiance over the surface (emissive units) and its standard error.
    pub estimate: Estimate,
}

/// The area-weighted mean of the surfaces' relative standard errors (those with a finite
/// one): the noise floor of any comparison with these estimates.
pub fn mean_rel_error(surfaces: &[SurfaceEstimate]) -> f64 {
    let (mut area, mut rel) = (0.0, 0.0);
    for s in surfaces
        .iter()
        .filter(|s| s.estimate.rel_error().is_finite())
    {
        area += s.area;
        rel += s.area * s.estimate.rel_error();
    }
    if area > 0.0 { rel / area } else { 0.0 }
}

/// A point to estimate radiosity at ([`Tracer::points`]), or irradiance at
/// ([`Tracer::probes`]), in scene units.
#[derive(Clone, Debug, PartialEq)]
pub struct Point {
    /// A name for reports.
    pub name: String,
    /// For [`Tracer::points`], on (or within 0.5 % of the scene's radius of) a surface; for
    /// [`Tracer::probes`], anywhere.
    pub position: DVec3,
    /// The surface's normal there (its front side), or the probe's.
    pub normal: DVec3,
}

/// A camera image: the mean radiance of each pixel (box filter), row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageEstimate {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// One estimate per pixel.
    pub pixels: Vec<Estimate>,
}

/// A surface or point stops at the target error only after 16 chunks (4096 paths).
const MIN_CHUNKS: u64 = 16;
const KIND_SURFACES: u64 = 1;
const KIND_POINTS: u64 = 2;
const KIND_PIXELS: u64 = 3;
const KIND_PROBES: u64 = 4;

impl Tracer {
    /// Mean outgoing radiance of every surface that has triangles of positive area, in the
    /// scene's surface order. Each sample is a path from a uniformly chosen point.
    pub fn surfaces(
        &self,
        params: &Params,
        progress: &(dyn Fn(&Progress) + Sync),
    ) -> Result<(Vec<SurfaceEstimate>, Run), ReferenceError> {
        let mut by_surface: Vec<Vec<u32>> = vec![Vec::new(); self.materials.len()];
        for (i, t) in self.tris.iter().enumerate() {
            if t.area > 0.0 {
                by_surface[t.surface as usize].push(i as u32);
            }
        }
        let items: Vec<(u32, Vec<u32>, Cdf)> = by_surface
            .into_iter()
            .enumerate()
            .filter(|(_, t)| !t.is_empty())
            .map(|(s, tris)| {
                let cdf = Cdf::new(tris.iter().map(|&i| self.tris[i as usize].area));
                (s as u32, tris, cdf)
            })
            .collect();
        let (estimates, run) = progressive::run(
            params,
            Job {
                items: items.len(),
                kind: KIND_SURFACES,
                chunk: 256,
                rule: Rule::PerItem,
                min_chunks: MIN_CHUNKS,
                what: "surfaces",
                sample: |i: usize, rng: &mut rng::Rng, rays: &mut u64| {
                    let (_, tris, cdf) = &items[i];
                    let tri = tris[cdf.sample(rng.f64())];
                    let x = self.tris[tri as usize].point(rng.f64(), rng.f64());
                    self.outgoing(tri, x, rng, rays)
                },
                progress,
            },
        )?;
        let s2 = self.frame.scale * self.frame.scale;
        Ok((
            items
                .iter()
                .zip(estimates)
                .map(|((s, _, cdf), estimate)| SurfaceEstimate {
                    surface: *s,
                    area: cdf.total() * s2,
                    estimate,
                })
                .collect(),
            run,
        ))
    }

    /// Outgoing radiance at each point. A point must lie on a front-facing surface.
    pub fn points(
        &self,
        points: &[Point],
        params: &Params,
        progress: &(dyn Fn(&Progress) + Sync),
    ) -> Result<(Vec<Estimate>, Run), ReferenceError> {
        let located: Vec<(u32, DVec3)> = points
            .iter()
            .enumerate()
            .map(|(index, p)| {
                self.locate(p.position, p.normal)
                    .ok_or_else(|| ReferenceError::PointOffSurface {
                        index,
                        name: p.name.clone(),
                    })
            })
            .collect::<Result<_, _>>()?;
        progressive::run(
            params,
            Job {
                items: located.len(),
                kind: KIND_POINTS,
                chunk: 256,
                rule: Rule::PerItem,
                min_chunks: MIN_CHUNKS,
                what: "points",
                sample: |i: usize, rng: &mut rng::Rng, rays: &mut u64| {
                    let (tri, x) = located[i];
                    self.outgoing(tri, x, rng, rays)
                },
                progress,
            },
        )
    }

    /// Irradiance at each probe (`E = ∫ L cos θ dω` over the hemisphere about its normal, in
    /// W/m² of the scene's emission units: a surface of reflectance ρ there would reflect
    /// ρ·E/π). A probe is a point anywhere in the scene, in free space or on a surface, with
    /// a normal of any length but zero ([`Point`]'s `normal` need not be unit here). Each
    /// sample is the path [`Tracer::points`] starts at a surface point: the emitters by light
    /// sampling, the punctual lights with a shadow ray, and a cosine-weighted bounce into the
    /// scene or the sky. A probe inside closed geometry meets back faces only and reads 0.
    pub fn probes(
        &self,
        probes: &[Point],
        params: &Params,
        progress: &(dyn Fn(&Progress) + Sync),
    ) -> Result<(Vec<Estimate>, Run), ReferenceError> {
        let local: Vec<(DVec3, DVec3)> = probes
            .iter()
            .enumerate()
            .map(|(index, p)| {
                let bad = |what| ReferenceError::InvalidProbe {
                    index,
                    name: p.name.clone(),
                    what,
                };
                if !p.position.is_finite() {
                    return Err(bad("its position is not finite"));
                }
                let n = p
                    .normal
                    .try_normalize()
                    .ok_or_else(|| bad("its normal is zero or not finite"))?;
                let x = self.frame.to_local(p.position);
                // The local frame holds the scene in the unit sphere; the rays are f32.
                if x.length() > 1e6 {
                    return Err(bad("it is over a million scene radii from the scene"));
                }
                Ok((x, n))
            })
            .collect::<Result<_, _>>()?;
        let (mut estimates, run) = progressive::run(
            params,
            Job {
                items: local.len(),
                kind: KIND_PROBES,
                chunk: 256,
                rule: Rule::PerItem,
                min_chunks: MIN_CHUNKS,
                what: "probes",
                sample: |i: usize, rng: &mut rng::Rng, rays: &mut u64| {
                    let (x, n) = local[i];
                    self.reflected(x, n, rng, rays)
                },
                progress,
            },
        )?;
        // The paths estimate E/π.
        for e in &mut estimates {
            e.mean = e.mean.map(|m| m * std::f64::consts::PI);
            e.se = e.se.map(|m| m * std::f64::consts::PI);
        }
        Ok((estimates, run))
    }

    /// The radiance `camera` sees, `width × height` pixels, each the mean over its area (box
    /// filter). Surfaces seen from behind and rays that leave the scene are black.
    pub fn image(
        &self,
        camera: &Camera,
        width: u32,
        height: u32,
        params: &Params,
        progress: &(dyn Fn(&Progress) + Sync),
    ) -> Result<(ImageEstimate, Run), ReferenceError> {
        if width == 0 || height == 0 || width > 16_384 || height > 16_384 {
            return Err(ReferenceError::InvalidParameter {
                name: "image size",
                value: format!("{width}×{height} (each side 1 to 16384)"),
            });
        }
        let forward = camera.forward.try_normalize();
        let right = forward.and_then(|f| f.cross(camera.up).try_normalize());
        let (Some(forward), Some(right)) = (forward, right) else {
            return Err(ReferenceError::InvalidScene(
                "the camera's forward and up are parallel or zero".into(),
            ));
        };
        if !(camera.yfov > 0.0 && camera.yfov < std::f64::consts::PI && camera.position.is_finite())
        {
            return Err(ReferenceError::InvalidScene(format!(
                "camera: field of view {} rad or position not usable",
                camera.yfov
            )));
        }
        let up = right.cross(forward);
        let origin = self.frame.to_local(camera.position);
        let tan = (0.5 * camera.yfov).tan();
        let aspect = width as f64 / height as f64;
        let (w, h) = (width as usize, height as usize);
        let (pixels, run) = progressive::run(
            params,
            Job {
                items: w * h,
                kind: KIND_PIXELS,
                chunk: 8,
                rule: Rule::Aggregate,
                min_chunks: 1,
                what: "pixels",
                sample: |i: usize, rng: &mut rng::Rng, rays: &mut u64| {
                    let (px, py) = ((i % w) as f64, (i / w) as f64);
                    let sx = (2.0 * (px + rng.f64()) / width as f64 - 1.0) * tan * aspect;
                    let sy = (1.0 - 2.0 * (py + rng.f64()) / height as f64) * tan;
                    let dir = (forward + right * sx + up * sy).normalize();
                    *rays += 1;
                    match self.trace(origin, dir) {
                        tracer::Found::Surface(tri, x) => self.outgoing(tri, x, rng, rays),
                        tracer::Found::Absorbed => [0.0; 3],
                        tracer::Found::Escaped => self.sky(dir),
                    }
                },
                progress,
            },
        )?;
        Ok((
            ImageEstimate {
                width,
                height,
                pixels,
            },
            run,
        ))
    }
}
