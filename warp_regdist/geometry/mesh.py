"""Simplicial meshes: triangle surfaces (element_dim 2) and tetrahedral volumes (element_dim 3).

A :class:`Mesh` is validated once on construction, so that no solver kernel ever sees
an index out of range, a NaN coordinate or a zero-volume element. Files are read by
:func:`warp_regdist.geometry.mesh_io.load_mesh`.
"""

from __future__ import annotations

import hashlib
import warnings

import numpy as np
from numpy.typing import ArrayLike
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph

from ..errors import MeshError, MeshWarning
from ..tolerances import tolerances

__all__ = ["Mesh", "boundary_vertices", "boundary_faces", "boundary_surface", "duplicate_vertices",
           "near_duplicate_vertices"]


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
    vertices : (n, 3) ndarray of float64, read-only
    elements : (m, d + 1) ndarray of int64, read-only
    element_volumes : (m,) ndarray of float64, read-only
        Areas (triangles, |e_1 x e_2| / 2) or volumes (tetrahedra, det[e_1 e_2 e_3] / 6)
        a_e > 0, with e_i = v_i - v_0: computed once, by the validation.
    element_dim : int
        2 for triangles, 3 for tetrahedra.

    Vertices that no element references are kept (their distance is +inf), so the
    user's vertex indices are never renumbered. Triangles may meet at non-manifold edges (three or
    more faces on one edge) and be oriented either way: the operators do not need a manifold. The
    arrays are copies of the input and read-only, so that what is derived from them once (the
    volumes, :meth:`components`) stays true.
    """

    element_weights = None
    """(m,) factors of the element volumes in the finite-element operators; None: all 1 (a point
    cloud's triangles, which overlap, carry their multiplicity / 3)."""

    input_index = None
    """(n_in,) the vertex of this mesh of every vertex of the file or arrays it was repaired from
    (:func:`~warp_regdist.repair_mesh`, ``load_mesh(path, repair=True)``): values on this mesh read back
    in the input's numbering as ``u[mesh.input_index]``; None: the numbering is the input's."""

    def __init__(self, vertices: ArrayLike, elements: ArrayLike) -> None:
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
        self._vertices = _read_only(V)
        self._elements = _read_only(T)
        self.element_dim = T.shape[1] - 1
        self._element_volumes = _read_only(self._checked_volumes())
        self._components = None
        self._sha256 = None
        self._warn_duplicates()

    def _warn_duplicates(self):
        used = np.zeros(self.n_vertices, dtype=bool)
        used[self.elements.ravel()] = True
        pairs = duplicate_vertices(self.vertices, used)
        if len(pairs):
            a, b = pairs[0]
            count = np.unique(pairs[:, 1]).size
            lie = "vertex lies" if count == 1 else "vertices lie"
            warnings.warn(f"{count} {lie} where another vertex of the mesh lies (first: "
                          f"{a} and {b}): the mesh is cut there and no distance crosses the cut; merge them with "
                          "warp_regdist.merge_duplicate_vertices(mesh) or load_mesh(path, repair=True)",
                          MeshWarning, stacklevel=3)
        if self.element_dim != 2 or self.element_weights is not None:
            return
        near = near_duplicate_vertices(self.vertices, self.elements)
        near = near[np.any(self.vertices[near[:, 0]] != self.vertices[near[:, 1]], axis=1)]
        if len(near):
            a, b = near[0]
            gap = np.linalg.norm(self.vertices[a] - self.vertices[b])
            warnings.warn(f"{len(near)} pairs of boundary vertices lie within {tolerances.weld:g} of the bounding box "
                          f"diagonal of each other (first: {a} and {b}, {gap:.3g} apart): the surface is cracked "
                          "there and no distance crosses the crack; load_mesh(path, repair=True) or "
                          "warp_regdist.repair_mesh(vertices, faces) welds them", MeshWarning, stacklevel=3)

    def __setstate__(self, state):
        self.__dict__.update(state)
        for name in ("_vertices", "_elements", "_element_volumes", "_components"):
            if self.__dict__[name] is not None:
                _read_only(self.__dict__[name])

    @property
    def vertices(self):
        """(n, 3) ndarray of float64 (read-only)."""
        return self._vertices

    @property
    def elements(self):
        """(m, d + 1) ndarray of int64 (read-only)."""
        return self._elements

    @property
    def element_volumes(self):
        """(m,) ndarray of float64 (read-only): areas (triangles) or volumes (tetrahedra) a_e."""
        return self._element_volumes

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

    def _checked_volumes(self):
        """The element volumes, after refusing inverted and degenerate elements."""
        V, T = self.vertices, self.elements
        E = V[T[:, 1:]] - V[T[:, :1]]                      # (m, d, 3): e_i = v_i - v_0
        longest_squared = np.einsum("mij,mij->mi", E, E).max(axis=1)
        if self.element_dim == 2:
            vol = 0.5 * np.linalg.norm(np.cross(E[:, 0], E[:, 1]), axis=1)
            kind, what = "face", "zero-area"
        else:
            vol = np.linalg.det(E) / 6.0
            kind, what = "tetrahedron", "zero-volume"
            inv = np.flatnonzero(vol < 0)
            if inv.size:
                raise MeshError(f"expected positively oriented tetrahedra, got {inv.size} inverted (first: tetrahedron {inv[0]})")
        tiny = tolerances.degenerate_element * longest_squared ** (self.element_dim / 2)
        bad = np.flatnonzero(np.abs(vol) <= tiny)
        if bad.size:
            fix = ("; load_mesh(path, repair=True) or warp_regdist.repair_mesh(vertices, faces) drops them"
                   if self.element_dim == 2 else "")
            raise MeshError(f"expected non-degenerate elements, got {bad.size} {what} {kind}(s) (first: {kind} "
                            f"{bad[0]} = {self.elements[bad[0]].tolist()}){fix}")
        return vol

    def components(self):
        """(n,) int64 connected-component label of every vertex, read-only; unreferenced vertices get -1.

        Computed on the first call and kept (the mesh's arrays cannot change)."""
        if self._components is None:
            T = self.elements
            n = self.n_vertices
            rows = np.repeat(T[:, 0], T.shape[1] - 1)
            cols = T[:, 1:].ravel()
            g = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
            _, labels = csgraph.connected_components(g, directed=False)
            used = np.zeros(n, bool)
            used[T.ravel()] = True
            self._components = _read_only(np.where(used, labels, -1).astype(np.int64))
        return self._components

    def sha256(self):
        """SHA-256 hex digest of the vertex positions and elements (little-endian float64 and int64
        bytes, each after its shape): what identifies the mesh in checkpoints and progress records."""
        if self._sha256 is None:
            h = hashlib.sha256()
            arrays = [np.ascontiguousarray(self.vertices, dtype="<f8"), np.ascontiguousarray(self.elements, dtype="<i8")]
            if self.element_weights is not None:
                arrays.append(np.ascontiguousarray(self.element_weights, dtype="<f8"))
            for a in arrays:
                h.update(str(a.shape).encode())
                h.update(a.tobytes())
            self._sha256 = h.hexdigest()
        return self._sha256

    def __repr__(self):
        kind = "triangles" if self.element_dim == 2 else "tetrahedra"
        return f"Mesh({self.n_vertices} vertices, {self.n_elements} {kind})"


def duplicate_vertices(vertices, used=None):
    """(p, 2) int64 pairs (i, j), i < j, of vertices at exactly the same position (among ``used``, (n,)
    bool, when given); each vertex j of a group is paired with the group's first vertex i.

    Rows are hashed (splitmix64 of the coordinates' bits, -0.0 as 0.0) and only rows whose hashes
    collide are compared, so the cost is one sort of n integers."""
    V = np.asarray(vertices, dtype=np.float64)
    index = np.arange(len(V)) if used is None else np.flatnonzero(used)
    bits = (V[index] + 0.0).view(np.uint64)
    h = _mix(bits[:, 0] ^ _mix(bits[:, 1] ^ _mix(bits[:, 2])))
    order = np.argsort(h)
    tie = np.flatnonzero(h[order[1:]] == h[order[:-1]])
    if tie.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    candidates = index[np.unique(np.concatenate([order[tie], order[tie + 1]]))]
    rows = V[candidates]
    ranked = candidates[np.lexsort(rows.T[::-1])]
    starts = np.concatenate([[True], ~np.all(V[ranked[1:]] == V[ranked[:-1]], axis=1)])   # a new position
    group = np.cumsum(starts) - 1
    lead = np.minimum.reduceat(ranked, np.flatnonzero(starts))[group]     # the smallest index at each position
    dup = ranked != lead
    return np.stack([lead[dup], ranked[dup]], axis=1).astype(np.int64)


def near_duplicate_vertices(vertices, faces):
    """(p, 2) int64 pairs (i, j), i < j, of *boundary* vertices of a triangle list (vertices (n, 3),
    faces (m, 3)) that a crack separates: not joined by an edge, at most ``tolerances.weld`` times the
    bounding box diagonal apart, and closer than a tenth of the shortest boundary edge at either.

    Boundary edges are those of one face. Interior vertices are never paired: two close vertices
    inside the surface are a short edge, not a crack."""
    from scipy.spatial import cKDTree

    V, F = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    n = len(V)
    a, b = F.ravel(), np.roll(F, -1, axis=1).ravel()
    keys = np.sort(np.minimum(a, b) * n + np.maximum(a, b))
    alone = np.ones(keys.size, dtype=bool)
    alone[1:] &= keys[1:] != keys[:-1]
    alone[:-1] &= keys[:-1] != keys[1:]
    if not alone.any():
        return np.zeros((0, 2), dtype=np.int64)
    rim = np.stack([keys[alone] // n, keys[alone] % n], axis=1)
    on_rim = np.unique(rim)
    shortest = np.full(len(V), np.inf)
    lengths = np.linalg.norm(V[rim[:, 0]] - V[rim[:, 1]], axis=1)
    np.minimum.at(shortest, rim[:, 0], lengths)
    np.minimum.at(shortest, rim[:, 1], lengths)
    radius = tolerances.weld * float(np.linalg.norm(V[F.ravel()].max(axis=0) - V[F.ravel()].min(axis=0)))
    pairs = cKDTree(V[on_rim]).query_pairs(radius, output_type="ndarray")
    if pairs.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    i, j = np.sort(on_rim[pairs], axis=1).T
    gap = np.linalg.norm(V[i] - V[j], axis=1)
    close = gap < 0.1 * np.minimum(shortest[i], shortest[j])
    joined = np.isin(i * n + j, keys)
    keep = close & ~joined
    return np.stack([i[keep], j[keep]], axis=1).astype(np.int64)


def _mix(z):
    """splitmix64's finalizer on uint64 arrays."""
    z = z ^ (z >> np.uint64(30))
    z = z * np.uint64(0xBF58476D1CE4E5B9)
    z = z ^ (z >> np.uint64(27))
    z = z * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


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
    _, inv, counts = np.unique(_row_keys(key), return_inverse=True, return_counts=True)
    return np.unique(key[counts[inv] == 1]).astype(np.int64)


_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
"""The faces of a positively oriented tetrahedron (v0, v1, v2, v3), each opposite its vertex, outward."""


def boundary_faces(mesh):
    """The boundary triangles of a tetrahedral mesh, outward: (b, 3) int64, and the (b,) tetrahedron of each."""
    if mesh.element_dim != 3:
        raise ValueError("expected a tetrahedral mesh for boundary_faces, got a triangle mesh")
    T = mesh.elements
    faces = T[:, _TET_FACES].reshape(-1, 3)
    key = _row_keys(np.sort(faces, axis=1))
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    outer = np.flatnonzero(counts[inverse.ravel()] == 1)
    return faces[outer], outer // 4


def boundary_surface(mesh):
    """The boundary of a tetrahedral mesh as a triangle :class:`Mesh` with all of its vertices (the
    interior ones unreferenced); a triangle mesh is returned as it is."""
    return mesh if mesh.element_dim == 2 else Mesh(mesh.vertices, boundary_faces(mesh)[0])


def _read_only(array):
    array.flags.writeable = False
    return array


def _row_keys(rows):
    """(k, c) non-negative int64 rows -> (k,) keys, equal exactly where the rows are equal.

    A row's base-(max + 1) number when it fits in int64 (a sort of integers instead of
    np.unique(axis=0)'s sort of byte strings), else its rank among the distinct rows."""
    base = int(rows.max(initial=0)) + 1
    if base ** rows.shape[1] < 2 ** 63:
        key = np.zeros(len(rows), dtype=np.int64)
        for column in rows.T:
            key = key * base + column
        return key
    return np.unique(rows, axis=0, return_inverse=True)[1].ravel()
