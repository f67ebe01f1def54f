"""All pairs at the defaults a user gets, by mesh size: iterations, time and memory to converge.

    python benchmarks/all_pairs_sizes.py [--sizes 300 600 1000] [--accuracy 0.01] [--dtype float32]
    python benchmarks/all_pairs_sizes.py --sizes 3000 --engine eigenbasis --max-iterations 8000

The mesh: the shipped cat_rr (1,949 vertices) decimated to each size by fast-simplification (the
[compare] extra), above its size Loop-subdivided once first; each size in its own process (peak RSS is
the run's own), alpha_hat 0.03, the default engine for the size (or ``--engine``) and the given accuracy
and dtype. Writes
benchmarks/results/all_pairs_sizes.csv: vertices, engine, iterations, converged, the error estimate,
seconds (setup included), seconds per iteration, the solver's memory estimate and the peak RSS.
"""

import argparse
import os
import resource
import sys
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from report import markdown_table, print_result, run_child, write_csv  # noqa: E402

RESULTS = os.path.join(HERE, "results", "all_pairs_sizes.csv")


def run_case(case):
    import fast_simplification
    import numpy as np
    import warp_regdist as wrd

    import trimesh

    size, accuracy, dtype, engine, cap = case.split(":")
    size, accuracy = int(size), float(accuracy)
    cat = wrd.load_mesh(wrd.data_path("cat_rr.off"))
    V, F = cat.vertices, cat.elements
    if size > cat.n_vertices:
        V, F = trimesh.remesh.subdivide_loop(V, F, iterations=1)
    if size < len(V):
        V, F = fast_simplification.simplify(V.astype(np.float32), F.astype(np.int32), target_reduction=1.0 - size / len(V))
    if len(V) != cat.n_vertices:
        cat = wrd.Mesh(np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64))
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        solver = wrd.AllPairsSolver(cat, 0.03, dtype=dtype, device="cpu", options=wrd.AllPairsOptions(engine=engine))
        res = solver.solve(accuracy=accuracy, max_iterations=int(cap) if cap != "None" else None)
    seconds = time.perf_counter() - t
    print_result(dict(vertices=cat.n_vertices, engine=res.engine, dtype=dtype, accuracy=accuracy,
                      iterations=int(res.iterations), converged=bool(res.converged),
                      estimate_pct=round(100.0 * float(res.error_estimate), 3), seconds=round(seconds, 1),
                      s_per_iteration=round(res.seconds / max(1, res.iterations), 4),
                      memory_gb=round(res.memory_bytes / 1e9, 2),
                      peak_rss_gb=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, 2)))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[300, 600, 1000])
    parser.add_argument("--accuracy", type=float, default=0.01)
    parser.add_argument("--dtype", default="float32")
    parser.add_argument("--engine", default="auto", choices=["auto", "eigenbasis", "consensus"])
    parser.add_argument("--max-iterations", type=int, default=None, help="the cap (default: the solver's)")
    parser.add_argument("--case", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        return run_case(args.case)
    rows = [r for r in (run_child(__file__, f"{n}:{args.accuracy}:{args.dtype}:{args.engine}:{args.max_iterations}") for n in args.sizes) if r]
    write_csv(rows, RESULTS)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
