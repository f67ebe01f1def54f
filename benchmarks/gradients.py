"""Cost of a backward pass (``DistanceResult.vjp``) against the forward solve it differentiates.

    python benchmarks/gradients.py            # spot_rr (packaged) and the 100k cube sphere
    python benchmarks/gradients.py --small    # spot_rr only

Per mesh (one source, alpha_hat 0.05, float64, one process), in one process: the forward solve
(``solve``, after a warm-up solve that compiles the kernels) and the vjp of a random loss gradient,
median of 3 (1 on the 100k sphere). Columns: seconds of each, their ratio, the Newton steps of the
smoothed problem, and smoothing_change (max |u_mu - u| / max u). Prints a markdown table and
writes benchmarks/results/gradients.csv.
"""

import argparse
import os
import statistics
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import meshes  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402

RESULTS = os.path.join(HERE, "results", "gradients.csv")


def cases(small):
    yield "spot_rr", wrd.load_mesh(wrd.data_path("spot_rr.off")), 2272, 3
    if not small:
        yield "sphere_100k", meshes.cube_sphere(129), 0, 1


def run(name, mesh, source, repeats):
    solver = wrd.DistanceSolver(mesh, 0.05, workers=1)
    solver.solve([source])
    b = np.random.default_rng(0).random(mesh.n_vertices)
    forward, backward = [], []
    for _ in range(repeats):
        res = solver.solve([source])
        g = res.vjp(b)
        forward.append(res.seconds)
        backward.append(g.seconds)
    f, s = statistics.median(forward), statistics.median(backward)
    return dict(mesh=name, vertices=mesh.n_vertices, admm_iterations=res.iterations, forward_s=f, backward_s=s,
                ratio=s / f, newton_steps=g.newton_iterations, smoothing_change_pct=100.0 * g.smoothing_change)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", action="store_true", help="spot_rr only")
    ap.add_argument("--out", default=RESULTS)
    args = ap.parse_args()
    import warp as wp
    wp.config.quiet = True
    rows = []
    for name, mesh, source, repeats in cases(args.small):
        print(f"running {name} ...", file=sys.stderr, flush=True)
        rows.append(run(name, mesh, source, repeats))
        write_csv(rows, args.out)
    print(markdown_table(rows))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
