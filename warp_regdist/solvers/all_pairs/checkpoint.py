"""All-pairs checkpoints: the file a run writes (:class:`Checkpoint`: its size, the room for it, atomic
saves), the fingerprint of the problem it holds, and reading one back as data (never unpickled):
checked against the problem and against the CRC-32 of every array before use, then read one array at
a time (a resumed run needs one state array more than a fresh one, not a second copy of the state)."""

from __future__ import annotations

import contextlib
import json
import os
import warnings
import zipfile
import zlib

import numpy as np

from ...atomic_write import write_atomic
from ...errors import CheckpointWarning, WriteError
from ...kernels.lanes import SCALARS, lane_width
from .state import STATE_ROWS

__all__ = ["Checkpoint", "checkpoint_bytes", "checkpoint_name", "checkpoint_room", "check_no_progress",
           "saved_iteration", "problem_fingerprint", "read_checkpoint"]


class Checkpoint:
    """The checkpoint file of one run: ``path``, written every ``seconds``, holding ``fingerprint``
    (the problem), at most ``bytes`` large; ``saved_at`` is the iteration the file holds (None until
    this run wrote it, or resumed it).

    :meth:`save` writes atomically; a save that fails (a full disk, a read-only directory) warns
    once with a :class:`~warp_regdist.CheckpointWarning` and leaves the last checkpoint as it was.
    """

    def __init__(self, path, seconds, fingerprint, bytes):
        self.path, self.seconds, self.fingerprint, self.bytes = os.fspath(path), seconds, fingerprint, bytes
        self.saved_at = None
        self.failed = False

    def save(self, arrays, iteration):
        """Write ``arrays`` (name -> array) with the fingerprint as the state of ``iteration``."""
        data = dict(arrays, fingerprint=np.array(json.dumps(self.fingerprint)))

        def write(tmp):
            with open(tmp, "wb") as f:
                np.savez(f, **data)

        try:
            write_atomic(self.path, write, "the checkpoint", size=self.bytes)
            self.saved_at = iteration
        except WriteError as exc:
            if not self.failed:
                kept = (f" (the checkpoint of iteration {self.saved_at} stays valid)" if self.saved_at is not None
                        else "")
                warnings.warn(f"{exc}; the run goes on without this checkpoint{kept}, and tries again at the next "
                              "one", CheckpointWarning, stacklevel=3)
            self.failed = True


def checkpoint_bytes(n, m, dtype, max_iterations):
    """Upper bound of the size of an all-pairs checkpoint file: the (n, n) state arrays and the
    (3m, n) element state in ``dtype`` (lanes padded), the residual history, small scalars."""
    W = lane_width(SCALARS[dtype], n)
    cols = -(-n // W) * W
    return (np.dtype(dtype).itemsize * cols * ((len(STATE_ROWS) + 1) * n + 3 * m + 8)  # + the change test's U
            + 56 * (max_iterations + 1) + 65536)


def checkpoint_name(path, role):
    """``path`` (the ``role`` argument: "checkpoint", "resume", "initial") as a str; ValueError unless it
    is a non-empty str or os.PathLike."""
    if not isinstance(path, (str, os.PathLike)) or not os.fspath(path):
        raise ValueError(f"expected {role} as a file name (str or os.PathLike), got {path!r}")
    return os.fspath(path)


def checkpoint_room(path, size):
    """The (path, bytes, what) entry of :func:`~warp_regdist.atomic_write.check_room` for a checkpoint of
    ``size`` bytes rewritten during a run: each save writes a new copy beside the last one, so the run
    needs room for two, less a file already at ``path``. ValueError unless ``path`` can be written."""
    path = checkpoint_name(path, "checkpoint")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise ValueError(f"expected checkpoint in an existing directory, got {path!r} (no directory {folder!r})")
    if os.path.isdir(path) or not os.access(folder, os.W_OK):
        raise ValueError(f"expected checkpoint as a writable file name, got {path!r}")
    existing = os.path.getsize(path) if os.path.isfile(path) else 0
    return path, max(size, 2 * size - existing), "two copies of the checkpoint"


def saved_iteration(path):
    """The iteration count recorded in the checkpoint ``path`` ("converged" for a final one), or None
    when the file is not a readable checkpoint (only the small arrays are read)."""
    try:
        with np.load(os.fspath(path), allow_pickle=False) as saved:
            if "final" in saved.files:
                return "converged"
            return int(saved["iteration"])
    except Exception:  # noqa: BLE001 - whatever the file holds, it is not a readable checkpoint
        return None


def check_no_progress(checkpoint, resume, flags=("checkpoint", "resume=", "restart=True")):
    """ValueError when the file ``checkpoint`` exists and is not ``resume``: writing there would discard
    a run's progress. ``flags`` name the argument and the two ways on (continue it, discard it)."""
    path = os.fspath(checkpoint)
    if not os.path.exists(path) or (resume is not None and os.path.exists(os.fspath(resume))
                                    and os.path.samefile(path, os.fspath(resume))):
        return
    iteration = saved_iteration(path)
    held = ("a file that is not a readable checkpoint" if iteration is None else
            "the checkpoint of a converged run" if iteration == "converged" else
            f"a checkpoint at iteration {iteration}")
    raise ValueError(f"expected {flags[0]} as a new file or the one resumed, got {path!r} holding {held}: "
                     f"{flags[1]}{path!r} continues it, {flags[2]} discards it")


def problem_fingerprint(mesh, alpha_hat, dtype, rho2_factor, triangulation, source_triangles, engine):
    """What identifies the problem of a checkpoint (JSON-able dict): the engine too, whose iterates
    another engine does not continue."""
    return dict(mesh_sha256=mesh.sha256(), n_vertices=int(mesh.n_vertices), alpha_hat=float(alpha_hat),
                dtype=dtype, rho2_factor=float(rho2_factor), triangulation=triangulation,
                source_triangles=source_triangles, engine=engine)


def read_checkpoint(path, fingerprint, n_elements, keys=None, role="resume"):
    """Checkpoint ``path`` (the ``role`` argument) as an open :class:`numpy.lib.npyio.NpzFile`, each
    array read when accessed, after checking from the arrays' headers that it agrees with
    ``fingerprint`` on ``keys`` (None: all, the same problem) and holds the arrays of that problem.
    The caller closes it (it is a context manager)."""
    path = os.fspath(path)
    with contextlib.ExitStack() as stack:
        try:
            saved = np.load(path, allow_pickle=False)
            if not isinstance(saved, np.lib.npyio.NpzFile):
                raise ValueError(f"a {type(saved).__name__}, not an .npz archive")
            stack.callback(saved.close)
            theirs = json.loads(str(saved["fingerprint"]))
            if not isinstance(theirs, dict):
                raise ValueError(f"a fingerprint {theirs!r}")
            headers = {name: _array_header(saved, name) for name in saved.files}
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, TypeError) as exc:
            raise ValueError(f"expected {role} as an all-pairs checkpoint (.npz), got {path!r} "
                             f"({type(exc).__name__}: {exc})") from None
        differ = [k for k in (fingerprint if keys is None else keys) if theirs.get(k) != fingerprint[k]]
        if differ:
            shown = ", ".join(f"{k} {fingerprint[k]!r}" for k in differ)
            got = ", ".join(f"{k} {theirs.get(k)!r}" for k in differ)
            what = "this problem" if keys is None else "this mesh and dtype"
            raise ValueError(f"expected a checkpoint of {what} ({shown}), got one of another problem ({got}) "
                             f"in {path!r}")
        first = int(saved["iteration"]) if headers.get("iteration", (None,))[0] == () else 0
        check_checkpoint_arrays(headers, first, fingerprint["n_vertices"], n_elements, fingerprint["dtype"], path,
                                role)
        check_crc(saved.zip, path, role)
        stack.pop_all()
    return saved


def check_crc(archive, path, role):
    """ValueError unless every array of the open zip ``archive`` matches the CRC-32 recorded for it
    (the whole file is read once, 64 KiB at a time, before the run allocates anything)."""
    for name in archive.namelist():
        try:
            with archive.open(name) as f:
                while f.read(1 << 16):   # zipfile compares the CRC-32 at the end of the member
                    pass
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise ValueError(f"expected {role} as an intact all-pairs checkpoint, got {path!r} whose array "
                             f"{name.removesuffix('.npy')!r} cannot be read back as written ({type(exc).__name__}: "
                             f"{exc}; the file changed on the disk)") from None


def _array_header(npz, name):
    """(shape, dtype) of array ``name`` of an open .npz, from its .npy header (the data is not read)."""
    with npz.zip.open(name + ".npy") as f:
        version = np.lib.format.read_magic(f)
        read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = read(f)
    return shape, dtype


def checkpoint_shapes(n, m, dtype):
    """{name: (shape, dtype)} of the arrays an all-pairs checkpoint of n vertices and m triangles may hold."""
    W = lane_width(SCALARS[dtype], n)
    nb = -(-n // W)
    state, f8 = ((n, nb, W), dtype), "float64"
    shapes = {name: state for name in STATE_ROWS + ("change_snapshot",)}
    shapes.update(v=((m, 3, nb, W), dtype), iteration=((), "int64"), rho_v=((), f8), cg_iterations=((), "int64"),
                  seconds=((), f8), penalties=((2,), f8), cols=((3, nb * W), f8), pairs=((5,), f8),
                  change=((2,), f8), excess=((), f8), residuals=((7,), f8), tolerance=((7,), f8), final=((), "bool"))
    return shapes


def check_checkpoint_arrays(headers, first, n, m, dtype, path, role):
    """ValueError unless ``headers`` ({name: (shape, dtype)} of a checkpoint's arrays, its iteration
    ``first``) are those a run of this problem needs."""
    shapes = checkpoint_shapes(n, m, dtype)
    if role == "initial":
        required = ("X", "U", "H", "v", "rho_v")
    else:
        required = ("X", "U", "H", "v", "iteration", "rho_v", "cg_iterations", "seconds", "history")
        required += ("residuals", "tolerance") if "final" in headers else ("DZ", "DZ_acc", "DY_acc")
        if first > 0:
            required += ("penalties", "cols", "pairs")
    missing = [name for name in required if name not in headers]
    if missing:
        raise ValueError(f"expected {role} as a complete all-pairs checkpoint, got {path!r} without "
                         f"{', '.join(missing)}")
    for name, (shape, kind) in headers.items():
        if name == "history":
            ok = len(shape) == 2 and shape[1] == 7 and kind == np.float64
            expected = "(k, 7) float64"
        elif name in shapes:
            ok = shape == shapes[name][0] and kind == np.dtype(shapes[name][1])
            expected = f"{shapes[name][0]} {shapes[name][1]}"
        else:
            continue
        if not ok:
            raise ValueError(f"expected {role} checkpoint array {name!r} of shape and dtype {expected}, got "
                             f"{shape} {kind} in {path!r}")
