"""Source sets: vertex indices, points anywhere on the surface, curves.

Vertex sources are checked here. The points and curves of all columns are inserted into
one refined mesh (:func:`warp_regdist.geometry.surface_points.refine`); each column's sources are then
vertices of that mesh: its vertex sources (the original vertices keep their numbers), the
vertices at its points, and the vertices along its curves.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph

from ...geometry.boundary_refinement import refine_boundary
from ...geometry.mesh import boundary_surface
from ...geometry.curves import trace_curve
from ...geometry.surface_points import check_surface_points, refine

__all__ = ["vertex_sources", "SurfaceSources", "surface_sources", "check_surface_batch", "refined_result"]


def vertex_sources(sources, column, n, labels):
    """Validated source vertices of column ``column`` -> (indices (s,), reachable (n,) bool: the
    vertices of the sources' connected components, ``labels`` (n,) from Mesh.components())."""
    if isinstance(sources, (str, bytes)):
        raise ValueError(f"expected source set {column} as vertex indices, got the string {sources!r}")
    if not hasattr(sources, "__iter__") or isinstance(sources, np.ndarray) and sources.ndim == 0:
        raise ValueError(f"expected source set {column} as a list of vertex indices, got {sources!r} "
                         "(one vertex i is the set [i]; solve_many takes a list of such sets)")
    try:
        arr = np.asarray(list(sources) if not isinstance(sources, np.ndarray) else sources)
    except (TypeError, ValueError):  # ragged nesting, non-iterable items
        raise ValueError(f"expected source set {column} as a flat list of vertex indices, "
                         f"got {repr(sources)[:80]}") from None
    if arr.size == 0:
        raise ValueError(f"expected at least one source vertex in source set {column}, got none")
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer) or
                                 (np.issubdtype(arr.dtype, np.floating) and np.all(arr == np.round(arr)))):
        raise ValueError(f"expected integer vertex indices in source set {column}, got {arr.ravel()[:5].tolist()}")
    bad = arr[(arr < 0) | (arr >= n)]
    if bad.size:
        raise ValueError(f"expected source vertex indices in [0, {n - 1}] in source set {column}, got {bad.ravel()[0].item()!r}")
    arr = arr.astype(np.int64).ravel()
    comps = np.unique(labels[arr])
    reachable = np.isin(labels, comps[comps >= 0])
    reachable[arr] = True
    return np.unique(arr), reachable


class SurfaceSources:
    """The refined mesh of a batch and every column's source vertices on it.

    Attributes
    ----------
    refinement : warp_regdist.geometry.surface_points.Refinement
    sets : list of (s_j,) ndarray of int64
        Column j's source vertices of the refined mesh.
    curves : list of list of (c,) ndarray
        Column j's curves, each as its chain of refined vertices.
    key : str
        Identifies the refined problem (for reusing its solver).
    bary : (P, 3) ndarray
        The barycentric coordinates of every point given to the refinement (the columns' points, then
        their curves' points).
    own_points : list of (p_j,) ndarray of int64
        Column j's points among them.
    """

    def __init__(self, refinement, sets, curves, key, bary, own_points):
        self.refinement, self.sets, self.curves, self.key = refinement, sets, curves, key
        self.bary, self.own_points = bary, own_points

    def signs(self, j):
        """(n',) +1 / -1 on the two sides of column j's closed curves (-1 on the left of their
        direction, seen from the side the face normals point to), 0 on them."""
        mesh = self.refinement.mesh
        F, n = mesh.elements, mesh.n_vertices
        cut = np.concatenate([chain[:-1] * n + chain[1:] for chain in self.curves[j]])   # the curves' directed edges
        a, b = F.ravel(), F[:, [1, 2, 0]].ravel()              # every face's sides, in its orientation
        face = np.repeat(np.arange(len(F)), 3)
        left, right = np.isin(a * n + b, cut), np.isin(b * n + a, cut)
        # faces joined across every edge that is not on a curve
        key = np.minimum(a, b) * n + np.maximum(a, b)
        on_curve = np.isin(key, key[left | right])
        order = np.argsort(key)
        same = (key[order][1:] == key[order][:-1]) & ~on_curve[order][1:]
        g = sp.coo_matrix((np.ones(same.sum()), (face[order][1:][same], face[order][:-1][same])), shape=(len(F),) * 2)
        _, label = csgraph.connected_components(g, directed=False)
        inside, outside = set(label[face[left]].tolist()), set(label[face[right]].tolist())
        if not inside or inside & outside:
            raise ValueError("expected closed curves that cut the surface into an inside (left of the curve) and an "
                             "outside for a signed distance, got curves with the same region on both sides (a curve "
                             "that crosses itself or retraces its path; give points a few faces apart)")
        sign = np.ones(n)
        vertex_face = np.full(n, -1)
        vertex_face[F.ravel()] = np.repeat(np.arange(len(F)), 3)
        sign[np.isin(label[np.maximum(vertex_face, 0)], list(inside))] = -1.0
        for chain in self.curves[j]:
            sign[chain] = 0.0
        return sign


def surface_sources(mesh, k, sets, points, curves, closed):
    """The refined mesh of k columns: ``sets`` (k lists of vertices or None), ``points`` (k lists
    of surface points or None), ``curves`` (k curves, each a list of surface points, or None)."""
    surface = boundary_surface(mesh)
    faces, bary, chains, own_points, own_curves, feet = [], [], [], [], [], []
    for j in range(k):
        f, b = (check_surface_points(surface, points[j], f"points of column {j}") if points is not None
                else (np.zeros(0, np.int64), np.zeros((0, 3))))
        own_points.append(np.arange(len(f)) + sum(len(x) for x in faces))
        faces.append(f)
        bary.append(b)
        feet.append(np.ones(len(f), dtype=bool))
        own_curves.append([])
        if curves is not None:
            cf, cb = check_surface_points(surface, curves[j], f"curve of column {j}")
            given = len(cf)
            cf, cb, chain = trace_curve(surface, cf, cb, closed)
            offset = sum(len(x) for x in faces)
            faces.append(cf)
            bary.append(cb)
            feet.append(np.arange(len(cf)) < given)         # the curve's own points, not its edge crossings
            own_curves[j].append(len(chains))
            chains.append([offset + i for i in chain])
    F, B, feet = np.concatenate(faces), np.concatenate(bary), np.concatenate(feet)
    R = refine(mesh, F, B, chains, feet) if mesh.element_dim == 2 else refine_boundary(mesh, F, B, chains, feet)
    out_sets, out_curves = [], []
    for j in range(k):
        s = [] if sets is None else [np.asarray(sets[j], dtype=np.int64).ravel()]
        s.append(R.point_vertices[own_points[j]])
        s += [R.curve_vertices[c] for c in own_curves[j]]
        out_sets.append(np.unique(np.concatenate(s)))
        out_curves.append([R.curve_vertices[c] for c in own_curves[j]])
    return SurfaceSources(R, out_sets, out_curves, R.mesh.sha256(), B, own_points)


def check_surface_batch(source_sets, points, curves, closed, initial):
    """The number of columns k of a batch with points or curves; ValueError for lists of other
    lengths, ``closed`` without curves, or a warm start (the refined mesh's vertices differ)."""
    given = {name: x for name, x in (("source sets", source_sets), ("points", points), ("curves", curves))
             if x is not None}
    for name, x in given.items():
        if isinstance(x, (str, bytes)) or not hasattr(x, "__len__"):
            raise ValueError(f"expected {name} as a list with one entry per column, got {x!r}")
    lengths = {name: len(x) for name, x in given.items()}
    if closed and curves is None:
        raise ValueError("expected a curve with closed=True, got none")
    if len(set(lengths.values())) != 1 or 0 in lengths.values():
        raise ValueError(f"expected one entry per column (at least one) in each of {', '.join(lengths)}, got lengths "
                         f"{lengths}")
    if initial is not None:
        raise ValueError("expected initial=None with points or curves (they refine the mesh, so a warm start of "
                         f"its vertices does not fit), got {type(initial).__name__}")
    return next(iter(lengths.values()))


def refined_result(res, S, n, closed):
    """The result ``res`` of a batch solved on the refined mesh of ``S`` (a :class:`SurfaceSources`),
    reported on the first n vertices (the original mesh's) with the refined mesh, its distances and
    curves beside them, and the signed distance of closed curves on triangle meshes."""
    k = len(S.sets)
    res["refined_mesh"] = S.refinement.mesh
    res["refined_distance"] = res.distance
    res["distance"] = res.distance[:n]
    res["refined_curves"] = S.curves
    if closed and S.refinement.mesh.element_dim == 2:
        signs = np.stack([S.signs(j) for j in range(k)], axis=1)
        res["refined_signed_distance"] = signs * res.refined_distance
        res["signed_distance"] = signs[:n] * res.distance
    return res
