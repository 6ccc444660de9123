//! Spectral radiosity: flat spectra reproduce the grey RGB solve exactly (luminance); the
//! measured Cornell spectra give finite, positive results; bad spectral data is a typed error.
//! The clustered bake's spectral solve does the same, and changes the light as the
//! per-triangle bake's does.

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

fn clustered(
    scene: &radiant_scene::Scene,
    p: &BakeParams,
) -> radiant_radiosity::cluster::ClusterBake {
    use radiant_radiosity::cluster::{ClusterBake, ClusterParams, Watch};
    let mut b =
        ClusterBake::new(scene, p, &ClusterParams::default(), &|_, _, _| {}, None).expect("builds");
    b.run_to_end(&|_, _, _| {}, &mut Watch::default())
        .expect("solves");
    b
}

#[test]
fn the_clustered_bake_solves_in_bands_too() {
    // Flat spectra: every band is the grey solve of the same links, so Y is its radiosity.
    let scene = grey_cornell(0.6);
    let mut p = BakeParams::default();
    p.links.refinement = 0.01;
    p.solver_params.tolerance = 1e-9;
    let b = clustered(&scene, &p);
    let mut flat = HashMap::new();
    for s in &scene.surfaces {
        let emission = s.is_emitter().then(|| Spectrum::constant(1.0));
        flat.insert(
            s.material.clone(),
            SpectralMaterial {
                reflectance: Spectrum::constant(0.6),
                emission,
            },
        );
    }
    let sp = b.solve_spectral(&flat, 8, 1e-9).expect("spectral");
    assert!(sp.converged);
    let rgb = b.radiosity();
    for (i, xyz) in sp.xyz.iter().enumerate() {
        let want = rgb[i][0];
        assert!(
            (xyz[1] - want).abs() <= 1e-6 * want.max(1e-9),
            "element {i}: Y {} vs {want}",
            xyz[1]
        );
    }

    // Measured spectra: what the spectra change (the spectral result over the RGB one, per
    // surface) is what they change in the per-triangle bake.
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let materials = common::cornell_spectra();
    let mut p = BakeParams::default();
    p.links.refinement = 0.004;
    let b = clustered(&scene, &p);
    let sp = b.solve_spectral(&materials, 16, 1e-6).expect("spectral");
    assert!(sp.converged);
    let rgb = b.finish().surfaces;
    let t = common::bake(&scene, &BakeParams::default());
    let tsp = solve_spectral(&t.system, &t.mesh, &scene.surfaces, &materials, 16, 1e-6)
        .expect("spectral");
    let (mut worst, mut sum, mut n) = (0.0f64, 0.0, 0.0);
    for (k, s) in rgb.iter().enumerate() {
        if s.emitter {
            continue;
        }
        for c in 0..3 {
            let ours = sp.surfaces[k].mean[c] / s.mean[c];
            let theirs = tsp.surfaces[k].mean[c] / t.surfaces[k].mean[c];
            let d = (ours / theirs - 1.0).abs();
            worst = worst.max(d);
            (sum, n) = (sum + d, n + 1.0);
        }
    }
    eprintln!(
        "spectral/RGB ratio, clustered against per-triangle: {:.2} % mean, {:.2} % at most",
        100.0 * sum / n,
        worst * 100.0
    );
    // Measured 0.14 % mean; 2.2 % at most, on the red wall's blue channel, a few percent of
    // its red.
    assert!(sum / n <= 0.005 && worst <= 0.03, "{} {worst}", sum / n);
    // A material without spectral data is a typed error here too.
    let mut missing = materials.clone();
    missing.remove("green");
    let b = clustered(&scene, &p);
    assert!(matches!(
        b.solve_spectral(&missing, 16, 1e-6),
        Err(BakeError::InvalidMaterial { .. })
    ));
}
