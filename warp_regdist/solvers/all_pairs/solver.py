"""All-pairs regularized distance matrices on M x M (Algorithm 2 of the paper, docs/method.md section 5).

The distance matrix is the minimizer of

    minimize_U  -A_V^T U A_V + (alpha / 2) Tr(M_V U^T W_D U + U W_D U^T M_V)
    subject to  |grad of every column| <= 1,  |grad of every row| <= 1,  U_ii <= 0,  U >= 0,

with alpha = alpha_hat sqrt(A). For a symmetric U both energy terms are equal, so every
column carries the Dirichlet energy twice: a column is close to the single-source
distance with 2 alpha, not alpha.

Symmetric ADMM. The consensus splitting of docs/method.md section 5 has the variables
(X, R, U, Z, Q, Y, S, H, K). The problem is invariant under U -> U^T, and so is one ADMM
iteration under the map (X, R, U, Z, Q, Y, S, H, K) -> (R, X, U^T, Q, Z, S, Y, K, H): the
objective splits as f(X) + f(R), the column constraints of R are the row constraints of
U, and the U-step averages X and R^T. Started from a fixed point of that map (R = X,
Q = Z, S = Y, K = H, U = U^T; zeros here) the iterates stay there, so the R-half is
never computed: its right-hand side equals the X-step's, its projections and dual updates
equal those of Z and Y, and the U-step reads

    U = max(0, (1/2) ((H + H^T) / rho2 + Xh + Xh^T)),  U_ii = 0,   Xh = a X + (1 - a) U_old,

exactly symmetric at every iteration. One iteration is: the X-step, one batched PCG over
the n columns with K2 = (alpha + rho) W_D + rho2 M_V (column j's optimality condition
divided by A_V[j]) and X[j, j] held at 0 (U[j, j] = 0 carried by its copy); the fused
z/y-step over elements x columns; the fused U/H-step over pairs of W x W tiles. Z and Y are
stored together as one (3m, n) array (kernels/all_pairs.py).
The seven residuals of docs/method.md section 5 are computed (r2 = r1, s2 = s1, rx2 = rx1 by the
symmetry) and reported.

Penalties and stopping test (:class:`~warp_regdist.AllPairsOptions`; ``accuracy`` derives the
tolerances from the error accepted, :meth:`~warp_regdist.AllPairsOptions.for_accuracy`):
rho_k = sqrt(A) min(rho_max, rho0 2^(k / rho_doubling)), rho2_k = rho2_factor rho_k^2 / (sqrt(A) A)
(the consensus penalty grows faster than rho), over-relaxation in all three steps; stop when every
residual is below its relative tolerance, the change still to come at the slower of the last two
windows' rate and 1 / k (:class:`~warp_regdist.solvers.common.stopping.ExtrapolatedChangeTest`, with c_k = max
|U_k - U_(k - window)| / max U_k) is at most eps_change, and U's steepness beyond the constraint is at
most eps_excess. K2 changes with the
penalties: ``BatchedPCG.set_matrix`` replaces its values (same pattern as W_D), the multigrid
preconditioner is built once.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
import functools
import math
import os
import time
import warnings

import numpy as np

from ...arguments import check_weight, parse_device, parse_workers
from ...atomic_write import check_room
from ...errors import ConvergenceWarning
from ...file_lock import FileLock
from ...geometry.mesh import Mesh
from ...geometry.operators import build_operators, choose_triangulation, largest_basis_angles
from ...kernels.lanes import SCALARS
from ...options import AllPairsOptions
from ..common.admm import PenaltySchedule
from ..common.progress import Progress
from ..common.results import AllPairsResult
from .checkpoint import (Checkpoint, check_no_progress, checkpoint_bytes, checkpoint_name, checkpoint_room,
                                   problem_fingerprint, read_checkpoint)
from .eigenbasis import EigenbasisADMM, EigenbasisUStep
from .engine import choose_engine
from .forecast import RunForecast, typical_iterations, with_cap
from .run import PairsRun, final_result
from .state import SymmetricADMM, middle_matrix
from .memory import check_memory, memory_estimate
from ...linalg.multigrid import smoothed_aggregation
from ..common.source_triangles import SourceTriangles, check_source_triangles
from ..common.stopping import gradient_excess, steep_columns, steepest_element

__all__ = ["AllPairsSolver", "all_pairs", "OBTUSE_ANGLE"]

OBTUSE_ANGLE = 120.0
"""An unconverged all-pairs result whose steepest triangle has an angle of this many degrees or more
says so (:meth:`AllPairsSolver.solve`): the iterations settle slowly at obtuse triangles, most often
at the column's own vertex (docs/design/all-pairs.md)."""


class AllPairsSolver:
    """Symmetric all-pairs regularized distance matrix (Algorithm 2) of a connected triangle mesh,
    set up once (operators, memory estimate; the engine's multigrid hierarchy or eigenvectors on first use)
    and solved by :meth:`solve`.

    Parameters
    ----------
    mesh : Mesh
        Connected triangle mesh whose every vertex is in a face.
    alpha_hat : float
        Scale-invariant regularization weight >= 0; alpha = alpha_hat sqrt(A).
    device : str or None
        Warp device ("cpu", "cuda"); None: Warp's default device.
    dtype : {"float64", "float32"}
        Precision of the solver's arrays; float32 halves the memory.
    workers : int or None
        CPU processes that share every step of the consensus engine (at most one per column block; the
        eigenbasis engine runs in one process, its products on BLAS threads). None: the cores
        available to this process, at most one per 10^6 pairs (a worker takes a few seconds to
        start). Ignored on CUDA and off Linux. The result does not depend on it.
    options : AllPairsOptions or None
        Stopping rule, penalties, iteration cap and X-step settings (None: the defaults; see
        :meth:`AllPairsOptions.for_accuracy`); :meth:`solve` overrides fields per call. The
        multigrid preconditioner targets the middle of these options' penalty range.
    triangulation : {"intrinsic", "mesh"} or None
        The triangulation of the operators, as for :class:`~warp_regdist.DistanceSolver` (None:
        "intrinsic"). U stays (n, n) over the input's vertices.
    source_triangles : {"edges", "gradient"} or None
        The constraint of column j on the triangles at vertex j, as for
        :class:`~warp_regdist.DistanceSolver` (None: "edges").

    Attributes
    ----------
    memory_bytes : int
        Estimated footprint of a solve's arrays (device and host); each :meth:`solve` checks it
        against the memory then available and frees its arrays when it returns.
    hierarchy : warp_regdist.linalg.multigrid.Hierarchy
        The consensus engine's X-step multigrid preconditioner, shared by every solve.
    u_step : warp_regdist.solvers.all_pairs.eigenbasis.EigenbasisUStep
        The eigenbasis engine's U-step (eigenvectors of the stiffness), shared by every solve.

    Examples
    --------
    >>> solver = AllPairsSolver(mesh, alpha_hat=0.03, dtype="float32")
    >>> U = solver.solve(accuracy=0.01, checkpoint="run.npz").distance
    """

    def __init__(self, mesh: Mesh, alpha_hat: float = 0.03, device: str | None = None, dtype: str = "float64",
                 workers: int | None = None, options: AllPairsOptions | None = None, triangulation: str | None = None,
                 source_triangles: str | None = None) -> None:
        if not isinstance(mesh, Mesh):
            raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
        if mesh.element_dim != 2:
            raise ValueError(f"expected a triangle mesh, got {mesh.n_elements} tetrahedra")
        if options is not None and not isinstance(options, AllPairsOptions):
            raise ValueError(f"expected options as an AllPairsOptions or None, got {type(options).__name__}")
        self.options = AllPairsOptions() if options is None else options
        self.alpha_hat = check_weight(alpha_hat, "alpha_hat")
        self._auto_workers = workers is None
        self.workers = parse_workers(workers)
        if dtype not in SCALARS:
            raise ValueError(f"expected dtype 'float64' or 'float32', got {dtype!r}")
        labels = mesh.components()
        if (labels < 0).any():
            raise ValueError(f"expected every vertex in a face, got {np.count_nonzero(labels < 0)} vertices in none "
                             f"(first: {np.flatnonzero(labels < 0)[0]})")
        if labels.max() > 0:
            raise ValueError(f"expected a connected mesh, got {labels.max() + 1} connected components "
                             "(warp_regdist.split_components(mesh) gives each as a mesh to solve separately)")
        self.mesh, self.dtype, self.device = mesh, dtype, parse_device(device)
        self.triangulation = choose_triangulation(mesh, "dirichlet", triangulation)
        self.operators = ops = build_operators(mesh, self.triangulation)
        self.source_triangles = SourceTriangles(ops, check_source_triangles(source_triangles, 2))
        self._excess = functools.partial(gradient_excess, self.source_triangles, ops.diameters)
        self._steepest = functools.partial(steepest_element, self.source_triangles, ops.diameters)
        self._penalty_mid = _penalty_mid(PenaltySchedule.of(self.options.for_engine("consensus"), ops.length_scale),
                                         ops.length_scale)
        self.memory_bytes = sum(memory_estimate(mesh.n_vertices, mesh.n_elements, dtype, self.device,
                                                self.engine(self.options)))

    def engine(self, options: AllPairsOptions) -> str:
        """The engine that ``options`` choose on this mesh and device: their ``engine``, or for "auto"
        "eigenbasis" on the CPU up to ``options.eigenbasis_max_vertices`` vertices and "consensus" otherwise."""
        return choose_engine(options.engine, self.mesh.n_vertices, self.device.is_cpu, options.eigenbasis_max_vertices)

    def forecast(self, accuracy: float | None = None, **options) -> RunForecast:
        """What :meth:`solve` with the same ``accuracy`` and ``options`` will take, before it starts: a
        :class:`~warp_regdist.solvers.all_pairs.forecast.RunForecast` (engine, memory, typical iterations
        at this size and accuracy, the cap)."""
        base = self.options if accuracy is None else self.options.at_accuracy(accuracy)
        run_options = base.replace(**options)
        engine = self.engine(run_options)
        n = self.mesh.n_vertices
        run_options = with_cap(n, run_options)
        memory = sum(memory_estimate(n, self.mesh.n_elements, self.dtype, self.device, engine))
        return RunForecast(n, engine, memory, typical_iterations(n, min(run_options.accuracy, 0.1)),
                           run_options.max_iterations, run_options.accuracy)

    @functools.cached_property
    def hierarchy(self):
        """The consensus engine's X-step multigrid preconditioner (built on first use, shared by every solve)."""
        return smoothed_aggregation(middle_matrix(self.operators, self.options.rho2_factor, self._penalty_mid))

    @functools.cached_property
    def u_step(self):
        """The eigenbasis engine's exact U-step (set up on first use, shared by every solve)."""
        return EigenbasisUStep(self.operators.stiffness, self.operators.vertex_volumes, self.dtype)

    def solve(self, accuracy: float | None = None, callback: Callable[[Progress], object] | None = None,
              checkpoint: str | os.PathLike | None = None, checkpoint_seconds: float = 300.0,
              resume: str | os.PathLike | None = None, initial: str | os.PathLike | None = None,
              restart: bool = False, **options) -> AllPairsResult:
        """Run the ADMM from zeros (or ``resume`` / ``initial``); returns an :class:`~warp_regdist.AllPairsResult`.

        Parameters
        ----------
        accuracy : float or None
            The max error accepted, as a fraction of the max distance, in (0, 0.1]: the tolerances
            follow from it (:meth:`AllPairsOptions.for_accuracy`, its other fields from this solver's
            options; docs/guides/all-pairs.md gives the errors measured against exact minimizers).
            None: this solver's options as they are.
        callback : callable or None
            Called after every iteration as ``callback(progress)`` with a
            :class:`~warp_regdist.solvers.common.progress.Progress`: the iteration, the seconds, every stop
            test against its threshold (``checked`` at the iterations that measure them all, once per
            ``change_window``) and the memory footprint; and once before the engine's setup, when every
            argument has been checked, with the iteration the run starts from and no tests.
        checkpoint : str or os.PathLike or None
            File (.npz) to which the whole state (iterates, duals, penalties, iteration count,
            residual history and the problem's fingerprint: mesh hash, alpha_hat, dtype,
            rho2_factor) is written atomically (a temporary file renamed over it) every
            ``checkpoint_seconds``, when the iteration cap is reached unconverged, when the
            run is interrupted, and at convergence (the final iterate and result: a warm start for
            ``initial``; resumed, it returns that result). Refused before any allocation when the
            file system lacks the room for two copies (each save writes the new one beside the last),
            when another run is writing it (it holds the lock file ``checkpoint + ".lock"`` for the
            length of the run), and when the file exists and is not ``resume``, unless ``restart``
            (no run's progress is overwritten by mistake). A save that fails during the run (a
            full disk) warns with a CheckpointWarning and the run goes on.
        checkpoint_seconds : float
            Interval between checkpoints (> 0).
        resume : str or os.PathLike or None
            A checkpoint of the same problem to continue from; with the same dtype the result is
            the same matrix as an uninterrupted run's. (May equal ``checkpoint``.)
        initial : str or os.PathLike or None
            A checkpoint of a run on the same mesh in the same dtype, of any alpha_hat and
            rho2_factor (continuation), to start from: its X, U, H and element state (the penalty
            schedule starts again). The result is this problem's minimizer; iterations, history and CG
            count are this run's.
        restart : bool
            Allow ``checkpoint`` to name an existing file that is not ``resume``: its progress is
            discarded and the run starts over.
        **options
            Fields of :class:`~warp_regdist.AllPairsOptions` for this call (``max_iterations=``,
            ``eps_rel=``, ...; after ``accuracy``).

        Returns
        -------
        AllPairsResult
            Ctrl-C (SIGINT) stops the run at the end of the current iteration: the result holds the
            current iterate with ``converged=False`` and ``interrupted=True`` (and the checkpoint is
            written); a second Ctrl-C raises KeyboardInterrupt at once. A result whose |grad| exceeds
            ``max_gradient`` on some element and column is reported with ``converged=False``
            and a ConvergenceWarning, whatever its residuals (a consensus not yet settled). An
            unconverged result whose gradient excess lies on a triangle with an angle of at least
            ``OBTUSE_ANGLE`` degrees gets a second ConvergenceWarning naming that triangle.

        Raises
        ------
        ValueError
            Bad arguments, a footprint above the available memory or a checkpoint above the free
            disk space (the message gives both), a resume or initial file of another problem or one
            that is not a complete checkpoint (truncated, foreign, arrays of other shapes or dtypes,
            a CRC-32 that does not match; read as data, never unpickled), and a resume file of an
            unconverged run already at ``max_iterations`` (raise it to continue).
        """
        t0 = time.perf_counter()
        mesh, dtype = self.mesh, self.dtype
        base = self.options if accuracy is None else self.options.at_accuracy(accuracy)
        run_options = base.replace(**options)
        check_weight(checkpoint_seconds, "checkpoint_seconds", positive=True)
        if callback is not None and not callable(callback):
            raise ValueError(f"expected callback as a callable or None, got {callback!r}")
        resume = None if resume is None else checkpoint_name(resume, "resume")
        initial = None if initial is None else checkpoint_name(initial, "initial")
        if resume is not None and initial is not None:
            raise ValueError(f"expected resume (the same problem) or initial (a warm start), got both: "
                             f"{resume!r} and {initial!r}")
        engine = self.engine(run_options)
        run_options = with_cap(mesh.n_vertices, run_options.for_engine(engine))
        fingerprint = problem_fingerprint(mesh, self.alpha_hat, dtype, run_options.rho2_factor, self.triangulation,
                                          self.source_triangles.rule,
                                          engine)
        size = checkpoint_bytes(mesh.n_vertices, mesh.n_elements, dtype, run_options.max_iterations)
        if checkpoint is not None:
            check_room([checkpoint_room(checkpoint, size)])
            if not restart:
                check_no_progress(checkpoint, resume)
        with contextlib.ExitStack() as stack:
            if checkpoint is not None:
                stack.enter_context(FileLock(checkpoint, "the checkpoint"))
            saved = (stack.enter_context(read_checkpoint(resume, fingerprint, mesh.n_elements))
                     if resume is not None else None)
            start = (stack.enter_context(read_checkpoint(initial, fingerprint, mesh.n_elements,
                                                         ("mesh_sha256", "n_vertices", "dtype", "triangulation"),
                                                         "initial"))
                     if initial is not None else None)
            memory = check_memory(mesh.n_vertices, mesh.n_elements, dtype, self.device, engine)
            if saved is not None and "final" in saved:
                return self._flag_steep(final_result(saved, memory, checkpoint), run_options)
            if saved is not None and int(saved["iteration"]) >= run_options.max_iterations:
                raise ValueError(f"expected max_iterations above {int(saved['iteration'])}, the iteration of the "
                                 f"checkpoint resumed ({resume!r}), got {run_options.max_iterations}: "
                                 "the run would stop where it is")
            if callback is not None:  # the arguments hold: the engine's setup starts
                callback(Progress(0 if saved is None else int(saved["iteration"]), time.perf_counter() - t0, (),
                                  checked=False, memory_bytes=memory))
            state = stack.enter_context(contextlib.closing(
                EigenbasisADMM(self.operators, self.alpha_hat, self.device, dtype, run_options, self.u_step,
                               self.source_triangles)
                if engine == "eigenbasis" else
                SymmetricADMM(self.operators, self.alpha_hat, self.device, dtype, run_options, self._penalty_mid,
                              self.workers, self.source_triangles, self._auto_workers, self.hierarchy)))
            saving = None if checkpoint is None else Checkpoint(checkpoint, checkpoint_seconds, fingerprint, size)
            run = PairsRun(state, run_options, PenaltySchedule.of(run_options, self.operators.length_scale), memory,
                           callback, saving, self._excess)
            if saved is not None:
                run.restore(saved)
                if saving is not None and resume is not None and os.path.exists(saving.path) \
                        and os.path.samefile(saving.path, resume):
                    saving.saved_at = run.start
            if start is not None:
                run.warm_start(start)
            return self._flag_steep(run.iterate(t0), run_options)

    def _flag_steep(self, res, options):
        """``res`` with its ``gradient_excess``, and with converged False and a ConvergenceWarning where
        max |G U| over elements and columns exceeds ``options.max_gradient`` or is NaN; a second
        ConvergenceWarning names the triangle of an unconverged result whose excess is above
        ``options.eps_excess`` when that triangle has an angle of OBTUSE_ANGLE or more."""
        res.gradient_excess, element, column = self._steepest(res.distance)
        limit = options.max_gradient
        if res.converged:
            steep, gradient = steep_columns(self.source_triangles, res.distance, limit, None)
            if steep.any():
                res.converged = False
                warnings.warn(f"all-pairs ADMM returned distances steeper than their constraint allows (max |grad U| "
                              f"relative to its bound {np.max(gradient):.3g}, above max_gradient = {limit:g}) although its residual tests "
                              "held: not converged; more iterations or a smaller accuracy", ConvergenceWarning,
                              stacklevel=3)
        if not res.converged and res.gradient_excess > options.eps_excess and element >= 0:
            angle = float(largest_basis_angles(self.operators.basis[[element]])[0])
            if angle >= OBTUSE_ANGLE:
                warnings.warn(f"all pairs: column {column} climbs {res.gradient_excess:.3g} of max U above unit speed "
                              f"across triangle {element}, whose largest angle is {angle:.0f} degrees: the iterations "
                              "settle slowly at obtuse triangles, and a mesh without them (Delaunay edge flips, "
                              "remeshing) converges sooner (docs/guides/all-pairs.md)", ConvergenceWarning, stacklevel=3)
        return res


def all_pairs(mesh: Mesh, alpha_hat: float = 0.03, device: str | None = None, dtype: str = "float64",
              workers: int | None = None, options: AllPairsOptions | None = None, accuracy: float | None = None,
              callback: Callable[[Progress], object] | None = None, checkpoint: str | os.PathLike | None = None,
              checkpoint_seconds: float = 300.0, resume: str | os.PathLike | None = None,
              initial: str | os.PathLike | None = None, restart: bool = False, triangulation: str | None = None,
              source_triangles: str | None = None, **overrides) -> AllPairsResult:
    """Symmetric all-pairs regularized distance matrix (Algorithm 2) on a connected triangle mesh:
    ``AllPairsSolver(mesh, alpha_hat, device, dtype, workers, options, triangulation, source_triangles).solve(accuracy,
    ...)`` with the
    other arguments and ``overrides`` (options fields) passed to :meth:`AllPairsSolver.solve`.

    Returns
    -------
    AllPairsResult
    """
    solver = AllPairsSolver(mesh, alpha_hat, device=device, dtype=dtype, workers=workers, options=options,
                            triangulation=triangulation, source_triangles=source_triangles)
    return solver.solve(accuracy=accuracy, callback=callback, checkpoint=checkpoint,
                        checkpoint_seconds=checkpoint_seconds, resume=resume, initial=initial, restart=restart,
                        **overrides)


def _penalty_mid(schedule, L):
    """sqrt(rho_start rho_end) / L of a schedule: of a PenaltySchedule its rho0 and rho_max, of
    another object its rho(0) and rho(10^6)."""
    if isinstance(schedule, PenaltySchedule):
        return math.sqrt(schedule.rho0 * schedule.rho_max)
    return math.sqrt(schedule.rho(0) * schedule.rho(10**6)) / L
