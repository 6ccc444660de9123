//! Picks surface points of a scene lit by a directional light (a sun) for `radiant bake
//! --points` and `radiant reference --points`, classed by what the sun does around them:
//! `sunlit` (the point and a 15 cm disc around it all see the sun), `shadowed` (none of them
//! does), `edge` (some do: a shadow edge crosses the disc) and `contact` (the point is in the
//! open, but within 10 cm of it other geometry stands on the surface: a point of a 10 cm disc
//! is buried, the first face along the normal being the back of a single-sided one), whatever
//! the sun does there. Points are drawn by area over the static opaque triangles with a seeded
//! generator, so the same command gives the same file; where the scene has a camera, only
//! points it sees (unblocked, within its vertical field of view and the width of a 16:9 frame)
//! are kept: the points a player looks at. The classes are geometric (rays against the scene's
//! own BVH, alpha masks included), not taken from any bake.
//!
//! `cargo run --release --example sun_points -- SCENE.gltf OUT.csv [PER_CLASS] [SEED]`
//! writes `name,x,y,z,nx,ny,nz,class`, PER_CLASS (default 16) points of each class.
//! Sponza's (`tools/sponza_sun_points.csv`): PER_CLASS 16, SEED 1.

use glam::{DVec3, Vec3};
use radiant::scene::{AlphaMode, LightKind};
use radiant_visibility::{Bvh, Visibility};

/// Radius of the disc the sun's classes look at, metres.
const DISC: f64 = 0.15;
/// Radius of the disc the contact class looks at, metres.
const CONTACT: f64 = 0.10;
/// Points on the disc (and its centre).
const RING: usize = 16;

/// SplitMix64: a seeded generator of uniform numbers.
struct Rng(u64);

impl Rng {
    fn f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(scene_path), Some(out)) = (args.first(), args.get(1)) else {
        anyhow::bail!("usage: sun_points SCENE.gltf OUT.csv [PER_CLASS] [SEED]");
    };
    let per_class: usize = args.get(2).map_or(Ok(16), |s| s.parse())?;
    let seed: u64 = args.get(3).map_or(Ok(1), |s| s.parse())?;
    let scene = radiant::scene::load_gltf(std::path::Path::new(scene_path))?;
    let sun = scene
        .lights
        .iter()
        .find(|l| matches!(l.kind, LightKind::Directional))
        .ok_or_else(|| anyhow::anyhow!("{scene_path}: no directional light"))?;
    let to_sun = -sun.direction.normalize();
    let tris: Vec<[Vec3; 3]> = scene
        .triangles
        .iter()
        .map(|t| t.vertices.map(|v| v.as_vec3()))
        .collect();
    // With the alpha masks, as the bake and the path tracer see them.
    let bvh = match radiant::scene::texture::AlphaMasks::new(&scene).map(std::sync::Arc::new) {
        Some(masks) => {
            let marks = std::sync::Arc::clone(&masks);
            Bvh::with_filter(
                &tris,
                move |t| marks.is_masked(t),
                std::sync::Arc::new(move |t, u, v| masks.blocks(t, u, v)),
            )
        }
        None => Bvh::new(&tris),
    };
    let lo = scene
        .triangles
        .iter()
        .flat_map(|t| t.vertices)
        .fold(DVec3::MAX, DVec3::min);
    let hi = scene
        .triangles
        .iter()
        .flat_map(|t| t.vertices)
        .fold(DVec3::MIN, DVec3::max);
    let reach = (hi - lo).length() * 2.0;
    let lift = radiant::radiosity::points::lift(&scene);
    let sees_sun = |p: DVec3, n: DVec3| {
        let a = p + n * 1e-3;
        bvh.segment_clear(a.as_vec3(), (a + to_sun * reach).as_vec3())
    };
    // Static triangles facing the sun less than grazing, drawn by area.
    let candidates: Vec<usize> = (0..scene.triangles.len())
        .filter(|&i| {
            let t = &scene.triangles[i];
            let s = &scene.surfaces[t.surface as usize];
            !s.dynamic
                && !s.is_emitter()
                && s.alpha == AlphaMode::Opaque
                && t.cross().normalize_or_zero().dot(to_sun) > 0.2
        })
        .collect();
    let mut cumulative = Vec::with_capacity(candidates.len());
    let mut total = 0.0;
    for &i in &candidates {
        total += scene.triangles[i].area();
        cumulative.push(total);
    }
    anyhow::ensure!(total > 0.0, "no triangle faces the sun");
    let mut rng = Rng(seed);
    let mut rows = Vec::new();
    let mut counts = [0usize; 4];
    let names = ["sunlit", "shadowed", "edge", "contact"];
    for _ in 0..2_000_000 {
        if counts.iter().all(|&c| c >= per_class) {
            break;
        }
        let r = rng.f64() * total;
        let k = cumulative
            .partition_point(|&c| c < r)
            .min(candidates.len() - 1);
        let t = &scene.triangles[candidates[k]];
        let (mut a, mut b) = (rng.f64(), rng.f64());
        if a + b > 1.0 {
            (a, b) = (1.0 - a, 1.0 - b);
        }
        let [v0, v1, v2] = t.vertices;
        let p = v0 + (v1 - v0) * a + (v2 - v0) * b;
        let n = t.cross().normalize();
        // Where `radiant reference` and `bake --points` will find it, with no doubt left by
        // rounding: nothing between the point and their lift along the normal, and its own
        // triangle's front the first face met from there.
        let from = (p + n * lift).as_vec3();
        let clear_above = bvh
            .closest_hit(from, (-n).as_vec3(), (0.99 * lift) as f32)
            .is_none();
        let own = bvh
            .closest_hit(from, (-n).as_vec3(), (1.01 * lift) as f32)
            .is_some_and(|h| h.front && h.triangle as usize == candidates[k]);
        if !(clear_above && own) {
            continue;
        }
        if let Some(cam) = &scene.camera {
            let to = p - cam.position;
            let f = cam.forward.normalize();
            let up = cam.up.normalize();
            let right = f.cross(up).normalize();
            let z = to.dot(f);
            let tan = (cam.yfov * 0.5).tan();
            let in_frame = z > 0.0
                && to.dot(up).abs() <= tan * z
                && to.dot(right).abs() <= tan * z * 16.0 / 9.0;
            let seen = in_frame
                && n.dot(to) < 0.0
                && bvh.segment_clear(cam.position.as_vec3(), (p + n * 1e-3).as_vec3());
            if !seen {
                continue;
            }
        }
        let (u, w) = n.any_orthonormal_pair();
        let lit_centre = sees_sun(p, n);
        let lit_ring = (0..RING)
            .filter(|&j| {
                let phi = std::f64::consts::TAU * j as f64 / RING as f64;
                sees_sun(p + (u * phi.cos() + w * phi.sin()) * DISC, n)
            })
            .count();
        let buried = |x: DVec3| {
            bvh.closest_hit((x + n * 1e-4).as_vec3(), n.as_vec3(), f32::MAX)
                .is_some_and(|h| {
                    let s = scene.triangles[h.triangle as usize].surface as usize;
                    !h.front && !scene.surfaces[s].double_sided
                })
        };
        if buried(p) {
            continue;
        }
        let near_contact = (0..RING).any(|j| {
            let phi = std::f64::consts::TAU * j as f64 / RING as f64;
            buried(p + (u * phi.cos() + w * phi.sin()) * CONTACT)
        });
        let class = match (near_contact, lit_centre, lit_ring) {
            (true, _, _) => 3,
            (false, true, l) if l == RING => 0,
            (false, false, 0) => 1,
            _ => 2,
        };
        if counts[class] >= per_class {
            continue;
        }
        counts[class] += 1;
        rows.push(format!(
            "{}_{:02},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{}",
            names[class], counts[class], p.x, p.y, p.z, n.x, n.y, n.z, names[class]
        ));
    }
    rows.sort();
    let mut text = String::from("name,x,y,z,nx,ny,nz,class\n");
    for r in rows {
        text.push_str(&r);
        text.push('\n');
    }
    std::fs::write(out, text)?;
    println!(
        "wrote {out}: {} sunlit, {} shadowed, {} edge, {} contact points",
        counts[0], counts[1], counts[2], counts[3]
    );
    Ok(())
}
