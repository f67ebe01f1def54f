"""Volumetric benchmark: distance to the boundary of a tetrahedralized cube, 1e4 to 1e6 tets.

    python benchmarks/volumetric.py                 # 1e4, 1e5, 1e6 tets
    python benchmarks/volumetric.py --sizes 12 26   # grid sizes n (6 n^3 tets) to run
    python benchmarks/volumetric.py --profile 26    # where the solve's time goes, per call site

The mesh is the unit cube cut into n^3 cells of 6 Kuhn tetrahedra (tests/meshes.py
`cube_tets`); the source set is every boundary vertex, alpha_hat 0.05 (alpha = alpha_hat
V^(1/3)), float64 on the CPU, default tolerances. Each size runs in its own process, so
its peak resident memory (ru_maxrss, which counts Warp's CPU arrays, unlike tracemalloc)
is its own. Before the timed work, a solve on a small cube loads the kernels (compiled
once per machine into Warp's kernel cache). Setup = DistanceSolver(...) (operators,
multigrid hierarchy, Warp arrays); solve = one solve() from zero. The exponent is the
least-squares slope of log(time) against log(tets) over the sizes run. Prints a markdown
table and writes benchmarks/results/volumetric.csv.
"""

import argparse
import os
import resource
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))  # meshes.cube_tets
sys.path.append(HERE)  # report (after tests/: benchmarks/ has its own meshes.py)

from report import markdown_table, print_result, run_child, write_csv  # noqa: E402

SIZES = (12, 26, 55)  # 10,368 / 105,456 / 998,250 tets
ALPHA_HAT = 0.05


def _solver_on_cube(n):
    import warp as wp
    wp.config.quiet = True
    import meshes
    import warp_regdist as wrd

    wrd.DistanceSolver(wrd.Mesh(*meshes.cube_tets(3)), alpha_hat=ALPHA_HAT, device="cpu").solve([0])  # load kernels
    V, T = meshes.cube_tets(n)
    mesh = wrd.Mesh(V, T)
    sources = wrd.boundary_vertices(mesh)
    t = time.perf_counter()
    solver = wrd.DistanceSolver(mesh, alpha_hat=ALPHA_HAT, device="cpu")
    return mesh, sources, solver, time.perf_counter() - t


def run_case(n):
    """One grid size in this process -> dict of measurements."""
    mesh, sources, solver, setup = _solver_on_cube(n)
    res = solver.solve(sources)
    return {"n": n, "tets": mesh.n_elements, "vertices": mesh.n_vertices, "boundary_vertices": int(sources.size),
            "alpha_hat": ALPHA_HAT, "setup_s": setup, "solve_s": res.seconds,
            "admm_iterations": int(res.iterations), "cg_iterations": int(res.cg_iterations),
            "cg_per_admm": res.cg_iterations / max(int(res.iterations), 1),
            "solve_ms_per_admm_iteration": 1e3 * res.seconds / max(int(res.iterations), 1),
            "primal_residual": float(res.primal_residual), "dual_residual": float(res.dual_residual),
            "converged": bool(res.converged), "max_distance": float(res.distance.max()),
            "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}


def profile_case(n):
    """cProfile of one solve: the time per call site (kernel launches, PCG, host work)."""
    import cProfile
    import pstats

    _, sources, solver, _ = _solver_on_cube(n)
    prof = cProfile.Profile()
    prof.enable()
    res = solver.solve(sources)
    prof.disable()
    print(f"n = {n}: {res.iterations} ADMM iterations, {res.cg_iterations} CG iterations, {res.seconds:.2f} s")
    pstats.Stats(prof).sort_stats("tottime").print_stats(15)


def _exponent(rows, key):
    x = np.log([r["tets"] for r in rows])
    y = np.log([r[key] for r in rows])
    return float(np.polyfit(x, y, 1)[0]) if len(rows) >= 2 else float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=list(SIZES), help="grid sizes n (6 n^3 tets)")
    ap.add_argument("--profile", type=int, metavar="N", help="profile one solve at grid size N and exit")
    ap.add_argument("--case", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--out", default=os.path.join(HERE, "results"))
    args = ap.parse_args()
    if args.profile:
        profile_case(args.profile)
        return
    if args.case:  # child process
        print_result(run_case(args.case))
        return
    rows = []
    for n in args.sizes:
        print(f"running n = {n} ({6 * n ** 3} tets) ...", file=sys.stderr, flush=True)
        row = run_child(__file__, n)
        if row is not None:
            rows.append(row)
    if not rows:
        return
    path = os.path.join(args.out, "volumetric.csv")
    write_csv(rows, path)
    print(markdown_table(rows))
    print()
    print("fitted exponent of time vs tets (time ~ tets^p): "
          f"setup p = {_exponent(rows, 'setup_s'):.2f}, solve p = {_exponent(rows, 'solve_s'):.2f}, "
          f"per ADMM iteration p = {_exponent(rows, 'solve_ms_per_admm_iteration'):.2f}")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
