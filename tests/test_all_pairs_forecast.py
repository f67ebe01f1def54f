"""What an all-pairs run is told before it starts (typical iterations, the default cap) and while it runs
(not settling): warp_regdist.solvers.all_pairs.forecast; and what the run needs of either engine (PairsEngine)."""

import csv
import os
import warnings

import numpy as np
import pytest

import meshes
import warp_regdist as wrd
from warp_regdist.solvers.all_pairs.forecast import (MEASURED_ITERATIONS, STALL_CHECKS, ChangeTrend, default_cap,
                                                     typical_iterations)

SIZES = os.path.join(os.path.dirname(__file__), "..", "docs", "data", "all_pairs_sizes.csv")


def test_the_measured_iterations_are_the_published_table():
    """The forecast's table is docs/data/all_pairs_sizes.csv (accuracy 0.01): republishing the table
    without updating the forecast fails here."""
    with open(SIZES, newline="") as f:
        rows = [row for row in csv.DictReader(f) if float(row["accuracy"]) == 0.01]
    assert [(int(r["vertices"]), int(r["iterations"])) for r in rows] == list(MEASURED_ITERATIONS)


def test_typical_iterations_pass_through_the_table_and_scale_with_the_accuracy():
    for n, iterations in MEASURED_ITERATIONS:
        assert typical_iterations(n, 0.01) == iterations
    assert typical_iterations(100, 0.01) == 1100                      # below the table: its first row
    assert typical_iterations(1949, 0.0025) == 5200                   # sqrt(0.01 / 0.0025) = 2
    middle = typical_iterations(int(np.sqrt(600 * 999)), 0.01)        # halfway in log n
    assert middle == 50 * round(np.sqrt(1750 * 2300) / 50)
    beyond = typical_iterations(3898, 0.01)                           # the last segment's slope, one more doubling
    assert beyond == 50 * round(2600 * (2600 / 2300) ** (np.log(2) / np.log(1949 / 999)) / 50)


def test_the_default_cap_is_twice_the_typical_run_and_at_least_3000():
    assert default_cap(300, 0.01) == 3000
    assert default_cap(1949, 0.01) == 5200
    assert default_cap(1949, 0.005) == 2 * typical_iterations(1949, 0.005) == 7400


def _trend(changes, window=50):
    trend = ChangeTrend()
    for j, c in enumerate(changes):
        trend.add(window * (j + 1), c)
    return trend


def test_a_change_that_goes_up_and_down_but_reaches_new_lows_is_settling():
    """The checks of a 298-vertex cat at accuracy 0.01 (it converged at the next check): 11 checks without a
    new low after 0.0138 at iteration 950, beyond a third of its 1,500."""
    cat = [np.inf, np.inf, 0.0579, 0.266, 0.0665, 0.156, 0.0546, 0.0366, 0.0549, 0.0471, 0.0285, 0.0592, 0.0587,
           0.0411, 0.0261, 0.0312, 0.0265, 0.0204, 0.0138, 0.0231, 0.0277, 0.0277, 0.0234, 0.0234, 0.0339, 0.042,
           0.042, 0.0393, 0.0289, 0.0148]
    assert not _trend(cat).stalled()
    assert _trend(cat).lowest() == (950, 0.0138)
    assert _trend(cat + [0.02] * 30).stalled()               # the low at 950, a third of the way to 3,000


def test_a_change_whose_low_lies_in_the_first_third_of_the_run_is_stalled():
    """Lowest at the 2nd check (iteration 100), then up and down above it: stalled from the 10th check (8
    checks without a new low, 100 within the first third of 500), and until a new low."""
    trend, flags = ChangeTrend(), []
    for j, c in enumerate([0.05, 0.03] + [0.04, 0.06] * 20):
        trend.add(50 * (j + 1), c)
        flags.append(trend.stalled())
    assert flags.index(True) == 2 + STALL_CHECKS - 1 and all(flags[9:])
    trend.add(50 * 43, 0.02)
    assert not trend.stalled() and trend.lowest() == (2150, 0.02)


def test_the_forecast_says_the_engine_memory_typical_iterations_and_cap_before_the_run():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        solver = wrd.AllPairsSolver(wrd.Mesh(*meshes.icosphere(2, 1.0)), dtype="float32")
    forecast = solver.forecast(accuracy=0.01)
    assert (forecast.vertices, forecast.engine, forecast.iterations, forecast.max_iterations) == (162, "eigenbasis",
                                                                                                1100, 3000)
    assert forecast.accuracy == pytest.approx(0.01) and forecast.memory_bytes == solver.memory_bytes
    assert str(forecast).startswith("162 vertices, eigenbasis engine, about 0.00 GB; typically 1100 iterations at this "
                                    "size and accuracy 0.01 (cap 3000)")
    assert solver.forecast(max_iterations=40, engine="consensus").max_iterations == 40
    assert solver.forecast(engine="consensus").engine == "consensus"


@pytest.mark.parametrize("engine", ["eigenbasis", "consensus"])
def test_both_engines_states_are_pairs_engines(engine, run_states):
    from warp_regdist.solvers.all_pairs.engine import PairsEngine

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wrd.all_pairs(wrd.Mesh(*meshes.icosphere(1, 1.0)), device="cpu", workers=1, engine=engine, max_iterations=2)
    assert len(run_states) == 1 and isinstance(run_states[0], PairsEngine) and run_states[0].engine == engine
