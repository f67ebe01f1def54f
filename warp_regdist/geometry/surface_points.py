"""Points and curves on a triangle mesh, made vertices and edges of a refined mesh.

A surface point is a face and barycentric coordinates (b0, b1, b2) on it (b_i >= 0,
sum 1), at sum_i b_i v_i; on a tetrahedral mesh, a face of its boundary
(:mod:`warp_regdist.geometry.boundary_refinement`). :func:`refine` inserts points into the mesh: a point on a
face's interior splits that face, a point on an edge splits the edge (both faces beside
it), a point at a vertex is that vertex; the faces that received points are then
re-triangulated to Delaunay in their own plane, so the surface does not change, and
the original vertices keep their numbers. A source point (not a curve's) also gets the feet
of its perpendiculars on the sides of its face (of both faces for a point on an edge): its
triangles then have no obtuse angle at it, which a split alone leaves (the angles at an
inside point sum to 360 degrees over three triangles) and which breaks the discrete maximum
principle (u went negative next to such points, by up to 0.4 h on spot). A source condition u = 0 at the inserted
vertex then holds at the point itself (docs/method.md, "Sources anywhere").
A curve's segment between two points of one face becomes a chain of edges (by edge flips
inside the face), so u = 0 at its vertices gives u = 0 all along it (u is linear on each edge).
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..errors import MeshError, MeshWarning
from ..tolerances import tolerances
from .face_triangulation import FaceTriangulation
from .mesh import Mesh, boundary_surface

__all__ = ["surface_points", "check_surface_points", "refine", "refinement_vjp", "Refinement", "Incidence", "snapped"]

_CHUNK = 4096
"""xyz points whose candidate faces :func:`surface_points` gathers at once."""

_FOOT_MARGIN = 0.05
"""A source point's perpendicular feet on its face's sides are inserted where they fall at least
this fraction of the side away from its ends (so no edge shorter than that is made)."""


def check_surface_points(mesh, points, name="points"):
    """Validated surface points: [(face, (b0, b1, b2)), ...] -> faces (p,) int64, bary (p, 3) float64."""
    if mesh.element_weights is not None:
        raise ValueError(f"expected a triangle mesh for {name}, got a PointCloud (its sources are point indices)")
    if mesh.element_dim == 3:
        mesh = boundary_surface(mesh)
    if isinstance(points, (str, bytes)) or not hasattr(points, "__len__"):
        raise ValueError(f"expected {name} as a list of (face, (b0, b1, b2)), got {points!r}")
    if len(points) == 0:
        raise ValueError(f"expected at least one surface point in {name}, got none")
    faces, bary = [], []
    for i, item in enumerate(points):
        try:
            face, b = item
            b = np.asarray(b, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"expected {name}[{i}] as (face, (b0, b1, b2)), got {item!r}") from None
        if isinstance(face, (bool, np.bool_)) or not isinstance(face, (int, np.integer)):
            raise ValueError(f"expected an integer face index in {name}[{i}], got {face!r}")
        if not 0 <= face < mesh.n_elements:
            raise ValueError(f"expected a face index in [0, {mesh.n_elements - 1}] in {name}[{i}], got {face}")
        if b.shape != (3,) or not np.isfinite(b).all():
            raise ValueError(f"expected 3 finite barycentric coordinates in {name}[{i}], got {item[1]!r}")
        if b.min() < -1e-9 or abs(b.sum() - 1.0) > 1e-6:
            raise ValueError(f"expected barycentric coordinates >= 0 that sum to 1 in {name}[{i}], got "
                             f"{b.tolist()} (sum {b.sum():.9g})")
        faces.append(int(face))
        bary.append(np.clip(b, 0.0, None) / np.clip(b, 0.0, None).sum())
    return np.asarray(faces, dtype=np.int64), np.asarray(bary)


def surface_points(mesh, xyz, return_distance=False, max_distance=None):
    """The closest surface point of every xyz point, as [(face, (b0, b1, b2)), ...].

    Parameters
    ----------
    mesh : Mesh
        Triangle mesh, or tetrahedral mesh: then its boundary, ``face`` indexing
        :func:`~warp_regdist.boundary_faces`.
    xyz : (p, 3) array_like
        Points in space.
    return_distance : bool
        Also return (p,) how far each point is from its surface point.
    max_distance : float or None
        Refuse points farther than this from the surface; None: 5% of the mesh's bounding box
        diagonal. math.inf accepts any point.
    """
    if mesh.element_weights is not None:
        raise ValueError("expected a triangle or tetrahedral mesh for surface_points, got a PointCloud")
    if mesh.element_dim == 3:
        mesh = boundary_surface(mesh)
    X = np.asarray(xyz, dtype=np.float64) if np.size(xyz) else np.zeros((0, 3))
    if X.ndim == 1 and X.size == 3:
        X = X[None]
    if X.ndim != 2 or X.shape[1] != 3 or X.shape[0] == 0:
        raise ValueError(f"expected xyz points of shape (p, 3) with p >= 1, got shape {np.shape(xyz)}")
    if not np.isfinite(X).all():
        raise ValueError(f"expected finite xyz points, got {np.count_nonzero(~np.isfinite(X).all(axis=1))} with NaN/inf")
    V, F = mesh.vertices, mesh.elements
    if max_distance is None:
        max_distance = 0.05 * float(np.linalg.norm(np.ptp(V[np.unique(F)], axis=0)))
    # the nearest vertex bounds the distance d0 to the surface; every face closer than d0 has its
    # centroid within d0 + (its largest centroid-to-corner distance)
    used = np.unique(F)
    d0, _ = cKDTree(V[used]).query(X)
    centroid = V[F].mean(axis=1)
    reach = d0 + np.linalg.norm(V[F] - centroid[:, None], axis=2).max() + 1e-12
    tree = cKDTree(centroid)
    faces = np.empty(len(X), dtype=np.int64)
    dist = np.empty(len(X))
    closest = np.empty((len(X), 3))
    for lo in range(0, len(X), _CHUNK):                     # (point, candidate face) pairs, a chunk at a time
        near = tree.query_ball_point(X[lo:lo + _CHUNK], reach[lo:lo + _CHUNK])
        point = np.repeat(np.arange(lo, lo + len(near)), [len(c) for c in near])
        face = np.concatenate([np.asarray(c, dtype=np.int64) for c in near])
        q = trimesh.triangles.closest_point(V[F[face]], X[point])
        d = np.linalg.norm(q - X[point], axis=1)
        best = np.lexsort((d, point))                       # by point, nearest first
        first = best[np.r_[0, np.flatnonzero(np.diff(point[best])) + 1]]
        faces[lo:lo + len(near)], dist[lo:lo + len(near)], closest[lo:lo + len(near)] = face[first], d[first], q[first]
    bary = np.clip(trimesh.triangles.points_to_barycentric(V[F[faces]], closest), 0.0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    far = np.flatnonzero(dist > max_distance)
    if far.size:
        raise ValueError(f"expected points within {max_distance:.6g} of the surface (max_distance), got point {far[0]} "
                         f"at distance {dist[far[0]]:.6g} ({far.size} such)")
    out = [(int(f), tuple(float(c) for c in b)) for f, b in zip(faces, bary)]
    return (out, dist) if return_distance else out


def snapped(b, vertex_snap):
    """Where the point of barycentric coordinates b lies once snapped: ("vertex", k) when
    b_k >= 1 - vertex_snap is its largest, ("side", k) (the side opposite corner k) when
    b_k <= ``tolerances.point_snap`` is its smallest, else ("face", None)."""
    k = int(np.argmax(b))
    if b[k] >= 1.0 - vertex_snap:
        return "vertex", k
    k = int(np.argmin(b))
    if b[k] <= tolerances.point_snap:
        return "side", k
    return "face", None


@dataclasses.dataclass(frozen=True)
class Refinement:
    """A mesh refined at surface points (see :func:`refine`).

    Attributes
    ----------
    mesh : Mesh
        The refined mesh; its first ``n_original`` vertices are the original ones.
    n_original : int
    point_vertices : (p,) ndarray of int64
        The refined mesh's vertex at every input point.
    displacement : (p,) ndarray of float
        How far each point moved onto a vertex or an edge (points within ``tolerances.point_snap``
        of one, in barycentric coordinates).
    curve_vertices : list of (c_i,) ndarray of int64
        For every segment chain given, its vertices in order.
    parent : (m',) ndarray of int64
        The original face of every refined face.
    edge_vertices : dict
        (lo, hi) original edge (lo < hi) -> the new vertices on it, in order from lo.
    origins : list of tuple
        How each new vertex n_original + q was placed, for :func:`refinement_vjp`: ("face", point,
        corners), ("side", point, a, c, corner a, corner c) at (1 - t) v_a + t v_c with t the point's
        barycentric share of c, ("foot", x vertex, a, c) the foot of the perpendicular from a vertex onto
        edge a-c, ("centroid", corners) of a split tetrahedron, or ("lifted",) where a curve crosses itself.
    """

    mesh: Mesh
    n_original: int
    point_vertices: np.ndarray
    displacement: np.ndarray
    curve_vertices: list
    parent: np.ndarray
    edge_vertices: dict
    origins: list


def refine(mesh, faces, bary, chains=(), feet=None):
    """Insert surface points (faces (p,), bary (p, 3)) into a triangle mesh.

    ``chains``: sequences of point indices; consecutive points of a chain must lie on one common
    face (closure included), and the segment between them becomes a chain of edges.
    ``feet``: (p,) bool, the points that also get the feet of their perpendiculars (default: those
    on no chain).
    """
    V, T, n = mesh.vertices, mesh.elements, mesh.n_vertices
    snap = tolerances.point_snap
    incidence = Incidence(T, n)
    positions = [p for p in V]
    origins = []
    edge_points = {}                              # (lo, hi) -> [[t, vertex], ...]
    face_points = {}                              # face -> [[bary, vertex], ...]

    def new_vertex(x, origin):
        positions.append(x)
        origins.append(origin)
        return len(positions) - 1

    def edge_vertex(a, c, t, origin):
        """The vertex at (1 - t) v_a + t v_c on edge a-c (a new one, placed by ``origin``, unless one is
        within snap)."""
        lo, hi, t = (a, c, t) if a < c else (c, a, 1.0 - t)
        bucket = edge_points.setdefault((lo, hi), [])
        hit = next((e for e in bucket if abs(e[0] - t) <= snap), None)
        if hit is None:
            hit = [t, new_vertex((1 - t) * V[lo] + t * V[hi], origin)]
            bucket.append(hit)
            incidence.on_edge[hit[1]] = (lo, hi)
        return hit[1]

    def add_feet(x, f):
        """The feet of the perpendiculars from vertex x onto the sides of face f, where they fall inside."""
        for s in range(3):
            a, c = T[f, s], T[f, (s + 1) % 3]
            e = V[c] - V[a]
            t = (positions[x] - V[a]) @ e / (e @ e)
            if _FOOT_MARGIN < t < 1 - _FOOT_MARGIN and np.linalg.norm(positions[x] - V[a] - t * e) > snap * np.sqrt(e @ e):
                edge_vertex(a, c, t, ("foot", x, a, c))

    on_curves = {i for chain in chains for i in chain}
    if feet is None:
        feet = np.array([i not in on_curves for i in range(len(faces))], dtype=bool)
    vertex_of = np.empty(len(faces), dtype=np.int64)
    for i, (f, b) in enumerate(zip(faces, bary)):
        corners = T[f]
        kind, k = snapped(b, tolerances.curve_snap if i in on_curves else snap)
        if kind == "vertex":
            vertex_of[i] = corners[k]
            continue
        if kind == "side":
            a, c = corners[(k + 1) % 3], corners[(k + 2) % 3]
            t = b[(k + 2) % 3] / (b[(k + 1) % 3] + b[(k + 2) % 3])
            vertex_of[i] = edge_vertex(a, c, t, ("side", i, a, c, (k + 1) % 3, (k + 2) % 3))
            if feet[i]:
                for g in incidence.edge(a, c):
                    add_feet(vertex_of[i], g)
            continue
        bucket = face_points.setdefault(int(f), [])
        hit = next((e for e in bucket if np.abs(e[0] - b).max() <= snap), None)
        if hit is None:
            hit = [b, new_vertex(b @ V[corners], ("face", i, corners))]
            bucket.append(hit)
            if feet[i]:
                add_feet(hit[1], f)
        vertex_of[i] = hit[1]
    requested = np.einsum("pi,pij->pj", bary, V[T[faces]])
    sources = set(vertex_of.tolist())

    # the faces of each chain segment: the common face of its two points
    segments = {}
    for chain in chains:
        for i, j in zip(chain[:-1], chain[1:]):
            if vertex_of[i] == vertex_of[j]:
                continue
            f = _common_face(incidence, faces[i], faces[j], vertex_of[i], vertex_of[j])
            segments.setdefault(f, []).append((vertex_of[i], vertex_of[j]))

    touched = set(face_points) | set(segments)
    for lo, hi in edge_points:
        touched |= set(incidence.edge(lo, hi))
    keep = np.ones(len(T), dtype=bool)
    new_faces, parent = [], []
    chain_points = {}
    for f in sorted(touched):
        corners = T[f]
        P = _plane_frame(V[corners])
        ft = FaceTriangulation(P, corners.tolist())
        # inside points first, so that each is joined to the corners; then the sides' points (the
        # feet of the perpendiculars split the triangles at the inside point into right triangles)
        for b, v in face_points.get(f, []):
            ft.insert(b @ P, v)
        on_sides = []
        for s in range(3):
            a, c = corners[s], corners[(s + 1) % 3]
            for t, v in edge_points.get((min(a, c), max(a, c)), []):
                ts = t if a < c else 1 - t
                on_sides.append((v not in sources, s, (1 - ts) * P[s] + ts * P[(s + 1) % 3], v))
        for _, s, xy, v in sorted(on_sides, key=lambda item: item[:2]):   # the points themselves before feet
            ft.split_side(s, xy, v)
        ft.make_delaunay()
        local = {label: i for i, label in enumerate(ft.labels)}
        for a, c in segments.get(f, []):
            chain = ft.recover(local[a], local[c])
            for idx, label in enumerate(ft.labels):
                if label is None:                      # where the curve crosses itself
                    ft.labels[idx] = new_vertex(_lift(ft.xy[idx], P, V[corners]), ("lifted",))
            chain_points[(a, c)] = [ft.labels[idx] for idx in chain]
        if len(ft.triangles) > 1:
            keep[f] = False
            new_faces += [[ft.labels[i] for i in tri] for tri in ft.triangles]
            parent += [f] * len(ft.triangles)
    elements = np.concatenate([T[keep], np.asarray(new_faces, dtype=np.int64).reshape(-1, 3)])
    parents = np.concatenate([np.flatnonzero(keep), np.asarray(parent, dtype=np.int64)])
    X = np.asarray(positions)
    try:
        with warnings.catch_warnings():      # the input's duplicate or cracked vertices warned when it was built
            warnings.simplefilter("ignore", MeshWarning)
            refined = Mesh(X, elements)
    except MeshError as err:
        raise ValueError(f"expected surface points that refine the mesh into valid triangles, got: {err}") from None
    curves = []
    for chain in chains:
        verts = [vertex_of[chain[0]]]
        for i, j in zip(chain[:-1], chain[1:]):
            a, c = vertex_of[i], vertex_of[j]
            verts += chain_points.get((a, c), [a, c])[1:]
        curves.append(np.asarray(verts, dtype=np.int64))
    return Refinement(mesh=refined, n_original=n, point_vertices=vertex_of,
                      displacement=np.linalg.norm(X[vertex_of] - requested, axis=1), curve_vertices=curves,
                      parent=parents, edge_vertices={key: [v for _, v in sorted(bucket)] for key, bucket in
                                                     edge_points.items()}, origins=origins)


def refinement_vjp(refinement, vertices, bary, grad_positions):
    """Pull the gradient of a loss with respect to the refined mesh's positions (n', 3) back to the
    original ``vertices`` (n, 3) and the points' barycentric coordinates ``bary`` (p, 3) as given to
    :func:`refine`, the points staying at their barycentric coordinates: ((n, 3), (p, 3)).

    New vertices are placed in order, each from original vertices and earlier new ones, so the
    pullback runs over them in reverse: a face point x = b . v_corners, a point on a side
    x = (1 - t) v_a + t v_c with t = b_c / (b_a + b_c), a foot x = v_a + s e with e = v_c - v_a and
    s = (y - v_a) . e / |e|^2 for the vertex y it drops from."""
    n = refinement.n_original
    V = np.asarray(vertices, dtype=np.float64)
    X = refinement.mesh.vertices
    grad = np.array(grad_positions, dtype=np.float64)
    gV, gb = grad[:n].copy(), np.zeros((len(bary), 3))
    for q in range(len(refinement.origins) - 1, -1, -1):
        origin, g = refinement.origins[q], grad[n + q]
        if origin[0] == "face":
            _, i, corners = origin
            gV[corners] += bary[i][:, None] * g
            gb[i] += V[corners] @ g
        elif origin[0] == "side":
            _, i, a, c, ka, kc = origin
            ba, bc = bary[i][ka], bary[i][kc]
            t = bc / (ba + bc)
            gV[a] += (1.0 - t) * g
            gV[c] += t * g
            dt = (V[c] - V[a]) @ g                       # dL/dt
            gb[i, ka] -= dt * bc / (ba + bc) ** 2
            gb[i, kc] += dt * ba / (ba + bc) ** 2
        elif origin[0] == "foot":
            _, y, a, c = origin
            e, w = V[c] - V[a], X[y] - V[a]
            ee = e @ e
            s = (w @ e) / ee
            ds = g @ e                                   # dL/ds; x = v_a + s e
            # s = (w . e) / (e . e): ds/dw = e / ee, ds/de = (w - 2 s e) / ee
            gw, ge = ds * e / ee, s * g + ds * (w - 2.0 * s * e) / ee
            if y < n:
                gV[y] += gw
            else:
                grad[y] += gw                            # a new vertex placed earlier: pulled back later
            gV[a] += g - gw - ge
            gV[c] += ge
        elif origin[0] == "centroid":
            gV[list(origin[1])] += g / len(origin[1])
        else:
            raise ValueError("expected points only to differentiate through, got a curve that crosses itself")
    return gV, gb


def _plane_frame(corners):
    """(3, 3) triangle -> (3, 2) its corners in an orthonormal frame of its plane (counter-clockwise)."""
    e1, e2 = corners[1] - corners[0], corners[2] - corners[0]
    x = e1 / np.linalg.norm(e1)
    y = e2 - (e2 @ x) * x
    y /= np.linalg.norm(y)
    return np.array([[0.0, 0.0], [np.linalg.norm(e1), 0.0], [e2 @ x, e2 @ y]])


def _lift(xy, P, corners):
    """A point of the plane frame P back to 3D."""
    M = np.array([[P[1, 0] - P[0, 0], P[2, 0] - P[0, 0]], [P[1, 1] - P[0, 1], P[2, 1] - P[0, 1]]])
    w1, w2 = np.linalg.solve(M, np.asarray(xy) - P[0])
    return (1 - w1 - w2) * corners[0] + w1 * corners[1] + w2 * corners[2]


class Incidence:
    """The faces at an edge and at a vertex of triangles T (m, 3), by binary search."""

    def __init__(self, T, n):
        self.n, self.m = n, len(T)
        a, b = T.T.ravel(), T[:, [1, 2, 0]].T.ravel()          # side s of every face, s = 0, 1, 2
        key = np.minimum(a, b) * n + np.maximum(a, b)
        self.edge_order = np.argsort(key, kind="stable")
        self.edge_keys = key[self.edge_order]
        flat = T.ravel()
        self.vertex_order = np.argsort(flat, kind="stable")
        self.vertex_starts = np.searchsorted(flat[self.vertex_order], np.arange(n + 1))
        self.on_edge = {}                                       # new vertex -> its original edge

    def edge(self, a, b):
        k = min(a, b) * self.n + max(a, b)
        lo, hi = np.searchsorted(self.edge_keys, k, "left"), np.searchsorted(self.edge_keys, k, "right")
        return (self.edge_order[lo:hi] % self.m).tolist()

    def vertex(self, v):
        return (self.vertex_order[self.vertex_starts[v]:self.vertex_starts[v + 1]] // 3).tolist()


def _common_face(incidence, fa, fb, va, vb):
    """A face whose closure holds both points (given by their faces and refined vertices)."""

    def faces_of(f, v):
        if v < incidence.n:
            return set(incidence.vertex(v))
        if v in incidence.on_edge:
            return set(incidence.edge(*incidence.on_edge[v]))
        return {int(f)}

    common = faces_of(fa, va) & faces_of(fb, vb)
    if not common:
        raise ValueError(f"expected consecutive curve points on a common face, got points on faces {fa} and {fb}")
    return min(common)
