"""What the solvers return: :class:`DistanceResult` (single sources) and :class:`AllPairsResult`,
both ``scipy.optimize.OptimizeResult`` (a dict with attribute access)."""

from __future__ import annotations

from scipy.optimize import OptimizeResult

__all__ = ["DistanceResult", "AllPairsResult", "RESIDUAL_NAMES"]


class DistanceResult(OptimizeResult):
    """Result of :meth:`~warp_regdist.DistanceSolver.solve` (scalars) or :meth:`~warp_regdist.DistanceSolver.solve_many` (per column).

    Attributes
    ----------
    distance : (n,) or (n, k) ndarray of float64
        Regularized distance; 0 on the sources, +inf on vertices no source can reach
        (other connected components, vertices referenced by no element).
    iterations : int or (k,) ndarray of int
        ADMM iterations until the stopping test held.
    converged : bool or (k,) ndarray of bool
    primal_residual, dual_residual : float or (k,) ndarray
        Final r = |sqrt(M_F)(G u - z)| and s = rho |D (z - z_old)|.
    error_estimate : float or (k,) ndarray
        The change of u still to come, in units of max u, extrapolated from the last two change
        tests (c / (1 - c / c_old), c = max |u_k - u_(k-10)| / max u; inf while c does not
        shrink): an estimate of max |u - u*| / max u*, not a bound. Against exact minimizers the
        true error was 0.27-5.7 times it on 42 cases and up to 10.7 times in the tests
        (docs/architecture.md, stopping rule).
    cg_iterations : int
        PCG iterations summed over ADMM iterations (shared by all columns of a batch).
    seconds : float
        Wall time of the solve.
    interrupted : bool
        True when Ctrl-C stopped the solve: the columns not yet converged hold their current
        iterate and ``converged`` False.
    duals : (m, 3) or (m, 3, k) ndarray of float64
        The per-element multipliers y of the gradient constraint at the returned iterate (always
        from :meth:`~warp_regdist.DistanceSolver.solve`, from :meth:`~warp_regdist.DistanceSolver.solve_many` with
        ``keep_duals=True``); with ``penalty`` (rho / L, float or (k,)) they make the result a
        warm start (``initial=``).
    refined_mesh, refined_distance : Mesh, (n',) or (n', k) ndarray
        With points or curves as sources: the mesh refined at them (its first n vertices are
        this mesh's) and the distance on all its vertices; ``duals`` then belong to it.
    signed_distance : (n,) or (n, k) ndarray
        With ``closed=True`` on a triangle mesh: ``distance``, negative on the left of the curve.
    """


RESIDUAL_NAMES = ("r1", "r2", "s1", "s2", "rx1", "rx2", "sx")
"""The seven residuals of docs/method.md section 5, in the order of ``AllPairsResult.residuals``."""


class AllPairsResult(OptimizeResult):
    """Result of :func:`~warp_regdist.all_pairs`.

    Attributes
    ----------
    distance : (n, n) ndarray of float64
        Exactly symmetric, zero diagonal, non-negative.
    iterations : int
    converged : bool
        True when all seven residuals met their tolerances and the last change test held
        (``eps_change``) before ``max_iterations``.
    residuals, tolerance : (7,) ndarray
        Final residuals (r1, r2, s1, s2, rx1, rx2, sx) and their tolerances.
    history : (iterations, 7) ndarray
        Residuals divided by their tolerances at every iteration.
    change, error_estimate : float
        The change of U still to come estimated at the last change test, in units of max U
        (inf before the third test, or while the change grows; see ``eps_change``): the run's
        estimate of max |U - U*| / max U. An estimate, not a bound: against the exact minimizers of
        small irregular meshes the true error at the stop was up to 3.7 times it at accuracy 0.01
        and 6.8 times at 0.002, and on the 1,949-vertex cat about 4.6 times at 0.005
        (docs/guides/all-pairs.md).
    cg_iterations : int
        PCG iterations summed over ADMM iterations (the largest count among the worker processes).
    seconds : float
    memory_bytes : int
        Estimated footprint of the solver's arrays (device and host).
    """
