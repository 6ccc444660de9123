//! Spectral radiosity: flat spectra reproduce the grey RGB solve exactly (luminance); the
//! measured Cornell spectra give finite, positive results; bad spectral data is a typed error.

mod common;

use std::collections::HashMap;

use radiant_color::cie::Spectrum;
use radiant_radiosity::spectral::{SpectralMaterial, solve_spectral};
use radiant_radiosity::{BakeError, BakeParams};

fn grey_cornell(rho: f64) -> radiant_scene::Scene {
    let mut scene = radiant_scene::builtin("cornell-box").expect("builtin");
    for s in &mut scene.surfaces {
        s.reflectance = [rho; 3];
        if s.is_emitter() {
            s.emission = [10.0; 3];
        }
    }
    scene
}

#[test]
fn flat_spectra_reproduce_the_grey_solve() {
    let scene = grey_cornell(0.6);
    let mut p = BakeParams::default();
    p.mesh.patch_size = 0.3;
    p.solver_params.tolerance = 1e-9;
    let r = common::bake(&scene, &p);
    let mut materials = HashMap::new();
    for s in &scene.surfaces {
        let emission = s.is_emitter().then(|| Spectrum::constant(1.0));
        materials.insert(
            s.material.clone(),
            SpectralMaterial {
                reflectance: Spectrum::constant(0.6),
                emission,
            },
        );
    }
    for bands in [3, 8, 16] {
        let sp = solve_spectral(&r.system, &r.mesh, &scene.surfaces, &materials, bands, 1e-9)
            .expect("spectral");
        // A flat spectrum has the same radiosity in every band; its luminance (Y) is that
        // radiosity, since emission is scaled to the RGB emission's luminance.
        for (i, xyz) in sp.xyz.iter().enumerate() {
            let want = r.radiosity[i][0];
            assert!(
                (xyz[1] - want).abs() <= 1e-6 * want.max(1e-9),
                "{bands} bands, element {i}: Y {} vs {want}",
                xyz[1]
            );
        }
    }
}

#[test]
fn measured_cornell_spectra_bake() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let mut p = BakeParams::default();
    p.mesh.patch_size = 0.3;
    let r = common::bake(&scene, &p);
    let mut materials = common::cornell_spectra();
    let sp = solve_spectral(&r.system, &r.mesh, &scene.surfaces, &materials, 16, 1e-6)
        .expect("spectral");
    assert!(sp.xyz.iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
    assert!(sp.converged);
    // The red wall is red and the green wall green in the spectral result too.
    let mean = |n: &str| {
        sp.surfaces
            .iter()
            .find(|s| s.name == n)
            .expect("surface")
            .mean
    };
    let (red, green) = (mean("left_wall"), mean("right_wall"));
    assert!(red[0] > red[1] && red[0] > red[2], "{red:?}");
    assert!(green[1] > green[0] && green[1] > green[2], "{green:?}");
    // A material without spectral data is a typed error.
    materials.remove("green");
    assert!(matches!(
        solve_spectral(&r.system, &r.mesh, &scene.surfaces, &materials, 16, 1e-6),
        Err(BakeError::InvalidMaterial { .. })
    ));
    assert!(matches!(
        solve_spectral(&r.system, &r.mesh, &scene.surfaces, &materials, 1, 1e-6),
        Err(BakeError::InvalidParameter(_))
    ));
}
