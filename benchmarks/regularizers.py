"""ADMM and CG iterations per regularizer on spot, varied vs fixed penalty.

    python benchmarks/regularizers.py            # spot_rr (../shared/meshes), source 2272

Prints a markdown table and writes benchmarks/results/regularizers.csv. Rows:
Dirichlet (alpha_hat 0.05), vector-field alignment (alpha_hat 0.05, beta_hat 10, the line
field through two constrained faces), Hessian (alpha_hat 0.05 and 1e-3). "varied" is the
default schedule rho_k = L min(rho_max, rho0 2^((k - 1) / rho_doubling)), L = sqrt(A), with the
regularizer's factors (docs/method.md section 8; Hessian: rho_max x8); "fixed" keeps
rho = 2 sqrt(A) (the authors' rho_0) for the whole solve. The difference column is against
the same problem solved with the varied schedule at tolerances / 10 (max over vertices, % of
the maximal distance). Times are single solves after one warm-up (noisy on a shared machine).
"""

import os
import sys
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from report import write_csv  # noqa: E402

MAX_ITERATIONS = 3000


def cases(mesh):
    import warp_regdist as wrd

    field = wrd.line_field(mesh, [0, 5000], [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    return [("dirichlet", 0.05, {}),
            ("vector_field", 0.05, dict(regularizer="vector_field", beta_hat=10.0, vector_field=field)),
            ("hessian", 0.05, dict(regularizer="hessian")),
            ("hessian", 1e-3, dict(regularizer="hessian"))]


def main():
    import warp as wp
    wp.config.quiet = True
    import meshes
    import warp_regdist as wrd

    mesh = meshes.shared_mesh("spot_rr")
    if mesh is None:
        print("skipped: ../shared/meshes not found")
        return
    source = 2272
    rows = []
    warnings.simplefilter("ignore", wrd.ConvergenceWarning)
    for name, alpha_hat, kwargs in cases(mesh):
        solver = wrd.DistanceSolver(mesh, alpha_hat=alpha_hat, device="cpu", **kwargs)
        t = solver.options
        tight = solver.solve([source], eps_rel=t.eps_rel / 10, eps_rel_dual=t.eps_rel_dual / 10,
                             max_iterations=3 * MAX_ITERATIONS).distance
        for schedule, override in (("varied", {}), ("fixed", dict(rho0=2.0, rho_doubling=float("inf")))):
            solver.solve([source], max_iterations=MAX_ITERATIONS, **override)
            res = solver.solve([source], max_iterations=MAX_ITERATIONS, **override)
            rows.append(dict(regularizer=name, alpha_hat=alpha_hat, rho=schedule, vertices=mesh.n_vertices,
                             admm_iterations=res.iterations, converged=res.converged, cg_iterations=res.cg_iterations,
                             cg_per_admm=res.cg_iterations / max(res.iterations, 1), seconds=res.seconds,
                             difference_percent=100 * np.abs(res.distance - tight).max() / tight.max()))
            print(rows[-1], flush=True)
    print("\n| regularizer | alpha_hat | rho | ADMM it. | CG it. | CG / ADMM | solve | difference |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        it = f"{r['admm_iterations']}" + ("" if r["converged"] else " (not converged)")
        print(f"| {r['regularizer']} | {r['alpha_hat']:g} | {r['rho']} | {it} | {r['cg_iterations']} | "
              f"{r['cg_per_admm']:.1f} | {r['seconds']:.2f} s | {r['difference_percent']:.3f}% |")
    write_csv(rows, os.path.join(HERE, "results", "regularizers.csv"))


if __name__ == "__main__":
    main()
