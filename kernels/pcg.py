"""Batched preconditioned conjugate gradient kernels for  mask * K * mask  x = b.

K is a symmetric CSR matrix with scalar values shared by all columns; ``mask`` (n, nb)
is 1 on the free unknowns of each column and 0 on fixed ones (sources, unreachable
vertices), where x, b and every iterate stay 0. Dot products are per lane and kept in a
small accumulator array ``acc`` of shape (3, 4, nb): three rotating slots (iteration
k uses slot k % 3, reads slot (k - 1) % 3 and clears slot (k + 1) % 3) with rows
PQ, RZ, RR, BB, so that no launch is needed to reset them.

With ``jacobi`` = 1, cg_init and cg_update also apply the Jacobi preconditioner
z = D^-1 r and add r.z to RZ (cg_init also sets p = z); with ``jacobi`` = 0 they leave z,
p and RZ to a separate preconditioner (kernels/multigrid.py) followed by cg_direction.
"""

import functools
import types

import warp as wp

from .lanes import lane_type

PQ, RZ, RR, BB = 0, 1, 2, 3


@functools.cache
def pcg_kernels(scalar, W):
    """The PCG kernels for lane vectors of W ``scalar`` values."""
    V = lane_type(scalar, W)
    module = wp.get_module(f"warp_regdist_pcg_{scalar.__name__}_{W}")
    zero = scalar(0.0)

    @wp.func(module=module)
    def matvec_row(offsets: wp.array(dtype=wp.int32), cols: wp.array(dtype=wp.int32),
                   vals: wp.array(dtype=scalar), x: wp.array2d(dtype=V), i: int, b: int):
        s = V()
        p = offsets[i]
        e = offsets[i + 1]
        while p < e:
            s += vals[p] * x[cols[p], b]
            p += 1
        return s

    @wp.kernel(enable_backward=False, module=module)
    def cg_init(offsets: wp.array(dtype=wp.int32), cols: wp.array(dtype=wp.int32), vals: wp.array(dtype=scalar),
                dinv: wp.array(dtype=scalar), mask: wp.array2d(dtype=V), rhs: wp.array2d(dtype=V),
                x: wp.array2d(dtype=V), r: wp.array2d(dtype=V), z: wp.array2d(dtype=V), p: wp.array2d(dtype=V),
                acc: wp.array3d(dtype=V), jacobi: int, chunk: int, n: int):
        """r = b - mask K x; slot 0: RR, BB (= |b|^2); with jacobi: z = p = D^-1 r and RZ."""
        c, b = wp.tid()
        rz = V()
        rr = V()
        bb = V()
        for i in range(c * chunk, wp.min(c * chunk + chunk, n)):
            mk = mask[i, b]
            ri = rhs[i, b] - wp.cw_mul(mk, matvec_row(offsets, cols, vals, x, i, b))
            r[i, b] = ri
            if jacobi != 0:
                zi = dinv[i] * ri
                z[i, b] = zi
                p[i, b] = zi
                rz += wp.cw_mul(ri, zi)
            rr += wp.cw_mul(ri, ri)
            bb += wp.cw_mul(rhs[i, b], rhs[i, b])
        if jacobi != 0:
            wp.atomic_add(acc, 0, RZ, b, rz)
        wp.atomic_add(acc, 0, RR, b, rr)
        wp.atomic_add(acc, 0, BB, b, bb)

    @wp.kernel(enable_backward=False, module=module)
    def cg_matvec(offsets: wp.array(dtype=wp.int32), cols: wp.array(dtype=wp.int32), vals: wp.array(dtype=scalar),
                  mask: wp.array2d(dtype=V), p: wp.array2d(dtype=V), q: wp.array2d(dtype=V),
                  acc: wp.array3d(dtype=V), slot: int, chunk: int, n: int):
        """q = mask K p; slot PQ += p.q."""
        c, b = wp.tid()
        pq = V()
        for i in range(c * chunk, wp.min(c * chunk + chunk, n)):
            qi = wp.cw_mul(mask[i, b], matvec_row(offsets, cols, vals, p, i, b))
            q[i, b] = qi
            pq += wp.cw_mul(p[i, b], qi)
        wp.atomic_add(acc, slot, PQ, b, pq)

    @wp.kernel(enable_backward=False, module=module)
    def cg_update(dinv: wp.array(dtype=scalar), x: wp.array2d(dtype=V), r: wp.array2d(dtype=V),
                  z: wp.array2d(dtype=V), p: wp.array2d(dtype=V), q: wp.array2d(dtype=V),
                  acc: wp.array3d(dtype=V), tol2: wp.array(dtype=V), slot: int, prev: int, jacobi: int,
                  chunk: int, n: int):
        """x += a p, r -= a q, a = rz_prev / pq per lane (0 where |r|^2 <= tol2); with jacobi: z = D^-1 r, RZ."""
        c, b = wp.tid()
        a = V()
        for l in range(W):
            pq = acc[slot, PQ, b][l]
            if pq > zero and acc[prev, RR, b][l] > tol2[b][l]:
                a[l] = acc[prev, RZ, b][l] / pq
        rz = V()
        rr = V()
        for i in range(c * chunk, wp.min(c * chunk + chunk, n)):
            x[i, b] = x[i, b] + wp.cw_mul(a, p[i, b])
            ri = r[i, b] - wp.cw_mul(a, q[i, b])
            r[i, b] = ri
            if jacobi != 0:
                zi = dinv[i] * ri
                z[i, b] = zi
                rz += wp.cw_mul(ri, zi)
            rr += wp.cw_mul(ri, ri)
        if jacobi != 0:
            wp.atomic_add(acc, slot, RZ, b, rz)
        wp.atomic_add(acc, slot, RR, b, rr)

    @wp.kernel(enable_backward=False, module=module)
    def cg_direction(p: wp.array2d(dtype=V), z: wp.array2d(dtype=V), acc: wp.array3d(dtype=V),
                     slot: int, prev: int, nxt: int, chunk: int, n: int):
        """p = z + beta p with beta = rz / rz_prev per lane; the first thread clears slot nxt."""
        c, b = wp.tid()
        beta = V()
        for l in range(W):
            den = acc[prev, RZ, b][l]
            if den > zero:
                beta[l] = acc[slot, RZ, b][l] / den
        for i in range(c * chunk, wp.min(c * chunk + chunk, n)):
            p[i, b] = z[i, b] + wp.cw_mul(beta, p[i, b])
        if c == 0:
            acc[nxt, PQ, b] = V()
            acc[nxt, RZ, b] = V()
            acc[nxt, RR, b] = V()

    return types.SimpleNamespace(cg_init=cg_init, cg_matvec=cg_matvec, cg_update=cg_update,
                                 cg_direction=cg_direction, matvec_row=matvec_row, V=V)
