//! `radiant bake --points`: what the renderer shows at the user's surface points
//! (`radiant::radiosity::points`), written to `points.csv`, and measured against a path-traced
//! `points.csv` (`--reference-points`).

use std::fmt::Write as _;
use std::path::Path;

use glam::DVec3;
use radiant::radiosity::lightmap::LightMap;
use radiant::radiosity::metrics::{self, PointComparison, PointReference, PointSpec};
use radiant::radiosity::points::{self as shown, ShownPoint};
use radiant::scene::Scene;
use radiant::scene::atlas::Atlas;
use serde_json::json;

use crate::common::read_text;
use crate::output::csv_name;

/// Millimetres to scene units for a points file in the Mitsuba layout (glTF is in metres).
const MM: f64 = 1e-3;

/// The points asked for, located on the scene before the bake, and the reference they are
/// measured against.
pub(crate) struct AskedPoints {
    file: String,
    points: Vec<PointSpec>,
    located: Vec<(u32, DVec3)>,
    reference: Option<(String, Vec<PointReference>)>,
}

/// Reads `--points` and `--reference-points` and locates every point on `scene`, so that a
/// bad file, a point off every surface or a point the reference lacks fails before the bake.
pub(crate) fn read(
    scene: &Scene,
    points: &Path,
    reference: Option<&Path>,
) -> anyhow::Result<AskedPoints> {
    let specs = metrics::parse_point_positions(&read_text(points, "--points")?, MM)
        .map_err(|e| anyhow::anyhow!("--points {}: {e}", points.display()))?;
    let located = shown::locate_all(scene, &specs)
        .map_err(|e| anyhow::anyhow!("--points {}: {e}", points.display()))?;
    let reference = match reference {
        None => None,
        Some(path) => {
            let rows = metrics::parse_point_csv(&read_text(path, "--reference-points")?, MM)
                .map_err(|e| anyhow::anyhow!("--reference-points {}: {e}", path.display()))?;
            if let Some(p) = specs
                .iter()
                .find(|p| !rows.iter().any(|r| r.name == p.name))
            {
                anyhow::bail!(
                    "--reference-points {}: no point '{}' (it names the points of --points by their first column)",
                    path.display(),
                    p.name
                );
            }
            Some((path.display().to_string(), rows))
        }
    };
    Ok(AskedPoints {
        file: points.display().to_string(),
        points: specs,
        located,
        reference,
    })
}

/// What the points came to: the values and, with a reference, the comparison.
pub(crate) struct PointsResult {
    comparison: Option<(String, PointComparison)>,
    json: serde_json::Value,
}

/// Samples the light map at the points, writes `out/points.csv` and compares with the
/// reference.
pub(crate) fn write(
    asked: &AskedPoints,
    scene: &Scene,
    atlas: &Atlas,
    map: &LightMap,
    out: &Path,
) -> anyhow::Result<PointsResult> {
    let values = shown::shown_at(scene, atlas, map, &asked.located)?;
    crate::output::write_atomic(
        &out.join("points.csv"),
        points_csv(&asked.points, &values).as_bytes(),
    )?;
    let comparison = compare(asked, &values)?;
    let mut json = json!({ "file": asked.file, "count": values.len(), "written": "points.csv" });
    if let Some((name, c)) = &comparison {
        let per_point: Vec<serde_json::Value> = c
            .points
            .iter()
            .map(|p| json!({ "point": p.name, "ours": p.ours, "reference": p.reference, "relative_error": p.rel, "signed_error": p.signed }))
            .collect();
        json["vs_reference"] = json!({
            "reference": name,
            "median_rel": c.median_rel,
            "mean_rel": c.mean_rel,
            "max_rel": c.max_rel,
            "bias": c.bias,
            "points": per_point,
        });
    }
    Ok(PointsResult { comparison, json })
}

/// The points' `values` against the reference, where one was given.
fn compare(
    asked: &AskedPoints,
    values: &[ShownPoint],
) -> anyhow::Result<Option<(String, PointComparison)>> {
    let Some((name, rows)) = &asked.reference else {
        return Ok(None);
    };
    let ours: Vec<PointReference> = rows
        .iter()
        .filter(|r| asked.points.iter().any(|p| p.name == r.name))
        .cloned()
        .collect();
    let c = metrics::compare_points_with(&ours, None, |r| {
        let k = asked.points.iter().position(|p| p.name == r.name)?;
        Some(values[k].l)
    })?;
    Ok(Some((name.clone(), c)))
}

/// What the renderer shows of `map` at the points, against the reference (`None` without one):
/// `radiant converge --light-maps`.
pub(crate) fn measure(
    asked: &AskedPoints,
    scene: &Scene,
    atlas: &Atlas,
    map: &LightMap,
) -> anyhow::Result<Option<PointComparison>> {
    let values = shown::shown_at(scene, atlas, map, &asked.located)?;
    Ok(compare(asked, &values)?.map(|(_, c)| c))
}

impl PointsResult {
    /// The part of `report.json`.
    pub(crate) fn json(&self) -> &serde_json::Value {
        &self.json
    }

    /// The summary's line, where a reference was given.
    pub(crate) fn summary(&self) -> Option<String> {
        let (name, c) = self.comparison.as_ref()?;
        let worst = c.points.iter().max_by(|a, b| a.rel.total_cmp(&b.rel))?;
        Some(format!(
            "light map at {} points against {name}: median {:.2} %, mean {:.2} %, worst {:.2} % ({}), bias {:+.2} %",
            c.points.len(),
            c.median_rel * 100.0,
            c.mean_rel * 100.0,
            c.max_rel * 100.0,
            worst.name,
            c.bias * 100.0
        ))
    }
}

/// `points.csv`: `name,x,y,z,L_r,L_g,L_b,H_r,H_g,H_b`, the point as asked (scene units).
fn points_csv(points: &[PointSpec], values: &[ShownPoint]) -> String {
    let mut s = String::from("name,x,y,z,L_r,L_g,L_b,H_r,H_g,H_b\n");
    for (p, v) in points.iter().zip(values) {
        let _ = writeln!(
            s,
            "{},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e}",
            csv_name(&p.name),
            p.position.x,
            p.position.y,
            p.position.z,
            v.l[0],
            v.l[1],
            v.l[2],
            v.h[0],
            v.h[1],
            v.h[2]
        );
    }
    s
}
