"""The second run of a solve in a fresh process must load every Warp module from the kernel cache."""

import os
import subprocess
import sys

SCRIPT = """
import warp as wp
import warp_regdist as wrd
wp.config.log_level = wp.LOG_INFO  # warp_regdist turns Warp's module-load lines off
import trimesh
s = trimesh.creation.icosphere(1)
solver = wrd.DistanceSolver(wrd.Mesh(s.vertices, s.faces), alpha_hat=0.1, device="cpu")
solver.solve([0]); solver.solve_many([[0], [3]])
"""


def test_second_run_does_not_recompile(tmp_path):
    env = dict(os.environ, WARP_CACHE_PATH=str(tmp_path / "cache"))
    runs = [subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600)
            for _ in range(2)]
    for run in runs:
        assert run.returncode == 0, run.stderr[-2000:]
    first, second = (run.stdout + run.stderr for run in runs)
    assert "(compiled)" in first
    assert "(cached)" in second
    assert "(compiled)" not in second, second
