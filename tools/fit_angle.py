"""Fits the polynomial of `angle` in crates/radiant_radiosity/src/form_factors/analytic.rs:
atan(z) = z P(z^2) for |z| <= tan(pi/8), P of degree 10 in w = z^2, by least squares on 200
Chebyshev nodes in [0, tan^2(pi/8)], at 50 digits (mpmath), and prints its coefficients as
doubles with the worst relative error of z P(z^2) evaluated in doubles (Horner) against atan.

  pip install mpmath && python3 tools/fit_angle.py      # worst relative error about 2e-16
"""
import mpmath as mp

mp.mp.dps = 50
W = (mp.sqrt(2) - 1) ** 2
DEGREE, NODES = 10, 200


def f(w):
    if w == 0:
        return mp.mpf(1)
    s = mp.sqrt(w)
    return mp.atan(s) / s


xs = [W * (1 + mp.cos(mp.pi * (k + 0.5) / NODES)) / 2 for k in range(NODES)]
A = mp.matrix(NODES, DEGREE + 1)
b = mp.matrix(NODES, 1)
for i, x in enumerate(xs):
    for j in range(DEGREE + 1):
        A[i, j] = x ** j
    b[i] = f(x)
c = [float(v) for v in mp.lu_solve(A.T * A, A.T * b)]
worst = 0
for k in range(1, 4001):
    z = float(mp.sqrt(W) * k / 4000)
    p = 0.0
    for cj in reversed(c):
        p = p * (z * z) + cj
    exact = mp.atan(mp.mpf(z))
    worst = max(worst, abs((mp.mpf(z * p) - exact) / exact))
print("const ATAN: [f64; 11] = [" + ", ".join(repr(v) for v in c) + "];")
print("worst relative error", mp.nstr(worst, 3))
