"""Row blocks of a distance matrix, in memory or on disk (Zarr or a ``.npy`` memory map), resumable.

A (k, n) matrix is written in blocks of ``chunk`` consecutive rows. On disk, next to the
matrix ``D.zarr`` (or ``D.npy``) lies the directory ``D.zarr.progress`` holding the problem's
fingerprint (``fingerprint.json``, written before the matrix) and one empty marker file per
block, created only after the block's rows are on disk: a block half-written by a killed run
has no marker and is redone. An ``out`` whose fingerprint differs from the call's is refused.

Symmetrization (D[r, src[c]] and D[c, src[r]] replaced by their mean) works block by block on
the stored rows: while solving, each block's source columns are also written, tile-major,
into ``source_columns.npy`` (S, (k, k) in (chunk, chunk) tiles), and row block I is then
rewritten from S alone, D[I, src] = (S[I, :] + S[:, I]^T) / 2, so redoing it is harmless.
Memory: two (chunk, n) row blocks and two (chunk, k) strips of S.
"""

from __future__ import annotations

import json
import os
import shutil

import numpy as np

__all__ = ["MemoryRows", "DiskRows", "open_rows", "average_source_pairs", "OUT_EXTENSIONS"]

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


class DiskRows:
    """A matrix stored at ``path`` (Zarr array or ``.npy``) with its progress record; see the module doc."""

    def __init__(self, path, shape, chunk, dtype, fingerprint):
        self.path = os.fspath(path)
        self.progress = self.path + ".progress"
        self.zarr = self.path.lower().endswith(".zarr")
        self.shape, self.chunk, self.dtype = shape, chunk, np.dtype(dtype)
        self.blocks = -(-shape[0] // chunk)
        if self.zarr:
            import zarr  # the 'distributed' extra; imported first, so nothing is created without it
            self._zarr = zarr
        stored = self._stored_fingerprint()
        if stored is None:
            self._create(fingerprint)
        else:
            _check_fingerprint(stored, fingerprint, self.path)
            self.array = self._open()

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
        with open(record, encoding="utf-8") as f:
            return json.load(f)

    def _create(self, fingerprint):
        os.makedirs(self.progress)
        _write_atomic(os.path.join(self.progress, "fingerprint.json"), json.dumps(fingerprint, indent=1))
        if self.zarr:
            self.array = self._zarr.open_array(store=self.path, mode="w", shape=self.shape,
                                               chunks=(self.chunk, self.shape[1]), dtype=self.dtype,
                                               fill_value=np.nan)
        else:
            self.array = np.lib.format.open_memmap(self.path, mode="w+", dtype=self.dtype, shape=self.shape)

    def _open(self):
        array = (self._zarr.open_array(store=self.path, mode="r+") if self.zarr
                 else np.lib.format.open_memmap(self.path, mode="r+"))
        if tuple(array.shape) != tuple(self.shape) or np.dtype(array.dtype) != self.dtype:
            raise ValueError(f"expected {self.path!r} of shape {self.shape} and dtype {self.dtype}, "
                             f"got shape {tuple(array.shape)} and dtype {array.dtype}")
        return array

    def _marker(self, kind, block):
        return os.path.join(self.progress, f"{kind}-{block:07d}")

    def _done(self, kind, block):
        return os.path.exists(self._marker(kind, block))

    def _mark(self, kind, block, done=True):
        if done:
            open(self._marker(kind, block), "w").close()
        elif os.path.exists(self._marker(kind, block)):
            os.remove(self._marker(kind, block))

    def todo(self):
        """Indices of the row blocks without a completion marker."""
        return [b for b in range(self.blocks) if not self._done("rows", b)]

    def _tiles(self, mode):
        """S in (chunk, chunk) tiles: memory map of shape (blocks, blocks, chunk, chunk)."""
        path = os.path.join(self.progress, "source_columns.npy")
        if mode == "r+" and not os.path.exists(path):
            mode = "w+"
        shape = (self.blocks, self.blocks, self.chunk, self.chunk)
        return np.lib.format.open_memmap(path, mode=mode, dtype=self.dtype, shape=shape if mode == "w+" else None)

    def _write_rows(self, block, rows):
        self.array[block * self.chunk:block * self.chunk + len(rows)] = rows
        if not self.zarr:
            self.array.flush()

    def write(self, block, rows, sources):
        """Rows of ``block`` (and, when ``sources`` is given, their source columns into S), then its marker."""
        self._write_rows(block, rows)
        if sources is not None:
            tiles = self._tiles("r+")
            strip = np.zeros((self.chunk, self.blocks * self.chunk), dtype=self.dtype)
            strip[:len(rows), :len(sources)] = rows[:, sources]
            tiles[block] = strip.reshape(self.chunk, self.blocks, self.chunk).transpose(1, 0, 2)
            tiles.flush()
            del tiles
        self._mark("rows", block)

    def symmetrize(self, sources):
        """Average the pairs of source columns, block by block from S; S is removed when all are done."""
        k = len(sources)
        path = os.path.join(self.progress, "source_columns.npy")
        todo = [b for b in range(self.blocks) if not self._done("symmetric", b)]
        if todo:
            tiles = self._tiles("r")
            for block in todo:
                lo, hi = block * self.chunk, min(k, (block + 1) * self.chunk)
                s_rows = tiles[block].transpose(1, 0, 2).reshape(self.chunk, -1)[:hi - lo, :k]
                s_cols = tiles[:, block].reshape(-1, self.chunk)[:k, :hi - lo]
                rows = average_source_pairs(np.asarray(self.array[lo:hi]), sources, s_rows, s_cols)
                self._mark("rows", block, done=False)  # a write cut short is then solved again
                self._write_rows(block, rows)
                self._mark("rows", block)
                self._mark("symmetric", block)
            del tiles
        if os.path.exists(path):
            os.remove(path)

    def result(self):
        return self.array


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


def _write_atomic(path, text):
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
