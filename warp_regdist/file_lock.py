"""One writer per output file: an exclusive lock held next to it while a run writes it.

``FileLock(path)`` takes an advisory lock (``flock``) on ``path + ".lock"``, which holds the
owner's pid. A second writer of the same path, in another process or in this one, is refused
with a ValueError instead of both writing. The kernel drops the lock when its owner exits
however it exits, so a killed run leaves no stale lock: the next run takes the file over.
The lock file is removed on release. Without ``fcntl`` (not POSIX) no lock is taken.
"""

from __future__ import annotations

import os
import types

fcntl: types.ModuleType | None
try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None

__all__ = ["FileLock"]


class FileLock:
    """Exclusive lock on ``path + ".lock"`` for writing ``path`` (``what`` names it in errors).

    Use as a context manager, or :meth:`acquire` / :meth:`release`.
    """

    def __init__(self, path, what="the file"):
        self.path = os.fspath(path)
        self.lock_path = self.path + ".lock"
        self.what = what
        self._fd = None

    def acquire(self):
        if fcntl is None or self._fd is not None:
            return self
        while True:
            fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 32).decode(errors="replace").strip() or "unknown"
                os.close(fd)
                raise ValueError(f"expected no other run writing {self.what} {self.path!r}, got one holding its "
                                 f"lock {self.lock_path!r} (pid {holder})") from None
            try:
                same = os.stat(self.lock_path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:  # not a file that its previous owner removed between our open and flock
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return self

    def release(self):
        """Drop the lock and remove its file; never raises (an error here must not hide the one that
        ended the run). A lock file that cannot be removed (a read-only directory) stays: it holds no
        lock, and the next run takes it over."""
        if self._fd is None:
            return
        try:
            os.remove(self.lock_path)
        except OSError:
            pass
        os.close(self._fd)
        self._fd = None

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()
