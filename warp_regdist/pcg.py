"""Column-batched preconditioned conjugate gradient on Warp arrays (no factorization).

Solves  mask K mask x = b  for every column at once, where K is one symmetric positive
(semi-)definite sparse matrix shared by all columns and ``mask`` selects each column's
free unknowns (K restricted to them is positive definite). Warm starts come for free:
``x`` holds the initial guess on entry.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .kernels.lanes import chunk_size
from .kernels.pcg import BB, RR, pcg_kernels

__all__ = ["BatchedPCG"]


class BatchedPCG:
    """Jacobi-preconditioned CG for (n, nb) lane-vector columns.

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
    """

    def __init__(self, matrix, scalar, width, blocks, device):
        K = matrix.tocsr()
        K.sort_indices()
        self.n = K.shape[0]
        self.device = wp.get_device(device)
        self.kernels = pcg_kernels(scalar, width)
        V = self.kernels.V
        self.width = width
        self.offsets = wp.array(K.indptr.astype(np.int32), dtype=wp.int32, device=device)
        self.columns = wp.array(K.indices.astype(np.int32), dtype=wp.int32, device=device)
        self.values = wp.array(K.data, dtype=scalar, device=device)
        diag = K.diagonal()
        self.dinv = wp.array(np.where(diag > 0, 1.0 / np.where(diag > 0, diag, 1.0), 0.0), dtype=scalar, device=device)
        shape = (self.n, blocks)
        self.r, self.z, self.p, self.q = (wp.zeros(shape, dtype=V, device=device) for _ in range(4))
        self.acc = wp.zeros((3, 4, blocks), dtype=V, device=device)
        self.tol2 = wp.zeros(blocks, dtype=V, device=device)
        self.chunk = chunk_size(device)
        self.dim = ((self.n + self.chunk - 1) // self.chunk, blocks)
        self.scalar = scalar

    def _accumulators(self):
        return self.acc.numpy().reshape(3, 4, -1)

    def solve(self, rhs, x, mask, rtol, max_iterations, atol=0.0):
        """Run PCG until |b - K x| <= max(rtol |b|, atol) in every lane or ``max_iterations``.

        Parameters
        ----------
        rhs, x, mask : (n, nb) wp.array of lane vectors
            Right-hand side (zero where mask is 0), initial guess (overwritten by the
            solution), free-unknown mask (1 free, 0 fixed).
        rtol : float
        max_iterations : int
        atol : float or (nb * width,) ndarray
            Absolute residual tolerance per lane.

        Returns
        -------
        iterations : int
        relative_residual : (nb * width,) ndarray, |r| / |b| per lane (0 where b = 0).
        """
        k = self.kernels
        chunk, n = self.chunk, self.n
        self.acc.zero_()
        wp.launch(k.cg_init, self.dim, inputs=[self.offsets, self.columns, self.values, self.dinv, mask, rhs, x,
                                               self.r, self.z, self.p, self.acc, chunk, n], device=self.device)
        acc = self._accumulators()
        tol2 = np.maximum(rtol * rtol * acc[0, BB], np.square(atol))
        self.tol2.assign(tol2.reshape(self.tol2.shape + (self.width,)))
        it = 0
        slot = 0
        while not np.all(acc[slot, RR] <= tol2) and it < max_iterations:
            it += 1
            prev, slot = slot, it % 3
            wp.launch(k.cg_matvec, self.dim, inputs=[self.offsets, self.columns, self.values, mask, self.p, self.q,
                                                     self.acc, slot, chunk, n], device=self.device)
            wp.launch(k.cg_update, self.dim, inputs=[self.dinv, x, self.r, self.z, self.p, self.q, self.acc,
                                                     self.tol2, slot, prev, chunk, n], device=self.device)
            acc = self._accumulators()
            if np.all(acc[slot, RR] <= tol2):
                break
            wp.launch(k.cg_direction, self.dim, inputs=[self.p, self.z, self.acc, slot, prev, (it + 1) % 3, chunk, n],
                      device=self.device)
        bb = acc[0, BB]
        rel = np.sqrt(np.divide(acc[slot, RR], bb, out=np.zeros_like(bb), where=bb > 0))
        return it, rel
