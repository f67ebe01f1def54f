"""The gradient constraint on a source's own triangles (docs/method.md section 2).

Every element e of column j has |(G u_j)_e| <= 1, except, with ``source_triangles="edges"`` (the
default on triangle meshes), a triangle with exactly one corner s among column j's sources: there
the constraint is the wedge

    u_a <= l_sa  for its other two corners a,   that is   n_a . g <= 1,  n_a = (x_a - x_s) / l_sa,

since u_s = 0 and u is linear on the triangle. It contains the unit ball and holds for the exact
distance (no point is farther from the source than along an edge). Where the angle at s is obtuse,
the ball forces u_a + u_b below what the exact distance has, down to u_a < 0 next to the source.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SOURCE_TRIANGLES", "check_source_triangles", "corner_sides", "corner_directions", "SourceTriangles"]

SOURCE_TRIANGLES = ("edges", "gradient")


def check_source_triangles(value, element_dim):
    """The rule for a mesh of ``element_dim`` (2 or 3): None -> "edges" on triangles, "gradient" on tetrahedra."""
    if value is None:
        return "edges" if element_dim == 2 else "gradient"
    if value not in SOURCE_TRIANGLES:
        raise ValueError(f"expected source_triangles 'edges' or 'gradient', got {value!r}")
    if value == "edges" and element_dim != 2:
        raise ValueError("expected source_triangles 'gradient' on a tetrahedral mesh, got 'edges' "
                         "(the edge bounds are defined on triangles)")
    return value


def corner_sides(basis):
    """(m, 3, 2, 3) the sides x_a - x_c from corner c of each triangle to its corners a = c + 1 and c + 2
    (mod 3), in the frame of the hat-function gradients ``basis`` (m, 3, 3): the vector of the
    triangle's plane with b_a . e = 1 and b_b . e = 0 (b_a, b_b the gradients of corner a and the third)."""
    out = np.empty((basis.shape[0], 3, 2, 3))
    for c in range(3):
        for k, (a, b) in enumerate((((c + 1) % 3, (c + 2) % 3), ((c + 2) % 3, (c + 1) % 3))):
            ba, bb = basis[:, a], basis[:, b]
            aa, ab, bb2 = (np.einsum("md,md->m", p, q) for p, q in ((ba, ba), (ba, bb), (bb, bb)))
            det = aa * bb2 - ab * ab
            out[:, c, k] = (bb2 / det)[:, None] * ba - (ab / det)[:, None] * bb
    return out


def corner_directions(basis):
    """(m, 3, 2, 3) the unit vectors along :func:`corner_sides`."""
    sides = corner_sides(basis)
    return sides / np.linalg.norm(sides, axis=-1, keepdims=True)


class SourceTriangles:
    """The constraint per element and column of one problem: ``rule`` "edges" or "gradient" on
    :class:`~warp_regdist.Operators` ``ops``.

    Attributes
    ----------
    active : bool
        Whether source triangles get the wedge (rule "edges" on triangles).
    directions : (m, 3, 2, 3) ndarray or None
        :func:`corner_directions` of the operators (None when not active).
    """

    def __init__(self, ops, rule):
        self.rule = rule
        self.elements, self.grad, self.n = ops.elements, ops.grad, ops.vertex_volumes.size
        self.active = rule == "edges" and ops.elements.shape[1] == 3
        self.directions = corner_directions(ops.basis) if self.active else None

    def corners(self, sources):
        """(faces (r,), corners (r,)) of the triangles with exactly one corner among ``sources`` (vertex
        indices): the triangles whose constraint is the wedge at that corner (none when not active)."""
        if not self.active:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        at = self._hit([sources])[self.elements]
        faces = np.flatnonzero(at.sum(axis=1) == 1)
        return faces, np.argmax(at[faces], axis=1)

    def touched(self, source_sets, m):
        """(m,) int32: 1 on the triangles with a corner in some set of ``source_sets`` (0 everywhere when
        not active): where an element step looks for wedges."""
        flag = np.zeros(m, dtype=np.int32)
        if self.active:
            flag[self._hit(source_sets)[self.elements].any(axis=1)] = 1
        return flag

    def _hit(self, source_sets):
        """(n,) bool: the vertices in some set of ``source_sets``."""
        hit = np.zeros(self.n, dtype=bool)
        for s in source_sets:
            hit[np.asarray(s, dtype=np.int64)] = True
        return hit

    def wedges(self, columns, k):
        """(faces, corners, column) of every wedge of the k columns of ``columns``: a list of (column,
        sources) items, or an int j0 for all-pairs columns (column j's source is vertex j0 + j)."""
        if not self.active:
            return (np.zeros(0, dtype=np.int64),) * 3
        if isinstance(columns, (int, np.integer)):
            faces, corners = np.nonzero((self.elements >= columns) & (self.elements < columns + k))
            return faces, corners, self.elements[faces, corners] - columns
        parts = [(f, c, np.full(f.size, j)) for j, s in columns for f, c in [self.corners(s)]]
        if not parts:
            return (np.zeros(0, dtype=np.int64),) * 3
        return tuple(np.concatenate(p) for p in zip(*parts))

    def gauge(self, g, columns):
        """(m, k) the gauge of every element's constraint set at g = G u (m, 3, k): |g|, or on the wedges of
        ``columns`` (as in :meth:`wedges`) max(n_1 . g, n_2 . g). A column is within its constraints where
        its gauge is <= 1."""
        out = np.sqrt(np.square(g).sum(axis=1))
        faces, corners, cols = self.wedges(columns, g.shape[2])
        if faces.size:
            n = self.directions[faces, corners]                           # (r, 2, 3)
            out[faces, cols] = np.einsum("rkd,rd->rk", n, g[faces, :, cols]).max(axis=1)
        return out

    def max_gauge(self, u, sources, block=256):
        """(k,) max over elements of the :meth:`gauge` of each column of ``u`` (n, k), column j from the
        vertices ``sources[j]`` (None: from vertex j, all pairs), ``block`` columns at a time; +inf entries
        (unreachable vertices) count as 0, NaN gives NaN."""
        u = np.where(np.isposinf(u), 0.0, u).reshape(u.shape[0], -1)
        m = self.elements.shape[0]
        out = []
        with np.errstate(over="ignore", invalid="ignore"):
            for j0 in range(0, u.shape[1], block):
                g = (self.grad @ u[:, j0:j0 + block]).reshape(m, 3, -1)
                cols = j0 if sources is None else [(j, sources[j0 + j]) for j in range(g.shape[2])]
                out.append(self.gauge(g, cols).max(axis=0, initial=0.0))
        return np.concatenate(out)

    def project(self, g, columns):
        """(m, 3, k): g = G u (m, 3, k) projected onto every element's constraint set (the unit ball, the
        wedges of ``columns`` as in :meth:`gauge`)."""
        z = g / np.maximum(1.0, np.sqrt(np.square(g).sum(axis=1, keepdims=True)))
        faces, corners, cols = self.wedges(columns, g.shape[2])
        if faces.size:
            z[faces, :, cols] = wedge_projection(g[faces, :, cols], self.directions[faces, corners])
        return z


def wedge_projection(v, n):
    """(r, 3): each v (r, 3) projected onto its wedge n_1 . g <= 1, n_2 . g <= 1 (n (r, 2, 3), unit vectors
    in v's plane): v inside, else its projection onto one side's line where that lies in the wedge, else
    the apex (n_1 + n_2) / (1 + n_1 . n_2)."""
    n1, n2 = n[:, 0], n[:, 1]
    t1, t2 = np.einsum("rd,rd->r", n1, v) - 1.0, np.einsum("rd,rd->r", n2, v) - 1.0
    p1, p2 = v - t1[:, None] * n1, v - t2[:, None] * n2
    apex = (n1 + n2) / (1.0 + np.einsum("rd,rd->r", n1, n2))[:, None]
    one = (t1 > 0) & (np.einsum("rd,rd->r", n2, p1) <= 1.0)
    two = ~one & (t2 > 0) & (np.einsum("rd,rd->r", n1, p2) <= 1.0)
    inside = (t1 <= 0) & (t2 <= 0)
    return np.where(inside[:, None], v, np.where(one[:, None], p1, np.where(two[:, None], p2, apex)))
