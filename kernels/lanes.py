"""Lane vector types, launch geometry and column moves shared by the kernel families."""

import functools
import types

import warp as wp

__all__ = ["lane_type", "lane_width", "thread_span", "row_dim", "chunk_rows", "group_blocks", "ALL_BLOCKS",
           "CUDA_THREADS", "lane_kernels", "SCALARS"]

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


ALL_BLOCKS = 32
"""From this many column blocks per row a CPU thread takes one row of all of them (:func:`thread_span`)."""

CUDA_THREADS = 1 << 20
"""About this many threads per CUDA launch over rows x blocks (:func:`thread_span`): a few waves of a
large GPU, each thread summing a run of rows before its one atomic add."""


def thread_span(device, blocks=1, row_blocks=None, rows=None):
    """(rows per thread, group): the rows and column blocks each thread of a launch handles, over
    ``blocks`` active column blocks of arrays whose rows hold ``row_blocks`` blocks (default
    ``blocks``); the launch's second dimension is blocks // group.

    On CUDA one block per thread, and ``rows`` x blocks / CUDA_THREADS consecutive rows (at least
    one; one without ``rows``): threads enough to fill the GPU, and per-lane sums added to their
    accumulators once per run of rows instead of once per row. On the CPU one core runs the launch
    thread by thread: 128 rows of one block per thread (one atomic per chunk) for short rows; for
    long rows (>= ``ALL_BLOCKS`` blocks: the all-pairs state, 122 on cat) the consecutive rows of one
    block lie row_blocks x 64 bytes apart, so one thread takes one row of every active block,
    a contiguous run of memory.
    The sums over rows are added in another order in the two layouts, so the choice depends
    on the arrays' layout alone, not on how many of their blocks a launch covers.
    """
    if wp.get_device(device).is_cuda:
        return (1 if rows is None else max(1, rows * blocks // CUDA_THREADS)), 1
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
