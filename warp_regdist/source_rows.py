"""Distance matrices from batched single-source solves (the cheaper alternative to all pairs).

Row r of the result is the single-source regularized distance (Algorithm 1) from vertex
``sources[r]``: solved as batched ADMMs of ``batch_size`` columns each by
:meth:`DistanceSolver.solve_many`, so the memory is that of one batch whatever the number
of rows. The rows are not symmetric (d(x, y) != d(y, x) for alpha > 0); ``symmetrize``
averages the two values of every pair of source vertices, as the paper does for its
"symmetrized fixed-source" comparison. Unlike :func:`~warp_regdist.all_pairs`, no
constraint couples the rows, so this is no minimizer of the all-pairs problem.
"""

from __future__ import annotations

import numpy as np

from .solver import DistanceSolver

__all__ = ["distance_matrix"]


def distance_matrix(mesh, alpha_hat=0.03, sources=None, symmetrize=True, device=None, dtype="float64",
                    batch_size=256, workers=None):
    """Single-source distances from many vertices, stacked as rows.

    Parameters
    ----------
    mesh : Mesh
    alpha_hat : float
        Scale-invariant regularization weight >= 0 of each single-source problem. (The
        all-pairs problem counts the Dirichlet energy of a symmetric U twice, so its rows
        are closest to single-source rows with 2 alpha_hat.)
    sources : (k,) array_like of int or None
        Distinct source vertices, one row each; None: all vertices (k = n).
    symmetrize : bool
        Replace D[r, sources[c]] and D[c, sources[r]] by their mean for every pair of rows,
        so the (k, k) block of source columns (all of D when sources is None) is symmetric.
    device, dtype, workers
        As for :class:`DistanceSolver` (each batch is split among ``workers`` CPU threads).
    batch_size : int
        Sources per batched ADMM (memory grows linearly with it).

    Returns
    -------
    (k, n) ndarray of float64
        D[r, i] = distance from sources[r] to vertex i (+inf where unreachable).
    """
    if not isinstance(symmetrize, (bool, np.bool_)):
        raise ValueError(f"expected symmetrize as True or False, got {symmetrize!r}")
    if not (isinstance(batch_size, (int, np.integer)) and batch_size >= 1):
        raise ValueError(f"expected batch_size as an integer >= 1, got {batch_size!r}")
    solver = DistanceSolver(mesh, alpha_hat=alpha_hat, device=device, dtype=dtype, workers=workers)
    n = mesh.n_vertices
    if sources is None:
        sources = np.arange(n)
    src = np.asarray(sources)
    if src.ndim != 1 or src.size == 0 or not np.issubdtype(src.dtype, np.integer):
        raise ValueError(f"expected sources as a non-empty 1-D array of vertex indices, got {sources!r}")
    if np.unique(src).size != src.size:
        raise ValueError(f"expected distinct source vertices, got {src.size - np.unique(src).size} repeated")
    rows = np.empty((src.size, n))
    for start in range(0, src.size, batch_size):
        batch = src[start:start + batch_size]
        rows[start:start + batch.size] = solver.solve_many([[s] for s in batch]).distance.T
    if symmetrize:
        block = rows[:, src]
        rows[:, src] = 0.5 * (block + block.T)
    return rows
