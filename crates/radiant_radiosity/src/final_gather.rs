//! A final gather per light-map texel (Christensen's final gather; Lischinski et al. 1993):
//! each texel's light other than the punctual lights' direct part, computed at the texel's own
//! point with its own rays into the solved scene, instead of interpolated from its element.
//!
//! `H` at a point `x` with normal `n` (incident radiance, emissive units: a surface of albedo
//! `a` reflects `a H`) is `1/π ∫ L(ω) cos θ dω`. With cosine-weighted directions that is the
//! mean of the radiance the rays meet:
//!
//! - a ray that meets a surface from its lit side takes the solution's radiosity there (the
//!   smooth field, [`SmoothField::radiosity`]) less its emission: the reflected light, which
//!   includes every bounce and the punctual lights' light as the elements carry it;
//! - a ray that meets the back of a single-sided face (inside closed geometry) takes nothing;
//! - a ray that leaves the scene takes the sky's radiance.
//!
//! Emitters' direct light is sampled on the emitters instead (an emitter the size of a ceiling
//! panel is met by few rays): points on emitting triangles chosen by power, each with a
//! shadow ray, `E cos θx cos θy / (π r²)` over their density. The punctual lights' direct light
//! is not here: [`crate::texel_light`] computes it per texel with its own shadow rays.
//!
//! Directions are stratified (`s × s` strata of the cosine-weighted hemisphere, one jittered
//! ray each) and the emitter samples too, from a generator seeded by the seed and the point,
//! so a gather gives the same bits on any thread count.

use glam::DVec3;
use radiant_scene::{Light, Scene, Sky};
use radiant_visibility::Visibility;

use crate::form_factors::analytic::point_to_triangle;
use crate::mesh::Mesh;
use crate::rng::{Rng, hash};
use crate::smooth::SmoothField;
use crate::system::Rgb;

/// A gathered texel's rays stand for a texel within this share of their harmonic mean
/// distance.
pub const VALID: f64 = 0.5;

/// In a penumbra (an emitter's parts partly hidden), its shadow rays go to parts this many
/// times finer along each edge.
pub const PENUMBRA: u32 = 2;

/// How a final gather samples a texel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GatherParams {
    /// Strata per side of the hemisphere: `strata²` rays per texel.
    pub strata: u32,
    /// Shadow rays per emitting triangle (the centroids of this many equal parts, rounded up
    /// to a square; 0: no emitters' direct light), or points sampled on all of them by power
    /// past `analytic_emitters` triangles.
    pub emitter_samples: u32,
    /// Up to this many emitting triangles, each texel takes each one's exact form factor
    /// (Lambert's contour integral) and shadow rays to its parts; past it, `emitter_samples`
    /// points sampled on them by power.
    pub analytic_emitters: usize,
    /// Seed of the rays.
    pub seed: u64,
    /// The rays' part is averaged over the gathered texels of the same surface within this
    /// many texels, at least `stride` (a `(2r + 1)²` window, normals within 25°), whose
    /// rays' harmonic mean distance is at least twice as far ([`VALID`]: Ward's irradiance
    /// caching): the noise falls as if each texel had shot as many rays as it averages, and
    /// where geometry is near (a contact) the average shrinks to the texels that see it alike.
    pub filter_radius: u32,
    /// Rays are shot at every `stride`-th texel along each axis of the atlas (1: at every
    /// texel), then on lattices twice as fine down to every second texel (after an odd
    /// stride, every texel), at each texel of a finer lattice that none gathered so far stands
    /// for (Ward's irradiance caching: nearer than [`VALID`] of its rays' harmonic mean
    /// distance, on its surface and plane): the open floor keeps the coarsest lattice, a
    /// contact or a chart of a few texels goes down to the finest. The filter spreads them to
    /// the others.
    pub stride: u32,
    /// Gathers at the elements before the texels' ([`regather_elements`]): each pass gives
    /// every element the light its own points gather from the last pass's solution (0: the
    /// solve's light as it is).
    pub element_passes: u32,
    /// Where a ray meets a surface, the punctual lights' direct light there is computed
    /// again with a shadow ray from the point it met ([`FinalGather::with_lights_at_hits`]),
    /// instead of read from the elements' (their nine points' mean, smeared across a shadow
    /// edge and interpolated across their neighbours): the sun's first bounce as sharp as the
    /// gather's rays. False: the solution's light as the field holds it.
    pub lights_at_hits: bool,
}

impl Default for GatherParams {
    fn default() -> Self {
        GatherParams {
            strata: 8,
            emitter_samples: 16,
            analytic_emitters: 64,
            seed: 1,
            filter_radius: 2,
            stride: 2,
            element_passes: 0,
            lights_at_hits: true,
        }
    }
}

/// An emitting input triangle, in the mesh's frame.
#[derive(Clone, Copy, Debug)]
pub struct Emitter {
    /// Its corners.
    pub v: [DVec3; 3],
    /// Its unit normal (front side).
    pub normal: DVec3,
    /// Its area (the mesh's frame).
    pub area: f64,
    /// Its surface's emission.
    pub emission: Rgb,
    /// Whether it emits from both sides.
    pub double_sided: bool,
}

/// What the input triangles of a bake's mesh emit, and which are double-sided: what a gather
/// at a point (the final gather, an irradiance probe) needs to take the emitters' light by
/// light sampling and the rest from the solution.
#[derive(Clone, Debug, Default)]
pub struct Emitters {
    /// Per input triangle of the mesh: its surface's emission.
    pub root_emission: Vec<Rgb>,
    /// Per input triangle of the mesh: whether its surface is double-sided.
    pub double_sided: Vec<bool>,
    /// The emitting triangles of positive, finite power.
    pub list: Vec<Emitter>,
    /// Cumulative power (area × the sum of the emission's channels) of `list`; the last entry
    /// is the total.
    pub cdf: Vec<f64>,
}

impl Emitters {
    /// The emitters of `mesh`, a bake of `scene`'s static part.
    pub fn new(scene: &Scene, mesh: &Mesh) -> Emitters {
        let surface = |root: usize| {
            mesh.root_surface
                .get(root)
                .and_then(|&s| scene.surfaces.get(s as usize))
        };
        let root_emission: Vec<Rgb> = (0..mesh.roots.len())
            .map(|r| surface(r).map_or([0.0; 3], |s| s.emission))
            .collect();
        let double_sided: Vec<bool> = (0..mesh.roots.len())
            .map(|r| surface(r).is_some_and(|s| s.double_sided))
            .collect();
        let (mut list, mut cdf, mut total) = (Vec::new(), Vec::new(), 0.0);
        for (r, &id) in mesh.roots.iter().enumerate() {
            let e = root_emission[r];
            if e.iter().all(|&c| c <= 0.0) {
                continue;
            }
            let v = mesh.nodes[id as usize].v;
            let cross = (v[1] - v[0]).cross(v[2] - v[0]);
            let area = 0.5 * cross.length();
            let power = area * (e[0] + e[1] + e[2]);
            if !(power > 0.0 && power.is_finite()) {
                continue;
            }
            total += power;
            cdf.push(total);
            list.push(Emitter {
                v,
                normal: cross / (2.0 * area),
                area,
                emission: e,
                double_sided: double_sided[r],
            });
        }
        Emitters {
            root_emission,
            double_sided,
            list,
            cdf,
        }
    }

    /// The `j`-th of `m` points sampled on the emitters, stratified over their power: the
    /// emitter, the point, and its density per unit area. `None` when nothing emits.
    pub fn sample(&self, j: u32, m: u32, rng: &mut Rng) -> Option<(&Emitter, DVec3, f64)> {
        let total = *self.cdf.last()?;
        let pick = (f64::from(j) + rng.f64()) / f64::from(m) * total;
        let i = self
            .cdf
            .partition_point(|&c| c <= pick)
            .min(self.cdf.len() - 1);
        let e = &self.list[i];
        let power = self.cdf[i] - if i > 0 { self.cdf[i - 1] } else { 0.0 };
        let (mut u, mut v) = (rng.f64(), rng.f64());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let y = e.v[0] + (e.v[1] - e.v[0]) * u + (e.v[2] - e.v[0]) * v;
        Some((e, y, power / total / e.area))
    }

    /// What a ray from `origin` along unit `d` (the mesh's frame) meets in a solved bake: the
    /// reflected radiance of the solution (`field`) where it meets a surface from its lit side
    /// (the emitters' own light is taken by light sampling instead), the sky's where it leaves
    /// the scene, nothing at the back of a one-sided face; how far it went (infinite when it
    /// left); and whether it met such a back face (inside closed geometry).
    pub fn along(
        &self,
        mesh: &Mesh,
        field: &SmoothField,
        vis: &impl Visibility,
        sky: Option<&Sky>,
        origin: DVec3,
        d: DVec3,
    ) -> (Rgb, f64, bool) {
        let (l, t, inside, _) = self.trace(mesh, field, vis, sky, origin, d);
        (l, t, inside)
    }

    /// [`Self::along`], and where the ray met a surface from its lit side, the element it met
    /// and that face's unit normal toward the ray's origin.
    fn trace(
        &self,
        mesh: &Mesh,
        field: &SmoothField,
        vis: &impl Visibility,
        sky: Option<&Sky>,
        origin: DVec3,
        d: DVec3,
    ) -> (Rgb, f64, bool, Option<(u32, DVec3)>) {
        match vis.closest_hit(origin.as_vec3(), d.as_vec3(), f32::INFINITY) {
            Some(hit) => {
                let (root, t) = (hit.triangle as usize, f64::from(hit.t));
                if root >= mesh.roots.len() {
                    return ([0.0; 3], t, false, None);
                }
                if !hit.front && !self.double_sided[root] {
                    return ([0.0; 3], t, true, None);
                }
                let (leaf, w) =
                    mesh.locate_weights(hit.triangle, f64::from(hit.u), f64::from(hit.v));
                let b = field.radiosity_in(leaf, w);
                let e = self.root_emission[root];
                let normal = mesh.nodes[mesh.roots[root] as usize].normal;
                let normal = if hit.front { normal } else { -normal };
                (
                    std::array::from_fn(|k| (b[k] - e[k]).max(0.0)),
                    t,
                    false,
                    Some((leaf, normal)),
                )
            }
            None => (
                sky.map_or([0.0; 3], |s| s.radiance(d)),
                f64::INFINITY,
                false,
                None,
            ),
        }
    }
}

/// Gathers light at points of a solved bake (see the module).
pub struct FinalGather<'a, V> {
    mesh: &'a Mesh,
    vis: &'a V,
    field: &'a SmoothField,
    params: GatherParams,
    emitters: Emitters,
    sky: Option<Sky>,
    /// The punctual lights (and their positions in the mesh's frame) whose direct light a ray
    /// takes at the point it meets; empty: the field's.
    hit_lights: Vec<(Light, DVec3)>,
}

impl<'a, V: Visibility> FinalGather<'a, V> {
    /// A gather over `mesh` (a bake of `scene`'s static part) whose solution is `field`, with
    /// the rays of `vis` (over `mesh`'s input triangles, in its frame).
    pub fn new(
        scene: &Scene,
        mesh: &'a Mesh,
        field: &'a SmoothField,
        vis: &'a V,
        params: GatherParams,
    ) -> FinalGather<'a, V> {
        FinalGather {
            mesh,
            vis,
            field,
            params,
            emitters: Emitters::new(scene, mesh),
            sky: scene.sky.clone().filter(|s| !s.is_dark()),
            hit_lights: Vec::new(),
        }
    }

    /// The same gather, but where a ray meets a surface it takes `scene`'s punctual lights'
    /// direct light at that point, with a shadow ray each, on top of the field, so the field
    /// must be the solution's light **without** the elements' direct part (`field.minus` of
    /// [`crate::texel_light::TexelLights::element_direct`]): `E + ρ (H_rest + D(p) / π)` at the
    /// point `p` met, ρ its element's reflectance.
    pub fn with_lights_at_hits(mut self, scene: &Scene) -> Self {
        let frame = self.mesh.frame;
        self.hit_lights = (scene.lights.iter())
            .filter(|l| l.intensity > 0.0)
            .map(|l| (l.clone(), frame.to_local(l.position)))
            .collect();
        self
    }

    /// `H` at `x` (the mesh's frame) on a surface of unit normal `n`, from the solution, the
    /// emitters and the sky (see the module); `key` seeds its rays.
    pub fn gather(&self, x: DVec3, n: DVec3, key: u64) -> Rgb {
        let (exact, rays) = self.gather_parts(x, n, key);
        std::array::from_fn(|k| exact[k] + rays[k])
    }

    /// [`Self::gather`] in two parts: the emitters' direct light (exact where unoccluded) and
    /// the rays' mean (noisy: what a filter may smooth).
    pub fn gather_parts(&self, x: DVec3, n: DVec3, key: u64) -> (Rgb, Rgb) {
        (self.emitted(x, n, key), self.reflected(x, n, key).0)
    }

    /// The emitters' direct `H` at `x` (normal `n`); `key` seeds its samples.
    pub fn emitted(&self, x: DVec3, n: DVec3, key: u64) -> Rgb {
        let mut rng = Rng::new(hash(self.params.seed, key, 0x656d_6974));
        self.emitters_direct(x, n, &mut rng)
    }

    /// The reflected light and the sky's at `x` (normal `n`): the mean of what `strata²`
    /// cosine-weighted rays meet; `key` seeds them. Also the harmonic mean of the rays' hit
    /// distances (infinite when none hits; the mesh's frame): how far the value holds (Ward's
    /// irradiance caching), small where geometry is near, as at a contact.
    pub fn reflected(&self, x: DVec3, n: DVec3, key: u64) -> (Rgb, f64) {
        let mut rng = Rng::new(hash(self.params.seed, key, 0x6761_7468));
        let (t, b) = basis(n);
        // Rays start a little above the surface, as the bake's own rays do.
        let origin = x + n * 1e-5;
        let s = self.params.strata.max(1);
        let (mut sum, mut inverse) = ([0.0; 3], 0.0);
        for i in 0..s * s {
            let (a, c) = (
                (f64::from(i % s) + rng.f64()) / f64::from(s),
                (f64::from(i / s) + rng.f64()) / f64::from(s),
            );
            // Cosine-weighted (Malley): a uniform point on the disc, lifted.
            let (r, phi) = (a.sqrt(), std::f64::consts::TAU * c);
            let d = t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - a).max(0.0).sqrt();
            let (l, t) = self.radiance(origin, d);
            for k in 0..3 {
                sum[k] += l[k];
            }
            inverse += 1.0 / t.max(1e-9);
        }
        let rays = f64::from(s * s);
        (sum.map(|v| v / rays), rays / inverse)
    }

    /// The reflected radiance (and the sky's) a ray from `origin` along unit `d` meets.
    /// And how far it went (infinite when it left the scene).
    fn radiance(&self, origin: DVec3, d: DVec3) -> (Rgb, f64) {
        if !self.hit_lights.is_empty() {
            return self.radiance_lit(origin, d);
        }
        let (l, t, _) = self.emitters.along(
            self.mesh,
            self.field,
            self.vis,
            self.sky.as_ref(),
            origin,
            d,
        );
        (l, t)
    }

    /// [`Self::radiance`] with the punctual lights' direct light taken where the ray lands
    /// (see [`Self::with_lights_at_hits`]).
    fn radiance_lit(&self, origin: DVec3, d: DVec3) -> (Rgb, f64) {
        let (mut l, t, _, met) = self.emitters.trace(
            self.mesh,
            self.field,
            self.vis,
            self.sky.as_ref(),
            origin,
            d,
        );
        let Some((leaf, normal)) = met else {
            return (l, t);
        };
        let rho = self.field.reflectance(leaf);
        if rho.iter().any(|&r| r > 0.0) {
            // Just off the surface met, on the side the ray came from.
            let p = origin + d * t + normal * 1e-5;
            let mut direct = [0.0; 3];
            for (light, local) in &self.hit_lights {
                crate::lights::light_one(
                    self.mesh.frame,
                    light,
                    *local,
                    (p, normal),
                    &mut direct,
                    self.vis,
                );
            }
            for c in 0..3 {
                l[c] += rho[c] * direct[c] / std::f64::consts::PI;
            }
        }
        (l, t)
    }

    /// The emitters' direct `H` at `x`: with few emitting triangles, each one's exact
    /// unoccluded form factor (Lambert's contour integral) times the share of it that is
    /// visible, from shadow rays to the centroids of `k²` equal parts weighted by the kernel;
    /// with many, points sampled on them by power.
    fn emitters_direct(&self, x: DVec3, n: DVec3, rng: &mut Rng) -> Rgb {
        let m = self.params.emitter_samples;
        if self.emitters.list.is_empty() || m == 0 {
            return [0.0; 3];
        }
        if self.emitters.list.len() > self.params.analytic_emitters {
            return self.emitters_sampled(x, n, rng);
        }
        let from = (x + n * 1e-5).as_vec3();
        let k = f64::from(m).sqrt().ceil().max(1.0) as u32;
        let mut sum = [0.0; 3];
        for e in &self.emitters.list {
            let mut f = point_to_triangle(x, n, &e.v, e.normal);
            if e.double_sided {
                f += point_to_triangle(x, n, &[e.v[0], e.v[2], e.v[1]], -e.normal);
            }
            if f.is_nan() || f <= 0.0 {
                continue;
            }
            // The kernel-weighted share of the parts' centroids a shadow ray reaches; where
            // they disagree (a penumbra), again on parts PENUMBRA² times finer.
            let share = |k: u32| -> (f64, f64, bool, bool) {
                let (mut seen, mut all, mut some, mut none) = (0.0, 0.0, false, false);
                for (b1, b2) in crate::points::lattice(k) {
                    let y = e.v[0] * (1.0 - b1 - b2) + e.v[1] * b1 + e.v[2] * b2;
                    let to = y - x;
                    let r2 = to.length_squared();
                    let cos_x = n.dot(to);
                    let cos_y = e.normal.dot(to);
                    let cos_y = if e.double_sided { cos_y.abs() } else { -cos_y };
                    if r2.is_nan() || r2 <= 0.0 || cos_x <= 0.0 || cos_y <= 0.0 {
                        continue;
                    }
                    let w = cos_x * cos_y / (r2 * r2);
                    all += w;
                    if self.vis.segment_clear(from, y.as_vec3()) {
                        seen += w;
                        some = true;
                    } else {
                        none = true;
                    }
                }
                (seen, all, some, none)
            };
            let (mut seen, mut all, some, none) = share(k);
            if some && none {
                (seen, all, _, _) = share(k * PENUMBRA);
            }
            // All parts behind the horizon (a sliver the contour sees): take it as seen.
            let visible = if all > 0.0 { seen / all } else { 1.0 };
            for c in 0..3 {
                sum[c] += e.emission[c] * f * visible;
            }
        }
        sum
    }

    /// The emitters' direct `H` at `x` from points sampled on them by power.
    fn emitters_sampled(&self, x: DVec3, n: DVec3, rng: &mut Rng) -> Rgb {
        let m = self.params.emitter_samples;
        let mut sum = [0.0; 3];
        for j in 0..m {
            let Some((e, y, pdf)) = self.emitters.sample(j, m, rng) else {
                return [0.0; 3];
            };
            let to = y - x;
            let r2 = to.length_squared();
            if r2.is_nan() || r2 <= 0.0 {
                continue;
            }
            let w = to / r2.sqrt();
            let cos_x = n.dot(w);
            let cos_y = if e.double_sided {
                e.normal.dot(w).abs()
            } else {
                -e.normal.dot(w)
            };
            if cos_x <= 0.0 || cos_y <= 0.0 {
                continue;
            }
            if !self
                .vis
                .segment_clear((x + n * 1e-5).as_vec3(), y.as_vec3())
            {
                continue;
            }
            let g = cos_x * cos_y / (std::f64::consts::PI * r2) / pdf;
            for k in 0..3 {
                sum[k] += e.emission[k] * g;
            }
        }
        sum.map(|s| s / f64::from(m))
    }
}

impl<V: Visibility> FinalGather<'_, V> {
    /// Whether `x` (normal `n`) lies inside or under other geometry, as the light map's
    /// texels are tested ([`crate::texel_light`]).
    fn buried(&self, x: DVec3, n: DVec3) -> bool {
        crate::texel_light::buried(self.vis, &self.emitters.double_sided, x, n)
    }
}

/// A final gather at the elements: `passes` times, every element of `mesh` (with reflectance
/// and not enclosed) takes `B = E + ρ H`, `H` the punctual lights' direct part the bake gave
/// it (nine shadow rays per light, [`crate::lights::direct_irradiance`]) plus the mean of
/// what [`FinalGather::gather`] finds at the open ones of its four quarter centroids in the last pass's solution (the
/// first: `radiosity`). The solve's sources carry the error of elements that span what
/// covers part of them; gathered at their own points they pass on what those points receive.
pub fn regather_elements<V: Visibility>(
    scene: &Scene,
    mesh: &Mesh,
    system: &crate::system::System,
    radiosity: &[Rgb],
    vis: &V,
    params: GatherParams,
    passes: u32,
) -> Vec<Rgb> {
    use rayon::prelude::*;
    let lights: Vec<radiant_scene::Light> = (scene.lights.iter())
        .filter(|l| l.intensity > 0.0)
        .cloned()
        .collect();
    let direct = if lights.is_empty() {
        Vec::new()
    } else {
        crate::lights::direct_irradiance(mesh, &lights, vis)
    };
    let emission = crate::smooth::element_emission(mesh, &scene.surfaces);
    let mut b = radiosity.to_vec();
    for pass in 0..passes {
        let field = SmoothField::new(mesh, system, &scene.surfaces, &b);
        let g = FinalGather::new(scene, mesh, &field, vis, params);
        b = (0..mesh.leaves.len())
            .into_par_iter()
            .map(|i| {
                let old = b.get(i).copied().unwrap_or([0.0; 3]);
                let rho = system.rho.get(i).copied().unwrap_or([0.0; 3]);
                if rho.iter().all(|&r| r <= 0.0) || system.weight.get(i).is_some_and(|&w| w <= 0.0)
                {
                    return old;
                }
                let node = mesh.leaf_node(i as u32);
                let (v, n) = (node.v, node.normal);
                let (mut h, mut k) = ([0.0; 3], 0.0);
                for (j, (b1, b2)) in crate::points::lattice(2).enumerate() {
                    let x = v[0] * (1.0 - b1 - b2) + v[1] * b1 + v[2] * b2;
                    if g.buried(x, n) {
                        continue;
                    }
                    let key = hash(i as u64, u64::from(pass), j as u64 + 0x656c);
                    let got = g.gather(x, n, key);
                    for c in 0..3 {
                        h[c] += got[c];
                    }
                    k += 1.0;
                }
                if k == 0.0 {
                    return old;
                }
                let d = direct.get(i).copied().unwrap_or([0.0; 3]);
                let e = emission.get(i).copied().unwrap_or([0.0; 3]);
                std::array::from_fn(|c| e[c] + rho[c] * (h[c] / k + d[c] / std::f64::consts::PI))
            })
            .collect();
    }
    b
}

/// Two unit tangents completing unit `n` to an orthonormal basis (Duff et al. 2017).
fn basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        DVec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}
