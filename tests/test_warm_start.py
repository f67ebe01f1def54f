"""Warm starts (``initial=``): the answer is the new problem's minimizer, only the start changes.

Reference: cvxpy + Clarabel on the same discrete problem (tests/reference_solver.py). A warm
start that leaked into the answer (a u that kept the old alpha_hat, or the old source) would
miss the new minimizer by the 2-6% that separates the two problems, 20x the tolerance here.
"""

import numpy as np
import pytest

import meshes
import reference_solver as rs
import warp_regdist as wrd
from conftest import TIGHT


@pytest.fixture(scope="module")
def bumpy():
    V, F = meshes.icosphere(3, 1.0)  # 642 vertices
    return meshes.perturbed(V, F, 0.02, seed=1), F


def _reference_error(V, F, sources, alpha_hat, distance):
    areas, _ = rs.face_geometry(V, F)
    expected = rs.solve_reference(V, F, sources, alpha_hat * np.sqrt(areas.sum()))
    return np.abs(distance - expected).max() / expected.max()


def test_continuation_in_alpha_hat_reaches_the_new_minimizer(bumpy, device):
    V, F = bumpy
    mesh = wrd.Mesh(V, F)
    first = wrd.DistanceSolver(mesh, 0.05, device=device, options=TIGHT).solve([100])
    solver = wrd.DistanceSolver(mesh, 0.1, device=device, options=TIGHT)
    cold, warm = solver.solve([100]), solver.solve([100], initial=first)
    assert warm.converged and warm.iterations < cold.iterations
    assert _reference_error(V, F, [100], 0.1, warm.distance) <= 1e-3


def test_warm_start_from_another_source_reaches_the_new_minimizer(bumpy, device):
    V, F = bumpy
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), 0.05, device=device, options=TIGHT)
    warm = solver.solve([101], initial=solver.solve([100]))
    assert warm.converged and warm.distance[101] == 0.0
    assert _reference_error(V, F, [101], 0.05, warm.distance) <= 1e-3


def test_warm_start_from_the_answer_stops_within_two_change_tests(bumpy):
    solver = wrd.DistanceSolver(wrd.Mesh(*bumpy), 0.05)
    res = solver.solve([100])
    again = solver.solve([100], initial=res)
    assert res.iterations > 2 * solver.options.change_window
    # the first change test extrapolates at the rate cap (20 times the window's change), the second at each vertex's rate
    assert again.iterations <= 2 * solver.options.change_window
    assert np.abs(again.distance - res.distance).max() <= 1e-3 * res.distance.max()
    assert res.duals.shape == (len(bumpy[1]), 3) and res.penalty == solver.options.rho_max


def test_solve_many_keeps_duals_per_column_and_takes_them_back(bumpy):
    solver = wrd.DistanceSolver(wrd.Mesh(*bumpy), 0.05)
    sets = [[0], [100], [7, 300]]
    res = solver.solve_many(sets, keep_duals=True)
    assert "duals" not in solver.solve_many(sets[:1])
    single = solver.solve([100])
    np.testing.assert_allclose(res.duals[:, :, 1], single.duals, atol=1e-12)
    again = solver.solve_many(sets, initial=res)
    assert (again.iterations <= 3 * solver.options.change_window).all()   # 10-30 measured, with either rule
    # a distance alone (no duals) is a start too; the iterations then follow the fixed schedule
    assert solver.solve_many(sets, initial=wrd.DistanceResult(distance=res.distance)).converged.all()


def test_bad_initial_is_refused(bumpy):
    solver = wrd.DistanceSolver(wrd.Mesh(*bumpy), 0.05)
    res = solver.solve([100])
    with pytest.raises(ValueError, match=r"expected initial with a distance of shape \(642, 2\) .*got shape \(642,\)"):
        solver.solve_many([[1], [2]], initial=res)
    with pytest.raises(ValueError, match="expected initial as a DistanceResult of solve or solve_many, got ndarray"):
        solver.solve([1], initial=res.distance)
    other = wrd.DistanceSolver(wrd.Mesh(*meshes.icosphere(2, 1.0)), 0.05).solve([1])
    with pytest.raises(ValueError, match=r"expected initial with a distance of shape \(642, 1\)"):
        solver.solve([1], initial=other)
    with pytest.raises(ValueError, match=r"expected initial duals of shape \(1280, 3, 1\), got shape \(5, 3\)"):
        solver.solve([1], initial=wrd.DistanceResult(distance=res.distance, duals=np.zeros((5, 3)), penalty=1.0))
    with pytest.raises(ValueError, match=r"expected initial duals finite and penalty > 0 \(scalar or \(1,\)\), got penalty "
                                         r"array\(-1\.\)"):
        solver.solve([1], initial=wrd.DistanceResult(distance=res.distance, duals=res.duals, penalty=-1.0))
    with pytest.raises(ValueError, match="expected initial distances without NaN, got 1 NaN"):
        solver.solve([1], initial=wrd.DistanceResult(distance=np.where(np.arange(642) == 3, np.nan, res.distance)))
