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
rho_k = sqrt(A) min(rho_max, rho0 2^(k / rho_doubling)) (``tolerances.pairs_rho0``,
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
import json
import math
import os
import shutil
import time
import warnings
import zipfile

import numpy as np
import scipy.sparse as sp
import warp as wp
from scipy.optimize import OptimizeResult

from .kernels.all_pairs import H2, RX2, SX2, U2, X2, all_pairs_kernels
from .kernels.lanes import DY2, G2, R2, S2, SCALARS, Z2, lane_type, lane_width, row_dim, thread_span
from .mesh import Mesh
from .multigrid import smoothed_aggregation
from .operators import build_operators
from .pcg import BatchedPCG
from .processes import SharedArrays, WorkerPool, processes_available
from . import interrupt
from .admm import CONVERGED, INTERRUPTED, ExtrapolatedChangeTest, PenaltySchedule, check_schedule, run_iterations
from .arguments import check_weight, parse_device, parse_workers
from .file_lock import FileLock
from .errors import ConvergenceWarning
from .tolerances import tolerances

__all__ = ["all_pairs", "AllPairsResult", "RESIDUAL_NAMES"]

RESIDUAL_NAMES = ("r1", "r2", "s1", "s2", "rx1", "rx2", "sx")
"""The seven residuals of docs/method.md section 5, in the order of ``AllPairsResult.residuals``."""


class AllPairsResult(OptimizeResult):
    """Result of :func:`all_pairs`.

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
    change : float
        The change of U still to come estimated at the last change test, in units of max U
        (inf before the third test, or while the change grows; see ``eps_change``).
    cg_iterations : int
        PCG iterations summed over ADMM iterations (the largest count among the worker processes).
    seconds : float
    memory_bytes : int
        Estimated footprint of the solver's arrays (device and host).
    """


def _available_memory(device):
    """Bytes available on the device (MemAvailable of /proc/meminfo for the CPU)."""
    if device.is_cuda:
        return int(device.free_memory)
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")


def memory_estimate(n, m, dtype="float64", device="cpu"):
    """Bytes needed by :func:`all_pairs` for n vertices and m triangles.

    Device arrays of n x (n padded to the lane width W) numbers each: X, U, H, DZ, rhs and
    the scattered divergences D Z, D Y (7), the PCG's r, z, p, q (4), the multigrid levels
    (~0.15 n per column, counted as n), the combined z/y state (3 m columns' worth); plus the float64 (n, n) result on the host,
    the U of the last change test in the solver's precision (and, on a GPU, the copy back to
    the host in the solver's precision).
    """
    W = lane_width(SCALARS[dtype], n)
    cols = -(-n // W) * W
    size = np.dtype(dtype).itemsize
    device_bytes = size * cols * (12 * n + 3 * m)
    host_bytes = 8 * n * n + size * n * cols * (2 if wp.get_device(device).is_cuda else 1)
    return device_bytes, host_bytes


def _even_splits(weights, parts):
    """Bounds b_0 = 0 <= ... <= b_parts = len(weights) cutting ``weights`` into ``parts`` runs of
    about equal sums (a run may be empty when single items outweigh a share)."""
    cum = np.concatenate([[0.0], np.cumsum(weights)])
    cuts = np.searchsorted(cum, cum[-1] * np.arange(1, parts) / parts)
    return np.concatenate([[0], np.clip(cuts, 0, len(weights)), [len(weights)]]).tolist()


class _Setup:
    """Host data that every part of the iteration needs (pickled to the worker processes)."""

    def __init__(self, mesh, alpha_hat, dtype, rho2_factor, parts):
        self.n, self.m = mesh.n_vertices, mesh.n_elements
        self.dtype = dtype
        ops = build_operators(mesh)
        self.elements = mesh.elements.astype(np.int32)
        self.basis, self.volumes, self.vertex_volumes = ops.basis, ops.element_volumes, ops.vertex_volumes
        self.divergence = (ops.grad.T @ sp.diags(np.repeat(ops.element_volumes, 3))).tocsr()  # D = G^T M_F
        self.stiffness = ops.stiffness.tocsr()
        self.A, self.L = ops.total_volume, ops.length_scale
        self.alpha = alpha_hat * ops.length_scale
        self.W = lane_width(SCALARS[dtype], self.n)
        self.nb = -(-self.n // self.W)
        self.relaxation = tolerances.relaxation
        # The multigrid hierarchy of K2 / (alpha + rho) at the geometric mean of the penalty schedule
        # (fewer CG iterations on cat than at either end); the mass term keeps the constants, which
        # W_D's own hierarchy ignores, in the preconditioner.
        self.K_mid = self.matrix(1.0, rho2_factor * math.sqrt(tolerances.pairs_rho0 * tolerances.pairs_rho_max)
                                 / self.A)
        self.hierarchy = smoothed_aggregation(self.K_mid)
        self.blocks = _even_splits(np.ones(self.nb), parts)  # column blocks [b_t, b_t+1) of part t
        self.rows = _even_splits(self.nb - np.arange(self.nb), parts)  # consensus tile rows (row I: nb - I pairs)

    def matrix(self, stiffness_weight, mass_weight):
        """K2 = stiffness_weight W_D + mass_weight M_V."""
        return (stiffness_weight * self.stiffness + mass_weight * sp.diags(self.vertex_volumes)).tocsr()

    def state_specs(self):
        """Shapes and numpy dtypes of the iteration's state (lane axis last)."""
        n, m, nb, W, dt = self.n, self.m, self.nb, self.W, np.dtype(self.dtype)
        specs = {name: ((n, nb, W), dt) for name in STATE_ROWS}
        specs.update(v=((m, 3, nb, W), dt), rhs=((n, nb, W), dt), acc=((5, nb, W), dt), acc_pairs=((nb, 5), dt))
        return specs


STATE_ROWS = ("X", "U", "H", "DZ", "DZ_acc", "DY_acc")
"""The (n, n) state arrays; with ``v`` (3m, n) they are what a checkpoint holds."""


class _Part:
    """Part t of one iteration: column blocks [b_t, b_t+1) of the vertex, X- (its own PCG) and
    element steps, and consensus tile rows [i_t, i_t+1). Built in the calling process (t = 0)
    or in a worker process on the same shared state."""

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
        k = all_pairs_kernels(sc, W)
        b0, b1 = setup.blocks[t], setup.blocks[t + 1]
        i0, i1 = setup.rows[t], setup.rows[t + 1]
        cols = slice(b0, b1)
        span = thread_span(dev, b1 - b0, nb)
        area = np.zeros(nb * W)
        area[:n] = setup.vertex_volumes
        self._arrays = dict(
            elements=wp.array(setup.elements, dtype=wp.int32, device=dev),
            basis=wp.array(setup.basis, dtype=wp.types.vector(3, sc), device=dev),
            volumes=wp.array(setup.volumes, dtype=sc, device=dev),
            vertex_volumes=wp.array(setup.vertex_volumes, dtype=sc, device=dev),
            lane_areas=wp.array(area.reshape(nb, W), dtype=V, device=dev),
            # one row of column masks (1 on real columns, 0 on padding), broadcast to n rows by a zero stride
            mask_row=wp.array((area > 0).astype(np.float64)[b0 * W:b1 * W].reshape(1, b1 - b0, W), dtype=V,
                              device=dev))
        a = self._arrays
        self.mask = wp.array(ptr=a["mask_row"].ptr, shape=(n, b1 - b0), strides=(0, a["mask_row"].strides[1]),
                             dtype=V, device=dev)
        self.X, self.rhs = arrays["X"][:, cols], arrays["rhs"][:, cols]
        # each process launches from one thread, so on the CPU the CG loop can be one captured graph
        self.pcg = BatchedPCG(setup.K_mid, sc, W, b1 - b0, dev, preconditioner=setup.hierarchy, capture=dev.is_cpu)
        self.vertex = wp.launch(k.vertex_step, row_dim(n, span, b1 - b0), device=dev, record_cmd=True,
                                inputs=[a["vertex_volumes"], self.mask, sc(1.0), sc(1.0)]
                                + [arrays[name][:, cols] for name in ("H", "U", "DZ_acc", "DY_acc", "DZ", "rhs", "acc")]
                                + [*span, n])
        self.element = wp.launch(k.element_step, row_dim(m, span, b1 - b0), device=dev, record_cmd=True,
                                 inputs=[a["elements"], a["basis"], a["volumes"], self.X, arrays["v"][:, :, cols],
                                         sc(1.0), sc(1.0), sc(setup.relaxation), arrays["DZ_acc"][:, cols],
                                         arrays["DY_acc"][:, cols], arrays["acc"][:, cols], *span, m])
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

    def consensus_step(self, rho2):
        if self.consensus is not None:  # None: this part has no tile rows
            self.consensus.set_param_by_name("rho2", self.scalar(rho2))
            self.consensus.launch()


class _SymmetricADMM:
    """State and one iteration of the symmetric all-pairs ADMM (see the module docstring).

    On the CPU the iteration is split into up to ``workers`` parts (by default at most one
    per 10^6 pairs), each run by its own process on state in shared memory (a CPU launch runs on one
    core): the part in this process and the others in :class:`~warp_regdist.processes.WorkerPool`
    workers meet three times per iteration. Every sum that decides the iteration is made per
    column or per consensus tile row, so the iterates do not depend on the split.
    """

    def __init__(self, mesh, alpha_hat, device, dtype, rho2_factor, workers, auto_workers=False):
        n = mesh.n_vertices
        nb = -(-n // lane_width(SCALARS[dtype], n))
        parts = 1 if device.is_cuda or not processes_available() else min(workers, nb)
        if auto_workers:  # a worker process takes a few seconds to start: from 10^6 pairs per part
            parts = max(1, min(parts, n * n // 1_000_000))
        self.setup = setup = _Setup(mesh, alpha_hat, dtype, rho2_factor, parts)
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

    def x_and_element_steps(self, atol, rtol, max_iterations):
        """X-step (PCG) then z/y-step of every part; returns the largest PCG iteration count."""
        self.arrays["acc"].zero_()
        rho = self.penalties[0]
        its = self._each("x_and_element_steps", atol, rtol, max_iterations, self.rho_v, rho)
        self.rho_v = rho
        return max(its)

    def consensus(self):
        """U/H-step; returns (per-column R2, G2, Z2 sums (3, nb W) of the element step, pair sums (5,))."""
        self.arrays["acc_pairs"].zero_()
        self._each("consensus_step", self.penalties[1])
        acc = self.arrays["acc"].numpy().reshape(5, -1)
        pairs = self.arrays["acc_pairs"].numpy().astype(np.float64).sum(axis=0)  # fixed order: tile rows
        return acc[[R2, G2, Z2]].astype(np.float64), pairs

    def divergences_from_element_state(self):
        """DZ_acc = DZ = D Z and DY_acc = rho_v D Y' from v (Z = Proj(v), Y' = v - Z), on the host:
        what the last element step scattered (D = G^T M_F, (n, 3m))."""
        D, m = self.setup.divergence, self.m
        v = self.get("v").astype(np.float64)
        z = v / np.maximum(1.0, np.sqrt(np.square(v).sum(axis=1, keepdims=True)))
        shape = self.arrays["DZ"].numpy().shape
        dz = (D @ z.reshape(3 * m, -1)).reshape(shape)
        for name in ("DZ", "DZ_acc"):
            self.put(name, dz)
        self.put("DY_acc", (self.rho_v * (D @ (v - z).reshape(3 * m, -1))).reshape(shape))

    def distance(self):
        """U as an (n, n) float64 array (the U-step writes the same value to U_ij and U_ji)."""
        return self.arrays["U"].numpy().reshape(self.n, -1)[:, :self.n].astype(np.float64)

    def get(self, name):
        """A copy of state array ``name`` as numpy (lane axis last)."""
        return np.array(self.arrays[name].numpy())

    def put(self, name, values):
        self.arrays[name].assign(values)


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
        default). All must be finite and > 0. None (this and the other tolerances below):
        the ``tolerances.pairs_*`` setting of the same name.
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
        ``rho2_factor``. None: ``PenaltySchedule.all_pairs`` of ``tolerances`` (``pairs_rho0``,
        ``pairs_rho_max``, ``pairs_rho_doubling``, in units of sqrt(A)). A checkpoint does not
        record it: resume with the same schedule.
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
    settings = dict(eps_rel=eps_rel, eps_rel_consensus=eps_rel_consensus, eps_rel_dual=eps_rel_dual,
                    rho2_factor=rho2_factor, cg_fraction=cg_fraction, eps_change=eps_change)
    settings = {k: getattr(tolerances, f"pairs_{k}") if v is None else v for k, v in settings.items()}
    for name, value in list(settings.items()) + [("checkpoint_seconds", checkpoint_seconds)]:
        if not (name == "eps_change" and value == math.inf):  # inf: no change test
            check_weight(value, name, positive=True)
    eps_rel, eps_rel_consensus, eps_rel_dual, rho2_factor, cg_fraction, eps_change = settings.values()
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
    fingerprint = _fingerprint(mesh, alpha_hat, dtype, rho2_factor)
    if resume is not None and initial is not None:
        raise ValueError(f"expected resume (the same problem) or initial (a warm start), got both: {os.fspath(resume)!r} "
                         f"and {os.fspath(initial)!r}")
    if checkpoint is not None:
        _check_checkpoint_room(checkpoint, checkpoint_bytes(mesh.n_vertices, mesh.n_elements, dtype, max_iterations))
    with contextlib.ExitStack() as stack:
        if checkpoint is not None:
            stack.enter_context(FileLock(checkpoint, "the checkpoint"))
        saved = _read_checkpoint(resume, fingerprint, mesh.n_elements) if resume is not None else None
        start = (_read_checkpoint(initial, fingerprint, mesh.n_elements, ("mesh_sha256", "n_vertices", "dtype"),
                                  "initial") if initial is not None else None)
        dev = parse_device(device)
        memory = _check_memory(mesh.n_vertices, mesh.n_elements, dtype, dev)
        if saved is not None and "final" in saved:
            return _final_result(saved, memory, checkpoint)
        state = stack.enter_context(contextlib.closing(
            _SymmetricADMM(mesh, alpha_hat, dev, dtype, rho2_factor, workers, auto_workers)))
        run = _Run(state, memory, max_iterations, eps_rel, eps_rel_consensus, eps_rel_dual, rho2_factor,
                   cg_fraction, progress, checkpoint, checkpoint_seconds, fingerprint, eps_change,
                   PenaltySchedule.all_pairs(tolerances, state.L) if schedule is None else schedule)
        if saved is not None:
            run.restore(saved)
        if start is not None:
            run.warm_start(start)
        return run.iterate(t0)


def _check_memory(n, m, dtype, dev):
    """The footprint (bytes) of an all-pairs run; ValueError when it exceeds the available memory."""
    device_bytes, host_bytes = memory_estimate(n, m, dtype, dev)
    if dev.is_cuda:
        cpu_available = _available_memory(wp.get_device("cpu"))
        if device_bytes > _available_memory(dev) or host_bytes > cpu_available:
            raise ValueError(f"expected enough memory for {n} vertices in {dtype}: needs {device_bytes / 1e9:.2f} GB "
                             f"on {dev} and {host_bytes / 1e9:.2f} GB on the host, got {_available_memory(dev) / 1e9:.2f} "
                             f"GB and {cpu_available / 1e9:.2f} GB available")
    else:
        available = _available_memory(dev)
        if device_bytes + host_bytes > available:
            raise ValueError(f"expected enough memory for {n} vertices in {dtype}: needs "
                             f"{(device_bytes + host_bytes) / 1e9:.2f} GB, got {available / 1e9:.2f} GB available"
                             + (" (float32 halves it)" if dtype == "float64" else ""))
    return device_bytes + host_bytes


def checkpoint_bytes(n, m, dtype, max_iterations):
    """Upper bound of the size of an all-pairs checkpoint file: the (n, n) state arrays and the
    (3m, n) element state in ``dtype`` (lanes padded), the residual history, small scalars."""
    W = lane_width(SCALARS[dtype], n)
    cols = -(-n // W) * W
    return (np.dtype(dtype).itemsize * cols * ((len(STATE_ROWS) + 1) * n + 3 * m + 8)  # + the change test's U
            + 56 * (max_iterations + 1) + 65536)


def _check_checkpoint_room(path, size):
    """ValueError unless ``path`` can be written and its file system has ``size`` bytes free."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise ValueError(f"expected checkpoint in an existing directory, got {path!r} (no directory {folder!r})")
    if os.path.isdir(path) or not os.access(folder, os.W_OK):
        raise ValueError(f"expected checkpoint as a writable file name, got {path!r}")
    free = shutil.disk_usage(folder).free
    if size > free:
        raise ValueError(f"expected {size / 1e9:.2f} GB free for the checkpoint {path!r}, got {free / 1e9:.2f} GB "
                         f"free on its file system")


def _fingerprint(mesh, alpha_hat, dtype, rho2_factor):
    """What identifies the problem of a checkpoint (JSON-able dict)."""
    return dict(mesh_sha256=mesh.sha256(), n_vertices=int(mesh.n_vertices), alpha_hat=float(alpha_hat),
                dtype=dtype, rho2_factor=float(rho2_factor))


def _read_checkpoint(path, fingerprint, n_elements, keys=None, role="resume"):
    """The arrays of checkpoint ``path`` (the ``role`` argument) after checking that it agrees with
    ``fingerprint`` on ``keys`` (None: all, the same problem) and holds the arrays of that problem."""
    path = os.fspath(path)
    try:
        with np.load(path, allow_pickle=False) as f:
            saved = {k: f[k] for k in f.files}
        theirs = json.loads(str(saved["fingerprint"]))
        if not isinstance(theirs, dict):
            raise ValueError(f"a fingerprint {theirs!r}")
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, TypeError) as exc:
        raise ValueError(f"expected {role} as an all-pairs checkpoint (.npz), got {path!r} "
                         f"({type(exc).__name__}: {exc})") from None
    differ = [k for k in (fingerprint if keys is None else keys) if theirs.get(k) != fingerprint[k]]
    if differ:
        shown = ", ".join(f"{k} {fingerprint[k]!r}" for k in differ)
        got = ", ".join(f"{k} {theirs.get(k)!r}" for k in differ)
        what = "this problem" if keys is None else "this mesh and dtype"
        raise ValueError(f"expected a checkpoint of {what} ({shown}), got one of another problem ({got}) "
                         f"in {path!r}")
    _check_checkpoint_arrays(saved, fingerprint["n_vertices"], n_elements, fingerprint["dtype"], path, role)
    return saved


def _checkpoint_shapes(n, m, dtype):
    """{name: (shape, dtype)} of the arrays an all-pairs checkpoint of n vertices and m triangles may hold."""
    W = lane_width(SCALARS[dtype], n)
    nb = -(-n // W)
    state, f8 = ((n, nb, W), dtype), "float64"
    shapes = {name: state for name in STATE_ROWS + ("change_snapshot",)}
    shapes.update(v=((m, 3, nb, W), dtype), iteration=((), "int64"), rho_v=((), f8), cg_iterations=((), "int64"),
                  seconds=((), f8), penalties=((2,), f8), cols=((3, nb * W), f8), pairs=((5,), f8),
                  change=((2,), f8), residuals=((7,), f8), tolerance=((7,), f8), final=((), "bool"))
    return shapes


def _check_checkpoint_arrays(saved, n, m, dtype, path, role):
    """ValueError unless ``saved`` holds the arrays a run of this problem needs, of their shapes and dtypes."""
    shapes = _checkpoint_shapes(n, m, dtype)
    if role == "initial":
        required = ("X", "U", "H", "v", "rho_v")
    else:
        required = ("X", "U", "H", "v", "iteration", "rho_v", "cg_iterations", "seconds", "history")
        required += ("residuals", "tolerance") if "final" in saved else ("DZ", "DZ_acc", "DY_acc")
        if "iteration" in saved and saved["iteration"].ndim == 0 and saved["iteration"] > 0:
            required += ("penalties", "cols", "pairs")
    missing = [name for name in required if name not in saved]
    if missing:
        raise ValueError(f"expected {role} as a complete all-pairs checkpoint, got {path!r} without "
                         f"{', '.join(missing)}")
    for name, a in saved.items():
        if name == "history":
            ok = a.ndim == 2 and a.shape[1] == 7 and a.dtype == np.float64
            expected = "(k, 7) float64"
        elif name in shapes:
            shape, kind = shapes[name]
            ok = a.shape == shape and a.dtype == np.dtype(kind)
            expected = f"{shape} {kind}"
        else:
            continue
        if not ok:
            raise ValueError(f"expected {role} checkpoint array {name!r} of shape and dtype {expected}, got "
                             f"{a.shape} {a.dtype} in {path!r}")


def _final_result(saved, memory, checkpoint):
    """The result recorded in the checkpoint of a converged run."""
    n = int(json.loads(str(saved["fingerprint"]))["n_vertices"])
    return AllPairsResult(distance=saved["U"].reshape(n, -1)[:, :n].astype(np.float64), iterations=int(saved["iteration"]),
                          converged=True, interrupted=False, residuals=saved["residuals"], tolerance=saved["tolerance"],
                          history=saved["history"], change=float(saved["change"][1]) if "change" in saved else math.inf,
                          cg_iterations=int(saved["cg_iterations"]), seconds=float(saved["seconds"]),
                          memory_bytes=memory, checkpoint=None if checkpoint is None else os.fspath(checkpoint))


class _Run:
    """The ADMM iterations of :func:`all_pairs` on a :class:`_SymmetricADMM`, with checkpoints.

    A checkpoint is the state at the top of an iteration: the state arrays, the penalties that
    formed the last iterate, the last element and consensus sums (the residuals of that
    iterate are computed from them) and the history; so a run restored from it repeats the
    uninterrupted run's arithmetic exactly.
    """

    def __init__(self, state, memory, max_iterations, eps_rel, eps_rel_consensus, eps_rel_dual, rho2_factor,
                 cg_fraction, progress, checkpoint, checkpoint_seconds, fingerprint, eps_change, schedule):
        self.state, self.memory, self.max_iterations = state, memory, max_iterations
        self.eps_rel, self.eps_rel_consensus, self.eps_rel_dual = eps_rel, eps_rel_consensus, eps_rel_dual
        self.rho2_factor, self.cg_fraction, self.progress = rho2_factor, cg_fraction, progress
        self.checkpoint, self.checkpoint_seconds, self.fingerprint = checkpoint, checkpoint_seconds, fingerprint
        self.start = 0
        self.history = []
        self.cg_total = 0
        self.cols = self.pairs = None
        self.last_penalties = None
        self.seconds_before = 0.0
        self.schedule = schedule
        # U as one column: its change test (snapshot, the last window's change, the change to come)
        self.change_test = ExtrapolatedChangeTest(tolerances.pairs_change_window, eps_change, 1)

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
        self.state.set_penalties(rho, self.rho2_factor * rho * rho / (self.state.L * self.state.A))
        self.s2, self.dy2 = self.state.right_hand_side()

    def status(self, it):
        """The seven residuals of the iterate after ``it`` iterations against their tolerances, the
        change test; history and progress. True when all hold (the final checkpoint is written)."""
        if it == 0:
            return False
        st, tol, w = self.state, tolerances, self.state.column_area
        n, m, A = st.n, st.m, st.A
        rho_old, rho2_old = self.last_penalties
        cols, pairs = self.cols, self.pairs
        r1 = math.sqrt(w @ cols[0])
        s1 = rho_old * math.sqrt((w * w) @ self.s2)
        rx = math.sqrt(pairs[RX2])
        sx = math.sqrt(2.0) * rho2_old * math.sqrt(pairs[SX2])
        eps_p = tol.eps_abs * math.sqrt(3 * m) * A + self.eps_rel * math.sqrt(max(w @ cols[1], w @ cols[2]))
        eps_d = tol.eps_abs * math.sqrt(n) * A * A + self.eps_rel_dual * max(math.sqrt((w * w) @ self.dy2),
                                                                              self.load_norm)
        eps_x = tol.eps_abs * math.sqrt(n) * A ** 1.5 + self.eps_rel_consensus * math.sqrt(min(pairs[X2], pairs[U2]))
        eps_dx = tol.eps_abs * math.sqrt(n) * A + self.eps_rel_dual * max(math.sqrt(pairs[H2]), 0.5 * A)
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
        st, tol = self.state, tolerances
        for j in range(it, it + count):
            atol = self.cg_fraction * (np.sqrt(self.dy2) + 0.5 * np.linalg.norm(st.setup.vertex_volumes))
            self.cg_total += st.x_and_element_steps(atol, tol.cg_rtol, tol.cg_max_iterations)
            self.last_penalties = st.penalties
            self.cols, self.pairs = st.consensus()
            self.top(j + 1)

    def iterate(self, t0):
        """The loop (:func:`~warp_regdist.admm.run_iterations`) from ``self.start``; the AllPairsResult."""
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
