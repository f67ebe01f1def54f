"""Files a user passes back in are data: checkpoints and matrix progress records are read
without unpickling and checked before use (truncated, empty, foreign, wrong shapes: an
"expected ..., got ..." ValueError), and one run at a time writes an output (a lock file
that the kernel releases when its owner dies)."""

import os
import signal
import subprocess
import sys
import warnings

import numpy as np
import pytest

import meshes
import warp_regdist as wrd
from warp_regdist.file_lock import FileLock

HOLD = """
import sys, time
from warp_regdist.file_lock import FileLock
lock = FileLock(sys.argv[1]).acquire()
print("LOCKED", flush=True)
time.sleep(600)
"""


@pytest.fixture(scope="module")
def sphere():
    V, F = meshes.icosphere(2, 1.0)
    return wrd.Mesh(meshes.perturbed(V, F, 0.05, seed=4), F)


@pytest.fixture(scope="module")
def checkpoint(sphere, tmp_path_factory):
    path = tmp_path_factory.mktemp("ckpt") / "run.npz"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        wrd.all_pairs(sphere, 0.05, max_iterations=4, device="cpu", checkpoint=path)
    return path


@pytest.fixture
def holder(tmp_path):
    """A second process that holds the lock of a path: call with the path; killed at the end."""
    procs = []

    def hold(path):
        proc = subprocess.Popen([sys.executable, "-c", HOLD, str(path)], stdout=subprocess.PIPE, text=True)
        procs.append(proc)
        assert proc.stdout.readline().strip() == "LOCKED"
        return proc

    yield hold
    for proc in procs:
        proc.kill()
        proc.wait()
        proc.stdout.close()


def _resume(sphere, path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        return wrd.all_pairs(sphere, 0.05, max_iterations=5, device="cpu", resume=path)


@pytest.mark.parametrize("size", [0, 50, "half"])
def test_truncated_checkpoint_is_refused(sphere, checkpoint, tmp_path, size):
    data = checkpoint.read_bytes()
    cut = tmp_path / "cut.npz"
    cut.write_bytes(data[:len(data) // 2 if size == "half" else size])
    with pytest.raises(ValueError, match=r"expected resume as an all-pairs checkpoint \(\.npz\), got '.*cut\.npz' "
                                         r"\((BadZipFile|EOFError): "):
        _resume(sphere, cut)


def test_npy_file_is_refused_as_a_checkpoint(sphere, tmp_path):
    np.save(tmp_path / "u.npy", np.zeros(3))
    with pytest.raises(ValueError, match=r"expected resume as an all-pairs checkpoint \(\.npz\), got '.*u\.npy' "
                                         r"\(ValueError: a ndarray, not an \.npz archive\)"):
        _resume(sphere, tmp_path / "u.npy")


def test_pickled_checkpoint_is_refused_without_running_it(sphere, checkpoint, tmp_path):
    saved = dict(np.load(checkpoint))
    saved["U"] = np.array([{"not": "data"}], dtype=object)
    bad = tmp_path / "pickled.npz"
    np.savez(bad, **saved)
    with pytest.raises(ValueError, match=r"expected resume checkpoint array 'U' of shape and dtype \(162, \d+, \d+\) "
                                         r"float64, got \(1,\) object in '.*pickled\.npz'"):
        _resume(sphere, bad)                       # refused from its header, never unpickled
    saved["fingerprint"] = np.array([{"not": "data"}], dtype=object)
    np.savez(bad, **saved)
    with pytest.raises(ValueError, match=r"expected resume as an all-pairs checkpoint \(\.npz\), got '.*pickled\.npz' "
                                         r"\(ValueError: Object arrays cannot be loaded when allow_pickle=False\)"):
        _resume(sphere, bad)


def test_checkpoint_arrays_are_checked(sphere, checkpoint, tmp_path):
    saved = dict(np.load(checkpoint))
    shape = saved["U"].shape
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, **{**saved, "U": saved["U"][:-1]})
    with pytest.raises(ValueError, match=rf"expected resume checkpoint array 'U' of shape and dtype "
                                         rf"\({shape[0]}, {shape[1]}, {shape[2]}\) float64, got \({shape[0] - 1}, "):
        _resume(sphere, wrong)
    np.savez(wrong, **{**saved, "v": saved["v"].astype(np.float32)})
    with pytest.raises(ValueError, match=r"expected resume checkpoint array 'v' of shape and dtype .* float64, got "
                                         r".* float32"):
        _resume(sphere, wrong)
    np.savez(wrong, **{k: a for k, a in saved.items() if k != "DZ"})
    with pytest.raises(ValueError, match=r"expected resume as a complete all-pairs checkpoint, got '.*wrong\.npz' "
                                         r"without DZ"):
        _resume(sphere, wrong)
    np.savez(wrong, **{**saved, "fingerprint": np.array("[1, 2]")})
    with pytest.raises(ValueError, match=r"expected resume as an all-pairs checkpoint .*\(ValueError: a fingerprint "):
        _resume(sphere, wrong)
    np.savez(wrong, **{k: a for k, a in saved.items() if k != "X"})
    with pytest.raises(ValueError, match=r"expected initial as a complete all-pairs checkpoint, got .* without X"):
        wrd.all_pairs(sphere, 0.1, max_iterations=2, device="cpu", initial=wrong)


def test_a_checkpoint_has_one_writer(sphere, checkpoint, tmp_path, holder):
    path = tmp_path / "run.npz"
    proc = holder(path)
    with pytest.raises(ValueError, match=rf"expected no other run writing the checkpoint '.*run\.npz', got one "
                                         rf"holding its lock '.*run\.npz\.lock' \(pid {proc.pid}\)"):
        wrd.all_pairs(sphere, 0.05, max_iterations=2, device="cpu", checkpoint=path)
    assert not path.exists()
    os.kill(proc.pid, signal.SIGKILL)  # a killed owner leaves no stale lock
    proc.wait()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        res = wrd.all_pairs(sphere, 0.05, max_iterations=2, device="cpu", checkpoint=path)
    assert res.iterations == 2 and path.exists() and not (tmp_path / "run.npz.lock").exists()


def test_a_matrix_output_has_one_writer(sphere, tmp_path, holder):
    out = tmp_path / "D.npy"
    proc = holder(out)
    with pytest.raises(ValueError, match=rf"expected no other run writing the matrix '.*D\.npy', got one holding its "
                                         rf"lock '.*D\.npy\.lock' \(pid {proc.pid}\)"):
        wrd.distance_matrix(sphere, sources=[0, 5], out=str(out))
    assert not out.exists()
    proc.kill()
    proc.wait()
    D = wrd.distance_matrix(sphere, sources=[0, 5], out=str(out))
    assert D.shape == (2, sphere.n_vertices) and not (tmp_path / "D.npy.lock").exists()


def test_lock_in_one_process(tmp_path):
    with FileLock(tmp_path / "x", "the file"):
        with pytest.raises(ValueError, match=rf"expected no other run writing the file '.*x', got one holding its "
                                             rf"lock '.*x\.lock' \(pid {os.getpid()}\)"):
            FileLock(tmp_path / "x", "the file").acquire()
    assert not (tmp_path / "x.lock").exists()
    with FileLock(tmp_path / "x"):  # free again
        pass


def _started_matrix(sphere, out):
    """A matrix run on ``out`` stopped after its first block (progress record and one block on disk)."""
    def stop(done, total, seconds):
        if done == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        wrd.distance_matrix(sphere, sources=[0, 5, 9, 30], chunk=2, out=str(out), progress=stop)


def test_damaged_matrix_progress_is_refused(sphere, tmp_path):
    out = tmp_path / "D.npy"
    _started_matrix(sphere, out)
    record = tmp_path / "D.npy.progress" / "fingerprint.json"
    text = record.read_text()
    record.write_text(text[:len(text) // 2])
    with pytest.raises(ValueError, match=r"expected '.*fingerprint\.json' as the JSON fingerprint that "
                                         r"distance_matrix writes, got JSONDecodeError: .*; remove '.*D\.npy' and its "
                                         "progress record"):
        wrd.distance_matrix(sphere, sources=[0, 5, 9, 30], chunk=2, out=str(out))
    record.write_text(text)
    data = out.read_bytes()
    out.write_bytes(data[:len(data) // 2])
    with pytest.raises(ValueError, match=r"expected '.*D\.npy' as a \.npy array written by distance_matrix, got an "
                                         r"unreadable file \(ValueError: "):
        wrd.distance_matrix(sphere, sources=[0, 5, 9, 30], chunk=2, out=str(out))
    np.save(out, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match=r"expected '.*D\.npy' as a \.npy array written by distance_matrix, got an "
                                         r"unreadable file \(ValueError: .*([Oo]bject|pickle)"):
        wrd.distance_matrix(sphere, sources=[0, 5, 9, 30], chunk=2, out=str(out))


def test_foreign_source_columns_are_refused(sphere, tmp_path):
    out = tmp_path / "D.npy"
    _started_matrix(sphere, out)
    np.save(tmp_path / "D.npy.progress" / "source_columns.npy", np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"expected '.*source_columns\.npy' of shape \(2, 2, 2, 2\) and dtype float64, "
                                         r"got shape \(3, 3\) and dtype float64; remove '.*D\.npy' and its progress "
                                         "record"):
        wrd.distance_matrix(sphere, sources=[0, 5, 9, 30], chunk=2, out=str(out))
