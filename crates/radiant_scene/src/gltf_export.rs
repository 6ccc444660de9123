//! glTF 2.0 export of a scene and its light map, for other engines (written with the `gltf`
//! crate's typed JSON model, `gltf::json`).
//!
//! Every surface becomes one mesh of one primitive (positions relative to the scene's centre,
//! which its node's translation restores; normals; TEXCOORD_0 with `KHR_texture_transform`
//! already applied (the scene's own first set on untextured surfaces); TEXCOORD_1 on the
//! light-map atlas) and one material (base colour factor and
//! texture, emission, alpha mode). Double-sided surfaces are written as their two sides, each
//! with its own light (`doubleSided` false). Base-colour images are written again as PNG.
//!
//! The light map is one PNG image per page, sRGB-encoded 8-bit: a texel `t` (in [0, 1] per
//! channel) stands for the incident radiance `H = scale · srgb_to_linear(t)`, so a surface of
//! base colour `a` reflects `a · H` (glTF emissive units). A surface whose charts lie on several
//! pages is one mesh with a primitive per page. Each baked primitive names its page in its
//! `extras`: `{"lightmap": {"texture": T, "texCoord": 1, "scale": S, "encoding": "srgb", "ktx2":
//! K, "exr": X}}`, `T` the index into `textures`. The same page is written in full range beside
//! the `.glb` (`crate::hdr_lightmap`): `K`, `STEM_lightmap[_P].ktx2` (RGBA16F, zstd), and `X`,
//! `STEM_lightmap[_P].exr` (32-bit float), URIs relative to the `.glb`, whose texels are `H`
//! itself (no scale, no sRGB), and `quantity` says so in words. The scene's camera is written
//! (a perspective camera node) and so are its punctual lights (`KHR_lights_punctual`), each
//! marked `extras.radiant.baked`: their light is in the light map already, so a client that
//! lights dynamic objects with them must not add it to the static ones.

use std::path::Path;

use glam::{DVec3, Vec2};
use gltf::json;
use gltf::json::validation::{Checked, USize64};

use crate::atlas::Atlas;
use crate::{AlphaMode, Scene, SceneError};

/// A light map to write: texels (`atlas.pages` pages of `atlas.width × atlas.height`, linear RGB
/// `H`, each row-major, one after the other) on `atlas`.
pub struct LightmapExport<'a> {
    /// The atlas the texels are on (its `uv` become TEXCOORD_1).
    pub atlas: &'a Atlas,
    /// The texels.
    pub texels: &'a [[f32; 3]],
}

/// Where the light map went in the file.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportReport {
    /// Primitives written.
    pub primitives: usize,
    /// Indices of the light map's pages in `textures` (empty without a light map).
    pub lightmap_textures: Vec<usize>,
    /// The light map's scale (`H = scale · srgb_to_linear(texel)`).
    pub lightmap_scale: f32,
    /// The full-range pages written beside the `.glb`, KTX2 then EXR for each page.
    pub hdr_files: Vec<std::path::PathBuf>,
    /// Their bytes, in the same order.
    pub hdr_bytes: Vec<usize>,
    /// Bytes written.
    pub bytes: usize,
}

fn err(what: impl Into<String>) -> SceneError {
    SceneError::Export(what.into())
}

/// Writes `scene` (and `lightmap`) to `path` as binary glTF (`.glb`), atomically (a temporary
/// file, then a rename).
pub fn export_gltf(
    scene: &Scene,
    lightmap: Option<LightmapExport<'_>>,
    path: &Path,
) -> Result<ExportReport, SceneError> {
    if let Some(lm) = &lightmap
        && (lm.atlas.uv.len() != scene.triangles.len()
            || lm.atlas.page.len() != scene.triangles.len()
            || lm.texels.len()
                != lm.atlas.width as usize * lm.atlas.height as usize * lm.atlas.pages as usize)
    {
        return Err(err("the light map does not match the scene's atlas"));
    }
    if !path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("glb"))
    {
        return Err(err(format!(
            "{}: Radiant writes binary glTF: name the file .glb",
            path.display()
        )));
    }
    let mut w = Writer::default();
    let mut root = json::Root {
        asset: json::Asset {
            generator: Some(format!("Radiant {}", env!("CARGO_PKG_VERSION"))),
            ..Default::default()
        },
        ..Default::default()
    };
    // Images: the base-colour ones, then the light map.
    let mut image_texture: Vec<Option<json::Index<json::Texture>>> = vec![None; scene.images.len()];
    let mut samplers: Vec<(crate::texture::Sampler, json::Index<json::texture::Sampler>)> =
        Vec::new();
    let mut means: Vec<Option<[f64; 4]>> = vec![None; scene.images.len()];
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for t in &scene.triangles {
        for v in t.vertices {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    let origin = if lo.is_finite() && hi.is_finite() {
        (lo + hi) * 0.5
    } else {
        DVec3::ZERO
    };
    // The light map's pages, one texture each, with one scale; and each in full range beside
    // the file.
    let mut page_textures = Vec::new();
    let mut page_hdr: Vec<(String, String)> = Vec::new();
    let mut hdr_files = Vec::new();
    let mut hdr_bytes = Vec::new();
    let stem = path
        .file_stem()
        .map_or_else(|| "scene".into(), |s| s.to_string_lossy().into_owned());
    let dir = path.parent().unwrap_or_else(|| Path::new(""));
    let mut lightmap_scale = 0.0f32;
    if let Some(lm) = &lightmap {
        let peak = lm
            .texels
            .iter()
            .flatten()
            .copied()
            .filter(|x| x.is_finite())
            .fold(0.0f32, f32::max);
        lightmap_scale = if peak > 0.0 { peak } else { 1.0 };
        let sampler = root.push(json::texture::Sampler {
            mag_filter: Some(Checked::Valid(json::texture::MagFilter::Linear)),
            min_filter: Some(Checked::Valid(json::texture::MinFilter::Linear)),
            wrap_s: Checked::Valid(json::texture::WrappingMode::ClampToEdge),
            wrap_t: Checked::Valid(json::texture::WrappingMode::ClampToEdge),
            ..Default::default()
        });
        let size = lm.atlas.width as usize * lm.atlas.height as usize;
        for (p, page) in lm.texels.chunks_exact(size.max(1)).enumerate() {
            let rgb: Vec<u8> = page
                .iter()
                .flatten()
                .map(|&x| {
                    let x = if x.is_finite() {
                        (x / lightmap_scale).clamp(0.0, 1.0)
                    } else {
                        0.0
                    };
                    radiant_color::linear_to_srgb8(f64::from(x))
                })
                .collect();
            let png = encode_png(
                lm.atlas.width,
                lm.atlas.height,
                image::ColorType::Rgb8,
                &rgb,
            )?;
            let name = if lm.atlas.pages > 1 {
                format!("lightmap_{p}")
            } else {
                "lightmap".to_string()
            };
            let (ktx2, exr) = (format!("{stem}_{name}.ktx2"), format!("{stem}_{name}.exr"));
            let (width, height) = (lm.atlas.width, lm.atlas.height);
            for (file, bytes) in [
                (
                    &ktx2,
                    crate::hdr_lightmap::ktx2_rgba16f(width, height, page)?,
                ),
                (&exr, crate::hdr_lightmap::exr_rgb32f(width, height, page)?),
            ] {
                write_atomic(&dir.join(file), &bytes)?;
                hdr_files.push(dir.join(file));
                hdr_bytes.push(bytes.len());
            }
            page_hdr.push((ktx2, exr));
            let image = w.image(&mut root, png, &name);
            page_textures.push(root.push(json::Texture {
                name: Some(name),
                sampler: Some(sampler),
                source: image,
                extensions: None,
                extras: Default::default(),
            }));
        }
    }
    let mut nodes = Vec::new();
    let mut primitives = 0;
    for (s, surface) in scene.surfaces.iter().enumerate() {
        let tris: Vec<usize> = (0..scene.triangles.len())
            .filter(|&i| scene.triangles[i].surface as usize == s)
            .collect();
        if tris.is_empty() {
            continue;
        }
        // Material.
        let tex = surface
            .base_color_texture
            .filter(|t| (t.image as usize) < scene.images.len());
        let factor: [f64; 3] = match tex {
            Some(t) => {
                let mean = *means[t.image as usize]
                    .get_or_insert_with(|| scene.images[t.image as usize].mean_linear());
                std::array::from_fn(|c| {
                    if mean[c] > 1e-9 {
                        (surface.reflectance[c] / mean[c]).min(1.0)
                    } else {
                        0.0
                    }
                })
            }
            None => surface.reflectance,
        };
        let base_color_texture = match tex {
            Some(t) => {
                let i = t.image as usize;
                let texture = match image_texture[i] {
                    Some(x) => x,
                    None => {
                        let img = &scene.images[i];
                        let png = encode_png(
                            img.width,
                            img.height,
                            image::ColorType::Rgba8,
                            &img.pixels,
                        )?;
                        let source = w.image(&mut root, png, &img.name);
                        let sampler = match samplers.iter().find(|(k, _)| *k == t.sampler) {
                            Some((_, x)) => *x,
                            None => {
                                let x = root.push(sampler(t.sampler));
                                samplers.push((t.sampler, x));
                                x
                            }
                        };
                        let x = root.push(json::Texture {
                            name: Some(img.name.clone()),
                            sampler: Some(sampler),
                            source,
                            extensions: None,
                            extras: Default::default(),
                        });
                        image_texture[i] = Some(x);
                        x
                    }
                };
                Some(json::texture::Info {
                    index: texture,
                    tex_coord: 0,
                    extensions: None,
                    extras: Default::default(),
                })
            }
            None => None,
        };
        let peak = surface.emission.iter().fold(0.0f64, |m, &e| m.max(e));
        let (emissive, strength) = if peak > 1.0 {
            (surface.emission.map(|e| (e / peak) as f32), Some(peak))
        } else {
            (surface.emission.map(|e| e as f32), None)
        };
        let (alpha_mode, alpha_cutoff) = match surface.alpha {
            AlphaMode::Opaque => (json::material::AlphaMode::Opaque, None),
            AlphaMode::Mask { cutoff } => (
                json::material::AlphaMode::Mask,
                Some(json::material::AlphaCutoff(cutoff as f32)),
            ),
            AlphaMode::Blend => (json::material::AlphaMode::Blend, None),
        };
        let material = root.push(json::Material {
            name: Some(surface.material.clone()),
            alpha_cutoff,
            alpha_mode: Checked::Valid(alpha_mode),
            double_sided: false,
            pbr_metallic_roughness: json::material::PbrMetallicRoughness {
                base_color_factor: json::material::PbrBaseColorFactor([
                    factor[0] as f32,
                    factor[1] as f32,
                    factor[2] as f32,
                    surface.base_color_alpha as f32,
                ]),
                base_color_texture,
                metallic_factor: json::material::StrengthFactor(0.0),
                roughness_factor: json::material::StrengthFactor(1.0),
                ..Default::default()
            },
            emissive_factor: json::material::EmissiveFactor(emissive),
            extensions: strength.map(|s| json::extensions::material::Material {
                emissive_strength: Some(json::extensions::material::EmissiveStrength {
                    emissive_strength: json::extensions::material::EmissiveStrengthFactor(s as f32),
                }),
            }),
            ..Default::default()
        });
        // One primitive per light-map page the surface's charts are on (one without a map).
        let page_of = |i: usize| lightmap.as_ref().map_or(0, |lm| lm.atlas.page[i]);
        let mut pages: Vec<u32> = tris.iter().map(|&i| page_of(i)).collect();
        pages.sort_unstable();
        pages.dedup();
        let mut prims = Vec::with_capacity(pages.len());
        for page in pages {
            let tris: Vec<usize> = tris
                .iter()
                .copied()
                .filter(|&i| page_of(i) == page)
                .collect();
            prims.push(primitive(
                &mut w,
                &mut root,
                scene,
                &tris,
                Vertices {
                    origin,
                    tex,
                    uv1: lightmap.as_ref().map(|lm| &lm.atlas.uv[..]),
                },
                material,
                page_textures
                    .get(page as usize)
                    .map(|&texture| LightmapRef {
                        texture,
                        scale: lightmap_scale,
                        hdr: &page_hdr[page as usize],
                    }),
            )?);
        }
        primitives += prims.len();
        let mesh = root.push(json::Mesh {
            name: Some(surface.name.clone()),
            primitives: prims,
            weights: None,
            extensions: None,
            extras: Default::default(),
        });
        nodes.push(root.push(json::Node {
            name: Some(surface.name.clone()),
            mesh: Some(mesh),
            translation: Some(origin.as_vec3().to_array()),
            ..Default::default()
        }));
    }
    // The camera, so a client renders the same view, and the punctual lights, marked as
    // already in the light map (`extras.radiant.baked`), for clients that light dynamic
    // objects with them.
    if let Some(cam) = &scene.camera {
        nodes.push(camera_node(&mut root, cam));
    }
    if !scene.lights.is_empty() {
        let lights: Vec<_> = scene.lights.iter().map(light).collect::<Result<_, _>>()?;
        for (i, l) in scene.lights.iter().enumerate() {
            nodes.push(light_node(&mut root, l, i as u32));
        }
        root.extensions = Some(json::extensions::Root {
            khr_lights_punctual: Some(json::extensions::root::KhrLightsPunctual { lights }),
        });
        root.extensions_used.push("KHR_lights_punctual".into());
    }
    let scene_index = root.push(json::Scene {
        name: None,
        nodes,
        extensions: None,
        extras: Default::default(),
    });
    root.scene = Some(scene_index);
    if strength_used(&root) {
        root.extensions_used
            .push("KHR_materials_emissive_strength".into());
    }
    let bytes = w.finish(&mut root)?;
    write_atomic(path, &bytes)?;
    Ok(ExportReport {
        primitives,
        lightmap_textures: page_textures.iter().map(|t| t.value()).collect(),
        lightmap_scale,
        hdr_files,
        hdr_bytes,
        bytes: bytes.len(),
    })
}

/// A node with the scene's camera: perspective, looking along its local −Z with +Y up.
fn camera_node(root: &mut json::Root, cam: &crate::Camera) -> json::Index<json::Node> {
    let camera = root.push(json::Camera {
        name: Some("camera".into()),
        orthographic: None,
        perspective: Some(json::camera::Perspective {
            aspect_ratio: None,
            yfov: cam.yfov as f32,
            zfar: None,
            znear: 0.01,
            extensions: None,
            extras: Default::default(),
        }),
        type_: Checked::Valid(json::camera::Type::Perspective),
        extensions: None,
        extras: Default::default(),
    });
    let forward = cam.forward.normalize();
    let right = forward.cross(cam.up).normalize();
    let up = right.cross(forward);
    let rotation = glam::DQuat::from_mat3(&glam::DMat3::from_cols(right, up, -forward));
    root.push(json::Node {
        name: Some("camera".into()),
        camera: Some(camera),
        translation: Some(cam.position.as_vec3().to_array()),
        rotation: Some(json::scene::UnitQuaternion(
            rotation.normalize().as_quat().to_array(),
        )),
        ..Default::default()
    })
}

/// A punctual light as `KHR_lights_punctual` has it, marked as baked into the light map.
fn light(
    l: &crate::Light,
) -> Result<json::extensions::scene::khr_lights_punctual::Light, SceneError> {
    use json::extensions::scene::khr_lights_punctual as khr;
    let (type_, spot) = match l.kind {
        crate::LightKind::Directional => (khr::Type::Directional, None),
        crate::LightKind::Point => (khr::Type::Point, None),
        crate::LightKind::Spot {
            inner_cone_angle,
            outer_cone_angle,
        } => (
            khr::Type::Spot,
            Some(khr::Spot {
                inner_cone_angle: inner_cone_angle as f32,
                outer_cone_angle: outer_cone_angle as f32,
            }),
        ),
    };
    let extras = serde_json::json!({ "radiant": { "baked": true } });
    Ok(khr::Light {
        color: l.color.map(|c| c as f32),
        extensions: None,
        extras: Some(
            serde_json::value::RawValue::from_string(extras.to_string())
                .map_err(|e| err(format!("extras: {e}")))?,
        ),
        intensity: l.intensity as f32,
        name: Some(l.name.clone()),
        range: l.range.map(|r| r as f32),
        spot,
        type_: Checked::Valid(type_),
    })
}

/// A node holding light `index`: at its position, its local −Z along its direction.
fn light_node(root: &mut json::Root, l: &crate::Light, index: u32) -> json::Index<json::Node> {
    let rotation = glam::DQuat::from_rotation_arc(DVec3::NEG_Z, l.direction.normalize());
    root.push(json::Node {
        name: Some(l.name.clone()),
        translation: Some(l.position.as_vec3().to_array()),
        rotation: Some(json::scene::UnitQuaternion(
            rotation.normalize().as_quat().to_array(),
        )),
        extensions: Some(json::extensions::scene::Node {
            khr_lights_punctual: Some(
                json::extensions::scene::khr_lights_punctual::KhrLightsPunctual {
                    light: json::Index::new(index),
                },
            ),
        }),
        ..Default::default()
    })
}

/// A primitive's light-map page: its texture, the PNG's scale and the full-range files.
struct LightmapRef<'a> {
    texture: json::Index<json::Texture>,
    scale: f32,
    /// The page's KTX2 and EXR, relative to the `.glb`.
    hdr: &'a (String, String),
}

/// What a primitive's vertices need besides its triangles.
struct Vertices<'a> {
    /// Subtracted from positions (the node's translation adds it back).
    origin: DVec3,
    /// The base-colour texture, whose transform TEXCOORD_0 gets.
    tex: Option<crate::TextureRef>,
    /// Per scene triangle, its light-map coordinates (TEXCOORD_1), if there is a light map.
    uv1: Option<&'a [[Vec2; 3]]>,
}

/// One primitive of scene triangles `tris` (three vertices each) with `material`, naming
/// `lightmap` (its page's texture and scale) in its extras.
fn primitive(
    w: &mut Writer,
    root: &mut json::Root,
    scene: &Scene,
    tris: &[usize],
    v: Vertices<'_>,
    material: json::Index<json::Material>,
    lightmap: Option<LightmapRef<'_>>,
) -> Result<json::mesh::Primitive, SceneError> {
    let (origin, tex) = (v.origin, v.tex);
    let mut pos = Vec::with_capacity(tris.len() * 9);
    let mut nrm = Vec::with_capacity(tris.len() * 9);
    let mut uv0 = Vec::with_capacity(tris.len() * 6);
    let mut uv1 = Vec::with_capacity(tris.len() * 6);
    for &i in tris {
        let t = &scene.triangles[i];
        let face = t.cross().normalize_or(DVec3::Z).as_vec3();
        for k in 0..3 {
            pos.extend((t.vertices[k] - origin).as_vec3().to_array());
            let n = t.normals[k];
            let n = if n.is_finite() && n.length_squared() > 0.5 {
                n.normalize()
            } else {
                face
            };
            nrm.extend(n.to_array());
            // TEXCOORD_0: the base colour's coordinates (transformed), or the scene's own
            // first set (glTF wants TEXCOORD_0 wherever TEXCOORD_1 is).
            let uv = match tex {
                Some(tex) => tex.uv([t.uv[0][k], t.uv[1][k]]),
                None => t.uv[0][k],
            };
            let uv = if uv.is_finite() { uv } else { Vec2::ZERO };
            uv0.extend(uv.to_array());
            if let Some(atlas_uv) = v.uv1 {
                uv1.extend(atlas_uv[i][k].to_array());
            }
        }
    }
    let count = tris.len() * 3;
    let mut attributes = std::collections::BTreeMap::new();
    attributes.insert(
        Checked::Valid(json::mesh::Semantic::Positions),
        w.accessor(root, &pos, count, json::accessor::Type::Vec3, true),
    );
    attributes.insert(
        Checked::Valid(json::mesh::Semantic::Normals),
        w.accessor(root, &nrm, count, json::accessor::Type::Vec3, false),
    );
    if !uv0.is_empty() {
        attributes.insert(
            Checked::Valid(json::mesh::Semantic::TexCoords(0)),
            w.accessor(root, &uv0, count, json::accessor::Type::Vec2, false),
        );
    }
    let mut extras = Default::default();
    if !uv1.is_empty() {
        attributes.insert(
            Checked::Valid(json::mesh::Semantic::TexCoords(1)),
            w.accessor(root, &uv1, count, json::accessor::Type::Vec2, false),
        );
        if let Some(lm) = lightmap {
            let e = serde_json::json!({ "lightmap": {
                "quantity": "H, incident radiance (irradiance / pi): outgoing = baseColor * H + emissive, in glTF emissive units",
                "texture": lm.texture.value(),
                "texCoord": 1,
                "scale": lm.scale,
                "encoding": "srgb",
                "ktx2": lm.hdr.0,
                "exr": lm.hdr.1,
                "hdrEncoding": "linear",
            }});
            extras = Some(
                serde_json::value::RawValue::from_string(e.to_string())
                    .map_err(|e| err(format!("extras: {e}")))?,
            );
        }
    }
    Ok(json::mesh::Primitive {
        attributes,
        extensions: None,
        extras,
        indices: None,
        material: Some(material),
        mode: Checked::Valid(json::mesh::Mode::Triangles),
        targets: None,
    })
}

fn strength_used(root: &json::Root) -> bool {
    root.materials.iter().any(|m| {
        m.extensions
            .as_ref()
            .is_some_and(|e| e.emissive_strength.is_some())
    })
}

fn sampler(s: crate::texture::Sampler) -> json::texture::Sampler {
    use crate::texture::Wrap;
    let wrap = |w: Wrap| {
        Checked::Valid(match w {
            Wrap::Repeat => json::texture::WrappingMode::Repeat,
            Wrap::MirroredRepeat => json::texture::WrappingMode::MirroredRepeat,
            Wrap::ClampToEdge => json::texture::WrappingMode::ClampToEdge,
        })
    };
    json::texture::Sampler {
        mag_filter: Some(Checked::Valid(if s.nearest {
            json::texture::MagFilter::Nearest
        } else {
            json::texture::MagFilter::Linear
        })),
        min_filter: Some(Checked::Valid(json::texture::MinFilter::LinearMipmapLinear)),
        wrap_s: wrap(s.wrap_s),
        wrap_t: wrap(s.wrap_t),
        ..Default::default()
    }
}

fn encode_png(
    width: u32,
    height: u32,
    color: image::ColorType,
    data: &[u8],
) -> Result<Vec<u8>, SceneError> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(data, width, height, color.into())
        .map_err(|e| err(format!("PNG encoding: {e}")))?;
    Ok(out)
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), SceneError> {
    let tmp = path.with_extension("tmp-export");
    std::fs::write(&tmp, bytes)
        .and_then(|()| std::fs::rename(&tmp, path))
        .map_err(|e| err(format!("{}: {e}", path.display())))
}

/// The binary buffer being built: one buffer view per accessor or image, 4-byte aligned.
#[derive(Default)]
struct Writer {
    bin: Vec<u8>,
}

impl Writer {
    fn view(
        &mut self,
        root: &mut json::Root,
        data: &[u8],
        target: Option<json::buffer::Target>,
    ) -> json::Index<json::buffer::View> {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(data);
        root.push(json::buffer::View {
            buffer: json::Index::new(0),
            byte_length: USize64::from(data.len()),
            byte_offset: Some(USize64::from(offset)),
            byte_stride: None,
            name: None,
            target: target.map(Checked::Valid),
            extensions: None,
            extras: Default::default(),
        })
    }

    fn accessor(
        &mut self,
        root: &mut json::Root,
        data: &[f32],
        count: usize,
        type_: json::accessor::Type,
        bounds: bool,
    ) -> json::Index<json::Accessor> {
        let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(root, &bytes, Some(json::buffer::Target::ArrayBuffer));
        let (min, max) = if bounds {
            let n = data.len() / count.max(1);
            let mut lo = vec![f32::INFINITY; n];
            let mut hi = vec![f32::NEG_INFINITY; n];
            for v in data.chunks_exact(n) {
                for c in 0..n {
                    lo[c] = lo[c].min(v[c]);
                    hi[c] = hi[c].max(v[c]);
                }
            }
            (Some(serde_json::json!(lo)), Some(serde_json::json!(hi)))
        } else {
            (None, None)
        };
        root.push(json::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64::from(count),
            component_type: Checked::Valid(json::accessor::GenericComponentType(
                json::accessor::ComponentType::F32,
            )),
            extensions: None,
            extras: Default::default(),
            type_: Checked::Valid(type_),
            min,
            max,
            name: None,
            normalized: false,
            sparse: None,
        })
    }

    fn image(
        &mut self,
        root: &mut json::Root,
        png: Vec<u8>,
        name: &str,
    ) -> json::Index<json::Image> {
        let view = self.view(root, &png, None);
        root.push(json::Image {
            buffer_view: Some(view),
            mime_type: Some(json::image::MimeType("image/png".into())),
            name: Some(name.to_string()),
            uri: None,
            extensions: None,
            extras: Default::default(),
        })
    }

    /// The GLB file: header, JSON chunk, binary chunk.
    fn finish(mut self, root: &mut json::Root) -> Result<Vec<u8>, SceneError> {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        root.buffers = vec![json::Buffer {
            byte_length: USize64::from(self.bin.len()),
            name: None,
            uri: None,
            extensions: None,
            extras: Default::default(),
        }];
        let mut text = root.to_vec().map_err(|e| err(format!("JSON: {e}")))?;
        while !text.len().is_multiple_of(4) {
            text.push(b' ');
        }
        let total = 12 + 8 + text.len() + 8 + self.bin.len();
        let mut out = Vec::with_capacity(total);
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(text.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&text);
        out.extend_from_slice(&(self.bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&self.bin);
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A KTX2 light map's texels as a loader reads them: the `ktx2` crate's reader, `ruzstd`'s
    /// decoder (Bevy's), `half`.
    fn decode_ktx2(file: &[u8]) -> Vec<[f32; 4]> {
        let reader = ktx2::Reader::new(file).expect("a valid KTX2 file");
        assert_eq!(
            reader.header().format,
            Some(ktx2::Format::R16G16B16A16_SFLOAT)
        );
        let level = reader.levels().next().expect("a level");
        let mut raw = Vec::new();
        std::io::Read::read_to_end(
            &mut ruzstd::decoding::StreamingDecoder::new(level.data).expect("zstd"),
            &mut raw,
        )
        .expect("decodes");
        raw.chunks_exact(8)
            .map(|t| {
                std::array::from_fn(|c| half::f16::from_le_bytes([t[2 * c], t[2 * c + 1]]).to_f32())
            })
            .collect()
    }

    /// The scene's camera and punctual lights travel into the file and come back as they were
    /// (the lights marked as baked into the light map).
    #[test]
    fn the_camera_and_the_lights_travel_into_the_file() {
        use crate::{Light, LightKind};
        let mut scene = crate::builtin("cornell-box").expect("builtin");
        let cam = scene.camera.expect("the box has a camera");
        let light = |name: &str, kind, position: DVec3, direction: DVec3, range| Light {
            name: name.into(),
            kind,
            position,
            direction: direction.normalize(),
            intensity: 3.5,
            color: [1.0, 0.5, 0.25],
            range,
        };
        scene.lights = vec![
            light(
                "sun",
                LightKind::Directional,
                DVec3::ZERO,
                DVec3::new(0.3, -1.0, 0.2),
                None,
            ),
            light(
                "bulb",
                LightKind::Point,
                DVec3::new(0.2, 0.4, 0.1),
                DVec3::NEG_Y,
                Some(2.0),
            ),
            light(
                "spot",
                LightKind::Spot {
                    inner_cone_angle: 0.25, // exact in f32, as glTF stores it
                    outer_cone_angle: 0.5,
                },
                DVec3::new(0.1, 0.5, 0.3),
                DVec3::new(-0.2, -1.0, 0.1),
                None,
            ),
        ];
        let dir =
            std::env::temp_dir().join(format!("radiant_export_lights_{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let path = dir.join("lit.glb");
        export_gltf(&scene, None, &path).expect("export");
        let bytes = std::fs::read(&path).expect("read back");
        let back = crate::load_gltf_slice(&bytes).expect("import");
        let c = back.camera.expect("a camera");
        let near = |a: DVec3, b: DVec3| (a - b).length() < 1e-5;
        assert!(near(c.position, cam.position) && near(c.forward, cam.forward.normalize()));
        assert!(near(c.up, cam.up.normalize()) && (c.yfov - cam.yfov).abs() < 1e-6);
        assert_eq!(back.lights.len(), 3);
        for want in &scene.lights {
            let got = back
                .lights
                .iter()
                .find(|l| l.name == want.name)
                .expect("the light");
            assert_eq!(got.kind, want.kind, "{}", want.name);
            assert!(
                near(got.direction, want.direction),
                "{}: {:?}",
                want.name,
                got.direction
            );
            if !matches!(want.kind, LightKind::Directional) {
                assert!(near(got.position, want.position), "{}", want.name);
            }
            assert_eq!(
                (got.intensity, got.color, got.range),
                (want.intensity, want.color, want.range)
            );
        }
        let (doc, _, _) = gltf::import_slice(&bytes).expect("gltf");
        for l in doc.lights().expect("KHR_lights_punctual") {
            let extras: serde_json::Value =
                serde_json::from_str(l.extras().as_ref().expect("extras").get()).expect("json");
            assert_eq!(extras["radiant"]["baked"], true);
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_round_trip_reads_back_the_scene_its_light_map_uvs_and_the_light_map() {
        let scene = crate::builtin("cornell-box").expect("builtin");
        let atlas = Atlas::new(&scene, None).expect("atlas");
        // A light map that varies across the atlas.
        let texels: Vec<[f32; 3]> = (0..atlas.width * atlas.height)
            .map(|i| {
                let (x, y) = (i % atlas.width, i / atlas.width);
                [x as f32 / 40.0, y as f32 / 60.0, 0.25]
            })
            .collect();
        let dir = std::env::temp_dir().join(format!("radiant_export_{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let path = dir.join("cornell.glb");
        let lm = LightmapExport {
            atlas: &atlas,
            texels: &texels,
        };
        let r = export_gltf(&scene, Some(lm), &path).expect("export");
        assert_eq!(r.primitives, scene.surfaces.len());
        let bytes = std::fs::read(&path).expect("read back");
        let back = crate::load_gltf_slice(&bytes).expect("import");
        assert_eq!(back.triangles.len(), scene.triangles.len());
        // Surfaces come back in the importer's order: match them by name.
        for s in &scene.surfaces {
            let b = back
                .surfaces
                .iter()
                .position(|x| x.name == s.name)
                .unwrap_or_else(|| panic!("{} lost", s.name));
            let bs = &back.surfaces[b];
            for c in 0..3 {
                assert!(
                    (bs.reflectance[c] - s.reflectance[c]).abs() < 1e-6,
                    "{}",
                    s.name
                );
                assert!(
                    (bs.emission[c] - s.emission[c]).abs() < 1e-4 * s.emission[c].max(1.0),
                    "{}",
                    s.name
                );
            }
            let si = scene
                .surfaces
                .iter()
                .position(|x| x.name == s.name)
                .expect("own");
            let ours: Vec<_> = scene
                .triangles
                .iter()
                .enumerate()
                .filter(|(_, t)| t.surface as usize == si)
                .collect();
            let theirs: Vec<_> = back
                .triangles
                .iter()
                .filter(|t| t.surface as usize == b)
                .collect();
            assert_eq!(ours.len(), theirs.len());
            for ((i, t), u) in ours.iter().zip(&theirs) {
                for k in 0..3 {
                    assert!((t.vertices[k] - u.vertices[k]).length() < 1e-5);
                    // Authored TEXCOORD_1 is the atlas, unchanged.
                    assert!((u.uv[1][k] - atlas.uv[*i][k]).length() < 1e-7);
                }
            }
        }
        // The light map, named in every primitive's extras, decodes to its texels.
        let (doc, _buffers, images) = gltf::import_slice(&bytes).expect("gltf");
        assert_eq!(r.lightmap_textures.len(), 1);
        let t = r.lightmap_textures[0];
        for mesh in doc.meshes() {
            let p = mesh.primitives().next().expect("one primitive");
            let extras: serde_json::Value =
                serde_json::from_str(p.extras().as_ref().expect("extras").get()).expect("json");
            assert_eq!(extras["lightmap"]["texture"], serde_json::json!(t));
            assert_eq!(extras["lightmap"]["texCoord"], serde_json::json!(1));
            assert_eq!(extras["lightmap"]["encoding"], "srgb");
            assert_eq!(extras["lightmap"]["ktx2"], "cornell_lightmap.ktx2");
            assert_eq!(extras["lightmap"]["exr"], "cornell_lightmap.exr");
        }
        // The full-range page beside it, as a loader decodes it: H itself, within f16's
        // precision (KTX2) and exactly (EXR).
        assert_eq!(
            r.hdr_files,
            [
                dir.join("cornell_lightmap.ktx2"),
                dir.join("cornell_lightmap.exr")
            ]
        );
        let ktx2 = decode_ktx2(&std::fs::read(&r.hdr_files[0]).expect("ktx2"));
        let exr = image::open(&r.hdr_files[1]).expect("exr").to_rgb32f();
        assert_eq!(ktx2.len(), texels.len());
        for ((want, k), e) in texels.iter().zip(&ktx2).zip(exr.pixels()) {
            assert_eq!(e.0, *want);
            for c in 0..3 {
                assert!(
                    (k[c] - want[c]).abs() <= 5e-4 * want[c] + 6e-8,
                    "{k:?} vs {want:?}"
                );
            }
        }
        let texture = doc.textures().nth(t).expect("texture");
        let img = &images[texture.source().index()];
        assert_eq!((img.width, img.height), (atlas.width, atlas.height));
        let n = img.pixels.len() / (img.width * img.height) as usize;
        for (i, want) in texels.iter().enumerate().step_by(97) {
            for c in 0..3 {
                let byte = img.pixels[i * n + c];
                let got = r.lightmap_scale as f64
                    * radiant_color::srgb_to_linear(f64::from(byte) / 255.0);
                let tol = r.lightmap_scale as f64 * 0.01 + 1e-3;
                assert!(
                    (got - f64::from(want[c])).abs() < tol,
                    "texel {i}: {got} vs {want:?}"
                );
            }
        }
        // A light map of several pages: one image each, and a primitive per page a surface's
        // charts are on, naming that page (the box as one surface: charts on every page).
        let mut scene = scene;
        for t in &mut scene.triangles {
            t.surface = 0;
        }
        let paged = Atlas::paged(&scene, Some(150.0), 128).expect("atlas");
        assert!(paged.pages > 1);
        let size = (paged.width * paged.height) as usize;
        let texels: Vec<[f32; 3]> = (0..size * paged.pages as usize)
            .map(|i| [(i / size) as f32 + 1.0; 3])
            .collect();
        let path = dir.join("paged.glb");
        let lm = LightmapExport {
            atlas: &paged,
            texels: &texels,
        };
        let r = export_gltf(&scene, Some(lm), &path).expect("export");
        assert_eq!(r.lightmap_textures.len(), paged.pages as usize);
        let split: usize = (0..scene.surfaces.len())
            .map(|s| {
                let mut p: Vec<u32> = (0..scene.triangles.len())
                    .filter(|&i| scene.triangles[i].surface as usize == s)
                    .map(|i| paged.page[i])
                    .collect();
                p.sort_unstable();
                p.dedup();
                p.len()
            })
            .sum();
        assert_eq!(split, paged.pages as usize, "one surface on every page");
        assert_eq!(r.primitives, split);
        let bytes = std::fs::read(&path).expect("read back");
        let (doc, _buffers, images) = gltf::import_slice(&bytes).expect("gltf");
        for p in doc
            .meshes()
            .flat_map(|m| m.primitives().collect::<Vec<_>>())
        {
            let extras: serde_json::Value =
                serde_json::from_str(p.extras().as_ref().expect("extras").get()).expect("json");
            let t = extras["lightmap"]["texture"].as_u64().expect("texture") as usize;
            assert!(r.lightmap_textures.contains(&t));
        }
        for (page, &t) in r.lightmap_textures.iter().enumerate() {
            let img = &images[doc.textures().nth(t).expect("texture").source().index()];
            assert_eq!((img.width, img.height), (paged.width, paged.height));
            let got = r.lightmap_scale as f64
                * radiant_color::srgb_to_linear(f64::from(img.pixels[0]) / 255.0);
            assert!((got - (page as f64 + 1.0)).abs() < 0.02 * r.lightmap_scale as f64);
            // Each page in full range, exactly its value (small integers are exact in f16).
            let file = dir.join(format!("paged_lightmap_{page}.ktx2"));
            let k = decode_ktx2(&std::fs::read(&file).expect("page's ktx2"));
            assert!(k.iter().all(|t| t[0] == page as f32 + 1.0 && t[3] == 1.0));
        }
        assert_eq!(r.hdr_files.len(), 2 * paged.pages as usize);
        // A name other engines would not read as binary glTF is refused.
        assert!(matches!(
            export_gltf(&scene, None, &dir.join("cornell.gltf")),
            Err(SceneError::Export(_))
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
