"""Faults at the edges, read as the contract of docs/guides/cli.md and docs/guides/long-runs.md: each
promise those pages make, and the test that holds it (``test_the_contract_names_tests_that_exist``
keeps this table true). Tests named without a module are in this one.

| promise | held by |
|---|---|
| exit 0/1/2/130/143; every refusal one ``warp-regdist: error:`` line, nothing written | test_every_refusal_of_every_subcommand_is_one_line_and_exit_2, test_huge_source_indices_are_one_line_errors |
| Ctrl-C and SIGTERM stop at an iteration boundary and keep the work (final checkpoint, iterate, blocks) | test_a_stop_signal_keeps_the_work_of_every_solving_subcommand, test_sigterm_from_outside_stops_allpairs_with_its_checkpoint, test_long_runs.py::test_interrupt_returns_the_iterate_and_checkpoints |
| a second Ctrl-C stops at once | test_a_second_ctrl_c_stops_at_once_with_exit_130 |
| outputs are written whole or not at all; a failed write leaves the old file | test_a_failed_write_leaves_the_old_file_and_no_temporary, test_allpairs_on_a_full_file_system_keeps_the_old_output |
| the room is checked before the work | test_a_write_larger_than_the_free_space_is_refused_unwritten, test_room_is_counted_per_file_system_for_all_outputs, test_distance_checks_the_room_before_the_solve_and_keeps_a_copy_when_the_disk_fills, test_matrix_checks_the_room_first_and_a_disk_that_fills_keeps_the_blocks, test_long_runs.py::test_checkpoint_without_room_is_refused_before_allocating |
| a disk that fills during a run says where the result is | test_a_final_write_that_fails_says_where_the_matrix_is, test_a_failed_final_write_says_what_an_older_checkpoint_holds, test_distance_checks_the_room_before_the_solve_and_keeps_a_copy_when_the_disk_fills |
| a checkpoint save that fails warns once and the run goes on | test_a_checkpoint_save_that_fails_warns_once_and_the_run_goes_on |
| damage is found before any work, and the advised recovery repairs | test_a_flipped_bit_in_a_checkpoint_is_refused_before_allocation, test_a_flipped_bit_in_a_matrix_block_is_refused_before_any_work, test_the_advised_recovery_of_a_damaged_finished_matrix_gives_the_undamaged_one |
| progress is never overwritten by mistake; one run per output | test_a_checkpoint_holding_progress_is_refused_without_resume_or_restart, test_resume_and_restart_of_one_file_is_refused, test_a_second_run_on_the_same_output_is_refused |
| a resumed run gives the uninterrupted result | test_long_runs.py::test_resumed_run_equals_uninterrupted, test_distance_matrix.py::test_disk_output_and_resume |
| stale temporaries and locks of dead runs are cleared | test_stale_temporaries_of_dead_writers_are_removed, test_releasing_a_lock_never_raises |
| a run at its cap says how to continue | test_allpairs_at_its_cap_without_a_checkpoint_says_how_a_rerun_could_continue, test_allpairs_flagged_steep_before_its_cap_is_not_sent_to_resume |
| workers die with their parent; a dead worker is one line | test_worker_processes.py::test_workers_exit_with_their_parent, test_a_dead_worker_is_one_line_and_exit_2 |
| files that are not what they claim are refused | test_a_truncated_ascii_ply_is_refused_and_unused_vertices_warn, test_a_zarr_store_with_foreign_codecs_is_refused_unread |
| progress lines, nothing on stdout from the library | test_allpairs_progress_is_one_line_per_window_with_every_stop_test, test_the_library_prints_nothing_on_stdout |
"""

import errno
import json
import os
import re
import signal
import subprocess
import sys
import types
import warnings

import numpy as np
import pytest
import trimesh

import meshes
from conftest import signal_after_iteration
import warp_regdist as wrd
import warp_regdist.atomic_write as atomic_write
import warp_regdist.cli.allpairs as cli_allpairs
import warp_regdist.solvers.all_pairs.solver as ap
import warp_regdist.solvers.all_pairs.run as all_pairs_run
from warp_regdist.atomic_write import check_room, remove_stale_temporaries, write_atomic
from warp_regdist.cli import main
from warp_regdist.file_lock import FileLock


@pytest.fixture(scope="module")
def sphere():
    V, F = meshes.icosphere(2, 1.0)
    return wrd.Mesh(meshes.perturbed(V, F, 0.05, seed=3), F)


@pytest.fixture(scope="module")
def sphere_file(sphere, tmp_path_factory):
    path = tmp_path_factory.mktemp("mesh") / "sphere.off"
    trimesh.Trimesh(sphere.vertices, sphere.elements, process=False).export(path)
    return path


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    err = "".join(line for line in err.splitlines(keepends=True) if not line.startswith("warp-regdist: compiling"))
    return code, out, err


def _full_disk_writer(written=1000):
    """A writer that puts ``written`` bytes into its file, then fails as a full disk does."""
    def write(tmp):
        with open(tmp, "wb") as f:
            f.write(b"x" * written)
        raise OSError(errno.ENOSPC, "No space left on device")
    return write


# ------------------------------------------------------------------ atomic writes

def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "U.npy"
    np.save(path, np.arange(3.0))
    with pytest.raises(wrd.WriteError, match=r"could not write --output '.*U\.npy': No space left on device "
                                            r"\(1 kB were written, .* free\); the existing file there is unchanged"
                       ) as caught:
        write_atomic(path, _full_disk_writer(), "--output")
    assert caught.value.errno == errno.ENOSPC
    assert np.array_equal(np.load(path), np.arange(3.0))
    assert sorted(os.listdir(tmp_path)) == ["U.npy"]


def test_a_write_larger_than_the_free_space_is_refused_unwritten(tmp_path, monkeypatch):
    path = tmp_path / "U.npy"
    monkeypatch.setattr(atomic_write.shutil, "disk_usage", lambda folder: types.SimpleNamespace(free=2_000_000))
    with pytest.raises(wrd.WriteError, match=r"could not write --output '.*U\.npy': it needs 3\.3 MB and its file "
                                            r"system has 2 MB free$"):
        write_atomic(path, lambda tmp: pytest.fail("written"), "--output", size=3_300_000)
    assert not path.exists()


def test_room_is_counted_per_file_system_for_all_outputs(tmp_path, monkeypatch):
    monkeypatch.setattr(atomic_write.shutil, "disk_usage", lambda folder: types.SimpleNamespace(free=5_000_000))
    check_room([(tmp_path / "a", 2_000_000, "a"), (tmp_path / "b", 3_000_000, "b")])
    with pytest.raises(ValueError, match=r"expected 5\.5 MB free for a '.*a' \(2 MB\) and b '.*b' \(3\.5 MB\), got "
                                         r"5 MB free on the file system of '.*'"):
        check_room([(tmp_path / "a", 2_000_000, "a"), (tmp_path / "b", 3_500_000, "b")])


def test_stale_temporaries_of_dead_writers_are_removed(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    stale = tmp_path / f"run.npz.tmp{pid}.npz"
    live = tmp_path / f"run.npz.tmp{os.getppid()}.npz"   # a running process's: kept
    other = tmp_path / f"other.npz.tmp{pid}"
    for p in (stale, live, other):
        p.write_bytes(b"partial")
    assert remove_stale_temporaries(tmp_path / "run.npz") == [stale.name]
    assert not stale.exists() and live.exists() and other.exists()


def test_releasing_a_lock_never_raises(tmp_path, monkeypatch):
    lock = FileLock(tmp_path / "run.npz").acquire()

    def refuse(path):
        raise PermissionError(errno.EPERM, "Operation not permitted", path)

    monkeypatch.setattr(os, "remove", refuse)
    lock.release()                        # the lock file stays; it holds no lock
    monkeypatch.undo()
    FileLock(tmp_path / "run.npz").acquire().release()


@pytest.mark.skipif(not sys.platform.startswith("linux") or os.geteuid() != 0, reason="mounts a tmpfs (root, Linux)")
def test_allpairs_on_a_full_file_system_keeps_the_old_output(sphere_file, tmp_path, capsys):
    small = tmp_path / "small"
    small.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=100k", "tmpfs", str(small)], capture_output=True).returncode:
        pytest.skip("tmpfs cannot be mounted here")
    try:
        (small / "U.npy").write_bytes(b"the good old matrix")
        code, out, err = _cli(capsys, "allpairs", sphere_file, "--output", small / "U.npy", "--max-iterations", "5",
                              "--device", "cpu")
        assert code == 2 and out == ""
        assert err.startswith("warp-regdist: error: expected 210 kB free for --output '") and "got " in err
        assert (small / "U.npy").read_bytes() == b"the good old matrix"
        assert sorted(os.listdir(small)) == ["U.npy"]
    finally:
        subprocess.run(["umount", str(small)], check=True)


def test_a_final_write_that_fails_says_where_the_matrix_is(sphere_file, tmp_path, capsys, monkeypatch):
    out, ckpt = tmp_path / "U.npy", tmp_path / "run.npz"
    out.write_bytes(b"the good old matrix")
    save = np.save

    def full_disk_for_the_output(file, array, *args, **kwargs):
        if str(file).startswith(str(out)):
            raise OSError(errno.ENOSPC, "No space left on device")
        return save(file, array, *args, **kwargs)

    monkeypatch.setattr(cli_allpairs.np, "save", full_disk_for_the_output)
    code, _, err = _cli(capsys, "allpairs", sphere_file, "--output", out, "--checkpoint", ckpt, "--max-iterations",
                        "5", "--device", "cpu", "--quiet")
    assert code == 2
    assert (f"; the existing file there is unchanged; the matrix is in the checkpoint '{ckpt}': run the same command "
            f"with --resume {ckpt} and an --output where there is room") in err
    assert out.read_bytes() == b"the good old matrix"
    code, _, err = _cli(capsys, "allpairs", sphere_file, "--output", out, "--max-iterations", "5", "--device", "cpu",
                        "--quiet")
    rescue = err.split("the matrix was written to '")[1].split("'")[0]
    assert code == 2 and os.path.isfile(rescue)
    monkeypatch.undo()
    U = np.load(rescue)
    os.remove(rescue)
    assert U.shape == (162, 162) and np.array_equal(U, U.T)


def test_a_checkpoint_save_that_fails_warns_once_and_the_run_goes_on(sphere, tmp_path, monkeypatch):
    whole = _quiet_all_pairs(sphere, max_iterations=12)
    calls = []
    savez = np.savez

    def third_and_later_fail(file, **arrays):
        calls.append(1)
        if len(calls) >= 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        return savez(file, **arrays)

    monkeypatch.setattr(all_pairs_run.np, "savez", third_and_later_fail)
    with pytest.warns(wrd.CheckpointWarning) as caught:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", wrd.ConvergenceWarning)
            res = wrd.all_pairs(sphere, 0.03, device="cpu", max_iterations=12, checkpoint=tmp_path / "run.npz",
                                checkpoint_seconds=1e-9)
    messages = [str(w.message) for w in caught if issubclass(w.category, wrd.CheckpointWarning)]
    assert len(messages) == 1 and "the checkpoint of iteration 2 stays valid" in messages[0], messages
    assert len(calls) > 3 and res.checkpoint_iteration == 2
    assert np.array_equal(res.distance, whole.distance)
    assert sorted(os.listdir(tmp_path)) == ["run.npz"]


# ------------------------------------------------------------------ damaged files

def _quiet_all_pairs(mesh, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        return wrd.all_pairs(mesh, 0.03, device="cpu", **kwargs)


def test_a_flipped_bit_in_a_checkpoint_is_refused_before_allocation(sphere, tmp_path, monkeypatch):
    path = tmp_path / "run.npz"
    _quiet_all_pairs(sphere, max_iterations=4, checkpoint=path)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x10
    path.write_bytes(bytes(data))
    monkeypatch.setattr(ap, "SymmetricADMM", lambda *a, **k: pytest.fail("allocated before the check"))
    with pytest.raises(ValueError, match=r"expected resume as an intact all-pairs checkpoint, got '.*run\.npz' whose "
                                         r"array '\w+' cannot be read back as written \(BadZipFile: Bad CRC-32"):
        wrd.all_pairs(sphere, 0.03, device="cpu", max_iterations=8, resume=path)


def test_a_flipped_bit_in_a_matrix_block_is_refused_before_any_work(sphere, tmp_path, monkeypatch):
    out = tmp_path / "D.npy"

    def stop(done, total, seconds):
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        wrd.distance_matrix(sphere, sources=[0, 5, 9, 30, 40, 50], chunk=2, out=str(out), progress=stop)
    data = bytearray(out.read_bytes())
    data[128 + 8 * (2 * 162 + 7)] ^= 0x01        # row 2 (block 1), vertex 7
    out.write_bytes(bytes(data))
    import warp_regdist.matrices.source_rows as source_rows
    monkeypatch.setattr(source_rows, "DistanceSolver", lambda *a, **k: pytest.fail("solved before the check"))
    with pytest.raises(ValueError, match=r"expected block 1 \(rows 2\.\.3\) of '.*D\.npy' to hold the values written "
                                         r"there \(CRC-32 \d+\), got CRC-32 \d+: the file changed on the disk; remove "
                                         r"'.*rows-0000001' to solve that block again"):
        wrd.distance_matrix(sphere, sources=[0, 5, 9, 30, 40, 50], chunk=2, out=str(out))
    os.remove(tmp_path / "D.npy.progress" / "rows-0000001")
    monkeypatch.undo()
    D = wrd.distance_matrix(sphere, sources=[0, 5, 9, 30, 40, 50], chunk=2, out=str(out))
    whole = wrd.distance_matrix(sphere, sources=[0, 5, 9, 30, 40, 50], chunk=2)
    assert np.array_equal(np.asarray(D), whole)


@pytest.mark.parametrize("meta, got", [
    ({"zarr_format": 3, "node_type": "array", "data_type": "float64", "codecs": [{"name": "bytes"}, {"name": "pickle"}]},
     r"got format 3, node 'array', data type 'float64', codecs \['bytes', 'pickle'\]; it was not read"),
    ({"zarr_format": 3, "node_type": "array", "data_type": "object", "codecs": [{"name": "vlen-bytes"}]},
     r"got format 3, node 'array', data type 'object', codecs \['vlen-bytes'\]; it was not read"),
    (None, r"got no readable '.*D\.zarr/zarr\.json'"),
])
def test_a_zarr_store_with_foreign_codecs_is_refused_unread(sphere, tmp_path, monkeypatch, meta, got):
    zarr = pytest.importorskip("zarr")
    out = tmp_path / "D.zarr"

    def stop(done, total, seconds):
        if done == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        wrd.distance_matrix(sphere, sources=[0, 5, 9, 30], chunk=2, out=str(out), progress=stop)
    if meta is None:   # a zarr 2 store: .zarray (it may carry a pickle filter) instead of zarr.json
        os.remove(out / "zarr.json")
        (out / ".zarray").write_text(json.dumps({"zarr_format": 2, "filters": [{"id": "pickle"}]}))
    else:
        (out / "zarr.json").write_text(json.dumps(meta))
    monkeypatch.setattr(zarr, "open_array", lambda *a, **k: pytest.fail("zarr opened the store"))
    with pytest.raises(ValueError, match=r"expected '.*D\.zarr' as a Zarr v3 .*" + got):
        wrd.distance_matrix(sphere, sources=[0, 5, 9, 30], chunk=2, out=str(out))


# ------------------------------------------------------------------ progress a rerun would lose

def test_a_checkpoint_holding_progress_is_refused_without_resume_or_restart(sphere, sphere_file, tmp_path, capsys):
    ckpt, out = tmp_path / "run.npz", tmp_path / "U.npy"
    args = ["allpairs", sphere_file, "--output", out, "--checkpoint", ckpt, "--max-iterations", "6", "--device", "cpu",
            "--quiet"]
    assert _cli(capsys, *args)[0] == 1                   # written, not converged
    before = ckpt.read_bytes()
    code, _, err = _cli(capsys, *args)
    assert code == 2 and err == (f"warp-regdist: error: expected --checkpoint as a new file or the one resumed, got "
                                 f"'{ckpt}' holding a checkpoint at iteration 6: --resume '{ckpt}' continues it, "
                                 "--restart discards it\n")
    assert ckpt.read_bytes() == before
    with pytest.raises(ValueError, match=r"expected checkpoint as a new file or the one resumed, got '.*run\.npz' "
                                         r"holding a checkpoint at iteration 6: resume='.*run\.npz' continues it, "
                                         r"restart=True discards it"):
        wrd.all_pairs(sphere, 0.03, device="cpu", checkpoint=ckpt)
    assert _cli(capsys, *args, "--resume", ckpt, "--max-iterations", "8")[0] == 1
    assert _cli(capsys, *args, "--restart")[0] == 1
    assert _cli(capsys, *args, "--restart")[0] == 1


# ------------------------------------------------------------------ numbers

@pytest.mark.parametrize("sources", ["99999999999999999999999", "3,-99999999999999999999999"])
def test_huge_source_indices_are_one_line_errors(sphere_file, tmp_path, capsys, sources):
    code, out, err = _cli(capsys, "distance", sphere_file, "--sources", sources, "--output", tmp_path / "u.npy")
    bad = sources.split(",")[-1]
    assert code == 2 and out == ""
    assert err == f"warp-regdist: error: expected --sources in [0, 161] (the mesh has 162 vertices), got {bad}\n"
    landmarks = tmp_path / "landmarks.txt"
    landmarks.write_text(sources.replace(",", "\n"))
    code, out, err = _cli(capsys, "matrix", sphere_file, "--sources", landmarks, "--output", tmp_path / "D.npy")
    assert code == 2 and err == (f"warp-regdist: error: expected vertex indices in [0, 161] in --sources "
                                 f"'{landmarks}' (the mesh has 162 vertices), got {bad}\n")


def test_a_run_past_ten_thousand_iterations_ends_unconverged_with_a_warning():
    schedule = wrd.PenaltySchedule(0.5, 4.0, 10.0, 1.0)
    assert schedule.rho(10**9) == 4.0 and schedule.rho(10_240) == 4.0
    V, F = meshes.icosphere(1, 1.0)
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), 0.05, device="cpu")
    with pytest.warns(wrd.ConvergenceWarning, match="did not converge in 12000 iterations"):
        res = solver.solve([0], max_iterations=12_000, eps_rel=1e-30, eps_change=0.0)
    assert res.iterations == 12_000 and not res.converged and np.isfinite(res.distance).all()


# ------------------------------------------------------------------ signals, workers, exit status

def test_a_second_ctrl_c_stops_at_once_with_exit_130(sphere_file, tmp_path, capsys, monkeypatch):
    def second_ctrl_c(progress):
        raise KeyboardInterrupt   # what a second Ctrl-C raises

    monkeypatch.setattr(cli_allpairs, "_allpairs_progress", lambda banner, forecast: second_ctrl_c)
    code, out, err = _cli(capsys, "allpairs", sphere_file, "--output", tmp_path / "V.npy", "--device", "cpu")
    assert (code, out, err.splitlines()) == (130, "", ["warp-regdist: interrupted"])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="worker processes need Linux")
def test_a_dead_worker_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    V, F = meshes.icosphere(3, 1.0)
    path = tmp_path / "ico3.off"
    trimesh.Trimesh(V, F, process=False).export(path)
    from test_worker_processes import _worker_pids
    others = _worker_pids(os.getpid())

    def kill_the_worker(progress):
        if progress.iteration == 2:
            for worker in _worker_pids(os.getpid()) - others:
                os.kill(worker, signal.SIGKILL)
                os.waitid(os.P_PID, worker, os.WEXITED | os.WNOWAIT)

    monkeypatch.setattr(cli_allpairs, "_allpairs_progress", lambda banner, forecast: kill_the_worker)
    code, out, err = _cli(capsys, "allpairs", path, "--output", tmp_path / "U.npy", "--workers", "2", "--device", "cpu",
                          "--dtype", "float32", "--engine", "consensus")
    assert code == 2 and out == ""
    (error,) = err.splitlines()                  # the banner line comes from the progress callback, replaced here
    assert error.startswith("warp-regdist: error: worker process 1 (pid ") and "was killed by SIGKILL" in error


def test_duplicate_vertices_warn_and_merge(sphere):
    V = np.vstack([sphere.vertices, sphere.vertices[[0]]])
    F = sphere.elements.copy()
    fan = np.flatnonzero((F == 0).any(axis=1))[:2]
    F[fan] = np.where(F[fan] == 0, len(V) - 1, F[fan])     # two faces of vertex 0 use its copy
    with pytest.warns(wrd.MeshWarning, match=r"^1 vertex lies where another vertex of the mesh lies \(first: 0 and "
                                             r"162\): the mesh is cut there and no distance crosses the cut; merge them "
                                             r"with warp_regdist.merge_duplicate_vertices\(mesh\)"):
        cut = wrd.Mesh(V, F)
    merged, index = wrd.merge_duplicate_vertices(cut)
    assert merged.n_vertices == 162 and index[162] == 0 and np.array_equal(index[:162], np.arange(162))
    assert np.array_equal(merged.elements, sphere.elements)
    u = wrd.DistanceSolver(merged, 0.05, device="cpu").solve([0]).distance[index]
    assert u[162] == 0.0 and u[0] == 0.0


# ------------------------------------------------------------------ a quiet command line and library

def test_the_library_prints_nothing_on_stdout(tmp_path):
    script = ("import warp_regdist as wrd, trimesh\n"
              "s = trimesh.creation.icosphere(1)\n"
              "wrd.DistanceSolver(wrd.Mesh(s.vertices, s.faces), 0.1, device='cpu').solve([0])\n")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout == ""


def test_allpairs_at_its_cap_without_a_checkpoint_says_how_a_rerun_could_continue(sphere_file, tmp_path, capsys):
    code, out, err = _cli(capsys, "allpairs", sphere_file, "--output", tmp_path / "U.npy", "--max-iterations", "3",
                          "--device", "cpu")
    assert code == 1 and err.splitlines()[-1] == ("warp-regdist: warning: the all-pairs ADMM did not converge in 3 "
                                                  "iterations; the matrix written is approximate; with --checkpoint FILE "
                                                  "a rerun could be continued by --resume FILE")
    assert "NOT converged" in out and "error not yet estimated and gradient excess" in out


def test_allpairs_flagged_steep_before_its_cap_is_not_sent_to_resume():
    from argparse import Namespace

    from warp_regdist.cli.allpairs import _unconverged

    steep = wrd.AllPairsResult(iterations=450, converged=False, interrupted=False, gradient_excess=0.012,
                               checkpoint_iteration=450)
    assert _unconverged(steep, Namespace(max_iterations=3000, checkpoint="run.npz")) == (
        "the all-pairs ADMM stopped at iteration 450 with |grad U| above unit speed (gradient excess 1.20%): the matrix "
        "written is approximate; a smaller --accuracy iterates longer")


def test_allpairs_progress_is_one_line_per_window_with_every_stop_test(sphere_file, tmp_path, capsys):
    code, _, err = _cli(capsys, "allpairs", sphere_file, "--output", tmp_path / "U.npy", "--max-iterations", "160",
                        "--device", "cpu")
    assert re.fullmatch(r"sphere\.off: 162 vertices, eigenbasis engine, about 0\.\d\d GB; typically 1550 iterations at "
                        r"this size and accuracy 0\.005 \(cap 160\); the eigenbasis engine's setup, then a progress line "
                        r"every 50 iterations", err.splitlines()[0])
    lines = [line for line in err.splitlines() if line.startswith("  iteration")]
    assert [line.split(":")[0] for line in lines] == ["  iteration 6", "  iteration 50", "  iteration 100",
                                                      "  iteration 150"]
    assert all("max residual/tolerance " in line and "change to come " in line and "gradient excess " in line
               for line in lines[1:])
    assert "change to come inf/0.0035 (holding it back)" in lines[1]
    assert all(re.search(r"[:;] [0-9.e-]+ s/iteration; about \d+ s to the typical 1550, at most \d+ s to the cap 160$",
                         line) for line in lines)


@pytest.mark.parametrize("suffix, removed", [(".npy", ["rows"]), (".zarr", ["rows"]), (".npy", ["rows", "symmetric"])])
def test_the_advised_recovery_of_a_damaged_finished_matrix_gives_the_undamaged_one(sphere_file, tmp_path, capsys,
                                                                                     suffix, removed):
    out = tmp_path / f"D{suffix}"
    command = ["matrix", str(sphere_file), "--sources", "all", "--output", str(out), "--chunk", "16", "--quiet"]
    assert main(command) == 0
    capsys.readouterr()
    if suffix == ".npy":
        whole = np.load(out)
        data = bytearray(out.read_bytes())
        data[128 + 8 * (130 * 162 + 7) + 3] ^= 0x10       # row 130 (block 8), vertex 7
        out.write_bytes(bytes(data))
    else:
        import zarr

        array = zarr.open_array(store=str(out), mode="r+")
        whole = array[:]
        array[130, 7] = whole[130, 7] * 1.01               # a block changed by hand
    assert main(command) == 2
    err = capsys.readouterr().err.strip()
    marker = str(out) + ".progress/rows-0000008"
    assert len(err.splitlines()) == 1 and err.endswith(f"remove {marker!r} to solve that block again")
    for kind in removed:
        os.remove(str(out) + f".progress/{kind}-0000008")
    assert main(command) == 0
    D = np.load(out) if suffix == ".npy" else zarr.open_array(store=str(out), mode="r")[:]
    assert np.array_equal(D, D.T)
    np.testing.assert_allclose(D, whole, rtol=0, atol=1e-12 * whole.max())


@pytest.mark.parametrize("sig, status, word", [(signal.SIGINT, 130, "interrupted"),
                                               (signal.SIGTERM, 143, "terminated (SIGTERM)")])
def test_a_stop_signal_keeps_the_work_of_every_solving_subcommand(sphere_file, tmp_path, capsys, monkeypatch, sig,
                                                                   status, word):
    import warp_regdist.cli.matrix as cli_matrix

    def signal_at_three(banner, forecast):
        def show(progress):
            if progress.iteration == 3:
                os.kill(os.getpid(), sig)
        return show

    monkeypatch.setattr(cli_allpairs, "_allpairs_progress", signal_at_three)
    code, out, err = _cli(capsys, "allpairs", sphere_file, "--output", tmp_path / "U.npy", "--checkpoint",
                          tmp_path / "run.npz", "--device", "cpu")
    assert code == status and f"{word} at ADMM iteration 4: the matrix written is the current iterate" in err
    with np.load(tmp_path / "run.npz") as saved:                       # the final checkpoint: nothing lost
        assert int(saved["iteration"]) == 4
    signal_after_iteration(monkeypatch, 5, sig)
    code, out, err = _cli(capsys, "distance", sphere_file, "--sources", "0", "--output", tmp_path / "u.npy")
    assert code == status and f"warp-regdist: warning: {word} at ADMM iteration" in err
    assert np.load(tmp_path / "u.npy").shape == (162,)
    monkeypatch.undo()
    show, state = cli_matrix._matrix_progress(True)

    def signal_after_one_block(done, total, seconds):
        show(done, total, seconds)
        if done == 1 and seconds > 0:
            os.kill(os.getpid(), sig)

    monkeypatch.setattr(cli_matrix, "_matrix_progress", lambda quiet: (signal_after_one_block, state))
    out_path = tmp_path / "D.npy"
    code, out, err = _cli(capsys, "matrix", sphere_file, "--sources", "all", "--chunk", "64", "--output", out_path)
    assert (code, err.strip()) == (status, f"warp-regdist: {word}; the blocks written so far stay in {out_path}: run "
                                           "the same command again to resume")
    assert sorted(os.listdir(f"{out_path}.progress"))[:2] == ["fingerprint.json", "rows-0000000"]


def test_sigterm_from_outside_stops_allpairs_with_its_checkpoint(sphere_file, tmp_path):
    # what a batch scheduler does: SIGTERM to the process once it is iterating, then wait
    checkpoint = tmp_path / "run.npz"
    command = [sys.executable, "-c", "import sys; from warp_regdist.cli import main; sys.exit(main(sys.argv[1:]))",
               "allpairs", str(sphere_file), "--output", str(tmp_path / "U.npy"), "--checkpoint", str(checkpoint),
               "--accuracy", "0.0005", "--max-iterations", "100000", "--device", "cpu"]
    proc = subprocess.Popen(command, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    for line in proc.stderr:                                     # the first line after a few iterations
        if line.startswith("  iteration "):
            break
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 143
    assert re.search(r"warp-regdist: warning: terminated \(SIGTERM\) at ADMM iteration \d+: the matrix written is the "
                     r"current iterate; the solver state of iteration \d+ is in .*run\.npz", err)
    with np.load(checkpoint) as saved:
        assert int(saved["iteration"]) >= 1


def test_resume_and_restart_of_one_file_is_refused(sphere_file, tmp_path, capsys):
    run = tmp_path / "run.npz"
    code, out, err = _cli(capsys, "allpairs", sphere_file, "--output", tmp_path / "U.npy", "--resume", run,
                          "--restart")
    assert (code, err.strip()) == (2, f"warp-regdist: error: expected --restart (start over) or --resume {run} "
                                      "(continue it), got both; --restart with --resume only lets a resumed run "
                                      "overwrite another --checkpoint")


def test_a_second_run_on_the_same_output_is_refused(sphere_file, tmp_path, capsys):
    out = tmp_path / "u.npy"
    with FileLock(out, "--output"):                                  # another run writing it
        code, _, err = _cli(capsys, "distance", sphere_file, "--sources", "0", "--output", out)
    path = re.escape(str(out))
    assert code == 2 and re.fullmatch(rf"warp-regdist: error: expected no other run writing --output '{path}', got "
                                      rf"one holding its lock '{path}\.lock' \(pid \d+\)\n", err)
    assert not out.exists()
    code, _, err = _cli(capsys, "distance", sphere_file, "--sources", "0", "--output", out, "--quiet")
    assert code == 0 and out.exists() and not os.path.exists(f"{out}.lock")


def test_a_truncated_ascii_ply_is_refused_and_unused_vertices_warn(sphere, tmp_path, capsys):
    whole = tmp_path / "whole.ply"
    trimesh.Trimesh(sphere.vertices, sphere.elements, process=False).export(whole, encoding="ascii")
    lines = whole.read_text().splitlines()
    body = lines.index("end_header") + 1
    for kept, name in ((162 + 100, "faces.ply"), (10, "vertices.ply")):
        path = tmp_path / name
        path.write_text("\n".join(lines[:body + kept]) + "\n")
        expected = (f"expected 162 vertex lines and 320 face lines after the header of '{path}', as it declares, got "
                    f"{kept} lines: the file is truncated")
        with pytest.raises(wrd.MeshError, match=f"^{re.escape(expected)}$"):
            wrd.load_mesh(path)
        code, _, err = _cli(capsys, "distance", path, "--sources", "0", "--output", tmp_path / "u.npy")
        assert (code, err) == (2, f"warp-regdist: error: {expected}\n")
    obj = tmp_path / "spare.obj"
    with open(obj, "w") as f:
        f.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in sphere.vertices.tolist() + [[9.0, 9.0, 9.0]] * 2)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in sphere.elements)
    with pytest.warns(wrd.MeshWarning, match=rf"^{re.escape(str(obj))}: 2 of 164 vertices are in no element \(first: "
                                             r"vertex 162\): their distance is \+inf$"):
        assert wrd.load_mesh(obj).n_vertices == 164


def test_distance_checks_the_room_before_the_solve_and_keeps_a_copy_when_the_disk_fills(sphere_file, tmp_path,
                                                                                        capsys, monkeypatch):
    import warp_regdist.cli.distance as cli_distance

    out = tmp_path / "u.npy"
    monkeypatch.setattr(atomic_write.shutil, "disk_usage", lambda folder: types.SimpleNamespace(free=1000))
    monkeypatch.setattr(cli_distance, "solve", lambda *a, **k: pytest.fail("solved before the room check"))
    code, _, err = _cli(capsys, "distance", sphere_file, "--sources", "0", "--output", out)
    assert (code, err) == (2, f"warp-regdist: error: expected 1.42 kB free for --output '{out}' (1.42 kB), got "
                              f"1 kB free on the file system of '{tmp_path}'\n")
    monkeypatch.undo()
    save = np.save

    def full_disk_for_the_output(file, array, *args, **kwargs):    # the disk fills during the solve
        if str(file).startswith(str(out)):
            raise OSError(errno.ENOSPC, "No space left on device")
        return save(file, array, *args, **kwargs)

    monkeypatch.setattr(np, "save", full_disk_for_the_output)
    code, _, err = _cli(capsys, "distance", sphere_file, "--sources", "0", "--output", out, "--quiet")
    assert code == 2 and not out.exists()
    rescue = err.split("the distance was written to '")[1].split("'")[0]
    monkeypatch.undo()
    u = np.load(rescue)
    os.remove(rescue)
    assert u.shape == (162,) and u[0] == 0.0 and u.max() > 1.0


def test_matrix_checks_the_room_first_and_a_disk_that_fills_keeps_the_blocks(sphere, tmp_path, monkeypatch):
    import warp_regdist.matrices.matrix_store as matrix_store

    out = tmp_path / "D.npy"
    sources = [0, 5, 9, 30, 40, 50]
    monkeypatch.setattr(atomic_write.shutil, "disk_usage", lambda folder: types.SimpleNamespace(free=1000))
    with pytest.raises(ValueError, match=r"^expected 8\.06 kB free for out '.*D\.npy' \(8\.06 kB\), got 1 kB free "
                                         r"on the file system of '.*'$"):    # 6 rows of 162, their strips of S
        wrd.distance_matrix(sphere, sources=sources, chunk=2, out=str(out))
    assert os.listdir(tmp_path) == []                                  # nothing created
    monkeypatch.undo()
    write = matrix_store.NpyFile.write

    def full_at_block_two(self, start, values):
        if self.path == str(out) and start >= 2 * 2 * 162:
            raise OSError(errno.ENOSPC, "No space left on device")
        return write(self, start, values)

    monkeypatch.setattr(matrix_store.NpyFile, "write", full_at_block_two)
    with pytest.raises(wrd.WriteError, match=r"^could not write block 2 of '.*D\.npy' \(2\.59 kB\): No space left on "
                                             r"device \(.* free\); the blocks written so far stay: make room and run "
                                             r"the same call again to go on$"):
        wrd.distance_matrix(sphere, sources=sources, chunk=2, out=str(out))
    monkeypatch.undo()
    D = wrd.distance_matrix(sphere, sources=sources, chunk=2, out=str(out))     # the same call, with room
    assert np.array_equal(np.asarray(D), wrd.distance_matrix(sphere, sources=sources, chunk=2))


def test_a_failed_final_write_says_what_an_older_checkpoint_holds(sphere_file, tmp_path, capsys, monkeypatch):
    out, ckpt = tmp_path / "U.npy", tmp_path / "run.npz"
    result = wrd.AllPairsResult(iterations=400, checkpoint_iteration=61)
    save = np.save

    def full_disk_for_the_output(file, array, *args, **kwargs):
        if str(file).startswith(str(out)):
            raise OSError(errno.ENOSPC, "No space left on device")
        return save(file, array, *args, **kwargs)

    monkeypatch.setattr(np, "save", full_disk_for_the_output)
    with pytest.raises(wrd.WriteError, match=rf"the matrix was written to '.*U\.npy' instead; the checkpoint "
                                             rf"'{re.escape(str(ckpt))}' holds iteration 61 of 400$") as caught:
        cli_allpairs.write_matrix(str(out), np.eye(3), str(ckpt), result)
    monkeypatch.undo()
    rescue = str(caught.value).split("the matrix was written to '")[1].split("'")[0]
    assert np.array_equal(np.load(rescue), np.eye(3))
    os.remove(rescue)


def _refusals(mesh, tmp):
    """(subcommand argv, a fragment of its one error line) for refusals of every subcommand."""
    missing = str(tmp / "no-such.off")
    out = str(tmp / "x.npy")
    bad_dir = str(tmp / "no-such-dir" / "x.npy")
    common = [(["--dtype", "float16"], "invalid choice: 'float16'"), (["--device", "cuda:7"], "expected a Warp device"),
              (["--bogus"], "unrecognized arguments: --bogus")]
    cases = []
    for argv, what in common:
        cases += [(["distance", mesh, "--sources", "0", "--output", out, *argv], what),
                  (["allpairs", mesh, "--output", out, *argv], what),
                  (["matrix", mesh, "--sources", "all", "--output", out, *argv], what),
                  (["volume", mesh, "--sources", "boundary", "--output", str(tmp / "x.vtu"), *argv], what)]
    cases += [
        (["distance", missing, "--sources", "0", "--output", out], "expected an existing mesh file"),
        (["distance", mesh, "--sources", "99999999999999999999", "--output", out], "expected --sources"),
        (["distance", mesh, "--sources", "0", "--output", str(tmp / "x.txt")], "expected --output ending in"),
        (["distance", mesh, "--sources", "0", "--output", bad_dir], "expected --output in an existing directory"),
        (["distance", mesh, "--sources", "0", "--output", out, "--max-iterations", "-3"], "max_iterations"),
        (["distance", mesh, "--output", out], "expected --sources or --curve"),
        (["allpairs", mesh, "--output", out, "--accuracy", "5"], "expected accuracy"),
        (["allpairs", mesh, "--output", out, "--resume", str(tmp / "no.npz")], "expected --resume as an existing"),
        (["allpairs", mesh, "--output", out, "--checkpoint-seconds", "1e400"], "checkpoint_seconds"),
        (["matrix", mesh, "--sources", "all", "--output", out, "--chunk", "0"], "chunk"),
        (["matrix", mesh, "--sources", "all", "--output", out, "--workers", "100000000000000000000"], "--workers"),
        (["matrix", mesh, "--sources", "0,1", "--output", out], "expected --sources as 'all' or an existing file"),
        (["volume", missing, "--sources", "boundary", "--output", str(tmp / "x.vtu")], "expected"),
        (["view", mesh, str(tmp / "no.npy")], "expected"),
        (["demo", "--dtype", "float16"], "invalid choice"),
        (["distance"], "the following arguments are required"),
        ([], "the following arguments are required: COMMAND"),
    ]
    return cases


def test_every_refusal_of_every_subcommand_is_one_line_and_exit_2(sphere_file, tmp_path, capsys):
    for argv, what in _refusals(str(sphere_file), tmp_path):
        code, out, err = _cli(capsys, *argv)
        assert code == 2 and out == "", argv
        assert len(err.splitlines()) == 1 and err.startswith("warp-regdist") and ": error: " in err, (argv, err)
        assert what in err, (argv, err)
    assert sorted(os.listdir(tmp_path)) == []                              # and nothing written


def test_the_contract_names_tests_that_exist():
    import ast

    here = os.path.dirname(os.path.abspath(__file__))
    table = [line for line in __doc__.splitlines() if line.startswith("| ") and not line.startswith("| promise")]
    named = [name.strip() for line in table for name in line.split("|")[2].split(",")]
    assert len(table) >= 15 and all(named)
    for name in named:
        module, _, test = name.rpartition("::")
        with open(os.path.join(here, module or os.path.basename(__file__))) as f:
            defined = {node.name for node in ast.walk(ast.parse(f.read())) if isinstance(node, ast.FunctionDef)}
        assert test in defined, name


def test_single_source_progress_reports_the_last_windows_change(sphere):
    seen = []
    wrd.DistanceSolver(sphere, 0.05).solve([0], callback=seen.append)
    running = [p for p in seen if p.columns_done < p.columns]           # the last report has no column left
    change = [next(t.value for t in p.tests if t.name == "max change") for p in running]
    window = next(p.iteration for p in seen if p.checked and p.iteration > 0)
    assert all(c == 0.0 for c in change[:window]) and all(c > 0.0 for c in change[window:])   # kept between tests
    assert change[-1] <= 8e-4 < change[window]                          # and shrinking to the change test's bound
