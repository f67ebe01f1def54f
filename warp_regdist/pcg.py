"""Column-batched preconditioned conjugate gradient on Warp arrays (no factorization).

Solves  mask K mask x = b  for every column at once, where K is one symmetric positive
(semi-)definite sparse matrix shared by all columns and ``mask`` selects each column's
free unknowns (K restricted to them is positive definite). Warm starts come for free:
``x`` holds the initial guess on entry.

Preconditioners: "multigrid" (default), one smoothed-aggregation V-cycle
z = mask M_0 r (warp_regdist/multigrid.py), which reads about 2.7 nnz(K) matrix entries
on the finest level, so an iteration costs 2-3 Jacobi iterations, but 18, 21 and 33
iterations reach 1e-6 on 5k, 100k and 1M vertices; "jacobi", z = D^-1 r, needs 250, 800
and 3000 there (iterations grow like sqrt(n)).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import warp as wp

from .kernels.lanes import chunk_size, lane_type
from .kernels.multigrid import multigrid_kernels
from .kernels.pcg import BB, RR, pcg_kernels
from .multigrid import Hierarchy, smoothed_aggregation

__all__ = ["BatchedPCG"]


def _csr_arrays(matrix, scalar, device):
    """(offsets, columns, values) Warp arrays of a scipy sparse matrix."""
    M = sp.csr_matrix(matrix)
    M.sort_indices()
    return (wp.array(M.indptr.astype(np.int32), dtype=wp.int32, device=device),
            wp.array(M.indices.astype(np.int32), dtype=wp.int32, device=device),
            wp.array(M.data, dtype=scalar, device=device))


class _VCycle:
    """A :class:`~warp_regdist.multigrid.Hierarchy` on a Warp device: z = mask M_0 r, RZ += r.z.

    A one-level hierarchy (n <= coarse size) applies its dense pseudo-inverse as S_0 with
    no coarse correction (an empty R_0^T). The launches are recorded once per mask array
    (a recorded CPU launch costs ~5 us instead of 20-80 us) and replayed, only the
    accumulator slot changing.
    """

    def __init__(self, hierarchy, scalar, width, blocks, device):
        self.kernels = multigrid_kernels(scalar, width)
        V = lane_type(scalar, width)
        self.device = device
        self.chunk = chunk_size(device)
        self.sizes = hierarchy.sizes
        n = self.sizes[0]
        if hierarchy.smoothers:
            smoothers, restrictions = hierarchy.smoothers, hierarchy.restrictions
            self.inverse = wp.array(hierarchy.coarse_inverse, dtype=scalar, device=device)
        else:
            smoothers, restrictions = [hierarchy.coarse_inverse], []
            self.sizes = [n]
        self.smoothers = [_csr_arrays(S, scalar, device) for S in smoothers]
        self.restrictions = [_csr_arrays(R, scalar, device) for R in restrictions]
        self.prolongations = ([_csr_arrays(R.T, scalar, device) for R in restrictions]
                              or [_csr_arrays(sp.csr_matrix((n, 1)), scalar, device)])
        self.y = [wp.zeros((m, blocks), dtype=V, device=device) for m in self.sizes[1:]]
        self.z = [wp.zeros((m, blocks), dtype=V, device=device) for m in self.sizes[1:]]
        self.blocks = blocks
        self.mask = None
        self.launches = []

    def _dim(self, level):
        return ((self.sizes[level] + self.chunk - 1) // self.chunk, self.blocks)

    def _record(self, mask, r, z, acc):
        """The launches of one application, finest (with the ``slot`` argument) last."""
        k, chunk, dev = self.kernels, self.chunk, self.device
        ys, zs = [r] + self.y, [z] + self.z
        levels = len(self.sizes)
        launches = []
        for l, R in enumerate(self.restrictions):
            launches.append(wp.launch(k.mg_restrict, self._dim(l + 1), device=dev, record_cmd=True,
                                      inputs=[*R, ys[l], ys[l + 1], chunk, self.sizes[l + 1]]))
        if levels > 1:
            launches.append(wp.launch(k.mg_coarse, self._dim(levels - 1), device=dev, record_cmd=True,
                                      inputs=[self.inverse, ys[-1], zs[-1], chunk, self.sizes[-1]]))
        for l in range(levels - 2, 0, -1):
            launches.append(wp.launch(k.mg_prolong, self._dim(l), device=dev, record_cmd=True,
                                      inputs=[*self.smoothers[l], *self.prolongations[l], ys[l], zs[l + 1], zs[l],
                                              chunk, self.sizes[l]]))
        zc = zs[1] if levels > 1 else r
        launches.append(wp.launch(k.mg_prolong_fine, self._dim(0), device=dev, record_cmd=True,
                                  inputs=[*self.smoothers[0], *self.prolongations[0], mask, r, zc, z, acc, 0, chunk,
                                          self.sizes[0]]))
        return launches

    def set_active_blocks(self, blocks):
        """Apply to column blocks 0..blocks-1 only (launches are recorded again)."""
        self.blocks = blocks
        self.mask = None

    def apply(self, mask, r, z, acc, slot):
        """z = mask M_0 r for (n, nb) lane vectors r (zero where mask is 0); acc[slot, RZ] += r.z.

        ``r``, ``z`` and ``acc`` must be the same arrays at every call (the PCG's own).
        """
        if mask is not self.mask:
            self.launches = self._record(mask, r, z, acc)
            self.mask = mask
        self.launches[-1].set_param_by_name("slot", slot)
        for launch in self.launches:
            launch.launch()


class BatchedPCG:
    """Preconditioned CG for (n, nb) lane-vector columns.

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
    preconditioner : {"multigrid", "jacobi"} or Hierarchy
        "multigrid" builds :func:`~warp_regdist.multigrid.smoothed_aggregation` of the
        matrix; pass a prebuilt Hierarchy to share one setup among several solvers.
    """

    def __init__(self, matrix, scalar, width, blocks, device, preconditioner="multigrid"):
        K = matrix.tocsr()
        K.sort_indices()
        self.n = K.shape[0]
        self.device = wp.get_device(device)
        self.kernels = pcg_kernels(scalar, width)
        V = self.kernels.V
        self.width = width
        self.offsets, self.columns, self.values = _csr_arrays(K, scalar, device)
        self._pattern = (K.indptr.copy(), K.indices.copy())
        self.dinv = wp.array(self._inverse_diagonal(K), dtype=scalar, device=device)
        shape = (self.n, blocks)
        self.r, self.z, self.p, self.q = (wp.zeros(shape, dtype=V, device=device) for _ in range(4))
        self.acc = wp.zeros((3, 4, blocks), dtype=V, device=device)
        self.tol2 = wp.zeros(blocks, dtype=V, device=device)
        self._tol2_host = np.zeros(blocks * width)
        self.chunk = chunk_size(device)
        self.blocks = blocks
        self.dim = ((self.n + self.chunk - 1) // self.chunk, blocks)
        self.scalar = scalar
        self._recorded = {}
        if isinstance(preconditioner, str) and preconditioner == "multigrid":
            preconditioner = smoothed_aggregation(K)
        if isinstance(preconditioner, Hierarchy):
            if preconditioner.sizes[0] != self.n:
                raise ValueError(f"expected a multigrid hierarchy for {self.n} unknowns, got {preconditioner.sizes[0]}")
            self.vcycle = _VCycle(preconditioner, scalar, width, blocks, self.device)
        elif isinstance(preconditioner, str) and preconditioner == "jacobi":
            self.vcycle = None
        else:
            raise ValueError(f"expected preconditioner 'multigrid', 'jacobi' or a Hierarchy, got {preconditioner!r}")

    def set_matrix(self, matrix):
        """Replace K by ``matrix`` of the same sparsity pattern (a new penalty, a new shift).

        The arrays are updated in place, so recorded launches stay valid; the
        preconditioner is kept (it only needs to stay spectrally close to K: build a new
        solver with ``smoothed_aggregation(matrix)`` when K changes by more than a scaling).
        """
        K = sp.csr_matrix(matrix)
        K.sort_indices()
        if K.shape != (self.n, self.n) or not (np.array_equal(K.indptr, self._pattern[0])
                                                and np.array_equal(K.indices, self._pattern[1])):
            raise ValueError(f"expected a ({self.n}, {self.n}) matrix with the solver's sparsity pattern, "
                             f"got shape {K.shape} with {K.nnz} nonzeros")
        self.values.assign(K.data.astype(self.values.numpy().dtype, copy=False))
        self.dinv.assign(self._inverse_diagonal(K))

    @staticmethod
    def _inverse_diagonal(K):
        diag = K.diagonal()
        return np.where(diag > 0, 1.0 / np.where(diag > 0, diag, 1.0), 0.0)

    def set_active_blocks(self, blocks):
        """Solve only column blocks 0..blocks-1 from now on (a batch whose other columns are done)."""
        if not 1 <= blocks <= self.tol2.shape[0]:
            raise ValueError(f"expected 1 <= active blocks <= {self.tol2.shape[0]}, got {blocks}")
        self.blocks = blocks
        self.dim = (self.dim[0], blocks)
        self._recorded = {}
        if self.vcycle is not None:
            self.vcycle.set_active_blocks(blocks)

    def _commands(self, rhs, x, mask):
        """Recorded launches (init, matvec[slot], update[slot], direction[slot]) for these arrays."""
        key = (rhs.ptr, x.ptr, mask.ptr)
        if key not in self._recorded:
            k, chunk, n, dev = self.kernels, self.chunk, self.n, self.device
            jacobi = int(self.vcycle is None)

            def rec(kernel, *args):
                return wp.launch(kernel, self.dim, inputs=list(args), device=dev, record_cmd=True)

            init = rec(k.cg_init, self.offsets, self.columns, self.values, self.dinv, mask, rhs, x,
                       self.r, self.z, self.p, self.acc, jacobi, chunk, n)
            matvec, update, direction = [], [], []
            for slot in range(3):
                prev, nxt = (slot - 1) % 3, (slot + 1) % 3
                matvec.append(rec(k.cg_matvec, self.offsets, self.columns, self.values, mask, self.p, self.q,
                                  self.acc, slot, chunk, n))
                update.append(rec(k.cg_update, self.dinv, x, self.r, self.z, self.p, self.q, self.acc,
                                  self.tol2, slot, prev, jacobi, chunk, n))
                direction.append(rec(k.cg_direction, self.p, self.z, self.acc, slot, prev, nxt, chunk, n))
            self._recorded = {key: (init, matvec, update, direction)}
        return self._recorded[key]

    def _accumulators(self):
        return self.acc.numpy().reshape(3, 4, -1)[:, :, :self.blocks * self.width]

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
        init, matvec, update, direction = self._commands(rhs, x, mask)
        self.acc.zero_()
        init.launch()
        acc = self._accumulators()
        tol2 = np.maximum(rtol * rtol * acc[0, BB], np.square(atol))
        self._tol2_host[:tol2.size] = tol2
        self.tol2.assign(self._tol2_host.reshape(self.tol2.shape + (self.width,)))
        it = 0
        slot = 0
        if self.vcycle is not None and not np.all(acc[slot, RR] <= tol2):
            # z = M r and RZ into slot 0, then p = z (beta = 0: slot 2 is still zero)
            self.vcycle.apply(mask, self.r, self.z, self.acc, 0)
            direction[0].launch()
        while not np.all(acc[slot, RR] <= tol2) and it < max_iterations:
            it += 1
            slot = it % 3
            matvec[slot].launch()
            update[slot].launch()
            acc = self._accumulators()
            if np.all(acc[slot, RR] <= tol2):
                break
            if self.vcycle is not None:
                self.vcycle.apply(mask, self.r, self.z, self.acc, slot)
            direction[slot].launch()
        bb = acc[0, BB]
        rel = np.sqrt(np.divide(acc[slot, RR], bb, out=np.zeros_like(bb), where=bb > 0))
        return it, rel
