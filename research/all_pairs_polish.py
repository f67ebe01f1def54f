"""All pairs: the symmetric ADMM's tail replaced by a barrier Newton polish (issue 24, a prototype).

    python research/all_pairs_polish.py --cache /tmp/stopping --admm 150 200 --meshes "cat_rr decimated 80"

Runs ``K`` iterations of the exact-step symmetric ADMM of research/symmetric_all_pairs.py (rho = 8 L),
then Newton's method on the smoothed symmetric problem over the n(n-1)/2 entries of U above the
diagonal (U symmetric, zero diagonal):

    minimize  -A_V^T U A_V + alpha sum_j A_j sum_e a_e |g_ej|^2 - mu sum_j A_j sum_e log(1 - |g_ej|^2),
    g_ej = (G U[:, j])_e,  mu = mu_hat A L / m,

the single-source polish's barrier (solvers/gradients.py) weighted by each column's vertex area A_j,
from the ADMM's U scaled so that max |g| = --interior, along the levels mu_hat of --levels (Newton
steps that keep a tenth of every slack, Armijo backtracking, every level centred until the decrement
is below 1e-6 mu A / n: a looser centring stops at points 0.05-0.3% apart on the same level), each
Newton system solved by scipy's sparse LU. Prints and writes the error after the ADMM and
after each level against the exact minimizer cached by benchmarks/stopping.py --pairs, with the
Newton steps so far: benchmarks/results/all_pairs_polish.csv.
"""

import argparse
import itertools
import os
import sys
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")
sys.path.insert(0, HERE)

import stopping  # noqa: E402
import symmetric_all_pairs  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402


class BarrierPolish:
    """The smoothed symmetric problem of one mesh (module docstring) on x = U[i, j], i < j."""

    def __init__(self, admm, element_volumes):
        n, m = len(admm.AV), admm.m
        self.n, self.m, self.alpha = n, m, admm.alpha
        self.iu, self.ju = np.triu_indices(n, 1)
        k = np.arange(self.iu.size)
        S = sp.csr_matrix((np.ones(2 * k.size), (np.concatenate([self.ju * n + self.iu, self.iu * n + self.ju]),
                                                 np.concatenate([k, k]))), shape=(n * n, k.size))  # x -> vec(U), columns stacked
        self.S = S
        self.K = (sp.kron(sp.identity(n), admm.G) @ S).tocsr()                 # x -> g, (3 m n,)
        self.column_area = np.repeat(admm.AV, m)                                # A_j of each (j, e)
        self.element_area = np.tile(element_volumes, n)
        self.load = S.T @ np.outer(admm.AV, admm.AV).ravel(order="F")
        self.mu_unit = element_volumes.sum() * admm.L / m
        self.weight_unit = self.mu_unit * admm.AV.sum() / n

    def _g(self, x):
        g = (self.K @ x).reshape(-1, 3)
        return g, np.einsum("ec,ec->e", g, g)

    def objective(self, x, mu):
        g, t = self._g(x)
        return (-self.load @ x + self.alpha * np.sum(self.column_area * self.element_area * t)
                - mu * np.sum(self.column_area * np.log1p(-t)))

    def gradient_hessian(self, x, mu):
        g, t = self._g(x)
        inv = 1.0 / (1.0 - t)
        c = 2.0 * self.column_area * (self.alpha * self.element_area + mu * inv)
        d = 4.0 * mu * self.column_area * inv ** 2
        blocks = c[:, None, None] * np.eye(3) + d[:, None, None] * g[:, :, None] * g[:, None, :]
        E = c.size
        B = sp.csr_matrix((blocks.ravel(), np.repeat(np.arange(3 * E).reshape(-1, 3), 3, axis=0).ravel(),
                           np.arange(0, 9 * E + 1, 3)), shape=(3 * E, 3 * E))
        return -self.load + self.K.T @ (c[:, None] * g).ravel(), (self.K.T @ B @ self.K).tocsc()

    def step_length(self, x, dx, keep=0.1):
        """The largest s <= 1 keeping 1 - |g + s dg|^2 >= keep (1 - |g|^2) everywhere."""
        g, t = self._g(x)
        dg = (self.K @ dx).reshape(-1, 3)
        a, b, c = np.einsum("ec,ec->e", dg, dg), 2.0 * np.einsum("ec,ec->e", g, dg), -(1.0 - keep) * (1.0 - t)
        with np.errstate(divide="ignore", invalid="ignore"):
            roots = (-b + np.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
        return float(min(1.0, np.min(roots[a > 0], initial=1.0)))

    def matrix(self, x):
        return (self.S @ x).reshape(self.n, self.n, order="F")

    def steps(self, U, levels, interior, solve=spla.spsolve, max_newton=40):
        """Yield (mu_hat, x, level done) after every Newton system solved along ``levels``, from the
        ADMM's U scaled to max |g| = ``interior``; solve(H, rhs) gives each Newton direction."""
        x = U[self.iu, self.ju] * (interior / np.sqrt(self._g(U[self.iu, self.ju])[1].max()))
        for mu_hat in levels:
            mu = mu_hat * self.mu_unit
            tight = 1e-6 * mu_hat * self.weight_unit
            for k in range(max_newton):
                grad, H = self.gradient_hessian(x, mu)
                dx = solve(H, -grad)
                decrement = -grad @ dx
                if decrement <= tight:
                    yield mu_hat, x, True
                    break
                s, f0 = self.step_length(x, dx), self.objective(x, mu)
                while s > 1e-12 and not self.objective(x + s * dx, mu) <= f0 - 0.25 * s * decrement:
                    s *= 0.5
                x = x + s * dx
                yield mu_hat, x, k == max_newton - 1

    def run(self, U, levels, exact, interior):
        """[(mu_hat, Newton steps so far, error (%))] at the end of each of ``levels``."""
        out = []
        for steps, (mu_hat, x, done) in enumerate(self.steps(U, levels, interior), 1):
            if done:
                out.append((mu_hat, steps, stopping.error_pct(self.matrix(x), exact)))
        return out


def problems(cache, meshes=None):
    """Yield (name, mesh, exact minimizer, SymmetricADMM, BarrierPolish) of the pairs set's meshes at
    alpha_hat 0.03 whose exact minimizer is in ``cache``, of those named "name n" in ``meshes`` (all: None)."""
    for name, mesh in stopping.pairs_set():
        if meshes and f"{name} {mesh.n_vertices}" not in meshes:
            continue
        exact = stopping.cached(cache, f"pairs {name} {mesh.n_vertices} 0.03", None)
        if exact is not None:
            admm = symmetric_all_pairs.SymmetricADMM(mesh, 0.03)
            yield name, mesh, exact, admm, BarrierPolish(admm, admm.element_volumes)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cache", required=True, help="folder of the exact minimizers (benchmarks/stopping.py --pairs)")
    parser.add_argument("--admm", type=int, nargs="+", default=[150, 200], help="ADMM iterations before the polish")
    parser.add_argument("--levels", type=float, nargs="+", default=[1e-3, 1e-4, 1e-5, 1e-6], help="mu_hat of the levels")
    parser.add_argument("--interior", type=float, default=0.95, help="max |g| of the polish's starting point")
    parser.add_argument("--meshes", nargs="+", default=None, help='"name n" of the pairs set (default: all cached)')
    parser.add_argument("--output", default=os.path.join(HERE, "results", "all_pairs_polish.csv"))
    args = parser.parse_args()
    rows = []
    for name, mesh, exact, admm, polish in problems(args.cache, args.meshes):
        for iterations in args.admm:
            U = next(itertools.islice(admm.iterates(8.0 * admm.L), iterations - 1, None))[0]
            t0 = time.perf_counter()
            levels = polish.run(U, args.levels, exact, args.interior)
            row = dict(mesh=name, n=mesh.n_vertices, admm_iterations=iterations,
                       admm_error_pct=stopping.error_pct(U, exact))
            for mu_hat, steps, error in levels:
                row.update({f"newton_{mu_hat:g}": steps, f"error_{mu_hat:g}_pct": error})
            rows.append(dict(row, polish_seconds=round(time.perf_counter() - t0, 1)))
            print("  " + str(rows[-1]), file=sys.stderr, flush=True)
    write_csv(rows, args.output)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
