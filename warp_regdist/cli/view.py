"""The ``view`` subcommand: per-vertex values on a mesh in a polyscope window."""

from __future__ import annotations

import argparse
import os

import numpy as np

from .common import load, parse_sources, subcommand


def add_parser(sub) -> None:
    view = subcommand(
        sub, "view",
        help="show per-vertex values on a mesh in an interactive window (polyscope)",
        description="Show a .npy of per-vertex values ((n,) or (n, k): k fields side by side) on a mesh\n"
        "in a polyscope window, as a colour map with isolines, sources marked, a slice plane\n"
        "for tetrahedra. Needs pip install 'warp-regdist[view]'.",
    )
    view.add_argument("mesh", metavar="MESH", help="the mesh the values belong to")
    view.add_argument("values", metavar="VALUES", help=".npy file of per-vertex values, (n,) or (n, k)")
    view.add_argument("--isolines", type=int, default=20, metavar="N", help="isolines per field (default: 20)")
    view.add_argument("--sources", metavar="SOURCES", help="vertices to mark: comma-separated indices")
    view.add_argument("--backend", metavar="NAME", help="polyscope backend (openGL_mock: headless, draws nothing)")
    view.add_argument("--frames", type=int, metavar="N", help="render N frames and exit instead of waiting")


def run(args: argparse.Namespace) -> None:
    from ..output.viewer import show

    mesh = load(args.mesh)
    if not args.values.lower().endswith(".npy") or not os.path.isfile(args.values):
        raise ValueError(f"expected VALUES as an existing .npy file, got {args.values!r}")
    try:
        values = np.load(args.values, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise ValueError(f"expected VALUES as a readable .npy array, got {args.values!r} ({exc})") from None
    sources = None
    if args.sources:
        sources, _ = parse_sources(args.sources, mesh)
    try:
        show(mesh, values, isolines=args.isolines, sources=sources, backend=args.backend, frames=args.frames)
    except ModuleNotFoundError as exc:
        raise ValueError(str(exc)) from None
