//! The light map of a bake, composed per texel: the punctual lights' direct light (a sun's
//! shadows) computed at every texel's own footprint with its own shadow rays, plus the rest of
//! the solution (bounced light, emitters, the sky) from the smooth field of the elements.
//!
//! Why: the solution carries a light's direct part by elements, each lit or shadowed by one
//! ray from its centroid and interpolated across its neighbours, so a shadow edge lands where
//! the element grid puts it (metre-wide elements on a level: bands of sun leaking into shadow,
//! sunlit texels darkened near an edge). The solution keeps that direct light for its bounces;
//! the light map takes it out again, `B − ρ D / π` per element with the same rays, and adds
//! each texel's own `D / π` instead, so nothing is counted twice. A scene without punctual
//! lights gets the smooth field alone, as before.
//!
//! A texel's footprint is its square in the atlas mapped onto its triangle (points outside the
//! triangle clamped onto it): each light is first sampled at the centres of its 2 × 2
//! quarters; where those agree (all lit or all shadowed) that is the texel's value, and
//! otherwise it takes the 4 × 4 grid, so an edge crossing a texel gives it the share of the
//! footprint the light reaches, in sixteenths, the same on every run and thread count.

use glam::{DVec2, DVec3};
use radiant_scene::atlas::Atlas;
use radiant_scene::{Light, LightKind, Scene};
use radiant_visibility::Visibility;
use rayon::prelude::*;

use crate::lightmap::{LightMap, static_roots};
use crate::mesh::{Frame, Mesh};
use crate::smooth::SmoothField;
use crate::system::{Rgb, System};

/// Sub-samples a side of a texel where its first 2 × 2 disagree.
pub const FINE: u32 = 4;

/// The punctual lights' direct light at light-map texels.
pub struct TexelLights<V> {
    frame: Frame,
    vis: V,
    /// Lights with some intensity, and their positions in the mesh's frame.
    lights: Vec<(Light, DVec3)>,
    /// Per scene triangle: its vertices in the mesh's frame and unit normal, `None` for a
    /// dynamic one.
    tris: Vec<Option<([DVec3; 3], DVec3)>>,
    /// Per scene triangle: its atlas coordinates in texels.
    uv: Vec<[DVec2; 3]>,
}

impl<V: Visibility> TexelLights<V> {
    /// The lights of `scene` at the texels of `atlas`, with shadow rays against `vis` (over
    /// `mesh`'s input triangles, in its frame, as [`crate::input::visibility`] builds it).
    pub fn new(scene: &Scene, atlas: &Atlas, mesh: &Mesh, vis: V) -> TexelLights<V> {
        let frame = mesh.frame;
        let lights = scene
            .lights
            .iter()
            .filter(|l| l.intensity > 0.0)
            .map(|l| (l.clone(), frame.to_local(l.position)))
            .collect();
        let roots = static_roots(scene);
        let tris = scene
            .triangles
            .iter()
            .zip(&roots)
            .map(|(t, root)| {
                root.map(|_| {
                    let v = t.vertices.map(|p| frame.to_local(p));
                    (v, (v[1] - v[0]).cross(v[2] - v[0]).normalize_or_zero())
                })
            })
            .collect();
        let size = DVec2::new(f64::from(atlas.width), f64::from(atlas.height));
        let uv = atlas
            .uv
            .iter()
            .map(|t| t.map(|c| c.as_dvec2() * size))
            .collect();
        TexelLights {
            frame,
            vis,
            lights,
            tris,
            uv,
        }
    }

    /// Whether any light shines.
    pub fn is_empty(&self) -> bool {
        self.lights.is_empty()
    }

    /// `D / π`, the incident radiance the lights give the texel that [`Atlas::fill`] fills from
    /// `triangle` at weights `(u, v)` (see the module).
    pub fn h(&self, triangle: usize, u: f32, v: f32) -> Rgb {
        let (Some(Some((p, n))), Some(uv)) = (self.tris.get(triangle), self.uv.get(triangle))
        else {
            return [0.0; 3];
        };
        let (u, v) = (f64::from(u), f64::from(v));
        let centre = uv[0] * (1.0 - u - v) + uv[1] * u + uv[2] * v;
        let (e1, e2) = (uv[1] - uv[0], uv[2] - uv[0]);
        let det = e1.perp_dot(e2);
        // The point of the triangle at texel coordinates `s`, clamped onto it.
        let at = |s: DVec2| -> DVec3 {
            let (a, b) = if det.abs() > 1e-12 && det.is_finite() {
                let q = s - uv[0];
                (q.perp_dot(e2) / det, e1.perp_dot(q) / det)
            } else {
                (u, v)
            };
            let a = a.clamp(0.0, 1.0);
            let b = b.clamp(0.0, 1.0 - a);
            p[0] + (p[1] - p[0]) * a + (p[2] - p[0]) * b
        };
        let grid = |k: u32| {
            (0..k * k).map(move |i| {
                let step = 1.0 / f64::from(k);
                let (x, y) = (f64::from(i % k), f64::from(i / k));
                centre + DVec2::new((x + 0.5) * step - 0.5, (y + 0.5) * step - 0.5)
            })
        };
        let mut out = [0.0; 3];
        for (light, local) in &self.lights {
            let one = |s: DVec2| -> (f64, bool) {
                let x = at(s);
                match self.unshadowed(light, *local, x, *n) {
                    Some((irr, target)) => {
                        (irr, self.vis.segment_clear(x.as_vec3(), target.as_vec3()))
                    }
                    None => (0.0, false),
                }
            };
            let coarse: Vec<(f64, bool)> = grid(2).map(one).collect();
            let agree = coarse.iter().all(|c| c.1 == coarse[0].1);
            let (sum, count) = if agree {
                let lit = coarse.iter().filter(|c| c.1).map(|c| c.0).sum::<f64>();
                (lit, 4.0)
            } else {
                let lit = grid(FINE)
                    .map(one)
                    .filter(|c| c.1)
                    .map(|c| c.0)
                    .sum::<f64>();
                (lit, f64::from(FINE * FINE))
            };
            let irr = sum / count / std::f64::consts::PI;
            for c in 0..3 {
                out[c] += irr * light.color[c];
            }
        }
        out
    }

    /// The light's irradiance at `x` (normal `n`) before shadows, and the point a shadow ray
    /// runs to; `None` where it gives none. As [`crate::lights`] evaluates it at centroids.
    fn unshadowed(&self, light: &Light, local: DVec3, x: DVec3, n: DVec3) -> Option<(f64, DVec3)> {
        let (to_light, dist_world, target) = match light.kind {
            LightKind::Directional => {
                let d = -light.direction;
                (d, 1.0, x + d * 4.0)
            }
            _ => {
                let d = local - x;
                let len = d.length();
                if len <= 0.0 {
                    return None;
                }
                (d / len, len * self.frame.scale, local)
            }
        };
        let irr = light.irradiance(to_light, n.dot(to_light), dist_world);
        (irr > 0.0).then_some((irr, target))
    }
}

/// The light map of a bake of `scene` (`mesh`, `system`, `radiosity`) on `atlas`, composed as
/// the module says. With punctual lights it builds the bake's ray tracer again
/// ([`crate::input::visibility`], with the alpha masks), so the elements' direct light it takes
/// out is the one the bake put in, bit for bit.
pub fn compose_lightmap(
    scene: &Scene,
    atlas: &Atlas,
    mesh: &Mesh,
    system: &System,
    radiosity: &[Rgb],
) -> LightMap {
    if scene.lights.iter().any(|l| l.intensity > 0.0) {
        let masks = crate::input::masks(&crate::input::static_scene(scene));
        let bvh = crate::input::visibility(mesh, masks.as_ref());
        compose_with(scene, atlas, mesh, system, radiosity, bvh)
    } else {
        compose_with(
            scene,
            atlas,
            mesh,
            system,
            radiosity,
            radiant_visibility::BruteForce::new(&[]),
        )
    }
}

/// [`compose_lightmap`] with the shadow rays of `vis`.
pub fn compose_with<V: Visibility>(
    scene: &Scene,
    atlas: &Atlas,
    mesh: &Mesh,
    system: &System,
    radiosity: &[Rgb],
    vis: V,
) -> LightMap {
    let lights = TexelLights::new(scene, atlas, mesh, vis);
    let field = if lights.is_empty() {
        SmoothField::new(mesh, system, &scene.surfaces, radiosity)
    } else {
        // The lights' direct part of each element, with the rays the bake cast for it.
        let lit: Vec<Light> = lights.lights.iter().map(|l| l.0.clone()).collect();
        let direct = crate::lights::direct_irradiance(mesh, &lit, &lights.vis);
        let rest: Vec<Rgb> = radiosity
            .iter()
            .zip(&direct)
            .zip(&system.rho)
            .map(|((b, d), rho)| {
                std::array::from_fn(|c| (b[c] - rho[c] * d[c] / std::f64::consts::PI).max(0.0))
            })
            .collect();
        SmoothField::new(mesh, system, &scene.surfaces, &rest)
    };
    let roots = static_roots(scene);
    let eval = |i: usize, u: f32, v: f32| -> [f32; 3] {
        let Some(&Some(root)) = roots.get(i) else {
            return [0.0; 3];
        };
        if root as usize >= mesh.roots.len() {
            return [0.0; 3];
        }
        let mut h = field.irradiance(mesh, root, f64::from(u), f64::from(v));
        if !lights.is_empty() {
            let d = lights.h(i, u, v);
            for c in 0..3 {
                h[c] += d[c];
            }
        }
        h.map(|x| x as f32)
    };
    let size = atlas.width as usize * atlas.height as usize;
    let mut texels = vec![[0.0f32; 3]; size * atlas.pages as usize];
    for (page, texels) in texels.chunks_exact_mut(size.max(1)).enumerate() {
        let owners = atlas.owners(scene, page as u32);
        texels
            .par_chunks_mut(atlas.width.max(1) as usize)
            .zip(owners.par_chunks(atlas.width.max(1) as usize))
            .for_each(|(row, owners)| {
                for (t, o) in row.iter_mut().zip(owners) {
                    if o.triangle != u32::MAX {
                        *t = eval(o.triangle as usize, o.u, o.v);
                    }
                }
            });
    }
    LightMap {
        width: atlas.width,
        height: atlas.height,
        pages: atlas.pages,
        texels,
    }
}
