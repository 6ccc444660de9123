//! Bad glTF inputs (tests/bad_inputs/, written by tools/make_bad_inputs.py): each gives its typed
//! [`SceneError`], with a one-line message, and none panics.

use std::panic;
use std::path::{Path, PathBuf};

use radiant_scene::{SceneError, load_gltf, load_gltf_slice};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bad_inputs")
}

/// Each bad file and the error it must give.
/// A check on the error a file must give.
type Expect = fn(&SceneError) -> bool;

const CASES: &[(&str, Expect)] = &[
    ("empty.gltf", |e| matches!(e, SceneError::Empty)),
    ("whitespace.gltf", |e| matches!(e, SceneError::Empty)),
    ("not_gltf.gltf", |e| matches!(e, SceneError::NotGltf(_))),
    ("truncated_json.gltf", |e| {
        matches!(e, SceneError::NotGltf(_))
    }),
    ("truncated.glb", |e| matches!(e, SceneError::Glb(_))),
    // Without the "glTF" magic the bytes are read as JSON, which they are not.
    ("bad_magic.glb", |e| matches!(e, SceneError::NotGltf(_))),
    ("glb_length_below_header.glb", |e| {
        matches!(e, SceneError::Glb(_))
    }),
    ("missing_buffer.gltf", |e| {
        matches!(e, SceneError::Buffer(_))
    }),
    ("short_buffer.gltf", |e| matches!(e, SceneError::Buffer(_))),
    // Compressed geometry marked required: refused, naming the extension.
    (
        "draco_required.gltf",
        |e| matches!(e, SceneError::Invalid(what) if what.contains("KHR_draco_mesh_compression")),
    ),
    (
        "meshopt_required.gltf",
        |e| matches!(e, SceneError::Invalid(what) if what.contains("EXT_meshopt_compression")),
    ),
    // `/dev/zero` as a buffer: refused before a byte is read (was read without end).
    (
        "buffer_is_a_device.gltf",
        |e| matches!(e, SceneError::Buffer(what) if what.contains("not a regular file")),
    ),
    ("bad_percent_uri.gltf", |e| {
        matches!(e, SceneError::Buffer(_))
    }),
    ("dangling_accessor.gltf", |e| {
        matches!(e, SceneError::Invalid(_))
    }),
    ("dangling_buffer_view.gltf", |e| {
        matches!(e, SceneError::Invalid(_))
    }),
    ("accessor_out_of_bounds.gltf", |e| {
        matches!(e, SceneError::AccessorOutOfBounds { accessor: 0 })
    }),
    ("zero_count_accessor.gltf", |e| {
        matches!(e, SceneError::Invalid(_))
    }),
    ("stride_too_small.gltf", |e| {
        matches!(e, SceneError::Invalid(_))
    }),
    ("position_not_vec3_float.gltf", |e| {
        matches!(e, SceneError::Invalid(_))
    }),
    ("float_indices.gltf", |e| {
        matches!(e, SceneError::Invalid(_))
    }),
    (
        "sparse_index_out_of_range.gltf",
        |e| matches!(e, SceneError::Invalid(what) if what.contains("sparse accessor 0")),
    ),
    ("image_view_out_of_bounds.gltf", |e| {
        matches!(e, SceneError::Invalid(_))
    }),
    // Image sources glTF 2.0 forbids (fuzzing found the first panicking in the gltf crate).
    (
        "image_view_without_mime.gltf",
        |e| matches!(e, SceneError::Invalid(what) if what.contains("images[0] has a bufferView but no mimeType")),
    ),
    (
        "image_without_source.gltf",
        |e| matches!(e, SceneError::Invalid(what) if what.contains("images[0]")),
    ),
    (
        "texcoord_u32.gltf",
        |e| matches!(e, SceneError::Invalid(what) if what.contains("TEXCOORD_0 accessor 2")),
    ),
    (
        "texcoord_vec3.gltf",
        |e| matches!(e, SceneError::Invalid(what) if what.contains("TEXCOORD_0 accessor 2")),
    ),
    (
        "normal_u8.gltf",
        |e| matches!(e, SceneError::Invalid(what) if what.contains("NORMAL accessor 2")),
    ),
    (
        "image_uri_and_view.gltf",
        |e| matches!(e, SceneError::Invalid(what) if what.contains("images[0] has both")),
    ),
    ("index_out_of_range.gltf", |e| {
        matches!(
            e,
            SceneError::IndexOutOfRange {
                index: 7,
                count: 4,
                ..
            }
        )
    }),
    ("nan_position.gltf", |e| {
        matches!(e, SceneError::NonFinitePosition { vertex: 1, .. })
    }),
    ("inf_position.gltf", |e| {
        matches!(e, SceneError::NonFinitePosition { vertex: 2, .. })
    }),
    ("cyclic_nodes.gltf", |e| matches!(e, SceneError::Invalid(_))),
    (
        "reflectance_above_one.gltf",
        |e| matches!(e, SceneError::ReflectanceOutOfRange { value, .. } if *value == 1.5),
    ),
    (
        "reflectance_negative.gltf",
        |e| matches!(e, SceneError::ReflectanceOutOfRange { value, .. } if *value == -0.25),
    ),
    (
        "negative_emission.gltf",
        |e| matches!(e, SceneError::InvalidEmission { value, .. } if *value == -1.0),
    ),
    (
        "negative_emissive_strength.gltf",
        |e| matches!(e, SceneError::InvalidEmission { value, .. } if *value == -2.0),
    ),
    ("light_negative_intensity.gltf", |e| {
        matches!(e, SceneError::InvalidLight { .. })
    }),
    ("texture_without_texcoord.gltf", |e| {
        matches!(e, SceneError::MissingTexCoord { set: 0, .. })
    }),
    ("sky_negative.gltf", |e| {
        matches!(e, SceneError::InvalidSky(_))
    }),
];

/// Files that must load.
const VALID: &[&str] = &[
    "ok_no_emitters.gltf",
    "ok_quad.glb",
    "degenerate_only.gltf",
    "texture_missing_file.gltf",
    "texture_undecodable.gltf",
    "sparse_accessor.gltf",
    "ok_sparse_positions.gltf",
];

/// Sparse accessors are core glTF 2.0: read, with the substituted values where they belong.
#[test]
fn a_sparse_accessor_is_read_right() {
    let scene = load_gltf(&dir().join("ok_sparse_positions.gltf")).expect("loads");
    let vertices: Vec<[f64; 3]> = scene
        .triangles
        .iter()
        .flat_map(|t| t.vertices.map(|v| v.to_array()))
        .collect();
    // The quad's vertex 2, (1, 1, 0), moved to (1, 2, 0); the others as they were.
    assert!(vertices.contains(&[1.0, 2.0, 0.0]), "{vertices:?}");
    assert!(!vertices.contains(&[1.0, 1.0, 0.0]), "{vertices:?}");
    assert!(vertices.contains(&[0.0, 1.0, 0.0]) && vertices.contains(&[1.0, 0.0, 0.0]));
    // The corpus's first sparse file substitutes vertex 0 by itself: the plain quad.
    let same = load_gltf(&dir().join("sparse_accessor.gltf")).expect("loads");
    assert_eq!(same.triangles.len(), 2);
}

/// Texture faults load with one warning each, naming the image, what is wrong and the material
/// and node that read it; the material keeps its colour factor.
#[test]
fn texture_faults_warn_and_the_scene_loads() {
    for (name, image, what) in [
        (
            "texture_missing_file.gltf",
            "does_not_exist.png",
            "cannot read",
        ),
        (
            "texture_undecodable.gltf",
            "image 0",
            "neither PNG nor JPEG (declared image/png)",
        ),
    ] {
        let scene = load_gltf(&dir().join(name)).expect(name);
        assert_eq!(scene.surfaces[0].base_color_texture, None, "{name}");
        assert_eq!(scene.surfaces[0].reflectance, [0.5; 3], "{name}");
        let warnings = scene.warnings();
        assert_eq!(warnings.len(), 1, "{name}: {warnings:?}");
        let w = &warnings[0];
        for part in [
            &format!("image '{image}'"),
            what,
            "material 'grey' on node 'quad' primitive 0",
        ] {
            assert!(w.contains(part), "{name}: {w:?} lacks {part:?}");
        }
    }
}

#[test]
fn each_bad_input_gives_its_typed_error() {
    let mut failures = Vec::new();
    for (name, expected) in CASES {
        match load_gltf(&dir().join(name)) {
            Ok(scene) => failures.push(format!(
                "{name}: loaded ({} triangles)",
                scene.triangles.len()
            )),
            Err(e) if !expected(&e) => failures.push(format!("{name}: unexpected {e:?}")),
            Err(e) => {
                let msg = e.to_string();
                if msg.is_empty() || msg.contains('\n') {
                    failures.push(format!("{name}: message not one line: {msg:?}"));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn no_input_panics() {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir())
        .expect("tests/bad_inputs exists")
        .map(|entry| entry.expect("directory entry").path())
        .collect();
    entries.sort();
    assert!(entries.len() >= CASES.len() + VALID.len());
    let panicked: Vec<String> = entries
        .iter()
        .filter(|path| {
            let bytes = std::fs::read(path).expect("readable");
            panic::catch_unwind(|| load_gltf(path)).is_err()
                || panic::catch_unwind(|| load_gltf_slice(&bytes)).is_err()
        })
        .map(|path| path.display().to_string())
        .collect();
    assert!(panicked.is_empty(), "panicked: {panicked:?}");
}

#[test]
fn every_case_file_exists() {
    for name in CASES.iter().map(|c| c.0).chain(VALID.iter().copied()) {
        assert!(dir().join(name).is_file(), "{name} is missing");
    }
}

#[test]
fn valid_inputs_load() {
    for name in ["ok_no_emitters.gltf", "ok_quad.glb"] {
        let scene = load_gltf(&dir().join(name)).expect(name);
        assert_eq!(scene.triangles.len(), 2, "{name}");
        assert_eq!(scene.surfaces.len(), 1, "{name}");
        assert_eq!(scene.surfaces[0].name, "quad");
        assert_eq!(scene.surfaces[0].reflectance, [0.5; 3]);
        assert!(!scene.has_emitters(), "{name}");
        assert_eq!(scene.stats.degenerate_triangles, 0, "{name}");
    }
}

#[test]
fn degenerate_triangles_are_skipped_and_counted() {
    let scene = load_gltf(&dir().join("degenerate_only.gltf")).expect("loads");
    assert_eq!(scene.stats.degenerate_triangles, 2);
    assert!(scene.triangles.is_empty());
    assert!(!scene.has_emitters());
    assert_eq!(scene.warnings().len(), 1);
}

/// Found by fuzzing the sky images: an OpenEXR whose data window is 671 million texels wide
/// behind an 8 × 4 display window passed the `image` crate's limits (it sizes an EXR by its
/// display window) and had the `exr` crate ask for 16 GB. Refused from its header, typed.
#[test]
fn an_exr_sky_whose_data_window_is_huge_is_refused_from_its_header() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/regressions/sky/exr_data_window_671m_wide.exr");
    let bytes = std::fs::read(&path).expect("the fuzzer's input");
    let e = radiant_scene::Sky::from_image_bytes("sky.exr", &bytes, 1.0).expect_err("refused");
    assert!(
        matches!(&e, SceneError::InvalidSky(what) if what.contains("data window of 2684354592")),
        "{e}"
    );
    let e = radiant_scene::exr_fits(&bytes, u64::MAX).map(|()| "fits");
    assert_eq!(
        e,
        Ok("fits"),
        "within an unbounded budget the header itself is sound"
    );
}

/// Found by fuzzing the sky images: a B44-compressed OpenEXR block whose arithmetic wraps,
/// which the exr crate's decoder (like OpenEXR's C reference) computes modulo 2^32; with
/// overflow checks it panicked there. Every build of the workspace wraps it (Cargo.toml's
/// profile for exr): decoded or refused, never a panic.
#[test]
fn a_b44_exr_sky_whose_arithmetic_wraps_does_not_panic() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/regressions/sky/exr_b44_wrapping.exr");
    let bytes = std::fs::read(&path).expect("the fuzzer's input");
    let decoded = panic::catch_unwind(|| {
        radiant_scene::Sky::from_image_bytes("sky.exr", &bytes, 1.0).map(|_| ())
    });
    assert!(decoded.is_ok(), "the decoder panicked");
}
