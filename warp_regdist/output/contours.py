"""Exact contours of piecewise-linear fields: isolines on triangle meshes, plane sections of tetrahedral meshes.

Both are exact for a field that is linear on every element: on a triangle its level set
is one straight segment between two edges (marching triangles, :func:`isolines`); a plane
meets a tetrahedron in a triangle or a quadrilateral on which the field is again linear
(marching tetrahedra, :func:`plane_section`). The pictures of :mod:`warp_regdist.output.render`
and the knitting example's polyline export are drawn from these.
"""

from __future__ import annotations

import numpy as np

__all__ = ["isolines", "isoline_segments", "plane_section", "surface_arrays", "vertex_values"]


def surface_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Validated float64 vertices (n, 3) and int64 faces (m, 3) of a triangle mesh."""
    if getattr(mesh, "element_dim", 2) == 3:
        raise ValueError(f"expected a triangle mesh, got {mesh.n_elements} tetrahedra (use render_cut)")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"expected mesh vertices of shape (n, 3), got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(f"expected triangle faces of shape (m, 3) with m >= 1, got {faces.shape}")
    return vertices, faces


def vertex_values(values, n_vertices: int) -> np.ndarray:
    """``values`` as float64 (n_vertices,); ValueError for another shape."""
    values = np.asarray(values, dtype=np.float64)
    if values.shape != (n_vertices,):
        raise ValueError(f"expected one value per vertex, shape ({n_vertices},), got {values.shape}")
    return values


def isolines(mesh, values, levels) -> list[np.ndarray]:
    """Level sets of a piecewise-linear function, computed exactly per triangle.

    On a triangle the linear interpolant of the vertex values crosses the level c along
    one straight segment whose endpoints lie on the two edges (i, j) with
    ``v_i < c <= v_j`` (or the reverse), at ``p = x_i + t (x_j - x_i)``,
    ``t = (c - v_i) / (v_j - v_i)`` (marching triangles).  A vertex with ``v = c``
    counts as above the level, so a level through a mesh edge yields that edge once.
    Triangles with a non-finite vertex value (``inf`` for unreachable vertices, ``nan``)
    are skipped.

    Parameters
    ----------
    mesh : Mesh
        Triangle mesh; any object with ``vertices`` (n, 3) and ``faces`` (m, 3).
    values : (n,) float
        Value per vertex.
    levels : (L,) float
        Levels c to extract.

    Returns
    -------
    list of (s_l, 2, 3) float64
        For each level, its segments (start, end), oriented so that the values increase to
        the left of the segment seen from the side the face normal points to (the face
        ``(a, b, c)`` turning counter-clockwise).  Segments are unordered; two segments
        meeting on a mesh edge share that endpoint exactly.
    """
    vertices, faces = surface_arrays(mesh)
    values = vertex_values(values, len(vertices))
    levels = np.atleast_1d(np.asarray(levels, dtype=np.float64))
    if levels.ndim != 1:
        raise ValueError(f"expected levels of shape (L,), got {levels.shape}")
    segments, _, level_index = isoline_segments(vertices, faces, values, levels)
    order = np.argsort(level_index, kind="stable")
    return np.split(segments[order], np.cumsum(np.bincount(level_index, minlength=len(levels)))[:-1])


def isoline_segments(vertices, faces, values, levels) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All isoline segments (s, 2, 3) of ``values`` (n,) on ``faces`` (m, 3) at ``levels`` (L,),
    the face (s,) and the level index (s,) of each (see :func:`isolines`)."""
    face_values = values[faces]  # (m, 3)
    finite = np.flatnonzero(np.isfinite(face_values).all(axis=1))
    faces, face_values = faces[finite], face_values[finite]
    above = face_values[:, :, None] >= levels[None, None, :]  # (m, 3, L)
    count = above.sum(axis=1)  # (m, L)
    face, level = np.nonzero((count == 1) | (count == 2))
    # The odd vertex k is alone on its side; the segment joins edges (k, k+1) and (k, k+2).
    odd_is_above = count[face, level] == 1
    odd = np.argmax(above[face, :, level] == odd_is_above[:, None], axis=1)
    k = np.stack([odd, (odd + 1) % 3, (odd + 2) % 3], axis=1)
    fv = face_values[face[:, None], k]  # (s, 3) values at k, k+1, k+2
    fx = vertices[faces[face[:, None], k]]  # (s, 3, 3)
    # Interpolate from the vertex below the level on each crossed edge, so that the two
    # faces sharing an edge compute its crossing point with the same operations.
    up = odd_is_above[:, None]
    v_lo, v_hi = np.where(up, fv[:, 1:], fv[:, :1]), np.where(up, fv[:, :1], fv[:, 1:])  # (s, 2)
    x_lo = np.where(up[:, :, None], fx[:, 1:], fx[:, :1])  # (s, 2, 3)
    x_hi = np.where(up[:, :, None], fx[:, :1], fx[:, 1:])
    t = (levels[level][:, None] - v_lo) / (v_hi - v_lo)  # (s, 2), on edges (k, k+1) and (k, k+2)
    ends = x_lo + t[:, :, None] * (x_hi - x_lo)  # (s, 2, 3)
    # Values increase to the left of (edge (k,k+1) -> edge (k,k+2)) when k is above.
    ends = np.where(odd_is_above[:, None, None], ends, ends[:, ::-1])
    nonzero = np.any(ends[:, 0] != ends[:, 1], axis=1)
    return ends[nonzero], finite[face[nonzero]], level[nonzero]


def _section_table() -> tuple[np.ndarray, np.ndarray]:
    """Marching-tetrahedra table: for each sign pattern (bit l set when corner l is on the
    positive side), up to two triangles, each given by the three tetrahedron edges (pairs of
    local corners) its corners lie on.  Returns (16, 2, 3, 2) edges and (16, 2) validity."""
    edges = np.zeros((16, 2, 3, 2), dtype=np.int64)
    valid = np.zeros((16, 2), dtype=bool)
    for mask in range(1, 15):
        up = [l for l in range(4) if mask >> l & 1]
        down = [l for l in range(4) if not mask >> l & 1]
        if len(up) == 2:  # quadrilateral (a,c) (a,d) (b,d) (b,c), cut into two triangles
            (a, b), (c, d) = up, down
            quad = [(a, c), (a, d), (b, d), (b, c)]
            edges[mask] = [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
            valid[mask] = True
        else:  # one corner alone on its side: a triangle on its three edges
            alone, rest = (up, down) if len(up) == 1 else (down, up)
            edges[mask, 0] = [(alone[0], r) for r in rest]
            valid[mask, 0] = True
    return edges, valid


def plane_section(mesh, values, plane_normal=(0.0, 0.0, 1.0), offset=None) -> tuple[np.ndarray, np.ndarray]:
    """Cut a tetrahedral mesh with a plane: triangles of the section and the field on them.

    Marching tetrahedra: with s_i = n . x_i - offset (n the unit normal), a tetrahedron
    whose corners are not all on one side (s >= 0 counts as the positive side) meets the
    plane in a triangle (one corner alone on its side) or a quadrilateral (two and two),
    cut here into two triangles.  Its corners lie on the edges (i, j) whose ends change
    side, at ``x_i + t (x_j - x_i)`` with ``t = s_i / (s_i - s_j)``, where the piecewise
    linear field is ``v_i + t (v_j - v_i)`` (exact: the field is linear on the tetrahedron,
    so it is linear on every section triangle too).  A tetrahedron face lying in the
    plane is returned once (by the tetrahedron on its negative side).

    Parameters
    ----------
    mesh : Mesh
        Tetrahedral mesh (``elements`` of shape (m, 4)).
    values : (n,) float
        Value per vertex; non-finite values propagate to the section.
    plane_normal : (3,) float
        Normal of the plane (any length but zero).
    offset : float, optional
        The plane is {x : n . x = offset} for the unit normal n; default: through the
        centre of the mesh's bounding box.

    Returns
    -------
    points : (t, 3, 3) float64
        Corners of the t section triangles (zero-area ones removed).
    point_values : (t, 3) float64
        The field at those corners.
    """
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    tets = np.asarray(mesh.elements, dtype=np.int64)
    if tets.ndim != 2 or tets.shape[1] != 4:
        raise ValueError(f"expected a tetrahedral mesh (elements of shape (m, 4)), got elements of shape {tets.shape}")
    values = vertex_values(values, len(vertices))
    normal = np.asarray(plane_normal, dtype=np.float64)
    if normal.shape != (3,) or not np.all(np.isfinite(normal)) or not np.linalg.norm(normal) > 0:
        raise ValueError(f"expected plane_normal as a non-zero finite 3-vector, got {plane_normal!r}")
    normal = normal / np.linalg.norm(normal)
    heights = vertices @ normal
    if offset is None:
        offset = float(0.5 * (vertices.min(axis=0) + vertices.max(axis=0)) @ normal)
    s = heights - float(offset)
    corner_s = s[tets]  # (m, 4)
    mask = (corner_s >= 0) @ np.array([1, 2, 4, 8])
    edges, valid = _section_table()
    tet, slot = np.nonzero(valid[mask])
    ends = tets[tet[:, None, None], edges[mask[tet], slot]]  # (t, 3, 2) global vertex indices
    si, sj = s[ends[..., 0]], s[ends[..., 1]]
    t = si / (si - sj)
    xi, xj = vertices[ends[..., 0]], vertices[ends[..., 1]]
    points = xi + t[..., None] * (xj - xi)
    with np.errstate(invalid="ignore"):  # inf - inf on unreachable vertices: NaN, drawn grey
        point_values = values[ends[..., 0]] + t * (values[ends[..., 1]] - values[ends[..., 0]])
    area = np.linalg.norm(np.cross(points[:, 1] - points[:, 0], points[:, 2] - points[:, 0]), axis=1)
    keep = area > 1e-12 * max(np.ptp(heights), np.finfo(np.float64).tiny) ** 2
    return points[keep], point_values[keep]
