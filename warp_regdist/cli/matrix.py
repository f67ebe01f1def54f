"""The ``matrix`` subcommand: single-source rows written block by block, optionally on a Dask cluster."""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import sys

import numpy as np

from ..arguments import parse_workers
from .common import (DEMO_ALPHA_HAT, PROG, announce_compile, check_output, load, max_distance_option,
                     max_iterations_option, read_xyz, single_source_options, solver_options, stop_status,
                     stop_word, subcommand, warnings_to_stderr)


def add_parser(sub) -> None:
    matrix = subcommand(
        sub, "matrix",
        help="distance matrix of single-source rows, written block by block to .zarr or .npy (resumable)",
        description="Rows of regularized distances from many source vertices (batched single-source\n"
        "solves), written block by block to a Zarr array or a .npy file, never all in memory; the\n"
        "same command run again resumes (blocks already written are skipped). With --workers or\n"
        "--scheduler the blocks are tasks on a Dask cluster (pip install 'warp-regdist[distributed]').",
    )
    matrix.add_argument("mesh", metavar="MESH", help="triangle or tetrahedral mesh file")
    matrix.add_argument(
        "--sources",
        default="all",
        metavar="all|FILE",
        help="'all' (default: a row per vertex), a text file of 0-based vertex indices separated by "
        "spaces, commas or newlines (a row per index, in the file's order), or a .csv file of 'x,y,z' "
        "rows: landmark points moved to the closest surface point and inserted into the mesh (a row "
        "each, not symmetrized)",
    )
    matrix.add_argument(
        "--alpha-hat",
        type=float,
        default=DEMO_ALPHA_HAT,
        metavar="A",
        help="scale-invariant regularization weight >= 0 of each row's problem (default: 0.05)",
    )
    matrix.add_argument(
        "--output",
        required=True,
        metavar="FILE",
        help="matrix (rows x vertices) as a Zarr array (.zarr, NaN where not yet written) or a .npy "
        "file; its progress record goes next to it (FILE.progress)",
    )
    matrix.add_argument("--chunk", type=int, default=64, metavar="ROWS",
                        help="rows per block: one batched solve, one task, one stored block (default: 64)")
    matrix.add_argument("--no-symmetrize", dest="symmetrize", action="store_false",
                        help="keep the rows as solved (default: average d(x, y) and d(y, x) over the sources)")
    cluster = matrix.add_mutually_exclusive_group()
    cluster.add_argument("--scheduler", metavar="ADDRESS",
                         help="solve on the Dask cluster of this scheduler (e.g. tcp://10.0.0.5:8786)")
    cluster.add_argument("--workers", type=int, metavar="N",
                         help="solve on a local Dask cluster of N worker processes (one thread each)")
    max_distance_option(matrix)
    max_iterations_option(matrix)
    solver_options(matrix)


def _matrix_sources(text: str, n: int):
    """None for 'all', else the vertex indices listed in the file ``text`` (each in [0, n - 1])."""
    if text.strip().lower() == "all":
        return None
    if not os.path.isfile(text):
        raise ValueError(f"expected --sources as 'all' or an existing file of vertex indices, got {text!r} "
                         "(no such file)")
    with open(text, encoding="utf-8", errors="replace") as f:
        items = [item for item in re.split(r"[,\s]+", f.read()) if item]
    if not items:
        raise ValueError(f"expected vertex indices in --sources {text!r}, got an empty file")
    bad = [item for item in items if not re.fullmatch(r"[+-]?\d+", item)]
    if bad:
        raise ValueError(f"expected integer vertex indices in --sources {text!r}, got {bad[0]!r}")
    values = [int(item) for item in items]
    bad = [v for v in values if not 0 <= v < n]
    if bad:
        raise ValueError(f"expected vertex indices in [0, {n - 1}] in --sources {text!r} (the mesh has {n} vertices), "
                         f"got {bad[0]}")
    return np.array(values, dtype=np.int64)


def _dask_client(args: argparse.Namespace, stack):
    """A dask.distributed Client for --scheduler or --workers (closed with ``stack``), else None."""
    if args.scheduler is None and args.workers is None:
        return None
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ValueError("expected dask.distributed for --scheduler or --workers (pip install "
                         "'warp-regdist[distributed]'), got no module 'distributed'") from None
    if args.scheduler is not None:
        try:
            return stack.enter_context(Client(args.scheduler, timeout=30))
        except OSError as exc:
            raise ValueError(f"expected a reachable Dask scheduler at --scheduler, got {args.scheduler!r} "
                             f"({exc})") from None
    cores = parse_workers(None)
    if not 1 <= args.workers <= cores:
        raise ValueError(f"expected --workers between 1 and the {cores} cores here (for more, a --scheduler of a "
                         f"cluster), got {args.workers}")
    cluster = stack.enter_context(LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                                               dashboard_address=":0"))
    return stack.enter_context(Client(cluster))


def _matrix_progress(quiet: bool):
    """A progress callback for ``distance_matrix`` drawing a bar on stderr (every ~2 s and at the
    end); ``state`` keeps the blocks found done and the elapsed time for the summary."""
    state = {"found": 0, "seconds": 0.0, "shown": -10.0}

    def show(done, total, seconds):
        if seconds == 0.0:
            state["found"] = done
        state["seconds"] = seconds
        if quiet or (seconds - state["shown"] < 2.0 and done < total):
            return
        state["shown"] = seconds
        bar = "#" * (30 * done // total) + "." * (30 - 30 * done // total)
        solved = done - state["found"]
        left = f", ~{seconds / solved * (total - done):.0f} s left" if 0 < solved and done < total else ""
        print(f"  [{bar}] {done}/{total} blocks, {seconds:.0f} s{left}", file=sys.stderr, flush=True)

    return show, state


def run(args: argparse.Namespace) -> int:
    from .. import ConvergenceWarning, distance_matrix, surface_points

    if not (args.output.lower().endswith(".zarr") and os.path.isdir(args.output)):  # a Zarr store is a directory
        check_output(args.output, (".zarr", ".npy"), "--output")
    mesh = load(args.mesh)
    points = None
    if args.sources.lower().endswith(".csv"):
        points = surface_points(mesh, read_xyz(args.sources, "--sources"), max_distance=args.max_distance)
        sources = None
    else:
        sources = _matrix_sources(args.sources, mesh.n_vertices)
    announce_compile(args.dtype, args.quiet)
    progress, state = _matrix_progress(args.quiet)
    with contextlib.ExitStack() as stack, warnings_to_stderr() as seen:
        client = _dask_client(args, stack)
        try:
            D = distance_matrix(mesh, args.alpha_hat, sources=sources, symmetrize=args.symmetrize,
                                device=args.device, dtype=args.dtype, chunk=args.chunk, client=client,
                                out=args.output, progress=progress, points=points,
                                options=single_source_options(args))
        except ImportError as exc:
            raise ValueError(f"expected zarr for a .zarr --output (pip install 'warp-regdist[distributed]'), "
                             f"got {exc}") from None
        except KeyboardInterrupt:
            print(f"{PROG}: {stop_word()}; the blocks written so far stay in {args.output}: run the same command "
                  "again to resume", file=sys.stderr)
            return stop_status()
    if not args.quiet:
        where = "here" if client is None else f"on a Dask cluster ({args.scheduler or f'{args.workers} workers'})"
        print(f"{os.path.basename(args.mesh)}: {mesh.n_vertices} vertices. Distance matrix of {D.shape[0]} "
              f"single-source rows, alpha_hat {args.alpha_hat:g}, {args.dtype}, "
              f"{'symmetrized' if args.symmetrize and points is None else 'not symmetrized'}: {-(-D.shape[0] // args.chunk)} blocks of "
              f"{args.chunk} rows ({state['found']} already written), solved {where} in {state['seconds']:.1f} s. "
              f"Wrote {args.output}.")
    return 1 if any(issubclass(category, ConvergenceWarning) for category in seen) else 0
