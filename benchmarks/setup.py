"""Setup-time benchmark: where DistanceSolver(mesh) spends its time, against another checkout in the same process.

    python benchmarks/setup.py                                  # spot, the 100k cube sphere
    python benchmarks/setup.py --large                          # also the 655k icosphere
    git worktree add --detach /tmp/base COMMIT
    python benchmarks/setup.py --large --baseline /tmp/base     # the same stages of COMMIT, alternating

Stages (medians over repeats; float64, CPU, one worker): ``mesh`` (Mesh(V, F): the
validation), ``operators`` (build_operators), ``components`` (the first components() of a
fresh Mesh), ``multigrid`` (smoothed_aggregation of W_D), ``solver`` (DistanceSolver(mesh)
on a fresh Mesh: all of the above but the validation, plus the regularizer and the Warp
arrays) and ``total`` = mesh + solver. With ``--baseline`` the checkout there is imported
under another package name and each repeat runs its stages right after this checkout's, so
both see the same machine load; ``identical`` says whether both give the same operators
(G, W_D, volumes, incidence) and multigrid hierarchy, bit for bit. Each mesh runs in its
own process. Prints a markdown table and writes benchmarks/results/setup.csv.
"""

import argparse
import importlib.util
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from report import markdown_table, print_result, run_child, write_csv  # noqa: E402
from single_source import CASES, load  # noqa: E402

STAGES = ("mesh", "operators", "components", "multigrid", "solver", "total")


def import_checkout(root, name="warp_regdist_baseline"):
    """The warp_regdist package of the checkout ``root`` (its kernels/ included), as module ``name``."""
    specs = []
    for package, folder in ((name, os.path.join(root, "warp_regdist")), (f"{name}.kernels", os.path.join(root, "kernels"))):
        spec = importlib.util.spec_from_file_location(package, os.path.join(folder, "__init__.py"),
                                                      submodule_search_locations=[folder])
        sys.modules[package] = importlib.util.module_from_spec(spec)
        specs.append(spec)
    for spec in reversed(specs):  # the kernels first: the package imports from them
        spec.loader.exec_module(sys.modules[spec.name])
    return sys.modules[name]


def stage_times(wrd, V, F):
    """Seconds of each stage of one setup with package ``wrd``, and what it built."""
    from importlib import import_module
    smoothed_aggregation = import_module(wrd.__name__ + ".multigrid").smoothed_aggregation
    t = {}
    start = time.perf_counter()
    mesh = wrd.Mesh(V, F)
    t["mesh"] = time.perf_counter() - start
    start = time.perf_counter()
    ops = wrd.build_operators(mesh)
    t["operators"] = time.perf_counter() - start
    start = time.perf_counter()
    wrd.Mesh.components(mesh)
    t["components"] = time.perf_counter() - start
    start = time.perf_counter()
    hierarchy = smoothed_aggregation(ops.stiffness)
    t["multigrid"] = time.perf_counter() - start
    fresh = wrd.Mesh(V, F)
    start = time.perf_counter()
    wrd.DistanceSolver(fresh, 0.05, device="cpu", workers=1)
    t["solver"] = time.perf_counter() - start
    t["total"] = t["mesh"] + t["solver"]
    return t, ops, hierarchy


def same_setup(a, b):
    """True when two (operators, hierarchy) pairs hold bit-identical arrays."""
    def arrays(ops, h):
        out = [ops.basis, ops.element_volumes, ops.vertex_volumes, np.float64(ops.total_volume), *ops.vertex_elements,
               h.coarse_inverse]
        for M in [ops.grad, ops.stiffness, *h.smoothers, *h.restrictions]:
            out += [M.indptr, M.indices, M.data]
        return out
    x, y = arrays(*a), arrays(*b)
    return len(x) == len(y) and all(p.dtype == q.dtype and np.array_equal(p, q) for p, q in zip(x, y))


def run_case(name, repeats, baseline):
    import warp as wp
    wp.config.quiet = True
    import warp_regdist as wrd
    wp.init()
    spec = CASES[name][0]
    mesh = load(spec)
    if mesh is None:
        return {"case": name, "skipped": "../shared/meshes not found"}
    V, F = np.array(mesh.vertices), np.array(mesh.elements)
    packages = {"": wrd}
    if baseline:
        packages["baseline_"] = import_checkout(baseline)
    times = {prefix: [] for prefix in packages}
    built = {}
    for r in range(repeats + 1):  # the first repeat warms caches and is left out
        for prefix, package in packages.items():
            t, ops, hierarchy = stage_times(package, V, F)
            built[prefix] = (ops, hierarchy)
            if r:
                times[prefix].append(t)
            print(f"  {name} {prefix or 'this '}repeat {r}: total {t['total']:.2f} s", file=sys.stderr, flush=True)
    row = {"case": name, "vertices": mesh.n_vertices, "elements": mesh.n_elements, "repeats": repeats}
    for prefix in packages:
        for stage in STAGES:
            row[f"{prefix}{stage}_s"] = float(np.median([t[stage] for t in times[prefix]]))
    if baseline:
        row["total_speedup"] = row["baseline_total_s"] / row["total_s"]
        row["identical"] = same_setup(built[""], built["baseline_"])
    row["levels"] = str(built[""][1].sizes)
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true", help="include the 655k icosphere")
    ap.add_argument("--baseline", help="another checkout (e.g. a git worktree) timed in the same processes")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--case", help=argparse.SUPPRESS)
    ap.add_argument("--out", default=os.path.join(HERE, "results"))
    args = ap.parse_args()
    if args.case:  # child process: "name repeats baseline"
        name, repeats, baseline = args.case.split(" ", 2)
        print_result(run_case(name, int(repeats), baseline or None))
        return
    names = ["spot_rr", "sphere_100k"] + (["icosphere_655k"] if args.large else [])
    baseline = os.path.abspath(args.baseline) if args.baseline else ""
    rows = []
    for name in names:
        print(f"running {name} ...", file=sys.stderr, flush=True)
        repeats = args.repeats if name != "icosphere_655k" else max(1, min(args.repeats, 3))
        row = run_child(__file__, f"{name} {repeats} {baseline}")
        if row is not None:
            rows.append(row)
    path = os.path.join(args.out, "setup.csv")
    write_csv(rows, path)
    print(markdown_table(rows))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
