"""The multigrid preconditioner: its host-side hierarchy, its Warp V-cycle and PCG solves with it."""

import importlib.resources

import numpy as np
import pytest
import scipy.sparse.linalg as spla
import warp as wp

import meshes
import warp_regdist as wrd
from warp_regdist.kernels.lanes import SCALARS, lane_type, lane_width
from warp_regdist.linalg.multigrid import MultigridPreconditioner, prolongator, smoothed_aggregation
from warp_regdist.linalg.pcg import BatchedPCG


@pytest.fixture(scope="module")
def spot_stiffness():
    with importlib.resources.as_file(importlib.resources.files("warp_regdist") / "data" / "spot_rr.off") as path:
        mesh = wrd.load_mesh(path)
    return wrd.build_operators(mesh).stiffness


@pytest.fixture(scope="module")
def spot_hierarchy(spot_stiffness):
    return smoothed_aggregation(spot_stiffness)


def test_prolongator_reproduces_the_constants(spot_stiffness):
    """P = (I - w D^-1 A) T maps sqrt(aggregate sizes) to the ones vector (A 1 = 0), aggregates ~1/10."""
    P, w, dinv = prolongator(spot_stiffness.tocsr(), 0.5, np.random.default_rng(0))
    n, nc = P.shape
    assert 4 < n / nc < 30
    c = spla.lsqr(P, np.ones(n), atol=1e-14, btol=1e-14, iter_lim=5000)[0]
    assert np.abs(P @ c - 1.0).max() < 1e-8
    assert w > 0 and np.allclose(dinv, 1 / spot_stiffness.diagonal())


def _lanes(values, dtype, device):
    """(n, cols) float array -> (n, nb) Warp array of lane vectors (cols a multiple of the width)."""
    n, cols = values.shape
    W = lane_width(SCALARS[dtype], cols)
    out = wp.zeros((n, cols // W), dtype=lane_type(SCALARS[dtype], W), device=device)
    out.assign(values.reshape(n, cols // W, W))
    return out


def _problem(K, cols, seed=0):
    """Masks with 1-3 sources per column and right-hand sides vanishing on them."""
    rng = np.random.default_rng(seed)
    n = K.shape[0]
    mask = np.ones((n, cols))
    for j in range(cols):
        mask[rng.choice(n, size=1 + j % 3, replace=False), j] = 0.0
    return mask, mask * rng.uniform(0.5, 1.5, size=(n, cols))


def _pcg(K, mask, b, dtype, device, preconditioner, rtol):
    """Solve every column of mask K mask x = b with BatchedPCG; returns x (n, cols) and the iteration count."""
    n, cols = b.shape
    W = lane_width(SCALARS[dtype], cols)
    pcg = BatchedPCG(K, SCALARS[dtype], W, cols // W, device, preconditioner=preconditioner)
    x = wp.zeros((n, cols // W), dtype=lane_type(SCALARS[dtype], W), device=device)
    it, rel = pcg.solve(_lanes(b, dtype, device), x, _lanes(mask, dtype, device), rtol, 2000)
    assert np.all(rel <= rtol)
    return x.numpy().reshape(n, cols).astype(np.float64), it


def _direct(K, mask, b):
    x = np.zeros_like(b)
    for j in range(b.shape[1]):
        f = mask[:, j] > 0
        x[f, j] = spla.spsolve(K[f][:, f].tocsc(), b[f, j])
    return x


def test_hierarchy_is_a_symmetric_positive_v_cycle(spot_stiffness, spot_hierarchy):
    H = spot_hierarchy
    assert H.sizes[0] == spot_stiffness.shape[0] and H.sizes[-1] <= 256
    assert all(a > 4 * b for a, b in zip(H.sizes, H.sizes[1:]))
    rng = np.random.default_rng(1)
    u, v = rng.standard_normal((2, H.sizes[0]))
    assert u @ H.apply(v) == pytest.approx(v @ H.apply(u), rel=1e-12)
    assert u @ H.apply(u) > 0


def test_small_matrix_is_one_dense_pseudo_inverse():
    V, F = meshes.icosphere(2)
    K = wrd.build_operators(wrd.Mesh(V, F)).stiffness
    H = smoothed_aggregation(K)
    assert H.sizes == [K.shape[0]] and not H.smoothers
    r = np.random.default_rng(2).standard_normal(K.shape[0])
    r -= r.mean()
    np.testing.assert_allclose(K @ H.apply(r), r, atol=1e-10 * np.abs(r).max())


@pytest.mark.parametrize("dtype, cols, rtol, tol", [("float64", 1, 1e-11, 1e-8), ("float64", 8, 1e-11, 1e-8),
                                                    ("float32", 1, 1e-5, 1e-3)])
def test_multigrid_pcg_matches_direct_solve(spot_stiffness, spot_hierarchy, device, dtype, cols, rtol, tol):
    mask, b = _problem(spot_stiffness, cols)
    x, it = _pcg(spot_stiffness, mask, b, dtype, device, spot_hierarchy, rtol)
    ref = _direct(spot_stiffness, mask, b)
    assert np.abs(x - ref).max() <= tol * np.abs(ref).max()
    assert it < 60  # Jacobi needs about 400 here


@pytest.mark.parametrize("levels", ["several", "one"])
def test_vcycle_kernels_match_host_apply(spot_stiffness, spot_hierarchy, device, levels):
    if levels == "one":
        V, F = meshes.icosphere(2)
        K = wrd.build_operators(wrd.Mesh(V, F)).stiffness
        H = smoothed_aggregation(K)
        assert len(H.sizes) == 1
    else:
        K, H = spot_stiffness, spot_hierarchy
    n, cols = K.shape[0], 4
    _, r = _problem(K, cols, seed=3)
    op = MultigridPreconditioner(H, wp.float64, 4, 1, device)
    wr = _lanes(r, "float64", device)
    z = wp.zeros_like(wr)
    for launch in op.record(wr, z, 1):
        launch.launch()
    expected = H.apply(r)
    np.testing.assert_allclose(z.numpy().reshape(n, cols), expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_components_and_unreferenced_vertices(device):
    """Zero rows (unreferenced vertex) and a second component without sources, masked out."""
    V, F = meshes.icosphere(3)
    n = len(V)
    V2 = np.concatenate([V, V + [3.0, 0.0, 0.0], [[0.0, 5.0, 0.0]]])
    F2 = np.concatenate([F, F + n])
    K = wrd.build_operators(wrd.Mesh(V2, F2)).stiffness
    H = smoothed_aggregation(K)
    assert len(H.sizes) > 1
    mask = np.zeros((2 * n + 1, 1))
    mask[:n] = 1.0
    mask[[0, 7]] = 0.0
    b = mask * np.linspace(0.5, 1.5, 2 * n + 1)[:, None]
    x, _ = _pcg(K, mask, b, "float64", device, H, 1e-11)
    ref = _direct(K, mask, b)
    assert np.abs(x - ref).max() <= 1e-8 * np.abs(ref).max()


def test_jacobi_remains_available(spot_stiffness, device):
    mask, b = _problem(spot_stiffness, 1, seed=4)
    x, it = _pcg(spot_stiffness, mask, b, "float64", device, "jacobi", 1e-10)
    ref = _direct(spot_stiffness, mask, b)
    assert np.abs(x - ref).max() <= 1e-7 * np.abs(ref).max()
    assert it > 100


def test_invalid_preconditioner(spot_stiffness):
    with pytest.raises(ValueError, match="expected preconditioner"):
        BatchedPCG(spot_stiffness, wp.float64, 1, 1, "cpu", preconditioner="ilu")
    with pytest.raises(ValueError, match="expected a multigrid hierarchy for 4764 unknowns"):
        small = smoothed_aggregation(spot_stiffness[:300, :300])
        BatchedPCG(spot_stiffness, wp.float64, 1, 1, "cpu", preconditioner=small)


def test_set_matrix_solves_the_new_matrix(spot_stiffness, spot_hierarchy, device):
    """A shifted matrix K + c M (same pattern) set in place: the solve is of the new matrix."""
    import scipy.sparse as sp

    mask, b = _problem(spot_stiffness, 4, seed=5)
    shifted = (spot_stiffness + sp.diags(np.linspace(1.0, 3.0, spot_stiffness.shape[0]))).tocsr()
    pcg = BatchedPCG(spot_stiffness, wp.float64, 4, 1, device, preconditioner=spot_hierarchy)
    wb, wm = _lanes(b, "float64", device), _lanes(mask, "float64", device)
    x = wp.zeros((spot_stiffness.shape[0], 1), dtype=lane_type(wp.float64, 4), device=device)
    pcg.solve(wb, x, wm, 1e-11, 500)  # records the launches with the old values
    pcg.set_matrix(shifted)
    x.zero_()
    _, rel = pcg.solve(wb, x, wm, 1e-11, 500)
    assert np.all(rel <= 1e-11)
    ref = _direct(shifted, mask, b)
    assert np.abs(x.numpy().reshape(-1, 4) - ref).max() <= 1e-8 * np.abs(ref).max()
    with pytest.raises(ValueError, match="expected a \\(4764, 4764\\) matrix with the solver's sparsity pattern"):
        pcg.set_matrix(sp.eye(4764))
