"""The all-pairs engines: what the package knows of each before a run (``ENGINES``: its penalties, its
memory model; :func:`choose_engine`: the size rule of "auto"), and what
:class:`~warp_regdist.solvers.all_pairs.run.PairsRun` needs of an engine's state: the :class:`PairsEngine`
Protocol that :class:`~warp_regdist.solvers.all_pairs.state.SymmetricADMM` (the consensus engine) and
:class:`~warp_regdist.solvers.all_pairs.eigenbasis.EigenbasisADMM` implement.

One iteration is ``linear_and_element_steps`` (the consensus engine's X-step PCG, or the eigenbasis
engine's exact U-step, then the fused z/y element step) and ``coupling_step`` (the consensus engine's
U/H-step; nothing in the eigenbasis engine, whose U is symmetric by construction), at the penalties of
``set_penalties``; the run reads the residuals' sums they return and the state arrays by name.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["EngineKind", "ENGINES", "FINE_ACCURACY", "choose_engine", "PairsEngine"]


@dataclasses.dataclass(frozen=True)
class EngineKind:
    """One engine of ``ENGINES``.

    Attributes
    ----------
    penalties : (rho0, rho_max, rho_doubling)
        Its penalty schedule (units of L) where the options leave those fields None.
    array_bytes : callable
        ``array_bytes(n, m, itemsize, cols)`` -> (device bytes, host bytes beyond the result and the
        change test's copies) of its state, cols = n padded to whole lanes
        (:func:`~warp_regdist.solvers.all_pairs.memory.memory_estimate` adds the rest).
    fine_rho_max : float or None
        Its rho_max at accuracies below ``FINE_ACCURACY`` (None: ``penalties``' at every accuracy).
    """

    penalties: tuple[float, float, float]
    array_bytes: Callable[[int, int, int, int], tuple[int, int]]
    fine_rho_max: float | None = None

    def penalties_at(self, accuracy):
        """(rho0, rho_max, rho_doubling) of a run at ``accuracy``."""
        rho0, rho_max, doubling = self.penalties
        if self.fine_rho_max is not None and accuracy < FINE_ACCURACY * (1 - 1e-9):  # 0.01 itself after eps_change / 0.7
            rho_max = self.fine_rho_max
        return rho0, rho_max, doubling


FINE_ACCURACY = 0.01
"""The accuracy below which an engine's ``fine_rho_max`` applies."""


ENGINES = {
    # X, U, H, DZ, rhs, D Z, D Y (7), the PCG's r, z, p, q (4) and mask, the multigrid levels (counted as n),
    # the z/y state (3 m columns' worth)
    "consensus": EngineKind((0.5, 8.0, 30.0), lambda n, m, size, cols: (size * cols * (13 * n + 3 * m), 0)),
    # U, H, DZ, the divergences and max(U, 0) for the steepness test (6) and the z/y state; on the host the
    # U-step's Phi, 1 / (lam_p + lam_q)
    # and four temporaries, its right-hand side, a temporary and A_V A_V^T, its bordered LU (float64) and its
    # result in lanes
    "eigenbasis": EngineKind((2.0, 32.0, 100.0), lambda n, m, size, cols: (
        size * cols * (6 * n + 3 * m), size * 9 * n * n + 8 * (n + 1) ** 2 + size * n * cols), fine_rho_max=64.0),
}
"""The engines by name. The eigenbasis engine's U-step is exact at any penalty and converges sooner on a
schedule four times higher and three times slower, and below accuracy 0.01 with a cap twice as high, which
ends the plateaus where a few pairs' multipliers drift sooner (docs/design/all-pairs.md)."""


def choose_engine(engine, n, on_cpu, eigenbasis_max_vertices):
    """The engine that option ``engine`` takes on an n-vertex mesh: itself, or for "auto" "eigenbasis" on the
    CPU up to ``eigenbasis_max_vertices`` vertices and "consensus" otherwise (the eigenbasis U-step costs
    O(n^3) an iteration on the host, the consensus engine's O(n^2))."""
    if engine != "auto":
        return engine
    return "eigenbasis" if on_cpu and n <= eigenbasis_max_vertices else "consensus"


@runtime_checkable
class PairsEngine(Protocol):
    """The state of one all-pairs run on an engine.

    Attributes
    ----------
    engine : str
        "consensus" or "eigenbasis".
    n, m : int
        Vertices and elements.
    A, L : float
        Total area and its square root (the length scale).
    column_area : (nb W,) ndarray
        A_V per column, 0 on the padding lanes.
    setup : object
        The run's setup (``vertex_volumes``, lane counts ``nb`` and ``W``, the constraints).
    penalties : tuple of float
        (rho, rho2) of the last ``set_penalties``.
    rho_v : float
        The penalty that formed the element state v (a checkpoint records it).
    change_rate_cap : float
        The engine's q_max of the change test.
    """

    engine: str
    n: int
    m: int
    A: float
    L: float
    column_area: np.ndarray
    setup: object
    penalties: tuple
    rho_v: float
    change_rate_cap: float

    def set_penalties(self, rho: float, rho2: float) -> None:
        """The penalties of the next iteration."""
        ...

    def right_hand_side(self) -> tuple:
        """Prepare the linear step; (|D (Z - Z_old)|^2, |D Y|^2) per column (nb W,) for the dual residual."""
        ...

    def linear_and_element_steps(self, atol: np.ndarray, rtol: float, max_iterations: int) -> int:
        """The linear step (PCG to ``atol`` per column, ``rtol``, ``max_iterations``, or an exact solve) and the
        element step; the PCG iterations (0 without PCG)."""
        ...

    def coupling_step(self) -> tuple:
        """The step that couples the columns and rows (or none); (per-column R2, G2, Z2 sums (3, nb W), pair
        sums (5,)) of this iteration."""
        ...

    def load(self, saved: Mapping, names: tuple) -> None:
        """State arrays ``names`` and ``rho_v`` from a checkpoint's ``saved`` arrays (X's diagonal at 0)."""
        ...

    def view(self, name: str) -> np.ndarray:
        """State array ``name`` as numpy (lanes last)."""
        ...

    def put(self, name: str, values: np.ndarray) -> None:
        """Write state array ``name``."""
        ...

    def distance(self) -> np.ndarray:
        """max(U, 0) (n, n) float64."""
        ...

    def gradient_excess(self, top: float) -> float:
        """U's steepness beyond its constraint relative to ``top``."""
        ...

    def divergences_from_element_state(self) -> None:
        """D Z and D Y recomputed from v (after a warm start)."""
        ...

    def close(self) -> None:
        """End the worker processes, if any."""
        ...
