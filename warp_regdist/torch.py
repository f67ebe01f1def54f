"""PyTorch autograd for regularized distances (the ``[torch]`` extra; docs/guides/gradients.md).

``distance(vertices, faces, sources, alpha_hat)`` is a ``torch.autograd.Function``: its value is
the barrier-smoothed minimizer u_mu (docs/method.md section 10), found by Newton's method from the
ADMM's solve, and its backward pass the adjoint of that same problem, so that value and gradient
belong to one smooth function (``torch.autograd.gradcheck`` holds). The mesh is built on the host
from the tensors (a copy); the ADMM runs on the tensors' device when Warp has it (CUDA), the
Newton and adjoint solves on the host.
"""

from __future__ import annotations

import warnings

import numpy as np

try:
    import torch
except ImportError as exc:  # the [torch] extra
    raise ImportError("warp_regdist.torch needs PyTorch: pip install 'warp-regdist[torch]' (or torch from "
                      "pytorch.org)") from exc

from .errors import ConvergenceWarning
from .geometry.mesh import Mesh
from .solvers.single_source.gradients import adjoint_gradients, smoothed_solution
from .solvers.single_source.solver import DistanceSolver

__all__ = ["distance"]


def _warp_device(tensor):
    """The Warp device of a tensor's device: 'cuda:i' for CUDA tensors when Warp sees a GPU, else 'cpu'."""
    import warp as wp

    if tensor.is_cuda and wp.is_cuda_available():
        return f"cuda:{tensor.device.index or 0}"
    return "cpu"


class _Distance(torch.autograd.Function):
    @staticmethod
    def forward(ctx, vertices, alpha_hat, faces, sources, options):
        mesh = Mesh(vertices.detach().cpu().numpy().astype(np.float64), faces)
        solver = DistanceSolver(mesh, float(alpha_hat), device=_warp_device(vertices), workers=1, options=options)
        with warnings.catch_warnings():  # a solve that does not converge raises below instead
            warnings.simplefilter("ignore", ConvergenceWarning)
            res = solver.solve(sources)
        if not res.converged:
            raise ValueError(f"expected a converged solve to differentiate, got one stopped after {res.iterations} "
                             "ADMM iterations")
        ctx.problem = solver.smoothing_problem()
        ctx.solution = smoothed_solution(ctx.problem, res.distance, sources)
        return torch.as_tensor(ctx.solution.distance, dtype=vertices.dtype, device=vertices.device)

    @staticmethod
    def backward(ctx, grad):
        b = np.nan_to_num(grad.detach().cpu().numpy().astype(np.float64))
        dx, da = adjoint_gradients(ctx.problem, ctx.solution, b)
        dv = torch.as_tensor(dx, dtype=grad.dtype, device=grad.device) if ctx.needs_input_grad[0] else None
        dalpha = torch.tensor(da, dtype=grad.dtype, device=grad.device) if ctx.needs_input_grad[1] else None
        return dv, dalpha, None, None, None


def distance(vertices, faces, sources, alpha_hat=0.05, options=None):
    """Regularized distance (n,) from vertex ``sources``, differentiable with respect to ``vertices``
    and ``alpha_hat``.

    Parameters
    ----------
    vertices : (n, 3) torch.Tensor, floating point (float64 for gradcheck), CPU or CUDA
    faces : (m, 3) or (m, 4) integer array or tensor (triangles or tetrahedra)
    sources : list of vertex indices
    alpha_hat : float or 0-d torch.Tensor (differentiable when it requires grad)
    options : SolverOptions or None
        The solve's settings (``gradient_smoothing`` among them); None: the defaults.

    Returns
    -------
    (n,) torch.Tensor on ``vertices``' device and dtype: u_mu, +inf where no source reaches.

    Raises ValueError for a tensor of another shape or dtype, a bad mesh or sources (as
    :class:`~warp_regdist.DistanceSolver` does), or a solve that does not converge.
    """
    if not isinstance(vertices, torch.Tensor) or vertices.ndim != 2 or vertices.shape[1] != 3 \
            or not vertices.is_floating_point():
        shape = tuple(vertices.shape) if hasattr(vertices, "shape") else type(vertices).__name__
        raise ValueError(f"expected vertices as a floating-point torch.Tensor of shape (n, 3), got {shape}")
    if isinstance(faces, torch.Tensor):
        faces = faces.detach().cpu().numpy()
    if not isinstance(alpha_hat, torch.Tensor):
        alpha_hat = torch.tensor(float(alpha_hat), dtype=vertices.dtype)
    elif alpha_hat.numel() != 1:
        raise ValueError(f"expected alpha_hat as a float or a one-element tensor, got shape {tuple(alpha_hat.shape)}")
    return _Distance.apply(vertices, alpha_hat.reshape(()), np.asarray(faces), list(sources), options)
