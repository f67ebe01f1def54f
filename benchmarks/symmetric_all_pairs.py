"""All pairs with U symmetric in the primal: iterations to the exact minimizer (issue 24, a prototype).

    python benchmarks/symmetric_all_pairs.py --cache /tmp/stopping            # rho = 8 L
    python benchmarks/symmetric_all_pairs.py --cache /tmp/stopping --rho 4 8 16

A dense numpy prototype of a 2-block ADMM for Algorithm 2's problem, not the package's
splitting: U is symmetric with a zero diagonal by construction, only the columns' gradients
are split (Z = G U; the rows' follow by symmetry), so there is no consensus variable:

    U-step  (alpha + rho/2)(W U M + M U W) = A A^T + sym(D (rho Z - Y) M) + Diag(mu),  diag(U) = 0
    Z-step  Z = face projection onto |g| <= 1 of relaxed G U + Y / rho,  Y += rho (relaxed G U - Z)

(M = diag(A_V), W the stiffness, D = G^T M_F; relaxation 1.7, fixed rho). The U-step is exact:
with W' = M^(-1/2) W M^(-1/2) = Phi Lambda Phi^T, X = M^(1/2) U M^(1/2) solves
W' X + X W' = C entrywise in the eigenbasis (8 dense n x n products per iteration), and the
diagonal's multipliers mu solve an (n + 1) system whose matrix, the diagonal of the response
to each Diag(e_k), is sum_pq Phi_ip Phi_kp Phi_iq Phi_kq / (lambda_p + lambda_q), the integral
of the squared heat kernel (trapezoid rule in log t). Counts the iterations until U stays
within 1%, 0.5% and 0.2% of max U* of the exact minimizer cached by benchmarks/stopping.py
--pairs in --cache. Writes benchmarks/results/symmetric_all_pairs.csv and prints a table.
"""

import argparse
import os
import sys
import time

import numpy as np
import scipy.linalg as sl
import scipy.sparse as sp

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import stopping  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402

LEVELS = (0.01, 0.005, 0.002)


def diagonal_response(Phi, lam, nodes=80):
    """K_ik = sum_(p,q) != (0,0) Phi_ip Phi_kp Phi_iq Phi_kq / (lam_p + lam_q) (n, n), as the integral over
    t of H_t(i,k)^2 - (phi0_i phi0_k)^2, H_t = Phi e^(-lam t) Phi^T, by the trapezoid rule in log t."""
    s = np.linspace(np.log(1e-4 / lam[-1]), np.log(60 / lam[1]), nodes)
    K, P1, F0 = np.zeros((len(lam),) * 2), Phi[:, 1:], np.outer(Phi[:, 0], Phi[:, 0])
    for sk in s:
        t = np.exp(sk)
        H1 = (P1 * np.exp(-lam[1:] * t)) @ P1.T
        K += H1 * (H1 + 2 * F0) * (t * (s[1] - s[0]))
    return K


class SymmetricADMM:
    """The prototype on one mesh: eigenvectors and the diagonal's system set up once."""

    def __init__(self, mesh, alpha_hat):
        ops = wrd.build_operators(mesh)
        self.G = ops.grad.tocsr()
        self.D = (ops.grad.T @ sp.diags(np.repeat(ops.element_volumes, 3))).tocsr()
        self.AV, self.L, n = ops.vertex_volumes, ops.length_scale, mesh.n_vertices
        self.alpha, self.m = alpha_hat * ops.length_scale, mesh.n_elements
        self.s = 1 / np.sqrt(self.AV)
        lam, self.Phi = np.linalg.eigh(self.s[:, None] * ops.stiffness.toarray() * self.s[None, :])
        lam[0] = 0.0
        d = lam[:, None] + lam[None, :]
        self.dinv = np.where(d > 0, 1 / np.where(d > 0, d, 1.0), 0.0)
        border = np.zeros((n + 1, n + 1))
        border[:n, :n] = self.s[:, None] ** 2 * diagonal_response(self.Phi, lam)
        border[:n, n], border[n, :n] = 1.0, self.AV
        self.border = sl.lu_factor(border)

    def u_step(self, R, scale):
        """The symmetric U with zero diagonal solving scale (W U M + M U W) = R + Diag(mu)."""
        Phi, s, dinv, n = self.Phi, self.s, self.dinv, len(self.AV)
        C = s[:, None] * R * s[None, :]
        PY = Phi @ ((Phi.T @ C @ Phi) * dinv)
        diag = np.einsum("ij,ij->i", PY, Phi) / scale
        sol = sl.lu_solve(self.border, np.concatenate([-s ** 2 * diag, [-R.sum() / scale]]))
        X = (PY + Phi @ (((Phi.T * (scale * sol[:n])) @ Phi) * dinv)) @ Phi.T / scale
        U = s[:, None] * X * s[None, :] + sol[n]
        return 0.5 * (U + U.T)

    def run(self, exact, rho, max_iterations, relaxation=1.7):
        """Iterations until U is within each of LEVELS of max |exact| (None: not reached)."""
        n, m, AV = len(self.AV), self.m, self.AV
        Z, Y = np.zeros((3 * m, n)), np.zeros((3 * m, n))
        reached, top = {}, np.abs(exact).max()
        for k in range(1, max_iterations + 1):
            B = self.D @ (rho * Z - Y) * AV[None, :]
            U = self.u_step(np.outer(AV, AV) + 0.5 * (B + B.T), self.alpha + rho / 2)
            h = relaxation * (self.G @ U) + (1 - relaxation) * Z
            T = (Y / rho + h).reshape(m, 3, n)
            Znew = (T / np.maximum(1.0, np.linalg.norm(T, axis=1, keepdims=True))).reshape(3 * m, n)
            Y += rho * (h - Znew)
            Z = Znew
            error = np.abs(U - exact).max() / top
            reached.update({level: k for level in LEVELS if level not in reached and error <= level})
            if len(reached) == len(LEVELS):
                break
        return reached


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cache", required=True, help="folder of the exact minimizers (benchmarks/stopping.py --pairs)")
    parser.add_argument("--rho", type=float, nargs="+", default=[8.0], help="fixed penalties, in units of L")
    parser.add_argument("--max-iterations", type=int, default=4000)
    parser.add_argument("--output", default=os.path.join(HERE, "results", "symmetric_all_pairs.csv"))
    args = parser.parse_args()
    rows = []
    for alpha_hat in (0.03, 0.1):
        for name, mesh in stopping.pairs_set():
            exact = stopping.cached(args.cache, f"pairs {name} {mesh.n_vertices} {alpha_hat}", None)
            if exact is None:
                continue
            prototype = SymmetricADMM(mesh, alpha_hat)
            for rho in args.rho:
                t0 = time.perf_counter()
                reached = prototype.run(exact, rho * prototype.L, args.max_iterations)
                rows.append(dict(mesh=name, n=mesh.n_vertices, alpha_hat=alpha_hat, rho=rho,
                                 **{f"iterations_{level * 100:g}pct": reached.get(level) for level in LEVELS},
                                 seconds=round(time.perf_counter() - t0, 2)))
                print("  " + str(rows[-1]), file=sys.stderr, flush=True)
    write_csv(rows, args.output)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
