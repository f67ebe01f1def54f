"""Intrinsic Delaunay triangulations by edge flips, and the operators on them (docs/method.md section 2).

A triangle of a surface mesh is known to the operators by its three edge lengths only. Flipping an
edge *intrinsically* replaces it by the other diagonal of the two triangles beside it, laid out flat
in the plane: the surface, its area and its vertices stay as they are, and only the triangulation
changes. Flipping every edge whose two opposite angles sum to more than pi (Lawson's algorithm,
Fisher et al. 2007; it ends on any intrinsic triangulation, Indermitte et al. 2001) ends at the
intrinsic Delaunay triangulation, whose cotangent weights are all >= 0 (the discrete maximum
principle), where obtuse triangles of the input made them negative.

The triangulation is a halfedge structure: halfedge h = 3 f + i runs from corner i of face f to
corner i + 1 and has a length, a twin (-1 on the boundary) and a variable id that names its length
for :func:`length_gradient`. Any gluing is allowed: two faces may share two edges, a face may be
glued to itself, a vertex may have degree 1. How the input's faces are glued:

- an edge-manifold mesh that can be oriented is oriented consistently (face by face, for the
  flips only: the faces' orientation does not change the surface) and glued along its edges;
- any other (edges with three or more faces, or a Moebius-like component) is replaced by its
  *tufted cover* (Sharp and Crane 2020, "A Laplacian for Nonmanifold Triangle Meshes"): every
  face twice, once each way, and around each edge each face's side glued to the side of the next
  face round the edge that faces it. That cover is an oriented surface without boundary over the
  same vertices, so the flips and the cotangent weights are those of an ordinary surface; every
  cover face counts half its area (``area_weight``), so the operators are those of the mesh.

The flips are made in rounds of non-adjacent edges, each round one vectorized step; every flip
records the five lengths its new diagonal came from, so that the derivative of the final lengths
with respect to the input's edge lengths (and positions) follows by the chain rule in reverse.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from ..errors import MeshError

__all__ = ["IntrinsicTriangulation", "intrinsic_delaunay", "flat_layout", "flat_layout_gradient", "length_gradient",
           "id_gradient"]

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
    flipped_faces : list of (f (k,), i (k,), g (k,), j (k,), vertices (k, 4))
        Per round, the two faces of each flip, the corners where its old edge a b started in them
        (a b c at corners i, i + 1, i + 2 of f, b a d at j, j + 1, j + 2 of g; afterwards f is a d c and
        g is b c d) and the vertices a, b, c, d.
    id_lengths : (E + flips,) float64
        The length of every variable id.
    twin : (3 m,) int64
        The halfedge on the other side of each halfedge's edge (-1 on the boundary).
    area_weight : float
        What each face's area counts in the operators: 1, or 1/2 on a tufted cover (each input face
        is there twice).
    """

    faces: np.ndarray
    lengths: np.ndarray
    length_ids: np.ndarray
    edges: np.ndarray
    flips: list
    area_weight: float = 1.0
    flipped_faces: list = dataclasses.field(default_factory=list)
    id_lengths: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    twin: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def flip_count(self):
        return int(sum(ids.size for ids, _, _ in self.flips))

    @property
    def tufted(self):
        """Whether the triangulation covers the mesh twice (non-manifold or non-orientable input)."""
        return self.area_weight != 1.0


def _edges(faces):
    """(edge id (3m,), edges (E, 2), forward (3m,) bool) of a triangle list: halfedge 3 f + i runs from
    faces[f, i] to faces[f, (i + 1) % 3]; ``forward`` where it runs from the lower vertex to the higher."""
    a, b = faces.ravel(), np.roll(faces, -1, axis=1).ravel()
    n = int(faces.max(initial=0)) + 1
    keys, edge_id = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_inverse=True)   # (lo, hi) order
    return edge_id.ravel(), np.stack([keys // n, keys % n], axis=1), a < b


def _pairs(edge_id):
    """(h0, h1): the halfedges of every edge with two of them (h0 first in halfedge order)."""
    order = np.argsort(edge_id, kind="stable")
    pair = edge_id[order[1:]] == edge_id[order[:-1]]
    return order[:-1][pair], order[1:][pair]


def _orientation(h0, h1, forward, m):
    """(m,) bool, the faces to reverse so that every edge with two faces (its halfedges h0, h1) is run
    both ways, or None where a component cannot be oriented. Face f is node f (as it is) and f + m
    (reversed) of a graph that joins the two faces of an edge as they fit; f is reversed when its
    reversed node has the smaller label."""
    fits = forward[h0] != forward[h1]
    if fits.all():
        return np.zeros(m, dtype=bool)
    f, g = h0 // 3, h1 // 3
    rows = np.concatenate([f, f + m])
    cols = np.concatenate([np.where(fits, g, g + m), np.where(fits, g + m, g)])
    graph = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(2 * m, 2 * m))
    labels = csgraph.connected_components(graph, directed=False)[1]
    if np.any(labels[:m] == labels[m:]):
        return None
    return labels[m:] < labels[:m]


def _tufted_cover(vertices, faces, edge_id, forward):
    """(faces (2m, 3), twin (6m,)): the faces, then each reversed (corners 0, 2, 1), glued round each
    edge. At edge (lo, hi), the faces are sorted by the angle of their third corner about the edge's
    direction e; the copy of a face that runs lo -> hi has the normal e x d (d: towards its third
    corner), facing the next face round, whose copy that runs hi -> lo faces back: those two halfedges
    are twins (one face alone: its two copies)."""
    m = faces.shape[0]
    h = np.arange(3 * m)
    f, i = h // 3, h % 3
    reverse = 3 * (m + f) + (2 - i)                       # the same edge in the reversed copy, run the other way
    a, b, c = faces[f, i], faces[f, (i + 1) % 3], faces[f, (i + 2) % 3]
    lo, hi = np.where(forward, a, b), np.where(forward, b, a)
    e = vertices[hi] - vertices[lo]
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    d = vertices[c] - vertices[lo]
    d -= np.einsum("ij,ij->i", d, e)[:, None] * e
    first = np.empty(edge_id.max() + 1, dtype=np.int64)
    first[edge_id[::-1]] = h[::-1]                        # each edge's first halfedge: its angles' zero
    reference = d[first[edge_id]]
    side = np.cross(e, reference)
    angle = np.arctan2(np.einsum("ij,ij->i", d, side), np.einsum("ij,ij->i", d, reference))
    order = np.lexsort((h, angle, edge_id))               # round each edge, by angle
    start = np.flatnonzero(np.concatenate([[True], edge_id[order[1:]] != edge_id[order[:-1]]]))
    group = np.repeat(start, np.diff(np.append(start, 3 * m)))
    end = np.repeat(np.append(start[1:], 3 * m), np.diff(np.append(start, 3 * m)))
    position = np.arange(3 * m)
    following = np.where(position + 1 < end, position + 1, group)
    runs_up = np.where(forward, h, reverse)[order]        # each face's copy that runs lo -> hi
    runs_down = np.where(forward, reverse, h)[order]
    twin = np.empty(6 * m, dtype=np.int64)
    twin[runs_up] = runs_down[following]
    twin[runs_down[following]] = runs_up
    return np.concatenate([faces, faces[:, [0, 2, 1]]]), twin


def _glued(vertices, faces):
    """(faces (m', 3), twin (3m',), edge id (3m',), edges (E, 2), area weight) of the triangulation the
    flips start from (module docstring): the mesh oriented, or its tufted cover."""
    edge_id, edges, forward = _edges(faces)
    m = faces.shape[0]
    f, i = np.arange(3 * m) // 3, np.arange(3 * m) % 3
    mirrored = 3 * f + (2 - i)           # halfedge i of face f reversed (corners 0, 2, 1) is its halfedge 2 - i
    if np.bincount(edge_id).max(initial=0) <= 2:
        h0, h1 = _pairs(edge_id)
        reverse = _orientation(h0, h1, forward, m)
        if reverse is not None:
            moved = np.where(reverse[f], mirrored, 3 * f + i)      # where each halfedge lies once oriented
            twin = np.full(3 * m, -1, dtype=np.int64)
            twin[moved[h0]], twin[moved[h1]] = moved[h1], moved[h0]
            oriented = np.where(reverse[:, None], faces[:, [0, 2, 1]], faces)
            return oriented, twin, edge_id[moved], edges, 1.0
    cover, twin = _tufted_cover(vertices, faces, edge_id, forward)
    return cover, twin, np.concatenate([edge_id, edge_id[mirrored]]), edges, 0.5


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
    pi (up to ``tolerance`` in the cotangents' sum), reached by flips of the input's edges, glued as
    the module docstring says. Boundary edges are never flipped (the tufted cover has none)."""
    V, F = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    F, twin, ids, edges, area_weight = _glued(V, F)
    m = F.shape[0]
    origin = F.ravel().copy()
    L = np.linalg.norm(V[np.roll(F, -1, axis=1)] - V[F], axis=2).ravel()
    next_id = edges.shape[0]
    flips, flipped_faces, id_lengths = [], [], [np.linalg.norm(V[edges[:, 1]] - V[edges[:, 0]], axis=1)]
    for _ in range(_MAX_ROUNDS):
        h = np.flatnonzero(twin > np.arange(3 * m))                  # every interior edge once
        t = twin[h]
        cot = _opposite_cot(L, h) + _opposite_cot(L, t)
        bad = cot < -tolerance * np.maximum(1.0, np.abs(cot))
        h, t, cot = h[bad], t[bad], cot[bad]
        f, g = h // 3, t // 3
        i, j = h % 3, t % 3
        ok = f != g             # one face on both sides (round a vertex of degree 1): isosceles, never flipped
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
        flipped_faces.append((f, i, g, j, np.stack([origin[h], origin[t], c, d], axis=1)))
        id_lengths.append(new_length)
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
        a, b = origin[h[0]], origin[3 * (h[0] // 3) + (h[0] + 1) % 3]
        raise MeshError(f"expected the intrinsic edge flips to end, got {_MAX_ROUNDS} rounds still flipping (an edge "
                        f"between vertices {a} and {b}); triangulation='mesh' solves on the mesh's own triangles")
    if not np.all(np.isfinite(L)):
        bad = int(np.flatnonzero(~np.isfinite(L))[0]) // 3
        raise MeshError(f"expected finite intrinsic edge lengths, got a non-finite one in the triangle on vertices "
                        f"{sorted(set(origin[3 * bad:3 * bad + 3].tolist()))} after the flips; triangulation='mesh' "
                        "solves on the mesh's own triangles")
    return IntrinsicTriangulation(origin.reshape(m, 3), L.reshape(m, 3), ids.reshape(m, 3), edges, flips, area_weight,
                                  flipped_faces, np.concatenate(id_lengths), twin)


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
    g = np.zeros(T.edges.shape[0] + sum(ids.size for ids, _, _ in T.flips))
    np.add.at(g, T.length_ids.ravel(), np.asarray(grad_lengths, dtype=np.float64).ravel())
    return id_gradient(T, vertices, g)


def id_gradient(triangulation, vertices, grad_ids):
    """dL/dx (n, 3) from dL/d(the length of every variable id) (E + flips,) of ``triangulation``."""
    T = triangulation
    g = np.array(grad_ids, dtype=np.float64)
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
