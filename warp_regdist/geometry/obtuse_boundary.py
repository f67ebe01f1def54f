"""Boundary sides opposite obtuse angles, split until the intrinsic Delaunay triangulation has none.

The intrinsic flips (:mod:`warp_regdist.geometry.intrinsic`) make every interior cotangent weight
>= 0, but they never flip a boundary side: where the angle opposite one is above 90 degrees, its
weight cot(theta) / 2 stays negative, and the distance at the vertices of such a triangle can fall
below 0 (docs/real-meshes.md). Splitting that side at the foot of the altitude from the obtuse
corner gives two right triangles, whose sides opposite the corner's two parts have acute angles
there. Boundary sides of an intrinsic triangulation are the input's own edges, so the new vertex
is a point of that edge in space: the refined mesh is an ordinary :class:`Mesh`, on the same
surface, whose first n vertices and their numbers are the input's. Rounds of splits (one side per
input face each round) and flips repeat until no boundary angle is obtuse.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from ..errors import MeshWarning
from .intrinsic import _edges, intrinsic_delaunay, length_gradient
from .mesh import Mesh

__all__ = ["BoundarySplit", "split_obtuse_boundary", "obtuse_boundary_sides", "boundary_split"]

OBTUSE = 1e-9
"""A boundary angle is obtuse where its cosine is below -OBTUSE."""
FOOT_RANGE = (0.01, 0.99)
"""The foot's parameter along its side is clamped to this range (within 1% of a corner the angle is all but right)."""
MAX_ROUNDS = 32


@dataclasses.dataclass
class BoundarySplit:
    """A triangle mesh with its boundary sides opposite obtuse angles split.

    Attributes
    ----------
    mesh : Mesh
        The refined mesh: vertices 0..n-1 are the input's, n..n+k-1 the inserted ones.
    ends : (k, 2) int64
        The input edge each inserted vertex lies on (two input vertices).
    t : (k,) float64
        Where on it: vertex n + i is ``(1 - t[i]) * x[ends[i, 0]] + t[i] * x[ends[i, 1]]``.
    parent : (m',) int64
        The input face each face of ``mesh`` lies in.
    remaining : int
        Boundary sides still opposite an obtuse angle after MAX_ROUNDS rounds (0 when it converged).
    original : Mesh
        The input mesh.
    """

    mesh: Mesh
    ends: np.ndarray
    t: np.ndarray
    parent: np.ndarray
    remaining: int
    original: Mesh

    @property
    def n_inserted(self):
        return int(self.t.size)

    def interpolation(self):
        """The (n + k, n) sparse matrix P of the inserted vertices' linear interpolation, P @ x = refined x."""
        import scipy.sparse as sp

        n, k = self.mesh.n_vertices - self.t.size, self.t.size
        rows = np.concatenate([np.arange(n), n + np.arange(k), n + np.arange(k)])
        cols = np.concatenate([np.arange(n), self.ends[:, 0], self.ends[:, 1]])
        vals = np.concatenate([np.ones(n), 1.0 - self.t, self.t])
        return sp.csr_matrix((vals, (rows, cols)), shape=(n + k, n))

    def vjp(self, grad_positions):
        """dL/dx (n, 3) of the input's positions from dL/dx' (n + k, 3) of the refined mesh's: each
        inserted vertex x' = (1 - s) x_a + s x_b moves with its ends and with its foot s, a function of
        the lengths of the intrinsic triangulation it was split in (the splits are replayed)."""
        g = np.array(grad_positions, dtype=np.float64)
        X = self.mesh.vertices
        if g.shape != X.shape:
            raise ValueError(f"expected a gradient of shape {X.shape} (the refined mesh's vertices), got {g.shape}")
        if self.n_inserted == 0:
            return g
        for T, n_r, a, b, foot, idx, partial in reversed(_split_rounds(self.original)[5]):
            gk = g[n_r:n_r + a.size]
            dfoot = np.einsum("ij,ij->i", gk, X[b] - X[a])
            g = g[:n_r]
            np.add.at(g, a, (1.0 - foot)[:, None] * gk)
            np.add.at(g, b, foot[:, None] * gk)
            dl = np.zeros(T.lengths.size)
            np.add.at(dl, idx.ravel(), (dfoot[:, None] * partial).ravel())
            g += length_gradient(T, X[:n_r], dl.reshape(T.lengths.shape))
        return g


def _sides(vertices, faces):
    """The boundary sides of the intrinsic Delaunay triangulation T of (``vertices`` (n, 3), ``faces``
    (m, 3)) opposite an obtuse angle, and how their feet depend on T's lengths: (T, input face (s,),
    corner i of that face where the side starts (s,), foot parameter (s,) from corner i to corner i + 1,
    the three lengths' indices into ``T.lengths.ravel()`` (s, 3) (the side l_ab, then l_bc and l_ca),
    d(foot) / d(those lengths) (s, 3), 0 where the foot is clamped). T is None without boundary and on a
    tufted cover."""
    F = np.asarray(faces, dtype=np.int64)
    edge_id, _, _ = _edges(F)
    count = np.bincount(edge_id)
    empty = np.zeros(0, dtype=np.int64)
    T = intrinsic_delaunay(vertices, F) if (count == 1).any() else None      # a closed mesh has no such sides
    if T is None or T.tufted:
        return None, empty, empty, np.zeros(0), np.zeros((0, 3), np.int64), np.zeros((0, 3))
    E = T.edges.shape[0]
    ids = T.length_ids.ravel()
    h = np.flatnonzero(ids < E)
    h = h[count[ids[h]] == 1]                           # boundary sides: never flipped, one halfedge each
    L = T.lengths.ravel()
    f, i = h // 3, h % 3
    idx = np.stack([h, 3 * f + (i + 1) % 3, 3 * f + (i + 2) % 3], axis=1)
    l_ab, l_bc, l_ca = L[idx[:, 0]], L[idx[:, 1]], L[idx[:, 2]]
    cos_c = (l_bc * l_bc + l_ca * l_ca - l_ab * l_ab) / (2.0 * l_bc * l_ca)
    bad = cos_c < -OBTUSE
    h, f, i, idx, l_ab, l_bc, l_ca = h[bad], f[bad], i[bad], idx[bad], l_ab[bad], l_bc[bad], l_ca[bad]
    raw = 0.5 + (l_ca * l_ca - l_bc * l_bc) / (2.0 * l_ab * l_ab)
    foot = np.clip(raw, *FOOT_RANGE)
    partial = np.stack([-(l_ca * l_ca - l_bc * l_bc) / l_ab ** 3, -l_bc / l_ab ** 2, l_ca / l_ab ** 2], axis=1)
    partial[foot != raw] = 0.0
    # the same side in the input: its one input halfedge, run the same way or (an oriented face) reversed
    start = T.faces[f, i]
    hin = np.full(E, -1, dtype=np.int64)
    hin[edge_id] = np.arange(edge_id.size)
    g = hin[ids[h]]
    face, corner = g // 3, g % 3
    same = F[face, corner] == start
    return T, face, corner, np.where(same, foot, 1.0 - foot), idx, np.where(same[:, None], partial, -partial)


def obtuse_boundary_sides(vertices, faces):
    """The boundary sides of the intrinsic Delaunay triangulation of (``vertices`` (n, 3), ``faces``
    (m, 3)) opposite an obtuse angle: (input face (s,), corner i of that face where the side starts
    (s,), foot parameter (s,) from corner i to corner i + 1). Empty on a tufted cover (no boundary)."""
    return _sides(vertices, faces)[1:4]


def _split_rounds(mesh):
    """Rounds of splits of ``mesh``: (vertices (n', 3), faces (m', 3), per inserted vertex its input edge
    (k, 2) and parameter (k,), parent faces (m',), rounds, remaining), each round (T, vertices before it,
    the sides' ends a and b (s,), feet (s,), length indices (s, 3), d(foot) / d(lengths) (s, 3))."""
    V = mesh.vertices.copy()
    F = mesh.elements.copy()
    n = V.shape[0]
    on_edge = np.zeros((0, 2), dtype=np.int64)          # per inserted vertex: its input edge (a, b) ...
    param = np.zeros(0)                                 # ... and its parameter from a to b
    parent = np.arange(F.shape[0])
    rounds = []
    remaining = 0
    for _ in range(MAX_ROUNDS):
        T, face, corner, foot, idx, partial = _sides(V, F)
        _, first = np.unique(face, return_index=True)   # one side per face a round
        face, corner, foot, idx, partial = face[first], corner[first], foot[first], idx[first], partial[first]
        if face.size == 0:
            break
        a, b, c = F[face, corner], F[face, (corner + 1) % 3], F[face, (corner + 2) % 3]
        rounds.append((T, V.shape[0], a, b, foot, idx, partial))
        k = np.arange(face.size) + V.shape[0]
        V = np.concatenate([V, (1.0 - foot)[:, None] * V[a] + foot[:, None] * V[b]])
        # on the input edge of the side: an inserted end carries its own, an input end is 0 or 1 along it
        pad_edge, pad_param = np.concatenate([on_edge, [[-1, -1]]]), np.concatenate([param, [0.0]])
        ia, ib = np.where(a >= n, a - n, param.size), np.where(b >= n, b - n, param.size)
        edge = np.where((a >= n)[:, None], pad_edge[ia],
                        np.where((b >= n)[:, None], pad_edge[ib], np.stack([a, b], axis=1)))
        pa = np.where(a >= n, pad_param[ia], (a == edge[:, 1]).astype(np.float64))
        pb = np.where(b >= n, pad_param[ib], (b == edge[:, 1]).astype(np.float64))
        on_edge = np.concatenate([on_edge, edge])
        param = np.concatenate([param, (1.0 - foot) * pa + foot * pb])
        F[face] = np.stack([a, k, c], axis=1)
        F = np.concatenate([F, np.stack([k, b, c], axis=1)])
        parent = np.concatenate([parent, parent[face]])
    else:
        remaining = obtuse_boundary_sides(V, F)[0].size
    return V, F, on_edge, param, parent, rounds, remaining


def split_obtuse_boundary(mesh: Mesh) -> BoundarySplit:
    """``mesh`` (triangles) with every boundary side opposite an obtuse angle of its intrinsic Delaunay
    triangulation split at the altitude's foot (:mod:`module docs <warp_regdist.geometry.obtuse_boundary>`);
    distances on ``result.mesh``, restricted to its first ``mesh.n_vertices`` rows, are per input vertex.
    A closed mesh, or one without such sides, comes back as it is (k = 0)."""
    if not isinstance(mesh, Mesh):
        raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
    if mesh.element_dim != 2:
        raise ValueError("expected a triangle mesh for split_obtuse_boundary, got a tetrahedral mesh")
    if mesh.element_weights is not None:
        raise ValueError("expected a triangle mesh for split_obtuse_boundary, got a PointCloud (its triangles are "
                         "local covers of the points, not a surface with a boundary)")
    V, F, on_edge, param, parent, _, remaining = _split_rounds(mesh)
    if remaining:
        warnings.warn(f"expected the boundary splits to end, got {remaining} boundary sides still opposite an "
                      f"obtuse angle after {MAX_ROUNDS} rounds; the distance may fall below 0 beside them",
                      MeshWarning, stacklevel=2)
    with warnings.catch_warnings():      # the input's duplicate or cracked vertices warned when it was built
        warnings.simplefilter("ignore", MeshWarning)
        refined = mesh if param.size == 0 else Mesh(V, F)
    return BoundarySplit(refined, on_edge, param, parent, remaining, mesh)


def boundary_split(mesh, triangulation, regularizer, split_boundary):
    """The :class:`BoundarySplit` a solver computes on (None: the mesh as it is) for ``split_boundary``
    (True, False or None: True with the intrinsic triangulation and the Dirichlet regularizer, whose
    maximum principle the splits restore; the Hessian's minimizer dips below 0 on a boundary either way)."""
    if split_boundary is None:
        split_boundary = triangulation == "intrinsic" and regularizer == "dirichlet"
    elif not isinstance(split_boundary, (bool, np.bool_)):
        raise ValueError(f"expected split_boundary as True, False or None, got {split_boundary!r}")
    elif split_boundary and triangulation != "intrinsic":
        raise ValueError(f"expected triangulation 'intrinsic' with split_boundary=True (the splits make the intrinsic "
                         f"Delaunay triangulation's boundary weights >= 0), got {triangulation!r}")
    if not split_boundary:
        return None
    split = split_obtuse_boundary(mesh)
    return split if split.n_inserted else None
