"""distance_matrix: rows on a Dask LocalCluster (2 worker processes) equal the local rows, a
killed worker's blocks are solved again, Zarr / .npy outputs are written block by block and
resumed, mismatching outputs are refused, and the ``warp-regdist matrix`` command.

Dask runs its workers with one BLAS thread (OMP_NUM_THREADS=1), which rounds the multigrid
set-up differently: their rows agree with this process's to ~1e-12 (bit for bit when this
process also runs with one BLAS thread), hence ``CLUSTER`` below."""

import inspect
import json
import os
import re

import numpy as np
import pytest

import warp_regdist as wrd
from meshes import icosphere, perturbed, square_grid
from warp_regdist.matrices import matrix_store
from warp_regdist.cli import main

distributed = pytest.importorskip("distributed")
pytest.importorskip("zarr")

SOURCES = np.array([40, 3, 17, 88, 120, 5, 61, 150, 9, 33])  # not sorted: rows follow this order
CHUNK = 3  # 4 blocks, the last one short
CLUSTER = 1e-9  # agreement with the cluster's rows, relative to the largest distance


@pytest.fixture(scope="module")
def mesh():
    V, F = icosphere(2)
    return wrd.Mesh(perturbed(V, F, 0.05), F)


@pytest.fixture(scope="module")
def rows(mesh):
    """Unsymmetrized rows from one batched solve, and their symmetrized matrix."""
    raw = wrd.DistanceSolver(mesh, 0.05).solve_many([[s] for s in SOURCES]).distance.T
    sym = raw.copy()
    block = raw[:, SOURCES]
    sym[:, SOURCES] = 0.5 * (block + block.T)
    return raw, sym


@pytest.fixture(scope="module")
def client():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster, distributed.Client(cluster) as c:
        yield c


def _matrix(mesh, **kwargs):
    return wrd.distance_matrix(mesh, 0.05, sources=SOURCES, chunk=CHUNK, **kwargs)


def test_default_alpha_hat_is_the_single_source_one():
    default = inspect.signature(wrd.distance_matrix).parameters["alpha_hat"].default
    assert default == inspect.signature(wrd.DistanceSolver).parameters["alpha_hat"].default == 0.05


def test_local_rows_equal_batched_single_sources(mesh, rows):
    raw, sym = rows
    assert np.array_equal(_matrix(mesh, symmetrize=False), raw)
    D = _matrix(mesh)
    assert np.array_equal(D, sym)
    assert np.array_equal(D[:, SOURCES], D[:, SOURCES].T) and np.all(np.diag(D[:, SOURCES]) == 0)


def test_rows_on_a_flat_square_are_euclidean(tmp_path):
    """alpha_hat 0 on a convex flat domain: the discrete geodesic distance, within 7% of the max
    of the Euclidean one on this 17 x 17 grid (5.9% measured; two rows swapped: 71%)."""
    V, F = square_grid(17)
    src = np.array([0, 16, 144, 288, 200, 77])
    D = wrd.distance_matrix(wrd.Mesh(V, F), 0.0, sources=src, chunk=4, out=str(tmp_path / "D.npy"))
    euclidean = np.linalg.norm(V[src][:, None, :] - V[None, :, :], axis=2)
    assert np.abs(D - euclidean).max() < 0.07 * euclidean.max()


def test_cluster_equals_local(mesh, rows, client, tmp_path):
    raw, sym = rows
    lazy = _matrix(mesh, client=client)
    assert lazy.chunks[0] == (3, 3, 3, 1) and lazy.dtype == np.float64
    np.testing.assert_allclose(lazy.compute(), sym, rtol=0, atol=CLUSTER * sym.max())
    np.testing.assert_allclose(_matrix(mesh, client=client, symmetrize=False).compute(), raw, rtol=0,
                               atol=CLUSTER * raw.max())
    stored = _matrix(mesh, client=client, out=str(tmp_path / "D.zarr"), dtype="float32")
    assert stored.dtype == np.float32
    np.testing.assert_allclose(stored[:], sym, rtol=0, atol=2e-3 * sym.max())


class _DieInBlockOnce(distributed.WorkerPlugin):
    """Makes the worker that first starts the block whose first source is ``first`` exit at once
    (``os._exit``, as a crash or an out-of-memory kill would), once per ``marker`` file.

    The death happens inside the block's task, so the scheduler must run that block again on a
    worker, whatever the timing of the other blocks."""

    def __init__(self, marker, first):
        self.marker, self.first = marker, first

    def setup(self, worker):
        import warp_regdist.matrices.distributed as wd

        self.solve_rows = solve_rows = wd.solve_rows
        marker, first = self.marker, self.first

        def die_once(solver, sources):
            if sources[0] == first:
                try:
                    os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
                except FileExistsError:
                    pass
                else:
                    os._exit(1)
            return solve_rows(solver, sources)

        wd.solve_rows = die_once

    def teardown(self, worker):
        import warp_regdist.matrices.distributed as wd

        wd.solve_rows = self.solve_rows


def test_killed_worker_blocks_are_solved_again(mesh, rows, client, tmp_path):
    marker = tmp_path / "died"
    client.register_plugin(_DieInBlockOnce(str(marker), int(SOURCES[CHUNK])), name="die-in-block-once")
    try:
        D = _matrix(mesh, client=client, out=str(tmp_path / "D.npy"))
    finally:
        client.unregister_worker_plugin("die-in-block-once")
        client.wait_for_workers(2, timeout=120)  # the nanny's restarted worker, for the next tests
    assert marker.exists()  # a worker died inside block 1's task
    assert not np.isnan(D).any()
    np.testing.assert_allclose(D, rows[1], rtol=0, atol=CLUSTER * rows[1].max())


@pytest.mark.parametrize("name", ["D.zarr", "D.npy"])
def test_disk_output_and_resume(mesh, rows, tmp_path, name):
    out = str(tmp_path / name)
    calls = []

    def stop_after_two(done, total, seconds):
        calls.append((done, total))
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _matrix(mesh, out=out, progress=stop_after_two)
    assert calls == [(0, 4), (1, 4), (2, 4)]
    assert sorted(f for f in os.listdir(out + ".progress") if f.startswith("rows")) == ["rows-0000000",
                                                                                        "rows-0000001"]
    calls.clear()
    D = _matrix(mesh, out=out, progress=lambda *a: calls.append(a[:2]))
    assert calls == [(2, 4), (3, 4), (4, 4)]  # the two blocks on disk were skipped
    assert np.array_equal(np.asarray(D[:]), rows[1])
    assert not os.path.exists(os.path.join(out + ".progress", "source_columns.npy"))
    calls.clear()
    again = _matrix(mesh, out=out, progress=lambda *a: calls.append(a[:2]))
    assert calls == [(4, 4)] and np.array_equal(np.asarray(again[:]), rows[1])


def test_symmetrization_interrupted_and_resumed(mesh, rows, tmp_path, monkeypatch):
    out = str(tmp_path / "D.npy")
    mark = matrix_store.DiskRows._mark
    count = [0]

    def interrupted_after_one_block(self, kind, block, done=True, rows=None):
        if kind == "symmetric" and count[0] == 1:
            raise KeyboardInterrupt
        count[0] += kind == "symmetric"
        mark(self, kind, block, done, rows)

    monkeypatch.setattr(matrix_store.DiskRows, "_mark", interrupted_after_one_block)
    with pytest.raises(KeyboardInterrupt):
        _matrix(mesh, out=out)
    monkeypatch.undo()
    assert np.array_equal(_matrix(mesh, out=out), rows[1])  # the block symmetrized twice is unchanged


def test_half_written_block_is_solved_again(mesh, rows, tmp_path):
    out = str(tmp_path / "D.npy")
    _matrix(mesh, out=out, symmetrize=False)
    os.remove(os.path.join(out + ".progress", "rows-0000002"))  # as if killed before its marker
    damaged = np.load(out, mmap_mode="r+")
    damaged[6:9] = np.nan
    damaged.flush()
    del damaged
    assert np.array_equal(_matrix(mesh, out=out, symmetrize=False), rows[0])


def test_refuses_another_problem_and_bad_input(mesh, tmp_path, client):
    out = str(tmp_path / "D.npy")
    _matrix(mesh, out=out, symmetrize=False)
    with pytest.raises(ValueError, match=r"expected '.*D\.npy' to hold the same problem \(alpha_hat 0\.06\), "
                                         r"got alpha_hat 0\.05 there"):
        wrd.distance_matrix(mesh, 0.06, sources=SOURCES, chunk=CHUNK, out=out, symmetrize=False)
    with pytest.raises(ValueError, match=r"same problem \(symmetrize True\), got symmetrize False"):
        _matrix(mesh, out=out)
    with pytest.raises(ValueError, match=r"same problem \(sources_sha256 '[0-9a-f]+'\)"):
        wrd.distance_matrix(mesh, 0.05, sources=SOURCES[::-1], chunk=CHUNK, out=out, symmetrize=False)
    with open(os.path.join(out + ".progress", "fingerprint.json")) as f:
        assert json.load(f)["mesh_sha256"] == mesh.sha256()
    foreign = tmp_path / "other.npy"
    np.save(foreign, np.zeros((10, 162)))
    with pytest.raises(ValueError, match=r"expected out as a new path or one written by distance_matrix, got an "
                                         r"existing '.*other\.npy' without its progress record"):
        _matrix(mesh, out=str(foreign))
    with pytest.raises(ValueError, match=r"expected out as a path ending in \.zarr or \.npy, got '.*D\.h5'"):
        _matrix(mesh, out=str(tmp_path / "D.h5"))
    with pytest.raises(ValueError, match=r"expected chunk as an integer >= 1, got 0"):
        wrd.distance_matrix(mesh, sources=SOURCES, chunk=0)
    with pytest.raises(ValueError, match=r"expected sources in \[0, 161\], got 162"):
        wrd.distance_matrix(mesh, sources=[1, 162])
    with pytest.raises(ValueError, match=r"expected client as a dask\.distributed\.Client or None, got str"):
        wrd.distance_matrix(mesh, sources=SOURCES, client="tcp://127.0.0.1:8786")
    with pytest.raises(ValueError, match=r"expected progress=None for a lazy dask array"):
        wrd.distance_matrix(mesh, sources=SOURCES, client=client, progress=print)


@pytest.fixture(scope="module")
def mesh_file(mesh, tmp_path_factory):
    path = tmp_path_factory.mktemp("mesh") / "sphere.off"
    path.write_text("OFF\n162 320 0\n" + "".join(f"{float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in mesh.vertices)
                    + "".join(f"3 {a} {b} {c}\n" for a, b, c in mesh.elements))
    return path


def test_cli_matrix_on_a_scheduler_and_resumed(mesh_file, rows, client, tmp_path, capsys):
    path = mesh_file
    landmarks = tmp_path / "landmarks.txt"
    landmarks.write_text(" ".join(map(str, SOURCES[:5])) + "\n" + ",".join(map(str, SOURCES[5:])) + "\n")
    out = str(tmp_path / "D.zarr")
    args = ["matrix", str(path), "--sources", str(landmarks), "--output", out, "--chunk", "3",
            "--scheduler", client.scheduler.address]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "[##############################] 4/4 blocks" in captured.err
    assert "10 single-source rows" in captured.out and "(0 already written)" in captured.out
    import zarr

    np.testing.assert_allclose(zarr.open_array(out, mode="r")[:], rows[1], rtol=0, atol=CLUSTER * rows[1].max())
    assert main(args[:-2]) == 0  # resumed here, without the cluster: nothing left to solve
    assert "(4 already written)" in capsys.readouterr().out


def test_cli_matrix_bad_input(tmp_path, capsys):
    mesh_file = os.path.join(os.path.dirname(wrd.__file__), "data", "spot_rr.off")
    bad = tmp_path / "bad.txt"
    bad.write_text("1 2 x3\n")
    for args, message in (
        (["--sources", str(tmp_path / "none.txt"), "--output", str(tmp_path / "D.npy")],
         r"expected --sources as 'all' or an existing file of vertex indices, got '.*none\.txt' \(no such file\)"),
        (["--sources", str(bad), "--output", str(tmp_path / "D.npy")],
         r"expected integer vertex indices in --sources '.*bad\.txt', got 'x3'"),
        (["--output", str(tmp_path / "D.csv")], r"expected --output ending in \.zarr or \.npy, got '.*D\.csv'"),
        (["--output", str(tmp_path / "D.npy"), "--workers", "0"],
         r"expected --workers between 1 and the \d+ cores here \(for more, a --scheduler of a cluster\), got 0"),
    ):
        assert main(["matrix", mesh_file, *args]) == 2
        err = capsys.readouterr().err
        assert err.startswith("warp-regdist: error: ") and len(err.strip().splitlines()) == 1
        assert re.search(message, err), err


def test_cli_matrix_reports_unconverged_blocks(mesh_file, tmp_path, capsys):
    assert main(["matrix", str(mesh_file), "--output", str(tmp_path / "D.npy"), "--chunk", "100", "--quiet",
                 "--max-iterations", "5"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert all(line.startswith("warp-regdist: warning: ADMM ") for line in err)
    unconverged = [line for line in err if "did not converge" in line]
    assert len(unconverged) == 2  # one line per block, of 100 and 62 rows
    for line, rows in zip(unconverged, (100, 62)):
        assert re.fullmatch(rf"warp-regdist: warning: ADMM did not converge in 5 iterations for \d+ of {rows} "
                            "source sets", line), line
