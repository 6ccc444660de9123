//! Irradiance probes from a radiosity solution: the light a dynamic mesh receives where the
//! bake has no light map (a character, a prop picked up, a door).
//!
//! A probe at a point `x` holds what the irradiance there needs for any normal `n`, in three
//! parts, each as exact as its light allows:
//!
//! - **Punctual lights** (sun, points, spots) are deltas: a second-order spherical harmonic
//!   would smear a sun's `E⊥ max(0, n·l)` by up to 9 % of `E⊥` (Ramamoorthi and Hanrahan's
//!   clamped cosine). The probe keeps whether each light is visible from `x` (one shadow ray),
//!   and the irradiance is evaluated exactly for the normal asked.
//! - **Emitting surfaces**, when there are at most [`ProbeParams::analytic_emitters`] emitting
//!   triangles (a Cornell box's panel, a few lamps): the share of each one visible from `x`
//!   (shadow rays to the centroids of equal parts, weighted by solid angle), and the exact
//!   unoccluded form factor for the normal asked (Lambert's contour integral) times that
//!   share. With more, they go into the harmonics (sampled by power).
//! - **The rest** (the solution's reflected light, every bounce, and the sky): the incident
//!   radiance projected on real spherical harmonics of order 4 (25 coefficients per channel,
//!   [`harmonics`]) from stratified rays over the whole sphere into the solved scene (the
//!   smooth field, as the final gather reads it). Indirect light is smooth over directions,
//!   where low orders hold (Ramamoorthi and Hanrahan's irradiance environment maps); order 4
//!   and not 2 for the normals that face a nearly black part of the sphere, where order 2's
//!   truncation reads as light (Cornell box: 1.33 → 0.80 % mean, see the benchmarks).
//!
//! Units: `H`, the light map's quantity (incident radiance, emissive units: a surface of albedo
//! `a` there reflects `a H`); the irradiance is `E = π H` (what `radiant reference --probes`
//! path-traces). A probe inside closed geometry meets back faces: [`Probe::inside`] tells it
//! ([`Probe::backfaces`], the share of its rays that met one), and it holds no light.
//!
//! Rays are seeded by the parameters' seed and the probe's key: the same bits on any thread
//! count. Positions are in the bake mesh's frame ([`radiant_radiosity::mesh::Frame`]).

use std::f64::consts::PI;

use glam::DVec3;
use radiant_radiosity::final_gather::{Emitter, Emitters};
use radiant_radiosity::form_factors::analytic::point_to_triangle;
use radiant_radiosity::mesh::Mesh;
use radiant_radiosity::rng::{Rng, hash};
use radiant_radiosity::smooth::SmoothField;
use radiant_radiosity::system::Rgb;
use radiant_scene::{Light, LightKind, Scene, Sky};
use radiant_visibility::Visibility;

pub mod harmonics;
mod volume;
pub use volume::{ProbeVolume, VolumeParams};

/// How probes are baked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProbeParams {
    /// Strata of the sphere's rays: `strata × 2·strata` (in cos θ and φ), one jittered ray each.
    /// The default 32 (2048 rays): on the Cornell box's free space, 24 probes of six normals
    /// against the path tracer (2^16 paths each), 16 gave 1.60 % mean and 8.1 % worst, 24 0.79
    /// and 4.2 %, 32 0.76 and 3.4 %, 48 0.73 and 3.1 % (the ray noise of dark directions).
    pub strata: u32,
    /// Up to this many emitting triangles, each is kept apart and its direct light evaluated
    /// exactly for the normal asked; past it, all go into the harmonics.
    pub analytic_emitters: usize,
    /// Emitters' shadow rays: the centroids of at least this many equal parts per emitting
    /// triangle (more where the probe is near it), or this many points sampled by power past
    /// `analytic_emitters`.
    pub emitter_samples: u32,
    /// Seed of every ray.
    pub seed: u64,
}

impl Default for ProbeParams {
    fn default() -> Self {
        ProbeParams {
            strata: 32,
            analytic_emitters: 64,
            emitter_samples: 16,
            seed: 1,
        }
    }
}

/// A probe: see the module.
#[derive(Clone, Debug, PartialEq)]
pub struct Probe {
    /// Where it is (the mesh's frame).
    pub position: DVec3,
    /// The incident radiance other than the lights and the emitters kept apart, as order-4
    /// harmonics per channel ([`harmonics`]; emissive units).
    pub sh: [harmonics::Coeffs; 3],
    /// Per punctual light of the scene, in order: whether it reaches the probe (1 or 0; a
    /// volume's interpolation blends them into soft shadows).
    pub lights: Vec<f32>,
    /// Per emitter kept apart, in order: the share of it visible from the probe.
    pub emitters: Vec<f32>,
    /// The share of the probe's rays that met the back of a one-sided face.
    pub backfaces: f64,
}

impl Probe {
    /// Whether the probe lies inside closed geometry (most of its rays met back faces): it
    /// holds no light, and a volume leaves it out of its interpolation.
    pub fn inside(&self) -> bool {
        self.backfaces > 0.5
    }
}

/// What a probe's light is evaluated with at a point, whatever the probe or blend of probes:
/// the punctual lights and the emitters kept apart, and the mesh's frame they are placed in.
/// A [`ProbeVolume`] owns one, so that it is read without the bake it came from.
#[derive(Clone, Debug)]
pub struct Lighting {
    frame: radiant_radiosity::mesh::Frame,
    lights: Vec<Light>,
    emitters: Vec<Emitter>,
    /// [`ProbeParams::emitter_samples`].
    emitter_samples: u32,
}

impl Lighting {
    /// `H` at `x` (the mesh's frame) for unit normal `n` from harmonics `sh` (clamped at 0),
    /// and the lights' and kept-apart emitters' light at `x` exactly, times their
    /// visibilities `lights` and `emitters` (in order; blended where several probes meet).
    pub fn evaluate(
        &self,
        x: DVec3,
        n: DVec3,
        sh: &[harmonics::Coeffs; 3],
        lights: &[f64],
        emitters: &[f64],
    ) -> Rgb {
        let mut h = sh_h(sh, n);
        for (l, &seen) in self.lights.iter().zip(lights) {
            if seen <= 0.0 {
                continue;
            }
            let Some((to_light, dist_world, _)) = self.toward(l, x) else {
                continue;
            };
            let irr = l.irradiance(to_light, n.dot(to_light), dist_world) * seen;
            for (h, colour) in h.iter_mut().zip(l.color) {
                *h += irr * colour / PI;
            }
        }
        for (e, &share) in self.emitters.iter().zip(emitters) {
            if share <= 0.0 {
                continue;
            }
            let mut f = point_to_triangle(x, n, &e.v, e.normal);
            if e.double_sided {
                f += point_to_triangle(x, n, &[e.v[0], e.v[2], e.v[1]], -e.normal);
            }
            if f.is_nan() || f <= 0.0 {
                continue;
            }
            for (h, emission) in h.iter_mut().zip(e.emission) {
                *h += emission * f * share;
            }
        }
        h
    }

    /// How many punctual lights and kept-apart emitters a probe holds visibilities for.
    pub fn counts(&self) -> (usize, usize) {
        (self.lights.len(), self.emitters.len())
    }

    /// The share of emitter `e`'s solid angle seen from `x` that no geometry hides: shadow rays
    /// to the centroids of `k²` equal parts, each weighted by its solid angle, `k` at least
    /// `√emitter_samples` and finer where `x` is near (a part no wider than a quarter of its
    /// distance). 0 where `x` is behind a one-sided emitter.
    fn visible_share(&self, e: &Emitter, x: DVec3, vis: &dyn Visibility) -> f64 {
        let centre = (e.v[0] + e.v[1] + e.v[2]) / 3.0;
        let near = (centre - x).length().max(1e-9);
        let base = f64::from(self.emitter_samples).sqrt().ceil().max(1.0);
        let k = base.max(4.0 * e.area.sqrt() / near).min(64.0) as u32;
        let (mut seen, mut all) = (0.0, 0.0);
        for (b1, b2) in radiant_radiosity::points::lattice(k) {
            let y = e.v[0] * (1.0 - b1 - b2) + e.v[1] * b1 + e.v[2] * b2;
            let to = y - x;
            let r2 = to.length_squared();
            let cos_y = -e.normal.dot(to);
            let cos_y = if e.double_sided { cos_y.abs() } else { cos_y };
            if r2.is_nan() || r2 <= 0.0 || cos_y <= 0.0 {
                continue;
            }
            let w = cos_y / (r2 * r2.sqrt());
            all += w;
            if vis.segment_clear(x.as_vec3(), y.as_vec3()) {
                seen += w;
            }
        }
        if all > 0.0 { seen / all } else { 0.0 }
    }

    /// The visibility of each light and each kept-apart emitter from `x` itself (shadow rays of
    /// `vis`, in order): what a probe holds for its own place, and what a point read with the
    /// scene's rays takes instead of its probes' blend (a sun's shadow edge is sharp where the
    /// probes are metres apart).
    pub fn visibility_at(&self, x: DVec3, vis: &dyn Visibility) -> (Vec<f64>, Vec<f64>) {
        let lights = self
            .lights
            .iter()
            .map(|l| match self.toward(l, x) {
                Some((_, _, target)) if vis.segment_clear(x.as_vec3(), target.as_vec3()) => 1.0,
                _ => 0.0,
            })
            .collect();
        let emitters = self
            .emitters
            .iter()
            .map(|e| self.visible_share(e, x, vis))
            .collect();
        (lights, emitters)
    }

    /// The mesh's frame (world → the probes' positions).
    pub fn frame(&self) -> radiant_radiosity::mesh::Frame {
        self.frame
    }

    /// Toward punctual light `l` from `x` (the mesh's frame): the unit direction, the distance
    /// in world units (1 for a directional light), and where its shadow ray ends.
    fn toward(&self, l: &Light, x: DVec3) -> Option<(DVec3, f64, DVec3)> {
        match l.kind {
            LightKind::Directional => {
                let d = (-l.direction).try_normalize()?;
                Some((d, 1.0, x + d * 4.0))
            }
            _ => {
                let local = self.frame.to_local(l.position);
                let to = local - x;
                let len = to.length();
                (len > 0.0).then(|| (to / len, len * self.frame.scale, local))
            }
        }
    }
}

/// Bakes probes from a solved bake and evaluates them (see the module).
pub struct ProbeBaker<'a, V> {
    pub(crate) mesh: &'a Mesh,
    field: &'a SmoothField,
    pub(crate) vis: &'a V,
    params: ProbeParams,
    pub(crate) lighting: Lighting,
    /// Every emitter (the kept-apart ones are `lighting`'s too, when `apart`).
    emitters: Emitters,
    /// Whether the emitters are kept apart (else they go into the harmonics).
    apart: bool,
    sky: Option<Sky>,
}

impl<'a, V: Visibility> ProbeBaker<'a, V> {
    /// A baker over `mesh` (a bake of `scene`'s static part) whose solution is `field`, with the
    /// rays of `vis` (over `mesh`'s input triangles, in its frame).
    pub fn new(
        scene: &Scene,
        mesh: &'a Mesh,
        field: &'a SmoothField,
        vis: &'a V,
        params: ProbeParams,
    ) -> ProbeBaker<'a, V> {
        let emitters = Emitters::new(scene, mesh);
        let apart = emitters.list.len() <= params.analytic_emitters;
        let lighting = Lighting {
            frame: mesh.frame,
            lights: scene.lights.clone(),
            emitters: if apart {
                emitters.list.clone()
            } else {
                Vec::new()
            },
            emitter_samples: params.emitter_samples,
        };
        ProbeBaker {
            mesh,
            field,
            vis,
            params,
            lighting,
            emitters,
            apart,
            sky: scene.sky.clone().filter(|s| !s.is_dark()),
        }
    }

    /// A probe at `x` (the mesh's frame); `key` seeds its rays.
    pub fn bake(&self, x: DVec3, key: u64) -> Probe {
        let mut rng = Rng::new(hash(self.params.seed, key, 0x7072_6f62));
        let mut sh = [[0.0; harmonics::COUNT]; 3];
        let s = self.params.strata.max(1);
        let rays = 2 * s * s;
        let mut back = 0u32;
        for i in 0..rays {
            let (a, b) = (
                (f64::from(i % s) + rng.f64()) / f64::from(s),
                (f64::from(i / s) + rng.f64()) / f64::from(2 * s),
            );
            let z = 1.0 - 2.0 * a;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = std::f64::consts::TAU * b;
            let d = DVec3::new(r * phi.cos(), r * phi.sin(), z);
            let (l, backface) = self.radiance(x, d);
            back += u32::from(backface);
            add(&mut sh, d, l, 4.0 * PI / f64::from(rays));
        }
        let backfaces = f64::from(back) / f64::from(rays);
        let (lights, emitters) = self.lighting.visibility_at(x, self.vis);
        let lights = lights.into_iter().map(|v| v as f32).collect();
        let emitters = if self.apart {
            emitters.into_iter().map(|v| v as f32).collect()
        } else {
            self.emitters_into(&mut sh, x, &mut rng);
            Vec::new()
        };
        Probe {
            position: x,
            sh,
            lights,
            emitters,
            backfaces,
        }
    }

    /// `H` (incident radiance, emissive units; irradiance over π) that `probe` gives a surface
    /// at the probe with unit normal `n`: the harmonics' irradiance (clamped at 0), the visible
    /// lights' and the kept-apart emitters' exactly.
    pub fn h(&self, probe: &Probe, n: DVec3) -> Rgb {
        let lights: Vec<f64> = probe.lights.iter().map(|&v| f64::from(v)).collect();
        let emitters: Vec<f64> = probe.emitters.iter().map(|&v| f64::from(v)).collect();
        self.lighting
            .evaluate(probe.position, n, &probe.sh, &lights, &emitters)
    }

    /// The irradiance `E = π H` (W/m² in the scene's emission units) for normal `n`.
    pub fn irradiance(&self, probe: &Probe, n: DVec3) -> Rgb {
        self.h(probe, n).map(|v| v * PI)
    }

    /// The radiance a ray from `x` along unit `d` meets, other than the emitters' own light
    /// (kept apart or sampled by power), and whether it met the back of a one-sided face.
    fn radiance(&self, x: DVec3, d: DVec3) -> (Rgb, bool) {
        let (l, _, back) =
            (self.emitters).along(self.mesh, self.field, self.vis, self.sky.as_ref(), x, d);
        (l, back)
    }

    /// The emitters' radiance into `sh` from `emitter_samples` points sampled by power, each
    /// with a shadow ray.
    fn emitters_into(&self, sh: &mut [harmonics::Coeffs; 3], x: DVec3, rng: &mut Rng) {
        let m = self.params.emitter_samples.max(1);
        for j in 0..m {
            let Some((e, y, pdf)) = self.emitters.sample(j, m, rng) else {
                return;
            };
            let to = y - x;
            let r2 = to.length_squared();
            let cos_y = -e.normal.dot(to) / r2.sqrt();
            let cos_y = if e.double_sided { cos_y.abs() } else { cos_y };
            if r2.is_nan() || r2 <= 0.0 || cos_y <= 0.0 {
                continue;
            }
            if !self.vis.segment_clear(x.as_vec3(), y.as_vec3()) {
                continue;
            }
            // The point's solid angle over its density, per sample.
            let weight = cos_y / r2 / pdf / f64::from(m);
            add(sh, to / r2.sqrt(), e.emission, weight);
        }
    }
}

/// What probes read from a finished bake: its smooth field and its ray tracer (the bake's own,
/// alpha masks included), built once.
pub struct Solved {
    /// The solution's radiosity, smooth across elements (what the final gather reads).
    pub field: SmoothField,
    /// The bake's rays, over its mesh's input triangles in the mesh's frame.
    pub vis: radiant_visibility::Bvh,
}

impl Solved {
    /// From a bake of `scene` (`result`).
    pub fn new(scene: &Scene, result: &radiant_radiosity::BakeResult) -> Solved {
        use radiant_radiosity::input;
        let masks = input::masks(&input::static_scene(scene));
        Solved {
            field: SmoothField::new(
                &result.mesh,
                &result.system,
                &scene.surfaces,
                &result.radiosity,
            ),
            vis: input::visibility(&result.mesh, masks.as_ref()),
        }
    }

    /// A baker over this solution of `scene`, whose mesh is `mesh`.
    pub fn baker<'a>(
        &'a self,
        scene: &Scene,
        mesh: &'a Mesh,
        params: ProbeParams,
    ) -> ProbeBaker<'a, radiant_visibility::Bvh> {
        ProbeBaker::new(scene, mesh, &self.field, &self.vis, params)
    }
}

impl<V: Visibility> ProbeBaker<'_, V> {
    /// [`ProbeBaker::bake`] at `p` in scene (world) units.
    pub fn bake_world(&self, p: DVec3, key: u64) -> Probe {
        self.bake(self.mesh.frame.to_local(p), key)
    }
}

/// `H` for unit normal `n` from radiance harmonics `sh`: the irradiance over π, clamped at 0
/// (a truncated series can ring below it where the light is sharp).
pub(crate) fn sh_h(coeffs: &[harmonics::Coeffs; 3], n: DVec3) -> Rgb {
    std::array::from_fn(|k| harmonics::irradiance(&coeffs[k], n).max(0.0) / PI)
}

/// Adds radiance `l` from unit direction `d`, times `weight` (a solid angle), to `sh`.
fn add(coeffs: &mut [harmonics::Coeffs; 3], d: DVec3, l: Rgb, weight: f64) {
    let y = harmonics::basis(d);
    for (c, l) in coeffs.iter_mut().zip(l) {
        if l == 0.0 {
            continue;
        }
        for (c, y) in c.iter_mut().zip(y) {
            *c += l * weight * y;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The harmonics of radiance `l(ω)` by a fine midpoint quadrature over (cos θ, φ).
    fn project(l: impl Fn(DVec3) -> Rgb) -> [harmonics::Coeffs; 3] {
        let mut sh = [[0.0; harmonics::COUNT]; 3];
        let n = 64;
        for i in 0..n {
            for j in 0..2 * n {
                let z = 1.0 - 2.0 * (f64::from(i) + 0.5) / f64::from(n);
                let r = (1.0 - z * z).sqrt();
                let phi = std::f64::consts::TAU * (f64::from(j) + 0.5) / f64::from(2 * n);
                let d = DVec3::new(r * phi.cos(), r * phi.sin(), z);
                add(&mut sh, d, l(d), 4.0 * PI / f64::from(2 * n * n));
            }
        }
        sh
    }

    /// Constant radiance over the sphere: irradiance π L for every normal (to the midpoint
    /// quadrature's error).
    #[test]
    fn uniform_radiance_gives_pi_l_for_every_normal() {
        let sh = project(|_| [1.0, 0.5, 0.0]);
        for d in [DVec3::X, DVec3::NEG_Y, DVec3::new(0.6, 0.0, 0.8)] {
            let e = sh_h(&sh, d).map(|h| h * PI);
            assert!((e[0] - PI).abs() < 1e-3, "{d}: {e:?}");
            assert!((e[1] - 0.5 * PI).abs() < 1e-3, "{d}: {e:?}");
        }
    }

    /// Radiance `1 + z` (a linear gradient, inside order 2): irradiance `π + (2π/3)·n_z`.
    #[test]
    fn a_linear_gradient_is_exact_in_order_two() {
        let sh = project(|d| [1.0 + d.z; 3]);
        for d in [DVec3::Z, DVec3::NEG_Z, DVec3::X, DVec3::new(0.0, 0.6, 0.8)] {
            let e = sh_h(&sh, d)[0] * PI;
            let want = PI + 2.0 * PI / 3.0 * d.z;
            assert!((e - want).abs() < 1e-3, "{d}: {e} vs {want}");
        }
    }
}
