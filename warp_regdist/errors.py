"""The package's exceptions and warnings, in one module that imports nothing of the package."""

from __future__ import annotations

from scipy.optimize import OptimizeWarning

__all__ = ["MeshError", "ConvergenceWarning", "WorkerError"]


class MeshError(ValueError):
    """A mesh (file or arrays) that cannot be used, with the reason in the message."""


class ConvergenceWarning(OptimizeWarning):
    """An ADMM run stopped at its iteration cap before meeting its stopping test, or returned a
    result that breaks |grad u| <= 1; the result says so (``converged`` False)."""


class WorkerError(RuntimeError):
    """A worker process raised (the message holds its traceback) or died (which worker, how)."""
