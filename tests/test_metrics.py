"""warp_regdist.metrics on inputs with known answers."""

import numpy as np
import pytest
import scipy.linalg

import warp_regdist as wrd
from meshes import icosphere
from warp_regdist.metrics import smoothness, symmetry_error, triangle_inequality_violations


def euclidean(n, seed=0):
    P = np.random.default_rng(seed).random((n, 3))
    return np.linalg.norm(P[:, None] - P[None], axis=2)


def test_symmetry_error_of_a_hand_made_matrix():
    D = np.array([[0.0, 1.0, 2.0],
                  [3.0, 0.0, 5.0],
                  [2.0, 4.0, 0.0]])
    E = symmetry_error(D, total_area=4.0)     # |D - D^T| / 2
    np.testing.assert_allclose(E, [[0.0, 1.0, 0.0],
                                   [1.0, 0.0, 0.5],
                                   [0.0, 0.5, 0.0]])


def test_symmetric_matrix_has_zero_symmetry_error():
    assert symmetry_error(euclidean(20), 1.0).max() == 0.0


def test_metric_has_no_violations():
    assert triangle_inequality_violations(euclidean(150)) == 0.0
    assert triangle_inequality_violations(euclidean(150), samples=10**5) == 0.0


def test_known_violating_count():
    # D[0, 1] = 10 exceeds D[0, y] + D[y, 1] <= 2 sqrt(3) for the n - 2 points y not in {0, 1};
    # y = 0 and y = 1 give exactly 10 + 0; every other triplet compares Euclidean distances
    # (raising D[0, 1] only enlarges right-hand sides), so it does not violate.
    n = 40
    D = euclidean(n)
    D[0, 1] = 10.0
    assert triangle_inequality_violations(D) == pytest.approx((n - 2) / n**3, rel=1e-12)
    # a tolerance above the gap removes them
    gap = 10.0 - (D[0, 2:] + D[2:, 1]).min()
    assert triangle_inequality_violations(D, tolerance=gap * 1.01) == 0.0


def test_negative_off_diagonal_count():
    # D = -1 off the diagonal, 0 on it: D[x, z] > D[x, y] + D[y, z] holds for x != z with y
    # outside {x, z} (-1 > -2): n (n - 1) (n - 2) triplets; for x == z with y != x (0 > -2):
    # n (n - 1) more; nothing else.
    n = 7
    D = np.eye(n) - 1.0
    expected = (n * (n - 1) * (n - 2) + n * (n - 1)) / n**3
    assert triangle_inequality_violations(D) == pytest.approx(expected, rel=1e-12)


def test_sampling_approximates_the_exact_share():
    rng = np.random.default_rng(1)
    D = rng.random((60, 60))                   # random non-metric: share ~ 1/6
    exact = triangle_inequality_violations(D)
    sampled = triangle_inequality_violations(D, samples=200_000, seed=3)
    se = np.sqrt(exact * (1 - exact) / 200_000)
    assert 0.1 < exact < 0.3
    assert abs(sampled - exact) < 5 * se


def test_exact_count_refused_for_large_matrices():
    with pytest.raises(ValueError, match="samples"):
        triangle_inequality_violations(np.zeros((600, 600)))
    assert triangle_inequality_violations(np.zeros((600, 600)), samples=1000) == 0.0


@pytest.mark.parametrize("bad, match", [
    (np.zeros((3, 4)), "square"),
    (np.zeros(3), "square"),
    (np.array([[0.0, np.nan], [1.0, 0.0]]), "finite"),
])
def test_bad_matrices_raise(bad, match):
    with pytest.raises(ValueError, match=match):
        symmetry_error(bad, 1.0)
    with pytest.raises(ValueError, match=match):
        triangle_inequality_violations(bad)


@pytest.mark.parametrize("kwargs", [dict(samples=0), dict(samples=2.5), dict(tolerance=-1.0)])
def test_bad_options_raise(kwargs):
    with pytest.raises(ValueError, match="expected"):
        triangle_inequality_violations(euclidean(5), **kwargs)


@pytest.mark.parametrize("area", [0.0, -1.0, np.inf, "1"])
def test_bad_area_raises(area):
    with pytest.raises(ValueError, match="total_area"):
        symmetry_error(euclidean(3), area)


@pytest.fixture(scope="module")
def sphere():
    V, F = icosphere(2)                        # 162 vertices on the unit sphere
    return V, wrd.build_operators(wrd.Mesh(V, F))


def test_smoothness_of_constant_and_eigenvectors_is_zero(sphere):
    _, ops = sphere
    _, phi = scipy.linalg.eigh(ops.stiffness.toarray(), np.diag(ops.vertex_volumes))
    assert smoothness(np.full(len(phi), 3.0), ops, k=9) < 1e-10
    # eigenvectors 1..8 (the discrete l = 1 and l = 2 harmonics) lie in the span of k = 9
    np.testing.assert_array_less(smoothness(phi[:, 1:9], ops, k=9), 1e-8)


def test_smoothness_is_the_same_by_arpack_on_a_mesh_without_symmetries(monkeypatch):
    """Above DENSE_EIGEN_VERTICES the eigenvectors come from ARPACK: the same projection to 1e-8 where
    no eigenvalue repeats (a jittered sphere), and the same number on every call."""
    from warp_regdist import metrics

    V, F = icosphere(2)
    V = V * (1.0 + 0.05 * np.random.default_rng(3).standard_normal((len(V), 1)))
    ops = wrd.build_operators(wrd.Mesh(V, F))
    fields = np.stack([V[:, 0] ** 2, np.exp(V[:, 2]), V[:, 1] * V[:, 2]], axis=1)
    dense = smoothness(fields, ops, k=12)
    monkeypatch.setattr(metrics, "DENSE_EIGEN_VERTICES", 10)
    arpack = smoothness(fields, ops, k=12)
    np.testing.assert_allclose(arpack, dense, atol=1e-8)
    assert np.array_equal(smoothness(fields, ops, k=12), arpack)
    assert dense.min() > 1e-3                  # not in the span: the comparison tests the projection


def test_smoothness_of_noise_is_large_and_of_a_coordinate_small(sphere):
    V, ops = sphere
    noise = np.random.default_rng(0).standard_normal(len(V))
    assert smoothness(noise, ops, k=9) > 0.9
    # a coordinate is a continuous l = 1 harmonic: in the span of the first 4 up to
    # discretization error
    assert smoothness(V[:, 2], ops, k=4) < 0.02


@pytest.mark.parametrize("values, k, match", [
    (np.ones(5), 4, "shape"),
    (np.full(162, np.nan), 4, "finite"),
    (np.zeros(162), 4, "zero"),
    (np.ones(162), 0, "k >= 1"),
    (np.ones(162), 162, "k < n"),
])
def test_bad_smoothness_input_raises(sphere, values, k, match):
    with pytest.raises(ValueError, match=match):
        smoothness(values, sphere[1], k=k)
    with pytest.raises(ValueError, match="Operators"):
        smoothness(np.ones(162), "not operators", k=4)
