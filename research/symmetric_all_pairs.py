"""All pairs with U symmetric in the primal: iterations to the exact minimizer (issue 24, a prototype).

    python research/symmetric_all_pairs.py --cache /tmp/stopping            # rho = 8 L
    python research/symmetric_all_pairs.py --cache /tmp/stopping --rho 4 8 16
    python research/symmetric_all_pairs.py --beside-package cat_rr --iterations 500

A dense numpy prototype of a 2-block ADMM for Algorithm 2's problem, not the package's
splitting: U is symmetric with a zero diagonal by construction, only the columns' gradients
are split (Z = G U; the rows' follow by symmetry), so there is no consensus variable:

    U-step  (alpha + rho/2)(W U M + M U W) = A A^T + sym(D (rho Z - Y) M) + Diag(mu),  diag(U) = 0
    Z-step  Z = face projection onto |g| <= 1 of relaxed G U + Y / rho,  Y += rho (relaxed G U - Z)

(M = diag(A_V), W the stiffness, D = G^T M_F; relaxation 1.7, fixed rho). The U-step is exact, the
package's eigenbasis engine's (warp_regdist.solvers.all_pairs.eigenbasis.EigenbasisUStep):
with W' = M^(-1/2) W M^(-1/2) = Phi Lambda Phi^T, X = M^(1/2) U M^(1/2) solves
W' X + X W' = C entrywise in the eigenbasis (6 dense n x n products per iteration), and the
diagonal's multipliers mu solve an (n + 1) system whose matrix, the diagonal of the response
to each Diag(e_k), is sum_pq Phi_ip Phi_kp Phi_iq Phi_kq / (lambda_p + lambda_q), the integral
of the squared heat kernel (trapezoid rule in log t). Counts the iterations until U stays
within 1%, 0.5% and 0.2% of max U* of the exact minimizer cached by benchmarks/stopping.py
--pairs in --cache. Writes benchmarks/results/symmetric_all_pairs.csv and prints a table.

``--u-step multigrid`` solves the U-step in O(n^2) work instead: PCG on the zero-diagonal
symmetric matrices, warm-started from the previous U and stopped when the residual has
dropped by ``--inner-tol``, preconditioned by a tensor-product V-cycle (:class:`TensorMultigrid`);
the table then also counts the PCG iterations, beside the package's consensus engine at accuracy 0.005
and 0.002 (its ADMM iterations, its one-sided PCG iterations summed over them, its error).

``--beside-package MESH`` compares on a shared mesh too large for an exact minimizer (cat_rr, 1,949
vertices): the package in float32 at its defaults and at accuracy 0.005, and ``--iterations`` of
the exact U-step at rho = 8 L, each row with its distance to the package's 0.005 run (max, mean
and 99th percentile of |U - U_0.005| in % of max U_0.005), the pair where the max falls, the
objective -a^T U a + alpha sum_j a_j U_j^T W U_j, max |grad U| and the share of (element, column)
pairs above 1.001. Writes benchmarks/results/symmetric_beside_package.csv.
"""

import argparse
import functools
import itertools
import os
import sys
import time
import warnings

import numpy as np
import scipy.linalg as sl
import scipy.sparse as sp

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")
sys.path.insert(0, HERE)

import meshes  # noqa: E402
import stopping  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402
from warp_regdist.solvers.all_pairs.eigenbasis import EigenbasisUStep  # noqa: E402
from warp_regdist.linalg.multigrid import prolongator  # noqa: E402

LEVELS = (0.01, 0.005, 0.002)


class TensorMultigrid:
    """A V(1,1)-cycle for S(U) = W U M + M U W on symmetric (n, n) U.

    Level l + 1 has W_l+1 = P^T W_l P and M_l+1 = P^T M_l P, with P the package's
    smoothed-aggregation prolongator of W_l, so that (P x P)^T S_l (P x P) = S_l+1 (Galerkin is
    exact for a Kronecker sum). The smoother is damped Jacobi with diagonal w_i m_j + m_i w_j
    (w, m the diagonals of W_l, M_l), weight 1.2 / rho(D^-1 S_l); the coarsest level (<= 80
    unknowns) is solved in the eigenbasis of W_L Phi = M_L Phi Lambda, the constants left out.
    """

    def __init__(self, stiffness, vertex_volumes, coarse_size=80):
        self.W, self.M, self.P = [sp.csr_matrix(stiffness)], [sp.diags(vertex_volumes).tocsr()], []
        rng = np.random.default_rng(0)
        while self.W[-1].shape[0] > coarse_size:
            level = prolongator(self.W[-1], 0.5, rng)
            if level is None:
                break
            P = level[0]
            self.P.append(P)
            self.W.append((P.T @ self.W[-1] @ P).tocsr())
            self.M.append((P.T @ self.M[-1] @ P).tocsr())
        self.dinv, self.weight = [], []
        for W, M in zip(self.W[:-1], self.M[:-1]):
            w, m = W.diagonal(), M.diagonal()
            dinv = 1.0 / (np.outer(w, m) + np.outer(m, w))
            X = np.random.default_rng(1).standard_normal(dinv.shape)
            X += X.T
            for _ in range(15):   # power iteration for rho(D^-1 S)
                Y = dinv * self.apply(X, len(self.dinv))
                radius, X = np.linalg.norm(Y) / np.linalg.norm(X), Y
            self.dinv.append(dinv)
            self.weight.append(1.2 / (1.05 * radius))
        lam, self.Phi = sl.eigh(self.W[-1].toarray(), self.M[-1].toarray())
        d = np.maximum(lam, 0.0)[:, None] + np.maximum(lam, 0.0)[None, :]
        self.coarse = np.where(d > 1e-9 * d.max(), 1 / np.where(d > 1e-9 * d.max(), d, 1.0), 0.0)

    def apply(self, U, level=0):
        """S_l(U) = T + T^T, T = W_l U M_l, for symmetric U."""
        T = np.asarray(self.W[level] @ np.asarray(self.M[level] @ U).T)
        return T + T.T

    def __call__(self, R, level=0):
        """The V-cycle's approximation of S_l^-1 R."""
        if level == len(self.P):
            return self.Phi @ ((self.Phi.T @ R @ self.Phi) * self.coarse) @ self.Phi.T
        dinv, weight, P = self.dinv[level], self.weight[level], self.P[level]
        U = weight * dinv * R
        coarse_rhs = np.asarray(P.T @ np.asarray(P.T @ (R - self.apply(U, level))).T)
        U += np.asarray(P @ np.asarray(P @ self(coarse_rhs, level + 1)).T)
        return U + weight * dinv * (R - self.apply(U, level))


def zero_diagonal(X):
    X = X.copy()
    np.fill_diagonal(X, 0.0)
    return X


def masked_pcg(apply, precondition, R, U, inner_tol, max_iterations=100):
    """PCG for apply(U) = R + Diag(mu) over symmetric U with diag(U) = 0, from U, until the residual
    has dropped by inner_tol; returns (U, iterations)."""
    U = U.copy()
    r = zero_diagonal(R - apply(U))
    stop = inner_tol * np.linalg.norm(r)
    z = zero_diagonal(precondition(r))
    p, rz = z.copy(), np.sum(r * z)
    for k in range(1, max_iterations + 1):
        q = zero_diagonal(apply(p))
        a = rz / np.sum(p * q)
        U += a * p
        r -= a * q
        if np.linalg.norm(r) <= stop:
            return U, k
        z = zero_diagonal(precondition(r))
        rz, rz_old = np.sum(r * z), rz
        p = z + (rz / rz_old) * p
    return U, max_iterations


class SymmetricADMM:
    """The prototype on one mesh's ``triangulation`` (default the intrinsic Delaunay one, the package's and the
    exact references'): eigenvectors and the diagonal's system set up once."""

    def __init__(self, mesh, alpha_hat, triangulation="intrinsic"):
        ops = wrd.build_operators(mesh, triangulation)
        self.G = ops.grad.tocsr()
        self.D = (ops.grad.T @ sp.diags(np.repeat(ops.element_volumes, 3))).tocsr()
        self.AV, self.L = ops.vertex_volumes, ops.length_scale
        self.element_volumes = ops.element_volumes
        self.alpha, self.m = alpha_hat * ops.length_scale, mesh.n_elements
        self.u_step = EigenbasisUStep(ops.stiffness, self.AV)  # the package's eigenbasis engine's U-step
        self.Phi, self.s, self.dinv, self.border = self.u_step.Phi, self.u_step.s, self.u_step.dinv, self.u_step.border
        self.stiffness = ops.stiffness

    @functools.cached_property
    def multigrid(self):
        """The TensorMultigrid of W U M + M U W (set up on first use: the exact U-step needs none)."""
        return TensorMultigrid(self.stiffness, self.AV)

    def iterates(self, rho, relaxation=1.7, inner_tol=None):
        """Yield (U, PCG iterations so far, Y) after each iteration at the penalty ``rho`` (a number, or
        rho(k) at iteration k = 0, 1, ...); the U-step exact (inner_tol None) or by :func:`masked_pcg`
        with the tensor multigrid. Y (3 m, n), the multipliers of Z = G U, is updated in place by the
        next iteration."""
        n, m, AV = len(self.AV), self.m, self.AV
        Z, Y, U = np.zeros((3 * m, n)), np.zeros((3 * m, n)), np.zeros((n, n))
        penalty = rho if callable(rho) else (lambda k, fixed=rho: fixed)
        pcg = 0
        for k in itertools.count():
            rho_k = penalty(k)
            scale = self.alpha + rho_k / 2
            B = self.D @ (rho_k * Z - Y) * AV[None, :]
            R = np.outer(AV, AV) + 0.5 * (B + B.T)
            if inner_tol is None:
                U = self.u_step(R, scale)
            else:
                U, used = masked_pcg(lambda X: scale * self.multigrid.apply(X), lambda r: self.multigrid(r) / scale,
                                     R, U, inner_tol)
                pcg += used
            h = relaxation * (self.G @ U) + (1 - relaxation) * Z
            T = (Y / rho_k + h).reshape(m, 3, n)
            Znew = (T / np.maximum(1.0, np.linalg.norm(T, axis=1, keepdims=True))).reshape(3 * m, n)
            Y += rho_k * (h - Znew)
            Z = Znew
            yield U, pcg, Y

    def reference(self, iterations, rho0=16.0, rho_max=128.0, doubling=300, window=500):
        """A long run of the exact U-step with the penalty rho_k = L min(rho_max, rho0 2^(k // doubling)), for
        meshes whose exact minimizer does not fit a conic solver: (U, max |U_k - U_(k - window)| / max U_k
        at the end, inf for fewer than ``window`` iterations)."""
        def schedule(k):
            return self.L * min(rho_max, rho0 * 2 ** (k // doubling))

        before = None
        for k, (U, _, _) in enumerate(itertools.islice(self.iterates(schedule), iterations)):
            if k == iterations - 1 - window:
                before = U.copy()
        return U, (np.abs(U - before).max() / U.max() if before is not None else np.inf)

    def run(self, exact, rho, max_iterations, inner_tol=None):
        """{level: (iterations, PCG iterations)} until U is within each of LEVELS of max |exact|."""
        reached, top = {}, np.abs(exact).max()
        for k, (U, pcg, _) in enumerate(itertools.islice(self.iterates(rho, inner_tol=inner_tol), max_iterations), 1):
            error = np.abs(U - exact).max() / top
            reached.update({level: (k, pcg) for level in LEVELS if level not in reached and error <= level})
            if len(reached) == len(LEVELS):
                break
        return reached


def package_rows(mesh, alpha_hat, exact):
    """The package's consensus engine (one-sided PCG U-steps) at accuracy 0.005 and 0.002: iterations, PCG
    iterations, error (%)."""
    out = {}
    for accuracy in (0.005, 0.002):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", wrd.ConvergenceWarning)
            res = wrd.AllPairsSolver(mesh, alpha_hat, device="cpu", workers=1,
                                     options=wrd.AllPairsOptions(engine="consensus")).solve(accuracy=accuracy)
        out.update({f"package_{accuracy:g}_iterations": res.iterations, f"package_{accuracy:g}_pcg": res.cg_iterations,
                    f"package_{accuracy:g}_error_pct": stopping.error_pct(res.distance, exact)})
    return out


def matrix_row(name, U, reference, operators, alpha_hat):
    """The --beside-package columns of one matrix U (n, n) against ``reference``."""
    U, reference = np.asarray(U, dtype=np.float64), np.asarray(reference, dtype=np.float64)
    a, top = operators.vertex_volumes, reference.max()
    E = np.abs(U - reference) / top
    i, j = np.unravel_index(E.argmax(), E.shape)
    energy = alpha_hat * operators.length_scale * float(np.einsum("ij,ij->j", U, operators.stiffness @ U) @ a)
    g = np.linalg.norm((operators.grad @ U).reshape(-1, 3, U.shape[1]), axis=1)
    return dict(run=name, max_pct=round(100 * E.max(), 3), mean_pct=round(100 * E.mean(), 4),
                p99_pct=round(100 * np.percentile(E, 99), 3), pair=f"{i}-{j}", u_pair=round(float(U[i, j]), 4),
                reference_pair=round(float(reference[i, j]), 4), objective=round(float(energy - a @ U @ a), 6),
                max_gradient=round(float(g.max()), 4), steep_share=float(np.mean(g > 1.001)))


def beside_package(name, iterations, alpha_hat=0.03):
    """Rows of --beside-package: the package at accuracy 0.005 and at its defaults, the exact U-step."""
    mesh = meshes.shared_mesh(name)
    operators = wrd.build_operators(mesh)
    runs = {}
    for label, accuracy in (("package accuracy 0.005", 0.005), ("package defaults", None)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", wrd.ConvergenceWarning)
            res = wrd.AllPairsSolver(mesh, alpha_hat, dtype="float32").solve(accuracy=accuracy)
        runs[label] = (res.distance, dict(iterations=res.iterations, converged=res.converged,
                                          estimate_pct=round(100 * res.error_estimate, 3), seconds=round(res.seconds, 1)))
    prototype = SymmetricADMM(mesh, alpha_hat)
    t0 = time.perf_counter()
    for U, _, _ in itertools.islice(prototype.iterates(8.0 * prototype.L), iterations):
        pass
    runs["symmetric exact U-step, rho 8 L"] = (U, dict(iterations=iterations, converged=None, estimate_pct=None,
                                                       seconds=round(time.perf_counter() - t0, 1)))
    reference = runs["package accuracy 0.005"][0]
    return [dict(mesh=name, n=mesh.n_vertices, **info, **matrix_row(label, U, reference, operators, alpha_hat))
            for label, (U, info) in runs.items()]


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cache", default=None, help="folder of the exact minimizers (benchmarks/stopping.py --pairs)")
    parser.add_argument("--rho", type=float, nargs="+", default=[8.0], help="fixed penalties, in units of L")
    parser.add_argument("--max-iterations", type=int, default=4000)
    parser.add_argument("--u-step", choices=("exact", "multigrid"), default="exact",
                        help="exact: eigenvectors; multigrid: warm-started tensor-product multigrid PCG")
    parser.add_argument("--inner-tol", type=float, default=0.1, help="the multigrid U-step's residual reduction")
    parser.add_argument("--output", default=None, help="CSV (default: benchmarks/results/symmetric_all_pairs[_multigrid].csv)")
    parser.add_argument("--beside-package", metavar="MESH", default=None,
                        help="compare with the package on this shared mesh instead (no --cache needed)")
    parser.add_argument("--iterations", type=int, default=500, help="with --beside-package: exact U-step iterations")
    args = parser.parse_args()
    if args.beside_package:
        rows = beside_package(args.beside_package, args.iterations)
        write_csv(rows, args.output or os.path.join(HERE, "results", "symmetric_beside_package.csv"))
        print(markdown_table(rows))
        return
    if args.cache is None:
        parser.error("--cache is required without --beside-package")
    multigrid = args.u_step == "multigrid"
    output = args.output or os.path.join(HERE, "results", "symmetric_all_pairs" + ("_multigrid" if multigrid else "") + ".csv")
    rows = []
    for alpha_hat in (0.03, 0.1):
        for name, mesh in stopping.pairs_set():
            exact = stopping.cached(args.cache, f"pairs {name} {mesh.n_vertices} {alpha_hat}", None)
            if exact is None:
                continue
            prototype = SymmetricADMM(mesh, alpha_hat)
            for rho in args.rho:
                t0 = time.perf_counter()
                reached = prototype.run(exact, rho * prototype.L, args.max_iterations,
                                        inner_tol=args.inner_tol if multigrid else None)
                row = dict(mesh=name, n=mesh.n_vertices, alpha_hat=alpha_hat, rho=rho)
                for level in LEVELS:
                    its, pcg = reached.get(level, (None, None))
                    row[f"iterations_{level * 100:g}pct"] = its
                    if multigrid:
                        row[f"pcg_{level * 100:g}pct"] = pcg
                row["seconds"] = round(time.perf_counter() - t0, 2)
                if multigrid:
                    row.update(package_rows(mesh, alpha_hat, exact))
                rows.append(row)
                print("  " + str(rows[-1]), file=sys.stderr, flush=True)
    write_csv(rows, output)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
