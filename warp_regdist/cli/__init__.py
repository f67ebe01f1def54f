"""The ``warp-regdist`` command: regularized geodesic distances from the shell.

One module per subcommand: ``demo`` (the spot cow shipped with the package), ``distance``
(any mesh file), ``allpairs`` (the symmetric all-pairs distance matrix), ``matrix``
(single-source rows written block by block, resumable, optionally on a Dask cluster),
``volume`` (a closed surface tetrahedralized, then the distance inside it), ``view`` (values
on a mesh in a polyscope window); what they share is in :mod:`.common`. Bad input (missing
or malformed files, bad sources, an unknown device, an unsupported output extension) ends
with one line ``warp-regdist: error: ...`` on stderr and exit status 2; other exceptions are
bugs and propagate with their traceback.
"""

from __future__ import annotations

import argparse
import sys

from . import allpairs, demo, distance, matrix, view, volume
from .common import EXIT_STATUS, PROG

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
        0 on success (also when the ADMM did not converge: a warning line goes to
        stderr), 2 on bad input or bad usage (one ``warp-regdist: error:`` line).
    """
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:  # --help, --version and usage errors
        return exc.code if isinstance(exc.code, int) else 2
    try:
        SUBCOMMANDS[args.command].run(args)
    except (ValueError, OSError) as exc:  # MeshError is a ValueError
        message = " ".join(str(exc).split())
        print(f"{PROG}: error: {message}", file=sys.stderr)
        return 2
    return 0
