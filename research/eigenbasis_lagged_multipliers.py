"""The eigenbasis U-step with the diagonal's multipliers lagged one iteration (issue 41, a measurement).

    python research/eigenbasis_lagged_multipliers.py --cache /tmp/stopping
    python research/eigenbasis_lagged_multipliers.py --cache /tmp/stopping --cases 'spot_rr_holes 302 0.03'

The exact U-step (``EigenbasisUStep``) spends 2 of its 8 n^3 flops on the diagonal's multipliers mu: their
response Phi^T Diag(mu) Phi (a rank-n update) and its product with Phi. Lagging them saves both: the
right-hand side carries the last iteration's mu, C' = C + Diag(mu_prev), which costs nothing before the
transforms (6 n^3 flops), and the diagonal of the result gives the exact mu = mu_prev + (its correction
from the same bordered system), kept for the next iteration; the diagonal is then set to zero. The fixed
points are the exact step's (there the correction is zero). ``damped`` keeps mu_prev + 0.5 (correction).

Runs the eigenbasis engine with each U-step on decimations of the shared meshes against their
5,000-iteration references in ``--cache`` (those of benchmarks/all_pairs.py), and prints per variant,
every 300 iterations, the max error against the reference and the mean over the last 10 iterations of
the max change of U in one iteration (both in % of max U), the run's stop at accuracy 0.01 and the
median U-step time. Writes benchmarks/results/eigenbasis_lagged_multipliers.csv.
"""

import argparse
import os
import sys
import time
import warnings

import numpy as np
import scipy.linalg as sl

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")
sys.path.insert(0, HERE)

import all_pairs as bench  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402
from warp_regdist.solvers.all_pairs import solver as all_pairs_admm  # noqa: E402
from warp_regdist.solvers.all_pairs.eigenbasis import EigenbasisUStep  # noqa: E402

RESULTS = os.path.join(HERE, "results", "eigenbasis_lagged_multipliers.csv")
REPORT_EVERY = 300


class LaggedUStep(EigenbasisUStep):
    """The U-step with mu from the last call in the right-hand side (6 n^3 flops); ``damping`` scales the
    correction kept for the next call."""

    damping = 1.0

    def __call__(self, R, scale):
        s, n = self.s, self.n
        mu_prev = getattr(self, "mu_prev", np.zeros(n))
        C = ((s[:, None] * R.astype(self.dtype, copy=False)) * s[None, :]).T
        C[np.diag_indices(n)] += mu_prev.astype(self.dtype)
        P = self.half_solve(C)
        diag = 2 * np.einsum("ij,ij->i", P, self.Phi, dtype=np.float64) / scale
        areas = 1 / s.astype(np.float64) ** 2
        rhs = np.concatenate([-diag / areas, [-(R.sum(dtype=np.float64) + areas @ mu_prev) / scale]])
        sol = sl.lu_solve(self.border, rhs)
        self.mu_prev = mu_prev + self.damping * scale * sol[:n]
        return self.to_vertices(P, scale, sol[n])


def traced(step_class, reference, trace):
    """``step_class`` whose calls append (seconds, max change of U / max reference, max error) to ``trace``."""
    top = reference.max()

    class Traced(step_class):
        def __call__(self, R, scale):
            start = time.perf_counter()
            U = super().__call__(R, scale)
            seconds = time.perf_counter() - start
            change = np.abs(U - self.last).max() / top if hasattr(self, "last") else np.inf
            self.last = U.copy()
            trace.append((seconds, change, np.abs(U - reference).max() / top))
            return U

    return Traced


def variant_rows(name, mesh, alpha_hat, reference, variant, max_iterations):
    trace = []
    step = LaggedUStep if variant != "exact" else EigenbasisUStep
    all_pairs_admm.EigenbasisUStep = traced(step, reference, trace)
    all_pairs_admm.EigenbasisUStep.damping = 0.5 if variant == "damped" else 1.0
    try:
        solver = wrd.AllPairsSolver(mesh, alpha_hat, device="cpu", workers=1, triangulation="intrinsic",
                                    options=wrd.AllPairsOptions(engine="eigenbasis", max_iterations=max_iterations))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = solver.solve(accuracy=0.01)
    finally:
        all_pairs_admm.EigenbasisUStep = EigenbasisUStep
    seconds, change, error = (np.array(c) for c in zip(*trace))
    stop = dict(stop=res.iterations, converged=res.converged, estimate_pct=round(100 * res.error_estimate, 3),
                u_step_ms=round(1000 * float(np.median(seconds)), 1))
    return [dict(mesh=name, n=mesh.n_vertices, variant=variant, iteration=k,
                 error_pct=round(100 * float(error[k - 1]), 3),
                 change_pct=round(100 * float(change[k - 10:k].mean()), 4), **stop)
            for k in range(REPORT_EVERY, len(trace) + 1, REPORT_EVERY)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", required=True, help="folder of the 5,000-iteration references")
    ap.add_argument("--cases", nargs="+", default=["cat_rr 500 0.03"],
                    help="'mesh vertices alpha_hat' (a shared mesh or a file)")
    ap.add_argument("--variants", nargs="+", default=["exact", "lagged", "damped"])
    ap.add_argument("--max-iterations", type=int, default=3000)
    ap.add_argument("--out", default=RESULTS)
    args = ap.parse_args()
    import warp as wp
    wp.config.quiet = True
    rows = []
    cases = bench.larger_cases(args.cache, "intrinsic", bench.parse_cases(args.cases))
    for name, mesh, alpha_hat, reference, _ in cases:
        for variant in args.variants:
            rows += variant_rows(name, mesh, alpha_hat, reference, variant, args.max_iterations)
            print(markdown_table(rows[-1:]), flush=True)
            write_csv(rows, args.out)
    print(markdown_table(rows))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
