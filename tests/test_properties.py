"""Invariances and bookkeeping of the solver, on every Warp device present.

Why a wrong implementation fails: alpha = alpha_hat * A (instead of sqrt(A)) gives the
10x mesh a 10x larger alpha relative to its size (38% of the maximum here); a stopping
test or penalty rule that is not scale-invariant stops the two meshes at different
iterations, ~0.3-0.8% apart at the default tolerances; a batch that mixes columns
(shared sources, a shared mask) breaks solve_many; a missing component or
unreferenced-vertex check gives finite or NaN values there.
"""

import os

import numpy as np
import pytest
from scipy.optimize import OptimizeWarning

import meshes
from same_run import assert_same_run
import warp_regdist as wrd
from conftest import TIGHT


def _bumpy_sphere():
    V, F = meshes.icosphere(2, 1.0)  # 162 vertices
    return meshes.perturbed(V, F, 0.05, seed=2), F


def _rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


def test_scaling_the_mesh_scales_the_distance(device):
    V, F = _bumpy_sphere()
    # default tolerances: with scale-invariant settings (docs/method.md sections 4 and 8) the ADMM runs
    # the same iterations on both meshes, so they agree far below the solver tolerance
    d1 = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, device=device).solve([3])
    d10 = wrd.DistanceSolver(wrd.Mesh(10.0 * V, F), alpha_hat=0.05, device=device).solve([3])
    assert d1.converged and d10.converged
    err = _rel(d10.distance, 10.0 * d1.distance)
    assert err <= 1e-3, (err, d1.iterations, d10.iterations)


def test_float32_agrees_with_float64(device):
    # tight tolerances, so that both stop near the same minimizer (at eps_rel = 1e-3 they
    # stop ~1e-3 apart for reasons unrelated to precision); float32 reaches them here
    V, F = _bumpy_sphere()
    mesh = wrd.Mesh(V, F)
    d64 = wrd.DistanceSolver(mesh, alpha_hat=0.05, device=device, dtype="float64", options=TIGHT).solve([7, 90])
    d32 = wrd.DistanceSolver(mesh, alpha_hat=0.05, device=device, dtype="float32", options=TIGHT).solve([7, 90])
    assert d64.converged and d32.converged
    assert d32.distance.dtype == np.float64 and d32.distance.shape == (len(V),)
    assert _rel(d32.distance, d64.distance) <= 1e-3


def test_solve_many_equals_separate_solves(device):
    # tight tolerances: a batch may run a column past its own stopping point (until the
    # slowest column stops), so at loose tolerances the two legitimately differ by the
    # solver's error (~1e-3 at eps_rel = 1e-3); near the minimizer they must coincide
    V, F = _bumpy_sphere()
    belt = np.flatnonzero(np.abs(V[:, 2]) < 0.15)  # a band of vertices around the equator
    assert len(belt) > 10
    sets = [[5], [11, 150], belt]
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, device=device, options=TIGHT)
    many = solver.solve_many(sets)
    single = [solver.solve(s) for s in sets]
    assert many.distance.shape == (len(V), 3)
    assert np.shape(many.iterations) == (3,) and np.shape(many.converged) == (3,)
    assert np.all(many.converged)
    for k, res in enumerate(single):
        assert _rel(many.distance[:, k], res.distance) <= 1e-3, k
        assert np.all(many.distance[sets[k], k] == 0.0)


def _sphere_gap_disk():
    """Icosphere (42 vertices), one unreferenced vertex (index 42), a flat disk beside it."""
    Vs, Fs = meshes.icosphere(1, 1.0)
    Vd, Fd = meshes.disk(1.0, 3)
    Vd = Vd + [5.0, 0.0, 0.0]
    V = np.concatenate([Vs, [[0.0, 0.0, 3.0]], Vd])
    F = np.concatenate([Fs, Fd + len(Vs) + 1])
    return V, F, np.arange(len(Vs)), len(Vs), len(Vs) + 1 + np.arange(len(Vd))


def test_distance_zero_on_sources_nonnegative_and_inf_where_unreachable(device):
    V, F, sphere, lonely, disk = _sphere_gap_disk()
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, device=device)
    d = solver.solve([0, 17]).distance
    assert d.shape == (len(V),) and d.dtype == np.float64
    assert d[0] == 0.0 and d[17] == 0.0
    assert np.all(np.isfinite(d[sphere])) and np.all(d[sphere] >= 0.0)
    assert np.all(d[np.setdiff1d(sphere, [0, 17])] > 0.0)
    assert d[lonely] == np.inf
    assert np.all(d[disk] == np.inf)


def test_sources_on_two_components(device):
    V, F, sphere, lonely, disk = _sphere_gap_disk()
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, device=device, options=TIGHT)
    d = solver.solve_many([[0], [0, int(disk[0])], [int(disk[0])]]).distance
    assert np.all(np.isfinite(d[sphere, 0])) and np.all(d[disk, 0] == np.inf)
    assert np.all(np.isfinite(d[sphere, 1])) and np.all(np.isfinite(d[disk, 1]))
    assert np.all(d[sphere, 2] == np.inf) and np.all(np.isfinite(d[disk, 2]))
    assert np.all(d[lonely] == np.inf)
    # the components do not interact: a source on the disk does not change the sphere
    assert _rel(d[sphere, 1], d[sphere, 0]) <= 1e-3
    assert _rel(d[disk, 1], d[disk, 2]) <= 1e-3
    # the source disk[0] is the centre of the unit disk: |grad u| <= 1 bounds u by 1
    assert 0.9 < d[disk, 2].max() < 1.0 + 1e-3


def test_not_converged_warns(device):
    V, F = _bumpy_sphere()
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, device=device)
    with pytest.warns(wrd.ConvergenceWarning):
        res = solver.solve([0], max_iterations=2)
    assert not res.converged
    assert res.iterations == 2
    assert issubclass(wrd.ConvergenceWarning, OptimizeWarning)


def test_batch_columns_match_single_solves_across_blocks(device):
    """11 columns = 2 lane blocks: columns that finish early are frozen and the running
    ones are moved into the freed lanes (the emptied block is dropped); every column must
    still take the same iterations and reach the same distance as its single solve."""
    V, F = _bumpy_sphere()
    rng = np.random.default_rng(7)
    sets = [[int(i)] for i in rng.choice(len(V), size=10, replace=False)] + [[0, 1, 2]]
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, device=device, workers=1)
    many = solver.solve_many(sets)
    assert len(set(many.iterations.tolist())) > 3  # columns stop at different iterations
    for k, s in enumerate(sets):
        res = solver.solve(s)
        assert many.iterations[k] == res.iterations, k
        assert_same_run(many.distance[:, k], res.distance, device)


def test_wide_batch_threads_take_rows_of_all_blocks(device):
    """330 columns = 42 lane blocks of 8 (float64): from 32 blocks a CPU thread takes one row of
    every block (kernels/lanes.py thread_span), adds the rows' sums in another order, and keeps
    that layout while the batch compacts below 32 blocks; every column must still be its single
    solve's distance (to rounding: the sums' order differs from a single solve's)."""
    V, F = _bumpy_sphere()
    sets = [[i % len(V), (7 * i + 3) % len(V)] for i in range(330)]  # 42 blocks of 8 lanes
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, device=device, workers=1)
    many = solver.solve_many(sets)
    assert many.converged.all() and len(set(many.iterations.tolist())) > 3
    for k in (0, 1, 57, 200, 329):
        res = solver.solve(sets[k])
        assert abs(int(many.iterations[k]) - int(res.iterations)) <= 1, k
        assert _rel(many.distance[:, k], res.distance) <= 1e-6, k


def test_tightened_tolerances_converge(device):
    # 10x tighter than the defaults on the 42-vertex bumpy sphere: with u-steps solved only
    # to a fixed tolerance, sources 1, 4 and 7 stalled with r ~2x above eps_pri for 5000
    # iterations (a warm start already meeting the tolerance left u unchanged)
    data = np.load(os.path.join(os.path.dirname(__file__), "data", "all_pairs_bumpy42.npz"))
    solver = wrd.DistanceSolver(wrd.Mesh(data["vertices"], data["faces"]), alpha_hat=0.05, device=device)
    res = solver.solve_many([[1], [4], [7]], eps_rel=2.5e-5, eps_rel_dual=0.015, max_iterations=2000)
    assert res.converged.all(), res.iterations
    assert res.iterations.max() < 600, res.iterations


def test_worker_threads_give_the_same_columns(device):
    """24 float64 columns = 3 lane blocks on the shipped spot mesh, one batch vs three
    threads of one block each: every column, its iterations and residuals must be equal.
    A per-column tolerance left behind when columns are compacted makes a column's CG
    tolerance depend on its batch (the two then differ by ~1e-6)."""
    mesh = wrd.load_mesh(os.path.join(os.path.dirname(wrd.__file__), "data", "spot_rr.off"))
    rng = np.random.default_rng(0)
    sets = [[int(i)] for i in rng.choice(mesh.n_vertices, size=24, replace=False)]
    one = wrd.DistanceSolver(mesh, alpha_hat=0.05, device=device, workers=1).solve_many(sets)
    three = wrd.DistanceSolver(mesh, alpha_hat=0.05, device=device, workers=3).solve_many(sets)
    assert_same_run(one.distance, three.distance, device)
    assert np.array_equal(one.iterations, three.iterations)
    assert_same_run(one.primal_residual, three.primal_residual, device)
    assert one.converged.all() and three.converged.all()


@pytest.mark.parametrize("workers", [0, -1, 1.5, True, "2"])
def test_bad_workers(workers):
    V, F = _bumpy_sphere()
    with pytest.raises(ValueError, match="expected workers as an integer >= 1 or None"):
        wrd.DistanceSolver(wrd.Mesh(V, F), workers=workers)


def test_convergence_warnings_point_at_the_caller(device):
    V, F = meshes.icosphere(1)
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, device=device,
                                options=wrd.SolverOptions(max_iterations=10))
    with pytest.warns(wrd.ConvergenceWarning, match=r"^ADMM did not converge in 10 iterations for 1 of 1 source sets$") as one:
        solver.solve([0])
    with pytest.warns(wrd.ConvergenceWarning, match=r"^ADMM did not converge in 10 iterations for 2 of 2 source sets$") as many:
        solver.solve_many([[0], [5]])
    assert [w.filename for w in one] == [__file__] and [w.filename for w in many] == [__file__]
