"""Long runs: worker processes instead of threads, checkpoints, resume, Ctrl-C (issue 11)."""

import os
import signal
import subprocess
import sys
import threading
import types
import warnings

import numpy as np
import pytest
import warp._src.context as warp_context

import meshes
from conftest import signal_after_iteration
import warp_regdist as wrd
import warp_regdist.solvers.all_pairs.solver as ap
import warp_regdist.atomic_write as atomic_write
import warp_regdist.solvers.all_pairs.checkpoint as all_pairs_checkpoint


@pytest.fixture(scope="module")
def sphere642():
    V, F = meshes.icosphere(3, 1.0)
    return wrd.Mesh(meshes.perturbed(V, F, 0.05, seed=2), F)


def _quiet_all_pairs(*args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        return wrd.all_pairs(*args, **kwargs)


def test_only_the_calling_thread_launches_kernels(sphere642, monkeypatch):
    """Warp does not support CPU launches from several threads of a process (the threaded
    all_pairs crashed under load): with several workers, every launch in this process must
    come from the calling thread, the others run in worker processes."""
    threads = set()
    invoke = warp_context.invoke

    def recording_invoke(*args, **kwargs):
        threads.add(threading.get_ident())
        return invoke(*args, **kwargs)

    monkeypatch.setattr(warp_context, "invoke", recording_invoke)
    _quiet_all_pairs(sphere642, 0.03, dtype="float32", max_iterations=3, workers=2, device="cpu", engine="consensus")
    solver = wrd.DistanceSolver(sphere642, 0.05, dtype="float32", device="cpu", workers=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        solver.solve_many([[i] for i in range(32)], max_iterations=3)  # two lane blocks: one per process
    solver.close()
    assert threads == {threading.get_ident()}


STRESSED = """
import sys, warnings
sys.path.insert(0, {tests!r})
import meshes, warp_regdist as wrd
V, F = meshes.icosphere(3, 1.0)
warnings.simplefilter("ignore")
res = wrd.all_pairs(wrd.Mesh(V, F), 0.03, dtype="float32", max_iterations=4, workers=2, device="cpu",
                    engine="consensus")
print("OK", res.iterations)
"""


def _busy():
    while True:
        pass


def test_all_pairs_with_workers_under_cpu_load():
    """One all_pairs run with two workers while a busy process loads each core (the threaded
    version died by SIGSEGV in 1 of 8 such runs; tools/stress_workers.py runs 20)."""
    import multiprocessing

    load = [multiprocessing.get_context("spawn").Process(target=_busy, daemon=True) for _ in range(os.cpu_count() or 1)]
    for p in load:
        p.start()
    try:
        out = subprocess.run([sys.executable, "-c", STRESSED.format(tests=os.path.dirname(__file__))],
                             capture_output=True, text=True, timeout=600)
    finally:
        for p in load:
            p.terminate()
    assert out.returncode == 0 and "OK 4" in out.stdout, out.stderr[-3000:]


def test_resumed_run_equals_uninterrupted(sphere642, tmp_path):
    whole = _quiet_all_pairs(sphere642, 0.03, max_iterations=30, workers=2, device="cpu", engine="consensus")
    path = tmp_path / "run.npz"
    first = _quiet_all_pairs(sphere642, 0.03, max_iterations=12, workers=2, device="cpu", checkpoint=path,
                             engine="consensus")
    assert not first.converged and first.iterations == 12 and path.exists()
    assert not any(p.name.startswith("run.npz.tmp") for p in tmp_path.iterdir())
    # the rest with another worker count: the split does not change the iterates
    rest = _quiet_all_pairs(sphere642, 0.03, max_iterations=30, workers=1, device="cpu", resume=path,
                            engine="consensus")
    assert rest.iterations == whole.iterations == 30
    assert np.array_equal(rest.distance, whole.distance)
    assert np.array_equal(rest.history, whole.history)
    assert rest.cg_iterations == whole.cg_iterations


@pytest.mark.parametrize("role", ["checkpoint", "resume", "initial"])
@pytest.mark.parametrize("path", ["", 3, True])
def test_checkpoint_that_is_no_file_name_is_refused_before_the_run(sphere642, role, path):
    with pytest.raises(ValueError, match=rf"expected {role} as a file name \(str or os.PathLike\), got {path!r}"):
        wrd.all_pairs(sphere642, 0.03, max_iterations=2, **{role: path})


def test_checkpoints_and_change_tests_read_the_state_without_copying_it(sphere642, tmp_path, monkeypatch):
    # a copy of the whole state at every checkpoint would hold 1.5x the solver's memory for a moment
    from warp_regdist.solvers.common import stopping

    written, compared = [], []
    savez, update = np.savez, stopping.ExtrapolatedChangeTest.update

    def recording_savez(file, **arrays):
        written.append({name: not a.flags.owndata for name, a in arrays.items() if a.ndim >= 3})
        return savez(file, **arrays)

    def recording_update(self, u, iteration):
        compared.append(not u.flags.owndata)
        return update(self, u, iteration)

    monkeypatch.setattr(np, "savez", recording_savez)
    monkeypatch.setattr(stopping.ExtrapolatedChangeTest, "update", recording_update)
    _quiet_all_pairs(sphere642, 0.03, max_iterations=101, workers=1, device="cpu", checkpoint=tmp_path / "run.npz",
                     engine="consensus")
    assert len(written) == 1 and set(written[0]) >= {"X", "U", "H", "v"} and all(written[0].values())
    assert compared == [True, True]


def test_interrupt_returns_the_iterate_and_checkpoints(sphere642, tmp_path):
    whole = _quiet_all_pairs(sphere642, 0.05, max_iterations=20, device="cpu")
    path = tmp_path / "run.npz"

    def ctrl_c(progress):
        if progress.iteration == 8:
            os.kill(os.getpid(), signal.SIGINT)

    cut = wrd.all_pairs(sphere642, 0.05, max_iterations=20, device="cpu", checkpoint=path, callback=ctrl_c)
    assert cut.interrupted and not cut.converged and cut.iterations == 9 and cut.checkpoint == str(path)
    assert np.array_equal(cut.distance, cut.distance.T) and cut.distance.max() > 0
    rest = _quiet_all_pairs(sphere642, 0.05, max_iterations=20, device="cpu", resume=path)
    assert not rest.interrupted and np.array_equal(rest.distance, whole.distance)


def test_solve_many_interrupt_returns_current_iterates(monkeypatch):
    """A Ctrl-C in the parent (sent right after its own part's 5th iteration) stops the worker
    process's part too: every column returns its current iterate, flagged not converged."""
    V, F = meshes.icosphere(4, 1.0)
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), 0.05, device="cpu", workers=2)
    sets = [[i] for i in range(16)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        signal_after_iteration(monkeypatch, 5, signal.SIGINT)
        res = solver.solve_many(sets, eps_rel=1e-9, eps_rel_dual=1e-9)  # would run to max_iterations
    solver.close()
    assert res.interrupted and not res.converged.any()
    assert np.all(res.iterations < solver.options.max_iterations)
    assert np.all(np.isfinite(res.distance)) and res.distance.max() > 0


def test_checkpoint_of_another_problem_is_refused(sphere642, tmp_path):
    path = tmp_path / "run.npz"
    _quiet_all_pairs(sphere642, 0.03, max_iterations=3, device="cpu", checkpoint=path)
    with pytest.raises(ValueError, match=r"expected a checkpoint of this problem \(alpha_hat 0\.1\), got one of "
                                         r"another problem \(alpha_hat 0\.03\)"):
        wrd.all_pairs(sphere642, 0.1, device="cpu", resume=path)
    other = wrd.Mesh(sphere642.vertices * 2.0, sphere642.elements)
    with pytest.raises(ValueError, match="expected a checkpoint of this problem \\(mesh_sha256 "):
        wrd.all_pairs(other, 0.03, device="cpu", resume=path)
    (tmp_path / "junk.npz").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="expected resume as an all-pairs checkpoint"):
        wrd.all_pairs(sphere642, 0.03, device="cpu", resume=tmp_path / "junk.npz")


def test_a_checkpoint_is_checked_from_its_headers_and_read_one_array_at_a_time(sphere642, tmp_path):
    """Reading and checking a checkpoint loads none of its state arrays (tracemalloc sees numpy's
    allocations), so a resumed run holds one state array more than a fresh one, not a second state."""
    import tracemalloc

    path = tmp_path / "run.npz"
    _quiet_all_pairs(sphere642, 0.03, max_iterations=3, device="cpu", checkpoint=path, engine="consensus")
    fingerprint = all_pairs_checkpoint.problem_fingerprint(sphere642, 0.03, "float64", wrd.AllPairsOptions().rho2_factor,
                                                           "intrinsic", "edges", "consensus")
    tracemalloc.start()
    try:
        with all_pairs_checkpoint.read_checkpoint(path, fingerprint, sphere642.n_elements) as saved:
            read_peak = tracemalloc.get_traced_memory()[1]
            one = saved["U"].nbytes
    finally:
        tracemalloc.stop()
    assert one >= 8 * 642 * 642 and read_peak < one / 4


def test_checkpoint_without_room_is_refused_before_allocating(sphere642, tmp_path, monkeypatch):
    def no_state(*args, **kwargs):
        raise AssertionError("allocated before the disk check")

    monkeypatch.setattr(ap, "SymmetricADMM", no_state)
    monkeypatch.setattr(atomic_write.shutil, "disk_usage", lambda path: types.SimpleNamespace(free=1000))
    with pytest.raises(ValueError, match=r"expected ([0-9.]+) MB free for two copies of the checkpoint '.*run\.npz' "
                                         r"\(\1 MB\), got 1 kB free on the file system of '.*'"):
        wrd.all_pairs(sphere642, 0.03, device="cpu", checkpoint=tmp_path / "run.npz")
    with pytest.raises(ValueError, match="expected checkpoint in an existing directory"):
        wrd.all_pairs(sphere642, 0.03, device="cpu", checkpoint=tmp_path / "missing" / "run.npz")


def _write_off(path, mesh):
    with open(path, "w") as f:
        f.write(f"OFF\n{mesh.n_vertices} {mesh.n_elements} 0\n")
        f.writelines(f"{float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in mesh.vertices)
        f.writelines(f"3 {a} {b} {c}\n" for a, b, c in mesh.elements)


def test_cli_allpairs_checkpoint_and_resume(sphere642, tmp_path, capsys):
    from warp_regdist.cli import main

    off, ckpt, out = tmp_path / "s.off", tmp_path / "c.npz", tmp_path / "d.npy"
    _write_off(off, sphere642)
    mesh = wrd.load_mesh(off)
    whole = _quiet_all_pairs(mesh, 0.03, max_iterations=15, device="cpu")
    assert main(["allpairs", str(off), "--output", str(out), "--checkpoint", str(ckpt), "--max-iterations", "6",
                 "--device", "cpu", "--quiet"]) == 1   # written, not converged
    err = capsys.readouterr().err
    assert err == (f"warp-regdist: warning: the all-pairs ADMM did not converge in 6 iterations; the matrix written is "
                   f"approximate; the solver state of iteration 6 is in {ckpt} (continue with --resume {ckpt} "
                   "--max-iterations 12)\n")
    assert main(["allpairs", str(off), "--output", str(out), "--resume", str(ckpt), "--max-iterations", "6",
                 "--device", "cpu", "--quiet"]) == 2   # resumed at its cap: it would not move
    assert capsys.readouterr().err == (f"warp-regdist: error: expected max_iterations above 6, the iteration of the "
                                       f"checkpoint resumed ('{ckpt}'), got 6: the run would stop where it is\n")
    assert main(["allpairs", str(off), "--output", str(out), "--resume", str(ckpt), "--max-iterations", "15",
                 "--device", "cpu", "--quiet"]) == 1
    assert np.array_equal(np.load(out), whole.distance)
    assert main(["allpairs", str(off), "--output", str(out), "--resume", str(tmp_path / "none.npz"),
                 "--device", "cpu"]) == 2
    assert "expected --resume as an existing checkpoint file" in capsys.readouterr().err
    # --initial: the checkpoint as the start of another alpha_hat (that the answer is then the new
    # minimizer is checked in test_all_pairs; here the plumbing)
    assert main(["allpairs", str(off), "--alpha-hat", "0.05", "--output", str(out), "--initial", str(ckpt),
                 "--max-iterations", "3", "--device", "cpu", "--quiet"]) == 1
    warm = _quiet_all_pairs(mesh, 0.05, max_iterations=3, device="cpu", initial=ckpt)
    assert np.array_equal(np.load(out), warm.distance)
    assert not np.array_equal(warm.distance, _quiet_all_pairs(mesh, 0.05, max_iterations=3, device="cpu").distance)
    assert main(["allpairs", str(off), "--output", str(out), "--initial", str(tmp_path / "none.npz"),
                 "--device", "cpu"]) == 2
    assert "expected --initial as an existing checkpoint file" in capsys.readouterr().err
