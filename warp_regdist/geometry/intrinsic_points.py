"""Points of an intrinsic triangulation: where a straight line from a face ends, and where a point lies
on the input mesh.

A point of an :class:`~warp_regdist.geometry.intrinsic.IntrinsicTriangulation` is a face and three
barycentric coordinates in that face's flat layout. :func:`trace` follows a straight line from a face's
centroid to a point given in that face's coordinates (inside or outside it), unfolding each face it
enters next to the last, as far as it goes on the surface (a boundary side stops it).
:func:`locator` takes a point back to the input mesh: the flips are undone newest first, the point laid
out in each flipped pair of faces and given the coordinates of the old face it lies in, until the face
is an input face; its position in space is then the barycentric combination of that face's vertices.

The arithmetic runs on floats or on :class:`Dual` numbers, which carry the derivatives with respect to
the lengths' variable ids (``IntrinsicTriangulation.length_ids`` and those of the flips), so that a
located point's derivative chains to the input's positions with
:func:`~warp_regdist.geometry.intrinsic.id_gradient`.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["Dual", "value", "side_length", "circumcenter", "trace", "locator"]


class Dual:
    """A number and its derivatives with respect to the lengths' variable ids (a dict id -> partial)."""

    __slots__ = ("v", "d")

    def __init__(self, v, d=None):
        self.v, self.d = float(v), d or {}

    def _plus(self, a, other, b):
        d = {k: a * x for k, x in self.d.items()}
        for k, x in other.d.items():
            d[k] = d.get(k, 0.0) + b * x
        return d

    def __add__(self, o):
        o = o if isinstance(o, Dual) else Dual(o)
        return Dual(self.v + o.v, self._plus(1.0, o, 1.0))

    __radd__ = __add__

    def __sub__(self, o):
        o = o if isinstance(o, Dual) else Dual(o)
        return Dual(self.v - o.v, self._plus(1.0, o, -1.0))

    def __rsub__(self, o):
        return Dual(o) - self

    def __neg__(self):
        return Dual(-self.v, {k: -x for k, x in self.d.items()})

    def __mul__(self, o):
        o = o if isinstance(o, Dual) else Dual(o)
        return Dual(self.v * o.v, self._plus(o.v, o, self.v))

    __rmul__ = __mul__

    def __truediv__(self, o):
        o = o if isinstance(o, Dual) else Dual(o)
        q = self.v / o.v
        return Dual(q, self._plus(1.0 / o.v, o, -q / o.v))

    def __rtruediv__(self, o):
        return Dual(o) / self


def value(x):
    """The float value of a float or :class:`Dual`."""
    return x.v if isinstance(x, Dual) else float(x)


def _sqrt(x):
    if isinstance(x, Dual):
        r = math.sqrt(max(x.v, 1e-300))
        return Dual(r, {k: 0.5 * p / r for k, p in x.d.items()})
    return math.sqrt(max(x, 0.0))


def side_length(T, h, dual=False):
    """The length of halfedge h of T (a float, or a :class:`Dual` of its variable id)."""
    return Dual(T.lengths.flat[h], {int(T.length_ids.flat[h]): 1.0}) if dual else float(T.lengths.flat[h])


def _third(A, B, l_a, l_b, away):
    """The point C with |C - A| = l_a and |C - B| = l_b on the side of the line A B away from ``away``."""
    ex, ey = B[0] - A[0], B[1] - A[1]
    d = _sqrt(ex * ex + ey * ey)
    ex, ey = ex / d, ey / d
    x = (d * d + l_a * l_a - l_b * l_b) / (2.0 * d)
    y = _sqrt(l_a * l_a - x * x)
    if value((away[0] - A[0]) * -ey + (away[1] - A[1]) * ex) > 0.0:
        y = -y
    return (A[0] + x * ex - y * ey, A[1] + x * ey + y * ex)


def _layout(T, f, dual):
    """Face f's corners in the plane: corner 0 at the origin, corner 1 on the x axis, corner 2 above."""
    l01, l12, l20 = (side_length(T, 3 * f + i, dual) for i in range(3))
    zero = Dual(0.0) if dual else 0.0
    return [(zero, zero), (l01, zero), _third((zero, zero), (l01, zero), l20, l12, (zero, -1.0))]


def _barycentric(P, X):
    """The barycentric coordinates of the point P in the triangle X (three points)."""
    (x0, y0), (x1, y1), (x2, y2) = X
    det = (x0 - x2) * (y1 - y2) - (x1 - x2) * (y0 - y2)
    b0 = ((P[0] - x2) * (y1 - y2) - (x1 - x2) * (P[1] - y2)) / det
    b1 = ((x0 - x2) * (P[1] - y2) - (P[0] - x2) * (y0 - y2)) / det
    return [b0, b1, 1.0 - b0 - b1]


def _point(beta, X):
    return (beta[0] * X[0][0] + beta[1] * X[1][0] + beta[2] * X[2][0],
            beta[0] * X[0][1] + beta[1] * X[1][1] + beta[2] * X[2][1])


def circumcenter(T, f, dual=False):
    """The barycentric coordinates (3,) of face f's circumcenter (outside f where an angle is obtuse)."""
    l01, l12, l20 = (side_length(T, 3 * f + i, dual) for i in range(3))
    a, b, c = l12 * l12, l20 * l20, l01 * l01           # squared sides opposite corners 0, 1, 2
    w = [a * (b + c - a), b * (c + a - b), c * (a + b - c)]
    total = w[0] + w[1] + w[2]
    return [x / total for x in w]


def trace(T, f, target, dual=False):
    """Follow the straight line from face f's centroid to the point of barycentric coordinates ``target``
    (3,) in f's layout. Returns (face, coordinates (3,)) where it ends, (None, the boundary halfedge it
    leaves the surface by), or (None, -1) where it crosses more faces than T has (round-off going round
    a vertex)."""
    X = _layout(T, f, dual)
    P = _point(target, X)
    Q = _point([1.0 / 3.0] * 3, X)
    entry = -1                                          # the corner opposite the side the line came in by
    for _ in range(T.faces.shape[0]):
        beta = _barycentric(P, X)
        if min(value(b) for b in beta) >= 0.0:
            return f, beta
        start = _barycentric(Q, X)
        step, c = math.inf, -1
        for k in range(3):
            change = value(beta[k]) - value(start[k])
            if k != entry and change < 0.0 and -value(start[k]) / change < step:
                step, c = -value(start[k]) / change, k
        h = 3 * f + (c + 1) % 3                         # the side opposite corner c
        t = int(T.twin[h])
        if t < 0:
            return None, h
        s = (0.0 - start[c]) / (beta[c] - start[c])
        Q = _point([start[k] + s * (beta[k] - start[k]) for k in range(3)], X)
        A, B = X[(c + 1) % 3], X[(c + 2) % 3]           # h runs A -> B; t runs B -> A in face g
        g, j = t // 3, t % 3
        C = _third(B, A, side_length(T, 3 * g + (j + 2) % 3, dual), side_length(T, 3 * g + (j + 1) % 3, dual),
                   X[c])
        X = [None] * 3
        X[j], X[(j + 1) % 3], X[(j + 2) % 3] = B, A, C
        f, entry = g, (j + 2) % 3
    return None, -1


def locator(T, dual=False):
    """A function (face, barycentric (3,)) -> (input face, its vertices (3,) in the order of the returned
    coordinates, barycentric (3,)): where a point of T lies on the input mesh (module docstring)."""
    # every flip's two faces, sorted by face and then round: the flips of face x are rows start[x]:start[x + 1]
    flips = T.flipped_faces
    faces = np.concatenate([np.zeros(0, dtype=np.int64)] + [np.concatenate([f, g]) for f, _, g, _, _ in flips])
    rounds = np.concatenate([np.zeros(0, dtype=np.int64)] + [np.full(2 * f.size, r) for r, (f, *_) in enumerate(flips)])
    ks = np.concatenate([np.zeros(0, dtype=np.int64)] + [np.tile(np.arange(f.size), 2) for f, *_ in flips])
    order = np.lexsort((rounds, faces))
    start = np.searchsorted(faces[order], np.arange(T.faces.shape[0] + 1))
    rounds, ks = rounds[order], ks[order]

    def length(i):
        return Dual(T.id_lengths[i], {int(i): 1.0}) if dual else float(T.id_lengths[i])

    def locate(face, barycentric):
        beta, at = list(barycentric), list(T.faces[face])
        now = len(T.flipped_faces)
        while True:
            lo, hi = start[face], start[face + 1]
            i = lo + int(np.searchsorted(rounds[lo:hi], now)) - 1        # its last flip before round ``now``
            if i < lo:
                return face, np.array(at), beta
            now, k = int(rounds[i]), int(ks[i])
            f, i, g, j, quad = (x[k] for x in T.flipped_faces[now])
            a, b, c, d = quad.tolist()
            s, l_bc, l_ca, l_ad, l_db = (length(p) for p in T.flips[now][1][k].tolist())
            zero = Dual(0.0) if dual else 0.0
            A, B = (zero, zero), (s, zero)
            C = _third(A, B, l_ca, l_bc, (zero, -1.0))
            D = _third(A, B, l_ad, l_db, C)
            # after the flip f is (a, d, c) and g is (b, c, d)
            P = _point(beta, (A, D, C) if face == f else (B, C, D))
            if value(P[1]) >= 0.0:                      # in the old f: a b c at corners i, i + 1, i + 2
                coords, face, first, ids = _barycentric(P, (A, B, C)), f, i, (a, b, c)
            else:                                       # in the old g: b a d at corners j, j + 1, j + 2
                coords, face, first, ids = _barycentric(P, (B, A, D)), g, j, (b, a, d)
            for q in range(3):
                beta[(first + q) % 3], at[(first + q) % 3] = coords[q], ids[q]
    return locate
