"""The ``allpairs`` subcommand: the symmetric all-pairs matrix, with checkpoints."""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from .common import (announce_compile, check_output, estimated_error, exit_status, load, repair_option,
                     solver_options, source_triangles_option, stop_word, subcommand, warn, warnings_to_stderr,
                     write_or_rescue)


LOCKED_OUTPUTS = ("output",)


def add_parser(sub) -> None:
    allpairs = subcommand(
        sub, "allpairs",
        help="symmetric all-pairs distance matrix (n x n), written as .npy",
        description="All-pairs regularized distance matrix on a connected triangle mesh (Algorithm 2,\n"
        "symmetric by construction), written as an (n, n) float64 .npy; progress on stderr.",
    )
    allpairs.add_argument("mesh", metavar="MESH", help="triangle mesh file (.obj, .off, .ply, .stl)")
    allpairs.add_argument(
        "--alpha-hat",
        type=float,
        default=0.03,
        metavar="A",
        help="scale-invariant regularization weight >= 0; alpha = A sqrt(area) (default: 0.03)",
    )
    allpairs.add_argument("--accuracy", type=float, default=None, metavar="E",
                          help="the max error accepted, as a fraction of the max distance, in (0, 0.1]: the stopping "
                          "tolerances follow from it (default: 0.005, the defaults of AllPairsOptions)")
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
    allpairs.add_argument("--restart", action="store_true",
                          help="start over although --checkpoint names a file that holds a run's progress (it is "
                          "overwritten); without it such a --checkpoint is refused unless it is the --resume file")
    allpairs.add_argument("--initial", metavar="FILE",
                          help="warm start from a checkpoint of this mesh and dtype at another alpha_hat")
    allpairs.add_argument("--max-iterations", type=int, default=None, metavar="N",
                          help="ADMM iteration cap (default: twice the typical iterations at the mesh's size and "
                          "accuracy, at least 3000; the first line says it)")
    allpairs.add_argument("--workers", type=int, default=None, metavar="N",
                          help="CPU processes sharing every step of the consensus engine (default: the cores available)")
    allpairs.add_argument("--engine", choices=("auto", "eigenbasis", "consensus"), default="auto",
                          help="the splitting: eigenbasis (exact dense U-step, small meshes), consensus (PCG, any size); "
                          "auto: eigenbasis on the CPU up to 3,000 vertices (default: auto)")
    repair_option(allpairs)
    source_triangles_option(allpairs)
    solver_options(allpairs)


def _allpairs_progress(banner, forecast):
    """A callback for ``all_pairs`` printing to stderr: ``banner`` before the engine's setup (when the run's
    arguments have been checked, so that a refusal is the only line), a line after a few iterations, one line per
    check window (every stop test against its threshold), both with the time an iteration takes, what the
    typical iterations of ``forecast`` (a RunForecast) leave at that rate and the most the run can still
    take to its cap; and once a line when the run is not settling."""
    first, told, warned = [], [], []

    def show(progress):
        if not progress.tests:
            print(banner, file=sys.stderr, flush=True)
            return
        if not first:
            first.append((progress.iteration, progress.seconds))
        start, t0 = first[0]
        done = progress.iteration - start
        rate = (progress.seconds - t0) / done if done > 0 else 0.0
        if not (progress.checked or not told and done >= 5) or rate <= 0:
            return
        told.append(True)
        cap, k = forecast.max_iterations, progress.iteration
        typical = (f"about {_duration(rate * (forecast.iterations - k))} to the typical {forecast.iterations}, "
                   if k < forecast.iterations else "")
        ahead = f"{rate:.2g} s/iteration; {typical}at most {_duration(rate * (cap - k))} to the cap {cap}"
        print(f"  {progress}; {ahead}" if progress.checked else f"  iteration {k}: {ahead}", file=sys.stderr,
              flush=True)
        if not progress.settling and not warned:
            warned.append(True)
            print("  not settling: the change still to come has reached no new low for many checks, so the run "
                  "may end at its cap unconverged; a larger --accuracy stops sooner, and Ctrl-C keeps the current "
                  "iterate", file=sys.stderr, flush=True)

    return show


def _duration(seconds: float) -> str:
    """'42 s', '7 min', '2.5 h'."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.0f} min" if seconds < 5400 else f"{seconds / 3600:.1f} h"


def run(args: argparse.Namespace) -> int:
    from .. import AllPairsOptions, AllPairsSolver, ConvergenceWarning
    from ..atomic_write import check_room
    from ..solvers.all_pairs.checkpoint import check_no_progress, checkpoint_bytes, checkpoint_room
    from ..solvers.all_pairs.forecast import with_cap

    check_output(args.output, (".npy",), "--output")
    if args.checkpoint is not None:
        check_output(args.checkpoint, (".npz",), "--checkpoint")
        if not args.restart:
            check_no_progress(args.checkpoint, args.resume, ("--checkpoint", "--resume ", "--restart"))
    if args.restart and args.resume is not None and (args.checkpoint is None or os.path.abspath(args.checkpoint)
                                                     == os.path.abspath(args.resume)):
        raise ValueError(f"expected --restart (start over) or --resume {args.resume} (continue it), got both; "
                         "--restart with --resume only lets a resumed run overwrite another --checkpoint")
    for flag, path in (("--resume", args.resume), ("--initial", args.initial)):
        if path is not None and not os.path.isfile(path):
            raise ValueError(f"expected {flag} as an existing checkpoint file, got {path!r} (no such file)")
    mesh = load(args.mesh, args.repair)
    n = mesh.n_vertices if mesh.input_index is None else mesh.input_index.size
    asked = AllPairsOptions() if args.accuracy is None else AllPairsOptions.for_accuracy(args.accuracy)
    args.max_iterations = with_cap(mesh.n_vertices, asked.replace(max_iterations=args.max_iterations)).max_iterations
    planned = [(args.output, 8 * n * n + 128, "--output")]
    if args.checkpoint is not None:
        size = checkpoint_bytes(mesh.n_vertices, mesh.n_elements, args.dtype, args.max_iterations)
        planned.append(checkpoint_room(args.checkpoint, size))
    check_room(planned)
    announce_compile(args.dtype, args.quiet)
    with warnings_to_stderr(reported_by_caller=(ConvergenceWarning,)):
        solver = AllPairsSolver(mesh, args.alpha_hat, device=args.device, dtype=args.dtype, workers=args.workers,
                                options=AllPairsOptions(engine=args.engine), source_triangles=args.source_triangles)
        forecast = solver.forecast(accuracy=args.accuracy, max_iterations=args.max_iterations)
        banner = (f"{os.path.basename(args.mesh)}: {forecast}; the {forecast.engine} engine's setup, then a progress "
                  f"line every {solver.options.change_window} iterations")
        result = solver.solve(callback=None if args.quiet else _allpairs_progress(banner, forecast),
                              max_iterations=args.max_iterations,
                              checkpoint=args.checkpoint, checkpoint_seconds=args.checkpoint_seconds,
                              resume=args.resume, initial=args.initial, accuracy=args.accuracy, restart=args.restart)
    if not result.converged:
        warn(_unconverged(result, args))
    U = result.distance if mesh.input_index is None else result.distance[np.ix_(mesh.input_index, mesh.input_index)]
    write_matrix(args.output, U, args.checkpoint, result)
    if not args.quiet:
        print(f"{os.path.basename(args.mesh)}: {n} vertices. All-pairs regularized distance, "
              f"alpha_hat {args.alpha_hat:g}, {args.dtype}: {result.iterations} ADMM iterations ({result.engine} engine), "
              f"{'converged' if result.converged else 'NOT converged'}, {result.seconds:.2f} s, "
              f"{result.memory_bytes / 1e9:.2f} GB, {estimated_error(result.error_estimate)} and gradient excess "
              f"{result.gradient_excess:.2%} of the largest distance {result.distance.max():.4g}. Wrote {args.output}.")
    return exit_status(result)


def _unconverged(result, args) -> str:
    """The warning for an unconverged ``result``: why it stopped and the command that continues it."""
    at_cap = not result.interrupted and result.iterations >= args.max_iterations
    if result.interrupted:
        what = f"{stop_word()} at ADMM iteration {result.iterations}: the matrix written is the current iterate"
    elif at_cap:
        what = f"the all-pairs ADMM did not converge in {result.iterations} iterations; the matrix written is approximate"
    else:
        return (f"the all-pairs ADMM stopped at iteration {result.iterations} with |grad U| above unit speed (gradient "
                f"excess {result.gradient_excess:.2%}): the matrix written is approximate; a smaller --accuracy "
                "iterates longer")
    if result.get("checkpoint_iteration") is None:
        return what + ("; with --checkpoint FILE a rerun could be continued by --resume FILE" if at_cap else "")
    more = f" --max-iterations {2 * result.iterations}" if at_cap else ""
    return (f"{what}; the solver state of iteration {result.checkpoint_iteration} is in {args.checkpoint} (continue "
            f"with --resume {args.checkpoint}{more})")


def write_matrix(path: str, U: np.ndarray, checkpoint: str | None, result) -> None:
    """``U`` to ``path`` atomically; when that fails (a disk that filled during the run), the error
    says where the matrix is: in the checkpoint when it holds the final iterate, else in a copy
    written to the temporary directory (and what the checkpoint holds)."""
    saved = result.get("checkpoint_iteration")
    if checkpoint is not None and saved is not None and saved == result.iterations:
        elsewhere = (f"the matrix is in the checkpoint {checkpoint!r}: run the same command with --resume "
                     f"{checkpoint} and an --output where there is room")
    else:
        elsewhere = None
    kept = (f"; the checkpoint {checkpoint!r} holds iteration {saved} of {result.iterations}"
            if checkpoint is not None and saved is not None and elsewhere is None else "")
    write_or_rescue(path, U, "--output", "the matrix", elsewhere, kept)
