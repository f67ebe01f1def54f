"""Warp kernels of warp-regdist, with their launchers (installed as ``warp_regdist.kernels``).

Column-batched data layout used by every kernel: a quantity with one value per vertex
(element) and per column (source set) is a 2-D ``wp.array`` of shape (rows, nb) whose
dtype is a lane vector ``wp.types.vector(W, scalar)``; column j lives in lane j % W of
block j // W. W = 1 for one column, so single-source solves carry no padding. Kernels
are built by cached factories per (scalar, W), one Warp module per family and type, so
each is compiled once and then loaded from the kernel cache.

Each thread of a row loop handles ``chunk`` consecutive rows of ``group`` column blocks and
adds its partial sums per block with a single atomic: on CUDA a run of rows sized to give a
launch about 2^20 threads; on the CPU 128 rows of one block, or one row of every block when
there are many (``lanes.thread_span``).
"""
