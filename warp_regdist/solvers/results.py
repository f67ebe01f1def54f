"""What the solvers return: :class:`DistanceResult` (single sources) and :class:`AllPairsResult`,
both ``scipy.optimize.OptimizeResult`` (a dict with attribute access)."""

from __future__ import annotations

import numpy as np
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

    Methods
    -------
    vjp(grad_u)
        Gradients of a loss through the solve (vertex sources, Dirichlet regularizer).
    """

    def _attach(self, solver, source_sets):
        """Keep the solver and the vertex source sets for :meth:`vjp` (an attribute, not a key)."""
        object.__setattr__(self, "_problem", (solver, source_sets))

    def vjp(self, grad_u):
        """Vector-Jacobian product: the gradients of a loss L with dL/ddistance = ``grad_u``
        ((n,) after :meth:`~warp_regdist.DistanceSolver.solve`, (n, k) after ``solve_many``;
        entries on sources and unreachable vertices are ignored) with respect to the vertex
        positions and alpha_hat, by implicit differentiation of the barrier-smoothed problem at
        the solution (docs/method.md section 10, ``tolerances.gradient_smoothing``).

        Returns a :class:`~warp_regdist.Gradients`: ``vertices`` (n, 3) dL/dx,
        ``alpha_hat`` dL/dalpha_hat, ``smoothed_distance`` (the minimizer whose derivative it is)
        and ``smoothing_change`` (its distance from ``distance``, in units of the max distance).
        """
        from .gradients import vector_jacobian_product

        solver, source_sets = vars(self).get("_problem", (None, None))
        if solver is None:
            raise ValueError("expected a result of DistanceSolver.solve or solve_many from vertex sources to "
                             "differentiate, got one from points or curves (or a copy)")
        if solver.regularizer.name != "dirichlet" or solver.mesh.element_weights is not None:
            what = "a point cloud" if solver.mesh.element_weights is not None else repr(solver.regularizer.name)
            raise ValueError(f"expected the Dirichlet regularizer on a mesh to differentiate, got {what}")
        converged = np.atleast_1d(self.converged)
        if not converged.all():
            raise ValueError(f"expected a converged solve to differentiate, got {np.count_nonzero(~converged)} of "
                             f"{converged.size} columns not converged (interrupted, or max_iterations reached)")
        distance = np.asarray(self.distance)
        try:
            grad = None if isinstance(grad_u, (str, bytes)) else np.asarray(grad_u, dtype=float)
        except (TypeError, ValueError):
            grad = None
        if grad is None:
            raise ValueError(f"expected grad_u as a real array of shape {distance.shape}, got {type(grad_u).__name__}")
        if grad.shape != distance.shape:
            raise ValueError(f"expected grad_u of shape {distance.shape} (the distance's), got {grad.shape}")
        if not np.all(np.isfinite(grad)):
            raise ValueError("expected finite grad_u, got NaN or inf")
        two = distance.ndim == 1
        out = vector_jacobian_product(solver, distance[:, None] if two else distance, source_sets,
                                      grad[:, None] if two else grad)
        if two:
            out["smoothed_distance"] = out.smoothed_distance[:, 0]
        return out


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
