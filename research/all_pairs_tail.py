"""How far the eigenbasis engine's stop is from the first iterate within the accuracy (issue 41, a measurement).

    python research/all_pairs_tail.py --cache /tmp/stopping
    python research/all_pairs_tail.py --cache /tmp/stopping --cases '/tmp/corpus/os_bunny.obj 1200 0.03' --dtype float32
    python research/all_pairs_tail.py --cache /tmp/stopping --polish-at 600 --cases 'spot_rr_holes 302 0.03'
    python research/all_pairs_tail.py --mesh cat_rr --reference U.npy --dtype float32 --max-iterations 1500

Runs ``AllPairsSolver(engine="eigenbasis").solve(accuracy=...)`` on decimations of the shared meshes against
their 5,000-iteration references in ``--cache`` (those of benchmarks/all_pairs.py; default its ``LARGER``) and,
every 50 iterations, measures the iterate's error against the reference in % of max U: the max, the 99.9th
percentile over the n^2 entries and the number of rows holding an entry above half the max. Reports the
rule's stop and error, and the first iteration from which each error stays below 1% and 0.5% (an oracle
stop, which no rule can make without the reference), with how far the iterate moved over the last half
of the run then (max |U_k - U_(k/2)|, in % of max U). Also an estimate that extrapolates in log time
(:func:`log_time_rest`, from the iterates at k / 4, k / 2 and k) and where it would stop: its first check
at or below ``eps_change`` = 0.7 e, and the error then (empty: not before the run's stop).

With ``--polish-at K``: at iteration K the row with the largest error is re-solved exactly with every
other entry fixed (block coordinate descent: its column's constraints, and each other column's
constraints on the elements around its vertex, whose bounds are raised to the iterate's own where it
exceeds 1; cvxpy + Clarabel), and the error before and after is printed. With ``--mesh NAME --reference
FILE``: that mesh as it is (a shared mesh or a file) against the matrix in FILE (a longer run of the same
problem). Writes benchmarks/results/all_pairs_tail.csv and prints a table.
"""

import argparse
import os
import sys

import numpy as np

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")
sys.path.insert(0, HERE)

import all_pairs as bench  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402
from warp_regdist.solvers.all_pairs import solver as all_pairs_admm  # noqa: E402
from warp_regdist.solvers.all_pairs.run import PairsRun  # noqa: E402

RESULTS = os.path.join(HERE, "results", "all_pairs_tail.csv")
EVERY = 50
LEVELS = (0.01, 0.005)


def log_time_rest(k, a, b, d1, d2):
    """The rest of a power law e_k = C k^(-p) fitted to the changes d1 = |U_k - U_a| and d2 = |U_a - U_b|
    (b < a < k): p solves d2 / d1 = (b^-p - a^-p) / (a^-p - k^-p) (geometric in log k: Aitken's
    extrapolation on the grid k / 4, k / 2, k), and the rest is d1 k^-p / (a^-p - k^-p); inf where the
    changes do not shrink like a power of k (p below 0.05)."""
    def ratio(p):
        return (b ** -p - a ** -p) / (a ** -p - k ** -p)

    lo, hi = 0.05, 8.0
    if d1 <= 0 or d2 / d1 <= ratio(lo):
        return np.inf if d1 > 0 else 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ratio(mid) < d2 / d1 else (lo, mid)
    p = 0.5 * (lo + hi)
    return d1 * k ** -p / (a ** -p - k ** -p)


class RecordedRun(PairsRun):
    """PairsRun that records, every ``EVERY`` iterations, the iterate's error against ``reference`` and
    the log-time estimate (keeping the iterates from k / 4 on) and, at ``polish_at``, keeps the iterate."""

    reference = polish_at = kept = None
    log = []
    iterates = {}

    def status(self, it):
        if it % EVERY == 0 and RecordedRun.reference is not None:
            U, ref = self.state.distance(), RecordedRun.reference
            E = np.abs(U - ref) / ref.max()
            worst = float(E.max())
            RecordedRun.log.append(dict(it=it, max=worst, q999=float(np.quantile(E, 0.999)),
                                        rows=int(((E > 0.5 * worst).any(axis=1)).sum()), log_time=np.inf,
                                        half=np.nan))
            kept, top = RecordedRun.iterates, U.max()
            kept[it] = U
            a, b = (EVERY * round(it / (f * EVERY)) for f in (2, 4))
            if 0 < b < a and a in kept and b in kept:
                d1, d2 = (float(np.abs(kept[x] - kept[y]).max() / top) for x, y in ((it, a), (a, b)))
                RecordedRun.log[-1].update(log_time=log_time_rest(it, a, b, d1, d2), half=d1)
            for x in [x for x in kept if x < b]:  # b grows with it: no later check needs these
                del kept[x]
        done = super().status(it)
        if it % EVERY == 0 and RecordedRun.reference is not None:
            RecordedRun.log[-1]["estimate"] = float(self.change_test.change[0])
            if it == RecordedRun.polish_at:
                RecordedRun.kept = U
        return done


def stays_below(log, key, level):
    """The first recorded iteration from which ``key`` stays below ``level`` (None: never)."""
    for r in log:
        if all(s[key] < level for s in log if s["it"] >= r["it"]):
            return r["it"]
    return None


def polish_row(U, i, ops, alpha):
    """U with row and column ``i`` replaced by the exact minimizer of the all-pairs objective
    f(U) = alpha sum_j a_j u_j^T W u_j - a^T U a over them, every other entry fixed."""
    import cvxpy as cp

    n, m = U.shape[0], len(ops.elements)
    G, W, a = ops.grad.tocsr(), ops.stiffness.tocsr(), ops.vertex_volumes
    rest = U.copy()
    rest[i, :] = 0.0
    w_i = W[i].toarray().ravel()
    x = cp.Variable(n)
    objective = (alpha * a[i] * cp.quad_form(x, W) + alpha * cp.sum(cp.multiply(a * w_i[i], cp.square(x)))
                 + 2 * alpha * cp.sum(cp.multiply(a * (w_i @ rest), x)) - 2 * a[i] * (a @ x))
    own = np.maximum(1.0, np.linalg.norm((G @ U[:, i]).reshape(m, 3), axis=1))
    constraints = [x[i] == 0, x >= 0, cp.norm(cp.reshape(G @ x, (m, 3), order="C"), 2, axis=1) <= own]
    for e in np.flatnonzero((ops.elements == i).any(axis=1)):
        G_e = G[3 * e:3 * e + 3].toarray()
        bound = np.maximum(1.0, np.linalg.norm(G_e @ U, axis=0))
        others = G_e @ rest + cp.reshape(G_e[:, i], (3, 1), order="C") @ cp.reshape(x, (1, n), order="C")
        constraints.append(cp.norm(others, 2, axis=0) <= bound)
    cp.Problem(cp.Minimize(objective), constraints).solve(solver=cp.CLARABEL)
    V = U.copy()
    V[i, :] = V[:, i] = x.value
    V[i, i] = 0.0
    return V


def measure(solver, name, reference, accuracy, args):
    """One run at ``accuracy``: its row (stop, error, the iterations from which each error stays within
    ``LEVELS``, the estimate then); prints the trace and the polish where asked."""
    RecordedRun.reference, RecordedRun.polish_at = reference, args.polish_at
    RecordedRun.log, RecordedRun.iterates = [], {}
    res = solver.solve(accuracy=accuracy)
    log = RecordedRun.log
    for r in log if args.trace else ():
        if r["it"] % 100 == 0:
            print(f"  iteration {r['it']}: max {100 * r['max']:.3f}%, 99.9th percentile {100 * r['q999']:.3f}%, "
                  f"estimate {100 * r.get('estimate', np.inf):.3f}%, log-time {100 * r['log_time']:.3f}%, "
                  f"moved over the last half {100 * r['half']:.3f}%", flush=True)
    row = dict(mesh=name, n=solver.mesh.n_vertices, alpha_hat=solver.alpha_hat, dtype=args.dtype, accuracy=accuracy,
               **bench._run_columns(res, reference))
    for level in LEVELS:
        row[f"max_below_{level}"] = stays_below(log, "max", level)
        row[f"q999_below_{level}"] = stays_below(log, "q999", level)
    at = {r["it"]: r for r in log}.get(row["max_below_0.01"])
    row["estimate_at_1pct"] = round(100 * at["estimate"], 3) if at else None
    row["half_change_at_1pct"] = round(100 * at["half"], 3) if at else None
    row["rows_at_half_max"] = log[-1]["rows"] if log else None
    stop = next((r for r in log if r["log_time"] <= 0.7 * accuracy), None)
    row["log_time_stop"] = stop["it"] if stop else None
    row["log_time_error_pct"] = round(100 * stop["max"], 3) if stop else None
    RecordedRun.iterates = {}
    if RecordedRun.kept is not None:
        U, RecordedRun.kept = RecordedRun.kept, None
        top = reference.max()
        E = np.abs(U - reference) / top
        i = int(np.unravel_index(np.argmax(E), E.shape)[0])
        V = polish_row(U, i, solver.operators, solver.alpha_hat * solver.operators.length_scale)
        after = np.abs(V - reference) / top
        print(f"polish at iteration {args.polish_at}, row {i}: max error {100 * E.max():.3f}% -> "
              f"{100 * after.max():.3f}%, the row's {100 * E[i].max():.3f}% -> {100 * after[i].max():.3f}%", flush=True)
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", help="folder of the 5,000-iteration references")
    ap.add_argument("--mesh", help="a shared mesh or a mesh file, solved as it is against --reference")
    ap.add_argument("--reference", help="the matrix (.npy) that --mesh is measured against")
    ap.add_argument("--alpha-hat", type=float, default=0.03)
    ap.add_argument("--max-iterations", type=int, default=3000)
    ap.add_argument("--cases", nargs="+", default=None,
                    help="'mesh vertices alpha_hat' (a shared mesh or a file); default: benchmarks/all_pairs.py LARGER")
    ap.add_argument("--accuracies", type=float, nargs="+", default=[0.01, 0.005])
    ap.add_argument("--dtype", default="float64", choices=("float64", "float32"))
    ap.add_argument("--polish-at", type=int, default=None, metavar="K")
    ap.add_argument("--trace", action="store_true", help="print the errors and the estimate every 100 iterations")
    ap.add_argument("--out", default=RESULTS)
    args = ap.parse_args()
    if (args.mesh is None) == (args.cache is None) or (args.mesh is None) != (args.reference is None):
        ap.error("expected --cache, or --mesh with --reference")
    import warp as wp
    wp.config.quiet = True
    if args.mesh is not None:
        import meshes

        name = os.path.splitext(os.path.basename(args.mesh))[0]
        solved = [(name, meshes.shared_mesh(args.mesh), args.alpha_hat, np.load(args.reference), "intrinsic")]
    else:
        cases = bench.parse_cases(args.cases)
        solved = bench.larger_cases(args.cache, "intrinsic", cases)
    rows = []
    all_pairs_admm.PairsRun = RecordedRun
    try:
        for name, mesh, alpha_hat, reference, _ in solved:
            options = wrd.AllPairsOptions(engine="eigenbasis", max_iterations=args.max_iterations)
            solver = wrd.AllPairsSolver(mesh, alpha_hat, device="cpu", dtype=args.dtype, workers=1,
                                        triangulation="intrinsic", options=options)
            for accuracy in args.accuracies:
                rows.append(measure(solver, name, reference, accuracy, args))
                print(rows[-1], flush=True)
                write_csv(rows, args.out)
    finally:
        all_pairs_admm.PairsRun = PairsRun
    print(markdown_table(rows))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
