"""Ctrl-C or SIGTERM during a long solve: stop at the next iteration boundary and keep the work.

Inside ``with catch_interrupt():`` (the solvers' iteration loops), the first SIGINT or SIGTERM
(what batch schedulers send before they kill a job) does not raise: it sets a flag that
:func:`requested` returns, the loops stop at the end of their current iteration and return
(or checkpoint) the iterate, flagged not converged; :func:`stopped_by` says which signal it
was. A second signal raises KeyboardInterrupt. In a worker process
(:mod:`warp_regdist.solvers.common.processes`) the flag is a byte of memory shared with the parent, which
raises it when the parent is interrupted.

Off the main thread (where Python cannot install signal handlers) the guard does nothing.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import weakref

import numpy as np

__all__ = ["catch_interrupt", "requested", "stopped_by", "sigterm_raises"]

SIGNALS = (signal.SIGINT, signal.SIGTERM)

_flag = np.zeros(1, dtype=np.uint8)
_depth = 0
_linked: weakref.WeakSet = weakref.WeakSet()
_by = [0]


def stopped_by():
    """The signal (SIGINT or SIGTERM) of the last stop request of the outermost block, or 0."""
    return _by[0]


def requested():
    """Whether an interrupt asked the running solve to stop."""
    return bool(_flag[0])


def use_flag(array):
    """Read the stop request from ``array[0]`` (a worker's byte of shared memory)."""
    global _flag
    _flag = array


def link(pool):
    """Pass stop requests on to ``pool.request_stop(bool)`` (worker processes) while it lives,
    starting with the current one."""
    _linked.add(pool)
    pool.request_stop(bool(_flag[0]))


def _set(value):
    _flag[0] = value
    for pool in list(_linked):
        pool.request_stop(bool(value))


@contextlib.contextmanager
def catch_interrupt():
    """Turn the first SIGINT or SIGTERM into a stop request for the duration of the block (nestable)."""
    global _depth
    if threading.current_thread() is not threading.main_thread() or _depth > 0:
        _depth += 1
        try:
            yield
        finally:
            _depth -= 1
        return

    def handler(signum, frame):
        if _flag[0]:
            raise KeyboardInterrupt
        _by[0] = signum
        _set(1)

    previous = {s: signal.signal(s, handler) for s in SIGNALS}
    _set(0)
    _by[0] = 0
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        for s, h in previous.items():
            signal.signal(s, h)
        _set(0)


@contextlib.contextmanager
def sigterm_raises():
    """For the duration of the block, SIGTERM raises KeyboardInterrupt (as SIGINT does), and then
    :func:`stopped_by` says SIGTERM; the solve loops inside still stop at an iteration boundary."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        _by[0] = signum
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    _by[0] = 0
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
