//! glTF 2.0 import with validation. Reads nodes (whole hierarchy), triangle primitives,
//! materials (base colour × texture mean, emissive × KHR_materials_emissive_strength),
//! KHR_lights_punctual lights and the first camera.

use std::path::Path;

use glam::{DMat3, DMat4, DVec3, Vec2};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;

use crate::texture::{Sampler, UvTransform, Wrap};
use crate::{
    AlphaMode, Camera, Image, Light, LightKind, Scene, SceneError, Surface, TextureRef, Triangle,
};

/// The most bytes a `.gltf` or `.glb` file may have (4 GiB, the GLB format's own limit).
pub const MAX_GLTF_FILE: u64 = u32::MAX as u64;

/// Loads a `.gltf` (with external or embedded buffers) or `.glb` file.
pub fn load_gltf(path: &Path) -> Result<Scene, SceneError> {
    let bytes =
        crate::read_regular_file(path, MAX_GLTF_FILE).map_err(|message| SceneError::Io {
            path: path.display().to_string(),
            message,
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
    check_image_sources(&json)?;
    let document = gltf::Document::from_json(json).map_err(parse_error)?;
    check_uris(&document)?;
    if let Some(dir) = base {
        check_buffer_files(&document, dir)?;
    }
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
    let (images, image_slot, image_warnings) = import_images(&document, base, &buffers)?;

    let mut importer = Importer {
        buffers: &buffers,
        image_slot: &image_slot,
        scene: Scene {
            images,
            stats: crate::ImportStats {
                notes: image_warnings,
                ..Default::default()
            },
            ..Scene::default()
        },
        material_surfaces: Vec::new(),
    };
    let scene_def = document
        .default_scene()
        .or_else(|| document.scenes().next());
    if let Some(raw) = scene_def.as_ref().and_then(|s| s.extras().as_ref())
        && let Ok(v) = serde_json::from_str::<serde_json::Value>(raw.get())
        && let Some(sky) = v.get("radiant").and_then(|r| r.get("sky"))
    {
        importer.scene.sky = crate::Sky::from_extras(sky, base)?;
    }
    let roots: Vec<gltf::Node> = match scene_def {
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

/// The decoded images, per glTF image index its slot among them (`u32::MAX` where none), and
/// the warnings of their import.
type ImportedImages = (Vec<Image>, Vec<u32>, Vec<String>);

/// One decoded image and the warning its decoding gave, if any.
type Decoded = (Image, Option<String>);

/// Decodes the images that base-colour and emissive textures read (normal and other maps are
/// not used), in parallel. Returns them, per glTF image index the slot in the scene's list
/// (`u32::MAX` where none), and one warning per image that was decoded with a repair or could not
/// be read or decoded (its materials then go without it).
fn import_images(
    document: &gltf::Document,
    base: Option<&Path>,
    buffers: &[gltf::buffer::Data],
) -> Result<ImportedImages, SceneError> {
    let mut used = vec![false; document.images().len()];
    for m in document.materials() {
        let tex = [
            m.pbr_metallic_roughness()
                .base_color_texture()
                .map(|t| t.texture()),
            m.emissive_texture().map(|t| t.texture()),
        ];
        for t in tex.into_iter().flatten() {
            used[t.source().index()] = true;
        }
    }
    let wanted: Vec<gltf::Image> = document.images().filter(|i| used[i.index()]).collect();
    if wanted.is_empty() {
        return Ok((Vec::new(), vec![u32::MAX; used.len()], Vec::new()));
    }
    let name_of = |i: &gltf::Image| match i.source() {
        gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => uri.to_string(),
        _ => i
            .name()
            .map_or_else(|| format!("image {}", i.index()), str::to_string),
    };
    // gltf 1.4.1 decodes an image's data URI only when given a base directory; without one
    // (slice import) it refuses every URI image as an external reference. So, without a
    // directory, refuse the truly external ones here and give it an empty base, which only
    // data URIs then reach (no file is read).
    let dir = match base {
        Some(dir) => dir,
        None => {
            if let Some(image) = wanted.iter().find(|i| {
                matches!(i.source(), gltf::image::Source::Uri { uri, .. }
                    if !uri.starts_with("data:"))
            }) {
                return Err(SceneError::Texture {
                    image: name_of(image),
                    what: "external reference, but no directory to resolve it".into(),
                });
            }
            Path::new("")
        }
    };
    let decode = |image: &gltf::Image| -> Result<Decoded, SceneError> {
        let name = name_of(image);
        let fail = |what: String| SceneError::Texture {
            image: name.clone(),
            what: format!("{what} (read by {})", image_users(document, image.index())),
        };
        let (bytes, declared): (std::borrow::Cow<[u8]>, Option<&str>) = match image.source() {
            gltf::image::Source::View { view, mime_type } => {
                let buffer = buffers
                    .get(view.buffer().index())
                    .ok_or_else(|| fail("its buffer is missing".into()))?;
                let end = view.offset().saturating_add(view.length());
                let bytes = buffer
                    .get(view.offset()..end)
                    .ok_or_else(|| fail("its buffer view lies outside the buffer".into()))?;
                (bytes.into(), Some(mime_type))
            }
            gltf::image::Source::Uri { uri, mime_type } => {
                // A file is read only when it is a regular file of a size an image can have:
                // a device (`/dev/urandom`) or a FIFO would be read without end.
                if !uri.starts_with("data:")
                    && let Some(path) = file_of(dir, uri)
                {
                    check_image_file(&path).map_err(&fail)?;
                }
                let data =
                    gltf::buffer::Data::from_source(gltf::buffer::Source::Uri(uri), Some(dir))
                        .map_err(|e| {
                            fail(match e {
                                gltf::Error::Io(io) => format!("cannot read it: {io}"),
                                other => other.to_string(),
                            })
                        })?;
                let declared = mime_type.or_else(|| {
                    uri.strip_prefix("data:")
                        .and_then(|r| r.split(';').next())
                        .filter(|m| !m.is_empty())
                });
                (data.0.into(), declared)
            }
        };
        Image::decode(&name, &bytes, declared).map_err(|e| fail(e.to_string()))
    };
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(wanted.len());
    let mut decoded: Vec<Option<Result<Decoded, SceneError>>> = Vec::new();
    decoded.resize_with(wanted.len(), || None);
    std::thread::scope(|scope| {
        let chunk = wanted.len().div_ceil(threads);
        for (images, out) in wanted.chunks(chunk).zip(decoded.chunks_mut(chunk)) {
            let decode = &decode;
            scope.spawn(move || {
                for (image, slot) in images.iter().zip(out) {
                    *slot = Some(decode(image));
                }
            });
        }
    });
    let mut slot = vec![u32::MAX; used.len()];
    let mut images = Vec::with_capacity(wanted.len());
    let mut warnings = Vec::new();
    for (image, result) in wanted.iter().zip(decoded) {
        let result = result.unwrap_or_else(|| {
            Err(SceneError::Texture {
                image: name_of(image),
                what: "its decoder thread stopped".into(),
            })
        });
        // A texture that cannot be read or decoded is one warning, naming the file and the
        // materials that read it; those materials keep their factors, as an engine would
        // draw them, and the bake goes on.
        match result {
            Ok((decoded, warning)) => {
                warnings.extend(warning);
                slot[image.index()] = images.len() as u32;
                images.push(decoded);
            }
            Err(e) => warnings.push(format!(
                "{e}; its materials use their colour factors without it"
            )),
        }
    }
    Ok((images, slot, warnings))
}

/// The most bytes an image file may have: a PNG of [`Image::MAX_TEXELS`] RGBA texels stored
/// uncompressed, four times over (a larger one is refused before it is read).
const MAX_IMAGE_FILE: u64 = Image::MAX_TEXELS * 4 * 4;

/// Whether `path` may be read as an image: a regular file of at most [`MAX_IMAGE_FILE`] bytes.
fn check_image_file(path: &Path) -> Result<(), String> {
    let meta = std::fs::metadata(path).map_err(|e| format!("cannot read it: {e}"))?;
    if !meta.is_file() {
        return Err(format!(
            "{} is not a regular file (a device or a pipe would be read without end)",
            path.display()
        ));
    }
    if meta.len() > MAX_IMAGE_FILE {
        return Err(format!(
            "{} bytes is more than an image file may have ({MAX_IMAGE_FILE})",
            meta.len()
        ));
    }
    Ok(())
}

/// A sparse accessor's substitution (core glTF 2.0, which `gltf`'s reader applies): its count
/// within the accessor's, its index and value arrays inside their views and buffers, and every
/// index naming an element of the accessor, increasing as the specification asks.
fn check_sparse(
    acc: &gltf::Accessor,
    sparse: &gltf::accessor::sparse::Sparse,
    buffers: &[gltf::buffer::Data],
) -> Result<(), SceneError> {
    use gltf::accessor::sparse::IndexType;
    let invalid =
        |what: String| SceneError::Invalid(format!("sparse accessor {}: {what}", acc.index()));
    let count = sparse.count();
    if count == 0 || count > acc.count() {
        return Err(invalid(format!(
            "{count} substitutions for {} elements",
            acc.count()
        )));
    }
    // The bytes of `len` bytes at `offset` of `view`, checked against the view and its buffer.
    let slice = |view: gltf::buffer::View, offset: usize, len: usize, what: &str| {
        let end = offset.checked_add(len).filter(|&e| e <= view.length());
        let buf = buffers.get(view.buffer().index());
        match (end, buf) {
            (Some(end), Some(buf)) => buf
                .get(view.offset() + offset..view.offset() + end)
                .ok_or_else(|| invalid(format!("its {what} lie outside their buffer"))),
            _ => Err(invalid(format!("its {what} lie outside their view"))),
        }
    };
    let indices = sparse.indices();
    let size = match indices.index_type() {
        IndexType::U8 => 1,
        IndexType::U16 => 2,
        IndexType::U32 => 4,
    };
    let bytes = slice(indices.view(), indices.offset(), count * size, "indices")?;
    let values = sparse.values();
    slice(values.view(), values.offset(), count * acc.size(), "values")?;
    let mut last: Option<u64> = None;
    for k in bytes.chunks_exact(size) {
        let i = match size {
            1 => u64::from(k[0]),
            2 => u64::from(u16::from_le_bytes([k[0], k[1]])),
            _ => u64::from(u32::from_le_bytes([k[0], k[1], k[2], k[3]])),
        };
        if i >= acc.count() as u64 || last.is_some_and(|l| i <= l) {
            return Err(invalid(format!(
                "index {i} is not an increasing index below its count {}",
                acc.count()
            )));
        }
        last = Some(i);
    }
    Ok(())
}

/// A relative URI's path with its `%XX` escapes decoded, as `gltf` decodes it before reading;
/// `None` where that is not UTF-8.
fn percent_decode(uri: &str) -> Option<String> {
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
    String::from_utf8(out).ok()
}

/// The file a buffer or image URI names, resolved against `dir` as `gltf` resolves it (`None`
/// for a data URI, another scheme, or a path that does not decode).
fn file_of(dir: &Path, uri: &str) -> Option<std::path::PathBuf> {
    if uri.contains(':') {
        return uri.strip_prefix("file://").map(std::path::PathBuf::from);
    }
    percent_decode(uri).map(|p| dir.join(p))
}

/// Refuses buffer files that would be read without end or far past their `byteLength`: a
/// device or a pipe (`/dev/zero`), or a file over its declared length by more than 1 MiB.
fn check_buffer_files(doc: &gltf::Document, dir: &Path) -> Result<(), SceneError> {
    for buffer in doc.buffers() {
        let gltf::buffer::Source::Uri(uri) = buffer.source() else {
            continue;
        };
        let Some(path) = file_of(dir, uri) else {
            continue;
        };
        // A file that cannot be read is the importer's own error, which names it.
        let Ok(meta) = std::fs::metadata(&path) else {
            continue;
        };
        let declared = buffer.length() as u64;
        if !meta.is_file() {
            return Err(SceneError::Buffer(format!(
                "buffer {}: {} is not a regular file (a device or a pipe would be read without end)",
                buffer.index(),
                path.display()
            )));
        }
        if meta.len() > declared.saturating_add(1 << 20) {
            return Err(SceneError::Buffer(format!(
                "buffer {}: {} holds {} bytes where the buffer declares {declared}",
                buffer.index(),
                path.display(),
                meta.len()
            )));
        }
    }
    Ok(())
}

/// Where an image is read: its materials, and the first node and primitive that uses each.
fn image_users(document: &gltf::Document, image: usize) -> String {
    let reads = |m: &gltf::Material| {
        [
            m.pbr_metallic_roughness()
                .base_color_texture()
                .map(|t| t.texture()),
            m.emissive_texture().map(|t| t.texture()),
        ]
        .into_iter()
        .flatten()
        .any(|t| t.source().index() == image)
    };
    let mut out = Vec::new();
    for m in document.materials().filter(reads) {
        let material = m.name().map_or_else(
            || format!("material {}", m.index().unwrap_or(0)),
            |n| format!("material '{n}'"),
        );
        let first = document.nodes().find_map(|n| {
            let mesh = n.mesh()?;
            let k = mesh
                .primitives()
                .position(|p| p.material().index() == m.index())?;
            Some(format!(
                "node '{}' primitive {k}",
                n.name()
                    .map_or_else(|| n.index().to_string(), str::to_string)
            ))
        });
        out.push(match first {
            Some(at) => format!("{material} on {at}"),
            None => material,
        });
    }
    if out.is_empty() {
        "no material".into()
    } else {
        out.join(", ")
    }
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

/// An image's source as glTF 2.0 requires it: a `uri` or a `bufferView`, not both, and a
/// `bufferView` with its `mimeType`. The `gltf` crate unwraps both (found by fuzzing: an
/// image from a buffer view without a MIME type panicked there).
fn check_image_sources(json: &gltf::json::Root) -> Result<(), SceneError> {
    for (i, image) in json.images.iter().enumerate() {
        let what = match (&image.uri, &image.buffer_view, &image.mime_type) {
            (Some(_), None, _) | (None, Some(_), Some(_)) => continue,
            (None, None, _) => "has neither a uri nor a bufferView",
            (Some(_), Some(_), _) => "has both a uri and a bufferView",
            (None, Some(_), None) => "has a bufferView but no mimeType",
        };
        return Err(SceneError::Invalid(format!(
            "images[{i}] {what}, which glTF 2.0 does not allow"
        )));
    }
    Ok(())
}

/// The `gltf` crate unwraps the percent-decoding of relative URIs, which panics when the
/// decoded bytes are not UTF-8.
fn check_uris(doc: &gltf::Document) -> Result<(), SceneError> {
    // data: and file: URIs are not percent-decoded.
    let decodes = |uri: &str| uri.contains(':') || percent_decode(uri).is_some();
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
        if let Some(sparse) = acc.sparse() {
            check_sparse(&acc, &sparse, buffers)?;
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

/// What a material gives its surfaces.
#[derive(Clone)]
struct MaterialValues {
    name: String,
    reflectance: [f64; 3],
    emission: [f64; 3],
    base_color_texture: Option<TextureRef>,
    base_color_alpha: f64,
    emissive_texture: Option<TextureRef>,
    alpha: AlphaMode,
    double_sided: bool,
}

struct Importer<'a> {
    buffers: &'a [gltf::buffer::Data],
    /// Per glTF image index: its slot in `scene.images` (`u32::MAX` when not decoded).
    image_slot: &'a [u32],
    scene: Scene,
    /// Materials already read, by glTF material index.
    material_surfaces: Vec<(Option<usize>, MaterialValues)>,
}

impl Importer<'_> {
    fn texture(
        &self,
        material: &str,
        info: &gltf::texture::Info,
    ) -> Result<Option<TextureRef>, SceneError> {
        use gltf::texture::{MagFilter, WrappingMode};
        let tex = info.texture();
        // An image that could not be read or decoded was warned about once, by name: the
        // material goes without it.
        let Some(image) = self
            .image_slot
            .get(tex.source().index())
            .copied()
            .filter(|&s| s != u32::MAX)
        else {
            return Ok(None);
        };
        let wrap = |w: WrappingMode| match w {
            WrappingMode::Repeat => Wrap::Repeat,
            WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
            WrappingMode::ClampToEdge => Wrap::ClampToEdge,
        };
        let sampler = tex.sampler();
        let transform = info.texture_transform();
        let tex_coord = transform
            .as_ref()
            .and_then(|t| t.tex_coord())
            .unwrap_or(info.tex_coord());
        if tex_coord > 1 {
            return Err(SceneError::Unsupported(format!(
                "material '{material}': a texture reads TEXCOORD_{tex_coord} (0 and 1 are read)"
            )));
        }
        let transform = transform.map_or_else(UvTransform::default, |t| UvTransform {
            offset: t.offset(),
            rotation: t.rotation(),
            scale: t.scale(),
        });
        if !(transform
            .offset
            .iter()
            .chain(&transform.scale)
            .all(|v| v.is_finite())
            && transform.rotation.is_finite())
        {
            return Err(SceneError::Invalid(format!(
                "material '{material}': KHR_texture_transform is not finite"
            )));
        }
        Ok(Some(TextureRef {
            image,
            sampler: Sampler {
                wrap_s: wrap(sampler.wrap_s()),
                wrap_t: wrap(sampler.wrap_t()),
                nearest: sampler.mag_filter() == Some(MagFilter::Nearest),
            },
            tex_coord: tex_coord as u8,
            transform,
        }))
    }

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
        let base_color_alpha = f64::from(base[3]);
        for &v in rho.iter().chain([base_color_alpha].iter()) {
            if !v.is_finite() || !(0.0..=1.0).contains(&v) {
                return Err(SceneError::ReflectanceOutOfRange {
                    material: name,
                    value: v,
                });
            }
        }
        let base_color_texture = match pbr.base_color_texture() {
            Some(info) => self.texture(&name, &info)?,
            None => None,
        };
        if let Some(t) = base_color_texture {
            let mean = self.scene.images[t.image as usize].mean_linear();
            for (r, t) in rho.iter_mut().zip(mean) {
                *r *= t;
            }
        }
        let strength = f64::from(m.emissive_strength().unwrap_or(1.0));
        let ef = m.emissive_factor().map(f64::from);
        let mut emission = ef.map(|e| e * strength);
        for &v in ef.iter().chain([strength].iter()).chain(emission.iter()) {
            if !v.is_finite() || v < 0.0 {
                return Err(SceneError::InvalidEmission {
                    material: name,
                    value: v,
                });
            }
        }
        let emissive_texture = match m.emissive_texture() {
            Some(info) => self.texture(&name, &info)?,
            None => None,
        };
        if let Some(t) = emissive_texture {
            let mean = self.scene.images[t.image as usize].mean_linear();
            for (e, t) in emission.iter_mut().zip(mean) {
                *e *= t;
            }
        }
        let alpha = match m.alpha_mode() {
            gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
            gltf::material::AlphaMode::Blend => AlphaMode::Blend,
            gltf::material::AlphaMode::Mask => {
                let cutoff = f64::from(m.alpha_cutoff().unwrap_or(0.5));
                if !cutoff.is_finite() || cutoff < 0.0 {
                    return Err(SceneError::Invalid(format!(
                        "material '{name}': alphaCutoff {cutoff} is negative or not finite"
                    )));
                }
                AlphaMode::Mask { cutoff }
            }
        };
        let values = MaterialValues {
            name,
            reflectance: rho,
            emission,
            base_color_texture,
            base_color_alpha,
            emissive_texture,
            alpha,
            double_sided: m.double_sided(),
        };
        self.material_surfaces.push((m.index(), values.clone()));
        Ok(values)
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
            // Found by fuzzing: TEXCOORD_n of UNSIGNED_INT reached `unreachable!` in the reader.
            if let Some(acc) = prim.get(&gltf::Semantic::Normals)
                && !matches!(
                    (acc.data_type(), acc.dimensions()),
                    (DataType::F32, Dimensions::Vec3)
                )
            {
                return Err(SceneError::Invalid(format!(
                    "mesh '{name}': NORMAL accessor {} is not VEC3 FLOAT",
                    acc.index()
                )));
            }
            for set in 0..2 {
                if let Some(acc) = prim.get(&gltf::Semantic::TexCoords(set))
                    && !matches!(
                        (acc.data_type(), acc.dimensions()),
                        (
                            DataType::F32 | DataType::U8 | DataType::U16,
                            Dimensions::Vec2
                        )
                    )
                {
                    return Err(SceneError::Invalid(format!(
                        "mesh '{name}': TEXCOORD_{set} accessor {} is not VEC2 of FLOAT, UNSIGNED_BYTE or UNSIGNED_SHORT",
                        acc.index()
                    )));
                }
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
            let m = self.material(&prim.material())?;
            // Shading normals: the inverse transpose of the node's linear part; the face normal
            // where the primitive has none (or a degenerate one).
            let normal_matrix = DMat3::from_mat4(world).inverse().transpose();
            let normals: Option<Vec<DVec3>> = reader.read_normals().map(|ns| {
                ns.map(|n| {
                    let n = DVec3::new(n[0].into(), n[1].into(), n[2].into());
                    (normal_matrix * n).normalize_or_zero()
                })
                .collect()
            });
            let mut uvs: [Option<Vec<Vec2>>; 2] = [None, None];
            for (set, slot) in uvs.iter_mut().enumerate() {
                *slot = reader
                    .read_tex_coords(set as u32)
                    .map(|tc| tc.into_f32().map(Vec2::from).collect());
            }
            for (texture, t) in [
                ("base colour", m.base_color_texture),
                ("emissive", m.emissive_texture),
            ] {
                if let Some(t) = t
                    && uvs[usize::from(t.tex_coord)]
                        .as_ref()
                        .is_none_or(|uv| uv.len() < verts.len())
                {
                    return Err(SceneError::MissingTexCoord {
                        mesh: name,
                        texture,
                        set: t.tex_coord,
                    });
                }
            }
            if let Some(uv) = uvs.iter().flatten().find(|uv| uv.len() < verts.len()) {
                return Err(SceneError::Invalid(format!(
                    "mesh '{name}': {} texture coordinates for {} vertices",
                    uv.len(),
                    verts.len()
                )));
            }
            let surface = self.scene.surfaces.len() as u32;
            self.scene.surfaces.push(Surface {
                name,
                material: m.name,
                reflectance: m.reflectance,
                emission: m.emission,
                dynamic,
                base_color_texture: m.base_color_texture,
                base_color_alpha: m.base_color_alpha,
                emissive_texture: m.emissive_texture,
                alpha: m.alpha,
                double_sided: m.double_sided,
                tex_coords: uvs.iter().take_while(|u| u.is_some()).count() as u8,
            });
            for corners in tris {
                let corners = if flip {
                    [corners[0], corners[2], corners[1]]
                } else {
                    corners
                };
                let mut t = Triangle::new(corners.map(|i| verts[i as usize]), surface);
                if is_degenerate(&t) {
                    self.scene.stats.degenerate_triangles += 1;
                    continue;
                }
                if let Some(ns) = &normals {
                    let face = t.normals[0];
                    t.normals = corners.map(|i| {
                        let n = ns[i as usize].as_vec3();
                        // A zero or non-finite normal, or one facing away from the front, is replaced.
                        if n.is_finite() && n.dot(face) > 0.0 {
                            n
                        } else {
                            face
                        }
                    });
                }
                for (set, uv) in uvs.iter().enumerate() {
                    if let Some(uv) = uv {
                        t.uv[set] = corners.map(|i| uv[i as usize]);
                    }
                }
                self.scene.triangles.push(t);
                if m.double_sided {
                    // The back: reversed winding, normals flipped, the same texture points.
                    let mut back = t.rewound();
                    back.normals = back.normals.map(|n| -n);
                    self.scene.triangles.push(back);
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
