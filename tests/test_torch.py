"""warp_regdist.torch: distances as a torch.autograd.Function (skipped where PyTorch is not installed)."""

import numpy as np
import pytest

import meshes
import warp_regdist as wrd

torch = pytest.importorskip("torch")


def small_mesh():
    """A 6 x 6 grid of the unit square, jittered in the plane and lifted a little (36 vertices)."""
    V, F = meshes.square_grid(6)[:2]
    rng = np.random.default_rng(4)
    V = V + rng.uniform(-0.03, 0.03, V.shape) * np.array([1.0, 1.0, 0.0])
    V[:, 2] = 0.05 * np.sin(3 * V[:, 0]) * np.cos(2 * V[:, 1])
    return V, F


def test_gradcheck_positions_and_alpha_hat():
    V, F = small_mesh()
    x = torch.tensor(V, dtype=torch.float64, requires_grad=True)
    a = torch.tensor(0.1, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x, a: wrd.torch.distance(x, F, [0], a), (x, a), eps=1e-6, atol=1e-6,
                                    rtol=1e-4, fast_mode=False)


def test_value_and_gradient_are_the_smoothed_problems():
    """The value is vjp's smoothed distance and the backward pass vjp's gradients."""
    V, F = small_mesh()
    b = np.random.default_rng(0).random(len(V))
    res = wrd.DistanceSolver(wrd.Mesh(V, F), 0.1, workers=1).solve([0, 20])
    g = res.vjp(b)
    x = torch.tensor(V, dtype=torch.float64, requires_grad=True)
    a = torch.tensor(0.1, dtype=torch.float64, requires_grad=True)
    u = wrd.torch.distance(x, torch.as_tensor(F), [0, 20], a)
    np.testing.assert_allclose(u.detach().numpy(), g.smoothed_distance, rtol=1e-9, atol=1e-12)
    (u * torch.as_tensor(b)).sum().backward()
    np.testing.assert_allclose(x.grad.numpy(), g.vertices, rtol=1e-6, atol=1e-9)
    assert a.grad.item() == pytest.approx(g.alpha_hat, rel=1e-6)


def test_refusals():
    V, F = small_mesh()
    with pytest.raises(ValueError, match=r"expected vertices as a floating-point torch.Tensor of shape \(n, 3\), got \(49, 2\)"):
        wrd.torch.distance(torch.zeros(49, 2, dtype=torch.float64), F, [0])
    with pytest.raises(ValueError, match=r"expected vertices as a floating-point torch.Tensor of shape \(n, 3\), got \(49, 3\)"):
        wrd.torch.distance(torch.zeros(49, 3, dtype=torch.int64), F, [0])
    with pytest.raises(ValueError, match="expected alpha_hat as a float or a one-element tensor, got shape \\(2,\\)"):
        wrd.torch.distance(torch.tensor(V), F, [0], torch.ones(2))
    with pytest.raises(ValueError, match="expected a converged solve to differentiate, got one stopped after 3"):
        wrd.torch.distance(torch.tensor(V), F, [0], options=wrd.SolverOptions(max_iterations=3))
