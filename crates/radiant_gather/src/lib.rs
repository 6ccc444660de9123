//! Radiosity by direct rendering, the lecture's "using direct rendering" (and what
//! lightmapper.h does): a GPU hemicube gather on wgpu whose receivers are the light map's texels.
//!
//! Each of the first [`PLAIN_SWEEPS`] iterations is one Jacobi sweep as the notes write it
//! (every one with [`GatherParams::acceleration`] off; after them, Chebyshev's weighted step):
//!
//! ```text
//! for each receiver i:  H_new[i] = D[i] + Σ_pixels ΔF · B_old(pixel)
//! ```
//!
//! where `B_old = E + ρ H_old` is what the scene shows, `ΔF` the delta form factors of the
//! hemicube (normalised so they sum to 1, as the CPU hemicube's), and `D` the light of punctual
//! lights (irradiance / π, with shadow rays on the CPU) and, by default, of emissive triangles
//! in closed form (the point-to-triangle form factor times the clear share of shadow rays; the
//! emitters then show only what they reflect, so a small light's aliasing leaves the
//! hemicubes). The light map the gather returns holds `H`, the incident radiance in emissive
//! units, as the bake's (`radiant_radiosity::lightmap`): a surface of reflectance `ρ` shows
//! `E + ρ H`.
//!
//! On the GPU (`gather.wgsl`): receivers go in batches onto atlases of hemicube cells (3R × R
//! pixels each: the top face and the four upper half side faces); one instanced draw per batch
//! renders every face of every cell, each clipped to its own frustum with clip distances, with
//! a reversed infinite depth (the near plane just above the receiver, which sits a hair above
//! its surface, so its own surface is never seen). A pixel holds what it sees, the light-map
//! coordinates and page there, or a back face (black: surfaces are one-sided), or nothing
//! (the sky). That does not change between sweeps, so a batch is drawn once and kept if its
//! ids fit what is left of [`GatherParams::keep_bytes`]; each sweep is then one compute pass
//! per batch, which samples the current radiosity map `B` at each pixel (bilinearly, as a
//! fragment would), weights it by the pixel's delta form factor (the multiplier buffer), sums
//! each cell in one workgroup, and writes the receiver's `H` into a buffer read back for the
//! convergence test and its `B = E + ρ H` into the next radiosity map (ping-pong, so the sweep
//! is Jacobi). On the Cornell box on lavapipe at 100 texels per metre, the first sweep
//! (drawing) takes about 1 s and each later one about 0.14 s, against 1.7 s per sweep when
//! every sweep drew colours. After [`PLAIN_SWEEPS`] sweeps, Chebyshev acceleration
//! ([`GatherParams::acceleration`]). The gather is a form-factor-free mode: no links, nothing
//! stored per pair.
//!
//! A texel of a surface with a base-colour texture reflects the texture's mean over the part
//! of it on its triangle (relative to the image's mean, as the bake's elements), so what it
//! writes into the radiosity map, and so what every hemicube sees of it, shows the texture.
//!
//! Alpha masks (`alphaMode` MASK, BLEND as a mask at 0.5) as the bake has them: a masked
//! triangle's fragments below its cutoff are not drawn (the mask's alpha sampled as its glTF
//! sampler says), wholly cut triangles are left out, and the shadow rays of the direct light
//! pass the cut parts.
//!
//! Not drawn as the bake has them (documented limits): emissive textures (an emitter shows its
//! mean emission), image skies (refused), dynamic surfaces (left out, as by the bake).

mod coverage;
mod gpu;

use std::time::Instant;

use glam::{DVec3, Vec3};
use radiant_radiosity::Rgb;
use radiant_radiosity::lightmap::LightMap;
use radiant_radiosity::metrics::SurfaceMean;
use radiant_render::{GpuContext, RenderError};
use radiant_scene::atlas::{Atlas, AtlasError, AtlasTexel};
use radiant_scene::{Scene, Sky};
use radiant_visibility::{Bvh, Visibility};

/// Chart texels the automatic texel density aims at. Once the emitters are lit in closed form
/// and texels are weighed by what they cover, the gather's error on the Cornell box comes
/// mostly from the texels' size, not from the hemicubes' pixels: on lavapipe, 10 000 texels
/// (72 per metre) at 16² hemicubes are 0.30 % from Mitsuba in 1.3 s (0.86 % mean at the 24
/// Mitsuba points); 5 000 (50 per metre) 0.36 % in 0.8 s, where the points are 2.1 % off.
pub const DEFAULT_TEXELS: f64 = 10000.0;

/// The CPU methods to name when there is no GPU.
pub const CPU_METHODS: &str = "--method jacobi, gauss-seidel, southwell or direct";

/// How to gather.
#[derive(Clone, Debug, PartialEq)]
pub struct GatherParams {
    /// Hemicube resolution: the top face is `resolution²` pixels (even, 8..=1024).
    pub resolution: u32,
    /// Light-map texels per scene unit; `None`: about [`DEFAULT_TEXELS`] chart texels.
    pub texel_density: Option<f64>,
    /// Side of a light-map page (64..=8192).
    pub page_side: u32,
    /// Stop when the estimated remaining relative change (`Δ q / (1 − q)`, `q` the observed
    /// contraction of `Δ`, the relative L1 change of a sweep) falls below this.
    pub tolerance: f64,
    /// At most this many sweeps.
    pub max_iterations: u32,
    /// Light straight from emissive surfaces as a closed form with shadow rays (the point to
    /// triangle form factor, times the clear share of [`EMITTER_RAYS`] rays to each emissive
    /// triangle) instead of the emitters' pixels, which alias a small light: the hemicubes
    /// then gather what surfaces reflect. Used when there are at most [`ANALYTIC_EMITTERS`]
    /// emissive triangles.
    pub analytic_emitters: bool,
    /// At most this many bytes of hemicube pixels kept between sweeps. A pixel holds what it
    /// sees ([`ID_BYTES`] each), which does not change between sweeps, so the batches of
    /// receivers whose hemicubes are kept are drawn once and only reduced with the current
    /// radiosity map afterwards; the others are drawn again every sweep into one shared atlas
    /// (not counted here, nor are the depth buffers). 0 draws every sweep.
    pub keep_bytes: u64,
    /// Chebyshev acceleration: after [`PLAIN_SWEEPS`] plain Jacobi sweeps, each sweep steps to
    /// `ω J(H) + (1 − ω) H_older` (`H_older` the sweep before last) with the Chebyshev weights
    /// for the spectral radius the plain sweeps showed (the ratio of their last two absolute
    /// changes, at most the largest reflectance). The radiosity operator's eigenvalues are real
    /// and below 1 (it is similar to a symmetric matrix), so this converges whatever that
    /// estimate, fastest when it is right; the hemicubes' discrete operator is only nearly
    /// reciprocal, so should the change grow [`CHEBYSHEV_GIVE_UP`] sweeps running, the gather
    /// goes back to plain sweeps. `false`: Jacobi sweeps as the notes write them.
    pub acceleration: bool,
}

/// Plain Jacobi sweeps before [`GatherParams::acceleration`] starts.
pub const PLAIN_SWEEPS: u32 = 3;

/// Accelerated sweeps running whose change grows before the gather goes back to plain ones.
pub const CHEBYSHEV_GIVE_UP: u32 = 3;

/// Bytes of one kept hemicube pixel ([`GatherParams::keep_bytes`]): a batch keeps `3R × R`
/// pixels per cell of its atlas.
pub const ID_BYTES: u64 = gpu::ID_BYTES;

/// Shadow rays from a receiver to each emissive triangle ([`GatherParams::analytic_emitters`]).
pub const EMITTER_RAYS: u32 = 16;

/// At most this many emissive triangles are lit in closed form; more are drawn.
pub const ANALYTIC_EMITTERS: usize = 256;

impl Default for GatherParams {
    fn default() -> Self {
        Self {
            resolution: 16,
            texel_density: None,
            page_side: 2048,
            tolerance: 1e-3,
            max_iterations: 500,
            analytic_emitters: true,
            keep_bytes: 1 << 30,
            acceleration: true,
        }
    }
}

/// What can go wrong.
#[derive(Debug, thiserror::Error)]
pub enum GatherError {
    /// No GPU adapter (or device).
    #[error(
        "--method gpu-hemicube needs a GPU adapter: {0}. Without one, use a CPU method: {CPU_METHODS}"
    )]
    NoAdapter(RenderError),
    /// The adapter lacks a feature the gather needs.
    #[error(
        "the GPU adapter {adapter} lacks {feature}, which --method gpu-hemicube needs; use a CPU method: {CPU_METHODS}"
    )]
    MissingFeature {
        /// The adapter.
        adapter: String,
        /// What it lacks.
        feature: &'static str,
    },
    /// A parameter out of its range.
    #[error("{field} = {value} is outside {range}")]
    InvalidSetting {
        /// The parameter.
        field: &'static str,
        /// Its value.
        value: f64,
        /// What it may be.
        range: &'static str,
    },
    /// Nothing in the scene emits light: there is nothing to gather.
    #[error("nothing in the scene emits light (no emissive surface, punctual light or sky)")]
    NoEmitters,
    /// The scene has nothing static to bake (or its alpha masks cut all of it away).
    #[error("the scene has no static triangles to bake (or its alpha masks cut them all away)")]
    NoGeometry,
    /// Something in the scene the gather does not draw.
    #[error("--method gpu-hemicube does not handle {0} yet; use a CPU method: {CPU_METHODS}")]
    Unsupported(&'static str),
    /// The light-map atlas could not be made.
    #[error(transparent)]
    Atlas(#[from] AtlasError),
    /// A wgpu validation or readback error.
    #[error("GPU: {0}")]
    Gpu(RenderError),
    /// A sweep produced a value that is not finite.
    #[error("sweep {iteration} produced a non-finite value at receiver {receiver}")]
    NonFinite {
        /// The sweep (1-based).
        iteration: u32,
        /// The receiver.
        receiver: usize,
    },
}

/// One sweep's outcome.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step {
    /// Sweeps so far.
    pub iterations: u32,
    /// Relative L1 change of `H` in this sweep.
    pub change: f64,
    /// Estimated remaining relative change (`change · q / (1 − q)`; `change` until `q` is known).
    pub estimate: f64,
    /// Whether the estimate fell below the tolerance (or the sweep limit was reached).
    pub converged: bool,
    /// Seconds this sweep took.
    pub seconds: f64,
}

/// A receiver on the CPU side: which texel, which triangle, and where its hemicube sits.
#[derive(Clone, Copy, Debug)]
struct Receiver {
    texel: AtlasTexel,
    /// The centroid of the part of the texel on its triangle (scene coordinates).
    position: DVec3,
}

/// The GPU gather over one scene.
pub struct GpuGather {
    gpu: gpu::Gpu,
    atlas: Atlas,
    receivers: Vec<Receiver>,
    h: Vec<[f32; 3]>,
    /// Which receivers cover each triangle, and how much.
    coverage: coverage::Coverage,
    /// Per receiver: the reflectance its texel shows (textures' footprints included).
    reflectance: Vec<Rgb>,
    /// Per scene triangle: reflectance and emission (of its surface), area, surface, static.
    triangles: Vec<TriangleInfo>,
    surfaces: Vec<(String, bool)>,
    params: GatherParams,
    iterations: u32,
    last_change: Option<f64>,
    steps: Chebyshev,
    setup_seconds: f64,
}

#[derive(Clone, Copy, Debug)]
struct TriangleInfo {
    rho: Rgb,
    emission: Rgb,
    area: f64,
    surface: u32,
    baked: bool,
}

impl GpuGather {
    /// Prepares the gather of `scene` on a headless GPU context.
    pub fn new(scene: &Scene, params: &GatherParams) -> Result<Self, GatherError> {
        check_params(params)?;
        check_scene(scene)?;
        let ctx = GpuContext::headless().map_err(GatherError::NoAdapter)?;
        Self::with_context(ctx, scene, params)
    }

    /// Prepares the gather of `scene` on `ctx`.
    pub fn with_context(
        ctx: GpuContext,
        scene: &Scene,
        params: &GatherParams,
    ) -> Result<Self, GatherError> {
        let start = Instant::now();
        check_params(params)?;
        check_scene(scene)?;
        if !ctx.features.contains(wgpu::Features::CLIP_DISTANCES) {
            return Err(GatherError::MissingFeature {
                adapter: ctx.info.name.clone(),
                feature: "clip distances (wgpu::Features::CLIP_DISTANCES)",
            });
        }
        let baked: Vec<bool> = scene
            .triangles
            .iter()
            .map(|t| {
                scene
                    .surfaces
                    .get(t.surface as usize)
                    .is_some_and(|s| !s.dynamic)
            })
            .collect();
        let density = match params.texel_density {
            Some(d) => d,
            None => {
                let area: f64 = scene
                    .triangles
                    .iter()
                    .zip(&baked)
                    .filter(|(_, b)| **b)
                    .map(|(t, _)| t.area())
                    .filter(|a| a.is_finite())
                    .sum();
                (DEFAULT_TEXELS / area.max(f64::MIN_POSITIVE)).sqrt()
            }
        };
        let atlas = Atlas::paged(scene, Some(density), params.page_side)?;
        let frame = Frame::of(scene, &baked).ok_or(GatherError::NoGeometry)?;
        let triangles: Vec<TriangleInfo> = scene
            .triangles
            .iter()
            .zip(&baked)
            .map(|(t, &baked)| {
                let s = scene.surfaces.get(t.surface as usize);
                TriangleInfo {
                    rho: s.map_or([0.0; 3], |s| s.reflectance),
                    emission: s.map_or([0.0; 3], |s| s.emission),
                    area: t.area(),
                    surface: t.surface,
                    baked,
                }
            })
            .collect();
        let footprints = texel_footprints(&atlas);
        let receivers = receivers(&atlas, scene, &baked, &footprints);
        if receivers.is_empty() {
            return Err(GatherError::NoGeometry);
        }
        let coverage = {
            let page = atlas.width as usize * atlas.height as usize;
            let mut at = vec![u32::MAX; page * atlas.pages as usize];
            for (k, r) in receivers.iter().enumerate() {
                let t = r.texel;
                at[t.page as usize * page + (t.y * atlas.width + t.x) as usize] = k as u32;
            }
            coverage::Coverage::new(
                &footprints,
                &atlas.page,
                &baked,
                (atlas.width, atlas.height),
                |p, x, y| {
                    let k = *at.get(p as usize * page + (y * atlas.width + x) as usize)?;
                    (k != u32::MAX).then_some(k)
                },
            )
        };
        let emitters: Vec<Emitter> = scene
            .triangles
            .iter()
            .zip(&baked)
            .filter_map(|(t, &b)| {
                let e = scene.surfaces.get(t.surface as usize)?.emission;
                let v = t.vertices.map(|v| frame.local(v));
                let n = (v[1] - v[0]).cross(v[2] - v[0]).normalize_or_zero();
                (b && e.iter().any(|&c| c > 0.0) && n != DVec3::ZERO).then_some(Emitter {
                    v,
                    n,
                    emission: e,
                })
            })
            .collect();
        let analytic = params.analytic_emitters && emitters.len() <= ANALYTIC_EMITTERS;
        let emitters = if analytic { &emitters[..] } else { &[] };
        let reflectance = receiver_reflectance(scene, &footprints, &receivers);
        // Alpha masks: cut fragments are not drawn, and shadow rays pass them.
        let alpha = radiant_radiosity::input::masks(scene);
        let gpu_receivers = gpu_receivers(
            scene,
            &frame,
            &receivers,
            &reflectance,
            &baked,
            &Direct {
                emitters,
                draw_emission: !analytic,
                masks: alpha.as_ref(),
            },
        );
        let max_reflectance = gpu_receivers
            .iter()
            .flat_map(|r| r.reflectance[..3].iter().map(|&c| f64::from(c)))
            .fold(0.0f64, f64::max);
        let (vertices, indices, masks) =
            gpu::vertices(scene, &atlas, &frame, &baked, alpha.as_deref());
        if indices.is_empty() {
            // Every triangle cut wholly by its mask: nothing to draw (wgpu refuses empty
            // vertex buffers), nothing to see.
            return Err(GatherError::NoGeometry);
        }
        let sky = match &scene.sky {
            None => gpu::SkyUniform::None,
            Some(Sky::Uniform { radiance }) => gpu::SkyUniform::Uniform(*radiance),
            Some(Sky::Gradient { zenith, horizon }) => gpu::SkyUniform::Gradient(*zenith, *horizon),
            Some(Sky::Image(_)) => return Err(GatherError::Unsupported("an image sky")),
        };
        let gpu = gpu::Gpu::new(
            ctx,
            &gpu::Setup {
                resolution: params.resolution,
                atlas: &atlas,
                receivers: &gpu_receivers,
                vertices: &vertices,
                indices: &indices,
                masks: &masks,
                sky,
                near: NEAR,
                keep_bytes: params.keep_bytes,
            },
        )?;
        let n = receivers.len();
        tracing::info!(
            "gpu-hemicube: {n} receivers on {} page(s) of {}×{} ({:.1} texels per unit), hemicubes of {}², {} batch(es) ({} drawn once), adapter {}",
            atlas.pages,
            atlas.width,
            atlas.height,
            density,
            params.resolution,
            gpu.batches(),
            gpu.kept_batches(),
            gpu.adapter()
        );
        Ok(Self {
            gpu,
            atlas,
            receivers,
            h: vec![[0.0; 3]; n],
            coverage,
            reflectance,
            triangles,
            surfaces: scene
                .surfaces
                .iter()
                .map(|s| (s.name.clone(), s.is_emitter()))
                .collect(),
            params: params.clone(),
            iterations: 0,
            last_change: None,
            steps: Chebyshev::new(params.acceleration, max_reflectance),
            setup_seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// One sweep over every receiver (Jacobi, or its Chebyshev acceleration).
    pub fn step(&mut self) -> Result<Step, GatherError> {
        self.step_with(|_, _| {})
    }

    /// [`GpuGather::step`], with `on_drawn(k, n)` called as the k-th of the n batches this
    /// sweep draws is drawn (all of them in the first sweep, the batches not kept later): the
    /// long part of a large scene's first sweep.
    pub fn step_with(
        &mut self,
        mut on_drawn: impl FnMut(usize, usize),
    ) -> Result<Step, GatherError> {
        let start = Instant::now();
        let omega = self.steps.omega(self.iterations);
        let new = self.gpu.sweep(omega as f32, &mut on_drawn)?;
        self.iterations += 1;
        let (mut diff, mut total) = (0.0f64, 0.0f64);
        for (i, (n, o)) in new.iter().zip(&self.h).enumerate() {
            if n.iter().any(|v| !v.is_finite()) {
                return Err(GatherError::NonFinite {
                    iteration: self.iterations,
                    receiver: i,
                });
            }
            for c in 0..3 {
                diff += f64::from((n[c] - o[c]).abs());
                total += f64::from(n[c].abs());
            }
        }
        self.h = new;
        let change = if total > 0.0 { diff / total } else { 0.0 };
        let estimate = match self.last_change {
            Some(prev) if prev > 0.0 && change < prev => {
                let q = change / prev;
                change * q / (1.0 - q)
            }
            _ => change,
        };
        self.steps.observe(diff, change);
        self.last_change = Some(change);
        Ok(Step {
            iterations: self.iterations,
            change,
            estimate,
            converged: estimate <= self.params.tolerance
                || self.iterations >= self.params.max_iterations,
            seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// Sweeps until converged; `on_step` sees each sweep.
    pub fn solve(&mut self, mut on_step: impl FnMut(&Step)) -> Result<Step, GatherError> {
        loop {
            let s = self.step()?;
            on_step(&s);
            if s.converged {
                return Ok(s);
            }
        }
    }

    /// Sweeps so far.
    pub fn iterations(&self) -> u32 {
        self.iterations
    }

    /// Receivers (light-map texels, the ring around each chart included).
    pub fn receivers(&self) -> usize {
        self.receivers.len()
    }

    /// Seconds the setup took (atlas, receivers, direct light, pipelines).
    pub fn setup_seconds(&self) -> f64 {
        self.setup_seconds
    }

    /// The light-map atlas the receivers sit on.
    pub fn atlas(&self) -> &Atlas {
        &self.atlas
    }

    /// The adapter's name and backend.
    pub fn adapter(&self) -> String {
        self.gpu.adapter()
    }

    /// Triangles every hemicube face draws.
    pub fn drawn_triangles(&self) -> usize {
        self.gpu.triangles()
    }

    /// Batches of hemicubes per sweep.
    pub fn batches(&self) -> usize {
        self.gpu.batches()
    }

    /// Batches whose hemicubes are drawn once and kept ([`GatherParams::keep_bytes`]); the
    /// others are drawn every sweep.
    pub fn kept_batches(&self) -> usize {
        self.gpu.kept_batches()
    }

    /// The current light map (`H`, as the bake's: texels outside charts and their ring are 0).
    pub fn lightmap(&self) -> LightMap {
        let page = self.atlas.width as usize * self.atlas.height as usize;
        let mut texels = vec![[0.0f32; 3]; page * self.atlas.pages as usize];
        for (r, h) in self.receivers.iter().zip(&self.h) {
            let t = r.texel;
            texels[t.page as usize * page + (t.y * self.atlas.width + t.x) as usize] = *h;
        }
        LightMap {
            width: self.atlas.width,
            height: self.atlas.height,
            pages: self.atlas.pages,
            texels,
        }
    }

    /// Per-surface area-weighted mean radiosity `E + ρ H` (each triangle's `H` its texels'
    /// values weighted by the area of it each covers; without such texels, the mean of those
    /// inside its chart, or of its ring when it has none).
    #[expect(
        clippy::needless_range_loop,
        reason = "RGB channels index three arrays at once"
    )]
    pub fn surface_means(&self) -> Vec<SurfaceMean> {
        // What each texel reflects, ρ H, its ρ its own (a texture's footprint).
        let reflected: Vec<[f32; 3]> = self
            .h
            .iter()
            .zip(&self.reflectance)
            .map(|(h, rho)| std::array::from_fn(|c| (rho[c] * f64::from(h[c])) as f32))
            .collect();
        let mut per_tri = vec![([0.0f64; 3], 0u32, [0.0f64; 3], 0u32); self.triangles.len()];
        for (r, h) in self.receivers.iter().zip(&reflected) {
            let e = &mut per_tri[r.texel.triangle as usize];
            let (sum, count) = if r.texel.inside {
                (&mut e.0, &mut e.1)
            } else {
                (&mut e.2, &mut e.3)
            };
            for (s, v) in sum.iter_mut().zip(h) {
                *s += f64::from(*v);
            }
            *count += 1;
        }
        let mut acc = vec![(0.0f64, [0.0f64; 3]); self.surfaces.len()];
        for (i, (t, (inside, ni, ring, nr))) in self.triangles.iter().zip(&per_tri).enumerate() {
            if !(t.baked && t.area > 0.0 && t.area.is_finite()) {
                continue;
            }
            let reflected = match self.coverage.mean(i, &reflected) {
                Some(v) => v,
                None if *ni > 0 => inside.map(|v| v / f64::from(*ni)),
                None if *nr > 0 => ring.map(|v| v / f64::from(*nr)),
                None => continue,
            };
            let a = &mut acc[t.surface as usize];
            a.0 += t.area;
            for c in 0..3 {
                a.1[c] += t.area * (t.emission[c] + reflected[c]);
            }
        }
        self.surfaces
            .iter()
            .zip(acc)
            .filter(|(_, (a, _))| *a > 0.0)
            .map(|((name, emitter), (a, m))| SurfaceMean {
                name: name.clone(),
                area: a,
                mean: m.map(|v| v / a),
                emitter: *emitter,
            })
            .collect()
    }

    /// Radiosity `E + ρ H` at the point `p` of the surface facing `normal` (the light map
    /// sampled bilinearly there), or `None` when no baked triangle holds the point.
    pub fn radiosity_at(&self, scene: &Scene, p: DVec3, normal: DVec3) -> Option<Rgb> {
        let map = self.lightmap();
        let diag = scene_diagonal(scene);
        let mut best: Option<(f64, usize, f64, f64)> = None;
        for (i, t) in scene.triangles.iter().enumerate() {
            if !self.triangles[i].baked {
                continue;
            }
            let [a, b, c] = t.vertices;
            let n = (b - a).cross(c - a);
            let len = n.length();
            if len <= 0.0 || len.is_nan() || n.dot(normal) / len < 0.9 {
                continue;
            }
            let dist = (p - a).dot(n / len).abs();
            if dist > 1e-3 * diag {
                continue;
            }
            let (u, v) = barycentric(a, b, c, p);
            let slack = 1e-6;
            if u < -slack || v < -slack || u + v > 1.0 + slack {
                continue;
            }
            if best.is_none_or(|b| dist < b.0) {
                best = Some((dist, i, u, v));
            }
        }
        let (_, i, u, v) = best?;
        let uv = self.atlas.uv[i];
        let q = uv[0] + (uv[1] - uv[0]) * u as f32 + (uv[2] - uv[0]) * v as f32;
        let h = bilinear(&map, self.atlas.page[i], q.x, q.y);
        let t = &self.triangles[i];
        Some(std::array::from_fn(|c| t.emission[c] + t.rho[c] * h[c]))
    }
}

/// The sweeps' step weights ([`GatherParams::acceleration`]).
#[derive(Clone, Debug)]
struct Chebyshev {
    /// Whether the sweeps are (still) accelerated.
    accelerate: bool,
    /// The largest reflectance a receiver has: a bound on the spectral radius.
    max_reflectance: f64,
    /// The absolute L1 changes of the last two sweeps (the older first): their ratio
    /// estimates the spectral radius.
    diffs: [f64; 2],
    /// The last relative change.
    last: Option<f64>,
    /// The spectral radius estimate and the last weight, once the acceleration has started.
    started: Option<(f64, f64)>,
    /// Accelerated sweeps running whose change grew.
    growing: u32,
}

impl Chebyshev {
    fn new(accelerate: bool, max_reflectance: f64) -> Self {
        Self {
            accelerate,
            max_reflectance,
            diffs: [0.0; 2],
            last: None,
            started: None,
            growing: 0,
        }
    }

    /// The weight of the sweep after `done` sweeps: 1 (Jacobi) for the first [`PLAIN_SWEEPS`]
    /// or without acceleration, then the Chebyshev semi-iteration's `ω₂ = 1 / (1 − β²/2)`,
    /// `ωₖ₊₁ = 1 / (1 − β² ωₖ / 4)`, started from the last plain sweep.
    fn omega(&mut self, done: u32) -> f64 {
        if !self.accelerate || done < PLAIN_SWEEPS {
            return 1.0;
        }
        let (beta, omega) = match self.started {
            Some((beta, w)) => (beta, 1.0 / (1.0 - beta * beta * w / 4.0)),
            None => {
                let [a, b] = self.diffs;
                let beta = if a > 0.0 && b >= 0.0 {
                    (b / a).min(self.max_reflectance).min(0.999)
                } else {
                    0.0
                };
                (beta, 1.0 / (1.0 - beta * beta / 2.0))
            }
        };
        self.started = Some((beta, omega));
        omega
    }

    /// A sweep's absolute and relative L1 change. Should the change of accelerated sweeps grow
    /// [`CHEBYSHEV_GIVE_UP`] sweeps running, the later sweeps are plain.
    fn observe(&mut self, diff: f64, change: f64) {
        self.diffs = [self.diffs[1], diff];
        if self.accelerate && self.started.is_some() {
            let grew = self.last.is_some_and(|last| change > last);
            self.growing = if grew { self.growing + 1 } else { 0 };
            if self.growing >= CHEBYSHEV_GIVE_UP {
                tracing::warn!(
                    "gpu-hemicube: the accelerated sweeps' change grew {} sweeps running; going on with plain sweeps",
                    self.growing
                );
                self.accelerate = false;
                self.started = None;
            }
        }
        self.last = Some(change);
    }
}

/// Bilinear sample of page `page` of `map` at `(u, v)` in [0, 1]² (clamped to the edge).
fn bilinear(map: &LightMap, page: u32, u: f32, v: f32) -> Rgb {
    let (w, h) = (map.width as f32, map.height as f32);
    let (x, y) = (u * w - 0.5, v * h - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (f64::from(x - x0), f64::from(y - y0));
    let at = |xi: f32, yi: f32| -> [f32; 3] {
        let xi = xi.clamp(0.0, w - 1.0) as usize;
        let yi = yi.clamp(0.0, h - 1.0) as usize;
        let base = page as usize * map.width as usize * map.height as usize;
        map.texels[base + yi * map.width as usize + xi]
    };
    let (a, b, c, d) = (
        at(x0, y0),
        at(x0 + 1.0, y0),
        at(x0, y0 + 1.0),
        at(x0 + 1.0, y0 + 1.0),
    );
    std::array::from_fn(|k| {
        let top = f64::from(a[k]) * (1.0 - fx) + f64::from(b[k]) * fx;
        let bottom = f64::from(c[k]) * (1.0 - fx) + f64::from(d[k]) * fx;
        top * (1.0 - fy) + bottom * fy
    })
}

/// Barycentric weights of `p` (projected) for vertices `b` and `c`.
fn barycentric(a: DVec3, b: DVec3, c: DVec3, p: DVec3) -> (f64, f64) {
    let (e1, e2, q) = (b - a, c - a, p - a);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (q1, q2) = (q.dot(e1), q.dot(e2));
    let det = d11 * d22 - d12 * d12;
    if det.abs() < f64::MIN_POSITIVE {
        return (-1.0, -1.0);
    }
    ((d22 * q1 - d12 * q2) / det, (d11 * q2 - d12 * q1) / det)
}

/// The hemicube's centre sits this far above its surface, and the near plane half as far
/// (scene-local units: the scene fits the unit sphere).
const LIFT: f64 = 1e-5;
const NEAR: f32 = 5e-6;

fn check_params(p: &GatherParams) -> Result<(), GatherError> {
    if !(8..=1024).contains(&p.resolution) || !p.resolution.is_multiple_of(2) {
        return Err(GatherError::InvalidSetting {
            field: "hemicube resolution",
            value: f64::from(p.resolution),
            range: "an even number in 8..=1024",
        });
    }
    if let Some(d) = p.texel_density
        && !(d > 0.0 && d.is_finite())
    {
        return Err(GatherError::InvalidSetting {
            field: "texel density",
            value: d,
            range: "a positive, finite number",
        });
    }
    if !(64..=8192).contains(&p.page_side) {
        return Err(GatherError::InvalidSetting {
            field: "light-map page side",
            value: f64::from(p.page_side),
            range: "64..=8192",
        });
    }
    if !(p.tolerance > 0.0 && p.tolerance.is_finite()) {
        return Err(GatherError::InvalidSetting {
            field: "tolerance",
            value: p.tolerance,
            range: "a positive, finite number",
        });
    }
    if p.max_iterations == 0 {
        return Err(GatherError::InvalidSetting {
            field: "max iterations",
            value: 0.0,
            range: "at least 1",
        });
    }
    Ok(())
}

fn check_scene(scene: &Scene) -> Result<(), GatherError> {
    if !scene.has_emitters() {
        return Err(GatherError::NoEmitters);
    }
    Ok(())
}

fn scene_diagonal(scene: &Scene) -> f64 {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for t in &scene.triangles {
        for v in t.vertices {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    (hi - lo).length()
}

/// Scene coordinates to local ones: the baked triangles' bounding box centred and scaled into
/// the unit sphere, so a level far from the origin keeps f32 precision.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Frame {
    centre: DVec3,
    scale: f64,
}

impl Frame {
    fn of(scene: &Scene, baked: &[bool]) -> Option<Frame> {
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for (t, _) in scene.triangles.iter().zip(baked).filter(|(_, b)| **b) {
            for v in t.vertices {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        let scale = 0.5 * (hi - lo).length();
        (scale > 0.0 && scale.is_finite()).then(|| Frame {
            centre: 0.5 * (lo + hi),
            scale,
        })
    }

    pub(crate) fn local(&self, p: DVec3) -> DVec3 {
        (p - self.centre) / self.scale
    }
}

/// Each triangle's light-map footprint in texel units.
fn texel_footprints(atlas: &Atlas) -> Vec<[glam::DVec2; 3]> {
    let size = glam::DVec2::new(f64::from(atlas.width), f64::from(atlas.height));
    atlas
        .uv
        .iter()
        .map(|uv| uv.map(|c| c.as_dvec2() * size))
        .collect()
}

/// The texels [`Atlas::fill`] writes on baked triangles, the last writer of each texel kept,
/// each at the centroid of the part of it on its triangle ([`coverage`]).
fn receivers(
    atlas: &Atlas,
    scene: &Scene,
    baked: &[bool],
    footprints: &[[glam::DVec2; 3]],
) -> Vec<Receiver> {
    let texels = atlas.texels(scene);
    let page = atlas.width as usize * atlas.height as usize;
    let mut last = vec![u32::MAX; page * atlas.pages as usize];
    for (k, t) in texels.iter().enumerate() {
        last[t.page as usize * page + (t.y * atlas.width + t.x) as usize] = k as u32;
    }
    texels
        .iter()
        .enumerate()
        .filter(|(k, t)| {
            last[t.page as usize * page + (t.y * atlas.width + t.x) as usize] == *k as u32
                && baked.get(t.triangle as usize).copied().unwrap_or(false)
        })
        .map(|(_, t)| {
            let tri = &scene.triangles[t.triangle as usize];
            let [a, b, c] = tri.vertices;
            let uv = footprints[t.triangle as usize];
            let covered = coverage::clip_texel(f64::from(t.x), f64::from(t.y), uv);
            let mut position = match covered {
                Some((_, centroid)) => {
                    let (u, v) = coverage::barycentric(uv, centroid);
                    a + (b - a) * u + (c - a) * v
                }
                None => t.position,
            };
            // A ring texel stands for the part of its triangle near an edge another surface
            // may meet: move it a hair inside, so its hemicube is not centred in that
            // surface's plane (half of it would look out of the scene).
            if !t.inside || !position.is_finite() {
                let base = if position.is_finite() {
                    position
                } else {
                    t.position
                };
                position = base + ((a + b + c) / 3.0 - base) * 1e-2;
            }
            Receiver {
                texel: *t,
                position,
            }
        })
        .collect()
}

/// Per receiver: its surface's reflectance, and where the surface has a base-colour texture,
/// that times the texture's mean over the part of the texel on its triangle relative to the
/// image's mean (as the bake's elements, `radiant_radiosity::input`), clamped to [0, 1].
fn receiver_reflectance(
    scene: &Scene,
    footprints: &[[glam::DVec2; 3]],
    receivers: &[Receiver],
) -> Vec<Rgb> {
    use radiant_radiosity::input::{footprint_ratio, texture_pyramids};
    use rayon::prelude::*;
    let surface = |r: &Receiver| {
        let t = scene.triangles.get(r.texel.triangle as usize)?;
        Some((t, scene.surfaces.get(t.surface as usize)?))
    };
    let mut used = vec![false; scene.images.len()];
    for r in receivers {
        if let Some((_, s)) = surface(r)
            && let Some(t) = &s.base_color_texture
            && let Some(u) = used.get_mut(t.image as usize)
        {
            *u = true;
        }
    }
    let pyramids = texture_pyramids(&scene.images, used);
    receivers
        .par_iter()
        .with_min_len(256)
        .map(|r| {
            let Some((tri, s)) = surface(r) else {
                return [0.0; 3];
            };
            let Some(t) = &s.base_color_texture else {
                return s.reflectance;
            };
            let fp = footprints[r.texel.triangle as usize];
            let Some(poly) = coverage::clip_polygon(f64::from(r.texel.x), f64::from(r.texel.y), fp)
            else {
                return s.reflectance;
            };
            // The covered part as a fan of triangles, each's footprint ratio weighed by its area.
            let (mut sum, mut weight) = ([0.0f64; 3], 0.0f64);
            for k in 1..poly.len() - 1 {
                let corners = [poly[0], poly[k], poly[k + 1]];
                let area = 0.5 * (corners[1] - corners[0]).perp_dot(corners[2] - corners[0]);
                if area.is_nan() || area <= 0.0 {
                    continue;
                }
                let bary = corners.map(|c| {
                    let (u, v) = coverage::barycentric(fp, c);
                    [1.0 - u - v, u, v]
                });
                let ratio = footprint_ratio(&pyramids, t, tri, bary);
                for c in 0..3 {
                    sum[c] += area * ratio[c];
                }
                weight += area;
            }
            if weight.is_nan() || weight <= 0.0 {
                return s.reflectance;
            }
            std::array::from_fn(|c| (s.reflectance[c] * sum[c] / weight).clamp(0.0, 1.0))
        })
        .collect()
}

/// An orthonormal `(t, b)` with `t × b = n` (Duff et al. 2017).
fn basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        DVec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// An emissive triangle lit in closed form (local frame).
struct Emitter {
    v: [DVec3; 3],
    n: DVec3,
    emission: Rgb,
}

/// What `emitter` sends to the point `x` facing `n` (local frame), as `H`: its emission times
/// the point-to-triangle form factor times the clear share of [`EMITTER_RAYS`] stratified rays
/// to it, each weighted by its kernel `cos cos / d²` (so a near, half-hidden emitter is not
/// judged by its far part).
fn emitter_light(vis: &dyn Visibility, x: DVec3, n: DVec3, e: &Emitter, seed: u64) -> Rgb {
    let f0 = radiant_radiosity::form_factors::analytic::point_to_triangle(x, n, &e.v, e.n);
    if f0.is_nan() || f0 <= 0.0 {
        return [0.0; 3];
    }
    let from = x + n * 1e-4;
    let side = f64::from(EMITTER_RAYS).sqrt().ceil() as u32;
    let mut rng = radiant_radiosity::rng::Rng::new(seed);
    let (mut clear, mut all) = (0.0f64, 0.0f64);
    for k in 0..side * side {
        let (u, v) = (
            (f64::from(k % side) + rng.f64()) / f64::from(side),
            (f64::from(k / side) + rng.f64()) / f64::from(side),
        );
        let p = radiant_radiosity::form_factors::sample_triangle(&e.v, u, v);
        let d = p - from;
        let (cr, cs) = (n.dot(d), -e.n.dot(d));
        let d2 = d.length_squared();
        if cr <= 0.0 || cs <= 0.0 || d2 <= 0.0 {
            continue;
        }
        let w = cr * cs / (d2 * d2);
        all += w;
        if vis.segment_clear(from.as_vec3(), p.as_vec3()) {
            clear += w;
        }
    }
    if all.is_nan() || all <= 0.0 {
        return [0.0; 3];
    }
    let f = f0 * clear / all;
    e.emission.map(|c| c * f)
}

/// What lights the receivers directly, besides the scene's lights.
struct Direct<'a> {
    /// Emissive triangles lit in closed form (none: the emitters are drawn).
    emitters: &'a [Emitter],
    /// Whether the emitters show their emission in the hemicubes.
    draw_emission: bool,
    /// The alpha masks the shadow rays pass.
    masks: Option<&'a std::sync::Arc<radiant_scene::AlphaMasks>>,
}

/// The receivers as the GPU reads them: frame, lifted centre, texel, material and direct
/// light.
fn gpu_receivers(
    scene: &Scene,
    frame: &Frame,
    receivers: &[Receiver],
    reflectance: &[Rgb],
    baked: &[bool],
    direct: &Direct,
) -> Vec<gpu::GpuReceiver> {
    let Direct {
        emitters,
        draw_emission,
        masks: alpha,
    } = *direct;
    use rayon::prelude::*;
    let local_tris: Vec<[Vec3; 3]> = scene
        .triangles
        .iter()
        .zip(baked)
        .filter(|(_, b)| **b)
        .map(|(t, _)| t.vertices.map(|v| frame.local(v).as_vec3()))
        .collect();
    // The BVH holds the baked triangles only; its ids map back to the scene's for the masks.
    let scene_index: std::sync::Arc<Vec<u32>> = std::sync::Arc::new(
        baked
            .iter()
            .enumerate()
            .filter(|(_, b)| **b)
            .map(|(i, _)| i as u32)
            .collect(),
    );
    let vis = (!scene.lights.is_empty() || !emitters.is_empty()).then(|| match alpha {
        Some(masks) => {
            let (marks, masks) = (std::sync::Arc::clone(masks), std::sync::Arc::clone(masks));
            let (ids, ids2) = (std::sync::Arc::clone(&scene_index), scene_index);
            Bvh::with_filter(
                &local_tris,
                move |t| ids.get(t as usize).is_some_and(|&i| marks.is_masked(i)),
                std::sync::Arc::new(move |t: u32, u: f32, v: f32| {
                    ids2.get(t as usize).is_none_or(|&i| masks.blocks(i, u, v))
                }),
            )
        }
        None => Bvh::new(&local_tris),
    });
    let lights: Vec<(DVec3, &radiant_scene::Light)> = scene
        .lights
        .iter()
        .map(|l| (frame.local(l.position), l))
        .collect();
    receivers
        .par_iter()
        .zip(reflectance)
        .with_min_len(256)
        .map(|(r, rho)| {
            let t = &scene.triangles[r.texel.triangle as usize];
            let [a, b, c] = t.vertices;
            let n = (b - a).cross(c - a).normalize_or_zero();
            let (tt, bb) = basis(n);
            let x = frame.local(r.position);
            let origin = x + n * LIFT;
            let mut direct = [0.0f64; 3];
            if let Some(vis) = &vis {
                for (local, light) in &lights {
                    let (to_light, dist, target) = match light.kind {
                        radiant_scene::LightKind::Directional => {
                            let d = -light.direction;
                            (d, 1.0, x + d * 4.0)
                        }
                        _ => {
                            let d = *local - x;
                            let len = d.length();
                            if len <= 0.0 {
                                continue;
                            }
                            (d / len, len * frame.scale, *local)
                        }
                    };
                    let irr = light.irradiance(to_light, n.dot(to_light), dist);
                    if irr <= 0.0 {
                        continue;
                    }
                    let from = x + n * 1e-4;
                    if !vis.segment_clear(from.as_vec3(), target.as_vec3()) {
                        continue;
                    }
                    for (k, d) in direct.iter_mut().enumerate() {
                        *d += irr * light.color[k] / std::f64::consts::PI;
                    }
                }
            }
            if let Some(vis) = &vis {
                for (i, e) in emitters.iter().enumerate() {
                    let texel = u64::from(r.texel.x) | (u64::from(r.texel.y) << 32);
                    let seed =
                        radiant_radiosity::rng::hash(texel, u64::from(r.texel.page), i as u64);
                    let h = emitter_light(vis, x, n, e, seed);
                    for (d, v) in direct.iter_mut().zip(h) {
                        *d += v;
                    }
                }
            }
            let v4 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32, 0.0];
            let rgb = |c: Rgb| [c[0] as f32, c[1] as f32, c[2] as f32, 0.0];
            let surface = scene.surfaces.get(t.surface as usize);
            // Emitters lit in closed form show only what they reflect.
            let emission = surface
                .filter(|_| draw_emission)
                .map_or([0.0; 3], |s| s.emission);
            gpu::GpuReceiver {
                reflectance: rgb(*rho),
                emission: rgb(emission),
                origin: v4(origin),
                t: v4(tt),
                b: v4(bb),
                n: v4(n),
                direct: [direct[0] as f32, direct[1] as f32, direct[2] as f32, 0.0],
                texel: [r.texel.x, r.texel.y, r.texel.page, 0],
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_basis_is_right_handed_and_orthonormal() {
        for n in [
            DVec3::Z,
            -DVec3::Z,
            DVec3::X,
            DVec3::new(0.3, -0.5, 0.8).normalize(),
        ] {
            let (t, b) = basis(n);
            assert!((t.cross(b) - n).length() < 1e-12, "{n}");
            assert!(t.dot(n).abs() < 1e-12 && b.dot(n).abs() < 1e-12);
        }
    }

    #[test]
    fn the_chebyshev_weights_follow_the_recurrence_and_give_up_when_the_change_grows() {
        // Plain sweeps first; then β from the last two absolute changes (0.5 here, under the
        // largest reflectance 0.8), ω₂ = 1 / (1 − β²/2), ωₖ₊₁ = 1 / (1 − β² ωₖ / 4).
        let mut c = Chebyshev::new(true, 0.8);
        for (done, diff) in [(0, 4.0), (1, 2.0), (2, 1.0)] {
            assert_eq!(c.omega(done), 1.0);
            c.observe(diff, diff / 10.0);
        }
        let w2 = c.omega(3);
        assert!((w2 - 1.0 / (1.0 - 0.125)).abs() < 1e-12, "{w2}");
        c.observe(0.3, 0.03);
        let w3 = c.omega(4);
        assert!((w3 - 1.0 / (1.0 - 0.25 * w2 / 4.0)).abs() < 1e-12, "{w3}");
        // The limit 2 / (1 + √(1 − β²)).
        let mut w = w3;
        for done in 5..60 {
            c.observe(0.01, 0.001);
            w = c.omega(done);
        }
        assert!((w - 2.0 / (1.0 + 0.75f64.sqrt())).abs() < 1e-9, "{w}");
        // β is capped by the largest reflectance.
        let mut capped = Chebyshev::new(true, 0.3);
        for (done, diff) in [(0, 1.0), (1, 0.9), (2, 0.81)] {
            capped.omega(done);
            capped.observe(diff, diff);
        }
        assert!((capped.omega(3) - 1.0 / (1.0 - 0.09 / 2.0)).abs() < 1e-12);
        // Growing three accelerated sweeps running: plain sweeps from then on.
        for (k, change) in [0.2, 0.3, 0.4].into_iter().enumerate() {
            assert!(c.omega(60 + k as u32) > 1.0);
            c.observe(change, change);
        }
        assert_eq!(c.omega(63), 1.0);
        assert_eq!(c.omega(64), 1.0);
        // Without acceleration every weight is 1.
        let mut plain = Chebyshev::new(false, 0.8);
        for done in 0..10 {
            assert_eq!(plain.omega(done), 1.0);
            plain.observe(1.0 / f64::from(done + 1), 0.1);
        }
    }

    #[test]
    fn bad_parameters_are_typed_errors() {
        for p in [
            GatherParams {
                resolution: 7,
                ..Default::default()
            },
            GatherParams {
                resolution: 2048,
                ..Default::default()
            },
            GatherParams {
                texel_density: Some(f64::NAN),
                ..Default::default()
            },
            GatherParams {
                tolerance: 0.0,
                ..Default::default()
            },
            GatherParams {
                page_side: 16,
                ..Default::default()
            },
        ] {
            assert!(matches!(
                check_params(&p),
                Err(GatherError::InvalidSetting { .. })
            ));
        }
        assert!(check_params(&GatherParams::default()).is_ok());
    }

    #[test]
    fn a_scene_without_emitters_is_refused_before_any_gpu_work() {
        let mut scene = radiant_scene::builtin("cornell-box").expect("builtin");
        for s in &mut scene.surfaces {
            s.emission = [0.0; 3];
        }
        scene.sky = None;
        scene.lights.clear();
        assert!(matches!(
            GpuGather::new(&scene, &GatherParams::default()),
            Err(GatherError::NoEmitters)
        ));
    }
}
