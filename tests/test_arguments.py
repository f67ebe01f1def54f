"""The generic argument checks (warp_regdist/arguments.py) and Warp's quiet start-up."""

import os
import subprocess
import sys

import numpy as np
import pytest

from warp_regdist.arguments import check_weight, parse_device, parse_workers

CUDA_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"


def test_check_weight_accepts_finite_reals():
    assert check_weight(np.float32(0.5), "alpha_hat") == 0.5
    assert check_weight(0, "alpha_hat") == 0.0
    assert isinstance(check_weight(np.int64(3), "beta_hat"), float)


@pytest.mark.parametrize("value, positive, message", [
    (True, False, r"expected a real alpha_hat >= 0, got True"),
    ("0.1", False, r"expected a real alpha_hat >= 0, got '0.1'"),
    ([0.1], False, r"expected a real alpha_hat >= 0, got \[0.1\]"),
    (-1e-3, False, r"expected a finite alpha_hat >= 0, got -0.001"),
    (float("nan"), False, r"expected a finite alpha_hat >= 0, got nan"),
    (float("inf"), False, r"expected a finite alpha_hat >= 0, got inf"),
    (0.0, True, r"expected a finite alpha_hat > 0, got 0.0"),
])
def test_check_weight_refuses(value, positive, message):
    with pytest.raises(ValueError, match=message):
        check_weight(value, "alpha_hat", positive=positive)


def test_parse_workers():
    assert parse_workers(3) == 3 and parse_workers(np.int32(2)) == 2
    assert parse_workers(None) >= 1
    for bad in (0, -2, 1.5, True, "2"):
        with pytest.raises(ValueError, match=r"expected workers as an integer >= 1 or None, got "):
            parse_workers(bad)


def test_parse_device():
    assert parse_device("cpu").is_cpu
    with pytest.raises(ValueError, match=r"expected a Warp device among \[.*'cpu'.*\], got 'tpu:7'"):
        parse_device("tpu:7")


_TINY_SOLVE = """
import numpy as np, warp_regdist as wrd
V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]); F = np.array([[0, 1, 3], [0, 3, 2]])
print(wrd.DistanceSolver(wrd.Mesh(V, F), 0.0, device="cpu").solve([0]).distance[3])
"""


@pytest.mark.skipif(sys.platform != "linux", reason="the driver probe of Warp's start-up is Linux's libcuda.so")
def test_a_cpu_solve_prints_no_cuda_driver_warning():
    import warp as wp

    wp.init()
    if wp.is_cuda_available():
        pytest.skip("a CUDA driver is installed: Warp prints no driver warning")
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    done = subprocess.run([sys.executable, "-c", _TINY_SOLVE], capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr
    assert 1.0 < float(done.stdout.split()[-1]) <= np.sqrt(2.0) + 1e-6  # at most the diagonal's length
    assert CUDA_DRIVER_WARNING not in done.stderr
    # asking for CUDA: Warp's explanation of why there is none is the error's reason, and nothing else is printed
    asked = subprocess.run([sys.executable, "-c", "from warp_regdist.arguments import parse_device\n"
                            "try:\n    parse_device('cuda')\nexcept ValueError as e:\n    print(e)"],
                           capture_output=True, text=True, env=env, timeout=600)
    assert asked.stderr == ""
    assert asked.stdout == f"expected a Warp device among ['cpu'], got 'cuda' (Warp: {CUDA_DRIVER_WARNING})\n"
