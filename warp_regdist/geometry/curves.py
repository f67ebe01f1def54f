"""Curves on a triangle mesh: polylines through surface points, traced across the faces.

Between two consecutive points A and B of a curve, the curve is the section of the surface
by the plane through A and B that contains the mean normal n of their faces (normal
(B - A) x n), from A towards B: :func:`trace_curve` walks that section face by face and
returns the points where it crosses edges. Between two crossings the curve is straight
inside one face, so inserting the points and these segments into the mesh
(:func:`warp_regdist.geometry.surface_points.refine`) makes the curve a chain of edges.
On a plane the section is the straight segment A-B (the geodesic); on a curved surface it
is a planar curve close to the geodesic for points a few faces apart. Vertices within
``tolerances.point_snap`` mean edge lengths of the plane lie on it, so a section along edges
(an equator through the vertices of a sphere) is walked the same way whether the file that held
the vertices rounded them or not.
"""

from __future__ import annotations

import numpy as np

from ..tolerances import tolerances
from .operators import mean_edge_length
from .surface_points import Incidence, snapped

__all__ = ["trace_curve", "face_neighbours"]


def face_neighbours(faces):
    """(m, 3) triangles -> (m, 3) the face across side s (corners s, s + 1) of every face, -1 at the boundary."""
    m = len(faces)
    a, b = faces.ravel(), faces[:, [1, 2, 0]].ravel()
    n = int(faces.max()) + 1
    key = a * n + b
    order = np.argsort(key)
    twin = np.searchsorted(key[order], b * n + a)
    twin = np.minimum(twin, m * 3 - 1)
    found = key[order][twin] == b * n + a
    out = np.where(found, order[twin] // 3, -1)
    return out.reshape(m, 3)


def _touching(incidence, T, neighbours, f, b):
    """The faces whose closure holds the surface point (f, b), snapped by ``tolerances.point_snap``: the
    faces a walk may start from (refine may move a curve's point further, onto a corner of them)."""
    kind, k = snapped(b, tolerances.point_snap)
    if kind == "vertex":
        return set(incidence.vertex(T[f, k]))
    if kind == "side":
        g = neighbours[f, (k + 1) % 3]                 # the side opposite corner k: corners k + 1, k + 2
        return {int(f)} | ({int(g)} if g >= 0 else set())
    return {int(f)}


def trace_curve(mesh, faces, bary, closed=False):
    """The curve through surface points (faces (p,), bary (p, 3)), with its edge crossings.

    Returns (faces (q,), bary (q, 3), chain (q',)): the input points followed by the crossings,
    and the chain of point indices along the curve (back to the first point when ``closed``).
    """
    if len(faces) < 2:
        raise ValueError(f"expected a curve of at least 2 points, got {len(faces)}")
    V, T = mesh.vertices, mesh.elements
    neighbours = face_neighbours(T)
    incidence = Incidence(T, mesh.n_vertices)

    normals = np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    on_plane = tolerances.point_snap * mean_edge_length(V, T)
    out_f, out_b = list(faces), list(bary)
    chain = [0]
    pairs = list(zip(range(len(faces) - 1), range(1, len(faces))))
    if closed:
        pairs.append((len(faces) - 1, 0))
    for ia, ib in pairs:
        pa, pb = bary[ia] @ V[T[faces[ia]]], bary[ib] @ V[T[faces[ib]]]
        start = _touching(incidence, T, neighbours, faces[ia], bary[ia])
        goal = _touching(incidence, T, neighbours, faces[ib], bary[ib])
        if not start & goal:
            for f, b in _walk(V, T, neighbours, normals, start, goal, pa, pb, (ia, ib), on_plane):
                out_f.append(f)
                out_b.append(b)
                chain.append(len(out_f) - 1)
        chain.append(ib)
    return np.asarray(out_f, dtype=np.int64), np.asarray(out_b), chain


def _walk(V, T, neighbours, normals, start, goal, pa, pb, names, on_plane):
    """Edge crossings [(face, bary)] of a plane section from pa (on the faces ``start``) to pb: the
    plane through both that contains their faces' mean normal, or else either point's normal; the
    vertices within ``on_plane`` of it lie on it."""
    d = pb - pa
    tiny = 1e-9 * np.linalg.norm(d)
    upright = False
    for normal in (normals[sorted(start)].sum(axis=0) + normals[sorted(goal)].sum(axis=0),
                   normals[sorted(start)].sum(axis=0), normals[sorted(goal)].sum(axis=0)):
        m = np.cross(d, normal)
        if np.linalg.norm(m) <= 1e-12 * np.linalg.norm(d) * np.linalg.norm(normal):
            upright = True
            continue
        phi = (V - pa) @ m
        phi[np.abs(phi) <= on_plane * np.linalg.norm(m)] = 0.0
        out = _section(V, T, neighbours, start, goal, pa, d, phi, tiny)
        if out is not None:
            return out
    if upright:
        raise ValueError(f"expected curve points {names[0]} and {names[1]} not along the surface normal, got "
                         "points one above the other")
    raise ValueError(f"expected curve points {names[0]} and {names[1]} joined by a section of the surface, got "
                     "sections that do not reach the next point either way round, or reach the boundary "
                     "(add points between them)")


def _section(V, T, neighbours, start, goal, pa, d, phi, tiny):
    """The crossings of the section phi = 0 from pa to a face of ``goal``, or None."""
    plus = phi >= 0

    def crossing(f, s):
        a, b = T[f, s], T[f, (s + 1) % 3]
        t = phi[a] / (phi[a] - phi[b])
        x = (1 - t) * V[a] + t * V[b]
        w = np.zeros(3)
        w[s], w[(s + 1) % 3] = 1 - t, t
        return x, w

    candidates = []
    for f in sorted(start):
        for s in range(3):
            if plus[T[f, s]] != plus[T[f, (s + 1) % 3]]:
                x, w = crossing(f, s)
                if np.linalg.norm(x - pa) > tiny:
                    ahead = (x - pa) @ d
                    candidates.append((ahead <= 0, abs(ahead), f, s, w))
    # towards the next point first; the section is a closed loop on a closed surface, so the
    # other way round reaches it too when the first way runs into the boundary
    for *_, f, s, w in sorted(candidates, key=lambda c: c[:2]):
        out = _follow(T, neighbours, plus, crossing, goal, f, s, w)
        if out is not None:
            return out
    return None


def _follow(T, neighbours, plus, crossing, goal, f, s, w):
    """The crossings from side s of face f on, until a face of ``goal``; None at the boundary or
    after every face (a loop that misses the goal)."""
    out = []
    for _ in range(len(T)):
        out.append((f, w))
        g = neighbours[f, s]
        if g < 0:
            return None
        if g in goal:
            return out
        a, b = T[f, s], T[f, (s + 1) % 3]
        sg = next(r for r in range(3) if T[g, r] == b and T[g, (r + 1) % 3] == a)
        s = next(r for r in ((sg + 1) % 3, (sg + 2) % 3) if plus[T[g, r]] != plus[T[g, (r + 1) % 3]])
        f = g
        _, w = crossing(f, s)
    return None
