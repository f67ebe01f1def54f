"""Distance matrices on a Dask LocalCluster: speed-up with worker processes, memory of a large run.

    python benchmarks/dask_matrix.py                 # spot x 256 sources: cluster of 1 and 2 workers, in-process
    python benchmarks/dask_matrix.py --large         # also the 100k-vertex cube sphere x 256 sources
    python benchmarks/dask_matrix.py --cases spot:cluster:1 spot:cluster:2

Every case streams ``wrd.distance_matrix(..., out=<tmp>.npy)`` (symmetrized, alpha_hat 0.05,
float64, random sources with seed 0) in its own process and reports the wall time of the
call (worker start-up excluded, each worker's solver set-up included), the CPU time of the
busiest worker and of all workers during the call (on a shared machine the wall time depends
on the other load; total CPU time of one worker / CPU time of the busiest of N estimates the
speed-up on an idle machine), the peak memory of every worker process (ru_maxrss, read in the
workers) and of the calling process, and the largest difference from the first case's matrix
on the same mesh. ``--max-iterations`` caps the
ADMM iterations (in the workers too): a memory probe, since the memory of a block is allocated
before its first iteration. Prints a markdown table and
writes benchmarks/results/dask_matrix.csv. Needs ``pip install -e '.[distributed]'``.
"""

import argparse
import os
import resource
import sys
import tempfile
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from report import markdown_table, print_result, run_child, write_csv  # noqa: E402

RESULTS = os.path.join(HERE, "results", "dask_matrix.csv")
MESHES = {"spot": "spot_rr", "sphere_100k": "cube_sphere:129"}


def load(name):
    import meshes

    import warp_regdist as wrd

    spec = MESHES[name]
    if spec.startswith("cube_sphere:"):
        return meshes.cube_sphere(int(spec.split(":")[1]))
    return wrd.load_mesh(os.path.join(os.path.dirname(wrd.__file__), "data", f"{spec}.off"))


def _cpu_seconds():
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _max_rss_gb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def run_case(spec):
    """spec = MESH:ENGINE:WORKERS:CHUNK:SOURCES:CAP:RUN:FOLDER, ENGINE 'cluster' (LocalCluster processes) or
    'local', CAP the ADMM iteration cap (0: the default), RUN the index of the run (a fresh output each)."""
    import warp_regdist as wrd

    name, engine, workers, chunk, k, cap, run, keep = spec.split(":", 7)
    case, workers, chunk, k, cap = f"{name}:{engine}:{workers}", int(workers), int(chunk), int(k), int(cap)
    warnings.simplefilter("ignore", wrd.ConvergenceWarning)
    mesh = load(name)
    sources = np.random.default_rng(0).choice(mesh.n_vertices, k, replace=False)
    out = os.path.join(keep, f"{case.replace(':', '_')}_{run}.npy")
    row = dict(mesh=name, n=mesh.n_vertices, sources=k, chunk=chunk, engine=engine, workers=workers,
               iteration_cap=cap or "default")
    kwargs = dict(sources=sources, chunk=chunk, out=out, options=wrd.SolverOptions(max_iterations=cap) if cap else None)
    if engine == "cluster":
        from distributed import Client, LocalCluster

        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
                Client(cluster) as client:
            cpu = client.run(_cpu_seconds)
            t0 = time.perf_counter()
            wrd.distance_matrix(mesh, 0.05, client=client, **kwargs)
            row["seconds"] = round(time.perf_counter() - t0, 2)
            cpu = {w: c - cpu[w] for w, c in client.run(_cpu_seconds).items()}
            rss = client.run(_max_rss_gb)
        row["worker_cpu_s"] = round(max(cpu.values()), 2)
        row["total_worker_cpu_s"] = round(sum(cpu.values()), 2)
        row["peak_worker_rss_gb"] = round(max(rss.values()), 3)
    else:
        t0 = time.perf_counter()
        wrd.distance_matrix(mesh, 0.05, workers=workers, **kwargs)
        row["seconds"] = round(time.perf_counter() - t0, 2)
    row["peak_caller_rss_gb"] = round(_max_rss_gb(), 3)
    row["matrix"] = out
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", help=argparse.SUPPRESS)
    ap.add_argument("--cases", nargs="+", default=["spot:cluster:1", "spot:cluster:2", "spot:local:2"],
                    help="MESH:ENGINE:WORKERS (MESH spot or sphere_100k, ENGINE cluster or local)")
    ap.add_argument("--large", action="store_true", help="also sphere_100k:cluster:2")
    ap.add_argument("--chunk", type=int, default=32, help="rows per block (default: 32)")
    ap.add_argument("--sources", type=int, default=256, help="rows: random source vertices (default: 256)")
    ap.add_argument("--max-iterations", type=int, default=0,
                    help="ADMM iteration cap of every block, for a memory probe (default: the tolerances' own)")
    ap.add_argument("--keep", default=None, help="folder for the matrices (default: a temporary one)")
    ap.add_argument("--csv", default=RESULTS, help=f"where to write the rows (default: {os.path.relpath(RESULTS)})")
    args = ap.parse_args()
    if args.case:
        print_result(run_case(args.case))
        return
    cases = args.cases + (["sphere_100k:cluster:2"] if args.large else [])
    with tempfile.TemporaryDirectory() as tmp:
        keep = args.keep or tmp
        rows, first = [], {}
        for run, case in enumerate(cases):
            row = run_child(__file__, f"{case}:{args.chunk}:{args.sources}:{args.max_iterations}:{run}:{keep}")
            if row is None:
                continue
            D = np.load(row.pop("matrix"), mmap_mode="r")
            if row["mesh"] in first:
                base = first[row["mesh"]]
                row["speedup_vs_first"] = round(base["seconds"] / row["seconds"], 2)
                row["max_diff_vs_first"] = float(np.abs(D - np.load(base["path"], mmap_mode="r")).max())
            else:
                first[row["mesh"]] = dict(seconds=row["seconds"], path=D.filename)
            rows.append(row)
    print(markdown_table(rows))
    write_csv(rows, args.csv)
    print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
