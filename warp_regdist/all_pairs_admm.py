"""All-pairs regularized distance matrices on M x M (Algorithm 2 of the paper, SPEC section 5).

The distance matrix is the minimizer of

    minimize_U  -A_V^T U A_V + (alpha / 2) Tr(M_V U^T W_D U + U W_D U^T M_V)
    subject to  |grad of every column| <= 1,  |grad of every row| <= 1,  U_ii <= 0,  U >= 0,

with alpha = alpha_hat sqrt(A). For a symmetric U both energy terms are equal, so every
column carries the Dirichlet energy twice: a column is close to the single-source
distance with 2 alpha, not alpha.

Symmetric ADMM. The consensus splitting of SPEC section 5 has the variables
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
The seven residuals of SPEC section 5 are computed (r2 = r1, s2 = s1, rx2 = rx1 by the
symmetry) and reported.

Penalties and stopping test (defaults tuned against exact minimizers, see the README):
rho_k = sqrt(A) min(rho_max, rho0 2^(k / rho_doubling)) (the single-source schedule of
``tolerances``), rho2_k = rho2_factor rho_k^2 / (sqrt(A) A) (the consensus penalty grows
16x faster; a fixed ratio rho2 / rho converged 1.5-3x slower), over-relaxation
``tolerances.relaxation`` in all three steps; stop when every residual is below its
relative tolerance. K2 changes with the penalties: ``BatchedPCG.set_matrix`` replaces its
values (same pattern as W_D), the multigrid preconditioner is built once.
"""

from __future__ import annotations

import concurrent.futures
import math
import os
import time
import warnings

import numpy as np
import scipy.sparse as sp
import warp as wp
from scipy.optimize import OptimizeResult

from .kernels.all_pairs import DY2, GX2, H2, R2, RX2, S2, SX2, U2, X2, Z2, all_pairs_kernels
from .kernels.lanes import SCALARS, chunk_size, lane_type, lane_width
from .mesh import Mesh
from .multigrid import smoothed_aggregation
from .operators import build_operators
from .pcg import BatchedPCG
from .regularizers import check_weight
from .solver import ConvergenceWarning, parse_device, parse_workers
from .tolerances import tolerances

__all__ = ["all_pairs", "AllPairsResult", "RESIDUAL_NAMES"]

RESIDUAL_NAMES = ("r1", "r2", "s1", "s2", "rx1", "rx2", "sx")
"""The seven residuals of SPEC section 5, in the order of ``AllPairsResult.residuals``."""


class AllPairsResult(OptimizeResult):
    """Result of :func:`all_pairs`.

    Attributes
    ----------
    distance : (n, n) ndarray of float64
        Exactly symmetric, zero diagonal, non-negative.
    iterations : int
    converged : bool
        True when all seven residuals met their tolerances before ``max_iterations``.
    residuals, tolerance : (7,) ndarray
        Final residuals (r1, r2, s1, s2, rx1, rx2, sx) and their tolerances.
    history : (iterations, 7) ndarray
        Residuals divided by their tolerances at every iteration.
    cg_iterations : int
        PCG iterations summed over ADMM iterations (the largest count among the worker threads).
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
    (~0.15 n per column, counted as n), the combined z/y state (3 m columns' worth); plus the float64 (n, n) result on the host
    (and, on a GPU, the copy back to the host in the solver's precision).
    """
    W = lane_width(SCALARS[dtype], n)
    cols = -(-n // W) * W
    size = np.dtype(dtype).itemsize
    device_bytes = size * cols * (12 * n + 3 * m)
    host_bytes = 8 * n * n + (size * n * cols if wp.get_device(device).is_cuda else 0)
    return device_bytes, host_bytes


def _even_splits(weights, parts):
    """Bounds b_0 = 0 < ... < b_parts = len(weights) cutting ``weights`` into ``parts`` runs of
    about equal sums (fewer runs when there are fewer items)."""
    parts = max(1, min(parts, len(weights)))
    cum = np.concatenate([[0.0], np.cumsum(weights)])
    cuts = np.searchsorted(cum, cum[-1] * np.arange(1, parts) / parts)
    return np.unique(np.concatenate([[0], np.clip(cuts, 1, len(weights) - 1), [len(weights)]])).tolist()


class _SymmetricADMM:
    """State and one iteration of the symmetric all-pairs ADMM (see the module docstring).

    On the CPU the column blocks are split into up to ``workers`` parts (at most one per 10^5
    pairs) run by parallel threads (a CPU launch runs on one core): each part has its own PCG and its own launches of the
    vertex and element steps on its columns, and the consensus step's tile pairs are split
    into rows of about equal work. The results do not depend on the split.
    """

    def __init__(self, mesh, alpha_hat, device, dtype, rho2_factor, workers):
        n, m = mesh.n_vertices, mesh.n_elements
        self.n, self.m = n, m
        self.device, self.scalar = device, SCALARS[dtype]
        self.ops = ops = build_operators(mesh)
        self.alpha = alpha_hat * ops.length_scale
        self.W = W = lane_width(self.scalar, n)
        self.nb = nb = -(-n // W)
        self.kern = all_pairs_kernels(self.scalar, W)
        sc, dev = self.scalar, device
        V = lane_type(sc, W)
        self.chunk = chunk_size(dev)
        self.A = ops.total_volume
        self.L = ops.length_scale
        area = np.zeros(nb * W)
        area[:n] = ops.vertex_volumes
        self.column_area = area
        self._elements = wp.array(mesh.elements.astype(np.int32), dtype=wp.int32, device=dev)
        self._basis = wp.array(ops.basis, dtype=wp.types.vector(3, sc), device=dev)
        self._volumes = wp.array(ops.element_volumes, dtype=sc, device=dev)
        self._vertex_volumes = wp.array(ops.vertex_volumes, dtype=sc, device=dev)
        self._lane_areas = wp.array(area.reshape(nb, W), dtype=V, device=dev)
        # One row of column masks (1 on real columns, 0 on padding), broadcast to n rows by a zero stride.
        self._mask_row = wp.array((area > 0).astype(np.float64).reshape(1, nb, W), dtype=V, device=dev)
        self.mask = wp.array(ptr=self._mask_row.ptr, shape=(n, nb), strides=(0, self._mask_row.strides[1]),
                             dtype=V, device=dev)
        self.X, self.U, self.H, self.DZ, self.DZ_acc, self.DY_acc, self.rhs = (
            wp.zeros((n, nb), dtype=V, device=dev) for _ in range(7))
        self.v = wp.zeros((m, 3, nb), dtype=V, device=dev)
        self.acc = wp.zeros((5, nb), dtype=V, device=dev)
        mass = sp.diags(ops.vertex_volumes)
        self._mass = mass
        # The multigrid hierarchy of K2 / (alpha + rho) at the geometric mean of the penalty schedule
        # (fewer CG iterations on cat than at either end); the mass term keeps the constants, which
        # W_D's own hierarchy ignores, in the preconditioner.
        K_mid = self._matrix(1.0, rho2_factor * math.sqrt(tolerances.rho0 * tolerances.rho_max) / self.A)
        hierarchy = smoothed_aggregation(K_mid)
        self.rho_v = 1.0  # the rho that formed v (any value while v = 0)
        self.rho = self.rho2 = None
        k = self.kern
        # threads meet three times per iteration (~0.1 ms each): only worth it from ~10^5 pairs per thread
        T = 1 if dev.is_cuda else max(1, min(workers, n * n // 100_000))
        self.blocks = _even_splits(np.ones(nb), T)  # column blocks [b_t, b_t+1) of part t
        self.rows = _even_splits(nb - np.arange(nb), T)  # consensus tile rows I (row I has nb - I pairs)
        self.pcgs, self._vertex, self._element, self._consensus = [], [], [], []
        for b0, b1 in zip(self.blocks[:-1], self.blocks[1:]):
            cols = slice(b0, b1)
            self.pcgs.append(BatchedPCG(K_mid, sc, W, b1 - b0, dev, preconditioner=hierarchy))
            elem_dim = ((m + self.chunk - 1) // self.chunk, b1 - b0)
            vert_dim = ((n + self.chunk - 1) // self.chunk, b1 - b0)
            self._vertex.append(wp.launch(k.vertex_step, vert_dim, device=dev, record_cmd=True, inputs=[
                self._vertex_volumes, self.mask[:, cols], sc(1.0), sc(1.0), self.H[:, cols], self.U[:, cols],
                self.DZ_acc[:, cols], self.DY_acc[:, cols], self.DZ[:, cols], self.rhs[:, cols],
                self.acc[:, cols], self.chunk, n]))
            self._element.append(wp.launch(k.element_step, elem_dim, device=dev, record_cmd=True, inputs=[
                self._elements, self._basis, self._volumes, self.X[:, cols], self.v[:, :, cols], sc(1.0), sc(1.0),
                sc(tolerances.relaxation), self.DZ_acc[:, cols], self.DY_acc[:, cols], self.acc[:, cols],
                self.chunk, m]))
        self.acc_pairs = wp.zeros((len(self.rows) - 1, 5), dtype=sc, device=dev)
        for t, (i0, i1) in enumerate(zip(self.rows[:-1], self.rows[1:])):
            self._consensus.append(wp.launch(k.consensus_step, (i1 - i0, nb), device=dev, record_cmd=True, inputs=[
                self.X, self.U, self.H, self._lane_areas, sc(1.0), sc(tolerances.relaxation), self.acc_pairs[t],
                i0, n]))
        self._pool = concurrent.futures.ThreadPoolExecutor(len(self.pcgs)) if len(self.pcgs) > 1 else None

    def close(self):
        """Stop the worker threads."""
        if self._pool is not None:
            self._pool.shutdown()

    def _each(self, work, count):
        """[work(t) for t in range(count)], in the worker threads when there are several."""
        if self._pool is None or count == 1:
            return [work(t) for t in range(count)]
        return list(self._pool.map(work, range(count)))

    def _matrix(self, stiffness_weight, mass_weight):
        return (stiffness_weight * self.ops.stiffness + mass_weight * self._mass).tocsr()

    def set_penalties(self, rho, rho2):
        if (rho, rho2) != (self.rho, self.rho2):
            K2 = self._matrix(self.alpha + rho, rho2)
            for pcg in self.pcgs:
                pcg.set_matrix(K2)
            self.rho, self.rho2 = rho, rho2

    def right_hand_side(self):
        """rhs of the X-step and D Z; returns per-column |D(Z - Z_old)|^2 and |D Y|^2 (nb W,)."""
        sc = self.scalar
        self.acc.zero_()
        for launch in self._vertex:
            for name, value in (("rho", self.rho), ("rho2", self.rho2)):
                launch.set_param_by_name(name, sc(value))
        self._each(lambda t: self._vertex[t].launch(), len(self._vertex))
        acc = self.acc.numpy().reshape(5, -1)
        return acc[S2].astype(np.float64), acc[DY2].astype(np.float64)

    def x_and_element_steps(self, atol, rtol, max_iterations):
        """X-step (PCG) then z/y-step of every part; returns the largest PCG iteration count."""
        sc = self.scalar
        self.acc.zero_()
        for launch in self._element:
            launch.set_param_by_name("rho_v", sc(self.rho_v))
            launch.set_param_by_name("rho", sc(self.rho))
        self.rho_v = self.rho
        W, b = self.W, self.blocks

        def part(t):
            cols = slice(b[t], b[t + 1])
            it, _ = self.pcgs[t].solve(self.rhs[:, cols], self.X[:, cols], self.mask[:, cols], rtol, max_iterations,
                                       atol[b[t] * W:b[t + 1] * W])
            self._element[t].launch()
            return it

        return max(self._each(part, len(self.pcgs)))

    def consensus(self):
        """U/H-step; returns (per-column R2, GX2, Z2 sums (3, nb W) of the element step, pair sums (5,))."""
        self.acc_pairs.zero_()
        for launch in self._consensus:
            launch.set_param_by_name("rho2", self.scalar(self.rho2))
        self._each(lambda t: self._consensus[t].launch(), len(self._consensus))
        acc = self.acc.numpy().reshape(5, -1)
        return acc[[R2, GX2, Z2]].astype(np.float64), self.acc_pairs.numpy().astype(np.float64).sum(axis=0)

    def distance(self):
        """U as an (n, n) float64 array (the U-step writes the same value to U_ij and U_ji)."""
        return self.U.numpy().reshape(self.n, -1)[:, :self.n].astype(np.float64)


def all_pairs(mesh, alpha_hat=0.03, device=None, dtype="float64", max_iterations=3000, eps_rel=5e-4,
              eps_rel_consensus=5e-5, eps_rel_dual=1e-2, rho2_factor=25.0, cg_fraction=1e-3, progress=None,
              workers=None):
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
        load), plus the absolute terms of SPEC section 5 with ``tolerances.eps_abs`` (0 by
        default). All must be finite and > 0.
        The defaults stopped 0.2-0.8% of the maximal distance away from the exact minimizer
        on the meshes we measured (README).
    rho2_factor : float
        rho2 = rho2_factor rho^2 / (sqrt(A) A): the consensus penalty grows like the square
        of the gradient penalty (the authors' initial values have rho2 = 5 rho / A).
    cg_fraction : float
        Each X-step's PCG stops at a residual of cg_fraction (|D Y_j| + |A_V| / 2) per column j
        (looser solves, 1e-2, can keep the residuals from ever meeting the stopping test).
    progress : callable or None
        Called after every iteration as progress(iteration, residuals (7,), tolerances (7,),
        elapsed seconds, memory bytes).
    workers : int or None
        CPU threads that share every step's columns (None: the cores available to the
        process; ignored on CUDA). The result does not depend on it.

    Returns
    -------
    AllPairsResult

    Raises
    ------
    ValueError
        Bad arguments, a mesh with several connected components, vertices in no face, or
        a footprint above the available memory (the message gives both).
    """
    t0 = time.perf_counter()
    if not isinstance(mesh, Mesh):
        raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
    if mesh.element_dim != 2:
        raise ValueError(f"expected a triangle mesh, got {mesh.n_elements} tetrahedra")
    alpha_hat = check_weight(alpha_hat, "alpha_hat")
    for name, value in (("eps_rel", eps_rel), ("eps_rel_consensus", eps_rel_consensus),
                        ("eps_rel_dual", eps_rel_dual), ("rho2_factor", rho2_factor), ("cg_fraction", cg_fraction)):
        check_weight(value, name, positive=True)
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
    wp.init()
    dev = parse_device(device)
    n, m = mesh.n_vertices, mesh.n_elements
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
    memory = device_bytes + host_bytes

    state = _SymmetricADMM(mesh, alpha_hat, dev, dtype, rho2_factor, workers)
    try:
        return _run(state, t0, memory, max_iterations, eps_rel, eps_rel_consensus, eps_rel_dual, rho2_factor,
                    cg_fraction, progress)
    finally:
        state.close()


def _run(state, t0, memory, max_iterations, eps_rel, eps_rel_consensus, eps_rel_dual, rho2_factor, cg_fraction,
         progress):
    """The ADMM iterations of :func:`all_pairs` on ``state``; returns the AllPairsResult."""
    n, m = state.n, state.m
    tol = tolerances
    A, L = state.A, state.L
    w = state.column_area
    history = []
    res = np.zeros(7)
    eps = np.ones(7)
    cg_total = 0
    converged = False
    pairs = None
    # Floors of the dual scales |D Y M_V| and |S_V H S_V|: the load (1/2) A_V 1^T that D Y and
    # M_V H balance in the X-step; Y (and H) vanish where no gradient constraint is active,
    # which can be everywhere (a large alpha_hat), and a test relative to them alone never holds.
    load_norm = 0.5 * np.linalg.norm(state.ops.vertex_volumes) * np.linalg.norm(w)
    it = 0
    for it in range(max_iterations + 1):
        rho_old, rho2_old = state.rho, state.rho2
        rho = L * min(tol.rho_max, tol.rho0 * 2.0 ** (it / tol.rho_doubling))
        state.set_penalties(rho, rho2_factor * rho * rho / (L * A))
        s2, dy2 = state.right_hand_side()
        if it > 0:
            r1 = math.sqrt(w @ cols[0])
            s1 = rho_old * math.sqrt((w * w) @ s2)
            rx = math.sqrt(pairs[RX2])
            sx = math.sqrt(2.0) * rho2_old * math.sqrt(pairs[SX2])
            eps_p = tol.eps_abs * math.sqrt(3 * m) * A + eps_rel * math.sqrt(max(w @ cols[1], w @ cols[2]))
            eps_d = tol.eps_abs * math.sqrt(n) * A * A + eps_rel_dual * max(math.sqrt((w * w) @ dy2), load_norm)
            eps_x = tol.eps_abs * math.sqrt(n) * A ** 1.5 + eps_rel_consensus * math.sqrt(min(pairs[X2], pairs[U2]))
            eps_dx = tol.eps_abs * math.sqrt(n) * A + eps_rel_dual * max(math.sqrt(pairs[H2]), 0.5 * A)
            res = np.array([r1, r1, s1, s1, rx, rx, sx])
            eps = np.array([eps_p, eps_p, eps_d, eps_d, eps_x, eps_x, eps_dx])
            history.append(res / np.maximum(eps, 1e-300))
            if progress is not None:
                progress(it, res, eps, time.perf_counter() - t0, memory)
            if np.all(res <= eps):
                converged = True
                break
            if it == max_iterations:
                break
        atol = cg_fraction * (np.sqrt(dy2) + 0.5 * np.linalg.norm(state.ops.vertex_volumes))
        cg_total += state.x_and_element_steps(atol, tol.cg_rtol, tol.cg_max_iterations)
        cols, pairs = state.consensus()
    if not converged:
        warnings.warn(f"all-pairs ADMM did not converge in {max_iterations} iterations "
                      f"(max residual / tolerance {np.max(res / np.maximum(eps, 1e-300)):.3g})", ConvergenceWarning, stacklevel=3)
    return AllPairsResult(distance=state.distance(), iterations=it, converged=converged, residuals=res,
                          tolerance=eps, history=np.array(history).reshape(-1, 7), cg_iterations=cg_total,
                          seconds=time.perf_counter() - t0, memory_bytes=memory)
