"""Error at the default stop against exact minimizers on irregular meshes (issue 13).

tests/data/stopping_cat80.npz: cat_rr quadric-decimated to 80 vertices (fast-simplification
0.2, target_reduction 1 - 80/1949: angles from 3.8 to 171 degrees) and the exact all-pairs
minimizers at alpha_hat 0.03 and 0.1 (tests/all_pairs_reference.py, symmetric=True, Clarabel
gap 1e-9). Before the change test the residual test alone stopped all_pairs 1.09% and 1.23%
of the maximal distance away from them (548 and 422 iterations); single sources on spot
needed 179 iterations (penalty doubling every 30 iterations, eps_rel 2.5e-4).
"""

import os
import pathlib

import numpy as np
import pytest

import reference_solver as rs
import warp_regdist as wrd

DATA = pathlib.Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def cat80():
    d = np.load(DATA / "stopping_cat80.npz")
    return wrd.Mesh(d["vertices"], d["faces"].astype(np.int64)), {0.03: d["U_003"], 0.1: d["U_01"]}


def _error(u, exact):
    return np.abs(u - exact).max() / exact.max()


@pytest.mark.parametrize("alpha_hat", [0.03, 0.1])
def test_all_pairs_default_stop_within_half_a_percent(cat80, alpha_hat, device):
    mesh, refs = cat80
    res = wrd.all_pairs(mesh, alpha_hat, device=device)
    assert res.converged and res.change <= wrd.tolerances.pairs_eps_change
    assert _error(res.distance, refs[alpha_hat]) <= 5e-3


def test_all_pairs_reads_its_settings_from_tolerances(cat80):
    mesh, _ = cat80
    with wrd.tolerances.override(pairs_eps_change=0.0):
        with pytest.raises(ValueError, match=r"expected a finite eps_change > 0, got 0\.0"):
            wrd.all_pairs(mesh, 0.1)
        with pytest.warns(wrd.ConvergenceWarning):  # the argument overrides the setting
            res = wrd.all_pairs(mesh, 0.1, device="cpu", max_iterations=3, eps_change=1.0)
    assert res.iterations == 3 and res.change == np.inf


def test_spot_single_source_in_100_iterations_within_half_a_percent(device):
    mesh = wrd.load_mesh(os.path.join(os.path.dirname(wrd.__file__), "data", "spot_rr.off"))
    exact = np.loadtxt(DATA / "spot_rr__2272__a0.05_exact.txt")
    res = wrd.DistanceSolver(mesh, 0.05, device=device).solve([2272])
    assert res.converged and res.iterations <= 100, res.iterations
    assert _error(res.distance, exact) <= 5e-3


@pytest.mark.parametrize("alpha_hat", [0.0, 0.03, 0.3])
def test_single_source_default_stop_on_decimated_cat(cat80, alpha_hat, device):
    mesh, _ = cat80
    V, F = mesh.vertices, mesh.elements
    exact = rs.solve_reference(V, F, [0], alpha_hat * np.sqrt(rs.face_geometry(V, F)[0].sum()))
    res = wrd.DistanceSolver(mesh, alpha_hat, device=device).solve([0])
    assert res.converged
    assert _error(res.distance, exact) <= 5e-3
