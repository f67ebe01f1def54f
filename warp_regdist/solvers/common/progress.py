"""What a running solve reports to its ``callback``: one :class:`Progress` per test of its iterate."""

from __future__ import annotations

import dataclasses
import math

__all__ = ["Progress", "StopTest"]


@dataclasses.dataclass(frozen=True)
class StopTest:
    """One part of a stopping rule: it holds when ``value <= threshold`` (both in the test's own units)."""

    name: str
    value: float
    threshold: float

    @property
    def holds(self):
        return self.value <= self.threshold


@dataclasses.dataclass(frozen=True)
class Progress:
    """The state of a solve after ``iteration`` iterations, as its ``callback(progress)`` receives it.

    Attributes
    ----------
    iteration : int
    seconds : float
        Wall time since the solve began (a resumed run counts its earlier part too).
    tests : tuple of StopTest
        Every part of the stopping rule against its threshold; the solve stops when all hold (empty:
        the report all pairs makes before its setup).
    checked : bool
        Whether every test was measured at this iteration (some are measured once per window of
        iterations, and keep their last value in between).
    memory_bytes : int
        The solve's estimated footprint (0 where not estimated).
    columns, columns_done : int
        Columns of a batch and how many of them have stopped (the tests are those of the others).
    settling : bool
        All pairs: False once the change still to come has reached no new low for many checks
        (:class:`~warp_regdist.solvers.all_pairs.forecast.ChangeTrend`).
    """

    iteration: int
    seconds: float
    tests: tuple
    checked: bool = True
    memory_bytes: int = 0
    columns: int = 1
    columns_done: int = 0
    settling: bool = True

    @property
    def converged(self):
        """Whether every test holds (False without tests)."""
        return bool(self.tests) and all(t.holds for t in self.tests)

    def __str__(self):
        parts = []
        for t in self.tests:
            if math.isinf(t.threshold):
                continue
            mark = "" if t.holds else " (holding it back)"
            parts.append(f"{t.name} {_number(t.value)}/{_number(t.threshold)}{mark}")
        memory = f", {self.memory_bytes / 1e9:.2f} GB" if self.memory_bytes else ""
        batch = f"{self.columns_done}/{self.columns} columns done, " if self.columns > 1 else ""
        return (f"iteration {self.iteration}: {batch}{', '.join(parts)} (value/threshold); {self.seconds:.1f} s"
                f"{memory}")


def _number(x):
    return "inf" if math.isinf(x) else f"{x:.3g}"
