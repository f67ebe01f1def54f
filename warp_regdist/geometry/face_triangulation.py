"""Triangulation of one planar triangle with points on its edges and inside it.

:class:`FaceTriangulation` starts from the triangle (corners 0, 1, 2, counter-clockwise in
its plane), inserts interior points (1 -> 3 split, or 2 -> 4 on an inner edge), splits its
sides at the given side points, flips inner edges to Delaunay (Lawson), and makes required
segments edges by flipping the edges that cross them. Everything stays in the triangle's plane,
so no step changes the surface; the sides are split only at the given points, so the
triangulations of neighbouring faces that share those side points fit together.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FaceTriangulation"]

_ON_EDGE = 1e-10
"""Relative barycentric coordinate below which an interior point lies on an inner edge."""


class FaceTriangulation:
    """Counter-clockwise triangles over 2D points; ``labels[i]`` is point i's caller-side name.

    Parameters
    ----------
    corners : (3, 2) array_like
        The triangle, counter-clockwise.
    labels : sequence of 3
        Names of the corners (e.g. global vertex indices).
    """

    def __init__(self, corners, labels):
        self.xy = [np.asarray(c, dtype=np.float64) for c in corners]
        self.labels = list(labels)
        self.side = [{0, 2}, {0, 1}, {1, 2}]        # sides (by first corner: 0 = 0-1, 1 = 1-2, 2 = 2-0) of each point
        self.triangles = [(0, 1, 2)]
        self.constrained = set()

    def _add(self, xy, label, sides=()):
        self.xy.append(np.asarray(xy, dtype=np.float64))
        self.labels.append(label)
        self.side.append(set(sides))
        return len(self.xy) - 1

    def split_side(self, side, xy, label):
        """Insert a point on side ``side`` (0: corners 0-1, 1: 1-2, 2: 2-0) strictly between two of its points."""
        p = self._add(xy, label, (side,))
        for t, tri in enumerate(self.triangles):
            for r in range(3):
                a, b, c = tri[r], tri[(r + 1) % 3], tri[(r + 2) % 3]
                if side in self.side[a] and side in self.side[b] and self._between(p, a, b):
                    self.triangles[t] = (a, p, c)
                    self.triangles.append((p, b, c))
                    return p
        raise AssertionError("side point outside its side")

    def insert(self, xy, label):
        """Insert an interior point; returns its index."""
        p = self._add(xy, label)
        q = self.xy[p]
        best, lam = None, None
        for t, tri in enumerate(self.triangles):
            w = self._barycentric(q, tri)
            if best is None or w.min() > lam.min():
                best, lam = t, w
        a, b, c = self.triangles[best]
        r = int(np.argmin(lam))
        if lam[r] > _ON_EDGE:
            self.triangles[best] = (a, b, p)
            self.triangles += [(b, c, p), (c, a, p)]
            return p
        tri = self.triangles[best]
        u, v = tri[(r + 1) % 3], tri[(r + 2) % 3]               # the edge opposite the smallest coordinate
        w = tri[r]
        self.triangles[best] = (w, u, p)
        self.triangles.append((v, w, p))
        other = self._triangle_with(v, u)
        if other is None:
            raise AssertionError("interior point on a side of the triangle")
        x = next(i for i in self.triangles[other] if i not in (u, v))
        self.triangles[other] = (u, x, p)
        self.triangles.append((x, v, p))
        return p

    def make_delaunay(self):
        """Flip inner, unconstrained edges until every one is locally Delaunay."""
        changed = True
        while changed:
            changed = False
            for t in range(len(self.triangles)):
                for r in range(3):
                    tri = self.triangles[t]
                    a, b, c = tri[r], tri[(r + 1) % 3], tri[(r + 2) % 3]
                    if frozenset((a, b)) in self.constrained:
                        continue
                    o = self._triangle_with(b, a)
                    if o is None:
                        continue
                    d = next(i for i in self.triangles[o] if i not in (a, b))
                    if self._in_circle(a, b, c, d) and self._convex(a, d, b, c):
                        self._flip(t, o, a, b, c, d)
                        changed = True

    def recover(self, a, b):
        """Make the segment a-b a chain of edges by flipping the edges that cross it (Sloan 1993) and
        keep those edges from later flips; where it crosses an earlier segment, their crossing is
        inserted (label None). Returns the points on the segment, in order from a to b."""
        for _ in range(len(self.xy) + 16):
            chain = self._points_on(a, b)
            if all(self._recover_edge(i, j) for i, j in zip(chain[:-1], chain[1:])):
                for i, j in zip(chain[:-1], chain[1:]):
                    self.constrained.add(frozenset((i, j)))
                return chain
        raise RuntimeError("could not make a curve segment a chain of edges of its face's triangulation")

    def _recover_edge(self, a, b):
        """Flip until a-b is an edge (True), or insert its crossing with a constrained edge (False)."""
        for _ in range(20 * len(self.triangles) + 100):
            if self._triangle_with(a, b) is not None or self._triangle_with(b, a) is not None:
                return True
            for t, tri in enumerate(self.triangles):
                r = next((r for r in range(3) if self._crosses(tri[r], tri[(r + 1) % 3], a, b)), None)
                if r is None:
                    continue
                u, v, c = tri[r], tri[(r + 1) % 3], tri[(r + 2) % 3]
                if frozenset((u, v)) in self.constrained:
                    pu, pv, pa, pb = (self.xy[i] for i in (u, v, a, b))
                    s = _cross(pb - pa, pu - pa) / (_cross(pb - pa, pu - pa) - _cross(pb - pa, pv - pa))
                    p = self.insert(pu + s * (pv - pu), None)
                    self.constrained -= {frozenset((u, v))}
                    self.constrained |= {frozenset((u, p)), frozenset((p, v))}
                    return False
                o = self._triangle_with(v, u)
                d = next(i for i in self.triangles[o] if i not in (u, v))
                if self._convex(u, d, v, c):
                    self._flip(t, o, u, v, c, d)
                    break
            else:
                break
        raise RuntimeError("could not make a curve segment an edge of its face's triangulation")

    def _flip(self, t, o, a, b, c, d):
        """Replace the edge a-b of triangles t = (a, b, c) and o = (b, a, d) by c-d."""
        self.triangles[t] = (c, a, d)
        self.triangles[o] = (d, b, c)

    # ------------------------------------------------------------------ geometry
    def _points_on(self, a, b):
        """The points on the closed segment a-b, ordered from a."""
        pa, d = self.xy[a], self.xy[b] - self.xy[a]
        dd = d @ d
        out = []
        for i, q in enumerate(self.xy):
            e = q - pa
            t = (e @ d) / dd
            if -1e-12 <= t <= 1 + 1e-12 and abs(e[0] * d[1] - e[1] * d[0]) <= 1e-10 * dd:
                out.append((t, i))
        return [i for _, i in sorted(out)]

    def _crosses(self, u, v, a, b):
        """Whether the segments u-v and a-b cross at a point inside both."""
        pu, pv, pa, pb = (self.xy[i] for i in (u, v, a, b))
        return (_cross(pb - pa, pu - pa) * _cross(pb - pa, pv - pa) < 0
                and _cross(pv - pu, pa - pu) * _cross(pv - pu, pb - pu) < 0)

    def _between(self, p, a, b):
        d = self.xy[b] - self.xy[a]
        t = (self.xy[p] - self.xy[a]) @ d / (d @ d)
        return 0.0 < t < 1.0

    def _barycentric(self, q, tri):
        a, b, c = (self.xy[i] for i in tri)
        area = _cross(b - a, c - a)
        return np.array([_cross(b - q, c - q), _cross(c - q, a - q), _cross(a - q, b - q)]) / area

    def _triangle_with(self, a, b):
        """The triangle with the directed edge a -> b, or None."""
        for t, tri in enumerate(self.triangles):
            for r in range(3):
                if tri[r] == a and tri[(r + 1) % 3] == b:
                    return t
        return None

    def _in_circle(self, a, b, c, d):
        """Whether d lies strictly inside the circumcircle of the counter-clockwise a, b, c."""
        rows = [self.xy[i] - self.xy[d] for i in (a, b, c)]
        m = np.array([[x, y, x * x + y * y] for x, y in rows])
        scale = max(float(np.abs(m[:, 2]).max()), 1e-300)
        return np.linalg.det(m) > 1e-9 * scale * scale

    def _convex(self, a, d, b, c):
        """Whether the quadrilateral a, d, b, c is strictly convex (its diagonal c-d can replace a-b)."""
        pts = [self.xy[i] for i in (a, d, b, c)]
        return all(_cross(pts[(i + 1) % 4] - pts[i], pts[(i + 2) % 4] - pts[(i + 1) % 4]) > 0 for i in range(4))


def _cross(u, v):
    return float(u[0] * v[1] - u[1] * v[0])
