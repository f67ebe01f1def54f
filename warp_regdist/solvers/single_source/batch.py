"""One batched single-source ADMM on the device (Algorithm 1; docs/method.md sections 4 and 8):
its arrays (:class:`Workspace`), the stopping rule's constants the device test reads
(:func:`device_rule`), the iteration as recorded launches replayed as one Warp graph
(:class:`ColumnBatch`), and the loop's problem for :func:`~warp_regdist.solvers.common.admm.run_iterations`
(:class:`BatchIterations`)."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import warp as wp

from ...kernels.single_source import (CHANGE, DONE, DUAL_SCALE, EPS_DUAL, EPS_DUAL_ABS, EPS_PRI, ESTIMATE,
                                     ESTIMATE_OUT, IT_OUT, LANE_ROWS, LOAD_NORM, R_LAST, R_OUT, RHO_OUT, S_LAST, S_OUT,
                                     rule_struct, single_source_kernels)
from ...kernels.lanes import lane_kernels, row_dim, thread_span
from ..common.progress import Progress, StopTest
from ..common.stopping import ESTIMATE_RATE_CAP, tolerance

__all__ = ["Workspace", "device_rule", "ColumnBatch", "BatchIterations", "lanes", "collect", "RHO_TABLE"]

RHO_TABLE = 64
"""Entries of the device's penalty table rho_table (iteration it at it % RHO_TABLE; the host writes
each iteration's entry just before the replay that reads it)."""


@dataclasses.dataclass
class Workspace:
    """The device arrays of a batch of nb blocks of W lanes: (n, nb) per vertex, (m, 3, nb) per
    element, (nb,) or (rows, nb) per lane; the device-resident stopping test keeps u at the last
    change test (snapshot) and its |u - snapshot| per vertex (moved_last), the per-lane test state
    (lane), the iterates frozen when a lane's test first held (u_out, y_out), the counters (step),
    the penalty table (rho_table) and the (m,) int32 flags of the triangles at some source of the batch
    (touched: where the element step looks for wedges)."""

    width: int
    u: wp.array
    mask: wp.array
    Dy: wp.array
    Dz: wp.array
    rhs: wp.array
    z: wp.array
    y: wp.array
    rho: wp.array
    acc: wp.array
    snapshot: wp.array
    moved_last: wp.array
    u_out: wp.array
    lane: wp.array
    step: wp.array
    rho_table: wp.array
    touched: wp.array
    pcg: object
    y_out: wp.array | None = None


def device_rule(ops, regularizer, element_dim, options, free):
    """The constants of the device's stopping test and CG tolerance rule for a batch (a
    ``device_rule_type`` struct, float64: the caller converts it) and the initial per-lane rows
    (LANE_ROWS, slots) of its test; ``free`` (n, slots) is 1 on each column's free vertices.

    The test is r <= eps_pri_abs + eps_rel max(|G u|, |z|), s <= eps_dual_abs + eps_rel_dual
    max(|D y|, |A_V|), the change test eps_change and the error estimate's eps_estimate; the CG
    tolerance is min(cg_fraction dual scale, eps_dual / 10, cg_primal r (alpha + rho)) / (shift +
    scale rho); the penalty is reported in units of ``length``. Per slot the dual test's floor
    eps_abs sqrt(n_free) A and load |mask A_V|: the dual residual is measured against
    max(|mask D y|, |mask A_V|), since at the optimum A_V = alpha W u + D y on the free vertices and
    y = 0 where |G u| < 1, which can be everywhere (a large alpha_hat, boundary sources on a coarse
    mesh, a smooth Hessian-regularized u), so |D y| alone can vanish and a test relative to it never
    holds.
    """
    factor = regularizer.tolerance_factor
    L, A, m = ops.length_scale, ops.total_volume, ops.element_volumes.size
    eps_abs, eps_rel, eps_rel_dual = (factor * t for t in (options.eps_abs, options.eps_rel, options.eps_rel_dual))
    eps_dual_abs = np.sqrt(np.maximum(free.sum(axis=0), 1.0)) * eps_abs * A
    load_norm = np.sqrt(np.square(ops.vertex_volumes) @ free)
    lane = np.zeros((LANE_ROWS, free.shape[1]))
    lane[EPS_DUAL_ABS], lane[LOAD_NORM] = eps_dual_abs, load_norm
    lane[DUAL_SCALE], lane[EPS_DUAL] = eps_dual_abs + load_norm, tolerance(eps_dual_abs, eps_rel_dual, load_norm)
    lane[ESTIMATE] = np.inf
    # the u-step's right-hand side is divided by shift + scale rho: by alpha + rho for the rescaled Dirichlet matrix
    shift, scale = (regularizer.alpha, 1.0) if regularizer.rescaled else (1.0, 0.0)
    values = dict(
        eps_pri_abs=math.sqrt(3 * m) * eps_abs * math.sqrt(A), eps_rel=eps_rel, eps_rel_dual=eps_rel_dual,
        eps_change=factor * options.eps_change, eps_estimate=factor * options.eps_estimate,
        cg_fraction=factor * options.cg_fraction,
        # the CG residual also below a fraction of r, in the units of the u-step's (alpha + rho) W_D u:
        # r ~ L^(d/2), W_D u ~ L^(d-1) for element dimension d
        cg_primal=options.cg_primal_fraction * L ** (0.5 * element_dim - 1.0),
        alpha=regularizer.alpha, shift=shift, scale=scale, length=L)
    return values, lane


def collect(ws, frozen, slots, cols, out, y_out):
    """Columns ``cols`` of ``out`` (n, k) (and of ``y_out`` (m, 3, k) unless None) from lanes
    ``slots``: of the iterates frozen on the device, or with ``frozen`` False of the current ones."""
    u, y = (ws.u_out, ws.y_out) if frozen else (ws.u, ws.y)
    out[:, cols] = u.numpy().reshape(out.shape[0], -1)[:, slots]
    if y_out is not None:
        y_out[:, :, cols] = y.numpy().reshape(y_out.shape[0], 3, -1)[:, :, slots]


def lanes(values, nb, W):
    """(..., k) host values -> (..., nb, W) lane layout, zero-padded to nb W columns."""
    padded = np.zeros(values.shape[:-1] + (nb * W,))
    padded[..., :values.shape[-1]] = values
    return padded.reshape(values.shape[:-1] + (nb, W))


def _max_ratio(a, b):
    """max(a / b) over the entries with b > 0 (a column made of sources only has a = b = 0)."""
    return float(np.max(np.divide(a, b, out=np.zeros_like(a), where=b > 0), initial=0.0))


class BatchIterations:
    """One batched single-source ADMM as the problem of :func:`~warp_regdist.solvers.common.admm.run_iterations`.

    ``status`` reads the device's per-lane flags, collects the columns whose test first held
    (frozen on the device at that iterate) and reports progress to ``callback``; ``advance`` compacts
    the batch when columns left it, then runs iterations with the schedule's penalties (written one
    iteration ahead into the device's table, which the device's test reads); ``regularizer``'s u-step
    matrix is replaced in the PCG when rho changes (unless it is the rescaled W_D).
    """

    def __init__(self, ws, batch, regularizer, slot_col, k, keep_duals, schedule, offset, callback, t0):
        n, m = batch.mesh.n, batch.mesh.m
        self.ws, self.batch, self.regularizer, self.slot_col = ws, batch, regularizer, slot_col
        self.schedule, self.offset, self.callback, self.t0 = schedule, offset, callback, t0
        self.on_cpu = batch.mesh.device.is_cpu
        self.iterations = np.full(k, -1)
        self.out = np.zeros((n, k))
        self.y_out = np.zeros((m, 3, k)) if keep_duals else None
        self.r_out, self.s_out, self.rho_out, self.estimate_out = np.zeros(k), np.zeros(k), np.zeros(k), np.zeros(k)
        self.compact_due = False
        self.system_rho = None
        self.rho_table = ws.rho_table.numpy() if self.on_cpu else np.zeros(RHO_TABLE)
        self.penalty_ahead(0)
        batch.check()

    def penalty_ahead(self, it):
        """The penalty of iteration ``it`` into the device's table (read by that iteration's test)."""
        self.rho_table[it % RHO_TABLE] = self.schedule.rho(it + self.offset)
        if not self.on_cpu:
            self.ws.rho_table.assign(self.rho_table)

    def status(self, it):
        """Collect the columns done by iteration ``it``; True when all are."""
        W, slot_col = self.batch.W, self.slot_col
        state = self.ws.lane.numpy().reshape(LANE_ROWS, -1)
        live = self.batch.blocks * W
        new = np.flatnonzero((state[DONE, :live] > 0) & (slot_col[:live] >= 0))
        if new.size:  # each column as frozen at the iterate that met its stopping test
            cols = slot_col[new]
            self.iterations[cols] = state[IT_OUT, new]
            collect(self.ws, True, new, cols, self.out, self.y_out)
            self.r_out[cols], self.s_out[cols] = state[R_OUT, new], state[S_OUT, new]
            self.rho_out[cols], self.estimate_out[cols] = state[RHO_OUT, new], state[ESTIMATE_OUT, new]
            slot_col[new] = -1
        self.compact_due = new.size > 0
        if self.callback is not None:
            running = np.flatnonzero(slot_col[:live] >= 0)
            rule = self.batch.rule_values
            change = state[CHANGE, running]                 # the last window's, relative to max |u|
            tests = (StopTest("max r/eps_pri", _max_ratio(state[R_LAST, running], state[EPS_PRI, running]), 1.0),
                     StopTest("max s/eps_dual", _max_ratio(state[S_LAST, running], state[EPS_DUAL, running]), 1.0),
                     StopTest("max change", float(np.max(change, initial=0.0)), rule["eps_change"]),
                     StopTest("max error estimate", float(np.max(state[ESTIMATE, running], initial=0.0)),
                              rule["eps_estimate"]))
            self.callback(Progress(it, time.perf_counter() - self.t0, tests,
                                   checked=it > 0 and it % self.batch.window == 0, columns=self.iterations.size,
                                   columns_done=int(np.count_nonzero(self.iterations >= 0))))
        return bool(np.all(self.iterations >= 0))

    def advance(self, it, count):
        """Iterations it .. it + count - 1 (after moving the running columns into fewer blocks)."""
        if self.compact_due:
            self.batch.compact(self.slot_col)
            self.compact_due = False
        for j in range(it, it + count):
            rho = self.schedule.rho(j + self.offset)
            if not self.regularizer.rescaled and rho != self.system_rho:
                self.system_rho = rho
                self.ws.pcg.set_matrix(self.regularizer.system(rho))
            self.penalty_ahead(j + 1)
            self.batch.iterate()


class ColumnBatch:
    """The ADMM iteration of one batch as recorded launches over its first ``blocks`` column blocks,
    on the CPU (``capture``) replayed as one Warp graph (the u-step's CG loop a ``wp.capture_while``).

    :meth:`iterate` runs iteration it: the u-step (right-hand side, PCG), the element step,
    it += 1, then the top of iteration it + 1: the divergences, the change test, the stopping
    test with the next penalty and CG tolerances, and the freezing of the lanes whose test
    first held (kernels/single_source.py). :meth:`check` runs that top alone (iteration 0).

    When columns converge, :meth:`compact` moves the columns still running into the freed
    lanes of the first blocks and drops the emptied blocks from every launch, so a batch
    costs about the sum of its columns' iterations rather than its slowest column's
    iterations times the batch size.
    """

    def __init__(self, mesh, ws, W, nb, window, rule, relaxation, capture):
        self.mesh, self.ws, self.W = mesh, ws, W
        self.window, self.relaxation, self.rule_values = window, relaxation, rule
        self.rule = rule_struct(mesh.scalar, rule)
        self.kernels = single_source_kernels(mesh.scalar, W, mesh.elements.shape[1])
        self.move = lane_kernels(mesh.scalar, W).move_columns
        self.capture = capture and mesh.device.is_cpu  # on CUDA the CG loop would need conditional graph nodes
        self._record(nb)

    def _record(self, blocks):
        """Record the launches over column blocks 0..blocks-1 (their arguments stay fixed for the
        whole solve: rho, the tolerances and the counters live in device arrays) and capture them."""
        mesh, ws, kern = self.mesh, self.ws, self.kernels
        n, m, sc, dev = mesh.n, mesh.m, mesh.scalar, mesh.device
        span = thread_span(dev, blocks, ws.u.shape[1])
        self.blocks = blocks
        pcg = ws.pcg
        pcg.set_active_blocks(blocks)

        def rec(kernel, dim, *args):
            return wp.launch(kernel, dim, device=dev, record_cmd=True, inputs=list(args))

        elem_dim, vert_dim = row_dim(m, span, blocks), row_dim(n, span, blocks)
        values = self.rule_values
        self.u_step = rec(kern.u_rhs, vert_dim, mesh.vertex_volumes, ws.mask, ws.Dy, ws.Dz, ws.rho,
                          sc(values["shift"]), sc(values["scale"]), ws.rhs, *span, n)
        self.after_u = [
            rec(kern.element_step, elem_dim, mesh.elements, mesh.basis, mesh.volumes, ws.u, ws.rho,
                sc(self.relaxation), ws.z, ws.y, ws.mask, ws.touched, mesh.directions, ws.acc, *span, m),
            rec(kern.advance, 1, ws.step, pcg.counters)]
        self.top = [
            rec(kern.vertex_divergence, vert_dim, mesh.vertex_offsets, mesh.incident, mesh.pair_weights, ws.mask,
                ws.y, ws.z, ws.Dy, ws.Dz, ws.acc, *span, n),
            rec(kern.change_measure, vert_dim, ws.u, ws.snapshot, ws.moved_last, ws.step, self.window,
                sc(ESTIMATE_RATE_CAP), ws.lane, *span, n),
            rec(kern.admm_check, blocks, ws.acc, ws.lane, ws.rho, ws.step, ws.rho_table, self.window, self.rule,
                pcg.atol2),
            rec(kern.freeze_lanes, vert_dim, ws.lane, ws.u, ws.u_out, *span, n)]
        if ws.y_out is not None:
            y, y_out = (a.reshape((3 * m, a.shape[2])) for a in (ws.y, ws.y_out))
            self.top.append(rec(kern.freeze_lanes, row_dim(3 * m, span, blocks), ws.lane, y, y_out, *span, 3 * m))
        self.graph = None
        if self.capture:
            wp.capture_begin(dev, force_module_load=False)
            try:
                self._launch_iteration(pcg.capture_solve)
            finally:
                self.graph = wp.capture_end(dev)

    def _launch_iteration(self, solve):
        self.u_step.launch()
        solve(self.ws.rhs, self.ws.u, self.ws.mask)
        for launch in self.after_u + self.top:
            launch.launch()

    def check(self):
        """The top of the current iteration alone (divergences, change and stopping tests, freezing)."""
        for launch in self.top:
            launch.launch()

    def iterate(self):
        """One iteration and the top of the next (the graph's replay on the CPU)."""
        if self.graph is not None:
            wp.capture_launch(self.graph)
        else:
            self._launch_iteration(self.ws.pcg.run)

    def compact(self, slot_col):
        """Move running columns out of the last blocks when they fit in fewer.

        ``slot_col`` (slots,) maps slot -> column (-1: free); it is permuted in place like the
        device state (iterates, mask, D y, D z, change-test snapshot and moves, per-lane test state, CG tolerances).
        """
        W, live = self.W, self.blocks * self.W
        running = np.flatnonzero(slot_col[:live] >= 0)
        blocks = max(1, -(-running.size // W))
        if blocks == self.blocks:
            return
        keep = blocks * W
        src = running[running >= keep]
        dst = np.flatnonzero(slot_col[:keep] < 0)[:src.size]
        if src.size:
            ws, dev = self.ws, self.mesh.device
            span = thread_span(dev)
            s_arr = wp.array(src.astype(np.int32), dtype=wp.int32, device=dev)
            d_arr = wp.array(dst.astype(np.int32), dtype=wp.int32, device=dev)
            nb = ws.u.shape[1]
            # Dy and Dz too: the u-step reads this iteration's, the next divergence step the old D z
            # and the CG tolerances that the last test set for the next u-step
            moved = ("u", "mask", "z", "y", "Dy", "Dz", "snapshot", "moved_last", "lane")
            for a in [getattr(ws, name) for name in moved] + [ws.pcg.atol2]:
                a2 = a.reshape((1, nb)) if a.ndim == 1 else a if a.ndim == 2 else a.reshape((a.shape[0] * a.shape[1], nb))
                wp.launch(self.move, row_dim(a2.shape[0], span), device=dev,
                          inputs=[a2, s_arr, d_arr, src.size, span[0], a2.shape[0]])
            slot_col[dst], slot_col[src] = slot_col[src], -1
        self._record(blocks)
