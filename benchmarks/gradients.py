"""Cost of a backward pass (``DistanceResult.vjp``) against the forward solve it differentiates.

    python benchmarks/gradients.py            # spot_rr, the 100k cube sphere, tet cubes of 4,096 and 17,576 vertices
    python benchmarks/gradients.py --small    # spot_rr only

Per mesh (one source, alpha_hat 0.05, float64, one process), in one process: the forward solve
(``solve``, after a warm-up solve that compiles the kernels) and the vjp of a random loss gradient
and ``polish()`` with each factorization of their Newton systems (``gradient_factorization``
"superlu", and "pardiso" where MKL is installed), median of 5 (1 on the 100k sphere and the 17k
cube). Columns: seconds of each, the backward's and the polish's ratio to the forward, the Newton steps of the smoothed problem, smoothing_change
(max |u_mu - u| / max u), and the largest difference between the two factorizations' position
gradients relative to the largest entry. Prints a markdown table and writes
benchmarks/results/gradients.csv.
"""

import argparse
import importlib.util
import os
import statistics
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import meshes  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402
from warp_regdist.solvers.single_source.gradients import factorization_backend  # noqa: E402


def cube_tets(n):
    """tests/meshes.py's tetrahedral cube (benchmarks/ has its own meshes module)."""
    spec = importlib.util.spec_from_file_location("test_meshes", os.path.join(HERE, "..", "tests", "meshes.py"))
    test_meshes = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(test_meshes)
    return test_meshes.cube_tets(n)

RESULTS = os.path.join(HERE, "results", "gradients.csv")


def cases(small):
    yield "spot_rr", wrd.load_mesh(wrd.data_path("spot_rr.off")), 2272, 5
    if not small:
        yield "sphere_100k", meshes.cube_sphere(129), 0, 1
        yield "tet_cube_15", wrd.Mesh(*cube_tets(15)), 0, 5
        yield "tet_cube_25", wrd.Mesh(*cube_tets(25)), 0, 1


def run(name, mesh, source, repeats, factorizations):
    solver = wrd.DistanceSolver(mesh, 0.05, workers=1)
    solver.solve([source])
    b = np.random.default_rng(0).random(mesh.n_vertices)
    forward, backward, polish, grads = [], {f: [] for f in factorizations}, {f: [] for f in factorizations}, {}
    for _ in range(repeats):
        for f in factorizations:
            res = solver.solve([source], gradient_factorization=f)
            forward.append(res.seconds)
            grads[f] = res.vjp(b)
            backward[f].append(grads[f].seconds)
            polish[f].append(res.polish().seconds - res.seconds)
    fwd = statistics.median(forward)
    g = grads[factorizations[0]]
    row = dict(mesh=name, vertices=mesh.n_vertices, admm_iterations=res.iterations, forward_s=fwd)
    for f in factorizations:
        row[f"backward_{f}_s"] = statistics.median(backward[f])
        row[f"ratio_{f}"] = row[f"backward_{f}_s"] / fwd
        row[f"polish_ratio_{f}"] = statistics.median(polish[f]) / fwd
    row.update(newton_steps=g.newton_iterations, smoothing_change_pct=100.0 * g.smoothing_change)
    if len(factorizations) > 1:
        a, c = (grads[f].vertices for f in factorizations)
        row["gradient_difference"] = float(np.abs(a - c).max() / np.abs(a).max())
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", action="store_true", help="spot_rr only")
    ap.add_argument("--out", default=RESULTS)
    args = ap.parse_args()
    import warp as wp
    wp.config.quiet = True
    rows = []
    factorizations = ("superlu",) + (("pardiso",) if factorization_backend("auto") == "pardiso" else ())
    for name, mesh, source, repeats in cases(args.small):
        print(f"running {name} ...", file=sys.stderr, flush=True)
        rows.append(run(name, mesh, source, repeats, factorizations))
        write_csv(rows, args.out)
    print(markdown_table(rows))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
