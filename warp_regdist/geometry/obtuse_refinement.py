"""Obtuse angles of the intrinsic Delaunay triangulation removed by inserting vertices.

The intrinsic flips (:mod:`warp_regdist.geometry.intrinsic`) make every interior cotangent weight
>= 0, but they leave obtuse angles: a boundary side is never flipped, and an interior edge is Delaunay
while one of its opposite angles is far above 90 degrees. Where a triangle's angle at c is obtuse,
the weight cot(c) / 2 of the side ab opposite it is negative, max(u, 0) can be steeper there than u,
and the minimizer can fall below 0 at a or b (on a triangulation without obtuse angles max(u, 0) is
feasible and never worse, so the minimizer is >= 0; docs/real-meshes.md). Two insertions remove them:

- a boundary side opposite an angle above 90 degrees is split at the foot of the altitude (two right
  triangles);
- a triangle with an angle above INTERIOR_ANGLE opposite an interior side gets a vertex at its
  circumcenter (Delaunay refinement, Chew 1989, Ruppert 1995; intrinsically Sharp, Soliman and Crane
  2019): the straight line from its centroid is traced across the faces to it
  (:func:`~warp_regdist.geometry.intrinsic_points.trace`); where the line leaves by a boundary side,
  that side is split at its midpoint instead. Inserting the circumcenter of every obtuse triangle
  cannot end (the triangles it makes are obtuse again); above 120 degrees it does, and the distance
  stays >= 0 on the meshes measured (docs/real-meshes.md).

Each new vertex is a point of the surface (:func:`~warp_regdist.geometry.intrinsic_points.locator`:
an input face and barycentric coordinates, moved onto a side within SNAP of it), and the mesh is split
there (two faces on an edge, one face into three): the refined mesh is an ordinary :class:`Mesh` on
the same surface, whose first n vertices and their numbers are the input's. Rounds of insertions (one
per face of the mesh and of the triangulation each round, the most obtuse first) and flips repeat
until no such angle is left.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import scipy.sparse as sp

from ..tolerances import tolerances
from ..errors import MeshWarning
from .intrinsic import _edges, _pairs, id_gradient, intrinsic_delaunay
from .intrinsic_points import Dual, circumcenter, locator, side_length, trace, value
from .mesh import Mesh

__all__ = ["ObtuseRefinement", "refine_obtuse_angles", "obtuse_angles", "obtuse_refinement"]

OBTUSE = 1e-9
"""A boundary side is split where the cosine of the angle opposite it is below -OBTUSE."""
INTERIOR_ANGLE = 120.0
"""A triangle gets its circumcenter where an angle opposite an interior side is above this (degrees)."""
FOOT_RANGE = (0.01, 0.99)
"""The foot's parameter along its side is clamped to this range (within 1% of a corner the angle is all but right)."""
SNAP = 0.01
"""A new vertex whose barycentric coordinate in its input face is below SNAP moves onto the side opposite;
one within SNAP of a vertex is not inserted."""
MAX_ROUNDS = 64


@dataclasses.dataclass
class ObtuseRefinement:
    """A triangle mesh refined until its intrinsic Delaunay triangulation has no angle to remove.

    Attributes
    ----------
    mesh : Mesh
        The refined mesh: vertices 0..n-1 are the input's, n..n+k-1 the inserted ones.
    weights : (k, n) scipy.sparse.csr_matrix
        Each inserted vertex as a combination of the input's: x[n + i] = weights[i] @ x (two entries on
        an input edge, three inside an input face; they sum to 1).
    parent : (m',) int64
        The input face each face of ``mesh`` lies in.
    remaining : int
        Angles still to remove when the rounds ended (0 when none is left).
    original : Mesh
        The input mesh.
    interior_angle : float
        The bound on interior angles it was refined to (degrees).
    triangulation : IntrinsicTriangulation or None
        The intrinsic Delaunay triangulation of ``mesh`` (None on a tufted cover).
    """

    mesh: Mesh
    weights: sp.csr_matrix
    parent: np.ndarray
    remaining: int
    original: Mesh
    interior_angle: float = INTERIOR_ANGLE
    triangulation: object = None

    @property
    def n_inserted(self):
        return int(self.weights.shape[0])

    def interpolation(self):
        """The (n + k, n) sparse matrix P = [I; weights], P @ x = the refined mesh's x."""
        return sp.vstack([sp.identity(self.original.n_vertices, format="csr"), self.weights], format="csr")

    def vjp(self, grad_positions):
        """dL/dx (n, 3) of the input's positions from dL/dx' (n + k, 3) of the refined mesh's: each
        inserted vertex x' = sum_c beta_c x_c moves with the corners x_c of the face it was put in and with
        its coordinates beta, functions of the lengths of the intrinsic triangulation it was found in (the
        rounds are replayed with :class:`~warp_regdist.geometry.intrinsic_points.Dual` numbers)."""
        g = np.array(grad_positions, dtype=np.float64)
        X = self.mesh.vertices
        if g.shape != X.shape:
            raise ValueError(f"expected a gradient of shape {X.shape} (the refined mesh's vertices), got {g.shape}")
        if self.n_inserted == 0:
            return g
        for T, n_r, corners, beta, dbeta in reversed(_rounds(self.original, self.interior_angle, dual=True)[5]):
            gk = g[n_r:n_r + beta.shape[0]]
            g = g[:n_r]
            for c in range(3):
                np.add.at(g, corners[:, c], beta[:, c, None] * gk)
            dbeta_value = np.einsum("sj,scj->sc", gk, X[corners])
            g += id_gradient(T, X[:n_r], dbeta.T @ dbeta_value.ravel())
        return g


def _candidates(vertices, faces, interior_angle=INTERIOR_ANGLE):
    """The intrinsic Delaunay triangulation T of (``vertices`` (n, 3), ``faces`` (m, 3)) and what to insert
    in it, most obtuse first: halfedges of T (s,) (a boundary side opposite an angle above 90 degrees: its
    foot; an interior side opposite one above ``interior_angle``: the circumcenter of its face) and the
    cosines of the angles opposite them (s,). T is None on a tufted cover (it has no boundary, and its
    faces are not the mesh's)."""
    F = np.asarray(faces, dtype=np.int64)
    T = intrinsic_delaunay(vertices, F)
    if T.tufted:
        return None, np.zeros(0, dtype=np.int64), np.zeros(0)
    L = T.lengths.ravel()
    h = np.arange(L.size)
    f, i = h // 3, h % 3
    l_ab, l_bc, l_ca = L[h], L[3 * f + (i + 1) % 3], L[3 * f + (i + 2) % 3]
    cos_c = (l_bc * l_bc + l_ca * l_ca - l_ab * l_ab) / (2.0 * l_bc * l_ca)
    boundary = T.twin < 0
    bad = np.flatnonzero(cos_c < np.where(boundary, -OBTUSE, np.cos(np.radians(interior_angle))))
    bad = bad[np.argsort(cos_c[bad], kind="stable")]
    return T, bad, cos_c[bad]


def obtuse_angles(vertices, faces, interior_angle=INTERIOR_ANGLE):
    """The angles :func:`refine_obtuse_angles` removes first in (``vertices`` (n, 3), ``faces`` (m, 3)),
    most obtuse first: (face of the intrinsic Delaunay triangulation (s,), corner where the side opposite
    the angle starts (s,), on the boundary (s,) bool, cosine of the angle (s,)). Empty on a tufted cover."""
    T, h, cos_c = _candidates(vertices, faces, interior_angle)
    return h // 3, h % 3, np.zeros(h.size, dtype=bool) if T is None else T.twin[h] < 0, cos_c


def _foot(T, h, dual):
    """The foot of the altitude onto halfedge h from the corner opposite, as barycentric coordinates (3,)
    of h's face."""
    f, i = h // 3, h % 3
    l_ab, l_bc, l_ca = (side_length(T, 3 * f + (i + k) % 3, dual) for k in range(3))
    t = 0.5 + (l_ca * l_ca - l_bc * l_bc) / (2.0 * l_ab * l_ab)
    if not FOOT_RANGE[0] <= value(t) <= FOOT_RANGE[1]:
        t = float(np.clip(value(t), *FOOT_RANGE))
    return _on_side(h, t)


def _on_side(h, t):
    beta = [0.0, 0.0, 0.0]
    beta[h % 3], beta[(h + 1) % 3] = 1.0 - t, t
    return beta


def _point(T, h, dual):
    """The point of T to insert for halfedge h (:func:`_candidates`): (face of T, barycentric (3,)), or
    None where the line to the circumcenter does not end."""
    if T.twin[h] < 0:
        return h // 3, _foot(T, h, dual)
    f = h // 3
    g, beta = trace(T, f, circumcenter(T, f, dual), dual)
    if g is None:                                       # the circumcenter is beyond a boundary side
        return None if beta < 0 else (beta // 3, _on_side(beta, 0.5))
    return g, beta


def _placed(face, at, beta, F, twin):
    """Where a point of the input face ``face`` (vertices ``at`` (3,), coordinates ``beta`` (3,)) goes in
    the mesh (``F`` (m, 3), ``twin`` (3m,)): (the mesh's faces it splits, halfedge it lies on or -1, face
    it lies inside or -1, corners (3,), coordinates (3,)), or None within SNAP of a vertex."""
    low = int(np.argmin([value(b) for b in beta]))
    if value(beta[low]) >= SNAP:
        return (face,), -1, face, at, beta
    p, q = at[(low + 1) % 3], at[(low + 2) % 3]
    bp, bq = beta[(low + 1) % 3], beta[(low + 2) % 3]
    if min(value(bp), value(bq)) < SNAP * (value(bp) + value(bq)):
        return None
    c = int(np.flatnonzero(F[face] == p)[0])
    if F[face, (c + 1) % 3] != q:                       # the face runs q -> p on that side
        c, p, q, bp, bq = (c + 2) % 3, q, p, bq, bp
    he = 3 * face + c
    faces = (face,) if twin[he] < 0 else (face, int(twin[he] // 3))
    rest = bp + bq
    return faces, he, -1, np.array([p, q, q]), [bp / rest, bq / rest, 0.0]


def _rounds(mesh, interior_angle, dual=False):
    """Rounds of insertions into ``mesh``: (vertices (n', 3), faces (m', 3), weights (k, n), parent faces
    (m',), the refined mesh's intrinsic Delaunay triangulation (None on a tufted cover), rounds,
    remaining), each round (T, vertices before it, corners (s, 3), coordinates (s, 3),
    d(coordinates) / d(T's length ids) (3 s, ids) sparse (with ``dual``, else None))."""
    V = mesh.vertices.copy()
    F = mesh.elements.copy()
    n = V.shape[0]
    weights = sp.csr_matrix((0, n))
    parent = np.arange(F.shape[0])
    rounds = []
    remaining = 0
    for _ in range(MAX_ROUNDS):
        T, sides, _ = _candidates(V, F, interior_angle)
        remaining = sides.size
        if remaining == 0:
            break
        edge_id = _edges(F)[0]
        twin = np.full(edge_id.size, -1, dtype=np.int64)
        h0, h1 = _pairs(edge_id)
        twin[h0], twin[h1] = h1, h0
        locate = locator(T, dual)
        # one insertion per face of the mesh and of the triangulation a round; none in a face so thin that
        # its parts could fall below the mesh's degenerate-element tolerance
        E = V[F[:, 1:]] - V[F[:, :1]]
        area = 0.5 * np.linalg.norm(np.cross(E[:, 0], E[:, 1]), axis=1)
        used = area <= tolerances.degenerate_element / SNAP * np.einsum("mij,mij->mi", E, E).max(axis=1)
        used_T = np.zeros(T.faces.shape[0], dtype=bool)
        taken = []
        for h in sides.tolist():
            if used_T[h // 3]:
                continue
            point = _point(T, h, dual)
            if point is None or used_T[point[0]]:
                continue
            g, beta = point
            placed = _placed(*locate(g, beta), F, twin)
            if placed is None or used[list(placed[0])].any():
                continue
            used[list(placed[0])] = used_T[[h // 3, g]] = True
            taken.append(placed)
        if not taken:
            break
        s = len(taken)
        corners = np.array([p[3] for p in taken], dtype=np.int64)
        beta = np.array([[value(b) for b in p[4]] for p in taken])
        dbeta = None
        if dual:
            rows, cols, vals = [], [], []
            for r, p in enumerate(taken):
                for c, b in enumerate(p[4]):
                    if isinstance(b, Dual):
                        rows += [3 * r + c] * len(b.d)
                        cols += list(b.d)
                        vals += list(b.d.values())
            dbeta = sp.csr_matrix((vals, (rows, cols)), shape=(3 * s, T.id_lengths.size))
        rounds.append((T, V.shape[0], corners, beta, dbeta))
        k = V.shape[0] + np.arange(s)
        V = np.concatenate([V, np.einsum("sc,scj->sj", beta, V[corners])])
        P = sp.vstack([sp.identity(n, format="csr"), weights], format="csr")
        weights = sp.vstack([weights, sum(sp.diags(beta[:, c]) @ P[corners[:, c]] for c in range(3))], format="csr")
        # a face (p, q, r) with k on its side p q: (p, k, r) and (k, q, r); with k inside: three around k
        he = np.array([p[1] for p in taken])
        on = he >= 0
        sides_of = np.concatenate([he[on], twin[he[on]]])
        k_of = np.concatenate([k[on], k[on]])
        sides_of, k_of = sides_of[sides_of >= 0], k_of[sides_of >= 0]
        fs, cs = sides_of // 3, sides_of % 3
        p_, q_, r_ = F[fs, cs], F[fs, (cs + 1) % 3], F[fs, (cs + 2) % 3]
        inside = np.array([p[2] for p in taken])[~on]
        ki = k[~on]
        a_, b_, c_ = F[inside, 0], F[inside, 1], F[inside, 2]
        F[fs] = np.stack([p_, k_of, r_], axis=1)
        F[inside] = np.stack([a_, b_, ki], axis=1)
        F = np.concatenate([F, np.stack([k_of, q_, r_], axis=1), np.stack([b_, c_, ki], axis=1),
                            np.stack([c_, a_, ki], axis=1)])
        parent = np.concatenate([parent, parent[fs], parent[inside], parent[inside]])
    else:
        T, sides, _ = _candidates(V, F, interior_angle)
        remaining = sides.size
    return V, F, weights, parent, T, rounds, remaining


def refine_obtuse_angles(mesh: Mesh, interior_angle: float = INTERIOR_ANGLE) -> ObtuseRefinement:
    """``mesh`` (triangles) with vertices inserted until its intrinsic Delaunay triangulation has no
    boundary side opposite an obtuse angle and no angle above ``interior_angle`` degrees opposite an
    interior side (:mod:`module docs <warp_regdist.geometry.obtuse_refinement>`; 180: the boundary only);
    distances on ``result.mesh``, restricted to its first ``mesh.n_vertices`` rows, are per input vertex.
    A mesh without such angles comes back as it is."""
    if not isinstance(mesh, Mesh):
        raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
    if mesh.element_dim != 2:
        raise ValueError("expected a triangle mesh for refine_obtuse_angles, got a tetrahedral mesh")
    if mesh.element_weights is not None:
        raise ValueError("expected a triangle mesh for refine_obtuse_angles, got a PointCloud (its triangles are "
                         "local covers of the points, not a surface)")
    if not (isinstance(interior_angle, (int, float, np.floating, np.integer)) and 90.0 < interior_angle <= 180.0):
        raise ValueError(f"expected interior_angle in (90, 180] degrees, got {interior_angle!r}")
    V, F, weights, parent, T, _, remaining = _rounds(mesh, float(interior_angle))
    if remaining:
        warnings.warn(f"expected the refinement to remove every obtuse angle it looks for, got {remaining} left "
                      f"(a circumcenter beside a vertex or in a needle-thin face, or {MAX_ROUNDS} rounds); the "
                      "distance may fall below 0 beside them", MeshWarning, stacklevel=2)
    with warnings.catch_warnings():      # the input's duplicate or cracked vertices warned when it was built
        warnings.simplefilter("ignore", MeshWarning)
        refined = mesh if weights.shape[0] == 0 else Mesh(V, F)
    return ObtuseRefinement(refined, weights, parent, remaining, mesh, float(interior_angle), T)


def obtuse_refinement(mesh, triangulation, regularizer, refine_obtuse):
    """The :class:`ObtuseRefinement` a solver computes on (None: the mesh as it is, not refined) for
    ``refine_obtuse`` (True, False or None: True with the intrinsic triangulation and the Dirichlet
    regularizer, whose maximum principle the refinement restores; the Hessian's minimizer dips below 0 on
    a boundary either way). It has n_inserted 0 where nothing was to be removed."""
    if refine_obtuse is None:
        refine_obtuse = triangulation == "intrinsic" and regularizer == "dirichlet"
    elif not isinstance(refine_obtuse, (bool, np.bool_)):
        raise ValueError(f"expected refine_obtuse as True, False or None, got {refine_obtuse!r}")
    elif refine_obtuse and triangulation != "intrinsic":
        raise ValueError(f"expected triangulation 'intrinsic' with refine_obtuse=True (the refinement removes the "
                         f"obtuse angles of the intrinsic Delaunay triangulation), got {triangulation!r}")
    if not refine_obtuse:
        return None
    return refine_obtuse_angles(mesh)
