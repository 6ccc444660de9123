//! The glTF importer: the input is a `.gltf` (JSON) or `.glb` file, read from a directory that
//! also holds a valid external buffer (`b.bin`) and image (`t.png`), so external URIs, data
//! URIs, GLB chunks, accessors, sparse accessors and images are all reached. A scene that loads
//! must hold only finite geometry and in-range materials: a NaN is a finding, as a panic is.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

fn dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("radiant-fuzz-gltf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temporary directory");
        std::fs::write(dir.join("b.bin"), include_bytes!("../seeds/gltf/b.bin")).expect("b.bin");
        std::fs::write(
            dir.join("t.png"),
            include_bytes!("../seeds/texture/checker_4x4.png"),
        )
        .expect("t.png");
        dir
    })
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let path = dir().join("scene.gltf");
    std::fs::write(&path, data).expect("write the input");
    let Ok(scene) = radiant_scene::load_gltf(&path) else {
        return;
    };
    for t in &scene.triangles {
        assert!(
            t.vertices.iter().all(|v| v.is_finite()),
            "a loaded triangle has a non-finite vertex"
        );
        assert!(
            (t.surface as usize) < scene.surfaces.len(),
            "triangle's surface out of range"
        );
    }
    for s in &scene.surfaces {
        assert!(
            s.reflectance.iter().all(|r| (0.0..=1.0).contains(r)),
            "reflectance out of [0, 1]: {:?}",
            s.reflectance
        );
        assert!(
            s.emission.iter().all(|e| e.is_finite() && *e >= 0.0),
            "emission negative or not finite: {:?}",
            s.emission
        );
    }
});
