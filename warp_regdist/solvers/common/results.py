"""What the solvers return: :class:`DistanceResult` (single sources) and :class:`AllPairsResult`,
both ``scipy.optimize.OptimizeResult`` (a dict with attribute access)."""

from __future__ import annotations

import time

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
        The change of u still to come, in units of max u, if every vertex kept converging at its
        own rate of the last two change tests (10 iterations apart), that rate capped at 0.95 per
        test (docs/method.md section 8). The solve runs until it is at most the options'
        ``eps_estimate`` (0.5%). An estimate, not a bound (docs/design/stopping.md compares it with
        the true error); :meth:`polish` measures the error instead.
    cg_iterations : int
        PCG iterations summed over ADMM iterations (shared by all columns of a batch).
    seconds : float
        Wall time of the solve.
    interrupted : bool
        True when Ctrl-C stopped the solve: the columns not yet converged hold their current
        iterate and ``converged`` False.
    duals : (m, 3) or (m, 3, k) ndarray of float64
        The per-element multipliers y of the gradient constraint at the returned iterate, m the
        elements of the mesh solved on (``DistanceSolver.solve_mesh``: with its obtuse angles refined) (always
        from :meth:`~warp_regdist.DistanceSolver.solve`, from :meth:`~warp_regdist.DistanceSolver.solve_many` with
        ``keep_duals=True``); with ``penalty`` (rho / L, float or (k,)) they make the result a
        warm start (``initial=``).
    refined_mesh, refined_distance : Mesh, (n',) or (n', k) ndarray
        With points or curves as sources: the mesh refined at them (its first n vertices are
        this mesh's) and the distance on all its vertices; ``duals`` then belong to it.
    refined_curves : list of (c,) ndarray of int, or k such lists
        With curves as sources: each curve as its chain of ``refined_mesh`` vertices.
    signed_distance, refined_signed_distance : (n,) or (n, k) ndarray, (n',) or (n', k) ndarray
        With ``closed=True`` on a triangle mesh: ``distance`` (``refined_distance``), negative on the
        left of the curve.

    Methods
    -------
    vjp(grad_u)
        Gradients of a loss through the solve (vertex sources, Dirichlet regularizer).
    polish()
        The result with the distance of the barrier-smoothed problem, within about 1e-4 of exact.
    """

    def _keep(self, problem, source_sets, surface=None, refinement=None, full=None):
        """Keep what :meth:`vjp` and :meth:`polish` need (an attribute, not a key): the
        :class:`~warp_regdist.solvers.single_source.gradients.SmoothingProblem` of the solve (None: not
        differentiable), the vertex source sets, for points the
        :class:`~warp_regdist.solvers.single_source.sources.SurfaceSources` whose refined mesh it ran on,
        and where the solver refined the mesh its :class:`~warp_regdist.ObtuseRefinement` with the distance
        (n', k) on all of the refined mesh's vertices."""
        object.__setattr__(self, "_problem", (problem, source_sets, surface, refinement, full))

    def _on_surface(self, surface):
        """Keep that this result's problem ran on the refined mesh of ``surface`` (a
        :class:`~warp_regdist.solvers.single_source.sources.SurfaceSources`)."""
        problem, source_sets, _, refinement, full = vars(self)["_problem"]
        self._keep(problem, source_sets, surface, refinement, full)

    def _on_refinement(self, refinement):
        """Keep that this result's problem ran on ``refinement.mesh`` (a :class:`~warp_regdist.ObtuseRefinement`) and
        report ``distance`` on the input's vertices only."""
        problem, source_sets, surface, _, _ = vars(self)["_problem"]
        self._keep(problem, source_sets, surface, refinement, self.distance)
        self.distance = self.distance[:refinement.original.n_vertices]

    def _smoothable(self, verb):
        """(problem, source sets, distance (n', k) on the problem's mesh, one column?, surface sources or
        None, refinement or None) after the checks that :meth:`vjp` and :meth:`polish` share (``verb``
        names the operation in their messages)."""
        problem, source_sets, surface, refinement, full = vars(self).get("_problem", (None,) * 5)
        if problem is None:
            raise ValueError(f"expected a result of DistanceSolver.solve or solve_many from vertices or points to "
                             f"{verb}, got one from curves (or a copy)")
        if problem.regularizer != "dirichlet" or problem.mesh.element_weights is not None:
            what = "a point cloud" if problem.mesh.element_weights is not None else repr(problem.regularizer)
            raise ValueError(f"expected the Dirichlet regularizer on a mesh to {verb}, got {what}")
        converged = np.atleast_1d(self.converged)
        if not converged.all():
            raise ValueError(f"expected a converged solve to {verb}, got {np.count_nonzero(~converged)} of "
                             f"{converged.size} columns not converged (interrupted, or max_iterations reached)")
        distance = np.asarray(self.distance if surface is None else self.refined_distance)
        one = distance.ndim == 1
        if refinement is not None:
            distance = np.asarray(full).reshape(full.shape[0], -1)
        return problem, source_sets, distance[:, None] if distance.ndim == 1 else distance, one, surface, refinement

    def vjp(self, grad_u):
        """Vector-Jacobian product: the gradients of a loss L with dL/ddistance = ``grad_u``
        ((n,) after :meth:`~warp_regdist.DistanceSolver.solve`, (n, k) after ``solve_many``;
        entries on sources and unreachable vertices are ignored) with respect to the vertex
        positions and alpha_hat, by implicit differentiation of the barrier-smoothed problem at
        the solution (docs/method.md section 10, the options' ``gradient_smoothing`` and
        ``gradient_factorization``).

        Returns a :class:`~warp_regdist.Gradients`: ``vertices`` (n, 3) dL/dx,
        ``alpha_hat`` dL/dalpha_hat, ``smoothed_distance`` (the minimizer whose derivative it is)
        and ``smoothing_change`` (its distance from ``distance``, in units of the max distance).
        After a solve from points also ``points``: dL/d(barycentric coordinates) of each point
        ((p, 3) after ``solve``, a list of them after ``solve_many``), the points moving with their
        face, and ``refined_vertices`` (n', 3) on the refined mesh.
        """
        from ..single_source.gradients import vector_jacobian_product

        problem, source_sets, distance, one, surface, refinement = self._smoothable("differentiate")
        n = np.asarray(self.distance).shape[0]
        try:
            grad = None if isinstance(grad_u, (str, bytes)) else np.asarray(grad_u, dtype=float)
        except (TypeError, ValueError):
            grad = None
        shape = (n,) if one else (n, distance.shape[1])
        if grad is None:
            raise ValueError(f"expected grad_u as a real array of shape {shape}, got {type(grad_u).__name__}")
        if grad.shape != shape:
            raise ValueError(f"expected grad_u of shape {shape} (the distance's), got {grad.shape}")
        if not np.all(np.isfinite(grad)):
            raise ValueError("expected finite grad_u, got NaN or inf")
        grad = grad[:, None] if one else grad
        # the new vertices of the refined mesh are no outputs: zero
        grad = np.concatenate([grad, np.zeros((distance.shape[0] - n, grad.shape[1]))])
        out = vector_jacobian_product(problem, distance, source_sets, grad)
        if refinement is not None:        # back through the refinement to the input mesh
            kept = refinement.original.n_vertices
            out["vertices"] = refinement.vjp(out.vertices)
            out["smoothed_distance"] = out.smoothed_distance[:kept]
            out["smoothing_change"] = float(np.max(_change(out.smoothed_distance, distance[:kept])))
        if surface is not None:
            from ...geometry.surface_points import refinement_vjp

            out["refined_vertices"] = out.vertices
            out["vertices"], gb = refinement_vjp(surface.refinement, problem.mesh.vertices[:n], surface.bary,
                                                 out.vertices)
            points = [gb[own] for own in surface.own_points]
            out["points"] = points[0] if one else points
            out["refined_smoothed_distance"] = out.smoothed_distance[:, 0] if one else out.smoothed_distance
            out["smoothed_distance"] = out.smoothed_distance[:n]
        if one:
            out["smoothed_distance"] = out.smoothed_distance[:, 0]
        return out

    def polish(self):
        """This result with ``distance`` replaced by the minimizer of the barrier-smoothed problem
        (docs/method.md section 10), found by Newton's method from it: within about 1e-4 of the max
        distance of the exact minimizer, for a sparse factorization per Newton step (MKL PARDISO or
        SuperLU, ``options.gradient_factorization``; docs/performance.md gives its cost). ``polish_change`` (float or (k,)) is how far it moved, in units of the max
        distance: the ADMM's own error, to within the smoothing's. ``error_estimate`` is dropped;
        ``seconds`` adds the polish's time.
        Vertex and point sources and the Dirichlet regularizer only, like :meth:`vjp`.
        """
        from ..single_source.gradients import smoothed_solution

        t0 = time.perf_counter()
        problem, source_sets, distance, one, surface, refinement = self._smoothable("polish")
        out = DistanceResult(self)
        out._keep(*vars(self)["_problem"])
        del out["error_estimate"]
        solutions = [smoothed_solution(problem, distance[:, j], source_sets[j], j)
                     for j in range(distance.shape[1])]
        polished = np.stack([x.distance for x in solutions], axis=1)
        change = np.array([x.change for x in solutions])
        if refinement is not None:        # the new vertices are no outputs: the change on the input's
            out._keep(*vars(self)["_problem"][:4], polished)
            polished = polished[:refinement.original.n_vertices]
            change = _change(polished, distance[:refinement.original.n_vertices])
        if surface is not None:
            out["refined_distance"] = polished[:, 0] if one else polished
            polished = polished[:np.asarray(self.distance).shape[0]]
        out["distance"], out["polish_change"] = (polished[:, 0], change[0].item()) if one else (polished, change)
        out["seconds"] = self.seconds + time.perf_counter() - t0
        return out


def _change(new, old):
    """max |new - old| / max |old| per column of (n, k) or (n,) distances, 0 where old is 0; (k,) or ()."""
    new, old = np.asarray(new, dtype=float), np.asarray(old, dtype=float)
    new, old = (new[:, None], old[:, None]) if old.ndim == 1 else (new, old)
    finite = np.isfinite(old) & np.isfinite(new)
    top = np.where(finite, np.abs(old), 0.0).max(axis=0)
    moved = np.where(finite, np.abs(new - old), 0.0).max(axis=0)
    return np.where(top > 0, moved / np.where(top > 0, top, 1.0), 0.0)


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
        True when all seven residuals met their tolerances and the last change and steepness
        tests held (``eps_change``, ``eps_excess``) before ``max_iterations``.
    residuals, tolerance : (7,) ndarray
        Final residuals (r1, r2, s1, s2, rx1, rx2, sx) and their tolerances.
    history : (iterations, 7) ndarray
        Residuals divided by their tolerances at every iteration.
    change, error_estimate : float
        The change of U still to come estimated at the last change test, in units of max U
        (inf before the third test; see ``eps_change``): the run's estimate of max |U - U*| / max U,
        at the slower of the last two windows' rate and 1 / k. An estimate, not a bound
        (docs/design/all-pairs.md compares it with the true error).
    gradient_excess : float
        How far ``distance`` breaks |grad U_j| <= 1: max over elements e and columns j of
        (|grad U_j|_e - 1)_+ diam(e) / max U (``eps_excess``).
    cg_iterations : int
        PCG iterations summed over ADMM iterations (the largest count among the worker processes).
    seconds : float
    memory_bytes : int
        Estimated footprint of the solver's arrays (device and host).
    interrupted : bool
        True when Ctrl-C stopped the run (``distance`` is the current iterate).
    checkpoint, checkpoint_iteration : str or None, int or None
        The checkpoint file, and the iteration of the state it holds (None where this run wrote none:
        its saves failed, or it resumed a converged run's final checkpoint).
    engine : {"eigenbasis", "consensus"}
        The splitting that computed it (``AllPairsOptions.engine``, "auto" resolved).
    """
