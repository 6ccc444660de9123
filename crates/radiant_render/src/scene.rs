//! What the renderer draws: vertices with smooth normals, material colours, texture and light-map
//! coordinates; materials with their textures, drawn one index range each; punctual lights, a
//! camera, a light map and a sky; and their GPU copies.
//!
//! Positions are stored relative to [`RenderScene::origin`] (f64), so a scene far from the world
//! origin keeps full f32 precision near the camera.

use glam::{DVec3, Mat4, Vec2, Vec3};
use radiant_scene::Sky;
use wgpu::util::DeviceExt;

use crate::RenderError;

/// Why a render scene cannot be uploaded.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SceneError {
    /// An atlas made for another scene.
    #[error("an atlas of {atlas} triangles for a scene of {triangles}")]
    AtlasSize {
        /// Triangles the atlas places.
        atlas: usize,
        /// Triangles of the scene.
        triangles: usize,
    },
    /// A triangle names a surface past the list.
    #[error("a triangle names surface {surface} of {surfaces}")]
    UnknownSurface {
        /// The surface index.
        surface: usize,
        /// Surfaces in the scene.
        surfaces: usize,
    },
    /// A draw's range past the data it indexes.
    #[error("range {start}..{end} is past the {len} {of}")]
    DrawRange {
        /// First index of the range.
        start: u64,
        /// One past its last.
        end: u64,
        /// Length of the data.
        len: usize,
        /// What it indexes.
        of: &'static str,
    },
    /// A texture whose bytes do not fill its size.
    #[error("texture {texture:?} has {bytes} bytes for {width}×{height} texels")]
    TextureBytes {
        /// The texture's name.
        texture: String,
        /// Bytes given.
        bytes: usize,
        /// Width.
        width: u32,
        /// Height.
        height: u32,
    },
    /// More light-map pages than the adapter has texture layers.
    #[error("a light map of {pages} pages, past the adapter's {max} texture layers")]
    LightMapPages {
        /// Pages.
        pages: u32,
        /// The adapter's limit.
        max: u32,
    },
    /// A vertex on a light-map page the map does not have.
    #[error("a vertex on light-map page {page} of {pages}")]
    LightMapPage {
        /// The page.
        page: u32,
        /// Pages of the map.
        pages: u32,
    },
}
pub use crate::instancing::InstanceData;
use crate::material::{DrawRange, GpuMaterial, RenderMaterial, RenderTexture, TextureCache};

/// One vertex of the static geometry.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Vertex {
    /// Position relative to the scene origin, metres.
    pub position: [f32; 3],
    /// Unit shading normal (smooth where the scene has vertex normals).
    pub normal: [f32; 3],
    /// Linear diffuse reflectance (albedo); with a base-colour texture, the factor it is
    /// multiplied by.
    pub albedo: [f32; 3],
    /// Emitted radiance, linear, in the bake's units.
    pub emissive: [f32; 3],
    /// Light-map coordinates (the second UV set), in [0, 1] of its page.
    pub lightmap_uv: [f32; 2],
    /// Base-colour texture coordinates (the material's set, `KHR_texture_transform` applied).
    pub uv: [f32; 2],
    /// The light-map page (a layer of the light-map texture array).
    pub lightmap_page: u32,
}

/// The kind of a punctual light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightKind {
    /// Shines along `direction` everywhere; `intensity` in lux.
    Directional,
    /// Omnidirectional from `position`; `intensity` in candela.
    Point,
    /// A cone from `position` along `direction`; `intensity` in candela.
    Spot {
        /// Cosine-space start of the falloff: angle from the axis in radians.
        inner_angle: f32,
        /// Angle from the axis where the light ends, radians.
        outer_angle: f32,
    },
}

/// A punctual light (KHR_lights_punctual conventions).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// Point, spot or directional.
    pub kind: LightKind,
    /// World position (point, spot), absolute.
    pub position: DVec3,
    /// Unit direction the light travels (spot, directional).
    pub direction: Vec3,
    /// Linear colour.
    pub color: Vec3,
    /// Candela (point, spot) or lux (directional).
    pub intensity: f32,
    /// Distance where the light reaches zero, metres; `f32::INFINITY` for none.
    pub range: f32,
}

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraView {
    /// World position, absolute.
    pub position: DVec3,
    /// Unit view direction.
    pub forward: Vec3,
    /// Up vector.
    pub up: Vec3,
    /// Vertical field of view, radians.
    pub yfov: f32,
    /// Near plane, metres.
    pub near: f32,
    /// Far plane, metres.
    pub far: f32,
}

impl CameraView {
    /// View matrix for a camera at `position - origin`.
    pub fn view(&self, origin: DVec3) -> Mat4 {
        let eye = (self.position - origin).as_vec3();
        let dir = self.forward.normalize_or(Vec3::NEG_Z);
        // An up vector parallel to the view direction would make the basis singular.
        let up = if dir.cross(self.up).length_squared() > 1e-8 {
            self.up.normalize()
        } else {
            dir.any_orthonormal_vector()
        };
        glam::camera::rh::view::look_to_mat4(eye, dir, up)
    }

    /// Projection matrix (depth 0 at the near plane, 1 at the far plane).
    pub fn projection(&self, aspect: f32) -> Mat4 {
        // wgpu's clip space: y up, depth in [0, 1] (the Direct3D convention).
        glam::camera::rh::proj::directx::perspective(
            self.yfov.clamp(1e-3, 3.1),
            aspect.max(1e-6),
            self.near,
            self.far.max(self.near * 2.0),
        )
    }
}

/// The largest light-map side [`RenderScene::from_scene`] makes (the WebGPU minimum of
/// `max_texture_dimension_2d` is 8192): a scene whose charts would not fit gets a lower texel
/// density, not a larger map.
pub const MAX_LIGHTMAP_SIDE: u32 = radiant_scene::atlas::MAX_SIDE;

/// A light map: incident radiance-weighted irradiance per texel (`H`, the bake's units: a
/// surface of albedo `a` reflects radiance `a · H`), linear RGB.
#[derive(Clone, Debug, PartialEq)]
pub struct LightMap {
    /// Width of a page in texels.
    pub width: u32,
    /// Height of a page in texels.
    pub height: u32,
    /// Pages (layers of the texture array).
    pub pages: u32,
    /// Texels, RGB: each page row-major, one after the other.
    pub texels: Vec<[f32; 3]>,
}

/// A copy's light-map coordinate for one vertex of its prototype's draw (16 bytes, as the
/// G-buffer's storage buffer reads it).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct InstanceUv {
    /// Coordinates in the page.
    pub uv: [f32; 2],
    /// The page.
    pub page: u32,
    /// Unused.
    pub pad: u32,
}

/// A light-map texel's place on the geometry, for [`RenderScene::fill_lightmap`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightmapTexel {
    /// Index of the triangle (the scene's triangle order).
    pub triangle: usize,
    /// Barycentric weight of the triangle's second vertex.
    pub u: f32,
    /// Barycentric weight of the third vertex.
    pub v: f32,
    /// World position.
    pub position: DVec3,
    /// The triangle's unit face normal.
    pub normal: Vec3,
}

/// Everything the renderer draws.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderScene {
    /// World position that vertex positions are relative to.
    pub origin: DVec3,
    /// Triangle-list vertices.
    pub vertices: Vec<Vertex>,
    /// Triangle indices into `vertices`, grouped by material.
    pub indices: Vec<u32>,
    /// Textures the materials sample.
    pub textures: Vec<RenderTexture>,
    /// Materials.
    pub materials: Vec<RenderMaterial>,
    /// Index ranges, each with one material and a range of `instances`; empty: every index
    /// with the default material, drawn once.
    pub draws: Vec<DrawRange>,
    /// How draws place their vertices: entry 0 (or none at all) is the identity; an instanced
    /// draw's vertices are its prototype's, moved and given their own light-map coordinates
    /// per copy.
    pub instances: Vec<InstanceData>,
    /// The copies' light-map coordinates: for each copy, one per vertex of its prototype's draw,
    /// in that order (see [`InstanceData::lightmap`]).
    pub instance_uvs: Vec<InstanceUv>,
    /// What is seen where no geometry is (black without one).
    pub sky: Option<Sky>,
    /// The light map's layout, when [`RenderScene::from_scene`] made it.
    pub atlas: Option<radiant_scene::atlas::Atlas>,
    /// Punctual lights.
    pub lights: Vec<Light>,
    /// The camera.
    pub camera: CameraView,
    /// The baked light map, if any (without one the indirect term is zero).
    pub lightmap: Option<LightMap>,
    /// The irradiance volume that lights dynamic surfaces (vertices on page [`PROBE_LIT`]);
    /// without one they receive no `H`.
    pub probes: Option<ProbeGrid>,
}

/// The light-map page of a dynamic surface's vertices: it has no chart, and its `H` comes from
/// [`RenderScene::probes`] at the fragment's position and normal.
pub const PROBE_LIT: u32 = u32::MAX;

/// An irradiance volume on a regular grid, as the G-buffer pass reads it for dynamic surfaces:
/// at a point, the eight probes of its cell blended with trilinear weights, leaving out those
/// that are not valid (inside geometry; the nearest valid corner alone where none is), and
/// each probe's harmonics evaluated for the fragment's normal.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeGrid {
    /// The first probe, relative to [`RenderScene::origin`].
    pub origin: [f32; 3],
    /// Distance between neighbouring probes (positive).
    pub step: f32,
    /// Probes along x, y and z (each at least 1).
    pub dims: [u32; 3],
    /// Per probe, x fastest: `H` (the light map's quantity) as real spherical harmonics of
    /// order 2, RGB per coefficient, in `radiant_radiosity::cluster::sh::basis`'s order:
    /// `H(n) = Σ_k sh[k] Y_k(n)`.
    pub sh: Vec<[[f32; 3]; 9]>,
    /// Per probe: whether it takes part in the blend.
    pub valid: Vec<bool>,
}

impl ProbeGrid {
    /// Checks the layout and the values (typed error: no NaN reaches the GPU).
    pub fn validate(&self) -> Result<(), RenderError> {
        // u128: three u32 sides cannot overflow it. The shader indexes nine words a probe in
        // u32, so at most u32::MAX / 9 probes.
        let count: u128 = self.dims.iter().map(|&d| u128::from(d)).product();
        if self.dims.contains(&0)
            || count != self.sh.len() as u128
            || count != self.valid.len() as u128
            || count > u128::from(u32::MAX / 9)
        {
            return Err(RenderError::ProbeLayout {
                dims: self.dims,
                probes: self.sh.len(),
            });
        }
        let finite = self.step.is_finite()
            && self.step > 0.0
            && self.origin.iter().all(|v| v.is_finite())
            && self.sh.iter().flatten().flatten().all(|v| v.is_finite());
        if !finite {
            return Err(RenderError::NonFinite("probe grid"));
        }
        Ok(())
    }

    /// The GPU layout: a header, then per probe nine RGB coefficients, validity in the first
    /// one's fourth component.
    fn gpu_words(&self) -> (ProbeGridUniform, Vec<[f32; 4]>) {
        let header = ProbeGridUniform {
            origin_step: [self.origin[0], self.origin[1], self.origin[2], self.step],
            dims: [self.dims[0], self.dims[1], self.dims[2], 1],
        };
        let mut words = Vec::with_capacity(self.sh.len() * 9);
        for (sh, &valid) in self.sh.iter().zip(&self.valid) {
            for (k, c) in sh.iter().enumerate() {
                let w = if k == 0 && valid { 1.0 } else { 0.0 };
                words.push([c[0], c[1], c[2], w]);
            }
        }
        (header, words)
    }
}

/// [`ProbeGrid`]'s header on the GPU (`dims.w` 0: no grid).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ProbeGridUniform {
    /// The first probe (relative to the origin) and the step.
    pub origin_step: [f32; 4],
    /// Probes along x, y, z; w 1 when there is a grid.
    pub dims: [u32; 4],
}

impl RenderScene {
    /// Converts a radiosity scene: triangles with their vertex normals, base-colour textures,
    /// alpha masks and light-map coordinates; the scene's lights, camera and sky; no light map
    /// yet.
    ///
    /// The light map is the scene's atlas (`radiant_scene::atlas`: its TEXCOORD_1, or charts
    /// generated at `texel_density` texels per scene unit, `None` for the automatic density).
    /// Surfaces that copy another under an affine map ([`crate::instancing`]) are drawn as its
    /// instances, each with its own light-map charts.
    pub fn from_scene(
        scene: &radiant_scene::Scene,
        texel_density: Option<f64>,
    ) -> Result<Self, RenderError> {
        let atlas = radiant_scene::atlas::Atlas::new(scene, texel_density)?;
        Self::build(scene, atlas, true)
    }

    /// [`RenderScene::from_scene`] on an atlas made before for the same triangles (UV charts
    /// cost about a second on a level: a new light on unchanged geometry need not pay it again).
    pub fn with_atlas(
        scene: &radiant_scene::Scene,
        atlas: radiant_scene::atlas::Atlas,
    ) -> Result<Self, RenderError> {
        if atlas.uv.len() != scene.triangles.len() || atlas.page.len() != scene.triangles.len() {
            return Err(SceneError::AtlasSize {
                atlas: atlas.uv.len().min(atlas.page.len()),
                triangles: scene.triangles.len(),
            }
            .into());
        }
        Self::build(scene, atlas, true)
    }

    /// [`RenderScene::from_scene`] with light-map pages of at most `page_side` texels a side
    /// (`radiant_scene::atlas::Atlas::paged`): the light map becomes a texture array.
    pub fn from_scene_paged(
        scene: &radiant_scene::Scene,
        texel_density: Option<f64>,
        page_side: u32,
    ) -> Result<Self, RenderError> {
        let atlas = radiant_scene::atlas::Atlas::paged(scene, texel_density, page_side)?;
        Self::build(scene, atlas, true)
    }

    /// [`RenderScene::from_scene`] without instances: every triangle drawn on its own (the
    /// same frame from more vertices; for comparisons and benchmarks).
    pub fn from_scene_flattened(
        scene: &radiant_scene::Scene,
        texel_density: Option<f64>,
    ) -> Result<Self, RenderError> {
        let atlas = radiant_scene::atlas::Atlas::new(scene, texel_density)?;
        Self::build(scene, atlas, false)
    }

    fn build(
        scene: &radiant_scene::Scene,
        atlas: radiant_scene::atlas::Atlas,
        instancing: bool,
    ) -> Result<Self, RenderError> {
        if scene.triangles.is_empty() {
            return Err(RenderError::EmptyScene);
        }
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for t in &scene.triangles {
            for v in t.vertices {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        if let Some(t) = scene
            .triangles
            .iter()
            .find(|t| t.surface as usize >= scene.surfaces.len())
        {
            return Err(SceneError::UnknownSurface {
                surface: t.surface as usize,
                surfaces: scene.surfaces.len(),
            }
            .into());
        }
        if !(lo.is_finite() && hi.is_finite()) {
            return Err(RenderError::NonFinite("vertex data"));
        }
        let origin = (lo + hi) * 0.5;
        let (materials, surface_material, factors) = materials(scene);
        let mut of_surface: Vec<Vec<u32>> = vec![Vec::new(); scene.surfaces.len()];
        for (i, t) in scene.triangles.iter().enumerate() {
            of_surface[t.surface as usize].push(i as u32);
        }
        let (w, h, pages) = (atlas.width, atlas.height, atlas.pages);
        let vertices = scene_vertices(scene, &atlas, origin, &factors);
        // Surfaces that copy another are drawn as its instances; the rest are grouped by
        // material (vertices stay in triangle order, which the light-map fill relies on).
        let copies = if instancing {
            crate::instancing::find_instances(scene, &of_surface, &surface_material)
        } else {
            vec![None; of_surface.len()]
        };
        let mut copies_of: Vec<Vec<(u32, glam::DAffine3)>> = vec![Vec::new(); of_surface.len()];
        for (s, c) in copies.iter().enumerate() {
            if let Some((p, m)) = c {
                copies_of[*p as usize].push((s as u32, *m));
            }
        }
        let flat = |s: usize| copies[s].is_none() && copies_of[s].is_empty();
        tracing::debug!(
            copies = copies.iter().flatten().count(),
            prototypes = copies_of.iter().filter(|c| !c.is_empty()).count(),
            surfaces = copies.len(),
            "render scene: surfaces drawn as instances"
        );
        let mut by_material: Vec<Vec<u32>> = vec![Vec::new(); materials.len()];
        for (i, t) in scene.triangles.iter().enumerate() {
            if flat(t.surface as usize) {
                let m = surface_material[t.surface as usize] as usize;
                let i = i as u32 * 3;
                by_material[m].extend([i, i + 1, i + 2]);
            }
        }
        let mut indices = Vec::with_capacity(vertices.len());
        let mut draws = Vec::new();
        for (m, list) in by_material.into_iter().enumerate() {
            if !list.is_empty() {
                draws.push(DrawRange::new(
                    m as u32,
                    indices.len() as u32,
                    list.len() as u32,
                ));
                indices.extend(list);
            }
        }
        let mut instances = vec![InstanceData::IDENTITY];
        let mut instance_uvs = Vec::new();
        for (p, list) in copies_of.iter().enumerate() {
            if list.is_empty() {
                continue;
            }
            let first = indices.len() as u32;
            for &i in &of_surface[p] {
                indices.extend([i * 3, i * 3 + 1, i * 3 + 2]);
            }
            let first_instance = instances.len() as u32;
            instances.push(InstanceData::IDENTITY);
            for &(s, m) in list {
                // Origin-relative: x − o ↦ A (x − o) + (A o + t − o).
                let rel = glam::DAffine3::from_mat3_translation(
                    m.matrix3,
                    m.matrix3 * origin + m.translation - origin,
                );
                // Its own charts, vertex for vertex with the prototype's (the copy's triangles
                // pair with the prototype's in order).
                let base = instance_uvs.len() as u32;
                for &i in &of_surface[s as usize] {
                    instance_uvs.extend((0..3).map(|k| {
                        let v = &vertices[i as usize * 3 + k];
                        InstanceUv {
                            uv: v.lightmap_uv,
                            page: v.lightmap_page,
                            pad: 0,
                        }
                    }));
                }
                instances.push(InstanceData::new(rel, base));
            }
            draws.push(DrawRange {
                material: surface_material[p],
                first,
                count: indices.len() as u32 - first,
                first_instance,
                instance_count: instances.len() as u32 - first_instance,
            });
        }
        let textures = scene
            .images
            .iter()
            .map(|img| RenderTexture {
                name: img.name.clone(),
                width: img.width,
                height: img.height,
                pixels: img.pixels.clone(),
            })
            .collect();
        let camera = scene_camera(scene, origin, (lo, hi));
        let lights = scene_lights(scene);
        Ok(Self {
            origin,
            indices,
            vertices,
            textures,
            materials,
            draws,
            instances,
            instance_uvs,
            sky: scene.sky.clone(),
            atlas: Some(atlas),
            lights,
            camera,
            lightmap: Some(LightMap {
                width: w,
                height: h,
                pages,
                texels: vec![[0.0; 3]; (w * h * pages) as usize],
            }),
            probes: None,
        })
    }

    /// Fills the light map by evaluating `h` at every chart texel (texels around a chart's edge
    /// get the value of the nearest point on the triangle, so bilinear filtering never reads
    /// outside it). Needs the layout of [`RenderScene::from_scene`].
    pub fn fill_lightmap(&mut self, h: impl Fn(&LightmapTexel) -> [f32; 3]) {
        let Some(lm) = self.lightmap.as_mut() else {
            return;
        };
        let (origin, vertices) = (self.origin, &self.vertices);
        let size = (lm.width as usize * lm.height as usize).max(1);
        for (page, texels) in lm.texels.chunks_exact_mut(size).enumerate() {
            let charts = vertices
                .chunks_exact(3)
                .enumerate()
                .filter(|(_, tri)| tri[0].lightmap_page as usize == page)
                .map(|(index, tri)| {
                    (
                        index,
                        [0, 1, 2].map(|k| Vec2::from(tri[k].lightmap_uv)),
                        [0, 1, 2].map(|k| origin + Vec3::from(tri[k].position).as_dvec3()),
                    )
                });
            radiant_scene::atlas::rasterize(
                lm.width,
                lm.height,
                texels,
                charts,
                |index, u, v, position| {
                    h(&LightmapTexel {
                        triangle: index,
                        u,
                        v,
                        position,
                        normal: face_normal(&vertices[index * 3..index * 3 + 3]),
                    })
                },
            );
        }
    }

    /// A smooth synthetic light map: the unoccluded irradiance from every emissive triangle,
    /// treated as a small area source at its centroid, plus a constant `ambient`. It has no
    /// shadows; it stands in for a bake in renderer tests.
    pub fn fill_synthetic_lightmap(&mut self, ambient: f32) {
        let emitters: Vec<(Vec3, Vec3, f32, Vec3)> = self
            .vertices
            .chunks_exact(3)
            .filter(|t| t[0].emissive.iter().any(|&e| e > 0.0))
            .map(|t| {
                let p = [0, 1, 2].map(|k| Vec3::from(t[k].position));
                let c = (p[0] + p[1] + p[2]) / 3.0;
                let cross = (p[1] - p[0]).cross(p[2] - p[0]);
                (
                    c,
                    face_normal(t),
                    0.5 * cross.length(),
                    Vec3::from(t[0].emissive),
                )
            })
            .collect();
        let origin = self.origin;
        self.fill_lightmap(|t| {
            let (p, n) = ((t.position - origin).as_vec3(), t.normal);
            let mut h = Vec3::splat(ambient);
            for &(c, ne, area, e) in &emitters {
                let d = c - p;
                let r2 = d.length_squared().max(1e-4);
                let dir = d / r2.sqrt();
                let cos_r = n.dot(dir).max(0.0);
                let cos_e = (-ne.dot(dir)).abs();
                h += e * (cos_r * cos_e * area / (std::f32::consts::PI * r2)).min(1.0);
            }
            h.to_array()
        });
    }
}

/// Three vertices per triangle, in triangle order (the light-map fill relies on it): relative
/// to `origin`, the shading normal where it is usable (else the face's), the surface's albedo
/// and emission, the atlas's light-map coordinates, the base-colour texture's coordinates.
fn scene_vertices(
    scene: &radiant_scene::Scene,
    atlas: &radiant_scene::atlas::Atlas,
    origin: DVec3,
    factors: &[[f32; 3]],
) -> Vec<Vertex> {
    let mut vertices = Vec::with_capacity(scene.triangles.len() * 3);
    for (i, t) in scene.triangles.iter().enumerate() {
        let s = &scene.surfaces[t.surface as usize];
        let face = t.cross().normalize_or_zero().as_vec3();
        let albedo = factors[t.surface as usize];
        let uvs = atlas.uv[i].map(|c| c.to_array());
        for (k, p) in t.vertices.iter().enumerate() {
            let n = t.normals[k];
            let normal = if n.is_finite() && n.length_squared() > 0.5 {
                n
            } else {
                face
            };
            let uv = s.base_color_texture.map_or(Vec2::ZERO, |tex| {
                let uv = tex.uv([t.uv[0][k], t.uv[1][k]]);
                if uv.is_finite() { uv } else { Vec2::ZERO }
            });
            vertices.push(Vertex {
                position: (*p - origin).as_vec3().to_array(),
                normal: normal.to_array(),
                albedo,
                emissive: s.emission.map(|x| x as f32),
                lightmap_uv: uvs[k],
                uv: uv.to_array(),
                lightmap_page: if s.dynamic { PROBE_LIT } else { atlas.page[i] },
            });
        }
    }
    vertices
}

/// The scene's camera, or one looking down −Z at the whole scene; far enough for the bounds
/// `lo`..`hi`.
fn scene_camera(
    scene: &radiant_scene::Scene,
    origin: DVec3,
    (lo, hi): (DVec3, DVec3),
) -> CameraView {
    let diag = (hi - lo).length().max(1e-6);
    scene.camera.map_or(
        CameraView {
            position: origin + DVec3::new(0.0, 0.0, diag * 1.5),
            forward: Vec3::NEG_Z,
            up: Vec3::Y,
            yfov: 0.7,
            near: (diag * 1e-3) as f32,
            far: (diag * 4.0).max(1.0) as f32,
        },
        |c| CameraView {
            position: c.position,
            forward: c.forward.as_vec3(),
            up: c.up.as_vec3(),
            yfov: c.yfov as f32,
            near: 0.01,
            far: ((hi - lo).length() * 4.0).max(1.0) as f32,
        },
    )
}

/// The scene's punctual lights in the renderer's types.
fn scene_lights(scene: &radiant_scene::Scene) -> Vec<Light> {
    scene
        .lights
        .iter()
        .map(|l| Light {
            kind: match l.kind {
                radiant_scene::LightKind::Point => LightKind::Point,
                radiant_scene::LightKind::Directional => LightKind::Directional,
                radiant_scene::LightKind::Spot {
                    inner_cone_angle,
                    outer_cone_angle,
                } => LightKind::Spot {
                    inner_angle: inner_cone_angle as f32,
                    outer_angle: outer_cone_angle as f32,
                },
            },
            position: l.position,
            direction: l.direction.as_vec3(),
            color: Vec3::from_array(l.color.map(|c| c as f32)),
            intensity: l.intensity as f32,
            range: l.range.map_or(f32::INFINITY, |r| r as f32),
        })
        .collect()
}

/// The unit face normal of three vertices (counter-clockwise front).
fn face_normal(t: &[Vertex]) -> Vec3 {
    let p = [0, 1, 2].map(|k| Vec3::from(t[k].position));
    (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero()
}

/// The renderer's materials for `scene`'s surfaces (equal ones merged), each surface's
/// material, and each surface's vertex albedo: the reflectance, or with a base-colour texture
/// the factor (the reflectance over the texture's mean, so factor × texture is the surface).
fn materials(scene: &radiant_scene::Scene) -> (Vec<RenderMaterial>, Vec<u32>, Vec<[f32; 3]>) {
    use radiant_scene::AlphaMode;
    let mut means: Vec<Option<[f64; 4]>> = vec![None; scene.images.len()];
    let mut list: Vec<RenderMaterial> = Vec::new();
    let mut of_surface = Vec::with_capacity(scene.surfaces.len());
    let mut factors = Vec::with_capacity(scene.surfaces.len());
    for s in &scene.surfaces {
        let tex = s
            .base_color_texture
            .filter(|t| (t.image as usize) < scene.images.len());
        let m = RenderMaterial {
            texture: tex.map(|t| t.image),
            sampler: tex.map(|t| t.sampler).unwrap_or_default(),
            alpha_factor: s.base_color_alpha as f32,
            alpha_cutoff: match s.alpha {
                AlphaMode::Opaque => None,
                AlphaMode::Mask { cutoff } => Some(cutoff as f32),
                AlphaMode::Blend => Some(0.5),
            },
            cull_back: s.double_sided,
        };
        let factor = match tex {
            Some(t) => {
                let mean = *means[t.image as usize]
                    .get_or_insert_with(|| scene.images[t.image as usize].mean_linear());
                std::array::from_fn(|c| {
                    if mean[c] > 1e-9 {
                        (s.reflectance[c] / mean[c]) as f32
                    } else {
                        0.0
                    }
                })
            }
            None => s.reflectance.map(|x| x as f32),
        };
        factors.push(factor);
        let index = match list.iter().position(|x| *x == m) {
            Some(i) => i,
            None => {
                list.push(m);
                list.len() - 1
            }
        };
        of_surface.push(index as u32);
    }
    (list, of_surface, factors)
}

/// Per-frame camera data as the shaders see it.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct CameraUniform {
    /// World (origin-relative) → clip.
    pub view_proj: [[f32; 4]; 4],
    /// Clip → world.
    pub inv_view_proj: [[f32; 4]; 4],
    /// World → view.
    pub view: [[f32; 4]; 4],
    /// View → clip.
    pub proj: [[f32; 4]; 4],
    /// Clip → view.
    pub inv_proj: [[f32; 4]; 4],
    /// Camera position (origin-relative), w = 1.
    pub position: [f32; 4],
    /// Width, height, 1/width, 1/height.
    pub viewport: [f32; 4],
    /// Near, far, light count, unused.
    pub params: [f32; 4],
}

/// A light as the shaders see it (64 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuLight {
    /// Origin-relative position, and range (0 for none).
    pub position_range: [f32; 4],
    /// Direction of travel, and kind (0 directional, 1 point, 2 spot).
    pub direction_kind: [f32; 4],
    /// Colour × intensity, and unused.
    pub color: [f32; 4],
    /// Spot cosines: outer, 1 / (inner − outer), unused × 2.
    pub spot: [f32; 4],
}

/// The sky as the lighting shader sees it (48 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SkyUniform {
    /// 0 none (black), 1 uniform, 2 gradient, 3 equirectangular image.
    pub kind: u32,
    /// Image width and height (texels).
    pub size: [u32; 2],
    /// Unused.
    pub pad: u32,
    /// Uniform radiance, or the zenith's.
    pub a: [f32; 4],
    /// The horizon's radiance.
    pub b: [f32; 4],
}

/// The scene's GPU buffers and textures.
pub struct GpuScene {
    /// Vertex buffer: the drawn vertices in draw order (each draw's indices resolved; copies
    /// of an instanced surface are not in it, only its prototype).
    pub vertices: wgpu::Buffer,
    /// Number of vertices.
    pub vertex_count: u32,
    /// Per-instance buffer of [`InstanceData`] (entry 0 the identity).
    pub instances: wgpu::Buffer,
    /// Storage buffer of the copies' light-map coordinates (one zeroed entry without copies).
    pub instance_uvs: wgpu::Buffer,
    /// One per draw range: texture, sampler, constants and indices.
    pub materials: Vec<GpuMaterial>,
    /// [`SkyUniform`].
    pub sky: wgpu::Buffer,
    /// The equirectangular sky, Rgba16Float, row 0 at the zenith (1×1 without one).
    pub sky_image: wgpu::TextureView,
    /// Storage buffer of [`GpuLight`] (at least one zeroed entry).
    pub lights: wgpu::Buffer,
    /// Number of real lights.
    pub light_count: u32,
    /// The light map, a Rgba16Float texture array of its pages (1×1 black without one).
    pub lightmap: wgpu::TextureView,
    /// Bilinear, clamped sampler.
    pub linear_sampler: wgpu::Sampler,
    /// [`ProbeGridUniform`] (`dims.w` 0 without a grid).
    pub probe_grid: wgpu::Buffer,
    /// The probes' harmonics (one zeroed probe without a grid).
    pub probes: wgpu::Buffer,
    /// [`CameraUniform`] buffer, written each frame.
    pub camera: wgpu::Buffer,
    /// The CPU scene's origin and camera.
    pub origin: DVec3,
    /// The camera used by [`GpuScene::update_camera`].
    pub camera_view: CameraView,
}

/// Converts an f32 to IEEE binary16 bits (round to nearest, saturating to ±65504).
fn f32_to_f16(x: f32) -> u16 {
    if x.is_nan() {
        return 0;
    }
    let x = x.clamp(-65504.0, 65504.0);
    let bits = x.to_bits();
    let sign = ((bits >> 16) & 0x8000) as u16;
    let a = x.abs();
    if a < 6.103_515_6e-5 {
        // Subnormal half.
        return sign | (a / 5.960_464_5e-8).round() as u16;
    }
    let e = ((bits >> 23) & 0xff) as i32 - 127 + 15;
    let m = bits & 0x7f_ffff;
    let mut h = ((e as u32) << 10) | (m >> 13);
    // Round half up on the dropped bits.
    if m & 0x1000 != 0 {
        h += 1;
    }
    sign | (h.min(0x7bff) as u16)
}

impl GpuScene {
    /// Uploads a scene. Refuses non-finite vertex data and lights (typed error, no NaN on the GPU).
    pub fn upload(gpu: &crate::GpuContext, scene: &RenderScene) -> Result<Self, RenderError> {
        Self::upload_cached(gpu, scene, &mut TextureCache::new())
    }

    /// [`GpuScene::upload`], taking textures from `cache` where it has them (and leaving the
    /// ones this scene uses in it).
    pub fn upload_cached(
        gpu: &crate::GpuContext,
        scene: &RenderScene,
        cache: &mut TextureCache,
    ) -> Result<Self, RenderError> {
        let dev = &gpu.device;
        let (draws, mut instance_data) = validate(scene)?;
        let (drawn, resolved) = flatten_draws(scene, &draws, &mut instance_data)?;
        let materials = cache.upload(
            dev,
            &gpu.queue,
            &scene.textures,
            &scene.materials,
            &resolved,
        );
        let (sky, sky_image) = upload_sky(gpu, scene.sky.as_ref())?;
        if drawn.is_empty() {
            return Err(RenderError::EmptyScene);
        }
        let vertices = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("scene_vertices"),
            contents: bytemuck::cast_slice(&drawn),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let instances = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("scene_instances"),
            contents: bytemuck::cast_slice(&instance_data),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let no_uvs = [InstanceUv::default()];
        let instance_uvs = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("scene_instance_uvs"),
            contents: bytemuck::cast_slice(if scene.instance_uvs.is_empty() {
                &no_uvs
            } else {
                &scene.instance_uvs
            }),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let (lights, light_count) = gpu_lights(scene)?;
        let lights = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("scene_lights"),
            contents: bytemuck::cast_slice(&lights),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let (lw, lh, layers, data) = lightmap_texels(gpu, scene)?;
        let lightmap = crate::util::sampled_texture_array(
            dev,
            &gpu.queue,
            "scene_lightmap",
            (lw, lh, layers),
            wgpu::TextureFormat::Rgba16Float,
            bytemuck::cast_slice(&data),
        );
        let linear_sampler = dev.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("linear_clamp"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let (grid, words) = match &scene.probes {
            Some(g) => {
                g.validate()?;
                g.gpu_words()
            }
            None => (ProbeGridUniform::default(), vec![[0.0; 4]; 9]),
        };
        let probe_grid = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("scene_probe_grid"),
            contents: bytemuck::bytes_of(&grid),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let probes = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("scene_probes"),
            contents: bytemuck::cast_slice(&words),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let camera = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("camera_uniform"),
            size: std::mem::size_of::<CameraUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Self {
            vertex_count: drawn.len() as u32,
            vertices,
            instances,
            instance_uvs,
            materials,
            sky,
            sky_image,
            lights,
            light_count,
            lightmap,
            linear_sampler,
            probe_grid,
            probes,
            camera,
            origin: scene.origin,
            camera_view: scene.camera,
        })
    }

    /// Writes the camera uniform for a `width × height` target, from the uploaded camera.
    pub fn update_camera(&self, queue: &wgpu::Queue, width: u32, height: u32) {
        self.write_camera(queue, &self.camera_view, width, height);
    }

    /// Writes the camera uniform for a `width × height` target, from `camera` (a moved view of
    /// the same scene; nothing else is uploaded).
    pub fn write_camera(&self, queue: &wgpu::Queue, camera: &CameraView, width: u32, height: u32) {
        let (w, h) = (width.max(1) as f32, height.max(1) as f32);
        let view = camera.view(self.origin);
        let proj = camera.projection(w / h);
        let vp = proj * view;
        let eye = (camera.position - self.origin).as_vec3();
        let u = CameraUniform {
            view_proj: vp.to_cols_array_2d(),
            inv_view_proj: vp.inverse().to_cols_array_2d(),
            view: view.to_cols_array_2d(),
            proj: proj.to_cols_array_2d(),
            inv_proj: proj.inverse().to_cols_array_2d(),
            position: [eye.x, eye.y, eye.z, 1.0],
            viewport: [w, h, 1.0 / w, 1.0 / h],
            params: [camera.near, camera.far, self.light_count as f32, 0.0],
        };
        queue.write_buffer(&self.camera, 0, bytemuck::bytes_of(&u));
    }
}

/// Refuses what would put NaN or out-of-range reads on the GPU: non-finite vertices and
/// instances, indices past the vertices, draws past the indices or instances, textures whose
/// bytes do not fill them. Returns the draws (one over everything when the scene has none) and
/// the instances (the identity when it has none).
fn validate(scene: &RenderScene) -> Result<(Vec<DrawRange>, Vec<InstanceData>), RenderError> {
    if scene.vertices.is_empty() || scene.indices.is_empty() {
        return Err(RenderError::EmptyScene);
    }
    for v in &scene.vertices {
        let all = v
            .position
            .iter()
            .chain(&v.normal)
            .chain(&v.albedo)
            .chain(&v.emissive)
            .chain(&v.lightmap_uv)
            .chain(&v.uv);
        if all.clone().any(|x| !x.is_finite()) {
            return Err(RenderError::NonFinite("vertex data"));
        }
    }
    if let Some(&i) = scene
        .indices
        .iter()
        .find(|&&i| i as usize >= scene.vertices.len())
    {
        return Err(RenderError::IndexOutOfRange {
            index: i,
            vertices: scene.vertices.len(),
        });
    }
    let whole = [DrawRange::new(0, 0, scene.indices.len() as u32)];
    let draws = if scene.draws.is_empty() {
        whole.to_vec()
    } else {
        scene.draws.clone()
    };
    let instance_count = scene.instances.len().max(1) as u64;
    for d in &draws {
        if u64::from(d.first) + u64::from(d.count) > scene.indices.len() as u64 {
            return Err(SceneError::DrawRange {
                start: d.first.into(),
                end: u64::from(d.first) + u64::from(d.count),
                len: scene.indices.len(),
                of: "indices",
            }
            .into());
        }
        if u64::from(d.first_instance) + u64::from(d.instance_count) > instance_count {
            return Err(SceneError::DrawRange {
                start: d.first_instance.into(),
                end: u64::from(d.first_instance) + u64::from(d.instance_count),
                len: instance_count as usize,
                of: "instances",
            }
            .into());
        }
    }
    let instance_data: Vec<InstanceData> = if scene.instances.is_empty() {
        vec![InstanceData::IDENTITY]
    } else {
        scene.instances.clone()
    };
    let finite = |i: &InstanceData| {
        i.model
            .iter()
            .chain(&i.normal)
            .flatten()
            .all(|x| x.is_finite())
    };
    if !instance_data.iter().all(finite) {
        return Err(RenderError::NonFinite("instance data"));
    }
    for t in &scene.textures {
        if t.pixels.len() as u64 != u64::from(t.width) * u64::from(t.height) * 4
            || t.width == 0
            || t.height == 0
        {
            return Err(SceneError::TextureBytes {
                texture: t.name.clone(),
                bytes: t.pixels.len(),
                width: t.width,
                height: t.height,
            }
            .into());
        }
    }
    Ok((draws, instance_data))
}

/// Each draw's vertices in draw order, so draws become plain vertex ranges; copies with their
/// own light-map coordinates read them relative to their draw.
fn flatten_draws(
    scene: &RenderScene,
    draws: &[DrawRange],
    instance_data: &mut [InstanceData],
) -> Result<(Vec<Vertex>, Vec<DrawRange>), RenderError> {
    let mut drawn: Vec<Vertex> = Vec::new();
    let mut resolved = Vec::with_capacity(draws.len());
    for d in draws {
        let first = drawn.len() as u32;
        drawn.extend(
            scene.indices[d.first as usize..(d.first + d.count) as usize]
                .iter()
                .map(|&i| scene.vertices[i as usize]),
        );
        resolved.push(DrawRange { first, ..*d });
        // Copies with their own light-map coordinates read them relative to this draw.
        let range = d.first_instance as usize..(d.first_instance + d.instance_count) as usize;
        for inst in &mut instance_data[range] {
            if inst.lightmap[2] != 0 {
                inst.lightmap[1] = first;
                if u64::from(inst.lightmap[0]) + u64::from(d.count)
                    > scene.instance_uvs.len() as u64
                {
                    return Err(SceneError::DrawRange {
                        start: inst.lightmap[0].into(),
                        end: u64::from(inst.lightmap[0]) + u64::from(d.count),
                        len: scene.instance_uvs.len(),
                        of: "copies' light-map coordinates",
                    }
                    .into());
                }
            }
        }
    }
    if !scene
        .instance_uvs
        .iter()
        .all(|u| u.uv.iter().all(|x| x.is_finite()))
    {
        return Err(RenderError::NonFinite("instance light-map coordinates"));
    }
    Ok((drawn, resolved))
}

/// The lights in the GPU's layout, relative to the scene's origin, and how many; a light with
/// a non-positive range reaches nothing and is left out.
fn gpu_lights(scene: &RenderScene) -> Result<(Vec<GpuLight>, u32), RenderError> {
    let mut lights: Vec<GpuLight> = Vec::with_capacity(scene.lights.len().max(1));
    for l in &scene.lights {
        if l.range.is_nan() {
            return Err(RenderError::NonFinite("light"));
        }
        if l.range <= 0.0 {
            // A non-positive range reaches nothing, as in the bake.
            continue;
        }
        let p = (l.position - scene.origin).as_vec3();
        let c = l.color * l.intensity;
        if !(p.is_finite() && c.is_finite() && l.direction.is_finite()) || l.intensity < 0.0 {
            return Err(RenderError::NonFinite("light"));
        }
        let (kind, spot) = match l.kind {
            LightKind::Directional => (0.0, [0.0; 4]),
            LightKind::Point => (1.0, [0.0; 4]),
            LightKind::Spot {
                inner_angle,
                outer_angle,
            } => {
                let (ci, co) = (inner_angle.cos(), outer_angle.cos());
                (2.0, [co, 1.0 / (ci - co).max(1e-4), 0.0, 0.0])
            }
        };
        lights.push(GpuLight {
            position_range: [
                p.x,
                p.y,
                p.z,
                if l.range.is_finite() { l.range } else { 0.0 },
            ],
            direction_kind: {
                let d = l.direction.normalize_or(Vec3::NEG_Y);
                [d.x, d.y, d.z, kind]
            },
            color: [c.x, c.y, c.z, 0.0],
            spot,
        });
    }
    let light_count = lights.len() as u32;
    if lights.is_empty() {
        lights.push(GpuLight::zeroed());
    }
    Ok((lights, light_count))
}

/// The light map's size, pages and half-float texels (a black 1×1 page without one), checked
/// against the adapter's limits and the pages the vertices name.
fn lightmap_texels(
    gpu: &crate::GpuContext,
    scene: &RenderScene,
) -> Result<(u32, u32, u32, Vec<u16>), RenderError> {
    let (lw, lh, layers, data): (u32, u32, u32, Vec<u16>) = match &scene.lightmap {
        Some(lm)
            if lm.width > 0
                && lm.height > 0
                && lm.pages > 0
                && lm.texels.len() as u64
                    == u64::from(lm.width) * u64::from(lm.height) * u64::from(lm.pages) =>
        {
            if lm.texels.iter().flatten().any(|x| !x.is_finite()) {
                return Err(RenderError::NonFinite("light map"));
            }
            let limits = gpu.device.limits();
            let max = limits.max_texture_dimension_2d;
            if lm.width > max || lm.height > max {
                return Err(RenderError::InvalidSize {
                    width: lm.width,
                    height: lm.height,
                    max,
                });
            }
            if lm.pages > limits.max_texture_array_layers {
                return Err(SceneError::LightMapPages {
                    pages: lm.pages,
                    max: limits.max_texture_array_layers,
                }
                .into());
            }
            (
                lm.width,
                lm.height,
                lm.pages,
                lm.texels
                    .iter()
                    .flat_map(|t| [t[0], t[1], t[2], 1.0].map(f32_to_f16))
                    .collect(),
            )
        }
        Some(_) => return Err(RenderError::NonFinite("light map size")),
        None => (1, 1, 1, vec![0; 4]),
    };
    let page = scene
        .vertices
        .iter()
        .map(|v| v.lightmap_page)
        .chain(scene.instance_uvs.iter().map(|u| u.page))
        .find(|&p| p >= layers && p != PROBE_LIT);
    if let Some(p) = page {
        return Err(SceneError::LightMapPage {
            page: p,
            pages: layers,
        }
        .into());
    }
    // wgpu's GL backend decides a texture's view dimension when it creates it, and takes a
    // one-layer texture for `D2`: the shaders' `texture_2d_array` then reads black. A second,
    // empty layer makes it an array there (never read: no vertex names page 1).
    if gpu.info.backend == wgpu::Backend::Gl && layers == 1 {
        let mut data = data;
        data.resize(data.len() * 2, 0);
        return Ok((lw, lh, 2, data));
    }
    Ok((lw, lh, layers, data))
}

/// The sky's uniform and image.
fn upload_sky(
    gpu: &crate::GpuContext,
    sky: Option<&Sky>,
) -> Result<(wgpu::Buffer, wgpu::TextureView), RenderError> {
    let rgb = |c: &[f64; 3]| [c[0] as f32, c[1] as f32, c[2] as f32, 0.0];
    let mut u = SkyUniform::zeroed();
    let (mut w, mut h, mut data) = (1u32, 1u32, vec![0u16; 4]);
    match sky {
        None => {}
        Some(Sky::Uniform { radiance }) => {
            u.kind = 1;
            u.a = rgb(radiance);
        }
        Some(Sky::Gradient { zenith, horizon }) => {
            u.kind = 2;
            u.a = rgb(zenith);
            u.b = rgb(horizon);
        }
        Some(Sky::Image(img)) => {
            let max = gpu.device.limits().max_texture_dimension_2d;
            if img.width > max || img.height > max {
                return Err(RenderError::InvalidSize {
                    width: img.width,
                    height: img.height,
                    max,
                });
            }
            if img.texels.len() as u64 != u64::from(img.width) * u64::from(img.height) {
                return Err(RenderError::NonFinite("sky image size"));
            }
            u.kind = 3;
            u.size = [img.width, img.height];
            (w, h) = (img.width, img.height);
            data = img
                .texels
                .iter()
                .flat_map(|t| [t[0], t[1], t[2], 1.0].map(f32_to_f16))
                .collect();
        }
    }
    if u.a.iter().chain(&u.b).any(|x| !x.is_finite()) {
        return Err(RenderError::NonFinite("sky"));
    }
    let buffer = gpu
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("scene_sky"),
            contents: bytemuck::bytes_of(&u),
            usage: wgpu::BufferUsages::UNIFORM,
        });
    Ok((buffer, rgba16f_texture(gpu, "scene_sky_image", w, h, &data)))
}

/// A sampled `width × height` Rgba16Float texture from f16 bits, RGBA per texel.
fn rgba16f_texture(
    gpu: &crate::GpuContext,
    label: &str,
    width: u32,
    height: u32,
    data: &[u16],
) -> wgpu::TextureView {
    crate::util::sampled_texture(
        &gpu.device,
        &gpu.queue,
        label,
        (width, height, 1),
        wgpu::TextureFormat::Rgba16Float,
        bytemuck::cast_slice(data),
    )
}

use bytemuck::Zeroable as _;

#[cfg(test)]
mod tests {
    use super::*;

    /// A probe grid whose sides multiply past any count is a typed error, not an overflow.
    #[test]
    fn a_huge_or_short_probe_grid_is_a_typed_error() {
        let grid = |dims: [u32; 3], n: usize| ProbeGrid {
            origin: [0.0; 3],
            step: 1.0,
            dims,
            sh: vec![[[0.0; 3]; 9]; n],
            valid: vec![true; n],
        };
        assert!(grid([2, 1, 1], 2).validate().is_ok());
        for (dims, n) in [([u32::MAX; 3], 1), ([3, 1, 1], 2), ([0, 1, 1], 0)] {
            assert!(matches!(
                grid(dims, n).validate(),
                Err(RenderError::ProbeLayout { .. })
            ));
        }
        let mut nan = grid([1, 1, 1], 1);
        nan.sh[0][4][1] = f32::NAN;
        assert!(matches!(nan.validate(), Err(RenderError::NonFinite(_))));
    }

    #[test]
    fn f16_round_trip() {
        for x in [0.0f32, 1.0, -2.5, 0.1, 1e-6, 65504.0, 1e9, 3.3e-5] {
            let back = crate::capture::f16_to_f32(f32_to_f16(x));
            let want = x.clamp(-65504.0, 65504.0);
            assert!(
                (back - want).abs() <= want.abs() * 1e-3 + 6e-8,
                "{x} -> {back}"
            );
        }
    }

    #[test]
    fn materials_textures_normals_and_draws_come_from_the_scene() {
        use radiant_scene::{AlphaMode, Image, Surface, TextureRef, Triangle};
        // A 2 × 1 texture: sRGB 255 and 0, mean linear 0.5 in every channel.
        let img = Image::new("t", 2, 1, vec![255, 255, 255, 255, 0, 0, 0, 0]).expect("image");
        let tex = TextureRef {
            image: 0,
            sampler: Default::default(),
            tex_coord: 0,
            transform: radiant_scene::texture::UvTransform {
                scale: [2.0, 2.0],
                ..Default::default()
            },
        };
        let textured = Surface {
            name: "leaves".into(),
            reflectance: [0.4, 0.2, 0.1],
            base_color_texture: Some(tex),
            alpha: AlphaMode::Mask { cutoff: 0.3 },
            double_sided: true,
            ..Surface::default()
        };
        let plain = Surface {
            name: "wall".into(),
            reflectance: [0.5; 3],
            ..Surface::default()
        };
        let mut scene = radiant_scene::Scene {
            surfaces: vec![plain.clone(), textured, plain],
            images: vec![img],
            ..Default::default()
        };
        for surface in [0u32, 1, 2, 1] {
            let mut t = Triangle::new(
                [DVec3::ZERO, DVec3::X, DVec3::Y].map(|p| p + DVec3::Z * f64::from(surface)),
                surface,
            );
            t.normals[2] = Vec3::new(0.6, 0.0, 0.8);
            t.uv[0] = [Vec2::ZERO, Vec2::X, Vec2::Y];
            scene.triangles.push(t);
        }
        let rs = RenderScene::from_scene(&scene, None).expect("convert");
        // The two plain surfaces share one material; the textured one has its own.
        assert_eq!(rs.materials.len(), 2);
        let m = rs.materials[1];
        assert_eq!(m.texture, Some(0));
        assert_eq!(m.alpha_cutoff, Some(0.3));
        assert!(m.cull_back && !rs.materials[0].cull_back);
        // Factor × texture mean is the surface's reflectance.
        let v = &rs.vertices[3];
        for (c, want) in [0.4f32, 0.2, 0.1].iter().enumerate() {
            assert!((v.albedo[c] * 0.5 - want).abs() < 1e-6, "{:?}", v.albedo);
        }
        // Texture coordinates with the transform, smooth normals per vertex.
        assert_eq!(rs.vertices[4].uv, [2.0, 0.0]);
        assert_eq!(rs.vertices[5].normal, [0.6, 0.0, 0.8]);
        assert_eq!(rs.vertices[4].normal, [0.0, 0.0, 1.0]);
        // The second wall is the first moved by 2 along z: drawn as its instance, with its own
        // light-map charts. The rest is drawn flattened, grouped by material.
        assert_eq!(rs.draws.len(), 2, "{:?}", rs.draws);
        let (flat, inst) = (rs.draws[0], rs.draws[1]);
        assert_eq!((flat.material, flat.instance_count), (1, 1));
        let flat_tris: Vec<u32> = rs.indices
            [flat.first as usize..(flat.first + flat.count) as usize]
            .iter()
            .map(|&i| i / 3)
            .collect();
        assert_eq!(flat_tris, vec![1, 1, 1, 3, 3, 3]);
        assert_eq!((inst.material, inst.count, inst.instance_count), (0, 3, 2));
        assert_eq!(rs.indices[inst.first as usize], 0);
        let copy = rs.instances[(inst.first_instance + 1) as usize];
        assert_eq!(copy.model[2][3], 2.0, "{copy:?}");
        // Its light-map coordinates are its own: the copy's triangle's, in the prototype's order.
        assert_eq!(copy.lightmap[2], 1);
        assert_eq!(rs.instances[inst.first_instance as usize].lightmap[2], 0);
        let base = copy.lightmap[0] as usize;
        for k in 0..3 {
            assert_eq!(rs.instance_uvs[base + k].uv, rs.vertices[6 + k].lightmap_uv);
            assert_ne!(rs.vertices[k].lightmap_uv, rs.vertices[6 + k].lightmap_uv);
        }
    }

    #[test]
    fn the_light_map_is_the_scenes_atlas_at_the_asked_density() {
        let scene = radiant_scene::builtin("cornell-box").expect("builtin");
        let rs = RenderScene::from_scene(&scene, Some(300.0)).expect("convert");
        let atlas = rs.atlas.as_ref().expect("atlas");
        assert_eq!(
            *atlas,
            radiant_scene::atlas::Atlas::new(&scene, Some(300.0)).expect("atlas")
        );
        let lm = rs.lightmap.as_ref().expect("light map");
        assert_eq!((lm.width, lm.height), (atlas.width, atlas.height));
        assert!((atlas.texel_density(&scene) / 300.0 - 1.0).abs() < 0.1);
        // Flattened, every vertex carries its triangle's atlas coordinates.
        let flat = RenderScene::from_scene_flattened(&scene, Some(300.0)).expect("convert");
        for (tri, uv) in flat.vertices.chunks_exact(3).zip(&atlas.uv) {
            for k in 0..3 {
                assert_eq!(tri[k].lightmap_uv, uv[k].to_array());
            }
        }
        assert!(matches!(
            RenderScene::from_scene(&scene, Some(f64::NAN)),
            Err(RenderError::Atlas(_))
        ));
    }

    #[test]
    fn cornell_conversion_keeps_every_triangle_and_a_valid_atlas() {
        let scene = radiant_scene::builtin("cornell-box").expect("builtin");
        let mut rs = RenderScene::from_scene(&scene, None).expect("convert");
        assert_eq!(rs.vertices.len(), scene.triangles.len() * 3);
        assert!(
            rs.vertices
                .iter()
                .all(|v| v.lightmap_uv.iter().all(|&c| (0.0..=1.0).contains(&c)))
        );
        rs.fill_synthetic_lightmap(0.05);
        let lm = rs.lightmap.as_ref().expect("light map");
        assert!(
            lm.texels
                .iter()
                .flatten()
                .all(|x| x.is_finite() && *x >= 0.0)
        );
        assert!(lm.texels.iter().any(|t| t[0] > 0.1));
    }
}
