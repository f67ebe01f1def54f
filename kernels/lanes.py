"""Lane vector types and launch geometry shared by the kernel families."""

import functools
import types

import warp as wp

__all__ = ["lane_type", "lane_width", "thread_span", "row_dim", "chunk_rows", "group_blocks", "ALL_BLOCKS",
           "lane_kernels", "lane_funcs", "SCALARS", "R2", "G2", "Z2", "S2", "DY2"]

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


ALL_BLOCKS = 32
"""From this many column blocks per row a CPU thread takes one row of all of them (:func:`thread_span`)."""


def thread_span(device, blocks=1, row_blocks=None):
    """(rows, group): the rows and column blocks each thread of a launch handles, over
    ``blocks`` active column blocks of arrays whose rows hold ``row_blocks`` blocks (default
    ``blocks``); the launch's second dimension is blocks // group.

    One row of one block on CUDA. On the CPU one core runs the launch thread by thread:
    128 rows of one block per thread (one atomic per chunk) for short rows; for long rows
    (>= ``ALL_BLOCKS`` blocks: the all-pairs state, 122 on cat) the consecutive rows of one
    block lie row_blocks x 64 bytes apart, so one thread takes one row of every active block,
    a contiguous run of memory.
    The sums over rows are added in another order in the two layouts, so the choice depends
    on the arrays' layout alone, not on how many of their blocks a launch covers.
    """
    if wp.get_device(device).is_cuda:
        return 1, 1
    return (1, blocks) if (blocks if row_blocks is None else row_blocks) >= ALL_BLOCKS else (128, 1)


def row_dim(n, span, blocks=None):
    """Launch dimension (row chunks, block groups) of a loop over n rows and ``blocks`` column blocks
    with ``span`` = (rows, group) per thread ((row chunks,) without blocks)."""
    chunks = (n + span[0] - 1) // span[0]
    return (chunks,) if blocks is None else (chunks, blocks // span[1])


@wp.func
def chunk_rows(c: int, chunk: int, n: int):
    """First and one-past-last row of chunk c."""
    return c * chunk, wp.min(c * chunk + chunk, n)


@wp.func
def group_blocks(g: int, group: int):
    """First and one-past-last column block of block group g."""
    return g * group, g * group + group


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
    """The per-element core both ADMM kernel families share (single source, all pairs): the element
    gradient, the projection onto the unit ball and the element's terms of the residual sums."""
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

    @wp.func(module=module)
    def project(vx: V, vy: V, vz: V):
        """Per lane the projection of v onto the unit ball, v / max(1, |v|)."""
        s = ball_scale(vx, vy, vz)
        return wp.cw_mul(s, vx), wp.cw_mul(s, vy), wp.cw_mul(s, vz)

    @wp.func(module=module)
    def element_sums(a: scalar, gx: V, gy: V, gz: V, zx: V, zy: V, zz: V):
        """Per lane the element's terms of the residual sums: a |g - z|^2, a |g|^2, a |z|^2 (rows R2, G2, Z2)."""
        return a * norm2(gx - zx, gy - zy, gz - zz), a * norm2(gx, gy, gz), a * norm2(zx, zy, zz)

    return types.SimpleNamespace(element_gradient=element_gradient, ball_scale=ball_scale, norm2=norm2,
                                 project=project, element_sums=element_sums)
