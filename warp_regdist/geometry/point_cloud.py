"""Point clouds as triangle sets: the local Delaunay triangles around every point.

As in Sharp and Crane's point-cloud Laplacian ("A Laplacian for Nonmanifold Triangle
Meshes", 2020), every point p gets its k nearest neighbours, a tangent plane (their
principal components), and the triangles around p of the Delaunay triangulation of the
neighbours projected to that plane. The union of these one-rings covers the sampled
surface about three times; each distinct triangle counts with weight (number of points
whose one-ring holds it) / 3 in the areas, the mass and the Dirichlet energy, so the
operators approximate those of a mesh of the surface. The triangle set is not a manifold
mesh, which the solver does not need; the ADMM is the same.

The one-ring of the centre c of a planar Delaunay triangulation is found without a
triangulation: the Voronoi cell of c is bounded by the half-planes x . q <= |q|^2 / 2 of
the neighbours q (relative to c), and the neighbours whose half-plane bounds it are the
vertices of the convex hull of the dual points 2 q / |q|^2; consecutive hull vertices
(in angle) make the triangles around c.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .mesh import Mesh, _read_only

__all__ = ["PointCloud"]


class PointCloud(Mesh):
    """A point cloud, accepted wherever a triangle :class:`Mesh` is; its vertices are the points.

    Parameters
    ----------
    points : (p, 3) array_like of float
        Distinct, finite points sampling a surface.
    neighbours : int
        k nearest neighbours of each point for its local triangulation (default 30, as
        robust-laplacian's point-cloud Laplacian).

    Attributes
    ----------
    vertices : (p, 3) ndarray, read-only
        The points.
    elements : (m, 3) ndarray
        The distinct local triangles; ``element_weights`` their multiplicity / 3.
    """

    def __init__(self, points, neighbours=30):
        P = np.asarray(points) if np.size(points) else np.zeros((0, 3))
        if P.ndim != 2 or P.shape[1] != 3 or P.shape[0] < 3:
            raise ValueError(f"expected points of shape (p, 3) with p >= 3, got shape {np.shape(points)}")
        if not np.issubdtype(P.dtype, np.number) or np.issubdtype(P.dtype, np.complexfloating):
            raise ValueError(f"expected real point coordinates, got dtype {P.dtype}")
        P = P.astype(np.float64)
        bad = np.flatnonzero(~np.isfinite(P).all(axis=1))
        if bad.size:
            raise ValueError(f"expected finite points, got {bad.size} points with NaN/inf (first: point {bad[0]})")
        if isinstance(neighbours, (bool, np.bool_)) or not isinstance(neighbours, (int, np.integer)) or neighbours < 3:
            raise ValueError(f"expected neighbours as an integer >= 3, got {neighbours!r}")
        k = int(min(neighbours, len(P) - 1))
        tree = cKDTree(P)
        dist, nbr = tree.query(P, k + 1)
        same = np.flatnonzero(dist[:, 1] == 0.0)
        if same.size:
            other = int(nbr[same[0], 1]) if nbr[same[0], 0] == same[0] else int(nbr[same[0], 0])
            raise ValueError(f"expected distinct points, got points {min(same[0], other)} and {max(same[0], other)} "
                             f"at the same place ({same.size} points have a twin)")
        triangles = _one_rings(P, nbr)
        key, counts = np.unique(np.sort(triangles, axis=1), axis=0, return_counts=True)
        E = P[key[:, 1:]] - P[key[:, :1]]
        area = 0.5 * np.linalg.norm(np.cross(E[:, 0], E[:, 1]), axis=1)
        longest = np.einsum("mij,mij->mi", E, E).max(axis=1)
        keep = area > 1e-9 * longest
        self._weights = _read_only(counts[keep] / 3.0)
        super().__init__(P, key[keep])

    @property
    def element_weights(self):
        return self._weights

    def __repr__(self):
        return f"PointCloud({self.n_vertices} points, {self.n_elements} local triangles)"


def _one_rings(P, nbr):
    """(t, 3) triangles: every point's one-ring in the Delaunay triangulation of its neighbours
    ``nbr`` (p, k + 1; column 0 the point itself) projected to their tangent plane."""
    Q = P[nbr[:, 1:]] - P[:, None]                                # (p, k, 3)
    centred = P[nbr] - P[nbr].mean(axis=1, keepdims=True)
    _, vectors = np.linalg.eigh(np.einsum("pki,pkj->pij", centred, centred))
    x = np.einsum("pki,pi->pk", Q, vectors[:, :, 2])
    y = np.einsum("pki,pi->pk", Q, vectors[:, :, 1])
    r2 = x * x + y * y
    seen = r2 > 1e-24 * r2.max(axis=1, keepdims=True)              # a neighbour straight along the normal has no dual
    r2 = np.where(seen, r2, 1.0)
    dx, dy = np.where(seen, 2 * x / r2, 0.0), np.where(seen, 2 * y / r2, 0.0)   # the dual points
    order = np.argsort(np.arctan2(dy, dx), axis=1)
    dx, dy = np.take_along_axis(dx, order, 1), np.take_along_axis(dy, order, 1)
    ids = np.take_along_axis(nbr[:, 1:], order, 1)
    seen = np.take_along_axis(seen, order, 1)
    p, K = dx.shape
    rows, positions = np.arange(p)[:, None], np.arange(2 * K)
    alive = seen.copy()
    for _ in range(K):
        # the previous and the next alive vertex of every vertex, cyclically in angle
        twice = np.concatenate([alive, alive], axis=1)
        before = np.maximum.accumulate(np.where(twice, positions, -1), axis=1)
        after = np.minimum.accumulate(np.where(twice, positions, 4 * K)[:, ::-1], axis=1)[:, ::-1]
        prev, nxt = before[:, K - 1:2 * K - 1] % K, after[:, 1:K + 1] % K
        ax, ay, bx, by = dx[rows, prev], dy[rows, prev], dx[rows, nxt], dy[rows, nxt]
        turn = (dx - ax) * (by - ay) - (dy - ay) * (bx - ax)
        reflex = alive & (turn <= 0) & (alive.sum(axis=1, keepdims=True) > 3)
        if not reflex.any():
            break
        alive &= ~reflex
    # consecutive hull vertices a, b make the triangle (centre, a, b) where the angle from a to b is below pi
    bx, by = dx[rows, nxt], dy[rows, nxt]
    good = alive & (dx * by - dy * bx > 0)
    i, j = np.nonzero(good)
    return np.stack([i, ids[i, j], ids[i, nxt[i, j]]], axis=1)
