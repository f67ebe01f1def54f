"""Kernels of the multigrid V-cycle preconditioner  z = M_0 r  (warp_regdist/multigrid.py).

Level l holds y_l (restricted residual) and z_l (its correction); y_0 = r and z_0 = z
are the caller's. One application is  y_l+1 = R_l y_l  down the levels (mg_restrict),
z_L = A_L^+ y_L  with a dense matrix (mg_coarse), then  z_l = S_l y_l + R_l^T z_l+1  up
the levels (mg_prolong). Every sparse product is a CSR row loop (the PCG's
``matvec_row`` over ``chunk_rows`` and ``group_blocks``), so the kernels are the same on CPU and CUDA.
"""

import functools
import types

import warp as wp

from .lanes import chunk_rows, group_blocks, lane_type
from .pcg import pcg_kernels


@functools.cache
def multigrid_kernels(scalar, W):
    """The V-cycle kernels for lane vectors of W ``scalar`` values."""
    V = lane_type(scalar, W)
    module = wp.get_module(f"warp_regdist_multigrid_{scalar.__name__}_{W}")
    matvec_row = pcg_kernels(scalar, W).matvec_row

    @wp.kernel(enable_backward=False, module=module)
    def mg_restrict(offsets: wp.array(dtype=wp.int32), cols: wp.array(dtype=wp.int32), vals: wp.array(dtype=scalar),
                    y: wp.array2d(dtype=V), yc: wp.array2d(dtype=V), chunk: int, group: int, n: int):
        """yc = R y (n rows of R)."""
        c, g = wp.tid()
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            for i in range(i0, i1):
                yc[i, b] = matvec_row(offsets, cols, vals, y, i, b)

    @wp.kernel(enable_backward=False, module=module)
    def mg_coarse(inverse: wp.array2d(dtype=scalar), y: wp.array2d(dtype=V), z: wp.array2d(dtype=V),
                  chunk: int, group: int, n: int):
        """z = A_L^+ y with the dense (n, n) pseudo-inverse; four rows at a time share the loads of y
        and keep four independent sums in flight (each still adds j = 0, 1, ... in order)."""
        c, g = wp.tid()
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            i = i0
            while i + 4 <= i1:
                s0 = V()
                s1 = V()
                s2 = V()
                s3 = V()
                j = int(0)
                while j < n:
                    yj = y[j, b]
                    s0 += inverse[i, j] * yj
                    s1 += inverse[i + 1, j] * yj
                    s2 += inverse[i + 2, j] * yj
                    s3 += inverse[i + 3, j] * yj
                    j += 1
                z[i, b] = s0
                z[i + 1, b] = s1
                z[i + 2, b] = s2
                z[i + 3, b] = s3
                i += 4
            while i < i1:
                s = V()
                j = int(0)
                while j < n:
                    s += inverse[i, j] * y[j, b]
                    j += 1
                z[i, b] = s
                i += 1

    @wp.kernel(enable_backward=False, module=module)
    def mg_prolong(s_offsets: wp.array(dtype=wp.int32), s_cols: wp.array(dtype=wp.int32),
                   s_vals: wp.array(dtype=scalar), p_offsets: wp.array(dtype=wp.int32),
                   p_cols: wp.array(dtype=wp.int32), p_vals: wp.array(dtype=scalar),
                   y: wp.array2d(dtype=V), zc: wp.array2d(dtype=V), z: wp.array2d(dtype=V), chunk: int, group: int,
                   n: int):
        """z = S y + R^T zc  (R^T stored as the CSR p_*)."""
        c, g = wp.tid()
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            for i in range(i0, i1):
                z[i, b] = (matvec_row(s_offsets, s_cols, s_vals, y, i, b)
                           + matvec_row(p_offsets, p_cols, p_vals, zc, i, b))

    return types.SimpleNamespace(mg_restrict=mg_restrict, mg_coarse=mg_coarse, mg_prolong=mg_prolong)
