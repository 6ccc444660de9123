//! The bake's input, scene → per-element terms, shared by every bake path (per-triangle,
//! clustered, edits):
//!
//! - [`visibility`]: the BVH over the input triangles, with the scene's alpha masks (a ray passes
//!   a masked triangle where its alpha is below the cutoff, in every query);
//! - [`ElementTextures`]: per element, how its own UV footprint's texture mean differs from the
//!   whole texture's (the surface's reflectance and emission hold the whole texture's mean, so a
//!   colour edit scales them and the footprints stay);
//! - [`materials`]: per-element reflectance and emission;
//! - [`direct_irradiance`]: light that arrives without a bounce from the punctual lights
//!   ([`crate::lights`]) and the sky ([`sky_irradiance`]), shadowed;
//! - [`sources`]: `S = E + ρ · E_direct / π`;
//! - [`Lighting`]: all of that kept for one mesh, so edits of materials or lights recompute
//!   only what they change;
//! - [`static_scene`] and [`validate`]: what takes part in a bake, and refusing what cannot.

use std::sync::Arc;

use glam::{DVec3, Vec2, Vec3};
use radiant_scene::texture::{Pyramid, barycentric};
use radiant_scene::{AlphaMasks, Light, Scene, Sky, Surface, TextureRef};
use radiant_visibility::{Bvh, Ends, Hit, Patched, Visibility};
use rayon::prelude::*;

use crate::mesh::{Frame, Mesh};
use crate::{BakeError, FormFactorParams, MaterialError, ParameterError, Rgb, SceneError};

/// The part of the scene a bake lights: dynamic surfaces take no part.
pub fn static_scene(scene: &Scene) -> std::borrow::Cow<'_, Scene> {
    if scene.surfaces.iter().any(|s| s.dynamic) {
        std::borrow::Cow::Owned(scene.static_part())
    } else {
        std::borrow::Cow::Borrowed(scene)
    }
}

/// Refuses materials out of range (reflectance outside [0, 1], negative or non-finite
/// emission) and triangles that name no surface.
pub fn validate(scene: &Scene) -> Result<(), BakeError> {
    validate_surfaces(&scene.surfaces)?;
    let surfaces = scene.surfaces.len();
    if let Some((triangle, t)) = scene
        .triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.surface as usize >= surfaces)
    {
        return Err(SceneError::UnknownSurface {
            triangle,
            surface: t.surface as usize,
            surfaces,
        }
        .into());
    }
    Ok(())
}

/// Refuses materials out of range, naming the surface.
pub fn validate_surfaces(surfaces: &[Surface]) -> Result<(), BakeError> {
    for s in surfaces {
        let bad = |what: MaterialError| BakeError::InvalidMaterial {
            surface: s.name.clone(),
            what,
        };
        if s.reflectance
            .iter()
            .any(|r| !r.is_finite() || !(0.0..=1.0).contains(r))
        {
            return Err(bad(MaterialError::Reflectance(s.reflectance)));
        }
        if s.emission.iter().any(|e| !e.is_finite() || *e < 0.0) {
            return Err(bad(MaterialError::Emission(s.emission)));
        }
    }
    Ok(())
}

/// Refuses lights with non-finite or negative values, naming the light.
pub fn validate_lights(lights: &[Light]) -> Result<(), BakeError> {
    for l in lights {
        let finite = l.position.is_finite()
            && l.direction.is_finite()
            && l.intensity.is_finite()
            && l.color.iter().all(|c| c.is_finite());
        if !finite || l.intensity < 0.0 || l.color.iter().any(|&c| c < 0.0) {
            return Err(ParameterError::BadLight {
                light: l.name.clone(),
            }
            .into());
        }
    }
    Ok(())
}

/// What lights one mesh's elements besides their own emission: the punctual lights and the
/// sky with their shadowed direct irradiance, the alpha masks their shadow rays pass, and the
/// textures' footprints.
#[derive(Clone, Debug)]
pub struct Lighting {
    /// The punctual lights.
    pub lights: Vec<Light>,
    /// The sky.
    pub sky: Option<Sky>,
    /// The alpha masks.
    pub masks: Option<Arc<AlphaMasks>>,
    /// Per element: the textures' footprints.
    pub textures: Option<ElementTextures>,
    /// Per element: irradiance from the lights and the sky ([`direct_irradiance`]).
    pub direct: Option<Vec<Rgb>>,
    /// What the footprints were read from: the scene's images, and per input triangle a hash
    /// of its texture coordinates and its surface's textures (empty without textures).
    sources: TextureSources,
}

/// See [`Lighting`]'s `sources`.
#[derive(Clone, Debug, Default)]
struct TextureSources {
    images: Vec<radiant_scene::texture::Image>,
    keys: Vec<u64>,
}

impl TextureSources {
    fn new(scene: &Scene) -> TextureSources {
        if !scene.surfaces.iter().any(textured) {
            return TextureSources::default();
        }
        let surface: Vec<u64> = (scene.surfaces.iter())
            .map(|s| {
                let mut h = crate::rng::Fnv::new();
                h.bytes(format!("{:?}|{:?}", s.base_color_texture, s.emissive_texture).as_bytes());
                h.0
            })
            .collect();
        let keys = (scene.triangles.par_iter())
            .map(|t| {
                let mut h = crate::rng::Fnv(surface.get(t.surface as usize).copied().unwrap_or(0));
                for uv in t.uv.iter().flatten() {
                    h.bytes(&uv.x.to_bits().to_le_bytes());
                    h.bytes(&uv.y.to_bits().to_le_bytes());
                }
                h.0
            })
            .collect();
        TextureSources {
            images: scene.images.clone(),
            keys,
        }
    }
}

impl Lighting {
    /// The scene's lighting of `mesh`, whose ray tracer `bvh` was built with `masks`.
    pub fn new(
        scene: &Scene,
        mesh: &Mesh,
        bvh: &Bvh,
        masks: Option<Arc<AlphaMasks>>,
        params: &FormFactorParams,
    ) -> Lighting {
        Lighting {
            lights: scene.lights.clone(),
            sky: scene.sky.clone(),
            masks,
            sources: TextureSources::new(scene),
            textures: element_textures(scene, mesh),
            direct: direct_irradiance(&scene.lights, scene.sky.as_ref(), mesh, bvh, params),
        }
    }

    /// Whether `scene`'s textures would give the same footprints as this lighting's: the same
    /// images, and every input triangle's texture coordinates and surface's textures.
    pub(crate) fn same_textures(&self, scene: &Scene) -> bool {
        let now = TextureSources::new(scene);
        now.keys == self.sources.keys && now.images == self.sources.images
    }

    /// The lighting of an edited scene, as [`Lighting::new`] makes it: the texture footprints
    /// of elements that stayed (`old_of_new_leaf`, against `old`'s mesh), on input triangles
    /// whose texture coordinates and surface's textures are the same, over the same images,
    /// are `old`'s, not read again.
    pub(crate) fn edited(
        scene: &Scene,
        (mesh, old_of_new_leaf): (&Mesh, &[u32]),
        bvh: &Bvh,
        masks: Option<Arc<AlphaMasks>>,
        params: &FormFactorParams,
        (old, old_mesh): (&Lighting, &Mesh),
    ) -> Lighting {
        let sources = TextureSources::new(scene);
        let kept = |leaf: usize| -> Option<(Rgb, Rgb)> {
            let t = old.textures.as_ref()?;
            let o = *old_of_new_leaf.get(leaf)? as usize;
            let root = mesh.leaf_node(leaf as u32).root as usize;
            let old_root = old_mesh.nodes[*old_mesh.leaves.get(o)? as usize].root as usize;
            let same = sources.keys.get(root)? == old.sources.keys.get(old_root)?;
            same.then(|| Some((*t.reflectance.get(o)?, *t.emission.get(o)?)))
                .flatten()
        };
        let textures = if old.sources.images == scene.images {
            element_textures_keeping(scene, mesh, &kept)
        } else {
            element_textures(scene, mesh)
        };
        Lighting {
            lights: scene.lights.clone(),
            sky: scene.sky.clone(),
            masks,
            sources,
            textures,
            direct: direct_irradiance(&scene.lights, scene.sky.as_ref(), mesh, bvh, params),
        }
    }

    /// Per element: reflectance and the source term `S` of `surfaces` under this lighting.
    pub fn terms(&self, surfaces: &[Surface], mesh: &Mesh) -> (Vec<Rgb>, Vec<Rgb>) {
        let (rho, emission) = materials(surfaces, mesh, self.textures.as_ref());
        let source = sources(&rho, &emission, self.direct.as_deref());
        (rho, source)
    }

    /// The same textures under other lights and sky: their direct light is traced again.
    pub fn relit(
        &self,
        lights: &[Light],
        sky: Option<&Sky>,
        mesh: &Mesh,
        params: &FormFactorParams,
    ) -> Lighting {
        let direct = (!lights.is_empty() || sky.is_some()).then(|| {
            let bvh = visibility(mesh, self.masks.as_ref());
            direct_irradiance(lights, sky, mesh, &bvh, params)
        });
        Lighting {
            lights: lights.to_vec(),
            sky: sky.cloned(),
            masks: self.masks.clone(),
            textures: self.textures.clone(),
            sources: self.sources.clone(),
            direct: direct.flatten(),
        }
    }
}

/// The alpha masks of the scene's triangles, `None` when nothing is masked.
pub fn masks(scene: &Scene) -> Option<Arc<AlphaMasks>> {
    let masks = AlphaMasks::new(scene)?;
    let [opaque, cut, mixed] = masks.counts;
    tracing::info!(
        opaque,
        cut,
        mixed,
        "alpha masks: triangles of masked surfaces wholly opaque, wholly cut and mixed"
    );
    Some(Arc::new(masks))
}

/// The BVH over the mesh's input triangles (the scene's, in order), with alpha masks.
pub fn visibility(mesh: &Mesh, masks: Option<&Arc<AlphaMasks>>) -> Bvh {
    bvh_over(&mesh.root_triangles_f32(), masks)
}

/// The BVH [`visibility`] builds for any mesh of `scene`, built from the scene alone: its
/// triangles in order, in the frame the mesh is made in ([`crate::mesh::Frame::of`]). For work
/// that needs the rays before the bake's mesh of the scene exists (the ECS probes start on it
/// as soon as an edit is made). The same errors as meshing the scene for a scene without
/// triangles, of zero extent or with a vertex that is not finite.
pub fn scene_visibility(scene: &Scene, masks: Option<&Arc<AlphaMasks>>) -> Result<Bvh, BakeError> {
    let frame = crate::mesh::Frame::of(scene)?;
    let tris: Vec<[Vec3; 3]> = (scene.triangles.iter())
        .map(|t| t.vertices.map(|p| frame.to_local(p).as_vec3()))
        .collect();
    Ok(bvh_over(&tris, masks))
}

/// Rays over a scene's triangles ([`scene_visibility`]) that follow its edits cheaply: the
/// BVH of one version of the scene is kept with a fingerprint of each triangle; a later
/// version with as many triangles and the same frame (a prop moved, turned or reshaped) is
/// traced as that BVH without the triangles that changed and with a small BVH over them where
/// they are now ([`Patched`], renumbered to the scene's indices), built in milliseconds where
/// a level's whole BVH takes most of a second. Alpha masks go with a triangle's index: a
/// changed triangle must keep its surface and texture coordinates to be patched.
pub struct SceneRays {
    bvh: Arc<Bvh>,
    frame: Frame,
    /// Per triangle: its vertices' fingerprint, and its surface's and UVs'.
    prints: Vec<(u64, u64)>,
    masks: Option<Arc<AlphaMasks>>,
}

/// The rays over one version of a scene: its own BVH, or an earlier version's patched.
pub enum Rays {
    /// The scene's own BVH.
    Built(Arc<Bvh>),
    /// An earlier version's BVH without the triangles that changed, with them as they are now.
    Patched(Box<Patched<Arc<Bvh>>>),
}

impl SceneRays {
    /// The largest share of a scene's triangles a patch replaces; past it the BVH is built
    /// again (each ray walks the base's removed triangles too, and the added ones' BVH: at
    /// most about twice the work of the scene's own).
    pub const MAX_PATCHED: f64 = 0.5;

    /// Builds the rays of `scene` (its alpha masks included). The same errors as meshing it.
    pub fn new(scene: &Scene) -> Result<SceneRays, BakeError> {
        let masks = masks(scene);
        let bvh = Arc::new(scene_visibility(scene, masks.as_ref())?);
        Ok(SceneRays {
            bvh,
            frame: Frame::of(scene)?,
            prints: scene.triangles.par_iter().map(prints).collect(),
            masks,
        })
    }

    /// The rays of the scene these were built for.
    pub fn rays(&self) -> Rays {
        Rays::Built(self.bvh.clone())
    }

    /// The rays of `scene`, a later version of the one these were built for: `None` when it
    /// has another triangle count or frame, a changed triangle another surface or UVs, or
    /// more than [`SceneRays::MAX_PATCHED`] of its triangles changed (build them again).
    pub fn patched(&self, scene: &Scene) -> Option<Rays> {
        if scene.triangles.len() != self.prints.len() || Frame::of(scene).ok()? != self.frame {
            return None;
        }
        let now: Vec<(u64, u64)> = scene.triangles.par_iter().map(prints).collect();
        let removed: Vec<bool> = (now.iter().zip(&self.prints))
            .map(|(a, b)| a.0 != b.0)
            .collect();
        let ids: Vec<u32> = (0..removed.len() as u32)
            .filter(|&i| removed[i as usize])
            .collect();
        let kept_attributes = ids
            .iter()
            .all(|&i| now[i as usize].1 == self.prints[i as usize].1);
        if !kept_attributes || ids.len() as f64 > Self::MAX_PATCHED * removed.len() as f64 {
            return None;
        }
        let tris: Vec<[Vec3; 3]> = (ids.iter())
            .map(|&i| {
                (scene.triangles[i as usize].vertices).map(|p| self.frame.to_local(p).as_vec3())
            })
            .collect();
        let added = masked_bvh(&tris, self.masks.as_ref(), Some(Arc::new(ids.clone())));
        Some(Rays::Patched(Box::new(
            Patched::new(self.bvh.clone(), removed, added).renumbered(ids),
        )))
    }
}

/// A triangle's fingerprints: of its vertices, and of its surface and texture coordinates.
fn prints(t: &radiant_scene::Triangle) -> (u64, u64) {
    let mix = |h: u64, x: u64| {
        // SplitMix64's finaliser over the running hash and the next word.
        let mut z = (h ^ x).wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    let vertices = (t.vertices.iter())
        .flat_map(|v| v.to_array())
        .fold(0, |h, x| mix(h, x.to_bits()));
    let uv = (t.uv.iter().flatten())
        .flat_map(|v| v.to_array())
        .fold(u64::from(t.surface), |h, x| mix(h, u64::from(x.to_bits())));
    (vertices, uv)
}

impl Visibility for Rays {
    fn segment_clear(&self, a: Vec3, b: Vec3) -> bool {
        match self {
            Rays::Built(bvh) => bvh.segment_clear(a, b),
            Rays::Patched(p) => p.segment_clear(a, b),
        }
    }
    fn segment_clear_between(&self, a: Vec3, b: Vec3, ends: &Ends) -> bool {
        match self {
            Rays::Built(bvh) => bvh.segment_clear_between(a, b, ends),
            Rays::Patched(p) => p.segment_clear_between(a, b, ends),
        }
    }
    fn segment_clear_hinted(
        &self,
        a: Vec3,
        b: Vec3,
        ends: Option<&Ends>,
        blocker: &mut u32,
    ) -> bool {
        match self {
            Rays::Built(bvh) => bvh.segment_clear_hinted(a, b, ends, blocker),
            Rays::Patched(p) => p.segment_clear_hinted(a, b, ends, blocker),
        }
    }
    fn closest_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        match self {
            Rays::Built(bvh) => bvh.closest_hit(origin, dir, tmax),
            Rays::Patched(p) => p.closest_hit(origin, dir, tmax),
        }
    }
    fn shaft_clear(
        &self,
        a: &[DVec3; 3],
        na: DVec3,
        b: &[DVec3; 3],
        nb: DVec3,
        witness: &mut u32,
    ) -> bool {
        match self {
            Rays::Built(bvh) => bvh.shaft_clear(a, na, b, nb, witness),
            Rays::Patched(p) => p.shaft_clear(a, na, b, nb, witness),
        }
    }
}

/// The BVH over triangles (the scene's, in order, in the mesh's frame), with alpha masks.
fn bvh_over(tris: &[[Vec3; 3]], masks: Option<&Arc<AlphaMasks>>) -> Bvh {
    masked_bvh(tris, masks, None)
}

/// The BVH over triangles whose `k`-th is scene triangle `ids[k]` (`None`: `k` itself), each
/// with its alpha mask.
fn masked_bvh(
    tris: &[[Vec3; 3]],
    masks: Option<&Arc<AlphaMasks>>,
    ids: Option<Arc<Vec<u32>>>,
) -> Bvh {
    let Some(masks) = masks else {
        return Bvh::new(tris);
    };
    let id = move |k: u32| ids.as_ref().map_or(k, |ids| ids[k as usize]);
    let (marks, masks, id2) = (Arc::clone(masks), Arc::clone(masks), id.clone());
    Bvh::with_filter(
        tris,
        move |k| marks.is_masked(id(k)),
        Arc::new(move |k, u, v| masks.blocks(id2(k), u, v)),
    )
}

/// Per element: its UV footprint's texture mean over the whole texture's, per channel, for
/// reflectance and emission (1 where a surface has no texture).
#[derive(Clone, Debug, PartialEq)]
pub struct ElementTextures {
    /// Multiplies the surface's reflectance.
    pub reflectance: Vec<Rgb>,
    /// Multiplies the surface's emission.
    pub emission: Vec<Rgb>,
}

/// The footprints of `scene`'s textures on `mesh`'s elements, or `None` when no surface has a
/// texture (nothing to compute).
pub fn element_textures(scene: &Scene, mesh: &Mesh) -> Option<ElementTextures> {
    element_textures_keeping(scene, mesh, &|_| None)
}

/// Whether a surface has a texture whose footprints an element takes.
fn textured(s: &Surface) -> bool {
    s.base_color_texture.is_some() || s.emissive_texture.is_some()
}

/// [`element_textures`], where `kept(element)` may give an element's footprints (reflectance,
/// emission) without reading them: only the images that the others read are filtered.
pub(crate) fn element_textures_keeping(
    scene: &Scene,
    mesh: &Mesh,
    kept: &(dyn Fn(usize) -> Option<(Rgb, Rgb)> + Sync),
) -> Option<ElementTextures> {
    if !scene.surfaces.iter().any(textured) || mesh.roots.len() != scene.triangles.len() {
        return None;
    }
    let surface_of = |leaf: usize| {
        let root = mesh.leaf_node(leaf as u32).root as usize;
        let tri = scene.triangles.get(root)?;
        Some((tri, scene.surfaces.get(tri.surface as usize)?))
    };
    let kept: Vec<Option<(Rgb, Rgb)>> = (0..mesh.element_count())
        .into_par_iter()
        .with_min_len(1024)
        .map(kept)
        .collect();
    // One pyramid per image a texture of an element not kept reads, built in parallel.
    let mut used = vec![false; scene.images.len()];
    let mut seen = vec![false; scene.surfaces.len()];
    for (leaf, k) in kept.iter().enumerate() {
        let Some((tri, s)) = surface_of(leaf).filter(|_| k.is_none()) else {
            continue;
        };
        if std::mem::replace(&mut seen[tri.surface as usize], true) {
            continue;
        }
        for t in [s.base_color_texture, s.emissive_texture]
            .into_iter()
            .flatten()
        {
            if let Some(u) = used.get_mut(t.image as usize) {
                *u = true;
            }
        }
    }
    let pyramids = texture_pyramids(&scene.images, used);
    let n = mesh.element_count();
    let mut out = ElementTextures {
        reflectance: vec![[1.0; 3]; n],
        emission: vec![[1.0; 3]; n],
    };
    let ratio = |t: &TextureRef, tri: &radiant_scene::Triangle, corners: [[f64; 3]; 3]| {
        footprint_ratio(&pyramids, t, tri, corners)
    };
    out.reflectance
        .par_iter_mut()
        .zip(out.emission.par_iter_mut())
        .enumerate()
        .with_min_len(256)
        .for_each(|(leaf, (rho, emit))| {
            if let Some((r, e)) = kept[leaf] {
                (*rho, *emit) = (r, e);
                return;
            }
            let node = mesh.leaf_node(leaf as u32);
            let root = node.root as usize;
            let (Some(tri), Some(&root_node)) = (scene.triangles.get(root), mesh.roots.get(root))
            else {
                return;
            };
            let Some(s) = scene.surfaces.get(tri.surface as usize) else {
                return;
            };
            if !textured(s) {
                return;
            }
            // The element's corners as barycentrics of its input triangle (both in the local
            // frame), then as texture coordinates.
            let rv = mesh.nodes[root_node as usize].v;
            let corners = node.v.map(|p| barycentric(rv, p));
            if let Some(t) = &s.base_color_texture {
                *rho = ratio(t, tri, corners);
            }
            if let Some(t) = &s.emissive_texture {
                *emit = ratio(t, tri, corners);
            }
        });
    Some(out)
}

/// One linear-light mip chain, and the image's mean, per image `used` marks (built in
/// parallel), for [`footprint_ratio`].
pub fn texture_pyramids(
    images: &[radiant_scene::Image],
    used: Vec<bool>,
) -> Vec<Option<(Pyramid, [f64; 4])>> {
    images
        .par_iter()
        .zip(used)
        .map(|(img, u)| u.then(|| (Pyramid::new(img), img.mean_linear())))
        .collect()
}

/// The mean of texture `t` over the part of `tri` with barycentric corners `corners`, over the
/// whole image's mean, per channel: what multiplies the surface's reflectance (or emission)
/// there. 1 where the image has no pyramid or a channel's mean is 0.
pub fn footprint_ratio(
    pyramids: &[Option<(Pyramid, [f64; 4])>],
    t: &TextureRef,
    tri: &radiant_scene::Triangle,
    corners: [[f64; 3]; 3],
) -> Rgb {
    let Some(Some((pyramid, mean))) = pyramids.get(t.image as usize) else {
        return [1.0; 3];
    };
    let uv = corners.map(|b| {
        let raw: [Vec2; 2] = std::array::from_fn(|set| {
            let u = tri.uv[set];
            (u[0].as_dvec2() * b[0] + u[1].as_dvec2() * b[1] + u[2].as_dvec2() * b[2]).as_vec2()
        });
        t.uv(raw)
    });
    let m = pyramid.footprint_mean(t.sampler, uv);
    std::array::from_fn(|c| if mean[c] > 0.0 { m[c] / mean[c] } else { 1.0 })
}

/// Per element: reflectance (clamped to [0, 1]) and emission, from the surfaces and, where
/// given, the textures' footprints.
pub fn materials(
    surfaces: &[Surface],
    mesh: &Mesh,
    textures: Option<&ElementTextures>,
) -> (Vec<Rgb>, Vec<Rgb>) {
    let n = mesh.element_count();
    let (mut rho, mut emission) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for (i, &id) in mesh.leaves.iter().enumerate() {
        let root = mesh.nodes[id as usize].root as usize;
        let s = &surfaces[mesh.root_surface[root] as usize];
        let (mut r, mut e) = (s.reflectance, s.emission);
        if let Some(t) = textures {
            for c in 0..3 {
                r[c] = (r[c] * t.reflectance[i][c]).clamp(0.0, 1.0);
                e[c] = (e[c] * t.emission[i][c]).max(0.0);
            }
        }
        rho.push(r);
        emission.push(e);
    }
    (rho, emission)
}

/// Irradiance (lux per unit of colour) per element from the punctual lights (the mean over
/// nine points, [`crate::lights::direct_irradiance`]) and the sky (its rays from the same nine
/// points in turn), shadowed; `None` when the scene has neither.
pub fn direct_irradiance(
    lights: &[Light],
    sky: Option<&Sky>,
    mesh: &Mesh,
    vis: &dyn Visibility,
    params: &FormFactorParams,
) -> Option<Vec<Rgb>> {
    let sky = sky.filter(|s| !s.is_dark());
    if lights.is_empty() && sky.is_none() {
        return None;
    }
    let mut e = if lights.is_empty() {
        vec![[0.0; 3]; mesh.element_count()]
    } else {
        crate::lights::direct_irradiance(mesh, lights, vis)
    };
    if let Some(sky) = sky {
        let s = sky_irradiance(mesh, sky, vis, params.sky_rays, params.seed);
        for (a, b) in e.iter_mut().zip(s) {
            for c in 0..3 {
                a[c] += b[c];
            }
        }
    }
    Some(e)
}

/// Irradiance from the sky at each element, its mean over the element: `rays` cosine-weighted
/// directions (stratified on a √rays × √rays grid, jittered by a generator seeded with the
/// element's stable id), from its nine points in turn, each that leaves the scene unblocked
/// adding `π · L_sky / rays`. Exact in the mean; an unoccluded element under a uniform sky gets
/// exactly `π · L`.
pub fn sky_irradiance(
    mesh: &Mesh,
    sky: &Sky,
    vis: &dyn Visibility,
    rays: u32,
    seed: u64,
) -> Vec<Rgb> {
    let mut out = vec![[0.0; 3]; mesh.element_count()];
    out.par_iter_mut()
        .with_min_len(64)
        .enumerate()
        .for_each(|(leaf, e)| *e = sky_at(mesh, sky, vis, (rays, seed), leaf));
    out
}

/// [`sky_irradiance`] of one element.
fn sky_at(
    mesh: &Mesh,
    sky: &Sky,
    vis: &dyn Visibility,
    (rays, seed): (u32, u64),
    leaf: usize,
) -> Rgb {
    let side = (f64::from(rays.max(1)).sqrt().round() as u32).max(1);
    let count = f64::from(side * side);
    let id = mesh.leaves[leaf];
    let node = &mesh.nodes[id as usize];
    let n = node.normal;
    let (t, b) = n.any_orthonormal_pair();
    let mut rng = crate::rng::Rng::new(crate::rng::hash(seed, mesh.stable_id(id), 0x5C7));
    // The rays leave from the element's nine points in turn (the lights' shadow points, one
    // at random in each ninth): the mean over the element, not its centroid's view, which a
    // regular set of centroids aliases with regular geometry as the lights' did.
    let points = crate::lights::shadow_points(mesh, leaf);
    let mut sum = DVec3::ZERO;
    for i in 0..side {
        for j in 0..side {
            // The scene fits in the unit cube around the origin: 1.75 units (past its half
            // diagonal) always leave it, and keep the segment's end cut short.
            let origin = points[(i * side + j) as usize % points.len()] + n * 1e-5;
            let u1 = (f64::from(i) + rng.f64()) / f64::from(side);
            let u2 = (f64::from(j) + rng.f64()) / f64::from(side);
            let r = u1.sqrt();
            let phi = std::f64::consts::TAU * u2;
            let dir = t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).sqrt();
            if vis.segment_clear(origin.as_vec3(), (origin + dir * 1.75).as_vec3()) {
                sum += DVec3::from(sky.radiance(dir));
            }
        }
    }
    (sum * (std::f64::consts::PI / count)).to_array()
}

/// [`direct_irradiance`] of the elements `leaves` only, in their order: the same values, bit
/// for bit, as the whole mesh's.
pub fn direct_irradiance_of(
    lights: &[Light],
    sky: Option<&Sky>,
    mesh: &Mesh,
    vis: &dyn Visibility,
    params: &FormFactorParams,
    leaves: &[u32],
) -> Vec<Rgb> {
    let sky = sky.filter(|s| !s.is_dark());
    (leaves.par_iter())
        .with_min_len(64)
        .map(|&leaf| {
            let leaf = leaf as usize;
            let mut e = if lights.is_empty() {
                [0.0; 3]
            } else {
                crate::lights::irradiance_at(mesh, lights, vis, leaf)
            };
            if let Some(sky) = sky {
                let s = sky_at(mesh, sky, vis, (params.sky_rays, params.seed), leaf);
                for c in 0..3 {
                    e[c] += s[c];
                }
            }
            e
        })
        .collect()
}

/// The source term `S = E + ρ · E_direct / π` per element.
pub fn sources(rho: &[Rgb], emission: &[Rgb], direct: Option<&[Rgb]>) -> Vec<Rgb> {
    let mut s = emission.to_vec();
    if let Some(d) = direct {
        for i in 0..s.len() {
            for c in 0..3 {
                s[i][c] += rho[i][c] * d[i][c] / std::f64::consts::PI;
            }
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::MeshParams;

    /// The BVH built from the scene alone answers every ray as the one built from its mesh,
    /// bit for bit, far from the origin too; a scene without triangles is a typed error.
    #[test]
    fn the_scenes_rays_are_the_meshs() {
        let mut scene = radiant_scene::builtin("cornell-box").expect("builtin");
        for t in &mut scene.triangles {
            for v in &mut t.vertices {
                *v += DVec3::new(4.0e5, -3.0e5, 1.0e5);
            }
        }
        let mesh = Mesh::adaptive(&scene, &MeshParams::default(), &mut |_| Ok(())).expect("mesh");
        let (a, b) = (
            visibility(&mesh, None),
            scene_visibility(&scene, None).expect("rays"),
        );
        let mut rng = crate::rng::Rng::new(7);
        let mut next = || rng.f64() as f32 - 0.5;
        let mut hits = 0;
        for _ in 0..4000 {
            let o = Vec3::new(next(), next(), next()) * 0.9;
            let d = Vec3::new(next(), next(), next());
            let (ha, hb) = (
                a.closest_hit(o, d, f32::INFINITY),
                b.closest_hit(o, d, f32::INFINITY),
            );
            assert_eq!(
                ha.map(|h| (h.triangle, h.t.to_bits())),
                hb.map(|h| (h.triangle, h.t.to_bits()))
            );
            hits += usize::from(ha.is_some());
            let e = o + d * 0.3;
            assert_eq!(a.segment_clear(o, e), b.segment_clear(o, e));
        }
        assert!(hits > 2000, "{hits} of 4000 rays hit the box");
        // Rays that follow an edit: the short block moved 5 cm is patched in, and answers as
        // its own BVH does (the same hits, by the edited scene's indices); a change of surface
        // or of triangle count builds them again.
        let rays = SceneRays::new(&scene).expect("rays");
        let mut moved = scene.clone();
        let block: Vec<u32> = (0..moved.surfaces.len() as u32)
            .filter(|&s| moved.surfaces[s as usize].name.starts_with("short_block"))
            .collect();
        let mut changed = 0;
        for t in (moved.triangles.iter_mut()).filter(|t| block.contains(&t.surface)) {
            t.vertices = t.vertices.map(|v| v + DVec3::new(0.05, 0.0, 0.0));
            changed += 1;
        }
        assert!(changed >= 10, "{changed} triangles moved");
        let patched = rays.patched(&moved).expect("patched");
        assert!(matches!(patched, Rays::Patched(_)));
        let own = visibility(
            &Mesh::adaptive(&moved, &MeshParams::default(), &mut |_| Ok(())).expect("mesh"),
            None,
        );
        let (mut on_block, mut differ) = (0, 0);
        for _ in 0..4000 {
            let o = Vec3::new(next(), next(), next()) * 0.9;
            let d = Vec3::new(next(), next(), next());
            let (hp, ho) = (
                patched.closest_hit(o, d, f32::INFINITY),
                own.closest_hit(o, d, f32::INFINITY),
            );
            assert_eq!(hp.map(|h| h.triangle), ho.map(|h| h.triangle), "{o} {d}");
            let (tp, to) = (hp.map_or(0.0, |h| h.t), ho.map_or(0.0, |h| h.t));
            assert!((tp - to).abs() <= 1e-6 * to.max(1.0), "{tp} {to}");
            on_block +=
                usize::from(hp.is_some_and(|h| {
                    block.contains(&moved.triangles[h.triangle as usize].surface)
                }));
            let e = o + d * 0.3;
            assert_eq!(patched.segment_clear(o, e), own.segment_clear(o, e));
            differ += usize::from(
                hp.map(|h| h.triangle) != a.closest_hit(o, d, f32::INFINITY).map(|h| h.triangle),
            );
        }
        assert!(
            on_block > 50 && differ > 20,
            "{on_block} on the block, {differ} moved"
        );
        let mut recoloured = moved.clone();
        let other = (recoloured.triangles.iter())
            .position(|t| !block.contains(&t.surface))
            .expect("a triangle off the block");
        recoloured.triangles[other].surface = block[0];
        recoloured.triangles[other].vertices[0].x += 1e-3;
        assert!(rays.patched(&recoloured).is_none(), "a changed surface");
        let mut fewer = moved.clone();
        fewer.triangles.pop();
        assert!(rays.patched(&fewer).is_none(), "another triangle count");
        // A blocker whose alpha mask is cut over its right half (x > 0.5), moved 5 cm along z
        // inside the scene's bounds (its UVs kept): patched in, rays pass where it is cut and stop where it is not, as
        // through its own BVH built with the masks.
        let mut masked = Scene::default();
        let quad = |o: DVec3, a: DVec3, b: DVec3, s: u32| {
            let (p, q, r, t) = (o, o + a, o + a + b, o + b);
            let mut tris = [
                radiant_scene::Triangle::new([p, q, r], s),
                radiant_scene::Triangle::new([p, r, t], s),
            ];
            for t in &mut tris {
                t.uv[0] = t.vertices.map(|v| glam::Vec2::new(v.x as f32, v.z as f32));
            }
            tris
        };
        masked
            .triangles
            .extend(quad(DVec3::ZERO, DVec3::Z, DVec3::X, 0));
        masked.triangles.extend(quad(
            DVec3::new(0.2, 0.3, 0.2),
            DVec3::Z * 0.6,
            DVec3::X * 0.6,
            1,
        ));
        let mut blocker = radiant_scene::Surface {
            name: "blocker".into(),
            alpha: radiant_scene::AlphaMode::Mask { cutoff: 0.5 },
            ..Default::default()
        };
        blocker.base_color_texture = Some(radiant_scene::TextureRef {
            image: 0,
            sampler: radiant_scene::texture::Sampler {
                nearest: true,
                ..Default::default()
            },
            tex_coord: 0,
            transform: Default::default(),
        });
        masked.surfaces = vec![
            radiant_scene::Surface {
                name: "floor".into(),
                ..Default::default()
            },
            blocker,
        ];
        masked.images = vec![radiant_scene::Image {
            name: "half".into(),
            width: 2,
            height: 1,
            pixels: vec![255, 255, 255, 255, 255, 255, 255, 0].into(),
        }];
        let rays = SceneRays::new(&masked).expect("rays");
        let mut slid = masked.clone();
        for t in slid.triangles.iter_mut().filter(|t| t.surface == 1) {
            t.vertices = t.vertices.map(|v| v + DVec3::new(0.0, 0.0, 0.05));
        }
        let patched = rays.patched(&slid).expect("patched");
        let own = scene_visibility(&slid, masks(&slid).as_ref()).expect("rays");
        let frame = Frame::of(&slid).expect("frame");
        let (mut through, mut stopped) = (0, 0);
        for i in 0..400 {
            // Straight down through the blocker's plane, over the floor.
            let (x, z) = (
                0.25 + 0.5 * f64::from(i % 20) / 19.0,
                0.3 + 0.4 * f64::from(i / 20) / 19.0,
            );
            let o = frame.to_local(DVec3::new(x, 0.6, z)).as_vec3();
            let (hp, ho) = (
                patched.closest_hit(o, Vec3::NEG_Y, f32::INFINITY),
                own.closest_hit(o, Vec3::NEG_Y, f32::INFINITY),
            );
            assert_eq!(hp.map(|h| h.triangle), ho.map(|h| h.triangle), "at {x} {z}");
            match hp.map(|h| slid.triangles[h.triangle as usize].surface) {
                Some(0) => through += 1,
                Some(_) => stopped += 1,
                None => {}
            }
        }
        assert!(
            through > 100 && stopped > 100,
            "{through} through, {stopped} stopped"
        );
        scene.triangles.clear();
        assert!(matches!(
            scene_visibility(&scene, None),
            Err(BakeError::InvalidScene(SceneError::NoTriangles))
        ));
    }
}
