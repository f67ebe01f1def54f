"""Meshes as users have them, made usable: vertices at one position merged, cracks welded, degenerate
faces dropped, non-manifold edges cut, components split.

:func:`repair_mesh` returns the new :class:`~warp_regdist.Mesh`, whose ``input_index`` (n_in,) is the
new vertex of every input vertex (so that values computed on it read back in the input's numbering as
``u[mesh.input_index]``), and a :class:`Repair` that says what changed.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from ..errors import MeshError
from ..tolerances import tolerances
from .mesh import Mesh, duplicate_vertices, near_duplicate_vertices

__all__ = ["Repair", "repair_mesh", "merge_duplicate_vertices", "split_components"]


@dataclasses.dataclass(frozen=True)
class Repair:
    """What :func:`repair_mesh` changed: vertices merged into another at the same position, boundary
    vertices welded onto another across a crack, faces dropped (a repeated corner, or zero area),
    non-manifold edges cut (the faces beyond a consistently oriented pair detached along the edge,
    with copies of its two vertices), and the components left."""

    merged_vertices: int = 0
    welded_vertices: int = 0
    dropped_faces: int = 0
    cut_edges: int = 0
    components: int = 1

    def __str__(self):
        parts = []
        if self.merged_vertices:
            parts.append(f"merged {self.merged_vertices} vertices into others at the same position")
        if self.welded_vertices:
            parts.append(f"welded {self.welded_vertices} boundary vertices onto others across cracks (within "
                         f"{tolerances.weld:g} of the bounding box diagonal)")
        if self.dropped_faces:
            parts.append(f"dropped {self.dropped_faces} degenerate faces (a repeated corner or zero area)")
        if self.cut_edges:
            parts.append(f"cut the mesh along {self.cut_edges} non-manifold edges (faces beyond a pair detached)")
        if not parts:
            return "nothing to repair"
        return "; ".join(parts) + f"; {self.components} connected component(s)"


def repair_mesh(vertices, faces, cut=True):
    """A triangle :class:`~warp_regdist.Mesh` from ``vertices`` (n, 3) and ``faces`` (m, 3) that may have
    vertices at one position, cracks, degenerate faces and non-manifold edges, and the :class:`Repair` made.

    In this order: vertices at exactly one position are merged into the first of them (kept vertices
    keep their order); boundary vertices on the two sides of a crack
    (:func:`~warp_regdist.geometry.mesh.near_duplicate_vertices`, ``tolerances.weld``) are welded onto
    the first of them, where it lies; faces with a repeated corner or an area
    <= ``tolerances.degenerate_element`` times their longest edge squared are dropped; with ``cut``,
    each edge with more than two faces keeps one pair of faces that run along it in opposite
    directions (the first such pair, else its first two faces), and every other face at the edge gets
    its own copies of the edge's two vertices (appended), so that no distance crosses the edge
    between them (``cut=False`` keeps such edges: the solvers compute on them). Vertices referenced by
    no face are kept (+inf distance). The mesh's ``input_index`` maps every input vertex to its vertex
    of the result.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3 or V.ndim != 2 or V.shape[1] != 3:
        raise MeshError(f"expected vertices (n, 3) and triangles (m, 3) to repair, got shapes {V.shape} and {F.shape}")
    if not np.isfinite(V).all():
        raise MeshError("expected finite vertex coordinates to repair, got NaN or inf")
    F = F.astype(np.int64)
    if F.size and (F.min() < 0 or F.max() >= len(V)):
        raise MeshError(f"expected face vertex indices in [0, {len(V) - 1}], got {int(F.min())}..{int(F.max())}")
    used = np.zeros(len(V), dtype=bool)
    used[F.ravel()] = True
    pairs = duplicate_vertices(V, used)
    keep, index = _merge_map(len(V), pairs)
    V, F = V[keep], index[F]
    welds = _chains_to_first(len(V), near_duplicate_vertices(V, F))
    keep, weld_index = _merge_map(len(V), welds)
    V, F, index = V[keep], weld_index[F], weld_index[index]
    degenerate = _degenerate(V, F)
    F = F[~degenerate]
    V, F, cut = _cut_non_manifold_edges(V, F) if cut else (V, F, 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the cut's copies of vertices are meant to lie where their originals do
        mesh = Mesh(V, F)
    mesh.input_index = index.astype(np.int64)
    labels = mesh.components()
    repair = Repair(merged_vertices=int(len(pairs)), welded_vertices=int(len(welds)),
                    dropped_faces=int(np.count_nonzero(degenerate)),
                    cut_edges=cut, components=int(np.unique(labels[labels >= 0]).size))
    return mesh, repair


def _merge_map(n, pairs):
    """(keep (n,) bool, index (n,) int64) merging each pair (i, j) of ``pairs`` (k, 2) into its first vertex:
    the vertices kept, and each vertex's index among them."""
    lead = np.arange(n)
    lead[pairs[:, 1]] = pairs[:, 0]
    keep = lead == np.arange(n)
    return keep, (np.cumsum(keep) - 1)[lead].astype(np.int64)


def _chains_to_first(n, pairs):
    """(p, 2) pairs (lead, j): every vertex of a group joined by ``pairs`` (k, 2) paired with the group's
    smallest index, as :func:`_merge_map` takes them."""
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    labels = csgraph.connected_components(graph, directed=False)[1]
    members = np.unique(pairs)
    lead = np.full(labels.max() + 1, n)
    np.minimum.at(lead, labels[members], members)
    lead = lead[labels[members]]
    return np.stack([lead[members != lead], members[members != lead]], axis=1).astype(np.int64)


def _repeated_corner(F):
    """(m,) bool: elements with a vertex twice."""
    S = np.sort(F, axis=1)
    return (S[:, 1:] == S[:, :-1]).any(axis=1)


def _degenerate(V, F):
    """(m,) bool: faces with a repeated corner or an area <= degenerate_element x longest edge squared."""
    repeated = _repeated_corner(F)
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    longest = np.max([np.einsum("ij,ij->i", e, e) for e in (e1, e2, V[F[:, 2]] - V[F[:, 1]])], axis=0)
    return repeated | (area <= tolerances.degenerate_element * longest)


def _cut_non_manifold_edges(V, F):
    """(V, F, count): every edge with more than two faces cut so that at most two remain on it."""
    a, b = F.ravel(), np.roll(F, -1, axis=1).ravel()
    key = np.minimum(a, b) * len(V) + np.maximum(a, b)
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    crowded = np.flatnonzero(counts[inverse.ravel()] > 2)          # halfedges on non-manifold edges
    if crowded.size == 0:
        return V, F, 0
    V, F = list(V), F.copy()
    groups = {}
    for h in crowded:
        groups.setdefault(int(inverse.ravel()[h]), []).append(int(h))
    for halfedges in groups.values():
        halfedges.sort()
        forward = [h for h in halfedges if a[h] < b[h]]
        backward = [h for h in halfedges if a[h] > b[h]]
        stay = [forward[0], backward[0]] if forward and backward else halfedges[:2]
        for h in halfedges:
            if h in stay:
                continue
            f = h // 3
            for vertex in (a[h], b[h]):
                V.append(V[vertex])
                F[f][F[f] == vertex] = len(V) - 1
    return np.array(V), F, len(groups)


def merge_duplicate_vertices(mesh):
    """The mesh with the vertices at one position merged into the first of them, and ``index`` (n,).

    Kept vertices keep their order; elements that the merge leaves with a repeated corner are dropped.

    Returns
    -------
    merged : Mesh
    index : (n,) ndarray of int64
        Vertex of ``merged`` of each vertex of ``mesh``.
    """
    if not isinstance(mesh, Mesh):
        raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
    keep, index = _merge_map(mesh.n_vertices, duplicate_vertices(mesh.vertices))
    T = index[mesh.elements]
    T = T[~_repeated_corner(T)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # no duplicates are left to warn about
        return Mesh(mesh.vertices[keep], T), index


def split_components(mesh):
    """Each connected component of ``mesh`` as its own Mesh, with the (n_c,) indices of its vertices in
    ``mesh`` (vertices in no element are left out): a list of (Mesh, indices), largest first."""
    labels = mesh.components()
    out = []
    for label in np.unique(labels[labels >= 0]):
        vertices = np.flatnonzero(labels == label)
        rank = np.full(mesh.n_vertices, -1)
        rank[vertices] = np.arange(vertices.size)
        elements = mesh.elements[labels[mesh.elements[:, 0]] == label]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", category=UserWarning)
            out.append((Mesh(mesh.vertices[vertices], rank[elements]), vertices))
    return sorted(out, key=lambda part: -part[1].size)
