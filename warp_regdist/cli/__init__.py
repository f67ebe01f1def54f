"""The ``warp-regdist`` command: regularized geodesic distances from the shell.

One module per subcommand: ``demo`` (the spot cow shipped with the package), ``distance``
(any mesh file), ``allpairs`` (the symmetric all-pairs distance matrix), ``matrix``
(single-source rows written block by block, resumable, optionally on a Dask cluster),
``volume`` (a closed surface tetrahedralized, then the distance inside it), ``view`` (values
on a mesh in a polyscope window); what they share is in :mod:`.common`. Every subcommand keeps
one contract (:data:`.common.EXIT_STATUS`): 0 done, 1 written but not converged, 2 bad input or
environment (missing or malformed files, bad sources, an unknown device, a full disk, a worker
process that died: one line ``warp-regdist: error: ...`` on stderr), 130 interrupted (Ctrl-C),
143 terminated (SIGTERM; a solve stops at an iteration boundary and keeps its work, as on
Ctrl-C); other exceptions are bugs and propagate with their traceback. A run holds the lock of
each output it writes (the module's ``LOCKED_OUTPUTS``; ``matrix`` locks its own), so that a
second run on the same output is refused instead of replacing it.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys

from . import allpairs, demo, distance, matrix, view, volume
from ..errors import WorkerError
from ..file_lock import FileLock
from ..solvers.common.interrupt import sigterm_raises
from .common import EXIT_STATUS, PROG, quiet_warp, stop_status, stop_word

__all__ = ["main"]

SUBCOMMANDS = {"demo": demo, "distance": distance, "allpairs": allpairs, "matrix": matrix, "volume": volume,
               "view": view}


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line, ``warp-regdist COMMAND: error: ...``, and
    exit 2 (argparse's own prints the whole usage first)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (--help lists the options)\n")


def _parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = OneLineParser(
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
        or environment (one ``warp-regdist: error:`` line, nothing written), 130 interrupted, 143
        terminated (SIGTERM).
    """
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:  # --help, --version and usage errors
        return exc.code if isinstance(exc.code, int) else 2
    quiet_warp(getattr(args, "verbose", False))
    module = SUBCOMMANDS[args.command]
    try:
        with sigterm_raises(), contextlib.ExitStack() as locks:
            for name in getattr(module, "LOCKED_OUTPUTS", ()):     # one run at a time writes each output
                path = getattr(args, name, None)
                folder = os.path.dirname(os.path.abspath(path)) if path is not None else None
                if folder is not None and os.path.isdir(folder) and os.access(folder, os.W_OK):
                    locks.enter_context(FileLock(path, f"--{name}"))   # else run() refuses the path
            return module.run(args) or 0
    except (ValueError, OSError, WorkerError) as exc:  # MeshError is a ValueError, WriteError an OSError
        lines = str(exc).strip().splitlines() or [type(exc).__name__]
        if isinstance(exc, WorkerError) and len(lines) > 1:  # a worker's traceback: its exception, the last line
            lines = [lines[0], lines[-1]]
        print(f"{PROG}: error: {' '.join(' '.join(lines).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: {stop_word()}", file=sys.stderr)
        return stop_status()
