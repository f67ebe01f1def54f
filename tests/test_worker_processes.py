"""Worker processes never outlive their parent, and a dead worker is reported, not waited for.

The parent is killed (SIGKILL as the out-of-memory killer does, or SIGTERM) while its worker
is busy in a solve (only the worker's watchdog can stop it) or idle between all-pairs
iterations (it then reads the end of its pipe); its workers must be gone within seconds and
with them the shared memory. A worker killed during a solve makes the parent raise
WorkerError naming the worker and the signal at its next check; an all-pairs run so stopped
resumes from its checkpoint to the uninterrupted result. Every wait here is bounded.
"""

import os
import select
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

import meshes
import warp_regdist as wrd
import warp_regdist.solvers.single_source.solver as solver_module
from warp_regdist.solvers.common.processes import processes_available

pytestmark = pytest.mark.skipif(not processes_available(), reason="worker processes need Linux")

GONE_WITHIN = 10.0  # seconds a worker may outlive its parent (the watchdog polls every 0.2 s)
READY_WITHIN = 300.0  # seconds for the parent to start its workers (kernels may compile)

PARENT = """
import os, sys, time, warnings
sys.path.insert(0, {tests!r})
import meshes, warp_regdist as wrd, warp_regdist.solvers.single_source.solver as solver_module
warnings.simplefilter("ignore")

def ready():
    print("READY", flush=True)
    time.sleep(600)

if {kind!r} == "all_pairs":  # the worker waits for the next call while the parent sleeps in progress
    V, F = meshes.icosphere(3, 1.0)
    wrd.all_pairs(wrd.Mesh(V, F), 0.03, dtype="float32", max_iterations=10000, workers=2, device="cpu",
                  engine="consensus", callback=lambda p: p.iteration == 2 and ready())
else:  # the worker solves its part (run to max_iterations) while the parent sleeps in its own
    V, F = meshes.icosphere(4, 1.0)
    run_iterations = solver_module.run_iterations

    def sleeping(problem, start, max_iterations, check_every=1, poll=None):
        advance = problem.advance
        problem.advance = lambda it, count: (advance(it, count), it >= 3 and ready())
        return run_iterations(problem, start, max_iterations, check_every, poll)

    solver_module.run_iterations = sleeping
    wrd.DistanceSolver(wrd.Mesh(V, F), 0.05, device="cpu", workers=2).solve_many(
        [[i] for i in range(16)], eps_rel=1e-12, eps_rel_dual=1e-12, max_iterations=10**6)
"""


def _children(pid):
    """Pids of the live (not zombie) processes whose parent is ``pid``."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid and fields[0] != "Z":
                found.append(int(entry))
    return found


def _alive(pid):
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _holders(name):
    """Pids of the processes holding a descriptor of the memfd ``name``."""
    pids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                links = [os.readlink(f"/proc/{entry}/fd/{fd}") for fd in os.listdir(f"/proc/{entry}/fd")]
            except OSError:
                continue
            if any(f"memfd:{name}" in link for link in links):
                pids.append(int(entry))
    return pids


def _wait_for_ready(stream):
    """Whether the line READY comes on ``stream`` within READY_WITHIN seconds (other lines are skipped)."""
    deadline = time.monotonic() + READY_WITHIN
    while select.select([stream], [], [], max(0.0, deadline - time.monotonic()))[0]:
        line = stream.readline()
        if line.strip() == "READY":
            return True
        if not line:  # the parent ended
            return False
    return False


def _worker_pids(pid):
    """Pids of the live WorkerPool workers whose parent is ``pid``."""
    found = []
    for child in _children(pid):
        try:
            with open(f"/proc/{child}/cmdline", "rb") as f:
                if b"_serve" in f.read():
                    found.append(child)
        except OSError:  # ended meanwhile
            pass
    return set(found)


@pytest.mark.parametrize("kind, sig", [("all_pairs", signal.SIGKILL), ("solve_many", signal.SIGKILL),
                                       ("solve_many", signal.SIGTERM)])
def test_workers_exit_with_their_parent(kind, sig, tmp_path):
    errors = open(tmp_path / "stderr.txt", "w+")
    parent = subprocess.Popen([sys.executable, "-c", PARENT.format(tests=os.path.dirname(__file__), kind=kind)],
                              stdout=subprocess.PIPE, stderr=errors, text=True)
    try:
        assert _wait_for_ready(parent.stdout), errors.read()[-3000:] if not errors.seek(0) else ""
        workers = _worker_pids(parent.pid)
        assert len(workers) == 1
        if kind == "all_pairs":  # all-pairs state lives in shared memory
            assert _holders(f"warp_regdist_shared_{parent.pid}")
        os.kill(parent.pid, sig)
        # a first SIGTERM asks the solve to stop at the end of its iteration, inside which the parent
        # sleeps; a second one ends it: signal until it is gone (a handler may take two as one)
        deadline = time.monotonic() + 60
        while sig == signal.SIGTERM and parent.poll() is None and time.monotonic() < deadline:
            try:
                parent.wait(timeout=0.5)
            except subprocess.TimeoutExpired:
                os.kill(parent.pid, sig)
        parent.wait(timeout=60)
        deadline = time.monotonic() + GONE_WITHIN
        while any(_alive(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(_alive(w) for w in workers), f"workers {workers} outlived their parent"
        assert _holders(f"warp_regdist_shared_{parent.pid}") == []
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        parent.stdout.close()
        errors.close()


def test_a_dead_worker_is_reported_at_the_next_check(monkeypatch):
    V, F = meshes.icosphere(4, 1.0)
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), 0.05, device="cpu", workers=2)
    sets = [[i] for i in range(16)]
    run_iterations = solver_module.run_iterations
    advances = []
    others = _worker_pids(os.getpid())  # workers of pools that other tests left to the garbage collector

    def kill_the_worker_at_three(problem, start, max_iterations, check_every=1, poll=None):
        advance = problem.advance

        def counted(it, count):
            advance(it, count)
            advances.append(it)
            if len(advances) == 3:
                (worker,) = _worker_pids(os.getpid()) - others
                os.kill(worker, signal.SIGKILL)
                os.waitid(os.P_PID, worker, os.WEXITED | os.WNOWAIT)  # dead before the next check

        problem.advance = counted
        return run_iterations(problem, start, max_iterations, check_every, poll)

    monkeypatch.setattr(solver_module, "run_iterations", kill_the_worker_at_three)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        with pytest.raises(wrd.WorkerError, match=r"worker process 1 \(pid \d+\) was killed by SIGKILL \(the "
                                              r"out-of-memory killer sends it, as does kill -9\)"):
            solver.solve_many(sets, eps_rel=1e-12, eps_rel_dual=1e-12)
    assert len(advances) == 3  # raised at the check right after the death, not at the end of the solve
    monkeypatch.undo()
    again = solver.solve_many(sets)  # a fresh pool
    solver.close()
    assert again.converged.all()


def test_all_pairs_with_a_dead_worker_raises_and_resumes(tmp_path):
    V, F = meshes.icosphere(2, 1.0)
    mesh = wrd.Mesh(meshes.perturbed(V, F, 0.05, seed=3), F)
    path = tmp_path / "run.npz"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        whole = wrd.all_pairs(mesh, 0.05, max_iterations=20, device="cpu", workers=2, engine="consensus")
        others = _worker_pids(os.getpid())

        def kill_at_eight(progress):
            if progress.iteration == 8:
                for worker in _worker_pids(os.getpid()) - others:
                    os.kill(worker, signal.SIGTERM)
                    os.waitid(os.P_PID, worker, os.WEXITED | os.WNOWAIT)

        with pytest.raises(wrd.WorkerError, match=r"worker process 1 \(pid \d+\) was killed by SIGTERM; its part of the "
                                              r"work is lost \(an all-pairs run resumes from its last checkpoint\)"):
            wrd.all_pairs(mesh, 0.05, max_iterations=20, device="cpu", workers=2, checkpoint=path, engine="consensus",
                          checkpoint_seconds=1e-9, callback=kill_at_eight)
        rest = wrd.all_pairs(mesh, 0.05, max_iterations=20, device="cpu", workers=2, resume=path, engine="consensus")
    assert rest.iterations == whole.iterations == 20
    assert np.array_equal(rest.distance, whole.distance)


def test_worker_columns_do_not_depend_on_the_environment(monkeypatch):
    """Dask sets OPENBLAS_NUM_THREADS=1 in the caller's environment when it starts a cluster, so
    later worker processes run BLAS on one thread where this process uses all cores: the
    workers must reuse this solver's multigrid hierarchy (a pseudo-inverse rounds differently
    on another thread count) so that every column stays bit-identical to its in-process solve."""
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    V, F = meshes.icosphere(2, 1.0)
    mesh = wrd.Mesh(meshes.perturbed(V, F, 0.05, seed=5), F)
    sets = [[j] for j in range(9)]  # two lane blocks of 8: one per process
    with wrd.DistanceSolver(mesh, 0.05, workers=2) as solver:
        split = solver.solve_many(sets)
        alone = wrd.DistanceSolver(mesh, 0.05, workers=1, hierarchy=solver.hierarchy).solve_many(sets)
    np.testing.assert_array_equal(split.distance, alone.distance)
    with pytest.raises(ValueError, match=r"expected hierarchy as a multigrid Hierarchy of 162 unknowns, got str"):
        wrd.DistanceSolver(mesh, 0.05, hierarchy="multigrid")
    small = wrd.DistanceSolver(wrd.Mesh(*meshes.icosphere(1, 1.0)), 0.05).hierarchy
    with pytest.raises(ValueError, match=r"expected hierarchy as a multigrid Hierarchy of 162 unknowns, got 42"):
        wrd.DistanceSolver(mesh, 0.05, hierarchy=small)


def test_workers_run_under_the_callers_options():
    """The call's options travel with it, so an override in the parent governs the worker's columns
    too: the same iterations and values as in one process."""
    V, F = meshes.icosphere(2, 1.0)
    mesh = wrd.Mesh(meshes.perturbed(V, F, 0.05, seed=6), F)
    sets = [[j] for j in range(9)]
    changed = dict(eps_rel=1e-4, eps_rel_dual=0.05, change_window=5)
    with wrd.DistanceSolver(mesh, 0.05, workers=2) as solver:
        split = solver.solve_many(sets, **changed)
    alone = wrd.DistanceSolver(mesh, 0.05, workers=1, hierarchy=solver.hierarchy).solve_many(sets, **changed)
    default = wrd.DistanceSolver(mesh, 0.05, workers=1, hierarchy=solver.hierarchy).solve_many(sets)
    np.testing.assert_array_equal(split.iterations, alone.iterations)
    np.testing.assert_array_equal(split.distance, alone.distance)
    assert split.iterations[8] > default.iterations[8]  # the override held in the worker
