//! Error metrics: per-surface means, comparison against a reference, and reference files.
//!
//! Against a per-surface reference (total error, discretisation included) the metrics are over
//! surfaces, area-weighted, emitters excluded (their radiosity is their emission), with `R`
//! floored at 1e-3 of its area-weighted mean (a surface the reference finds unlit):
//! - `mean_rel`: `Σ_s A_s mean_c |B_sc − R_sc| / R_sc / Σ_s A_s`;
//! - `max_rel`: `max_{s,c} |B_sc − R_sc| / R_sc`;
//! - `rel_rms`: `sqrt(Σ_s A_s Σ_c (B_sc − R_sc)² / Σ_s A_s Σ_c R_sc²)`.
//!
//! Against the direct solve on the same mesh (solver error) the same formulas run over elements,
//! with `R` floored at 1e-3 of the mean so that unlit elements do not divide by zero.

use radiant_scene::Surface;

use crate::BakeError;

/// Why a reference file (a surface or point CSV) cannot be compared with.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ReferenceFileError {
    /// No lines besides comments.
    #[error("empty {what}")]
    Empty {
        /// Which file.
        what: &'static str,
    },
    /// A surface CSV with neither our columns nor Mitsuba's.
    #[error("header needs b_r,b_g,b_b (ours) or B_r,B_g,B_b (Mitsuba)")]
    NoRadiosityColumns,
    /// A point CSV without a column it needs.
    #[error("point reference: no column '{column}'")]
    NoColumn {
        /// The column.
        column: &'static str,
    },
    /// A cell that is not a finite number.
    #[error("row {row}: bad number in column {column}")]
    BadNumber {
        /// The line, counting the header as 1.
        row: usize,
        /// The column, from 1.
        column: usize,
    },
    /// A row without a surface name.
    #[error("row {row}: no surface name")]
    NoName {
        /// The line, counting the header as 1.
        row: usize,
    },
    /// A point whose normal is zero.
    #[error("point row {row}: zero normal")]
    ZeroNormal {
        /// The line, counting the header as 1.
        row: usize,
    },
    /// A header and no rows.
    #[error("no rows")]
    NoRows,
    /// No surface of the scene has a row.
    #[error("no surface of the scene is in the reference")]
    NoCommonSurface,
    /// No element of the bake lies at a reference point.
    #[error("no element at point '{point}'")]
    NoElementAt {
        /// The point's name.
        point: String,
    },
    /// The point to normalise by is not in the reference.
    #[error("no reference point '{point}'")]
    NoPoint {
        /// The point's name.
        point: String,
    },
    /// The point to normalise by is black (in the bake or the reference).
    #[error("point '{point}' has no luminance to normalise by")]
    NoLuminance {
        /// The point's name.
        point: String,
    },
    /// Only the normalising point, or none.
    #[error("no points to compare")]
    NoPoints,
}
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
    surface_means_with(surfaces, mesh, b, |_| 1.0)
}

/// Per-surface means of a clustered bake's radiosity, that of each element's exposed part
/// ([`crate::exposure`]): an element's buried part counts in its surface's area, dark, as a
/// path tracer that samples the whole surface sees it.
pub fn surface_means_exposed(
    surfaces: &[Surface],
    mesh: &Mesh,
    b: &[Rgb],
    live: &[u8],
) -> Vec<SurfaceMean> {
    surface_means_with(surfaces, mesh, b, |i| {
        live.get(i).map_or(1.0, |&l| crate::exposure::fraction(l))
    })
}

fn surface_means_with(
    surfaces: &[Surface],
    mesh: &Mesh,
    b: &[Rgb],
    share: impl Fn(usize) -> f64,
) -> Vec<SurfaceMean> {
    let mut acc = vec![(0.0, [0.0; 3]); surfaces.len()];
    for (i, &id) in mesh.leaves.iter().enumerate() {
        let node = &mesh.nodes[id as usize];
        let s = mesh.root_surface[node.root as usize] as usize;
        acc[s].0 += node.area;
        let lit = node.area * share(i);
        for c in 0..3 {
            acc[s].1[c] += lit * b[i][c];
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
        return Err(ReferenceFileError::NoCommonSurface.into());
    }
    // Relative to at least 1e-3 of the mean: a surface the reference finds (almost) unlit
    // would otherwise divide by nearly zero.
    let area: f64 = pairs.iter().map(|p| p.0).sum();
    let mean_r = pairs
        .iter()
        .map(|(a, _, r)| a * (r[0] + r[1] + r[2]) / 3.0)
        .sum::<f64>()
        / area.max(f64::MIN_POSITIVE);
    Ok(stats(pairs.into_iter(), (1e-3 * mean_r).max(1e-12)))
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

/// How far a light is from another, as one number: `‖got − reference‖ / ‖reference‖` over
/// every element and channel (0 for equal lights). The live-rebake examples say a light is
/// "within 1 %" of its converged one when this is below 0.01.
pub fn relative_difference(got: &[Rgb], reference: &[Rgb]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (x, y) in got.iter().zip(reference) {
        for c in 0..3 {
            num += (x[c] - y[c]).powi(2);
            den += y[c].powi(2);
        }
    }
    (num / den.max(1e-300)).sqrt()
}

/// The header fields and the data lines of a CSV (blank lines and `#` comments skipped);
/// `what` names the file in the error for an empty one.
fn csv_lines<'a>(
    text: &'a str,
    what: &'static str,
) -> Result<(Vec<&'a str>, impl Iterator<Item = &'a str>), ReferenceFileError> {
    let mut lines = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'));
    let header = lines
        .next()
        .ok_or(ReferenceFileError::Empty { what })?
        .split(',')
        .map(str::trim)
        .collect();
    Ok((header, lines))
}

/// Parses a per-surface reference CSV into (surface, radiosity in emissive units). Two layouts:
/// - ours (`surfaces.csv`): `surface,area,b_r,b_g,b_b`;
/// - Mitsuba irradiance meters (`quad,...,B_r,B_g,B_b,...`): `B` is exitance, divided by π.
pub fn parse_reference_csv(text: &str) -> Result<Vec<(String, Rgb)>, BakeError> {
    let (header, lines) = csv_lines(text, "reference file")?;
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
        return Err(ReferenceFileError::NoRadiosityColumns.into());
    };
    let mut out = Vec::new();
    for (k, line) in lines.enumerate() {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let get = |i: usize| -> Result<f64, BakeError> {
            f.get(i)
                .and_then(|s| s.parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or(
                    ReferenceFileError::BadNumber {
                        row: k + 2,
                        column: i + 1,
                    }
                    .into(),
                )
        };
        let name = f
            .first()
            .filter(|s| !s.is_empty())
            .ok_or(ReferenceFileError::NoName { row: k + 2 })?;
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
        return Err(ReferenceFileError::NoRows.into());
    }
    Ok(out)
}

/// The Mitsuba 3 reference for the builtin Cornell box: irradiance meters on each quad,
/// 2^25 samples per pixel, `llvm_ad_rgb`, unbounded depth (`assets/reference/`).
pub const CORNELL_BOX_REFERENCE: &str =
    include_str!("../../../assets/reference/cornell_box_mitsuba_irradiance.csv");

/// Mitsuba 3 radiance meters 1 mm off 24 points of the builtin Cornell box (quad centres and
/// five probes), bitterli RGB materials, `scalar_rgb`, 2^20 samples each
/// (`tools/make_cornell_point_references.sh`). Positions in mm.
pub const CORNELL_POINTS_RGB: &str =
    include_str!("../../../assets/reference/cornell_points_rgb_mitsuba.csv");
/// The same points with the measured spectra (`scalar_spectral`): the light's spectrum is
/// relative, so compare after scaling to a light point ([`compare_points`]).
pub const CORNELL_POINTS_SPECTRAL: &str =
    include_str!("../../../assets/reference/cornell_points_spectral_mitsuba.csv");

/// The measured spectra of the builtin Cornell box's materials (`--spectral`; the format of a
/// spectra side file).
pub const CORNELL_BOX_SPECTRA: &str = include_str!("../../../assets/cornell_box_spectra.json");

/// What ships with a builtin scene to measure a bake against.
#[derive(Clone, Copy, Debug)]
pub struct ShippedReferences {
    /// Where the per-surface reference comes from.
    pub surfaces_source: &'static str,
    /// The per-surface reference ([`parse_reference_csv`]).
    pub surfaces: &'static str,
    /// Path-traced radiosity at surface points, RGB materials ([`parse_point_csv`]).
    pub points_rgb: &'static str,
    /// The same points with the measured spectra.
    pub points_spectral: &'static str,
    /// The measured spectra of its materials.
    pub spectra: &'static str,
}

/// The references shipped with a builtin scene.
pub fn shipped_references(scene: radiant_scene::Builtin) -> ShippedReferences {
    match scene {
        radiant_scene::Builtin::CornellBox => ShippedReferences {
            surfaces_source: "Mitsuba 3 path-traced irradiance meters (assets/reference)",
            surfaces: CORNELL_BOX_REFERENCE,
            points_rgb: CORNELL_POINTS_RGB,
            points_spectral: CORNELL_POINTS_SPECTRAL,
            spectra: CORNELL_BOX_SPECTRA,
        },
    }
}

/// How far one per-surface solution (the spectral one, say) is from another (the RGB bake),
/// emitters left out: relative per channel, area-weighted mean and max.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceDifference {
    /// Area-weighted mean of the channels' mean relative difference.
    pub mean: f64,
    /// The largest relative difference of any channel.
    pub max: f64,
    /// Each surface's relative difference per channel.
    pub per_surface: Vec<(String, Rgb)>,
}

/// The relative difference of `a` from `b`, surface by surface (the two in the same order).
pub fn surface_difference(a: &[SurfaceMean], b: &[SurfaceMean]) -> SurfaceDifference {
    let (mut max, mut mean, mut area) = (0.0f64, 0.0, 0.0);
    let mut per_surface = Vec::new();
    for (s, r) in a.iter().zip(b).filter(|(s, _)| !s.emitter) {
        let d: Rgb = std::array::from_fn(|c| (s.mean[c] - r.mean[c]) / r.mean[c].abs().max(1e-12));
        max = d.iter().fold(max, |m, v| m.max(v.abs()));
        mean += s.area * d.iter().map(|v| v.abs()).sum::<f64>() / 3.0;
        area += s.area;
        per_surface.push((s.name.clone(), d));
    }
    SurfaceDifference {
        mean: if area > 0.0 { mean / area } else { 0.0 },
        max,
        per_surface,
    }
}

/// A path-traced radiosity at one surface point: Mitsuba radiance meters 1 mm off the surface,
/// looking back into it (`tools`: `cornell_mitsuba.py points`).
#[derive(Clone, Debug, PartialEq)]
pub struct PointReference {
    /// The point's name (`left_wall_centre`, `floor_under_light`, ...).
    pub name: String,
    /// Position on the surface, scene units.
    pub position: glam::DVec3,
    /// Unit normal of the surface there.
    pub normal: glam::DVec3,
    /// Radiosity in emissive units (the meter's outgoing radiance).
    pub radiosity: Rgb,
}

/// A point where a value is asked for: a surface point and the normal it is seen along.
#[derive(Clone, Debug, PartialEq)]
pub struct PointSpec {
    /// The point's name (the first column).
    pub name: String,
    /// Position on the surface, scene units.
    pub position: glam::DVec3,
    /// Unit normal of the surface there.
    pub normal: glam::DVec3,
}

/// Parses a points CSV: a first column naming each point, then either `x,y,z` (scene units) or
/// `x_mm,y_mm,z_mm` (millimetres, multiplied by `mm_to_scene`: 1e-3 for a scene in metres),
/// and `nx,ny,nz` (any length but 0). Other columns are ignored. The layout `radiant reference
/// --points` reads, and the one it and Mitsuba's meters write.
pub fn parse_point_positions(text: &str, mm_to_scene: f64) -> Result<Vec<PointSpec>, BakeError> {
    Ok(parse_points(text, mm_to_scene, &[])?
        .into_iter()
        .map(|(spec, _)| spec)
        .collect())
}

/// Parses a `point,x,y,z,nx,ny,nz,L_r,L_g,L_b,...` CSV (or `x_mm,y_mm,z_mm`, multiplied by
/// `mm_to_scene`, see [`parse_point_positions`]): a path-traced outgoing radiance per point,
/// as `radiant reference --points` and Mitsuba's radiance meters write it.
pub fn parse_point_csv(text: &str, mm_to_scene: f64) -> Result<Vec<PointReference>, BakeError> {
    Ok(parse_points(text, mm_to_scene, &["L_r", "L_g", "L_b"])?
        .into_iter()
        .map(|(p, l)| PointReference {
            name: p.name,
            position: p.position,
            normal: p.normal,
            radiosity: [l[0], l[1], l[2]],
        })
        .collect())
}

/// The rows of a points CSV with the numbers of the `extra` columns.
fn parse_points(
    text: &str,
    mm_to_scene: f64,
    extra: &[&'static str],
) -> Result<Vec<(PointSpec, Vec<f64>)>, BakeError> {
    let (header, lines) = csv_lines(text, "point file")?;
    let column = |w: &'static str| {
        header
            .iter()
            .position(|h| *h == w)
            .ok_or(ReferenceFileError::NoColumn { column: w })
    };
    let (xyz, scale) = match header.contains(&"x") {
        true => (["x", "y", "z"], 1.0),
        false => (["x_mm", "y_mm", "z_mm"], mm_to_scene),
    };
    let cols: Vec<usize> = xyz
        .iter()
        .chain(&["nx", "ny", "nz"])
        .chain(extra)
        .map(|w| column(w))
        .collect::<Result<_, _>>()?;
    let mut out = Vec::new();
    for (k, line) in lines.enumerate() {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let v: Vec<f64> = cols
            .iter()
            .map(|&c| {
                f.get(c)
                    .and_then(|s| s.parse::<f64>().ok())
                    .filter(|x| x.is_finite())
                    .ok_or(ReferenceFileError::BadNumber {
                        row: k + 2,
                        column: c + 1,
                    })
            })
            .collect::<Result<_, _>>()?;
        let normal = glam::DVec3::new(v[3], v[4], v[5])
            .try_normalize()
            .ok_or(ReferenceFileError::ZeroNormal { row: k + 2 })?;
        let spec = PointSpec {
            name: f.first().copied().unwrap_or_default().to_string(),
            position: glam::DVec3::new(v[0], v[1], v[2]) * scale,
            normal,
        };
        out.push((spec, v[6..].to_vec()));
    }
    if out.is_empty() {
        return Err(ReferenceFileError::NoRows.into());
    }
    Ok(out)
}

/// The element whose triangle contains `p` seen along `normal` and lies nearest to it (at most
/// 0.5 % of the scene's size off its plane: published quads such as the Cornell box's left
/// wall are not quite planar), facing along `normal`; `None` if no element does.
pub fn element_at(mesh: &Mesh, p: glam::DVec3, normal: glam::DVec3) -> Option<usize> {
    let q = mesh.frame.to_local(p);
    let (plane_tol, edge_tol) = (5e-3, 1e-6);
    let mut best: Option<(usize, f64)> = None;
    for (i, &leaf) in mesh.leaves.iter().enumerate() {
        let node = &mesh.nodes[leaf as usize];
        if node.normal.dot(normal) < 0.99 {
            continue;
        }
        let off = (q - node.v[0]).dot(node.normal).abs();
        if off > plane_tol {
            continue;
        }
        // Inside (edges included) by the signs of the three sub-triangle normals.
        let inside = (0..3).all(|k| {
            let (a, b) = (node.v[k], node.v[(k + 1) % 3]);
            (b - a).cross(q - a).dot(node.normal) >= -edge_tol * (b - a).length()
        });
        if inside && best.is_none_or(|(_, d)| off < d) {
            best = Some((i, off));
        }
    }
    best.map(|(i, _)| i)
}

/// One point of a [`compare_points`].
#[derive(Clone, Debug, PartialEq)]
pub struct PointError {
    /// The reference point's name.
    pub name: String,
    /// Our radiosity at the point (its element's).
    pub ours: Rgb,
    /// The reference, after scaling.
    pub reference: Rgb,
    /// `Σ_c |ours − ref| / Σ_c ref`.
    pub rel: f64,
    /// `Σ_c (ours − ref) / Σ_c ref`: below 0 where ours is darker.
    pub signed: f64,
}

/// Radiosity at reference points against a path tracer.
#[derive(Clone, Debug, PartialEq)]
pub struct PointComparison {
    /// Every point but the normalising one.
    pub points: Vec<PointError>,
    /// Mean of `rel` over the points.
    pub mean_rel: f64,
    /// Largest `rel`.
    pub max_rel: f64,
    /// Median of `rel` (the mean of the middle two for an even count).
    pub median_rel: f64,
    /// Mean signed error, `Σ_c (ours − ref) / Σ_c ref` averaged over the points: below 0 where
    /// ours is darker.
    pub bias: f64,
    /// The factor the reference was multiplied by (1 unless normalised).
    pub scale: f64,
}

/// Compares `radiosity` (per element of `mesh`) with `reference` at its points. With
/// `normalise_to`, the reference is first scaled so that its luminance at that point equals
/// ours, and that point is left out: for references whose emitters share only the relative
/// spectrum with ours (a spectral bake scales emission to the RGB emission's luminance).
pub fn compare_points(
    mesh: &Mesh,
    radiosity: &[Rgb],
    reference: &[PointReference],
    normalise_to: Option<&str>,
) -> Result<PointComparison, BakeError> {
    compare_points_with(reference, normalise_to, |r| {
        element_at(mesh, r.position, r.normal).and_then(|e| radiosity.get(e).copied())
    })
}

/// [`compare_points`] with our radiosity at a point from `at` (`None`: no surface there),
/// e.g. the smooth field's (`crate::smooth::SmoothField::radiosity_at`).
pub fn compare_points_with(
    reference: &[PointReference],
    normalise_to: Option<&str>,
    at: impl Fn(&PointReference) -> Option<Rgb>,
) -> Result<PointComparison, BakeError> {
    let at = |r: &PointReference| -> Result<Rgb, BakeError> {
        at(r).ok_or_else(|| {
            ReferenceFileError::NoElementAt {
                point: r.name.clone(),
            }
            .into()
        })
    };
    let scale = match normalise_to {
        Some(name) => {
            let r = reference.iter().find(|r| r.name == name).ok_or_else(|| {
                ReferenceFileError::NoPoint {
                    point: name.to_string(),
                }
            })?;
            let (ours, theirs) = (
                radiant_color::luminance(at(r)?),
                radiant_color::luminance(r.radiosity),
            );
            if !(theirs > 0.0 && ours > 0.0 && ours.is_finite()) {
                return Err(ReferenceFileError::NoLuminance {
                    point: name.to_string(),
                }
                .into());
            }
            ours / theirs
        }
        None => 1.0,
    };
    let mut points = Vec::new();
    for r in reference
        .iter()
        .filter(|r| Some(r.name.as_str()) != normalise_to)
    {
        let ours = at(r)?;
        let reference = r.radiosity.map(|v| v * scale);
        let sum: f64 = reference.iter().sum();
        let diff: f64 = (0..3).map(|c| (ours[c] - reference[c]).abs()).sum();
        points.push(PointError {
            name: r.name.clone(),
            ours,
            reference,
            rel: if sum > 0.0 { diff / sum } else { f64::INFINITY },
            signed: if sum > 0.0 {
                (ours.iter().sum::<f64>() - sum) / sum
            } else {
                f64::INFINITY
            },
        });
    }
    if points.is_empty() {
        return Err(ReferenceFileError::NoPoints.into());
    }
    let n = points.len() as f64;
    let mut sorted: Vec<f64> = points.iter().map(|p| p.rel).collect();
    sorted.sort_by(f64::total_cmp);
    let half = sorted.len() / 2;
    let median_rel = match sorted.len() % 2 {
        1 => sorted[half],
        _ => 0.5 * (sorted[half - 1] + sorted[half]),
    };
    Ok(PointComparison {
        mean_rel: points.iter().map(|p| p.rel).sum::<f64>() / n,
        max_rel: points.iter().map(|p| p.rel).fold(0.0, f64::max),
        median_rel,
        bias: points.iter().map(|p| p.signed).sum::<f64>() / n,
        scale,
        points,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mean(name: &str, area: f64, mean: Rgb, emitter: bool) -> SurfaceMean {
        SurfaceMean {
            name: name.into(),
            area,
            mean,
            emitter,
        }
    }

    #[test]
    fn the_surface_difference_is_relative_area_weighted_and_leaves_emitters_out() {
        let b = [
            mean("light", 1.0, [10.0; 3], true),
            mean("wall", 1.0, [1.0, 1.0, 1.0], false),
            mean("floor", 3.0, [2.0, 2.0, 2.0], false),
        ];
        let a = [
            mean("light", 1.0, [20.0; 3], true),
            mean("wall", 1.0, [1.1, 1.0, 0.7], false),
            mean("floor", 3.0, [2.0, 2.0, 2.0], false),
        ];
        let d = surface_difference(&a, &b);
        assert_eq!(d.per_surface.len(), 2);
        assert!((d.max - 0.3).abs() < 1e-12, "{}", d.max);
        // The wall's mean |difference| is (0.1 + 0 + 0.3) / 3, a quarter of the area.
        assert!((d.mean - 0.4 / 3.0 / 4.0).abs() < 1e-12, "{}", d.mean);
        let s = shipped_references(radiant_scene::Builtin::CornellBox);
        assert!(parse_reference_csv(s.surfaces).is_ok());
        assert!(parse_point_csv(s.points_rgb, 1e-3).is_ok());
    }
}
