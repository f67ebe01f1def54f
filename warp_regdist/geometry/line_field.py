"""Smooth line fields (sign-free direction fields) from a few constrained faces, for the vector-field regularizer.

Each face f gets a tangent frame (e1_f = first edge direction, e2_f = N_f x e1_f); a line
at angle phi_f in that frame is stored as the power-2 complex number c_f = exp(2 i phi_f),
so that the directions d and -d are the same value. Across an interior edge e shared by
faces f and g, with theta_f(e), theta_g(e) the angles of the (same) edge vector in the two
frames, a line is carried from f to g by the rotation r_fg = exp(2 i (theta_g - theta_f))
(the Levi-Civita transport of the unfolded face pair). The field is the minimizer of

    E(c) = sum over interior edges e = (f, g) of  w_e |c_g - r_fg c_f|^2,
    w_e = |e| / (|x_f - m_e| + |x_g - m_e|)        (edge length over dual edge length;
                                                    x_f face centroid, m_e edge midpoint)

with c fixed on the constrained faces (a sparse Hermitian solve), then normalized:
V_f = cos(phi_f) e1_f + sin(phi_f) e2_f with phi_f = arg(c_f) / 2. With ``fade`` the unit
field is multiplied by exp(-d_f^2 / (2 sigma^2)), sigma = fade sqrt(A), where d_f is the
mean over the face's corners of the exact polyhedral geodesic distance (libigl's
``exact_geodesic``, the MMP algorithm) to the vertices of the constrained faces. The
field does not depend on the distance solver that consumes it. :func:`read_directions`
reads a field, or the constraints of one, from a file (the command line's ``--directions``).
"""

from __future__ import annotations

import math
import os

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as spla

from ..arguments import read_csv_rows
from .mesh import Mesh

__all__ = ["line_field", "read_directions"]


def _frames(vertices, faces):
    """Face frames e1, e2, unit normals N, each (m, 3)."""
    P = vertices[faces]
    e1 = P[:, 1] - P[:, 0]
    normal = np.cross(e1, P[:, 2] - P[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(normal, e1), normal


def _interior_edges(faces):
    """Interior edges as (f (k,), g (k,), a (k,), b (k,)): faces f, g share the edge from vertex a to b."""
    m = len(faces)
    a = faces.ravel()
    b = faces[:, [1, 2, 0]].ravel()
    owner = np.repeat(np.arange(m), 3)
    key = np.minimum(a, b) * (faces.max() + 1) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    same = np.flatnonzero(key[order][1:] == key[order][:-1])
    first, second = order[same], order[same + 1]
    return owner[first], owner[second], a[first], b[first]


def _check_constraints(mesh, faces, directions, normals):
    m = mesh.n_elements
    try:
        faces = np.asarray(faces)
        directions = np.asarray(directions, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("expected faces as integers and directions as a real (k, 3) array, got "
                         f"{type(faces).__name__} and {type(directions).__name__}") from None
    if faces.ndim != 1 or faces.size == 0 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"expected a non-empty 1-d array of integer face indices, got {faces.tolist()!r}")
    if directions.shape != (faces.size, 3):
        raise ValueError(f"expected directions of shape ({faces.size}, 3) (one per constrained face), "
                         f"got {directions.shape}")
    bad = faces[(faces < 0) | (faces >= m)]
    if bad.size:
        raise ValueError(f"expected face indices in [0, {m - 1}], got {bad[0]}")
    if np.unique(faces).size != faces.size:
        raise ValueError(f"expected distinct constrained faces, got {faces.tolist()}")
    if not np.all(np.isfinite(directions)):
        bad = directions[~np.all(np.isfinite(directions), axis=1)][0]
        raise ValueError(f"expected finite directions, got {bad.tolist()}")
    tangent = directions - np.sum(directions * normals[faces], axis=1, keepdims=True) * normals[faces]
    length = np.linalg.norm(tangent, axis=1)
    flat = length <= 1e-6 * np.linalg.norm(directions, axis=1)
    if np.any(flat):
        i = np.flatnonzero(flat)[0]
        raise ValueError(f"expected directions with a component tangent to their face, got {directions[i].tolist()} "
                         f"on face {faces[i]} (normal {normals[faces[i]].round(6).tolist()})")
    return faces.astype(np.int64), tangent / length[:, None]


def line_field(mesh, faces, directions, fade=None):
    """Smoothest unit line field through the given face directions (see the module docstring).

    Parameters
    ----------
    mesh : Mesh
        Triangle mesh.
    faces : (k,) array_like of int
        Distinct constrained faces; every connected component needs at least one.
    directions : (k, 3) array_like of float
        Direction on each constrained face, sign-free (d and -d are the same line); it is
        projected to the face's plane (a direction normal to its face is refused).
    fade : float or None
        Scale-invariant width: multiply the field by exp(-d^2 / (2 sigma^2)) with
        sigma = fade * sqrt(total area) and d the exact geodesic distance to the vertices
        of the constrained faces; None: no fading (unit length everywhere).

    Returns
    -------
    (m, 3) ndarray of float64
        Per-face field, tangent to the faces, of length exp(-d_f^2 / (2 sigma^2)) (1 without
        fade); on constrained faces exactly +-(the projected unit direction).
    """
    if not isinstance(mesh, Mesh):
        raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
    if mesh.elements.shape[1] != 3:
        raise ValueError(f"expected a triangle mesh for a line field, got a tetrahedral mesh "
                         f"({mesh.n_elements} tetrahedra)")
    if fade is not None and (isinstance(fade, (bool, np.bool_)) or not isinstance(fade, (int, float, np.integer, np.floating))
                             or not math.isfinite(fade) or fade <= 0):
        raise ValueError(f"expected fade as a finite number > 0 or None, got {fade!r}")
    fade = None if fade is None else float(fade)
    V, F = mesh.vertices, mesh.elements
    m = len(F)
    e1, e2, normals = _frames(V, F)
    faces, tangent = _check_constraints(mesh, faces, directions, normals)

    f, g, a, b = _interior_edges(F)
    edge = V[b] - V[a]
    theta_f = np.arctan2(np.sum(edge * e2[f], axis=1), np.sum(edge * e1[f], axis=1))
    theta_g = np.arctan2(np.sum(edge * e2[g], axis=1), np.sum(edge * e1[g], axis=1))
    r = np.exp(2j * (theta_g - theta_f))
    centroid = V[F].mean(axis=1)
    middle = 0.5 * (V[a] + V[b])
    w = np.linalg.norm(edge, axis=1) / (np.linalg.norm(centroid[f] - middle, axis=1)
                                        + np.linalg.norm(centroid[g] - middle, axis=1))
    L = sp.csr_matrix((np.concatenate([w, w, -w * r, -w * np.conj(r)]),
                       (np.concatenate([f, g, g, f]), np.concatenate([f, g, f, g]))), shape=(m, m))

    n_comp, label = csgraph.connected_components(sp.csr_matrix((np.ones(f.size), (f, g)), shape=(m, m)), directed=False)
    missing = np.setdiff1d(np.arange(n_comp), label[faces])
    if missing.size:
        raise ValueError(f"expected a constrained face in every connected component, got none in the component "
                         f"of face {np.flatnonzero(label == missing[0])[0]}")

    c = np.zeros(m, dtype=np.complex128)
    c[faces] = (np.sum(tangent * e1[faces], axis=1) + 1j * np.sum(tangent * e2[faces], axis=1)) ** 2
    free = np.setdiff1d(np.arange(m), faces)
    if free.size:
        c[free] = spla.spsolve(L[free][:, free].tocsc(), -(L[free][:, faces] @ c[faces]))
    phi = 0.5 * np.angle(c)
    field = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    if fade is not None:
        import igl

        d = igl.exact_geodesic(np.ascontiguousarray(V, dtype=np.float64), np.ascontiguousarray(F, dtype=np.int64),
                               np.unique(F[faces]).astype(np.int64), np.empty(0, dtype=np.int64),
                               np.arange(len(V), dtype=np.int64), np.empty(0, dtype=np.int64))
        sigma = fade * math.sqrt(mesh.element_volumes.sum())
        field *= np.exp(-np.square(d[F].mean(axis=1)) / (2.0 * sigma * sigma))[:, None]
    return field


def read_directions(path, mesh):
    """The vector field of the "vector_field" regularizer from a file, as (m, 3) float64.

    ``.npy``: the field itself, one vector per element (its shape and values are checked by
    the solver). ``.csv``: rows ``face,dx,dy,dz`` (lines starting with ``#`` are comments),
    sign-free directions on a few faces, interpolated by :func:`line_field`.
    """
    path = os.fsdecode(os.fspath(path))
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".npy", ".csv"):
        raise ValueError(f"expected a directions file ending in .npy or .csv, got {path!r}")
    if not os.path.isfile(path):
        raise ValueError(f"expected an existing directions file, got {path!r} (no such file)")
    if ext == ".npy":
        try:
            return np.load(path, allow_pickle=False)
        except ValueError:
            raise ValueError(f"expected a numeric .npy array of shape (elements, 3), got an unreadable file "
                             f"{path!r}") from None
    rows = read_csv_rows(path, "face,dx,dy,dz", "CSV")
    fractional = rows[:, 0] != np.round(rows[:, 0])
    if fractional.any():
        raise ValueError(f"expected integer face indices in the first column, got {rows[fractional, 0][0]:g} "
                         f"in {path!r}")
    return line_field(mesh, rows[:, 0].astype(np.int64), rows[:, 1:])
