"""warp-regdist: regularized geodesic distances on triangle and tetrahedral meshes.

Implements Edelstein, Guillen, Solomon, Ben-Chen, "A Convex Optimization Framework for
Regularized Geodesic Distances" (SIGGRAPH 2023) with Warp kernels (CPU and CUDA).
"""

from . import metrics
from .admm import PenaltySchedule
from .all_pairs_admm import AllPairsResult, all_pairs
from .export import save_vtu
from .line_field import line_field
from .errors import ConvergenceWarning, MeshError, WorkerError
from .mesh import Mesh, boundary_vertices
from .mesh_io import data_path, load_mesh
from .operators import Operators, build_operators
from .regularizers import REGULARIZERS
from .solver import DistanceResult, DistanceSolver
from .source_rows import distance_matrix
from .tetrahedralize import tetrahedralize
from .tolerances import Tolerances, tolerances
from .viewer import show

__version__ = "0.1.0"

__all__ = ["Mesh", "MeshError", "load_mesh", "data_path", "boundary_vertices", "Operators", "build_operators",
           "DistanceSolver", "DistanceResult", "ConvergenceWarning", "REGULARIZERS", "line_field",
           "all_pairs", "AllPairsResult", "distance_matrix", "save_vtu", "metrics",
           "Tolerances", "tolerances", "PenaltySchedule", "tetrahedralize", "WorkerError", "show", "__version__"]
