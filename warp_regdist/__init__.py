"""warp-regdist: regularized geodesic distances on triangle and tetrahedral meshes.

Implements Edelstein, Guillen, Solomon, Ben-Chen, "A Convex Optimization Framework for
Regularized Geodesic Distances" (SIGGRAPH 2023) with Warp kernels (CPU and CUDA).
"""

import warp as _wp

from . import metrics
from .solvers.common.admm import PenaltySchedule
from .solvers.all_pairs.solver import AllPairsSolver, all_pairs
from .output.export import save_vtu
from .geometry.line_field import line_field
from .errors import CheckpointWarning, ConvergenceWarning, MeshError, MeshWarning, WorkerError, WriteError
from .geometry.mesh import Mesh, boundary_faces, boundary_vertices
from .geometry.obtuse_refinement import ObtuseRefinement, refine_obtuse_angles
from .geometry.mesh_io import data_path, load_mesh
from .geometry.repair import Repair, merge_duplicate_vertices, repair_mesh, split_components
from .geometry.surface_points import surface_points
from .geometry.point_cloud import PointCloud
from .geometry.operators import Operators, build_operators
from .geometry.regularizers import REGULARIZERS
from .solvers.common.results import AllPairsResult, DistanceResult
from .solvers.common.progress import Progress, StopTest
from .linalg.multigrid import Hierarchy
from .solvers.single_source.gradients import Gradients
from .solvers.single_source.solver import DistanceSolver
from .matrices.source_rows import distance_matrix
from .geometry.tetrahedralize import tetrahedralize
from .options import AllPairsOptions, SolverOptions
from .tolerances import Tolerances, tolerances
from .output.viewer import show

__version__ = "0.1.0"

if _wp.config.log_level == _wp.LOG_INFO:  # Warp's default: its banner and module loads printed on stdout
    _wp.config.log_level = _wp.LOG_WARNING


def __getattr__(name):
    """``warp_regdist.torch`` (PyTorch autograd, the [torch] extra) imports on first use."""
    if name == "torch":
        import importlib

        return importlib.import_module(".torch", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["Mesh", "MeshError", "MeshWarning", "merge_duplicate_vertices", "repair_mesh", "Repair",
           "split_components", "load_mesh", "data_path", "boundary_vertices", "refine_obtuse_angles", "ObtuseRefinement", "surface_points", "boundary_faces", "PointCloud", "Operators", "build_operators",
           "DistanceSolver", "DistanceResult", "Gradients", "ConvergenceWarning", "REGULARIZERS", "line_field",
           "all_pairs", "AllPairsSolver", "AllPairsResult", "distance_matrix", "save_vtu", "metrics",
           "SolverOptions", "AllPairsOptions", "Tolerances", "tolerances", "PenaltySchedule", "tetrahedralize", "WorkerError", "WriteError", "CheckpointWarning", "show", "Progress", "StopTest", "Hierarchy",
           "__version__"]
