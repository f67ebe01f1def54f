"""The all-pairs change test against long runs: where each rule would stop, on the same iterates.

    python benchmarks/all_pairs_change_test.py --cache /tmp/stopping
    python benchmarks/all_pairs_change_test.py --cache /tmp/stopping --engines eigenbasis --cases cat_rr:1000:0.03
    python benchmarks/all_pairs_change_test.py --cache /tmp/stopping --cases /tmp/bunny.obj:600:0.1

Each case and engine is run once, one process, at the default tolerances (accuracy 0.005) with the
change test switched off (``eps_change`` 1e-12), up to ``--iterations``; every ``change_window`` (50)
iterations the run is checkpointed and resumed (``solve(checkpoint=, resume=)`` repeats the
uninterrupted run's arithmetic), so U there is read from the result: its error against the
reference, its window change c_k = max |U_k - U_(k - 50)| / max U_k, and from the callback the max
residual / tolerance and the gradient excess. The iterates do not depend on the change test (nor, at
accuracy 0.005 to 0.02, on the accuracy: only the stopping tests scale), so each rule's stop at
accuracy e is the first window where the residual ratio x 0.005 / e <= 1, the gradient excess <= e
and the rule's change estimate holds:

- ``geometric``: c_k / (1 - c_k / c_(k - 50)) <= 0.3 e (the rule before: the rest of a geometric series);
- ``20 windows``: the package's rest counted over at most 20 windows (``capped``; the eigenbasis engine's,
  and the consensus engine's before it counted 40) <= 0.7 e;
- ``package``: the package's own ``error_estimate`` <= ``AllPairsOptions.for_accuracy(e).eps_change``
  (0.7 e; the larger of the capped geometric rest and the rest at a 1 / k rate,
  warp_regdist.solvers.common.stopping.ExtrapolatedChangeTest, at most 20 windows (eigenbasis) or 40 (consensus)).

Cases: the exact minimizers of tests/data (the meshes' own triangles), the decimations of
benchmarks/all_pairs.py ``LARGER`` (intrinsic operators) against their cached 5,000-iteration
references in ``--cache`` (computed there when missing: research/symmetric_all_pairs.py), and
``--cases PATH_OR_NAME:VERTICES:ALPHA_HAT`` for more decimations. Writes
benchmarks/results/all_pairs_change_test.csv (one row per case, engine, rule and accuracy;
all_pairs_change_test_ENGINE.csv with one ``--engines``).
"""

import argparse
import math
import os
import sys
import tempfile
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.append(os.path.join(HERE, "..", "research"))
sys.path.append(os.path.join(HERE, "..", "tests"))

import all_pairs as bench  # noqa: E402
import warp as wp  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402

RESULTS = os.path.join(HERE, "results", "all_pairs_change_test.csv")
ACCURACIES = (0.02, 0.01, 0.005)
ITERATIONS = {"eigenbasis": 2500, "consensus": 3000}


def trajectory(mesh, alpha_hat, triangulation, engine, reference, iterations):
    """Per window k (every change_window iterations up to ``iterations``): dict of arrays it, error,
    window_change, ratio (max residual / tolerance at accuracy 0.005), excess and estimate (the
    package's error_estimate)."""
    solver = wrd.AllPairsSolver(mesh, alpha_hat, device="cpu", workers=1, triangulation=triangulation,
                                options=wrd.AllPairsOptions(engine=engine))
    window = solver.options.change_window
    tests, rows, before = {}, [], None
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "run.npz")
        for k in range(window, iterations + 1, window):
            res = solver.solve(accuracy=0.005, eps_change=1e-12, max_iterations=k, checkpoint=path,
                               resume=path if k > window else None,
                               callback=lambda p: tests.__setitem__(p.iteration, p.tests))
            U = res.distance
            top = U.max()
            c = math.inf if before is None else float(np.abs(U - before).max() / top)
            before = U
            rows.append((k, float(np.abs(U - reference).max() / reference.max()), c, tests[k][0].value,
                         tests[k][2].value, res.error_estimate))
    return dict(zip(("it", "error", "window_change", "ratio", "excess", "estimate"), map(np.array, zip(*rows))))


def geometric(t):
    """The rule before: c_k / (1 - c_k / c_(k - 50)) (inf before the third window and while c grows)."""
    c = t["window_change"]
    prev = np.concatenate([[math.inf], c[:-1]])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((c < prev) & np.isfinite(prev), c / (1 - c / prev), np.where(c == 0, 0.0, math.inf))


def capped(t, windows):
    """The package's rest with at most ``windows`` windows to come: max(c_k / (1 - q), c_(k - 50) min(k / 50,
    windows)), q = min(c_k / c_(k - 50), 1 - 1 / windows) (inf before the third window)."""
    c, it = t["window_change"], t["it"]
    prev = np.concatenate([[math.inf], c[:-1]])
    cap = 1 - 1 / windows
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(c < cap * prev, c / prev, cap)
        rest = np.maximum(c / (1 - q), prev * np.minimum(it / 50, windows))
    return np.where(np.isfinite(prev), np.where(c == 0, 0.0, rest), math.inf)


def stop(t, estimate, threshold, accuracy):
    """(index of the first window where every test holds, or None)."""
    ok = (t["ratio"] * 0.005 / accuracy <= 1) & (estimate <= threshold) & (t["excess"] <= accuracy)
    return int(np.argmax(ok)) if ok.any() else None


def cases(cache, extra, only_extra):
    """Yield (name, mesh, alpha_hat, triangulation, reference): the exact cases and LARGER (unless
    ``only_extra``), then the decimations ``extra`` ("MESH:VERTICES:ALPHA_HAT")."""
    parsed = tuple((p, int(v), float(a)) for p, v, a in (spec.rsplit(":", 2) for spec in extra))
    if not only_extra:
        for name, mesh, alpha_hat, exact, triangulation in bench.exact_cases(None):
            yield name, mesh, alpha_hat, triangulation, exact
        parsed = bench.LARGER + parsed
    for name, mesh, alpha_hat, reference, triangulation in bench.larger_cases(cache, "intrinsic", parsed):
        yield name, mesh, alpha_hat, triangulation, reference


def rows_of(name, mesh, alpha_hat, engine, t):
    rows = []
    eps_change = lambda e: wrd.AllPairsOptions.for_accuracy(e).eps_change  # noqa: E731
    rules = {"geometric": (geometric(t), lambda e: 0.3 * e), "20 windows": (capped(t, 20), eps_change),
             "package": (t["estimate"], eps_change)}
    for rule, (estimate, threshold) in rules.items():
        for accuracy in ACCURACIES:
            i = stop(t, estimate, threshold(accuracy), accuracy)
            j = len(t["it"]) - 1 if i is None else i
            rows.append(dict(mesh=name, n=mesh.n_vertices, alpha_hat=alpha_hat, engine=engine, rule=rule,
                             accuracy=accuracy, iterations=int(t["it"][j]), converged=i is not None,
                             error_pct=round(100 * float(t["error"][j]), 3),
                             estimate_pct=round(100 * float(estimate[j]), 3),
                             within=bool(t["error"][j] <= accuracy)))
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cache", required=True, help="the folder of the long-run references")
    parser.add_argument("--cases", nargs="*", default=[], metavar="MESH:VERTICES:ALPHA_HAT",
                        help="more decimations (a shared mesh's name or a mesh file)")
    parser.add_argument("--engines", nargs="+", default=["eigenbasis", "consensus"],
                        choices=["eigenbasis", "consensus"])
    parser.add_argument("--only-extra", action="store_true", help="only the --cases")
    parser.add_argument("--iterations", type=int, default=None, help="per run (default: ITERATIONS per engine)")
    parser.add_argument("--output", default=None, help="default: RESULTS, with _ENGINE for one engine")
    args = parser.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    warnings.simplefilter("ignore", wrd.ConvergenceWarning)
    rows = []
    for name, mesh, alpha_hat, triangulation, reference in cases(args.cache, args.cases, args.only_extra):
        for engine in args.engines:
            t = trajectory(mesh, alpha_hat, triangulation, engine, reference, args.iterations or ITERATIONS[engine])
            new = rows_of(name, mesh, alpha_hat, engine, t)
            print(markdown_table(new), flush=True)
            rows += new
    output = args.output or (RESULTS if len(args.engines) == 2 else RESULTS.replace(".csv", f"_{args.engines[0]}.csv"))
    write_csv(rows, output)
    print(f"wrote {output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
