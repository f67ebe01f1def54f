"""Column-batched preconditioned conjugate gradient on Warp arrays (no factorization).

Solves  mask K mask x = b  for every column at once, where K is one symmetric positive
(semi-)definite sparse matrix shared by all columns and ``mask`` selects each column's
free unknowns (K restricted to them is positive definite). Warm starts come for free:
``x`` holds the initial guess on entry.

The preconditioner is an operator z = M r with its own launches (the PCG masks z):
:class:`~warp_regdist.linalg.multigrid.MultigridPreconditioner` (default), one smoothed-aggregation
V-cycle, which reads about 2.7 nnz(K) matrix entries on the finest level, so an iteration
costs 2-3 Jacobi iterations, but their count barely grows with n; :class:`JacobiPreconditioner`,
z = D^-1 r, needs iterations that grow like sqrt(n) (docs/performance.md gives both).

The stopping test runs on the device (kernels/pcg.py): per-lane converged flags, the
iteration counter and a ``running`` flag, so one CG iteration is a fixed sequence of
recorded launches. The host reads ``running`` every ``check_every`` iterations, or
never: with ``capture=True`` the whole solve is one Warp graph whose loop is a
``wp.capture_while`` on ``running`` (a CPU graph replay, or unchanged a CUDA graph).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
import scipy.sparse as sp
import warp as wp

from .csr import csr_arrays
from ..kernels.lanes import row_dim, thread_span
from ..kernels.pcg import ITERATION, RR, pcg_kernels
from .multigrid import Hierarchy, MultigridPreconditioner, smoothed_aggregation

__all__ = ["BatchedPCG", "Preconditioner", "JacobiPreconditioner"]


@runtime_checkable
class Preconditioner(Protocol):
    """What :class:`BatchedPCG` needs of a preconditioner z = M r (M symmetric positive definite on the
    free unknowns): its size, its launches recorded once, and a way to follow a new matrix in place."""

    n: int
    """Unknowns (rows of r and z)."""

    def record(self, r: wp.array, z: wp.array, blocks: int) -> list:
        """Recorded launches (``wp.launch(..., record_cmd=True)``) computing z = M r on column blocks
        0..blocks-1 of the (n, nb) lane arrays ``r`` and ``z``; replayed at every iteration."""
        ...

    def set_matrix(self, matrix) -> None:
        """Follow a change of the PCG's matrix (same pattern) without invalidating the recorded launches."""
        ...


def _write(array, values):
    """array[...] = values (NumPy-shaped: vector lanes last); through the zero-copy view on the CPU."""
    values = np.reshape(values, array.shape + getattr(array.dtype, "_shape_", ()))
    if array.device.is_cpu:
        array.numpy()[...] = values
    else:
        array.assign(values)


def _inverse_diagonal(K):
    diag = K.diagonal()
    return np.where(diag > 0, 1.0 / np.where(diag > 0, diag, 1.0), 0.0)


class JacobiPreconditioner:
    """z = D^-1 r, D the diagonal of the PCG's matrix (0 where it is not positive).

    Parameters
    ----------
    matrix : (n, n) scipy.sparse matrix
    scalar : warp scalar type
    width : int
        Lanes per vector.
    device : warp device
    """

    def __init__(self, matrix, scalar, width, device):
        self.n = matrix.shape[0]
        self.kernel = pcg_kernels(scalar, width).jacobi_apply
        self.device = device
        self.dinv = wp.array(_inverse_diagonal(matrix), dtype=scalar, device=device)

    def record(self, r, z, blocks):
        """Recorded launches computing z = D^-1 r on column blocks 0..blocks-1 of (n, nb) ``r``, ``z``."""
        span = thread_span(self.device, blocks, rows=self.n)
        return [wp.launch(self.kernel, row_dim(self.n, span, blocks), device=self.device, record_cmd=True,
                          inputs=[self.dinv, r, z, *span, self.n])]

    def set_matrix(self, matrix):
        """Follow a change of the PCG's matrix (in place: recorded launches stay valid)."""
        self.dinv.assign(_inverse_diagonal(matrix))


class BatchedPCG:
    """Preconditioned CG for (n, nb) lane-vector columns, stopping decided on the device.

    Parameters
    ----------
    matrix : (n, n) scipy.sparse matrix
        Symmetric K, with a positive diagonal on every row that is free in some column.
    scalar : warp scalar type (wp.float32 or wp.float64)
    width : int
        Lanes per vector (columns per block).
    blocks : int
        Number of column blocks nb.
    device : warp device
    preconditioner : "multigrid", "jacobi", Hierarchy or operator
        "multigrid" builds :func:`~warp_regdist.linalg.multigrid.smoothed_aggregation` of the
        matrix; a prebuilt Hierarchy shares one setup among several solvers. An operator
        is any object with ``n``, ``record(r, z, blocks)`` (recorded launches computing
        z = M r on blocks 0..blocks-1 of this solver's (n, nb) arrays ``r``, ``z``; M
        symmetric positive definite on the free rows) and ``set_matrix(matrix)``, e.g.
        :class:`JacobiPreconditioner` or
        :class:`~warp_regdist.linalg.multigrid.MultigridPreconditioner`, built for this solver alone.
    check_every : int
        Without capture, the host reads the device's ``running`` flag every
        ``check_every`` iterations (iterations after convergence are no-ops, but each
        still applies the preconditioner).
    capture : bool
        Run every solve as one Warp graph (captured at the first solve with new arrays or
        new active blocks, then replayed), the CG loop a ``wp.capture_while``. Capture is
        process-global in Warp 1.19 on the CPU (every CPU launch from any thread is
        recorded into the graph meanwhile), so use it only when no other thread launches;
        on CUDA it needs conditional graph nodes (CUDA 12.4+).

    The per-lane squared absolute tolerance is a device array, ``atol2`` (blocks,) of lane
    vectors, which the next solves read: :meth:`solve` writes it from the host; a device loop
    (the single-source stopping kernel) writes it in place, so the tolerance of every u-step is
    decided on the device without a host round trip.

    Thread safety: kernels are loaded and launches recorded (graphs captured) only at the
    first solve with new arrays and after :meth:`set_active_blocks`; later solves with the
    same arrays only replay them, so several solvers can run in several threads once each
    has made its first solve.
    """

    def __init__(self, matrix, scalar, width, blocks, device, preconditioner="multigrid", check_every=1,
                 capture=False):
        K = sp.csr_matrix(matrix)
        K.sort_indices()
        if not (isinstance(check_every, (int, np.integer)) and check_every >= 1):
            raise ValueError(f"expected check_every a positive integer, got {check_every!r}")
        self.n = K.shape[0]
        self.device = wp.get_device(device)
        self.kernels = pcg_kernels(scalar, width)
        V = self.kernels.V
        self.scalar = scalar
        self.width = width
        self.check_every = int(check_every)
        self.capture = bool(capture)
        self.offsets, self.columns, self.values = csr_arrays(K, scalar, device)
        self._pattern = (K.indptr.copy(), K.indices.copy())
        shape = (self.n, blocks)
        self.r, self.z, self.p, self.q = (wp.zeros(shape, dtype=V, device=device) for _ in range(4))
        self.acc = wp.zeros((3, 3, blocks), dtype=V, device=device)
        self.coef = wp.zeros((2, blocks), dtype=V, device=device)
        self.bb, self.converged, self.atol2 = (wp.zeros(blocks, dtype=V, device=device) for _ in range(3))
        self.rtol2 = wp.zeros(1, dtype=scalar, device=device)
        self.counters = wp.zeros(2, dtype=wp.int32, device=device)
        self.running = wp.zeros(1, dtype=wp.int32, device=device)
        self._atol2_host = np.zeros((blocks, width))
        self.blocks = blocks
        self._program = None
        self.preconditioner = self._operator(preconditioner, K, scalar, width, blocks)

    def _operator(self, spec, K, scalar, width, blocks):
        """The preconditioner operator for a ``preconditioner`` argument."""
        if isinstance(spec, str) and spec == "multigrid":
            spec = smoothed_aggregation(K)
        if isinstance(spec, Hierarchy):
            if spec.sizes[0] != self.n:
                raise ValueError(f"expected a multigrid hierarchy for {self.n} unknowns, got {spec.sizes[0]}")
            return MultigridPreconditioner(spec, scalar, width, blocks, self.device)
        if isinstance(spec, str) and spec == "jacobi":
            return JacobiPreconditioner(K, scalar, width, self.device)
        if isinstance(spec, Preconditioner):
            if spec.n != self.n:
                raise ValueError(f"expected a preconditioner for {self.n} unknowns, got {spec.n}")
            return spec
        raise ValueError(f"expected preconditioner 'multigrid', 'jacobi', a Hierarchy or a Preconditioner (n, record "
                         f"and set_matrix), got {spec!r}")

    def set_matrix(self, matrix):
        """Replace K by ``matrix`` of the same sparsity pattern (a new penalty, a new shift).

        The arrays are updated in place, so recorded launches and graphs stay valid; the
        preconditioner's ``set_matrix`` follows (the multigrid hierarchy is kept: it only
        needs to stay spectrally close to K; build a new solver with
        ``smoothed_aggregation(matrix)`` when K changes by more than a scaling).
        """
        K = sp.csr_matrix(matrix)
        K.sort_indices()
        if K.shape != (self.n, self.n) or not (np.array_equal(K.indptr, self._pattern[0])
                                                and np.array_equal(K.indices, self._pattern[1])):
            raise ValueError(f"expected a ({self.n}, {self.n}) matrix with the solver's sparsity pattern, "
                             f"got shape {K.shape} with {K.nnz} nonzeros")
        self.values.assign(K.data.astype(wp.dtype_to_numpy(self.scalar), copy=False))
        self.preconditioner.set_matrix(K)

    def set_active_blocks(self, blocks):
        """Solve only column blocks 0..blocks-1 from now on (a batch whose other columns are done)."""
        if not 1 <= blocks <= self.acc.shape[2]:
            raise ValueError(f"expected 1 <= active blocks <= {self.acc.shape[2]}, got {blocks}")
        if blocks != self.blocks:
            self.blocks = blocks
            self._program = None

    def capture_solve(self, rhs, x, mask):
        """Inside the caller's graph capture: record one solve of these arrays (the start launches,
        then one CG iteration while ``running`` is nonzero, a ``wp.capture_while``), with the
        tolerances left by :meth:`configure` and in ``atol2`` (squared, per lane) when it replays."""
        start, body = self._launches(rhs, x, mask)[:2]
        for launch in start:
            launch.launch()
        wp.capture_while(self.running, lambda: [launch.launch() for launch in body])

    def configure(self, rtol, max_iterations):
        """Set the relative tolerance and the iteration cap of the next solves run by :meth:`launches`."""
        _write(self.rtol2, rtol * rtol)
        _write(self.counters, [0, min(int(max_iterations), 2**31 - 1)])

    def run(self, rhs, x, mask):
        """One solve by the recorded launches (no graph), the host reading ``running`` every
        ``check_every`` iterations; tolerances as left by :meth:`configure` and in ``atol2``."""
        start, body = self._launches(rhs, x, mask)[:2]
        for launch in start:
            launch.launch()
        while self._is_running():
            for _ in range(self.check_every):
                for launch in body:
                    launch.launch()

    def _launches(self, rhs, x, mask):
        """(start, body, graph) for these arrays: start = reset, init, check; body = one CG iteration."""
        key = tuple((a.ptr, a.shape, a.strides) for a in (rhs, x, mask))
        if self._program is None or self._program[0] != key:
            k, n, dev, blocks = self.kernels, self.n, self.device, self.blocks
            state = (self.counters, self.running)
            span = thread_span(dev, blocks, x.strides[0] // x.strides[1], n)  # the caller's row layout
            dim = row_dim(n, span, blocks)

            def rec(kernel, dim, *args):
                return wp.launch(kernel, dim, inputs=list(args), device=dev, record_cmd=True)

            check = [self.acc, self.bb, self.rtol2, self.atol2, self.converged, *state]
            start = [rec(k.cg_reset, blocks, self.acc, self.bb, self.converged, *state),
                     rec(k.cg_init, dim, self.offsets, self.columns, self.values, mask, rhs, x, self.r, self.acc,
                         self.bb, *span, n),
                     rec(k.cg_check, 1, *check, 0, blocks)]
            body = [*self.preconditioner.record(self.r, self.z, blocks),
                    rec(k.cg_dot, dim, self.r, self.z, self.acc, *state, *span, n),
                    rec(k.cg_beta, blocks, self.acc, self.coef, *state),
                    rec(k.cg_direction, dim, mask, self.p, self.z, self.coef, *state, *span, n),
                    rec(k.cg_matvec, dim, self.offsets, self.columns, self.values, mask, self.p, self.q, self.acc,
                        *state, *span, n),
                    rec(k.cg_alpha, blocks, self.acc, self.converged, self.coef, *state),
                    rec(k.cg_update, dim, x, self.r, self.p, self.q, self.acc, self.coef, *state, *span, n),
                    rec(k.cg_check, 1, *check, 1, blocks)]
            self._program = (key, start, body, None)
            if self.capture:
                wp.capture_begin(self.device, force_module_load=False)
                try:
                    self.capture_solve(rhs, x, mask)
                finally:
                    self._program = (key, start, body, wp.capture_end(self.device))
        return self._program[1:]

    def _is_running(self):
        return bool(self.running.numpy()[0])

    def solve(self, rhs, x, mask, rtol, max_iterations, atol=0.0):
        """Run PCG until |b - K x| <= max(rtol |b|, atol) in every lane or ``max_iterations``.

        Parameters
        ----------
        rhs, x, mask : (n, nb) wp.array of lane vectors
            Right-hand side (zero where mask is 0), initial guess (overwritten by the
            solution), free-unknown mask (1 free, 0 fixed).
        rtol : float
        max_iterations : int
        atol : float or (blocks * width,) ndarray
            Absolute residual tolerance per lane of the active blocks.

        Returns
        -------
        iterations : int
        relative_residual : (blocks * width,) ndarray, |r| / |b| per lane of the active blocks
            (0 where b = 0).
        """
        lanes = self.blocks * self.width
        atol = np.asarray(atol, dtype=np.float64)
        if atol.shape not in ((), (lanes,)):
            raise ValueError(f"expected atol a scalar or a ({lanes},) array, got shape {atol.shape}")
        self._atol2_host.reshape(-1)[:lanes] = np.square(atol)
        _write(self.atol2, self._atol2_host)
        self.configure(rtol, max_iterations)
        graph = self._launches(rhs, x, mask)[2]
        if graph is not None:
            wp.capture_launch(graph)
        else:
            self.run(rhs, x, mask)
        it = int(self.counters.numpy()[ITERATION])
        rr = self.acc.numpy().reshape(3, 3, -1)[it % 3, RR, :lanes].astype(np.float64)
        bb = self.bb.numpy().reshape(-1)[:lanes].astype(np.float64)
        with np.errstate(invalid="ignore", over="ignore"):  # a blown-up iterate (inf / inf) reports NaN
            return it, np.sqrt(np.divide(rr, bb, out=np.zeros_like(bb), where=bb > 0))
