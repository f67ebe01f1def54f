"""The package's exceptions and warnings, in one module that imports nothing of the package."""

from __future__ import annotations

from scipy.optimize import OptimizeWarning

__all__ = ["MeshError", "MeshWarning", "ConvergenceWarning", "CheckpointWarning", "WorkerError", "WriteError"]


class MeshError(ValueError):
    """A mesh (file or arrays) that cannot be used, with the reason in the message."""


class MeshWarning(UserWarning):
    """A mesh that can be used but probably not as meant (vertices at one position), or that was
    repaired on loading; the message says what and how to fix it."""


class ConvergenceWarning(OptimizeWarning):
    """An ADMM run stopped at its iteration cap before meeting its stopping test, or returned a
    result that breaks |grad u| <= 1; the result says so (``converged`` False)."""


class CheckpointWarning(RuntimeWarning):
    """A checkpoint could not be written (full disk, no permission); the run went on, and the last
    checkpoint written stays valid."""


class WorkerError(RuntimeError):
    """A worker process raised (the message holds its traceback) or died (which worker, how)."""


class WriteError(OSError):
    """An output file that could not be written (full disk, no permission): the message names the
    path, the cause and the space needed and free; an existing file at the path is unchanged.
    ``errno`` is the cause's error number."""

    def __init__(self, message, errno=None):
        super().__init__(message)
        self.errno = errno
