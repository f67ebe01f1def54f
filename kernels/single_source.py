"""The single-source kernels: per-element and per-vertex steps of one ADMM iteration (docs/method.md section 4),
and the stopping test, penalty and CG tolerances decided on the device (section 8).

Shapes: u (n, nb); z, y (m, 3, nb); Dy, Dz, rhs (n, nb); rho (nb,); all of lane vector
dtype V. ``basis`` (m, k) vec3 are the hat-function gradients, ``vol`` (m,) the element
volumes a_e, k = d + 1 vertices per element; the change test's snapshot (u at the last test) and
moved_last (its |u - snapshot| per vertex) are (n, nb).

Device-resident loop state: ``step`` (2,) int32 holds the iteration IT and the CG iterations
summed so far CG_TOTAL; ``lane`` (LANE_ROWS, nb) holds per lane (column) the rows below;
``rho_table`` (T,) the penalty of iteration it at it % T (written ahead by the host).
"""

import functools
import types

import warp as wp

from .element_core import DY2, G2, R2, S2, Z2, element_funcs
from .lanes import chunk_rows, group_blocks, lane_type

IT, CG_TOTAL = 0, 1
# Rows of ``lane``: the per-lane constants of the test (eps_abs sqrt(n_free) A, |mask A_V|), the
# change test's maxima (the window's change, |u| and the vertices' extrapolated changes) and flag,
# the change still to come, the done / newly-done flags, this check's residuals and tolerances,
# the values recorded when the lane's test first held, and the last window's change relative to max |u|.
(EPS_DUAL_ABS, LOAD_NORM, MOVED, UMAX, EXTRAPOLATED, SETTLED, ESTIMATE, DONE, NEWLY, R_LAST, S_LAST, EPS_PRI,
 EPS_DUAL, DUAL_SCALE, RHO_LAST, IT_OUT, R_OUT, S_OUT, RHO_OUT, ESTIMATE_OUT, CHANGE) = range(21)
LANE_ROWS = 21


@functools.cache
def device_rule_type(scalar):
    """The Warp struct of the constants of ``admm_check``'s stopping test and CG tolerance rule in ``scalar``."""

    @wp.struct
    class DeviceRule:
        eps_pri_abs: scalar
        eps_rel: scalar
        eps_rel_dual: scalar
        eps_change: scalar
        eps_estimate: scalar
        cg_fraction: scalar
        cg_primal: scalar
        alpha: scalar
        shift: scalar
        scale: scalar
        length: scalar

    return DeviceRule


RULE_FIELDS = ("eps_pri_abs", "eps_rel", "eps_rel_dual", "eps_change", "eps_estimate", "cg_fraction", "cg_primal",
               "alpha", "shift", "scale", "length")


def rule_struct(scalar, values):
    """A ``device_rule_type(scalar)`` struct from ``values`` ({field: number}, every field of RULE_FIELDS)."""
    missing = set(RULE_FIELDS) ^ set(values)
    if missing:
        raise ValueError(f"expected the fields {list(RULE_FIELDS)}, got {sorted(values)}")
    rule = device_rule_type(scalar)()
    for name in RULE_FIELDS:
        setattr(rule, name, scalar(values[name]))
    return rule


@functools.cache
def single_source_kernels(scalar, W, k):
    """Single-source ADMM kernels for lane vectors of W ``scalar`` values on elements with k vertices."""
    V = lane_type(scalar, W)
    Rule = device_rule_type(scalar)
    V3 = wp.types.vector(3, scalar)
    module = wp.get_module(f"warp_regdist_single_source_{scalar.__name__}_{W}_{k}")
    one = scalar(1.0)
    zero = scalar(0.0)
    f = element_funcs(scalar, W)
    element_gradient, project, element_sums, add_sums = f.element_gradient, f.project, f.element_sums, f.add_sums
    project_lane = f.project_lane

    @wp.func(module=module)
    def source_corner(m0: scalar, m1: scalar, m2: scalar):
        """The corner whose mask is 0 where exactly one of the three is (a wedge), else -1."""
        count = int(0)
        c = int(-1)
        if m0 == zero:
            count += 1
            c = 0
        if m1 == zero:
            count += 1
            c = 1
        if m2 == zero:
            count += 1
            c = 2
        if count != 1:
            c = -1
        return c

    @wp.func(module=module)
    def project_sources(elements: wp.array2d(dtype=wp.int32), mask: wp.array2d(dtype=V),
                        touched: wp.array(dtype=wp.int32), directions: wp.array3d(dtype=V3), e: int, b: int,
                        vx: V, vy: V, vz: V):
        """Proj_C(v) per lane: the unit ball, or on a ``touched`` triangle the wedge of the lanes where exactly
        one corner is a source (mask 0). An untouched element returns after one test."""
        zx, zy, zz = project(vx, vy, vz)
        if touched[e] == 0:
            return zx, zy, zz
        s0 = mask[elements[e, 0], b]
        s1 = mask[elements[e, 1], b]
        s2 = mask[elements[e, 2], b]
        for l in range(W):
            c = source_corner(s0[l], s1[l], s2[l])
            if c >= 0:
                zx, zy, zz = project_lane(zx, zy, zz, vx, vy, vz, l, directions[e, c, 0], directions[e, c, 1])
        return zx, zy, zz

    @wp.kernel(enable_backward=False, module=module)
    def element_step(elements: wp.array2d(dtype=wp.int32), basis: wp.array2d(dtype=V3), vol: wp.array(dtype=scalar),
                     u: wp.array2d(dtype=V), rho: wp.array(dtype=V), relaxation: scalar,
                     z: wp.array3d(dtype=V), y: wp.array3d(dtype=V), mask: wp.array2d(dtype=V),
                     touched: wp.array(dtype=wp.int32), directions: wp.array3d(dtype=V3),
                     acc: wp.array2d(dtype=V), chunk: int, group: int, m: int):
        """Fused over-relaxed z- and y-steps on a chunk of elements, per column lane:

            g = (G u)_e,  h = a g + (1 - a) z_old,  z_e = Proj_C(y_e / rho + h),
            y_e += rho (h - z_e),
        and the partial sums a_e |g - z|^2, a_e |g|^2, a_e |z|^2 into acc rows R2, G2, Z2. C is the unit
        ball, or on a ``touched`` triangle the wedge of the lanes where exactly one corner is a source
        (mask 0; element_core).
        """
        c, g = wp.tid()
        e0, e1 = chunk_rows(c, chunk, m)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            rb = rho[b]
            r2 = V()
            g2 = V()
            z2 = V()
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
                zx, zy, zz = project_sources(elements, mask, touched, directions, e, b, vx, vy, vz)
                y[e, 0, b] = y[e, 0, b] + wp.cw_mul(rb, hx - zx)
                y[e, 1, b] = y[e, 1, b] + wp.cw_mul(rb, hy - zy)
                y[e, 2, b] = y[e, 2, b] + wp.cw_mul(rb, hz - zz)
                z[e, 0, b] = zx
                z[e, 1, b] = zy
                z[e, 2, b] = zz
                dr2, dg2, dz2 = element_sums(vol[e], gx, gy, gz, zx, zy, zz)
                r2 += dr2
                g2 += dg2
                z2 += dz2
            add_sums(acc, b, r2, g2, z2)

    @wp.kernel(enable_backward=False, module=module)
    def vertex_divergence(offsets: wp.array(dtype=wp.int32), incident: wp.array(dtype=wp.int32),
                          weights: wp.array(dtype=V3), mask: wp.array2d(dtype=V), y: wp.array3d(dtype=V), z: wp.array3d(dtype=V),
                          Dy: wp.array2d(dtype=V), Dz: wp.array2d(dtype=V),
                          acc: wp.array2d(dtype=V), chunk: int, group: int, n: int):
        """Gather form of D = G^T M_F:  (D w)_i = sum over elements e at i of a_e basis[e, l_i] . w_e,
        with the products a_e basis[e, l_i] precomputed per (vertex, element) pair in ``weights``.

        Writes Dy = D y and Dz = D z; adds |mask D (z - z_old)|^2 = |mask (D z - Dz_old)|^2 (Dz holds
        the previous iteration's D z on entry) and |mask D y|^2 to acc rows S2, DY2.
        """
        c, g = wp.tid()
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            s2 = V()
            d2 = V()
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
              rhs: wp.array2d(dtype=V), chunk: int, group: int, n: int):
        """Right-hand side of the u-step, divided by the factor of its matrix:
            rhs = mask (A_V - D y + rho D z) / (shift + scale rho)
        (shift = alpha, scale = 1 for the Dirichlet matrix (alpha + rho) W_D; 1, 0 otherwise)."""
        c, g = wp.tid()
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            rb = rho[b]
            den = V()
            for l in range(W):
                den[l] = shift + scale * rb[l]
            for i in range(i0, i1):
                num = vertex_vol[i] * V(one) - Dy[i, b] + wp.cw_mul(rb, Dz[i, b])
                rhs[i, b] = wp.cw_mul(mask[i, b], wp.cw_div(num, den))

    @wp.kernel(enable_backward=False, module=module)
    def change_measure(u: wp.array2d(dtype=V), snapshot: wp.array2d(dtype=V), moved_last: wp.array2d(dtype=V),
                       step: wp.array(dtype=wp.int32), window: int, rate_cap: scalar, lane: wp.array2d(dtype=V),
                       chunk: int, group: int, n: int):
        """Change test at iterations it > 0 with it % window == 0 (else nothing): per lane, the maxima
        of d_i = |u_i - snapshot_i|, of |u_i| and of the change still to come at vertex i,
        d_i / (1 - q_i) with q_i = min(d_i / d_i_last, rate_cap) (rate_cap where d_i_last = 0, as
        at the first test), into lane rows MOVED, UMAX, EXTRAPOLATED (cleared by admm_check);
        then snapshot = u, moved_last = d."""
        it = step[IT]
        if it == 0 or it % window != 0:
            return
        c, g = wp.tid()
        i0, i1 = chunk_rows(c, chunk, n)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            moved = V()
            top = V()
            ahead = V()
            for i in range(i0, i1):
                ui = u[i, b]
                si = snapshot[i, b]
                last = moved_last[i, b]
                d = V()
                for l in range(W):
                    d[l] = wp.abs(ui[l] - si[l])
                    q = rate_cap
                    if d[l] < rate_cap * last[l]:
                        q = d[l] / last[l]
                    moved[l] = wp.max(moved[l], d[l])
                    top[l] = wp.max(top[l], wp.abs(ui[l]))
                    ahead[l] = wp.max(ahead[l], d[l] / (one - q))
                snapshot[i, b] = ui
                moved_last[i, b] = d
            wp.atomic_max(lane, MOVED, b, moved)
            wp.atomic_max(lane, UMAX, b, top)
            wp.atomic_max(lane, EXTRAPOLATED, b, ahead)

    @wp.kernel(enable_backward=False, module=module)
    def admm_check(acc: wp.array2d(dtype=V), lane: wp.array2d(dtype=V), rho: wp.array(dtype=V),
                   step: wp.array(dtype=wp.int32), rho_table: wp.array(dtype=scalar), window: int,
                   rule: Rule, atol2: wp.array(dtype=V)):
        """Top of iteration it, per lane of block b: the residuals of the last iterate (it > 0),

            r = |sqrt(M_F)(G u - z)|,  s = rho_old |D (z - z_old)|,
            eps_pri = eps_pri_abs + eps_rel max(|G u|, |z|),  dy = max(|D y|, |mask A_V|),
            eps_dual = eps_dual_abs + eps_rel_dual dy,
            the change test every ``window`` iterations, with ESTIMATE = EXTRAPOLATED / UMAX (0 where
            MOVED or UMAX = 0), CHANGE = MOVED / UMAX (kept for the progress reports), settled:
            (MOVED = 0 or MOVED <= eps_change UMAX) and ESTIMATE <= eps_estimate,
        done once r <= eps_pri, s <= eps_dual and settled (NEWLY marks the first time, which
        records it, r, s, rho_old / length, ESTIMATE); then rho = rho_table[it % T] for this iteration
        and the u-step's CG tolerance per lane,
            atol = min(cg_fraction (eps_dual_abs + dy), eps_dual / 10) / (shift + scale rho),
            atol = min(atol, cg_primal r (alpha + rho) / (shift + scale rho))   (it > 0),
        into atol2 (squared); clears acc for the iteration. The constants are the fields of ``rule``.
        """
        eps_pri_abs, eps_rel, eps_rel_dual = rule.eps_pri_abs, rule.eps_rel, rule.eps_rel_dual
        eps_change, eps_estimate = rule.eps_change, rule.eps_estimate
        cg_fraction, cg_primal = rule.cg_fraction, rule.cg_primal
        alpha, shift, scale, length = rule.alpha, rule.shift, rule.scale, rule.length
        b = wp.tid()
        it = step[IT]
        rho_new = rho_table[it % rho_table.shape[0]]
        rho_old = rho[b]
        due = it > 0 and it % window == 0
        eps_dual_abs = lane[EPS_DUAL_ABS, b]
        load_norm = lane[LOAD_NORM, b]
        moved = lane[MOVED, b]
        top = lane[UMAX, b]
        ahead = lane[EXTRAPOLATED, b]
        settled = lane[SETTLED, b]
        estimate = lane[ESTIMATE, b]
        change = lane[CHANGE, b]
        done = lane[DONE, b]
        newly = V()
        r_last = lane[R_LAST, b]
        s_last = lane[S_LAST, b]
        eps_pri = lane[EPS_PRI, b]
        eps_dual = lane[EPS_DUAL, b]
        dual_scale = lane[DUAL_SCALE, b]
        rho_last = lane[RHO_LAST, b]
        it_out = lane[IT_OUT, b]
        r_out = lane[R_OUT, b]
        s_out = lane[S_OUT, b]
        rho_out = lane[RHO_OUT, b]
        estimate_out = lane[ESTIMATE_OUT, b]
        a2 = V()
        rv = V()
        for l in range(W):
            if it > 0:
                r = wp.sqrt(acc[R2, b][l])
                s = rho_old[l] * wp.sqrt(acc[S2, b][l])
                eps_pri[l] = eps_pri_abs + eps_rel * wp.sqrt(wp.max(acc[G2, b][l], acc[Z2, b][l]))
                dy = wp.max(wp.sqrt(acc[DY2, b][l]), load_norm[l])
                eps_dual[l] = eps_dual_abs[l] + eps_rel_dual * dy
                dual_scale[l] = eps_dual_abs[l] + dy
                if due:
                    estimate[l] = zero
                    change[l] = zero
                    if moved[l] > zero and top[l] > zero:
                        estimate[l] = ahead[l] / top[l]
                        change[l] = moved[l] / top[l]
                    settled[l] = zero
                    if (moved[l] == zero or moved[l] <= eps_change * top[l]) and estimate[l] <= eps_estimate:
                        settled[l] = one
                    moved[l] = zero
                    top[l] = zero
                    ahead[l] = zero
                if done[l] == zero and r <= eps_pri[l] and s <= eps_dual[l] and settled[l] == one:
                    newly[l] = one
                    done[l] = one
                    it_out[l] = scalar(it)
                    r_out[l] = r
                    s_out[l] = s
                    rho_out[l] = rho_old[l] / length
                    estimate_out[l] = estimate[l]
                r_last[l] = r
                s_last[l] = s
                rho_last[l] = rho_old[l] / length
            den = shift + scale * rho_new
            atol = wp.min(cg_fraction * dual_scale[l], scalar(0.1) * eps_dual[l]) / den
            if it > 0:
                atol = wp.min(atol, cg_primal * r_last[l] * (alpha + rho_new) / den)
            a2[l] = atol * atol
            rv[l] = rho_new
        lane[MOVED, b] = moved
        lane[UMAX, b] = top
        lane[EXTRAPOLATED, b] = ahead
        lane[SETTLED, b] = settled
        lane[ESTIMATE, b] = estimate
        lane[CHANGE, b] = change
        lane[DONE, b] = done
        lane[NEWLY, b] = newly
        lane[R_LAST, b] = r_last
        lane[S_LAST, b] = s_last
        lane[EPS_PRI, b] = eps_pri
        lane[EPS_DUAL, b] = eps_dual
        lane[DUAL_SCALE, b] = dual_scale
        lane[RHO_LAST, b] = rho_last
        lane[IT_OUT, b] = it_out
        lane[R_OUT, b] = r_out
        lane[S_OUT, b] = s_out
        lane[RHO_OUT, b] = rho_out
        lane[ESTIMATE_OUT, b] = estimate_out
        atol2[b] = a2
        rho[b] = rv
        for q in range(5):
            acc[q, b] = V()

    @wp.kernel(enable_backward=False, module=module)
    def freeze_lanes(lane: wp.array2d(dtype=V), source: wp.array2d(dtype=V), frozen: wp.array2d(dtype=V),
                     chunk: int, group: int, rows: int):
        """frozen = source on the lanes whose test first held at this check (lane row NEWLY)."""
        c, g = wp.tid()
        i0, i1 = chunk_rows(c, chunk, rows)
        b0, b1 = group_blocks(g, group)
        for b in range(b0, b1):
            newly = lane[NEWLY, b]
            if newly == V():
                continue
            for i in range(i0, i1):
                f = frozen[i, b]
                v = source[i, b]
                for l in range(W):
                    if newly[l] != zero:
                        f[l] = v[l]
                frozen[i, b] = f

    @wp.kernel(enable_backward=False, module=module)
    def advance(step: wp.array(dtype=wp.int32), cg_counters: wp.array(dtype=wp.int32)):
        """End of an iteration: it += 1, and the u-step's CG iterations into CG_TOTAL."""
        step[IT] = step[IT] + 1
        step[CG_TOTAL] = step[CG_TOTAL] + cg_counters[0]

    return types.SimpleNamespace(element_step=element_step, vertex_divergence=vertex_divergence, u_rhs=u_rhs,
                                 change_measure=change_measure, admm_check=admm_check, freeze_lanes=freeze_lanes,
                                 advance=advance, V=V, V3=V3)
