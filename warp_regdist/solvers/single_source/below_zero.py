"""Distances below 0: the warning a converged column gets where it dips below -NEGATIVE of its max, and why."""

from __future__ import annotations

import warnings

import numpy as np

from ...errors import MeshWarning
from ...geometry.obtuse_refinement import obtuse_angles
from ...geometry.operators import corner_angle, largest_basis_angles

__all__ = ["NEGATIVE", "warn_below_zero"]


NEGATIVE = 1e-6
"""A distance below -NEGATIVE x its column's max is reported (:func:`warn_below_zero`)."""


def warn_below_zero(mesh, ops, u, converged, source_sets, refinable):
    """A MeshWarning naming the lowest vertex, its source set and the largest angle at it where some
    converged column of ``u`` (n, k) goes below -NEGATIVE of its max: the minimizer of the discrete problem dips
    below 0 next to badly shaped triangles (obtuse, where the cone of the distance from a source cannot
    be represented), which the intrinsic triangulation and its refinement make rare but not impossible;
    where the solver could refine and did not (``refinable``: an intrinsic triangulation, refine_obtuse off)
    and the mesh has obtuse angles the refinement would remove, it names ``refine_obtuse=True``."""
    finite = np.where(np.isfinite(u), u, 0.0)
    top = finite.max(axis=0)
    low = finite.min(axis=0)
    bad = np.flatnonzero((low < -NEGATIVE * np.maximum(top, 1e-300)) & converged)
    if bad.size == 0:
        return
    j = bad[np.argmin(low[bad] / top[bad])]
    i = int(np.argmin(finite[:, j]))
    where = ""
    if ops.basis.shape[1] == 3:
        around = np.flatnonzero((ops.elements == i).any(axis=1))
        at_source = [(corner_angle(ops.basis[e], c), int(ops.elements[e, c])) for e in around
                     for c in range(3) if int(ops.elements[e, c]) in set(np.atleast_1d(source_sets[j]).tolist())]
        if at_source:
            angle, source = max(at_source)
            where = f"; the triangle at that vertex and source {source} has a {angle:.0f}-degree angle at the source"
        else:
            angle = float(np.max(largest_basis_angles(ops.basis[around]), initial=0.0))
            where = f"; the largest angle of a triangle at that vertex is {angle:.0f} degrees"
    remedy = "a finer or better shaped mesh near the sources avoids it"
    if refinable and obtuse_angles(mesh.vertices, mesh.elements)[0].size:
        remedy = ("the mesh has obtuse angles that no flip removes (boundary sides opposite obtuse angles, angles "
                  "above 120 degrees): refine_obtuse=True inserts vertices there (the default with the Dirichlet "
                  "regularizer)")
    warnings.warn(f"{bad.size} of {u.shape[1]} source sets have distances below 0, down to "
                  f"{100 * low[j] / top[j]:.3g}% of the max distance at vertex {i} (source set {j}: "
                  f"{[int(x) for x in np.atleast_1d(source_sets[j])[:4]]}{where}): a linear distance from a source across an "
                  f"obtuse angle there must fall below 0; {remedy} (docs/real-meshes.md)", MeshWarning, stacklevel=4)
