"""All-pairs benchmark (issue 4): Algorithm 2 on cat_rr beside n symmetrized single-source solves.

    python benchmarks/all_pairs.py                         # cat_rr, float32 and float64, baseline
    python benchmarks/all_pairs.py --dtypes float32 --no-baseline
    python benchmarks/all_pairs.py --reference-scale 0.2   # also a run at every tolerance x 0.2 (slow)
    python benchmarks/all_pairs.py --dtypes float32 --no-baseline --workers 1 0   # 1 process vs all cores
    python benchmarks/all_pairs.py --dtypes float32 --accuracies 0.02 0.01 0.005 --no-baseline
    python benchmarks/all_pairs.py --accuracy --cache /tmp/stopping   # accuracy= against exact minimizers
    python benchmarks/all_pairs.py --larger --cache /tmp/stopping     # 300-500 vertices against long runs
    python benchmarks/all_pairs.py --larger --cache /tmp/stopping --triangulations mesh intrinsic
    python benchmarks/all_pairs.py --engines --cache /tmp/stopping    # eigenbasis against consensus engine
    python benchmarks/all_pairs.py --engines --cache /tmp/stopping --decimate 1000
    python benchmarks/all_pairs.py --engines --cache /tmp/stopping --decimate 600 --mesh bunny.obj --alpha-hat 0.1
    python benchmarks/all_pairs.py --engines --cache /tmp/stopping --decimate 302 --mesh spot_rr_holes --exact

For each precision: ``wrd.all_pairs`` at default settings (time, ADMM and CG iterations,
the seven final residuals and their tolerances, estimated memory, bytes per n^2, peak
RSS of the process, symmetry error and sampled triangle-inequality violations); then, in
the same process, ``wrd.distance_matrix`` over all n vertices (batched single-source solves,
symmetrized) at alpha_hat and at 2 alpha_hat (the single-source weight whose rows are
closest to the all-pairs rows), with its distance to the all-pairs matrix. With
``--reference-scale S`` a float64 run at accuracy 0.005 S (every tolerance of the default
accuracy scaled by S: a tighter solve of the same problem, at most 5,000 iterations) is the
reference, and each run's max deviation from it is reported in % of the maximal distance. The
kernel cache is warmed on a small mesh first, so no time includes compilation. Writes benchmarks/results/all_pairs.csv.

With ``--accuracy``: ``AllPairsSolver.solve(accuracy=e)`` for e in 0.02, 0.01, 0.005, 0.002 on the
irregular meshes whose exact minimizers are known (the two in tests/data, and those of
benchmarks/stopping.py's all-pairs sets found in ``--cache``, ``--pairs --larger``, each on its reference's
triangulation), both engines: iterations, time, time per iteration, error, the result's error_estimate and
gradient_excess in % of the max distance, one process. Writes
benchmarks/results/all_pairs_accuracy.csv.

With ``--larger``: the same at 0.01 and 0.005 on decimations of the shared meshes to 300-500 vertices
(``LARGER``; their exact minimizers only with ``--exact``, below), against a long run of the same problem
(:func:`long_run_reference`, cached in ``--cache``), and
beside each run the same solve without the steepness test (``eps_excess=inf``, columns
``unchecked_*``). With ``--triangulations mesh intrinsic`` each decimation is solved on both operators
(the mesh's own and the intrinsic Delaunay ones), each against its own reference. Writes
benchmarks/results/all_pairs_larger.csv.

With ``--engines``: both engines (``AllPairsOptions.engine``) at accuracy 0.01 and 0.005, one process, on
the exact cases of tests/data (the mesh's operators) and on ``LARGER`` (intrinsic operators, against
the long runs in ``--cache``); then each engine's setup and time per iteration (``ENGINE_COST_ITERATIONS``
iterations, float32 and float64) on cat_rr decimated to 1,000 vertices and on cat_rr itself, the sizes
that ``AllPairsOptions.eigenbasis_max_vertices`` is chosen among. Writes benchmarks/results/all_pairs_engines.csv. With
``--decimate N`` only the runs on cat_rr (or ``--mesh NAME``, a shared mesh or a mesh file) decimated to about
N vertices (at ``--alpha-hat``), against its own 5,000-iteration reference, into
benchmarks/results/all_pairs_engines_N.csv (all_pairs_engines_NAME_N.csv for another mesh,
all_pairs_engines_NAME_ALPHA_N.csv at another alpha_hat than 0.03). With ``--exact`` as well, against the exact
minimizer (Clarabel, intrinsic operators; about 15 minutes and 3 GB at 304 vertices, cached in ``--cache``), with
the 5,000-iteration run's own error as one more row, into ..._N_exact.csv.
"""

import argparse
import math
import os
import resource
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import meshes  # noqa: E402
import warp as wp  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from warp_regdist.solvers.common.results import RESIDUAL_NAMES  # noqa: E402
from report import write_csv  # noqa: E402
from warp_regdist.metrics import symmetry_error, triangle_inequality_violations  # noqa: E402

RESULTS = os.path.join(HERE, "results", "all_pairs.csv")
ACCURACY_RESULTS = os.path.join(HERE, "results", "all_pairs_accuracy.csv")
LARGER_RESULTS = os.path.join(HERE, "results", "all_pairs_larger.csv")
ACCURACIES = (0.02, 0.01, 0.005, 0.002)
LARGER = (("cat_rr", 500, 0.03), ("spot_rr_holes", 302, 0.03), ("spot_rr", 400, 0.03), ("bent_pipe_closed_lr", 350, 0.03),
          ("cat_rr", 350, 0.1))
LARGER_ACCURACIES = (0.01, 0.005)
ENGINES_RESULTS = os.path.join(HERE, "results", "all_pairs_engines.csv")
ENGINE_COST_ITERATIONS = 30
REFERENCE_ITERATIONS = 5000


def peak_rss_gb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def quality(D, area):
    return dict(symmetry_max=float(symmetry_error(D, area).max()),
                violations=float(triangle_inequality_violations(D, samples=2_000_000, seed=0)))


def exact_cases(cache):
    """(name, mesh, alpha_hat, exact minimizer, triangulation): the stored references (tests/data, on the
    mesh's own triangles) and the cached ones (benchmarks/stopping.py, on the intrinsic Delaunay operators)."""
    tests = os.path.join(HERE, "..", "tests", "data")
    cases = []
    for file, name in (("all_pairs_bumpy42.npz", "bumpy icosphere"), ("stopping_cat80.npz", "cat_rr decimated")):
        d = np.load(os.path.join(tests, file))
        mesh = wrd.Mesh(d["vertices"], d["faces"].astype(np.int64))
        cases += [(name, mesh, 0.03, d["U_003"], "mesh"), (name, mesh, 0.1, d["U_01"], "mesh")]
    if cache is not None:
        import stopping

        for alpha_hat in (0.03, 0.1):
            for name, mesh in stopping.pairs_set() + stopping.larger_pairs_set():
                exact = stopping.cached(cache, f"pairs {name} {mesh.n_vertices} {alpha_hat}", None)
                if exact is not None:
                    cases.append((name, mesh, alpha_hat, exact, "intrinsic"))
    return cases


def long_run_reference(cache, name, mesh, alpha_hat, triangulation):
    """U on ``mesh`` of the eigenbasis engine in float64 at accuracy 0.0005, at most REFERENCE_ITERATIONS
    iterations (the runs' own problem, source triangles included), computed once into ``cache``."""
    import stopping

    def long_run():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", wrd.ConvergenceWarning)
            return wrd.AllPairsSolver(mesh, alpha_hat, triangulation=triangulation,
                                      options=wrd.AllPairsOptions(engine="eigenbasis")).solve(
                accuracy=0.0005, max_iterations=REFERENCE_ITERATIONS).distance

    key = f"eigenbasis 0.0005 {REFERENCE_ITERATIONS} {name} decimated {mesh.n_vertices} {alpha_hat} {triangulation}"
    return stopping.cached(cache, key, long_run)


def exact_reference(cache, name, mesh, alpha_hat):
    """The exact minimizer on ``mesh``'s intrinsic operators (Clarabel; minutes to an hour at 300-500
    vertices), computed once into ``cache``."""
    import all_pairs_reference as apr
    import reference_solver as rs
    import stopping

    V, F = mesh.vertices, mesh.elements
    alpha = alpha_hat * np.sqrt(rs.face_geometry(V, F)[0].sum())
    return stopping.cached(cache, f"pairs {name} decimated {mesh.n_vertices} {alpha_hat}",
                           lambda: stopping.exact_pairs(apr, V, F, alpha))


def parse_cases(strings):
    """(path, vertices, alpha_hat) of each 'mesh vertices alpha_hat' in ``strings``; ``LARGER`` for None."""
    if strings is None:
        return LARGER
    return [(c.split()[0], int(c.split()[1]), float(c.split()[2])) for c in strings]


def larger_cases(cache, triangulation="mesh", cases=LARGER, exact=False):
    """Yield (name, mesh, alpha_hat, reference, triangulation) of ``cases`` (default ``LARGER``), each
    reference (the long run's, or with ``exact`` the exact minimizer on the intrinsic operators) computed once
    into ``cache``."""
    import stopping

    for path, vertices, alpha_hat in cases:
        mesh = stopping.decimated(path, vertices)
        name = os.path.splitext(os.path.basename(path))[0]
        reference = (exact_reference(cache, name, mesh, alpha_hat) if exact
                     else long_run_reference(cache, name, mesh, alpha_hat, triangulation))
        yield f"{name} decimated", mesh, alpha_hat, reference, triangulation


def _run_columns(res, reference, prefix=""):
    return {f"{prefix}iterations": res.iterations, f"{prefix}converged": res.converged,
            f"{prefix}error_pct": round(100 * float(np.abs(res.distance - reference).max() / reference.max()), 3),
            f"{prefix}estimate_pct": round(100 * res.error_estimate, 3),
            f"{prefix}excess_pct": round(100 * res.gradient_excess, 3)}


def accuracy_rows(cases, accuracies, baseline=False, engines=("consensus",)):
    """One row per case (name, mesh, alpha_hat, reference, triangulation), engine and accuracy; with ``baseline``
    also the run with ``eps_excess=inf``."""
    rows = []
    for (name, mesh, alpha_hat, reference, triangulation), engine in ((c, e) for c in cases for e in engines):
        solver = wrd.AllPairsSolver(mesh, alpha_hat, device="cpu", workers=1, triangulation=triangulation,
                                    options=wrd.AllPairsOptions(engine=engine))
        for accuracy in accuracies:
            res = solver.solve(accuracy=accuracy)
            row = dict(mesh=name, n=mesh.n_vertices, alpha_hat=alpha_hat, method="all_pairs", engine=engine,
                       accuracy=accuracy, triangulation=triangulation,
                       **_run_columns(res, reference), seconds=round(res.seconds, 3),
                       ms_per_iteration=round(1e3 * res.seconds / res.iterations, 3), peak_rss_gb=round(peak_rss_gb(), 2))
            if baseline:
                row.update(_run_columns(solver.solve(accuracy=accuracy, eps_excess=math.inf), reference, "unchecked_"))
            rows.append(row)
            print(row, flush=True)
    return rows


def long_run_row(cache, name, mesh, alpha_hat, exact):
    """The 5,000-iteration reference's max error against the exact minimizer, as an engine's row."""
    reference = long_run_reference(cache, name.removesuffix(" decimated"), mesh, alpha_hat, "intrinsic")
    row = dict(mesh=name, n=mesh.n_vertices, alpha_hat=alpha_hat, method="all_pairs",
               engine=f"symmetric splitting, {REFERENCE_ITERATIONS:,} it.", triangulation="intrinsic",
               iterations=REFERENCE_ITERATIONS,
               error_pct=round(100 * float(np.abs(reference - exact).max() / exact.max()), 3))
    print(row, flush=True)
    return row


def engine_cost_rows():
    """Setup seconds and ms per iteration of both engines on cat_rr decimated to 1,000 vertices and on cat_rr."""
    import stopping

    rows = []
    for name, mesh in (("cat_rr decimated", stopping.decimated("cat_rr", 1000)), ("cat_rr", meshes.shared_mesh("cat_rr"))):
        for dtype, engine in ((d, e) for d in ("float32", "float64") for e in ("eigenbasis", "consensus")):
            t0 = time.perf_counter()
            solver = wrd.AllPairsSolver(mesh, 0.03, device="cpu", dtype=dtype, options=wrd.AllPairsOptions(engine=engine))
            getattr(solver, "u_step" if engine == "eigenbasis" else "hierarchy")
            setup = time.perf_counter() - t0
            res = solver.solve(max_iterations=ENGINE_COST_ITERATIONS)
            rows.append(dict(mesh=name, n=mesh.n_vertices, dtype=dtype, engine=engine, workers=len(os.sched_getaffinity(0)),
                             setup_seconds=round(setup, 2),
                             ms_per_iteration=round(1e3 * res.seconds / res.iterations, 1)))
            print(rows[-1], flush=True)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mesh", default="cat_rr",
                        help="a shared mesh's name or a mesh file (with --decimate: the one decimated)")
    parser.add_argument("--alpha-hat", type=float, default=0.03)
    parser.add_argument("--dtypes", nargs="+", default=["float32", "float64"])
    parser.add_argument("--no-baseline", action="store_true")
    parser.add_argument("--reference-scale", type=float, default=None)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--workers", type=int, nargs="+", default=[0],
                        help="CPU processes of each all_pairs run (0: all cores; several values: one run each)")
    parser.add_argument("--accuracies", type=float, nargs="+", default=[None],
                        help="all_pairs(accuracy=) of the runs (default: the tolerances' settings)")
    parser.add_argument("--accuracy", action="store_true", help="accuracy= against exact minimizers of small meshes")
    parser.add_argument("--cache", default=None, help="with --accuracy: benchmarks/stopping.py's cache of minimizers")
    parser.add_argument("--larger", action="store_true", help="accuracy= on LARGER against long symmetric runs")
    parser.add_argument("--engines", action="store_true", help="both engines on the exact cases and LARGER, and their costs")
    parser.add_argument("--decimate", type=int, default=None, metavar="N",
                        help="with --engines: only --mesh decimated to about N vertices (its own reference; "
                        "at --alpha-hat; all_pairs_engines[_NAME][_ALPHA]_N.csv)")
    parser.add_argument("--exact", action="store_true",
                        help="with --decimate: against the exact minimizer (Clarabel, cached in --cache) and the "
                        "5,000-iteration run as a row of its own (all_pairs_engines[_NAME][_ALPHA]_N_exact.csv)")
    parser.add_argument("--triangulations", nargs="+", default=["mesh"], choices=["mesh", "intrinsic"],
                        help="with --larger: the operators' triangulations (one reference and one set of runs each)")
    args = parser.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    warnings.simplefilter("ignore", wrd.ConvergenceWarning)
    if (args.larger or args.engines) and args.cache is None:
        parser.error("--larger and --engines need --cache, the folder of their references")
    if args.engines:
        sys.path.append(os.path.join(HERE, "..", "tests"))
        engines = ("eigenbasis", "consensus")
        if args.decimate:
            name = os.path.splitext(os.path.basename(args.mesh))[0]
            tag = ("" if name == "cat_rr" else f"_{name}") + ("" if args.alpha_hat == 0.03 else f"_{args.alpha_hat:g}")
            output = ENGINES_RESULTS.replace(".csv", f"{tag}_{args.decimate}.csv")
            output = output.replace(".csv", "_exact.csv") if args.exact else output
            case = ((args.mesh, args.decimate, args.alpha_hat),)
            cases = list(larger_cases(args.cache, "intrinsic", case, exact=args.exact))
            rows = accuracy_rows(cases, LARGER_ACCURACIES, engines=engines)
            if args.exact:
                rows.append(long_run_row(args.cache, *cases[0][:4]))
        else:
            output = ENGINES_RESULTS
            rows = accuracy_rows(exact_cases(None), LARGER_ACCURACIES, engines=engines)
            rows += accuracy_rows(larger_cases(args.cache, "intrinsic"), LARGER_ACCURACIES, engines=engines)
            rows += engine_cost_rows()
        write_csv(rows, output)
        print(f"wrote {output}")
        return 0
    if args.accuracy or args.larger:
        sys.path.append(os.path.join(HERE, "..", "tests"))  # stopping.py's references (after benchmarks/)
        if args.accuracy:
            write_csv(accuracy_rows(exact_cases(args.cache), ACCURACIES, engines=("eigenbasis", "consensus")),
                      ACCURACY_RESULTS)
            print(f"wrote {ACCURACY_RESULTS}")
        if args.larger:
            rows = [row for t in args.triangulations
                    for row in accuracy_rows(larger_cases(args.cache, t), LARGER_ACCURACIES, baseline=True)]
            write_csv(rows, LARGER_RESULTS)
            print(f"wrote {LARGER_RESULTS}")
        return 0
    mesh = meshes.shared_mesh(args.mesh)
    if mesh is None:
        sys.exit(f"expected ../shared/meshes/{args.mesh}.off beside the checkout, got none")
    area = wrd.build_operators(mesh).total_volume
    n = mesh.n_vertices
    small = meshes.cube_sphere(3)
    rows = []
    results = {}
    for dtype in args.dtypes:  # warm the kernel cache (all_pairs and the single-source solver)
        wrd.all_pairs(small, args.alpha_hat, device=args.device, dtype=dtype, max_iterations=2)
        wrd.distance_matrix(small, args.alpha_hat, sources=[0], device=args.device, dtype=dtype)
    for dtype, workers, accuracy in ((d, w, a) for d in args.dtypes for w in args.workers for a in args.accuracies):
        res = wrd.all_pairs(mesh, args.alpha_hat, device=args.device, dtype=dtype, workers=workers or None,
                            accuracy=accuracy)
        results[len(rows)] = res.distance
        row = dict(method="all_pairs" if accuracy is None else f"all_pairs (accuracy {accuracy:g})", dtype=dtype, n=n,
                   alpha_hat=args.alpha_hat, estimate_pct=round(100 * res.error_estimate, 3),
                   workers=workers or len(os.sched_getaffinity(0)), seconds=round(res.seconds, 2),
                   iterations=res.iterations, cg_iterations=res.cg_iterations, converged=res.converged,
                   memory_gb=round(res.memory_bytes / 1e9, 3), bytes_per_n2=round(res.memory_bytes / n**2, 1),
                   peak_rss_gb=round(peak_rss_gb(), 2), **quality(res.distance, area))
        row.update({f"{k}/eps": round(float(r / t), 3) for k, r, t in zip(RESIDUAL_NAMES, res.residuals, res.tolerance)})
        rows.append(row)
        print(row, flush=True)
    if args.reference_scale:
        ref = wrd.all_pairs(mesh, args.alpha_hat, device=args.device, dtype="float64", max_iterations=5000,
                            accuracy=0.005 * args.reference_scale)
        print(f"reference (tolerances x {args.reference_scale}): {ref.iterations} iterations, {ref.seconds:.1f} s, "
              f"converged {ref.converged}", flush=True)
        for i, row in enumerate(rows):
            row["error_vs_tight_pct"] = round(100 * float(np.abs(results[i] - ref.distance).max()
                                                    / ref.distance.max()), 3)
            row.update(reference_iterations=ref.iterations, reference_converged=ref.converged)
    if not args.no_baseline:
        U = results[0]
        for scale in (1.0, 2.0):
            t0 = time.perf_counter()
            D = wrd.distance_matrix(mesh, scale * args.alpha_hat, symmetrize=True, device=args.device,
                                    dtype=args.dtypes[0])
            row = dict(method=f"distance_matrix (alpha_hat x {scale:g}, symmetrized)", dtype=args.dtypes[0], n=n,
                       alpha_hat=args.alpha_hat * scale, seconds=round(time.perf_counter() - t0, 2),
                       peak_rss_gb=round(peak_rss_gb(), 2), **quality(D, area),
                       max_diff_vs_all_pairs_pct=round(100 * float(np.abs(D - U).max() / U.max()), 3))
            rows.append(row)
            print(row, flush=True)
    write_csv(rows, RESULTS)
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    sys.exit(main())
