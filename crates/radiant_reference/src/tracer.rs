//! The path tracer: one estimate of reflected radiance at a surface point per call.
//!
//! The scene is moved into a local frame (centred, scaled into the unit sphere) so that the
//! `f32` BVH of `radiant_visibility` loses nothing at far-off origins or extreme scales; shading
//! runs in `f64`. Surfaces are one-sided and diffuse, as in the bake: a ray that meets a
//! triangle's back is absorbed, emitters emit from their front.
//!
//! Each vertex of a path gathers light three ways:
//! - punctual lights, deterministically with a shadow ray (the bake's formulas, KHR units);
//! - emissive triangles, sampled by power (area × emitted radiance) with a shadow ray;
//! - the next bounce, cosine-sampled, which also collects emission it hits.
//!
//! The last two are combined by multiple importance sampling (power heuristic), so neither a
//! small bright emitter nor a large dim one is noisy. Paths end by Russian roulette on their
//! throughput, so depth is unbounded and the estimate unbiased.

use std::f64::consts::PI;

use std::sync::Arc;

use glam::{DVec3, Vec2};
use radiant_scene::texture::barycentric;
use radiant_scene::{AlphaMasks, Image, Light, LightKind, Scene, Sky, TextureRef};
use radiant_visibility::{Bvh, Visibility};

use crate::ReferenceError;
use crate::rng::Rng;

/// How far a ray's origin is moved off its surface, in the local frame (the scene fits the
/// unit sphere): 1e-5 of the scene's radius.
const OFFSET: f64 = 1e-5;
/// Bounces before Russian roulette may end a path.
const RR_DEPTH: u32 = 3;
/// Length of a shadow segment towards a directional light: leaves the unit sphere from inside.
const SUN_SEGMENT: f64 = 3.0;

#[derive(Clone, Copy, Debug)]
pub(crate) struct Tri {
    pub(crate) v0: DVec3,
    pub(crate) e1: DVec3,
    pub(crate) e2: DVec3,
    /// Unit normal of the front (counter-clockwise) side.
    pub(crate) n: DVec3,
    /// Area in the local frame.
    pub(crate) area: f64,
    pub(crate) surface: u32,
    /// The scene triangle's two UV sets.
    pub(crate) uv: [[Vec2; 3]; 2],
}

impl Tri {
    /// A uniformly distributed point, from two uniform numbers.
    #[inline]
    pub(crate) fn point(&self, r1: f64, r2: f64) -> DVec3 {
        let s = r1.sqrt();
        self.v0 + self.e1 * (s * (1.0 - r2)) + self.e2 * (s * r2)
    }
}

/// Scene units ↔ the local frame.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Frame {
    pub(crate) center: DVec3,
    /// Scene units per local unit.
    pub(crate) scale: f64,
}

impl Frame {
    pub(crate) fn to_local(self, p: DVec3) -> DVec3 {
        (p - self.center) / self.scale
    }
}

#[derive(Clone, Debug)]
pub(crate) struct Material {
    /// Mean reflectance and emission (over the whole texture where there is one).
    pub(crate) rho: [f64; 3],
    pub(crate) emission: [f64; 3],
    /// Textures modulate them: at a point, the texel over the texture's mean.
    pub(crate) rho_texture: Option<(TextureRef, [f64; 4])>,
    pub(crate) emission_texture: Option<(TextureRef, [f64; 4])>,
}

/// What a ray found.
pub(crate) enum Found {
    /// A front face (or a double-sided twin's): the triangle and the point.
    Surface(u32, DVec3),
    /// A back face, which absorbs.
    Absorbed,
    /// Nothing: the ray left the scene (and sees the sky, if any).
    Escaped,
}

/// A punctual light in the local frame.
#[derive(Clone, Debug)]
struct LocalLight {
    light: Light,
    position: DVec3,
}

/// A cumulative distribution over weights; `sample` returns an index with probability
/// proportional to its weight.
#[derive(Clone, Debug, Default)]
pub(crate) struct Cdf {
    cum: Vec<f64>,
}

impl Cdf {
    pub(crate) fn new(weights: impl Iterator<Item = f64>) -> Cdf {
        let mut acc = 0.0;
        let cum = weights
            .map(|w| {
                acc += w;
                acc
            })
            .collect();
        Cdf { cum }
    }
    pub(crate) fn total(&self) -> f64 {
        self.cum.last().copied().unwrap_or(0.0)
    }
    pub(crate) fn sample(&self, u: f64) -> usize {
        let t = u * self.total();
        self.cum
            .partition_point(|&c| c <= t)
            .min(self.cum.len().saturating_sub(1))
    }
}

/// The scene, ready to trace.
pub struct Tracer {
    pub(crate) frame: Frame,
    pub(crate) tris: Vec<Tri>,
    pub(crate) materials: Vec<Material>,
    bvh: Bvh,
    /// BVH index → triangle.
    bvh_ids: Vec<u32>,
    /// BVH index → the back-to-back twin of a double-sided pair (`u32::MAX`: none).
    back_twin: Vec<u32>,
    /// Emissive triangles and their power distribution.
    emitters: Vec<u32>,
    emitter_cdf: Cdf,
    lights: Vec<LocalLight>,
    images: Vec<Image>,
    sky: Option<Sky>,
}

impl Tracer {
    /// Prepares `scene` (all its triangles: pass `scene.static_part()` to match a bake that
    /// leaves dynamic surfaces out). Fails on a scene without triangles or with a non-finite
    /// vertex, reflectance or emission.
    pub fn new(scene: &Scene) -> Result<Tracer, ReferenceError> {
        if scene.triangles.is_empty() {
            return Err(ReferenceError::EmptyScene);
        }
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for (i, t) in scene.triangles.iter().enumerate() {
            for v in t.vertices {
                if !v.is_finite() {
                    return Err(ReferenceError::InvalidScene(format!(
                        "triangle {i} has a non-finite vertex"
                    )));
                }
                lo = lo.min(v);
                hi = hi.max(v);
            }
            if t.surface as usize >= scene.surfaces.len() {
                return Err(ReferenceError::InvalidScene(format!(
                    "triangle {i} names surface {} of {}",
                    t.surface,
                    scene.surfaces.len()
                )));
            }
        }
        let radius = 0.5 * (hi - lo).length();
        if !(radius > 0.0 && radius.is_finite()) {
            return Err(ReferenceError::InvalidScene(
                "the scene has no extent".into(),
            ));
        }
        let frame = Frame {
            center: 0.5 * (lo + hi),
            scale: radius,
        };
        let mut materials = Vec::with_capacity(scene.surfaces.len());
        for s in &scene.surfaces {
            let ok =
                |v: &[f64; 3], max: f64| v.iter().all(|x| x.is_finite() && (0.0..=max).contains(x));
            if !ok(&s.reflectance, 1.0) || !ok(&s.emission, f64::MAX) {
                return Err(ReferenceError::InvalidScene(format!(
                    "surface '{}': reflectance outside [0, 1] or emission negative or not finite",
                    s.name
                )));
            }
            let with_mean = |t: Option<TextureRef>| {
                t.and_then(|t| {
                    let img = scene.images.get(t.image as usize)?;
                    Some((t, img.mean_linear()))
                })
            };
            materials.push(Material {
                rho: s.reflectance,
                emission: s.emission,
                rho_texture: with_mean(s.base_color_texture),
                emission_texture: with_mean(s.emissive_texture),
            });
        }
        let mut tris = Vec::with_capacity(scene.triangles.len());
        let mut local = Vec::with_capacity(scene.triangles.len());
        for t in &scene.triangles {
            let [a, b, c] = t.vertices.map(|v| frame.to_local(v));
            let cross = (b - a).cross(c - a);
            let len = cross.length();
            // Degenerate triangles stay in the BVH's index space but are never sampled; a ray
            // cannot hit them either (zero determinant).
            let n = if len > 0.0 { cross / len } else { DVec3::Z };
            tris.push(Tri {
                v0: a,
                e1: b - a,
                e2: c - a,
                n,
                area: 0.5 * len,
                surface: t.surface,
                uv: t.uv,
            });
            local.push([a.as_vec3(), b.as_vec3(), c.as_vec3()]);
        }
        // A double-sided glTF material arrives as two triangles back to back. Hitting the
        // back of one at the same distance as the front of the other is a tie a ray may break
        // either way, and the back absorbs: so only one of a pair goes into the BVH, and a hit
        // on its back is a hit on its twin's front.
        let mut seen: std::collections::HashMap<([u64; 9], u32), u32> =
            std::collections::HashMap::with_capacity(tris.len());
        let mut bvh_tris = Vec::with_capacity(tris.len());
        let mut bvh_ids = Vec::with_capacity(tris.len());
        let mut back_twin = Vec::with_capacity(tris.len());
        for (i, t) in scene.triangles.iter().enumerate() {
            let mut v = t.vertices.map(|p| [p.x, p.y, p.z].map(f64::to_bits));
            v.sort_unstable();
            let key = (
                [v[0], v[1], v[2]].concat().try_into().unwrap_or([0; 9]),
                t.surface,
            );
            match seen.get(&key) {
                Some(&slot) if back_twin[slot as usize] == u32::MAX => {
                    back_twin[slot as usize] = i as u32;
                }
                _ => {
                    seen.insert(key, bvh_ids.len() as u32);
                    bvh_tris.push(local[i]);
                    bvh_ids.push(i as u32);
                    back_twin.push(u32::MAX);
                }
            }
        }
        // A pair facing the same way (a duplicated triangle, not a double-sided one) keeps
        // both halves' fronts: undo the pairing where the normals agree.
        for slot in 0..bvh_ids.len() {
            let twin = back_twin[slot];
            if twin != u32::MAX && tris[twin as usize].n.dot(tris[bvh_ids[slot] as usize].n) > 0.0 {
                back_twin[slot] = u32::MAX;
                bvh_tris.push(local[twin as usize]);
                bvh_ids.push(twin);
                back_twin.push(u32::MAX);
            }
        }
        // Alpha masks, asked about by BVH index (a folded pair's kept half has its own UVs).
        let bvh = match AlphaMasks::new(scene) {
            Some(masks) => {
                let masks = Arc::new(masks);
                let ids = Arc::new(bvh_ids.clone());
                let (m2, ids2) = (Arc::clone(&masks), Arc::clone(&ids));
                Bvh::with_filter(
                    &bvh_tris,
                    move |i| m2.is_masked(ids2[i as usize]),
                    Arc::new(move |i, u, v| masks.blocks(ids[i as usize], u, v)),
                )
            }
            None => Bvh::new(&bvh_tris),
        };
        let emitters: Vec<u32> = (0..tris.len() as u32)
            .filter(|&i| {
                let t = &tris[i as usize];
                t.area > 0.0 && power(&materials[t.surface as usize].emission) > 0.0
            })
            .collect();
        let emitter_cdf = Cdf::new(emitters.iter().map(|&i| {
            let t = &tris[i as usize];
            t.area * power(&materials[t.surface as usize].emission)
        }));
        let mut lights = Vec::new();
        for l in &scene.lights {
            let finite = l.position.is_finite()
                && l.direction.is_finite()
                && l.intensity.is_finite()
                && l.intensity >= 0.0
                && l.color.iter().all(|c| c.is_finite() && *c >= 0.0);
            if !finite {
                return Err(ReferenceError::InvalidScene(format!(
                    "light '{}' has a negative or non-finite parameter",
                    l.name
                )));
            }
            lights.push(LocalLight {
                light: l.clone(),
                position: frame.to_local(l.position),
            });
        }
        Ok(Tracer {
            frame,
            tris,
            materials,
            bvh,
            bvh_ids,
            back_twin,
            emitters,
            emitter_cdf,
            lights,
            images: scene.images.clone(),
            sky: scene.sky.clone().filter(|s| !s.is_dark()),
        })
    }

    /// Whether anything emits: an emissive triangle, a punctual light or a sky.
    pub fn has_emitters(&self) -> bool {
        !self.emitters.is_empty()
            || self.lights.iter().any(|l| l.light.intensity > 0.0)
            || self.sky.is_some()
    }

    /// A texture's factor at point `x` (local frame) of triangle `tri`: the texel over the
    /// texture's mean, per channel.
    #[inline]
    fn modulation(&self, tri: &Tri, x: DVec3, texture: &(TextureRef, [f64; 4])) -> [f64; 3] {
        let (t, mean) = texture;
        let b = barycentric([tri.v0, tri.v0 + tri.e1, tri.v0 + tri.e2], x);
        let raw: [Vec2; 2] = std::array::from_fn(|set| {
            let u = tri.uv[set];
            (u[0].as_dvec2() * b[0] + u[1].as_dvec2() * b[1] + u[2].as_dvec2() * b[2]).as_vec2()
        });
        let texel = t.sample_linear(&self.images, t.uv(raw));
        std::array::from_fn(|c| {
            if mean[c] > 0.0 {
                f64::from(texel[c]) / mean[c]
            } else {
                1.0
            }
        })
    }

    /// Reflectance at point `x` of triangle `tri`.
    #[inline]
    pub(crate) fn rho_at(&self, tri: &Tri, x: DVec3) -> [f64; 3] {
        let m = &self.materials[tri.surface as usize];
        match &m.rho_texture {
            None => m.rho,
            Some(t) => {
                let k = self.modulation(tri, x, t);
                std::array::from_fn(|c| (m.rho[c] * k[c]).clamp(0.0, 1.0))
            }
        }
    }

    /// Emitted radiance at point `x` of triangle `tri`.
    #[inline]
    pub(crate) fn emission_at(&self, tri: &Tri, x: DVec3) -> [f64; 3] {
        let m = &self.materials[tri.surface as usize];
        match &m.emission_texture {
            None => m.emission,
            Some(t) => {
                let k = self.modulation(tri, x, t);
                std::array::from_fn(|c| m.emission[c] * k[c])
            }
        }
    }

    /// The sky's radiance along `dir` (local frame directions are world directions).
    #[inline]
    pub(crate) fn sky(&self, dir: DVec3) -> [f64; 3] {
        self.sky.as_ref().map_or([0.0; 3], |s| s.radiance(dir))
    }

    /// The closest front-facing hit of a ray from `origin` along unit `dir` (local frame):
    /// the triangle and the point. `None` on a miss or when the ray meets a back face.
    #[inline]
    pub(crate) fn trace(&self, origin: DVec3, dir: DVec3) -> Found {
        let Some(h) = self
            .bvh
            .closest_hit(origin.as_vec3(), dir.as_vec3(), f32::INFINITY)
        else {
            return Found::Escaped;
        };
        let (index, twin) = (
            self.bvh_ids[h.triangle as usize],
            self.back_twin[h.triangle as usize],
        );
        let hit = match (h.front, twin) {
            (true, _) => index,
            (false, u32::MAX) => return Found::Absorbed,
            (false, twin) => twin,
        };
        let t = &self.tris[index as usize];
        // The point from the barycentrics, in f64, rather than origin + t·dir in f32.
        let (u, v) = (h.u.clamp(0.0, 1.0) as f64, h.v.clamp(0.0, 1.0) as f64);
        Found::Surface(hit, t.v0 + t.e1 * u + t.e2 * v)
    }

    fn clear(&self, a: DVec3, b: DVec3) -> bool {
        self.bvh.segment_clear(a.as_vec3(), b.as_vec3())
    }

    /// Irradiance (lux, RGB) at `x` with unit normal `n` from the punctual lights, shadowed.
    fn punctual(&self, x: DVec3, n: DVec3, rays: &mut u64) -> [f64; 3] {
        let mut e = [0.0; 3];
        for l in &self.lights {
            let light = &l.light;
            let (to_light, dist_world, target) = match light.kind {
                LightKind::Directional => {
                    let d = -light.direction;
                    (d, 1.0, x + d * SUN_SEGMENT)
                }
                _ => {
                    let d = l.position - x;
                    let len = d.length();
                    if len <= 0.0 {
                        continue;
                    }
                    (d / len, len * self.frame.scale, l.position)
                }
            };
            let irr = light.irradiance(to_light, n.dot(to_light), dist_world);
            if irr <= 0.0 {
                continue;
            }
            *rays += 1;
            if !self.clear(x, target) {
                continue;
            }
            for c in 0..3 {
                e[c] += irr * light.color[c];
            }
        }
        e
    }

    /// Probability density, per unit area, of choosing a point on emitter triangle `t` by
    /// light sampling.
    #[inline]
    fn light_area_pdf(&self, t: &Tri) -> f64 {
        power(&self.materials[t.surface as usize].emission) / self.emitter_cdf.total()
    }

    /// One estimate of the reflected-radiance factor `R(x) = E(x)/π` at `x` (local frame) with
    /// unit normal `n`: the outgoing radiance there is `L_e + ρ·R`. Counts the rays it casts.
    pub(crate) fn reflected(&self, x: DVec3, n: DVec3, rng: &mut Rng, rays: &mut u64) -> [f64; 3] {
        let mut acc = [0.0; 3];
        let mut beta = [1.0; 3];
        let (mut x, mut n) = (x, n);
        let mut depth = 0u32;
        loop {
            // Punctual lights: E/π.
            if !self.lights.is_empty() {
                let e = self.punctual(x, n, rays);
                for c in 0..3 {
                    acc[c] += beta[c] * e[c] / PI;
                }
            }
            // Emitters by light sampling.
            if !self.emitters.is_empty() {
                let j = self.emitters[self.emitter_cdf.sample(rng.f64())] as usize;
                let t = &self.tris[j];
                let y = t.point(rng.f64(), rng.f64());
                let w = y - x;
                let d2 = w.length_squared();
                if d2 > 0.0 {
                    let d = d2.sqrt();
                    let wd = w / d;
                    let (cx, cy) = (n.dot(wd), -t.n.dot(wd));
                    if cx > 0.0 && cy > 0.0 {
                        *rays += 1;
                        if self.clear(x, y) {
                            let p_area = self.light_area_pdf(t);
                            let p_light = p_area * d2 / cy;
                            let p_bsdf = cx / PI;
                            let mis = p_light * p_light / (p_light * p_light + p_bsdf * p_bsdf);
                            let le = self.emission_at(t, y);
                            // E = ∫ L cos_x dω = L cos_x / p_light; R = E/π.
                            let f = cx / (p_light * PI) * mis;
                            for c in 0..3 {
                                acc[c] += beta[c] * le[c] * f;
                            }
                        }
                    }
                }
            }
            // The next bounce, cosine-weighted: the estimator of R is the radiance it finds.
            let dir = cosine_direction(n, rng.f64(), rng.f64());
            *rays += 1;
            let (hit, y) = match self.trace(x + n * OFFSET, dir) {
                Found::Surface(hit, y) => (hit, y),
                Found::Absorbed => break,
                Found::Escaped => {
                    // The sky has no light sampling: the bounce sees it with weight 1.
                    let l = self.sky(dir);
                    for c in 0..3 {
                        acc[c] += beta[c] * l[c];
                    }
                    break;
                }
            };
            let t = &self.tris[hit as usize];
            let m = &self.materials[t.surface as usize];
            if power(&m.emission) > 0.0 && t.area > 0.0 {
                let emission = self.emission_at(t, y);
                let d2 = (y - x).length_squared();
                let cy = -t.n.dot(dir);
                let p_bsdf = n.dot(dir).max(0.0) / PI;
                let p_light = self.light_area_pdf(t) * d2 / cy.max(f64::MIN_POSITIVE);
                let mis = if p_bsdf > 0.0 {
                    p_bsdf * p_bsdf / (p_bsdf * p_bsdf + p_light * p_light)
                } else {
                    0.0
                };
                for c in 0..3 {
                    acc[c] += beta[c] * emission[c] * mis;
                }
            }
            let rho = self.rho_at(t, y);
            for c in 0..3 {
                beta[c] *= rho[c];
            }
            depth += 1;
            let bmax = beta[0].max(beta[1]).max(beta[2]);
            if bmax <= 0.0 {
                break;
            }
            if depth >= RR_DEPTH {
                let survive = bmax.min(1.0);
                if rng.f64() >= survive {
                    break;
                }
                for b in &mut beta {
                    *b /= survive;
                }
            }
            x = y;
            n = t.n;
        }
        acc
    }

    /// One estimate of the outgoing radiance at `x` on triangle `tri`.
    #[inline]
    pub(crate) fn outgoing(&self, tri: u32, x: DVec3, rng: &mut Rng, rays: &mut u64) -> [f64; 3] {
        let t = &self.tris[tri as usize];
        let (rho, emission) = (self.rho_at(t, x), self.emission_at(t, x));
        let r = if rho.iter().any(|&p| p > 0.0) {
            self.reflected(x, t.n, rng, rays)
        } else {
            [0.0; 3]
        };
        [0, 1, 2].map(|c| emission[c] + rho[c] * r[c])
    }

    /// The triangle a point given in scene units lies on, seen along `normal`: the closest
    /// front face hit by a short ray from just above the point back along the normal (within
    /// 0.5 % of the scene's radius, as published quads are not always planar).
    pub(crate) fn locate(&self, p: DVec3, normal: DVec3) -> Option<(u32, DVec3)> {
        let n = normal.try_normalize()?;
        let q = self.frame.to_local(p);
        let lift = 5e-3;
        let h = self.bvh.closest_hit(
            (q + n * lift).as_vec3(),
            (-n).as_vec3(),
            (2.0 * lift) as f32,
        )?;
        let hit = match (h.front, self.back_twin[h.triangle as usize]) {
            (true, _) => self.bvh_ids[h.triangle as usize],
            (false, u32::MAX) => return None,
            (false, twin) => twin,
        };
        // The point itself, projected onto the triangle's plane in f64 (the hit's f32
        // barycentrics would move it by rounding).
        let t = &self.tris[hit as usize];
        Some((hit, q - t.n * (q - t.v0).dot(t.n)))
    }
}

/// The sum of a colour's channels: the weight emitters are sampled by.
#[inline]
fn power(e: &[f64; 3]) -> f64 {
    e[0] + e[1] + e[2]
}

/// A cosine-weighted direction about unit `n` (pdf `cos θ / π`).
#[inline]
pub(crate) fn cosine_direction(n: DVec3, r1: f64, r2: f64) -> DVec3 {
    let (t, b) = n.any_orthonormal_pair();
    let r = r1.sqrt();
    let phi = 2.0 * PI * r2;
    let z = (1.0 - r1).max(0.0).sqrt();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * z).normalize()
}
