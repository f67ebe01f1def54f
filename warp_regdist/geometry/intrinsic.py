"""Intrinsic Delaunay triangulations by edge flips, and the operators on them (docs/method.md section 2).

A triangle of a surface mesh is known to the operators by its three edge lengths only. Flipping an
edge *intrinsically* replaces it by the other diagonal of the two triangles beside it, laid out flat
in the plane: the surface, its area and its vertices stay as they are, and only the triangulation
changes. Flipping every edge whose two opposite angles sum to more than pi (Lawson's algorithm,
Fisher et al. 2007) ends at the intrinsic Delaunay triangulation, whose cotangent weights are all
>= 0 (the discrete maximum principle), where obtuse triangles of the input made them negative.

The triangulation is a halfedge structure: halfedge h = 3 f + i runs from corner i of face f to
corner i + 1 and has a length, a twin (-1 on the boundary) and a variable id that names its length
for :func:`length_gradient`. The flips are made in rounds of non-adjacent edges, each round one
vectorized step; every flip records the five lengths its new diagonal came from, so that the
derivative of the final lengths with respect to the input's edge lengths (and positions) follows by
the chain rule in reverse.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["IntrinsicTriangulation", "intrinsic_delaunay", "flat_layout", "flat_layout_gradient", "length_gradient"]

_MAX_ROUNDS = 100_000


@dataclasses.dataclass
class IntrinsicTriangulation:
    """An intrinsic triangulation of the vertices of a mesh.

    Attributes
    ----------
    faces : (m, 3) int64
        Corners of each triangle (a vertex may appear twice in a face, and two faces may share two
        edges: intrinsic triangulations allow it).
    lengths : (m, 3) float64
        lengths[f, i]: the length of the edge from corner i to corner (i + 1) % 3.
    length_ids : (m, 3) int64
        The variable id of each length: 0..E-1 the input's edges (``edges``), then one per flip.
    edges : (E, 2) int64
        The input's undirected edges, the first E variables.
    flips : list of (ids (k,), parents (k, 5), partials (k, 5))
        One entry per round: the new lengths' ids, the five ids each was computed from
        (l_ab, l_bc, l_ca, l_ad, l_db of its quad) and d(new length) / d(each of them).
    """

    faces: np.ndarray
    lengths: np.ndarray
    length_ids: np.ndarray
    edges: np.ndarray
    flips: list

    @property
    def flip_count(self):
        return int(sum(ids.size for ids, _, _ in self.flips))


def _halfedges(faces):
    """(twin (3m,), edge id (3m,), edges (E, 2)) of a triangle list: halfedge 3 f + i runs from
    faces[f, i] to faces[f, (i + 1) % 3]; the twin is the opposite halfedge of the same edge in another
    face (-1 on the boundary, and where two faces run along their shared edge the same way)."""
    m = faces.shape[0]
    a, b = faces.ravel(), np.roll(faces, -1, axis=1).ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    edges, edge_id = np.unique(np.stack([lo, hi], axis=1), axis=0, return_inverse=True)
    edge_id = edge_id.ravel()
    order = np.argsort(edge_id, kind="stable")
    twin = np.full(3 * m, -1, dtype=np.int64)
    same = edge_id[order[1:]] == edge_id[order[:-1]]
    h0, h1 = order[:-1][same], order[1:][same]
    opposite = a[h0] == b[h1]
    twin[h0[opposite]], twin[h1[opposite]] = h1[opposite], h0[opposite]
    return twin, edge_id, edges


def _area(l0, l1, l2):
    """Triangle areas from the side lengths (Kahan's stable Heron formula; 0 for violated inequalities)."""
    s = np.sort(np.stack([l0, l1, l2]), axis=0)[::-1]       # a >= b >= c
    a, b, c = s
    q = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c))
    return 0.25 * np.sqrt(np.maximum(q, 0.0))


def _opposite_cot(L, h):
    """cot of the angle opposite halfedge h in its face, from the face's three lengths."""
    f, i = h // 3, h % 3
    lh, ln, lp = L[3 * f + i], L[3 * f + (i + 1) % 3], L[3 * f + (i + 2) % 3]
    return (ln * ln + lp * lp - lh * lh) / (4.0 * np.maximum(_area(lh, ln, lp), 1e-300))


def _diagonal(l_ab, l_bc, l_ca, l_ad, l_db):
    """The length of the other diagonal cd of the quad a c b d (triangles a b c and b a d laid out on
    both sides of ab) and its partial derivatives with respect to the five lengths, (k,), (k, 5)."""
    s = l_ab
    xc = (s * s + l_ca * l_ca - l_bc * l_bc) / (2.0 * s)
    yc = np.sqrt(np.maximum(l_ca * l_ca - xc * xc, 1e-300))
    xd = (s * s + l_ad * l_ad - l_db * l_db) / (2.0 * s)
    yd = -np.sqrt(np.maximum(l_ad * l_ad - xd * xd, 1e-300))
    dx, dy = xc - xd, yc - yd
    length = np.sqrt(dx * dx + dy * dy)
    # d(xc, yc, xd, yd) / d(s, l_bc, l_ca, l_ad, l_db)
    dxc = np.stack([1.0 - xc / s, -l_bc / s, l_ca / s, 0 * s, 0 * s], axis=1)
    dyc = (np.stack([0 * s, 0 * s, l_ca, 0 * s, 0 * s], axis=1) - xc[:, None] * dxc) / yc[:, None]
    dxd = np.stack([1.0 - xd / s, 0 * s, 0 * s, l_ad / s, -l_db / s], axis=1)
    dyd = -(np.stack([0 * s, 0 * s, 0 * s, l_ad, 0 * s], axis=1) - xd[:, None] * dxd) / (-yd)[:, None]
    partials = (dx[:, None] * (dxc - dxd) + dy[:, None] * (dyc - dyd)) / length[:, None]
    return length, partials


def intrinsic_delaunay(vertices, faces, tolerance=1e-10):
    """The intrinsic Delaunay triangulation of a triangle mesh (``vertices`` (n, 3), ``faces`` (m, 3)):
    an :class:`IntrinsicTriangulation` whose every interior edge has opposite angles summing to at most
    pi (up to ``tolerance`` in the cotangents' sum), reached by flips of the input's edges.

    Edges on the boundary, and edges whose two faces run along them the same way (inconsistent
    orientation), are never flipped."""
    V, F = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    m = F.shape[0]
    twin, edge_id, edges = _halfedges(F)
    origin = F.ravel().copy()
    L = np.linalg.norm(V[np.roll(F, -1, axis=1)] - V[F], axis=2).ravel()
    ids = edge_id.copy()
    next_id = edges.shape[0]
    flips = []
    for _ in range(_MAX_ROUNDS):
        h = np.flatnonzero(twin > np.arange(3 * m))                  # every interior edge once
        t = twin[h]
        cot = _opposite_cot(L, h) + _opposite_cot(L, t)
        bad = cot < -tolerance * np.maximum(1.0, np.abs(cot))
        h, t, cot = h[bad], t[bad], cot[bad]
        f, g = h // 3, t // 3
        i, j = h % 3, t % 3
        # two faces that share a second edge, or one face on both sides: not flipped
        ok = (f != g) & (twin[3 * f + (i + 1) % 3] // 3 != g) & (twin[3 * f + (i + 2) % 3] // 3 != g)
        h, t, f, g, i, j, cot = h[ok], t[ok], f[ok], g[ok], i[ok], j[ok], cot[ok]
        if h.size == 0:
            break
        # non-adjacent flips: an edge is taken when it is the most violated candidate of both its faces
        rank = np.empty(h.size, dtype=np.int64)
        rank[np.lexsort((h, cot))] = np.arange(h.size)                # most negative first, then by id
        best = np.full(m, h.size, dtype=np.int64)
        np.minimum.at(best, f, rank)
        np.minimum.at(best, g, rank)
        take = (best[f] == rank) & (best[g] == rank)
        h, t, f, g, i, j = h[take], t[take], f[take], g[take], i[take], j[take]
        hb, hc = 3 * f + (i + 1) % 3, 3 * f + (i + 2) % 3            # b -> c, c -> a in face f
        ha, hd = 3 * g + (j + 1) % 3, 3 * g + (j + 2) % 3            # a -> d, d -> b in face g
        c, d = origin[hc], origin[hd]
        new_length, partials = _diagonal(L[h], L[hb], L[hc], L[ha], L[hd])
        new_ids = next_id + np.arange(h.size)
        next_id += h.size
        flips.append((new_ids, np.stack([ids[h], ids[hb], ids[hc], ids[ha], ids[hd]], axis=1), partials))
        # new faces (a, d, c) in f and (b, c, d) in g: where each kept halfedge moves
        relocate = np.arange(3 * m)
        relocate[ha], relocate[hc], relocate[hb], relocate[hd] = 3 * f, 3 * f + 2, 3 * g, 3 * g + 2
        kept = np.ones(3 * m, dtype=bool)
        kept[h] = kept[t] = False
        src = np.flatnonzero(kept)
        dst = relocate[src]
        new_origin, new_L, new_ids_all, new_twin = (np.empty_like(x) for x in (origin, L, ids, twin))
        new_origin[dst], new_L[dst], new_ids_all[dst] = origin[src], L[src], ids[src]
        new_twin[dst] = np.where(twin[src] >= 0, relocate[np.maximum(twin[src], 0)], -1)
        new_origin[3 * f + 1], new_origin[3 * g + 1] = d, c
        new_L[3 * f + 1] = new_L[3 * g + 1] = new_length
        new_ids_all[3 * f + 1] = new_ids_all[3 * g + 1] = new_ids
        new_twin[3 * f + 1], new_twin[3 * g + 1] = 3 * g + 1, 3 * f + 1
        origin, L, ids, twin = new_origin, new_L, new_ids_all, new_twin
    else:
        raise RuntimeError(f"expected the intrinsic edge flips to end, got {_MAX_ROUNDS} rounds")
    return IntrinsicTriangulation(origin.reshape(m, 3), L.reshape(m, 3), ids.reshape(m, 3), edges, flips)


def flat_layout(lengths):
    """(m, 3, 3) corner positions of every face laid out in the plane z = 0 from its side lengths
    (m, 3) (lengths[f, i] from corner i to corner i + 1): corner 0 at the origin, corner 1 on the x
    axis, corner 2 above it (counter-clockwise)."""
    l01, l12, l20 = lengths[:, 0], lengths[:, 1], lengths[:, 2]
    x = (l01 * l01 + l20 * l20 - l12 * l12) / (2.0 * l01)
    y = np.sqrt(np.maximum(l20 * l20 - x * x, 0.0))
    P = np.zeros((lengths.shape[0], 3, 3))
    P[:, 1, 0] = l01
    P[:, 2, 0], P[:, 2, 1] = x, y
    return P


def flat_layout_gradient(lengths, grad_positions):
    """dL/d(lengths) (m, 3) from dL/d(corner positions) (m, 3, 3) of :func:`flat_layout`."""
    l01, l12, l20 = lengths[:, 0], lengths[:, 1], lengths[:, 2]
    x = (l01 * l01 + l20 * l20 - l12 * l12) / (2.0 * l01)
    y = np.sqrt(np.maximum(l20 * l20 - x * x, 1e-300))
    dx = np.stack([1.0 - x / l01, -l12 / l01, l20 / l01], axis=1)              # d x / d(l01, l12, l20)
    dy = (np.stack([0 * x, 0 * x, l20], axis=1) - x[:, None] * dx) / y[:, None]
    g = np.asarray(grad_positions)
    out = g[:, 2, 0, None] * dx + g[:, 2, 1, None] * dy
    out[:, 0] += g[:, 1, 0]
    return out


def length_gradient(triangulation, vertices, grad_lengths):
    """dL/dx (n, 3) from dL/d(lengths) (m, 3) of ``triangulation`` (built from ``vertices``): back
    through the flips, newest first, to the input's edge lengths, then to the positions."""
    T = triangulation
    size = T.edges.shape[0] + sum(ids.size for ids, _, _ in T.flips)
    g = np.zeros(size)
    np.add.at(g, T.length_ids.ravel(), np.asarray(grad_lengths, dtype=np.float64).ravel())
    for ids, parents, partials in reversed(T.flips):
        np.add.at(g, parents.ravel(), (g[ids][:, None] * partials).ravel())
    V = np.asarray(vertices, dtype=np.float64)
    a, b = T.edges[:, 0], T.edges[:, 1]
    e = V[a] - V[b]
    unit = e / np.linalg.norm(e, axis=1, keepdims=True)
    ge = g[:T.edges.shape[0], None] * unit
    out = np.zeros_like(V)
    np.add.at(out, a, ge)
    np.add.at(out, b, -ge)
    return out
