"""Row blocks of a distance matrix, in memory or on disk (a Zarr array or a ``.npy`` file), resumable.

A (k, n) matrix is written in blocks of ``chunk`` consecutive rows. On disk, next to the
matrix ``D.zarr`` (or ``D.npy``) lies the directory ``D.zarr.progress`` holding the problem's
fingerprint (``fingerprint.json``, written before the matrix) and one marker file per block,
holding the CRC-32 of its rows and created only after they are on disk: a block half-written
by a killed run has no marker and is redone, and a resumed run first checks every finished
block against its CRC. An ``out`` whose fingerprint differs from the call's, whose finished
blocks changed on the disk, or whose files are not what this module writes (truncated,
foreign, another shape or dtype, a Zarr store with codecs outside :data:`ZARR_CODECS`), is
refused with a ValueError before any work; files are read as data, never unpickled. While a run writes
``D.npy`` it holds ``D.npy.lock`` (:class:`~warp_regdist.file_lock.FileLock`): a second run on
the same path is refused.

Symmetrization (D[r, src[c]] and D[c, src[r]] replaced by their mean) works block by block on
the stored rows: while solving, each block's source columns are also written, tile-major,
into ``source_columns.npy`` (S, (k, k) in (chunk, chunk) tiles, removed at the end; a ``tile``
marker per block says its strip is there), and row block I is then rewritten from S,
D[I, src[J]] = (S[I, J] + S[J, I]^T) / 2, so redoing it is harmless. A block J whose strip is
not in S (solved in an earlier run, whose S was removed once every block was symmetric) holds
final values, so D[I, src[J]] = D[J, src[I]]^T: a block solved again, its rows marker removed
after damage, is symmetrized against the others. Memory: a (chunk, n) row block and two
(chunk, k) strips of S.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import zlib

import numpy as np

from ..atomic_write import check_room, format_bytes, write_atomic
from ..errors import WriteError
from ..file_lock import FileLock

__all__ = ["MemoryRows", "DiskRows", "NpyFile", "open_rows", "average_source_pairs", "OUT_EXTENSIONS"]

OUT_EXTENSIONS = (".zarr", ".npy")


def average_source_pairs(rows, sources, s_rows, s_cols):
    """Set ``rows[:, sources] = (s_rows + s_cols^T) / 2`` in place and return ``rows``.

    rows : (c, n) block of matrix rows I; sources : (k,) source vertex of each row;
    s_rows : (c, k) = S[I, :], s_cols : (k, c) = S[:, I], with S[r, c'] = D[r, sources[c']]
    before symmetrization.
    """
    rows[:, sources] = 0.5 * (s_rows + s_cols.T)
    return rows


class MemoryRows:
    """The matrix as one (k, n) ndarray (``distance_matrix`` without ``out``)."""

    def __init__(self, shape, chunk, dtype):
        self.array = np.empty(shape, dtype=dtype)
        self.chunk = chunk
        self.blocks = -(-shape[0] // chunk)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def todo(self):
        """Indices of the row blocks still to solve."""
        return list(range(self.blocks))

    def write(self, block, rows, sources):
        self.array[block * self.chunk:block * self.chunk + len(rows)] = rows

    def symmetrize(self, sources):
        s = self.array[:, sources].copy()
        average_source_pairs(self.array, sources, s, s)

    def result(self):
        return self.array


class NpyFile:
    """A ``.npy`` file read and written in place by file offsets, never mapped (so a long run's
    memory does not grow with the pages it touched). Values are addressed by flat C-order index."""

    def __init__(self, path, shape=None, dtype=None):
        """Open ``path``, or create it (sparse, zeros) when ``shape`` and ``dtype`` are given."""
        if shape is not None:
            m = np.lib.format.open_memmap(path, mode="w+", dtype=dtype, shape=shape)
        else:
            try:
                m = np.load(path, mmap_mode="r", allow_pickle=False)
                if not isinstance(m, np.memmap):
                    raise ValueError(f"a {type(m).__name__}")
            except (OSError, ValueError, EOFError) as exc:
                raise ValueError(f"expected {path!r} as a .npy array written by distance_matrix, got an unreadable "
                                 f"file ({type(exc).__name__}: {exc})") from None
        self.path, self.shape, self.dtype, self.offset = path, m.shape, m.dtype, m.offset
        del m

    def write(self, start, values):
        with open(self.path, "r+b") as f:
            f.seek(self.offset + start * self.dtype.itemsize)
            f.write(np.ascontiguousarray(values, dtype=self.dtype).data)

    def read(self, start, count):
        with open(self.path, "rb") as f:
            f.seek(self.offset + start * self.dtype.itemsize)
            return np.fromfile(f, dtype=self.dtype, count=count)


class DiskRows:
    """A matrix stored at ``path`` (Zarr array or ``.npy``) with its progress record; see the module doc."""

    def __init__(self, path, shape, chunk, dtype, fingerprint):
        self.path = os.fspath(path)
        self.progress = self.path + ".progress"
        self.zarr = self.path.lower().endswith(".zarr")
        self.shape, self.chunk, self.dtype = shape, chunk, np.dtype(dtype)
        self.blocks = -(-shape[0] // chunk)
        self.tiles_path = os.path.join(self.progress, "source_columns.npy")
        if self.zarr:
            import zarr  # the 'distributed' extra; imported first, so nothing is created without it
            self._zarr = zarr
        self.lock = FileLock(self.path, "the matrix").acquire()
        try:
            stored = self._stored_fingerprint()
            symmetrize = bool(fingerprint.get("symmetrize", False))
            if stored is None:
                self._check_room(self.blocks, symmetrize)      # before anything is created
                self._create(fingerprint)
            else:
                _check_fingerprint(stored, fingerprint, self.path)
                self.array = self._open()
                self.verify()
                self._check_room(len(self.todo()), symmetrize)
        except BaseException:
            self.lock.release()
            raise

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.lock.release()

    def _stored_fingerprint(self):
        exists = os.path.exists(self.path)
        record = os.path.join(self.progress, "fingerprint.json")
        if not os.path.isfile(record):
            if exists:
                raise ValueError(f"expected out as a new path or one written by distance_matrix, got an existing "
                                 f"{self.path!r} without its progress record {record!r}")
            return None
        if not exists:  # killed between the record and the matrix, or the matrix was removed
            shutil.rmtree(self.progress)
            return None
        try:
            with open(record, encoding="utf-8") as f:
                stored = json.load(f)
        except (OSError, ValueError) as exc:
            stored = exc
        if not isinstance(stored, dict):
            raise ValueError(f"expected {record!r} as the JSON fingerprint that distance_matrix writes, got "
                             f"{type(stored).__name__}: {stored}; remove {self.path!r} and its progress record")
        return stored

    def _create(self, fingerprint):
        os.makedirs(self.progress)
        _write_atomic(os.path.join(self.progress, "fingerprint.json"), json.dumps(fingerprint, indent=1))
        if self.zarr:
            self.array = self._zarr.open_array(store=self.path, mode="w", shape=self.shape,
                                               chunks=(self.chunk, self.shape[1]), dtype=self.dtype,
                                               fill_value=np.nan)
        else:
            self.array = NpyFile(self.path, self.shape, self.dtype)

    def _open(self):
        if self.zarr:
            _check_zarr_metadata(self.path)
            try:
                array = self._zarr.open_array(store=self.path, mode="r+")
            except Exception as exc:  # zarr's errors differ between versions
                raise ValueError(f"expected {self.path!r} as a Zarr array written by distance_matrix, got an "
                                 f"unreadable store ({type(exc).__name__}: {exc})") from None
        else:
            array = NpyFile(self.path)
        if tuple(array.shape) != tuple(self.shape) or np.dtype(array.dtype) != self.dtype:
            raise ValueError(f"expected {self.path!r} of shape {self.shape} and dtype {self.dtype}, "
                             f"got shape {tuple(array.shape)} and dtype {array.dtype}")
        return array

    def _marker(self, kind, block):
        return os.path.join(self.progress, f"{kind}-{block:07d}")

    def _done(self, kind, block):
        return os.path.exists(self._marker(kind, block))

    def _mark(self, kind, block, done=True, rows=None):
        """Create (``done``) or remove the marker of ``block``; a rows marker holds the CRC-32 of ``rows``."""
        if done:
            _write_atomic(self._marker(kind, block), "" if rows is None else f"{_crc(rows, self.dtype)}\n")
        elif os.path.exists(self._marker(kind, block)):
            os.remove(self._marker(kind, block))

    def verify(self):
        """ValueError unless every block with a rows marker still holds the rows whose CRC-32 its marker
        recorded (a flipped bit on the disk, a block changed by hand, a marker not written here)."""
        c = self.chunk
        for block in range(self.blocks):
            if not self._done("rows", block):
                continue
            marker = self._marker("rows", block)
            with open(marker, encoding="ascii", errors="replace") as f:
                recorded = f.read().strip()
            lo, hi = block * c, min(self.shape[0], (block + 1) * c)
            found = _crc(self._rows(lo, hi), self.dtype)
            if recorded != str(found):
                raise ValueError(f"expected block {block} (rows {lo}..{hi - 1}) of {self.path!r} to hold the values "
                                 f"written there (CRC-32 {recorded or 'none'}), got CRC-32 {found}: the file changed "
                                 f"on the disk; remove {marker!r} to solve that block again")

    def todo(self):
        """Indices of the row blocks without a completion marker."""
        return [b for b in range(self.blocks) if not self._done("rows", b)]

    def _rows(self, lo, hi):
        if self.zarr:
            return self.array[lo:hi]
        return self.array.read(lo * self.shape[1], (hi - lo) * self.shape[1]).reshape(hi - lo, self.shape[1])

    def _write_rows(self, block, rows):
        lo = block * self.chunk
        if self.zarr:
            self.array[lo:lo + len(rows)] = rows
        else:
            self.array.write(lo * self.shape[1], rows)

    def _check_room(self, todo, symmetrize):
        """ValueError unless the file system of a ``.npy`` matrix has room for ``todo`` blocks still to
        write (and their strips of S with ``symmetrize``); a Zarr store compresses, so it is not checked."""
        if self.zarr:
            return
        c, itemsize = self.chunk, self.dtype.itemsize
        needed = todo * c * self.shape[1] * itemsize + (todo * self.blocks * c * c * itemsize if symmetrize else 0)
        check_room([(self.path, needed, "out")])

    @contextlib.contextmanager
    def _writing(self, block):
        """Turn a full disk while block ``block`` is written into a WriteError naming the matrix, the
        room left and how to go on (the blocks already written stay)."""
        try:
            yield
        except OSError as exc:
            if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
                raise
            free = shutil.disk_usage(os.path.dirname(os.path.abspath(self.path))).free
            size = format_bytes(self.chunk * self.shape[1] * self.dtype.itemsize)
            raise WriteError(f"could not write block {block} of {self.path!r} ({size}): {exc.strerror} "
                             f"({format_bytes(free)} free); the blocks written so far stay: make room and run the "
                             "same call again to go on", exc.errno) from None

    def write(self, block, rows, sources):
        """Rows of ``block`` (and, when ``sources`` is given, their source columns into S), then its marker.

        S is a (blocks, blocks, chunk, chunk) ``.npy``: tile (i, j) = S[rows of block i, columns of block j].
        """
        with self._writing(block):
            self._write_block(block, rows, sources)

    def _write_block(self, block, rows, sources):
        self._mark("symmetric", block, done=False)     # its rows are solved again, unsymmetrized
        self._write_rows(block, rows)
        if sources is not None:
            nb, c = self.blocks, self.chunk
            tiles = (NpyFile(self.tiles_path) if os.path.exists(self.tiles_path)
                     else NpyFile(self.tiles_path, (nb, nb, c, c), self.dtype))
            strip = np.zeros((c, nb * c), dtype=self.dtype)
            strip[:len(rows), :len(sources)] = rows[:, sources]
            tiles.write(block * nb * c * c, strip.reshape(c, nb, c).transpose(1, 0, 2))
            self._mark("tile", block)
        self._mark("rows", block, rows=rows)

    def symmetrize(self, sources):
        """Average the pairs of source columns, block by block from S (the module doc); S and its tile
        markers are removed when all blocks are done."""
        k, nb, c = len(sources), self.blocks, self.chunk
        todo = [b for b in range(nb) if not self._done("symmetric", b)]
        stored = np.array([self._done("tile", b) for b in range(nb)])
        if todo and stored.any():
            tiles = NpyFile(self.tiles_path) if os.path.exists(self.tiles_path) else None
            if tiles is None or tiles.shape != (nb, nb, c, c) or tiles.dtype != self.dtype:
                found = "none" if tiles is None else f"shape {tiles.shape} and dtype {tiles.dtype}"
                raise ValueError(f"expected {self.tiles_path!r} of shape {(nb, nb, c, c)} and dtype {self.dtype}, "
                                 f"got {found}; remove {self.path!r} and its progress record")
        for block in todo:
            lo, hi = block * c, min(k, (block + 1) * c)
            rows = self._rows(lo, hi)
            if stored[block]:
                s_rows = tiles.read(block * nb * c * c, nb * c * c).reshape(nb, c, c).transpose(1, 0, 2)
                s_cols = np.concatenate([tiles.read((j * nb + block) * c * c, c * c).reshape(c, c) for j in range(nb)])
                pairs = np.repeat(stored, c)[:k]                       # the source columns whose strips are in S
                rows[:, sources[pairs]] = 0.5 * (s_rows.reshape(c, -1)[:hi - lo, :k][:, pairs]
                                                 + s_cols[:k, :hi - lo][pairs].T)
            for j in np.flatnonzero(~stored):                        # final values: the transpose of block j's
                if j != block:
                    j0, j1 = j * c, min(k, (j + 1) * c)
                    rows[:, sources[j0:j1]] = self._rows(j0, j1)[:, sources[lo:hi]].T
            with self._writing(block):
                self._mark("rows", block, done=False)  # a write cut short is then solved again
                self._write_rows(block, rows)
                self._mark("rows", block, rows=rows)
                self._mark("symmetric", block)
        if os.path.exists(self.tiles_path):
            os.remove(self.tiles_path)
        for block in np.flatnonzero(stored):
            self._mark("tile", block, done=False)

    def result(self):
        """The Zarr array, or the ``.npy`` as a read-write memory map."""
        return self.array if self.zarr else np.load(self.path, mmap_mode="r+", allow_pickle=False)


def open_rows(out, shape, chunk, dtype, fingerprint):
    """A :class:`MemoryRows` for ``out=None``, else a :class:`DiskRows` at the path ``out``."""
    if out is None:
        return MemoryRows(shape, chunk, dtype)
    if not isinstance(out, (str, os.PathLike)) or not os.fspath(out).lower().endswith(OUT_EXTENSIONS):
        raise ValueError(f"expected out as a path ending in .zarr or .npy, got {out!r}")
    folder = os.path.dirname(os.path.abspath(out))
    if not os.path.isdir(folder):
        raise ValueError(f"expected out in an existing directory, got {out!r} (no directory {folder!r})")
    return DiskRows(out, shape, chunk, dtype, fingerprint)


def _check_fingerprint(stored, given, path):
    for key, value in given.items():
        if stored.get(key) != value:
            raise ValueError(f"expected {path!r} to hold the same problem ({key} {value!r}), got {key} "
                             f"{stored.get(key)!r} there; remove it or choose another path")


ZARR_CODECS = ("bytes", "zstd", "blosc", "gzip", "crc32c", "transpose")
"""The codecs a stored Zarr array may use: what zarr writes by default, compressors and checksums
that hold data only. A store naming any other (a pickle or object codec) is refused unread."""


def _check_zarr_metadata(path):
    """ValueError unless the Zarr store ``path`` is a v3 array of float32 / float64 whose codecs are
    all in :data:`ZARR_CODECS` (read as JSON before zarr opens it)."""
    record = os.path.join(path, "zarr.json")
    try:
        with open(record, encoding="utf-8") as f:
            meta = json.load(f)
        codecs = [c["name"] if isinstance(c, dict) else c for c in meta.get("codecs", [])]
        kind = (meta.get("zarr_format"), meta.get("node_type"), meta.get("data_type"))
        transformers = meta.get("storage_transformers", [])
    except (OSError, ValueError, TypeError, KeyError, AttributeError) as exc:
        raise ValueError(f"expected {path!r} as a Zarr v3 array written by distance_matrix, got no readable "
                         f"{record!r} ({type(exc).__name__}: {exc})") from None
    foreign = [c for c in codecs if c not in ZARR_CODECS]
    if kind[:2] != (3, "array") or kind[2] not in ("float32", "float64") or foreign or transformers:
        raise ValueError(f"expected {path!r} as a Zarr v3 float32/float64 array with codecs among {list(ZARR_CODECS)}, "
                         f"got format {kind[0]!r}, node {kind[1]!r}, data type {kind[2]!r}, codecs {codecs}"
                         f"{', storage transformers' if transformers else ''}; it was not read")


def _crc(rows, dtype):
    """CRC-32 of ``rows`` as stored: C-order bytes in ``dtype``."""
    return zlib.crc32(np.ascontiguousarray(rows, dtype=dtype).data)


def _write_atomic(path, text):
    def write(tmp):
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)

    write_atomic(path, write, "the progress record")
