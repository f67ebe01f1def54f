"""Meshes as users have them, made usable: vertices at one position merged into one.

Each function returns the new :class:`~warp_regdist.Mesh` and ``index`` (n,), the new vertex of
every input vertex, so that values and sources move between the two numberings
(``u_input = u_new[index]``).
"""

from __future__ import annotations

import warnings

import numpy as np

from .mesh import Mesh, duplicate_vertices

__all__ = ["merge_duplicate_vertices"]


def merge_duplicate_vertices(mesh):
    """The mesh with the vertices at one position merged into the first of them, and ``index`` (n,).

    Kept vertices keep their order; elements that the merge leaves with a repeated corner are dropped.

    Returns
    -------
    merged : Mesh
    index : (n,) ndarray of int64
        Vertex of ``merged`` of each vertex of ``mesh``.
    """
    if not isinstance(mesh, Mesh):
        raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
    pairs = duplicate_vertices(mesh.vertices)
    lead = np.arange(mesh.n_vertices)
    lead[pairs[:, 1]] = pairs[:, 0]
    keep = lead == np.arange(mesh.n_vertices)
    rank = np.cumsum(keep) - 1
    index = rank[lead]
    T = index[mesh.elements]
    S = np.sort(T, axis=1)
    T = T[~(S[:, 1:] == S[:, :-1]).any(axis=1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # no duplicates are left to warn about
        return Mesh(mesh.vertices[keep], T), index.astype(np.int64)
