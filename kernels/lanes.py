"""Lane vector types and launch geometry shared by the kernel families."""

import functools
import types

import warp as wp

__all__ = ["lane_type", "lane_width", "chunk_size", "row_dim", "chunk_rows", "lane_kernels", "lane_funcs", "SCALARS",
           "R2", "G2", "Z2", "S2", "DY2"]

SCALARS = {"float32": wp.float32, "float64": wp.float64}

# Rows of the per-lane ADMM accumulator acc (5, nb) of both solvers: the element step's
# a_e |G u - z|^2, a_e |G u|^2, a_e |z|^2 (R2, G2, Z2), the vertex step's |D (z - z_old)|^2, |D y|^2 (S2, DY2).
R2, G2, Z2, S2, DY2 = 0, 1, 2, 3, 4

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


def chunk_size(device, blocks=1):
    """Rows per thread of a (row chunks, blocks) launch over arrays of ``blocks`` column blocks.

    One row on CUDA. On the CPU one core runs the launch thread by thread, blocks fastest:
    128 rows per thread (one atomic per chunk), except for arrays of many blocks (the
    all-pairs state: 122 on cat), whose consecutive rows of one block lie blocks x 64 bytes
    apart; one row per thread then walks each row's blocks contiguously (the all-pairs
    element step on cat: 92 ms instead of 300-370 ms; a 64-source batch, 8 blocks, was
    fastest at 128).
    """
    return 1 if wp.get_device(device).is_cuda or blocks >= 32 else 128


def row_dim(n, chunk, blocks=None):
    """Launch dimension (row chunks, blocks) of a row loop over n rows, ``chunk`` rows per thread
    ((row chunks,) without blocks)."""
    chunks = (n + chunk - 1) // chunk
    return (chunks,) if blocks is None else (chunks, blocks)


@wp.func
def chunk_rows(c: int, chunk: int, n: int):
    """First and one-past-last row of chunk c."""
    return c * chunk, wp.min(c * chunk + chunk, n)


@functools.cache
def lane_kernels(scalar, W):
    """Kernels that rearrange columns stored as lanes of W ``scalar`` values."""
    V = lane_type(scalar, W)
    module = wp.get_module(f"warp_regdist_lanes_{scalar.__name__}_{W}")

    @wp.kernel(enable_backward=False, module=module)
    def move_columns(a: wp.array2d(dtype=V), src: wp.array(dtype=wp.int32), dst: wp.array(dtype=wp.int32),
                     count: int, chunk: int, rows: int):
        """Column dst[t] = column src[t] for t < count, in every row; column j is lane j % W of block j // W.
        The sources and destinations must be disjoint sets of columns."""
        c = wp.tid()
        i0, i1 = chunk_rows(c, chunk, rows)
        for i in range(i0, i1):
            for t in range(count):
                s = src[t]
                d = dst[t]
                v = a[i, d // W]
                v[d % W] = a[i, s // W][s % W]
                a[i, d // W] = v

    return types.SimpleNamespace(move_columns=move_columns)


@functools.cache
def lane_funcs(scalar, W):
    """Per-element functions on lane vectors shared by the ADMM kernel families."""
    V = lane_type(scalar, W)
    V3 = wp.types.vector(3, scalar)
    module = wp.get_module(f"warp_regdist_lanes_{scalar.__name__}_{W}")
    one = scalar(1.0)

    @wp.func(module=module)
    def element_gradient(elements: wp.array2d(dtype=wp.int32), basis: wp.array2d(dtype=V3), u: wp.array2d(dtype=V),
                         e: int, b: int, k: int):
        """(G u)_e per lane as its x, y, z components: sum over the k corners l of basis[e, l] u_l."""
        gx = V()
        gy = V()
        gz = V()
        for l in range(k):
            ul = u[elements[e, l], b]
            gl = basis[e, l]
            gx += gl[0] * ul
            gy += gl[1] * ul
            gz += gl[2] * ul
        return gx, gy, gz

    @wp.func(module=module)
    def ball_scale(vx: V, vy: V, vz: V):
        """Per lane 1 / max(1, |v|): the projection onto the unit ball is scale * v."""
        s = V()
        for l in range(W):
            s[l] = one / wp.max(one, wp.sqrt(vx[l] * vx[l] + vy[l] * vy[l] + vz[l] * vz[l]))
        return s

    @wp.func(module=module)
    def norm2(x: V, y: V, z: V):
        """Per lane |(x, y, z)|^2."""
        return wp.cw_mul(x, x) + wp.cw_mul(y, y) + wp.cw_mul(z, z)

    return types.SimpleNamespace(element_gradient=element_gradient, ball_scale=ball_scale, norm2=norm2)
