"""The ``warp-regdist`` command: regularized geodesic distances from the shell.

One module per subcommand: ``demo`` (the spot cow shipped with the package), ``distance``
(any mesh file), ``allpairs`` (the symmetric all-pairs distance matrix), ``matrix``
(single-source rows written block by block, resumable, optionally on a Dask cluster),
``volume`` (a closed surface tetrahedralized, then the distance inside it), ``view`` (values
on a mesh in a polyscope window); what they share is in :mod:`.common`. Every subcommand keeps
one contract (:data:`.common.EXIT_STATUS`): 0 done, 1 written but not converged, 2 bad input or
environment (missing or malformed files, bad sources, an unknown device, a full disk, a worker
process that died: one line ``warp-regdist: error: ...`` on stderr), 130 interrupted; other
exceptions are bugs and propagate with their traceback.
"""

from __future__ import annotations

import argparse
import sys

from . import allpairs, demo, distance, matrix, view, volume
from ..errors import WorkerError
from .common import EXIT_STATUS, PROG, quiet_warp

__all__ = ["main"]

SUBCOMMANDS = {"demo": demo, "distance": distance, "allpairs": allpairs, "matrix": matrix, "volume": volume,
               "view": view}


def _parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Regularized geodesic distances on triangle and tetrahedral meshes (Edelstein et al.,\n"
        "SIGGRAPH 2023), solved by ADMM with Warp kernels on the CPU or a CUDA GPU.",
        epilog=EXIT_STATUS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in SUBCOMMANDS.values():
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the ``warp-regdist`` command line; returns the exit status.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
        0 done, 1 written but not converged (a ``warp-regdist: warning:`` line says so), 2 bad input
        or environment (one ``warp-regdist: error:`` line, nothing written), 130 interrupted.
    """
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:  # --help, --version and usage errors
        return exc.code if isinstance(exc.code, int) else 2
    quiet_warp(getattr(args, "verbose", False))
    try:
        return SUBCOMMANDS[args.command].run(args) or 0
    except (ValueError, OSError, WorkerError) as exc:  # MeshError is a ValueError, WriteError an OSError
        lines = str(exc).strip().splitlines() or [type(exc).__name__]
        if isinstance(exc, WorkerError) and len(lines) > 1:  # a worker's traceback: its exception, the last line
            lines = [lines[0], lines[-1]]
        print(f"{PROG}: error: {' '.join(' '.join(lines).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
