"""Error at stop of the default stopping rules against exact minimizers on irregular meshes (issue 13).

    python benchmarks/stopping.py                 # single sources and all pairs
    python benchmarks/stopping.py --single        # single sources only (minutes)
    python benchmarks/stopping.py --pairs --cache /tmp/stopping   # all pairs (Clarabel: minutes per case)
    python benchmarks/stopping.py --pairs --larger --alpha-hats 0.03 --cache /tmp/stopping   # and 250 vertices

Measurement set: quadric-decimated cat_rr, spot_rr and spot_rr_holes (fast-simplification,
the decimator trimesh's ``simplify_quadric_decimation`` uses: obtuse and sliver triangles,
a boundary for the holes), a bumpy icosphere (vertices moved along their normals by up to
0.15 of the radius), an ellipsoid 1 x 1 x 2.5 (half of its triangles obtuse); single
sources also on the full spot_rr, bent_pipe_closed_lr and cat_rr, and on a tetrahedral
ball and cube (a vertex and the boundary as sources). The exact minimizer of
each discrete problem (all pairs also on decimations to 60-80 vertices) is solved by cvxpy + Clarabel (tests/reference_solver.py,
tests/all_pairs_reference.py) and cached in --cache. Each case runs at the package's
defaults and, in the same process, at the previous defaults (``PREVIOUS``), one thread.
Single sources also on spot_rr decimated to 955 vertices (three sources, alpha_hat 0.01-0.2), and
each single-source result polished (``DistanceResult.polish``): its error and how far it moved.
Error: max over vertices (pairs) of |u - u_exact| in % of max u_exact. Writes
benchmarks/results/stopping.csv and prints a table.
"""

import argparse
import functools
import importlib.util
import math
import os
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
TESTS = os.path.join(HERE, "..", "tests")
sys.path.insert(0, HERE)
sys.path.append(TESTS)  # reference_solver, all_pairs_reference (after benchmarks/: both have a meshes.py)

import meshes  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import cached, markdown_table, write_csv  # noqa: E402

RESULTS = os.path.join(HERE, "results", "stopping.csv")
PREVIOUS = dict(single=dict(eps_rel=2.5e-4, eps_rel_dual=0.15, rho0=0.5, rho_max=8.0, rho_doubling=30.0,
                            eps_change=math.inf),
                pairs=dict(eps_change=math.inf))
"""The defaults before issue 13 (eps_change inf: no change test)."""


def decimated(name, vertices):
    """shared mesh ``name`` (or a mesh file) decimated to about ``vertices`` vertices by fast-simplification."""
    import fast_simplification

    mesh = meshes.shared_mesh(name)
    V, F = fast_simplification.simplify(np.array(mesh.vertices), np.array(mesh.elements),  # writeable copies
                                        target_reduction=1 - vertices / mesh.n_vertices)
    return wrd.Mesh(V.astype(np.float64), F.astype(np.int64))


@functools.lru_cache(maxsize=1)
def measurement_set():
    """(name, mesh) of the irregular meshes of 136-162 vertices."""
    spec = importlib.util.spec_from_file_location("test_meshes", os.path.join(TESTS, "meshes.py"))
    test_meshes = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(test_meshes)
    V, F = test_meshes.icosphere(2)
    return [("cat_rr decimated", decimated("cat_rr", 136)), ("spot_rr decimated", decimated("spot_rr", 150)),
            ("spot_rr_holes decimated", decimated("spot_rr_holes", 150)),
            ("bumpy icosphere", wrd.Mesh(test_meshes.perturbed(V, F, 0.15, seed=3), F)),
            ("ellipsoid", wrd.Mesh(V * np.array([1.0, 1.0, 2.5]), F))]


def pairs_set():
    """The measurement set and smaller decimations (60-80 vertices) for all pairs."""
    return measurement_set() + [("cat_rr decimated", decimated("cat_rr", 60)), ("cat_rr decimated", decimated("cat_rr", 80)),
                                ("spot_rr_holes decimated", decimated("spot_rr_holes", 80))]


def larger_pairs_set():
    """cat_rr decimated to 250 vertices: an all-pairs case whose exact minimizer takes Clarabel about
    25 minutes and 2 GB (``--larger``)."""
    return [("cat_rr decimated", decimated("cat_rr", 250))]


def error_pct(u, exact):
    return float(100 * np.abs(u - exact).max() / exact.max())


def tet_set():
    """(name, mesh) of two small tetrahedral meshes: a ball (127 vertices) and a cube (216)."""
    spec = importlib.util.spec_from_file_location("test_meshes", os.path.join(TESTS, "meshes.py"))
    test_meshes = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(test_meshes)
    return [("ball tets", wrd.Mesh(*test_meshes.ball_tets(1, 3))), ("cube tets", wrd.Mesh(*test_meshes.cube_tets(5)))]


def single_cases():
    out = [(name, mesh, [0], a) for name, mesh in measurement_set() for a in (0.0, 0.01, 0.03, 0.1, 0.3)]
    out += [(name, mesh, [5, 77], 0.05) for name, mesh in measurement_set()]
    holes = measurement_set()[2]
    out.append((holes[0], holes[1], wrd.boundary_vertices(holes[1]).tolist(), 0.05))
    for name, mesh in tet_set():
        out += [(name, mesh, [0], a) for a in (0.01, 0.05, 0.3)]
        out.append((name, mesh, wrd.boundary_vertices(mesh).tolist(), 0.05))
    for name, source in (("spot_rr", 2272), ("bent_pipe_closed_lr", 4882), ("cat_rr", 0)):
        mesh = meshes.shared_mesh(name)
        if mesh is not None:
            out.append((name, mesh, [source], 0.05))
    spot955 = decimated("spot_rr", 954)
    out += [("spot_rr decimated", spot955, [s], a) for s in (0, 100, 500) for a in (0.01, 0.05, 0.2)]
    return out


def run_single(cache):
    import reference_solver as rs

    rows = []
    for name, mesh, sources, alpha_hat in single_cases():
        label = "boundary" if len(sources) > 2 else ",".join(map(str, sources))
        V, F = mesh.vertices, mesh.elements
        size = rs.face_geometry(V, F)[0].sum() ** (1.0 / mesh.element_dim)     # sqrt(area), cube root of volume
        solver = wrd.DistanceSolver(mesh, alpha_hat, device="cpu", workers=1)
        on = solver.solve_mesh                                     # with its obtuse angles refined (the default)
        exact = cached(cache, f"single {name} {on.n_vertices} {label} {alpha_hat}",
                       lambda: rs.solve_reference(on.vertices, on.elements, sources, alpha_hat * size))[:mesh.n_vertices]
        row = dict(solver="single", mesh=name, n=mesh.n_vertices, sources=label, alpha_hat=alpha_hat)
        for tag, settings in (("", {}), ("previous_", PREVIOUS["single"])):
            res = solver.solve(sources, **settings)
            row.update({f"{tag}iterations": int(res.iterations), f"{tag}error_pct": error_pct(res.distance, exact),
                        f"{tag}seconds": res.seconds})
            if not tag:
                row["estimate_pct"] = 100.0 * res.error_estimate
                polished = res.polish()
                row["polished_error_pct"] = error_pct(polished.distance, exact)
                row["polish_change_pct"] = 100.0 * polished.polish_change
        rows.append(row)
        print("  " + str(row), file=sys.stderr, flush=True)
    return rows


def exact_pairs(apr, V, F, alpha):
    """The all-pairs reference over symmetric U at Clarabel gap / feasibility tolerances 1e-9 / 1e-8,
    else 1e-8 / 1e-7 (Clarabel 0.11 reports 'optimal_inaccurate' at the first on some meshes of
    136-162 vertices)."""
    try:
        return apr.solve_all_pairs_reference(V, F, alpha, symmetric=True)
    except RuntimeError:
        return apr.solve_all_pairs_reference(V, F, alpha, symmetric=True, gap_tol=1e-8, feas_tol=1e-7)


def run_pairs(cache, alpha_hats, cached_only, larger=False):
    import all_pairs_reference as apr
    import reference_solver as rs

    rows = []
    for alpha_hat in alpha_hats:
        for name, mesh in pairs_set() + (larger_pairs_set() if larger else []):
            V, F = mesh.vertices, mesh.elements
            t0 = time.perf_counter()
            exact = cached(cache, f"pairs {name} {mesh.n_vertices} {alpha_hat}", None if cached_only else (
                lambda: exact_pairs(apr, V, F, alpha_hat * np.sqrt(rs.face_geometry(V, F)[0].sum()))))
            if exact is None:
                continue
            row = dict(solver="all_pairs", mesh=name, n=mesh.n_vertices, sources="all", alpha_hat=alpha_hat,
                       reference_seconds=time.perf_counter() - t0)
            for tag, settings in (("", {}), ("previous_", PREVIOUS["pairs"])):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", wrd.ConvergenceWarning)
                    res = wrd.all_pairs(mesh, alpha_hat, device="cpu", workers=1, **settings)
                row.update({f"{tag}iterations": int(res.iterations), f"{tag}error_pct": error_pct(res.distance, exact),
                            f"{tag}seconds": res.seconds, f"{tag}converged": bool(res.converged)})
            rows.append(row)
            print("  " + str(row), file=sys.stderr, flush=True)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--single", action="store_true", help="single sources only")
    parser.add_argument("--pairs", action="store_true", help="all pairs only")
    parser.add_argument("--alpha-hats", type=float, nargs="+", default=[0.03, 0.1, 0.3], help="all pairs")
    parser.add_argument("--cache", default=os.path.join(HERE, "results", "stopping_cache"),
                        help="folder of the exact minimizers")
    parser.add_argument("--cached-only", action="store_true",
                        help="all pairs: skip the cases whose exact minimizer is not in --cache yet")
    parser.add_argument("--larger", action="store_true", help="all pairs: also larger_pairs_set()")
    parser.add_argument("--output", default=RESULTS)
    args = parser.parse_args()
    both = not (args.single or args.pairs)
    rows = []
    if args.single or both:
        rows += run_single(args.cache)
    if args.pairs or both:
        rows += run_pairs(args.cache, args.alpha_hats, args.cached_only, args.larger)
    write_csv(rows, args.output)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
