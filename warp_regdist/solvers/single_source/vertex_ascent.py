"""The last step of a single-source solve: each vertex moved alone to its best value (docs/method.md section 8).

With the other values of column j held, vertex i can move by t along its hat function; each element e
around it keeps its constraint (|g + t b| <= 1, g = (G u_j)_e, b the gradient of i's hat function on e; on a source's triangle
the wedge n . (g + t b) <= 1) on an interval [t1_e, t2_e], and the objective
A_V^T u - (alpha / 2) u^T W u changes by t (A_i - alpha (W u)_i) - (alpha / 2) W_ii t^2. Its best move is

    t_ij = clip((A_i - alpha (W u)_i) / (alpha W_ii), min(lo, 0), max(hi, 0)),   (+inf before the clip at alpha = 0)
    lo = max_e t1_e,  hi = min_e t2_e,

which moves no element's gauge above max(1, its gauge now) and never lowers the objective. At the
minimizer every t_ij is 0 (else moving i alone would improve it). An ADMM stop can leave a few
vertices far from it where the elements are small: a vertex's pull is its area, its change per
iteration that small, and the change tests see nothing moving (on a split scan of 1,587 vertices at
alpha_hat 0, 5.9% of the max below the minimizer at one vertex after 640 iterations, 30,000 to
settle). :func:`ascend` moves such vertices, on sets of vertices with no element or W entry in common
(whose moves do not interact: a vertex moves when its move is the largest among its neighbours', ties
broken by a fixed order), until no move exceeds its threshold.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["VertexAscent", "MAX_ROUNDS", "BLOCK_ENTRIES"]

MAX_ROUNDS = 100
"""Rounds of :meth:`VertexAscent.ascend` at most (each moves an independent set of vertices per column)."""

BLOCK_ENTRIES = 1 << 20
"""Elements x columns that one block of :meth:`VertexAscent.ascend` holds (its arrays are (m, 3, columns))."""


class VertexAscent:
    """The best single-vertex moves t (n, k) of one problem: ``ops`` (Operators), the regularizer's
    ``weights`` W (n, n; None: the stiffness) and ``alpha``, ``source_triangles`` (SourceTriangles)."""

    def __init__(self, ops, weights, alpha, source_triangles):
        self.ops, self.alpha, self.source_triangles = ops, float(alpha), source_triangles
        self.W = (ops.stiffness if weights is None else weights).tocsr()
        E = ops.elements
        m, c = E.shape
        n = ops.vertex_volumes.size
        # the hat function's gradient at each corner: a vertex at two corners of a triangle (intrinsic
        # triangulations have them) moves both
        self.hat = ops.basis                                                       # (m, c, d), read only
        twice = np.flatnonzero((E[:, :, None] == E[:, None, :]).sum(axis=(1, 2)) > c)   # elements with such a vertex
        if twice.size:
            same = (E[twice, :, None] == E[twice, None, :]).astype(np.float64)       # (r, c, c)
            self.hat = ops.basis.copy()
            self.hat[twice] = np.einsum("mcl,mld->mcd", same, ops.basis[twice])
        self.corner_norms = np.square(self.hat).sum(axis=2)                        # (m, c) |b|^2
        flat = E.ravel()
        self.order = np.argsort(flat, kind="stable")                               # (element, corner) by vertex
        counts = np.bincount(flat, minlength=n)
        self.has_elements = counts > 0
        self.starts = np.concatenate([[0], np.cumsum(counts)[:-1]])[self.has_elements]
        # vertices that share an element or a W entry: the pattern of B B^T + |W|, B the (n, m) incidence
        incidence = sp.csr_matrix((np.ones(flat.size), (flat, np.repeat(np.arange(m), c))), shape=(n, m))
        touch = (incidence @ incidence.T + abs(self.W)).tocsr()
        touch.setdiag(0)
        touch.eliminate_zeros()
        touch.sort_indices()
        self.neighbours = touch
        self.has_neighbours = np.diff(touch.indptr) > 0
        # a fixed order of the vertices that breaks ties between neighbours' equal moves (a symmetric mesh has them)
        self.tie_break = 1.0 + 1e-12 * ((np.arange(n) * 0.6180339887498949) % 1.0)[:, None]

    def moves(self, u, free, sources):
        """t (n, k) of u (n, k) finite: 0 where ``free`` (n, k) is False; column j's sources ``sources[j]``
        (vertex indices: the wedges of :class:`SourceTriangles`)."""
        ops = self.ops
        E = ops.elements
        m, c = E.shape
        k = u.shape[1]
        g = (ops.grad @ u).reshape(m, 3, k)
        b = np.einsum("mcd,mdk->mck", self.hat, g)                               # (m, c, k) b . g
        a = self.corner_norms[:, :, None]
        with np.errstate(over="ignore", invalid="ignore"):     # a blown-up iterate (the steepness test refuses it)
            disc = np.square(b) - a * (np.square(g).sum(axis=1) - 1.0)[:, None, :]
            root = np.sqrt(np.maximum(disc, 0.0))
        real = disc >= 0.0
        t1 = np.where(real, (-b - root) / a, 0.0)
        t2 = np.where(real, (-b + root) / a, 0.0)
        faces, corners, cols = self.source_triangles.wedges(list(enumerate(sources)), k)
        if faces.size:
            directions = self.source_triangles.directions[faces, corners]        # (r, 2, 3)
            nd = np.einsum("rkd,rd->rk", directions, g[faces, :, cols])           # n . g on both sides
            for side, offset in ((0, 1), (1, 2)):
                corner = (corners + offset) % 3                                    # the corner that side leads to
                nb = np.einsum("rd,rd->r", directions[:, side], self.hat[faces, corner])
                t1[faces, corner, cols] = -np.inf
                t2[faces, corner, cols] = (1.0 - nd[:, side]) / nb
            t1[faces, corners, cols] = t2[faces, corners, cols] = 0.0
        n = u.shape[0]
        lo = np.full((n, k), -np.inf)
        hi = np.full((n, k), np.inf)
        lo[self.has_elements] = np.maximum.reduceat(t1.reshape(m * c, k)[self.order], self.starts, axis=0)
        hi[self.has_elements] = np.minimum.reduceat(t2.reshape(m * c, k)[self.order], self.starts, axis=0)
        pull = ops.vertex_volumes[:, None] - self.alpha * (self.W @ u)
        with np.errstate(divide="ignore", invalid="ignore"):
            best = pull / (self.alpha * self.W.diagonal())[:, None] if self.alpha > 0 else np.where(
                pull > 0, np.inf, -np.inf)
        t = np.clip(best, np.minimum(lo, 0.0), np.maximum(hi, 0.0))
        return np.where(free & self.has_elements[:, None] & np.isfinite(t), t, 0.0)

    def ascend(self, u, free, sources, threshold):
        """u (n, k) after rounds of moves: in each column, every vertex whose |t| exceeds ``threshold``
        (k,) and those of its neighbours moves by t, until none exceeds it or after MAX_ROUNDS. Returns
        (u, the largest |t| left per column (k,)); a few columns at a time (the moves hold (m, 3, k))."""
        u = np.array(u, dtype=np.float64)
        left = np.zeros(u.shape[1])
        block = max(1, min(64, BLOCK_ENTRIES // self.ops.elements.shape[0]))
        for j0 in range(0, u.shape[1], block):
            cols = slice(j0, j0 + block)
            u[:, cols], left[cols] = self._ascend(u[:, cols], free[:, cols], sources[cols], threshold[cols])
        return u, left

    def _ascend(self, u, free, sources, threshold):
        left = np.zeros(u.shape[1])
        active = np.arange(u.shape[1])
        T = self.neighbours
        for _ in range(MAX_ROUNDS + 1):
            t = self.moves(u[:, active], free[:, active], [sources[j] for j in active])
            size = np.abs(t)
            left[active] = size.max(axis=0, initial=0.0)
            over = size > threshold[active]
            keep = over.any(axis=0)
            if not keep.any() or _ == MAX_ROUNDS:
                break
            active, t, over = active[keep], t[:, keep], over[:, keep]
            size = size[:, keep] * self.tie_break
            nearby = np.zeros_like(size)
            nearby[self.has_neighbours] = np.maximum.reduceat(size[T.indices], T.indptr[:-1][self.has_neighbours],
                                                              axis=0)
            move = over & (size > nearby)
            u[:, active] += np.where(move, t, 0.0)
        return u, left
