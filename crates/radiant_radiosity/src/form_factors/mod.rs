//! Form factors: four methods behind one trait, so they can be compared on the same scene.
//!
//! Every method answers the same question: for a receiver element (a leaf, sampled at its
//! centroid) and a list of disjoint source nodes, what fraction of the energy arriving at the
//! receiver's point comes from each source, occlusion included. Which source nodes a receiver
//! links to is decided once, by the hierarchical refinement in [`crate::links`], with the exact
//! unoccluded analytic value as the oracle; the method then computes the link values.
//!
//! | method | visibility | row sums in a closed scene |
//! |---|---|---|
//! | [`FormFactorKind::Analytic`] | rays to stratified points on the source | exactly 1 (unoccluded) |
//! | [`FormFactorKind::Hemicube`] | z-buffer | exactly 1 (normalised delta form factors) |
//! | [`FormFactorKind::RayCast`] | per sample ray (Wallace et al. 1989) | ≈ 1 (disc approximation) |
//! | [`FormFactorKind::MonteCarlo`] | first hit of cosine-distributed rays | exactly 1 |

pub mod analytic;
pub mod hemicube;

use glam::DVec3;
use radiant_visibility::Visibility;

use crate::mesh::Mesh;
use crate::rng::{Rng, hash};

/// The form-factor methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FormFactorKind {
    /// Lambert's contour integral to the source polygon, times a ray-traced visibility fraction.
    Analytic,
    /// Cohen & Greenberg's hemicube: rasterise the scene around the receiver.
    Hemicube,
    /// Wallace, Elmquist & Haines 1989: rays to sample points on the source, disc approximation.
    RayCast,
    /// Monte Carlo hemisphere sampling (Nusselt's analogue): cosine-distributed rays.
    MonteCarlo,
}

impl FormFactorKind {
    /// All methods, in the order reports list them.
    pub const ALL: [FormFactorKind; 4] = [
        Self::Analytic,
        Self::Hemicube,
        Self::RayCast,
        Self::MonteCarlo,
    ];

    /// The CLI name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Analytic => "analytic",
            Self::Hemicube => "hemicube",
            Self::RayCast => "raycast",
            Self::MonteCarlo => "montecarlo",
        }
    }

    /// Other names each method is known by.
    pub const ALIASES: &[(&str, FormFactorKind)] = &[
        ("ray-cast", Self::RayCast),
        ("monte-carlo", Self::MonteCarlo),
    ];

    /// Parses a CLI name or an alias.
    pub fn parse(s: &str) -> Option<Self> {
        (Self::ALL.into_iter().find(|k| k.name() == s))
            .or_else(|| Self::ALIASES.iter().find(|(a, _)| *a == s).map(|&(_, k)| k))
    }
}

/// Parameters of the form-factor methods.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FormFactorParams {
    /// Hemicube: pixels along the full top face's edge (default: 128).
    pub hemicube_resolution: u32,
    /// Monte Carlo: rays per receiver (default: 256).
    pub monte_carlo_rays: u32,
    /// Ray-cast: minimum sample points per source node; nodes that subtend more get up to 256
    /// (default: 4).
    pub ray_cast_samples: u32,
    /// Sky light: rays per element, stratified (default: 64).
    pub sky_rays: u32,
    /// Seed for every random choice; results depend on nothing else (default: 1).
    pub seed: u64,
}

impl Default for FormFactorParams {
    fn default() -> Self {
        FormFactorParams {
            hemicube_resolution: 128,
            monte_carlo_rays: 256,
            ray_cast_samples: 4,
            sky_rays: 64,
            seed: 1,
        }
    }
}

/// What a method needs to see the scene.
pub struct FfContext<'a> {
    /// The element hierarchy.
    pub mesh: &'a Mesh,
    /// Visibility over the input triangles (local frame, index = input triangle).
    pub vis: &'a dyn Visibility,
    /// Method parameters.
    pub params: FormFactorParams,
}

/// One receiver's links, given to a method to fill in.
pub struct Row<'a> {
    /// The receiver element.
    pub leaf: u32,
    /// Source nodes, disjoint and sorted by their first leaf.
    pub sources: &'a [u32],
    /// The unoccluded analytic value of each link (from the refinement).
    pub unoccluded: &'a [f64],
    /// Visibility samples the refinement asks for on each link (≥ 1).
    pub samples: &'a [u8],
}

/// A form-factor method.
pub trait FormFactorMethod: Send + Sync {
    /// Which method this is.
    fn kind(&self) -> FormFactorKind;
    /// Writes the form factor of each link of `row` into `out` (same length as `row.sources`).
    fn compute(&self, ctx: &FfContext, row: &Row, out: &mut [f32]);
}

/// The method of a kind.
pub fn method(kind: FormFactorKind) -> &'static dyn FormFactorMethod {
    match kind {
        FormFactorKind::Analytic => &AnalyticMethod,
        FormFactorKind::Hemicube => &hemicube::HemicubeMethod,
        FormFactorKind::RayCast => &RayCastMethod,
        FormFactorKind::MonteCarlo => &MonteCarloMethod,
    }
}

/// A uniformly distributed point on a triangle, from two uniform numbers in [0, 1).
#[inline]
pub fn sample_triangle(v: &[DVec3; 3], r1: f64, r2: f64) -> DVec3 {
    let (a, b) = if r1 + r2 > 1.0 {
        (1.0 - r1, 1.0 - r2)
    } else {
        (r1, r2)
    };
    v[0] + (v[1] - v[0]) * a + (v[2] - v[0]) * b
}

/// Stratified sample `k` of `n` in the unit square, jittered by `rng`.
#[inline]
/// A perfect-square `n` gets an `m × m` jittered grid; any other `n` is stratified along the
/// first coordinate only, so that every sample keeps the weight `1/n` without bias.
fn stratified(k: u32, n: u32, rng: &mut Rng) -> (f64, f64) {
    let m = (n as f64).sqrt().round() as u32;
    if m * m == n {
        let (i, j) = (k % m, k / m);
        (
            (i as f64 + rng.f64()) / m as f64,
            (j as f64 + rng.f64()) / m as f64,
        )
    } else {
        ((k as f64 + rng.f64()) / n as f64, rng.f64())
    }
}

/// A ray origin just off an element's front face: far enough that rounding to `f32` cannot put
/// it behind its own triangle (the local frame has unit extent), near enough to see everything.
pub(crate) fn ray_origin(centroid: DVec3, normal: DVec3) -> glam::Vec3 {
    (centroid + normal * 1e-5).as_vec3()
}

/// Fraction of `n` segments from `x` to stratified points on `node`'s triangle that are clear.
/// Points behind the receiver's tangent plane do not count.
fn visible_fraction(ctx: &FfContext, x: DVec3, nx: DVec3, node: u32, n: u32, rng: &mut Rng) -> f64 {
    let v = &ctx.mesh.nodes[node as usize].v;
    let (mut clear, mut valid) = (0u32, 0u32);
    let xf = x.as_vec3();
    for k in 0..n {
        let (r1, r2) = stratified(k, n, rng);
        let p = sample_triangle(v, r1, r2);
        if nx.dot(p - x) <= 0.0 {
            continue;
        }
        valid += 1;
        if ctx.vis.segment_clear(xf, p.as_vec3()) {
            clear += 1;
        }
    }
    if valid == 0 {
        1.0
    } else {
        f64::from(clear) / f64::from(valid)
    }
}

/// Lambert's contour integral times a visibility fraction.
pub struct AnalyticMethod;

impl FormFactorMethod for AnalyticMethod {
    fn kind(&self) -> FormFactorKind {
        FormFactorKind::Analytic
    }
    fn compute(&self, ctx: &FfContext, row: &Row, out: &mut [f32]) {
        let r = ctx.mesh.leaf_node(row.leaf);
        for (k, &s) in row.sources.iter().enumerate() {
            let mut rng = Rng::new(hash(
                ctx.params.seed,
                ctx.mesh.stable_id(ctx.mesh.leaves[row.leaf as usize]),
                ctx.mesh.stable_id(s),
            ));
            let v = visible_fraction(
                ctx,
                r.centroid,
                r.normal,
                s,
                u32::from(row.samples[k]),
                &mut rng,
            );
            out[k] = (row.unoccluded[k] * v) as f32;
        }
    }
}

/// Wallace, Elmquist & Haines 1989: the source is split into `n` equal parts, each a disc of
/// its area, `F ≈ Σ V_k (A/n) cos θ_r cos θ_s / (π r² + A/n)`.
pub struct RayCastMethod;

impl FormFactorMethod for RayCastMethod {
    fn kind(&self) -> FormFactorKind {
        FormFactorKind::RayCast
    }
    fn compute(&self, ctx: &FfContext, row: &Row, out: &mut [f32]) {
        let r = ctx.mesh.leaf_node(row.leaf);
        let x = r.centroid;
        for (k, &s) in row.sources.iter().enumerate() {
            let node = &ctx.mesh.nodes[s as usize];
            // More samples where the source subtends more (Wallace et al. subdivide the source
            // until each disc is small against its distance): the disc approximation
            // underestimates near sources.
            let by_size = (row.unoccluded[k] * 256.0).ceil().min(256.0) as u32;
            let want = u32::from(row.samples[k])
                .max(ctx.params.ray_cast_samples)
                .max(by_size)
                .max(1);
            // A square number of samples gets a 2D stratified grid.
            let side = (f64::from(want)).sqrt().ceil() as u32;
            let n = side * side;
            let da = node.area / f64::from(n);
            let mut rng = Rng::new(hash(
                ctx.params.seed ^ 0x5A5A,
                ctx.mesh.stable_id(ctx.mesh.leaves[row.leaf as usize]),
                ctx.mesh.stable_id(s),
            ));
            let mut f = 0.0;
            for i in 0..n {
                let (r1, r2) = stratified(i, n, &mut rng);
                let p = sample_triangle(&node.v, r1, r2);
                let d = p - x;
                let d2 = d.length_squared();
                let cr = r.normal.dot(d);
                let cs = -node.normal.dot(d);
                if cr <= 0.0 || cs <= 0.0 || d2 <= 0.0 {
                    continue;
                }
                if ctx.vis.segment_clear(x.as_vec3(), p.as_vec3()) {
                    // cos θ = (n·d)/|d| on both ends.
                    f += da * (cr * cs / d2) / (std::f64::consts::PI * d2 + da);
                }
            }
            out[k] = f.clamp(0.0, 1.0) as f32;
        }
    }
}

/// Cosine-distributed rays from the receiver; each front-side hit counts for the source node that
/// contains it (the Nusselt analogue, sampled).
pub struct MonteCarloMethod;

impl FormFactorMethod for MonteCarloMethod {
    fn kind(&self) -> FormFactorKind {
        FormFactorKind::MonteCarlo
    }
    fn compute(&self, ctx: &FfContext, row: &Row, out: &mut [f32]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        let r = ctx.mesh.leaf_node(row.leaf);
        let (t, b) = basis(r.normal);
        let n = ctx.params.monte_carlo_rays.max(1);
        let mut rng = Rng::new(hash(
            ctx.params.seed ^ 0xC0FFEE,
            ctx.mesh.stable_id(ctx.mesh.leaves[row.leaf as usize]),
            0,
        ));
        let mut counts = vec![0u32; row.sources.len()];
        for i in 0..n {
            let (u1, u2) = stratified(i, n, &mut rng);
            // Malley's method: uniform on the disc, projected up.
            let (rad, phi) = (u1.sqrt(), std::f64::consts::TAU * u2);
            let z = (1.0 - u1).max(0.0).sqrt();
            let dir = t * (rad * phi.cos()) + b * (rad * phi.sin()) + r.normal * z;
            let Some(hit) = ctx.vis.closest_hit(
                ray_origin(r.centroid, r.normal),
                dir.as_vec3(),
                f32::INFINITY,
            ) else {
                continue;
            };
            if !hit.front {
                continue;
            }
            let leaf = ctx
                .mesh
                .locate(hit.triangle, f64::from(hit.u), f64::from(hit.v));
            if let Some(k) = find_source(ctx.mesh, row.sources, leaf) {
                counts[k] += 1;
            }
        }
        for (o, c) in out.iter_mut().zip(counts) {
            *o = (f64::from(c) / f64::from(n)) as f32;
        }
    }
}

/// The index of the source node (sorted by first leaf, disjoint) that contains `leaf`.
pub(crate) fn find_source(mesh: &Mesh, sources: &[u32], leaf: u32) -> Option<usize> {
    let k = sources.partition_point(|&s| mesh.nodes[s as usize].leaf_lo <= leaf);
    if k == 0 {
        return None;
    }
    let n = &mesh.nodes[sources[k - 1] as usize];
    (leaf < n.leaf_hi).then_some(k - 1)
}

/// An orthonormal basis `(t, b)` around the unit vector `n` (Duff et al. 2017).
pub(crate) fn basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        DVec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}
