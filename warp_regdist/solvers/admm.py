"""The ADMM engine shared by DistanceSolver and all_pairs (docs/method.md section 8): the loop
:func:`run_iterations` and its swappable parts.

:func:`run_iterations` drives a problem that supplies ``status(it)`` (the tests of its iterate
after ``it`` iterations, read from the device) and ``advance(it, count)`` (``count`` iterations
on the device, ending with the device work of the next test). :class:`PenaltySchedule` is the
penalty rho at iteration k; the stopping rule is :mod:`warp_regdist.solvers.stopping`. Both solvers build
them from :data:`warp_regdist.tolerances` (overridable per call with ``tolerances.override``);
``DistanceSolver.solve``, ``solve_many`` and ``all_pairs`` take ``schedule=`` to swap the
schedule for a :class:`PenaltySchedule` or any object with ``rho(k)`` and ``offset_for(penalty)``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from . import interrupt
from .processes import check_workers

__all__ = ["run_iterations", "CONVERGED", "MAX_ITERATIONS", "INTERRUPTED", "PenaltySchedule", "check_schedule"]

CONVERGED, MAX_ITERATIONS, INTERRUPTED = "converged", "max_iterations", "interrupted"
"""Why :func:`run_iterations` stopped."""


def run_iterations(problem, start, max_iterations, check_every=1):
    """The ADMM loop: from iteration ``start``, test, then advance ``check_every`` iterations at a time.

    ``problem.status(it)`` returns True when the iterate after ``it`` iterations passes its
    stopping test (it may also collect finished columns, record history, report progress);
    ``problem.advance(it, count)`` runs iterations it .. it + count - 1 and the device work of the
    next test. The loop stops at the first passing test, at ``max_iterations`` (the last advance
    is shortened to end there), or at a Ctrl-C caught by :func:`warp_regdist.solvers.interrupt.catch_interrupt`
    (checked before each test: an interrupted run returns after the advance under way, untested).
    Before each test it also raises :class:`~warp_regdist.errors.WorkerError` if a worker
    process of this process has died.

    Returns
    -------
    iterations : int
    reason : CONVERGED, MAX_ITERATIONS or INTERRUPTED
    """
    it = start
    while True:
        check_workers()
        if interrupt.requested():
            return it, INTERRUPTED
        if problem.status(it):
            return it, CONVERGED
        if it >= max_iterations:
            return it, MAX_ITERATIONS
        count = min(check_every, max_iterations - it)
        problem.advance(it, count)
        it += count


@dataclasses.dataclass(frozen=True)
class PenaltySchedule:
    """rho(k) = scale min(rho_max, rho0 2^(k / doubling)) at iteration k = 0, 1, ...

    ``rho0`` and ``rho_max`` are in units of ``scale`` (the length scale L = sqrt(A) in both
    solvers); ``doubling`` = inf gives the constant penalty scale rho0. The penalty of the
    ADMM's iteration k (loop index, the first is 0) is ``rho(k + offset)``, offset = 0 from a
    cold start and ``offset_for(penalty)`` from a warm start that carries ``penalty``.
    """

    rho0: float
    rho_max: float
    doubling: float
    scale: float

    def __post_init__(self):
        for name in ("rho0", "rho_max", "doubling", "scale"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float, np.integer, np.floating)) and value > 0
                    and (math.isfinite(value) or name == "doubling")):
                raise ValueError(f"expected PenaltySchedule {name} as a finite number > 0"
                                 f"{' (or inf)' if name == 'doubling' else ''}, got {value!r}")

    def rho(self, k):
        """The penalty at iteration k (float k allowed: a warm start's continuation); the exponent is
        capped at 1000 doublings, far past rho_max, so that no iteration count overflows."""
        return self.scale * min(self.rho_max, self.rho0 * 2.0 ** min(k / self.doubling, 1000.0))

    def offset_for(self, penalty):
        """The k >= 0 at which rho(k) = penalty (absolute, as ``rho(k)``): the schedule a warm
        start continues; 0 for a penalty at or below scale rho0, and for a constant schedule."""
        if math.isinf(self.doubling):
            return 0.0
        return max(0.0, self.doubling * math.log2(penalty / self.scale / self.rho0))

    @classmethod
    def single_source(cls, tol, rho_factors, scale):
        """DistanceSolver's schedule: ``tol.rho0``, ``tol.rho_max`` times the regularizer's
        ``rho_factors`` (f0, f1), doubling every ``tol.rho_doubling`` iterations."""
        return cls(rho_factors[0] * tol.rho0, rho_factors[1] * tol.rho_max, tol.rho_doubling, scale)

    @classmethod
    def all_pairs(cls, tol, scale):
        """all_pairs' schedule: ``tol.rho0``, ``tol.pairs_rho_max``, ``tol.pairs_rho_doubling``."""
        return cls(tol.rho0, tol.pairs_rho_max, tol.pairs_rho_doubling, scale)


def check_schedule(schedule):
    """``schedule`` itself when it has callable ``rho`` and ``offset_for``; ValueError otherwise."""
    if not (callable(getattr(schedule, "rho", None)) and callable(getattr(schedule, "offset_for", None))):
        raise ValueError(f"expected schedule as a PenaltySchedule or an object with rho(k) and offset_for(penalty), "
                         f"got {type(schedule).__name__}")
    return schedule
