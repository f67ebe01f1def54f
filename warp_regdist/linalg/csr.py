"""scipy sparse matrices as the Warp CSR arrays the PCG and multigrid kernels read."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import warp as wp

__all__ = ["csr_arrays"]


def csr_arrays(matrix, scalar, device):
    """(offsets, columns, values) Warp arrays of a scipy sparse matrix, column indices sorted."""
    M = sp.csr_matrix(matrix)
    M.sort_indices()
    return (wp.array(M.indptr.astype(np.int32), dtype=wp.int32, device=device),
            wp.array(M.indices.astype(np.int32), dtype=wp.int32, device=device),
            wp.array(M.data, dtype=scalar, device=device))
