"""Checks of the generic arguments shared by the solvers: weights, worker counts, Warp devices.

Each returns the value in canonical form or raises ValueError("expected ..., got ...").
"""

from __future__ import annotations

import math
import os
import sys
import tempfile

import numpy as np
import warp as wp

__all__ = ["check_weight", "parse_device", "parse_workers", "read_csv_rows"]

_CUDA_DRIVER_WARNING = b"Could not find or load the NVIDIA CUDA driver"
"""Printed by Warp's native start-up on every machine without an NVIDIA driver."""


def check_weight(value, name, positive=False):
    """``value`` as a float; ValueError unless it is a finite real >= 0 (> 0 if ``positive``).

    Used for alpha_hat, beta_hat and the all-pairs tolerances; booleans and strings are refused
    (True would silently mean 1).
    """
    bound = "> 0" if positive else ">= 0"
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise ValueError(f"expected a real {name} {bound}, got {value!r}")
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"expected a real {name} {bound}, got {value!r}") from None
    if not math.isfinite(value) or value < 0 or (positive and value == 0):
        raise ValueError(f"expected a finite {name} {bound}, got {value!r}")
    return value


def parse_workers(workers):
    """Number of CPU worker processes: ``workers`` (an integer >= 1) or, for None, the cores available."""
    if workers is None:
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if isinstance(workers, (bool, np.bool_)) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ValueError(f"expected workers as an integer >= 1 or None, got {workers!r}")
    return int(workers)


def parse_device(device):
    """The Warp device named ``device`` (None: Warp's default), initializing Warp first.

    ValueError naming the available devices for an unknown name. What Warp's native code writes
    to stderr meanwhile (file descriptor 2) is captured: "Could not find or load the NVIDIA CUDA
    driver", which Warp writes on every machine without one, is dropped, or, when ``device`` is a
    CUDA device that is missing, becomes the reason in the error; the driver calls that then fail
    are dropped; anything else is written back.
    """
    with _native_stderr() as native:
        wp.init()  # a no-op once Warp is initialized
        try:
            found = wp.get_device(device)
        except Exception:
            found = None
        names = [str(d) for d in wp.get_devices()]
    lines = native.captured.splitlines(keepends=True)
    driver = [line for line in lines if _CUDA_DRIVER_WARNING in line]
    if found is None:
        reason = f" (Warp: {_CUDA_DRIVER_WARNING.decode()})" if driver and str(device).startswith("cuda") else ""
        raise ValueError(f"expected a Warp device among {names}, got {device!r}{reason}")
    kept = b"".join(line for line in lines if _CUDA_DRIVER_WARNING not in line
                    and not (driver and line.startswith(b"Warp CUDA error")))
    if kept:
        os.write(2, kept)
    return found


class _native_stderr:
    """Within the block, file descriptor 2 goes to a temporary file; the bytes written are
    ``captured`` after it (nothing is captured where there is no descriptor 2)."""

    def __enter__(self):
        sys.stderr.flush()
        self.captured = b""
        try:
            self.saved = os.dup(2)
        except OSError:
            self.saved = None
            return self
        self.file = tempfile.TemporaryFile()
        os.dup2(self.file.fileno(), 2)
        return self

    def __exit__(self, *exc):
        if self.saved is None:
            return
        sys.stderr.flush()
        os.dup2(self.saved, 2)
        os.close(self.saved)
        self.file.seek(0)
        self.captured = self.file.read()
        self.file.close()


def read_csv_rows(path, row, what):
    """(k, len(row)) float64 rows of the CSV file ``path`` ('#' starts a comment), as in
    "expected {what} rows '{row}' of numbers, got unreadable rows in ..." on failure; ``row``
    names the columns ("x,y,z"), ``what`` the input ("--sources", "CSV")."""
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file: numpy warns, then the size check refuses it
            rows = np.loadtxt(path, delimiter=",", ndmin=2, comments="#")
    except ValueError:
        raise ValueError(f"expected {what} rows '{row}' of numbers, got unreadable rows in {path!r}") from None
    width = len(row.split(","))
    if rows.size == 0 or rows.shape[1] != width:
        raise ValueError(f"expected {what} rows '{row}', got {rows.shape[1] if rows.size else 0} columns in {path!r}")
    return rows
