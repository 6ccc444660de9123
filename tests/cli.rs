//! The `radiant` command line, run as a user would: outputs, reports, and bad input giving one
//! clear line and a non-zero exit code.

use std::path::PathBuf;

mod common;
use common::{radiant, run_ok, tmp};

/// Without a terminal the progress bars are hidden, and the log says how far a bake is:
/// lines under `radiant::progress`, plain text, also with `RUST_LOG` unset.
#[test]
fn progress_goes_to_the_log_without_a_terminal() {
    for (hierarchy, line) in [
        ("triangles", "form factors progress"),
        ("clustered", "clustered bake progress"),
    ] {
        let out = tmp("progress");
        let st = radiant()
            .args(["bake", "--builtin", "cornell-box", "--patch-size", "0.3"])
            .args(["--hierarchy", hierarchy, "--out"])
            .arg(&out)
            .env_remove("RUST_LOG")
            .env("RADIANT_PROGRESS_SECONDS", "0")
            .output()
            .expect("runs");
        let stderr = String::from_utf8_lossy(&st.stderr);
        assert!(st.status.success(), "{hierarchy}: {stderr}");
        assert!(
            stderr.contains("radiant::progress"),
            "{hierarchy}: {stderr}"
        );
        assert!(stderr.contains(line), "{hierarchy}: {stderr}");
        assert!(stderr.contains("total="), "{hierarchy}: {stderr}");
        assert!(
            !stderr.contains('\u{1b}'),
            "{hierarchy}: colour codes: {stderr}"
        );
    }
}

#[test]
fn bake_writes_every_output() {
    let out = tmp("bake");
    let st = radiant()
        .args([
            "bake",
            "--builtin",
            "cornell-box",
            "--patch-size",
            "0.3",
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
    let stdout = String::from_utf8_lossy(&st.stdout);
    assert!(stdout.contains("error against"), "{stdout}");
    for f in [
        "surfaces.csv",
        "patches.csv",
        "report.json",
        "lightmap.exr",
        "lightmap.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let surfaces = std::fs::read_to_string(out.join("surfaces.csv")).expect("surfaces.csv");
    let mut lines = surfaces.lines();
    assert_eq!(lines.next(), Some("surface,area,b_r,b_g,b_b"));
    assert_eq!(lines.count(), 19);
    let patches = std::fs::read_to_string(out.join("patches.csv")).expect("patches.csv");
    assert!(patches.starts_with(
        "id,surface,cx,cy,cz,nx,ny,nz,area,rho_r,rho_g,rho_b,e_r,e_g,e_b,b_r,b_g,b_b\n"
    ));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report"))
            .expect("json");
    for key in [
        "patches",
        "elements",
        "method",
        "form_factors",
        "seconds",
        "iterations",
        "converged",
        "residual",
        "unshot_fraction",
        "timeline",
        "warnings",
    ] {
        assert!(report.get(key).is_some(), "report.json lacks {key}");
    }
    for phase in [
        "import",
        "meshing",
        "visibility",
        "form_factors",
        "solve",
        "total",
    ] {
        assert!(report["seconds"][phase].is_number(), "no time for {phase}");
    }
    assert_eq!(report["converged"], true);
    assert!(
        report["reference"]["error"]["mean_rel_error"]
            .as_f64()
            .expect("error")
            < 0.05
    );
    // With a reference, the light map is measured over the same surfaces too.
    assert!(stdout.contains("the light map against"), "{stdout}");
    let shown = std::fs::read_to_string(out.join("lightmap_surfaces.csv")).expect("light map");
    let mut lines = shown.lines();
    assert_eq!(lines.next(), Some("surface,area,b_r,b_g,b_b"));
    assert_eq!(lines.count(), 19);
    assert!(
        report["reference"]["lightmap_error"]["mean_rel_error"]
            .as_f64()
            .expect("the light map's error")
            < 0.05
    );
    // No temporary files are left behind.
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .expect("dir")
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty());
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn converge_writes_curves_for_each_combination() {
    let out = tmp("converge");
    let st = radiant()
        .args([
            "converge",
            "--builtin",
            "cornell-box",
            "--patch-size",
            "0.3",
            "--element-levels",
            "1",
            "--methods",
            "jacobi,southwell,direct",
            "--form-factors",
            "analytic,montecarlo",
            "--reference",
            "direct",
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
    let csv = std::fs::read_to_string(out.join("convergence.csv")).expect("csv");
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some(
            "method,form_factors,t_s,iterations,rel_rms_error,max_rel_error,residual,mean_rel_error"
        )
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    for m in ["jacobi", "southwell", "direct"] {
        for f in ["analytic", "montecarlo"] {
            let curve: Vec<&Vec<&str>> = rows.iter().filter(|r| r[0] == m && r[1] == f).collect();
            assert!(!curve.is_empty(), "no rows for {m}/{f}");
            // Against the direct solve on the same mesh, every method converges to it.
            let last: f64 = curve.last().expect("row")[4].parse().expect("number");
            assert!(last < 1e-3, "{m}/{f} ends at relative RMS {last}");
        }
    }
    let png = std::fs::read(out.join("convergence.png")).expect("png");
    assert!(png.starts_with(b"\x89PNG"));
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn bad_input_gives_one_line_and_nonzero_exit() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/bad_inputs");
    // A pipe where a checkpoint would go (a pipe, not a device: were the refusal to fail, a
    // rename would replace it, not /dev/null).
    let fifo_dir = tmp("fifo");
    std::fs::create_dir_all(&fifo_dir).expect("dir");
    let fifo = fifo_dir.join("bake.ckpt");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .expect("mkfifo runs");
    assert!(made.success());
    let zero_normal = fifo_dir.join("zero_normal.csv");
    std::fs::write(&zero_normal, "name,x,y,z,nx,ny,nz\np,0.2,0.2,0.2,0,0,0\n").expect("csv");
    let cases: Vec<Vec<String>> = vec![
        vec![
            "bake".into(),
            dir.join("truncated_json.gltf").display().to_string(),
        ],
        vec![
            "bake".into(),
            dir.join("nan_position.gltf").display().to_string(),
        ],
        vec!["bake".into(), dir.join("empty.gltf").display().to_string()],
        vec!["bake".into(), "/does/not/exist.gltf".into()],
        vec!["bake".into(), "--builtin".into(), "teapot".into()],
        vec![
            "bake".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--patch-size=-1".into(),
        ],
        vec![
            "bake".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--method".into(),
            "magic".into(),
        ],
        vec![
            "bake".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--tolerance".into(),
            "nan".into(),
        ],
        vec![
            "bake".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--reference".into(),
            "/does/not/exist.csv".into(),
        ],
        // Devices named as inputs: refused before a byte is read (were read without end), and a
        // checkpoint is never written in a device's place.
        vec!["bake".into(), "/dev/zero".into()],
        vec![
            "bake".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--points".into(),
            "/dev/zero".into(),
        ],
        vec![
            "bake".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--reference".into(),
            "/dev/urandom".into(),
        ],
        vec![
            "bake".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--checkpoint".into(),
            fifo.display().to_string(),
        ],
        vec![
            "reference".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--samples".into(),
            "8".into(),
            "--points".into(),
            "/dev/zero".into(),
        ],
        vec![
            "reference".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--samples".into(),
            "8".into(),
            "--probes".into(),
            zero_normal.display().to_string(),
        ],
        vec![
            "reference".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--samples".into(),
            "0".into(),
        ],
        vec![
            "reference".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--target-error".into(),
            "nan".into(),
        ],
        vec![
            "reference".into(),
            "--builtin".into(),
            "cornell-box".into(),
            "--samples".into(),
            "8".into(),
            "--image".into(),
            "0x5".into(),
        ],
        vec![
            "reference".into(),
            dir.join("nan_position.gltf").display().to_string(),
            "--samples".into(),
            "8".into(),
        ],
    ];
    for args in cases {
        let out = tmp("bad");
        let st = radiant()
            .args(&args)
            .arg("--out")
            .arg(&out)
            .output()
            .expect("runs");
        let stderr = String::from_utf8_lossy(&st.stderr);
        assert!(!st.status.success(), "{args:?} succeeded");
        assert_eq!(st.status.code(), Some(1), "{args:?}: {stderr}");
        let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(lines.len(), 1, "{args:?}: not one line: {stderr}");
        assert!(lines[0].starts_with("error: "), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        let _ = std::fs::remove_dir_all(&out);
    }
    assert!(
        std::fs::metadata(&fifo).is_ok_and(|m| !m.is_file()),
        "the pipe was replaced"
    );
    let _ = std::fs::remove_dir_all(&fifo_dir);
}

#[test]
fn scene_without_emitters_says_so() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/bad_inputs");
    let out = tmp("dark");
    let st = radiant()
        .arg("bake")
        .arg(dir.join("ok_no_emitters.gltf"))
        .arg("--out")
        .arg(&out)
        .output()
        .expect("runs");
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    assert!(String::from_utf8_lossy(&st.stdout).contains("no emitters"));
    let surfaces = std::fs::read_to_string(out.join("surfaces.csv")).expect("surfaces");
    for line in surfaces.lines().skip(1) {
        let f: Vec<f64> = line
            .split(',')
            .skip(2)
            .map(|v| v.parse().expect("number"))
            .collect();
        assert_eq!(f, vec![0.0, 0.0, 0.0]);
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn spectral_bake_compares_with_rgb() {
    let out = tmp("spectral");
    let st = radiant()
        .args([
            "bake",
            "--builtin",
            "cornell-box",
            "--patch-size",
            "0.3",
            "--spectral",
            "--bands",
            "8",
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
    assert!(String::from_utf8_lossy(&st.stdout).contains("spectral (8 bands"));
    assert!(out.join("surfaces_rgb.csv").is_file());
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["spectral"]["bands"], 8);
    // The builtin box is compared with path tracing at surface points too, RGB and spectral.
    for key in [
        &report["points_vs_path_traced"],
        &report["points_vs_path_traced"]["smooth"],
        &report["spectral"]["vs_path_traced_points"],
    ] {
        let mean = key["mean_rel"].as_f64().expect("mean_rel");
        assert!(mean.is_finite() && mean > 0.0 && mean < 0.5, "{key}");
        assert!(key["points"].as_array().expect("points").len() >= 23);
    }
    assert!(
        report["spectral"]["relative_difference_from_rgb"]["mean"]
            .as_f64()
            .expect("mean")
            .is_finite()
    );
    // The clustered hierarchy solves in bands too (levels are no longer sent to the
    // per-triangle bake for it).
    let clustered = tmp("spectral-clustered");
    let st = radiant()
        .args([
            "bake",
            "--builtin",
            "cornell-box",
            "--hierarchy",
            "clustered",
            "--spectral",
            "--bands",
            "8",
            "--out",
        ])
        .arg(&clustered)
        .output()
        .expect("runs");
    assert!(
        st.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&st.stderr)
    );
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(clustered.join("report.json")).expect("report"),
    )
    .expect("json");
    assert_eq!(report["hierarchy"]["kind"], "clustered");
    assert_eq!(report["spectral"]["bands"], 8);
    assert_eq!(report["spectral"]["converged"], true);
    let mean = report["spectral"]["vs_path_traced_points"]["mean_rel"]
        .as_f64()
        .expect("mean_rel");
    assert!(mean.is_finite() && mean > 0.0 && mean < 0.5, "{mean}");
    // Spectral needs spectra: a scene file without --spectra is a clear error.
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/bad_inputs");
    let st = radiant()
        .arg("bake")
        .arg(dir.join("ok_no_emitters.gltf"))
        .arg("--spectral")
        .arg("--out")
        .arg(&out)
        .output()
        .expect("runs");
    assert!(!st.status.success());
    assert!(String::from_utf8_lossy(&st.stderr).contains("--spectra"));
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_checkpoint_lets_the_next_bake_skip_form_factors() {
    let out = tmp("ckpt");
    let ckpt = std::env::temp_dir().join(format!("radiant-cli-{}.ckpt", std::process::id()));
    let _ = std::fs::remove_file(&ckpt);
    let bake = || {
        radiant()
            .args(["bake", "--builtin", "cornell-box", "--patch-size", "0.3"])
            .arg("--checkpoint")
            .arg(&ckpt)
            .arg("--out")
            .arg(&out)
            .output()
            .expect("runs")
    };
    let first = bake();
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    assert!(!String::from_utf8_lossy(&first.stdout).contains("resumed"));
    assert!(ckpt.is_file());
    let surfaces_1 = std::fs::read_to_string(out.join("surfaces.csv")).expect("csv");
    let second = bake();
    assert!(
        second.status.success(),
        "{}",
        String::from_utf8_lossy(&second.stderr)
    );
    assert!(String::from_utf8_lossy(&second.stdout).contains("resumed from"));
    let surfaces_2 = std::fs::read_to_string(out.join("surfaces.csv")).expect("csv");
    let parse = |s: &str| -> Vec<f64> {
        s.lines()
            .skip(1)
            .flat_map(|l| {
                l.split(',')
                    .skip(2)
                    .map(|v| v.parse::<f64>().expect("number"))
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    for (a, b) in parse(&surfaces_1).iter().zip(parse(&surfaces_2)) {
        assert!((a - b).abs() <= 1e-3 * a.abs().max(1e-3), "{a} vs {b}");
    }
    // The clustered hierarchy refuses the per-triangle checkpoint (a typed "rebake"), bakes
    // afresh and writes its own (version 4), which the next clustered bake resumes from.
    let clustered = || {
        radiant()
            .args(["bake", "--builtin", "cornell-box", "--patch-size", "0.3"])
            .args(["--hierarchy", "clustered", "--checkpoint"])
            .arg(&ckpt)
            .arg("--out")
            .arg(&out)
            .output()
            .expect("runs")
    };
    let fourth = clustered();
    assert!(fourth.status.success());
    let stdout = String::from_utf8_lossy(&fourth.stdout);
    assert!(
        stdout.contains("not resuming") && stdout.contains("rebake"),
        "{stdout}"
    );
    let fifth = clustered();
    assert!(fifth.status.success());
    let stdout = String::from_utf8_lossy(&fifth.stdout);
    assert!(
        stdout.contains("resumed from") && stdout.contains("no links refined"),
        "{stdout}"
    );
    // A checkpoint of another scene is not used.
    std::fs::write(&ckpt, b"garbage").expect("write");
    let third = bake();
    assert!(third.status.success());
    assert!(String::from_utf8_lossy(&third.stdout).contains("not resuming"));
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_file(&ckpt);
}

#[test]
fn clustered_bake_reports_its_hierarchy_and_memory_limit_refuses() {
    let out = tmp("clustered");
    let st = radiant()
        .args([
            "bake",
            "--builtin",
            "cornell-box",
            "--hierarchy",
            "clustered",
            "--patch-size",
            "0.3",
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
    let stdout = String::from_utf8_lossy(&st.stdout);
    assert!(stdout.contains("clustered hierarchy:"), "{stdout}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["hierarchy"]["kind"], "clustered");
    assert_eq!(report["hierarchy"]["push"], "transfer");
    assert!(
        report["hierarchy"]["memory_counted_bytes"]
            .as_u64()
            .unwrap_or(0)
            > 0
    );
    assert!(out.join("surfaces.csv").is_file());
    let surfaces = std::fs::read_to_string(out.join("surfaces.csv")).expect("surfaces");

    // The old push, by the elements' normals alone: other light, reported.
    let normal = tmp("clustered_normal");
    let st = radiant()
        .args([
            "bake",
            "--builtin",
            "cornell-box",
            "--hierarchy",
            "clustered",
        ])
        .args(["--patch-size", "0.3", "--push-by-normal", "--out"])
        .arg(&normal)
        .output()
        .expect("runs");
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let read = |f: &str| std::fs::read_to_string(normal.join(f)).expect("output");
    let r: serde_json::Value = serde_json::from_str(&read("report.json")).expect("json");
    assert_eq!(r["hierarchy"]["push"], "normal");
    assert_ne!(read("surfaces.csv"), surfaces);

    // A budget far below the mesh: one line naming the limit, a non-zero exit, in no time.
    let st = radiant()
        .args([
            "bake",
            "--builtin",
            "cornell-box",
            "--hierarchy",
            "clustered",
            "--patch-size",
            "0.002",
            "--memory-limit",
            "8M",
            "--out",
        ])
        .arg(&out)
        .output()
        .expect("runs");
    assert!(!st.status.success());
    let stderr = String::from_utf8_lossy(&st.stderr);
    assert!(stderr.contains("memory limit of 8 MiB"), "{stderr}");
    // Options the clustered bake does not have are refused, not ignored.
    let st = radiant()
        .args([
            "bake",
            "--builtin",
            "cornell-box",
            "--hierarchy",
            "clustered",
            "--method",
            "southwell",
            "--out",
        ])
        .arg(&out)
        .output()
        .expect("runs");
    assert!(!st.status.success());
    assert!(String::from_utf8_lossy(&st.stderr).contains("--hierarchy triangles"));
}

#[test]
fn reference_writes_surfaces_points_image_and_a_report_the_bake_reads() {
    let out = tmp("reference");
    let points = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("assets/reference/cornell_points_rgb_mitsuba.csv");
    let points = points.display().to_string();
    // Probes in the box's free space: under the light facing it and facing the floor, and
    // facing a wall with a normal that is not unit.
    std::fs::create_dir_all(&out).expect("out");
    let probes = out.join("probes_in.csv");
    std::fs::write(
        &probes,
        "name,x,y,z,nx,ny,nz\nup,0.278,0.3,0.28,0,1,0\ndown,0.278,0.3,0.28,0,-1,0\nred wall,0.278,0.3,0.28,3,0,0\n",
    )
    .expect("probes");
    let probes = probes.display().to_string();
    let common = [
        "reference",
        "--builtin",
        "cornell-box",
        "--samples",
        "512",
        "--image",
        "32x24",
        "--points",
        &points,
        "--probes",
        &probes,
    ];
    let stdout = run_ok(&[&common[..], &["--threads", "1"]].concat(), &out);
    assert!(stdout.contains("stopped by samples"), "{stdout}");
    let surfaces = std::fs::read_to_string(out.join("surfaces.csv")).expect("surfaces.csv");
    let mut lines = surfaces.lines();
    assert_eq!(
        lines.next(),
        Some("surface,area,b_r,b_g,b_b,se_r,se_g,se_b,samples")
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 19);
    for r in &rows {
        let se: f64 = r[5].parse().expect("se");
        assert!(se > 0.0 && se.is_finite(), "{r:?}");
        assert_eq!(r[8], "512");
    }
    let pts = std::fs::read_to_string(out.join("points.csv")).expect("points.csv");
    assert_eq!(pts.lines().count(), 25, "a header and 24 points");
    let probes = std::fs::read_to_string(out.join("probes.csv")).expect("probes.csv");
    let mut lines = probes.lines();
    assert_eq!(
        lines.next(),
        Some("name,E_r,E_g,E_b,se_r,se_g,se_b,samples")
    );
    let e: Vec<(String, [f64; 3])> = lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let v = |i: usize| f[i].parse::<f64>().expect("number");
            assert_eq!(f[7], "512", "{l}");
            (f[0].to_string(), [v(1), v(2), v(3)])
        })
        .collect();
    assert_eq!(e.len(), 3);
    assert!(
        e.iter().flat_map(|p| p.1).all(|v| v.is_finite() && v > 0.0),
        "{e:?}"
    );
    // Facing the light is brighter than facing the floor; facing +x, the red wall (x = 0.556;
    // the green one is at x = 0) fills most of the hemisphere.
    assert!(e[0].1[0] > 2.0 * e[1].1[0], "{e:?}");
    assert!(e[2].1[0] > 1.5 * e[2].1[1], "the red wall: {e:?}");
    let img = image::open(out.join("image.exr"))
        .expect("image.exr")
        .to_rgb32f();
    assert_eq!((img.width(), img.height()), (32, 24));
    assert!(img.pixels().any(|p| p.0[0] > 1.0), "the light is in view");
    assert!(out.join("image_se.exr").is_file() && out.join("image.png").is_file());
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["surfaces"]["paths"], 19 * 512);
    assert_eq!(report["image"]["samples_per_pixel"], 512);
    assert_eq!(report["surfaces"]["stopped_by"], "samples");

    // The same sample count on two threads: the same bytes.
    let out2 = tmp("reference2");
    run_ok(&[&common[..], &["--threads", "2"]].concat(), &out2);
    for f in ["surfaces.csv", "points.csv", "probes.csv", "image.exr"] {
        assert_eq!(
            std::fs::read(out.join(f)).expect("1 thread"),
            std::fs::read(out2.join(f)).expect("2 threads"),
            "{f} differs between 1 and 2 threads"
        );
    }

    // The bake takes the file as its reference.
    let baked = tmp("reference-bake");
    let reference = out.join("surfaces.csv").display().to_string();
    let stdout = run_ok(
        &[
            "bake",
            "--builtin",
            "cornell-box",
            "--patch-size",
            "0.3",
            "--reference",
            &reference,
        ],
        &baked,
    );
    assert!(stdout.contains("error against"), "{stdout}");
    for d in [out, out2, baked] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn converge_on_a_scene_file_path_traces_its_reference() {
    let dir = tmp("converge-path");
    std::fs::create_dir_all(&dir).expect("dir");
    let scene = dir.join("box.gltf");
    std::fs::write(&scene, radiant::scene::CORNELL_BOX_GLTF).expect("write scene");
    let scene = scene.display().to_string();
    let out = dir.join("out");
    let coarse = ["--patch-size", "0.3", "--element-levels", "1"];
    let stdout = run_ok(
        &[
            &[
                "converge",
                &scene,
                "--methods",
                "jacobi",
                "--form-factors",
                "analytic",
            ][..],
            &coarse,
            &["--reference-error", "0.02"],
        ]
        .concat(),
        &out,
    );
    assert!(stdout.contains("path-traced"), "{stdout}");
    assert!(out.join("reference/surfaces.csv").is_file());
    let csv = std::fs::read_to_string(out.join("convergence.csv")).expect("csv");
    let last: Vec<&str> = csv.lines().last().expect("rows").split(',').collect();
    let mean: f64 = last[7].parse().expect("mean error");
    // A coarse bake against path-traced truth: a total error of a few per cent, not zero.
    assert!(mean > 0.002 && mean < 0.2, "{mean}");

    // The clustered curve: one whole bake per refinement threshold.
    let out = dir.join("clustered");
    run_ok(
        &[
            &[
                "converge",
                &scene,
                "--hierarchy",
                "clustered",
                "--form-factors",
                "analytic",
            ][..],
            &["--refinements", "0.32,0.04", "--reference-error", "0.02"],
        ]
        .concat(),
        &out,
    );
    let csv = std::fs::read_to_string(out.join("convergence.csv")).expect("csv");
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len(), 2, "{csv}");
    let err = |r: &Vec<&str>| r[8].parse::<f64>().expect("mean error");
    assert!(rows.iter().all(|r| r[0] == "clustered"));
    assert!(err(&rows[1]) < err(&rows[0]), "finer is closer: {csv}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bake_exports_binary_gltf_that_the_khronos_validator_accepts() {
    let out = tmp("export");
    std::fs::create_dir_all(&out).expect("dir");
    let glb = out.join("cornell.glb");
    let stdout = run_ok(
        &[
            "bake",
            "--builtin",
            "cornell-box",
            "--patch-size",
            "0.3",
            // Small pages, so the light map takes several: one image each in the file.
            "--texel-density",
            "100",
            "--lightmap-page",
            "64",
            "--export",
            glb.to_str().expect("utf-8 path"),
        ],
        &out,
    );
    assert!(stdout.contains("exported"), "{stdout}");
    let bytes = std::fs::read(&glb).expect("the .glb");
    assert_eq!(&bytes[..4], b"glTF");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["parameters"]["export"]["primitives"], 19);
    let lm = &report["parameters"]["lightmap"];
    let pages = lm["pages"].as_u64().expect("pages");
    assert!(pages > 1, "{lm}");
    assert_eq!(
        report["parameters"]["export"]["lightmap_textures"]
            .as_array()
            .expect("textures")
            .len() as u64,
        pages
    );
    // Each page in full range beside the .glb, KTX2 and EXR, named in report.json; the EXR
    // page equals its rows of lightmap.exr.
    let hdr = report["parameters"]["export"]["hdr_files"]
        .as_array()
        .expect("hdr_files");
    assert_eq!(hdr.len() as u64, 2 * pages);
    for p in 0..pages {
        assert!(out.join(format!("cornell_lightmap_{p}.ktx2")).is_file());
        let page = image::open(out.join(format!("cornell_lightmap_{p}.exr")))
            .expect("page's exr")
            .to_rgb32f();
        let all = image::open(out.join("lightmap.exr"))
            .expect("lightmap.exr")
            .to_rgb32f();
        for (x, y, px) in page.enumerate_pixels().step_by(37) {
            assert_eq!(
                px,
                all.get_pixel(x, y + 64 * p as u32),
                "page {p} at {x},{y}"
            );
        }
    }
    // lightmap.exr stacks the pages top to bottom.
    let exr = image::open(out.join("lightmap.exr")).expect("lightmap.exr");
    assert_eq!(
        (u64::from(exr.width()), u64::from(exr.height())),
        (64, 64 * pages)
    );
    // The Khronos validator, where npm put it (tools/test.sh installs it when npm exists).
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let modules = std::env::var_os("RADIANT_GLTF_VALIDATOR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("target/gltf-validator/node_modules"));
    let node = std::process::Command::new("node").arg("--version").output();
    if node.is_err() || !modules.join("gltf-validator").exists() {
        eprintln!(
            "not validated: no node or no gltf-validator in {} (npm install --prefix target/gltf-validator gltf-validator)",
            modules.display()
        );
        return;
    }
    let v = std::process::Command::new("node")
        .arg(root.join("tools/validate_gltf.js"))
        .arg(&glb)
        .env("NODE_PATH", &modules)
        .output()
        .expect("node runs");
    let text = String::from_utf8_lossy(&v.stdout);
    eprintln!("gltf-validator: {text}");
    let r: serde_json::Value = serde_json::from_str(text.trim()).expect("validator JSON");
    assert_eq!(r["errors"], 0, "{text}");
    assert!(v.status.success(), "{text}");
}

/// `bake --points`: `points.csv` holds what the renderer shows at each point (the light map `H`
/// as the GPU samples it, and `L = albedo × H`), and with `--reference-points` (here Mitsuba 3's
/// meters at the Cornell box's 24 points) `report.json` and the summary give the error. A
/// point on no surface, or one the reference lacks, fails before the bake, in one line.
#[test]
fn bake_points_answers_what_the_renderer_shows_against_a_path_tracer() {
    let out = tmp("bake-points");
    let mitsuba = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("assets/reference/cornell_points_rgb_mitsuba.csv")
        .display()
        .to_string();
    let stdout = run_ok(
        &[
            "bake",
            "--builtin",
            "cornell-box",
            "--points",
            &mitsuba,
            "--reference-points",
            &mitsuba,
        ],
        &out,
    );
    let csv = std::fs::read_to_string(out.join("points.csv")).expect("points.csv");
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("name,x,y,z,L_r,L_g,L_b,H_r,H_g,H_b"));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 24);
    let floor = rows
        .iter()
        .find(|r| r[0] == "floor_centre")
        .expect("floor_centre");
    let v: Vec<f64> = floor[1..]
        .iter()
        .map(|x| x.parse().expect("a number"))
        .collect();
    // Millimetres in, metres out.
    assert!(
        (v[0] - 0.2756).abs() < 1e-9 && (v[2] - 0.2796).abs() < 1e-9,
        "{v:?}"
    );
    for r in &rows {
        let v: Vec<f64> = r[4..]
            .iter()
            .map(|x| x.parse().expect("a number"))
            .collect();
        assert!(v.iter().all(|x| x.is_finite() && *x >= 0.0), "{r:?}");
        // The box has no textures: L / H is the surface's reflectance, under 1 (the light's
        // own points, which emit, are the exception).
        if !r[0].starts_with("light") {
            assert!((0..3).all(|c| v[c] < v[c + 3] && v[c] > 0.0), "{r:?}");
        }
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report"))
            .expect("json");
    let vs = &report["points"]["vs_reference"];
    let (median, mean, max, bias) = (
        vs["median_rel"].as_f64().expect("median"),
        vs["mean_rel"].as_f64().expect("mean"),
        vs["max_rel"].as_f64().expect("max"),
        vs["bias"].as_f64().expect("bias"),
    );
    assert_eq!(vs["points"].as_array().map(Vec::len), Some(24));
    assert!(median <= mean.max(median) && mean <= max, "{vs}");
    // Today's light map on the default bake (measured: see the README); generous, but a light
    // map in the wrong place, scaled or sampled off its texels is far outside it.
    assert!(mean < 0.04 && max < 0.2 && bias.abs() < 0.03, "{vs}");
    assert!(
        stdout.contains("light map at 24 points against") && stdout.contains("median"),
        "{stdout}"
    );

    // A point on no surface, and a reference without the asked points: one line, before the
    // bake (no report is written).
    let bad = tmp("bake-points-bad");
    std::fs::create_dir_all(&bad).expect("scratch");
    let off = bad.join("off.csv");
    std::fs::write(&off, "name,x,y,z,nx,ny,nz\nmid_air,0.25,0.25,0.25,0,1,0\n").expect("write");
    let other = bad.join("other.csv");
    std::fs::write(
        &other,
        "point,x,y,z,nx,ny,nz,L_r,L_g,L_b\nelsewhere,0.2756,0,0.2796,0,1,0,1,1,1\n",
    )
    .expect("write");
    for (args, says) in [
        (vec!["--points", off.to_str().expect("utf-8")], "'mid_air'"),
        (
            vec![
                "--points",
                &mitsuba,
                "--reference-points",
                other.to_str().expect("utf-8"),
            ],
            "no point 'floor_centre'",
        ),
    ] {
        let st = radiant()
            .args(["bake", "--builtin", "cornell-box", "--out"])
            .arg(bad.join("out"))
            .args(&args)
            .output()
            .expect("runs");
        let stderr = String::from_utf8_lossy(&st.stderr);
        assert!(!st.status.success(), "{args:?}");
        assert!(
            stderr.contains(says) && stderr.trim().lines().count() == 1,
            "{stderr}"
        );
        assert!(!bad.join("out/report.json").exists());
    }
}

/// The README's quick start has the two commands, and CI runs the second: no drift between
/// what a user is told and what CI does.
#[test]
fn the_readme_quick_start_is_what_ci_runs() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(root.join("README.md")).expect("README.md");
    let start = readme.find("## Quick start").expect("a quick start");
    let block = readme[start..]
        .split("```")
        .nth(1)
        .expect("a code block in the quick start");
    let commands: Vec<&str> = block
        .lines()
        .skip(1)
        .map(|l| l.split('#').next().unwrap_or("").trim())
        .filter(|l| !l.is_empty())
        .collect();
    assert_eq!(commands, ["cargo run --release", "bash tools/test.sh"]);
    let ci = std::fs::read_to_string(root.join(".ci/run")).expect(".ci/run");
    let run: Vec<&str> = ci
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .filter(|l| l.contains("tools/"))
        .collect();
    assert_eq!(run, ["exec bash tools/test.sh"], "{ci}");
    assert!(
        readme.lines().count() <= 250,
        "the README is for users: at most 250 lines"
    );
    let arch = std::fs::read_to_string(root.join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    assert!(
        arch.lines().count() <= 400,
        "ARCHITECTURE.md is a map: at most 400 lines"
    );
}

/// `--final-gather`: the light map gathered per texel, its settings in the report, and a bad
/// setting refused before any work.
#[test]
fn bake_final_gather_is_reported_and_bad_settings_are_refused() {
    let out = tmp("final-gather");
    let args = [
        "bake",
        "--builtin",
        "cornell-box",
        "--final-gather",
        "3",
        "--gather-stride",
        "1",
    ];
    let st = radiant()
        .args(args)
        .arg("--out")
        .arg(&*out)
        .env_remove("RUST_LOG")
        .env("RADIANT_PROGRESS_SECONDS", "0")
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&st.stderr);
    assert!(st.status.success(), "{stderr}");
    // A long gather says how far it is, also without a terminal.
    assert!(stderr.contains("final gather progress"), "{stderr}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report"))
            .expect("json");
    let gather = &report["parameters"]["lightmap"]["final_gather"];
    assert_eq!(gather["rays_per_gather"], 9);
    assert_eq!(gather["stride"], 1);
    assert_eq!(gather["radius"], 2);
    assert_eq!(gather["element_passes"], 0);
    // Off by default: the smooth field, no gather in the report.
    let plain = tmp("final-gather-off");
    run_ok(&["bake", "--builtin", "cornell-box"], &plain);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(plain.join("report.json")).expect("report"))
            .expect("json");
    assert!(report["parameters"]["lightmap"]["final_gather"].is_null());
    for bad in [["--final-gather", "65"], ["--gather-stride", "0"]] {
        let st = radiant()
            .args(["bake", "--builtin", "cornell-box", "--out"])
            .arg(&*out)
            .args(bad)
            .output()
            .expect("runs");
        assert!(!st.status.success(), "{bad:?} accepted");
        let stderr = String::from_utf8_lossy(&st.stderr);
        assert!(stderr.contains(bad[0]), "{bad:?}: {stderr}");
    }
}

/// `converge --light-maps`: one bake, its light map composed at each final-gather setting and
/// measured over the surfaces and at the points, against time.
#[test]
fn converge_measures_light_maps_against_time() {
    let out = tmp("converge-light-maps");
    let points = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("assets/reference/cornell_points_rgb_mitsuba.csv");
    let points = points.display().to_string();
    let stdout = run_ok(
        &[
            "converge",
            "--builtin",
            "cornell-box",
            "--light-maps",
            "0,2",
            "--points",
            &points,
            "--reference-points",
            &points,
            "--gather-stride",
            "1",
        ],
        &out,
    );
    assert!(stdout.contains("gather  2"), "{stdout}");
    let csv = std::fs::read_to_string(out.join("lightmap_convergence.csv")).expect("csv");
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len(), 2, "{csv}");
    assert_eq!((rows[0][0], rows[1][0]), ("smooth", "gather"));
    // strata, stride, radius (at least the stride), element passes.
    assert_eq!(&rows[1][1..5], &["2", "1", "2", "0"]);
    // The sun's bounce taken where the gather's rays land (the default); nothing for the
    // smooth field.
    assert_eq!((rows[0][13], rows[1][13]), ("", "true"));
    for r in &rows {
        let t: f64 = r[7].parse().expect("t_s");
        let surfaces: f64 = r[8].parse().expect("surfaces' error");
        let points: f64 = r[11].parse().expect("points' error");
        assert!(t > 0.0 && surfaces < 0.02 && points < 0.2, "{r:?}");
    }
    assert!(out.join("lightmap_convergence.png").is_file());
}

/// `bake --probes`: what a dynamic mesh at each point receives from the irradiance volume, in
/// the layout `reference --probes` writes, measured against it.
#[test]
fn bake_probes_writes_the_volumes_light_and_its_error_against_the_path_tracer() {
    let dir = tmp("probes");
    std::fs::create_dir_all(&dir).expect("dir");
    let probes = dir.join("probes_in.csv");
    std::fs::write(
        &probes,
        "name,x,y,z,nx,ny,nz\nup,0.278,0.3,0.28,0,1,0\ndown,0.278,0.3,0.28,0,-1,0\n\
         red wall,0.4,0.45,0.2,1,0,0\ngreen wall,0.1,0.45,0.2,-1,0,0\n",
    )
    .expect("probes");
    let probes = probes.display().to_string();
    let reference = dir.join("reference");
    run_ok(
        &[
            "reference",
            "--builtin",
            "cornell-box",
            "--no-surfaces",
            "--samples",
            "16384",
            "--probes",
            &probes,
        ],
        &reference,
    );
    let baked = dir.join("bake");
    let ref_csv = reference.join("probes.csv").display().to_string();
    let stdout = run_ok(
        &[
            "bake",
            "--builtin",
            "cornell-box",
            "--probes",
            &probes,
            "--reference-probes",
            &ref_csv,
        ],
        &baked,
    );
    assert!(stdout.contains("probes: a volume of 17×17×17"), "{stdout}");
    let csv = std::fs::read_to_string(baked.join("probes.csv")).expect("probes.csv");
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("name,E_r,E_g,E_b"));
    let rows: Vec<Vec<String>> = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    assert_eq!(rows.len(), 4);
    let e = |r: &Vec<String>, c: usize| r[c].parse::<f64>().expect("number");
    assert!(
        e(&rows[2], 1) > 1.5 * e(&rows[2], 2),
        "facing the red wall: {rows:?}"
    );
    assert!(
        e(&rows[3], 2) > 1.5 * e(&rows[3], 1),
        "facing the green wall: {rows:?}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(baked.join("report.json")).expect("report"))
            .expect("json");
    let vs = &report["probes"]["vs_reference"];
    let mean = vs["mean_rel"].as_f64().expect("mean");
    assert!(mean < 0.03, "{vs}");
    assert_eq!(report["probes"]["volume"]["probes"], 17 * 17 * 17);
    // A reference that lacks a probe is refused before the bake, in one line.
    std::fs::write(dir.join("short.csv"), "name,E_r,E_g,E_b\nup,1,1,1\n").expect("short");
    let st = radiant()
        .args(["bake", "--builtin", "cornell-box", "--probes", &probes])
        .arg("--reference-probes")
        .arg(dir.join("short.csv"))
        .arg("--out")
        .arg(dir.join("refused"))
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&st.stderr);
    assert_eq!(st.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("no probe 'down'") && stderr.lines().count() == 1,
        "{stderr}"
    );
}
