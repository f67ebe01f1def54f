"""warp-regdist: regularized geodesic distances on triangle and tetrahedral meshes.

Implements Edelstein, Guillen, Solomon, Ben-Chen, "A Convex Optimization Framework for
Regularized Geodesic Distances" (SIGGRAPH 2023) with Warp kernels (CPU and CUDA).
"""

from . import metrics
from .mesh import Mesh, MeshError, boundary_vertices, load_mesh
from .operators import Operators, build_operators
from .solver import ConvergenceWarning, DistanceResult, DistanceSolver
from .tolerances import Tolerances, tolerances

__version__ = "0.1.0"

__all__ = ["Mesh", "MeshError", "load_mesh", "boundary_vertices", "Operators", "build_operators",
           "DistanceSolver", "DistanceResult", "ConvergenceWarning", "Tolerances", "tolerances", "metrics", "__version__"]
