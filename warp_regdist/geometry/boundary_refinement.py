"""Points and curves on the boundary of a tetrahedral mesh, made vertices and edges of a refined mesh.

The boundary triangles are refined as a surface (:func:`~warp_regdist.geometry.surface_points.refine`,
which numbers the new vertices after the mesh's). Every tetrahedron that has a refined
boundary face or an edge with new vertices is then replaced by a cone over the triangulations
of its faces: from a corner that is on no split edge and no refined face, over the opposite
face, or else from its centroid (a new vertex) over all four. A refined boundary face keeps
its triangulation; another face is cut by the Delaunay triangulation (in its plane) of its
corners and the new vertices on its edges, computed in one canonical order, so that the two
tetrahedra beside a face cut it the same way (a face split on one side only has one
triangulation, the fan from the opposite corner). No vertex moves: the solid is unchanged.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .face_triangulation import FaceTriangulation
from .mesh import _TET_FACES, Mesh, boundary_faces
from .surface_points import _plane_frame, refine

__all__ = ["refine_boundary"]

def refine_boundary(mesh, faces, bary, chains=(), feet=None):
    """:func:`~warp_regdist.geometry.surface_points.refine` for points on the boundary of a tetrahedral mesh
    (``faces`` index :func:`boundary_faces`); the Refinement's ``parent`` is the original tetrahedron."""
    F, owner = boundary_faces(mesh)
    R = refine(Mesh(mesh.vertices, F), faces, bary, chains, feet)
    X = list(R.mesh.vertices)
    origins = list(R.origins)
    T = mesh.elements
    split = R.edge_vertices
    cut = {}                                                       # sorted corners -> triangles
    for f in np.unique(R.parent[R.parent >= 0]):
        mine = R.mesh.faces[R.parent == f]
        if len(mine) > 1:
            cut[tuple(sorted(F[f].tolist()))] = mine.tolist()
    edges = T[:, [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]]
    lo, hi = edges.min(axis=2), edges.max(axis=2)
    split_keys = {a * len(X) + b for a, b in split}
    touched = np.isin(lo * len(X) + hi, list(split_keys)).any(axis=1)
    touched[owner[[f for f in range(len(F)) if tuple(sorted(F[f].tolist())) in cut]]] = True
    keep = ~touched
    refined_faces = set(cut)
    new, parent = [], []
    for t in np.flatnonzero(touched):
        corners = T[t].tolist()
        blocked = {v for a, b in zip(lo[t], hi[t]) if (a, b) in split for v in (a, b)}
        blocked |= {v for face in T[t][_TET_FACES] if tuple(sorted(face.tolist())) in refined_faces for v in face}
        free = [v for v in corners if v not in blocked]
        if free:
            # the cone from a corner on no split edge over its opposite face: the faces at that corner are
            # split only on their side opposite it, whose triangulation (a fan from it) is unique
            apex = min(free)
            bases = [face for face in T[t][_TET_FACES] if apex not in face]
        else:
            X.append(np.mean([X[v] for v in corners], axis=0))
            origins.append(("centroid", corners))
            apex, bases = len(X) - 1, list(T[t][_TET_FACES])
        triangles = []
        for face in bases:
            key = tuple(sorted(face.tolist()))
            if key not in cut:
                cut[key] = _triangulate(key, split, X)
            triangles += cut[key]
        for a, b, c in triangles:
            volume = np.linalg.det(np.array([X[b] - X[a], X[c] - X[a], X[apex] - X[a]]))
            new.append([a, b, c, apex] if volume > 0 else [a, c, b, apex])
            parent.append(t)
    elements = np.concatenate([T[keep], np.asarray(new, dtype=np.int64).reshape(-1, 4)])
    refined = Mesh(np.asarray(X), elements)
    return dataclasses.replace(R, mesh=refined, parent=np.concatenate([np.flatnonzero(keep), parent]).astype(np.int64),
                               origins=origins)


def _triangulate(key, split, X):
    """Delaunay triangles of face ``key`` (sorted corners) and the new vertices on its edges."""
    corners = np.array([X[v] for v in key])
    P = _plane_frame(corners)
    ft = FaceTriangulation(P, list(key))
    for s in range(3):
        a, c = key[s], key[(s + 1) % 3]
        for v in split.get((min(a, c), max(a, c)), []):
            e = X[c] - X[a]
            t = (X[v] - X[a]) @ e / (e @ e)
            ft.split_side(s, (1 - t) * P[s] + t * P[(s + 1) % 3], v)
    ft.make_delaunay()
    return [[ft.labels[i] for i in tri] for tri in ft.triangles]
