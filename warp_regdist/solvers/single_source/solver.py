"""Regularized geodesic distance from source sets: ADMM (Algorithm 1 of the paper; docs/method.md sections 4 and 8).

For each source set E the solver returns the minimizer of

    minimize_u  -A_V^T u + (alpha / 2) u^T W u
    subject to  |(G u)_e| <= 1 on every element e,   u_i = 0 for i in E,

with the regularizer W = W_D (Dirichlet), W_V (vector-field alignment) or W_H (curved
Hessian) and alpha = alpha_hat * A^(1/d) (A the total area, or volume for d = 3;
A^(3/2) for the Hessian), so that alpha_hat is scale-invariant (geometry/regularizers.py).
Many source sets are solved as batched ADMMs whose per-element, per-vertex and
linear-solve steps are Warp kernels over (rows x columns). The u-step matrix is
alpha W + rho W_D: for Dirichlet the rescaled (alpha + rho) W_D (only the right-hand side
is divided by alpha + rho), otherwise its values are replaced in the PCG whenever rho changes;
the multigrid preconditioner of W_D serves all three.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import sys
import time
import warnings

import numpy as np
from numpy.typing import ArrayLike
import warp as wp

from ...arguments import check_weight, parse_device, parse_workers
from ...errors import ConvergenceWarning
from ...geometry.mesh import Mesh
from ...geometry.obtuse_refinement import obtuse_refinement
from ...geometry.operators import build_operators, choose_triangulation
from ...geometry.regularizers import build_regularizer
from ...kernels.lanes import SCALARS, lane_type, lane_width
from ...kernels.single_source import CG_TOTAL, ESTIMATE, LANE_ROWS, R_LAST, RHO_LAST, S_LAST
from ...options import SolverOptions
from ..common import interrupt
from ..common.admm import INTERRUPTED, PenaltySchedule, run_iterations
from ..common.device_mesh import DeviceMesh
from ...linalg.multigrid import Hierarchy, smoothed_aggregation
from ...linalg.pcg import BatchedPCG
from ..common.processes import WorkerPool, check_workers, processes_available, watch
from ..common.progress import Progress
from ..common.results import DistanceResult
from .batch import RHO_TABLE, BatchIterations, ColumnBatch, Workspace, collect, device_rule, lanes
from .sources import check_surface_batch, refined_result, surface_sources, vertex_sources
from .gradients import SmoothingProblem
from .below_zero import warn_below_zero
from .vertex_ascent import VertexAscent
from ..common.source_triangles import SourceTriangles, check_source_triangles
from ..common.stopping import steep_columns

__all__ = ["DistanceSolver"]

_PROCESS_WORK = 100_000
"""Vertices x source sets from which solve_many starts worker processes by default (spot x 21)."""


class DistanceSolver:
    """Precompute once, solve for many source sets (cf. potpourri3d's solver objects).

    Parameters
    ----------
    mesh : Mesh
        Triangle or tetrahedral mesh.
    alpha_hat : float
        Scale-invariant regularization weight >= 0 (0: the discrete geodesic distance).
    regularizer : {"dirichlet", "vector_field", "hessian"}
        The quadratic regularizer W (docs/method.md section 3). "hessian" needs a triangle mesh and
        stops at tolerances / 20; below alpha_hat 0.02 the others stop at tolerances shrinking to / 4
        and on triangles their penalty starts lower and doubles more slowly (docs/method.md section 8).
    beta_hat : float or None
        Alignment weight >= 0 of "vector_field" (default 10; scale-invariant).
    vector_field : (m, 3) array_like or None
        Per-element field of "vector_field": the isolines turn to follow it (its length
        scales the alignment; see :func:`warp_regdist.line_field` to build one from a few
        directions).
    device : str or None
        Warp device ("cpu", "cuda", "cuda:0"); None: Warp's default device.
    dtype : {"float64", "float32"}
        Precision of the solver's arrays (float32 halves memory; agreement ~1e-3).
    workers : int or None
        CPU processes for :meth:`solve_many`: a CPU kernel launch runs on one core, so the
        source sets are split into up to ``workers`` independent batches (whole lane blocks),
        one solved in this process and the others in worker processes that build their own
        copy of the solver at the first such call and are kept for the next ones (see
        :meth:`close`). None: the cores available to the process, used once a batch has at
        least 10^5 vertices x source sets (a worker takes a few seconds to start). Ignored on
        CUDA (one batch fills the GPU) and off Linux. Each column's result does not depend on it:
        the workers receive this solver's multigrid hierarchy instead of building their own.
    hierarchy : warp_regdist.linalg.multigrid.Hierarchy or None
        A multigrid hierarchy of the stiffness matrix W_D of ``solve_mesh`` to reuse (e.g. a solver's
        ``hierarchy`` of the same mesh at another alpha_hat); None: built here.
    options : SolverOptions or None
        Stopping rule, penalty schedule, iteration cap and linear-solve settings (None: the
        defaults); :meth:`solve` and :meth:`solve_many` override fields per call by keyword.
    triangulation : {"intrinsic", "mesh"} or None
        The triangulation the operators live on: "intrinsic" the intrinsic Delaunay triangulation
        of a triangle mesh's vertices (edge flips: the same vertices and surface, no obtuse pair of
        opposite angles; docs/concepts.md), "mesh" the mesh's own elements. None: "intrinsic" for
        triangle meshes with the Dirichlet or Hessian regularizer, "mesh" otherwise (tetrahedra,
        point clouds, the vector-field regularizer, whose field lives on the mesh's faces). Outputs
        are per input vertex either way; ``duals`` are per element of the triangulation used.
    source_triangles : {"edges", "gradient"} or None
        The constraint on a triangle with exactly one corner s among a column's sources: "edges" bounds
        u at its other corners a by the side lengths, u_a <= |x_a - x_s| (the exact distance does; the
        unit-speed bound on such a triangle takes u below 0 next to s where its angle at s is obtuse),
        "gradient" keeps |grad u| <= 1 there as everywhere (the paper's problem). None: "edges" on
        triangle meshes, "gradient" on tetrahedra (docs/method.md section 2).
    refine_obtuse : bool or None
        With the intrinsic triangulation, insert vertices until no boundary side is opposite an obtuse
        angle and no angle is above 120 degrees (:func:`~warp_regdist.refine_obtuse_angles`: feet of
        altitudes on the boundary, circumcenters inside) and solve on the refined mesh: the distance then
        does not dip below 0 beside such angles (docs/real-meshes.md). Outputs stay per input vertex;
        ``duals`` are the refined mesh's; a new vertex between sources only is a source.
        None: True with the intrinsic triangulation and the Dirichlet regularizer (a mesh without such
        angles is solved as it is). The solver's ``refinement`` is the
        :class:`~warp_regdist.ObtuseRefinement` (None without insertions) and ``solve_mesh`` the mesh it
        computes on.

    Examples
    --------
    >>> solver = DistanceSolver(load_mesh("spot.off"), alpha_hat=0.05)
    >>> u = solver.solve([2272]).distance
    >>> rough = solver.solve([2272], max_iterations=50)          # an options field, for this call

    Ctrl-C during :meth:`solve` or :meth:`solve_many` stops at the end of the current ADMM
    iteration and returns the current iterate (``interrupted=True``, unconverged columns
    ``converged=False``); a second Ctrl-C raises KeyboardInterrupt.
    """

    def __init__(self, mesh: Mesh, alpha_hat: float = 0.05, regularizer: str = "dirichlet",
                 beta_hat: float | None = None, vector_field: ArrayLike | None = None, device: str | None = None,
                 dtype: str = "float64", workers: int | None = None, hierarchy: Hierarchy | None = None,
                 options: SolverOptions | None = None, triangulation: str | None = None,
                 source_triangles: str | None = None, refine_obtuse: bool | None = None) -> None:
        if not isinstance(mesh, Mesh):
            raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
        alpha_hat = check_weight(alpha_hat, "alpha_hat")
        if dtype not in SCALARS:
            raise ValueError(f"expected dtype 'float64' or 'float32', got {dtype!r}")
        if options is not None and not isinstance(options, SolverOptions):
            raise ValueError(f"expected options as a SolverOptions or None, got {type(options).__name__}")
        self.options = SolverOptions() if options is None else options
        self._auto_workers = workers is None
        workers = parse_workers(workers)
        self.device = parse_device(device)
        self.workers = 1 if self.device.is_cuda or not processes_available() else workers
        self._copy_arguments = dict(alpha_hat=alpha_hat, regularizer=regularizer, beta_hat=beta_hat,
                                    vector_field=vector_field, dtype=dtype, options=self.options,
                                    triangulation=triangulation, source_triangles=source_triangles,
                                    refine_obtuse=refine_obtuse)
        self._pool = None
        self.mesh = mesh
        self.alpha_hat = alpha_hat
        self.dtype = dtype
        self.scalar = SCALARS[dtype]
        self.triangulation = triangulation = choose_triangulation(mesh, regularizer, triangulation)
        refinement = obtuse_refinement(mesh, triangulation, regularizer, refine_obtuse)
        self._refines = refinement is not None
        self.refinement = refinement if self._refines and refinement.n_inserted else None
        self.solve_mesh = solve_mesh = mesh if self.refinement is None else self.refinement.mesh
        self.operators = ops = build_operators(solve_mesh, triangulation,
                                               None if refinement is None else refinement.triangulation)
        self.regularizer = build_regularizer(solve_mesh, ops, regularizer, alpha_hat, beta_hat, vector_field)
        self.alpha = self.regularizer.alpha
        self.source_triangles = SourceTriangles(ops, check_source_triangles(source_triangles, mesh.element_dim))
        self.device_mesh = DeviceMesh(ops, self.scalar, self.device, self.source_triangles.directions)
        self.vertex_ascent = VertexAscent(ops, self.regularizer.weights, self.alpha, self.source_triangles)
        if hierarchy is None:
            hierarchy = smoothed_aggregation(ops.stiffness)
        elif not isinstance(hierarchy, Hierarchy) or hierarchy.sizes[0] != solve_mesh.n_vertices:
            raise ValueError(f"expected hierarchy as a multigrid Hierarchy of {solve_mesh.n_vertices} unknowns, got "
                             f"{hierarchy.sizes[0] if isinstance(hierarchy, Hierarchy) else type(hierarchy).__name__}")
        self.hierarchy = hierarchy
        self._workspaces: dict = {}
        self._refined = None   # (key, the DistanceSolver of the latest refined mesh of points and curves)

    def smoothing_problem(self, options=None):
        """The :class:`~warp_regdist.solvers.single_source.gradients.SmoothingProblem` of a solve with
        ``options`` (None: this solver's): what a result's vjp and polish keep of this solver."""
        return SmoothingProblem(self.solve_mesh, self.operators, self.alpha, self.alpha_hat, self.regularizer.name,
                                self.source_triangles, self.options if options is None else options)

    def source_mask(self, sources, column=0):
        """Validated vertex ``sources`` of column ``column`` -> (indices (s,) of ``solve_mesh``, reachable (n',)
        bool: its vertices in the sources' connected components). A vertex the refinement inserted between
        sources only (on an edge whose two ends are sources) is one too: it does not change where u = 0."""
        idx, reach = vertex_sources(sources, column, self.mesh.n_vertices, self.solve_mesh.components())
        if self.refinement is not None:
            others = np.ones(self.mesh.n_vertices)
            others[idx] = 0.0
            idx = np.concatenate([idx, self.mesh.n_vertices + np.flatnonzero(abs(self.refinement.weights) @ others == 0.0)])
        return idx, reach

    # ------------------------------------------------------------------ public API
    def _initial_state(self, initial, k):
        """Warm start ``initial`` (a DistanceResult of this mesh with k columns) as
        (u (n, k), y (m, 3, k) or None, penalty (k,) or None); None stays None."""
        if initial is None:
            return None
        n, m = self.mesh.n_vertices, self.operators.element_volumes.size
        if not isinstance(initial, DistanceResult):
            raise ValueError(f"expected initial as a DistanceResult of solve or solve_many, got {type(initial).__name__}")
        u = np.asarray(initial.distance, dtype=np.float64)
        u = u[:, None] if u.ndim == 1 else u
        if u.shape != (n, k):
            raise ValueError(f"expected initial with a distance of shape ({n}, {k}) (this mesh, one column per "
                             f"source set), got shape {np.shape(initial.distance)}")
        if np.isnan(u).any():
            raise ValueError(f"expected initial distances without NaN, got {np.count_nonzero(np.isnan(u))} NaN")
        if self.refinement is not None:
            u = self.refinement.interpolation() @ u
        if "duals" not in initial:
            return u, None, None
        y = np.asarray(initial.duals, dtype=np.float64)
        y = y[:, :, None] if y.ndim == 2 else y
        penalty = np.asarray(initial.get("penalty", np.nan), dtype=np.float64)
        if y.shape != (m, 3, k):
            raise ValueError(f"expected initial duals of shape ({m}, 3, {k}), got shape {np.shape(initial.duals)}")
        if penalty.shape not in ((), (k,)) or not (np.isfinite(y).all() and (penalty > 0).all()):
            raise ValueError(f"expected initial duals finite and penalty > 0 (scalar or ({k},)), got penalty "
                             f"{penalty!r} and {np.count_nonzero(~np.isfinite(y))} non-finite duals")
        return u, y, np.broadcast_to(penalty, (k,))

    def solve(self, sources: ArrayLike | None = None, verbose: bool = False, initial: DistanceResult | None = None,
              points: ArrayLike | None = None, curve: ArrayLike | None = None, closed: bool = False,
              callback: Callable[[Progress], object] | None = None, **options) -> DistanceResult:
        """Distance from one source set; see :class:`DistanceResult`.

        ``sources``: vertex indices. ``points``: surface points [(face, (b0, b1, b2)), ...] (e.g. from
        :func:`~warp_regdist.surface_points`), sources at the points themselves. ``curve``: a polyline
        of surface points, u = 0 all along it (``closed``: back to its first point, and the result
        has ``signed_distance``, negative on the curve's left). Points and curves are inserted into a
        refined mesh (triangle meshes; docs/method.md, "Sources anywhere"): ``distance`` is reported
        on this mesh's vertices, ``refined_distance`` on ``refined_mesh``'s. Any of the three may be
        combined; at least one is needed.

        ``initial``: a result of an earlier :meth:`solve` on this mesh (other sources or another
        solver's alpha_hat) to start from: its distance, duals and penalty. The answer is this
        problem's minimizer; only the iterations needed change.

        ``callback``: called at every test of the iterate (every iteration on the CPU, every 10 on
        CUDA) as ``callback(progress)`` with a :class:`~warp_regdist.solvers.common.progress.Progress`;
        ``verbose`` prints it on stderr every 2 s.

        ``options``: fields of :class:`~warp_regdist.SolverOptions` for this call (``max_iterations=``,
        ``eps_rel=``, ``schedule=``, ...); the answer is the same minimizer, the iterations and the
        stop change.
        """
        def one(x):
            return None if x is None else [x]

        res = self._solve_many(one(sources), verbose, initial, True, one(points), one(curve), closed, callback,
                               self.options.replace(**options))
        for key in ("iterations", "converged", "primal_residual", "dual_residual", "penalty", "error_estimate"):
            res[key] = res[key][0].item()
        for key in ("distance", "refined_distance", "signed_distance", "refined_signed_distance"):
            if key in res:
                res[key] = res[key][:, 0]
        if "refined_curves" in res:
            res["refined_curves"] = res["refined_curves"][0]
        res["duals"] = res["duals"][:, :, 0]
        return res

    def solve_many(self, source_sets: Sequence[ArrayLike] | None = None, verbose: bool = False,
                   initial: DistanceResult | None = None, keep_duals: bool = False,
                   points: Sequence[ArrayLike] | None = None, curves: Sequence[ArrayLike] | None = None,
                   closed: bool = False, callback: Callable[[Progress], object] | None = None,
                   **options) -> DistanceResult:
        """Distances from k source sets as batched ADMMs (on the CPU ``cpu_blocks`` lane blocks of up to 8
        (float64) or 16 (float32) columns at a time, on CUDA all at once): ``distance`` is (n, k).

        ``points``, ``curves``: k lists of surface points, k curves (see :meth:`solve`), one per
        column, alone or with k ``source_sets``; all columns share one refined mesh (so a column
        differs from its own solve where another column's point refines the mesh near its sources).
        ``initial``: a result with k columns to start from (see :meth:`solve`); ``keep_duals``:
        return ``duals`` (m, 3, k) too, which makes the result a full warm start; ``callback``,
        ``verbose``, ``options``: as in :meth:`solve` (the callback sees this process's part of the
        batch).
        """
        return self._solve_many(source_sets, verbose, initial, keep_duals, points, curves, closed, callback,
                                self.options.replace(**options))

    def _solve_many(self, source_sets, verbose, initial, keep_duals, points, curves, closed, callback, options):
        """The work of :meth:`solve_many`; its warnings name the caller of solve / solve_many."""
        if callback is not None and not callable(callback):
            raise ValueError(f"expected callback as a callable or None, got {callback!r}")
        if verbose:
            callback = _printer(callback)
        if points is not None or curves is not None or closed:
            k = check_surface_batch(source_sets, points, curves, closed, initial)
            sets = None if source_sets is None else [vertex_sources(s, j, self.mesh.n_vertices, self.mesh.components())[0]
                                                     for j, s in enumerate(source_sets)]
            S = surface_sources(self.mesh, k, sets, points, curves, closed)
            refined = self._refined_solver(S)
            res = refined._solve_many([s.tolist() for s in S.sets], False, None, keep_duals, None, None, False,
                                      callback, options)
            if curves is None:   # vjp and polish on the refined mesh, pulled back through its new vertices
                res._on_surface(S)
            else:
                res._keep(None, None)
            return refined_result(res, S, self.mesh.n_vertices, closed)
        if source_sets is None:
            raise ValueError("expected sources, points or a curve, got none")
        if isinstance(source_sets, (str, bytes)) or not hasattr(source_sets, "__iter__"):
            raise ValueError(f"expected a list of source sets, got {source_sets!r}")
        sets = [self.source_mask(s, j) for j, s in enumerate(source_sets)]
        if not sets:
            raise ValueError("expected at least one source set, got none")
        start = self._initial_state(initial, len(sets))
        t0 = time.perf_counter()
        k = len(sets)
        W = lane_width(self.scalar, k)
        blocks = -(-k // W)
        # whole lane blocks per worker, as even as possible; by default only for batches whose work
        # (vertices x columns) outweighs a worker process's start (~3 s, once per solver)
        parts = min(self.workers, blocks)
        if self._auto_workers and self._pool is None and self.solve_mesh.n_vertices * k < _PROCESS_WORK:
            parts = 1
        bounds = [min(k, W * (blocks * i // parts)) for i in range(parts + 1)]
        groups = [sets[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
        starts = [None if start is None else tuple(None if x is None else x[..., a:b] for x in start)
                  for a, b in zip(bounds[:-1], bounds[1:])]
        with interrupt.catch_interrupt():
            if len(groups) == 1:
                parts = self._admm_blocks(groups[0], W, options, starts[0], keep_duals, callback)
            else:
                pool = self._worker_pool(len(groups) - 1)
                pool.start("solve", [(g, W, options, st, keep_duals) for g, st in zip(groups[1:], starts[1:])])
                try:
                    with watch(pool):
                        mine = self._admm_blocks(groups[0], W, options, starts[0], keep_duals, callback, check_workers)
                finally:
                    others = pool.finish()
                parts = mine + [part for parts_of_worker in others for part in parts_of_worker]
        keys = ("distance", "iterations", "converged", "primal_residual", "dual_residual", "penalty", "error_estimate")
        res = DistanceResult(
            {key: np.concatenate([p[key] for p in parts], axis=-1) for key in keys + ("duals",) * keep_duals},
            cg_iterations=sum(p.cg_iterations for p in parts), seconds=time.perf_counter() - t0,
            interrupted=any(p.interrupted for p in parts))
        res._keep(self.smoothing_problem(options), [src for src, _ in sets])
        stuck = self._ascend(res, sets, options)
        steep, gradient = steep_columns(self.source_triangles, res.distance, options.max_gradient,
                                       [src for src, _ in sets])
        res.converged &= ~steep
        if steep.any():
            warnings.warn(f"ADMM returned distances steeper than their constraint allows (max |grad u| relative to "
                          f"its bound {np.max(gradient[steep]):.3g}) for {np.count_nonzero(steep)} of {k} "
                          "source sets: not converged (needle-like elements?)", ConvergenceWarning, stacklevel=3)
        warn_below_zero(self.solve_mesh, self.operators, res.distance, res.converged, source_sets,
                        self.triangulation == "intrinsic" and self.mesh.element_dim == 2 and not self._refines)
        capped = ~res.converged & ~steep & ~stuck
        if capped.any() and not res.interrupted:
            warnings.warn(f"ADMM did not converge in {options.max_iterations} iterations for "
                          f"{np.count_nonzero(capped)} of {k} source sets", ConvergenceWarning, stacklevel=3)
        if self.refinement is not None:   # the inserted vertices are no outputs; vjp and polish keep them
            res._on_refinement(self.refinement)
        return res

    def _ascend(self, res, sets, options):
        """The ADMM's result ``res`` after :class:`VertexAscent` (vertices moved alone by more than a tenth of
        the error estimate's tolerance eps): ``error_estimate`` at least the largest move left (in units of
        max u), and a column whose move left exceeds eps not converged (with a ConvergenceWarning). Returns
        those columns (k,) bool."""
        eps = self.regularizer.tolerance_factor * options.eps_estimate
        if not np.isfinite(eps):
            return np.zeros(len(sets), dtype=bool)
        u = res.distance
        finite = np.isfinite(u)
        free = finite.copy()
        for j, (src, _) in enumerate(sets):
            free[src, j] = False
        u0 = np.where(finite, u, 0.0)
        top = np.maximum(np.abs(u0).max(axis=0), 1e-300)
        moved, left = self.vertex_ascent.ascend(u0, free, [src for src, _ in sets], 0.1 * eps * top)
        res.distance = np.where(finite, moved, u).astype(u.dtype)
        left /= top
        res.error_estimate = np.maximum(res.error_estimate, left)
        stuck = res.converged & (left > eps)
        res.converged &= ~stuck
        if stuck.any():
            warnings.warn(f"{np.count_nonzero(stuck)} of {left.size} source sets stopped with a vertex that alone "
                          f"could still move by {100 * left[stuck].max():.3g}% of the max (more than eps_estimate "
                          f"{100 * eps:.3g}%): not converged; res.polish() finds the minimizer",
                          ConvergenceWarning, stacklevel=4)
        return stuck

    def _refined_solver(self, S):
        """A solver of the same settings on the refined mesh of ``S``, kept for the next call with the same
        refined mesh."""
        if self._refined is None or self._refined[0] != S.key:
            if self._refined is not None:
                self._refined[1].close()
            args = dict(self._copy_arguments)
            if args["vector_field"] is not None:
                args["vector_field"] = np.asarray(args["vector_field"])[S.refinement.parent]
            self._refined = (S.key, DistanceSolver(S.refinement.mesh, device=self.device,
                                                   workers=None if self._auto_workers else self.workers, **args))
        return self._refined[1]

    # ------------------------------------------------------------------ ADMM
    def _worker_pool(self, count):
        """At least ``count`` running worker processes, each holding a copy of this solver (kept until
        :meth:`close`; a pool with a dead worker is replaced)."""
        if self._pool is None or len(self._pool) < count or not self._pool.alive():
            self.close()
            self._pool = WorkerPool(_SolverCopy, (dict(self._copy_arguments, mesh=self.solve_mesh, refine_obtuse=False,
                                                       hierarchy=self.hierarchy),),
                                    count, first_index=1)
        return self._pool

    def close(self):
        """End the worker processes of :meth:`solve_many` (also done when the solver is garbage collected)."""
        if self._pool is not None:
            self._pool.close()
            self._pool = None
        if self._refined is not None:
            self._refined[1].close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _workspace(self, W, nb):
        """The arrays of a batch of nb blocks of W lanes (only the latest batch shape is kept:
        the memory scales with the batch)."""
        key = (W, nb)
        if key not in self._workspaces:
            self._workspaces = {}
            V = lane_type(self.scalar, W)
            n, m, dev = self.solve_mesh.n_vertices, self.operators.element_volumes.size, self.device
            vertexwise = [wp.zeros((n, nb), dtype=V, device=dev) for _ in range(8)]
            ws = Workspace(
                width=W, u=vertexwise[0], mask=vertexwise[1], Dy=vertexwise[2], Dz=vertexwise[3], rhs=vertexwise[4],
                z=wp.zeros((m, 3, nb), dtype=V, device=dev), y=wp.zeros((m, 3, nb), dtype=V, device=dev),
                rho=wp.zeros(nb, dtype=V, device=dev), acc=wp.zeros((5, nb), dtype=V, device=dev),
                # the device-resident stopping test (kernels/single_source.py): u at the last change test and
                # its move, the per-lane state, the iterates frozen when a lane's test first held, counters, penalties
                snapshot=vertexwise[5], moved_last=vertexwise[6], u_out=vertexwise[7],
                lane=wp.zeros((LANE_ROWS, nb), dtype=V, device=dev), step=wp.zeros(2, dtype=wp.int32, device=dev),
                rho_table=wp.zeros(RHO_TABLE, dtype=self.scalar, device=dev),
                touched=wp.zeros(m, dtype=wp.int32, device=dev),
                pcg=BatchedPCG(self.operators.stiffness if self.regularizer.rescaled else self.regularizer.system(0.0),
                               self.scalar, W, nb, dev, preconditioner=self.hierarchy),
            )
            self._workspaces[key] = ws
        return self._workspaces[key]

    def _admm_blocks(self, sets, W, options, start=None, keep_duals=False, callback=None, poll=None):
        """:meth:`_admm` of ``sets`` in lane blocks of W columns: all at once on CUDA, on the CPU
        ``options.cpu_blocks`` at a time, one batch after another; returns the batches' results."""
        step = len(sets) if self.device.is_cuda else W * options.cpu_blocks
        parts = []
        for a in range(0, len(sets), step):
            part = sets[a:a + step]
            begun = None if start is None else tuple(None if x is None else x[..., a:a + len(part)] for x in start)
            parts.append(self._admm(part, self._workspace(W, -(-len(part) // W)), options, begun, keep_duals,
                                    callback, poll))
        return parts

    def _admm(self, sets, ws, options, start=None, keep_duals=False, callback=None, poll=None):
        """One batched ADMM over ``sets`` in the workspace ``ws`` (its lane width and blocks), from
        zero or from ``start`` = (u (n, k), y (m, 3, k) or None, penalty (k,) or None), under ``options``.

        The stopping test, the penalty and the CG tolerances are decided on the device (kernels/single_source.py);
        the host reads the per-lane flags every ``options.check_every`` iterations to collect the columns
        done (frozen on the device at the iteration their test held) and to compact the batch.
        """
        t0 = time.perf_counter()
        k = len(sets)
        n = self.solve_mesh.n_vertices
        nb = ws.u.shape[1]
        W = ws.width

        # Slot j (lane j % W of block j // W) holds column slot_col[j] of the batch, -1 when it is
        # free: padding, or a column already collected (its lane still computes).
        slot_col = np.where(np.arange(nb * W) < k, np.arange(nb * W), -1)
        free = np.zeros((n, nb * W))
        for j in range(nb * W):
            src, reach = sets[min(j, k - 1)]
            free[:, j] = reach
            free[src, j] = 0.0
        ws.mask.assign(free.reshape(n, nb, W))
        ws.touched.assign(self.source_triangles.touched([src for src, _ in sets], ws.touched.shape[0]))
        for name in ("u", "z", "y", "Dy", "Dz", "snapshot", "moved_last", "step"):
            getattr(ws, name).zero_()
        L = self.operators.length_scale
        schedule = PenaltySchedule.of(options, L, self.regularizer.schedule_factors)
        # iteration it runs with rho = schedule.rho(it + offset); a warm start continues the
        # schedule from the penalty it carries. The change test compares with u0 (zero or the start's).
        offset = 0.0
        if start is not None:
            u0, y0, penalty = start
            u0 = np.where(np.isfinite(u0), u0, 0.0) * free[:, :k]
            ws.u.assign(lanes(u0, nb, W))
            ws.snapshot.assign(lanes(u0, nb, W))
            if y0 is not None:
                ws.y.assign(lanes(y0, nb, W))
                ws.z.assign(lanes(self._project_gradient(u0, [src for src, _ in sets]), nb, W))
                offset = schedule.offset_for(L * float(np.median(penalty)))
        if keep_duals and ws.y_out is None:
            ws.y_out = wp.zeros_like(ws.y)

        rule, lane = device_rule(self.operators, self.regularizer, self.mesh.element_dim, options, free)
        ws.lane.assign(lane.reshape(LANE_ROWS, nb, W))
        ws.pcg.configure(options.cg_rtol, options.cg_max_iterations)
        batch = ColumnBatch(self.device_mesh, ws, W, nb, options.change_window, rule, options.relaxation,
                            options.capture)
        run = BatchIterations(ws, batch, self.regularizer, slot_col, k, keep_duals, schedule, offset, callback, t0)
        check_every = options.check_every or (10 if self.device.is_cuda else 1)
        it, reason = run_iterations(run, 0, options.max_iterations, check_every, poll)
        iterations, out, y_out, r_out, s_out, rho_out, estimate = (run.iterations, run.out, run.y_out, run.r_out,
                                                                    run.s_out, run.rho_out, run.estimate_out)
        state = ws.lane.numpy().reshape(LANE_ROWS, -1)  # the last iterate's, tested or not (Ctrl-C)

        late = np.flatnonzero(slot_col[:batch.blocks * W] >= 0)
        if late.size:
            cols = slot_col[late]
            collect(ws, False, late, cols, out, y_out)
            r_out[cols], s_out[cols], rho_out[cols] = state[R_LAST, late], state[S_LAST, late], state[RHO_LAST, late]
            estimate[cols] = state[ESTIMATE, late]
        u = out
        for j, (src, reach) in enumerate(sets):
            u[~reach, j] = np.inf
            u[src, j] = 0.0
        converged = iterations >= 0
        res = DistanceResult(
            distance=u, iterations=np.where(converged, iterations, it), converged=converged,
            primal_residual=r_out, dual_residual=s_out, penalty=rho_out, error_estimate=estimate,
            cg_iterations=int(ws.step.numpy()[CG_TOTAL]), seconds=time.perf_counter() - t0,
            interrupted=reason == INTERRUPTED)
        if keep_duals:
            res["duals"] = y_out
        return res

    def _project_gradient(self, u, sources):
        """z = G u (n, k) -> (m, 3, k) projected per element and column onto its constraint set (column j's
        sources ``sources[j]``)."""
        g = (self.operators.grad @ u).reshape(self.operators.element_volumes.size, 3, -1)
        return self.source_triangles.project(g, list(enumerate(sources[:g.shape[2]])))


def _printer(callback):
    """A callback that prints the progress on stderr every 2 s once every test has been measured (the
    first change window), then calls ``callback`` (or None)."""
    last = [0.0]
    measured = [False]

    def show(progress):
        measured[0] = measured[0] or progress.checked
        if measured[0] and progress.seconds - last[0] >= 2.0:
            last[0] = progress.seconds
            print(f"  {progress}", file=sys.stderr, flush=True)
        if callback is not None:
            callback(progress)

    return show


class _SolverCopy:
    """A worker process's copy of a :class:`DistanceSolver` (one process, one batch at a time)."""

    def __init__(self, arguments, index):
        self.solver = DistanceSolver(device="cpu", workers=1, **arguments)

    def solve(self, sets, W, options, start, keep_duals):
        """The batched ADMMs of ``sets`` at lane width W under the caller's ``options`` (a SolverOptions)."""
        return self.solver._admm_blocks(sets, W, options, start, keep_duals)
