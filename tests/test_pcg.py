"""BatchedPCG: device-side stopping against a host-side PCG, and the captured loop against the launched one."""

import importlib.resources

import numpy as np
import pytest
import scipy.sparse.linalg
import warp as wp

import warp_regdist as wrd
from same_run import assert_same_run, on_cuda, same_count
from test_multigrid import _lanes, _problem
from warp_regdist.kernels.lanes import SCALARS, lane_type
from warp_regdist.linalg.multigrid import MultigridPreconditioner, smoothed_aggregation
from warp_regdist.linalg.pcg import BatchedPCG, JacobiPreconditioner, Preconditioner


@pytest.fixture(scope="module")
def spot_stiffness():
    with importlib.resources.as_file(importlib.resources.files("warp_regdist") / "data" / "spot_rr.off") as path:
        return wrd.build_operators(wrd.load_mesh(path)).stiffness


@pytest.fixture(scope="module")
def spot_hierarchy(spot_stiffness):
    return smoothed_aggregation(spot_stiffness)


def _host_pcg(K, mask, b, apply_m, rtol, max_iterations):
    """Textbook PCG per column on the host (float64), stopping when |r| <= rtol |b|: (x, iterations)."""
    x = np.zeros_like(b)
    its = []
    for j in range(b.shape[1]):
        m = mask[:, j]
        r = b[:, j].copy()
        tol2 = rtol * rtol * (b[:, j] @ b[:, j])
        z = m * apply_m(r)
        p, rz, k = z.copy(), r @ z, 0
        while r @ r > tol2 and k < max_iterations:
            q = m * (K @ p)
            a = rz / (p @ q)
            x[:, j] += a * p
            r -= a * q
            k += 1
            if r @ r <= tol2:
                break
            z = m * apply_m(r)
            rz, rz_old = r @ z, rz
            p = z + (rz / rz_old) * p
        its.append(k)
    return x, its


def _blocks(values, device, W=4):
    """(n, cols) float64 array -> (n, cols // W) Warp array of float64 lane vectors of width W."""
    n, cols = values.shape
    out = wp.zeros((n, cols // W), dtype=lane_type(wp.float64, W), device=device)
    out.assign(values.reshape(n, cols // W, W))
    return out


def _solve(K, mask, b, dtype, device, rtol=1e-10, max_iterations=500, x0=None, **options):
    """BatchedPCG solve of all columns (one block of len(columns) lanes): (x, iterations, rel, pcg)."""
    n, cols = b.shape
    pcg = BatchedPCG(K, SCALARS[dtype], cols, 1, device, **options)
    x = _lanes(np.zeros_like(b) if x0 is None else x0, dtype, device)
    it, rel = pcg.solve(_lanes(b, dtype, device), x, _lanes(mask, dtype, device), rtol, max_iterations)
    return x.numpy().reshape(n, cols).astype(np.float64), it, rel, pcg


@pytest.mark.parametrize("preconditioner", ["jacobi", "multigrid"])
def test_device_stopping_gives_the_host_pcg_iterates(spot_stiffness, spot_hierarchy, device, preconditioner):
    """The iterates of a host PCG after k iterations, and its stopping point up to rounding at the threshold."""
    K = spot_stiffness
    mask, b = _problem(K, 4, seed=7)
    if preconditioner == "jacobi":
        d = K.diagonal()
        apply_m, spec, rtol = (lambda r: r / d), "jacobi", 1e-6
    else:
        apply_m, spec, rtol = spot_hierarchy.apply, spot_hierarchy, 1e-9
    for k in (1, 4, 7):
        ref, _ = _host_pcg(K, mask, b, apply_m, 0.0, k)
        x, it, _, _ = _solve(K, mask, b, "float64", device, 0.0, k, preconditioner=spec, check_every=3)
        assert it == k
        assert np.abs(x - ref).max() <= 1e-8 * np.abs(ref).max()  # one iteration more: > 1e-4
    ref, ref_its = _host_pcg(K, mask, b, apply_m, rtol, 2000)
    x, it, rel, _ = _solve(K, mask, b, "float64", device, rtol, 2000, preconditioner=spec, check_every=3)
    assert abs(it - max(ref_its)) <= 1 and np.all(rel <= rtol)
    assert np.abs(x - ref).max() <= 1e-5 * np.abs(ref).max()


@pytest.mark.parametrize("dtype, cols", [("float64", 1), ("float64", 8), ("float32", 16)])
def test_captured_and_device_checked_loops_match_the_host_checked_one(spot_stiffness, spot_hierarchy, device,
                                                                      dtype, cols):
    mask, b = _problem(spot_stiffness, cols, seed=8)
    rtol = 1e-9 if dtype == "float64" else 1e-4
    runs = [_solve(spot_stiffness, mask, b, dtype, device, rtol, preconditioner=spot_hierarchy, **options)
            for options in (dict(check_every=1), dict(check_every=5), dict(capture=True))]
    (x, it, rel, _), others = runs[0], runs[1:]
    assert 5 < it < 60 and np.all(rel <= rtol)
    for x2, it2, rel2, _ in others:
        assert same_count(it2, it, device)
        assert_same_run(x2, x, device, dtype)
        if on_cuda(device):
            assert np.all(rel2 <= rtol)
        else:
            np.testing.assert_array_equal(rel2, rel)


def test_converged_lanes_are_left_unchanged(spot_stiffness, spot_hierarchy, device):
    """A lane that starts at the solution stays bit for bit where it was while the others iterate."""
    K = spot_stiffness
    mask, b = _problem(K, 4, seed=9)
    exact, _ = _host_pcg(K, mask, b, spot_hierarchy.apply, 1e-13, 500)
    x0 = np.zeros_like(b)
    x0[:, 2] = exact[:, 2]
    x, it, rel, _ = _solve(K, mask, b, "float64", device, 1e-9, x0=x0, preconditioner=spot_hierarchy, capture=True)
    assert it > 5 and np.all(rel <= 1e-9)
    np.testing.assert_array_equal(x[:, 2], x0[:, 2])


def test_zero_iterations(spot_stiffness, device):
    mask, b = _problem(spot_stiffness, 1, seed=10)
    for capture in (False, True):
        x, it, rel, _ = _solve(spot_stiffness, mask, 0 * b, "float64", device, preconditioner="jacobi",
                               capture=capture)
        assert it == 0 and rel[0] == 0.0 and not x.any()
        x, it, rel, _ = _solve(spot_stiffness, mask, b, "float64", device, max_iterations=0, preconditioner="jacobi",
                               capture=capture)
        assert it == 0 and rel[0] == pytest.approx(1.0, rel=1e-12) and not x.any()  # |b| / |b|, two sums


def test_fewer_active_blocks_recapture(spot_stiffness, spot_hierarchy, device):
    """Two blocks, then only the first: the captured graph follows the active blocks; block 1 is untouched."""
    K, n = spot_stiffness, spot_stiffness.shape[0]
    mask, b = _problem(K, 8, seed=11)
    V = lane_type(wp.float64, 4)
    pcg = BatchedPCG(K, wp.float64, 4, 2, device, preconditioner=spot_hierarchy, capture=True)
    wb, wm = _blocks(b, device), _blocks(mask, device)
    x = wp.zeros((n, 2), dtype=V, device=device)
    pcg.solve(wb, x, wm, 1e-9, 500)
    first = x.numpy().reshape(n, 8).copy()
    x.zero_()
    pcg.set_active_blocks(1)
    it, rel = pcg.solve(wb, x, wm, 1e-9, 500)
    assert rel.shape == (4,) and np.all(rel <= 1e-9)
    got = x.numpy().reshape(n, 8)
    assert not got[:, 4:].any()
    ref, ref_its = _host_pcg(K, mask[:, :4], b[:, :4], spot_hierarchy.apply, 1e-9, 500)
    assert abs(it - max(ref_its)) <= 1
    assert np.abs(got[:, :4] - ref).max() <= 1e-7 * np.abs(ref).max()
    assert np.abs(first[:, :4] - ref).max() <= 1e-7 * np.abs(ref).max()


def test_repeated_solves_replay_without_recording(spot_stiffness, device):
    """New view objects of the same arrays (all_pairs slices its columns every iteration) reuse the launches."""
    n = spot_stiffness.shape[0]
    mask, b = _problem(spot_stiffness, 8, seed=12)
    wb, wm = _blocks(b, device), _blocks(mask, device)
    x = wp.zeros_like(wb)
    pcg = BatchedPCG(spot_stiffness, wp.float64, 4, 1, device, preconditioner="jacobi")
    pcg.solve(wb[:, 1:2], x[:, 1:2], wm[:, 1:2], 1e-8, 1000)
    program = pcg._program
    x.zero_()
    it, rel = pcg.solve(wb[:, 1:2], x[:, 1:2], wm[:, 1:2], 1e-8, 1000)
    assert pcg._program is program and np.all(rel <= 1e-8)
    assert not x.numpy().reshape(n, 8)[:, :4].any()


def test_preconditioner_operator_and_bad_options(spot_stiffness, device):
    mask, b = _problem(spot_stiffness, 1, seed=13)
    op = JacobiPreconditioner(spot_stiffness, wp.float64, 1, device)
    x, it, rel, _ = _solve(spot_stiffness, mask, b, "float64", device, 1e-8, 2000, preconditioner=op)
    x2, it2, _, _ = _solve(spot_stiffness, mask, b, "float64", device, 1e-8, 2000, preconditioner="jacobi")
    assert same_count(it, it2, device) and it > 100 and rel[0] <= 1e-8
    assert_same_run(x, x2, device)
    with pytest.raises(ValueError, match=r"expected a preconditioner for 4764 unknowns, got 300"):
        small = JacobiPreconditioner(spot_stiffness[:300, :300], wp.float64, 1, device)
        BatchedPCG(spot_stiffness, wp.float64, 1, 1, device, preconditioner=small)
    assert isinstance(op, Preconditioner) and isinstance(MultigridPreconditioner(smoothed_aggregation(spot_stiffness),
                                                                               wp.float64, 1, 1, device), Preconditioner)

    class NoSize:                                      # record and set_matrix, but no n: not a Preconditioner
        def record(self, r, z, blocks):
            return []

        def set_matrix(self, matrix):
            pass

    with pytest.raises(ValueError, match=r"expected preconditioner 'multigrid', 'jacobi', a Hierarchy or a "
                                         r"Preconditioner \(n, record and set_matrix\), got <"):
        BatchedPCG(spot_stiffness, wp.float64, 1, 1, device, preconditioner=NoSize())
    pcg = BatchedPCG(spot_stiffness, wp.float64, 1, 1, device, preconditioner="jacobi")
    with pytest.raises(ValueError, match=r"expected atol a scalar or a \(1,\) array, got shape \(2,\)"):
        pcg.solve(_lanes(b, "float64", device), _lanes(0 * b, "float64", device), _lanes(mask, "float64", device),
                  1e-8, 10, atol=[1e-3, 1e-3])
    with pytest.raises(ValueError, match=r"expected check_every a positive integer, got 0"):
        BatchedPCG(spot_stiffness, wp.float64, 1, 1, device, preconditioner="jacobi", check_every=0)


@pytest.mark.parametrize("row_blocks", [6, 40])  # 128 rows of one block per thread / one row of all blocks
def test_column_slices_of_a_wider_state(spot_stiffness, spot_hierarchy, device, row_blocks):
    """x, rhs and mask as blocks 2..4 of (n, row_blocks) arrays (the all-pairs parts' layout): the
    row products index rows by the arrays' strides, and the answer is the direct solve's."""
    n, W = spot_stiffness.shape[0], 4
    mask, b = _problem(spot_stiffness, 3 * W, seed=5)
    wide = {name: np.zeros((n, row_blocks * W)) for name in ("x", "b", "mask")}
    wide["b"][:, 2 * W:5 * W], wide["mask"][:, 2 * W:5 * W] = b, mask
    arrays = {name: _blocks(values, device)[:, 2:5] for name, values in wide.items()}
    pcg = BatchedPCG(spot_stiffness, wp.float64, W, 3, device, preconditioner=spot_hierarchy)
    it, rel = pcg.solve(arrays["b"], arrays["x"], arrays["mask"], 1e-11, 500)
    assert np.all(rel <= 1e-11) and 0 < it < 60
    x = arrays["x"].numpy().reshape(n, 3 * W)
    ref = np.zeros_like(b)
    for j in range(3 * W):
        f = mask[:, j] > 0
        ref[f, j] = scipy.sparse.linalg.spsolve(spot_stiffness[f][:, f].tocsc(), b[f, j])
    assert np.abs(x - ref).max() <= 1e-8 * np.abs(ref).max()
