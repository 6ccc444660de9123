//! Helpers shared by the integration tests.
#![allow(dead_code)]

use glam::DVec3;
use radiant_radiosity::metrics::SurfaceMean;
use radiant_radiosity::scenes::{add_surface, quad};
use radiant_radiosity::{Bake, BakeParams, BakeResult, FormFactorKind, SolverKind};
use radiant_scene::Scene;

/// Bakes to the end.
pub fn bake(scene: &Scene, params: &BakeParams) -> BakeResult {
    Bake::new(scene, params)
        .expect("bake prepares")
        .run_to_end(&mut |_| {})
        .expect("bake runs")
}

/// The mean of a named surface.
pub fn surface<'a>(r: &'a BakeResult, name: &str) -> &'a SurfaceMean {
    r.surfaces
        .iter()
        .find(|s| s.name == name)
        .unwrap_or_else(|| panic!("surface {name}"))
}

/// Form factor from surface `a` to surface `b` measured through a whole bake: `b` emits 1 and
/// reflects nothing, `a` reflects everything and emits nothing, so `a`'s mean radiosity is
/// `F_ab` (one bounce, `a` does not see itself).
pub fn form_factor(
    a: &[[DVec3; 3]],
    b: &[[DVec3; 3]],
    method: FormFactorKind,
    patch_size: f64,
    levels: u8,
) -> f64 {
    let mut s = Scene::default();
    add_surface(&mut s, "a", [1.0; 3], [0.0; 3], a);
    add_surface(&mut s, "b", [0.0; 3], [1.0; 3], b);
    let mut p = BakeParams::default();
    p.mesh.patch_size = patch_size;
    p.mesh.element_levels = levels;
    p.form_factors = method;
    p.ff.hemicube_resolution = 128;
    p.ff.monte_carlo_rays = 1024;
    // Uniform links (every element to every patch): the closed forms test the form factors,
    // not the refinement.
    p.links.hierarchical = false;
    p.solver = SolverKind::Jacobi;
    p.solver_params.tolerance = 1e-9;
    let r = bake(&s, &p);
    surface(&r, "a").mean[0]
}

/// An `a × b` rectangle in the plane `z = z0`, facing `+z` (`up`) or `-z`.
pub fn rect_z(a: f64, b: f64, z0: f64, up: bool) -> Vec<[DVec3; 3]> {
    let q = if up {
        quad(
            DVec3::new(0.0, 0.0, z0),
            DVec3::new(a, 0.0, 0.0),
            DVec3::new(0.0, b, 0.0),
        )
    } else {
        quad(
            DVec3::new(0.0, 0.0, z0),
            DVec3::new(0.0, b, 0.0),
            DVec3::new(a, 0.0, 0.0),
        )
    };
    q.to_vec()
}

/// The Cornell box's measured spectra (Cornell PCG data, as exported in radiant_color's test
/// data): white, red and green reflectances and the light's relative emission, reflectance
/// 0.78 (bitterli's).
pub fn cornell_spectra()
-> std::collections::HashMap<String, radiant_radiosity::spectral::SpectralMaterial> {
    use radiant_color::cie::Spectrum;
    use radiant_radiosity::spectral::SpectralMaterial;
    let text = include_str!("../../../radiant_color/tests/data/cornell_spectra_reflectance.csv");
    let table = |name: &str| -> Spectrum {
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().expect("header").split(',').collect();
        let col = header.iter().position(|h| *h == name).expect("column");
        let (mut w, mut v) = (Vec::new(), Vec::new());
        for l in lines {
            let f: Vec<f64> = l.split(',').map(|x| x.parse().expect("number")).collect();
            w.push(f[0]);
            v.push(f[col]);
        }
        Spectrum::new(w, v).expect("spectrum")
    };
    let mut m = std::collections::HashMap::new();
    for name in ["white", "red", "green"] {
        m.insert(
            name.to_string(),
            SpectralMaterial {
                reflectance: table(name),
                emission: None,
            },
        );
    }
    m.insert(
        "light".into(),
        SpectralMaterial {
            reflectance: Spectrum::constant(0.78),
            emission: Some(
                Spectrum::new(vec![400.0, 500.0, 600.0, 700.0], vec![0.0, 8.0, 15.6, 18.4])
                    .expect("spd"),
            ),
        },
    );
    m
}
