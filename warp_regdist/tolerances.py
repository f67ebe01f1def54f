"""The mesh-level tolerances: when an element is degenerate, when a source point or a curve's
crossing moves onto a nearby edge or vertex (cf. ``trimesh.tol``).

Change a value for the whole process (``warp_regdist.tolerances.point_snap = 1e-4``) or for one
block with ``with warp_regdist.tolerances.override(point_snap=1e-4): ...``. The solvers' settings
are their options objects (:class:`~warp_regdist.SolverOptions`, :class:`~warp_regdist.AllPairsOptions`).
"""

from __future__ import annotations

import contextlib
import dataclasses

__all__ = ["Tolerances", "tolerances"]


@dataclasses.dataclass
class Tolerances:
    """Dimensionless mesh-level tolerances.

    Attributes
    ----------
    degenerate_element : float
        An element whose area (volume) is <= this times its longest edge squared (cubed) is
        refused as degenerate.
    point_snap : float
        A source point whose barycentric coordinate on a face is <= this lies on that face's edge
        (or vertex, when 1 - point_snap <= its largest coordinate) and is moved there: the triangles
        it would cut off would be slivers (see :func:`warp_regdist.surface_points`).
    weld : float
        Two boundary vertices at most this times the bounding box diagonal apart (and closer than a
        tenth of the boundary edges at either) are the two sides of a crack: a load warns, and the
        repair (:func:`warp_regdist.repair_mesh`) welds them.
    curve_snap : float
        A curve's crossing of an edge within this fraction of the edge from a vertex moves to the
        vertex (the curve then passes through it): the cuts would leave slivers and obtuse angles
        next to the curve, where u dips below 0.
    """

    degenerate_element: float = 1e-12
    point_snap: float = 1e-3
    weld: float = 1e-3
    curve_snap: float = 0.2

    @contextlib.contextmanager
    def override(self, **values):
        """Temporarily set some attributes (restored on exit, also after an exception)."""
        names = [f.name for f in dataclasses.fields(self)]
        unknown = sorted(set(values) - set(names))
        if unknown:
            raise ValueError(f"expected tolerance names among {names}, got {unknown}")
        old = {k: getattr(self, k) for k in values}
        for k, v in values.items():
            setattr(self, k, v)
        try:
            yield self
        finally:
            for k, v in old.items():
                setattr(self, k, v)


tolerances = Tolerances()
