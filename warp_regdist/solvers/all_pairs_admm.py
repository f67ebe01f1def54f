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
z/y-step over elements x columns; the fused U/H-step over pairs of W x W tiles. Z and Y are stored together as one (3m, n) array (kernels/all_pairs.py).
The seven residuals of docs/method.md section 5 are computed (r2 = r1, s2 = s1, rx2 = rx1 by the
symmetry) and reported.

Penalties and stopping test (defaults chosen against exact minimizers, docs/guides/all-pairs.md;
``accuracy`` derives the tolerances below from the error accepted, :func:`accuracy_tolerances`):
rho_k = sqrt(A) min(rho_max, rho0 2^(k / rho_doubling)) (``tolerances.rho0``,
``pairs_rho_max``, ``pairs_rho_doubling``), rho2_k = rho2_factor rho_k^2 / (sqrt(A) A) (the
consensus penalty grows faster than rho),
over-relaxation ``tolerances.relaxation`` in all three steps; stop when every residual is
below its relative tolerance and the change test of the last window of
``tolerances.pairs_change_window`` iterations held: with c_k = max |U_k - U_(k - window)| / max U_k,
the change still to come if U keeps converging at the rate of the last two windows,
c_k / (1 - c_k / c_(k - window)), is at most eps_change (neither the residuals alone nor
the change of one window bound the distance to the exact minimizer). K2 changes with the penalties:
``BatchedPCG.set_matrix`` replaces its
values (same pattern as W_D), the multigrid preconditioner is built once.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import time
import warnings

import numpy as np

from .admm import PenaltySchedule, check_schedule
from .all_pairs_checkpoint import (check_no_progress, checkpoint_bytes, checkpoint_room, problem_fingerprint,
                                   read_checkpoint)
from .all_pairs_run import Checkpointing, PairsRun, final_result
from .all_pairs_state import PairsSettings, SymmetricADMM, check_memory, memory_estimate, middle_matrix
from .multigrid import smoothed_aggregation
from .stopping import gradient_excess, steepest_element
from ..atomic_write import check_room
from ..arguments import check_weight, parse_device, parse_workers
from ..errors import ConvergenceWarning
from ..file_lock import FileLock
from ..geometry.mesh import Mesh
from ..geometry.operators import build_operators, element_diameters, largest_angles
from ..kernels.lanes import SCALARS
from ..tolerances import tolerances

__all__ = ["AllPairsSolver", "all_pairs", "DEFAULT_ACCURACY", "CHANGE_SHARE", "EXCESS_SHARE", "OBTUSE_ANGLE",
           "accuracy_tolerances"]

DEFAULT_ACCURACY = 0.005
"""Max error, in units of the max distance, that the residual tolerances ``tolerances.pairs_eps_rel*``
were chosen for (with ``pairs_eps_change`` they stopped within it on irregular meshes)."""

CHANGE_SHARE = 0.3
"""eps_change = CHANGE_SHARE x accuracy: on 9 irregular meshes of 42-162 vertices the true error at the
stop was up to 3.7 times the change test's estimate at accuracy 0.01 and 6.8 times at 0.002; with 0.6 x
accuracy 5 of 64 runs stopped outside the accuracy asked, with 0.3 x accuracy 1 of 68."""

EXCESS_SHARE = 1.0
"""eps_excess = EXCESS_SHARE x accuracy (:func:`~warp_regdist.solvers.stopping.gradient_excess`). Replayed on
the recorded iterates of 19 exact cases (42-250 vertices) and 5 decimations to 300-500 vertices: at 1 x
accuracy 1 of 10 larger runs stopped as converged outside the accuracy (2.08% at 0.01) and the 250-vertex
cat ended unconverged within it at 0.005; at 0.5 x that larger run still stopped outside at 0.02, and
at 0.5 x and 0.3 x 5 and 6 small cases ended unconverged at 0.002."""


OBTUSE_ANGLE = 120.0
"""An unconverged all-pairs result whose steepest triangle has an angle of this many degrees or more
says so (:meth:`AllPairsSolver.solve`). On decimated meshes the excess that holds runs back sits at
such triangles, most often at the column's own vertex: on cat_rr subdivided and decimated to 2,000
vertices it was 0.052 after 4,000 iterations at a 164-degree triangle (26 triangles above 150
degrees), and 0.0044 on the same vertices after Delaunay edge flips (largest angle 149)."""


def accuracy_tolerances(accuracy, tol=tolerances):
    """The tolerances of a run asked to stop within ``accuracy`` x max U of the minimizer, as a dict
    keyed by the argument names: the residual tolerances ``tol.pairs_eps_rel``, ``pairs_eps_rel_consensus``
    and ``pairs_eps_rel_dual`` scaled by s = accuracy / DEFAULT_ACCURACY, eps_change = CHANGE_SHARE x
    accuracy, eps_excess = EXCESS_SHARE x accuracy and the PCG's ``tol.cg_fraction`` x min(1, s) (a
    finer run needs finer X-steps). None: the settings themselves."""
    if accuracy is None:
        return dict(eps_rel=tol.pairs_eps_rel, eps_rel_consensus=tol.pairs_eps_rel_consensus,
                    eps_rel_dual=tol.pairs_eps_rel_dual, eps_change=tol.pairs_eps_change,
                    eps_excess=tol.pairs_eps_excess, cg_fraction=tol.cg_fraction)
    scale = accuracy / DEFAULT_ACCURACY
    return dict(eps_rel=tol.pairs_eps_rel * scale, eps_rel_consensus=tol.pairs_eps_rel_consensus * scale,
                eps_rel_dual=tol.pairs_eps_rel_dual * scale, eps_change=CHANGE_SHARE * accuracy,
                eps_excess=EXCESS_SHARE * accuracy, cg_fraction=tol.cg_fraction * min(1.0, scale))


def _check_accuracy(accuracy):
    if accuracy is None:
        return None
    if not (isinstance(accuracy, (int, float, np.floating)) and not isinstance(accuracy, bool)
            and 0.0 < accuracy <= 0.1):
        raise ValueError(f"expected accuracy as a fraction of the max distance in (0, 0.1], got {accuracy!r}")
    return float(accuracy)


class AllPairsSolver:
    """Symmetric all-pairs regularized distance matrix (Algorithm 2) of a connected triangle mesh,
    set up once (operators, multigrid hierarchy, memory estimate) and solved by :meth:`solve`.

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
    rho2_factor : float or None
        rho2 = rho2_factor rho^2 / (sqrt(A) A): the consensus penalty grows like the square
        of the gradient penalty (the authors' initial values have rho2 = 5 rho / A).
        None: ``tolerances.pairs_rho2_factor``.
    schedule : PenaltySchedule or None
        The gradient penalty rho at iteration k = 0, 1, ...: a :class:`~warp_regdist.PenaltySchedule`
        or any object with ``rho(k)`` (absolute) and ``offset_for(penalty)``; rho2 follows from
        ``rho2_factor``. None: ``PenaltySchedule.all_pairs`` of ``tolerances`` (``rho0``,
        ``pairs_rho_max``, ``pairs_rho_doubling``, in units of sqrt(A)). The multigrid
        preconditioner targets the middle of its range. A checkpoint does not record it:
        resume with the same schedule.
    workers : int or None
        CPU processes that share every step (at most one per column block). None: the cores
        available to this process, at most one per 10^6 pairs (a worker takes a few seconds to
        start). Ignored on CUDA and off Linux. The result does not depend on it.

    Attributes
    ----------
    memory_bytes : int
        Estimated footprint of a solve's arrays (device and host); each :meth:`solve` checks it
        against the memory then available and frees its arrays when it returns.
    hierarchy : warp_regdist.solvers.multigrid.Hierarchy
        The X-step's multigrid preconditioner, shared by every solve.

    Examples
    --------
    >>> solver = AllPairsSolver(mesh, alpha_hat=0.03, dtype="float32")
    >>> U = solver.solve(accuracy=0.01, checkpoint="run.npz").distance
    """

    def __init__(self, mesh, alpha_hat=0.03, device=None, dtype="float64", rho2_factor=None, schedule=None,
                 workers=None):
        if not isinstance(mesh, Mesh):
            raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
        if mesh.element_dim != 2:
            raise ValueError(f"expected a triangle mesh, got {mesh.n_elements} tetrahedra")
        self.alpha_hat = check_weight(alpha_hat, "alpha_hat")
        self.rho2_factor = tolerances.pairs_rho2_factor if rho2_factor is None else rho2_factor
        check_weight(self.rho2_factor, "rho2_factor", positive=True)
        if schedule is not None:
            check_schedule(schedule)
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
                             "(solve each component separately)")
        self.mesh, self.dtype, self.device = mesh, dtype, parse_device(device)
        self.operators = ops = build_operators(mesh)
        diameters = element_diameters(mesh.vertices, mesh.elements)
        self._excess = functools.partial(gradient_excess, ops.grad, diameters)
        self._steepest = functools.partial(steepest_element, ops.grad, diameters)
        self.schedule = PenaltySchedule.all_pairs(tolerances, ops.length_scale) if schedule is None else schedule
        self._penalty_mid = _penalty_mid(self.schedule, ops.length_scale)
        self.memory_bytes = sum(memory_estimate(mesh.n_vertices, mesh.n_elements, dtype, self.device))
        self.hierarchy = smoothed_aggregation(middle_matrix(ops, self.rho2_factor, self._penalty_mid))

    def solve(self, accuracy=None, max_iterations=3000, eps_rel=None, eps_rel_consensus=None, eps_rel_dual=None,
              eps_change=None, cg_fraction=None, callback=None, checkpoint=None, checkpoint_seconds=300.0,
              resume=None, initial=None, eps_excess=None, restart=False):
        """Run the ADMM from zeros (or ``resume`` / ``initial``); returns an :class:`~warp_regdist.AllPairsResult`.

        Parameters
        ----------
        accuracy : float or None
            The max error accepted, as a fraction of the max distance, in (0, 0.1]: the tolerances
            below follow from it (:func:`accuracy_tolerances`; docs/guides/all-pairs.md gives the
            errors measured against exact minimizers). None: the ``tolerances.pairs_*`` settings
            themselves (they stopped within 0.5% on the same meshes).
        max_iterations : int
            ADMM iteration cap (a ConvergenceWarning is issued when it is reached).
        eps_rel, eps_rel_consensus, eps_rel_dual : float or None
            Relative stopping tolerances: r1 <= eps_rel max(|S_F G X S_V|, |S_F Z S_V|),
            rx1 <= eps_rel_consensus min(|S_V X S_V|, |S_V U S_V|),
            s1 <= eps_rel_dual max(|D Y M_V|, |A_V| |A_V| / 2), sx <= eps_rel_dual max(|S_V H S_V|, A / 2)
            (r2, s2, rx2 equal r1, s1, rx1 by symmetry; the floors are the scale of the X-step's
            load), plus the absolute terms of docs/method.md section 5 with ``tolerances.eps_abs`` (0 by
            default). All must be finite and > 0. None: from ``accuracy``.
        eps_change : float or None
            Change test, every ``tolerances.pairs_change_window`` (w) iterations: with
            c_k = max |U_k - U_(k - w)| / max U_k, stop only once c_k / (1 - c_k / c_(k - w)) (the
            rest of a geometric series at the last two windows' rate) is <= eps_change (math.inf:
            no change test, the residual test alone). None: from ``accuracy``.
        eps_excess : float or None
            Steepness test, at the same iterations: stop only once U breaks |grad U_j| <= 1 by at
            most max over elements e and columns j of (|grad U_j|_e - 1)_+ diam(e) <= eps_excess
            max U (:func:`~warp_regdist.solvers.stopping.gradient_excess`; the result's
            ``gradient_excess``). math.inf: no such test. None: from ``accuracy``.
        cg_fraction : float or None
            Each X-step's PCG stops at a residual of cg_fraction (|D Y_j| + |A_V| / 2) per column j
            (looser solves, 1e-2, can keep the residuals from ever meeting the stopping test).
            None: from ``accuracy``.
        callback : callable or None
            Called after every iteration as ``callback(progress)`` with a
            :class:`~warp_regdist.solvers.progress.Progress`: the iteration, the seconds, every stop
            test against its threshold (``checked`` at the iterations that measure them all, once per
            ``tolerances.pairs_change_window``) and the memory footprint.
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
        restart : bool
            Allow ``checkpoint`` to name an existing file that is not ``resume``: its progress is
            discarded and the run starts over.
        initial : str or os.PathLike or None
            A checkpoint of a run on the same mesh in the same dtype, of any alpha_hat and
            rho2_factor (continuation), to start from: its X, U, H and element state (the penalty
            schedule starts again). The result is this problem's minimizer; iterations, history and CG
            count are this run's.

        Returns
        -------
        AllPairsResult
            Ctrl-C (SIGINT) stops the run at the end of the current iteration: the result holds the
            current iterate with ``converged=False`` and ``interrupted=True`` (and the checkpoint is
            written); a second Ctrl-C raises KeyboardInterrupt at once. A result whose |grad| exceeds
            ``tolerances.max_gradient`` on some element and column is reported with ``converged=False``
            and a ConvergenceWarning, whatever its residuals (a consensus not yet settled). An
            unconverged result whose gradient excess lies on a triangle with an angle of at least
            ``OBTUSE_ANGLE`` degrees gets a second ConvergenceWarning naming that triangle.

        Raises
        ------
        ValueError
            Bad arguments, a footprint above the available memory or a checkpoint above the free
            disk space (the message gives both), a resume or initial file of another problem, or one
            that is not a complete checkpoint (truncated, foreign, arrays of other shapes or dtypes;
            read as data, never unpickled).
        """
        t0 = time.perf_counter()
        tol, mesh, dtype = tolerances, self.mesh, self.dtype
        chosen = accuracy_tolerances(_check_accuracy(accuracy), tol)
        for name, value in dict(eps_rel=eps_rel, eps_rel_consensus=eps_rel_consensus, eps_rel_dual=eps_rel_dual,
                                eps_change=eps_change, eps_excess=eps_excess, cg_fraction=cg_fraction).items():
            if value is not None:
                chosen[name] = value
        for name, value in list(chosen.items()) + [("checkpoint_seconds", checkpoint_seconds)]:
            if not (name in ("eps_change", "eps_excess") and value == math.inf):  # inf: no such test
                check_weight(value, name, positive=True)
        if callback is not None and not callable(callback):
            raise ValueError(f"expected callback as a callable or None, got {callback!r}")
        if not (isinstance(max_iterations, (int, np.integer)) and max_iterations >= 1):
            raise ValueError(f"expected max_iterations as an integer >= 1, got {max_iterations!r}")
        if resume is not None and initial is not None:
            raise ValueError(f"expected resume (the same problem) or initial (a warm start), got both: "
                             f"{os.fspath(resume)!r} and {os.fspath(initial)!r}")
        fingerprint = problem_fingerprint(mesh, self.alpha_hat, dtype, self.rho2_factor)
        settings = PairsSettings(eps_abs=tol.eps_abs, change_window=tol.pairs_change_window,
                                 relaxation=tol.relaxation, cg_rtol=tol.cg_rtol,
                                 cg_max_iterations=tol.cg_max_iterations, penalty_mid=self._penalty_mid,
                                 rho2_factor=self.rho2_factor, **chosen)
        size = checkpoint_bytes(mesh.n_vertices, mesh.n_elements, dtype, max_iterations)
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
                                                         ("mesh_sha256", "n_vertices", "dtype"), "initial"))
                     if initial is not None else None)
            memory = check_memory(mesh.n_vertices, mesh.n_elements, dtype, self.device)
            if saved is not None and "final" in saved:
                return self._flag_steep(final_result(saved, memory, checkpoint), chosen["eps_excess"])
            state = stack.enter_context(contextlib.closing(SymmetricADMM(
                mesh, self.operators, self.alpha_hat, self.device, dtype, settings, self.workers, self._auto_workers,
                self.hierarchy)))
            run = PairsRun(state, settings, self.schedule, memory, max_iterations, callback,
                           Checkpointing(checkpoint, checkpoint_seconds, fingerprint, size), self._excess)
            if saved is not None:
                run.restore(saved)
                if checkpoint is not None and os.path.exists(checkpoint) and os.path.samefile(checkpoint, resume):
                    run.saved_at = run.start
            if start is not None:
                run.warm_start(start)
            return self._flag_steep(run.iterate(t0), chosen["eps_excess"])

    def _flag_steep(self, res, eps_excess):
        """``res`` with its ``gradient_excess``, and with converged False and a ConvergenceWarning where
        max |G U| over elements and columns exceeds ``tolerances.max_gradient`` or is NaN; a second
        ConvergenceWarning names the triangle of an unconverged result whose excess is above
        ``eps_excess`` when that triangle has an angle of OBTUSE_ANGLE or more."""
        res.gradient_excess, element, column = self._steepest(res.distance)
        limit = tolerances.max_gradient
        steepest = np.max(self.operators.max_gradient(res.distance)) if res.converged else None
        if res.converged and not steepest <= limit:
            res.converged = False
            warnings.warn(f"all-pairs ADMM returned distances that break |grad U| <= 1 (max |grad U| {steepest:.3g}, "
                          f"above tolerances.max_gradient = {limit:g}) although its residual tests held: not converged; "
                          "more iterations or a smaller accuracy", ConvergenceWarning, stacklevel=3)
        if not res.converged and res.gradient_excess > eps_excess and element >= 0:
            angle = float(largest_angles(self.mesh.vertices, self.mesh.elements[[element]])[0])
            if angle >= OBTUSE_ANGLE:
                warnings.warn(f"all pairs: column {column} climbs {res.gradient_excess:.3g} of max U above unit speed "
                              f"across triangle {element}, whose largest angle is {angle:.0f} degrees: the iterations "
                              "settle slowly at obtuse triangles, and a mesh without them (Delaunay edge flips, "
                              "remeshing) converges sooner (docs/guides/all-pairs.md)", ConvergenceWarning, stacklevel=3)
        return res


def all_pairs(mesh, alpha_hat=0.03, device=None, dtype="float64", max_iterations=3000, accuracy=None, eps_rel=None,
              eps_rel_consensus=None, eps_rel_dual=None, rho2_factor=None, cg_fraction=None, callback=None,
              workers=None, checkpoint=None, checkpoint_seconds=300.0, resume=None, eps_change=None, schedule=None,
              initial=None, eps_excess=None, restart=False):
    """Symmetric all-pairs regularized distance matrix (Algorithm 2) on a connected triangle mesh:
    ``AllPairsSolver(mesh, alpha_hat, device, dtype, rho2_factor, schedule, workers).solve(...)`` with
    the other arguments (see :class:`AllPairsSolver` and :meth:`AllPairsSolver.solve`).

    Returns
    -------
    AllPairsResult
    """
    solver = AllPairsSolver(mesh, alpha_hat, device=device, dtype=dtype, rho2_factor=rho2_factor, schedule=schedule,
                            workers=workers)
    return solver.solve(accuracy=accuracy, max_iterations=max_iterations, eps_rel=eps_rel,
                        eps_rel_consensus=eps_rel_consensus, eps_rel_dual=eps_rel_dual, eps_change=eps_change,
                        eps_excess=eps_excess, cg_fraction=cg_fraction, callback=callback, checkpoint=checkpoint,
                        checkpoint_seconds=checkpoint_seconds, resume=resume, initial=initial, restart=restart)



def _penalty_mid(schedule, L):
    """sqrt(rho_start rho_end) / L of a schedule: of a PenaltySchedule its rho0 and rho_max, of
    another object its rho(0) and rho(10^6)."""
    if isinstance(schedule, PenaltySchedule):
        return math.sqrt(schedule.rho0 * schedule.rho_max)
    return math.sqrt(schedule.rho(0) * schedule.rho(10**6)) / L
