//! Writing bake outputs. Every file is written to a temporary name in the same directory and
//! renamed into place, so a crash never leaves a half-written output.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use radiant::radiosity::lightmap::LightMap;
use radiant::radiosity::metrics::{ErrorStats, SurfaceMean};
use radiant::radiosity::{BakeReport, BakeResult};
use radiant::scene::Scene;
use serde_json::{Value, json};

/// Writes `bytes` to `path` atomically (temporary file, then rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .context("output path has no file name")?
        .to_string_lossy();
    let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    let write = || -> std::io::Result<()> {
        use std::io::Write as _;
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        // On disk before the rename, so a crash leaves the old file or the new one, never half.
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    };
    write().map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        anyhow::anyhow!("cannot write {}: {e}", path.display())
    })
}

/// Creates the output directory.
pub fn ensure_dir(dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create output directory {}", dir.display()))
}

/// `surfaces.csv`: `surface,area,b_r,b_g,b_b`.
pub fn surfaces_csv(surfaces: &[SurfaceMean]) -> String {
    let mut s = String::from("surface,area,b_r,b_g,b_b\n");
    for m in surfaces {
        let _ = writeln!(
            s,
            "{},{:.9e},{:.9e},{:.9e},{:.9e}",
            csv_name(&m.name),
            m.area,
            m.mean[0],
            m.mean[1],
            m.mean[2]
        );
    }
    s
}

pub fn csv_name(name: &str) -> String {
    if name.contains([',', '"', '\n']) {
        format!("\"{}\"", name.replace('"', "\"\""))
    } else {
        name.to_string()
    }
}

/// `patches.csv`: one row per element, world units.
pub fn patches_csv(scene: &Scene, result: &BakeResult) -> String {
    let mesh = &result.mesh;
    let sys = &result.system;
    let mut s = String::with_capacity(mesh.element_count() * 200);
    s.push_str("id,surface,cx,cy,cz,nx,ny,nz,area,rho_r,rho_g,rho_b,e_r,e_g,e_b,b_r,b_g,b_b\n");
    let s2 = mesh.frame.scale * mesh.frame.scale;
    for (i, &id) in mesh.leaves.iter().enumerate() {
        let n = &mesh.nodes[id as usize];
        let surface = &scene.surfaces[mesh.root_surface[n.root as usize] as usize];
        let c = mesh.frame.to_world(n.centroid);
        let (r, e, b) = (sys.rho[i], surface.emission, result.radiosity[i]);
        let _ = writeln!(
            s,
            "{i},{},{:.7},{:.7},{:.7},{:.6},{:.6},{:.6},{:.6e},{},{},{},{},{},{},{:.6e},{:.6e},{:.6e}",
            csv_name(&surface.name),
            c.x,
            c.y,
            c.z,
            n.normal.x,
            n.normal.y,
            n.normal.z,
            n.area * s2,
            r[0],
            r[1],
            r[2],
            e[0],
            e[1],
            e[2],
            b[0],
            b[1],
            b[2]
        );
    }
    s
}

/// Error statistics as JSON.
pub fn error_json(e: &ErrorStats) -> Value {
    json!({ "rel_rms_error": e.rel_rms, "mean_rel_error": e.mean_rel, "max_rel_error": e.max_rel })
}

/// `report.json`.
pub fn report_json(
    source: &str,
    r: &BakeReport,
    import_s: f64,
    total_s: f64,
    reference: Option<(&str, &ErrorStats)>,
    extra: Value,
) -> Value {
    let timeline: Vec<Value> = r
        .timeline
        .iter()
        .map(|p| json!({ "t_s": p.t_s, "iterations": p.iterations, "residual": finite(p.residual), "unshot_fraction": finite(p.unshot_fraction) }))
        .collect();
    let mut v = json!({
        "scene": source,
        "patches": r.patches,
        "elements": r.elements,
        "links": r.links,
        "link_bytes": r.link_bytes,
        "method": r.solver.name(),
        "form_factors": r.form_factors.name(),
        "seconds": {
            "import": import_s,
            "meshing": r.times.meshing,
            "visibility": r.times.visibility,
            "direct_light": r.times.direct_light,
            "form_factors": r.times.form_factors,
            "solve": r.times.solve,
            "total": total_s,
        },
        "iterations": r.iterations,
        "converged": r.converged,
        "residual": finite(r.residual),
        "unshot_fraction": finite(r.unshot_fraction),
        "has_emitters": r.has_emitters,
        "timeline": timeline,
        "warnings": r.warnings,
        "parameters": extra,
    });
    if let Some((name, e)) = reference {
        v["reference"] = json!({ "source": name, "error": error_json(e) });
    }
    v["hierarchy"] = match &r.clusters {
        Some(c) => json!({
            "kind": "clustered",
            "clusters": c.clusters,
            "cluster_receiver_links": c.cluster_receiver_links,
            "cluster_source_links": c.cluster_source_links,
            "form_factors_computed": c.form_factors,
            "links_per_element": r.links as f64 / r.elements.max(1) as f64,
            "refinement_asked": c.refinement_asked,
            "refinement_used": c.refinement_used,
            "memory_limit_bytes": c.memory_limit,
            "memory_counted_bytes": c.memory_estimate,
            "enclosed_elements": c.enclosed,
            "partly_enclosed_elements": c.partly_enclosed,
            "push": if c.transfer { "transfer" } else { "normal" },
        }),
        None => json!({ "kind": "triangles" }),
    };
    v
}

/// JSON has no NaN or infinity: such values become null.
fn finite(x: f64) -> Value {
    if x.is_finite() { json!(x) } else { Value::Null }
}

/// Writes `lightmap.exr` (linear f32) and `lightmap.png` (a tone-mapped preview): a light map
/// of several pages is one image of its pages stacked top to bottom (`width × height·pages`).
pub fn write_lightmaps(dir: &Path, map: &LightMap) -> anyhow::Result<()> {
    let (width, height) = (map.width, map.height * map.pages.max(1));
    // The two encoders, each on one thread, side by side.
    let (exr, png) = rayon::join(
        || -> anyhow::Result<Vec<u8>> {
            let data: Vec<f32> = map
                .texels
                .iter()
                .flat_map(|t| t.map(|v| if v.is_finite() { v.max(0.0) } else { 0.0 }))
                .collect();
            let img =
                image::Rgb32FImage::from_raw(width, height, data).context("light-map size")?;
            let mut exr = std::io::Cursor::new(Vec::new());
            image::DynamicImage::ImageRgb32F(img)
                .write_to(&mut exr, image::ImageFormat::OpenExr)
                .context("encoding the EXR light map")?;
            Ok(exr.into_inner())
        },
        || preview_png(width, height, &map.texels),
    );
    write_atomic(&dir.join("lightmap.exr"), &exr?)?;
    write_atomic(&dir.join("lightmap.png"), &png?)
}

/// A tone-mapped sRGB PNG of linear RGB texels (row-major, top row first): the mean of the lit
/// texels maps to mid grey, then ACES.
pub fn preview_png(width: u32, height: u32, texels: &[[f32; 3]]) -> anyhow::Result<Vec<u8>> {
    use rayon::prelude::*;
    // Summed in fixed chunks, then in order: the same bytes whatever the thread count.
    let (sum, lit) = texels
        .par_chunks(1 << 14)
        .map(|c| {
            c.iter()
                .map(|t| radiant::color::luminance(t.map(f64::from)))
                .filter(|&l| l > 0.0 && l.is_finite())
                .fold((0.0, 0u64), |(s, n), l| (s + l, n + 1))
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((0.0f64, 0u64), |(s, n), (cs, cn)| (s + cs, n + cn));
    let mean = if lit == 0 { 1.0 } else { sum / lit as f64 };
    let exposure = if mean > 0.0 { 0.18 / mean } else { 1.0 };
    let mut png = image::RgbImage::new(width, height);
    let row = (width as usize * 3).max(1);
    png.par_chunks_mut(row)
        .zip(texels.par_chunks(width.max(1) as usize))
        .for_each(|(out, texels)| {
            for (p, t) in out.chunks_exact_mut(3).zip(texels) {
                let c =
                    radiant::color::Tonemap::AcesFitted.apply(t.map(|v| f64::from(v) * exposure));
                p.copy_from_slice(&c.map(radiant::color::linear_to_srgb8));
            }
        });
    let mut bytes = std::io::Cursor::new(Vec::new());
    png.write_to(&mut bytes, image::ImageFormat::Png)
        .context("encoding a PNG preview")?;
    Ok(bytes.into_inner())
}

/// Linear RGB texels (row-major, top row first) as an OpenEXR file (32-bit float RGBA).
pub fn exr_bytes(width: u32, height: u32, texels: &[[f32; 3]]) -> anyhow::Result<Vec<u8>> {
    let data: Vec<f32> = texels
        .iter()
        .flat_map(|t| [t[0], t[1], t[2], 1.0])
        .collect();
    let img = image::Rgba32FImage::from_raw(width, height, data)
        .context("EXR: texel count does not match the size")?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::OpenExr)
        .context("encoding an EXR image")?;
    Ok(bytes.into_inner())
}
