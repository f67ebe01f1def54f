"""A per-vertex field of a tetrahedral mesh sampled on a regular grid (point location in the tetrahedra)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mesh import Mesh

__all__ = ["VolumeGrid", "sample_on_grid"]

_CANDIDATES_PER_CHUNK = 4_000_000  # (tetrahedron, grid point) pairs tested at once


@dataclass
class VolumeGrid:
    """Samples of a field at the points ``origin + spacing * (i, j, k)``.

    Attributes
    ----------
    values : (nx, ny, nz) ndarray of float64
        The field at grid point (i, j, k); NaN outside the mesh.
    origin : (3,) ndarray of float64
        Grid point (0, 0, 0): the minimum corner of the mesh's bounding box.
    spacing : float
        Distance between neighbouring grid points, the same along x, y and z.
    """

    values: np.ndarray
    origin: np.ndarray
    spacing: float


def sample_on_grid(mesh, values, resolution=128):
    """Sample a piecewise-linear per-vertex field on a regular grid covering the mesh's bounding box.

    A grid point p inside tetrahedron (a, b, c, d) gets sum_i lambda_i u_i with the
    barycentric coordinates lambda = [b-a, c-a, d-a]^-1 (p - a) (and 1 - their sum for a);
    on a face shared by two tetrahedra both give the same value. Points in no
    tetrahedron get NaN.

    Parameters
    ----------
    mesh : Mesh
        Tetrahedral mesh.
    values : (n,) array_like of float
        Field per vertex (``inf`` stays ``inf`` at the vertex, NaN where it mixes).
    resolution : int
        Grid points along the longest side of the bounding box, >= 2; the spacing is
        that side / (resolution - 1) and the other sides get as many points as fit.

    Returns
    -------
    VolumeGrid
    """
    if not isinstance(mesh, Mesh) or mesh.element_dim != 3:
        got = type(mesh).__name__ if not isinstance(mesh, Mesh) else "a triangle mesh"
        raise ValueError(f"expected a tetrahedral Mesh, got {got}")
    u = np.asarray(values, dtype=np.float64)
    if u.shape != (mesh.n_vertices,):
        raise ValueError(f"expected values of shape ({mesh.n_vertices},) (one per vertex), got {u.shape}")
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 2:
        raise ValueError(f"expected an integer resolution >= 2, got {resolution!r}")
    T = mesh.elements
    P = mesh.vertices[T]
    origin = mesh.vertices[np.unique(T)].min(axis=0)
    extent = mesh.vertices[np.unique(T)].max(axis=0) - origin
    spacing = float(extent.max()) / (resolution - 1)
    shape = np.floor(extent / spacing + 1e-9).astype(np.int64) + 1
    grid = np.full(shape, np.nan)

    lo = np.clip(np.ceil((P.min(axis=1) - origin) / spacing - 1e-9).astype(np.int64), 0, shape - 1)
    hi = np.clip(np.floor((P.max(axis=1) - origin) / spacing + 1e-9).astype(np.int64), 0, shape - 1)
    span = np.maximum(hi - lo + 1, 0)
    counts = span.prod(axis=1)
    inverse = np.linalg.inv(np.transpose(P[:, 1:] - P[:, :1], (0, 2, 1)))  # (m, 3, 3): E^-1, E's columns the edges
    affine = np.concatenate([inverse, -(inverse @ P[:, 0, :, None])], axis=2)  # lambda_1..3 = affine (p, 1)
    ends = np.cumsum(counts)
    start = 0
    while start < len(T):
        stop = max(int(np.searchsorted(ends, ends[start] - counts[start] + _CANDIDATES_PER_CHUNK)), start + 1)
        tet = np.repeat(np.arange(start, stop), counts[start:stop])
        k = np.arange(ends[start] - counts[start], ends[stop - 1]) - np.repeat(ends[start:stop] - counts[start:stop],
                                                                                counts[start:stop])
        k, i = np.divmod(k, span[tet, 0])
        l, j = np.divmod(k, span[tet, 1])
        ijk = (lo[tet, 0] + i, lo[tet, 1] + j, lo[tet, 2] + l)
        x, y, z = (origin[axis] + spacing * ijk[axis] for axis in range(3))
        lam = [None] + [affine[tet, r, 0] * x + affine[tet, r, 1] * y + affine[tet, r, 2] * z + affine[tet, r, 3]
                        for r in range(3)]
        lam[0] = 1.0 - lam[1] - lam[2] - lam[3]
        inside = np.flatnonzero(np.minimum(np.minimum(lam[0], lam[1]), np.minimum(lam[2], lam[3])) >= -1e-10)
        corners = T[tet[inside]]
        with np.errstate(invalid="ignore"):
            sampled = sum(lam[c][inside] * u[corners[:, c]] for c in range(4))
        grid[ijk[0][inside], ijk[1][inside], ijk[2][inside]] = sampled
        start = stop
    return VolumeGrid(grid, origin, spacing)
