"""Warp kernels of warp-regdist, with their launchers (installed as ``warp_regdist.kernels``).

Column-batched data layout used by every kernel: a quantity with one value per vertex
(element) and per column (source set) is a 2-D ``wp.array`` of shape (rows, nb) whose
dtype is a lane vector ``wp.types.vector(W, scalar)``; column j lives in lane j % W of
block j // W. W = 1 for one column, so single-source solves carry no padding. Kernels
are built by cached factories per (scalar, W), one Warp module per family and type, so
each is compiled once and then loaded from the kernel cache.

Each thread handles a chunk of ``chunk`` consecutive rows of one column block and adds
its partial sums with a single atomic (chunk 128 on the CPU, 1 on CUDA: lanes.chunk_size).
"""

from .lanes import lane_type, chunk_size  # noqa: F401
