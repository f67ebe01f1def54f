"""All pairs: PCG on the Newton systems of two second-order methods (issue 24, a prototype).

    python research/all_pairs_newton_pcg.py --cache /tmp/stopping --meshes "cat_rr decimated 80"

From --admm iterations of the exact-step symmetric ADMM (research/symmetric_all_pairs.py, rho = 8 L),
two Newton paths over x = U[i, j], i < j, every Newton system solved by sparse LU:

    barrier  the polish of research/all_pairs_polish.py (mu_hat 1e-3 ... 1e-6, from max |g| = 0.95);
    ssnal    a semismooth Newton augmented Lagrangian (:class:`AugmentedLagrangian`), from the
             ADMM's U and its multipliers Y.

On every Newton system H dx = -grad it counts the iterations of PCG from zero until the residual has
dropped 100-fold and 10^6-fold (at most --max-pcg), with two preconditioners:

    tensor   the tensor-product V-cycle of the symmetric ADMM's U-step (:class:`TensorMultigrid`,
             of W U M + M U W), applied to the symmetric matrix whose entries above the diagonal are r;
    amg      pyamg's smoothed aggregation (the [compare] extra) set up on each assembled H
             (evolution strength, the best of pyamg's strength measures here; skipped without pyamg).

``ssnal_amg`` runs the ssnal path without LU: each direction is pyamg's PCG to a 1000-fold residual
drop (``pcg_used``, the V-cycles spent; ``seconds``, the path's wall time with setups).

Rows: per mesh, method and error level (% of max U* from the exact minimizer cached by
benchmarks/stopping.py --pairs), the Newton steps until the iterate is first within the level and
the PCG iterations summed over those steps: benchmarks/results/all_pairs_newton_pcg.csv.
"""

import argparse
import importlib.util
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
from all_pairs_polish import problems  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402

LEVELS = (0.005, 0.002, 0.0005, 0.0001)
DROPS = (1e-2, 1e-6)


class AugmentedLagrangian:
    """The problem of a :class:`BarrierPolish` (g = K x, weights w = A_j a_e) with g in the unit balls
    split off and priced by multipliers y (3 m n,):

        phi(x) = -load x + alpha sum w |g|^2 + (sigma / 2) sum w dist(g + y / sigma, ball)^2,

    minimized by semismooth Newton (generalized Hessian K^T w [2 alpha I + sigma (I - dPi(v))] K,
    v = g + y / sigma, dPi = (I - v v^T / |v|^2) / |v| outside the ball and I inside; Armijo steps)
    until |grad phi| has dropped ``inner_drop``-fold, then y = sigma (v - Pi(v)) and sigma doubles
    up to ``sigma_max``."""

    def __init__(self, problem):
        self.p = problem
        self.w = problem.column_area * problem.element_area                    # (m n,)

    def _split(self, x, y, sigma):
        g = self.p.K @ x
        v = (g + y / sigma).reshape(-1, 3)
        size = np.linalg.norm(v, axis=1)
        return g, v, size, v / np.maximum(1.0, size)[:, None]

    def value(self, x, y, sigma):
        g, v, _, proj = self._split(x, y, sigma)
        t = np.einsum("ec,ec->e", g.reshape(-1, 3), g.reshape(-1, 3))
        return -self.p.load @ x + self.p.alpha * self.w @ t + 0.5 * sigma * self.w @ np.sum((v - proj) ** 2, axis=1)

    def gradient_hessian(self, x, y, sigma):
        g, v, size, proj = self._split(x, y, sigma)
        grad = -self.p.load + self.p.K.T @ (np.repeat(self.w, 3) * (2 * self.p.alpha * g + sigma * (v - proj).ravel()))
        outside = size > 1.0
        inv = np.where(outside, 1.0 / np.maximum(size, 1e-300), 0.0)
        unit = v * inv[:, None]
        blocks = (np.where(outside, 1.0 - inv, 0.0)[:, None, None] * np.eye(3)
                  + inv[:, None, None] * unit[:, :, None] * unit[:, None, :])
        blocks = self.w[:, None, None] * (2 * self.p.alpha * np.eye(3) + sigma * blocks)
        E = blocks.shape[0]
        B = sp.csr_matrix((blocks.ravel(), np.repeat(np.arange(3 * E).reshape(-1, 3), 3, axis=0).ravel(),
                           np.arange(0, 9 * E + 1, 3)), shape=(3 * E, 3 * E))
        return grad, (self.p.K.T @ B @ self.p.K).tocsc()

    def steps(self, x, y, sigma, sigma_max, solve=spla.spsolve, outer=40, inner_drop=0.1, max_inner=50):
        """Yield x after every Newton system solved; solve(H, rhs) gives each direction."""
        for _ in range(outer):
            start = None
            for k in range(max_inner):
                grad, H = self.gradient_hessian(x, y, sigma)
                size = np.linalg.norm(grad)
                start = size if start is None else start
                if k > 0 and size <= inner_drop * start:
                    break
                dx = solve(H, -grad)
                f0, slope, s = self.value(x, y, sigma), grad @ dx, 1.0
                while s > 1e-10 and self.value(x + s * dx, y, sigma) > f0 + 1e-4 * s * slope:
                    s *= 0.5
                x = x + s * dx
                yield x
            _, v, _, proj = self._split(x, y, sigma)
            y = sigma * (v - proj).ravel()
            sigma = min(2.0 * sigma, sigma_max)


def pcg_drops(H, b, precondition, max_iterations):
    """Iterations of PCG from zero until |r| <= drop |b|, for each of DROPS (None: not within max_iterations)."""
    r = b.copy()
    z = precondition(r)
    p, rz, top, reached = z.copy(), r @ z, np.linalg.norm(b), {}
    for k in range(1, max_iterations + 1):
        q = H @ p
        a = rz / (p @ q)
        r -= a * q
        size = np.linalg.norm(r)
        reached.update({d: k for d in DROPS if d not in reached and size <= d * top})
        if len(reached) == len(DROPS):
            break
        z = precondition(r)
        rz, rz_old = r @ z, rz
        p = z + (rz / rz_old) * p
    return [reached.get(d) for d in DROPS]


def amg(H):
    """pyamg's smoothed-aggregation hierarchy of H (evolution strength of connection)."""
    import pyamg

    return pyamg.smoothed_aggregation_solver(sp.csr_matrix(H), max_coarse=500, strength=(
        "evolution", {"k": 2, "proj_type": "D_A", "epsilon": 4.0}))


def preconditioners(problem, multigrid):
    """{name: H -> (r -> z)}: the tensor V-cycle, and pyamg's V-cycle where pyamg is installed."""
    n, iu, ju = problem.n, problem.iu, problem.ju

    def tensor(H):
        def apply(r):
            R = np.zeros((n, n))
            R[iu, ju] = r
            return multigrid(R + R.T)[iu, ju]
        return apply

    out = dict(tensor=tensor)
    if importlib.util.find_spec("pyamg") is None:
        print("pyamg is not installed: the amg column is left out", file=sys.stderr)
        return out
    out["amg"] = lambda H: amg(H).aspreconditioner(cycle="V")
    return out


def amg_solver(used):
    """solve(H, rhs) by pyamg's smoothed-aggregation PCG to a 1000-fold residual drop; appends the
    iterations to ``used``."""
    def solve(H, rhs):
        residuals = []
        dx = amg(H).solve(rhs, tol=1e-3, accel="cg", maxiter=2000, residuals=residuals)
        used.append(len(residuals) - 1)
        return dx
    return solve


def measure(path, problem, exact, counts, label, max_steps):
    """Rows of one Newton path (an iterator of x) until within every level or after max_steps."""
    rows, reached, t0 = [], set(), time.perf_counter()
    for step, x in enumerate(path, 1):
        error = stopping.error_pct(problem.matrix(x), exact)
        for level in LEVELS:
            if level not in reached and error <= 100 * level:
                reached.add(level)
                row = dict(label, level_pct=100 * level, newton=step, error_pct=error)
                for name, per_system in counts.items():
                    if name == "used":
                        continue
                    for i, drop in enumerate(DROPS):
                        done = [c[i] for c in per_system]
                        row[f"{name}_pcg_{drop:g}"] = (sum(done) if None not in done else None)
                        row[f"{name}_max_{drop:g}"] = max((c for c in done if c is not None), default=None)
                if "used" in counts:
                    row["pcg_used"], row["seconds"] = sum(counts["used"]), round(time.perf_counter() - t0, 1)
                rows.append(row)
                print("  " + str(row), file=sys.stderr, flush=True)
        if len(reached) == len(LEVELS) or step == max_steps:
            break
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cache", required=True, help="folder of the exact minimizers (benchmarks/stopping.py --pairs)")
    parser.add_argument("--admm", type=int, default=200, help="ADMM iterations before the Newton paths")
    parser.add_argument("--max-pcg", type=int, default=3000)
    parser.add_argument("--max-newton", type=int, default=80, help="Newton systems per path at most")
    parser.add_argument("--sigma", type=float, nargs=2, default=[8.0, 1e4], help="ssnal's first and largest sigma / L")
    parser.add_argument("--methods", nargs="+", choices=("barrier", "ssnal", "ssnal_amg"), default=["barrier", "ssnal"])
    parser.add_argument("--meshes", nargs="+", default=None, help='"name n" of the pairs set (default: all cached)')
    parser.add_argument("--output", default=os.path.join(HERE, "results", "all_pairs_newton_pcg.csv"))
    args = parser.parse_args()
    rows = []
    for name, mesh, exact, admm, problem in problems(args.cache, args.meshes):
        U, _, Y = next(itertools.islice(admm.iterates(8.0 * admm.L), args.admm - 1, None))
        U, Y = U.copy(), Y.copy()
        builders = preconditioners(problem, admm.multigrid)
        for method in args.methods:
            counts = {key: [] for key in builders} if method != "ssnal_amg" else dict(used=[])

            def solve(H, rhs):
                for key, build in builders.items():
                    counts[key].append(pcg_drops(H, rhs, build(H), args.max_pcg))
                return spla.spsolve(H, rhs)

            if method == "barrier":
                path = (x for _, x, _ in problem.steps(U, [1e-3, 1e-4, 1e-5, 1e-6], 0.95, solve))
            else:
                path = AugmentedLagrangian(problem).steps(
                    U[problem.iu, problem.ju], Y.T.ravel(), args.sigma[0] * admm.L, args.sigma[1] * admm.L,
                    solve if method == "ssnal" else amg_solver(counts["used"]))
            label = dict(mesh=name, n=mesh.n_vertices, method=method, admm_iterations=args.admm)
            rows += measure(path, problem, exact, counts, label, args.max_newton)
    write_csv(rows, args.output)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
