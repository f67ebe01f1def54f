"""Shared fixtures: tests/ on sys.path (for the helper modules) and the Warp devices."""

import os
import sys

import pytest
import warp as wp

import warp_regdist as wrd

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

DEVICES = ["cpu"] + (["cuda"] if wp.get_cuda_device_count() > 0 else [])


@pytest.fixture(params=DEVICES)
def device(request):
    """Every Warp device present: "cpu" always, "cuda" when a GPU is visible."""
    return request.param


TIGHT = wrd.SolverOptions(eps_abs=1e-7, eps_rel=1e-5, eps_rel_dual=1e-3)
"""ADMM stopping tolerances 50-100x below the defaults. The tests that use them accept
1e-3 of the maximal distance (or compare at the 1e-4 level on the cylinder and the disk);
the exact discrete minimizer is reached to ~5e-4 on spot, ~1e-4 on small meshes."""


def signal_after_iteration(monkeypatch, at, sig):
    """Make the single-source solves send ``sig`` to this process right after iteration ``at``
    (wrapping ``solver.run_iterations``), as a user's Ctrl-C or a scheduler's SIGTERM would."""
    import warp_regdist.solvers.single_source.solver as solver_module

    run_iterations = solver_module.run_iterations

    def signalling(problem, start, max_iterations, check_every=1, poll=None):
        advance = problem.advance

        def advance_then_signal(it, count):
            advance(it, count)
            if it < at <= it + count:
                os.kill(os.getpid(), sig)

        problem.advance = advance_then_signal
        return run_iterations(problem, start, max_iterations, check_every, poll)

    monkeypatch.setattr(solver_module, "run_iterations", signalling)


@pytest.fixture
def run_states(monkeypatch):
    """The engine states of the all-pairs runs of a test, in order (wrapping ``PairsRun.__init__``)."""
    from warp_regdist.solvers.all_pairs import run

    seen = []
    start = run.PairsRun.__init__

    def keep(self, state, *args):
        seen.append(state)
        start(self, state, *args)

    monkeypatch.setattr(run.PairsRun, "__init__", keep)
    return seen
