"""The ``warp-regdist`` command: regularized geodesic distances from the shell.

Subcommands: ``demo`` (the spot cow shipped with the package), ``distance`` (any
mesh file), ``allpairs`` (the symmetric all-pairs distance matrix) and ``matrix``
(single-source rows written block by block, resumable, optionally on a Dask cluster); ``volume`` (a closed surface
tetrahedralized, then the distance inside it); ``view`` (values on a mesh in a polyscope window).  Bad input (missing or malformed files, bad sources, an unknown device, an
unsupported output extension) ends with one line ``warp-regdist: error: ...`` on stderr
and exit status 2; other exceptions are bugs and propagate with their traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.resources
import os
import re
import sys
import warnings

import numpy as np

__all__ = ["main"]

PROG = "warp-regdist"
DEMO_SOURCE = 2272
DEMO_ALPHA_HAT = 0.05
_OUTPUT_EXTENSIONS = (".npy", ".csv", ".vtu")
_LISTED_SOURCES = 8  # sources named one by one in the summary


_EXIT_STATUS = """\
exit status:
  0  the distance was written; also when the ADMM stopped at the iteration cap
     without meeting its stopping test (then a line 'warp-regdist: warning: ...'
     on stderr says so and the values are approximate)
  2  bad input (missing or unreadable mesh, bad --sources, unsupported output
     extension, unavailable device, ...): one line 'warp-regdist: error: ...'
"""


def _parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Regularized geodesic distances on triangle and tetrahedral meshes (Edelstein et al.,\n"
        "SIGGRAPH 2023), solved by ADMM with Warp kernels on the CPU or a CUDA GPU.",
        epilog=_EXIT_STATUS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def solver_options(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--device",
            default=None,
            help="Warp device: cpu, cuda, cuda:1, ... (default: Warp's default, the first CUDA "
            "GPU if there is one, else cpu)",
        )
        p.add_argument(
            "--dtype",
            default="float64",
            choices=("float64", "float32"),
            help="precision of the solver (default: float64)",
        )
        p.add_argument("--quiet", action="store_true", help="print nothing but warnings and errors")

    demo = sub.add_parser(
        "demo",
        help="solve on the shipped spot cow and write distance.npy and distance.png",
        description=f"Solve from vertex {DEMO_SOURCE} of the spot cow (4764 vertices, shipped with\n"
        f"the package) at alpha_hat {DEMO_ALPHA_HAT}; write distance.npy and distance.png.",
        epilog=_EXIT_STATUS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    demo.add_argument(
        "--output",
        default="warp-regdist-demo",
        metavar="DIR",
        help="output directory, created if missing (default: ./warp-regdist-demo)",
    )
    solver_options(demo)

    distance = sub.add_parser(
        "distance",
        help="regularized distance on a mesh file, written as .npy, .csv or .vtu",
        description="Regularized geodesic distance from a set of source vertices on a triangle\n"
        "mesh (OBJ, OFF, PLY or STL) or a tetrahedral mesh (gmsh .msh, .vtk, .vtu, Medit\n"
        ".mesh); vertex order as in the file.",
        epilog=_EXIT_STATUS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    distance.add_argument(
        "mesh",
        metavar="MESH",
        help="triangle or tetrahedral mesh file (.obj, .off, .ply, .stl, .msh, .vtk, .vtu, .mesh)",
    )
    distance.add_argument(
        "--sources",
        required=True,
        metavar="LIST",
        help="comma-separated 0-based vertex indices (e.g. 2272,17), or 'boundary' for all "
        "boundary vertices",
    )
    distance.add_argument(
        "--alpha-hat",
        type=float,
        default=DEMO_ALPHA_HAT,
        metavar="A",
        help="scale-invariant regularization weight >= 0; alpha = A sqrt(area), or A volume^(1/3) "
        "on a tetrahedral mesh (default: 0.05)",
    )
    distance.add_argument(
        "--regularizer",
        default="dirichlet",
        choices=("dirichlet", "vector_field", "hessian"),
        help="dirichlet (default); vector_field: isolines follow the field of --directions; "
        "hessian: isolines ignore the boundary (triangle meshes; alpha = A area^(3/2), so use "
        "a much smaller A, e.g. 1e-3)",
    )
    distance.add_argument(
        "--beta-hat",
        type=float,
        default=None,
        metavar="B",
        help="alignment weight >= 0 of --regularizer vector_field (default: 10)",
    )
    distance.add_argument(
        "--directions",
        metavar="FILE",
        help="field of --regularizer vector_field: .npy of shape (faces, 3), one vector per face; "
        "or .csv with rows 'face,dx,dy,dz' (sign-free directions on a few faces, interpolated "
        "into the smoothest line field)",
    )
    distance.add_argument(
        "--output",
        required=True,
        metavar="FILE",
        help="distance per vertex: .npy (float64 array), .csv (one value per line, full "
        "precision, 'inf' for vertices no source reaches) or .vtu (the mesh with point data "
        "'distance', NaN where no source reaches; opens in ParaView)",
    )
    distance.add_argument(
        "--png",
        metavar="FILE",
        help="also write a picture of the distance (.png); on a tetrahedral mesh, its cut by the "
        "plane z = centre of the bounding box, with isolines",
    )
    solver_options(distance)

    allpairs = sub.add_parser(
        "allpairs",
        help="symmetric all-pairs distance matrix (n x n), written as .npy",
        description="All-pairs regularized distance matrix on a connected triangle mesh (Algorithm 2,\n"
        "symmetric by construction), written as an (n, n) float64 .npy; progress on stderr.",
        epilog=_EXIT_STATUS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    allpairs.add_argument("mesh", metavar="MESH", help="triangle mesh file (.obj, .off, .ply, .stl)")
    allpairs.add_argument(
        "--alpha-hat",
        type=float,
        default=0.03,
        metavar="A",
        help="scale-invariant regularization weight >= 0; alpha = A sqrt(area) (default: 0.03)",
    )
    allpairs.add_argument("--output", required=True, metavar="FILE", help="distance matrix (.npy)")
    allpairs.add_argument(
        "--checkpoint",
        metavar="FILE",
        help="write the whole solver state to FILE (.npz) every --checkpoint-seconds, at the iteration cap "
        "on Ctrl-C and at convergence, so that --resume FILE continues the run (the same matrix as an uninterrupted "
        "run) and --initial FILE starts another alpha_hat from it",
    )
    allpairs.add_argument("--checkpoint-seconds", type=float, default=300.0, metavar="S",
                          help="seconds between checkpoints (default: 300)")
    allpairs.add_argument("--resume", metavar="FILE", help="continue from a checkpoint of the same problem")
    allpairs.add_argument("--initial", metavar="FILE",
                          help="warm start from a checkpoint of this mesh and dtype at another alpha_hat")
    allpairs.add_argument("--max-iterations", type=int, default=3000, metavar="N",
                          help="ADMM iteration cap (default: 3000)")
    allpairs.add_argument("--workers", type=int, default=None, metavar="N",
                          help="CPU processes sharing every step (default: the cores available)")
    solver_options(allpairs)
    _add_matrix_parser(sub, solver_options)
    _add_volume_parser(sub, solver_options)
    _add_view_parser(sub)
    return parser


def _add_view_parser(sub) -> None:
    view = sub.add_parser(
        "view",
        help="show per-vertex values on a mesh in an interactive window (polyscope)",
        description="Show a .npy of per-vertex values ((n,) or (n, k): k fields side by side) on a mesh\n"
        "in a polyscope window, as a colour map with isolines, sources marked, a slice plane\n"
        "for tetrahedra. Needs pip install 'warp-regdist[view]'.",
        epilog=_EXIT_STATUS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    view.add_argument("mesh", metavar="MESH", help="the mesh the values belong to")
    view.add_argument("values", metavar="VALUES", help=".npy file of per-vertex values, (n,) or (n, k)")
    view.add_argument("--isolines", type=int, default=20, metavar="N", help="isolines per field (default: 20)")
    view.add_argument("--sources", metavar="SOURCES", help="vertices to mark: comma-separated indices")
    view.add_argument("--backend", metavar="NAME", help="polyscope backend (openGL_mock: headless, draws nothing)")
    view.add_argument("--frames", type=int, metavar="N", help="render N frames and exit instead of waiting")


def _view(args: argparse.Namespace) -> None:
    from .viewer import show

    mesh = _load(args.mesh)
    if not args.values.lower().endswith(".npy") or not os.path.isfile(args.values):
        raise ValueError(f"expected VALUES as an existing .npy file, got {args.values!r}")
    try:
        values = np.load(args.values, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise ValueError(f"expected VALUES as a readable .npy array, got {args.values!r} ({exc})") from None
    sources = None
    if args.sources:
        sources, _ = _parse_sources(args.sources, mesh)
    try:
        show(mesh, values, isolines=args.isolines, sources=sources, backend=args.backend, frames=args.frames)
    except ModuleNotFoundError as exc:
        raise ValueError(str(exc)) from None


def _check_output(path: str, extensions: tuple[str, ...], option: str) -> None:
    ext = os.path.splitext(path)[1].lower()
    if ext not in extensions:
        raise ValueError(f"expected {option} ending in {' or '.join(extensions)}, got {path!r}")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise ValueError(f"expected {option} in an existing directory, got {path!r} (no directory {folder!r})")
    if os.path.isdir(path):
        raise ValueError(f"expected {option} as a file name, got the directory {path!r}")
    if not os.access(folder, os.W_OK) or (os.path.exists(path) and not os.access(path, os.W_OK)):
        raise ValueError(f"expected {option} in a writable place, got {path!r} (permission denied)")


def _parse_sources(text: str, mesh) -> tuple[np.ndarray, str]:
    """Source vertex indices (s,) and their description for the summary."""
    from . import boundary_vertices

    if text.strip().lower() == "boundary":
        sources = boundary_vertices(mesh)
        if sources.size == 0:
            raise ValueError("expected a mesh with a boundary for --sources boundary, got a closed mesh")
        return sources, f"{sources.size} boundary vertices"
    items = [item.strip() for item in text.split(",")]
    if not all(re.fullmatch(r"[+-]?\d+", item) for item in items):
        raise ValueError(
            f"expected --sources as comma-separated vertex indices (e.g. 2272,17) or 'boundary', got {text!r}"
        )
    sources = np.unique(np.array([int(item) for item in items], dtype=np.int64))
    bad = sources[(sources < 0) | (sources >= mesh.n_vertices)]
    if bad.size:
        raise ValueError(
            f"expected --sources in [0, {mesh.n_vertices - 1}] (the mesh has {mesh.n_vertices} "
            f"vertices), got {bad[0]}"
        )
    listed = ", ".join(str(s) for s in sources[:_LISTED_SOURCES])
    more = f", ... ({sources.size} in all)" if sources.size > _LISTED_SOURCES else ""
    noun = "vertex" if sources.size == 1 else "vertices"
    return sources, f"source {noun} {listed}{more}"


def _write_values(path: str, values: np.ndarray) -> None:
    if path.lower().endswith(".npy"):
        np.save(path, values)
    else:
        with open(path, "w", encoding="ascii") as f:
            f.writelines(f"{float(v)!r}\n" for v in values)


def _warn(message: str) -> None:
    print(f"{PROG}: warning: {message}", file=sys.stderr)


@contextlib.contextmanager
def _warnings_to_stderr(reported_by_caller=()):
    """Record the warnings of the block, then print each as one 'warp-regdist: warning: ...'
    line, except those of the categories ``reported_by_caller`` (a tuple of classes)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    for w in caught:
        if not issubclass(w.category, reported_by_caller):
            _warn(str(w.message))


def _solve(mesh, sources, alpha_hat: float, device: str | None, dtype: str, verbose: bool = False,
           **regularization):
    """Solve once; returns (solver, result), reporting non-convergence on stderr
    (and, with ``verbose``, the ADMM's progress every 2 s on stderr). ``regularization``:
    the DistanceSolver keywords regularizer, beta_hat, vector_field."""
    import warp as wp

    from . import ConvergenceWarning, DistanceSolver

    wp.config.log_level = wp.LOG_WARNING  # no start-up banner on stdout
    solver = DistanceSolver(mesh, alpha_hat=alpha_hat, device=device, dtype=dtype, **regularization)
    with _warnings_to_stderr(reported_by_caller=(ConvergenceWarning,)):
        result = solver.solve(sources, verbose=verbose)
    if result.interrupted:
        _warn(f"interrupted at ADMM iteration {result.iterations}: the distance written is the current iterate")
    elif not result.converged:
        _warn(
            f"the ADMM did not converge in {result.iterations} iterations (primal residual "
            f"{result.primal_residual:.3g}, dual residual {result.dual_residual:.3g}); the "
            "distance written is approximate"
        )
    return solver, result


def _load(path: str):
    from . import load_mesh

    with _warnings_to_stderr():
        return load_mesh(path)


def _summary(name: str, mesh, described: str, solver, result, written: list[str]) -> str:
    status = "converged" if result.converged else "NOT converged"
    elements = "faces" if mesh.element_dim == 2 else "tetrahedra"
    return (
        f"{name}: {mesh.n_vertices} vertices, {mesh.n_elements} {elements}. Regularized geodesic "
        f"distance from {described}, {solver.regularizer.name} regularizer, alpha_hat {solver.alpha_hat:g} "
        f"(alpha {solver.alpha:.4g}), "
        f"on {solver.device} in {solver.dtype}: {result.iterations} ADMM iterations, {status} "
        f"(primal residual {result.primal_residual:.3g}, dual residual {result.dual_residual:.3g}), "
        f"{result.seconds:.2f} s. Largest finite distance "
        f"{_finite_max(result.distance):.4g}. Wrote {', '.join(written)}."
    )


def _finite_max(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite.max()) if finite.size else float("nan")


def _regularization(args: argparse.Namespace, mesh) -> dict:
    """DistanceSolver keywords from --regularizer, --beta-hat and --directions."""
    from .line_field import read_directions

    if args.directions is None:
        if args.regularizer == "vector_field":
            raise ValueError("expected --directions FILE with --regularizer vector_field, got none")
        return {"regularizer": args.regularizer, "beta_hat": args.beta_hat}  # the solver refuses a lone beta_hat
    if args.regularizer != "vector_field":
        raise ValueError(f"expected --directions only with --regularizer vector_field, "
                         f"got --regularizer {args.regularizer}")
    field = read_directions(args.directions, mesh)
    return {"regularizer": args.regularizer, "beta_hat": args.beta_hat, "vector_field": field}


def _distance(args: argparse.Namespace) -> None:
    from .export import save_vtu
    from .render import render_cut, render_distance

    _check_output(args.output, _OUTPUT_EXTENSIONS, "--output")
    if args.png is not None:
        _check_output(args.png, (".png",), "--png")
    mesh = _load(args.mesh)
    sources, described = _parse_sources(args.sources, mesh)
    solver, result = _solve(mesh, sources, args.alpha_hat, args.device, args.dtype, verbose=not args.quiet,
                            **_regularization(args, mesh))
    if args.output.lower().endswith(".vtu"):
        save_vtu(args.output, mesh, {"distance": result.distance})
    else:
        _write_values(args.output, result.distance)
    written = [args.output]
    if args.png is not None:
        marked = None if args.sources.strip().lower() == "boundary" else sources
        name = os.path.basename(args.mesh)
        title = f"{name}: regularized geodesic distance, alpha_hat {solver.alpha_hat:g}"
        if mesh.element_dim == 3:
            render_cut(mesh, result.distance, args.png, title=f"{title}, cut z = centre")
        else:
            render_distance(mesh, result.distance, args.png, sources=marked, title=title)
        written.append(args.png)
    if not args.quiet:
        print(_summary(os.path.basename(args.mesh), mesh, described, solver, result, written))


def _allpairs_progress():
    """A progress callback for ``all_pairs`` printing one stderr line per ~2 s (and the last
    iteration): iteration, the seven residuals / their tolerances, elapsed time, memory."""
    from .all_pairs_admm import RESIDUAL_NAMES

    last = [-10.0]

    def show(iteration, residuals, tolerance, seconds, memory):
        if seconds - last[0] < 2.0 and np.any(residuals > tolerance):
            return
        last[0] = seconds
        parts = " ".join(f"{k} {r:.2e}/{t:.2e}" for k, r, t in zip(RESIDUAL_NAMES, residuals, tolerance))
        print(f"  iteration {iteration}: {parts} (residual/tolerance), {seconds:.1f} s, {memory / 1e9:.2f} GB",
              file=sys.stderr, flush=True)

    return show


def _allpairs(args: argparse.Namespace) -> None:
    import warp as wp

    from . import ConvergenceWarning, all_pairs

    _check_output(args.output, (".npy",), "--output")
    if args.checkpoint is not None:
        _check_output(args.checkpoint, (".npz",), "--checkpoint")
    for flag, path in (("--resume", args.resume), ("--initial", args.initial)):
        if path is not None and not os.path.isfile(path):
            raise ValueError(f"expected {flag} as an existing checkpoint file, got {path!r} (no such file)")
    mesh = _load(args.mesh)
    wp.config.log_level = wp.LOG_WARNING
    with _warnings_to_stderr(reported_by_caller=(ConvergenceWarning,)):
        result = all_pairs(mesh, args.alpha_hat, device=args.device, dtype=args.dtype,
                           progress=None if args.quiet else _allpairs_progress(), max_iterations=args.max_iterations,
                           workers=args.workers, checkpoint=args.checkpoint, checkpoint_seconds=args.checkpoint_seconds,
                           resume=args.resume, initial=args.initial)
    saved = f"; the solver state is in {args.checkpoint} (continue with --resume {args.checkpoint})" \
        if args.checkpoint is not None else ""
    if result.interrupted:
        _warn(f"interrupted at ADMM iteration {result.iterations}: the matrix written is the current iterate{saved}")
    elif not result.converged:
        _warn(f"the all-pairs ADMM did not converge in {result.iterations} iterations; the matrix written is "
              f"approximate{saved}")
    np.save(args.output, result.distance)
    if not args.quiet:
        print(f"{os.path.basename(args.mesh)}: {mesh.n_vertices} vertices. All-pairs regularized distance, "
              f"alpha_hat {args.alpha_hat:g}, {args.dtype}: {result.iterations} ADMM iterations, "
              f"{'converged' if result.converged else 'NOT converged'}, {result.seconds:.2f} s, "
              f"{result.memory_bytes / 1e9:.2f} GB. Largest distance {result.distance.max():.4g}. Wrote {args.output}.")


def _add_matrix_parser(sub, solver_options) -> None:
    matrix = sub.add_parser(
        "matrix",
        help="distance matrix of single-source rows, written block by block to .zarr or .npy (resumable)",
        description="Rows of regularized distances from many source vertices (batched single-source\n"
        "solves), written block by block to a Zarr array or a .npy file, never all in memory; the\n"
        "same command run again resumes (blocks already written are skipped). With --workers or\n"
        "--scheduler the blocks are tasks on a Dask cluster (pip install 'warp-regdist[distributed]').",
        epilog=_EXIT_STATUS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    matrix.add_argument("mesh", metavar="MESH", help="triangle or tetrahedral mesh file")
    matrix.add_argument(
        "--sources",
        default="all",
        metavar="all|FILE",
        help="'all' (default: a row per vertex) or a text file of 0-based vertex indices separated by "
        "spaces, commas or newlines (a row per index, in the file's order)",
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
    solver_options(matrix)


def _matrix_sources(text: str):
    """None for 'all', else the vertex indices listed in the file ``text``."""
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
    return np.array([int(item) for item in items], dtype=np.int64)


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
    if args.workers < 1:
        raise ValueError(f"expected --workers as an integer >= 1, got {args.workers}")
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


def _matrix(args: argparse.Namespace) -> None:
    import contextlib

    import warp as wp

    from . import distance_matrix

    if not (args.output.lower().endswith(".zarr") and os.path.isdir(args.output)):  # a Zarr store is a directory
        _check_output(args.output, (".zarr", ".npy"), "--output")
    mesh = _load(args.mesh)
    sources = _matrix_sources(args.sources)
    wp.config.log_level = wp.LOG_WARNING
    progress, state = _matrix_progress(args.quiet)
    with contextlib.ExitStack() as stack, _warnings_to_stderr():
        client = _dask_client(args, stack)
        try:
            D = distance_matrix(mesh, args.alpha_hat, sources=sources, symmetrize=args.symmetrize,
                                device=args.device, dtype=args.dtype, chunk=args.chunk, client=client,
                                out=args.output, progress=progress)
        except ImportError as exc:
            raise ValueError(f"expected zarr for a .zarr --output (pip install 'warp-regdist[distributed]'), "
                             f"got {exc}") from None
        except KeyboardInterrupt:
            print(f"{PROG}: interrupted; the blocks written so far stay in {args.output}: run the same command "
                  "again to resume", file=sys.stderr)
            raise SystemExit(130) from None
    if not args.quiet:
        where = "here" if client is None else f"on a Dask cluster ({args.scheduler or f'{args.workers} workers'})"
        print(f"{os.path.basename(args.mesh)}: {mesh.n_vertices} vertices. Distance matrix of {D.shape[0]} "
              f"single-source rows, alpha_hat {args.alpha_hat:g}, {args.dtype}, "
              f"{'symmetrized' if args.symmetrize else 'not symmetrized'}: {-(-D.shape[0] // args.chunk)} blocks of "
              f"{args.chunk} rows ({state['found']} already written), solved {where} in {state['seconds']:.1f} s. "
              f"Wrote {args.output}.")


def _add_volume_parser(sub, solver_options) -> None:
    volume = sub.add_parser(
        "volume",
        help="tetrahedralize a closed surface, then the distance inside it (.vtu, optional grid)",
        description="Fill a closed triangle surface (STL, OBJ, OFF, PLY) with tetrahedra (TetGen,\n"
        "pip install 'warp-regdist[volume]'), solve the regularized distance inside from the\n"
        "boundary or from points, write it per vertex (.vtu) and optionally sampled on a regular\n"
        "grid (NaN outside the solid) for SDF-like use.",
        epilog=_EXIT_STATUS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    volume.add_argument("surface", metavar="SURFACE", help="closed triangle surface (.stl, .obj, .off, .ply)")
    volume.add_argument(
        "--sources",
        required=True,
        metavar="boundary|FILE",
        help="'boundary' (distance to the surface: depth) or a .csv file of rows 'x,y,z', each point "
        "snapped to the nearest vertex of the tetrahedral mesh (said in the output)",
    )
    volume.add_argument("--alpha-hat", type=float, default=DEMO_ALPHA_HAT, metavar="A",
                        help="scale-invariant regularization weight >= 0; alpha = A volume^(1/3) (default: 0.05)")
    volume.add_argument("--output", required=True, metavar="FILE",
                        help="the tetrahedral mesh with point data 'distance' (.vtu, opens in ParaView)")
    volume.add_argument("--png", metavar="FILE", help="also write the distance's cut by the plane z = centre (.png)")
    volume.add_argument("--grid", type=int, metavar="N",
                        help="also sample the distance on a regular grid of N points along the longest side "
                        "of the bounding box (needs --grid-output)")
    volume.add_argument("--grid-output", metavar="FILE",
                        help="the grid samples: .npy (nx, ny, nz) array, or .npz with 'values', 'origin' and "
                        "'spacing' (point (i, j, k) at origin + spacing (i, j, k)); NaN outside the solid")
    volume.add_argument("--max-edge", type=float, metavar="L",
                        help="longest interior edge in the surface's units (default without --max-volume: the "
                        "smaller of the surface's mean edge and alpha = A volume^(1/3), so the interior resolves "
                        "the distance's smooth cap)")
    volume.add_argument("--max-volume", type=float, metavar="V",
                        help="largest tetrahedron volume in the surface's units cubed (replaces the default --max-edge)")
    volume.add_argument("--quality", type=float, default=1.5, metavar="Q",
                        help="largest radius-edge ratio of a tetrahedron, > 1 (default: 1.5)")
    solver_options(volume)


def _read_points(path: str) -> np.ndarray:
    """(k, 3) points from the rows 'x,y,z' of a .csv file (--sources of ``volume``)."""
    if not path.lower().endswith(".csv"):
        raise ValueError(f"expected --sources 'boundary' or a .csv file of 'x,y,z' rows, got {path!r}")
    if not os.path.isfile(path):
        raise ValueError(f"expected --sources as an existing .csv file of 'x,y,z' rows, got {path!r} (no such file)")
    from .arguments import read_csv_rows

    points = read_csv_rows(path, "x,y,z", "--sources")
    if not np.isfinite(points).all():
        raise ValueError(f"expected finite --sources coordinates, got NaN or inf in {path!r}")
    return points


def _volume(args: argparse.Namespace) -> None:
    import time

    from scipy.spatial import cKDTree

    from .export import save_vtu
    from .render import render_cut
    from .tetrahedralize import tetrahedralize
    from .volume_grid import sample_on_grid

    _check_output(args.output, (".vtu",), "--output")
    if args.png is not None:
        _check_output(args.png, (".png",), "--png")
    if (args.grid is None) != (args.grid_output is None):
        raise ValueError("expected --grid N and --grid-output FILE together, got only "
                         f"{'--grid' if args.grid_output is None else '--grid-output'}")
    if args.grid is not None:
        _check_output(args.grid_output, (".npy", ".npz"), "--grid-output")
        if args.grid < 2:
            raise ValueError(f"expected --grid N >= 2, got {args.grid}")
    if args.max_edge is not None and not (np.isfinite(args.max_edge) and args.max_edge > 0):
        raise ValueError(f"expected --max-edge as a length > 0, got {args.max_edge}")
    points = None if args.sources.strip().lower() == "boundary" else _read_points(args.sources)
    surface = _load(args.surface)
    name = os.path.basename(args.surface)
    say = (lambda text: None) if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    say(f"{name}: tetrahedralizing {surface.n_vertices} vertices, {surface.n_elements} faces with TetGen...")
    start = time.perf_counter()
    try:
        max_edge = "auto" if args.max_edge is None else args.max_edge
        mesh = tetrahedralize(surface, max_volume=args.max_volume, quality=args.quality, max_edge=max_edge,
                              alpha_hat=args.alpha_hat)
    except ModuleNotFoundError as exc:
        raise ValueError(str(exc)) from None
    if args.max_edge is None and args.max_volume is None:
        from .tetrahedralize import interior_edge

        max_edge = interior_edge(surface.vertices, surface.faces, args.alpha_hat)
    bounds = "" if max_edge == "auto" else f", max edge {max_edge:.3g}"
    bounds += "" if args.max_volume is None else f", max volume {args.max_volume:g}"
    meshed = (f"TetGen: {mesh.n_elements} tetrahedra (quality {args.quality:g}{bounds}, "
              f"{mesh.components().max() + 1} connected component(s)) in {time.perf_counter() - start:.2f} s")
    say(meshed)
    if points is None:
        sources, described = _parse_sources(args.sources, mesh)
    else:
        moved, nearest = cKDTree(mesh.vertices).query(points)
        sources = np.unique(nearest).astype(np.int64)
        listed = ", ".join(str(s) for s in sources[:_LISTED_SOURCES])
        more = f", ... ({sources.size} in all)" if sources.size > _LISTED_SOURCES else ""
        described = (f"{len(points)} points snapped to the nearest vertices {listed}{more} (moved by at most "
                     f"{moved.max():.3g}; point sources do not exist yet)")
    solver, result = _solve(mesh, sources, args.alpha_hat, args.device, args.dtype, verbose=not args.quiet)
    save_vtu(args.output, mesh, {"distance": result.distance})
    written = [args.output]
    if args.png is not None:
        render_cut(mesh, result.distance, args.png,
                   title=f"{name}: regularized distance, alpha_hat {solver.alpha_hat:g}, cut z = centre")
        written.append(args.png)
    if args.grid is not None:
        say(f"sampling the distance on a grid of {args.grid} points along the longest side...")
        grid = sample_on_grid(mesh, result.distance, args.grid)
        if args.grid_output.lower().endswith(".npz"):
            np.savez(args.grid_output, values=grid.values, origin=grid.origin, spacing=grid.spacing)
        else:
            np.save(args.grid_output, grid.values)
        written.append(f"{args.grid_output} ({' x '.join(map(str, grid.values.shape))} grid, origin "
                       f"{np.array2string(grid.origin, precision=4, separator=', ')}, spacing {grid.spacing:.4g}, "
                       "NaN outside)")
    if not args.quiet:
        print(f"{meshed}. " + _summary(name, mesh, described, solver, result, written))


def _demo(args: argparse.Namespace) -> None:
    from .render import render_distance

    if os.path.exists(args.output) and not os.path.isdir(args.output):
        raise ValueError(f"expected --output as a directory, got the file {args.output!r}")
    os.makedirs(args.output, exist_ok=True)
    npy = os.path.join(args.output, "distance.npy")
    png = os.path.join(args.output, "distance.png")
    with importlib.resources.as_file(importlib.resources.files("warp_regdist") / "data" / "spot_rr.off") as path:
        mesh = _load(os.fspath(path))
    if not args.quiet:
        print(
            f"Demo: spot cow ({mesh.n_vertices} vertices, {mesh.n_elements} faces), source vertex "
            f"{DEMO_SOURCE}, alpha_hat {DEMO_ALPHA_HAT}, {args.dtype}. Solving...",
            flush=True,
        )
    solver, result = _solve(mesh, [DEMO_SOURCE], DEMO_ALPHA_HAT, args.device, args.dtype)
    np.save(npy, result.distance)
    title = f"spot: regularized geodesic distance from vertex {DEMO_SOURCE}, alpha_hat {DEMO_ALPHA_HAT:g}"
    render_distance(mesh, result.distance, png, sources=[DEMO_SOURCE], title=title)
    if not args.quiet:
        print(_summary("spot_rr.off", mesh, f"source vertex {DEMO_SOURCE}", solver, result, [npy, png]))


def main(argv: list[str] | None = None) -> int:
    """Run the ``warp-regdist`` command line; returns the exit status.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
        0 on success (also when the ADMM did not converge: a warning line goes to
        stderr), 2 on bad input or bad usage (one ``warp-regdist: error:`` line).
    """
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:  # --help, --version and usage errors
        return exc.code if isinstance(exc.code, int) else 2
    try:
        {"demo": _demo, "distance": _distance, "allpairs": _allpairs, "matrix": _matrix, "volume": _volume,
         "view": _view}[args.command](args)
    except (ValueError, OSError) as exc:  # MeshError is a ValueError
        message = " ".join(str(exc).split())
        print(f"{PROG}: error: {message}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
