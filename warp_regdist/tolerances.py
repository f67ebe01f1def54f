"""The single settings object for numerical tolerances and ADMM defaults (cf. ``trimesh.tol``).

Change a value for the whole process (``warp_regdist.tolerances.eps_rel = 1e-3``) or for
one block with ``with warp_regdist.tolerances.override(eps_rel=1e-3): ...``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import warnings

__all__ = ["Tolerances", "tolerances"]


@dataclasses.dataclass
class Tolerances:
    """Tolerances and defaults; all are dimensionless (scale-invariant).

    Attributes
    ----------
    eps_abs, eps_rel, eps_rel_dual : float
        ADMM residual test (docs/method.md section 8: section 4's test with separate relative tolerances):
        r < sqrt(3m) eps_abs sqrt(A) + eps_rel max(|G u|, |z|) and
        s < sqrt(n) eps_abs A + eps_rel_dual |D y| (norms weighted by the areas).
    eps_change, change_window : float, int
        Change test: every change_window iterations, u_k is compared with the u of
        change_window iterations before; a column stops once its residual test holds and
        the last comparison gave max |u_k - u_(k - change_window)| <= eps_change max |u_k|
        (math.inf: no change test). The residuals alone do not tell when the error is
        small; the change test bounds it (docs/architecture.md, benchmarks/stopping.py).
    eps_estimate : float
        The column also waits until its ``error_estimate`` is at most eps_estimate (a fraction
        of max u; math.inf: no such test): the change still to come if every vertex kept
        converging at its own rate of the last two comparisons, that rate capped at
        ``stopping.ESTIMATE_RATE_CAP`` per window (docs/method.md section 8).
    max_iterations : int
        ADMM iteration cap.
    relaxation : float
        Over-relaxation a of the z- and y-steps (Boyd et al. 2011, sec. 3.4.3).
    rho0, rho_max, rho_doubling : float
        Penalty schedule, in units of the length scale L = sqrt(A):
        rho_k = L min(rho_max, rho0 2^((k - 1) / rho_doubling)) at iteration k = 1, 2, ...
        A changing penalty costs nothing here (the Dirichlet u-step matrix (alpha + rho) W_D
        is only rescaled), and a fixed schedule converges more reliably than residual
        balancing.
    cg_fraction, cg_rtol : float
        Each u-step is solved inexactly by warm-started PCG, until its residual is below
        min(cg_fraction |D y|, eps_dual / 10) (|D y| is the scale of the dual residual s),
        or below cg_rtol times the right-hand side. 1e-3 keeps the iterates as with exact
        solves; looser fractions save CG work but can stall the ADMM on small meshes.
    cg_primal_fraction : float
        The u-step's residual is also kept below cg_primal_fraction times the last primal
        residual r (times L^(d/2 - 1), in the units of (alpha + rho) W_D u, so that the rule
        is scale-invariant on tetrahedra too): a warm start that already meets the fixed
        tolerance would otherwise leave u unchanged and r stalled above its tolerance.
    cg_max_iterations : int
        PCG iteration cap per ADMM iteration.
    pairs_eps_rel, pairs_eps_rel_consensus, pairs_eps_rel_dual, pairs_rho2_factor : float
        Defaults of the same-named arguments of :func:`warp_regdist.all_pairs` (its residual
        test and consensus penalty); its CG tolerance defaults to ``cg_fraction``.
    pairs_rho_max, pairs_rho_doubling : float
        The all-pairs penalty schedule (as rho_max, rho_doubling; it starts at ``rho0`` too).
    pairs_eps_change, pairs_change_window : float, int
        Change test of :func:`warp_regdist.all_pairs`, every pairs_change_window iterations:
        with c = max |U_k - U_(k - window)| / max U_k, it holds once c / (1 - c / c_before),
        the change still to come at the rate of the last two windows, is <= pairs_eps_change
        (math.inf: no change test).
    pairs_eps_excess : float
        The all-pairs stop also waits until U's steepness beyond |grad| <= 1, max over elements
        and columns of (|grad U_j| - 1)_+ diam(e) / max U (:func:`warp_regdist.solvers.stopping.gradient_excess`,
        measured every pairs_change_window iterations), is <= pairs_eps_excess (math.inf: no
        such test).
    degenerate_element : float
        An element whose area (volume) is <= this times its longest edge squared (cubed)
        is refused as degenerate.
    point_snap : float
        A source point whose barycentric coordinate on a face is <= this lies on that face's
        edge (or vertex, when 1 - point_snap <= its largest coordinate) and is moved there:
        the triangles it would cut off would be slivers (see warp_regdist.surface_points).
    curve_snap : float
        A curve's crossing of an edge within this fraction of the edge from a vertex moves to the
        vertex (the curve then passes through it): the cuts would leave slivers and obtuse
        angles next to the curve, where u dipped below 0 (to -0.07 h on spot with 1e-3).
    gradient_smoothing : float
        mu_hat of :meth:`~warp_regdist.DistanceResult.vjp`: the derivative is that of the
        minimizer of the problem with the barrier -mu_hat (A^(1 + 1/d) / m) sum_e log(1 - |G u|_e^2)
        added (docs/method.md section 10). At 1e-6 that minimizer was 4.4e-5 of the max distance
        from the unsmoothed one on a decimated spot, and its derivatives within 2% of the
        unsmoothed problem's; smaller values come closer, but the smoothed map then bends within
        steps of about mu_hat in the positions, and below about 1e-8 rounding limits its accuracy.
    max_gradient : float
        A result (single sources, and all pairs column by column) whose gradient exceeds this
        on some element is reported as not converged, with a warning (the constraint is
        |G u| <= 1, which converged results meet to about 1%). It catches single-source
        iterations that blew up on needle-like elements, and all-pairs runs whose consensus
        had not settled near the diagonal, while their relative stopping tests held.
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
    cg_fraction: float = 1e-3
    cg_primal_fraction: float = 0.01
    cg_rtol: float = 1e-10
    cg_max_iterations: int = 500
    pairs_eps_rel: float = 5e-4
    pairs_eps_rel_consensus: float = 5e-5
    pairs_eps_rel_dual: float = 1e-2
    pairs_rho2_factor: float = 25.0
    pairs_rho_max: float = 8.0
    pairs_rho_doubling: float = 30.0
    pairs_eps_change: float = 3e-3
    pairs_change_window: int = 50
    pairs_eps_excess: float = 5e-3
    degenerate_element: float = 1e-12
    point_snap: float = 1e-3
    curve_snap: float = 0.2
    max_gradient: float = 1.5
    gradient_smoothing: float = 1e-6

    def __getattr__(self, name):
        if name in _RENAMED:
            _warn_renamed(name)
            return getattr(self, _RENAMED[name])
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __setattr__(self, name, value):
        if name in _RENAMED:
            _warn_renamed(name)
            name = _RENAMED[name]
        super().__setattr__(name, value)

    @contextlib.contextmanager
    def override(self, **values):
        """Temporarily set some attributes (restored on exit, also after an exception)."""
        for name in [n for n in values if n in _RENAMED]:
            _warn_renamed(name)
            values[_RENAMED[name]] = values.pop(name)
        unknown = set(values) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise ValueError(f"expected tolerance names among {[f.name for f in dataclasses.fields(self)]}, got {sorted(unknown)}")
        old = {k: getattr(self, k) for k in values}
        for k, v in values.items():
            setattr(self, k, v)
        try:
            yield self
        finally:
            for k, v in old.items():
                setattr(self, k, v)


_RENAMED = {"pairs_cg_fraction": "cg_fraction", "pairs_rho0": "rho0"}
"""Settings both solvers now share under one name (the old all-pairs names still work, with a warning)."""


def _warn_renamed(name):
    warnings.warn(f"tolerances.{name} is tolerances.{_RENAMED[name]}, shared by both solvers; the old name "
                  "will be removed", DeprecationWarning, stacklevel=4)


tolerances = Tolerances()
