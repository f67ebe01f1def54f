"""Simplicial meshes: triangle surfaces (element_dim 2) and tetrahedral volumes (element_dim 3).

A :class:`Mesh` is validated once on construction, so that no solver kernel ever sees
an index out of range, a NaN coordinate or a zero-volume element. Files are read by
:func:`warp_regdist.mesh_io.load_mesh`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph

from .tolerances import tolerances

__all__ = ["Mesh", "MeshError", "boundary_vertices"]


class MeshError(ValueError):
    """A mesh (file or arrays) that cannot be used, with the reason in the message."""


class Mesh:
    """Triangle or tetrahedral mesh.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex positions; every coordinate finite.
    elements : (m, 3) or (m, 4) array_like of int
        Triangles (surface) or tetrahedra (volume), 0-based vertex indices.

    Attributes
    ----------
    vertices : (n, 3) ndarray of float64
    elements : (m, d + 1) ndarray of int64
    element_dim : int
        2 for triangles, 3 for tetrahedra.

    Vertices that no element references are kept (their distance is +inf), so the
    user's vertex indices are never renumbered.
    """

    def __init__(self, vertices, elements):
        V = np.asarray(vertices)
        T = np.asarray(elements)
        if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] == 0:
            raise MeshError(f"expected vertices of shape (n, 3) with n >= 1, got shape {V.shape}")
        if not np.issubdtype(V.dtype, np.number) or np.issubdtype(V.dtype, np.complexfloating):
            raise MeshError(f"expected real vertex coordinates, got dtype {V.dtype}")
        V = V.astype(np.float64)
        bad = np.flatnonzero(~np.isfinite(V).all(axis=1))
        if bad.size:
            raise MeshError(f"expected finite vertex coordinates, got {bad.size} vertices with NaN/inf (first: vertex {bad[0]})")
        if T.size == 0:
            raise MeshError("expected at least one face (triangle) or tetrahedron, got none")
        if T.ndim != 2 or T.shape[1] not in (3, 4):
            raise MeshError(f"expected elements of shape (m, 3) (triangles) or (m, 4) (tetrahedra), got shape {T.shape}")
        if not np.issubdtype(T.dtype, np.integer):
            if np.issubdtype(T.dtype, np.floating) and np.all(np.isfinite(T)) and np.all(T == np.round(T)):
                T = T.astype(np.int64)
            else:
                raise MeshError(f"expected integer vertex indices in the elements, got dtype {T.dtype}")
        T = T.astype(np.int64)
        n = V.shape[0]
        out = np.flatnonzero((T < 0).any(axis=1) | (T >= n).any(axis=1))
        if out.size:
            raise MeshError(
                f"expected element vertex indices in [0, {n - 1}], got {T[out[0]].tolist()} in element {out[0]} "
                f"({out.size} elements out of range)")
        S = np.sort(T, axis=1)
        rep = np.flatnonzero((S[:, 1:] == S[:, :-1]).any(axis=1))
        if rep.size:
            raise MeshError(f"expected distinct vertices in every element, got element {rep[0]} = {T[rep[0]].tolist()} (degenerate, {rep.size} such)")
        self.vertices = V
        self.elements = T
        self.element_dim = T.shape[1] - 1
        self._check_volumes()
        if self.element_dim == 2:
            self._check_manifold_edges()

    @property
    def faces(self):
        """(m, 3) ndarray of int64: the triangles (triangle meshes only)."""
        if self.element_dim != 2:
            raise AttributeError("a tetrahedral mesh has no 'faces' array; use 'elements'")
        return self.elements

    @property
    def n_vertices(self):
        return self.vertices.shape[0]

    @property
    def n_elements(self):
        return self.elements.shape[0]

    def _check_volumes(self):
        P = self.vertices[self.elements]
        E = P[:, 1:] - P[:, :1]
        scale = np.max(np.linalg.norm(E, axis=2), axis=1)
        if self.element_dim == 2:
            vol = 0.5 * np.linalg.norm(np.cross(E[:, 0], E[:, 1]), axis=1)
            kind, what = "face", "zero-area"
        else:
            vol = np.linalg.det(E) / 6.0
            kind, what = "tetrahedron", "zero-volume"
            inv = np.flatnonzero(vol < 0)
            if inv.size:
                raise MeshError(f"expected positively oriented tetrahedra, got {inv.size} inverted (first: tetrahedron {inv[0]})")
        tiny = tolerances.degenerate_element * scale ** self.element_dim
        bad = np.flatnonzero(np.abs(vol) <= tiny)
        if bad.size:
            raise MeshError(f"expected non-degenerate elements, got {bad.size} {what} {kind}(s) (first: {kind} {bad[0]} = {self.elements[bad[0]].tolist()})")

    def _check_manifold_edges(self):
        F = self.elements
        e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        _, inv, counts = np.unique(e, axis=0, return_inverse=True, return_counts=True)
        over = np.flatnonzero(counts > 2)
        if over.size:
            k = np.flatnonzero(counts[inv.ravel()] > 2)[0]
            raise MeshError(
                f"expected a manifold mesh (at most 2 faces per edge), got {over.size} non-manifold edges "
                f"(first: edge {e[k].tolist()} shared by {counts[over[0]]} faces)")

    def components(self):
        """(n,) int64 connected-component label of every vertex; unreferenced vertices get -1."""
        T = self.elements
        n = self.n_vertices
        rows = np.repeat(T[:, 0], T.shape[1] - 1)
        cols = T[:, 1:].ravel()
        g = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
        _, labels = csgraph.connected_components(g, directed=False)
        used = np.zeros(n, bool)
        used[T.ravel()] = True
        return np.where(used, labels, -1).astype(np.int64)

    def __repr__(self):
        kind = "triangles" if self.element_dim == 2 else "tetrahedra"
        return f"Mesh({self.n_vertices} vertices, {self.n_elements} {kind})"


def boundary_vertices(mesh):
    """Vertices on the boundary: of boundary edges (triangles) or boundary faces (tets).

    Returns
    -------
    (b,) ndarray of int64, sorted. Empty for a closed surface.
    """
    T = mesh.elements
    d = mesh.element_dim
    facets = np.concatenate([np.delete(T, i, axis=1) for i in range(d + 1)])
    key = np.sort(facets, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return np.unique(key[counts[inv.ravel()] == 1]).astype(np.int64)
