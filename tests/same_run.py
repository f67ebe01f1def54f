"""Comparisons of two runs that must be the same run: bit for bit on the CPU, to rounding on CUDA.

On the CPU a launch runs its threads in order on one core, so every sum over rows adds in a
fixed order and two runs of one problem (another batch, worker count, check interval or
graph) give the same bits. On CUDA the per-row partial sums meet in atomic adds in the order
the threads arrive, so two runs agree to rounding only, and a stopping test sitting on its
threshold can take one iteration more. Measured on an H200 on the spot mesh, in units of the
largest value: 1e-11 in float64 and 1e-5 in float32 after a few dozen PCG iterations, 3e-9
after 120-160 ADMM iterations in float64 (a column compacted with another column's CG
tolerance differs by 1e-6).
"""

import numpy as np

ROUNDING = {"float64": 5e-8, "float32": 1e-4}
"""Largest difference between two CUDA runs of one problem, in units of the largest value."""


def on_cuda(device):
    """Whether ``device`` ("cpu", "cuda", "cuda:1", ...) is a CUDA device."""
    return str(device).startswith("cuda")


def assert_same_run(actual, desired, device, dtype="float64"):
    """Equal on the CPU; within ROUNDING[dtype] max |desired| on CUDA."""
    actual, desired = np.asarray(actual), np.asarray(desired)
    if on_cuda(device):
        np.testing.assert_allclose(actual, desired, rtol=0, atol=ROUNDING[dtype] * np.abs(desired).max())
    else:
        np.testing.assert_array_equal(actual, desired)


def same_count(a, b, device):
    """Iteration counts of the same run: equal on the CPU, within one on CUDA."""
    return abs(int(a) - int(b)) <= 1 if on_cuda(device) else a == b
