//! `radiant render`, run as a user would, on the GPU adapter the test command provides
//! (lavapipe in CI): outputs, linear radiance in the EXR, and bad flags as one-line errors.
#![cfg(feature = "render")]

use std::path::PathBuf;

mod common;
use common::{radiant, run_ok, tmp};

/// The render.json `radiant render` wrote in `out`.
fn render_json(out: &std::path::Path) -> serde_json::Value {
    let text = std::fs::read_to_string(out.join("render.json")).expect("render.json");
    serde_json::from_str(&text).expect("valid json")
}

#[test]
fn render_writes_a_tone_mapped_png_a_linear_exr_and_a_report() {
    let out = tmp("ok");
    let st = radiant()
        .args([
            "render",
            "--builtin",
            "cornell-box",
            "--patch-size",
            "0.3",
            "--size",
            "96x80",
            "--out",
        ])
        .arg(&out)
        .output()
        .expect("runs");
    assert!(
        st.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&st.stderr)
    );
    let png = image::open(out.join("frame.png")).expect("png").to_rgba8();
    assert_eq!(png.dimensions(), (96, 80));
    let exr = image::open(out.join("frame.exr"))
        .expect("exr")
        .to_rgba32f();
    assert_eq!(exr.dimensions(), (96, 80));
    assert!(
        exr.pixels()
            .all(|p| p.0.iter().all(|v| v.is_finite() && *v >= 0.0))
    );
    // The EXR is linear radiance: the light's pixels carry its emission (17, 12, 4) plus a
    // little reflected light, far above display white.
    let brightest = exr.pixels().map(|p| p.0[0]).fold(0.0f32, f32::max);
    assert!(
        (17.0..19.0).contains(&brightest),
        "brightest red radiance {brightest}"
    );
    let report = render_json(&out);
    assert_eq!(report["baked"], true);
    let passes = report["graph"]["passes"].as_array().expect("passes");
    assert!(passes.iter().any(|p| p == "ssao_pass"));
    assert!(passes.iter().any(|p| p == "bloom_composite_pass"));
    // The builtin box is compared with Mitsuba 3 from the same camera (supersampled radiance,
    // no SSAO, no bloom). At this coarse bake (patch size 0.3, the automatic light-map density)
    // the surfaces were measured at 3.3 % L1 and -0.5 % bias (the default bake: 1.5 % L1);
    // the bounds leave room for drivers, not for regressions.
    let s = &report["path_traced_reference"]["surfaces"];
    let l1 = s["rel_l1"].as_f64().expect("l1");
    let bias = s["mean_bias"].as_f64().expect("bias");
    assert!(l1 < 0.04, "surface L1 {l1}");
    assert!(bias.abs() < 0.01, "surface bias {bias}");
    let _ = std::fs::remove_dir_all(&out);
}

/// `render --final-gather` draws the gathered light map: on the coarse bake above (elements
/// of 0.3 m) the surfaces were measured at 2.8 % over 4×4 blocks with the smooth field and
/// 1.0 % with a gather of 8 × 8 rays (0.8 % over 8×8 blocks); render.json says which.
#[test]
fn render_draws_the_final_gather() {
    let out = tmp("gather");
    run_ok(
        &[
            "render",
            "--builtin",
            "cornell-box",
            "--patch-size",
            "0.3",
            "--size",
            "96x80",
            "--final-gather",
            "8",
        ],
        &out,
    );
    let report = render_json(&out);
    assert_eq!(report["final_gather"]["strata"], 8);
    assert!(report["lightmap_s"].as_f64().expect("light-map seconds") > 0.0);
    let s = &report["path_traced_reference"]["surfaces"];
    let blocks = s["rel_l1_4x4"].as_f64().expect("4x4");
    let coarse = s["rel_l1_8x8"].as_f64().expect("8x8");
    assert!(blocks < 0.015, "surfaces over 4x4 blocks {blocks}");
    assert!(coarse <= blocks * 1.05, "8x8 {coarse} against 4x4 {blocks}");
}

#[test]
fn disabled_effects_are_not_in_the_frame() {
    let out = tmp("minimal");
    let st = radiant()
        .args([
            "render",
            "--builtin",
            "cornell-box",
            "--patch-size",
            "0.3",
            "--texel-density",
            "40",
            "--size",
            "32x32",
            "--no-ssao",
            "--no-bloom",
            "--tonemap",
            "agx",
            "--out",
        ])
        .arg(&out)
        .output()
        .expect("runs");
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let report = render_json(&out);
    assert_eq!(
        report["graph"]["passes"],
        serde_json::json!(["gbuffer_pass", "lighting_pass", "tonemapping_pass"])
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_scene_without_emitters_renders_without_a_bake() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/bad_inputs");
    let out = tmp("dark");
    let st = radiant()
        .arg("render")
        .arg(dir.join("ok_no_emitters.gltf"))
        .args(["--size", "16x16", "--out"])
        .arg(&out)
        .output()
        .expect("runs");
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    assert!(String::from_utf8_lossy(&st.stdout).contains("no bake"));
    let report = render_json(&out);
    assert_eq!(report["baked"], false);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn bad_render_flags_give_one_line() {
    for flags in [
        vec!["--size", "0x10"],
        vec!["--size", "wide"],
        vec!["--size", "99999x10"],
        vec!["--tonemap", "filmic-magic"],
        vec!["--debug", "xray"],
        vec!["--exposure", "nan"],
        vec!["--texel-density", "0"],
        vec!["--texel-density", "inf"],
        vec!["--final-gather", "65"],
        vec!["--final-gather", "-1"],
        vec!["--final-gather", "4", "--gather-stride", "0"],
    ] {
        let out = tmp("bad");
        let st = radiant()
            .args(["render", "--builtin", "cornell-box", "--out"])
            .arg(&out)
            .args(&flags)
            .output()
            .expect("runs");
        let stderr = String::from_utf8_lossy(&st.stderr);
        assert!(!st.status.success(), "{flags:?} succeeded");
        let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
        assert!(!stderr.contains("panicked"), "{flags:?}: {stderr}");
        assert!(
            lines.len() == 1 || stderr.starts_with("error: invalid value"),
            "{flags:?}: {stderr}"
        );
        let _ = std::fs::remove_dir_all(&out);
    }
}

#[test]
fn render_compares_with_the_reference_tracers_image() {
    let dir = tmp("with-reference");
    let reference = dir.join("reference");
    run_ok(
        &[
            "reference",
            "--builtin",
            "cornell-box",
            "--samples",
            "64",
            "--image",
            "32x32",
            "--no-surfaces",
        ],
        &reference,
    );
    let out = dir.join("render");
    let image = reference.join("image.exr").display().to_string();
    run_ok(
        &[
            "render",
            "--builtin",
            "cornell-box",
            "--patch-size",
            "0.3",
            "--reference-image",
            &image,
        ],
        &out,
    );
    let report = render_json(&out);
    let r = &report["path_traced_reference"];
    assert_eq!(r["size"], serde_json::json!([32, 32]));
    // The same light as the bake, seen through 64 noisy paths per pixel: no bias beyond the
    // coarse bake's few per cent.
    let bias = r["surfaces"]["mean_bias"].as_f64().expect("bias");
    assert!(bias.abs() < 0.08, "mean bias {bias}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A node marked dynamic (`--dynamic`) is left out of the bake and drawn lit by the probes
/// baked from the solution: not black, the colour of the light around it (the Cornell box's
/// tall block against the same block light-mapped), and report.json says how many probes.
#[test]
fn a_dynamic_node_is_lit_by_the_probes() {
    let dir = tmp("dynamic");
    let frame = |extra: &[&str], name: &str| {
        let out = dir.join(name);
        let mut args = vec![
            "render",
            "--builtin",
            "cornell-box",
            "--patch-size",
            "0.3",
            "--size",
            "64x64",
        ];
        args.extend_from_slice(extra);
        let stdout = run_ok(&args, &out);
        let exr = image::open(out.join("frame.exr")).expect("exr").to_rgb32f();
        (stdout, exr, render_json(&out))
    };
    let (_, fixed, report) = frame(&[], "static");
    assert!(report["probes"].is_null(), "no dynamic node, no probes");
    let block = [
        "--dynamic",
        "tall_block_side1",
        "--dynamic",
        "tall_block_side2",
        "--dynamic",
        "tall_block_side3",
        "--dynamic",
        "tall_block_side4",
        "--dynamic",
        "tall_block_top",
    ];
    let (stdout, moving, report) = frame(&block, "dynamic");
    assert!(stdout.contains("5 dynamic surfaces lit by"), "{stdout}");
    assert_eq!(report["probes"]["dynamic_surfaces"], 5);
    assert!(report["probes"]["probes"].as_u64().expect("probes") > 1000);
    // The block's front face, mid-height.
    for (x, y) in [(24, 42), (20, 36), (28, 48)] {
        let (a, b) = (moving.get_pixel(x, y).0, fixed.get_pixel(x, y).0);
        assert!(a.iter().all(|&v| v > 0.0), "({x}, {y}) black: {a:?}");
        // The solution without the block is brighter there (it no longer shades its own
        // surroundings), but the light is the same light: within 2× and of the same colour.
        let ratio = a[1] / b[1];
        assert!((0.5..2.0).contains(&ratio), "({x}, {y}): {a:?} vs {b:?}");
        for k in [0, 2] {
            let (ca, cb) = (a[k] / a[1], b[k] / b[1]);
            assert!(
                (ca - cb).abs() <= 0.2 * cb,
                "({x}, {y}) colour: {a:?} vs {b:?}"
            );
        }
    }
    // A dynamic emitter is not baked: with the box's only one dynamic, nothing is.
    let out = dir.join("dynamic-light");
    let stdout = run_ok(
        &[
            "render",
            "--builtin",
            "cornell-box",
            "--size",
            "16x16",
            "--dynamic",
            "light",
        ],
        &out,
    );
    assert!(
        stdout.contains("no emitters among the static surfaces"),
        "{stdout}"
    );
    assert_eq!(render_json(&out)["baked"], false);
    // A node that is not there: one line that names some that are.
    let st = radiant()
        .args([
            "render",
            "--builtin",
            "cornell-box",
            "--dynamic",
            "tall_blok",
        ])
        .arg("--out")
        .arg(dir.join("typo"))
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&st.stderr);
    assert!(!st.status.success());
    assert!(
        stderr.contains("no node of that name") && stderr.contains("tall_block_top"),
        "{stderr}"
    );
}

/// A reference image with no light, or with a value no radiance has, is refused in one line
/// before anything is baked (it had given relative errors of 10^300 %).
#[test]
fn a_black_or_broken_reference_image_is_refused_before_the_bake() {
    let dir = tmp("bad-reference");
    std::fs::create_dir_all(&*dir).expect("dir");
    let write = |name: &str, v: f32| {
        let path = dir.join(name);
        let img = image::Rgba32FImage::from_pixel(8, 8, image::Rgba([v, v, v, 1.0]));
        image::DynamicImage::ImageRgba32F(img)
            .save_with_format(&path, image::ImageFormat::OpenExr)
            .expect("exr");
        path
    };
    for (path, says) in [
        (write("black.exr", 0.0), "the image is black"),
        (write("nan.exr", f32::NAN), "finite, non-negative"),
        (write("negative.exr", -1.0), "finite, non-negative"),
    ] {
        let out = dir.join("out");
        let st = radiant()
            .args(["render", "--builtin", "cornell-box", "--reference-image"])
            .arg(&path)
            .arg("--out")
            .arg(&out)
            .output()
            .expect("runs");
        let stderr = String::from_utf8_lossy(&st.stderr);
        assert!(!st.status.success(), "{}: accepted", path.display());
        assert!(stderr.contains(says), "{}: {stderr}", path.display());
        assert!(!stderr.contains("panicked"), "{stderr}");
        assert!(!out.join("frame.png").exists(), "refused before the frame");
    }
}

#[test]
fn bake_with_the_gpu_hemicube_writes_a_light_map_and_its_error() {
    let out = tmp("gpu-hemicube");
    let args = [
        "bake",
        "--builtin",
        "cornell-box",
        "--method",
        "gpu-hemicube",
        "--hemicube-resolution",
        "32",
        "--texel-density",
        "24",
        "--tolerance",
        "1e-2",
    ];
    let stdout = run_ok(&args, &out);
    assert!(stdout.contains("gpu-hemicube on"), "{stdout}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["method"], "gpu-hemicube");
    assert_eq!(report["hemicube_resolution"], 32);
    assert!(report["receivers"].as_u64().expect("receivers") > 500);
    let timeline = report["timeline"].as_array().expect("timeline");
    assert_eq!(
        timeline.len() as u64,
        report["iterations"].as_u64().expect("iterations")
    );
    // Coarse (32² hemicubes, 2 cm texels, 1 % tolerance) but well within 5 % of Mitsuba.
    let err = report["error_vs_reference"]["mean_rel"]
        .as_f64()
        .expect("error");
    assert!(err < 0.05, "{err}");
    for f in ["surfaces.csv", "lightmap.exr", "lightmap.png"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    assert_eq!(report["batches_drawn_once"], report["batches"]);

    // --memory-limit bounds the hemicubes kept between sweeps: under 1 MB nothing is kept,
    // every sweep draws them again, and the light is the same.
    let tight = tmp("gpu-hemicube-tight");
    run_ok(&[&args[..], &["--memory-limit", "1M"]].concat(), &tight);
    let tight_report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tight.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(tight_report["batches_drawn_once"], 0);
    assert_eq!(
        tight_report["error_vs_reference"]["mean_rel"],
        report["error_vs_reference"]["mean_rel"]
    );
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_dir_all(&tight);
}

#[test]
fn the_gpu_hemicube_without_an_adapter_names_the_cpu_methods() {
    // A backend this platform has no adapter for stands in for a machine without a GPU.
    let missing = if cfg!(target_os = "macos") {
        "dx12"
    } else {
        "metal"
    };
    let out = tmp("gpu-hemicube-no-adapter");
    let st = radiant()
        .args([
            "bake",
            "--builtin",
            "cornell-box",
            "--method",
            "gpu-hemicube",
            "--out",
        ])
        .arg(&out)
        .env("WGPU_BACKEND", missing)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&st.stderr);
    assert!(!st.status.success());
    assert!(
        stderr.contains("needs a GPU adapter") && stderr.contains("--method jacobi"),
        "{stderr}"
    );
    assert!(!out.join("report.json").exists());
    let _ = std::fs::remove_dir_all(&out);
}

/// `radiant render` on wgpu's GL backend (Mesa's llvmpipe where there is no GPU), as a machine
/// without a Vulkan driver gets it: the frame is drawn, with the same error against the path
/// tracer as on Vulkan, and no validation error. Depth is
/// read as an unfilterable float texture (GLSL cannot load a depth texture) and a one-page
/// light map gets a second, empty layer (GL takes a one-layer texture for a plain 2D one).
#[test]
fn render_draws_the_same_frame_on_the_gl_backend() {
    let mut errors = Vec::new();
    for backend in ["vulkan", "gl"] {
        let out = tmp(&format!("backend-{backend}"));
        let st = radiant()
            .args([
                "render",
                "--builtin",
                "cornell-box",
                "--size",
                "128x128",
                "--out",
            ])
            .arg(&out)
            .env("WGPU_BACKEND", backend)
            .output()
            .expect("runs");
        let stderr = String::from_utf8_lossy(&st.stderr);
        assert!(st.status.success(), "{backend}: {stderr}");
        // (A debug build's EGL probing may log a platform it skipped; no validation error.)
        assert!(
            !stderr.contains("Validation Error") && !stderr.contains("error:"),
            "{backend}: {stderr}"
        );
        let report = render_json(&out);
        let adapter = report["adapter"].as_str().expect("adapter").to_string();
        assert!(
            adapter.to_lowercase().contains(&format!("({backend})")),
            "asked for {backend}, got {adapter}"
        );
        let l1 = report["path_traced_reference"]["surfaces"]["rel_l1"]
            .as_f64()
            .expect("the frame's error");
        errors.push(l1);
    }
    // Measured: 1.52 % on both.
    assert!(
        errors[1] < 0.03,
        "GL frame {:.2} % from the path tracer",
        errors[1] * 100.0
    );
    assert!(
        (errors[0] - errors[1]).abs() < 0.002,
        "Vulkan {errors:?} vs GL"
    );
}

/// With no adapter at all (Vulkan asked for, its loader pointed at no driver) `radiant render`
/// says why in one line, naming the package that installs one, and `radiant bake` still bakes;
/// an adapter name that matches none is its own typed error listing the adapters there are.
/// Where `XDG_RUNTIME_DIR` is unset (a headless machine, CI) Mesa prints nothing.
#[test]
fn without_an_adapter_render_says_why_and_bake_still_works() {
    let out = tmp("no-adapter");
    let run = |args: &[&str], env: &[(&str, &str)]| {
        let mut c = radiant();
        c.args(args)
            .arg("--out")
            .arg(&out)
            .env_remove("XDG_RUNTIME_DIR");
        for (k, v) in env {
            c.env(k, v);
        }
        c.output().expect("runs")
    };
    let none = [
        ("WGPU_BACKEND", "vulkan"),
        ("VK_ICD_FILENAMES", "/nonexistent.json"),
    ];
    let st = run(
        &["render", "--builtin", "cornell-box", "--size", "32x32"],
        &none,
    );
    let stderr = String::from_utf8_lossy(&st.stderr);
    assert!(!st.status.success(), "{stderr}");
    assert!(
        stderr.contains("no GPU adapter") && stderr.contains("apt-get install mesa-vulkan-drivers"),
        "{stderr}"
    );
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    let st = run(
        &["bake", "--builtin", "cornell-box", "--patch-size", "0.3"],
        &none,
    );
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    assert!(out.join("lightmap.exr").is_file());
    let st = run(
        &["render", "--builtin", "cornell-box", "--size", "32x32"],
        &[("WGPU_ADAPTER_NAME", "no such adapter")],
    );
    let stderr = String::from_utf8_lossy(&st.stderr);
    assert!(!st.status.success());
    assert!(
        stderr.contains("matches no adapter") && stderr.contains("available"),
        "{stderr}"
    );
    assert!(
        !stderr.contains("XDG_RUNTIME_DIR"),
        "Mesa's noise: {stderr}"
    );
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
}

/// The camera test's scene ([`camera_scene`]): where it was written, the markers (centre and
/// colour channel), and the camera as glTF defines it.
struct CameraScene {
    path: PathBuf,
    markers: Vec<([f64; 3], usize)>,
    eye: glam::DVec3,
    forward: glam::DVec3,
    up: glam::DVec3,
    yfov: f64,
}

/// A glTF scene no symmetry can hide a flip in: three coloured emissive squares on a wall
/// (red up left, green up right, blue low in the middle), a floor they light, and a camera on
/// a child node of a turned and shifted parent, itself tilted, with a 2:1 image. The camera
/// as glTF defines it: the node's world transform applied to −Z and +Y.
fn camera_scene(dir: &std::path::Path) -> CameraScene {
    use glam::{DQuat, DVec3};
    std::fs::create_dir_all(dir).expect("dir");
    let mut bin: Vec<u8> = Vec::new();
    let (mut views, mut accessors, mut meshes, mut nodes) = (vec![], vec![], vec![], vec![]);
    // A quad as two triangles, counter-clockwise as seen from where it faces.
    let mut quad = |corners: [[f32; 3]; 4], material: usize| {
        let (lo, hi) = corners.iter().fold(
            ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]),
            |(lo, hi), p| {
                (
                    [0, 1, 2].map(|c| lo[c].min(p[c])),
                    [0, 1, 2].map(|c| hi[c].max(p[c])),
                )
            },
        );
        let offset = bin.len();
        for p in corners {
            for v in p {
                bin.extend_from_slice(&v.to_le_bytes());
            }
        }
        for i in [0u16, 1, 2, 0, 2, 3] {
            bin.extend_from_slice(&i.to_le_bytes());
        }
        bin.extend_from_slice(&[0, 0, 0, 0]); // 4-byte alignment
        views.push(format!(
            r#"{{"buffer":0,"byteOffset":{offset},"byteLength":48}}"#
        ));
        views.push(format!(
            r#"{{"buffer":0,"byteOffset":{},"byteLength":12}}"#,
            offset + 48
        ));
        let (pv, iv) = (views.len() - 2, views.len() - 1);
        accessors.push(format!(
            r#"{{"bufferView":{pv},"componentType":5126,"count":4,"type":"VEC3","min":{lo:?},"max":{hi:?}}}"#
        ));
        accessors.push(format!(
            r#"{{"bufferView":{iv},"componentType":5123,"count":6,"type":"SCALAR"}}"#
        ));
        let (pa, ia) = (accessors.len() - 2, accessors.len() - 1);
        meshes.push(format!(
            r#"{{"primitives":[{{"attributes":{{"POSITION":{pa}}},"indices":{ia},"material":{material}}}]}}"#
        ));
        nodes.push(format!(r#"{{"mesh":{}}}"#, meshes.len() - 1));
    };
    // The wall (z = −4, facing +z) and the floor (y = −2.5, facing +y), grey.
    quad(
        [
            [-6.0, -2.5, -4.0],
            [6.0, -2.5, -4.0],
            [6.0, 4.0, -4.0],
            [-6.0, 4.0, -4.0],
        ],
        0,
    );
    quad(
        [
            [-6.0, -2.5, 3.0],
            [6.0, -2.5, 3.0],
            [6.0, -2.5, -4.0],
            [-6.0, -2.5, -4.0],
        ],
        0,
    );
    let markers = [
        ([-2.2, 1.0, -3.9], 0),
        ([1.8, 1.3, -3.9], 1),
        ([0.9, -1.4, -3.9], 2),
    ];
    for (i, (c, _)) in markers.iter().enumerate() {
        let h = 0.35f32;
        let [x, y, z] = [c[0] as f32, c[1] as f32, c[2] as f32];
        quad(
            [
                [x - h, y - h, z],
                [x + h, y - h, z],
                [x + h, y + h, z],
                [x - h, y + h, z],
            ],
            1 + i,
        );
    }
    let (turn, tilt, yfov) = (0.15f64, 0.08f64, 0.7f64);
    let rig_t = DVec3::new(0.6, 0.2, 0.0);
    let rig_q = DQuat::from_rotation_y(turn);
    let cam_t = DVec3::new(0.0, 0.0, 6.0);
    let cam_q = DQuat::from_rotation_x(tilt);
    let q = |q: DQuat| format!("[{},{},{},{}]", q.x, q.y, q.z, q.w);
    let v = |v: DVec3| format!("[{},{},{}]", v.x, v.y, v.z);
    nodes.push(format!(
        r#"{{"translation":{},"rotation":{},"children":[{}]}}"#,
        v(rig_t),
        q(rig_q),
        nodes.len() + 1
    ));
    nodes.push(format!(
        r#"{{"name":"eye","translation":{},"rotation":{},"camera":0}}"#,
        v(cam_t),
        q(cam_q)
    ));
    let roots: Vec<String> = (0..nodes.len() - 1).map(|i| i.to_string()).collect();
    let emissive = |rgb: [f64; 3]| {
        format!(
            r#"{{"pbrMetallicRoughness":{{"baseColorFactor":[0,0,0,1],"metallicFactor":0}},"emissiveFactor":{rgb:?},"extensions":{{"KHR_materials_emissive_strength":{{"emissiveStrength":4}}}}}}"#
        )
    };
    let materials = [
        r#"{"pbrMetallicRoughness":{"baseColorFactor":[0.5,0.5,0.5,1],"metallicFactor":0}}"#
            .to_string(),
        emissive([1.0, 0.0, 0.0]),
        emissive([0.0, 1.0, 0.0]),
        emissive([0.0, 0.0, 1.0]),
    ];
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"extensionsUsed":["KHR_materials_emissive_strength"],"scene":0,"scenes":[{{"nodes":[{}]}}],"nodes":[{}],"meshes":[{}],"materials":[{}],"accessors":[{}],"bufferViews":[{}],"buffers":[{{"byteLength":{},"uri":"scene.bin"}}],"cameras":[{{"type":"perspective","perspective":{{"yfov":{yfov},"aspectRatio":2.0,"znear":0.05,"zfar":100}}}}]}}"#,
        roots.join(","),
        nodes.join(","),
        meshes.join(","),
        materials.join(","),
        accessors.join(","),
        views.join(","),
        bin.len()
    );
    std::fs::write(dir.join("scene.bin"), &bin).expect("bin");
    let path = dir.join("scene.gltf");
    std::fs::write(&path, json).expect("gltf");
    let world = |p: DVec3| rig_t + rig_q * p;
    let eye = world(cam_t);
    let forward = rig_q * (cam_q * DVec3::NEG_Z);
    let up = rig_q * (cam_q * DVec3::Y);
    CameraScene {
        path,
        markers: markers.to_vec(),
        eye,
        forward,
        up,
        yfov,
    }
}

/// The coverage-weighted centre (pixels, from the top-left corner) and area of the pixels
/// where `channel` shines and the others do not.
fn marker(img: &image::Rgba32FImage, channel: usize) -> Option<([f64; 2], f64)> {
    let (mut sum, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (x, y, p) in img.enumerate_pixels() {
        let v = f64::from(p.0[channel]);
        let others = (0..3).filter(|&c| c != channel).map(|c| f64::from(p.0[c]));
        if v > 0.5 && others.clone().all(|o| o < 0.25 * v) {
            let w = (v / 4.0).min(1.0);
            sum += w;
            sx += w * (f64::from(x) + 0.5);
            sy += w * (f64::from(y) + 0.5);
        }
    }
    (sum > 0.0).then(|| ([sx / sum, sy / sum], sum))
}

/// `radiant render` and `radiant reference --image` put the glTF camera's view in the same
/// place: left is left, up is up, the image's aspect and the camera's vertical field of view
/// as glTF defines them (a pinhole looking along the node's −Z, +Y up, through the parent's
/// transform), checked at three coloured markers against where the pinhole puts them.
#[test]
fn render_and_reference_see_the_gltf_camera_alike() {
    let dir = tmp("camera");
    let CameraScene {
        path,
        markers,
        eye,
        forward,
        up,
        yfov,
    } = camera_scene(&dir.join("scene"));
    let scene = path.display().to_string();
    let (w, h) = (160u32, 80u32);
    run_ok(
        &[
            "reference",
            &scene,
            "--samples",
            "16",
            "--image",
            "160x80",
            "--no-surfaces",
        ],
        &dir.join("reference"),
    );
    run_ok(
        &[
            "render",
            &scene,
            "--size",
            "160x80",
            "--no-ssao",
            "--no-bloom",
        ],
        &dir.join("render"),
    );
    let read = |p: PathBuf| image::open(&p).expect("exr").to_rgba32f();
    let traced = read(dir.join("reference/image.exr"));
    let frame = read(dir.join("render/frame.exr"));
    assert_eq!(traced.dimensions(), (w, h));
    assert_eq!(frame.dimensions(), (w, h));
    // Where the pinhole puts each marker's square: the centroid and area of its projected
    // corners (a plane quad projects to a quad), in pixels.
    let right = forward.cross(up).normalize();
    let tan = (0.5 * yfov).tan();
    let aspect = f64::from(w) / f64::from(h);
    let project = |p: glam::DVec3| {
        let d = p - eye;
        let z = d.dot(forward);
        glam::DVec2::new(
            0.5 * (1.0 + d.dot(right) / z / (tan * aspect)) * f64::from(w),
            0.5 * (1.0 - d.dot(up) / z / tan) * f64::from(h),
        )
    };
    for (centre, channel) in markers {
        let c = glam::DVec3::from(centre);
        let q = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
            .map(|(x, y)| project(c + glam::DVec3::new(0.35 * x, 0.35 * y, 0.0)));
        let (mut area, mut cx, mut cy) = (0.0, 0.0, 0.0);
        for i in 0..4 {
            let (p, n) = (q[i], q[(i + 1) % 4]);
            let cross = p.perp_dot(n);
            area += 0.5 * cross;
            cx += (p.x + n.x) * cross / 6.0;
            cy += (p.y + n.y) * cross / 6.0;
        }
        let want = [cx / area, cy / area];
        let area = area.abs();
        for (what, img) in [("render", &frame), ("reference", &traced)] {
            let (got, covered) = marker(img, channel)
                .unwrap_or_else(|| panic!("{what}: marker {channel} is not in the image"));
            let off = ((got[0] - want[0]).powi(2) + (got[1] - want[1]).powi(2)).sqrt();
            assert!(
                off < 0.6,
                "{what}: marker {channel} at {got:?}, the pinhole puts it at {want:?}"
            );
            assert!(
                (covered / area - 1.0).abs() < 0.2,
                "{what}: marker {channel} covers {covered:.1} px, the pinhole {area:.1}"
            );
        }
    }
}
