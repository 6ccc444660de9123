//! The hemicube (Cohen & Greenberg 1985), rasterised on the CPU.
//!
//! Around the receiver's centroid, the input triangles are projected onto the top face and the
//! four upper half side faces of a unit hemicube and depth-tested; each pixel then adds its delta
//! form factor to the source node that owns the visible point. The delta form factors are
//! normalised to sum to exactly 1, so a closed scene has row sums of exactly 1. Aliasing (small
//! or distant sources falling between pixel centres) is the method's known fault; the resolution
//! is a parameter so its cost and error can be measured.

use glam::DVec3;

use super::{FfContext, FormFactorKind, FormFactorMethod, Row, basis, find_source};

/// The hemicube method.
pub struct HemicubeMethod;

/// Normalised delta form factors for the top face (`res × res`) and one side face
/// (`res × res/2`, row 0 at the horizon).
pub(crate) fn delta_form_factors(res: u32) -> (Vec<f64>, Vec<f64>) {
    let res = res.max(2) & !1;
    let h = res / 2;
    let d = 2.0 / f64::from(res);
    let c = |i: u32| -1.0 + (f64::from(i) + 0.5) * d;
    let mut top = Vec::with_capacity((res * res) as usize);
    for j in 0..res {
        for i in 0..res {
            let (x, y) = (c(i), c(j));
            top.push(d * d / (std::f64::consts::PI * (x * x + y * y + 1.0).powi(2)));
        }
    }
    let mut side = Vec::with_capacity((res * h) as usize);
    for j in 0..h {
        for i in 0..res {
            let (x, z) = (c(i), (f64::from(j) + 0.5) * d);
            side.push(z * d * d / (std::f64::consts::PI * (x * x + z * z + 1.0).powi(2)));
        }
    }
    let total: f64 = top.iter().sum::<f64>() + 4.0 * side.iter().sum::<f64>();
    top.iter_mut().for_each(|v| *v /= total);
    side.iter_mut().for_each(|v| *v /= total);
    (top, side)
}

impl FormFactorMethod for HemicubeMethod {
    fn kind(&self) -> FormFactorKind {
        FormFactorKind::Hemicube
    }

    fn compute(&self, ctx: &FfContext, row: &Row, out: &mut [f32]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let res = ctx.params.hemicube_resolution.clamp(2, 4096) & !1;
        let (top, side) = delta_form_factors(res);
        let r = ctx.mesh.leaf_node(row.leaf);
        let (x, n) = (r.centroid, r.normal);
        let (t, b) = basis(n);
        // (forward, right, up, rows): the top face, then the four sides with the normal up.
        let faces = [
            (n, t, b, res),
            (t, b, n, res / 2),
            (-t, -b, n, res / 2),
            (b, -t, n, res / 2),
            (-b, t, n, res / 2),
        ];
        let mut acc = vec![0.0f64; row.sources.len()];
        let mut depth = vec![f64::INFINITY; (res * res) as usize];
        let mut owner = vec![u32::MAX; (res * res) as usize];
        for (fi, &(f, u, w, rows)) in faces.iter().enumerate() {
            let pixels = (res * rows) as usize;
            depth[..pixels].iter_mut().for_each(|d| *d = f64::INFINITY);
            owner[..pixels].iter_mut().for_each(|o| *o = u32::MAX);
            let y0 = if fi == 0 { -1.0 } else { 0.0 };
            for (ti, &root) in ctx.mesh.roots.iter().enumerate() {
                let tri = &ctx.mesh.nodes[root as usize];
                if tri.v.iter().all(|p| n.dot(*p - x) <= 0.0) {
                    continue;
                }
                let local = tri.v.map(|p| {
                    let q = p - x;
                    DVec3::new(q.dot(u), q.dot(w), q.dot(f))
                });
                raster(&local, res, rows, y0, |pix, depth_of| {
                    let dz = depth_of;
                    if dz < depth[pix] {
                        depth[pix] = dz;
                        owner[pix] = ti as u32;
                    }
                });
            }
            let weights = if fi == 0 { &top } else { &side };
            for (pix, &o) in owner[..pixels].iter().enumerate() {
                if o == u32::MAX {
                    continue;
                }
                let tri = &ctx.mesh.nodes[ctx.mesh.roots[o as usize] as usize];
                let (i, j) = (pix as u32 % res, pix as u32 / res);
                let sx = -1.0 + (f64::from(i) + 0.5) * 2.0 / f64::from(res);
                let sy = y0 + (f64::from(j) + 0.5) * 2.0 / f64::from(res);
                let dir = u * sx + w * sy + f;
                // Front side only: back faces occlude but do not emit.
                if dir.dot(tri.normal) >= 0.0 {
                    continue;
                }
                let Some((bu, bv)) = barycentric_hit(x, dir, &tri.v) else {
                    continue;
                };
                let leaf = ctx.mesh.locate(o, bu, bv);
                if let Some(k) = find_source(ctx.mesh, row.sources, leaf) {
                    acc[k] += weights[pix];
                }
            }
        }
        for (o, a) in out.iter_mut().zip(acc) {
            *o = a.clamp(0.0, 1.0) as f32;
        }
    }
}

/// Barycentric `(u, v)` of where the ray `x + s·dir` meets the triangle's plane, clamped into
/// the triangle (pixel centres can fall a hair outside).
fn barycentric_hit(x: DVec3, dir: DVec3, v: &[DVec3; 3]) -> Option<(f64, f64)> {
    let (e1, e2) = (v[1] - v[0], v[2] - v[0]);
    let nrm = e1.cross(e2);
    let denom = nrm.dot(dir);
    if denom == 0.0 {
        return None;
    }
    let s = nrm.dot(v[0] - x) / denom;
    let p = x + dir * s - v[0];
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (p1, p2) = (p.dot(e1), p.dot(e2));
    let det = d11 * d22 - d12 * d12;
    if det <= 0.0 {
        return None;
    }
    let mut bu = ((d22 * p1 - d12 * p2) / det).clamp(0.0, 1.0);
    let mut bv = ((d11 * p2 - d12 * p1) / det).clamp(0.0, 1.0);
    if bu + bv > 1.0 {
        let s = bu + bv;
        bu /= s;
        bv /= s;
    }
    (bu.is_finite() && bv.is_finite()).then_some((bu, bv))
}

/// Rasterises a triangle given in face coordinates (right, up, forward): clips it to
/// `forward > near`, projects it, and calls `emit(pixel, depth)` for each covered pixel centre,
/// with the depth along the pixel's ray (forward distance).
fn raster(tri: &[DVec3; 3], res: u32, rows: u32, y0: f64, mut emit: impl FnMut(usize, f64)) {
    const NEAR: f64 = 1e-9;
    let mut poly = [DVec3::ZERO; 4];
    let mut m = 0;
    for k in 0..3 {
        let (a, b) = (tri[k], tri[(k + 1) % 3]);
        if a.z >= NEAR {
            poly[m] = a;
            m += 1;
        }
        if (a.z >= NEAR) != (b.z >= NEAR) {
            let t = (NEAR - a.z) / (b.z - a.z);
            poly[m] = a + (b - a) * t;
            m += 1;
        }
    }
    if m < 3 {
        return;
    }
    let scr: Vec<(f64, f64)> = poly[..m].iter().map(|p| (p.x / p.z, p.y / p.z)).collect();
    // Plane of the triangle in face coordinates: depth along the pixel ray (sx, sy, 1).
    let nrm = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
    let num = nrm.dot(tri[0]);
    let (mut lo_x, mut hi_x, mut lo_y, mut hi_y) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(sx, sy) in &scr {
        lo_x = lo_x.min(sx);
        hi_x = hi_x.max(sx);
        lo_y = lo_y.min(sy);
        hi_y = hi_y.max(sy);
    }
    let px = 2.0 / f64::from(res);
    let to_i = |v: f64, lo: f64, n: u32| (((v - lo) / px - 0.5).clamp(-1.0, f64::from(n))) as i64;
    let (i0, i1) = (
        to_i(lo_x, -1.0, res).max(0),
        (to_i(hi_x, -1.0, res) + 1).min(i64::from(res) - 1),
    );
    let (j0, j1) = (
        to_i(lo_y, y0, rows).max(0),
        (to_i(hi_y, y0, rows) + 1).min(i64::from(rows) - 1),
    );
    if i0 > i1 || j0 > j1 {
        return;
    }
    let area: f64 = (0..m)
        .map(|k| {
            let (a, b) = (scr[k], scr[(k + 1) % m]);
            a.0 * b.1 - a.1 * b.0
        })
        .sum();
    if area == 0.0 || !area.is_finite() {
        return;
    }
    let sign = area.signum();
    for j in j0..=j1 {
        let sy = y0 + (j as f64 + 0.5) * px;
        for i in i0..=i1 {
            let sx = -1.0 + (i as f64 + 0.5) * px;
            // A hair of tolerance makes the raster watertight: a pixel centre on an edge shared
            // by two triangles must not fall through both by rounding (the depth test then
            // picks one of the two).
            let inside = (0..m).all(|k| {
                let (a, b) = (scr[k], scr[(k + 1) % m]);
                let e = (b.0 - a.0) * (sy - a.1) - (b.1 - a.1) * (sx - a.0);
                sign * e >= -1e-9 * ((b.0 - a.0).abs() + (b.1 - a.1).abs())
            });
            if inside {
                let den = nrm.dot(DVec3::new(sx, sy, 1.0));
                let d = if den != 0.0 { num / den } else { f64::INFINITY };
                if d > 0.0 {
                    emit((j as u32 * res + i as u32) as usize, d);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn delta_form_factors_sum_to_one() {
        for res in [2, 16, 100] {
            let (top, side) = super::delta_form_factors(res);
            let s: f64 = top.iter().sum::<f64>() + 4.0 * side.iter().sum::<f64>();
            assert!((s - 1.0).abs() < 1e-12);
        }
    }
}
