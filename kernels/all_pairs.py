"""Kernels of the symmetric all-pairs ADMM (docs/method.md section 5), column-batched.

Shapes: X, U, H, DZ, DZ_acc, DY_acc, rhs (n, nb) of lane vectors V (column j = lane j % W of block
j // W, so row i of block b holds U[i, bW : bW + W]); v (m, 3, nb) per element and
component; A_V padded with zeros to nb W entries. Columns j >= n are padding (kept 0).

The element state is stored combined as v = Y / rho_v + h (the point that the last
z-step projected), from which Z = Proj(v) and Y = rho_v (v - Proj(v)) are recovered: the
projection onto the unit ball leaves Y / rho_v and Z on complementary sides, so one
(3m, n) array holds both (half the memory of Z and Y).

D = G^T M_F is applied by scattering from the element step (the single-source kernels gather
per vertex): a gather would need Z and Y per element, that is one projection of v per
incident vertex, which costs more than the scatter.
"""

import functools
import types

import warp as wp

from .element_core import DY2, S2, element_funcs
from .lanes import chunk_rows, group_blocks, lane_type

# Entries of the scalar accumulator (5,) of the consensus step, weighted by A_V[i] A_V[j].
RX2, X2, U2, SX2, H2 = 0, 1, 2, 3, 4


@functools.cache
def all_pairs_kernels(scalar, W):
    """All-pairs kernels for lane vectors of W ``scalar`` values on triangles."""
    V = lane_type(scalar, W)
    V3 = wp.types.vector(3, scalar)
    M = wp.types.matrix((W, W), scalar)
    module = wp.get_module(f"warp_regdist_all_pairs_{scalar.__name__}_{W}")
    one = scalar(1.0)
    zero = scalar(0.0)
    half = scalar(0.5)
    f = element_funcs(scalar, W)
    element_gradient, project, element_sums, add_sums = f.element_gradient, f.project, f.element_sums, f.add_sums
    project_lane = f.project_lane

    @wp.func(module=module)
    def own_lane(elements: wp.array2d(dtype=wp.int32), e: int, c: int, b: int, col0: int):
        """The lane of block b whose column is corner c of element e (column j's source is vertex j; the
        blocks' first column is col0), or -1."""
        local = elements[e, c] - col0
        lane = int(-1)
        if local >= 0 and local // W == b:
            lane = local % W
        return lane

    @wp.func(module=module)
    def project_own(elements: wp.array2d(dtype=wp.int32), directions: wp.array3d(dtype=V3), e: int, b: int,
                    col0: int, vx: V, vy: V, vz: V):
        """Proj_C(v) per lane: the unit ball, or the wedge at corner c on the lane of the column of corner c
        (element_core; ``directions`` (1, 3, 2) zeros: no wedges, col0 < 0). Most element blocks hold no
        corner's column: they return after three integer tests."""
        zx, zy, zz = project(vx, vy, vz)
        if col0 < 0:
            return zx, zy, zz
        l0 = own_lane(elements, e, 0, b, col0)
        l1 = own_lane(elements, e, 1, b, col0)
        l2 = own_lane(elements, e, 2, b, col0)
        if l0 < 0 and l1 < 0 and l2 < 0:
            return zx, zy, zz
        if l0 >= 0:
            zx, zy, zz = project_lane(zx, zy, zz, vx, vy, vz, l0, directions[e, 0, 0], directions[e, 0, 1])
        if l1 >= 0:
            zx, zy, zz = project_lane(zx, zy, zz, vx, vy, vz, l1, directions[e, 1, 0], directions[e, 1, 1])
        if l2 >= 0:
            zx, zy, zz = project_lane(zx, zy, zz, vx, vy, vz, l2, directions[e, 2, 0], directions[e, 2, 1])
        return zx, zy, zz

    @wp.kernel(enable_backward=False, module=module)
    def element_step(elements: wp.array2d(dtype=wp.int32), basis: wp.array2d(dtype=V3), vol: wp.array(dtype=scalar),
                     X: wp.array2d(dtype=V), v: wp.array3d(dtype=V), rho_v: scalar, rho: scalar,
                     relaxation: scalar, DZ_acc: wp.array2d(dtype=V), DY_acc: wp.array2d(dtype=V),
                     acc: wp.array2d(dtype=V), directions: wp.array3d(dtype=V3), col0: int,
                     chunk: int, group: int, m: int):
        """Over-relaxed z- and y-steps of the column gradients on a chunk of elements:

            Z_old = Proj(v), Y = rho_v (v - Z_old), g = (G X)_e, h = a g + (1 - a) Z_old,
            v <- Y / rho + h   (so Z_new = Proj(v), Y_new = rho (v - Z_new)),
        scatters the divergences D Z_new and D Y_new, (D w)_i += a_e basis[e, l_i] . w_e, into
        DZ_acc and DY_acc (zero on entry; atomic adds, plain adds on the CPU), and adds per
        lane a_e |g - Z_new|^2, a_e |g|^2, a_e |Z_new|^2 to acc rows R2, G2, Z2. Proj is onto the unit
        ball, or the wedge on a column's own triangles (:func:`project_own`).
        """
        c, g = wp.tid()
        e0, e1 = chunk_rows(c, chunk, m)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            r2 = V()
            g2 = V()
            z2 = V()
            for e in range(e0, e1):
                gx, gy, gz = element_gradient(elements, basis, X, e, b, 3)
                ox = v[e, 0, b]
                oy = v[e, 1, b]
                oz = v[e, 2, b]
                ox_z, oy_z, oz_z = project_own(elements, directions, e, b, col0, ox, oy, oz)
                k = rho_v / rho
                vx = k * (ox - ox_z) + relaxation * gx + (one - relaxation) * ox_z
                vy = k * (oy - oy_z) + relaxation * gy + (one - relaxation) * oy_z
                vz = k * (oz - oz_z) + relaxation * gz + (one - relaxation) * oz_z
                v[e, 0, b] = vx
                v[e, 1, b] = vy
                v[e, 2, b] = vz
                zx, zy, zz = project_own(elements, directions, e, b, col0, vx, vy, vz)
                a = vol[e]
                for l in range(3):
                    w = a * basis[e, l]
                    dz = w[0] * zx + w[1] * zy + w[2] * zz
                    wp.atomic_add(DZ_acc, elements[e, l], b, dz)
                    wp.atomic_add(DY_acc, elements[e, l], b, rho * (w[0] * vx + w[1] * vy + w[2] * vz - dz))
                dr2, dg2, dz2 = element_sums(a, gx, gy, gz, zx, zy, zz)
                r2 += dr2
                g2 += dg2
                z2 += dz2
            add_sums(acc, b, r2, g2, z2)

    @wp.kernel(enable_backward=False, module=module)
    def vertex_step(vertex_vol: wp.array(dtype=scalar), mask: wp.array2d(dtype=V), rho: scalar, rho2: scalar,
                    H: wp.array2d(dtype=V), U: wp.array2d(dtype=V), DZ_acc: wp.array2d(dtype=V),
                    DY_acc: wp.array2d(dtype=V), DZ: wp.array2d(dtype=V), rhs: wp.array2d(dtype=V),
                    acc: wp.array2d(dtype=V), chunk: int, group: int, n: int):
        """Right-hand side of the X-step (column j divided by A_V[j]) from the scattered divergences:

            rhs = mask ((1/2) A_V - D Y + rho D Z - M_V H + rho2 M_V U);
        adds |D Z - DZ|^2 (DZ: the previous D Z, then overwritten) and |D Y|^2 per lane to acc
        rows S2, DY2, and clears DZ_acc and DY_acc for the next element step.
        """
        c, g = wp.tid()
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            s2 = V()
            d2 = V()
            for i in range(i0, i1):
                dz = DZ_acc[i, b]
                dy = DY_acc[i, b]
                DZ_acc[i, b] = V()
                DY_acc[i, b] = V()
                ddz = dz - DZ[i, b]
                DZ[i, b] = dz
                s2 += wp.cw_mul(ddz, ddz)
                d2 += wp.cw_mul(dy, dy)
                ai = vertex_vol[i]
                rhs[i, b] = wp.cw_mul(mask[i, b], half * ai * V(one) - dy + rho * dz + ai * (rho2 * U[i, b] - H[i, b]))
            wp.atomic_add(acc, S2, b, s2)
            wp.atomic_add(acc, DY2, b, d2)

    @wp.func(module=module)
    def load_transposed(A: wp.array2d(dtype=V), row0: int, block: int, n: int):
        """T[r, l] = A[row0 + l, block][r]: the W x W tile of A^T (zero past row n)."""
        T = M()
        for l in range(W):
            if row0 + l < n:
                a = A[row0 + l, block]
                for r in range(W):
                    T[r, l] = a[r]
        return T

    @wp.kernel(enable_backward=False, module=module)
    def consensus_step(X: wp.array2d(dtype=V), U: wp.array2d(dtype=V), H: wp.array2d(dtype=V),
                       vertex_vol: wp.array(dtype=V), rho2: scalar, relaxation: scalar,
                       acc: wp.array2d(dtype=scalar), I0: int, n: int):
        """U- and H-steps on the tile pair (I, J), (J, I) of W x W entries, I <= J, I = I0 + first
        thread index (disjoint ranges of I may run in parallel):

            Xh = a X + (1 - a) U_old,
            U_ij = max(0, (1/2) ((H_ij + H_ji) / rho2 + Xh_ij + Xh_ji)),  U_ii = 0,
            H += rho2 (Xh - U),
        and the sums over entries, weighted by A_V[i] A_V[j], of (X - U)^2, X^2, U^2,
        (U - U_old)^2, H^2 (new H) into row I of acc (nb, 5), columns RX2, X2, U2, SX2, H2 (one row
        per tile row, so the totals do not depend on how the rows are split).
        """
        I, J = wp.tid()
        I += I0
        if I > J:
            return
        XT = load_transposed(X, J * W, I, n)
        HT = load_transposed(H, J * W, I, n)
        areas_j = vertex_vol[J]
        areas_i = vertex_vol[I]
        UT = M()
        HTn = M()
        rx2 = zero
        x2 = zero
        u2 = zero
        sx2 = zero
        h2 = zero
        for r in range(W):
            i = I * W + r
            if i < n:
                xa = X[i, J]
                ha = H[i, J]
                uo = U[i, J]
                xb = XT[r]
                hb = HT[r]
                xha = relaxation * xa + (one - relaxation) * uo
                xhb = relaxation * xb + (one - relaxation) * uo
                un = half * (wp.cw_div(ha + hb, V(rho2)) + (xha + xhb))  # symmetric in (a, b) to the last bit
                for l in range(W):
                    un[l] = wp.max(un[l], zero)
                if I == J:
                    un[r] = zero
                han = ha + rho2 * (xha - un)
                hbn = hb + rho2 * (xhb - un)
                U[i, J] = un
                H[i, J] = han
                if I != J:
                    for l in range(W):
                        UT[r, l] = un[l]
                        HTn[r, l] = hbn[l]
                w = areas_i[r] * areas_j
                da = xa - un
                du = un - uo
                rx2 += wp.dot(w, wp.cw_mul(da, da))
                x2 += wp.dot(w, wp.cw_mul(xa, xa))
                u2 += wp.dot(w, wp.cw_mul(un, un))
                sx2 += wp.dot(w, wp.cw_mul(du, du))
                h2 += wp.dot(w, wp.cw_mul(han, han))
                if I != J:
                    db = xb - un
                    rx2 += wp.dot(w, wp.cw_mul(db, db))
                    x2 += wp.dot(w, wp.cw_mul(xb, xb))
                    u2 += wp.dot(w, wp.cw_mul(un, un))
                    sx2 += wp.dot(w, wp.cw_mul(du, du))
                    h2 += wp.dot(w, wp.cw_mul(hbn, hbn))
        if I != J:
            for l in range(W):
                j = J * W + l
                if j < n:
                    ut = V()
                    ht = V()
                    for r in range(W):
                        ut[r] = UT[r, l]
                        ht[r] = HTn[r, l]
                    U[j, I] = ut
                    H[j, I] = ht
        wp.atomic_add(acc, I, RX2, rx2)
        wp.atomic_add(acc, I, X2, x2)
        wp.atomic_add(acc, I, U2, u2)
        wp.atomic_add(acc, I, SX2, sx2)
        wp.atomic_add(acc, I, H2, h2)

    @wp.kernel(enable_backward=False, module=module)
    def steepness(elements: wp.array2d(dtype=wp.int32), basis: wp.array2d(dtype=V3),
                  diameters: wp.array(dtype=scalar), U: wp.array2d(dtype=V), worst: wp.array(dtype=V),
                  directions: wp.array3d(dtype=V3), col0: int, chunk: int, group: int, m: int):
        """worst = max(worst, max over a chunk of elements e of (gauge - 1)_+ diam(e)) per lane, the gauge
        |(G U)_e| or on a column's own triangles the wedge's max(n_1 . g, n_2 . g): the numerator of
        stopping.gradient_excess (atomic max, the same on every device and in any order)."""
        c, g = wp.tid()
        e0, e1 = chunk_rows(c, chunk, m)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            w = V()
            for e in range(e0, e1):
                gx, gy, gz = element_gradient(elements, basis, U, e, b, 3)
                g2 = f.norm2(gx, gy, gz)
                gauge = V()
                for l in range(W):
                    gauge[l] = wp.sqrt(g2[l])
                if col0 >= 0:
                    for c in range(3):
                        l = own_lane(elements, e, c, b, col0)
                        if l >= 0:
                            gl = V3(gx[l], gy[l], gz[l])
                            gauge[l] = wp.max(wp.dot(directions[e, c, 0], gl), wp.dot(directions[e, c, 1], gl))
                for l in range(W):
                    w[l] = wp.max(w[l], (gauge[l] - one) * diameters[e])
            wp.atomic_max(worst, b, w)

    return types.SimpleNamespace(element_step=element_step, vertex_step=vertex_step,
                                 consensus_step=consensus_step, steepness=steepness, V=V, V3=V3)
