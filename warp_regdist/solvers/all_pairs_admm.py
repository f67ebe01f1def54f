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
divided by A_V[j]); the fused z/y-step over elements x columns; the fused U/H-step over
pairs of W x W tiles. Z and Y are stored together as one (3m, n) array (kernels/all_pairs.py).
The seven residuals of docs/method.md section 5 are computed (r2 = r1, s2 = s1, rx2 = rx1 by the
symmetry) and reported.

Penalties and stopping test (defaults chosen against exact minimizers, docs/guides/all-pairs.md):
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
import dataclasses
import json
import math
import os
import time
import warnings

import numpy as np

from . import interrupt
from .admm import CONVERGED, INTERRUPTED, PenaltySchedule, check_schedule, run_iterations
from .all_pairs_checkpoint import check_checkpoint_room, checkpoint_bytes, problem_fingerprint, read_checkpoint
from .all_pairs_state import STATE_ROWS, PairsSettings, SymmetricADMM, check_memory
from ..arguments import check_weight, parse_device, parse_workers
from ..errors import ConvergenceWarning
from ..file_lock import FileLock
from ..kernels.all_pairs import H2, RX2, SX2, U2, X2
from ..kernels.lanes import SCALARS
from .stopping import ExtrapolatedChangeTest, cg_tolerance, dual_scale, tolerance
from ..geometry.mesh import Mesh
from ..geometry.operators import build_operators
from ..tolerances import tolerances
from .results import AllPairsResult

__all__ = ["all_pairs"]


def all_pairs(mesh, alpha_hat=0.03, device=None, dtype="float64", max_iterations=3000, eps_rel=None,
              eps_rel_consensus=None, eps_rel_dual=None, rho2_factor=None, cg_fraction=None, progress=None,
              workers=None, checkpoint=None, checkpoint_seconds=300.0, resume=None, eps_change=None, schedule=None,
              initial=None):
    """Symmetric all-pairs regularized distance matrix (Algorithm 2) on a connected triangle mesh.

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
    max_iterations : int
        ADMM iteration cap (a ConvergenceWarning is issued when it is reached).
    eps_rel, eps_rel_consensus, eps_rel_dual : float
        Relative stopping tolerances: r1 <= eps_rel max(|S_F G X S_V|, |S_F Z S_V|),
        rx1 <= eps_rel_consensus min(|S_V X S_V|, |S_V U S_V|),
        s1 <= eps_rel_dual max(|D Y M_V|, |A_V| |A_V| / 2), sx <= eps_rel_dual max(|S_V H S_V|, A / 2)
        (r2, s2, rx2 equal r1, s1, rx1 by symmetry; the floors are the scale of the X-step's
        load), plus the absolute terms of docs/method.md section 5 with ``tolerances.eps_abs`` (0 by
        default). All must be finite and > 0. None (this and the other settings below):
        the ``tolerances.pairs_*`` setting of the same name (``tolerances.cg_fraction`` for
        cg_fraction). The settings are read once per call (:class:`PairsSettings`).
    rho2_factor : float
        rho2 = rho2_factor rho^2 / (sqrt(A) A): the consensus penalty grows like the square
        of the gradient penalty (the authors' initial values have rho2 = 5 rho / A).
    cg_fraction : float
        Each X-step's PCG stops at a residual of cg_fraction (|D Y_j| + |A_V| / 2) per column j
        (looser solves, 1e-2, can keep the residuals from ever meeting the stopping test).
    eps_change : float or None
        Change test, every ``tolerances.pairs_change_window`` (w) iterations: with
        c_k = max |U_k - U_(k - w)| / max U_k, stop only once c_k / (1 - c_k / c_(k - w)) (the
        rest of a geometric series at the last two windows' rate) is <= eps_change (math.inf:
        no change test, the residual test alone).
    schedule : PenaltySchedule or None
        The gradient penalty rho at iteration k = 0, 1, ...: a :class:`~warp_regdist.PenaltySchedule`
        or any object with ``rho(k)`` (absolute) and ``offset_for(penalty)``; rho2 follows from
        ``rho2_factor``. None: ``PenaltySchedule.all_pairs`` of ``tolerances`` (``rho0``,
        ``pairs_rho_max``, ``pairs_rho_doubling``, in units of sqrt(A)). The multigrid
        preconditioner targets the middle of its range. A checkpoint does not record it:
        resume with the same schedule.
    progress : callable or None
        Called after every iteration as progress(iteration, residuals (7,), tolerances (7,),
        elapsed seconds, memory bytes).
    workers : int or None
        CPU processes that share every step (at most one per column block). None: the cores
        available to this process, at most one per 10^6 pairs (a worker takes a few seconds to
        start). Ignored on CUDA and off Linux. The result does not depend on it.
    checkpoint : str or os.PathLike or None
        File (.npz) to which the whole state (iterates, duals, penalties, iteration count,
        residual history and the problem's fingerprint: mesh hash, alpha_hat, dtype,
        rho2_factor) is written atomically (a temporary file renamed over it) every
        ``checkpoint_seconds``, when the iteration cap is reached unconverged, when the
        run is interrupted, and at convergence (the final iterate and result: a warm start for
        ``initial``; resumed, it returns that result). Refused before any allocation when the
        file system lacks the room, or when another run is writing it (it holds the lock file
        ``checkpoint + ".lock"`` for the length of the run).
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

    Returns
    -------
    AllPairsResult
        Ctrl-C (SIGINT) stops the run at the end of the current iteration: the result holds the
        current iterate with ``converged=False`` and ``interrupted=True`` (and the checkpoint is
        written); a second Ctrl-C raises KeyboardInterrupt at once.

    Raises
    ------
    ValueError
        Bad arguments, a mesh with several connected components, vertices in no face, a
        footprint above the available memory or a checkpoint above the free disk space (the
        message gives both), a resume or initial file of another problem, or one that is not a
        complete checkpoint (truncated, foreign, arrays of other shapes or dtypes; read as
        data, never unpickled).
    """
    t0 = time.perf_counter()
    if not isinstance(mesh, Mesh):
        raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
    if mesh.element_dim != 2:
        raise ValueError(f"expected a triangle mesh, got {mesh.n_elements} tetrahedra")
    alpha_hat = check_weight(alpha_hat, "alpha_hat")
    tol = tolerances
    given = dict(eps_rel=eps_rel, eps_rel_consensus=eps_rel_consensus, eps_rel_dual=eps_rel_dual,
                 rho2_factor=rho2_factor, cg_fraction=cg_fraction, eps_change=eps_change)
    defaults = dict(eps_rel=tol.pairs_eps_rel, eps_rel_consensus=tol.pairs_eps_rel_consensus,
                    eps_rel_dual=tol.pairs_eps_rel_dual, rho2_factor=tol.pairs_rho2_factor, cg_fraction=tol.cg_fraction,
                    eps_change=tol.pairs_eps_change)
    chosen = {k: defaults[k] if v is None else v for k, v in given.items()}
    for name, value in list(chosen.items()) + [("checkpoint_seconds", checkpoint_seconds)]:
        if not (name == "eps_change" and value == math.inf):  # inf: no change test
            check_weight(value, name, positive=True)
    if schedule is not None:
        check_schedule(schedule)
    auto_workers = workers is None
    workers = parse_workers(workers)
    if progress is not None and not callable(progress):
        raise ValueError(f"expected progress as a callable or None, got {progress!r}")
    if dtype not in SCALARS:
        raise ValueError(f"expected dtype 'float64' or 'float32', got {dtype!r}")
    if not (isinstance(max_iterations, (int, np.integer)) and max_iterations >= 1):
        raise ValueError(f"expected max_iterations as an integer >= 1, got {max_iterations!r}")
    labels = mesh.components()
    if (labels < 0).any():
        raise ValueError(f"expected every vertex in a face, got {np.count_nonzero(labels < 0)} vertices in none "
                         f"(first: {np.flatnonzero(labels < 0)[0]})")
    if labels.max() > 0:
        raise ValueError(f"expected a connected mesh, got {labels.max() + 1} connected components "
                         "(solve each component separately)")
    fingerprint = problem_fingerprint(mesh, alpha_hat, dtype, chosen["rho2_factor"])
    ops = build_operators(mesh)  # once: for the schedule's scale and the state's setup
    L = ops.length_scale
    schedule = PenaltySchedule.all_pairs(tol, L) if schedule is None else schedule
    settings = PairsSettings(eps_abs=tol.eps_abs, change_window=tol.pairs_change_window, relaxation=tol.relaxation,
                             cg_rtol=tol.cg_rtol, cg_max_iterations=tol.cg_max_iterations,
                             penalty_mid=_penalty_mid(schedule, L), **chosen)
    if resume is not None and initial is not None:
        raise ValueError(f"expected resume (the same problem) or initial (a warm start), got both: {os.fspath(resume)!r} "
                         f"and {os.fspath(initial)!r}")
    if checkpoint is not None:
        check_checkpoint_room(checkpoint, checkpoint_bytes(mesh.n_vertices, mesh.n_elements, dtype, max_iterations))
    with contextlib.ExitStack() as stack:
        if checkpoint is not None:
            stack.enter_context(FileLock(checkpoint, "the checkpoint"))
        saved = read_checkpoint(resume, fingerprint, mesh.n_elements) if resume is not None else None
        start = (read_checkpoint(initial, fingerprint, mesh.n_elements, ("mesh_sha256", "n_vertices", "dtype"),
                                  "initial") if initial is not None else None)
        dev = parse_device(device)
        memory = check_memory(mesh.n_vertices, mesh.n_elements, dtype, dev)
        if saved is not None and "final" in saved:
            return _final_result(saved, memory, checkpoint)
        state = stack.enter_context(contextlib.closing(
            SymmetricADMM(mesh, ops, alpha_hat, dev, dtype, settings, workers, auto_workers)))
        run = _Run(state, settings, schedule, memory, max_iterations, progress,
                   Checkpointing(checkpoint, checkpoint_seconds, fingerprint))
        if saved is not None:
            run.restore(saved)
        if start is not None:
            run.warm_start(start)
        return run.iterate(t0)

def _penalty_mid(schedule, L):
    """sqrt(rho_start rho_end) / L of a schedule: of a PenaltySchedule its rho0 and rho_max, of
    another object its rho(0) and rho(10^6)."""
    if isinstance(schedule, PenaltySchedule):
        return math.sqrt(schedule.rho0 * schedule.rho_max)
    return math.sqrt(schedule.rho(0) * schedule.rho(10**6)) / L


@dataclasses.dataclass(frozen=True)
class Checkpointing:
    """Where (``path``, None: no checkpoints) and how often (``seconds``) a run writes its state,
    and the ``fingerprint`` of the problem written with it."""

    path: object
    seconds: float
    fingerprint: dict


def _final_result(saved, memory, checkpoint):
    """The result recorded in the checkpoint of a converged run."""
    n = int(json.loads(str(saved["fingerprint"]))["n_vertices"])
    return AllPairsResult(distance=saved["U"].reshape(n, -1)[:, :n].astype(np.float64), iterations=int(saved["iteration"]),
                          converged=True, interrupted=False, residuals=saved["residuals"], tolerance=saved["tolerance"],
                          history=saved["history"], change=float(saved["change"][1]) if "change" in saved else math.inf,
                          cg_iterations=int(saved["cg_iterations"]), seconds=float(saved["seconds"]),
                          memory_bytes=memory, checkpoint=None if checkpoint is None else os.fspath(checkpoint))


class _Run:
    """The ADMM iterations of :func:`all_pairs` on a :class:`SymmetricADMM`, with checkpoints.

    A checkpoint is the state at the top of an iteration: the state arrays, the penalties that
    formed the last iterate, the last element and consensus sums (the residuals of that
    iterate are computed from them) and the history; so a run restored from it repeats the
    uninterrupted run's arithmetic exactly.
    """

    def __init__(self, state, settings, schedule, memory, max_iterations, progress, checkpointing):
        self.state, self.settings, self.schedule = state, settings, schedule
        self.memory, self.max_iterations, self.progress = memory, max_iterations, progress
        self.checkpoint, self.checkpoint_seconds = checkpointing.path, checkpointing.seconds
        self.fingerprint = checkpointing.fingerprint
        self.start = 0
        self.history = []
        self.cg_total = 0
        self.cols = self.pairs = None
        self.last_penalties = None
        self.seconds_before = 0.0
        # U as one column: its change test (snapshot, the last window's change, the change to come)
        self.change_test = ExtrapolatedChangeTest(settings.change_window, settings.eps_change, 1)

    def restore(self, saved):
        st = self.state
        for name in STATE_ROWS + ("v",):
            st.put(name, saved[name])
        st.rho_v = float(saved["rho_v"])
        self.start = int(saved["iteration"])
        if self.start > 0:
            self.last_penalties = tuple(float(x) for x in saved["penalties"])
            self.cols, self.pairs = saved["cols"], saved["pairs"]
        self.history = list(saved["history"])
        self.cg_total = int(saved["cg_iterations"])
        self.seconds_before = float(saved["seconds"])
        if "change_snapshot" in saved:
            window_change, change = saved["change"]
            self.change_test.restore(dict(snapshot=saved["change_snapshot"].reshape(-1, 1),
                                          window_change=[window_change], change=[change]))

    def warm_start(self, saved):
        """Start from the iterate of checkpoint ``saved`` (another problem on this mesh): X, U, H, v
        and the divergences recomputed from v. The penalty schedule starts again: continued from
        the carried penalty, continuation in alpha_hat on a bumpy 162-vertex sphere took 850-1,300
        iterations where a cold start took 450-1,000, restarted 250-700."""
        st = self.state
        for name in ("X", "U", "H", "v"):
            st.put(name, saved[name])
        st.rho_v = float(saved["rho_v"])
        st.divergences_from_element_state()
        self.change_test.reset(st.get("U").reshape(-1, 1))

    def save(self, it, seconds, final=None):
        """Write the state at the top of iteration ``it`` to the checkpoint file, atomically; with
        ``final`` (dict of residuals, tolerance) the converged iterate and its result instead."""
        st = self.state
        data = {name: st.get(name) for name in (("X", "U", "H") if final else STATE_ROWS) + ("v",)}
        data.update(final or {})
        data.update(iteration=np.array(it), rho_v=np.array(st.rho_v), cg_iterations=np.array(self.cg_total),
                    seconds=np.array(seconds), history=np.array(self.history).reshape(-1, 7),
                    fingerprint=np.array(json.dumps(self.fingerprint)))
        if it > 0:
            data.update(penalties=np.array(self.last_penalties), cols=self.cols, pairs=self.pairs)
        change = self.change_test.state()
        if change["snapshot"] is not None:  # U's lane layout (n, nb, W)
            data.update(change_snapshot=change["snapshot"].reshape(st.n, st.setup.nb, st.setup.W),
                        change=np.array([change["window_change"][0], change["change"][0]]))
        path = os.fspath(self.checkpoint)
        tmp = f"{path}.tmp{os.getpid()}"
        try:
            with open(tmp, "wb") as f:
                np.savez(f, **data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.remove(tmp)

    def _elapsed(self):
        return self.seconds_before + time.perf_counter() - self.t0

    def top(self, it):
        """The top of iteration ``it``: the checkpoint when one is due (after the first iteration of
        this run: every ``checkpoint_seconds``, at the iteration cap, on Ctrl-C), this iteration's
        penalties and the X-step's right-hand side (with the sums of the dual residual)."""
        if self.checkpoint is not None and it > self.start and (
                interrupt.requested() or it == self.max_iterations
                or time.perf_counter() - self.last_save >= self.checkpoint_seconds):
            self.save(it, self._elapsed())
            self.last_save = time.perf_counter()
        rho = self.schedule.rho(it)
        self.state.set_penalties(rho, self.settings.rho2_factor * rho * rho / (self.state.L * self.state.A))
        self.s2, self.dy2 = self.state.right_hand_side()

    def status(self, it):
        """The seven residuals of the iterate after ``it`` iterations against their tolerances, the
        change test; history and progress. True when all hold (the final checkpoint is written)."""
        if it == 0:
            return False
        st, tol, w = self.state, self.settings, self.state.column_area
        n, m, A = st.n, st.m, st.A
        rho_old, rho2_old = self.last_penalties
        cols, pairs = self.cols, self.pairs
        r1 = math.sqrt(w @ cols[0])
        s1 = rho_old * math.sqrt((w * w) @ self.s2)
        rx = math.sqrt(pairs[RX2])
        sx = math.sqrt(2.0) * rho2_old * math.sqrt(pairs[SX2])
        eps_p = tolerance(tol.eps_abs * math.sqrt(3 * m) * A, tol.eps_rel, math.sqrt(max(w @ cols[1], w @ cols[2])))
        eps_d = tolerance(tol.eps_abs * math.sqrt(n) * A * A, tol.eps_rel_dual,
                          dual_scale(math.sqrt((w * w) @ self.dy2), self.load_norm))
        eps_x = tolerance(tol.eps_abs * math.sqrt(n) * A ** 1.5, tol.eps_rel_consensus,
                          math.sqrt(min(pairs[X2], pairs[U2])))
        eps_dx = tolerance(tol.eps_abs * math.sqrt(n) * A, tol.eps_rel_dual, dual_scale(math.sqrt(pairs[H2]), 0.5 * A))
        self.res = res = np.array([r1, r1, s1, s1, rx, rx, sx])
        self.eps = eps = np.array([eps_p, eps_p, eps_d, eps_d, eps_x, eps_x, eps_dx])
        self.history.append(res / np.maximum(eps, 1e-300))
        if self.progress is not None:
            self.progress(it, res, eps, self._elapsed(), self.memory)
        if self.change_test.due(it):
            self.change_test.update(st.get("U").reshape(-1, 1))
        if np.all(res <= eps) and self.change_test.settled[0]:
            if self.checkpoint is not None:
                self.save(it, self._elapsed(), dict(final=np.array(True), residuals=res, tolerance=eps))
            return True
        return False

    def advance(self, it, count):
        """Iterations it .. it + count - 1: X-step (PCG) and z/y-step, U/H-step; then the top of the next."""
        st, tol = self.state, self.settings
        for j in range(it, it + count):
            atol = cg_tolerance(tol.cg_fraction, np.sqrt(self.dy2) + 0.5 * np.linalg.norm(st.setup.vertex_volumes))
            self.cg_total += st.x_and_element_steps(atol, tol.cg_rtol, tol.cg_max_iterations)
            self.last_penalties = st.penalties
            self.cols, self.pairs = st.consensus()
            self.top(j + 1)

    def iterate(self, t0):
        """The loop (:func:`~warp_regdist.solvers.admm.run_iterations`) from ``self.start``; the AllPairsResult."""
        self.t0 = t0
        self.last_save = time.perf_counter()
        # Floors of the dual scales |D Y M_V| and |S_V H S_V|: the load (1/2) A_V 1^T that D Y and
        # M_V H balance in the X-step; Y (and H) vanish where no gradient constraint is active,
        # which can be everywhere (a large alpha_hat), and a test relative to them alone never holds.
        self.load_norm = 0.5 * np.linalg.norm(self.state.setup.vertex_volumes) * np.linalg.norm(self.state.column_area)
        self.res, self.eps = np.zeros(7), np.ones(7)
        with interrupt.catch_interrupt():
            self.top(self.start)
            it, reason = run_iterations(self, self.start, self.max_iterations)
        converged, interrupted = reason == CONVERGED, reason == INTERRUPTED
        res, eps, st = self.res, self.eps, self.state
        if not converged and not interrupted:
            warnings.warn(f"all-pairs ADMM did not converge in {self.max_iterations} iterations "
                          f"(max residual / tolerance {np.max(res / np.maximum(eps, 1e-300)):.3g})", ConvergenceWarning,
                          stacklevel=3)
        return AllPairsResult(distance=st.distance(), iterations=it, converged=converged, interrupted=interrupted,
                              residuals=res, tolerance=eps, history=np.array(self.history).reshape(-1, 7),
                              change=float(self.change_test.change[0]),
                              cg_iterations=self.cg_total, seconds=self._elapsed(),
                              memory_bytes=self.memory,
                              checkpoint=None if self.checkpoint is None else os.fspath(self.checkpoint))
