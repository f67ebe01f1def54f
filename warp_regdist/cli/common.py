"""What the subcommands share: the exit-status text, the solver options, output checks,
source parsing, loading, one solve with its warnings on stderr, and the summary line."""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import signal
import sys
import warnings

import numpy as np

PROG = "warp-regdist"
DEMO_SOURCE = 2272
DEMO_ALPHA_HAT = 0.05
OUTPUT_EXTENSIONS = (".npy", ".csv", ".vtu")
LISTED_SOURCES = 8  # sources named one by one in the summary
PICTURE_BYTES = 4_000_000  # at most the bytes of a --png picture, for the room check before a solve

EXIT_STATUS = """\
exit status (the same for every subcommand):
  0    done: the output was written and the solve converged
  1    the output was written, but the solve stopped without meeting its stopping
       test (the iteration cap): a line 'warp-regdist: warning: ...' says so and
       the values are approximate
  2    bad input or environment (missing or unreadable mesh, bad --sources,
       unsupported output, unavailable device, no room on the disk, a worker
       process that died, ...): one line 'warp-regdist: error: ...'
  130  interrupted (Ctrl-C): what was computed so far is kept as the
       subcommand's warning says (a second Ctrl-C stops at once)
  143  terminated (SIGTERM, what batch schedulers send before a kill): as for 130,
       the run stops at the end of its iteration and keeps its work
"""


def stop_status() -> int:
    """The exit status of a stopped run: 143 for SIGTERM, else 130 (Ctrl-C)."""
    from ..solvers.common.interrupt import stopped_by

    return 143 if stopped_by() == signal.SIGTERM else 130


def stop_word() -> str:
    """How a stopped run was stopped, for its messages: "terminated (SIGTERM)" or "interrupted"."""
    return "terminated (SIGTERM)" if stop_status() == 143 else "interrupted"


def exit_status(result) -> int:
    """The exit status of a written result: 130 or 143 stopped, 1 not converged (any column), else 0."""
    if getattr(result, "interrupted", False):
        return stop_status()
    return 0 if np.all(result.converged) else 1


def quiet_warp(verbose: bool) -> None:
    """Warp's messages (start-up banner, module loads, where Warp prints them) with ``verbose``, else none."""
    import warp as wp

    wp.config.log_level = wp.LOG_INFO if verbose else wp.LOG_WARNING


def announce_compile(dtype: str, quiet: bool) -> None:
    """Say so before a solve whose Warp kernels of ``dtype`` are not in the kernel cache yet."""
    import warp as wp

    from ..arguments import parse_device

    if quiet:
        return
    parse_device("cpu")  # initializes Warp, which sets the cache folder
    folder = wp.config.kernel_cache_dir
    names = os.listdir(folder) if folder and os.path.isdir(folder) else []
    if not any("warp_regdist_" in name and f"_{dtype}_" in name for name in names):
        print(f"{PROG}: compiling the Warp kernels for {dtype}, once (seconds to a minute; they are cached in "
              f"{folder})", file=sys.stderr, flush=True)


def subcommand(sub, name: str, help: str, description: str) -> argparse.ArgumentParser:
    """A subcommand's parser, with the exit-status epilog and the description's line breaks kept."""
    return sub.add_parser(name, help=help, description=description, epilog=EXIT_STATUS,
                          formatter_class=argparse.RawDescriptionHelpFormatter)


def source_triangles_option(p: argparse.ArgumentParser) -> None:
    """--source-triangles."""
    p.add_argument(
        "--source-triangles",
        choices=("edges", "gradient"),
        default=None,
        help="the bound on a triangle with one source corner: 'edges' u <= the side lengths from the source "
        "(default on triangle meshes), 'gradient' |grad u| <= 1 as on every other triangle (the paper's problem)",
    )


def solver_options(p: argparse.ArgumentParser) -> None:
    """--device, --dtype, --quiet, --verbose."""
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
    p.add_argument("--verbose", action="store_true", help="also print Warp's messages (start-up, module loads)")


def check_output(path: str, extensions: tuple[str, ...], option: str) -> None:
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


def read_xyz(path: str, option: str) -> np.ndarray:
    """(k, 3) points from the rows 'x,y,z' of a .csv file given to ``option``."""
    from ..arguments import read_csv_rows

    if not os.path.isfile(path):
        raise ValueError(f"expected {option} as an existing .csv file of 'x,y,z' rows, got {path!r} (no such file)")
    points = read_csv_rows(path, "x,y,z", option)
    if not np.isfinite(points).all():
        raise ValueError(f"expected finite {option} coordinates, got NaN or inf in {path!r}")
    return points


def max_distance_option(p: argparse.ArgumentParser) -> None:
    """--max-distance, for the commands that read points from a .csv file."""
    p.add_argument("--max-distance", type=float, default=None, metavar="D",
                   help="the farthest a point of a .csv file may lie from the surface, in the mesh's units; "
                   "it is moved to its closest surface point (default: 5%% of the bounding box diagonal; "
                   "inf: any distance)")


def parse_surface_points(path: str, mesh, option: str, max_distance: float | None = None) -> tuple[list, str]:
    """Surface points [(face, barycentric)] of the rows of a .csv file and their description."""
    from .. import surface_points

    xyz = read_xyz(path, option)
    if mesh.element_dim != 2:
        raise ValueError(f"expected a triangle mesh for {option} given as points ({path!r}), got a tetrahedral mesh "
                         "(give vertex indices)")
    if max_distance is not None and not max_distance > 0:
        raise ValueError(f"expected --max-distance > 0, got {max_distance!r}")
    points, moved = surface_points(mesh, xyz, return_distance=True, max_distance=max_distance)
    return points, f"{len(points)} surface points of {os.path.basename(path)} (moved onto the surface by at most {moved.max():.3g})"


def parse_sources(text: str, mesh) -> tuple[np.ndarray, str]:
    """Source vertex indices (s,) of ``mesh`` (given in its file's numbering) and their description."""
    from .. import boundary_vertices

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
    n = mesh.n_vertices if mesh.input_index is None else mesh.input_index.size
    sources = vertex_indices([int(item) for item in items], n, "--sources")
    listed = ", ".join(str(s) for s in sources[:LISTED_SOURCES])
    more = f", ... ({sources.size} in all)" if sources.size > LISTED_SOURCES else ""
    noun = "vertex" if sources.size == 1 else "vertices"
    return file_indices(mesh, sources), f"source {noun} {listed}{more}"


def vertex_indices(values: list[int], n: int, option: str) -> np.ndarray:
    """Sorted distinct (s,) int64 of the Python ints ``values``; ValueError for one outside [0, n - 1]
    (checked before the conversion, so that no number is too large for it)."""
    bad = [v for v in values if not 0 <= v < n]
    if bad:
        raise ValueError(f"expected {option} in [0, {n - 1}] (the mesh has {n} vertices), got {bad[0]}")
    return np.unique(np.array(values, dtype=np.int64))


def write_values(path: str, values: np.ndarray) -> None:
    """``values`` as .npy (the array) or .csv (a value per line, full precision), written atomically."""
    from ..atomic_write import write_atomic

    if path.lower().endswith(".npy"):
        write_atomic(path, lambda tmp: np.save(tmp, values), "--output", size=values.nbytes + 128)
    else:
        def write_csv(tmp):
            with open(tmp, "w", encoding="ascii") as f:
                f.writelines(f"{float(v)!r}\n" for v in values)

        write_atomic(path, write_csv, "--output")


def values_bytes(path: str, n_values: int, n_elements: int = 0) -> int:
    """An upper bound of the bytes of an output of ``n_values`` values (.npy, .csv; .vtu with the mesh's
    ``n_elements`` elements too), for the room check before a solve."""
    ext = os.path.splitext(path)[1].lower()
    if ext == ".npy":
        return 8 * n_values + 128
    if ext == ".csv":
        return 26 * n_values
    return 64 * (n_values + n_elements) + 4096


def write_or_rescue(path: str, values: np.ndarray, what: str, called: str, elsewhere: str | None = None,
                    kept: str = "", write=None) -> None:
    """Write ``values`` to ``path`` (``write(path)``, default :func:`write_values`); when that fails
    (a disk that filled during the run) raise a WriteError that says where ``called`` (the result)
    is: ``elsewhere`` when given, else a .npy copy written to the temporary directory."""
    import tempfile

    from ..atomic_write import write_atomic
    from ..errors import WriteError

    try:
        (write or (lambda target: write_values(target, values)))(path)
        return
    except WriteError as exc:
        failed = exc
    if elsewhere is not None:
        raise WriteError(f"{failed}; {elsewhere}", failed.errno) from None
    stem = os.path.splitext(os.path.basename(path))[0]
    rescue = os.path.join(tempfile.gettempdir(), f"warp-regdist-{os.getpid()}-{stem}.npy")
    try:
        write_atomic(rescue, lambda tmp: np.save(tmp, values), f"the copy of {what}", size=values.nbytes + 128)
    except WriteError:
        raise WriteError(f"{failed}; no copy could be written to {tempfile.gettempdir()!r} either: {called} is "
                         f"lost{kept}", failed.errno) from None
    raise WriteError(f"{failed}; {called} was written to {rescue!r} instead{kept}", failed.errno) from None


def warn(message: str) -> None:
    print(f"{PROG}: warning: {message}", file=sys.stderr)


@contextlib.contextmanager
def warnings_to_stderr(reported_by_caller=()):
    """Record the warnings of the block, then print each as one 'warp-regdist: warning: ...'
    line, except those of the categories ``reported_by_caller`` (a tuple of classes). Yields a
    list that holds the categories of all of them after the block."""
    seen = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield seen
    finally:
        for w in caught:
            seen.append(w.category)
            if not issubclass(w.category, reported_by_caller):
                warn(str(w.message))


def max_iterations_option(p: argparse.ArgumentParser) -> None:
    """--max-iterations, for the commands that run single-source solves."""
    p.add_argument("--max-iterations", type=int, default=None, metavar="N",
                   help="ADMM iteration cap of each solve (default: 10000)")


def single_source_options(args: argparse.Namespace):
    """The SolverOptions of --max-iterations."""
    from ..options import SolverOptions

    return SolverOptions() if args.max_iterations is None else SolverOptions(max_iterations=args.max_iterations)


def solve(mesh, sources, alpha_hat: float, device: str | None, dtype: str, verbose: bool = False,
          where=None, quiet: bool = False, options=None, **regularization):
    """Solve once; returns (solver, result), reporting non-convergence on stderr
    (and, with ``verbose``, the ADMM's progress every 2 s on stderr; unless ``quiet``, a first
    compile of the kernels). ``where``: the
    DistanceSolver.solve keywords points, curve, closed; ``regularization``: the DistanceSolver
    keywords regularizer, beta_hat, vector_field."""
    from .. import ConvergenceWarning, DistanceSolver

    solver = DistanceSolver(mesh, alpha_hat=alpha_hat, device=device, dtype=dtype, options=options, **regularization)
    announce_compile(dtype, quiet)
    with warnings_to_stderr(reported_by_caller=(ConvergenceWarning,)):
        result = solver.solve(sources, verbose=verbose, **(where or {}))
    if result.interrupted:
        warn(f"{stop_word()} at ADMM iteration {result.iterations}: the distance written is the current iterate")
    elif not result.converged:
        warn(
            f"the ADMM did not converge in {result.iterations} iterations (primal residual "
            f"{result.primal_residual:.3g}, dual residual {result.dual_residual:.3g}); the "
            "distance written is approximate"
        )
    return solver, result


def repair_option(p: argparse.ArgumentParser) -> None:
    """--repair, for the commands that read a triangle mesh."""
    p.add_argument("--repair", action="store_true",
                   help="merge vertices at one position, weld cracks, drop degenerate faces and cut non-manifold "
                   "edges (a warning says what changed); vertex indices and outputs stay those of the file")


def load(path: str, repair: bool = False):
    """The mesh of a mesh file (``repair``: repaired, its ``input_index`` mapping the file's vertices),
    or the PointCloud of a point file (.xyz, .npy, a PLY without faces)."""
    from .. import MeshError, load_mesh
    from ..geometry.mesh_io import load_points

    with warnings_to_stderr():
        if path.lower().endswith((".xyz", ".npy")):
            return load_points(path)
        try:
            return load_mesh(path, repair=repair)
        except MeshError as exc:
            if path.lower().endswith(".ply") and "got none (empty file, or a point cloud)" in str(exc):
                return load_points(path)
            raise MeshError(str(exc).replace("load_mesh(path, repair=True) or warp_regdist.repair_mesh(vertices, "
                                             "faces)", "--repair")) from None


def file_indices(mesh, sources: np.ndarray) -> np.ndarray:
    """Vertex indices of the file as indices of ``mesh`` (the same unless it was repaired)."""
    return sources if mesh.input_index is None else np.unique(mesh.input_index[sources])


def file_values(mesh, values: np.ndarray) -> np.ndarray:
    """Per-vertex values of ``mesh`` per vertex of its file (the same unless it was repaired)."""
    return values if mesh.input_index is None else values[mesh.input_index]


def estimated_error(estimate: float) -> str:
    """``estimate`` (a fraction of the largest distance) for a summary line; inf before the first estimate."""
    return f"estimated error {estimate:.2%}" if np.isfinite(estimate) else "error not yet estimated"


def summary(name: str, mesh, described: str, solver, result, written: list[str]) -> str:
    status = "converged" if result.converged else "NOT converged"
    elements = "faces" if mesh.element_dim == 2 else "tetrahedra"
    vertices = "vertices"
    if mesh.element_weights is not None:
        vertices, elements = "points", "local triangles"
    accuracy = (f"polished: moved {result.polish_change:.2%}" if "polish_change" in result
                else estimated_error(result.error_estimate))
    return (
        f"{name}: {mesh.n_vertices} {vertices}, {mesh.n_elements} {elements}. Regularized geodesic "
        f"distance from {described}, {solver.regularizer.name} regularizer, alpha_hat {solver.alpha_hat:g} "
        f"(alpha {solver.alpha:.4g}), "
        f"on {solver.device} in {solver.dtype}: {result.iterations} ADMM iterations, {status} "
        f"(primal residual {result.primal_residual:.3g}, dual residual {result.dual_residual:.3g}, "
        f"{accuracy} of the largest distance), "
        f"{result.seconds:.2f} s. Largest finite distance "
        f"{finite_max(result.distance):.4g}. Wrote {', '.join(written)}."
    )


def finite_max(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite.max()) if finite.size else float("nan")
