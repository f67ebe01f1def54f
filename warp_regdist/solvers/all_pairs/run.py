"""One all-pairs ADMM run on an engine's state (:class:`~warp_regdist.solvers.all_pairs.engine.PairsEngine`): the iteration
loop, the seven residuals, the change and steepness tests of docs/method.md section 8, checkpoints and
the result."""

from __future__ import annotations

import json
import math
import os
import time
import warnings

import numpy as np

from ..common import interrupt
from ..common.admm import CONVERGED, INTERRUPTED, run_iterations
from .forecast import ChangeTrend
from .state import STATE_ROWS
from ...errors import ConvergenceWarning
from ...kernels.all_pairs import H2, RX2, SX2, U2, X2
from ..common.processes import check_workers
from ..common.progress import Progress, StopTest
from ..common.stopping import ExtrapolatedChangeTest, cg_tolerance, dual_scale, tolerance
from ..common.results import AllPairsResult

__all__ = ["PairsRun", "final_result"]


def _estimate(change):
    """The result's ``change`` and ``error_estimate`` (the same number: the change still to come)."""
    return dict(change=change, error_estimate=change)


def final_result(saved, memory, checkpoint):
    """The result recorded in the checkpoint of a converged run."""
    fingerprint = json.loads(str(saved["fingerprint"]))
    n = int(fingerprint["n_vertices"])
    return AllPairsResult(distance=np.maximum(saved["U"].reshape(n, -1)[:, :n], 0).astype(np.float64),
                          iterations=int(saved["iteration"]),
                          converged=True, interrupted=False, residuals=saved["residuals"], tolerance=saved["tolerance"],
                          history=saved["history"], **_estimate(float(saved["change"][1]) if "change" in saved else math.inf),
                          cg_iterations=int(saved["cg_iterations"]), seconds=float(saved["seconds"]),
                          memory_bytes=memory, checkpoint=None if checkpoint is None else os.fspath(checkpoint),
                          checkpoint_iteration=None, engine=fingerprint["engine"])


class PairsRun:
    """The ADMM iterations of :func:`all_pairs` on an engine's state (a
    :class:`~warp_regdist.solvers.all_pairs.engine.PairsEngine`), with checkpoints.

    A checkpoint is the state at the top of an iteration: the state arrays, the penalties that
    formed the last iterate, the last element and consensus sums (the residuals of that
    iterate are computed from them) and the history; so a run restored from it repeats the
    uninterrupted run's arithmetic exactly.
    """

    def __init__(self, state, options, schedule, memory, callback, checkpoint, excess):
        self.state, self.options, self.schedule = state, options, schedule
        self.memory, self.max_iterations, self.callback = memory, options.max_iterations, callback
        self.checkpoint = checkpoint
        self.start = 0
        self.history = []
        self.cg_total = 0
        self.cols = self.pairs = None
        self.last_penalties = None
        self.seconds_before = 0.0
        # U as one column: its change test (snapshot, the last window's change, the change to come)
        self.change_test = ExtrapolatedChangeTest(options.change_window, options.eps_change, 1,
                                                  rate_cap=state.change_rate_cap)
        # stopping.gradient_excess of the U of the last change test (measured on the device); excess(U (n, n)):
        # the same on the host, for a checkpoint that does not record it
        self.excess, self.last_excess = excess, math.inf
        self.trend = ChangeTrend()   # this run's checks (a resumed run forecasts from its own)
        self.settling, self.warned_stall = True, False   # ChangeTrend.stalled at the last check; warned once

    def restore(self, saved):
        self.state.load(saved, STATE_ROWS + ("v",))
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
            if "excess" in saved:
                self.last_excess = float(saved["excess"])
            elif self.options.eps_excess < math.inf:  # a checkpoint without it: measured on the host
                n = self.state.n
                self.last_excess = self.excess(np.maximum(self.change_test.snapshot.reshape(n, -1)[:, :n], 0))

    def warm_start(self, saved):
        """Start from the iterate of checkpoint ``saved`` (another problem on this mesh): X, U, H, v
        and the divergences recomputed from v. The penalty schedule starts again (continuing it from
        the carried penalty took more iterations than a cold start: docs/design/all-pairs.md)."""
        st = self.state
        st.load(saved, ("X", "U", "H", "v"))
        st.divergences_from_element_state()
        self.change_test.reset(st.view("U").reshape(-1, 1))

    def save(self, it, seconds, final=None):
        """Write the state at the top of iteration ``it`` to the checkpoint; with ``final`` (dict of
        residuals, tolerance) the converged iterate and its result instead."""
        st = self.state
        data = {name: st.view(name) for name in (("X", "U", "H") if final else STATE_ROWS) + ("v",)}
        data.update(final or {})
        data.update(iteration=np.array(it), rho_v=np.array(st.rho_v), cg_iterations=np.array(self.cg_total),
                    seconds=np.array(seconds), history=np.array(self.history).reshape(-1, 7))
        if it > 0:
            data.update(penalties=np.array(self.last_penalties), cols=self.cols, pairs=self.pairs)
        change = self.change_test.state()
        if change["snapshot"] is not None:  # U's lane layout (n, nb, W)
            data.update(change_snapshot=change["snapshot"].reshape(st.n, st.setup.nb, st.setup.W),
                        change=np.array([change["window_change"][0], change["change"][0]]),
                        excess=np.array(self.last_excess))
        self.checkpoint.save(data, it)

    def _elapsed(self):
        return self.seconds_before + time.perf_counter() - self.t0

    def top(self, it):
        """The top of iteration ``it``: the checkpoint when one is due (after the first iteration of
        this run: every ``checkpoint_seconds``, at the iteration cap, on Ctrl-C), this iteration's
        penalties and the X-step's right-hand side (with the sums of the dual residual)."""
        if self.checkpoint is not None and it > self.start and (
                interrupt.requested() or it == self.max_iterations
                or time.perf_counter() - self.last_save >= self.checkpoint.seconds):
            self.save(it, self._elapsed())
            self.last_save = time.perf_counter()
        rho = self.schedule.rho(it)
        self.state.set_penalties(rho, self.options.rho2_factor * rho * rho / (self.state.L * self.state.A))
        self.s2, self.dy2 = self.state.right_hand_side()

    def status(self, it):
        """The seven residuals of the iterate after ``it`` iterations against their tolerances, the
        change test; history and the callback. True when all hold (the final checkpoint is written)."""
        if it == 0:
            return False
        st, tol, w = self.state, self.options, self.state.column_area
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
        due = self.change_test.due(it)
        if due:
            self.change_test.update(st.view("U").reshape(-1, 1), it)
            if tol.eps_excess < math.inf:
                self.last_excess = st.gradient_excess(float(np.max(self.change_test.snapshot)))
            self._follow_trend(it)
        if self.callback is not None:
            self.callback(Progress(it, self._elapsed(), self.tests(), checked=due, memory_bytes=self.memory,
                                   settling=self.settling))
        if np.all(res <= eps) and self.change_test.settled[0] and self.last_excess <= tol.eps_excess:
            if self.checkpoint is not None:
                self.save(it, self._elapsed(), dict(final=np.array(True), residuals=res, tolerance=eps))
            return True
        return False

    def _follow_trend(self, it):
        """Record the check of iteration ``it``; the first time the change still to come has reached no
        new low for many checks (ChangeTrend.stalled), a ConvergenceWarning that says so and what helps."""
        trend, tol = self.trend, self.options
        trend.add(it, float(self.change_test.change[0]))
        was_settling, self.settling = self.settling, not trend.stalled()
        if was_settling and not self.settling and not self.warned_stall:
            self.warned_stall = True
            low_at, low = trend.lowest()
            warnings.warn(f"all pairs is not settling: the change still to come has reached no new low since "
                          f"iteration {low_at} ({low:.3g}; now {trend.changes[-1]:.3g} at iteration {it}, threshold "
                          f"{tol.eps_change:.3g}), so the run may reach its cap ({self.max_iterations}) unconverged: "
                          "a larger accuracy stops sooner, and Ctrl-C (or SIGTERM) keeps the current iterate",
                          ConvergenceWarning, stacklevel=2)

    def tests(self):
        """The stopping rule's parts at the last test, as :class:`~warp_regdist.solvers.common.progress.StopTest`."""
        tol = self.options
        return (StopTest("max residual/tolerance", float(np.max(self.res / np.maximum(self.eps, 1e-300))), 1.0),
                StopTest("change to come", float(self.change_test.change[0]), tol.eps_change),
                StopTest("gradient excess", float(self.last_excess), tol.eps_excess))

    def advance(self, it, count):
        """Iterations it .. it + count - 1: X-step (PCG) and z/y-step, U/H-step; then the top of the next."""
        st, tol = self.state, self.options
        for j in range(it, it + count):
            atol = cg_tolerance(tol.cg_fraction, np.sqrt(self.dy2) + 0.5 * np.linalg.norm(st.setup.vertex_volumes))
            self.cg_total += st.linear_and_element_steps(atol, tol.cg_rtol, tol.cg_max_iterations)
            self.last_penalties = st.penalties
            self.cols, self.pairs = st.coupling_step()
            self.top(j + 1)

    def iterate(self, t0):
        """The loop (:func:`~warp_regdist.solvers.common.admm.run_iterations`) from ``self.start``; the AllPairsResult."""
        self.t0 = t0
        self.last_save = time.perf_counter()
        # Floors of the dual scales |D Y M_V| and |S_V H S_V|: the load (1/2) A_V 1^T that D Y and
        # M_V H balance in the X-step; Y (and H) vanish where no gradient constraint is active,
        # which can be everywhere (a large alpha_hat), and a test relative to them alone never holds.
        self.load_norm = 0.5 * np.linalg.norm(self.state.setup.vertex_volumes) * np.linalg.norm(self.state.column_area)
        self.res, self.eps = np.zeros(7), np.ones(7)
        with interrupt.catch_interrupt():
            self.top(self.start)
            it, reason = run_iterations(self, self.start, self.max_iterations, poll=check_workers)
        converged, interrupted = reason == CONVERGED, reason == INTERRUPTED
        res, eps, st = self.res, self.eps, self.state
        if not converged and not interrupted:
            tol = self.options
            warnings.warn(f"all-pairs ADMM did not converge in {self.max_iterations} iterations "
                          f"(max residual / tolerance {np.max(res / np.maximum(eps, 1e-300)):.3g}, change to come "
                          f"{self.change_test.change[0]:.3g} / eps_change {tol.eps_change:.3g}, gradient excess "
                          f"{self.last_excess:.3g} / eps_excess {tol.eps_excess:.3g})", ConvergenceWarning, stacklevel=3)
        return AllPairsResult(distance=st.distance(), iterations=it, converged=converged, interrupted=interrupted,
                              residuals=res, tolerance=eps, history=np.array(self.history).reshape(-1, 7),
                              **_estimate(float(self.change_test.change[0])),
                              cg_iterations=self.cg_total, seconds=self._elapsed(),
                              memory_bytes=self.memory,
                              checkpoint=None if self.checkpoint is None else self.checkpoint.path,
                              checkpoint_iteration=None if self.checkpoint is None else self.checkpoint.saved_at,
                              engine=st.engine)
