"""Closed triangle surface -> tetrahedral mesh of the solid it bounds (TetGen, through the ``tetgen`` package).

The surface is checked first (closed, not intersecting itself), since TetGen either
fails with a vague message or crashes the process on such input; shells inside other
shells bound cavities, which TetGen is told to leave empty.
TetGen is deterministic (its internal random seed is fixed): the same surface and
settings give the same tetrahedra on every run.
"""

from __future__ import annotations

import contextlib
import os

import numpy as np

from ..arguments import check_weight
from ..errors import MeshError
from .mesh import Mesh
from .mesh_io import load_mesh
from .operators import mean_edge_length

__all__ = ["tetrahedralize", "interior_edge"]

_TETGEN_DEBRIS = ("_skipped.face", "_skipped.node")  # what TetGen writes into the working directory when it fails
_PAIR_CHUNK = 2_000_000  # candidate (face, cell) entries handled at once in the self-intersection test


def tetrahedralize(surface, max_volume=None, quality=1.5, min_dihedral=10.0, max_edge="auto", alpha_hat=0.05):
    """Fill a closed triangle surface with tetrahedra (constrained Delaunay + quality refinement, TetGen ``-pq``).

    The interior is as fine as the surface and the distance it will carry need: by default no
    tetrahedron is larger than the regular one of edge ``min(mean surface edge, alpha)``,
    alpha = alpha_hat V^(1/3) the regularization length of the solve (V the enclosed volume;
    the smooth cap of the distance has radius ~3 alpha and needs edges of that order).
    Without that bound TetGen's grading from the surface alone leaves the interior coarse.

    Parameters
    ----------
    surface : Mesh or str or os.PathLike
        Closed (watertight), manifold, not self-intersecting triangle surface, or a
        surface file for :func:`load_mesh`. Several disjoint shells give a mesh with one
        connected component per shell; a shell inside another bounds a cavity (left
        empty), a shell inside that cavity a solid again, and so on.
    max_volume : float, optional
        Target largest tetrahedron volume (mesh units cubed, TetGen ``-a``; TetGen may
        leave a few tetrahedra above it on coarse meshes). It replaces ``max_edge="auto"``;
        with a numeric ``max_edge`` the smaller of the two bounds applies.
    quality : float or None
        Largest radius-edge ratio (circumradius / shortest edge) of a tetrahedron, > 1
        (TetGen ``-q``; the regular tetrahedron has 0.61). None: no quality refinement,
        only the constrained Delaunay tetrahedralization of the surface's vertices.
    min_dihedral : float
        Smallest dihedral angle in degrees, in [0, 18] (used with ``quality``).
    max_edge : "auto", float or None
        Target longest interior edge (mesh units): tetrahedra are bounded by the volume
        L^3 / (6 sqrt 2) of the regular tetrahedron of edge L. "auto": L = min(mean surface
        edge, alpha_hat V^(1/3)) unless ``max_volume`` is given; None: no bound (TetGen's
        grading from the surface alone). Bounding the volume lets TetGen split surface
        triangles too (the surface's vertices still come first).
    alpha_hat : float or None
        The regularization weight the mesh is for (used by ``max_edge="auto"``; None or 0:
        the mean surface edge alone).

    Returns
    -------
    Mesh
        Tetrahedral mesh, positively oriented. Its first vertices are the surface's
        vertices that faces reference, in the surface's order (unreferenced ones are
        dropped, and of vertices at the same position only the first is kept), followed
        by the points TetGen inserted (on the surface and inside).

    Raises
    ------
    MeshError
        For a tetrahedral input, an open surface (boundary edges), a self-intersecting
        surface, or a surface TetGen cannot mesh.
    ValueError
        For max_volume, quality or min_dihedral out of range.
    ModuleNotFoundError
        When the optional ``tetgen`` package is missing (``pip install 'warp-regdist[volume]'``).
    """
    if isinstance(surface, (str, bytes, os.PathLike)):
        surface = load_mesh(surface)
    if not isinstance(surface, Mesh):
        raise ValueError(f"expected a triangle surface (a Mesh or a file path), got {type(surface).__name__}")
    if surface.element_dim != 2:
        raise MeshError(f"expected a triangle surface, got a tetrahedral mesh ({surface.n_elements} tetrahedra)")
    if max_volume is not None and not (_is_real(max_volume) and np.isfinite(max_volume) and max_volume > 0):
        raise ValueError(f"expected max_volume > 0 (or None), got {max_volume!r}")
    if quality is not None and not (_is_real(quality) and np.isfinite(quality) and quality > 1.0):
        raise ValueError(f"expected quality (largest radius-edge ratio) > 1 (or None), got {quality!r}")
    if not (_is_real(min_dihedral) and 0.0 <= min_dihedral <= 18.0):
        raise ValueError(f"expected min_dihedral in [0, 18] degrees, got {min_dihedral!r}")
    if not (max_edge is None or (isinstance(max_edge, str) and max_edge == "auto")
            or (_is_real(max_edge) and np.isfinite(max_edge) and max_edge > 0)):
        raise ValueError(f"expected max_edge 'auto', a length > 0 or None, got {max_edge!r}")
    if alpha_hat is not None:
        alpha_hat = check_weight(alpha_hat, "alpha_hat")
    try:
        import tetgen
    except ImportError:
        raise ModuleNotFoundError("expected the optional package 'tetgen' for tetrahedralize "
                                  "(pip install 'warp-regdist[volume]'), got none installed") from None

    _, first, same = np.unique(surface.vertices, axis=0, return_index=True, return_inverse=True)
    welded = first[same.ravel()][surface.faces]  # vertices at one position are one vertex (OBJ seams)
    used = np.unique(welded)
    V = surface.vertices[used]
    F = np.searchsorted(used, welded)
    _check_closed(F, used)
    _check_no_self_intersection(V, F)
    shells, depth = _shell_depths(V, F)
    cavities = _cavity_points(V, F, shells, depth)
    if isinstance(max_edge, str):
        max_edge = interior_edge(V, F, alpha_hat, shells, depth) if max_volume is None else None
    if max_edge is not None:
        by_edge = float(max_edge) ** 3 / (6.0 * np.sqrt(2.0))
        max_volume = by_edge if max_volume is None else min(float(max_volume), by_edge)

    options = {"quality": quality is not None, "quiet": True, "nowarning": True}
    if quality is not None:
        options.update(minratio=float(quality), mindihedral=float(min_dihedral))
    if max_volume is not None:
        options.update(fixedvolume=True, maxvolume=float(max_volume))
    debris = [name for name in _TETGEN_DEBRIS if not os.path.exists(name)]
    try:
        mesher = tetgen.TetGen(V, F.astype(np.int32))
        for point in cavities:
            mesher.add_hole(point)
        nodes, tets, *_ = mesher.tetrahedralize(**options)
    except RuntimeError as exc:
        raise MeshError(f"expected a surface TetGen can tetrahedralize, got its error: {exc}") from None
    finally:
        for name in debris:
            with contextlib.suppress(OSError):
                os.remove(name)
    tets = np.asarray(tets, dtype=np.int64)
    keep = np.zeros(len(nodes), bool)
    keep[tets.ravel()] = True
    keep[: len(V)] = True
    renumber = np.cumsum(keep) - 1
    return Mesh(np.asarray(nodes)[keep], renumber[tets])


def _is_real(value):
    """A real number (Python or numpy), not a bool."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _check_closed(F, numbers):
    """Refuse boundary edges (edges of one face): TetGen needs a closed surface. ``numbers``: vertex
    numbers to report (the surface's, before unreferenced vertices were dropped)."""
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    edges, counts = np.unique(e, axis=0, return_counts=True)
    open_edges = edges[counts == 1]
    if open_edges.size:
        raise MeshError(f"expected a closed (watertight) surface, got {len(open_edges)} boundary edges "
                        f"(first: between vertices {numbers[open_edges[0]].tolist()}); close the holes first")


def _face_components(F):
    """(m,) shell label of every face: faces joined by shared vertices."""
    import scipy.sparse as sp
    from scipy.sparse import csgraph

    n = int(F.max()) + 1
    g = sp.coo_matrix((np.ones(2 * len(F)), (np.repeat(F[:, 0], 2), F[:, 1:].ravel())), shape=(n, n))
    _, labels = csgraph.connected_components(g, directed=False)
    return labels[F[:, 0]]


def interior_edge(V, F, alpha_hat, shells=None, depth=None):
    """The default longest interior edge: min(mean edge of the surface (V, F), alpha_hat vol^(1/3)),
    vol the volume the closed surface encloses (cavities excluded); the mean edge alone when
    alpha_hat is None or 0."""
    mean_edge = mean_edge_length(V, F)
    if not alpha_hat:
        return mean_edge
    if shells is None:
        shells, depth = _shell_depths(V, F)
    return min(mean_edge, float(alpha_hat) * _enclosed_volume(V, F, shells, depth) ** (1.0 / 3.0))


def _shell_depths(V, F):
    """(m,) shell label of every face and (shells,) depth of every shell: the number of other
    shells it lies inside (generalized winding numbers); odd depth: the shell bounds a cavity."""
    import igl

    shells = _face_components(F)
    count = shells.max() + 1
    if count == 1:
        return shells, np.zeros(1, np.int64)
    probes = V[F[np.unique(shells, return_index=True)[1], 0]]  # one vertex of every shell
    contains = np.zeros((count, count), bool)  # contains[s, t]: shell t inside shell s
    for s in range(count):
        contains[s] = np.abs(igl.winding_number(V, F[shells == s], probes)) > 0.5
        contains[s, s] = False
    return shells, contains.sum(axis=0)


def _enclosed_volume(V, F, shells, depth):
    """Volume of the solid: each shell's enclosed volume (divergence theorem, either orientation),
    added at even depth and removed at odd depth (cavities)."""
    P = V[F] - V.mean(axis=0)
    signed = np.einsum("ij,ij->i", P[:, 0], np.cross(P[:, 1], P[:, 2])) / 6.0
    per_shell = np.abs(np.bincount(shells, weights=signed, minlength=len(depth)))
    return float(np.sum(np.where(depth % 2 == 0, per_shell, -per_shell)))


def _cavity_points(V, F, shells, depth):
    """(c, 3) one point inside every cavity: the region enclosed by a shell of odd depth
    (:func:`_shell_depths`), outside the shells within it.

    The point is a face centroid of the cavity's shell moved by a hundredth of the face's
    shortest edge to the shell's inner side; TetGen removes the tetrahedra of the region
    holding it (``-p`` with holes), and solids nested deeper stay meshed.
    """
    import igl

    points = []
    for s in np.flatnonzero(depth % 2 == 1):
        faces = F[shells == s]
        P = V[faces]
        lengths = np.linalg.norm(P - np.roll(P, 1, axis=1), axis=2).min(axis=1)
        f = int(np.argmax(lengths))
        normal = np.cross(P[f, 1] - P[f, 0], P[f, 2] - P[f, 0])
        centroid = P[f].mean(axis=0)
        step = 0.01 * lengths[f] * normal / np.linalg.norm(normal)
        sides = np.stack([centroid + step, centroid - step])
        inside = np.abs(igl.winding_number(V, faces, sides)) > 0.5
        if inside[0] == inside[1]:
            raise MeshError(f"expected shells that bound volumes, got shell {s} with no inner side at face "
                            f"{int(np.flatnonzero(shells == s)[f])}")
        points.append(sides[int(np.argmax(inside))])
    return np.array(points).reshape(-1, 3)


def _check_no_self_intersection(V, F):
    """Refuse faces that cross each other (TetGen crashes on them).

    Broad phase: faces sharing a cell of a uniform grid (cell = mean face bounding-box
    size) with overlapping bounding boxes and no shared vertex. Narrow phase: two
    triangles in general position intersect iff an edge of one crosses the other, i.e.
    the edge's endpoints lie strictly on both sides of the other's plane and the edge's
    line passes strictly inside it (signed volumes). Touching and coplanar contacts are
    not counted.
    """
    P = V[F]
    lo, hi = P.min(axis=1), P.max(axis=1)
    cell = float(np.mean(np.max(hi - lo, axis=1)))
    if cell <= 0:
        return
    c_lo = np.floor((lo - lo.min(axis=0)) / cell).astype(np.int64)
    c_hi = np.floor((hi - lo.min(axis=0)) / cell).astype(np.int64)
    span = c_hi - c_lo + 1
    counts = span.prod(axis=1)
    face = np.repeat(np.arange(len(F)), counts)
    k = np.arange(face.size) - np.repeat(np.cumsum(counts) - counts, counts)
    sx, sy = span[face, 0], span[face, 1]
    ijk = c_lo[face] + np.stack([k % sx, (k // sx) % sy, k // (sx * sy)], axis=1)
    dims = c_hi.max(axis=0) + 1
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(key, kind="stable")
    key, face = key[order], face[order]
    group_end = np.searchsorted(key, key, side="right")
    partners = group_end - np.arange(key.size) - 1
    for start in range(0, key.size, _PAIR_CHUNK):
        idx = np.arange(start, min(start + _PAIR_CHUNK, key.size))
        reps = partners[idx]
        first = np.repeat(idx, reps)
        second = first + 1 + (np.arange(first.size) - np.repeat(np.cumsum(reps) - reps, reps))
        a, b = face[first], face[second]
        pairs = np.unique(np.minimum(a, b) * len(F) + np.maximum(a, b))
        a, b = pairs // len(F), pairs % len(F)
        overlap = np.all((lo[a] <= hi[b]) & (lo[b] <= hi[a]), axis=1)
        shared = (F[a][:, :, None] == F[b][:, None, :]).any(axis=(1, 2))
        a, b = a[overlap & ~shared], b[overlap & ~shared]
        hit = _edges_cross(P[a], P[b]) | _edges_cross(P[b], P[a])
        if hit.any():
            i = np.flatnonzero(hit)
            raise MeshError(f"expected a surface that does not intersect itself, got {i.size} crossing face "
                            f"pairs (first: faces {a[i[0]]} and {b[i[0]]}); repair the surface first")


def _orient(a, b, c, d):
    """Signed volume x 6 of (a, b, c, d), rows of shape (k, 3)."""
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)


def _edges_cross(S, T):
    """(k,) bool: some edge of triangle S[i] (k, 3, 3) crosses triangle T[i] strictly inside."""
    a, b, c = T[:, 0], T[:, 1], T[:, 2]
    hit = np.zeros(len(S), bool)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        p, q = S[:, i], S[:, j]
        sides = _orient(a, b, c, p) * _orient(a, b, c, q) < 0
        w = np.stack([_orient(p, q, a, b), _orient(p, q, b, c), _orient(p, q, c, a)], axis=1)
        hit |= sides & ((w > 0).all(axis=1) | (w < 0).all(axis=1))
    return hit
