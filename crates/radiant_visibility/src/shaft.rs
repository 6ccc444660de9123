//! Shaft culling (Haines & Wallace 1994): whether anything at all lies where the segments
//! between two triangles run, so that a pair found empty needs no rays, nor do the pairs that
//! subdividing either triangle makes.
//!
//! The region is the convex hull of both triangles, cut by each triangle's plane: the segments
//! that count leave the first triangle on its front (along `na`) and reach the second from its
//! front (against `nb`). A triangle is left out when a plane separates it from that region:
//! the hull's faces (the planes through an edge of one triangle and a vertex of the other that
//! have every vertex on one side), its box, the triangle's own plane, and the two triangles'
//! planes. The test is conservative: margins cover `f32` rounding of the segments' end points
//! and the barycentric slack of the ray–triangle test, so whatever it leaves out no segment
//! the rays would draw can meet, with one exception: what lies within rounding of either
//! triangle's plane (the two triangles themselves, their coplanar neighbours) is left out,
//! where a segment grazing that plane (within a few degrees) may still meet it by rounding.
//! Such a segment's weight in a form factor is its cosine there, a few hundredths at most, and
//! its hit is an artefact: the shaft's answer is the better one.

use glam::{DVec3, Vec3A};

/// The two end triangles' planes of a set of segments, each segment leaving the first triangle
/// along `na` and reaching the second against `nb`: what lies wholly on or behind either plane
/// (within rounding) none of them can meet, except by rounding, where it grazes that plane.
/// [`Visibility::segment_clear_between`](crate::Visibility::segment_clear_between) leaves such
/// triangles out, as [`Shaft`] does, so that a shaft called clear and the rays agree.
#[derive(Clone, Copy, Debug)]
pub struct Ends {
    /// Unit normal and offset: behind when `n · y >= o - tol`.
    planes: [(DVec3, f64); 2],
    /// Rounding margin (local units), from the six vertices' magnitude.
    tol: f64,
}

impl Ends {
    /// The end planes of the segments from triangle `a` (leaving along `na`) to triangle `b`
    /// (reached against `nb`).
    pub fn new(a: &[DVec3; 3], na: DVec3, b: &[DVec3; 3], nb: DVec3) -> Ends {
        let scale = a
            .iter()
            .chain(b)
            .map(|p| p.abs().max_element())
            .fold(0.0, f64::max);
        let plane = |n: DVec3, p: DVec3| {
            let n = -n.normalize_or_zero();
            (n, n.dot(p))
        };
        Ends {
            planes: [plane(na, a[0]), plane(nb, b[0])],
            tol: 1e-6 * (1.0 + scale),
        }
    }

    /// Whether the triangle `v` lies wholly on or behind one of the two planes.
    #[inline]
    pub fn leave_out(&self, v: &[DVec3; 3]) -> bool {
        self.planes
            .iter()
            .any(|&(n, o)| n != DVec3::ZERO && v.iter().all(|&p| n.dot(p) >= o - self.tol))
    }
}

/// At most this many planes: the two triangles' own and the hull's faces (3 edges × 3
/// vertices, both ways).
const MAX_PLANES: usize = 20;

/// One shaft: its box and planes. A point `y` lies outside when `n · y > o + slack` for one of
/// its planes `(n, o, slack)`.
#[derive(Clone, Debug)]
pub struct Shaft {
    lo: DVec3,
    hi: DVec3,
    pts: [DVec3; 6],
    planes: [(DVec3, f64, f64); MAX_PLANES],
    n: usize,
    /// Rounding margin (local units).
    tol: f64,
    ends: Ends,
}

impl Shaft {
    /// The shaft of the segments from triangle `a` (leaving along `na`) to triangle `b`
    /// (reached against `nb`), without its sides yet ([`Shaft::add_sides`]); `None` when an
    /// input is not finite.
    pub fn new(a: &[DVec3; 3], na: DVec3, b: &[DVec3; 3], nb: DVec3) -> Option<Shaft> {
        let pts = [a[0], a[1], a[2], b[0], b[1], b[2]];
        if !pts.iter().all(|p| p.is_finite()) || !na.is_finite() || !nb.is_finite() {
            return None;
        }
        let (lo, hi) = pts.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let ends = Ends::new(a, na, b, nb);
        let tol = ends.tol;
        let mut s = Shaft {
            lo: lo - tol,
            hi: hi + tol,
            pts,
            planes: [(DVec3::ZERO, 0.0, 0.0); MAX_PLANES],
            n: 0,
            tol,
            ends,
        };
        // The two triangles' planes: what lies on or behind them (within rounding) no counted
        // segment reaches ([`Ends`]).
        for (n, o) in ends.planes {
            if n != DVec3::ZERO {
                s.push(n, o, -tol);
            }
        }
        Some(s)
    }

    /// Adds the hull's side faces: the planes through an edge of one triangle and a vertex of
    /// the other that have all six vertices on one side. Until then the shaft is its box and
    /// the two triangles' planes alone, a looser shaft that is cheaper to make (enough to find
    /// a witness in it).
    pub fn add_sides(&mut self) {
        let ([a0, a1, a2, b0, b1, b2], tol) = (self.pts, self.tol);
        let (a, b) = ([a0, a1, a2], [b0, b1, b2]);
        for (x, y) in [(&a, &b), (&b, &a)] {
            for i in 0..3 {
                let (p, q) = (x[i], x[(i + 1) % 3]);
                for &c in y {
                    let n = (q - p).cross(c - p).normalize_or_zero();
                    if n == DVec3::ZERO {
                        continue;
                    }
                    let o = n.dot(p);
                    let (mn, mx) =
                        (self.pts)
                            .iter()
                            .fold((f64::INFINITY, f64::NEG_INFINITY), |m, &v| {
                                let d = n.dot(v) - o;
                                (m.0.min(d), m.1.max(d))
                            });
                    if mx <= tol {
                        self.push(n, o, tol);
                    } else if mn >= -tol {
                        self.push(-n, -o, tol);
                    }
                }
            }
        }
    }

    fn push(&mut self, n: DVec3, o: f64, slack: f64) {
        if self.n < MAX_PLANES {
            self.planes[self.n] = (n, o, slack);
            self.n += 1;
        }
    }

    /// Whether the box `[lo, hi]` lies wholly outside (so nothing in it can block).
    pub(crate) fn misses_box(&self, lo: Vec3A, hi: Vec3A) -> bool {
        let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
        if lo.cmpgt(self.hi).any() || hi.cmplt(self.lo).any() {
            return true;
        }
        self.planes[..self.n].iter().any(|&(n, o, slack)| {
            let near = DVec3::select(n.cmpge(DVec3::ZERO), lo, hi);
            n.dot(near) > o + slack
        })
    }

    /// Whether the triangle `v` (grown by `grow` for its hits' slack) lies wholly outside.
    pub(crate) fn misses_triangle(&self, v: &[DVec3; 3], grow: f64) -> bool {
        let (lo, hi) = (v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]));
        if (lo - grow).cmpgt(self.hi).any() || (hi + grow).cmplt(self.lo).any() {
            return true;
        }
        if self.ends.leave_out(v) {
            return true;
        }
        let outside = self.planes[..self.n]
            .iter()
            .any(|&(n, o, slack)| slack > 0.0 && v.iter().all(|&p| n.dot(p) > o + slack + grow));
        if outside {
            return true;
        }
        // The triangle's own plane, with the shaft's points all on one side.
        let n = (v[1] - v[0]).cross(v[2] - v[0]).normalize_or_zero();
        if n == DVec3::ZERO {
            return false;
        }
        let m = self.tol + grow;
        let d = self.pts.map(|p| n.dot(p - v[0]));
        d.iter().all(|&x| x > m) || d.iter().all(|&x| x < -m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square_pair(gap: f64) -> ([DVec3; 3], [DVec3; 3]) {
        // A floor triangle and a ceiling triangle `gap` above it, facing each other.
        let a = [DVec3::ZERO, DVec3::X, DVec3::Z];
        let b = [
            DVec3::new(0.0, gap, 0.0),
            DVec3::new(0.0, gap, 1.0),
            DVec3::new(1.0, gap, 0.0),
        ];
        (a, b)
    }

    #[test]
    fn a_shaft_between_facing_triangles_holds_what_lies_between_and_not_beside() {
        let (a, b) = square_pair(1.0);
        let mut s = Shaft::new(&a, DVec3::Y, &b, DVec3::NEG_Y).expect("finite");
        let diagonal = [
            DVec3::new(0.8, 0.5, 0.8),
            DVec3::new(0.9, 0.5, 0.8),
            DVec3::new(0.8, 0.5, 0.9),
        ];
        // Without its sides the shaft is its box: it holds what lies beyond the diagonal face.
        assert!(!s.misses_triangle(&diagonal, 0.0));
        s.add_sides();
        assert!(s.misses_triangle(&diagonal, 0.0));
        let between = [
            DVec3::new(0.2, 0.5, 0.2),
            DVec3::new(0.3, 0.5, 0.2),
            DVec3::new(0.2, 0.5, 0.3),
        ];
        assert!(!s.misses_triangle(&between, 0.0));
        // Beside the hull (x > 1), under the floor, above the ceiling, in the floor's plane.
        let shift = |d: DVec3| between.map(|p| p + d);
        assert!(s.misses_triangle(&shift(DVec3::X * 2.0), 0.0));
        assert!(s.misses_triangle(&shift(DVec3::NEG_Y * 0.6), 0.0));
        assert!(s.misses_triangle(&shift(DVec3::Y * 0.6), 0.0));
        assert!(s.misses_triangle(&shift(DVec3::NEG_Y * 0.5), 0.0));
        // Beyond the diagonal face x + z = 1 of both triangles' hull.
        assert!(s.misses_triangle(&shift(DVec3::new(0.6, 0.0, 0.6)), 0.0));
        // A box: one holding the middle is not missed, one beside is.
        let mid = Vec3A::new(0.2, 0.4, 0.2);
        assert!(!s.misses_box(mid, mid + 0.1));
        assert!(s.misses_box(mid + Vec3A::X * 2.0, mid + Vec3A::X * 2.0 + 0.1));
    }
}
