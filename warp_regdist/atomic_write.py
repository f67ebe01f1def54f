"""Output files that are whole or absent: written beside their path, then renamed over it.

:func:`write_atomic` has a writer fill ``path + ".tmp<pid>" + ext`` (same directory, so the
rename stays on one file system), flushes it to the disk and renames it over ``path``: a
reader sees the old file or the new one, never a part, and a failed write (a full disk, a
read-only directory, a kill) leaves the old file as it was. :func:`check_room` refuses a run
before its work when the file systems of its outputs lack the space they will need, and
:func:`remove_stale_temporaries` clears the temporary files of writers that died.
"""

from __future__ import annotations

import errno
import os
import re
import shutil

from .errors import WriteError

__all__ = ["write_atomic", "check_room", "free_bytes", "remove_stale_temporaries", "temporary_name", "format_bytes"]


def format_bytes(size):
    """A byte count for messages: '412 kB', '5.30 GB'."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if size >= scale:
            return f"{size / scale:.3g} {unit}"
    return f"{int(size)} bytes"


def free_bytes(path):
    """Bytes free on the file system that holds ``path`` (a file or the directory it would go to)."""
    return shutil.disk_usage(os.path.dirname(os.path.abspath(os.fspath(path)))).free


def check_room(files):
    """ValueError unless every file system has room for the files planned on it.

    ``files``: (path, bytes, what) triples; the bytes of the files on one file system add up,
    less what the existing files at those paths already occupy when they are to be replaced
    (an atomic replacement needs the new file's room while the old one still stands, so pass
    the peak: e.g. two checkpoints for a checkpoint that is rewritten while the run goes on).
    """
    needed = {}
    for path, size, what in files:
        folder = os.path.dirname(os.path.abspath(os.fspath(path)))
        device = os.stat(folder).st_dev
        total, listed = needed.get(device, (0, []))
        needed[device] = (total + int(size), listed + [(os.fspath(path), int(size), what, folder)])
    for total, listed in needed.values():
        free = shutil.disk_usage(listed[0][3]).free
        if total > free:
            parts = " and ".join(f"{what} {path!r} ({format_bytes(size)})" for path, size, what, _ in listed)
            raise ValueError(f"expected {format_bytes(total)} free for {parts}, got {format_bytes(free)} free on "
                             f"the file system of {listed[0][3]!r}")


def temporary_name(path):
    """``path + ".tmp<pid>"`` followed by the path's extension (so writers that add one, like
    ``np.save``, keep the name)."""
    path = os.fspath(path)
    return f"{path}.tmp{os.getpid()}{os.path.splitext(path)[1]}"


def remove_stale_temporaries(path):
    """Remove the temporary files of :func:`write_atomic` for ``path`` whose writer process no longer
    runs (a kill during a write leaves one); returns their names."""
    path = os.fspath(path)
    folder, base = os.path.split(os.path.abspath(path))
    pattern = re.compile(re.escape(base) + r"\.tmp(\d+)(\.[^.]*)?")
    removed = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        match = pattern.fullmatch(name)
        if match is None or _running(int(match.group(1))):
            continue
        try:
            os.remove(os.path.join(folder, name))
            removed.append(name)
        except OSError:
            pass
    return removed


def _running(pid):
    if pid == os.getpid():
        return False  # this process's own leftover of an earlier, failed write
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # it exists, owned by another user
        return True
    return True


def write_atomic(path, write, what="the output", size=None):
    """Write ``path`` whole or not at all: ``write(tmp)`` fills a temporary file beside it, which is
    then synced to the disk and renamed over ``path`` (the directory synced too).

    The temporary files of earlier writers of ``path`` that died are removed first, and ``size``
    (bytes, when known) is checked against the free space. Any failure removes
    the temporary file, leaves an existing file at ``path`` untouched and raises
    :class:`~warp_regdist.errors.WriteError` naming the path, the cause and the space needed and
    free. Returns ``path``.
    """
    path = os.fspath(path)
    remove_stale_temporaries(path)
    if size is not None:
        free = free_bytes(path)
        if size > free:
            raise WriteError(f"could not write {what} {path!r}: it needs {format_bytes(size)} and its file system "
                             f"has {format_bytes(free)} free{_kept(path)}", errno.ENOSPC)
    tmp = temporary_name(path)
    try:
        write(tmp)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError as exc:
        written = os.path.getsize(tmp) if os.path.exists(tmp) else 0
        _remove(tmp)
        cause = exc.strerror or str(exc)
        try:
            free = format_bytes(free_bytes(path))
        except OSError:
            free = "unknown"
        need = f"it needs {format_bytes(size)}" if size is not None else f"{format_bytes(written)} were written"
        raise WriteError(f"could not write {what} {path!r}: {cause} ({need}, {free} free){_kept(path)}",
                         exc.errno) from None
    except BaseException:
        _remove(tmp)
        raise
    _sync_directory(path)
    return path


def _kept(path):
    return "; the existing file there is unchanged" if os.path.exists(path) else ""


def _remove(tmp):
    try:
        os.remove(tmp)
    except OSError:
        pass


def _sync_directory(path):
    """Make the rename durable (a no-op where directories cannot be opened)."""
    try:
        fd = os.open(os.path.dirname(os.path.abspath(path)), os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
