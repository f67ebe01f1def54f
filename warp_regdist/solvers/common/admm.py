"""The ADMM engine shared by DistanceSolver and AllPairsSolver (docs/method.md section 8): the loop
:func:`run_iterations` over an :class:`AdmmProblem`, and the penalty schedule :class:`PenaltySchedule`.

The stopping rule is :mod:`warp_regdist.solvers.common.stopping`; both solvers build their schedule from
their options (``rho0``, ``rho_max``, ``rho_doubling``) unless the options carry a ``schedule``,
any object with ``rho(k)`` and ``offset_for(penalty)``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Protocol

import numpy as np

from . import interrupt

__all__ = ["run_iterations", "AdmmProblem", "CONVERGED", "MAX_ITERATIONS", "INTERRUPTED", "PenaltySchedule"]

CONVERGED, MAX_ITERATIONS, INTERRUPTED = "converged", "max_iterations", "interrupted"
"""Why :func:`run_iterations` stopped."""


class AdmmProblem(Protocol):
    """What :func:`run_iterations` drives."""

    def status(self, it: int) -> bool:
        """Whether the iterate after ``it`` iterations passes its stopping test (read from the device; it
        may also collect finished columns, record history, report progress)."""

    def advance(self, it: int, count: int) -> None:
        """Iterations it .. it + count - 1 on the device, ending with the device work of the next test."""


def run_iterations(problem, start, max_iterations, check_every=1, poll=None):
    """The ADMM loop: from iteration ``start``, test, then advance ``check_every`` iterations at a time.

    Stops at the first passing test, at ``max_iterations`` (the last advance is shortened to end
    there), or at a Ctrl-C caught by :func:`warp_regdist.solvers.common.interrupt.catch_interrupt` (checked
    before each test: an interrupted run returns after the advance under way, untested). ``poll``,
    when given, is called before each test and may raise to end the run (the solvers check their
    worker processes there).

    Returns
    -------
    iterations : int
    reason : CONVERGED, MAX_ITERATIONS or INTERRUPTED
    """
    it = start
    while True:
        if poll is not None:
            poll()
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
    def of(cls, options, scale, factors=(1.0, 1.0, 1.0)):
        """The schedule of a solver's ``options``: their ``schedule`` when they carry one, else rho0,
        rho_max and rho_doubling times ``factors`` (the regularizer's ``schedule_factors``), the
        penalties in units of ``scale``."""
        if options.schedule is not None:
            return options.schedule
        return cls(factors[0] * options.rho0, factors[1] * options.rho_max, factors[2] * options.rho_doubling, scale)
