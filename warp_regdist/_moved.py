"""The module paths of earlier releases (``warp_regdist.render``, ``warp_regdist.solver``, ...),
kept importable with a DeprecationWarning: each is the same module object as its new path."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

GROUPS = {
    "geometry": ("mesh", "mesh_io", "operators", "regularizers", "line_field", "tetrahedralize", "volume_grid"),
    "solvers": ("solver", "single_source_batch", "all_pairs_admm", "all_pairs_state", "all_pairs_checkpoint", "admm",
                "stopping", "pcg", "multigrid", "csr", "processes", "interrupt"),
    "matrices": ("source_rows", "matrix_store", "distributed", "row_solves"),
    "output": ("render", "contours", "viewer", "export"),
}
MOVED = {f"warp_regdist.{name}": f"warp_regdist.{group}.{name}" for group, names in GROUPS.items() for name in names
         if name not in ("tetrahedralize", "line_field")}  # the package's functions of those names stay what they are


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds ``warp_regdist.<old>`` and loads it as its new module (a warning says where it lives)."""

    def find_spec(self, fullname, path, target=None):
        return importlib.util.spec_from_loader(fullname, self) if fullname in MOVED else None

    def create_module(self, spec):
        warnings.warn(f"{spec.name} is {MOVED[spec.name]}; the old path will be removed", DeprecationWarning,
                      stacklevel=2)
        return importlib.import_module(MOVED[spec.name])

    def exec_module(self, module):
        pass


def install():
    """Put the finder on sys.meta_path (once)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.append(_MovedFinder())
