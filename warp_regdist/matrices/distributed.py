"""Blocks of distance-matrix rows as tasks on a Dask cluster (``dask.distributed``).

The mesh is the result of one task that every block depends on: a worker fetches it once,
and where the workers holding it die the scheduler runs that task again (scattered data
would be lost with them, and the blocks that need it cancelled). Each worker process builds
one :class:`DistanceSolver` (one CPU thread) for the problem on its first task and keeps it
for the next ones; a task solves one block of sources as one batched ADMM and returns its
(len(block), n) rows. Warp's CPU launches must not interleave between threads of a process,
so a worker runs one block at a time whatever its thread count (start workers with one
thread each and as many processes as cores). The scheduler runs the tasks of a worker that dies
again elsewhere. Needs
``pip install 'warp-regdist[distributed]'``.
"""

from __future__ import annotations

import threading
import warnings

import numpy as np

from .matrix_store import average_source_pairs
from ..errors import ConvergenceWarning
from ..solvers.single_source.solver import DistanceSolver
from .row_solves import solve_rows

__all__ = ["check_client", "solve_blocks", "lazy_matrix"]

_LOCK = threading.Lock()  # one solve at a time per worker process
_SOLVER = [None]  # this worker process's (problem key, solver)


def check_client(client):
    """ValueError unless ``client`` is a ``dask.distributed.Client``."""
    try:
        from distributed import Client
    except ImportError as exc:
        raise ImportError("a client needs dask.distributed: pip install 'warp-regdist[distributed]'") from exc
    if not isinstance(client, Client):
        raise ValueError(f"expected client as a dask.distributed.Client or None, got {type(client).__name__}")


def _solve_block(mesh, key, problem, sources):
    """(rows, ConvergenceWarning messages) of one block, with this process's cached solver."""
    with _LOCK:
        if _SOLVER[0] is None or _SOLVER[0][0] != key:
            _SOLVER[0] = None  # free the previous problem's solver before building the next
            _SOLVER[0] = (key, DistanceSolver(mesh, workers=1, **problem))
        return solve_rows(_SOLVER[0][1], sources)


def _problem_key(mesh, problem):
    return (mesh.sha256(), *sorted(problem.items()))


def solve_blocks(client, mesh, problem, blocks):
    """Yield (block, rows, messages) as the tasks for ``blocks`` ({block: sources}) finish.

    Closing the generator (an exception or Ctrl-C in the caller) cancels the tasks left.
    """
    from distributed import as_completed

    if not blocks:
        return
    key = _problem_key(mesh, problem)
    mesh_future = _mesh_task(client, mesh)
    futures = {client.submit(_solve_block, mesh_future, key, problem, sources, pure=False): block
               for block, sources in blocks.items()}
    try:
        for future in as_completed(futures):
            rows, messages = future.result()
            block = futures.pop(future)
            future.release()
            yield block, rows, messages
    finally:
        client.cancel(list(futures))


def _mesh_task(client, mesh):
    """A future of ``mesh`` computed by a task (recomputed if every worker holding it dies)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Large object")   # the mesh is meant to travel once
        return client.submit(_same, mesh, pure=False)


def _same(value):
    return value


def _block_rows(mesh, key, problem, sources):
    rows, messages = _solve_block(mesh, key, problem, sources)
    for message in messages:
        warnings.warn(message, ConvergenceWarning, stacklevel=2)
    return rows


def _symmetric_block(rows, sources, s, lo, hi):
    return average_source_pairs(rows.copy(), sources, s[lo:hi], s[:, lo:hi])


def lazy_matrix(client, mesh, problem, sources, chunk, symmetrize):
    """The (k, n) matrix as a lazy dask array of (chunk, n) row blocks.

    With ``symmetrize`` the source columns S = D[:, sources] (k, k) are gathered in one task.
    """
    import dask
    import dask.array as da

    key = _problem_key(mesh, problem)
    mesh_future = _mesh_task(client, mesh)
    k, n = len(sources), mesh.n_vertices
    bounds = [(lo, min(k, lo + chunk)) for lo in range(0, k, chunk)]
    blocks = [dask.delayed(_block_rows, pure=True)(mesh_future, key, problem, sources[lo:hi]) for lo, hi in bounds]
    if symmetrize:
        s = dask.delayed(np.concatenate)([b[:, sources] for b in blocks])
        blocks = [dask.delayed(_symmetric_block)(b, sources, s, lo, hi) for b, (lo, hi) in zip(blocks, bounds)]
    return da.concatenate([da.from_delayed(b, shape=(hi - lo, n), dtype=problem["dtype"])
                           for b, (lo, hi) in zip(blocks, bounds)])
