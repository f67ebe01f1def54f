"""The state of the symmetric all-pairs ADMM (:mod:`warp_regdist.solvers.all_pairs.solver`) and its steps,
split among CPU processes: the operators every part shares (``Setup``),
one part's arrays, PCG and launches (``_Part``), and the whole state with its worker processes
(``SymmetricADMM``)."""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import warp as wp

from ...kernels.all_pairs import all_pairs_kernels
from ...kernels.element_core import DY2, G2, R2, S2, Z2
from ...kernels.lanes import SCALARS, lane_type, lane_width, row_dim, thread_span
from ..common.device_mesh import DeviceMesh
from ...linalg.multigrid import smoothed_aggregation
from ...linalg.pcg import BatchedPCG
from ..common.processes import SharedArrays, WorkerPool, processes_available
from ..common.stopping import ESTIMATE_RATE_CAP

__all__ = ["PairsState", "SymmetricADMM", "middle_matrix", "STATE_ROWS"]


def middle_matrix(ops, rho2_factor, penalty_mid):
    """K2 / (alpha + rho) = W_D + (rho2_factor penalty_mid / A) M_V: the X-step matrix (within a factor)
    at the penalty ``penalty_mid`` (units of L), whose multigrid hierarchy preconditions every X-step."""
    return (ops.stiffness + (rho2_factor * penalty_mid / ops.total_volume) * sp.diags(ops.vertex_volumes)).tocsr()


def _even_splits(weights, parts):
    """Bounds b_0 = 0 <= ... <= b_parts = len(weights) cutting ``weights`` into ``parts`` runs of
    about equal sums (a run may be empty when single items outweigh a share)."""
    cum = np.concatenate([[0.0], np.cumsum(weights)])
    cuts = np.searchsorted(cum, cum[-1] * np.arange(1, parts) / parts)
    return np.concatenate([[0], np.clip(cuts, 0, len(weights)), [len(weights)]]).tolist()


class _Setup:
    """Host data that every part of the iteration needs (pickled to the worker processes): the
    operators ``ops``, the X-step matrix at the penalty ``penalty_mid`` (units of L) and its multigrid
    ``hierarchy`` when the caller has it (built here otherwise; neither with ``penalty_mid`` None, for
    an engine without X-step), the split into ``parts``, and the elements' ``constraints`` (a
    :class:`~warp_regdist.solvers.common.source_triangles.SourceTriangles` of ``ops``)."""

    def __init__(self, ops, alpha_hat, dtype, options, penalty_mid, parts, constraints, hierarchy=None):
        self.operators = ops
        self.constraints = constraints
        self.n, self.m = ops.vertex_volumes.size, ops.element_volumes.size
        self.dtype = dtype
        self.vertex_volumes = ops.vertex_volumes
        self.divergence = (ops.grad.T @ sp.diags(np.repeat(ops.element_volumes, 3))).tocsr()  # D = G^T M_F
        self.stiffness = ops.stiffness.tocsr()
        self.A, self.L = ops.total_volume, ops.length_scale
        self.alpha = alpha_hat * ops.length_scale
        self.W = lane_width(SCALARS[dtype], self.n)
        self.nb = -(-self.n // self.W)
        self.relaxation = options.relaxation
        # The multigrid hierarchy of K2 / (alpha + rho) at the geometric mean of the penalty schedule
        # (fewer CG iterations than at either end); the mass term keeps the constants, which
        # W_D's own hierarchy ignores, in the preconditioner.
        if penalty_mid is not None:
            self.K_mid = middle_matrix(ops, options.rho2_factor, penalty_mid)
            self.hierarchy = smoothed_aggregation(self.K_mid) if hierarchy is None else hierarchy
        self.blocks = _even_splits(np.ones(self.nb), parts)  # column blocks [b_t, b_t+1) of part t
        self.rows = _even_splits(self.nb - np.arange(self.nb), parts)  # consensus tile rows (row I: nb - I pairs)

    def matrix(self, stiffness_weight, mass_weight):
        """K2 = stiffness_weight W_D + mass_weight M_V."""
        return (stiffness_weight * self.stiffness + mass_weight * sp.diags(self.vertex_volumes)).tocsr()

    def state_specs(self):
        """Shapes and numpy dtypes of the iteration's state (lane axis last)."""
        n, m, nb, W, dt = self.n, self.m, self.nb, self.W, np.dtype(self.dtype)
        specs = {name: ((n, nb, W), dt) for name in STATE_ROWS}
        specs.update(v=((m, 3, nb, W), dt), rhs=((n, nb, W), dt), acc=((5, nb, W), dt), acc_pairs=((nb, 5), dt),
                     steep=((nb, W), dt))
        return specs


STATE_ROWS = ("X", "U", "H", "DZ", "DZ_acc", "DY_acc")
"""The (n, n) state arrays; with ``v`` (3m, n) they are what a checkpoint holds."""


def _free_entries(n, b0, b1, W, V, device):
    """The X-step's mask of column blocks [b0, b1): an (n, b1 - b0) array of lanes V, 1 on the
    entries the PCG solves for, 0 on padding columns (j >= n) and on each column's own vertex
    (X[j, j] = 0, as U[j, j] is: column j's X-step is the Dirichlet problem at vertex j). Written
    through the zero-copy view on the CPU (no second n x n copy while the state is allocated)."""
    mask = wp.zeros((n, b1 - b0), dtype=V, device=device)
    values = mask.numpy().reshape(n, -1) if device.is_cpu else np.zeros((n, (b1 - b0) * W))
    c0, c1 = b0 * W, min(b1 * W, n)
    values[:, :max(0, c1 - c0)] = 1
    own = np.arange(c0, c1)
    values[own, own - c0] = 0
    if not device.is_cpu:
        mask.assign(values.reshape(n, b1 - b0, W))
    return mask


def _lane_view(a, scalar, W, width):
    """``a`` (..., nb) of W-lane ``scalar`` vectors seen as (..., nb W / width) vectors of ``width`` lanes:
    the same memory, not a copy (the caller keeps ``a`` alive)."""
    if width == W:
        return a
    return wp.array(ptr=a.ptr, dtype=lane_type(scalar, width), shape=a.shape[:-1] + (a.shape[-1] * W // width,),
                    strides=a.strides[:-1] + (a.strides[-1] * width // W,), device=a.device)


def lanes_per_thread(device, W):
    """Lanes each thread of the lane-wise steps takes (:class:`_Part`): W on the CPU, 1 on CUDA."""
    return 1 if device.is_cuda else W


class _Part:
    """Part t of one iteration: column blocks [b_t, b_t+1) of the vertex, X- (its own PCG) and
    element steps, and consensus tile rows [i_t, i_t+1). Built in the calling process (t = 0)
    or in a worker process on the same shared state.

    The state is stored in lanes of W columns (the consensus step transposes W x W tiles). The
    lane-wise steps (vertex, X, element) take W lanes per thread on the CPU (SIMD within a core)
    and one column per thread on CUDA, through views of the same memory: the threads of a warp
    then read consecutive numbers and add to consecutive accumulators."""

    def __init__(self, setup, arrays, t):
        sc = SCALARS[setup.dtype]
        V = lane_type(sc, setup.W)
        if isinstance(arrays, SharedArrays):
            self._shared = arrays  # the mapping lives as long as its views
            arrays = {name: arrays.warp(name, sc if name == "acc_pairs" else V) for name in setup.state_specs()}
        self.setup = setup
        self.scalar = sc
        dev = arrays["X"].device
        n, m, nb, W = setup.n, setup.m, setup.nb, setup.W
        width = lanes_per_thread(dev, W)
        k, lane_step = all_pairs_kernels(sc, W), all_pairs_kernels(sc, width)
        b0, b1 = setup.blocks[t], setup.blocks[t + 1]
        i0, i1 = setup.rows[t], setup.rows[t + 1]
        cols = slice(b0, b1)
        lanes = (b1 - b0) * W // width  # the lane-wise launches' blocks

        def view(name, *index):
            return _lane_view(arrays[name][index + (cols,)], sc, W, width)

        area = np.zeros(nb * W)
        area[:n] = setup.vertex_volumes
        self.mesh = mesh = DeviceMesh(setup.operators, sc, dev, setup.constraints.directions)
        col0 = b0 * W if setup.constraints.active else -1   # the first column of these blocks (-1: no wedges)
        self._arrays = dict(lane_areas=wp.array(area.reshape(nb, W), dtype=V, device=dev),
                            mask=_free_entries(n, b0, b1, W, V, dev))
        a = self._arrays
        self.mask = _lane_view(a["mask"], sc, W, width)
        self.X, self.rhs = view("X", slice(None)), view("rhs", slice(None))
        # each process launches from one thread, so on the CPU the CG loop can be one captured graph
        self.pcg = BatchedPCG(setup.K_mid, sc, width, lanes, dev, preconditioner=setup.hierarchy, capture=dev.is_cpu)
        span = thread_span(dev, lanes, nb * W // width, n)
        self.vertex = wp.launch(lane_step.vertex_step, row_dim(n, span, lanes), device=dev, record_cmd=True,
                                inputs=[mesh.vertex_volumes, self.mask, sc(1.0), sc(1.0)]
                                + [view(name, slice(None)) for name in ("H", "U", "DZ_acc", "DY_acc", "DZ", "rhs", "acc")]
                                + [*span, n])
        span = thread_span(dev, lanes, nb * W // width, m)
        self.element = wp.launch(lane_step.element_step, row_dim(m, span, lanes), device=dev, record_cmd=True,
                                 inputs=[mesh.elements, mesh.basis, mesh.volumes, self.X, view("v", slice(None), slice(None)),
                                         sc(1.0), sc(1.0), sc(setup.relaxation), view("DZ_acc", slice(None)),
                                         view("DY_acc", slice(None)), view("acc", slice(None)), mesh.directions,
                                         col0, *span, m])
        self.steep = wp.launch(lane_step.steepness, row_dim(m, span, lanes), device=dev, record_cmd=True,
                               inputs=[mesh.elements, mesh.basis, mesh.diameters, view("U", slice(None)), view("steep"),
                                       mesh.directions, col0, *span, m])
        self.consensus = wp.launch(k.consensus_step, (i1 - i0, nb), device=dev, record_cmd=True, inputs=[
            arrays["X"], arrays["U"], arrays["H"], a["lane_areas"], sc(1.0), sc(setup.relaxation),
            arrays["acc_pairs"], i0, n]) if i1 > i0 else None
        self.columns = slice(b0 * W, b1 * W)

    def set_penalties(self, stiffness_weight, mass_weight):
        self.pcg.set_matrix(self.setup.matrix(stiffness_weight, mass_weight))

    def right_hand_side(self, rho, rho2):
        self.vertex.set_param_by_name("rho", self.scalar(rho))
        self.vertex.set_param_by_name("rho2", self.scalar(rho2))
        self.vertex.launch()

    def x_and_element_steps(self, atol, rtol, max_iterations, rho_v, rho):
        """The X-step's PCG on this part's columns, then their z/y-step; returns the CG iterations."""
        it, _ = self.pcg.solve(self.rhs, self.X, self.mask, rtol, max_iterations, atol[self.columns])
        self.element.set_param_by_name("rho_v", self.scalar(rho_v))
        self.element.set_param_by_name("rho", self.scalar(rho))
        self.element.launch()
        return it

    def steepness(self):
        self.steep.launch()

    def consensus_step(self, rho2):
        if self.consensus is not None:  # None: this part has no tile rows
            self.consensus.set_param_by_name("rho2", self.scalar(rho2))
            self.consensus.launch()


class PairsState:
    """What the all-pairs engines' states share (:class:`SymmetricADMM`, and
    :class:`~warp_regdist.solvers.all_pairs.eigenbasis.EigenbasisADMM`): the state ``arrays`` in lanes of
    ``setup.W`` columns, read and written as numpy, and the steepness of U (``_steepness`` launches it).

    ``change_rate_cap`` is the engine's q_max of the change test
    (:class:`~warp_regdist.solvers.common.stopping.ExtrapolatedChangeTest`): the change still to come counts at
    most 1 / (1 - q_max) windows."""

    change_rate_cap = ESTIMATE_RATE_CAP

    def close(self):
        """End the worker processes (none by default)."""

    def gradient_excess(self, top):
        """:func:`~warp_regdist.solvers.common.stopping.gradient_excess` of U, whose max is ``top``, on the device:
        max over elements e and columns j of (|(G U_j)_e| - 1)_+ diam(e) / top (0 where top is 0, NaN
        where it is not finite)."""
        if not math.isfinite(top):
            return math.nan
        self.arrays["steep"].zero_()
        self._steepness()
        worst = float(self.arrays["steep"].numpy().max())
        return worst / top if top > 0 else 0.0

    def divergences_from_element_state(self):
        """DZ_acc = DZ = D Z and DY_acc = rho_v D Y' from v (Z = Proj(v) onto each element's constraint set,
        Y' = v - Z), on the host: what the last element step scattered (D = G^T M_F, (n, 3m))."""
        D, m = self.setup.divergence, self.m
        v = self.view("v").astype(np.float64)
        z = self.setup.constraints.project(v.reshape(m, 3, -1), 0).reshape(v.shape)
        shape = self.arrays["DZ"].numpy().shape
        dz = (D @ z.reshape(3 * m, -1)).reshape(shape)
        for name in ("DZ", "DZ_acc"):
            self.put(name, dz)
        self.put("DY_acc", (self.rho_v * (D @ (v - z).reshape(3 * m, -1))).reshape(shape))

    def distance(self):
        """max(U, 0) as an (n, n) float64 array (the U-steps write the same value to U_ij and U_ji; the
        eigenbasis engine's U, unlike the consensus engine's, is not clipped at 0 by its U-step)."""
        return np.maximum(self.arrays["U"].numpy().reshape(self.n, -1)[:, :self.n], 0).astype(np.float64)

    def view(self, name):
        """State array ``name`` as numpy (lane axis last) without a copy on the CPU (a host copy on
        CUDA): valid until the next step writes it, for reading the state without doubling it."""
        return self.arrays[name].numpy()

    def put(self, name, values):
        self.arrays[name].assign(values)

    def load(self, saved, names):
        """State arrays ``names`` and ``rho_v`` from a checkpoint's ``saved`` arrays; X[j, j] at 0 whatever the
        file holds (the X-step keeps it there)."""
        for name in names:
            self.put(name, saved[name])
        self.clear_diagonal("X")
        self.rho_v = float(saved["rho_v"])

    def clear_diagonal(self, name):
        """State array ``name``[j, j] = 0 for every vertex j (in place on the CPU)."""
        j = np.arange(self.n)
        values = self.view(name)
        values[j, j // self.setup.W, j % self.setup.W] = 0
        if not self.arrays[name].device.is_cpu:
            self.put(name, values)


class SymmetricADMM(PairsState):
    """State and one iteration of the symmetric all-pairs ADMM (see the module docstring).

    On the CPU the iteration is split into up to ``workers`` parts (by default at most one
    per 10^6 pairs), each run by its own process on state in shared memory (a CPU launch runs on one
    core): the part in this process and the others in :class:`~warp_regdist.solvers.common.processes.WorkerPool`
    workers meet three times per iteration. Every sum that decides the iteration is made per
    column or per consensus tile row, so the iterates do not depend on the split.
    """

    engine = "consensus"
    # 40 windows: its PCG U-steps creep more slowly than 1 / k on obtuse meshes (docs/design/all-pairs.md)
    change_rate_cap = 0.975

    def __init__(self, ops, alpha_hat, device, dtype, options, penalty_mid, workers, constraints, auto_workers=False,
                 hierarchy=None):
        n = ops.vertex_volumes.size
        nb = -(-n // lane_width(SCALARS[dtype], n))
        parts = 1 if device.is_cuda or not processes_available() else min(workers, nb)
        if auto_workers:  # a worker process takes a few seconds to start: from 10^6 pairs per part
            parts = max(1, min(parts, n * n // 1_000_000))
        self.setup = setup = _Setup(ops, alpha_hat, dtype, options, penalty_mid, parts, constraints, hierarchy)
        self.n, self.m, self.A, self.L, self.alpha = setup.n, setup.m, setup.A, setup.L, setup.alpha
        self.column_area = np.zeros(setup.nb * setup.W)
        self.column_area[:n] = setup.vertex_volumes
        sc = SCALARS[dtype]
        V = lane_type(sc, setup.W)
        specs = setup.state_specs()
        self.shared = SharedArrays(specs) if parts > 1 else None
        self.arrays = {name: (self.shared.warp(name, sc if name == "acc_pairs" else V) if self.shared else
                              wp.zeros(shape[:-1] if name != "acc_pairs" else shape, dtype=sc if name == "acc_pairs"
                                       else V, device=device))
                       for name, (shape, _) in specs.items()}
        self.part = _Part(setup, self.arrays, 0)
        self.pool = (WorkerPool(_Part, (setup, self.shared), parts - 1, first_index=1, shared=[self.shared])
                     if parts > 1 else None)
        self.rho_v = 1.0  # the rho that formed v (any value while v = 0)
        self.penalties = None  # (rho, rho2) of the PCG matrices

    def close(self):
        """End the worker processes."""
        if self.pool is not None:
            self.pool.close()

    def _each(self, method, *args):
        """part.method(*args) in every part, this process's while the workers run theirs."""
        if self.pool is None:
            return [getattr(self.part, method)(*args)]
        self.pool.start(method, [args] * len(self.pool))
        try:
            mine = getattr(self.part, method)(*args)
        finally:
            others = self.pool.finish()
        return [mine] + others

    def set_penalties(self, rho, rho2):
        if (rho, rho2) != self.penalties:
            self._each("set_penalties", self.alpha + rho, rho2)
            self.penalties = (rho, rho2)

    def right_hand_side(self):
        """rhs of the X-step and D Z; returns per-column |D(Z - Z_old)|^2 and |D Y|^2 (nb W,)."""
        self.arrays["acc"].zero_()
        self._each("right_hand_side", *self.penalties)
        acc = self.arrays["acc"].numpy().reshape(5, -1)
        return acc[S2].astype(np.float64), acc[DY2].astype(np.float64)

    def linear_and_element_steps(self, atol, rtol, max_iterations):
        """X-step (PCG) then z/y-step of every part; returns the largest PCG iteration count."""
        self.arrays["acc"].zero_()
        rho = self.penalties[0]
        its = self._each("x_and_element_steps", atol, rtol, max_iterations, self.rho_v, rho)
        self.rho_v = rho
        return max(its)

    def coupling_step(self):
        """U/H-step; returns (per-column R2, G2, Z2 sums (3, nb W) of the element step, pair sums (5,))."""
        self.arrays["acc_pairs"].zero_()
        self._each("consensus_step", self.penalties[1])
        acc = self.arrays["acc"].numpy().reshape(5, -1)
        pairs = self.arrays["acc_pairs"].numpy().astype(np.float64).sum(axis=0)  # fixed order: tile rows
        return acc[[R2, G2, Z2]].astype(np.float64), pairs

    def _steepness(self):
        self._each("steepness")
