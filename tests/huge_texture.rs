//! A base-colour texture too large to hold (16384 × 16384, 1 GiB as RGBA) bakes within the
//! memory budget: averaged down to the import's limit as it is read, with one warning. Its own
//! test binary, so that the process's peak resident memory is this test's alone.

use std::io::Write;
use std::path::Path;

use radiant::radiosity::{Bake, BakeParams};

const SIDE: u32 = 16384;

/// A smooth RGB gradient written row by row (never held whole).
fn write_png(path: &Path) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).expect("create the PNG"));
    let mut enc = png::Encoder::new(file, SIDE, SIDE);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut w = enc.write_header().expect("header");
    let mut s = w.stream_writer().expect("stream");
    let mut row = vec![0u8; SIDE as usize * 3];
    for y in 0..SIDE {
        for (x, px) in row.chunks_exact_mut(3).enumerate() {
            px.copy_from_slice(&[(x * 255 / (SIDE as usize - 1)) as u8, (y >> 6) as u8, 128]);
        }
        s.write_all(&row).expect("row");
    }
    s.finish().expect("finish");
}

/// A 1 m floor with the texture, under an emitting panel 0.6 m above it.
fn write_scene(dir: &Path) -> std::path::PathBuf {
    let floor = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 0.0, 1.0],
        [0.0, 0.0, 1.0],
    ];
    let panel = [
        [0.3f32, 0.6, 0.3],
        [0.3, 0.6, 0.7],
        [0.7, 0.6, 0.7],
        [0.7, 0.6, 0.3],
    ];
    let uv = [[0.0f32, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    let mut bin: Vec<u8> = Vec::new();
    for v in floor
        .iter()
        .chain(&panel)
        .flatten()
        .chain(uv.iter().flatten())
    {
        bin.extend(v.to_le_bytes());
    }
    for i in [0u16, 2, 1, 0, 3, 2] {
        bin.extend(i.to_le_bytes());
    }
    std::fs::write(dir.join("geometry.bin"), &bin).expect("buffer");
    let gltf = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0,1]}}],
"nodes":[{{"name":"floor","mesh":0}},{{"name":"panel","mesh":1}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"TEXCOORD_0":2}},"indices":3,"material":0}}]}},
 {{"primitives":[{{"attributes":{{"POSITION":1}},"indices":3,"material":1}}]}}],
"materials":[{{"name":"huge","pbrMetallicRoughness":{{"baseColorFactor":[0.8,0.8,0.8,1],"baseColorTexture":{{"index":0}}}}}},
 {{"name":"panel","emissiveFactor":[1,1,1]}}],
"textures":[{{"source":0}}],"images":[{{"uri":"huge.png"}}],
"buffers":[{{"uri":"geometry.bin","byteLength":{}}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":48}},
 {{"buffer":0,"byteOffset":96,"byteLength":32}},{{"buffer":0,"byteOffset":128,"byteLength":12}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,0,1]}},
 {{"bufferView":1,"componentType":5126,"count":4,"type":"VEC3","min":[0.3,0.6,0.3],"max":[0.7,0.6,0.7]}},
 {{"bufferView":2,"componentType":5126,"count":4,"type":"VEC2"}},
 {{"bufferView":3,"componentType":5123,"count":6,"type":"SCALAR"}}]}}"#,
        bin.len()
    );
    let path = dir.join("huge_texture.gltf");
    std::fs::write(&path, gltf).expect("glTF");
    path
}

/// The process's peak resident memory (Linux's VmHWM), in bytes.
fn peak_rss() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").expect("/proc/self/status");
    let kb: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmHWM");
    kb * 1024
}

#[test]
fn a_16k_texture_bakes_within_the_memory_budget() {
    let dir = std::env::temp_dir().join(format!("radiant-huge-texture-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    write_png(&dir.join("huge.png"));
    let scene = radiant::scene::load_gltf(&write_scene(&dir)).expect("the scene loads");
    let warnings = scene.warnings();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(
        warnings[0].contains("16384×16384") && warnings[0].contains("averaged down 2×"),
        "{warnings:?}"
    );
    let image = &scene.images[0];
    assert_eq!((image.width, image.height), (8192, 8192));
    let mut params = BakeParams::default();
    params.mesh.patch_size = 0.5;
    let result = Bake::new(&scene, &params)
        .expect("bake prepares")
        .run_to_end(&mut |_| {})
        .expect("bake runs");
    assert!(result.radiosity.iter().flatten().all(|b| b.is_finite()));
    let _ = std::fs::remove_dir_all(&dir);
    // The whole image alone would be 1 GiB as RGBA; the import holds the 8192² average
    // (256 MiB) and the bake its filtered pyramid.
    let peak = peak_rss();
    eprintln!("peak resident memory {} MiB", peak >> 20);
    assert!(peak < 900 << 20, "peak resident memory {} MiB", peak >> 20);
}
