"""The per-element core of both ADMM kernel families (single source, all pairs), and the rows of
the per-lane accumulator their residual sums go to."""

import functools
import types

import warp as wp

from .lanes import lane_type

__all__ = ["element_funcs", "R2", "G2", "Z2", "S2", "DY2"]

# Rows of the per-lane ADMM accumulator acc (5, nb) of both solvers: the element step's
# a_e |G u - z|^2, a_e |G u|^2, a_e |z|^2 (R2, G2, Z2), the vertex step's |D (z - z_old)|^2, |D y|^2 (S2, DY2).
R2, G2, Z2, S2, DY2 = 0, 1, 2, 3, 4


@functools.cache
def element_funcs(scalar, W):
    """The per-element core both ADMM kernel families share (single source, all pairs): the element
    gradient, the projection onto the unit ball and the element's terms of the residual sums."""
    V = lane_type(scalar, W)
    V3 = wp.types.vector(3, scalar)
    module = wp.get_module(f"warp_regdist_element_core_{scalar.__name__}_{W}")
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

    @wp.func(module=module)
    def add_sums(acc: wp.array2d(dtype=V), b: int, r2: V, g2: V, z2: V):
        """Add a thread's element sums of block b to the accumulator rows R2, G2, Z2."""
        wp.atomic_add(acc, R2, b, r2)
        wp.atomic_add(acc, G2, b, g2)
        wp.atomic_add(acc, Z2, b, z2)

    return types.SimpleNamespace(element_gradient=element_gradient, ball_scale=ball_scale, norm2=norm2,
                                 project=project, element_sums=element_sums, add_sums=add_sums)
