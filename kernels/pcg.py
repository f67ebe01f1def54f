"""Batched preconditioned conjugate gradient kernels for  mask * K * mask  x = b.

K is a symmetric CSR matrix with scalar values shared by all columns; ``mask`` (n, nb)
is 1 on the free unknowns of each column and 0 on fixed ones (sources, unreachable
vertices), where x, b, r and every iterate stay 0. The preconditioner z = M r is a separate
operator (its own launches between those of the loop); the loop masks z in cg_direction.

Everything the loop decides lives on the device, so a loop body is one fixed sequence
of launches (replayable, capturable as a graph):

- ``counters`` (2,) int32: ITERATION k (iterations done), MAX_ITERATIONS;
  ``running`` (1,) int32: 1 while some lane has |r|^2 > tol2 and k < MAX_ITERATIONS.
  Every loop kernel returns at once when ``running`` is 0, so extra bodies are no-ops.
- ``acc`` (3, 3, nb): per-lane dot products in three rotating slots with rows PQ, RZ, RR;
  after k iterations slot k % 3 holds the current r.r, slot (k - 1) % 3 the previous
  r.z, and slot (k + 1) % 3 is cleared for the next iteration (no reset launch).
- ``bb`` (nb,): |b|^2 per lane; ``converged`` (nb,): 1 on lanes with |r|^2 <= tol2,
  tol2 = max(rtol2 |b|^2, atol2) per lane (``rtol2`` (1,), ``atol2`` (nb,)).
- ``coef`` (2, nb): per-lane BETA and ALPHA of the current iteration, computed once per
  block by one-thread-per-block kernels, so the row loops only read them.

One iteration from k: z = M r, cg_dot (RZ of slot k), cg_beta (beta = rz_k / rz_k-1, clears
slot k + 1), cg_direction (p = mask z + beta p), cg_matvec (q = mask K p, PQ of slot k + 1),
cg_alpha (a = rz_k / pq on lanes not converged), cg_update (x += a p, r -= a q, RR of slot
k + 1), cg_check (k += 1, converged flags, running).

Row loops: each thread of a (row chunks, block groups) launch handles ``chunk`` consecutive
rows (``lanes.chunk_rows``) of ``group`` column blocks (``lanes.group_blocks``);
``lanes.row_dim`` is that launch's dimension, ``lanes.thread_span`` chooses (chunk, group).
"""

import functools
import types

import warp as wp

from .lanes import chunk_rows, group_blocks, lane_type

PQ, RZ, RR = 0, 1, 2
BETA, ALPHA = 0, 1
ITERATION, MAX_ITERATIONS = 0, 1


@functools.cache
def pcg_kernels(scalar, W):
    """The PCG kernels for lane vectors of W ``scalar`` values."""
    V = lane_type(scalar, W)
    module = wp.get_module(f"warp_regdist_pcg_{scalar.__name__}_{W}")
    zero = scalar(0.0)
    one = scalar(1.0)

    vector_cpp = f"wp::vec_t<{W}, wp::{scalar.__name__}>"

    @wp.func_native(f"""
    // raw pointers: Warp's own indexing adds a negative-index wrap and a stride product per access
    const char* column = reinterpret_cast<const char*>(x.data) + static_cast<size_t>(b) * x.strides[1];
    const size_t row_stride = static_cast<size_t>(x.strides[0]);
    {vector_cpp} s = {vector_cpp}();
    const int e = offsets.data[i + 1];
    for (int p = offsets.data[i]; p < e; ++p)
        s = wp::add(s, wp::mul(vals.data[p],
                               *reinterpret_cast<const {vector_cpp}*>(column + cols.data[p] * row_stride)));
    return s;
    """)
    def matvec_row(offsets: wp.array(dtype=wp.int32), cols: wp.array(dtype=wp.int32),
                   vals: wp.array(dtype=scalar), x: wp.array2d(dtype=V), i: int, b: int) -> V:
        """(A x)_i of column block b for a CSR matrix A (sum over the row's entries in storage order)."""
        ...

    @wp.kernel(enable_backward=False, module=module)
    def cg_reset(acc: wp.array3d(dtype=V), bb: wp.array(dtype=V), converged: wp.array(dtype=V),
                 counters: wp.array(dtype=wp.int32), running: wp.array(dtype=wp.int32)):
        """Clear the accumulators of block b; the first thread sets k = 0 and running = 1."""
        b = wp.tid()
        for s in range(3):
            acc[s, PQ, b] = V()
            acc[s, RZ, b] = V()
            acc[s, RR, b] = V()
        bb[b] = V()
        converged[b] = V()
        if b == 0:
            counters[ITERATION] = 0
            running[0] = 1

    @wp.kernel(enable_backward=False, module=module)
    def cg_init(offsets: wp.array(dtype=wp.int32), cols: wp.array(dtype=wp.int32), vals: wp.array(dtype=scalar),
                mask: wp.array2d(dtype=V), rhs: wp.array2d(dtype=V), x: wp.array2d(dtype=V),
                r: wp.array2d(dtype=V), acc: wp.array3d(dtype=V), bb: wp.array(dtype=V), chunk: int, group: int,
                n: int):
        """r = b - mask K x; slot 0 RR += r.r, bb += b.b."""
        c, g = wp.tid()
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            rr = V()
            sb = V()
            for i in range(i0, i1):
                ri = rhs[i, b] - wp.cw_mul(mask[i, b], matvec_row(offsets, cols, vals, x, i, b))
                r[i, b] = ri
                rr += wp.cw_mul(ri, ri)
                sb += wp.cw_mul(rhs[i, b], rhs[i, b])
            wp.atomic_add(acc, 0, RR, b, rr)
            wp.atomic_add(bb, b, sb)

    @wp.kernel(enable_backward=False, module=module)
    def cg_check(acc: wp.array3d(dtype=V), bb: wp.array(dtype=V), rtol2: wp.array(dtype=scalar),
                 atol2: wp.array(dtype=V), converged: wp.array(dtype=V), counters: wp.array(dtype=wp.int32),
                 running: wp.array(dtype=wp.int32), advance: int, blocks: int):
        """One thread: k += advance; converged = |r|^2 <= tol2 per lane (NaN is not); running."""
        if running[0] == 0:
            return
        k = counters[ITERATION] + advance
        counters[ITERATION] = k
        s = k % 3
        active = int(0)
        for b in range(blocks):
            flags = V()
            for l in range(W):
                if acc[s, RR, b][l] <= wp.max(rtol2[0] * bb[b][l], atol2[b][l]):
                    flags[l] = one
                else:
                    active = 1
            converged[b] = flags
        if k >= counters[MAX_ITERATIONS]:
            active = 0
        running[0] = active

    @wp.kernel(enable_backward=False, module=module)
    def cg_dot(r: wp.array2d(dtype=V), z: wp.array2d(dtype=V), acc: wp.array3d(dtype=V),
               counters: wp.array(dtype=wp.int32), running: wp.array(dtype=wp.int32), chunk: int, group: int,
               n: int):
        """slot k RZ += r.z (= r.(mask z): r vanishes where mask is 0)."""
        if running[0] == 0:
            return
        c, g = wp.tid()
        s = counters[ITERATION] % 3
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            rz = V()
            for i in range(i0, i1):
                rz += wp.cw_mul(r[i, b], z[i, b])
            wp.atomic_add(acc, s, RZ, b, rz)

    @wp.kernel(enable_backward=False, module=module)
    def cg_beta(acc: wp.array3d(dtype=V), coef: wp.array2d(dtype=V), counters: wp.array(dtype=wp.int32),
                running: wp.array(dtype=wp.int32)):
        """Block b: coef BETA = rz_k / rz_k-1 per lane (0 at k = 0); clears slot k + 1."""
        if running[0] == 0:
            return
        b = wp.tid()
        k = counters[ITERATION]
        beta = V()
        for l in range(W):
            den = acc[(k + 2) % 3, RZ, b][l]
            if den > zero:
                beta[l] = acc[k % 3, RZ, b][l] / den
        coef[BETA, b] = beta
        nxt = (k + 1) % 3
        acc[nxt, PQ, b] = V()
        acc[nxt, RZ, b] = V()
        acc[nxt, RR, b] = V()

    @wp.kernel(enable_backward=False, module=module)
    def cg_direction(mask: wp.array2d(dtype=V), p: wp.array2d(dtype=V), z: wp.array2d(dtype=V),
                     coef: wp.array2d(dtype=V),
                     counters: wp.array(dtype=wp.int32), running: wp.array(dtype=wp.int32), chunk: int, group: int,
                     n: int):
        """p = mask z + beta p (p = mask z at k = 0)."""
        if running[0] == 0:
            return
        c, g = wp.tid()
        k = counters[ITERATION]
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            beta = coef[BETA, b]
            for i in range(i0, i1):
                zi = wp.cw_mul(mask[i, b], z[i, b])
                if k == 0:
                    p[i, b] = zi
                else:
                    p[i, b] = zi + wp.cw_mul(beta, p[i, b])

    @wp.kernel(enable_backward=False, module=module)
    def cg_matvec(offsets: wp.array(dtype=wp.int32), cols: wp.array(dtype=wp.int32), vals: wp.array(dtype=scalar),
                  mask: wp.array2d(dtype=V), p: wp.array2d(dtype=V), q: wp.array2d(dtype=V),
                  acc: wp.array3d(dtype=V), counters: wp.array(dtype=wp.int32), running: wp.array(dtype=wp.int32),
                  chunk: int, group: int, n: int):
        """q = mask K p; slot k + 1 PQ += p.q."""
        if running[0] == 0:
            return
        c, g = wp.tid()
        s = (counters[ITERATION] + 1) % 3
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            pq = V()
            for i in range(i0, i1):
                qi = wp.cw_mul(mask[i, b], matvec_row(offsets, cols, vals, p, i, b))
                q[i, b] = qi
                pq += wp.cw_mul(p[i, b], qi)
            wp.atomic_add(acc, s, PQ, b, pq)

    @wp.kernel(enable_backward=False, module=module)
    def cg_alpha(acc: wp.array3d(dtype=V), converged: wp.array(dtype=V), coef: wp.array2d(dtype=V),
                 counters: wp.array(dtype=wp.int32), running: wp.array(dtype=wp.int32)):
        """Block b: coef ALPHA = rz_k / pq per lane (0 on converged lanes)."""
        if running[0] == 0:
            return
        b = wp.tid()
        k = counters[ITERATION]
        a = V()
        for l in range(W):
            pq = acc[(k + 1) % 3, PQ, b][l]
            if pq > zero and converged[b][l] == zero:
                a[l] = acc[k % 3, RZ, b][l] / pq
        coef[ALPHA, b] = a

    @wp.kernel(enable_backward=False, module=module)
    def cg_update(x: wp.array2d(dtype=V), r: wp.array2d(dtype=V), p: wp.array2d(dtype=V), q: wp.array2d(dtype=V),
                  acc: wp.array3d(dtype=V), coef: wp.array2d(dtype=V), counters: wp.array(dtype=wp.int32),
                  running: wp.array(dtype=wp.int32), chunk: int, group: int, n: int):
        """x += a p, r -= a q with a = coef ALPHA; slot k + 1 RR += r.r."""
        if running[0] == 0:
            return
        c, g = wp.tid()
        s = (counters[ITERATION] + 1) % 3
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            a = coef[ALPHA, b]
            rr = V()
            for i in range(i0, i1):
                x[i, b] = x[i, b] + wp.cw_mul(a, p[i, b])
                ri = r[i, b] - wp.cw_mul(a, q[i, b])
                r[i, b] = ri
                rr += wp.cw_mul(ri, ri)
            wp.atomic_add(acc, s, RR, b, rr)

    @wp.kernel(enable_backward=False, module=module)
    def jacobi_apply(dinv: wp.array(dtype=scalar), r: wp.array2d(dtype=V), z: wp.array2d(dtype=V),
                     chunk: int, group: int, n: int):
        """z = D^-1 r."""
        c, g = wp.tid()
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            for i in range(i0, i1):
                z[i, b] = dinv[i] * r[i, b]

    return types.SimpleNamespace(cg_reset=cg_reset, cg_init=cg_init, cg_check=cg_check, cg_dot=cg_dot,
                                 cg_beta=cg_beta, cg_direction=cg_direction, cg_alpha=cg_alpha, cg_matvec=cg_matvec, cg_update=cg_update,
                                 jacobi_apply=jacobi_apply, matvec_row=matvec_row, V=V)
