"""Baseline: the same ADMM (Algorithm 1, Dirichlet) in numpy with a direct sparse factorization.

The u-step matrix is (alpha + rho) W_D restricted to the free vertices, so one LU
factorization of W_ff serves every iteration and every penalty. Stopping test, penalty
schedule and over-relaxation follow ``warp_regdist.tolerances`` (the package's defaults),
so iteration counts are comparable with :class:`warp_regdist.DistanceSolver`.
"""

import time

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

import warp_regdist as wrd


def solve_admm(vertices, faces, sources, alpha_hat, eps_abs=None, eps_rel=None, max_iter=None):
    """Minimize -A_V^T u + (alpha/2) u^T W_D u s.t. |G u| <= 1, u_E = 0; returns a dict.

    Returns
    -------
    dict with u (n,), iterations, r, s, seconds (factorization included), factor_seconds.
    """
    tol = wrd.tolerances
    eps_abs = tol.eps_abs if eps_abs is None else eps_abs
    eps_rel = tol.eps_rel if eps_rel is None else eps_rel
    max_iter = tol.max_iterations if max_iter is None else max_iter
    t0 = time.perf_counter()
    ops = wrd.build_operators(wrd.Mesh(vertices, faces))
    n, m = len(vertices), len(faces)
    A, L = ops.total_volume, ops.length_scale
    alpha = alpha_hat * L
    free = np.setdiff1d(np.arange(n), np.asarray(sources))
    G = ops.grad[:, free].tocsr()
    mf = np.repeat(ops.element_volumes, 3)
    D = (G.T @ sp.diags(mf)).tocsr()
    b = ops.vertex_volumes[free]
    t1 = time.perf_counter()
    lu = splu(ops.stiffness[free][:, free].tocsc())
    factor_seconds = time.perf_counter() - t1
    rho = tol.rho0 * L
    z = np.zeros(3 * m)
    y = np.zeros(3 * m)
    sq = np.sqrt(mf)
    a = tol.relaxation
    for k in range(1, max_iter + 1):
        u = lu.solve(b - D @ y + rho * (D @ z)) / (alpha + rho)
        g = G @ u
        z_old = z
        v = (y / rho + g).reshape(m, 3)
        z = (v / np.maximum(1.0, np.linalg.norm(v, axis=1))[:, None]).ravel()
        y = y + rho * (a * g + (1 - a) * z_old - z)
        r = np.linalg.norm(sq * (g - z))
        s = rho * np.linalg.norm(D @ (z - z_old))
        eps_pri = np.sqrt(3 * m) * eps_abs * np.sqrt(A) + eps_rel * max(np.linalg.norm(sq * g), np.linalg.norm(sq * z))
        eps_dual = np.sqrt(len(free)) * eps_abs * A + eps_rel * np.linalg.norm(D @ y)
        if r < eps_pri and s < eps_dual:
            break
        if r * L > tol.penalty_ratio * s:
            rho *= tol.penalty_factor
        elif s > tol.penalty_ratio * r * L:
            rho /= tol.penalty_factor
    out = np.zeros(n)
    out[free] = u
    return dict(u=out, iterations=k, r=r, s=s, seconds=time.perf_counter() - t0, factor_seconds=factor_seconds)
