"""One block of distance-matrix rows from one batched single-source solve (here or on a Dask worker)."""

from __future__ import annotations

import warnings

from ..errors import ConvergenceWarning

__all__ = ["solve_rows"]


def solve_rows(solver, sources):
    """Rows (len(sources), n) in the solver's dtype from one batched ADMM, and its warning messages.

    A solve stopped by Ctrl-C raises KeyboardInterrupt: its unfinished rows are never stored.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        res = solver.solve_many([[s] for s in sources])
    if res.interrupted:
        raise KeyboardInterrupt
    rows = res.distance.T.astype(solver.dtype)
    for w in caught:
        if not issubclass(w.category, ConvergenceWarning):
            warnings.warn(w.message, w.category, stacklevel=2)
    return rows, [str(w.message) for w in caught if issubclass(w.category, ConvergenceWarning)]
