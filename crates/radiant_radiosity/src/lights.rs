//! Direct illumination from punctual lights (KHR_lights_punctual), with shadow rays.
//!
//! A point or spot light of intensity `I` (candela) at distance `d` gives irradiance
//! `E = I cos θ / d²`; a directional light of illuminance `E⊥` (lux) gives `E⊥ cos θ`. The
//! radiosity it adds to an element, in emissive units, is `ρ E / π`. Range follows the glTF
//! recommendation `clamp(1 - (d / range)⁴, 0, 1)`; spot cones use glTF's smooth falloff. The
//! formulas are `radiant_scene::Light::irradiance`, which the reference path tracer uses too.

use radiant_scene::{Light, LightKind};
use radiant_visibility::Visibility;

use crate::mesh::Mesh;

/// Irradiance (linear RGB, lux) from all lights, with shadows, per element: the mean over
/// its [`crate::exposure::POINTS`] points, one at random in each ninth of it (as the exposure
/// probes take them), a shadow ray each. One ray from the centroid was biased where regular
/// geometry casts regular shadows: on Sponza's floor and arches the centroids lay in shadow
/// more often than the elements did (their sun 16 % and 28 % below the nine points' mean).
pub fn direct_irradiance(mesh: &Mesh, lights: &[Light], vis: &dyn Visibility) -> Vec<[f64; 3]> {
    use rayon::prelude::*;
    let mut out = vec![[0.0; 3]; mesh.element_count()];
    // Per element, the lights in order: the same sums on any number of threads.
    out.par_iter_mut()
        .with_min_len(256)
        .enumerate()
        .for_each(|(leaf, e)| *e = irradiance_at(mesh, lights, vis, leaf));
    out
}

/// [`direct_irradiance`] of one element.
pub fn irradiance_at(mesh: &Mesh, lights: &[Light], vis: &dyn Visibility, leaf: usize) -> [f64; 3] {
    let frame = mesh.frame;
    let node = mesh.leaf_node(leaf as u32);
    let points = shadow_points(mesh, leaf);
    let mut e = [0.0; 3];
    for light in lights {
        let local = frame.to_local(light.position);
        for &x in &points {
            light_one(frame, light, local, (x, node.normal), &mut e, vis);
        }
    }
    e.map(|v| v / points.len() as f64)
}

/// The points of element `leaf` whose shadow rays [`irradiance_at`] casts. Seeded by the
/// element's stable id alone: the light map takes the same direct part out of the field as the
/// bake put in, bit for bit (`texel_light`), and an edit knows which rays a change can meet.
pub(crate) fn shadow_points(mesh: &Mesh, leaf: usize) -> [glam::DVec3; crate::exposure::POINTS] {
    let node = mesh.leaf_node(leaf as u32);
    let id = mesh.stable_id(mesh.leaves[leaf]);
    let mut rng = crate::rng::Rng::new(crate::rng::hash(0x11_6475, id, 0));
    crate::exposure::points(&node.v, &mut rng)
}

/// Adds `light`'s direct irradiance at `x` (normal `n`; the mesh's `frame`, the light at
/// `local` there) to `e` where a shadow ray reaches it.
#[inline]
pub(crate) fn light_one(
    frame: crate::mesh::Frame,
    light: &Light,
    local: glam::DVec3,
    (x, n): (glam::DVec3, glam::DVec3),
    e: &mut [f64; 3],
    vis: &dyn Visibility,
) {
    let Some((irr, target)) = unshadowed(frame, light, local, x, n) else {
        return;
    };
    if !vis.segment_clear(x.as_vec3(), target.as_vec3()) {
        return;
    }
    for c in 0..3 {
        e[c] += irr * light.color[c];
    }
}

/// `light`'s irradiance at `x` (unit normal `n`; both in the mesh's `frame`, the light at
/// `local` there) before shadows, and the point a shadow ray from `x` runs to; `None` where
/// it gives none. What the elements' direct light and the light map's per texel share.
#[inline]
pub(crate) fn unshadowed(
    frame: crate::mesh::Frame,
    light: &Light,
    local: glam::DVec3,
    x: glam::DVec3,
    n: glam::DVec3,
) -> Option<(f64, glam::DVec3)> {
    let (to_light, dist_world, target) = match light.kind {
        LightKind::Directional => {
            let d = -light.direction;
            (d, 1.0, x + d * 4.0)
        }
        _ => {
            let d = local - x;
            let len = d.length();
            if len <= 0.0 {
                return None;
            }
            (d / len, len * frame.scale, local)
        }
    };
    let irr = light.irradiance(to_light, n.dot(to_light), dist_world);
    (irr > 0.0).then_some((irr, target))
}
