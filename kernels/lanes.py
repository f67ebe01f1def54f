"""Lane vector types and launch geometry shared by the kernel families."""

from __future__ import annotations

import functools

import warp as wp

__all__ = ["lane_type", "lane_width", "chunk_size", "SCALARS"]

SCALARS = {"float32": wp.float32, "float64": wp.float64}

# Lane widths per scalar type: 1 (single column) and a full SIMD-friendly block.
_WIDTHS = {wp.float64: (1, 4, 8), wp.float32: (1, 4, 16)}


def lane_width(scalar, n_columns):
    """Smallest supported lane width >= n_columns (the widest one for many columns)."""
    for w in _WIDTHS[scalar]:
        if n_columns <= w:
            return w
    return _WIDTHS[scalar][-1]


@functools.cache
def lane_type(scalar, width):
    """The Warp vector type with ``width`` lanes of ``scalar``."""
    return wp.types.vector(width, scalar)


def chunk_size(device):
    """Rows per thread: long chunks on the CPU (one core runs the launch), one row on CUDA."""
    return 1 if wp.get_device(device).is_cuda else 128
