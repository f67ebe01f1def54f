"""The solvers' settings: one frozen options object per solver, its defaults in one place.

``DistanceSolver(mesh, options=SolverOptions(eps_rel=1e-4))`` and
``AllPairsSolver(mesh, options=AllPairsOptions.for_accuracy(0.01))`` take them whole;
``solve(..., max_iterations=500)`` overrides fields for one call; worker processes receive
the object itself. A name means the same in both classes (``eps_rel`` the relative primal
tolerance, ``rho_max`` the largest penalty in units of the length scale L = A^(1/d), ...);
only the defaults differ. All tolerances are dimensionless. How the defaults were chosen:
docs/architecture.md, "Stopping rule and penalty schedule".

The mesh-level tolerances (degenerate elements, snapping of points and curves) are not
solver settings: see :data:`warp_regdist.tolerances`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np

__all__ = ["SolverOptions", "AllPairsOptions", "DEFAULT_ACCURACY"]

DEFAULT_ACCURACY = 0.005
"""The max error, in units of the max distance, that the all-pairs residual tolerances were chosen for."""

_CHANGE_SHARE = 0.7
"""All pairs: eps_change = 0.7 x accuracy (chosen against exact minimizers and long runs:
docs/design/all-pairs.md)."""

_EXCESS_SHARE = 1.0
"""All pairs: eps_excess = accuracy."""


def _check_number(name, value, low=0.0, strict=False, infinite=False, integer=False):
    bound = f"{'>' if strict else '>='} {low:g}"
    kind = "an integer" if integer else "a number"
    ok = not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, np.integer) if integer else
                                                                  (int, float, np.integer, np.floating))
    if ok:
        v = float(value)
        ok = (math.isfinite(v) or (infinite and v == math.inf)) and (v > low if strict else v >= low)
    if not ok:
        raise ValueError(f"expected {name} as {kind} {bound}{' (or inf)' if infinite else ''}, got {value!r}")


class _Options:
    """What both options classes share: checks of every field and :meth:`replace`."""

    _INFINITE: ClassVar[tuple[str, ...]] = ()     # fields that may be inf (that test switched off)
    _POSITIVE: ClassVar[tuple[str, ...]] = ()     # fields that must be > 0 (the others >= 0)
    _INTEGERS: ClassVar[tuple[str, ...]] = ()     # fields that are integers >= 1
    _CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {}   # fields that take one of a few strings
    _OPTIONAL: ClassVar[tuple[str, ...]] = ()     # fields that may be None (a default chosen later)

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.name == "schedule":
                if value is not None and not (callable(getattr(value, "rho", None))
                                              and callable(getattr(value, "offset_for", None))):
                    raise ValueError(f"expected schedule as None, a PenaltySchedule or an object with rho(k) and "
                                     f"offset_for(penalty), got {type(value).__name__}")
            elif field.type == "bool" or isinstance(field.default, bool):
                if not isinstance(value, (bool, np.bool_)):
                    raise ValueError(f"expected {field.name} as True or False, got {value!r}")
            elif value is None and field.name in self._OPTIONAL:
                pass
            elif field.name in self._CHOICES:
                if not (isinstance(value, str) and value in self._CHOICES[field.name]):
                    raise ValueError(f"expected {field.name} as one of {', '.join(map(repr, self._CHOICES[field.name]))}, "
                                     f"got {value!r}")
            elif field.name == "check_every":
                if value is not None:
                    _check_number(field.name, value, 1, integer=True)
            elif field.name in self._INTEGERS:
                _check_number(field.name, value, 1, integer=True)
            else:
                _check_number(field.name, value, strict=field.name in self._POSITIVE,
                              infinite=field.name in self._INFINITE)

    def replace(self, **changes):
        """A copy with ``changes`` (field names; ValueError naming the fields for another name)."""
        names = [f.name for f in dataclasses.fields(self)]
        unknown = sorted(set(changes) - set(names))
        if unknown:
            raise ValueError(f"expected {type(self).__name__} fields among {names}, got {unknown}")
        return dataclasses.replace(self, **changes) if changes else self


@dataclasses.dataclass(frozen=True)
class SolverOptions(_Options):
    """Settings of :class:`~warp_regdist.DistanceSolver` (docs/method.md section 8).

    Attributes
    ----------
    eps_abs, eps_rel, eps_rel_dual : float
        Residual test: r <= sqrt(3m) eps_abs sqrt(A) + eps_rel max(|G u|, |z|) and
        s <= sqrt(n) eps_abs A + eps_rel_dual max(|D y|, |A_V|) (norms weighted by the areas).
    eps_change : float
        Change test, every ``change_window`` iterations: max |u_k - u_(k - window)| <= eps_change
        max |u_k| (inf: no change test).
    eps_estimate : float
        The ``error_estimate`` (the change still to come at each vertex's own rate of the last two
        windows, capped at 0.95 a window) must be at most this fraction of max u (inf: no such test).
    change_window : int
    max_iterations : int
        ADMM iteration cap (then a ConvergenceWarning and ``converged`` False).
    relaxation : float
        Over-relaxation of the z- and y-steps (Boyd et al. 2011, sec. 3.4.3).
    rho0, rho_max, rho_doubling : float
        The penalty schedule rho_k = L min(rho_max, rho0 2^(k / rho_doubling)) (the regularizer's
        factors apply: the Hessian's rho_max is 8 times larger; below alpha_hat 0.02 the Dirichlet and
        vector-field rho0 on triangles shrinks to 1/2 and rho_doubling grows to 2 times at alpha_hat 0).
    schedule : object or None
        Instead of the three above: a :class:`~warp_regdist.PenaltySchedule` or any object with
        ``rho(k)`` (absolute penalty, float k after a warm start) and ``offset_for(penalty)``;
        picklable when worker processes share the batch.
    cg_fraction, cg_primal_fraction, cg_rtol, cg_max_iterations
        The u-step's PCG stops below min(cg_fraction max(|D y|, |A_V|), eps_dual / 10,
        cg_primal_fraction r L^(d/2 - 1) (alpha + rho)), or below cg_rtol of the right-hand side,
        or after cg_max_iterations.
    max_gradient : float
        A result whose |grad u| relative to its bound (1, or on a source's own triangle the side
        lengths' wedge: ``source_triangles``) exceeds this on some element is reported as not converged.
    gradient_smoothing : float
        mu_hat of ``vjp`` and ``polish``: the barrier weight of the smoothed problem whose
        minimizer is differentiated (docs/method.md section 10).
    gradient_factorization : str
        The sparse factorization of ``vjp``'s and ``polish``'s Newton systems: "pardiso" (MKL
        PARDISO's Cholesky, threaded, the ``[pardiso]`` extra), "superlu" (scipy), or "auto"
        (PARDISO where it is installed).
    capture : bool
        On the CPU, replay each iteration as one captured Warp graph (False: the same launches one
        by one; the same numbers).
    check_every : int or None
        ADMM iterations between the host's reads of the per-column test state (None: 1 on the
        CPU, 10 on CUDA). The columns stop at the same iterate either way.
    cpu_blocks : int
        Lane blocks (of 8 float64 or 16 float32 columns) that one CPU batch runs at once; more run
        one batch after another, so that a block's arrays stay in the caches.
    """

    eps_abs: float = 0.0
    eps_rel: float = 1e-3
    eps_rel_dual: float = 0.5
    eps_change: float = 8e-4
    eps_estimate: float = 5e-3
    change_window: int = 10
    max_iterations: int = 10_000
    relaxation: float = 1.7
    rho0: float = 0.5
    rho_max: float = 4.0
    rho_doubling: float = 10.0
    schedule: object = None
    cg_fraction: float = 1e-3
    cg_primal_fraction: float = 0.01
    cg_rtol: float = 1e-10
    cg_max_iterations: int = 500
    max_gradient: float = 1.5
    gradient_smoothing: float = 1e-6
    gradient_factorization: str = "auto"
    capture: bool = True
    check_every: object = None
    cpu_blocks: int = 1

    _INFINITE: ClassVar[tuple[str, ...]] = ("eps_change", "eps_estimate", "rho_doubling")
    _POSITIVE: ClassVar[tuple[str, ...]] = ("eps_rel", "eps_rel_dual", "relaxation", "rho0", "rho_max", "rho_doubling", "cg_fraction",
                 "cg_primal_fraction", "cg_rtol", "max_gradient", "gradient_smoothing")
    _INTEGERS: ClassVar[tuple[str, ...]] = ("change_window", "max_iterations", "cg_max_iterations", "cpu_blocks")
    _CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"gradient_factorization": ("auto", "pardiso", "superlu")}


@dataclasses.dataclass(frozen=True)
class AllPairsOptions(_Options):
    """Settings of :class:`~warp_regdist.AllPairsSolver` (docs/method.md section 8).

    Attributes
    ----------
    eps_abs, eps_rel, eps_rel_consensus, eps_rel_dual : float
        The seven residuals' tests: r1 <= eps_rel max(|S_F G X S_V|, |S_F Z S_V|), rx1 <=
        eps_rel_consensus min(|S_V X S_V|, |S_V U S_V|), s1 <= eps_rel_dual max(|D Y M_V|,
        |A_V|^2 / 2), sx <= eps_rel_dual max(|S_V H S_V|, A / 2), plus eps_abs times the
        authors' absolute terms.
    eps_change : float
        Change test, every ``change_window`` iterations: with c_k = max |U_k - U_(k - window)| /
        max U_k and q = min(c_k / c_(k - window), 0.95), max(c_k / (1 - q), c_(k - window) min(k /
        window, 20)) <= eps_change: the change still to come at the slower of the last two windows'
        rate and 1 / k (inf: no change test).
    eps_excess : float
        Steepness test, at the same iterations: max over elements e and columns j of
        (|grad U_j|_e - 1)_+ diam(e) <= eps_excess max U, |grad U_j|_e relative to its bound (inf: no such test).
    change_window : int
    max_iterations : int or None
        ADMM iteration cap (then a ConvergenceWarning and ``converged`` False); None: twice the typical
        iterations at the mesh's size and accuracy, at least 3,000
        (:func:`~warp_regdist.solvers.all_pairs.forecast.default_cap`).
    relaxation : float
        Over-relaxation of all three steps.
    rho0, rho_max, rho_doubling : float or None
        rho_k = L min(rho_max, rho0 2^(k / rho_doubling)); None: the engine's own at the run's accuracy,
        ``ENGINES[engine].penalties_at(accuracy)`` of :mod:`warp_regdist.solvers.all_pairs.engine` (the eigenbasis
        engine's U-step is exact at any penalty and converges sooner on a schedule four times higher and three
        times slower, capped at 32 L from accuracy 0.01 and at 64 L below).
    rho2_factor : float
        The consensus penalty rho2 = rho2_factor rho^2 / (L A).
    schedule : object or None
        As in :class:`SolverOptions` (rho2 follows from rho2_factor). A checkpoint does not record
        it: resume with the same schedule.
    cg_fraction, cg_rtol, cg_max_iterations
        Each X-step's PCG stops at cg_fraction (|D Y_j| + |A_V| / 2) per column j.
    max_gradient : float
        A result whose |grad U| relative to its bound (as for :class:`SolverOptions`) exceeds this on some
        element and column is not converged.
    engine : {"auto", "eigenbasis", "consensus"}
        The splitting (docs/method.md section 5): "eigenbasis", U symmetric in the primal with an
        exact dense U-step (no PCG, no consensus; O(n^3) work an iteration and (n, n) eigenvectors);
        "consensus", Algorithm 2's splitting with PCG X-steps (O(n^2) work an iteration, worker
        processes); "auto": eigenbasis on the CPU up to ``eigenbasis_max_vertices`` vertices, consensus
        otherwise.
    eigenbasis_max_vertices : int
        The largest mesh on which ``engine="auto"`` takes the eigenbasis engine on the CPU: its dense U-step
        costs O(n^3) an iteration against the consensus engine's O(n^2), but it converges where the
        consensus engine creeps (docs/guides/all-pairs.md gives the measurements behind the default).
    """

    eps_abs: float = 0.0
    eps_rel: float = 5e-4
    eps_rel_consensus: float = 5e-5
    eps_rel_dual: float = 1e-2
    eps_change: float = _CHANGE_SHARE * DEFAULT_ACCURACY
    eps_excess: float = 5e-3
    change_window: int = 50
    max_iterations: int | None = None
    relaxation: float = 1.7
    rho0: float | None = None
    rho_max: float | None = None
    rho_doubling: float | None = None
    rho2_factor: float = 25.0
    schedule: object = None
    cg_fraction: float = 1e-3
    cg_rtol: float = 1e-10
    cg_max_iterations: int = 500
    max_gradient: float = 1.5
    engine: str = "auto"
    eigenbasis_max_vertices: int = 3000

    _INFINITE: ClassVar[tuple[str, ...]] = ("eps_change", "eps_excess", "rho_doubling")
    _CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"engine": ("auto", "eigenbasis", "consensus")}
    _OPTIONAL: ClassVar[tuple[str, ...]] = ("rho0", "rho_max", "rho_doubling", "max_iterations")

    def for_engine(self, engine):
        """These options with ``engine`` ("eigenbasis" or "consensus") and its penalties at their accuracy
        (``ENGINES[engine].penalties_at(self.accuracy)``) in the penalty fields left None."""
        from .solvers.all_pairs.engine import ENGINES

        defaults = dict(zip(("rho0", "rho_max", "rho_doubling"), ENGINES[engine].penalties_at(self.accuracy)))
        return self.replace(engine=engine, **{k: v for k, v in defaults.items() if getattr(self, k) is None})
    _POSITIVE: ClassVar[tuple[str, ...]] = ("eps_rel", "eps_rel_consensus", "eps_rel_dual", "eps_change", "eps_excess", "relaxation", "rho0",
                 "rho_max", "rho_doubling", "rho2_factor", "cg_fraction", "cg_rtol", "max_gradient")
    _INTEGERS: ClassVar[tuple[str, ...]] = ("change_window", "max_iterations", "cg_max_iterations", "eigenbasis_max_vertices")

    @classmethod
    def for_accuracy(cls, accuracy, **overrides):
        """The options of a run asked to stop within ``accuracy`` x max U of the minimizer, in (0, 0.1]:
        the residual tolerances scaled by s = accuracy / DEFAULT_ACCURACY, eps_change = 0.7 accuracy,
        eps_excess = accuracy and cg_fraction x min(1, s) (a finer run needs finer X-steps); then
        ``overrides``."""
        if isinstance(accuracy, (bool, np.bool_)) or not (isinstance(accuracy, (int, float, np.integer, np.floating))
                                                          and 0.0 < accuracy <= 0.1):
            raise ValueError(f"expected accuracy as a fraction of the max distance in (0, 0.1], got {accuracy!r}")
        base, s = cls(), float(accuracy) / DEFAULT_ACCURACY
        return cls(eps_rel=base.eps_rel * s, eps_rel_consensus=base.eps_rel_consensus * s,
                   eps_rel_dual=base.eps_rel_dual * s, eps_change=_CHANGE_SHARE * accuracy,
                   eps_excess=_EXCESS_SHARE * accuracy, cg_fraction=base.cg_fraction * min(1.0, s)).replace(**overrides)

    @property
    def accuracy(self):
        """The accuracy that these options' change test stands for, eps_change / 0.7 (that of
        :meth:`for_accuracy`; DEFAULT_ACCURACY without a change test)."""
        return self.eps_change / _CHANGE_SHARE if math.isfinite(self.eps_change) else DEFAULT_ACCURACY

    def at_accuracy(self, accuracy):
        """These options with the fields that :meth:`for_accuracy` sets (``FROM_ACCURACY``) taken from it; every
        other field stays."""
        target = type(self).for_accuracy(accuracy)
        return self.replace(**{name: getattr(target, name) for name in self.FROM_ACCURACY})

    FROM_ACCURACY = ("eps_rel", "eps_rel_consensus", "eps_rel_dual", "eps_change", "eps_excess", "cg_fraction")
