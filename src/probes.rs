//! `radiant bake --probes FILE.csv`: what a dynamic mesh at each probe point would receive from
//! the irradiance volume baked with the level (`radiant_probes`), in the layout `radiant
//! reference --probes` writes, and with `--reference-probes` its error against it.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use radiant::probes::{ProbeParams, ProbeVolume, Solved, VolumeParams};
use radiant::radiosity::BakeResult;
use radiant::radiosity::metrics::{self, PointSpec};
use radiant::scene::Scene;
use serde_json::{Value, json};

use crate::common::read_text;
use crate::output::{csv_name, write_atomic};

/// Irradiance by probe name.
type Irradiance = Vec<(String, [f64; 3])>;

/// `--probes` and `--reference-probes`, read before the bake.
pub(crate) struct AskedProbes {
    probes: Vec<PointSpec>,
    /// The reference's file and its irradiance by probe name.
    reference: Option<(String, Irradiance)>,
}

/// Reads `--probes` (`name,x,y,z,nx,ny,nz`, scene units) and `--reference-probes` (a
/// `probes.csv` of `radiant reference`), which must name every probe.
pub(crate) fn read(probes: &Path, reference: Option<&Path>) -> anyhow::Result<AskedProbes> {
    let specs = metrics::parse_point_positions(&read_text(probes, "--probes")?, 1e-3)
        .map_err(|e| anyhow::anyhow!("--probes {}: {e}", probes.display()))?;
    let reference = match reference {
        None => None,
        Some(path) => {
            let rows = parse_irradiance(&read_text(path, "--reference-probes")?)
                .map_err(|e| anyhow::anyhow!("--reference-probes {}: {e}", path.display()))?;
            if let Some(p) = specs.iter().find(|p| !rows.iter().any(|r| r.0 == p.name)) {
                anyhow::bail!(
                    "--reference-probes {}: no probe '{}' (it names the probes of --probes by their first column)",
                    path.display(),
                    p.name
                );
            }
            Some((path.display().to_string(), rows))
        }
    };
    Ok(AskedProbes {
        probes: specs,
        reference,
    })
}

/// `name,E_r,E_g,E_b[,...]` rows.
fn parse_irradiance(text: &str) -> anyhow::Result<Irradiance> {
    let mut lines = text
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'));
    let header: Vec<&str> = lines
        .next()
        .ok_or_else(|| anyhow::anyhow!("empty"))?
        .split(',')
        .map(str::trim)
        .collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .ok_or_else(|| anyhow::anyhow!("no column {name}"))
    };
    let cols = [col("E_r")?, col("E_g")?, col("E_b")?];
    let mut rows = Vec::new();
    for (k, line) in lines.enumerate() {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let e = cols.map(|c| f.get(c).and_then(|v| v.parse::<f64>().ok()));
        let [Some(r), Some(g), Some(b)] = e else {
            anyhow::bail!("row {}: E_r, E_g, E_b are not numbers", k + 2);
        };
        anyhow::ensure!(
            [r, g, b].iter().all(|v| v.is_finite() && *v >= 0.0),
            "row {}: irradiance negative or not finite",
            k + 2
        );
        rows.push((f[0].to_string(), [r, g, b]));
    }
    anyhow::ensure!(!rows.is_empty(), "no rows");
    Ok(rows)
}

/// The irradiance volume over `result`'s solution of `scene` (probes `spacing` scene units
/// apart, or the default), with the solution's rays it read.
pub(crate) fn bake_volume(
    scene: &Scene,
    result: &BakeResult,
    spacing: Option<f64>,
) -> (Solved, ProbeVolume) {
    let solved = Solved::new(scene, result);
    let volume = {
        let baker = solved.baker(scene, &result.mesh, ProbeParams::default());
        let params = VolumeParams {
            spacing,
            ..VolumeParams::default()
        };
        ProbeVolume::bake(&baker, &params)
    };
    (solved, volume)
}

/// `--dynamic NODE`: marks the surfaces of each named glTF node dynamic (`NODE`, or `NODE#k`
/// for a mesh's k-th primitive), as `{"radiant": {"dynamic": true}}` in its extras would;
/// returns how many surfaces it marked. A name that matches no node is an error that lists
/// some that exist.
pub(crate) fn mark_dynamic(scene: &mut Scene, nodes: &[String]) -> anyhow::Result<usize> {
    let mut marked = 0;
    for node in nodes {
        let mut found = false;
        for s in &mut scene.surfaces {
            let base = s.name.split_once('#').map_or(s.name.as_str(), |(b, _)| b);
            if s.name == *node || base == node {
                found |= true;
                if !s.dynamic {
                    s.dynamic = true;
                    marked += 1;
                }
            }
        }
        if !found {
            let mut names: Vec<&str> = scene
                .surfaces
                .iter()
                .map(|s| s.name.split_once('#').map_or(s.name.as_str(), |(b, _)| b))
                .collect();
            names.dedup();
            let shown = names
                .iter()
                .take(12)
                .copied()
                .collect::<Vec<_>>()
                .join(", ");
            anyhow::bail!(
                "--dynamic {node:?}: no node of that name (the scene's nodes include: {shown}{})",
                if names.len() > 12 { ", ..." } else { "" }
            );
        }
    }
    Ok(marked)
}

/// What `--probes` measured, before `probes.csv` is written.
pub(crate) struct Measured {
    /// `probes.csv`.
    csv: String,
    /// The report's `probes`.
    pub(crate) json: Value,
    /// The summary's line.
    pub(crate) summary: String,
}

impl Measured {
    /// Writes `probes.csv` in `out`.
    pub(crate) fn write(&self, out: &Path) -> anyhow::Result<()> {
        write_atomic(&out.join("probes.csv"), self.csv.as_bytes())
    }
}

/// Bakes the volume over `result` (with `spacing`, scene units, or the default) and reads it at
/// the asked points: `probes.csv`, report.json's `probes` and the summary line.
pub(crate) fn measure(
    asked: &AskedProbes,
    scene: &Scene,
    result: &BakeResult,
    spacing: Option<f64>,
) -> Measured {
    let t0 = Instant::now();
    let (solved, volume) = bake_volume(scene, result, spacing);
    let bake_s = t0.elapsed().as_secs_f64();
    let values: Vec<[f64; 3]> = asked
        .probes
        .iter()
        .map(|p| volume.irradiance_world(p.position, p.normal, Some(&solved.vis)))
        .collect();
    let mut csv = String::from("name,E_r,E_g,E_b\n");
    for (p, e) in asked.probes.iter().zip(&values) {
        let _ = writeln!(
            csv,
            "{},{:.9e},{:.9e},{:.9e}",
            csv_name(&p.name),
            e[0],
            e[1],
            e[2]
        );
    }
    let spacing = volume.step * result.mesh.frame.scale;
    let mut json = json!({
        "count": asked.probes.len(),
        "volume": {
            "dims": volume.dims,
            "probes": volume.probes.len(),
            "inside": volume.inside(),
            "spacing": spacing,
            "bytes": volume.probes.iter().map(|p| {
                std::mem::size_of_val(p) + 4 * (p.lights.len() + p.emitters.len())
            }).sum::<usize>(),
            "seconds": bake_s,
        },
        "units": "irradiance E, W/m² in the scene's emission units",
    });
    let mut summary = format!(
        "probes: a volume of {}×{}×{} ({} inside geometry, {spacing:.3} apart) in {bake_s:.2} s; wrote probes.csv",
        volume.dims[0],
        volume.dims[1],
        volume.dims[2],
        volume.inside()
    );
    if let Some((file, rows)) = &asked.reference {
        let mut errors: Vec<f64> = asked
            .probes
            .iter()
            .zip(&values)
            .map(|(p, e)| {
                let r = rows
                    .iter()
                    .find(|r| r.0 == p.name)
                    .map_or([0.0; 3], |r| r.1);
                let sum: f64 = r.iter().sum();
                let d: f64 = (0..3).map(|c| (e[c] - r[c]).abs()).sum();
                if sum > 0.0 { d / sum } else { d }
            })
            .collect();
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        errors.sort_by(f64::total_cmp);
        let (median, worst) = (errors[errors.len() / 2], errors[errors.len() - 1]);
        json["vs_reference"] = json!({
            "file": file,
            "median_rel": median,
            "mean_rel": mean,
            "max_rel": worst,
            "measure": "Σ|E − ref| / Σ ref over RGB, per probe",
        });
        let _ = write!(
            summary,
            "; against {file}: median {:.2} %, mean {:.2} %, worst {:.2} %",
            100.0 * median,
            100.0 * mean,
            100.0 * worst
        );
    }
    Measured { csv, json, summary }
}
