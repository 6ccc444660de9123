//! Error metrics: per-surface means, comparison against a reference, and reference files.
//!
//! Against a per-surface reference (total error, discretisation included) the metrics are over
//! surfaces, area-weighted, emitters excluded (their radiosity is their emission):
//! - `mean_rel`: `Σ_s A_s mean_c |B_sc − R_sc| / R_sc / Σ_s A_s`;
//! - `max_rel`: `max_{s,c} |B_sc − R_sc| / R_sc`;
//! - `rel_rms`: `sqrt(Σ_s A_s Σ_c (B_sc − R_sc)² / Σ_s A_s Σ_c R_sc²)`.
//!
//! Against the direct solve on the same mesh (solver error) the same formulas run over elements,
//! with `R` floored at 1e-3 of the mean so that unlit elements do not divide by zero.

use radiant_scene::Surface;

use crate::BakeError;
use crate::mesh::Mesh;
use crate::system::Rgb;

/// Area-weighted mean radiosity of one surface.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceMean {
    /// The surface name.
    pub name: String,
    /// Area in world units².
    pub area: f64,
    /// Mean radiosity (emissive units).
    pub mean: Rgb,
    /// Whether the surface emits.
    pub emitter: bool,
}

/// Per-surface area-weighted means of per-element radiosity.
pub fn surface_means(surfaces: &[Surface], mesh: &Mesh, b: &[Rgb]) -> Vec<SurfaceMean> {
    let mut acc = vec![(0.0, [0.0; 3]); surfaces.len()];
    for (i, &id) in mesh.leaves.iter().enumerate() {
        let node = &mesh.nodes[id as usize];
        let s = mesh.root_surface[node.root as usize] as usize;
        acc[s].0 += node.area;
        for c in 0..3 {
            acc[s].1[c] += node.area * b[i][c];
        }
    }
    let s2 = mesh.frame.scale * mesh.frame.scale;
    surfaces
        .iter()
        .zip(acc)
        .filter(|(_, (a, _))| *a > 0.0)
        .map(|(s, (a, m))| SurfaceMean {
            name: s.name.clone(),
            area: a * s2,
            mean: m.map(|v| v / a),
            emitter: s.is_emitter(),
        })
        .collect()
}

/// Errors against a reference.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ErrorStats {
    /// Area-weighted relative RMS.
    pub rel_rms: f64,
    /// Area-weighted mean relative error.
    pub mean_rel: f64,
    /// Largest relative error.
    pub max_rel: f64,
}

fn stats<'a>(items: impl Iterator<Item = (f64, &'a Rgb, &'a Rgb)>, floor: f64) -> ErrorStats {
    let (mut area, mut num, mut den, mut mean, mut max) = (0.0, 0.0, 0.0, 0.0, 0.0f64);
    for (a, b, r) in items {
        area += a;
        let mut m = 0.0;
        for c in 0..3 {
            let d = b[c] - r[c];
            num += a * d * d;
            den += a * r[c] * r[c];
            let rel = d.abs() / r[c].abs().max(floor);
            m += rel / 3.0;
            max = max.max(rel);
        }
        mean += a * m;
    }
    ErrorStats {
        rel_rms: if den > 0.0 { (num / den).sqrt() } else { 0.0 },
        mean_rel: if area > 0.0 { mean / area } else { 0.0 },
        max_rel: max,
    }
}

/// Errors of per-surface means against a per-surface reference, emitters excluded. Surfaces
/// missing from the reference are skipped; it is an error if none match.
pub fn compare_surfaces(
    got: &[SurfaceMean],
    reference: &[(String, Rgb)],
) -> Result<ErrorStats, BakeError> {
    let pairs: Vec<(f64, &Rgb, &Rgb)> = got
        .iter()
        .filter(|s| !s.emitter)
        .filter_map(|s| {
            reference
                .iter()
                .find(|(n, _)| *n == s.name)
                .map(|(_, r)| (s.area, &s.mean, r))
        })
        .collect();
    if pairs.is_empty() {
        return Err(BakeError::Reference(
            "no surface of the scene is in the reference".into(),
        ));
    }
    Ok(stats(pairs.into_iter(), 1e-12))
}

/// Errors of per-element radiosity against a per-element reference (same mesh).
pub fn compare_elements(area: &[f64], got: &[Rgb], reference: &[Rgb]) -> ErrorStats {
    let total: f64 = area.iter().sum();
    let mean_r = reference
        .iter()
        .zip(area)
        .map(|(r, a)| a * (r[0] + r[1] + r[2]) / 3.0)
        .sum::<f64>()
        / total.max(f64::MIN_POSITIVE);
    stats(
        area.iter()
            .zip(got)
            .zip(reference)
            .map(|((a, b), r)| (*a, b, r)),
        (1e-3 * mean_r).max(f64::MIN_POSITIVE),
    )
}

/// Parses a per-surface reference CSV into (surface, radiosity in emissive units). Two layouts:
/// - ours (`surfaces.csv`): `surface,area,b_r,b_g,b_b`;
/// - Mitsuba irradiance meters (`quad,...,B_r,B_g,B_b,...`): `B` is exitance, divided by π.
pub fn parse_reference_csv(text: &str) -> Result<Vec<(String, Rgb)>, BakeError> {
    let mut lines = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'));
    let header: Vec<&str> = lines
        .next()
        .ok_or_else(|| BakeError::Reference("empty reference file".into()))?
        .split(',')
        .map(str::trim)
        .collect();
    let col = |name: &str| header.iter().position(|h| h.eq_ignore_ascii_case(name));
    let (cols, scale) = if let (Some(r), Some(g), Some(b)) = (col("b_r"), col("b_g"), col("b_b")) {
        // Mitsuba's columns are upper case B_r; ours lower case b_r: tell them apart by the
        // first column's name.
        let mitsuba = header.first().is_some_and(|h| *h == "quad");
        (
            [r, g, b],
            if mitsuba {
                1.0 / std::f64::consts::PI
            } else {
                1.0
            },
        )
    } else {
        return Err(BakeError::Reference(
            "header needs b_r,b_g,b_b (ours) or B_r,B_g,B_b (Mitsuba)".into(),
        ));
    };
    let mut out = Vec::new();
    for (k, line) in lines.enumerate() {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let get = |i: usize| -> Result<f64, BakeError> {
            f.get(i)
                .and_then(|s| s.parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    BakeError::Reference(format!("row {}: bad number in column {}", k + 2, i + 1))
                })
        };
        let name = f
            .first()
            .filter(|s| !s.is_empty())
            .ok_or_else(|| BakeError::Reference(format!("row {}: no surface name", k + 2)))?;
        out.push((
            name.to_string(),
            [
                get(cols[0])? * scale,
                get(cols[1])? * scale,
                get(cols[2])? * scale,
            ],
        ));
    }
    if out.is_empty() {
        return Err(BakeError::Reference("no rows".into()));
    }
    Ok(out)
}

/// The Mitsuba 3 reference for the builtin Cornell box: irradiance meters on each quad,
/// 2^25 samples per pixel, `llvm_ad_rgb`, unbounded depth (`assets/reference/`).
pub const CORNELL_BOX_REFERENCE: &str =
    include_str!("../../../assets/reference/cornell_box_mitsuba_irradiance.csv");
