"""The per-element core of both ADMM kernel families (single source, all pairs), and the rows of
the per-lane accumulator their residual sums go to.

The constraint set of element e in a column is the unit ball |g| <= 1, except on a triangle with
exactly one corner s among the column's sources (``source_triangles="edges"``, docs/method.md
section 2): there it is the wedge n_1 . g <= 1, n_2 . g <= 1, with n_k the unit vectors from s
along its two sides (u_a = g . (x_a - x_s) <= |x_a - x_s| at the other corners a).
``directions`` (m, 3, 2) vec3 holds, per triangle and corner c, the unit vectors to corners c + 1
and c + 2 (mod 3) in the frame of ``basis``.
"""

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
    gradient, the projections onto the unit ball and onto a source triangle's wedge, and the element's terms of
    the residual sums."""
    V = lane_type(scalar, W)
    V3 = wp.types.vector(3, scalar)
    module = wp.get_module(f"warp_regdist_element_core_{scalar.__name__}_{W}")
    one = scalar(1.0)
    zero = scalar(0.0)

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
    def wedge_project(v: V3, n1: V3, n2: V3):
        """The projection of v (in the triangle's plane) onto the wedge n1 . g <= 1, n2 . g <= 1: v
        itself, its projection onto one side's line where that lies in the wedge, else the apex
        (n1 + n2) / (1 + n1 . n2)."""
        t1 = wp.dot(n1, v) - one
        t2 = wp.dot(n2, v) - one
        if t1 <= zero and t2 <= zero:
            return v
        if t1 > zero:
            p1 = v - t1 * n1
            if wp.dot(n2, p1) <= one:
                return p1
        if t2 > zero:
            p2 = v - t2 * n2
            if wp.dot(n1, p2) <= one:
                return p2
        return (n1 + n2) / (one + wp.dot(n1, n2))

    @wp.func(module=module)
    def project_lane(zx: V, zy: V, zz: V, vx: V, vy: V, vz: V, l: int, n1: V3, n2: V3):
        """(zx, zy, zz) with lane l replaced by the wedge projection of lane l of v."""
        p = wedge_project(V3(vx[l], vy[l], vz[l]), n1, n2)
        rx = zx
        ry = zy
        rz = zz
        rx[l] = p[0]
        ry[l] = p[1]
        rz[l] = p[2]
        return rx, ry, rz

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
                                 project=project, wedge_project=wedge_project, project_lane=project_lane,
                                 element_sums=element_sums, add_sums=add_sums)
