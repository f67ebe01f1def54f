"""The ``demo`` subcommand: the spot cow shipped with the package, written as distance.npy and distance.png."""

from __future__ import annotations

import argparse
import importlib.resources
import os

from .common import (DEMO_ALPHA_HAT, DEMO_SOURCE, exit_status, load, solve, solver_options, subcommand, summary,
                     write_values)


def add_parser(sub) -> None:
    demo = subcommand(
        sub, "demo",
        help="solve on the shipped spot cow and write distance.npy and distance.png",
        description=f"Solve from vertex {DEMO_SOURCE} of the spot cow (4764 vertices, shipped with\n"
        f"the package) at alpha_hat {DEMO_ALPHA_HAT}; write distance.npy and distance.png.",
    )
    demo.add_argument(
        "--output",
        default="warp-regdist-demo",
        metavar="DIR",
        help="output directory, created if missing (default: ./warp-regdist-demo)",
    )
    solver_options(demo)


def run(args: argparse.Namespace) -> int:
    from ..output.render import render_distance

    if os.path.exists(args.output) and not os.path.isdir(args.output):
        raise ValueError(f"expected --output as a directory, got the file {args.output!r}")
    os.makedirs(args.output, exist_ok=True)
    npy = os.path.join(args.output, "distance.npy")
    png = os.path.join(args.output, "distance.png")
    with importlib.resources.as_file(importlib.resources.files("warp_regdist") / "data" / "spot_rr.off") as path:
        mesh = load(os.fspath(path))
    if not args.quiet:
        print(
            f"Demo: spot cow ({mesh.n_vertices} vertices, {mesh.n_elements} faces), source vertex "
            f"{DEMO_SOURCE}, alpha_hat {DEMO_ALPHA_HAT}, {args.dtype}. Solving...",
            flush=True,
        )
    solver, result = solve(mesh, [DEMO_SOURCE], DEMO_ALPHA_HAT, args.device, args.dtype, quiet=args.quiet)
    write_values(npy, result.distance)
    title = f"spot: regularized geodesic distance from vertex {DEMO_SOURCE}, alpha_hat {DEMO_ALPHA_HAT:g}"
    render_distance(mesh, result.distance, png, sources=[DEMO_SOURCE], title=title)
    if not args.quiet:
        print(summary("spot_rr.off", mesh, f"source vertex {DEMO_SOURCE}", solver, result, [npy, png]))
    return exit_status(result)
