"""CPU worker processes and the memory they share.

A Warp launch on the CPU runs on one core, and Warp does not support CPU launches from
several Python threads of one process (generated CPU code keeps process-global state: the
tile-storage pointer that every launch sets and restores; two threads interleaving it
crashed ``all_pairs`` under load). So the solvers use more cores through processes:

- :class:`WorkerPool` starts ``count`` fresh Python processes (``python -c``, so a user's
  script is never re-imported, whatever its ``__main__`` guard), each of which builds one
  object ``factory(*args, index)`` and then runs the method calls the parent sends it over a
  pipe. The workers live in their own session: a Ctrl-C in the terminal reaches the parent
  only, which decides what it means (see :mod:`warp_regdist.solvers.common.interrupt`) and raises the
  workers' shared stop flag. A worker dies with its parent, however the parent died (SIGKILL,
  SIGTERM, the out-of-memory killer): the kernel kills it when the parent thread that started
  it ends (``PR_SET_PDEATHSIG``), and a watchdog thread, which compares its parent's pid with
  the one it was started by, covers the rest. So a pool must be used from the thread that
  started it; a pool whose thread ended is found dead and replaced at its next use. A worker that dies makes
  the parent raise :class:`WorkerError` naming the worker and the signal, when the parent
  next waits for it, or earlier at :func:`check_workers` (the ADMM loop calls it before every
  test) while the parent runs its own part inside ``with watch(pool):``.
- :class:`SharedArrays` lays named numpy arrays out in one anonymous shared mapping
  (``memfd`` named ``warp_regdist_shared_<parent pid>``; not limited by the size of /dev/shm,
  freed by the kernel when the last process holding it exits) that the workers map too; :meth:`warp`
  views an array as a ``wp.array`` on the CPU device without copying.

Linux only (``os.memfd_create``, fd passing); elsewhere :func:`processes_available` is
False and the solvers use one process.
"""

from __future__ import annotations

import contextlib
import mmap
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
import weakref
from multiprocessing.connection import Connection

import numpy as np

from . import interrupt
from ...errors import WorkerError

__all__ = ["WorkerPool", "SharedArrays", "processes_available", "watch", "check_workers"]

_ALIGN = 64
_WATCHED: list = []  # the pools whose workers run calls that the current loop of this process waits for
_PARENT_POLL = 0.2  # seconds between a worker's checks that its parent is alive


def processes_available():
    """Whether worker processes with shared memory work on this platform."""
    return sys.platform.startswith("linux") and hasattr(os, "memfd_create")


class SharedArrays:
    """Named numpy arrays in one shared anonymous mapping, zero-initialized.

    Parameters
    ----------
    specs : dict name -> (shape, numpy dtype)

    The object pickles to a handle that attaches to the same memory, but only into a
    :class:`WorkerPool` worker, which receives the mapping's file descriptor at start.
    """

    def __init__(self, specs, fd=None):
        self.layout = {}
        offset = 0
        for name, (shape, dtype) in specs.items():
            shape = tuple(int(s) for s in shape)
            dtype = np.dtype(dtype)
            self.layout[name] = (offset, shape, dtype.str)
            offset += -(-int(np.prod(shape)) * dtype.itemsize // _ALIGN) * _ALIGN
        self.size = max(offset, _ALIGN)
        if fd is None:
            fd = os.memfd_create(f"warp_regdist_shared_{os.getpid()}")
            os.ftruncate(fd, self.size)
            self._owner = weakref.finalize(self, os.close, fd)
        self.fd = fd
        self._map = mmap.mmap(fd, self.size)
        self.arrays = {name: np.ndarray(shape, dtype=np.dtype(dt), buffer=self._map, offset=off)
                       for name, (off, shape, dt) in self.layout.items()}

    def __getitem__(self, name):
        return self.arrays[name]

    def warp(self, name, dtype, shape=None):
        """The array ``name`` as a ``wp.array`` of ``dtype`` on the CPU (no copy; ``shape`` in
        elements of ``dtype``, default: the numpy shape without the trailing lane axis)."""
        import warp as wp

        a = self.arrays[name]
        if shape is None:
            shape = a.shape[:-1] if wp.types.type_size_in_bytes(dtype) > a.itemsize else a.shape
        return wp.array(ptr=a.ctypes.data, shape=tuple(shape), dtype=dtype, device="cpu")

    def __reduce__(self):
        specs = {name: (shape, dt) for name, (_, shape, dt) in self.layout.items()}
        return (_attach, (specs, self.fd))


def _attach(specs, fd):
    """SharedArrays on an inherited descriptor (the worker received it under the same number)."""
    return SharedArrays(specs, fd=fd)


_WORKER = """
import sys
import warp
warp.config.log_level = warp.LOG_WARNING
from warp_regdist.solvers.common.processes import _serve
_serve(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))
"""


class WorkerPool:
    """``count`` worker processes, worker i holding ``factory(*args, i + first_index)``.

    Parameters
    ----------
    factory : picklable callable (a class or function importable by module path)
    args : tuple, picklable (may contain :class:`SharedArrays`)
    count : int
    first_index : int
        Index passed to the first worker's factory (the parent often does part 0 itself).
    shared : list of SharedArrays
        Mappings whose descriptors the workers inherit.

    Use :meth:`start` then :meth:`finish` to overlap the workers' calls with the parent's
    own share of the work; :meth:`close` (also at garbage collection) ends them.
    """

    def __init__(self, factory, args, count, first_index=0, shared=()):
        self.stop_flag = SharedArrays({"stop": ((1,), np.uint8)})
        fds = [s.fd for s in shared] + [self.stop_flag.fd]
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
        self.first_index = first_index
        self._procs, self._conns = [], []
        try:
            for i in range(count):
                down_r, down_w = os.pipe()
                up_r, up_w = os.pipe()
                proc = subprocess.Popen([sys.executable, "-c", _WORKER, str(down_r), str(up_w), str(os.getpid())],
                                        pass_fds=(down_r, up_w, *fds), env=env, stdin=subprocess.DEVNULL,
                                        start_new_session=True)
                os.close(down_r)
                os.close(up_w)
                conn = _Channel(up_r, down_w)
                self._procs.append(proc)
                self._conns.append(conn)
                conn.send((factory, args, i + first_index, self.stop_flag))
            for i in range(count):
                self._receive(i)  # the factory's result: ready, or its error
        except BaseException:
            self.close()
            raise
        self._finalizer = weakref.finalize(self, _shutdown, self._procs, self._conns)
        interrupt.link(self)

    def __len__(self):
        return len(self._procs)

    def start(self, method, calls):
        """Send ``method(*calls[i])`` to worker i (no waiting)."""
        for i, (conn, args) in enumerate(zip(self._conns, calls)):
            try:
                conn.send((method, args))
            except OSError:  # a broken pipe: the worker is gone
                self._procs[i].wait()
                self._died(i)

    def alive(self):
        """Whether every worker process is still running."""
        return all(proc.poll() is None for proc in self._procs)

    def finish(self):
        """The results of the calls sent by :meth:`start`, one per worker."""
        return [self._receive(i) for i in range(len(self._conns))]

    def request_stop(self, value=True):
        """Raise (or clear) the stop flag that the workers' solvers poll once per iteration."""
        self.stop_flag["stop"][0] = 1 if value else 0

    def _receive(self, i):
        try:
            status, value = self._conns[i].recv()
        except (EOFError, OSError):
            self._procs[i].wait()
            self._died(i)
        if status == "error":
            raise WorkerError(f"worker process {i + self.first_index} (pid {self._procs[i].pid}) failed:\n{value}")
        return value

    def check(self):
        """Raise :class:`WorkerError` if a worker process has exited (the pool is then closed)."""
        for i, proc in enumerate(self._procs):
            if proc.poll() is not None:
                self._died(i)

    def _died(self, i):
        """Close the pool and raise the :class:`WorkerError` of worker i's death."""
        proc = self._procs[i]
        code = proc.returncode
        if code < 0:
            name = signal.Signals(-code).name if -code in signal.valid_signals() else f"signal {-code}"
            how = f"was killed by {name}" + (" (the out-of-memory killer sends it, as does kill -9)"
                                              if -code == signal.SIGKILL else "")
        else:
            how = f"exited with status {code}"
        self.close()
        raise WorkerError(f"worker process {i + self.first_index} (pid {proc.pid}) {how}; its part of the work "
                          "is lost (an all-pairs run resumes from its last checkpoint)") from None

    def close(self):
        _shutdown(self._procs, self._conns)


@contextlib.contextmanager
def watch(pool):
    """Make :func:`check_workers` check ``pool`` within the block (while the parent does its own part)."""
    _WATCHED.append(pool)
    try:
        yield pool
    finally:
        _WATCHED.remove(pool)


def check_workers():
    """Raise :class:`WorkerError` if a worker process of a pool under :func:`watch` has died."""
    for pool in list(_WATCHED):
        pool.check()


def _shutdown(procs, conns):
    for conn in conns:
        try:
            conn.send(None)
        except OSError:
            pass
        conn.close()
    for proc in procs:
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    procs.clear()
    conns.clear()


class _Channel:
    """A pickle channel over a pair of pipe descriptors (read from one, write to the other)."""

    def __init__(self, read_fd, write_fd):
        self._read = Connection(read_fd, readable=True, writable=False)
        self._write = Connection(write_fd, readable=False, writable=True)

    def send(self, obj):
        self._write.send_bytes(pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL))

    def recv(self):
        return pickle.loads(self._read.recv_bytes())

    def close(self):
        self._read.close()
        self._write.close()


def _die_with_parent(parent):
    """Have the kernel SIGKILL this process when the thread that started it ends (Linux
    ``PR_SET_PDEATHSIG``: at once, whatever this process is doing), and exit now if the parent
    ``parent`` (a pid) is already gone; False where the call is not available."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, int(signal.SIGKILL), 0, 0, 0) != 0:   # PR_SET_PDEATHSIG
            return False
    except (OSError, AttributeError):
        return False
    if os.getppid() != parent:  # the parent died before the call
        os._exit(1)
    return True


def _exit_with_parent(parent):
    """Exit this process as soon as its parent ``parent`` (a pid) is gone (it is then reparented)."""
    while os.getppid() == parent:
        time.sleep(_PARENT_POLL)
    os._exit(1)


def _serve(read_fd, write_fd, parent):
    """Worker main loop: build the object, then answer method calls until told to stop or the parent dies."""
    import traceback

    _die_with_parent(parent)
    threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()  # where the kernel cannot
    os.dup2(2, 1)  # the channel is a pipe of its own; anything printed goes to stderr
    channel = _Channel(read_fd, write_fd)
    try:
        message = channel.recv()
    except EOFError:
        return
    try:
        from ...arguments import parse_device

        parse_device("cpu")  # starts Warp without its CUDA-driver warning
        factory, args, index, stop_flag = message
        interrupt.use_flag(stop_flag["stop"])
        obj = factory(*args, index)
        channel.send(("ok", None))
    except BaseException:
        channel.send(("error", traceback.format_exc()))
        return
    while True:
        try:
            message = channel.recv()
        except EOFError:
            return
        if message is None:
            return
        method, args = message
        try:
            channel.send(("ok", getattr(obj, method)(*args)))
        except BaseException:
            channel.send(("error", traceback.format_exc()))
