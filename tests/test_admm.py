"""The ADMM engine's parts (warp_regdist/solvers/common/admm.py) on their own, and swapped into both solvers.

Schedules and change tests are checked on exact numbers (powers of two, hand-made columns);
a swapped schedule must change the iterations but not the answer: the cvxpy + Clarabel
minimizer (tests/reference_solver.py for single sources, tests/data/all_pairs_bumpy42.npz for
all pairs) within 1e-3 of the maximal distance.
"""

import copy
import dataclasses
import math
import os
import signal

import numpy as np
import pytest

import meshes
import reference_solver as rs
import warp_regdist as wrd
from conftest import TIGHT
from warp_regdist.solvers.common.stopping import ChangeTest, ExtrapolatedChangeTest
from warp_regdist import PenaltySchedule

PAIRS = os.path.join(os.path.dirname(__file__), "data", "all_pairs_bumpy42.npz")


def _tight(**changes):
    """The fields of conftest.TIGHT with ``changes``, as per-call keyword options."""
    return {f.name: getattr(TIGHT, f.name) for f in dataclasses.fields(TIGHT)} | changes


def test_schedule_values_and_offsets():
    s = PenaltySchedule(rho0=0.5, rho_max=4.0, doubling=10.0, scale=2.0)
    assert [s.rho(k) for k in (0, 10, 20, 25, 30, 31, 1000)] == [1.0, 2.0, 4.0, 4.0 * math.sqrt(2.0), 8.0, 8.0, 8.0]
    assert s.offset_for(4.0) == 20.0 and s.rho(s.offset_for(4.0)) == 4.0
    assert s.offset_for(1.0) == 0.0 and s.offset_for(0.25) == 0.0  # at or below scale rho0: from the start
    constant = PenaltySchedule(0.5, 4.0, math.inf, 2.0)
    assert constant.rho(0) == constant.rho(500) == 1.0 and constant.offset_for(8.0) == 0.0


def test_schedules_from_options():
    assert PenaltySchedule.of(wrd.SolverOptions(), 3.0, (1.0, 8.0, 1.0)) == PenaltySchedule(0.5, 32.0, 10.0, 3.0)
    assert PenaltySchedule.of(wrd.SolverOptions(), 3.0, (0.5, 1.0, 2.0)) == PenaltySchedule(0.25, 4.0, 20.0, 3.0)
    pairs = wrd.AllPairsOptions()
    assert PenaltySchedule.of(pairs.for_engine("consensus"), 3.0) == PenaltySchedule(0.5, 8.0, 30.0, 3.0)
    assert PenaltySchedule.of(pairs.for_engine("eigenbasis"), 3.0) == PenaltySchedule(2.0, 64.0, 100.0, 3.0)
    coarse = wrd.AllPairsOptions.for_accuracy(0.01)
    assert PenaltySchedule.of(coarse.for_engine("eigenbasis"), 3.0) == PenaltySchedule(2.0, 32.0, 100.0, 3.0)
    assert PenaltySchedule.of(coarse.for_engine("consensus"), 3.0) == PenaltySchedule(0.5, 8.0, 30.0, 3.0)
    assert PenaltySchedule.of(wrd.SolverOptions(rho0=1.0), 1.0).rho0 == 1.0
    doubling = wrd.AllPairsOptions(rho_doubling=15.0).for_engine("eigenbasis")
    assert PenaltySchedule.of(doubling, 1.0) == PenaltySchedule(2.0, 64.0, 15.0, 1.0)
    assert PenaltySchedule.of(wrd.AllPairsOptions(rho_max=32.0).for_engine("eigenbasis"), 1.0).rho_max == 32.0
    constant = _Constant()
    assert PenaltySchedule.of(wrd.SolverOptions(schedule=constant), 1.0) is constant


def test_bad_schedules_are_refused():
    with pytest.raises(ValueError, match=r"expected PenaltySchedule rho0 as a finite number > 0, got -1\.0"):
        PenaltySchedule(-1.0, 4.0, 10.0, 1.0)
    with pytest.raises(ValueError, match=r"expected PenaltySchedule doubling as a finite number > 0 \(or inf\), got 0"):
        PenaltySchedule(0.5, 4.0, 0, 1.0)
    mesh = wrd.Mesh(*meshes.icosphere(1, 1.0))
    message = (r"expected schedule as None, a PenaltySchedule or an object with rho\(k\) and offset_for\(penalty\), "
               "got float")
    with pytest.raises(ValueError, match=message):
        wrd.DistanceSolver(mesh, 0.05).solve([0], schedule=2.0)
    with pytest.raises(ValueError, match=message):
        wrd.all_pairs(mesh, 0.05, schedule=2.0)
    with pytest.raises(ValueError, match=r"expected a change-test window as an integer >= 1, got 0"):
        ChangeTest(0, 1e-3, 2)


def test_change_test_settles_exactly_when_it_should():
    test = ChangeTest(window=10, eps=0.125, columns=3)
    assert [test.due(k) for k in (5, 10, 20)] == [False, True, True]
    test.reset(np.zeros((2, 3)))
    # column 0 stays 0 (a source-only column), columns 1 and 2 start
    assert test.update(np.array([[0.0, 8.0, 8.0], [0.0, 1.0, 2.0]])).tolist() == [True, False, False]
    # moved 1 = 0.125 max |u| (settled, the bound is inclusive), moved 2 > 0.125 * 8
    assert test.update(np.array([[0.0, 8.0, 8.0], [0.0, 2.0, 4.0]])).tolist() == [True, True, False]
    # only the first two columns are live: the third keeps its flag and snapshot
    assert test.update(np.array([[0.0, 8.0], [0.0, 4.0]])).tolist() == [True, False]
    assert test.settled.tolist() == [True, False, False] and test.snapshot[:, 2].tolist() == [8.0, 4.0]
    never = ChangeTest(10, math.inf, 1)  # inf: no change test, settled at the first comparison
    never.reset(np.zeros((2, 1)))
    assert never.update(np.array([[1.0], [2.0]])).tolist() == [True]


def test_change_test_reset_and_state_round_trip():
    test = ChangeTest(10, 0.125, 3)
    test.reset(np.array([[30.0, 2.0, 3.0]]))
    test.update(np.array([[30.0, 2.0, 30.0]]))
    assert test.settled.tolist() == [True, True, False]
    saved = copy.deepcopy(test.state())
    again = ChangeTest(10, 0.125, 3)
    again.restore(saved)
    u = np.array([[31.0, 2.0, 0.0]])
    assert again.update(u).tolist() == test.update(u).tolist() == [True, True, False]
    test.reset(np.zeros((1, 3)))
    assert test.settled.tolist() == [False] * 3 and test.snapshot.tolist() == [[0.0] * 3]


def test_extrapolated_change_test_numbers():
    test = ExtrapolatedChangeTest(window=50, eps=1.5, columns=1)
    assert not test.settled[0] and test.change[0] == math.inf
    u = np.array([[8.0], [0.0]])
    assert test.update(u, 50).tolist() == [False] and test.change[0] == math.inf  # the first only records u
    test.update(u + [[0.0], [4.0]], 100)  # c = 4 / 8, nothing to extrapolate from yet
    assert test.window_change[0] == 0.5 and test.change[0] == math.inf and not test.settled[0]
    saved = copy.deepcopy(test.state())
    # c = 2 / 8: geometric 0.25 / (1 - 0.25 / 0.5) = 0.5, at 1 / k the larger window's 0.5 x 150 / 50 = 1.5
    assert test.update(u + [[0.0], [6.0]], 150).tolist() == [True]
    assert test.window_change[0] == 0.25 and test.change[0] == 1.5
    test.update(u + [[0.0], [2.0]], 200)  # c = 4 / 8 grows: at the capped rate 0.95, 0.5 / 0.05
    assert test.change[0] == pytest.approx(10.0) and not test.settled[0]
    test.update(u + [[0.0], [5.6]], 250)  # c = 0.45: geometric 0.45 / 0.1 = 4.5 beyond 0.5 x 250 / 50 = 2.5
    assert test.change[0] == pytest.approx(4.5) and not test.settled[0]
    test.update(u + [[0.0], [5.6]], 300)  # U stopped moving
    assert test.change[0] == 0.0 and test.settled[0]
    test.update(u + [[0.0], [5.68]], 5000)  # moves again (c = 0.01): 0.01 / 0.05, the 1 / k term 0 x min(100, 20)
    assert test.change[0] == pytest.approx(0.2) and test.settled[0]
    test.update(u + [[0.0], [5.679]], 5050)  # c = 1.25e-4: 1/k with 0.01 x 20 windows (the cap), not x 101
    assert test.change[0] == pytest.approx(0.2) and test.settled[0]
    resumed = ExtrapolatedChangeTest(50, 1.5, 1)
    resumed.restore(saved)
    assert resumed.update(u + [[0.0], [6.0]], 150).tolist() == [True] and resumed.change[0] == 1.5
    assert ExtrapolatedChangeTest(50, math.inf, 1).settled[0]  # no change test: settled from the start
    slower = ExtrapolatedChangeTest(50, 0.3, 1, rate_cap=0.975)  # the consensus engine's: at most 40 windows
    for k, moved in ((50, 0.0), (100, 0.08), (5000, 0.16), (5050, 0.1601)):
        slower.update(u + [[0.0], [moved]], k)
    assert slower.window_change[0] == pytest.approx(1.25e-5) and slower.change[0] == pytest.approx(0.4)
    assert not slower.settled[0]  # 0.01 x 40 windows; with 20 it would be 0.2


def test_the_consensus_engine_counts_more_windows_to_come():
    """Its PCG U-steps creep on obtuse meshes: its change test counts up to 40 windows, the eigenbasis
    engine's (exact U-steps) 20."""
    from warp_regdist.solvers.all_pairs.eigenbasis import EigenbasisADMM
    from warp_regdist.solvers.all_pairs.run import PairsRun
    from warp_regdist.solvers.all_pairs.state import SymmetricADMM

    for state, windows in ((SymmetricADMM, 40), (EigenbasisADMM, 20)):
        run = PairsRun(state, wrd.AllPairsOptions(), None, 0, None, None, None)
        assert 1 / (1 - run.change_test.rate_cap) == pytest.approx(windows)


@pytest.fixture(scope="module")
def sphere162():
    V, F = meshes.icosphere(2, 1.0)
    V = meshes.perturbed(V, F, 0.02, seed=1)
    exact = rs.solve_reference(V, F, [5], 0.05 * np.sqrt(rs.face_geometry(V, F)[0].sum()))
    return wrd.Mesh(V, F), exact


def _error(u, exact):
    return np.abs(u - exact).max() / exact.max()


def test_swapped_schedule_changes_the_iterations_not_the_minimizer(sphere162):
    mesh, exact = sphere162
    solver = wrd.DistanceSolver(mesh, 0.05, workers=1)
    slow = PenaltySchedule(0.5, 4.0, 20.0, solver.operators.length_scale)
    default, swapped = solver.solve([5], **_tight()), solver.solve([5], **_tight(schedule=slow))
    assert default.converged and swapped.converged and swapped.iterations != default.iterations
    assert _error(default.distance, exact) <= 1e-3 and _error(swapped.distance, exact) <= 1e-3
    assert np.abs(swapped.distance - default.distance).max() <= 1e-3 * default.distance.max()


class _Constant:
    """A schedule that is no PenaltySchedule: rho(k) = 2 for all k; records the offsets asked."""

    def __init__(self):
        self.asked = []

    def rho(self, k):
        return 2.0

    def offset_for(self, penalty):
        self.asked.append(penalty)
        return 0.0


def test_any_object_with_rho_and_offset_for_is_a_schedule(sphere162):
    mesh, exact = sphere162
    solver = wrd.DistanceSolver(mesh, 0.05, workers=1)
    constant = _Constant()
    res = solver.solve([5], **_tight(schedule=constant))
    assert res.converged and res.penalty == 2.0 / solver.operators.length_scale
    assert _error(res.distance, exact) <= 1e-3
    again = solver.solve([5], initial=res, schedule=constant)  # the warm start asks for its absolute penalty
    assert constant.asked == [pytest.approx(2.0, rel=1e-15)] and again.iterations == solver.options.change_window


def test_swapped_schedule_reaches_the_worker_processes(sphere162):
    mesh, _ = sphere162
    sets = [[j] for j in range(9)]  # two lane blocks of 8: one per process
    slow = PenaltySchedule(0.5, 4.0, 20.0, wrd.build_operators(mesh).length_scale)
    with wrd.DistanceSolver(mesh, 0.05, workers=2) as solver:
        split = solver.solve_many(sets, schedule=slow)
    alone = wrd.DistanceSolver(mesh, 0.05, workers=1).solve_many(sets, schedule=slow)
    np.testing.assert_array_equal(split.iterations, alone.iterations)
    np.testing.assert_array_equal(split.distance, alone.distance)


def test_single_source_honors_the_options_rho0(sphere162):
    solver = wrd.DistanceSolver(sphere162[0], 0.05, workers=1)
    default = solver.solve([5])
    started = wrd.DistanceSolver(sphere162[0], 0.05, workers=1, options=wrd.SolverOptions(rho0=1.0)).solve([5])
    assert started.iterations != default.iterations
    assert solver.solve([5], rho0=1.0).iterations == started.iterations      # per call
    schedule = PenaltySchedule(1.0, 4.0, 10.0, solver.operators.length_scale)
    assert solver.solve([5], schedule=schedule).iterations == started.iterations  # the same schedule as an object


@pytest.fixture(scope="module")
def bumpy42():
    d = np.load(PAIRS)
    return wrd.Mesh(d["vertices"], d["faces"]), d["U_01"]


def test_all_pairs_swapped_schedule_and_rho0(bumpy42):
    mesh, exact = bumpy42
    fast = PenaltySchedule(0.5, 4.0, 10.0, wrd.build_operators(mesh).length_scale)
    default = wrd.all_pairs(mesh, 0.1, device="cpu", workers=1, accuracy=0.001, engine="consensus")
    swapped = wrd.all_pairs(mesh, 0.1, device="cpu", workers=1, accuracy=0.001, schedule=fast,
                            engine="consensus")
    assert default.converged and swapped.converged and swapped.iterations != default.iterations
    assert _error(default.distance, exact) <= 1e-3 and _error(swapped.distance, exact) <= 1e-3
    assert np.abs(swapped.distance - default.distance).max() <= 1e-3 * default.distance.max()
    started = wrd.all_pairs(mesh, 0.1, device="cpu", workers=1, accuracy=0.001, rho0=1.0,
                             engine="consensus")   # per call
    assert started.iterations != default.iterations
    # in the solver's options rho0 also moves the multigrid's target penalty: other iterates, the same minimizer
    again = wrd.AllPairsSolver(mesh, 0.1, device="cpu", workers=1,
                               options=wrd.AllPairsOptions.for_accuracy(0.001, rho0=1.0, engine="consensus")).solve()
    assert again.converged and _error(again.distance, exact) <= 1e-3


def test_device_change_test_matches_the_host_rule():
    """The solver's change test runs on the device (kernels/single_source.py: change_measure, admm_check);
    ChangeTest is its host statement (without the error estimate's test, eps_estimate = inf). Four lanes:
    fast and slow decay, a jump, zeros."""
    import warp as wp
    from warp_regdist.kernels.single_source import LANE_ROWS, RULE_FIELDS, SETTLED, rule_struct, single_source_kernels
    from warp_regdist.kernels.lanes import row_dim

    kern = single_source_kernels(wp.float64, 4, 3)
    V = kern.V
    n, window, eps = 40, 10, 0.02
    rng = np.random.default_rng(3)
    base = rng.random((n, 4)) + 1.0
    base[:, 3] = 0.0
    u, snapshot, moved = (wp.zeros((n, 1), dtype=V, device="cpu") for _ in range(3))
    lane, acc = wp.zeros((LANE_ROWS, 1), dtype=V, device="cpu"), wp.zeros((5, 1), dtype=V, device="cpu")
    step, rho = wp.zeros(2, dtype=wp.int32, device="cpu"), wp.ones(1, dtype=V, device="cpu")
    table, atol2 = wp.ones(4, dtype=wp.float64, device="cpu"), wp.zeros(1, dtype=V, device="cpu")
    host = ChangeTest(window, eps, 4)
    host.reset(np.zeros((n, 4)))
    seen = []
    for j in range(1, 7):
        values = base * (1.0 + np.array([0.5 ** (3 * j), 0.9 ** j, 0.0, 0.0]) * rng.standard_normal((n, 4)))
        values[:, 2] = base[:, 2] * (2.0 if j == 4 else 1.0)  # settles, jumps at the 4th test, settles again
        u.assign(values.reshape(n, 1, 4))
        step.assign(np.array([j * window, 0], dtype=np.int32))
        wp.launch(kern.change_measure, row_dim(n, (16, 1), 1), device="cpu",
                  inputs=[u, snapshot, moved, step, window, wp.float64(0.95), lane, 16, 1, n])
        rule = rule_struct(wp.float64, dict(zip(RULE_FIELDS, (0.0, 1.0, 1.0, eps, np.inf, 1.0, 1.0, 1.0, 1.0, 0.0, 1.0))))
        wp.launch(kern.admm_check, 1, device="cpu", inputs=[acc, lane, rho, step, table, window, rule, atol2])
        device_settled = lane.numpy()[SETTLED, 0] == 1.0
        np.testing.assert_array_equal(device_settled, host.update(values))
        seen.append(device_settled.copy())
    seen = np.array(seen)
    assert seen[-1].tolist() == [True, False, True, True] and not seen[3, 2] and seen[2, 2]


def test_captured_graph_launches_and_sparse_checks_give_the_same_solve(sphere162):
    """The captured iteration, the same launches one by one, and host reads every 7 iterations
    (the device freezes each column at its own iteration): the same columns, bit for bit."""

    solver = wrd.DistanceSolver(sphere162[0], 0.05, workers=1)
    sets = [[j * 17] for j in range(6)] + [[3, 90]]
    graph = solver.solve_many(sets, keep_duals=True)
    launches = solver.solve_many(sets, keep_duals=True, capture=False)
    sparse = solver.solve_many(sets, keep_duals=True, capture=False, check_every=7)
    for other in (launches, sparse):
        for key in ("distance", "duals", "iterations", "primal_residual", "dual_residual", "penalty"):
            np.testing.assert_array_equal(other[key], graph[key])
    assert launches.cg_iterations == graph.cg_iterations <= sparse.cg_iterations  # sparse checks: a few spare iterations
    assert len(set(graph.iterations.tolist())) > 1


class _Countdown:
    """A problem for run_iterations: its test passes from iteration ``done_at``; records the calls."""

    def __init__(self, done_at, interrupt_at=None):
        self.done_at, self.interrupt_at, self.calls = done_at, interrupt_at, []

    def status(self, it):
        self.calls.append(("status", it))
        return it >= self.done_at

    def advance(self, it, count):
        self.calls.append(("advance", it, count))
        if self.interrupt_at is not None and it <= self.interrupt_at < it + count:
            os.kill(os.getpid(), signal.SIGINT)


def test_engine_loop_tests_every_check_and_stops_where_it_should():
    from warp_regdist.solvers.common.admm import CONVERGED, INTERRUPTED, MAX_ITERATIONS, run_iterations
    from warp_regdist.solvers.common import interrupt

    p = _Countdown(7)
    assert run_iterations(p, 0, 100, check_every=3) == (9, CONVERGED)
    assert p.calls == [("status", 0), ("advance", 0, 3), ("status", 3), ("advance", 3, 3), ("status", 6),
                       ("advance", 6, 3), ("status", 9)]
    p = _Countdown(10**9)
    assert run_iterations(p, 2, 8, check_every=3) == (8, MAX_ITERATIONS)
    assert p.calls[-3:] == [("status", 5), ("advance", 5, 3), ("status", 8)]
    p = _Countdown(10**9)
    assert run_iterations(p, 0, 8, check_every=3)[0] == 8 and p.calls[-2:] == [("advance", 6, 2), ("status", 8)]
    # Ctrl-C during an advance: the loop returns after it, without testing its iterate
    p = _Countdown(10**9, interrupt_at=4)
    with interrupt.catch_interrupt():
        assert run_iterations(p, 0, 100, check_every=2) == (6, INTERRUPTED)
    assert p.calls[-1] == ("advance", 4, 2)
