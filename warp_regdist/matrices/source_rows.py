"""Distance matrices from batched single-source solves (the cheaper alternative to all pairs).

Row r of the result is the single-source regularized distance (Algorithm 1) from vertex
``sources[r]``. The rows are solved in blocks of ``chunk`` sources, each block one batched
ADMM (:meth:`DistanceSolver.solve_many`): here, or as tasks on a Dask cluster
(:mod:`warp_regdist.matrices.distributed`). Blocks go to memory or, with ``out``, to a Zarr array or
a ``.npy`` file, resumably (:mod:`warp_regdist.matrices.matrix_store`). The rows are not
symmetric (d(x, y) != d(y, x) for alpha > 0); ``symmetrize`` averages the two values of
every pair of source vertices, as the paper does for its "symmetrized fixed-source"
comparison. Unlike :func:`~warp_regdist.all_pairs`, no constraint couples the rows, so this
is no minimizer of the all-pairs problem.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from . import distributed
from ..arguments import check_weight, parse_device, parse_workers
from ..kernels.lanes import SCALARS
from .matrix_store import open_rows
from ..geometry.mesh import Mesh
from ..geometry.boundary_refinement import refine_boundary
from ..geometry.surface_points import check_surface_points, refine
from ..errors import ConvergenceWarning
from .row_solves import solve_rows
from ..options import SolverOptions
from ..solvers.single_source.solver import DistanceSolver

__all__ = ["distance_matrix"]


def distance_matrix(mesh: Mesh, alpha_hat: float = 0.05, sources: ArrayLike | None = None, symmetrize: bool = True,
                    device: str | None = None, dtype: str = "float64", chunk: int = 64, workers: int | None = None,
                    client: object = None, out: str | os.PathLike | None = None,
                    progress: Callable[[int, int, float], object] | None = None, points: ArrayLike | None = None,
                    options: SolverOptions | None = None) -> np.ndarray:
    """Single-source distances from many vertices, stacked as rows.

    Parameters
    ----------
    mesh : Mesh
    alpha_hat : float
        Scale-invariant regularization weight >= 0 of each single-source problem (default
        0.05, as :class:`DistanceSolver`). The all-pairs problem counts the Dirichlet energy
        of a symmetric U twice, so its rows are closest to single-source rows at 2 alpha_hat.
    sources : (k,) array_like of int or None
        Distinct source vertices, one row each; None: all vertices (k = n), unless ``points``.
    points : list of (face, (b0, b1, b2)) or None
        Landmarks anywhere on a triangle mesh instead of ``sources`` (e.g. from
        :func:`~warp_regdist.surface_points`), one row each: they are inserted into one refined mesh
        (as in :meth:`DistanceSolver.solve`) and the rows hold the distances at this mesh's n
        vertices. ``symmetrize`` does not apply (no landmark is a column).
    symmetrize : bool
        Replace D[r, sources[c]] and D[c, sources[r]] by their mean for every pair of rows,
        so the (k, k) block of source columns (all of D when sources is None) is symmetric.
    device, dtype
        As for :class:`DistanceSolver`; the matrix has the solver's dtype.
    chunk : int
        Rows per block (at most the number of rows): one batched ADMM, one Dask task, one stored
        block (memory grows linearly with it).
    workers : int or None
        CPU workers of the local solver, as for :class:`DistanceSolver` (each block is split
        among them); with a client each task runs on one core of its Dask worker.
    client : dask.distributed.Client or None
        Solve the blocks as tasks on this cluster (needs ``pip install 'warp-regdist[distributed]'``);
        the mesh goes once to every worker, which builds its solver once.
    out : str, path or None
        Write the matrix to this ``.zarr`` (Zarr array, chunks of (chunk, n), NaN where not yet
        written; needs zarr) or ``.npy`` (0 where not yet written) path, block by block,
        never holding the whole matrix in memory. Run again with the same arguments, it skips
        the blocks already written; a path holding another problem, a damaged or foreign file,
        or a path another run is writing (its ``.lock`` is held) is refused.
    progress : callable or None
        ``progress(blocks_done, blocks_total, seconds)`` after each block is stored (and once
        at the start, counting the blocks found done).
    options : SolverOptions or None
        The settings of every row's solve (None: the defaults); they travel with the tasks to a
        cluster's workers and are part of the fingerprint of ``out``.

    Returns
    -------
    (k, n) ndarray, or the Zarr array / ``.npy`` memory map ``out``, or with a client and no
    ``out`` a lazy dask array of (chunk, n) blocks (compute or persist it)
        D[r, i] = distance from sources[r] to vertex i (+inf where unreachable).
    """
    if not isinstance(mesh, Mesh):
        raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
    alpha_hat = check_weight(alpha_hat, "alpha_hat")
    if dtype not in SCALARS:
        raise ValueError(f"expected dtype 'float64' or 'float32', got {dtype!r}")
    if not isinstance(symmetrize, (bool, np.bool_)):
        raise ValueError(f"expected symmetrize as True or False, got {symmetrize!r}")
    if isinstance(chunk, (bool, np.bool_)) or not (isinstance(chunk, (int, np.integer)) and chunk >= 1):
        raise ValueError(f"expected chunk as an integer >= 1, got {chunk!r}")
    parse_workers(workers)
    if progress is not None and not callable(progress):
        raise ValueError(f"expected progress as a callable or None, got {progress!r}")
    n = mesh.n_vertices
    landmarks = None
    if points is not None:
        if sources is not None:
            raise ValueError("expected sources or points, got both")
        landmarks, sources, points_sha256 = _landmarks(mesh, points)
        symmetrize = False
    src = np.arange(n) if sources is None else np.asarray(sources)
    if src.ndim != 1 or src.size == 0 or not np.issubdtype(src.dtype, np.integer):
        raise ValueError(f"expected sources as a non-empty 1-D array of vertex indices, got {sources!r}")
    if np.unique(src).size != src.size:
        raise ValueError(f"expected distinct source vertices, got {src.size - np.unique(src).size} repeated")
    if landmarks is None and (src.min() < 0 or src.max() >= n):
        raise ValueError(f"expected sources in [0, {n - 1}], got {src.min() if src.min() < 0 else src.max()}")
    src = src.astype(np.int64)
    chunk = int(min(chunk, src.size))          # one block holds every row
    if options is not None and not isinstance(options, SolverOptions):
        raise ValueError(f"expected options as a SolverOptions or None, got {type(options).__name__}")
    options = SolverOptions() if options is None else options
    problem: dict[str, Any] = dict(alpha_hat=alpha_hat, device=device, dtype=dtype, options=options)
    if client is None:
        parse_device(device)                   # refused before the output is created
    if client is not None:
        distributed.check_client(client)
        if out is None:
            if progress is not None:
                raise ValueError(f"expected progress=None for a lazy dask array (client without out), got {progress!r}")
            lazy = distributed.lazy_matrix(client, mesh if landmarks is None else landmarks, problem, src, chunk, symmetrize)
            return lazy if landmarks is None else lazy[:, :n]
    fingerprint = dict(mesh_sha256=mesh.sha256(), n=int(n), alpha_hat=alpha_hat, dtype=dtype,
                       sources_sha256=hashlib.sha256(src.tobytes()).hexdigest(), k=int(src.size), chunk=chunk,
                       symmetrize=bool(symmetrize), options={f.name: _recorded(getattr(options, f.name))
                                                             for f in dataclasses.fields(options)})
    if landmarks is not None:
        fingerprint["points_sha256"] = points_sha256
    with open_rows(out, (src.size, n), chunk, dtype, fingerprint) as store:
        todo = store.todo()
        blocks = {b: src[b * chunk:(b + 1) * chunk] for b in todo}
        solve_on = mesh if landmarks is None else landmarks
        if client is not None:
            solved = distributed.solve_blocks(client, solve_on, problem, blocks)
        else:
            solved = _solve_blocks_here(DistanceSolver(solve_on, workers=workers, **problem), blocks) if blocks else iter(())
        t0 = time.perf_counter()
        done = store.blocks - len(todo)
        if progress is not None:
            progress(done, store.blocks, 0.0)
        for block, rows, messages in solved:
            for message in messages:
                warnings.warn(message, ConvergenceWarning, stacklevel=2)
            store.write(block, rows[:, :n], src if symmetrize else None)
            done += 1
            if progress is not None:
                progress(done, store.blocks, time.perf_counter() - t0)
        if symmetrize:
            store.symmetrize(src)
        return store.result()


def _recorded(value):
    """An options value as the fingerprint records it: a JSON number, bool or null as it is, else its repr."""
    return value if value is None or isinstance(value, (bool, int, float)) else repr(value)


def _landmarks(mesh, points):
    """Surface points -> (the refined mesh, their (k,) vertices on it, a SHA-256 of the points)."""
    faces, bary = check_surface_points(mesh, points, "points")
    R = refine(mesh, faces, bary) if mesh.element_dim == 2 else refine_boundary(mesh, faces, bary)
    vertices, first = np.unique(R.point_vertices, return_index=True)
    if vertices.size != len(faces):
        twice = np.setdiff1d(np.arange(len(faces)), first)[0]
        same = int(np.flatnonzero(R.point_vertices == R.point_vertices[twice])[0])
        raise ValueError(f"expected distinct points, got points {same} and {twice} at the same place (within "
                         "tolerances.point_snap)")
    digest = hashlib.sha256(faces.astype("<i8").tobytes() + bary.astype("<f8").tobytes()).hexdigest()
    return R.mesh, R.point_vertices, digest


def _solve_blocks_here(solver, blocks):
    for block, sources in blocks.items():
        yield (block, *solve_rows(solver, sources))
