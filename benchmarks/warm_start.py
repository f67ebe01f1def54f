"""Warm starts (``solve(..., initial=result)``) against cold solves of the same problem (issue 13).

    python benchmarks/warm_start.py            # spot_rr, bent_pipe_closed_lr, cat_rr
    python benchmarks/warm_start.py --large    # also the 100k cube sphere of single_source.py and
                                               # spot_rr Loop-subdivided twice (76k vertices)
    python benchmarks/warm_start.py --meshes spot_rr_loop_76k --out benchmarks/results/warm_start_76k.csv

Per mesh (one source, alpha_hat 0.05), in one process, cold vs warm start of the same fine problem:

- continuation: from the answer at alpha_hat 0.05 to 0.06 and to 0.1;
- neighbour: from the answer at the source to one at a 1-ring vertex of it;
- multilevel: from a coarse solve on the mesh quadric-decimated 4x and 8x (fast-simplification),
  and a chain 16x -> 4x -> fine. Prolongation: u interpolated barycentrically at each fine
  vertex's closest point on the coarse mesh; the duals y (per unit area) of the coarse face
  closest to each fine face's centroid, projected onto the fine face's plane; the penalty
  carried. The coarse source is the coarse vertex nearest the fine one.

Columns: ADMM and CG iterations; solve seconds (median of 3, of 1 on the large meshes); total
seconds of a warm start including its coarse work (decimation, coarse solvers' setup, coarse
solves, prolongation; the answer a continuation or neighbour starts from is given, as in
its use); error = max over vertices vs a tight solve of the fine problem
(the solve's options at ``TIGHT``), in % of its max, of the cold and warm answers and of the
start. The fine solver's setup is common to both and left out. Prints a markdown table and
writes benchmarks/results/warm_start.csv after each mesh.
"""

import argparse
import os
import sys
import time

import fast_simplification
import igl
import numpy as np
import trimesh

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import warp_regdist as wrd  # noqa: E402
from compare import median_time  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402
from robustness import sampler  # noqa: E402
from single_source import CASES as SINGLE_SOURCE, load  # noqa: E402


def loop_subdivided(name, times):
    """Shared mesh ``name`` after ``times`` Loop subdivisions (trimesh): 4^times x the faces, smooth, so
    that its quadric decimations stay non-degenerate (those of a midpoint subdivision get zero-area faces)."""
    mesh = load(name)
    if mesh is None:
        return None
    V, F = trimesh.remesh.subdivide_loop(mesh.vertices, mesh.elements, iterations=times)
    return wrd.Mesh(V, F)


CASES = {**{k: (lambda spec=SINGLE_SOURCE[k][0]: load(spec), SINGLE_SOURCE[k][1])
            for k in ("spot_rr", "bent_pipe_closed_lr", "sphere_100k")},
         "cat_rr": (lambda: load("cat_rr"), 0), "spot_rr_loop_76k": (lambda: loop_subdivided("spot_rr", 2), 2272)}
"""name: (mesh loader, source vertex)"""
LARGE = ("sphere_100k", "spot_rr_loop_76k")
ALPHA_HAT = 0.05
CONTINUATION = (0.06, 0.1)
MULTILEVEL = {"4x": (4,), "8x": (8,), "16x -> 4x": (16, 4)}
TIGHT = dict(eps_rel=1e-5, eps_rel_dual=1e-3, eps_change=1e-6, max_iterations=2000)
RESULTS = os.path.join(HERE, "results", "warm_start.csv")


def decimate(mesh, factor):
    """``mesh`` quadric-decimated to about 1/factor of its vertices (fast-simplification)."""
    V, F = fast_simplification.simplify(np.array(mesh.vertices), np.array(mesh.elements),  # writeable copies
                                        target_reduction=1 - 1 / factor)
    return wrd.Mesh(V.astype(np.float64), F.astype(np.int64))


def prolong(coarse, res, fine):
    """A coarse result as a warm start of ``fine``: DistanceResult(distance (n,), duals (m, 3), penalty)."""
    u = np.where(np.isfinite(res.distance), res.distance, 0.0)
    tri, bary = sampler(coarse, fine.vertices)
    F = fine.elements
    _, face, _ = igl.point_mesh_squared_distance(fine.vertices[F].mean(axis=1), coarse.vertices,
                                                 coarse.elements.astype(np.int64))
    normal = np.cross(fine.vertices[F[:, 1]] - fine.vertices[F[:, 0]], fine.vertices[F[:, 2]] - fine.vertices[F[:, 0]])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    y = res.duals[face]
    y -= (y * normal).sum(axis=1, keepdims=True) * normal
    return wrd.DistanceResult(distance=(u[coarse.elements[tri]] * bary).sum(axis=1), duals=y, penalty=res.penalty)


def multilevel_start(mesh, source, factors):
    """Coarse solves on ``mesh`` decimated by each of ``factors`` (coarsest first), each warm-started
    from the previous one, prolonged to ``mesh`` -> (DistanceResult, [coarse results])."""
    levels = [decimate(mesh, f) for f in factors] + [mesh]
    start, coarse_results = None, []
    for coarse, finer in zip(levels[:-1], levels[1:]):
        s = int(np.argmin(np.linalg.norm(coarse.vertices - mesh.vertices[source], axis=1)))
        res = wrd.DistanceSolver(coarse, ALPHA_HAT, device="cpu", workers=1).solve([s], initial=start)
        coarse_results.append(res)
        start = prolong(coarse, res, finer)
    return start, coarse_results


def error_pct(u, reference):
    """max |u - reference| in % of max reference (finite vertices)."""
    ok = np.isfinite(reference)
    return float(100 * np.abs(u[ok] - reference[ok]).max() / reference[ok].max())


def neighbour(mesh, source):
    """The lowest-numbered vertex of ``source``'s 1-ring."""
    F = mesh.elements
    ring = np.unique(F[(F == source).any(axis=1)])
    return int(ring[ring != source][0])


def run_mesh(name, repeats):
    """Rows of one mesh: each warm start against the cold solve of the same fine problem."""
    loader, source = CASES[name]
    mesh = loader()
    if mesh is None:
        return [{"mesh": name, "skipped": "../shared/meshes not found"}]
    solvers = {a: wrd.DistanceSolver(mesh, a, device="cpu", workers=1) for a in (ALPHA_HAT,) + CONTINUATION}
    base = solvers[ALPHA_HAT]
    base.solve([source])  # warm-up: kernels loaded
    other = neighbour(mesh, source)
    problems = {(a, source) for a in solvers} | {(ALPHA_HAT, other)}
    reference, reference_it, cold = {}, {}, {}
    for a, s in sorted(problems):
        t = time.perf_counter()
        ref = solvers[a].solve([s], **TIGHT)
        reference[a, s] = ref.distance
        reference_it[a, s] = f"{ref.iterations}" + " (not converged)" * (not ref.converged)
        cold[a, s] = [solvers[a].solve([s]) for _ in range(repeats)]
        print(f"  {name} alpha_hat {a} source {s}: reference {ref.iterations} it. "
              f"(converged {ref.converged}, {time.perf_counter() - t:.1f} s)", file=sys.stderr, flush=True)
    given = base.solve([source])

    def row(scenario, problem, start, coarse_s=0.0, coarse_it=""):
        a, s = problem
        cold_res = cold[problem]
        warm_res = [solvers[a].solve([s], initial=start) for _ in range(repeats)]
        c, w = cold_res[-1], warm_res[-1]
        warm_s = float(np.median([r.seconds for r in warm_res]))
        out = {"mesh": name, "vertices": mesh.n_vertices, "scenario": scenario, "alpha_hat": a, "source": s,
               "cold_admm": int(c.iterations), "warm_admm": int(w.iterations), "coarse_admm": coarse_it,
               "cold_cg": int(c.cg_iterations), "warm_cg": int(w.cg_iterations),
               "cold_solve_s": float(np.median([r.seconds for r in cold_res])), "warm_solve_s": warm_s,
               "coarse_s": coarse_s, "warm_total_s": warm_s + coarse_s,
               "cold_error_pct": error_pct(c.distance, reference[problem]),
               "warm_error_pct": error_pct(w.distance, reference[problem]),
               "start_error_pct": error_pct(np.where(np.isfinite(start.distance), start.distance, 0.0),
                                            reference[problem]),
               "converged": bool(c.converged and w.converged), "reference_admm": reference_it[problem]}
        print("  " + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in out.items()),
              file=sys.stderr, flush=True)
        return out

    rows = [row(f"continuation {ALPHA_HAT} -> {a}", (a, source), given) for a in CONTINUATION]
    rows.append(row(f"neighbour {source} -> {other}", (ALPHA_HAT, other), given))
    for label, factors in MULTILEVEL.items():
        coarse_s, (start, coarse) = median_time(lambda: multilevel_start(mesh, source, factors), repeats)
        coarse_it = " + ".join(str(r.iterations) for r in coarse)
        rows.append(row(f"multilevel {label}", (ALPHA_HAT, source), start, coarse_s, coarse_it))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true", help="also the 100k cube sphere and spot Loop-subdivided "
                    "to 76k vertices (half an hour on 2 cores)")
    ap.add_argument("--meshes", nargs="+", choices=list(CASES), help="only these meshes")
    ap.add_argument("--out", default=RESULTS)
    args = ap.parse_args()
    import warp as wp
    wp.config.quiet = True
    rows = []
    names = args.meshes or [name for name in CASES if args.large or name not in LARGE]
    for name in names:
        print(f"running {name} ...", file=sys.stderr, flush=True)
        rows += run_mesh(name, repeats=1 if name in LARGE else 3)
        write_csv(rows, args.out)
    print(markdown_table(rows))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
