//! Direct illumination from punctual lights (KHR_lights_punctual), with shadow rays.
//!
//! A point or spot light of intensity `I` (candela) at distance `d` gives irradiance
//! `E = I cos θ / d²`; a directional light of illuminance `E⊥` (lux) gives `E⊥ cos θ`. The
//! radiosity it adds to an element, in emissive units, is `ρ E / π`. Range follows the glTF
//! recommendation `clamp(1 - (d / range)⁴, 0, 1)`; spot cones use glTF's smooth falloff.

use radiant_scene::{Light, LightKind};
use radiant_visibility::Visibility;

use crate::mesh::Mesh;

/// Irradiance (linear RGB, lux) at each element's centroid from all lights, with shadows.
pub fn direct_irradiance(mesh: &Mesh, lights: &[Light], vis: &dyn Visibility) -> Vec<[f64; 3]> {
    use rayon::prelude::*;
    let frame = mesh.frame;
    let mut out = vec![[0.0; 3]; mesh.element_count()];
    // Per element, the lights in order: the same sums on any number of threads.
    out.par_iter_mut()
        .with_min_len(256)
        .enumerate()
        .for_each(|(leaf, e)| {
            for light in lights {
                let local = frame.to_local(light.position);
                light_one(mesh, frame, light, local, leaf, e, vis);
            }
        });
    out
}

#[inline]
fn light_one(
    mesh: &Mesh,
    frame: crate::mesh::Frame,
    light: &Light,
    local: glam::DVec3,
    leaf: usize,
    e: &mut [f64; 3],
    vis: &dyn Visibility,
) {
    let node = mesh.leaf_node(leaf as u32);
    let x = node.centroid;
    let (to_light, dist_world, target) = match light.kind {
        LightKind::Directional => {
            let d = -light.direction;
            (d, 1.0, x + d * 4.0)
        }
        _ => {
            let d = local - x;
            let len = d.length();
            if len <= 0.0 {
                return;
            }
            (d / len, len * frame.scale, local)
        }
    };
    let cos = node.normal.dot(to_light);
    if cos <= 0.0 {
        return;
    }
    let mut irr = light.intensity * cos;
    match light.kind {
        LightKind::Directional => {}
        LightKind::Point | LightKind::Spot { .. } => {
            irr /= dist_world * dist_world;
            if let Some(range) = light.range {
                let q = (dist_world / range).powi(4);
                irr *= (1.0 - q).clamp(0.0, 1.0);
            }
        }
    }
    if let LightKind::Spot {
        inner_cone_angle,
        outer_cone_angle,
    } = light.kind
    {
        let cd = light.direction.dot(-to_light);
        let (ci, co) = (inner_cone_angle.cos(), outer_cone_angle.cos());
        let t = ((cd - co) / (ci - co).max(1e-9)).clamp(0.0, 1.0);
        irr *= t * t;
    }
    if !(irr > 0.0 && irr.is_finite()) {
        return;
    }
    if !vis.segment_clear(x.as_vec3(), target.as_vec3()) {
        return;
    }
    for c in 0..3 {
        e[c] += irr * light.color[c];
    }
}
