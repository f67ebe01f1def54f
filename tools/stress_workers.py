"""Stress test of the parallel CPU paths (2 workers) while busy-looping processes load every core.

    python tools/stress_workers.py                  # 20 runs of each path, cat_rr all pairs
    python tools/stress_workers.py --runs 5 --iterations 3

Each run is its own child process (a segmentation fault kills the child, not this script):
``all_pairs`` on cat_rr (float32, ``workers=2``, a few ADMM iterations: the threads start in the
first one) and ``solve_many`` on spot with 2 workers (2 lane blocks, one per thread). While the
runs go, one busy-looping process per core competes for the CPU. A run counts as a crash when
the child dies by a signal or exits non-zero; its last output lines are shown. Prints a table
and writes benchmarks/results/stress_workers.csv. (When the workers were threads of one process,
all_pairs died by SIGSEGV in 1 of 8 such runs: Warp's CPU launches keep process-global state.)
"""

import argparse
import multiprocessing
import os
import subprocess
import sys
import time

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")
sys.path.insert(0, HERE)

from report import markdown_table, write_csv  # noqa: E402

RESULTS = os.path.join(HERE, "results", "stress_workers.csv")

CHILD = {
    "all_pairs": """
import faulthandler, sys; faulthandler.enable()
sys.path.insert(0, {here!r})
import meshes, warnings, warp_regdist as wrd
mesh = meshes.shared_mesh("cat_rr") or meshes.cube_sphere(18)
warnings.simplefilter("ignore")
res = wrd.all_pairs(mesh, alpha_hat=0.03, dtype="float32", workers=2, max_iterations={iterations})
print("OK", res.iterations, float(res.distance.max()))
""",
    "solve_many": """
import faulthandler, sys; faulthandler.enable()
sys.path.insert(0, {here!r})
import meshes, warnings, warp_regdist as wrd
mesh = meshes.shared_mesh("spot_rr") or meshes.cube_sphere(28)
warnings.simplefilter("ignore")
res = wrd.DistanceSolver(mesh, alpha_hat=0.05, dtype="float32", workers=2).solve_many([[i] for i in range(32)],
                                                                                 max_iterations={iterations})
print("OK", int(res.iterations.max()), float(res.distance.max()))
""",
}


def _busy():
    while True:
        pass


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--iterations", type=int, default=3, help="ADMM iterations per run")
    parser.add_argument("--paths", nargs="+", default=list(CHILD), choices=list(CHILD))
    parser.add_argument("--no-load", action="store_true", help="run without the busy-looping processes")
    args = parser.parse_args()

    # compile or load the kernels once, unloaded, so the stressed runs only load them from the cache
    for path in args.paths:
        subprocess.run([sys.executable, "-c", CHILD[path].format(here=HERE, iterations=1)], capture_output=True)
    load = [] if args.no_load else [multiprocessing.Process(target=_busy, daemon=True)
                                    for _ in range(os.cpu_count() or 1)]
    for p in load:
        p.start()
    rows = []
    try:
        for path in args.paths:
            crashes, seconds = 0, []
            for run in range(args.runs):
                t0 = time.perf_counter()
                out = subprocess.run([sys.executable, "-c", CHILD[path].format(here=HERE, iterations=args.iterations)],
                                     capture_output=True, text=True)
                seconds.append(time.perf_counter() - t0)
                if out.returncode != 0 or "OK" not in out.stdout:
                    crashes += 1
                    print(f"{path} run {run}: exit {out.returncode}\n" + "\n".join(out.stderr.splitlines()[-25:]),
                          file=sys.stderr, flush=True)
                else:
                    print(f"{path} run {run}: ok ({seconds[-1]:.1f} s)", file=sys.stderr, flush=True)
            seconds.sort()
            rows.append(dict(path=path, runs=args.runs, crashes=crashes, busy_processes=len(load),
                             median_seconds=seconds[len(seconds) // 2]))
    finally:
        for p in load:
            p.terminate()
    print(markdown_table(rows))
    write_csv(rows, RESULTS)
    return 1 if any(r["crashes"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
