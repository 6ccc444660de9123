//! glTF 2.0 import with validation. Reads nodes (whole hierarchy), triangle primitives,
//! materials (base colour × texture mean, emissive × KHR_materials_emissive_strength),
//! KHR_lights_punctual lights and the first camera.

use std::path::Path;

use glam::{DMat4, DVec3, DVec4};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;

use crate::{Camera, Light, LightKind, Scene, SceneError, Surface, Triangle};

/// Loads a `.gltf` (with external or embedded buffers) or `.glb` file.
pub fn load_gltf(path: &Path) -> Result<Scene, SceneError> {
    let bytes = std::fs::read(path).map_err(|e| SceneError::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    })?;
    load(&bytes, path.parent())
}

/// Loads glTF or GLB from memory; buffers must be embedded (data URIs or the GLB chunk).
pub fn load_gltf_slice(bytes: &[u8]) -> Result<Scene, SceneError> {
    load(bytes, None)
}

fn load(bytes: &[u8], base: Option<&Path>) -> Result<Scene, SceneError> {
    if bytes.iter().all(|b| b.is_ascii_whitespace()) {
        return Err(SceneError::Empty);
    }
    // The `gltf` crate subtracts the 12-byte header from the declared length unchecked.
    if bytes.starts_with(b"glTF")
        && let Some(&[a, b, c, d]) = bytes.get(8..12)
        && u32::from_le_bytes([a, b, c, d]) < 12
    {
        return Err(SceneError::Glb(format!(
            "declared length {} is shorter than the 12-byte header",
            u32::from_le_bytes([a, b, c, d])
        )));
    }
    let parse_error = |e: gltf::Error| match e {
        gltf::Error::Binary(b) => SceneError::Glb(b.to_string()),
        gltf::Error::Validation(v) => SceneError::Invalid(
            v.iter()
                .take(3)
                .map(|(path, err)| format!("{path}: {err}"))
                .collect::<Vec<_>>()
                .join("; "),
        ),
        gltf::Error::Deserialize(d) if bytes.starts_with(b"glTF") => SceneError::Glb(d.to_string()),
        other => SceneError::NotGltf(other.to_string()),
    };
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(bytes).map_err(parse_error)?;
    let json = document.into_json();
    check_attribute_indices(&json)?;
    let document = gltf::Document::from_json(json).map_err(parse_error)?;
    check_uris(&document)?;
    let buffers = gltf::import_buffers(&document, base, blob).map_err(|e| match e {
        gltf::Error::ExternalReferenceInSliceImport => {
            SceneError::Buffer("external buffer reference, but no directory to resolve it".into())
        }
        gltf::Error::Io(io) => {
            // Name the file: the gltf crate's I/O error does not.
            let uris: Vec<String> = document
                .buffers()
                .filter_map(|b| match b.source() {
                    gltf::buffer::Source::Uri(u) if !u.starts_with("data:") => {
                        Some(format!("'{u}'"))
                    }
                    _ => None,
                })
                .collect();
            SceneError::Buffer(format!("cannot read {}: {io}", uris.join(", ")))
        }
        other => SceneError::Buffer(other.to_string()),
    })?;
    check_accessors(&document, &buffers)?;
    // Images are only needed for base-colour texture means; a broken image is an error.
    let needs_images = document
        .materials()
        .any(|m| m.pbr_metallic_roughness().base_color_texture().is_some());
    let images = if needs_images {
        // gltf 1.4.1 decodes an image's data URI only when given a base directory; without one
        // (slice import) it refuses every URI image as an external reference. So, without a
        // directory, refuse the truly external ones here and give it an empty base, which only
        // data URIs then reach (no file is read).
        let base = match base {
            Some(dir) => dir,
            None => {
                if let Some(image) = document.images().find(|i| {
                    matches!(i.source(), gltf::image::Source::Uri { uri, .. }
                        if !uri.starts_with("data:"))
                }) {
                    return Err(SceneError::Invalid(format!(
                        "image {}: external reference, but no directory to resolve it",
                        image.index()
                    )));
                }
                Path::new("")
            }
        };
        gltf::import_images(&document, Some(base), &buffers)
            .map_err(|e| SceneError::Invalid(format!("image: {e}")))?
    } else {
        Vec::new()
    };

    let mut importer = Importer {
        buffers: &buffers,
        images: &images,
        scene: Scene::default(),
        material_surfaces: Vec::new(),
    };
    let roots: Vec<gltf::Node> = match document
        .default_scene()
        .or_else(|| document.scenes().next())
    {
        Some(s) => s.nodes().collect(),
        None => {
            let mut is_child = vec![false; document.nodes().len()];
            for n in document.nodes() {
                for c in n.children() {
                    is_child[c.index()] = true;
                }
            }
            document.nodes().filter(|n| !is_child[n.index()]).collect()
        }
    };
    // Iterative traversal with a depth guard: glTF forbids cycles, but do not trust input.
    let mut stack: Vec<(gltf::Node, DMat4, usize)> =
        roots.into_iter().map(|n| (n, DMat4::IDENTITY, 0)).collect();
    let mut camera_node: Option<usize> = None;
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > 256 {
            return Err(SceneError::Invalid(
                "node hierarchy deeper than 256 levels".into(),
            ));
        }
        let local = DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(f64::from)));
        let world = parent * local;
        let name = node
            .name()
            .map(str::to_string)
            .unwrap_or_else(|| format!("node{}", node.index()));
        if !world.is_finite() {
            return Err(SceneError::NonFiniteTransform { node: name });
        }
        if let Some(mesh) = node.mesh() {
            importer.mesh(&name, &mesh, world, is_dynamic(&node))?;
        }
        if let Some(light) = node.light() {
            importer.light(&name, &light, world)?;
        }
        // The first camera in document order (the traversal pops the last root first).
        if let Some(cam) = node.camera()
            && camera_node.is_none_or(|i| node.index() < i)
            && let gltf::camera::Projection::Perspective(p) = cam.projection()
        {
            let forward = world.transform_vector3(DVec3::NEG_Z).normalize_or_zero();
            let up = world.transform_vector3(DVec3::Y).normalize_or_zero();
            let yfov = f64::from(p.yfov());
            if forward != DVec3::ZERO && up != DVec3::ZERO && yfov.is_finite() && yfov > 0.0 {
                importer.scene.camera = Some(Camera {
                    position: world.transform_point3(DVec3::ZERO),
                    forward,
                    up,
                    yfov,
                });
                camera_node = Some(node.index());
            }
        }
        for child in node.children() {
            stack.push((child, world, depth + 1));
        }
    }
    Ok(importer.scene)
}

/// Whether a node's extras mark it dynamic: `{"radiant": {"dynamic": true}}`. Malformed extras
/// leave it static.
fn is_dynamic(node: &gltf::Node) -> bool {
    let Some(raw) = node.extras() else {
        return false;
    };
    serde_json::from_str::<serde_json::Value>(raw.get())
        .ok()
        .and_then(|v| v.get("radiant")?.get("dynamic")?.as_bool())
        .unwrap_or(false)
}

/// gltf-json's validation indexes the accessor array with each primitive's POSITION index
/// before it checks that index, so a dangling one would panic there.
fn check_attribute_indices(json: &gltf::json::Root) -> Result<(), SceneError> {
    for (m, mesh) in json.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            if let Some(index) = prim
                .attributes
                .values()
                .find(|i| i.value() >= json.accessors.len())
            {
                return Err(SceneError::Invalid(format!(
                    "meshes[{m}].primitives[{p}]: attribute accessor {} does not exist ({} accessors)",
                    index.value(),
                    json.accessors.len()
                )));
            }
        }
    }
    Ok(())
}

/// The `gltf` crate unwraps the percent-decoding of relative URIs, which panics when the
/// decoded bytes are not UTF-8.
fn check_uris(doc: &gltf::Document) -> Result<(), SceneError> {
    fn decodes(uri: &str) -> bool {
        if uri.contains(':') {
            return true; // data: and file: URIs are not percent-decoded
        }
        let b = uri.as_bytes();
        let hex = |k: usize| b.get(k).and_then(|&c| char::from(c).to_digit(16));
        let mut out = Vec::with_capacity(b.len());
        let mut i = 0;
        while i < b.len() {
            if let (b'%', Some(hi), Some(lo)) = (b[i], hex(i + 1), hex(i + 2)) {
                out.push((hi * 16 + lo) as u8); // both digits are below 16
                i += 3;
            } else {
                out.push(b[i]);
                i += 1;
            }
        }
        std::str::from_utf8(&out).is_ok()
    }
    for buffer in doc.buffers() {
        if let gltf::buffer::Source::Uri(uri) = buffer.source()
            && !decodes(uri)
        {
            return Err(SceneError::Buffer(format!(
                "buffer {}: URI {uri:?} does not percent-decode to UTF-8",
                buffer.index()
            )));
        }
    }
    for image in doc.images() {
        if let gltf::image::Source::Uri { uri, .. } = image.source()
            && !decodes(uri)
        {
            return Err(SceneError::Invalid(format!(
                "image {}: URI {uri:?} does not percent-decode to UTF-8",
                image.index()
            )));
        }
    }
    Ok(())
}

/// Every accessor must lie inside its buffer view, and every view inside its buffer, before any
/// is read (the `gltf` reader would otherwise index out of bounds, and it asserts a non-zero
/// count and a stride no smaller than the element).
fn check_accessors(doc: &gltf::Document, buffers: &[gltf::buffer::Data]) -> Result<(), SceneError> {
    for acc in doc.accessors() {
        let bad = || SceneError::AccessorOutOfBounds {
            accessor: acc.index(),
        };
        if acc.sparse().is_some() {
            return Err(SceneError::Unsupported(format!(
                "sparse accessor {}",
                acc.index()
            )));
        }
        if acc.count() == 0 {
            return Err(SceneError::Invalid(format!(
                "accessor {} has count 0",
                acc.index()
            )));
        }
        let Some(view) = acc.view() else { continue };
        let buf = buffers.get(view.buffer().index()).ok_or_else(bad)?;
        let view_end = view.offset().checked_add(view.length()).ok_or_else(bad)?;
        if view_end > buf.len() {
            return Err(bad());
        }
        let elem = acc.size();
        let stride = view.stride().unwrap_or(elem);
        if stride < elem {
            return Err(SceneError::Invalid(format!(
                "accessor {}: byteStride {stride} is less than its element size {elem}",
                acc.index()
            )));
        }
        let need = (acc.count() - 1)
            .checked_mul(stride)
            .and_then(|x| x.checked_add(elem))
            .and_then(|x| x.checked_add(acc.offset()))
            .ok_or_else(bad)?;
        if need > view.length() {
            return Err(bad());
        }
    }
    // Views not read through an accessor (images) are sliced unchecked by `gltf` too.
    for view in doc.views() {
        let len = buffers.get(view.buffer().index()).map_or(0, |b| b.len());
        if view
            .offset()
            .checked_add(view.length())
            .is_none_or(|end| end > len)
        {
            return Err(SceneError::Invalid(format!(
                "buffer view {} lies outside buffer {} ({len} bytes)",
                view.index(),
                view.buffer().index()
            )));
        }
    }
    Ok(())
}

/// Reflectance, emission and name of a material.
type MaterialValues = ([f64; 3], [f64; 3], String);

struct Importer<'a> {
    buffers: &'a [gltf::buffer::Data],
    images: &'a [gltf::image::Data],
    scene: Scene,
    /// Materials already read, by glTF material index.
    material_surfaces: Vec<(Option<usize>, MaterialValues)>,
}

impl Importer<'_> {
    fn material(&mut self, m: &gltf::Material) -> Result<MaterialValues, SceneError> {
        if let Some(hit) = self.material_surfaces.iter().find(|c| c.0 == m.index()) {
            return Ok(hit.1.clone());
        }
        let name = m
            .name()
            .map(str::to_string)
            .unwrap_or_else(|| match m.index() {
                Some(i) => format!("material{i}"),
                None => "default".to_string(),
            });
        let pbr = m.pbr_metallic_roughness();
        let base = pbr.base_color_factor();
        let mut rho = [base[0], base[1], base[2]].map(f64::from);
        for &v in &rho {
            if !v.is_finite() || !(0.0..=1.0).contains(&v) {
                return Err(SceneError::ReflectanceOutOfRange {
                    material: name,
                    value: v,
                });
            }
        }
        if let Some(tex) = pbr.base_color_texture() {
            let index = tex.texture().source().index();
            if let Some(mean) = self.images.get(index).and_then(texture_mean) {
                for (r, t) in rho.iter_mut().zip(mean) {
                    *r *= t;
                }
            }
        }
        let strength = f64::from(m.emissive_strength().unwrap_or(1.0));
        let ef = m.emissive_factor().map(f64::from);
        let emission = ef.map(|e| e * strength);
        for &v in ef.iter().chain([strength].iter()).chain(emission.iter()) {
            if !v.is_finite() || v < 0.0 {
                return Err(SceneError::InvalidEmission {
                    material: name,
                    value: v,
                });
            }
        }
        self.material_surfaces
            .push((m.index(), (rho, emission, name.clone())));
        Ok((rho, emission, name))
    }

    fn mesh(
        &mut self,
        node_name: &str,
        mesh: &gltf::Mesh,
        world: DMat4,
        dynamic: bool,
    ) -> Result<(), SceneError> {
        let prims: Vec<_> = mesh.primitives().collect();
        let flip = world.determinant() < 0.0;
        for (k, prim) in prims.iter().enumerate() {
            let name = if prims.len() > 1 {
                format!("{node_name}#{k}")
            } else {
                node_name.to_string()
            };
            let mode = prim.mode();
            if !matches!(
                mode,
                Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
            ) {
                self.scene.stats.skipped_primitives += 1;
                continue;
            }
            // The `gltf` reader asserts these types (and has no arm for float indices).
            if let Some(acc) = prim.get(&gltf::Semantic::Positions)
                && !matches!(
                    (acc.data_type(), acc.dimensions()),
                    (DataType::F32, Dimensions::Vec3)
                )
            {
                return Err(SceneError::Invalid(format!(
                    "mesh '{name}': POSITION accessor {} is not VEC3 FLOAT",
                    acc.index()
                )));
            }
            if let Some(acc) = prim.indices()
                && !matches!(
                    (acc.data_type(), acc.dimensions()),
                    (
                        DataType::U8 | DataType::U16 | DataType::U32,
                        Dimensions::Scalar
                    )
                )
            {
                return Err(SceneError::Invalid(format!(
                    "mesh '{name}': index accessor {} is not SCALAR unsigned integers",
                    acc.index()
                )));
            }
            let reader = prim.reader(|b| self.buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(positions) = reader.read_positions() else {
                return Err(SceneError::Invalid(format!(
                    "mesh '{name}' has no POSITION"
                )));
            };
            let mut verts = Vec::with_capacity(positions.len());
            for (i, p) in positions.enumerate() {
                let v = DVec3::new(p[0].into(), p[1].into(), p[2].into());
                let w = world.transform_point3(v);
                if !v.is_finite() || !w.is_finite() {
                    return Err(SceneError::NonFinitePosition {
                        mesh: name,
                        vertex: i,
                    });
                }
                verts.push(w);
            }
            let indices: Vec<u32> = match reader.read_indices() {
                Some(ix) => ix.into_u32().collect(),
                None => (0..verts.len() as u32).collect(),
            };
            if let Some(&bad) = indices.iter().find(|&&i| i as usize >= verts.len()) {
                return Err(SceneError::IndexOutOfRange {
                    mesh: name,
                    index: bad,
                    count: verts.len(),
                });
            }
            let tris: Vec<[u32; 3]> = match mode {
                Mode::Triangles => indices
                    .chunks_exact(3)
                    .map(|c| [c[0], c[1], c[2]])
                    .collect(),
                Mode::TriangleStrip => (2..indices.len())
                    .map(|i| {
                        if i % 2 == 0 {
                            [indices[i - 2], indices[i - 1], indices[i]]
                        } else {
                            [indices[i - 1], indices[i - 2], indices[i]]
                        }
                    })
                    .collect(),
                _ => (2..indices.len())
                    .map(|i| [indices[0], indices[i - 1], indices[i]])
                    .collect(),
            };
            let (reflectance, emission, material) = self.material(&prim.material())?;
            let double_sided = prim.material().double_sided();
            let surface = self.scene.surfaces.len() as u32;
            self.scene.surfaces.push(Surface {
                name,
                material,
                reflectance,
                emission,
                dynamic,
            });
            for [a, b, c] in tris {
                let (a, b, c) = (verts[a as usize], verts[b as usize], verts[c as usize]);
                let vertices = if flip { [a, c, b] } else { [a, b, c] };
                let t = Triangle { vertices, surface };
                if is_degenerate(&t) {
                    self.scene.stats.degenerate_triangles += 1;
                    continue;
                }
                self.scene.triangles.push(t);
                if double_sided {
                    let [a, b, c] = vertices;
                    self.scene.triangles.push(Triangle {
                        vertices: [a, c, b],
                        surface,
                    });
                }
            }
        }
        Ok(())
    }

    fn light(
        &mut self,
        node_name: &str,
        light: &gltf::khr_lights_punctual::Light,
        world: DMat4,
    ) -> Result<(), SceneError> {
        use gltf::khr_lights_punctual::Kind;
        let name = light
            .name()
            .map(str::to_string)
            .unwrap_or_else(|| node_name.to_string());
        let intensity = f64::from(light.intensity());
        let color = light.color().map(f64::from);
        let bad = |what: String| SceneError::InvalidLight {
            light: name.clone(),
            what,
        };
        if !intensity.is_finite() || intensity < 0.0 {
            return Err(bad(format!(
                "intensity {intensity} is negative or not finite"
            )));
        }
        if color.iter().any(|c| !c.is_finite() || *c < 0.0) {
            return Err(bad("colour is negative or not finite".into()));
        }
        let range = light.range().map(f64::from);
        if let Some(r) = range
            && !(r.is_finite() && r > 0.0)
        {
            return Err(bad(format!("range {r} must be positive")));
        }
        let kind = match light.kind() {
            Kind::Point => LightKind::Point,
            Kind::Directional => LightKind::Directional,
            Kind::Spot {
                inner_cone_angle,
                outer_cone_angle,
            } => {
                let (i, o) = (f64::from(inner_cone_angle), f64::from(outer_cone_angle));
                if !(i.is_finite()
                    && o.is_finite()
                    && 0.0 <= i
                    && i < o
                    && o <= std::f64::consts::FRAC_PI_2)
                {
                    return Err(bad(format!(
                        "spot cone angles {i}, {o} are not 0 <= inner < outer <= pi/2"
                    )));
                }
                LightKind::Spot {
                    inner_cone_angle: i,
                    outer_cone_angle: o,
                }
            }
        };
        let direction = world.transform_vector3(DVec3::NEG_Z).normalize_or_zero();
        if direction == DVec3::ZERO {
            return Err(bad("degenerate node transform".into()));
        }
        self.scene.lights.push(Light {
            name,
            kind,
            position: world.transform_point3(DVec3::ZERO),
            direction,
            color,
            intensity,
            range,
        });
        Ok(())
    }
}

/// Zero-area, collinear or needle triangles: area below 1e-12 of the squared longest edge.
fn is_degenerate(t: &Triangle) -> bool {
    let [a, b, c] = t.vertices;
    let longest = (b - a)
        .length_squared()
        .max((c - b).length_squared())
        .max((a - c).length_squared());
    let cross = t.cross().length();
    cross.partial_cmp(&(1e-12 * longest)) != Some(std::cmp::Ordering::Greater) || !cross.is_finite()
}

/// Mean linear colour of an 8-bit sRGB texture; `None` for formats it does not read.
fn texture_mean(img: &gltf::image::Data) -> Option<[f64; 3]> {
    use gltf::image::Format;
    let channels = match img.format {
        Format::R8G8B8 => 3,
        Format::R8G8B8A8 => 4,
        _ => return None,
    };
    let lut: Vec<f64> = (0..256)
        .map(|i| radiant_color::srgb_to_linear(i as f64 / 255.0))
        .collect();
    let mut sum = DVec4::ZERO;
    for px in img.pixels.chunks_exact(channels) {
        sum += DVec4::new(
            lut[px[0] as usize],
            lut[px[1] as usize],
            lut[px[2] as usize],
            1.0,
        );
    }
    (sum.w > 0.0).then(|| [sum.x / sum.w, sum.y / sum.w, sum.z / sum.w])
}
