//! The light map of a bake, composed per texel: the punctual lights' direct light (a sun's
//! shadows) computed at every texel's own footprint with its own shadow rays, plus the rest of
//! the solution (bounced light, emitters, the sky) from the smooth field of the elements; and
//! where part of a texel lies inside or under other geometry, only the part in the open.
//!
//! Why: the solution carries a light's direct part by elements, each lit or shadowed by the
//! mean of nine rays and interpolated across its neighbours, so a shadow edge lands where
//! the element grid puts it (metre-wide elements on a level: bands of sun leaking into shadow,
//! sunlit texels darkened near an edge). The solution keeps that direct light for its bounces;
//! the light map takes it out again, `B − ρ D / π` per element with the same rays, and adds
//! each texel's own `D / π` instead, so nothing is counted twice.
//!
//! A texel's footprint is its square in the atlas mapped onto its triangle (points outside the
//! triangle clamped onto it). A point of it is buried when the first face a ray along its
//! normal meets is the back of a single-sided one (a box on a floor, a wall's foot, a column
//! on its plinth). Short segments just above the surface, from the footprint's centre to its
//! 2 × 2 quarter centres, say whether other geometry splits it; when none does, one such ray
//! at the centre says whether all of it is open or buried. All open (the usual case), each
//! light is sampled at the four quarter centres, and where they disagree (lit and shadowed) on
//! the 4 × 4 grid, so an edge crossing the texel gives it its share in sixteenths; the rest of
//! the light is read at the texel's centre. Split, the texel takes the 4 × 4 grid's open
//! points alone: the lights over them, the rest at their centroid, so no light reaches it
//! through the occluder and no shade from under it. A wholly buried texel takes the mean of
//! its open neighbours on the same surface and chart, which bilinear filtering reads at a
//! contact. The same bytes on every run and thread count.

use glam::{DVec2, DVec3};
use std::borrow::Cow;

use radiant_scene::atlas::{Atlas, TexelOwner, texel_position};
use radiant_scene::{Light, Scene};
use radiant_visibility::Visibility;
use rayon::prelude::*;

use crate::final_gather::{FinalGather, GatherParams, VALID};
use crate::lightmap::{LightMap, static_roots};
use crate::mesh::{Frame, Mesh};
use crate::rng::hash;
use crate::smooth::SmoothField;
use crate::system::{Rgb, System};

/// Sub-samples a side of a texel where its first 2 × 2 disagree (on the light, or on what is
/// buried).
pub const FINE: u32 = 4;

/// What a texel's footprint comes to (see the module).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TexelSample {
    /// The barycentric weights `(u, v)` of vertices 1 and 2 of the texel's triangle where the
    /// rest of the light is read: the texel's centre, or where part of its footprint is
    /// buried, the centroid of the part that is not; `None` when all of it is buried.
    pub at: Option<(f32, f32)>,
    /// `D / π`, the lights' direct light over the footprint's visible part.
    pub direct: Rgb,
}

/// The punctual lights' direct light, and what is buried, at light-map texels.
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
    /// Per triangle of `vis` (the mesh's input triangles): whether its surface is
    /// double-sided (a back face that hides nothing).
    double_sided: Vec<bool>,
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
        let double_sided = mesh
            .root_surface
            .iter()
            .map(|&s| {
                scene
                    .surfaces
                    .get(s as usize)
                    .is_some_and(|s| s.double_sided)
            })
            .collect();
        TexelLights {
            frame,
            vis,
            lights,
            tris,
            uv,
            double_sided,
        }
    }

    /// Whether any light shines.
    pub fn is_empty(&self) -> bool {
        self.lights.is_empty()
    }

    /// Whether the point `x` (normal `n`) lies inside or under other geometry: the first face
    /// a ray along its normal meets is the back of a single-sided one (a box standing on a
    /// floor, a wall's foot, a column on its plinth).
    fn buried(&self, x: DVec3, n: DVec3) -> bool {
        buried(&self.vis, &self.double_sided, x, n)
    }

    /// Whether the point `x` (world units) of scene triangle `triangle` lies in the open: not
    /// inside or under other geometry (see [`Self::sample`]).
    pub fn open_at(&self, triangle: usize, x: DVec3) -> bool {
        match self.tris.get(triangle) {
            Some(Some((_, n))) => !self.buried(self.frame.to_local(x), *n),
            _ => true,
        }
    }

    /// The texel that [`Atlas::fill`] fills from `triangle` at weights `(u, v)` (see the
    /// module): where its light is read, and the lights' direct part.
    pub fn sample(&self, triangle: usize, u: f32, v: f32) -> TexelSample {
        let (Some(Some((p, n))), Some(uv)) = (self.tris.get(triangle), self.uv.get(triangle))
        else {
            return TexelSample {
                at: Some((u, v)),
                direct: [0.0; 3],
            };
        };
        let (u0, v0) = (f64::from(u), f64::from(v));
        let centre = uv[0] * (1.0 - u0 - v0) + uv[1] * u0 + uv[2] * v0;
        let (e1, e2) = (uv[1] - uv[0], uv[2] - uv[0]);
        let det = e1.perp_dot(e2);
        // The weights on the triangle of texel coordinates `s`, clamped onto it.
        let weights = |s: DVec2| -> (f64, f64) {
            let (a, b) = if det.abs() > 1e-12 && det.is_finite() {
                let q = s - uv[0];
                (q.perp_dot(e2) / det, e1.perp_dot(q) / det)
            } else {
                (u0, v0)
            };
            let a = a.clamp(0.0, 1.0);
            (a, b.clamp(0.0, 1.0 - a))
        };
        let point = |(a, b): (f64, f64)| p[0] + (p[1] - p[0]) * a + (p[2] - p[0]) * b;
        let grid = |k: u32| -> Vec<(f64, f64)> {
            (0..k * k)
                .map(|i| {
                    let step = 1.0 / f64::from(k);
                    let (x, y) = (f64::from(i % k), f64::from(i / k));
                    weights(centre + DVec2::new((x + 0.5) * step - 0.5, (y + 0.5) * step - 0.5))
                })
                .collect()
        };
        let coarse = grid(2);
        // Is the footprint split by other geometry? Short segments from its centre to its
        // quarters, just above the surface (cheap: they stay near the texel); when none is
        // blocked, one probe at the centre says whether all of it is in the open or buried.
        let centre_point = point((u0, v0));
        let above = |x: DVec3| (x + *n * 1e-5).as_vec3();
        let split = coarse
            .iter()
            .any(|&w| !self.vis.segment_clear(above(centre_point), above(point(w))));
        // All of the footprint in the open (the usual case): read the light at the texel's
        // centre; otherwise at the centroid of the fine grid's open points, and the lights over
        // those alone.
        let (open, at, whole) = if !split {
            if self.buried(centre_point, *n) {
                return TexelSample {
                    at: None,
                    direct: [0.0; 3],
                };
            }
            (coarse, Some((u, v)), true)
        } else {
            let open: Vec<(f64, f64)> = grid(FINE)
                .into_iter()
                .filter(|&w| !self.buried(point(w), *n))
                .collect();
            if open.is_empty() {
                return TexelSample {
                    at: None,
                    direct: [0.0; 3],
                };
            }
            let k = open.len() as f64;
            let (a, b) = open.iter().fold((0.0, 0.0), |s, w| (s.0 + w.0, s.1 + w.1));
            let at = Some(((a / k) as f32, (b / k) as f32));
            (open, at, false)
        };
        let mut direct = [0.0; 3];
        for (light, local) in &self.lights {
            let one = |&w: &(f64, f64)| -> (f64, bool) {
                let x = point(w);
                match crate::lights::unshadowed(self.frame, light, *local, x, *n) {
                    Some((irr, target)) => {
                        (irr, self.vis.segment_clear(x.as_vec3(), target.as_vec3()))
                    }
                    None => (0.0, false),
                }
            };
            let first: Vec<(f64, bool)> = open.iter().map(one).collect();
            let agree = first.iter().all(|c| c.1 == first[0].1);
            let lit = |s: &[(f64, bool)]| s.iter().filter(|c| c.1).map(|c| c.0).sum::<f64>();
            let mean = if agree || !whole {
                lit(&first) / first.len() as f64
            } else {
                let fine: Vec<(f64, bool)> = grid(FINE).iter().map(one).collect();
                lit(&fine) / fine.len() as f64
            };
            let irr = mean / std::f64::consts::PI;
            for c in 0..3 {
                direct[c] += irr * light.color[c];
            }
        }
        TexelSample { at, direct }
    }
}

/// The light map of a bake of `scene` (`mesh`, `system`, `radiosity`) on `atlas`, composed as
/// the module says. It builds the bake's ray tracer again ([`crate::input::visibility`], with
/// the alpha masks), so the elements' direct light it takes out is the one the bake put in, bit
/// for bit.
pub fn compose_lightmap(
    scene: &Scene,
    atlas: &Atlas,
    mesh: &Mesh,
    system: &System,
    radiosity: &[Rgb],
) -> LightMap {
    let masks = crate::input::masks(&crate::input::static_scene(scene));
    let bvh = crate::input::visibility(mesh, masks.as_ref());
    compose_with(scene, atlas, mesh, system, radiosity, bvh)
}

/// The light map of a bake as [`compose_lightmap`] composes it, but for the rest of the light
/// (all but the punctual lights' direct part): a final gather at each texel
/// ([`crate::final_gather`]) instead of the smooth field, so that a texel near a contact or in
/// an element's shadowed part takes the light its own point receives.
pub fn compose_gathered(
    scene: &Scene,
    atlas: &Atlas,
    mesh: &Mesh,
    system: &System,
    radiosity: &[Rgb],
    params: GatherParams,
) -> LightMap {
    compose_gathered_with_progress(scene, atlas, mesh, system, radiosity, params, &|_, _| {})
}

/// [`compose_gathered`], telling `progress(done, total)` how many rows of the atlas's pages
/// are gathered (from any thread, in any order; the last call has `done == total`).
pub fn compose_gathered_with_progress(
    scene: &Scene,
    atlas: &Atlas,
    mesh: &Mesh,
    system: &System,
    radiosity: &[Rgb],
    params: GatherParams,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> LightMap {
    let masks = crate::input::masks(&crate::input::static_scene(scene));
    let bvh = crate::input::visibility(mesh, masks.as_ref());
    let lights = TexelLights::new(scene, atlas, mesh, bvh);
    let regathered;
    let radiosity = match params.element_passes {
        0 => radiosity,
        passes => {
            regathered = crate::final_gather::regather_elements(
                scene,
                mesh,
                system,
                radiosity,
                &lights.vis,
                params,
                passes,
            );
            &regathered[..]
        }
    };
    let field = SmoothField::new(mesh, system, &scene.surfaces, radiosity);
    // With the lights taken where the rays land, the rays read the field without the
    // elements' direct part (which they would count twice).
    let lit = params.lights_at_hits && !lights.is_empty();
    let field = if lit {
        field.minus(&lights.element_direct(mesh))
    } else {
        field
    };
    let gather = FinalGather::new(scene, mesh, &field, &lights.vis, params);
    let gather = if lit {
        gather.with_lights_at_hits(scene)
    } else {
        gather
    };
    let (width, height) = (atlas.width.max(1) as usize, atlas.height as usize);
    let size = width * height;
    let mut texels = vec![[0.0f32; 3]; size * atlas.pages as usize];
    let strides = lattice_strides(params.stride);
    let (coarsest, finest) = (strides[0], strides[strides.len() - 1]);
    // The window a texel looks in for gathered texels that stand for it: at least the
    // coarsest lattice's spacing, so one of its texels is always in reach.
    let r = i64::from(params.filter_radius).max(coarsest as i64);
    // A twentieth of a texel, in the mesh's frame.
    let nudge = 0.05 / atlas.density / mesh.frame.scale;
    let rows_done = std::sync::atomic::AtomicUsize::new(0);
    // Pass 1, each finer lattice, and pass 2, over every row of every page.
    let rows_total = height * atlas.pages as usize * (strides.len() + 1);
    let tick = || {
        let done = rows_done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        progress(done, rows_total);
    };
    for (page, texels) in texels.chunks_exact_mut(size.max(1)).enumerate() {
        let owners = atlas.owners(scene, page as u32);
        if owners.len() != texels.len() {
            continue;
        }
        // Where texel `k` gathers (its sample's point, nudged off the triangle's edges: a ring
        // texel lies on one, and a point on the edge of a floor and a wall is in the wall's
        // plane, where its rays and form factors miss the wall), its normal and its key.
        let point = |k: usize, at: (f32, f32)| -> Option<(DVec3, DVec3, u64)> {
            let o = owners[k];
            let (p, n) = lights.tris.get(o.triangle as usize).copied().flatten()?;
            let (a, b) = (f64::from(at.0), f64::from(at.1));
            let x = p[0] + (p[1] - p[0]) * a + (p[2] - p[0]) * b;
            let to_centre = (p[0] + p[1] + p[2]) / 3.0 - x;
            let x = x + to_centre.clamp_length_max(nudge.min(0.5 * to_centre.length()));
            let key = hash(
                u64::from(o.triangle),
                u64::from(at.0.to_bits()),
                u64::from(at.1.to_bits()),
            );
            Some((x, n, key))
        };
        // Pass 1, per texel: the exact part (the lights' and the emitters' direct light) into
        // the map, where an open texel's light is read (NaN: not open), and on the coarsest
        // lattice the rays' part (NaN elsewhere): 25 bytes a texel.
        let mut rays = vec![[f32::NAN; 4]; size];
        let mut at = vec![[f32::NAN; 2]; size];
        let mut buried = vec![false; size];
        texels
            .par_chunks_mut(width)
            .zip(rays.par_chunks_mut(width))
            .zip(at.par_chunks_mut(width))
            .zip(buried.par_chunks_mut(width))
            .enumerate()
            .for_each(|(y, (((trow, rrow), arow), brow))| {
                for x in 0..trow.len() {
                    let k = y * width + x;
                    let o = owners[k];
                    if lights
                        .tris
                        .get(o.triangle as usize)
                        .is_none_or(Option::is_none)
                    {
                        continue;
                    }
                    let s = lights.sample(o.triangle as usize, o.u, o.v);
                    let Some(a) = s.at else {
                        brow[x] = true;
                        continue;
                    };
                    let Some((p, n, key)) = point(k, a) else {
                        continue;
                    };
                    arow[x] = [a.0, a.1];
                    let emitted = gather.emitted(p, n, key);
                    trow[x] = std::array::from_fn(|c| (s.direct[c] + emitted[c]) as f32);
                    if x % coarsest == 0 && y % coarsest == 0 {
                        let (g, reach) = gather.reflected(p, n, key);
                        rrow[x] = [g[0] as f32, g[1] as f32, g[2] as f32, reach as f32];
                    }
                }
                tick();
            });
        // Where a texel lies and faces, in the mesh's frame, and its surface.
        let place = |k: usize| -> Option<(DVec3, DVec3, u32)> {
            let o = owners[k];
            let (p, n) = lights.tris.get(o.triangle as usize).copied().flatten()?;
            let (a, b) = (f64::from(o.u), f64::from(o.v));
            let x = p[0] + (p[1] - p[0]) * a + (p[2] - p[0]) * b;
            Some((x, n, scene.triangles[o.triangle as usize].surface))
        };
        // Neighbours within the window's reach in the scene (the mesh's frame): the same chart,
        // not one packed beside it.
        let reach = (r as f64 + 1.0) * std::f64::consts::SQRT_2 / atlas.density / mesh.frame.scale;
        // How far gathered texel `j` lies from texel `k` (at `here`) in shares of its rays'
        // reach, where it is on the same surface and plane within the window's reach.
        let share = |rays: &[[f32; 4]], j: usize, k: usize, here: (DVec3, DVec3, u32)| {
            if j == k {
                return Some(0.0);
            }
            let (pk, nk, sk) = here;
            place(j).and_then(|(pj, nj, sj)| {
                let d = pj.distance(pk);
                (sj == sk && d <= reach && nj.dot(nk) >= crate::smooth::SAME_PLANE)
                    .then(|| d / f64::from(rays[j][3]).max(1e-12))
            })
        };
        // The texels of stride `s`'s lattice within `r` of `c` along an axis of `len` texels:
        // the first multiple of the stride at or after the window's start, then every s-th.
        let window = |c: usize, s: usize, len: usize| {
            let lo = (c as i64 - r).max(0);
            let first = lo + (s as i64 - lo % s as i64) % s as i64;
            (first..=(c as i64 + r).min(len as i64 - 1)).step_by(s)
        };
        tracing::debug!(
            page,
            stride = coarsest,
            gathered = rays.iter().filter(|v| !v[0].is_nan()).count(),
            open = at.iter().filter(|v| !v[0].is_nan()).count(),
            "final gather: the coarsest lattice"
        );
        // Each finer lattice (Ward's irradiance caching on the atlas): its open texels that
        // no texel gathered so far stands for (nearer than VALID of its rays' reach) gather
        // their own; the open floor far from walls stays on the coarsest lattice, a contact
        // or a small chart goes down to the finest (every second texel).
        for pair in strides.windows(2) {
            let (prev, s) = (pair[0], pair[1]);
            let fresh: Vec<Vec<(usize, [f32; 4])>> = (0..height)
                .into_par_iter()
                .map(|y| {
                    let mut out = Vec::new();
                    if y % s == 0 {
                        for x in (0..width).step_by(s) {
                            let k = y * width + x;
                            if (x % prev == 0 && y % prev == 0) || at[k][0].is_nan() {
                                continue;
                            }
                            let Some(here) = place(k) else {
                                continue;
                            };
                            // What was gathered lies on the last lattice.
                            let stood_for = window(y, prev, height).any(|ny| {
                                window(x, prev, width).any(|nx| {
                                    let j = ny as usize * width + nx as usize;
                                    !rays[j][0].is_nan()
                                        && share(&rays, j, k, here).is_some_and(|q| q <= VALID)
                                })
                            });
                            if stood_for {
                                continue;
                            }
                            let Some((p, n, key)) = point(k, (at[k][0], at[k][1])) else {
                                continue;
                            };
                            let (g, reach) = gather.reflected(p, n, key);
                            out.push((k, [g[0] as f32, g[1] as f32, g[2] as f32, reach as f32]));
                        }
                    }
                    tick();
                    out
                })
                .collect();
            let mut gathered = 0usize;
            for (k, v) in fresh.into_iter().flatten() {
                rays[k] = v;
                gathered += 1;
            }
            tracing::debug!(page, stride = s, gathered, "final gather: a finer lattice");
        }
        // Pass 2: each open texel adds the mean of the rays' parts gathered on its surface
        // within the window that stand for it; with none that does, the one nearest to it (in
        // shares of their reach); with none at all, its own.
        texels
            .par_chunks_mut(width)
            .enumerate()
            .for_each(|(y, row)| {
                for (x, t) in row.iter_mut().enumerate() {
                    let k = y * width + x;
                    if at[k][0].is_nan() {
                        continue;
                    }
                    let Some(here) = place(k) else {
                        continue;
                    };
                    let (mut sum, mut count) = ([0.0f64; 3], 0.0);
                    let mut nearest: Option<(f64, usize)> = None;
                    for ny in window(y, finest, height) {
                        for nx in window(x, finest, width) {
                            let j = ny as usize * width + nx as usize;
                            if rays[j][0].is_nan() {
                                continue;
                            }
                            let Some(q) = share(&rays, j, k, here) else {
                                continue;
                            };
                            if q <= VALID {
                                for c in 0..3 {
                                    sum[c] += f64::from(rays[j][c]);
                                }
                                count += 1.0;
                            } else if nearest.is_none_or(|(best, _)| q < best) {
                                nearest = Some((q, j));
                            }
                        }
                    }
                    let mean = if count > 0.0 {
                        sum.map(|v| v / count)
                    } else if let Some((_, j)) = nearest {
                        // None stands for it: the one that comes nearest (bounded work where
                        // geometry crowds a sparse lattice).
                        std::array::from_fn(|c| f64::from(rays[j][c]))
                    } else {
                        match point(k, (at[k][0], at[k][1])) {
                            Some((p, n, key)) => gather.reflected(p, n, key).0,
                            None => [0.0; 3],
                        }
                    };
                    for c in 0..3 {
                        t[c] = (f64::from(t[c]) + mean[c]) as f32;
                    }
                }
                tick();
            });
        tracing::debug!(page, "final gather: filtered");
        dilate_buried(
            texels,
            &buried,
            &owners,
            scene,
            (width, 2.5 / atlas.density),
        );
    }
    LightMap {
        width: atlas.width,
        height: atlas.height,
        pages: atlas.pages,
        texels,
    }
}

/// The gather's lattices, coarsest first: `coarsest`, halved while it is even (then 1) down to
/// every second texel, each holding the last (every texel of a lattice lies on the next).
/// Not down to every texel: on Sponza that doubled the gathered texels (320 k more, +21 s) for
/// no measured gain; nor stopping at a quarter of a coarse stride: charts of a few texels with
/// no texel on the finest lattice then gather at every texel (stride 16: +17 s).
fn lattice_strides(coarsest: u32) -> Vec<usize> {
    let finest = (coarsest as usize).clamp(1, 2);
    let mut strides = vec![coarsest.max(1) as usize];
    while let Some(&last) = strides.last() {
        if last <= finest {
            break;
        }
        strides.push(if last % 2 == 0 { last / 2 } else { 1 });
    }
    strides
}

/// Whether the point `x` (normal `n`, the frame of `vis`) lies inside or under other
/// geometry: the first face a ray along its normal meets is the back of a single-sided one
/// (`double_sided` per triangle of `vis`). From just above the surface: a face lying on it (a
/// box's bottom on a floor) is not met, the box's top from inside is. The one test of the
/// light map's texels and of the final gather's points.
pub(crate) fn buried<V: Visibility>(vis: &V, double_sided: &[bool], x: DVec3, n: DVec3) -> bool {
    vis.closest_hit((x + n * 1e-5).as_vec3(), n.as_vec3(), 4.0)
        .is_some_and(|h| {
            !h.front
                && !double_sided
                    .get(h.triangle as usize)
                    .copied()
                    .unwrap_or(false)
        })
}

/// What the renderer shows of `map` (a light map of `scene` on `atlas`, baked on `mesh`),
/// averaged over each surface ([`crate::points::surface_means`]), a point buried under other
/// geometry counted dark as [`compose_lightmap`] finds it (with the bake's rays, built again).
///
/// # Errors
/// [`crate::points::PointError::AtlasMismatch`] when `atlas` is not `scene`'s.
pub fn shown_surface_means(
    scene: &Scene,
    atlas: &Atlas,
    mesh: &Mesh,
    map: &LightMap,
) -> Result<Vec<crate::metrics::SurfaceMean>, crate::points::PointError> {
    let masks = crate::input::masks(&crate::input::static_scene(scene));
    let bvh = crate::input::visibility(mesh, masks.as_ref());
    let lights = TexelLights::new(scene, atlas, mesh, bvh);
    crate::points::surface_means(scene, atlas, map, |i, x| lights.open_at(i as usize, x))
}

/// [`compose_lightmap`] with the rays of `vis`.
pub fn compose_with<V: Visibility>(
    scene: &Scene,
    atlas: &Atlas,
    mesh: &Mesh,
    system: &System,
    radiosity: &[Rgb],
    vis: V,
) -> LightMap {
    let lights = TexelLights::new(scene, atlas, mesh, vis);
    let field = SmoothField::new(mesh, system, &scene.surfaces, radiosity);
    let rest = field.minus(&lights.element_direct(mesh));
    let roots = static_roots(scene);
    fill(
        scene,
        atlas,
        |page| Cow::Owned(atlas.owners(scene, page)),
        |_, o| lights.sample(o.triangle as usize, o.u, o.v),
        |triangle, at| rest_at(mesh, &roots, &rest, triangle, at),
    )
}

impl<V: Visibility> TexelLights<V> {
    /// Per element of `mesh`, the lights' direct `D / π` the bake put into its source term
    /// (nine points per element, [`crate::lights::direct_irradiance`], with these
    /// rays: bit for bit the bake's); empty without lights.
    pub fn element_direct(&self, mesh: &Mesh) -> Vec<Rgb> {
        if self.is_empty() {
            return Vec::new();
        }
        let lit: Vec<Light> = self.lights.iter().map(|l| l.0.clone()).collect();
        let mut d = crate::lights::direct_irradiance(mesh, &lit, &self.vis);
        for e in &mut d {
            for c in e.iter_mut() {
                *c /= std::f64::consts::PI;
            }
        }
        d
    }
}

/// What a light map on one atlas takes from geometry and lights alone, computed once with
/// rays and composed with any later light of the same mesh without a ray: per texel where its
/// light is read and the lights' direct part, per element the direct part to take out of the
/// field. What a live editor keeps while materials, and so the light, change (32 bytes a
/// texel).
#[derive(Clone, Debug)]
pub struct TexelBasis {
    /// Per page, each texel's triangle and weights ([`Atlas::owners`]).
    owners: Vec<Vec<TexelOwner>>,
    /// Per texel (pages one after the other): where its light is read (NaN: buried) and the
    /// lights' direct `H`.
    samples: Vec<([f32; 2], [f32; 3])>,
    /// Per element, the lights' direct `H` the field holds.
    element_direct: Vec<Rgb>,
    /// Per scene triangle, the bake's input triangle.
    roots: Vec<Option<u32>>,
}

impl TexelBasis {
    /// The basis of `scene`'s light map on `atlas`, for bakes on `mesh`, with the rays of
    /// `vis` (as [`compose_lightmap`] builds it).
    pub fn new<V: Visibility>(scene: &Scene, atlas: &Atlas, mesh: &Mesh, vis: V) -> TexelBasis {
        let lights = TexelLights::new(scene, atlas, mesh, vis);
        let owners: Vec<Vec<TexelOwner>> =
            (0..atlas.pages).map(|p| atlas.owners(scene, p)).collect();
        let samples = owners
            .par_iter()
            .flat_map_iter(|page| page.iter())
            .map(|o| {
                if o.triangle == u32::MAX {
                    return ([f32::NAN; 2], [0.0; 3]);
                }
                let s = lights.sample(o.triangle as usize, o.u, o.v);
                let at = s.at.map_or([f32::NAN; 2], |(a, b)| [a, b]);
                (at, s.direct.map(|x| x as f32))
            })
            .collect();
        TexelBasis {
            element_direct: lights.element_direct(mesh),
            owners,
            samples,
            roots: static_roots(scene),
        }
    }

    /// The light map of `field` (the whole light of a bake on the basis's mesh: its smooth
    /// field, as [`SmoothField::new`] or [`crate::smooth::exposed_field`] makes it), as
    /// [`compose_lightmap`] composes it (the lights' direct part rounded to `f32` first).
    pub fn compose(
        &self,
        scene: &Scene,
        atlas: &Atlas,
        mesh: &Mesh,
        field: &SmoothField,
    ) -> LightMap {
        let rest = field.minus(&self.element_direct);
        fill(
            scene,
            atlas,
            |page| {
                Cow::Borrowed(
                    self.owners
                        .get(page as usize)
                        .map_or(&[][..], Vec::as_slice),
                )
            },
            |k, _| {
                let (at, direct) = self
                    .samples
                    .get(k)
                    .copied()
                    .unwrap_or(([f32::NAN; 2], [0.0; 3]));
                TexelSample {
                    at: (!at[0].is_nan()).then_some((at[0], at[1])),
                    direct: direct.map(f64::from),
                }
            },
            |triangle, at| rest_at(mesh, &self.roots, &rest, triangle, at),
        )
    }
}

/// `H` of the field `rest` on scene triangle `triangle` at weights `at` (0 off the bake).
fn rest_at(
    mesh: &Mesh,
    roots: &[Option<u32>],
    rest: &SmoothField,
    triangle: usize,
    at: (f32, f32),
) -> Rgb {
    match roots.get(triangle).copied().flatten() {
        Some(root) if (root as usize) < mesh.roots.len() => {
            rest.irradiance(mesh, root, f64::from(at.0), f64::from(at.1))
        }
        _ => [0.0; 3],
    }
}

/// The light map on `atlas`: for each texel some triangle fills (`owners` of a page), its
/// [`TexelSample`] (`sample` of its index over all pages and its owner), `H` = `rest(triangle,
/// at)` + the sample's direct part, in parallel by rows; then the wholly buried texels from
/// their open neighbours.
fn fill<'a>(
    scene: &Scene,
    atlas: &Atlas,
    owners: impl Fn(u32) -> Cow<'a, [TexelOwner]>,
    sample: impl Fn(usize, &TexelOwner) -> TexelSample + Sync,
    rest: impl Fn(usize, (f32, f32)) -> Rgb + Sync,
) -> LightMap {
    let (width, height) = (atlas.width.max(1) as usize, atlas.height as usize);
    let size = width * height;
    let mut texels = vec![[0.0f32; 3]; size * atlas.pages as usize];
    for (page, texels) in texels.chunks_exact_mut(size.max(1)).enumerate() {
        let owners = owners(page as u32);
        if owners.len() != texels.len() {
            continue;
        }
        let mut buried = vec![false; size];
        texels
            .par_chunks_mut(width)
            .zip(owners.par_chunks(width))
            .zip(buried.par_chunks_mut(width))
            .enumerate()
            .for_each(|(y, ((row, owners), buried))| {
                for (x, ((t, o), b)) in row.iter_mut().zip(owners).zip(buried).enumerate() {
                    if o.triangle == u32::MAX {
                        continue;
                    }
                    let s = sample(page * size + y * width + x, o);
                    match s.at {
                        Some(at) => {
                            let h = rest(o.triangle as usize, at);
                            *t = std::array::from_fn(|c| (h[c] + s.direct[c]) as f32);
                        }
                        None => *b = true,
                    }
                }
            });
        dilate_buried(
            texels,
            &buried,
            &owners,
            scene,
            (width, 2.5 / atlas.density),
        );
    }
    LightMap {
        width: atlas.width,
        height: atlas.height,
        pages: atlas.pages,
        texels,
    }
}

/// Gives each wholly buried texel the mean of its open neighbours (8-connected) on the same
/// surface and near it in the scene (within `near`, scene units: the same chart, not one
/// packed beside it), so that bilinear filtering at a contact reads the light of the open side,
/// not black or light from under the occluder. One pass: filtering reads one texel deep.
fn dilate_buried(
    texels: &mut [[f32; 3]],
    buried: &[bool],
    owners: &[radiant_scene::atlas::TexelOwner],
    scene: &Scene,
    (width, near): (usize, f64),
) {
    if !buried.iter().any(|&b| b) {
        return;
    }
    let at = |k: usize| {
        let o = owners[k];
        scene
            .triangles
            .get(o.triangle as usize)
            .map(|t| (t.surface, texel_position(t.vertices, o.u, o.v)))
    };
    let same_place = |j: usize, k: usize| match (at(j), at(k)) {
        (Some((sj, pj)), Some((sk, pk))) => sj == sk && pj.distance(pk) <= near,
        _ => false,
    };
    let height = texels.len() / width.max(1);
    let mut out = Vec::new();
    for k in (0..buried.len()).filter(|&k| buried[k]) {
        let (x, y) = ((k % width) as i64, (k / width) as i64);
        let mut sum = [0.0f64; 3];
        let mut count = 0u32;
        for (dx, dy) in [
            (-1, -1),
            (0, -1),
            (1, -1),
            (-1, 0),
            (1, 0),
            (-1, 1),
            (0, 1),
            (1, 1),
        ] {
            let (nx, ny) = (x + dx, y + dy);
            if nx < 0 || ny < 0 || nx >= width as i64 || ny >= height as i64 {
                continue;
            }
            let j = (ny as usize) * width + nx as usize;
            if buried[j] || owners[j].triangle == u32::MAX || !same_place(j, k) {
                continue;
            }
            for c in 0..3 {
                sum[c] += f64::from(texels[j][c]);
            }
            count += 1;
        }
        if count > 0 {
            out.push((k, sum.map(|v| (v / f64::from(count)) as f32)));
        }
    }
    for (k, h) in out {
        texels[k] = h;
    }
}
