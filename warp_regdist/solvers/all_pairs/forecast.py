"""What an all-pairs run will take: its iterations told before it starts (from the package's measured
sizes), its default cap, and a run that is not settling.

Before the run, the typical number of iterations at n vertices and accuracy e is interpolated in log n
through ``MEASURED_ITERATIONS`` (docs/data/all_pairs_sizes.csv, accuracy 0.01, float32) and scaled by
sqrt(0.01 / e); the mesh's own triangles move it by a factor of about 2 either way
(docs/guides/all-pairs.md). A run whose change still to come (:class:`ExtrapolatedChangeTest`) has
reached no new low for many checks is not settling (:class:`ChangeTrend`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

__all__ = ["MEASURED_ITERATIONS", "MIN_CAP", "STALL_CHECKS", "RunForecast", "typical_iterations", "default_cap",
           "with_cap", "ChangeTrend"]

MEASURED_ITERATIONS = ((300, 1100), (600, 1750), (999, 2300), (1949, 2600))
"""(vertices, iterations) of docs/data/all_pairs_sizes.csv: cat_rr decimated, accuracy 0.01, float32."""

MIN_CAP = 3000
"""The smallest default iteration cap."""

STALL_CHECKS = 8
"""The fewest checks (change windows) without a new low of the change still to come after which a run is
said not to be settling (and the low must lie in the first third of its iterations)."""


def typical_iterations(n, accuracy):
    """Iterations typical of an n-vertex mesh at ``accuracy``: ``MEASURED_ITERATIONS`` interpolated in
    log n (extended along its last segment), times sqrt(0.01 / accuracy); to the nearest multiple of 50."""
    sizes, counts = (np.log([float(v) for v, _ in MEASURED_ITERATIONS]),
                     np.log([float(c) for _, c in MEASURED_ITERATIONS]))
    x = math.log(max(int(n), 2))
    if x <= sizes[-1]:
        y = float(np.interp(x, sizes, counts))
    else:
        y = counts[-1] + (counts[-1] - counts[-2]) / (sizes[-1] - sizes[-2]) * (x - sizes[-1])
    return int(50 * round(math.exp(y) * math.sqrt(0.01 / accuracy) / 50))


def default_cap(n, accuracy):
    """The iteration cap of a run that sets none: twice :func:`typical_iterations`, at least ``MIN_CAP``."""
    return max(MIN_CAP, 2 * typical_iterations(n, accuracy))


def with_cap(n, options):
    """``options`` (AllPairsOptions) with max_iterations None replaced by :func:`default_cap` at their accuracy."""
    if options.max_iterations is not None:
        return options
    return options.replace(max_iterations=default_cap(n, min(options.accuracy, 0.1)))


@dataclasses.dataclass(frozen=True)
class RunForecast:
    """What a run of :meth:`~warp_regdist.AllPairsSolver.solve` will take, told before it starts.

    Attributes
    ----------
    vertices : int
    engine : str
        "eigenbasis" or "consensus".
    memory_bytes : int
        Estimated footprint of the run's arrays.
    iterations : int
        Typical iterations at this size and accuracy (:func:`typical_iterations`).
    max_iterations : int
        The run's cap.
    accuracy : float
        The accuracy the run's change test stands for (eps_change / 0.7).
    """

    vertices: int
    engine: str
    memory_bytes: int
    iterations: int
    max_iterations: int
    accuracy: float

    def __str__(self):
        return (f"{self.vertices} vertices, {self.engine} engine, about {self.memory_bytes / 1e9:.2f} GB; typically "
                f"{self.iterations} iterations at this size and accuracy {self.accuracy:.3g} (cap {self.max_iterations})")


class ChangeTrend:
    """The change still to come at each check of a run, and whether the run is settling.

    ``add(k, change)`` after every change test (change inf before the test has a rate). The change
    goes up and down from window to window for many windows before a run stops
    (docs/design/all-pairs.md), so ``stalled()`` looks at the whole run: whether its lowest change came
    at most a third of the way into it, at least STALL_CHECKS checks ago.
    """

    def __init__(self):
        self.iterations, self.changes = [], []

    def add(self, k, change):
        if math.isfinite(change) and change > 0.0:
            self.iterations.append(int(k))
            self.changes.append(float(change))

    def stalled(self):
        if len(self.changes) <= STALL_CHECKS:
            return False
        low = int(np.argmin(self.changes))
        return len(self.changes) - 1 - low >= STALL_CHECKS and 3 * self.iterations[low] <= self.iterations[-1]

    def lowest(self):
        """(iteration, change) of the lowest change so far."""
        j = int(np.argmin(self.changes))
        return self.iterations[j], self.changes[j]
