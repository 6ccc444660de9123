//! Spectral radiosity: the links of a bake solved again in `N` wavelength bands over
//! 400–700 nm, then converted to CIE XYZ and linear sRGB.
//!
//! Multiplying RGB triples is not multiplying spectra: a white wall lit by a red wall reflects
//! `ρ_white(λ) ρ_red(λ) E(λ)`, which three numbers cannot follow through several bounces. Form
//! factors do not depend on wavelength, so only the solve is repeated, three bands at a time.
//!
//! Spectra come per material name. Reflectance is absolute; an emission spectrum is relative
//! and is scaled so that its luminance equals the luminance of the material's RGB emission, so
//! an RGB bake and a spectral bake of the same scene are directly comparable.

use std::collections::HashMap;
use std::time::Duration;

use radiant_color::cie::{self, Spectrum};
use radiant_scene::Surface;

use crate::mesh::Mesh;
use crate::metrics::{SurfaceMean, surface_means};
use crate::solve::{Solve, SolveError};
use crate::solvers::{SolverKind, SolverParams};
use crate::system::{Rgb, System};
use crate::{BakeError, MaterialError, ParameterError};

/// Spectral data of one material.
#[derive(Clone, Debug, PartialEq)]
pub struct SpectralMaterial {
    /// Diffuse reflectance, absolute, in [0, 1].
    pub reflectance: Spectrum,
    /// Relative emission spectrum, if the material emits.
    pub emission: Option<Spectrum>,
}

/// The outcome of a spectral solve.
#[derive(Clone, Debug)]
pub struct SpectralResult {
    /// Number of bands.
    pub bands: usize,
    /// Per element linear sRGB (D65 white, no chromatic adaptation), emissive units.
    pub radiosity: Vec<Rgb>,
    /// Per element XYZ.
    pub xyz: Vec<Rgb>,
    /// Per surface means of the linear sRGB.
    pub surfaces: Vec<SurfaceMean>,
    /// Whether every band's solve met the tolerance (false: one stopped making progress).
    pub converged: bool,
}

const LO: f64 = 400.0;
const HI: f64 = 700.0;

/// Band averages of a spectrum over `bands` equal bands of 400–700 nm (1 nm sampling).
fn band_means(s: &Spectrum, bands: usize) -> Vec<f64> {
    let width = (HI - LO) / bands as f64;
    (0..bands)
        .map(|b| {
            let (a, z) = (LO + width * b as f64, LO + width * (b + 1) as f64);
            let n = ((z - a).round() as usize).max(1);
            (0..n)
                .map(|k| s.at(a + (k as f64 + 0.5) * (z - a) / n as f64))
                .sum::<f64>()
                / n as f64
        })
        .collect()
}

/// Per band, the integrals of x̄, ȳ, z̄ over the band, normalised so that a flat spectrum of 1
/// over 400–700 nm has Y = 1.
fn band_cmf(bands: usize) -> Vec<[f64; 3]> {
    let width = (HI - LO) / bands as f64;
    let mut out = vec![[0.0; 3]; bands];
    let mut y_total = 0.0;
    for &(w, c) in cie::cmf_xyz().iter().filter(|(w, _)| *w >= LO && *w < HI) {
        let b = (((w - LO) / width) as usize).min(bands - 1);
        for k in 0..3 {
            out[b][k] += c[k];
        }
        y_total += c[1];
    }
    out.iter().map(|c| c.map(|v| v / y_total)).collect()
}

/// Solves the system's links in `bands` bands with the given spectral materials (by material
/// name; every surface needs one), to `tolerance`. Only emissive surfaces light a spectral
/// solve: direct light from punctual lights (RGB only) is not carried over.
pub fn solve_spectral(
    system: &System,
    mesh: &Mesh,
    surfaces: &[Surface],
    materials: &HashMap<String, SpectralMaterial>,
    bands: usize,
    tolerance: f64,
) -> Result<SpectralResult, BakeError> {
    let params = SolverParams {
        tolerance,
        ..Default::default()
    };
    solve_in_bands(mesh, surfaces, materials, bands, |rho, source| {
        let sys = system.with_materials(rho, source);
        // The stopping rule of a bake: converged, or stalled.
        let mut solve = Solve::new(SolverKind::GaussSeidel, &sys, params);
        loop {
            match solve.step(&sys, Duration::from_millis(25)) {
                Ok(info) if info.converged => return Ok((solve.radiosity(&sys), true)),
                Ok(_) => {}
                Err(SolveError::Stalled { .. }) => return Ok((solve.radiosity(&sys), false)),
                Err(e) => return Err(e.into()),
            }
        }
    })
}

/// The spectral solve around any solver of three bands at a time: `solve3(ρ, source)` (per
/// element, the three bands in the RGB slots) returns the radiosity and whether it converged.
/// Bands are summed into XYZ and converted to linear sRGB.
pub(crate) fn solve_in_bands(
    mesh: &Mesh,
    surfaces: &[Surface],
    materials: &HashMap<String, SpectralMaterial>,
    bands: usize,
    mut solve3: impl FnMut(Vec<Rgb>, Vec<Rgb>) -> Result<(Vec<Rgb>, bool), BakeError>,
) -> Result<SpectralResult, BakeError> {
    if !(3..=96).contains(&bands) {
        return Err(ParameterError::out_of_range("bands", bands as f64, "3..=96").into());
    }
    let cmf = band_cmf(bands);
    let per_surface = surface_bands(surfaces, materials, bands, &cmf)?;
    let n = mesh.element_count();
    let surface_of: Vec<usize> = (0..n)
        .map(|i| mesh.root_surface[mesh.nodes[mesh.leaves[i] as usize].root as usize] as usize)
        .collect();
    let mut xyz = vec![[0.0; 3]; n];
    let mut converged = true;
    for first in (0..bands).step_by(3) {
        let pick = |b: usize| (first + b).min(bands - 1);
        let rho: Vec<Rgb> = surface_of
            .iter()
            .map(|&s| std::array::from_fn(|k| per_surface[s].0[pick(k)]))
            .collect();
        let source: Vec<Rgb> = surface_of
            .iter()
            .map(|&s| std::array::from_fn(|k| per_surface[s].1[pick(k)]))
            .collect();
        let (b, ok) = solve3(rho, source)?;
        converged &= ok;
        for (k, band) in (first..(first + 3).min(bands)).enumerate() {
            for i in 0..n {
                for c in 0..3 {
                    xyz[i][c] += b[i][k] * cmf[band][c];
                }
            }
        }
    }
    let to_rgb = &cie::srgb_matrices().1;
    let radiosity: Vec<Rgb> = xyz.iter().map(|x| cie::mul(to_rgb, *x)).collect();
    let surfaces = surface_means(surfaces, mesh, &radiosity);
    Ok(SpectralResult {
        bands,
        radiosity,
        xyz,
        surfaces,
        converged,
    })
}

/// One surface's band reflectance and band emission.
type Bands = (Vec<f64>, Vec<f64>);

/// Per surface: band reflectance and band emission (scaled to the RGB emission's luminance).
fn surface_bands(
    surfaces: &[Surface],
    materials: &HashMap<String, SpectralMaterial>,
    bands: usize,
    cmf: &[[f64; 3]],
) -> Result<Vec<Bands>, BakeError> {
    let mut per_surface = Vec::with_capacity(surfaces.len());
    for s in surfaces {
        let m = materials
            .get(&s.material)
            .ok_or_else(|| BakeError::InvalidMaterial {
                surface: s.name.clone(),
                what: MaterialError::NoSpectrum(s.material.clone()),
            })?;
        let rho = band_means(&m.reflectance, bands);
        if let Some((band, &value)) = rho
            .iter()
            .enumerate()
            .find(|(_, r)| !(0.0..=1.0).contains(*r))
        {
            return Err(BakeError::InvalidMaterial {
                surface: s.name.clone(),
                what: MaterialError::SpectralReflectance { band, value },
            });
        }
        let emission = match (&m.emission, s.is_emitter()) {
            (Some(e), true) => {
                let raw = band_means(e, bands);
                let y: f64 = raw.iter().zip(cmf).map(|(v, c)| v * c[1]).sum();
                let target = radiant_color::luminance(s.emission);
                if y.is_nan() || y <= 0.0 {
                    return Err(BakeError::InvalidMaterial {
                        surface: s.name.clone(),
                        what: MaterialError::DarkEmission,
                    });
                }
                raw.iter().map(|v| v * target / y).collect()
            }
            _ => vec![0.0; bands],
        };
        per_surface.push((rho, emission));
    }
    Ok(per_surface)
}
