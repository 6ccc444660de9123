//! Shaft tests: whether the volume a link's visibility rays sweep (a receiver point and a
//! source triangle) may cross a triangle that an edit moved, added or removed.

use glam::DVec3;

/// Whether the tetrahedron `t` (a receiver point and a source triangle: the volume the
/// visibility rays of a link sweep) overlaps the box `[lo, hi]`, by separating axes.
pub fn shaft_hits_box(t: &[DVec3; 4], lo: DVec3, hi: DVec3) -> bool {
    let centre = (lo + hi) * 0.5;
    let half = (hi - lo) * 0.5;
    let overlaps = |axis: DVec3| -> bool {
        if axis.length_squared() < 1e-24 {
            return true;
        }
        let r = half.x * axis.x.abs() + half.y * axis.y.abs() + half.z * axis.z.abs();
        let c = centre.dot(axis);
        let (mn, mx) = extent(t, axis);
        mx >= c - r && mn <= c + r
    };
    let box_axes = [DVec3::X, DVec3::Y, DVec3::Z];
    if !box_axes.iter().all(|&a| overlaps(a)) {
        return false;
    }
    if !TET_FACES.iter().all(|f| overlaps(face_normal(t, f))) {
        return false;
    }
    for e in TET_EDGES {
        let d = t[e[1]] - t[e[0]];
        for a in box_axes {
            if !overlaps(d.cross(a)) {
                return false;
            }
        }
    }
    true
}

const TET_FACES: [[usize; 3]; 4] = [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]];
const TET_EDGES: [[usize; 2]; 6] = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];

fn face_normal(t: &[DVec3; 4], f: &[usize; 3]) -> DVec3 {
    (t[f[1]] - t[f[0]]).cross(t[f[2]] - t[f[0]])
}

/// The interval of `points` projected on `axis`.
#[inline]
fn extent(points: &[DVec3], axis: DVec3) -> (f64, f64) {
    points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(mn, mx), p| {
            let d = p.dot(axis);
            (mn.min(d), mx.max(d))
        })
}

/// A triangle seen from a point: its vertices relative to the point, the unit normals of the
/// planes through the point and each edge (towards the triangle; zero when seen edge-on), its
/// own plane (unit normal, pointing away from the point, and offset), its bounding radius and a
/// lower bound on its distance from the point.
#[derive(Clone, Copy, Debug)]
pub struct Pyramid {
    v: [DVec3; 3],
    edge: [DVec3; 3],
    normal: DVec3,
    offset: f64,
    radius: f64,
    near: f64,
}

impl Pyramid {
    /// Triangle `tri` seen from `x`.
    pub fn new(x: DVec3, tri: &[DVec3; 3]) -> Pyramid {
        let v = [tri[0] - x, tri[1] - x, tri[2] - x];
        // The unit normal of `a × b`, none when the two are (nearly) parallel: rounding would
        // give it an arbitrary direction.
        let unit = |a: DVec3, b: DVec3| {
            let n = a.cross(b);
            let l2 = n.length_squared();
            if l2 > 1e-24 * a.length_squared() * b.length_squared() && l2.is_finite() {
                n / l2.sqrt()
            } else {
                DVec3::ZERO
            }
        };
        let edge = std::array::from_fn(|k| {
            let (a, b, c) = (v[k], v[(k + 1) % 3], v[(k + 2) % 3]);
            let n = unit(a, b);
            // Towards the third vertex; none when the point is in the triangle's plane.
            let side = n.dot(c);
            if side > 0.0 {
                n
            } else if side < 0.0 {
                -n
            } else {
                DVec3::ZERO
            }
        });
        let mut normal = unit(v[1] - v[0], v[2] - v[0]);
        let mut offset = normal.dot(v[0]);
        // The point (the origin) on the negative side; in the plane: no depth test.
        if offset < 0.0 {
            normal = -normal;
            offset = -offset;
        } else if offset == 0.0 || !offset.is_finite() {
            normal = DVec3::ZERO;
            offset = 0.0;
        }
        let centre = (v[0] + v[1] + v[2]) / 3.0;
        let radius = v.iter().map(|p| p.distance(centre)).fold(0.0, f64::max);
        Pyramid {
            v,
            edge,
            normal,
            offset,
            radius,
            near: (centre.length() - radius).max(0.0),
        }
    }

    /// Whether rays from the point to `self` (the source) may cross `other`: false only when a
    /// plane separates them with room to spare. Seen from the point, two triangles overlap
    /// unless an edge plane of one separates them; and a ray crosses `other` only if the
    /// source is not wholly in front of `other`'s plane and `other` not wholly beyond the
    /// source's. `margin` is how far the rays may stray from the exact shaft (their origin's
    /// offset and rounding); a ray caster also sees `other` a little past its edges
    /// (`Pyramid::slack`). Both must be seen from the same point.
    pub fn shaft_may_cross(&self, other: &Pyramid, margin: f64) -> bool {
        !(other.keeps_clear_of(&self.v, margin) || self.shaft_clears(other, margin))
    }

    /// How far past this triangle a ray may still hit it: `margin`, and the ray caster's
    /// watertight slack of 1e-6 of the triangle's heights (`radiant_visibility`), doubled.
    fn slack(&self, margin: f64) -> f64 {
        margin + 2e-6 * 2.0 * self.radius
    }

    /// Whether this (changed) triangle's edge planes keep rays from the point to the triangle
    /// `src` (vertices relative to the point) clear of it, or `src` lies wholly in front of it.
    /// Needs nothing of `src` but its vertices. An edge plane passes through the point, so a
    /// source vertex `d` below it is only `d × near / far` below it where the rays pass this
    /// triangle: the room asked for is scaled up by that ratio.
    fn keeps_clear_of(&self, src: &[DVec3; 3], margin: f64) -> bool {
        let slack = self.slack(margin);
        let far = src.iter().map(|p| p.length()).fold(0.0, f64::max);
        let edges = self.near > 0.0
            && far.is_finite()
            && self
                .edge
                .iter()
                .any(|&n| below(n, 0.0, src, slack * far / self.near));
        edges || (self.offset > margin && below(self.normal, self.offset, src, margin))
    }

    /// Whether this (source) triangle's edge planes keep `other` clear of the rays to it, or
    /// `other` lies wholly beyond it.
    fn shaft_clears(&self, other: &Pyramid, margin: f64) -> bool {
        let slack = other.slack(margin);
        self.edge.iter().any(|&n| below(n, 0.0, &other.v, slack))
            || (self.normal != DVec3::ZERO
                && other
                    .v
                    .iter()
                    .all(|p| self.normal.dot(*p) - self.offset > slack))
    }
}

/// Whether all of `q` lies below the plane `n·p = d` by more than `pad` (never for a zero `n`).
#[inline]
fn below(n: DVec3, d: f64, q: &[DVec3; 3], pad: f64) -> bool {
    n != DVec3::ZERO && q.iter().all(|p| n.dot(*p) - d < -pad)
}

/// The triangles an edit took away or put in (local frame): the shafts they may cut. They are
/// kept in at most 64 groups (one triangle each when there are that few), so that a shaft's
/// answer is a bit mask and a child's shaft is tested only against the groups its parent's met.
pub struct ChangeSet {
    groups: Vec<Group>,
    count: usize,
    /// How far the rays of a link may stray from its exact shaft.
    margin: f64,
}

/// Consecutive changed triangles (from `first` in the set) and their padded bounds.
struct Group {
    lo: DVec3,
    hi: DVec3,
    first: usize,
    triangles: Vec<([DVec3; 3], DVec3, DVec3)>,
}

/// Changed triangles seen from a receiver (stamped with it), computed when first needed.
#[derive(Default)]
pub struct SeenFrom {
    seen: Vec<(u32, Pyramid)>,
}

impl ChangeSet {
    /// Past the `f32` rounding of the visibility rays' ends (the local frame has unit extent).
    pub const ROUNDING: f64 = 1e-6;

    /// The change made of `triangles`, for rays that stray at most `margin` from the exact
    /// shaft between a receiver's centroid and a source (at least [`ChangeSet::ROUNDING`]).
    pub fn new(triangles: &[[DVec3; 3]], margin: f64) -> ChangeSet {
        let margin = margin.max(Self::ROUNDING);
        let per_group = triangles.len().div_ceil(64).max(1);
        let groups = triangles
            .chunks(per_group)
            .enumerate()
            .map(|(g, chunk)| {
                let triangles: Vec<_> = chunk
                    .iter()
                    .map(|v| {
                        // Padded by the most a ray may stray and the ray caster's slack.
                        let size = (v[1] - v[0]).length() + (v[2] - v[0]).length();
                        let pad = DVec3::splat(margin + 4e-6 * size);
                        (
                            *v,
                            v[0].min(v[1]).min(v[2]) - pad,
                            v[0].max(v[1]).max(v[2]) + pad,
                        )
                    })
                    .collect();
                let lo = triangles.iter().fold(DVec3::INFINITY, |a, t| a.min(t.1));
                let hi = triangles
                    .iter()
                    .fold(DVec3::NEG_INFINITY, |a, t| a.max(t.2));
                Group {
                    lo,
                    hi,
                    first: g * per_group,
                    triangles,
                }
            })
            .collect();
        ChangeSet {
            groups,
            count: triangles.len(),
            margin,
        }
    }

    /// Whether nothing changed.
    pub fn is_empty(&self) -> bool {
        self.groups.is_empty()
    }

    /// Every group's bit.
    pub fn all(&self) -> u64 {
        if self.groups.len() >= 64 {
            u64::MAX
        } else {
            (1u64 << self.groups.len()) - 1
        }
    }

    /// The groups among `within` whose triangles the shaft from receiver `leaf`'s point `x` to
    /// the triangle `tri` may cross (with `first_only`, at most the first such group).
    pub fn meets(
        &self,
        leaf: u32,
        x: DVec3,
        tri: &[DVec3; 3],
        within: u64,
        first_only: bool,
        cache: &mut SeenFrom,
    ) -> u64 {
        if cache.seen.len() != self.count {
            // Entries are stamped with their receiver: stale ones are recomputed.
            cache.seen.clear();
            cache.seen.resize(
                self.count,
                (u32::MAX, Pyramid::new(DVec3::ZERO, &[DVec3::X; 3])),
            );
        }
        let t = [x, tri[0], tri[1], tri[2]];
        let (tlo, thi) = (
            t[0].min(t[1]).min(t[2].min(t[3])),
            t[0].max(t[1]).max(t[2].max(t[3])),
        );
        let overlap = |lo: DVec3, hi: DVec3| tlo.cmple(hi).all() && lo.cmple(thi).all();
        let rel = [tri[0] - x, tri[1] - x, tri[2] - x];
        let mut source = None;
        let mut hit = 0;
        let mut rest = within;
        while rest != 0 {
            let k = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            let Some(g) = self.groups.get(k) else {
                break;
            };
            if !overlap(g.lo, g.hi) || (g.triangles.len() > 1 && !shaft_hits_box(&t, g.lo, g.hi)) {
                continue;
            }
            for (j, (other, lo, hi)) in g.triangles.iter().enumerate() {
                if !overlap(*lo, *hi) {
                    continue;
                }
                let slot = &mut cache.seen[g.first + j];
                if slot.0 != leaf {
                    *slot = (leaf, Pyramid::new(x, other));
                }
                // The changed triangle's own planes first: they need nothing of the source but
                // its vertices (and usually settle it).
                if slot.1.keeps_clear_of(&rel, self.margin) {
                    continue;
                }
                let src = source.get_or_insert_with(|| Pyramid::new(x, tri));
                if !src.shaft_clears(&slot.1, self.margin) {
                    hit |= 1 << k;
                    break;
                }
            }
            if first_only && hit != 0 {
                break;
            }
        }
        hit
    }
}

#[cfg(test)]
mod shaft_tests {
    use super::*;
    use crate::rng::Rng;

    /// Whether the segment `a`–`b` crosses the triangle `t` (Möller–Trumbore, in f64).
    fn segment_hits(a: DVec3, b: DVec3, t: &[DVec3; 3]) -> bool {
        let d = b - a;
        let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-14 {
            return false;
        }
        let s = a - t[0];
        let u = s.dot(p) / det;
        let q = s.cross(e1);
        let v = d.dot(q) / det;
        let w = e2.dot(q) / det;
        u >= 0.0 && v >= 0.0 && u + v <= 1.0 && (0.0..=1.0).contains(&w)
    }

    fn point(rng: &mut Rng) -> DVec3 {
        DVec3::new(rng.f64(), rng.f64(), rng.f64())
    }

    #[test]
    fn a_shaft_that_crosses_a_triangle_is_never_culled() {
        let mut rng = Rng::new(11);
        let (mut crossing, mut culled) = (0, 0);
        for _ in 0..20_000 {
            let x = point(&mut rng);
            let src = [point(&mut rng), point(&mut rng), point(&mut rng)];
            let other = [point(&mut rng), point(&mut rng), point(&mut rng)];
            let may = Pyramid::new(x, &src).shaft_may_cross(&Pyramid::new(x, &other), 0.0);
            let set = ChangeSet::new(&[other], 0.0);
            let met = set.meets(0, x, &src, set.all(), false, &mut SeenFrom::default()) != 0;
            // Segments from the point to points of the source.
            let hits = (0..64).any(|_| {
                let (r1, r2) = (rng.f64(), rng.f64());
                let p = crate::form_factors::sample_triangle(&src, r1, r2);
                segment_hits(x, p, &other)
            });
            if hits {
                crossing += 1;
                assert!(
                    may && met,
                    "a crossing shaft was culled: {x} {src:?} {other:?}"
                );
            } else if !may {
                culled += 1;
            }
        }
        // The test means something: both cases occur, and most shafts that miss are culled.
        assert!(crossing > 1000 && culled > 5000, "{crossing} {culled}");
    }

    #[test]
    fn a_shaft_beside_or_in_front_of_a_triangle_is_culled() {
        let x = DVec3::ZERO;
        let src = [
            DVec3::new(-1.0, -1.0, 10.0),
            DVec3::new(1.0, -1.0, 10.0),
            DVec3::new(0.0, 1.0, 10.0),
        ];
        let s = Pyramid::new(x, &src);
        let on_axis = [
            DVec3::new(-0.1, -0.1, 5.0),
            DVec3::new(0.1, -0.1, 5.0),
            DVec3::new(0.0, 0.1, 5.0),
        ];
        assert!(s.shaft_may_cross(&Pyramid::new(x, &on_axis), 1e-6));
        let beside = on_axis.map(|p| p + DVec3::new(3.0, 0.0, 0.0));
        assert!(!s.shaft_may_cross(&Pyramid::new(x, &beside), 1e-6));
        let behind = on_axis.map(|p| p + DVec3::new(0.0, 0.0, 10.0));
        assert!(!s.shaft_may_cross(&Pyramid::new(x, &behind), 1e-6));
    }

    /// A source edge that grazes a changed triangle seen from close by: the ray caster's
    /// slack past the triangle's edges must keep this shaft (it once did not).
    #[test]
    fn a_grazing_shaft_near_the_receiver_is_kept() {
        let x = DVec3::ZERO;
        let changed = [
            DVec3::new(0.01, -0.05, 0.0),
            DVec3::new(0.01, 0.05, 0.0),
            DVec3::new(0.01, 0.0, -0.1),
        ];
        let src = [
            DVec3::new(0.5, -0.1, 2e-6),
            DVec3::new(0.5, 0.1, 2e-6),
            DVec3::new(0.5, 0.0, 0.1),
        ];
        let set = ChangeSet::new(&[changed], 0.0);
        assert_ne!(
            set.meets(0, x, &src, set.all(), false, &mut SeenFrom::default()),
            0
        );
        // Farther off, with room to spare, the same shaft is culled.
        let lifted = src.map(|p| p + DVec3::new(0.0, 0.0, 0.01));
        assert_eq!(
            set.meets(1, x, &lifted, set.all(), false, &mut SeenFrom::default()),
            0
        );
    }

    #[test]
    fn many_changed_triangles_are_grouped_and_still_found() {
        // 200 small triangles along a line: more than one per group.
        let tris: Vec<[DVec3; 3]> = (0..200)
            .map(|k| {
                let c = DVec3::new(k as f64 * 0.01, 0.5, 0.5);
                [
                    c,
                    c + DVec3::new(0.004, 0.0, 0.0),
                    c + DVec3::new(0.0, 0.004, 0.0),
                ]
            })
            .collect();
        let set = ChangeSet::new(&tris, 0.0);
        assert_eq!(set.all().count_ones(), 50); // four triangles a group
        let mut seen = SeenFrom::default();
        // A shaft through the 150th triangle's interior, and one far from all of them.
        let target = tris[150][0] + DVec3::new(0.001, 0.001, 0.0);
        let x = target - DVec3::new(0.0, 0.0, 0.4);
        let far = target + DVec3::new(0.0, 0.0, 0.4);
        let src = [
            far,
            far + DVec3::new(0.001, 0.0, 0.0),
            far + DVec3::new(0.0, 0.001, 0.0),
        ];
        assert_ne!(set.meets(1, x, &src, set.all(), false, &mut seen), 0);
        let away = src.map(|p| p + DVec3::new(0.0, 5.0, 0.0));
        assert_eq!(set.meets(1, x, &away, set.all(), false, &mut seen), 0);
    }

    #[test]
    fn shaft_box_overlap() {
        let t = [
            DVec3::ZERO,
            DVec3::new(0.0, 0.0, 10.0),
            DVec3::new(1.0, 0.0, 10.0),
            DVec3::new(0.0, 1.0, 10.0),
        ];
        // A box on the shaft's axis.
        assert!(shaft_hits_box(
            &t,
            DVec3::splat(0.05),
            DVec3::new(0.1, 0.1, 5.0)
        ));
        // Beside it, where only the bounding boxes overlap.
        assert!(!shaft_hits_box(
            &t,
            DVec3::new(0.8, 0.8, 0.5),
            DVec3::new(1.0, 1.0, 1.0)
        ));
        // Far away.
        assert!(!shaft_hits_box(&t, DVec3::splat(20.0), DVec3::splat(21.0)));
    }
}
