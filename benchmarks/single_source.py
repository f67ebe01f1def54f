"""Single-source benchmark: this package vs the same ADMM with a direct factorization (scipy).

    python benchmarks/single_source.py                # spot, pipe, 100k sphere, 64-source batch
    python benchmarks/single_source.py --large        # also the 655k icosphere and the 1M-vertex sphere
    python benchmarks/single_source.py --quick        # spot and pipe only, 8-source batch
    python benchmarks/single_source.py --batch        # only the 64-source batch (results/batch.csv)

Prints a markdown table and writes benchmarks/results/single_source.csv. Each case runs in
its own process (so peak memory is its own); solve times are medians over repeats after
one warm-up solve (kernel cache warm). The error columns, up to 20,000 vertices, are against the
exact minimizer (cvxpy + Clarabel, the ``compare`` extra, else none; cached in results/stopping_cache) of the
problem each solves: the package's (its defaults) and the paper's (the baseline's). With potpourri3d
installed (the ``compare`` extra) the heat method's setup and solve times are measured in the
same process, after the peak memory, on the cases with a baseline (its factorization takes
minutes on the largest).
"""

import argparse
import importlib.util
import os
import resource
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from report import cached, markdown_table, print_result, run_child, write_csv  # noqa: E402

CACHE = os.path.join(HERE, "results", "stopping_cache")  # the exact minimizers, shared with stopping.py
EXACT_MAX_VERTICES = 20000

CASES = {  # name: (mesh, source, alpha_hat, repeats)
    "spot_rr": ("spot_rr", 2272, 0.05, 5),
    "bent_pipe_closed_lr": ("bent_pipe_closed_lr", 4882, 0.05, 5),
    "sphere_100k": ("cube_sphere:129", 0, 0.05, 2),
    "icosphere_655k": ("icosphere:8", 0, 0.05, 1),
    "sphere_1M": ("cube_sphere:408", 0, 0.05, 1),
}


def load(spec):
    import meshes
    if spec.startswith("cube_sphere:"):
        return meshes.cube_sphere(int(spec.split(":")[1]))
    if spec.startswith("icosphere:"):
        import trimesh
        import warp_regdist as wrd
        s = trimesh.creation.icosphere(subdivisions=int(spec.split(":")[1]))
        return wrd.Mesh(np.asarray(s.vertices), np.asarray(s.faces))
    return meshes.shared_mesh(spec)


def run_case(name, baseline=True):
    """One case in this process -> dict of measurements."""
    import warp as wp
    wp.config.quiet = True
    import warp_regdist as wrd
    import scipy_admm

    spec, source, alpha_hat, repeats = CASES[name]
    mesh = load(spec)
    if mesh is None:
        return {"case": name, "skipped": "../shared/meshes not found"}
    t = time.perf_counter()
    solver = wrd.DistanceSolver(mesh, alpha_hat=alpha_hat, device="cpu")
    setup = time.perf_counter() - t
    results = [solver.solve([source]) for _ in range(repeats + 1)][1:]
    res = results[-1]
    row = {"case": name, "vertices": mesh.n_vertices, "faces": mesh.n_elements, "alpha_hat": alpha_hat,
           "setup_s": setup, "solve_s": float(np.median([r.seconds for r in results])),
           "admm_iterations": int(res.iterations), "cg_iterations": int(res.cg_iterations),
           "primal_residual": float(res.primal_residual), "dual_residual": float(res.dual_residual),
           "converged": bool(res.converged)}
    if baseline:
        base = scipy_admm.solve_admm(mesh.vertices, mesh.elements, [source], alpha_hat)
        authors = scipy_admm.solve_admm(mesh.vertices, mesh.elements, [source], alpha_hat, rule=scipy_admm.AUTHORS_RULE)
        row.update(baseline_s=base["seconds"], baseline_iterations=int(base["iterations"]),
                   authors_rule_iterations=int(authors["iterations"]))
    if mesh.n_vertices <= EXACT_MAX_VERTICES and importlib.util.find_spec("cvxpy") is not None:
        exact, paper = exact_minimizers(name, solver, source, alpha_hat)
        row["max_error_pct"] = float(100 * np.abs(res.distance - exact).max() / exact.max())
        if baseline:
            row["authors_rule_error_pct"] = float(100 * np.abs(authors["u"] - paper).max() / paper.max())
    row["peak_rss_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20   # before the heat method's
    heat = _heat_method(mesh, source, repeats) if baseline else None
    if heat is not None:
        row.update(heat_setup_s=heat[0], heat_solve_s=heat[1])
    return row


def exact_minimizers(name, solver, source, alpha_hat):
    """The exact minimizers (cvxpy + Clarabel, tests/reference_solver.py, cached in CACHE) of the problem the
    package solves (its intrinsic triangulation of the mesh with the obtuse angles refined, the side-length
    bound on the source's triangles) and of the paper's problem that the baseline solves (the mesh's own
    triangles, |grad u| <= 1 on every triangle), both (n,) on the mesh's vertices."""
    sys.path.append(os.path.join(HERE, "..", "tests"))  # after benchmarks/: both have a meshes.py
    import reference_solver as rs

    mesh, on = solver.mesh, solver.solve_mesh
    alpha = alpha_hat * np.sqrt(rs.face_geometry(mesh.vertices, mesh.elements)[0].sum())
    exact = cached(CACHE, f"single {name} {on.n_vertices} {source} {alpha_hat}",
                   lambda: rs.solve_reference(on.vertices, on.elements, [source], alpha))
    paper = cached(CACHE, f"paper {name} {mesh.n_vertices} {source} {alpha_hat}",
                   lambda: rs.solve_reference(mesh.vertices, mesh.elements, [source], alpha, triangulation="mesh",
                                              source_triangles="gradient"))
    return exact[:mesh.n_vertices], paper


def _heat_method(mesh, source, repeats):
    """(setup s, median solve s) of potpourri3d's heat method (t_coef 1) on a triangle mesh, or None
    without potpourri3d (the ``compare`` extra) or on tetrahedra."""
    try:
        import potpourri3d as pp3d
    except ImportError:
        return None
    if mesh.element_dim != 2:
        return None
    t = time.perf_counter()
    solver = pp3d.MeshHeatMethodDistanceSolver(mesh.vertices, mesh.elements)
    setup = time.perf_counter() - t
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        solver.compute_distance(source)
        times.append(time.perf_counter() - t)
    return setup, float(np.median(times))


def run_batch(k):
    """k random sources on spot: one batched solve_many (one process, then one per core) vs k single solves."""
    import warp as wp
    wp.config.quiet = True
    import warp_regdist as wrd
    mesh = load("spot_rr")
    if mesh is None:
        return {"case": f"batch_{k}", "skipped": "../shared/meshes not found"}
    sources = np.random.default_rng(0).choice(mesh.n_vertices, k, replace=False)
    sets = [[s] for s in sources]
    solver = wrd.DistanceSolver(mesh, alpha_hat=0.05, device="cpu", workers=1)
    parallel_solver = wrd.DistanceSolver(mesh, alpha_hat=0.05, device="cpu")
    solver.solve_many(sets)  # warm-up: load this batch width's kernels
    solver.solve([sources[0]])
    batch = solver.solve_many(sets)
    solver.solve_many(sets, cpu_blocks=len(sets))   # A/B: every lane block at once
    all_blocks = solver.solve_many(sets, cpu_blocks=len(sets))
    first = parallel_solver.solve_many(sets)  # includes starting the worker processes
    parallel = parallel_solver.solve_many(sets)
    parallel_solver.close()
    singles = [solver.solve([s]) for s in sources]
    single_s = sum(r.seconds for r in singles)
    diff = max(np.abs(batch.distance[:, j] - singles[j].distance).max() for j in range(k)) / batch.distance.max()
    return {"case": f"batch_{k}", "vertices": mesh.n_vertices, "faces": mesh.n_elements, "sources": k,
            "batched_1_process_s": batch.seconds, "all_blocks_at_once_s": all_blocks.seconds,
            "processes": parallel_solver.workers,
            "batched_processes_s": parallel.seconds, "batched_processes_with_start_s": first.seconds,
            "singles_s": single_s, "speedup_1_process": single_s / batch.seconds,
            "speedup_processes": single_s / parallel.seconds,
            "processes_identical": bool(np.array_equal(batch.distance, parallel.distance)),
            "batched_admm_iterations_max": int(batch.iterations.max()), "batched_cg_iterations": batch.cg_iterations,
            "max_batch_vs_single_pct": 100 * diff}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true", help="include the 1M-vertex sphere")
    ap.add_argument("--quick", action="store_true", help="spot and pipe only, 8-source batch")
    ap.add_argument("--batch", action="store_true", help="only the 64-source batch, to results/batch.csv")
    ap.add_argument("--case", help=argparse.SUPPRESS)
    ap.add_argument("--out", default=os.path.join(HERE, "results"))
    args = ap.parse_args()
    if args.case:  # child process
        row = run_batch(int(args.case.split("_")[1])) if args.case.startswith("batch_") else \
            run_case(args.case, baseline=args.case not in ("sphere_1M", "icosphere_655k"))
        print_result(row)
        return
    names = ["spot_rr", "bent_pipe_closed_lr"]
    if not args.quick:
        names.append("sphere_100k")
    if args.large:
        names += ["icosphere_655k", "sphere_1M"]
    names.append("batch_8" if args.quick else "batch_64")
    if args.batch:
        names = ["batch_64"]
    rows = []
    for name in names:
        print(f"running {name} ...", file=sys.stderr, flush=True)
        row = run_child(__file__, name)
        if row is not None:
            rows.append(row)
    path = os.path.join(args.out, "batch.csv" if args.batch else "single_source.csv")
    write_csv(rows, path)
    for group in ([r for r in rows if not r["case"].startswith("batch")], [r for r in rows if r["case"].startswith("batch")]):
        if group:
            print(markdown_table(group) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
