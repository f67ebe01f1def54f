"""Interactive viewing with polyscope (the ``[view]`` extra): a distance as a colour map with
isolines, its sources marked, a slice plane through tetrahedral meshes, several fields side
by side. ``warp-regdist view MESH values.npy`` is the same from the command line.
"""

from __future__ import annotations

import os
import sys

import numpy as np

from ..geometry.mesh import Mesh

__all__ = ["show"]


def show(mesh, u, isolines=20, sources=None, names=None, backend=None, frames=None):
    """Show one or several per-vertex fields on ``mesh`` in a polyscope window.

    Tetrahedral meshes get a scene slice plane (drag it in the window) to see inside; a
    :class:`~warp_regdist.PointCloud` is shown as its points (colours, no isolines).

    Parameters
    ----------
    mesh : Mesh
        Triangle or tetrahedral mesh of n vertices.
    u : (n,) or (n, k) array_like, or dict name -> (n,) array_like
        Field(s); k fields are shown on k copies of the mesh placed side by side along x
        (+inf, unreachable vertices, is shown as the largest finite value).
    isolines : int
        Isolines per field (spaced max finite value / isolines apart); 0: none.
    sources : array_like of int, optional
        Source vertices, drawn as points.
    names : list of str, optional
        One name per field (default "distance", or "distance 0", "distance 1", ...).
    backend : str, optional
        Polyscope backend; ``"openGL_mock"`` draws nothing (headless tests).
    frames : int, optional
        Render this many frames and return instead of waiting for the window to close.
    """
    if not isinstance(mesh, Mesh):
        raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
    fields = _fields(u, mesh.n_vertices, names)
    if isinstance(isolines, (bool, np.bool_)) or not (isinstance(isolines, (int, np.integer)) and isolines >= 0):
        raise ValueError(f"expected isolines as an integer >= 0, got {isolines!r}")
    src = None
    if sources is not None:
        src = np.asarray(sources).ravel()
        if src.size and (not np.issubdtype(src.dtype, np.integer) or src.min() < 0 or src.max() >= mesh.n_vertices):
            raise ValueError(f"expected sources as vertex indices in [0, {mesh.n_vertices - 1}], got {sources!r}")
    try:
        import polyscope as ps
    except ImportError:
        raise ModuleNotFoundError("expected the optional package 'polyscope' for show "
                                  "(pip install 'warp-regdist[view]'), got none installed") from None
    if backend is None and sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                                  or os.environ.get("WAYLAND_DISPLAY")):
        raise ValueError("expected a display for the viewer window, got none (DISPLAY and WAYLAND_DISPLAY are "
                         "unset): run it on a desktop, or write a picture instead (warp-regdist distance --png)")
    ps.set_use_prefs_file(False)  # no .polyscope.ini in the user's working directory
    ps.init(backend) if backend else ps.init()
    ps.remove_all_structures()
    ps.remove_all_slice_planes()
    V = np.asarray(mesh.vertices, dtype=np.float64)
    width = float(np.ptp(V[:, 0])) * 1.15 or 1.0
    for i, (name, values) in enumerate(fields.items()):
        offset = np.array([i * width, 0.0, 0.0])
        cloud = mesh.element_weights is not None
        if cloud:                                  # a PointCloud: its points, not its overlapping local triangles
            structure = ps.register_point_cloud(name, V + offset)
        elif mesh.element_dim == 3:
            structure = ps.register_volume_mesh(name, V + offset, tets=np.asarray(mesh.elements))
        else:
            structure = ps.register_surface_mesh(name, V + offset, np.asarray(mesh.elements))
        finite = values[np.isfinite(values)]
        top = float(finite.max()) if finite.size else 1.0
        shown = np.where(np.isfinite(values), values, top)
        options = dict(enabled=True, cmap="viridis")
        if isolines and top > 0 and not cloud:
            options.update(isolines_enabled=True, isoline_period=top / isolines, isoline_period_relative=False)
        structure.add_scalar_quantity("distance", shown, **options)
        if src is not None and src.size:
            ps.register_point_cloud(f"{name} sources", V[src] + offset, radius=0.006, color=(0.9, 0.1, 0.1))
    if mesh.element_dim == 3:
        ps.add_scene_slice_plane()
    ps.show(forFrames=frames) if frames is not None else ps.show()


def _fields(u, n, names):
    """{name: (n,) float64 array} from the forms :func:`show` accepts."""
    if isinstance(u, dict):
        items = list(u.items())
    else:
        a = np.asarray(u, dtype=np.float64)
        if a.ndim == 1:
            a = a[:, None]
        if a.ndim != 2 or a.shape[0] != n:
            raise ValueError(f"expected u of shape ({n},) or ({n}, k), got {np.shape(u)}")
        if names is None:
            names = ["distance"] if a.shape[1] == 1 else [f"distance {j}" for j in range(a.shape[1])]
        if len(names) != a.shape[1]:
            raise ValueError(f"expected {a.shape[1]} names, got {len(names)}")
        items = list(zip(names, a.T))
    fields = {}
    for name, values in items:
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (n,):
            raise ValueError(f"expected field {name!r} of shape ({n},), got {values.shape}")
        if np.isnan(values).any():
            raise ValueError(f"expected field {name!r} without NaN, got {int(np.isnan(values).sum())} NaN values")
        fields[str(name)] = values
    if not fields:
        raise ValueError("expected at least one field, got none")
    return fields
