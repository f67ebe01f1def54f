"""The eigenbasis engine of AllPairsSolver (warp_regdist/solvers/all_pairs/eigenbasis.py).

References: the interior-point minimizers of tests/data/all_pairs_bumpy42.npz (cvxpy + Clarabel on the
full problem, tests/all_pairs_reference.py), the U-step's own equation with dense numpy operators,
and the diagonal's response summed term by term over pairs of eigenvectors.
"""

import functools
import os
import warnings

import numpy as np
import pytest

import warp_regdist as wrd
from warp_regdist.cli import allpairs as cli_allpairs
from warp_regdist.solvers.all_pairs.eigenbasis import EigenbasisUStep, diagonal_response

DATA = os.path.join(os.path.dirname(__file__), "data", "all_pairs_bumpy42.npz")


@pytest.fixture(scope="module")
def bumpy42():
    d = np.load(DATA)
    return wrd.Mesh(d["vertices"], d["faces"]), {0.03: d["U_003"], 0.1: d["U_01"]}


def _quiet(mesh, alpha_hat, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        return wrd.all_pairs(mesh, alpha_hat, **kwargs)


def test_diagonal_response_is_the_sum_over_eigenvector_pairs(bumpy42):
    mesh, _ = bumpy42
    ops = wrd.build_operators(mesh)
    s = 1 / np.sqrt(ops.vertex_volumes)
    lam, Phi = np.linalg.eigh(s[:, None] * ops.stiffness.toarray() * s[None, :])
    lam[0] = 0.0
    d = lam[:, None] + lam[None, :]
    exact = np.einsum("ip,kp,iq,kq,pq->ik", Phi, Phi, Phi, Phi, np.where(d > 0, 1 / np.where(d > 0, d, 1), 0))
    assert np.abs(diagonal_response(Phi, lam) - exact).max() <= 1e-9 * np.abs(exact).max()


@pytest.mark.parametrize("dtype, tol", [("float64", 1e-9), ("float32", 5e-6)])
def test_u_step_solves_its_equation_off_the_diagonal(bumpy42, dtype, tol):
    """scale (W U M + M U W) - R is diagonal (the multipliers of diag(U) = 0), U is symmetric to the
    last bit with a zero diagonal."""
    mesh, _ = bumpy42
    ops = wrd.build_operators(mesh)
    W, a = ops.stiffness.toarray(), ops.vertex_volumes
    R = np.random.default_rng(0).standard_normal((mesh.n_vertices,) * 2)
    R += R.T
    U = EigenbasisUStep(ops.stiffness, a, dtype)(R, 2.5).astype(np.float64)
    E = 2.5 * (W @ U * a[None, :] + a[:, None] * U @ W) - R
    np.fill_diagonal(E, 0)
    assert np.abs(E).max() <= tol * np.abs(R).max()
    assert np.array_equal(U, U.T) and np.all(np.diag(U) == 0)


@pytest.mark.parametrize("alpha_hat", [0.03, 0.1])
def test_matches_conic_reference(bumpy42, alpha_hat):
    mesh, refs = bumpy42
    res = wrd.all_pairs(mesh, alpha_hat, device="cpu", engine="eigenbasis", accuracy=0.0005)
    expected = refs[alpha_hat]
    assert res.converged and res.cg_iterations == 0
    assert np.abs(res.distance - expected).max() <= 1e-3 * expected.max()


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_defaults_within_their_accuracy_symmetric_by_construction(bumpy42, dtype):
    mesh, refs = bumpy42
    res = wrd.all_pairs(mesh, 0.03, device="cpu", dtype=dtype, engine="eigenbasis", accuracy=0.01)
    U = res.distance
    assert res.converged and res.iterations == len(res.history)
    assert np.array_equal(U, U.T) and np.all(np.diag(U) == 0) and U.min() >= 0
    assert np.abs(U - refs[0.03]).max() <= 0.01 * refs[0.03].max()
    assert np.all(res.residuals <= res.tolerance)


def test_auto_takes_eigenbasis_on_small_meshes_on_the_cpu(bumpy42):
    mesh, _ = bumpy42
    solver = wrd.AllPairsSolver(mesh, 0.03, device="cpu")
    assert solver.engine(solver.options) == "eigenbasis"
    assert solver.engine(solver.options.replace(engine="consensus")) == "consensus"


def test_auto_takes_consensus_above_the_eigenbasis_bound(bumpy42):
    mesh, _ = bumpy42
    assert wrd.AllPairsOptions().eigenbasis_max_vertices == 3000
    assert "auto: eigenbasis on the CPU up to 3,000 vertices" in open(cli_allpairs.__file__).read()  # --help says it
    options = wrd.AllPairsOptions(eigenbasis_max_vertices=mesh.n_vertices - 1)
    solver = wrd.AllPairsSolver(mesh, 0.03, device="cpu", options=options)
    assert solver.engine(solver.options) == "consensus"
    # accuracy sets the tolerances and keeps every other field of the solver's options, this one too
    assert solver.engine(solver.options.at_accuracy(0.01)) == "consensus"
    assert solver.options.at_accuracy(0.01).eps_change == wrd.AllPairsOptions.for_accuracy(0.01).eps_change
    with pytest.raises(ValueError, match=r"expected eigenbasis_max_vertices as an integer"):
        wrd.AllPairsOptions(eigenbasis_max_vertices=1.5)


def test_engine_must_be_named(bumpy42):
    with pytest.raises(ValueError, match="expected engine as one of 'auto', 'eigenbasis', 'consensus', got 'dense'"):
        wrd.AllPairsOptions(engine="dense")


def test_resume_gives_the_uninterrupted_matrix(bumpy42, tmp_path):
    mesh, _ = bumpy42
    path = tmp_path / "run.npz"
    whole = _quiet(mesh, 0.03, device="cpu", engine="eigenbasis", max_iterations=120)
    part = _quiet(mesh, 0.03, device="cpu", engine="eigenbasis", max_iterations=70, checkpoint=path)
    assert not part.converged and part.checkpoint_iteration == 70
    rest = _quiet(mesh, 0.03, device="cpu", engine="eigenbasis", max_iterations=120, checkpoint=path, resume=path)
    assert rest.iterations == whole.iterations
    assert np.array_equal(rest.distance, whole.distance)


def test_a_checkpoint_of_the_other_engine_is_refused(bumpy42, tmp_path):
    mesh, _ = bumpy42
    path = tmp_path / "run.npz"
    _quiet(mesh, 0.03, device="cpu", engine="consensus", max_iterations=10, checkpoint=path)
    with pytest.raises(ValueError, match=r"expected a checkpoint of this problem \(engine 'eigenbasis'\), got one of "
                                         r"another problem \(engine 'consensus'\)"):
        wrd.all_pairs(mesh, 0.03, device="cpu", engine="eigenbasis", resume=path)


def test_warm_start_from_a_consensus_run_reaches_the_minimizer(bumpy42, tmp_path):
    mesh, refs = bumpy42
    path = tmp_path / "run.npz"
    _quiet(mesh, 0.1, device="cpu", engine="consensus", max_iterations=100, checkpoint=path)
    res = wrd.all_pairs(mesh, 0.03, device="cpu", engine="eigenbasis", initial=path, accuracy=0.002)
    assert res.converged
    assert np.abs(res.distance - refs[0.03]).max() <= 0.002 * refs[0.03].max()


def test_cli_engine(bumpy42, tmp_path, capsys):
    from warp_regdist.cli import main

    mesh, refs = bumpy42
    path, out = tmp_path / "bumpy.off", tmp_path / "U.npy"
    with open(path, "w") as f:
        f.write(f"OFF\n{mesh.n_vertices} {mesh.n_elements} 0\n")
        f.writelines(f"{x!r} {y!r} {z!r}\n" for x, y, z in np.asarray(mesh.vertices).tolist())
        f.writelines(f"3 {a} {b} {c}\n" for a, b, c in np.asarray(mesh.elements))
    for engine in ("auto", "consensus"):
        assert main(["allpairs", str(path), "--output", str(out), "--device", "cpu", "--engine", engine]) == 0
        assert np.abs(np.load(out) - refs[0.03]).max() <= 0.005 * refs[0.03].max()
        shown = "eigenbasis" if engine == "auto" else engine
        assert f"ADMM iterations ({shown} engine)" in capsys.readouterr().out
    assert main(["allpairs", str(path), "--output", str(out), "--engine", "dense"]) == 2
    assert "argument --engine: invalid choice: 'dense'" in capsys.readouterr().err


def test_interrupt_returns_the_iterate_and_resumes_to_the_uninterrupted_matrix(bumpy42, tmp_path):
    import signal

    mesh, _ = bumpy42
    whole = _quiet(mesh, 0.05, device="cpu", engine="eigenbasis", max_iterations=30)
    path = tmp_path / "run.npz"

    def ctrl_c(progress):
        if progress.iteration == 8:
            os.kill(os.getpid(), signal.SIGINT)

    cut = wrd.all_pairs(mesh, 0.05, device="cpu", engine="eigenbasis", max_iterations=30, checkpoint=path,
                        callback=ctrl_c)
    assert cut.interrupted and not cut.converged and cut.iterations == 9 and cut.engine == "eigenbasis"
    assert np.array_equal(cut.distance, cut.distance.T) and cut.distance.max() > 0
    rest = _quiet(mesh, 0.05, device="cpu", engine="eigenbasis", max_iterations=30, resume=path)
    assert not rest.interrupted and np.array_equal(rest.distance, whole.distance)



def test_the_steepness_test_measures_the_matrix_returned(bumpy42, run_states):
    """The eigenbasis engine's U-step does not clip U at 0; the steepness test measures max(U, 0), what a
    result returns, not the iterate: with entries below 0 beside the diagonal the two differ."""
    from warp_regdist.solvers.common.stopping import gradient_excess

    mesh, _ = bumpy42
    _quiet(mesh, 0.05, device="cpu", engine="eigenbasis", max_iterations=60)
    state = run_states[0]
    n, nb, W = state.n, state.setup.nb, state.setup.W
    U = state.view("U").reshape(n, -1)[:, :n].astype(np.float64)
    ring = np.unique(mesh.elements[(mesh.elements == 0).any(axis=1)])
    U[0, ring[ring > 0]] = U[ring[ring > 0], 0] = -0.2 * U.max()
    lanes = np.zeros((n, nb * W))
    lanes[:, :n] = U
    state.put("U", lanes.reshape(n, nb, W).astype(state.view("U").dtype))
    excess = functools.partial(gradient_excess, state.setup.constraints, state.setup.operators.diameters)
    clipped, raw = excess(np.maximum(U, 0)), excess(U)
    assert state.gradient_excess(float(U.max())) == pytest.approx(clipped, rel=1e-5)
    assert abs(clipped - raw) > 0.1 * max(clipped, raw)
