"""The ``allpairs`` subcommand: the symmetric all-pairs matrix, with checkpoints."""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from .common import check_output, load, solver_options, subcommand, warn, warnings_to_stderr


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
                          "tolerances follow from it (default: the tolerances' settings)")
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


def _allpairs_progress():
    """A progress callback for ``all_pairs`` printing one stderr line per ~2 s (and the last
    iteration): iteration, the seven residuals / their tolerances, elapsed time, memory."""
    from ..solvers.results import RESIDUAL_NAMES

    last = [-10.0]

    def show(iteration, residuals, tolerance, seconds, memory):
        if seconds - last[0] < 2.0 and np.any(residuals > tolerance):
            return
        last[0] = seconds
        parts = " ".join(f"{k} {r:.2e}/{t:.2e}" for k, r, t in zip(RESIDUAL_NAMES, residuals, tolerance))
        print(f"  iteration {iteration}: {parts} (residual/tolerance), {seconds:.1f} s, {memory / 1e9:.2f} GB",
              file=sys.stderr, flush=True)

    return show


def run(args: argparse.Namespace) -> None:
    import warp as wp

    from .. import ConvergenceWarning, all_pairs

    check_output(args.output, (".npy",), "--output")
    if args.checkpoint is not None:
        check_output(args.checkpoint, (".npz",), "--checkpoint")
    for flag, path in (("--resume", args.resume), ("--initial", args.initial)):
        if path is not None and not os.path.isfile(path):
            raise ValueError(f"expected {flag} as an existing checkpoint file, got {path!r} (no such file)")
    mesh = load(args.mesh)
    wp.config.log_level = wp.LOG_WARNING
    with warnings_to_stderr(reported_by_caller=(ConvergenceWarning,)):
        result = all_pairs(mesh, args.alpha_hat, device=args.device, dtype=args.dtype,
                           progress=None if args.quiet else _allpairs_progress(), max_iterations=args.max_iterations,
                           workers=args.workers, checkpoint=args.checkpoint, checkpoint_seconds=args.checkpoint_seconds,
                           resume=args.resume, initial=args.initial, accuracy=args.accuracy)
    saved = f"; the solver state is in {args.checkpoint} (continue with --resume {args.checkpoint})" \
        if args.checkpoint is not None else ""
    if result.interrupted:
        warn(f"interrupted at ADMM iteration {result.iterations}: the matrix written is the current iterate{saved}")
    elif not result.converged:
        warn(f"the all-pairs ADMM did not converge in {result.iterations} iterations; the matrix written is "
              f"approximate{saved}")
    np.save(args.output, result.distance)
    if not args.quiet:
        print(f"{os.path.basename(args.mesh)}: {mesh.n_vertices} vertices. All-pairs regularized distance, "
              f"alpha_hat {args.alpha_hat:g}, {args.dtype}: {result.iterations} ADMM iterations, "
              f"{'converged' if result.converged else 'NOT converged'}, {result.seconds:.2f} s, "
              f"{result.memory_bytes / 1e9:.2f} GB, estimated error {result.error_estimate:.2%} and gradient excess "
              f"{result.gradient_excess:.2%} of the largest distance {result.distance.max():.4g}. Wrote {args.output}.")
