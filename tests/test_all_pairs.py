"""All-pairs distance matrices (Algorithm 2) and the batched single-source alternative.

References: an interior-point solve of the all-pairs problem (tests/all_pairs_reference.py,
cvxpy + Clarabel, full problem with row and column constraints, not symmetrized) stored in
tests/data/all_pairs_bumpy42.npz (a perturbed 42-vertex icosphere, alpha_hat 0.03 and 0.1);
a dense numpy transcription of the full ADMM of docs/method.md section 5 (all nine variables) for the
claim that the symmetric half-state ADMM reproduces it iterate by iteration.
"""

import math
import os
import warnings

import numpy as np
import pytest

import meshes
import reference_solver as rs
import warp_regdist as wrd
import warp_regdist.solvers.all_pairs.state as all_pairs_state
import warp_regdist.solvers.all_pairs.memory as memory
from warp_regdist.cli import main
from warp_regdist.metrics import triangle_inequality_violations


DATA = os.path.join(os.path.dirname(__file__), "data", "all_pairs_bumpy42.npz")
TIGHT = dict(eps_rel=2e-6, eps_rel_consensus=2e-7, eps_rel_dual=2e-4, cg_fraction=1e-8, max_iterations=10_000)


@pytest.fixture(scope="module")
def bumpy42():
    d = np.load(DATA)
    return wrd.Mesh(d["vertices"], d["faces"]), {0.03: d["U_003"], 0.1: d["U_01"]}


@pytest.mark.parametrize("alpha_hat", [0.03, 0.1])
def test_matches_conic_reference(bumpy42, alpha_hat, device):
    mesh, refs = bumpy42
    expected = refs[alpha_hat]
    res = wrd.all_pairs(mesh, alpha_hat, device=device, **TIGHT)
    assert res.converged
    assert np.abs(res.distance - expected).max() <= 1e-3 * expected.max()


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_defaults_within_one_percent_symmetric_by_construction(bumpy42, dtype, device):
    mesh, refs = bumpy42
    res = wrd.all_pairs(mesh, 0.03, device=device, dtype=dtype)
    U = res.distance
    assert res.converged and res.iterations == len(res.history)
    assert np.array_equal(U, U.T) and np.all(np.diag(U) == 0) and U.min() >= 0
    assert np.abs(U - refs[0.03]).max() <= 0.01 * refs[0.03].max()
    assert np.all(res.residuals <= res.tolerance)


def test_result_breaking_the_gradient_bound_is_not_converged(bumpy42, tmp_path):
    """A result whose residual tests held but whose |grad U| relative to its bound (1, or on column j's
    triangles at vertex j the wedge u_a <= l_ja) exceeds max_gradient is reported as not converged, with
    that ratio in the warning; a converged checkpoint resumed is checked the same way."""
    from warp_regdist.solvers.common.source_triangles import SourceTriangles

    mesh, _ = bumpy42
    ops = wrd.build_operators(mesh)
    res = wrd.all_pairs(mesh, 0.1, checkpoint=tmp_path / "run.npz")
    plain = np.linalg.norm((ops.grad @ res.distance).reshape(mesh.n_elements, 3, -1), axis=1).max()
    steepest = SourceTriangles(ops, "edges").max_gauge(res.distance, None).max()
    assert plain > 1.1 and res.converged and 1.0 < steepest <= 1.02   # the wedges are steeper than 1 by design
    with pytest.warns(wrd.ConvergenceWarning, match=rf"relative to its bound {steepest:.3g}, above max_gradient = 1\)"):
        flagged = wrd.all_pairs(mesh, 0.1, max_gradient=1.0)
    assert not flagged.converged and np.array_equal(flagged.distance, res.distance)
    with pytest.warns(wrd.ConvergenceWarning, match="although its residual tests held: not converged"):
        assert not wrd.all_pairs(mesh, 0.1, resume=tmp_path / "run.npz", max_gradient=1.0).converged


def test_large_alpha_without_active_constraints_converges(bumpy42, device):
    # alpha_hat 2: |grad| < 1 almost everywhere, so Y (and the dual residual's scale |D Y|)
    # nearly vanish; measured against |D Y| alone the dual test never held (3000 iterations)
    mesh, _ = bumpy42
    res = wrd.all_pairs(mesh, 2.0, device=device)
    assert res.converged and res.iterations < 300, res.iterations
    U = res.distance
    assert np.array_equal(U, U.T) and U.max() > 0


def test_worker_processes_give_the_same_matrix():
    # 642 vertices: two processes share the columns of every step and the consensus tiles
    V, F = meshes.icosphere(3, 1.0)
    mesh = wrd.Mesh(meshes.perturbed(V, F, 0.05, seed=2), F)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        one = wrd.all_pairs(mesh, 0.03, dtype="float32", max_iterations=25, workers=1, device="cpu", engine="consensus")
        two = wrd.all_pairs(mesh, 0.03, dtype="float32", max_iterations=25, workers=2, device="cpu", engine="consensus")
    assert np.array_equal(one.distance, two.distance) and one.distance.max() > 0
    # every residual is summed per column or per consensus tile row: the split changes no bit
    assert np.array_equal(one.history, two.history)
    with pytest.raises(ValueError, match="expected workers as an integer >= 1 or None"):
        wrd.all_pairs(mesh, workers=0)


def _full_admm(V, F, alpha_hat, iterations):
    """docs/method.md section 5 verbatim on dense arrays (X, R, U, Z, Q, Y, S, H, K), exact linear solves."""
    tol = wrd.AllPairsOptions().for_engine("consensus")
    a_f, _ = rs.face_geometry(V, F)
    G = rs.gradient_matrices(V, F)
    A_V = rs.vertex_areas(V, F)
    A, n = a_f.sum(), len(V)
    L = np.sqrt(A)
    alpha = alpha_hat * L
    Wd = sum(Gc.T @ (a_f[:, None] * Gc.toarray()) for Gc in G)
    M = np.diag(A_V)

    def grad(X):
        return np.stack([Gc @ X for Gc in G])  # (3, m, n)

    def div(Y):
        return sum(Gc.T @ (a_f[:, None] * Yc) for Gc, Yc in zip(G, Y))

    def proj(P):
        """The unit ball per face and column, and on face f at vertex j = F[f, c] (column j's source) the
        wedge n_a . g <= 1 for the unit sides n_a from j: the nearest of v, its foot on either side's
        line and the apex that meets both bounds."""
        out = P / np.maximum(1.0, np.linalg.norm(P, axis=0))
        for f in range(len(F)):
            for c in range(3):
                j = F[f, c]
                n = [(V[F[f, (c + s) % 3]] - V[j]) / np.linalg.norm(V[F[f, (c + s) % 3]] - V[j]) for s in (1, 2)]
                v = P[:, f, j]
                apex = np.linalg.lstsq(np.array(n), np.ones(2), rcond=None)[0]
                feet = [v - (n[k] @ v - 1.0) * n[k] for k in range(2)]
                feasible = [p for p in [v, *feet, apex] if all(nk @ p <= 1.0 + 1e-12 for nk in n)]
                out[:, f, j] = min(feasible, key=lambda p: np.linalg.norm(p - v))
        return out

    def dirichlet_solve(K2, B):
        """Column j of the result solves K2 x = B[:, j] on the rows other than j, with x_j = 0."""
        X = np.zeros_like(B)
        for j in range(n):
            free = np.arange(n) != j
            X[free, j] = np.linalg.solve(K2[np.ix_(free, free)], B[free, j])
        return X

    X, R, U, H, K = (np.zeros((n, n)) for _ in range(5))
    Z, Q, Y, S = (np.zeros((3, len(F), n)) for _ in range(4))
    a = tol.relaxation
    for k in range(iterations):
        rho = L * min(tol.rho_max, tol.rho0 * 2.0 ** (k / tol.rho_doubling))
        rho2 = 25.0 * rho * rho / (L * A)
        K2 = (alpha + rho) * Wd + rho2 * M
        b = 0.5 * A_V[:, None] * np.ones(n)
        X = dirichlet_solve(K2, b - div(Y) + rho * div(Z) - M @ H + rho2 * M @ U)
        R = dirichlet_solve(K2, b - div(S) + rho * div(Q) - M @ K + rho2 * M @ U.T)
        hX, hR = a * grad(X) + (1 - a) * Z, a * grad(R) + (1 - a) * Q
        Z, Q = proj(Y / rho + hX), proj(S / rho + hR)
        Y, S = Y + rho * (hX - Z), S + rho * (hR - Q)
        Xh, Rh = a * X + (1 - a) * U, a * R + (1 - a) * U.T
        U = np.maximum(0.0, 0.5 * ((H + K.T) / rho2 + Xh + Rh.T))
        np.fill_diagonal(U, 0.0)
        H, K = H + rho2 * (Xh - U), K + rho2 * (Rh - U.T)
    return U


def test_x_step_holds_each_columns_own_entry_at_zero(bumpy42, tmp_path):
    # X[j, j] = 0 in every iterate, also after resuming from a file whose X has a diagonal
    mesh, _ = bumpy42
    n, path = mesh.n_vertices, tmp_path / "run.npz"

    def x_of(file):
        with np.load(file) as d:
            return d["X"].reshape(n, -1)[:, :n]

    with pytest.warns(wrd.ConvergenceWarning):
        wrd.all_pairs(mesh, 0.03, max_iterations=30, checkpoint=path)
    X = x_of(path)
    assert np.all(np.diag(X) == 0) and X.max() > 0.1
    with np.load(path) as d:
        state = dict(d)
    j = np.arange(n)
    state["X"][j, j // state["X"].shape[2], j % state["X"].shape[2]] = 0.5
    np.savez(tmp_path / "diagonal.npz", **state)
    with pytest.warns(wrd.ConvergenceWarning):
        wrd.all_pairs(mesh, 0.03, max_iterations=40, resume=tmp_path / "diagonal.npz", checkpoint=tmp_path / "more.npz")
    assert np.all(np.diag(x_of(tmp_path / "more.npz")) == 0)


def test_half_state_admm_reproduces_full_admm(device):
    V, F = meshes.icosphere(1, 1.0)
    V = meshes.perturbed(V, F, 0.1, seed=5)
    expected = _full_admm(V, F, 0.05, 40)
    with pytest.warns(wrd.ConvergenceWarning):
        res = wrd.all_pairs(wrd.Mesh(V, F), 0.05, device=device, max_iterations=40, cg_fraction=1e-12,
                            engine="consensus")
    assert res.iterations == 40
    assert np.abs(res.distance - expected).max() <= 1e-8 * expected.max()
    assert np.abs(expected - expected.T).max() <= 1e-10 * expected.max()  # the full ADMM stays symmetric too


def test_rows_close_to_single_source_with_twice_alpha(device):
    V, F = meshes.icosphere(2, 1.0)  # 162 vertices
    mesh = wrd.Mesh(V, F)
    U = wrd.all_pairs(mesh, 0.03, device=device).distance
    rows2 = wrd.distance_matrix(mesh, 0.06, symmetrize=False, device=device)
    rows1 = wrd.distance_matrix(mesh, 0.03, sources=np.arange(0, 162, 4), symmetrize=False, device=device)
    assert np.array_equal(U, U.T)
    err2 = np.abs(U - rows2).max() / U.max()
    err1 = np.abs(U[::4] - rows1).max() / U.max()
    assert err2 <= 0.035 and err2 < err1


def test_triangle_inequality_violations_drop_as_alpha_grows(bumpy42):
    mesh, _ = bumpy42
    share = [triangle_inequality_violations(wrd.all_pairs(mesh, a, device="cpu").distance) for a in (0.01, 0.1, 0.3)]
    assert share[0] > share[1] > share[2]


def test_distance_matrix_rows_and_symmetrization(bumpy42):
    mesh, _ = bumpy42
    src = np.array([3, 17, 40])
    rows = wrd.distance_matrix(mesh, 0.03, sources=src, symmetrize=False, chunk=2)
    single = wrd.DistanceSolver(mesh, 0.03).solve_many([[s] for s in src]).distance.T
    assert np.array_equal(rows, single)
    sym = wrd.distance_matrix(mesh, 0.03, sources=src, chunk=2)
    block = rows[:, src]
    assert np.array_equal(sym[:, src], 0.5 * (block + block.T))
    full = wrd.distance_matrix(mesh, 0.03)
    assert np.array_equal(full, full.T) and full.shape == (42, 42)


def test_refuses_what_does_not_fit(bumpy42, monkeypatch):
    mesh, _ = bumpy42
    monkeypatch.setattr(memory, "available_memory", lambda device: 1000)
    with pytest.raises(ValueError, match=r"needs .* GB, got 0\.00 GB available"):
        wrd.all_pairs(mesh, 0.03, device="cpu")
    device_bytes, host_bytes = memory.memory_estimate(10_000, 20_000, "float32")
    assert device_bytes + host_bytes < 12e9  # a 10k-vertex surface fits in float32


def test_bad_input(bumpy42):
    mesh, _ = bumpy42
    V, F = mesh.vertices, mesh.elements
    two = wrd.Mesh(np.vstack([V, V + 5.0]), np.vstack([F, F + len(V)]))
    with pytest.raises(ValueError, match="connected"):
        wrd.all_pairs(two)
    for kwargs, message in ((dict(alpha_hat=-1.0), "alpha_hat"), (dict(dtype="float16"), "dtype"),
                            (dict(max_iterations=0), "max_iterations"), (dict(rho2_factor=0.0), "rho2_factor"),
                            (dict(eps_rel=float("nan")), "eps_rel"), (dict(eps_rel_dual=-1.0), "eps_rel_dual"),
                            (dict(cg_fraction=True), "cg_fraction"), (dict(callback=5), "callback")):
        with pytest.raises(ValueError, match=message):
            wrd.all_pairs(mesh, **kwargs)
    with pytest.raises(ValueError, match="distinct"):
        wrd.distance_matrix(mesh, sources=[1, 1])
    with pytest.raises(ValueError, match="expected symmetrize as True or False"):
        wrd.distance_matrix(mesh, sources=[1, 2], symmetrize="no")


def test_cli_allpairs(tmp_path, capsys):
    d = np.load(DATA)
    path = tmp_path / "bumpy.off"
    with open(path, "w") as f:
        f.write(f"OFF\n{len(d['vertices'])} {len(d['faces'])} 0\n")
        f.writelines(f"{x!r} {y!r} {z!r}\n" for x, y, z in d["vertices"].tolist())
        f.writelines(f"3 {a} {b} {c}\n" for a, b, c in d["faces"])
    out = tmp_path / "U.npy"
    assert main(["allpairs", str(path), "--alpha-hat", "0.03", "--output", str(out), "--device", "cpu"]) == 0
    U = np.load(out)
    assert np.abs(U - d["U_003"]).max() <= 0.01 * d["U_003"].max()
    captured = capsys.readouterr()
    assert "iteration 50: max residual/tolerance " in captured.err and "estimated error" in captured.out
    assert "gradient excess" in captured.out
    assert main(["allpairs", str(path), "--alpha-hat", "0.03", "--output", str(out), "--accuracy", "0.002",
                 "--quiet"]) == 0
    assert np.abs(np.load(out) - d["U_003"]).max() <= 0.002 * d["U_003"].max()
    assert main(["allpairs", str(path), "--output", str(out), "--accuracy", "0.5"]) == 2
    assert "expected accuracy as a fraction of the max distance in (0, 0.1], got 0.5" in capsys.readouterr().err
    assert main(["allpairs", str(tmp_path / "missing.off"), "--output", str(out)]) == 2
    assert capsys.readouterr().err.startswith("warp-regdist: error:")


def test_solver_object_solves_again_as_all_pairs_does(bumpy42):
    mesh, _ = bumpy42
    once = wrd.all_pairs(mesh, 0.1, workers=1, accuracy=0.02)
    solver = wrd.AllPairsSolver(mesh, 0.1, workers=1)
    assert solver.memory_bytes == once.memory_bytes
    for _ in range(2):  # the second solve starts from zeros again
        again = solver.solve(accuracy=0.02)
        assert again.iterations == once.iterations and np.array_equal(again.distance, once.distance)
    residuals_only = solver.solve(accuracy=0.02, eps_change=math.inf)  # an explicit tolerance overrides accuracy's
    assert residuals_only.iterations < once.iterations and residuals_only.error_estimate == residuals_only.change


def test_stop_waits_until_the_gradient_excess_is_within_eps_excess(bumpy42):
    mesh, refs = bumpy42
    solver = wrd.AllPairsSolver(mesh, 0.1, workers=1)
    loose = solver.solve(accuracy=0.01)
    assert loose.converged and 0.0 < loose.gradient_excess <= 0.01
    strict = solver.solve(accuracy=0.01, eps_excess=0.5 * loose.gradient_excess)
    # measured: 550 iterations against 350, excess 0.31 of loose's, error 0.10% against 0.23%
    assert strict.converged and strict.iterations > loose.iterations
    assert strict.gradient_excess <= 0.5 * loose.gradient_excess
    error = [np.abs(r.distance - refs[0.1]).max() for r in (loose, strict)]
    assert error[1] < error[0]
    unchecked = solver.solve(accuracy=0.01, eps_excess=math.inf)
    assert unchecked.iterations == loose.iterations and np.array_equal(unchecked.distance, loose.distance)


def test_resume_restores_the_excess_of_the_last_change_test(bumpy42, tmp_path):
    """The checkpoint records the gradient excess measured on the device at the last change test (the
    host's gradient_excess of that U to rounding); a resumed run goes on with it, as the uninterrupted run
    did, so that it stops where that run stops. A checkpoint without it has it measured again on the host."""
    mesh, _ = bumpy42
    n = mesh.n_vertices
    solver = wrd.AllPairsSolver(mesh, 0.1, workers=1)
    with pytest.warns(wrd.ConvergenceWarning, match=r"gradient excess [0-9.e-]+ / eps_excess 0\.005\)"):
        solver.solve(max_iterations=120, checkpoint=tmp_path / "run.npz")
    with np.load(tmp_path / "run.npz") as saved:
        data = dict(saved)
    host = solver._excess(data["change_snapshot"].reshape(n, -1)[:, :n])  # U at iteration 100
    assert host > 0 and float(data["excess"]) == pytest.approx(host, rel=1e-12)
    del data["excess"]
    np.savez(tmp_path / "without.npz", **data)
    messages = []
    for resume in (None, tmp_path / "run.npz", tmp_path / "without.npz"):  # 121: no change test after 100
        with pytest.warns(wrd.ConvergenceWarning) as caught:
            solver.solve(max_iterations=121, resume=resume)
        messages.append(str(caught[0].message))
    assert f"gradient excess {host:.3g} / eps_excess" in messages[0]
    assert messages[1] == messages[0] and messages[2] == messages[0]


@pytest.mark.parametrize("accuracy", [0.0, -0.01, 0.2, math.nan, "0.01", True])
def test_accuracy_outside_its_range_is_refused(bumpy42, accuracy):
    mesh, _ = bumpy42
    with pytest.raises(ValueError, match=r"expected accuracy as a fraction of the max distance in \(0, 0\.1\], got"):
        wrd.AllPairsSolver(mesh, 0.1).solve(accuracy=accuracy)


def test_warm_start_from_another_alpha_hat_reaches_the_new_minimizer(bumpy42, tmp_path):
    # continuation 0.03 -> 0.1: the start is 2.9% of the maximum away from the new minimizer
    mesh, refs = bumpy42
    path = tmp_path / "a003.npz"
    first = wrd.all_pairs(mesh, 0.03, checkpoint=path, engine="consensus")
    assert first.converged and np.abs(refs[0.03] - refs[0.1]).max() > 0.02 * refs[0.1].max()
    again = wrd.all_pairs(mesh, 0.03, resume=path, engine="consensus")  # a converged run's checkpoint holds its result
    assert again.iterations == first.iterations and np.array_equal(again.distance, first.distance)
    cold = wrd.all_pairs(mesh, 0.1, engine="consensus")
    warm = wrd.all_pairs(mesh, 0.1, initial=path, engine="consensus")
    # the change test cannot tell the start's head start: it stops within two windows of the cold start
    # (700 against 600 iterations), 2.6 times closer (0.0096% against 0.025%)
    window = wrd.AllPairsOptions().change_window
    assert warm.converged and warm.iterations <= cold.iterations + 2 * window and warm.iterations == len(warm.history)
    error = [np.abs(r.distance - refs[0.1]).max() / refs[0.1].max() for r in (warm, cold)]
    assert error[0] <= 0.5 * error[1]
    assert np.array_equal(warm.distance, warm.distance.T)


def test_warm_start_checkpoint_is_checked(bumpy42, tmp_path):
    mesh, _ = bumpy42
    path = tmp_path / "a.npz"
    with pytest.warns(wrd.ConvergenceWarning):
        wrd.all_pairs(mesh, 0.1, max_iterations=3, checkpoint=path, dtype="float32")
    with pytest.raises(ValueError, match=r"expected a checkpoint of this mesh and dtype \(dtype 'float64'\), "
                                         r"got one of another problem \(dtype 'float32'\)"):
        wrd.all_pairs(mesh, 0.1, initial=path)
    with pytest.raises(ValueError, match="expected resume .* or initial .*, got both"):
        wrd.all_pairs(mesh, 0.1, initial=path, resume=path, dtype="float32")
    with pytest.raises(ValueError, match=r"expected initial as an all-pairs checkpoint \(\.npz\), got .*nothing\.npz"):
        wrd.all_pairs(mesh, 0.1, initial=tmp_path / "nothing.npz")


def test_one_column_per_thread_gives_the_same_iterates(bumpy42, monkeypatch):
    """The lane-wise steps as CUDA runs them (one column per thread, through views of the W-lane state)
    give the iterates of W columns per thread, to the rounding of sums added in another order."""
    mesh, _ = bumpy42
    capped = pytest.warns(wrd.ConvergenceWarning, match="did not converge in 200 iterations")
    with capped:
        lanes = wrd.all_pairs(mesh, 0.1, workers=1, max_iterations=200, eps_change=math.inf,
                                  engine="consensus")
    widths = []
    monkeypatch.setattr(all_pairs_state, "lanes_per_thread", lambda device, W: widths.append(W) or 1)
    with capped:
        columns = wrd.all_pairs(mesh, 0.1, workers=1, max_iterations=200, eps_change=math.inf,
                                  engine="consensus")
    assert widths == [8]  # float64 lanes of 8 columns, seen as 48 columns of one
    assert columns.iterations == lanes.iterations and columns.cg_iterations == lanes.cg_iterations
    assert np.abs(columns.distance - lanes.distance).max() <= 1e-9 * lanes.distance.max()


def test_no_obtuse_hint_without_obtuse_triangles(bumpy42):
    """An unconverged result on a mesh whose angles are all below OBTUSE_ANGLE gets the cap's warning alone."""
    from warp_regdist.geometry.operators import largest_angles

    mesh, _ = bumpy42
    assert largest_angles(mesh.vertices, mesh.elements).max() < wrd.solvers.all_pairs.solver.OBTUSE_ANGLE
    with pytest.warns(wrd.ConvergenceWarning) as caught:
        res = wrd.all_pairs(mesh, 0.1, workers=1, max_iterations=30)
    assert not res.converged and res.gradient_excess > 0.005
    assert [str(w.message)[:40] for w in caught] == ["all-pairs ADMM did not converge in 30 it"]
