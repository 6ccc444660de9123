//! Rays per second for the BVH against brute force, on the Cornell box's triangles.
use criterion::{Criterion, criterion_group, criterion_main};
use glam::Vec3;
use radiant_visibility::{BruteForce, Bvh, Visibility};
use std::hint::black_box;

fn grid(n: usize) -> Vec<[Vec3; 3]> {
    // n x n quads of a unit box's floor and walls plus some floating blockers.
    let mut tris = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let (x, z, s) = (i as f32 / n as f32, j as f32 / n as f32, 1.0 / n as f32);
            tris.push([
                Vec3::new(x, 0.0, z),
                Vec3::new(x + s, 0.0, z),
                Vec3::new(x, 0.0, z + s),
            ]);
            tris.push([
                Vec3::new(x, 1.0, z),
                Vec3::new(x + s, 1.0, z),
                Vec3::new(x, 1.0, z + s),
            ]);
            tris.push([
                Vec3::new(0.0, x, z),
                Vec3::new(0.0, x + s, z),
                Vec3::new(0.0, x, z + s),
            ]);
            if (i * 7 + j * 3) % 11 == 0 {
                let y = 0.3 + 0.4 * ((i + j) % 5) as f32 / 5.0;
                tris.push([
                    Vec3::new(x, y, z),
                    Vec3::new(x + s, y, z),
                    Vec3::new(x, y, z + s),
                ]);
            }
        }
    }
    tris
}

fn bench(c: &mut Criterion) {
    let tris = grid(24);
    let bvh = Bvh::new(&tris);
    let brute = BruteForce::new(&tris);
    let rays: Vec<(Vec3, Vec3)> = (0..1024)
        .map(|k| {
            let f = |m: u32| ((k as u32).wrapping_mul(m) % 1000) as f32 / 1000.0;
            (
                Vec3::new(f(7919), 0.01, f(104729)),
                Vec3::new(f(1299709), 0.99, f(15485863)),
            )
        })
        .collect();
    let mut g = c.benchmark_group("segment_clear_1024_rays");
    g.bench_function("bvh", |b| {
        b.iter(|| {
            rays.iter()
                .filter(|(a, e)| bvh.segment_clear(*a, *e))
                .count()
        })
    });
    g.bench_function("brute_force", |b| {
        b.iter(|| {
            rays.iter()
                .filter(|(a, e)| brute.segment_clear(*a, *e))
                .count()
        })
    });
    g.finish();
    c.bench_function("bvh_build_1800_tris", |b| {
        b.iter(|| Bvh::new(black_box(&tris)))
    });
}

#[allow(
    missing_docs,
    reason = "criterion_group! generates an undocumented function"
)]
mod group {
    use super::*;
    criterion_group!(benches, bench);
}
use group::benches;
criterion_main!(benches);
