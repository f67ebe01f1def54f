"""Per-element and per-vertex kernels of one ADMM iteration (docs/method.md section 4), column-batched.

Shapes: u (n, nb); z, y (m, 3, nb); Dy, Dz, rhs (n, nb); rho (nb,); all of lane vector
dtype V. ``basis`` (m, k) vec3 are the hat-function gradients, ``vol`` (m,) the element
volumes a_e, k = d + 1 vertices per element.
"""

import functools
import types

import warp as wp

from .lanes import DY2, G2, R2, S2, Z2, chunk_rows, lane_funcs, lane_type


@functools.cache
def admm_kernels(scalar, W, k):
    """ADMM kernels for lane vectors of W ``scalar`` values on elements with k vertices."""
    V = lane_type(scalar, W)
    V3 = wp.types.vector(3, scalar)
    module = wp.get_module(f"warp_regdist_admm_{scalar.__name__}_{W}_{k}")
    one = scalar(1.0)
    f = lane_funcs(scalar, W)
    element_gradient, ball_scale, norm2 = f.element_gradient, f.ball_scale, f.norm2

    @wp.kernel(enable_backward=False, module=module)
    def element_step(elements: wp.array2d(dtype=wp.int32), basis: wp.array2d(dtype=V3), vol: wp.array(dtype=scalar),
                     u: wp.array2d(dtype=V), rho: wp.array(dtype=V), relaxation: scalar,
                     z: wp.array3d(dtype=V), y: wp.array3d(dtype=V),
                     acc: wp.array2d(dtype=V), chunk: int, m: int):
        """Fused over-relaxed z- and y-steps on a chunk of elements, per column lane:

            g = (G u)_e,  h = a g + (1 - a) z_old,  z_e = Proj_{|.|<=1}(y_e / rho + h),
            y_e += rho (h - z_e),
        and the partial sums a_e |g - z|^2, a_e |g|^2, a_e |z|^2 into acc rows R2, G2, Z2.
        """
        c, b = wp.tid()
        rb = rho[b]
        r2 = V()
        g2 = V()
        z2 = V()
        e0, e1 = chunk_rows(c, chunk, m)
        for e in range(e0, e1):
            gx, gy, gz = element_gradient(elements, basis, u, e, b, k)
            ox = z[e, 0, b]
            oy = z[e, 1, b]
            oz = z[e, 2, b]
            hx = relaxation * gx + (one - relaxation) * ox
            hy = relaxation * gy + (one - relaxation) * oy
            hz = relaxation * gz + (one - relaxation) * oz
            vx = wp.cw_div(y[e, 0, b], rb) + hx
            vy = wp.cw_div(y[e, 1, b], rb) + hy
            vz = wp.cw_div(y[e, 2, b], rb) + hz
            s = ball_scale(vx, vy, vz)
            zx = wp.cw_mul(s, vx)
            zy = wp.cw_mul(s, vy)
            zz = wp.cw_mul(s, vz)
            y[e, 0, b] = y[e, 0, b] + wp.cw_mul(rb, hx - zx)
            y[e, 1, b] = y[e, 1, b] + wp.cw_mul(rb, hy - zy)
            y[e, 2, b] = y[e, 2, b] + wp.cw_mul(rb, hz - zz)
            z[e, 0, b] = zx
            z[e, 1, b] = zy
            z[e, 2, b] = zz
            a = vol[e]
            r2 += a * norm2(gx - zx, gy - zy, gz - zz)
            g2 += a * norm2(gx, gy, gz)
            z2 += a * norm2(zx, zy, zz)
        wp.atomic_add(acc, R2, b, r2)
        wp.atomic_add(acc, G2, b, g2)
        wp.atomic_add(acc, Z2, b, z2)

    @wp.kernel(enable_backward=False, module=module)
    def vertex_divergence(offsets: wp.array(dtype=wp.int32), incident: wp.array(dtype=wp.int32),
                          weights: wp.array(dtype=V3), mask: wp.array2d(dtype=V), y: wp.array3d(dtype=V), z: wp.array3d(dtype=V),
                          Dy: wp.array2d(dtype=V), Dz: wp.array2d(dtype=V),
                          acc: wp.array2d(dtype=V), chunk: int, n: int):
        """Gather form of D = G^T M_F:  (D w)_i = sum over elements e at i of a_e basis[e, l_i] . w_e,
        with the products a_e basis[e, l_i] precomputed per (vertex, element) pair in ``weights``.

        Writes Dy = D y and Dz = D z; adds |mask D (z - z_old)|^2 = |mask (D z - Dz_old)|^2 (Dz holds
        the previous iteration's D z on entry) and |mask D y|^2 to acc rows S2, DY2.
        """
        c, b = wp.tid()
        s2 = V()
        d2 = V()
        i0, i1 = chunk_rows(c, chunk, n)
        for i in range(i0, i1):
            dy = V()
            dzi = V()
            p = offsets[i]
            pe = offsets[i + 1]
            while p < pe:
                e = incident[p]
                w = weights[p]
                dy += w[0] * y[e, 0, b] + w[1] * y[e, 1, b] + w[2] * y[e, 2, b]
                dzi += w[0] * z[e, 0, b] + w[1] * z[e, 1, b] + w[2] * z[e, 2, b]
                p += 1
            mk = mask[i, b]
            ddz = wp.cw_mul(mk, dzi - Dz[i, b])
            Dy[i, b] = dy
            Dz[i, b] = dzi
            dy = wp.cw_mul(mk, dy)
            s2 += wp.cw_mul(ddz, ddz)
            d2 += wp.cw_mul(dy, dy)
        wp.atomic_add(acc, S2, b, s2)
        wp.atomic_add(acc, DY2, b, d2)

    @wp.kernel(enable_backward=False, module=module)
    def u_rhs(vertex_vol: wp.array(dtype=scalar), mask: wp.array2d(dtype=V), Dy: wp.array2d(dtype=V),
              Dz: wp.array2d(dtype=V), rho: wp.array(dtype=V), shift: scalar, scale: scalar,
              rhs: wp.array2d(dtype=V), chunk: int, n: int):
        """Right-hand side of the u-step, divided by the factor of its matrix:
            rhs = mask (A_V - D y + rho D z) / (shift + scale rho)
        (shift = alpha, scale = 1 for the Dirichlet matrix (alpha + rho) W_D; 1, 0 otherwise)."""
        c, b = wp.tid()
        rb = rho[b]
        den = V()
        for l in range(W):
            den[l] = shift + scale * rb[l]
        i0, i1 = chunk_rows(c, chunk, n)
        for i in range(i0, i1):
            num = vertex_vol[i] * V(one) - Dy[i, b] + wp.cw_mul(rb, Dz[i, b])
            rhs[i, b] = wp.cw_mul(mask[i, b], wp.cw_div(num, den))

    return types.SimpleNamespace(element_step=element_step, vertex_divergence=vertex_divergence, u_rhs=u_rhs, V=V, V3=V3)
