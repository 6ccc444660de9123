//! What the renderer shows at chosen surface points: the light map sampled there as the GPU
//! samples it (`H`), and the outgoing radiance `L = ρ(x) H + E(x)` with the albedo and emission
//! at the point itself, textures included. `L` is the quantity `radiant reference --points`
//! path-traces, so the two compare point by point (`radiant bake --points`).
//!
//! A point is found on the scene as the path tracer finds it: the nearest surface a short ray
//! from just above the point ([`lift`]: 0.5 % of the scene's radius), back along its normal,
//! meets within twice that, which must face the point (or be double-sided). The point is then
//! projected onto that triangle's plane.

use std::collections::HashMap;

use glam::{DVec3, Vec2};
use radiant_scene::atlas::Atlas;
use radiant_scene::texture::{TextureRef, barycentric};
use radiant_scene::{Scene, Triangle};
use rayon::prelude::*;

use crate::lightmap::{LightMap, static_roots};
use crate::metrics::{PointSpec, SurfaceMean};
use crate::system::Rgb;

/// How far above a point (along its normal) the locating ray starts, and half the distance it
/// searches, as a share of the scene's radius (half its bounding box's diagonal): the reference
/// path tracer's lift, so both find the same triangle (published quads are not always planar).
pub const LIFT: f64 = 5e-3;

/// [`LIFT`] in scene units: 0.5 % of half the diagonal of `scene`'s bounding box.
pub fn lift(scene: &Scene) -> f64 {
    let (lo, hi) = scene
        .triangles
        .iter()
        .flat_map(|t| t.vertices)
        .filter(|v| v.is_finite())
        .fold((DVec3::MAX, DVec3::MIN), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    let radius = 0.5 * (hi - lo).length();
    if radius.is_finite() {
        LIFT * radius
    } else {
        0.0
    }
}

/// What the renderer shows at one point.
#[derive(Clone, Debug, PartialEq)]
pub struct ShownPoint {
    /// The scene triangle the point lies on.
    pub triangle: u32,
    /// The point projected onto that triangle's plane.
    pub position: DVec3,
    /// The light map's value there (incident radiance, emissive units), bilinear as the
    /// renderer samples it.
    pub h: Rgb,
    /// Outgoing radiance: `H` times the albedo at the point plus its emission.
    pub l: Rgb,
}

/// Why a point has no value.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PointError {
    /// No light-mapped surface facing the point's normal within [`lift`] of it.
    #[error(
        "point {index} ('{name}') lies on no light-mapped surface that faces its normal (searched 0.5 % of the scene's radius either side along the normal)"
    )]
    OffSurface {
        /// Row of the point (0-based).
        index: usize,
        /// Its name.
        name: String,
    },
    /// The atlas is not the scene's (another triangle count), or a point's triangle is not in
    /// the scene.
    #[error("the atlas has {atlas} triangles but the scene {scene}")]
    AtlasMismatch {
        /// Triangles in the atlas.
        atlas: usize,
        /// Triangles in the scene.
        scene: usize,
    },
}

/// The light-mapped (static) triangle a point lies on and the point projected onto its plane,
/// as `radiant reference` locates it (see the module); `None` where there is none.
pub fn locate(scene: &Scene, position: DVec3, normal: DVec3) -> Option<(u32, DVec3)> {
    locate_among(scene, &static_roots(scene), lift(scene), position, normal)
}

/// [`locate`] among the triangles `roots` (from [`static_roots`]) marks as static.
fn locate_among(
    scene: &Scene,
    roots: &[Option<u32>],
    lift: f64,
    position: DVec3,
    normal: DVec3,
) -> Option<(u32, DVec3)> {
    let n = normal.try_normalize()?;
    if !position.is_finite() {
        return None;
    }
    let origin = position + n * lift;
    // The nearest face met, front or back (a front face wins a tie).
    let mut best: Option<(f64, bool, u32)> = None;
    for (i, t) in scene.triangles.iter().enumerate() {
        if roots.get(i).is_none_or(Option::is_none) {
            continue;
        }
        let Some((dist, front)) = hit(t, origin, -n) else {
            continue;
        };
        let nearer = best.is_none_or(|(d, f, _)| dist < d || (dist == d && front && !f));
        if dist <= 2.0 * lift && nearer {
            best = Some((dist, front, i as u32));
        }
    }
    let (_, front, i) = best?;
    let t = &scene.triangles[i as usize];
    let double_sided = scene
        .surfaces
        .get(t.surface as usize)
        .is_some_and(|s| s.double_sided);
    if !(front || double_sided) {
        return None;
    }
    let normal = t.cross().normalize();
    Some((
        i,
        position - normal * (position - t.vertices[0]).dot(normal),
    ))
}

/// Distance along `dir` from `origin` to triangle `t`, and whether it is met from the front
/// (Möller–Trumbore in f64, edges included).
fn hit(t: &Triangle, origin: DVec3, dir: DVec3) -> Option<(f64, bool)> {
    let [a, b, c] = t.vertices;
    let (e1, e2) = (b - a, c - a);
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - a;
    let u = s.dot(p) * inv;
    let q = s.cross(e1);
    let v = dir.dot(q) * inv;
    let eps = 1e-9;
    if u < -eps || v < -eps || u + v > 1.0 + eps {
        return None;
    }
    let dist = e2.dot(q) * inv;
    // det = −dir · (e1 × e2): positive where the ray meets the counter-clockwise (front) side.
    (dist >= 0.0).then_some((dist, det > 0.0))
}

/// Each of `points` located on `scene` (see [`locate`]): its triangle and the point on it.
///
/// # Errors
/// [`PointError::OffSurface`] for the first point on no light-mapped surface.
pub fn locate_all(scene: &Scene, points: &[PointSpec]) -> Result<Vec<(u32, DVec3)>, PointError> {
    let (roots, lift) = (static_roots(scene), lift(scene));
    points
        .par_iter()
        .enumerate()
        .map(|(index, p)| {
            locate_among(scene, &roots, lift, p.position, p.normal).ok_or_else(|| {
                PointError::OffSurface {
                    index,
                    name: p.name.clone(),
                }
            })
        })
        .collect()
}

/// What the renderer shows at each `located` point (from [`locate_all`]) of `scene`, whose
/// light map `map` lies on `atlas`.
///
/// # Errors
/// [`PointError::AtlasMismatch`] when `atlas` is not `scene`'s.
pub fn shown_at(
    scene: &Scene,
    atlas: &Atlas,
    map: &LightMap,
    located: &[(u32, DVec3)],
) -> Result<Vec<ShownPoint>, PointError> {
    if atlas.uv.len() != scene.triangles.len()
        || located
            .iter()
            .any(|&(i, _)| i as usize >= scene.triangles.len())
    {
        return Err(PointError::AtlasMismatch {
            atlas: atlas.uv.len(),
            scene: scene.triangles.len(),
        });
    }
    let means = texture_means(scene, located.iter().map(|&(i, _)| i));
    Ok(located
        .iter()
        .map(|&(i, x)| shown(scene, atlas, map, &means, i, x))
        .collect())
}

/// The means of the textures of the surfaces of `triangles`, by image: the albedo is
/// modulated by the texel over its image's mean (the surface's reflectance is its factor times
/// that mean, as the reference path tracer reads it).
fn texture_means(scene: &Scene, triangles: impl Iterator<Item = u32>) -> HashMap<u32, [f64; 4]> {
    let mut means: HashMap<u32, [f64; 4]> = HashMap::new();
    for i in triangles {
        let Some(t) = scene.triangles.get(i as usize) else {
            continue;
        };
        let Some(s) = scene.surfaces.get(t.surface as usize) else {
            continue;
        };
        for t in [s.base_color_texture, s.emissive_texture]
            .into_iter()
            .flatten()
        {
            if let Some(image) = scene.images.get(t.image as usize) {
                means.entry(t.image).or_insert_with(|| image.mean_linear());
            }
        }
    }
    means
}

/// What the renderer shows at `x` on triangle `i` (on the atlas: checked by the caller).
fn shown(
    scene: &Scene,
    atlas: &Atlas,
    map: &LightMap,
    means: &HashMap<u32, [f64; 4]>,
    i: u32,
    x: DVec3,
) -> ShownPoint {
    let t = &scene.triangles[i as usize];
    let s = &scene.surfaces[t.surface as usize];
    let b = barycentric(t.vertices, x);
    let uv = atlas.uv[i as usize];
    let at = |k: usize| {
        f64::from(uv[0][k]) * b[0] + f64::from(uv[1][k]) * b[1] + f64::from(uv[2][k]) * b[2]
    };
    let page = atlas.page.get(i as usize).copied().unwrap_or(0);
    let h = map.sample(page, [at(0), at(1)]);
    let raw: [Vec2; 2] = std::array::from_fn(|set| {
        let u = t.uv[set];
        (u[0].as_dvec2() * b[0] + u[1].as_dvec2() * b[1] + u[2].as_dvec2() * b[2]).as_vec2()
    });
    let modulation = |texture: Option<TextureRef>| -> [f64; 3] {
        let Some(tex) = texture else {
            return [1.0; 3];
        };
        let Some(mean) = means.get(&tex.image) else {
            return [1.0; 3];
        };
        let texel = tex.sample_linear(&scene.images, tex.uv(raw));
        std::array::from_fn(|c| {
            if mean[c] > 0.0 {
                f64::from(texel[c]) / mean[c]
            } else {
                1.0
            }
        })
    };
    let (kr, ke) = (
        modulation(s.base_color_texture),
        modulation(s.emissive_texture),
    );
    let l = std::array::from_fn(|c| {
        (s.reflectance[c] * kr[c]).clamp(0.0, 1.0) * h[c] + s.emission[c] * ke[c]
    });
    ShownPoint {
        triangle: i,
        position: x,
        h,
        l,
    }
}

/// Most samples along a triangle's edge in [`surface_means`] (so at most `MAX_SPLIT²` per
/// triangle): a 20 m floor of two triangles under 5 000 boxes needs its texels' worth (1 400
/// a side), or a coarser lattice beats against the boxes' grid.
pub const MAX_SPLIT: u32 = 4096;

/// Samples per texel along a triangle's edge in [`surface_means`]: a sample every two texels,
/// which the bilinear ramps between texel centres average over.
const SAMPLES_PER_TEXEL: f64 = 0.5;

/// The mean over each static surface of what the renderer shows (`L`, as [`shown_at`]
/// computes it at a point), area-weighted: the light map's counterpart of the bake's
/// `surfaces.csv` (the solution's means) and of `radiant reference`'s (the path tracer's), so
/// that the three compare surface by surface and the light lost in the solution is told apart
/// from the light lost in its reconstruction into texels. A point where `open(triangle, x)` is
/// false (inside or under other geometry: nobody sees it) counts dark, as the path tracer,
/// which samples the whole surface, finds it.
///
/// Each triangle is cut into `n²` equal sub-triangles and `L` taken at their centroids, `n`
/// half its longest edge on the atlas in texels (rounded up; 1 to [`MAX_SPLIT`]). Surfaces without
/// a static triangle are left out, as in `surfaces.csv`; areas in scene units².
///
/// # Errors
/// [`PointError::AtlasMismatch`] when `atlas` is not `scene`'s.
pub fn surface_means(
    scene: &Scene,
    atlas: &Atlas,
    map: &LightMap,
    open: impl Fn(u32, DVec3) -> bool + Sync,
) -> Result<Vec<SurfaceMean>, PointError> {
    if atlas.uv.len() != scene.triangles.len() {
        return Err(PointError::AtlasMismatch {
            atlas: atlas.uv.len(),
            scene: scene.triangles.len(),
        });
    }
    let roots = static_roots(scene);
    let lit: Vec<u32> = (0..scene.triangles.len() as u32)
        .filter(|&i| roots[i as usize].is_some())
        .collect();
    let means = texture_means(scene, lit.iter().copied());
    let side = f64::from(map.width.max(map.height));
    // Per triangle: its surface, area and the mean of L over it (f64 throughout).
    let per_triangle: Vec<(u32, f64, Rgb)> = lit
        .par_iter()
        .map(|&i| {
            let t = &scene.triangles[i as usize];
            let uv = atlas.uv[i as usize];
            let edge = (0..3)
                .map(|k| (uv[(k + 1) % 3] - uv[k]).length())
                .fold(0.0f32, f32::max);
            let n = (f64::from(edge) * side * SAMPLES_PER_TEXEL)
                .ceil()
                .clamp(1.0, f64::from(MAX_SPLIT)) as u32;
            let mut sum = [0.0; 3];
            for (b1, b2) in lattice(n) {
                let x = t.vertices[0] * (1.0 - b1 - b2) + t.vertices[1] * b1 + t.vertices[2] * b2;
                if !open(i, x) {
                    continue;
                }
                let l = shown(scene, atlas, map, &means, i, x).l;
                for c in 0..3 {
                    sum[c] += l[c];
                }
            }
            let k = f64::from(n * n);
            (t.surface, t.area(), sum.map(|v| v / k))
        })
        .collect();
    let mut acc = vec![(0.0, [0.0; 3]); scene.surfaces.len()];
    for (s, area, l) in per_triangle {
        let a = &mut acc[s as usize];
        a.0 += area;
        for c in 0..3 {
            a.1[c] += area * l[c];
        }
    }
    Ok(scene
        .surfaces
        .iter()
        .zip(acc)
        .filter(|(_, (a, _))| *a > 0.0)
        .map(|(s, (a, m))| SurfaceMean {
            name: s.name.clone(),
            area: a,
            mean: m.map(|v| v / a),
            emitter: s.is_emitter(),
        })
        .collect())
}

/// The centroids of the `n²` equal sub-triangles of a triangle cut `n` times along each edge,
/// as barycentric `(b1, b2)` (the weight of the first vertex is `1 − b1 − b2`).
pub fn lattice(n: u32) -> impl Iterator<Item = (f64, f64)> {
    let f = f64::from(n);
    (0..n).flat_map(move |i| {
        (0..n - i).flat_map(move |j| {
            let (i, j) = (f64::from(i), f64::from(j));
            let up = ((i + 1.0 / 3.0) / f, (j + 1.0 / 3.0) / f);
            let down = ((i + 2.0 / 3.0) / f, (j + 2.0 / 3.0) / f);
            // The sub-triangle pointing down exists where one more fits: i + j ≤ n − 2.
            let has_down = i + j + 2.0 <= f;
            std::iter::once(up).chain(has_down.then_some(down))
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use radiant_scene::Surface;

    fn quad_scene(double_sided: bool) -> Scene {
        let v = |x: f64, z: f64| DVec3::new(x, 0.0, z);
        let mut scene = Scene::default();
        scene.surfaces.push(Surface {
            name: "floor".into(),
            reflectance: [0.5, 0.25, 0.125],
            double_sided,
            ..Surface::default()
        });
        // Counter-clockwise seen from +y.
        scene
            .triangles
            .push(Triangle::new([v(0.0, 0.0), v(0.0, 1.0), v(1.0, 1.0)], 0));
        scene
            .triangles
            .push(Triangle::new([v(0.0, 0.0), v(1.0, 1.0), v(1.0, 0.0)], 0));
        scene
    }

    #[test]
    fn a_point_is_found_on_the_face_it_looks_at() {
        let scene = quad_scene(false);
        let up = DVec3::Y;
        // The floor's radius is 0.71: points within 3.5 mm of it are on it.
        let (t, x) = locate(&scene, DVec3::new(0.25, 0.003, 0.75), up).expect("on the floor");
        assert_eq!(t, 0);
        assert_eq!(x, DVec3::new(0.25, 0.0, 0.75));
        assert_eq!(
            locate(&scene, DVec3::new(0.75, -0.003, 0.25), up).map(|h| h.0),
            Some(1)
        );
        // Too far off, outside, or looking at its back.
        assert_eq!(locate(&scene, DVec3::new(0.25, 0.02, 0.75), up), None);
        assert_eq!(locate(&scene, DVec3::new(1.5, 0.0, 0.5), up), None);
        assert_eq!(locate(&scene, DVec3::new(0.25, 0.0, 0.75), -up), None);
        assert_eq!(locate(&scene, DVec3::new(f64::NAN, 0.0, 0.5), up), None);
        assert!(locate(&quad_scene(true), DVec3::new(0.25, 0.0, 0.75), -up).is_some());
    }

    #[test]
    fn the_light_map_is_sampled_bilinearly_and_clamped_at_its_edge() {
        // 2 × 1 texels: 0 and 1 in red.
        let map = LightMap {
            width: 2,
            height: 1,
            pages: 1,
            texels: vec![[0.0, 2.0, 0.0], [1.0, 2.0, 0.0]],
        };
        assert_eq!(map.sample(0, [0.25, 0.5]), [0.0, 2.0, 0.0]);
        assert_eq!(map.sample(0, [0.5, 0.5]), [0.5, 2.0, 0.0]);
        assert_eq!(map.sample(0, [0.625, 0.5]), [0.75, 2.0, 0.0]);
        assert_eq!(map.sample(0, [0.0, 0.0]), [0.0, 2.0, 0.0]);
        assert_eq!(map.sample(0, [1.0, 1.0]), [1.0, 2.0, 0.0]);
        assert_eq!(map.sample(1, [0.5, 0.5]), [0.0; 3]);
        assert_eq!(map.sample(0, [f64::NAN, 0.5]), [0.0; 3]);
    }

    #[test]
    fn outgoing_radiance_is_the_albedo_times_the_light_map() {
        let scene = quad_scene(false);
        let atlas = Atlas::new(&scene, Some(8.0)).expect("atlas");
        // A uniform map: every point reads it exactly, whatever the charts.
        let map = LightMap {
            width: atlas.width,
            height: atlas.height,
            pages: atlas.pages,
            texels: vec![[2.0, 4.0, 8.0]; (atlas.width * atlas.height * atlas.pages) as usize],
        };
        let points = [PointSpec {
            name: "p".into(),
            position: DVec3::new(0.3, 0.001, 0.6),
            normal: DVec3::Y,
        }];
        let located = locate_all(&scene, &points).expect("located");
        let shown = shown_at(&scene, &atlas, &map, &located).expect("on the atlas");
        assert_eq!(shown[0].h, [2.0, 4.0, 8.0]);
        assert_eq!(shown[0].l, [1.0, 1.0, 1.0]);
        let off = [PointSpec {
            position: DVec3::new(3.0, 0.0, 0.0),
            ..points[0].clone()
        }];
        assert!(matches!(
            locate_all(&scene, &off),
            Err(PointError::OffSurface { index: 0, .. })
        ));
    }

    #[test]
    fn the_lattice_cuts_a_triangle_into_equal_parts() {
        for n in [1, 2, 3, 7, 32, 301] {
            let points: Vec<_> = lattice(n).collect();
            assert_eq!(points.len(), (n * n) as usize);
            assert!(
                points
                    .iter()
                    .all(|&(a, b)| a > 0.0 && b > 0.0 && a + b < 1.0)
            );
            // Equal parts: the mean of a linear function is its value at the centroid.
            let k = f64::from(n * n);
            let mean_b1 = points.iter().map(|p| p.0).sum::<f64>() / k;
            let mean_b2 = points.iter().map(|p| p.1).sum::<f64>() / k;
            assert!((mean_b1 - 1.0 / 3.0).abs() < 1e-12, "n {n}: {mean_b1}");
            assert!((mean_b2 - 1.0 / 3.0).abs() < 1e-12, "n {n}: {mean_b2}");
        }
    }

    #[test]
    fn a_surface_mean_is_the_area_weighted_mean_of_what_is_shown() {
        let mut scene = quad_scene(false);
        // A second surface, 2 m² and emitting, on the far side of x = 1.
        scene.surfaces.push(Surface {
            name: "lamp".into(),
            reflectance: [0.0; 3],
            emission: [3.0, 3.0, 3.0],
            ..Surface::default()
        });
        let v = |x: f64, z: f64| DVec3::new(x, 0.0, z);
        scene
            .triangles
            .push(Triangle::new([v(2.0, 0.0), v(2.0, 2.0), v(4.0, 2.0)], 1));
        let atlas = Atlas::new(&scene, Some(8.0)).expect("atlas");
        let map = LightMap {
            width: atlas.width,
            height: atlas.height,
            pages: atlas.pages,
            texels: vec![[2.0, 4.0, 8.0]; (atlas.width * atlas.height * atlas.pages) as usize],
        };
        let means = surface_means(&scene, &atlas, &map, |_, _| true).expect("on the atlas");
        assert_eq!(means.len(), 2);
        assert_eq!(means[0].name, "floor");
        assert!((means[0].area - 1.0).abs() < 1e-12);
        assert!(
            means[0].mean.iter().all(|&l| (l - 1.0).abs() < 1e-12),
            "{:?}",
            means[0].mean
        );
        assert!(!means[0].emitter);
        assert!((means[1].area - 2.0).abs() < 1e-12);
        assert_eq!(means[1].mean, [3.0; 3]);
        assert!(means[1].emitter);
        // Points that nobody sees (here the half x < 0.5 of the floor) count dark.
        let half = surface_means(&scene, &atlas, &map, |_, x| x.x >= 0.5).expect("on the atlas");
        assert!(
            half[0].mean.iter().all(|&l| (l - 0.5).abs() < 0.02),
            "{:?}",
            half[0].mean
        );
        assert!((half[0].area - 1.0).abs() < 1e-12);
        // A map that is not the scene's is refused.
        let mut other = scene.clone();
        other.triangles.pop();
        assert!(matches!(
            surface_means(&other, &atlas, &map, |_, _| true),
            Err(PointError::AtlasMismatch { .. })
        ));
    }
}
