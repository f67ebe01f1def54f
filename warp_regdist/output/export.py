"""Writing a mesh with per-vertex fields for viewers (ParaView, VisIt): VTK ``.vtu`` files."""

from __future__ import annotations

import os

import numpy as np

from ..atomic_write import write_atomic
from ..geometry.mesh import Mesh

__all__ = ["save_vtu"]


def save_vtu(path, mesh, point_data):
    """Write a mesh and per-vertex fields as a VTK unstructured grid (``.vtu``, via meshio).

    ParaView opens the file directly and lists every field under "Points" data. Non-finite
    values (``+inf`` on vertices no source reaches) are written as NaN: VTK viewers leave
    NaN out of the colour range and draw it in their NaN colour, whereas ``inf`` would
    stretch the automatic range to infinity and hide the field.

    Parameters
    ----------
    path : str or os.PathLike
        Output file, ending in ``.vtu`` (binary, zlib-compressed, the VTK XML format).
    mesh : Mesh
        Triangle (VTK_TRIANGLE cells) or tetrahedral (VTK_TETRA cells) mesh; the vertex
        order is kept.
    point_data : dict of str -> (n,) or (n, c) array_like of float
        Fields per vertex, stored as float64 (a (n, 3) field is a vector field in ParaView).

    Raises
    ------
    ValueError
        For a path without the ``.vtu`` extension, a field of the wrong length or not real.
    WriteError
        When the file cannot be written (an existing file at ``path`` is then unchanged).
    """
    import meshio

    path = os.fspath(path)
    if not path.lower().endswith(".vtu"):
        raise ValueError(f"expected a path ending in .vtu, got {path!r}")
    if not isinstance(mesh, Mesh):
        raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
    fields = {}
    for name, values in dict(point_data).items():
        arr = np.asarray(values)
        if arr.ndim not in (1, 2) or arr.shape[0] != mesh.n_vertices:
            raise ValueError(f"expected point_data[{name!r}] of shape ({mesh.n_vertices},) or "
                             f"({mesh.n_vertices}, c), got {arr.shape}")
        if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
            raise ValueError(f"expected real values in point_data[{name!r}], got dtype {arr.dtype}")
        arr = arr.astype(np.float64)
        fields[str(name)] = np.where(np.isfinite(arr), arr, np.nan)
    kind = "triangle" if mesh.element_dim == 2 else "tetra"
    grid = meshio.Mesh(mesh.vertices, [(kind, mesh.elements)], point_data=fields)
    write_atomic(path, lambda tmp: meshio.write(tmp, grid, file_format="vtu"), "the .vtu file")
