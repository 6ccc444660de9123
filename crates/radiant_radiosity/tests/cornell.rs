//! The Cornell box at default settings against the Mitsuba 3 path-traced reference shipped in
//! assets/reference (irradiance meters on each quad, 2^25 samples): at most 1 % area-weighted
//! mean and 3 % maximum relative error over the surfaces, the light excluded.

mod common;

use radiant_radiosity::metrics::{CORNELL_BOX_REFERENCE, compare_surfaces, parse_reference_csv};
use radiant_radiosity::{BakeParams, SolverKind};

#[test]
fn cornell_box_matches_mitsuba_at_default_settings() {
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let reference = parse_reference_csv(CORNELL_BOX_REFERENCE).expect("reference parses");
    assert_eq!(reference.len(), 19);
    let r = common::bake(&scene, &BakeParams::default());
    assert!(r.report.converged);
    assert!(
        r.report.elements >= 13_000,
        "{} elements",
        r.report.elements
    );
    let e = compare_surfaces(&r.surfaces, &reference).expect("compare");
    eprintln!(
        "Cornell box vs Mitsuba: mean {:.3} %, max {:.3} %",
        e.mean_rel * 100.0,
        e.max_rel * 100.0
    );
    assert!(
        e.mean_rel <= 0.01,
        "mean relative error {:.3} %",
        e.mean_rel * 100.0
    );
    assert!(
        e.max_rel <= 0.03,
        "max relative error {:.3} %",
        e.max_rel * 100.0
    );
}

#[test]
fn cornell_box_light_leaks_nowhere() {
    // The blocks stand on the floor: the floor under them is dark, and the block faces next to
    // the floor are not lit through the joint. Elements whose centroid is under a block are 0,
    // except that a ray grazing a block's bottom edge may reach a millionth of the light.
    let scene = radiant_scene::builtin("cornell-box").expect("builtin");
    let mut p = BakeParams::default();
    p.mesh.patch_size = 0.2;
    p.solver = SolverKind::Southwell;
    let r = common::bake(&scene, &p);
    let mesh = &r.mesh;
    // The short block's footprint (mm, from the published data): a quadrilateral.
    let foot = [[130.0, 65.0], [82.0, 225.0], [240.0, 272.0], [290.0, 114.0]];
    let inside = |x: f64, z: f64| {
        (0..4).all(|k| {
            let (a, b) = (foot[k], foot[(k + 1) % 4]);
            (b[0] - a[0]) * (z - a[1]) - (b[1] - a[1]) * (x - a[0]) <= 0.0
        }) || (0..4).all(|k| {
            let (a, b) = (foot[k], foot[(k + 1) % 4]);
            (b[0] - a[0]) * (z - a[1]) - (b[1] - a[1]) * (x - a[0]) >= 0.0
        })
    };
    let floor_mean = r
        .surfaces
        .iter()
        .find(|s| s.name == "floor")
        .expect("floor")
        .mean[0];
    let (mut under, mut exact) = (0, 0);
    for (i, &id) in mesh.leaves.iter().enumerate() {
        let n = &mesh.nodes[id as usize];
        let name = &scene.surfaces[mesh.root_surface[n.root as usize] as usize].name;
        let c = mesh.frame.to_world(n.centroid) * 1000.0;
        if name == "floor" && inside(c.x, c.z) {
            under += 1;
            exact += usize::from(r.radiosity[i] == [0.0; 3]);
            let b = r.radiosity[i];
            assert!(
                b.iter().all(|&v| v <= 1e-4 * floor_mean),
                "floor element under the block at {c} is lit: {b:?}"
            );
        }
    }
    assert!(
        under > 10,
        "the test must see elements under the block ({under})"
    );
    assert!(
        exact * 10 >= under * 9,
        "only {exact} of {under} elements under the block are exactly 0"
    );
}
