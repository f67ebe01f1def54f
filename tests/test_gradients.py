"""Vector-Jacobian products through the solve (DistanceResult.vjp, warp_regdist/solvers/single_source/gradients.py).

Levels: the per-element kernels against numpy's operators and their reverse pass against
finite differences (one element at a time, exact); the whole vjp against central differences of
the smoothed problem solved by Newton's method (positions and alpha_hat, a decimated surface, a
surface with a hole, a tetrahedral cube); the smoothed minimizer against an independent conic
solver; refusals.

tests/data/spot_rr_955.npz: the packaged spot_rr quadric-decimated to 955 vertices
(fast-simplification, target_reduction 1 - 954/4764): obtuse and sliver triangles.
"""

import pathlib
import warnings

import numpy as np
import pytest
import warp as wp

import meshes
import reference_solver as rs
import warp_regdist as wrd
from warp_regdist.geometry.operators import element_gradients
from warp_regdist.solvers.single_source.gradients import SmoothedProblem

DATA = pathlib.Path(__file__).parent / "data"


def spot955():
    d = np.load(DATA / "spot_rr_955.npz")
    return wrd.Mesh(d["vertices"], d["faces"].astype(np.int64))


def jittered(V, F, amount, planar=False, seed=3):
    """V moved by uniform noise in [-amount, amount] per coordinate (not z when planar)."""
    noise = np.random.default_rng(seed).uniform(-amount, amount, V.shape)
    if planar:
        noise[:, 2] = 0.0
    return wrd.Mesh(V + noise, F)


def hole_mesh():
    V, F = meshes.square_with_hole(30)[:2]
    return jittered(V, F, 0.02, planar=True)


def cube_mesh():
    V, F = meshes.cube_tets(8)
    return jittered(V, F, 0.02)


def smoothed_value(mesh, alpha_hat, sources, b, start):
    """b . u_mu of the smoothed problem on ``mesh`` (Newton from ``start``)."""
    solver = wrd.DistanceSolver(mesh, alpha_hat, workers=1)
    if solver.refinement is not None:       # on the refined mesh, from its own ADMM solve; read on the input's vertices
        start = wrd.DistanceSolver(solver.solve_mesh, alpha_hat, workers=1).solve(sources).distance
    free = np.ones(solver.solve_mesh.n_vertices, dtype=bool)
    free[sources] = False
    problem = SmoothedProblem(solver.operators, solver.alpha, solver.options.gradient_smoothing, free,
                              wedges=solver.source_triangles.corners(sources))
    u = np.zeros(free.size)
    u[free] = problem.minimize(start[free])[0]
    return b @ u[:mesh.n_vertices]


@pytest.mark.parametrize("kind", ["triangle", "tetrahedron"])
def test_element_terms_and_their_reverse_pass(kind):
    """kernels/adjoint.py: volume and Dirichlet terms equal numpy's operators, the barrier terms their
    formulas (the wedge's on the triangles given a source corner); the reverse pass of a weighted sum of
    all four outputs equals its central difference along a random displacement."""
    from warp_regdist.kernels import adjoint

    rng = np.random.default_rng(0)
    k = 3 if kind == "triangle" else 4
    kernel = adjoint.triangle_terms if k == 3 else adjoint.tetrahedron_terms
    X = rng.random((12, 3))
    T = np.array([rng.choice(12, k, replace=False) for _ in range(20)])
    u, w = rng.random(12) * 0.01, rng.random(12)
    seeds = [rng.random(len(T)) for _ in range(4)]
    corner = np.where(np.arange(len(T)) % 2 == 0, np.arange(len(T)) % 3, -1).astype(np.int32)
    extra = [wp.array(corner, dtype=wp.int32)] if k == 3 else []

    def run(X, grad=False):
        x = wp.array(X, dtype=wp.vec3d, device="cpu", requires_grad=grad)
        out = [wp.zeros(len(T), dtype=wp.float64, device="cpu", requires_grad=grad) for _ in range(4)]
        tape = wp.Tape()
        with tape:
            wp.launch(kernel, len(T), device="cpu", inputs=[x, wp.array(T.astype(np.int32), dtype=wp.int32),
                                                             wp.array(u, dtype=wp.float64),
                                                             wp.array(w, dtype=wp.float64)] + extra, outputs=out)
        return x, out, tape

    x, out, tape = run(X, True)
    basis, vol = element_gradients(X, T)
    g, gw = np.einsum("mkc,mk->mc", basis, u[T]), np.einsum("mkc,mk->mc", basis, w[T])
    p, t = (g * gw).sum(1), (g * g).sum(1)
    np.testing.assert_allclose(out[3].numpy(), vol, rtol=1e-12)
    np.testing.assert_allclose(out[0].numpy(), -vol / k * w[T].sum(1), rtol=1e-12)
    np.testing.assert_allclose(out[1].numpy(), vol * p, rtol=1e-10, atol=1e-14)
    barrier = 2 * p / (1 - t)
    if k == 3:
        for e in np.flatnonzero(corner >= 0):
            s = T[e, corner[e]]
            barrier[e] = sum((w[a] - w[s]) / (np.linalg.norm(X[a] - X[s]) - u[a] + u[s])
                             for a in T[e, [(corner[e] + 1) % 3, (corner[e] + 2) % 3]])
    np.testing.assert_allclose(out[2].numpy(), barrier, rtol=1e-10, atol=1e-14)
    tape.backward(grads={o: wp.array(s, dtype=wp.float64) for o, s in zip(out, seeds)})
    D, h = rng.standard_normal(X.shape), 1e-6

    def f(X):
        return sum(float(o.numpy() @ s) for o, s in zip(run(X)[1], seeds))

    fd = (f(X + h * D) - f(X - h * D)) / (2 * h)
    assert abs((x.grad.numpy() * D).sum() - fd) <= 1e-6 * abs(fd)


@pytest.mark.parametrize("case", ["spot955", "hole", "cube"])
def test_vjp_matches_central_differences_of_the_smoothed_problem(case):
    """dL/dx . D and dL/dalpha_hat against central differences of b . u_mu (h = 1e-7 and 1e-6):
    measured 1e-7 to 7e-6 relative at h = 1e-6 on these meshes; 1e-5 would fail with any missing term
    (the barrier's mu(A), alpha(A), the lumped load)."""
    mesh = {"spot955": spot955, "hole": hole_mesh, "cube": cube_mesh}[case]()
    alpha_hat, sources = 0.05, [0]
    res = wrd.DistanceSolver(mesh, alpha_hat, workers=1).solve(sources)
    rng = np.random.default_rng(0)
    b = rng.random(mesh.n_vertices)
    D = rng.standard_normal(mesh.vertices.shape)
    if case == "hole":
        D[:, 2] = 0.0
    g = res.vjp(b)
    assert g.vertices.shape == (mesh.n_vertices, 3) and np.isfinite(g.vertices).all()
    start = g.smoothed_distance
    V, F = mesh.vertices, mesh.elements
    h = 1e-7
    fd = (smoothed_value(wrd.Mesh(V + h * D, F), alpha_hat, sources, b, start)
          - smoothed_value(wrd.Mesh(V - h * D, F), alpha_hat, sources, b, start)) / (2 * h)
    assert abs((g.vertices * D).sum() - fd) <= 1e-5 * abs(fd), ((g.vertices * D).sum(), fd)
    h = 1e-6
    fd = (smoothed_value(mesh, alpha_hat + h, sources, b, start)
          - smoothed_value(mesh, alpha_hat - h, sources, b, start)) / (2 * h)
    assert abs(g.alpha_hat - fd) <= 1e-5 * abs(fd), (g.alpha_hat, fd)


def test_smoothed_minimizer_is_near_the_conic_solvers():
    """u_mu at the default smoothing (vjp's smoothed_distance, polish's distance) against Clarabel's exact
    minimizer of the unsmoothed problem: measured 4.4e-5 of the max distance on the decimated spot,
    where the ADMM's distance is 0.32% away (its iterates creep there); polish_change measures that."""
    mesh = spot955()
    V, F = mesh.vertices, mesh.elements
    exact = rs.solve_reference(V, F, [0], 0.05 * np.sqrt(rs.face_geometry(V, F)[0].sum()))
    res = wrd.DistanceSolver(mesh, 0.05, workers=1, refine_obtuse=False).solve([0])     # the reference's problem
    g = res.vjp(np.ones(mesh.n_vertices))
    assert np.abs(g.smoothed_distance - exact).max() <= 2e-4 * exact.max()
    assert g.smoothing_change == pytest.approx(np.abs(g.smoothed_distance - res.distance).max() / res.distance.max())
    polished = res.polish()
    np.testing.assert_allclose(polished.distance, g.smoothed_distance, rtol=1e-10, atol=1e-12)
    admm_error = np.abs(res.distance - exact).max() / exact.max()
    assert 1e-3 < admm_error <= 5e-3 and polished.polish_change == pytest.approx(admm_error, rel=0.05)
    assert "error_estimate" not in polished and "error_estimate" in res
    assert polished.vjp(np.ones(mesh.n_vertices)).smoothing_change <= 1e-6


def test_polish_of_solve_many_is_per_column():
    mesh = hole_mesh()
    many = wrd.DistanceSolver(mesh, 0.1, workers=1).solve_many([[0], [5, 40]])
    polished = many.polish()
    assert polished.distance.shape == (mesh.n_vertices, 2) and polished.polish_change.shape == (2,)
    change = np.abs(polished.distance - many.distance).max(axis=0) / many.distance.max(axis=0)
    np.testing.assert_allclose(polished.polish_change, change, rtol=1e-12)
    assert np.all(polished.distance[[5, 40], 1] == 0.0) and polished.distance[0, 0] == 0.0


def test_a_result_keeps_its_problem_not_its_solver():
    """vjp and polish work from the data a result keeps, after its solver (device arrays, workers) is gone."""
    import gc
    import weakref

    mesh = hole_mesh()
    solver = wrd.DistanceSolver(mesh, 0.1, workers=1)
    res = solver.solve([0])
    b = np.random.default_rng(4).random(mesh.n_vertices)
    before = res.vjp(b).vertices
    gone = weakref.ref(solver)
    del solver
    gc.collect()
    assert gone() is None
    np.testing.assert_array_equal(res.vjp(b).vertices, before)
    assert res.polish().polish_change >= 0.0


def test_solve_many_vjp_is_the_sum_of_its_columns():
    mesh = hole_mesh()
    solver = wrd.DistanceSolver(mesh, 0.1, workers=1)
    rng = np.random.default_rng(1)
    b = rng.random((mesh.n_vertices, 2))
    many = solver.solve_many([[0], [5, 40]]).vjp(b)
    one = [solver.solve(s).vjp(b[:, j]) for j, s in enumerate([[0], [5, 40]])]
    np.testing.assert_allclose(many.vertices, one[0].vertices + one[1].vertices, rtol=1e-6, atol=1e-8)
    assert many.alpha_hat == pytest.approx(one[0].alpha_hat + one[1].alpha_hat, rel=1e-6)
    assert many.smoothed_distance.shape == (mesh.n_vertices, 2)


def test_float32_solve_differentiates_in_float64():
    mesh = hole_mesh()
    b = np.random.default_rng(2).random(mesh.n_vertices)
    g64 = wrd.DistanceSolver(mesh, 0.05, workers=1).solve([0]).vjp(b)
    g32 = wrd.DistanceSolver(mesh, 0.05, workers=1, dtype="float32").solve([0]).vjp(b)
    np.testing.assert_allclose(g32.vertices, g64.vertices, rtol=1e-6, atol=1e-6 * np.abs(g64.vertices).max())


def test_vjp_refusals():
    mesh = hole_mesh()
    solver = wrd.DistanceSolver(mesh, 0.05, workers=1)
    res = solver.solve([0])
    n = mesh.n_vertices
    with pytest.raises(ValueError, match=r"expected grad_u of shape \(800,\) \(the distance's\), got \(799,\)"):
        res.vjp(np.ones(n - 1))
    with pytest.raises(ValueError, match="expected finite grad_u, got NaN or inf"):
        res.vjp(np.full(n, np.nan))
    with pytest.raises(ValueError, match=r"expected grad_u as a real array of shape \(800,\), got str"):
        res.vjp("1")
    with pytest.raises(ValueError, match=r"expected grad_u as a real array of shape \(800,\), got list"):
        res.vjp([[1.0], [1.0, 2.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        short = solver.solve([0], max_iterations=5)
    with pytest.raises(ValueError, match="expected a converged solve to differentiate, got 1 of 1 columns not converged"):
        short.vjp(np.ones(n))
    with pytest.raises(ValueError, match="expected a converged solve to polish, got 1 of 1 columns not converged"):
        short.polish()
    point = solver.solve(points=[(3, (0.2, 0.3, 0.5))])
    with pytest.raises(ValueError, match=r"expected grad_u of shape \(800,\) \(the distance's\), got \(80[1-9]\d*,\)"):
        point.vjp(np.ones(point.refined_mesh.n_vertices))
    curve = solver.solve(curve=[(3, (0.2, 0.3, 0.5)), (3, (0.5, 0.3, 0.2))])
    with pytest.raises(ValueError, match="expected a result of DistanceSolver.solve or solve_many from vertices or "
                                         "points to differentiate, got one from curves"):
        curve.vjp(np.ones(n))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        hessian = wrd.DistanceSolver(mesh, 0.05, regularizer="hessian", workers=1).solve([0], max_iterations=5)
    with pytest.raises(ValueError, match="expected the Dirichlet regularizer on a mesh to differentiate, got 'hessian'"):
        hessian.vjp(np.ones(n))
    for bad in (0.0, -1e-6, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="expected gradient_smoothing as a number > 0, got"):
            wrd.SolverOptions(gradient_smoothing=bad)


def test_factorizations_give_the_same_gradients(monkeypatch):
    """PARDISO's Cholesky and SuperLU on the same Newton path: gradients to 1e-6 of their largest
    entry (both refine each solve once; measured 2e-8 on spot_rr, 1e-7 on tet cubes); "auto" is
    PARDISO where MKL loads and SuperLU where it does not; PARDISO without MKL says how to install it."""
    from warp_regdist.solvers.single_source import gradients

    with pytest.raises(ValueError, match="expected gradient_factorization as one of 'auto', 'pardiso', 'superlu', "
                                         "got 'cholmod'"):
        wrd.SolverOptions(gradient_factorization="cholmod")
    mesh = hole_mesh()
    solver = wrd.DistanceSolver(mesh, 0.05, workers=1)
    b = np.random.default_rng(0).random(mesh.n_vertices)
    superlu = solver.solve([0], gradient_factorization="superlu").vjp(b)
    assert superlu.factorization == "superlu"
    try:
        gradients.load_mkl()
    except OSError:
        pytest.skip("MKL not installed")
    pardiso = solver.solve([0]).vjp(b)
    assert pardiso.factorization == "pardiso"
    assert np.abs(pardiso.vertices - superlu.vertices).max() <= 1e-6 * np.abs(superlu.vertices).max()
    assert abs(pardiso.alpha_hat - superlu.alpha_hat) <= 1e-6 * abs(superlu.alpha_hat)
    assert pardiso.newton_iterations == superlu.newton_iterations

    def missing():
        raise OSError("no libmkl_rt")

    monkeypatch.setattr(gradients, "load_mkl", missing)
    assert solver.solve([0]).vjp(b).factorization == "superlu"
    with pytest.raises(ValueError, match=r"expected gradient_factorization 'pardiso' to find MKL \(pip install "
                                         r"'warp-regdist\[pardiso\]', x86-64 only\), got no libmkl_rt"):
        solver.solve([0], gradient_factorization="pardiso").polish()


@pytest.mark.parametrize("case", ["spot955", "cube"])
def test_hessian_on_its_pattern_equals_the_sparse_products(case):
    """The Newton Hessian assembled by one bincount equals G^T blockdiag(c_e I + w_e g_e g_e^T) G
    formed by sparse products, with sources removed from G's columns."""
    import scipy.sparse as sp

    mesh = {"spot955": spot955, "cube": cube_mesh}[case]()
    solver = wrd.DistanceSolver(mesh, 0.05, workers=1, refine_obtuse=False if mesh.element_dim == 2 else None)
    free = np.ones(mesh.n_vertices, dtype=bool)
    free[[0, 7, 11]] = False
    problem = SmoothedProblem(solver.operators, solver.alpha, 1e-6, free)
    rng = np.random.default_rng(0)
    c, w, g = rng.random(problem.m), rng.random(problem.m), rng.standard_normal((problem.m, 3))
    H = problem.hessian.matrix(c, w, g)
    blocks = c[:, None, None] * np.eye(3) + w[:, None, None] * g[:, :, None] * g[:, None, :]
    expected = (problem.G.T @ sp.block_diag(list(blocks), format="csr") @ problem.G).toarray()
    assert H.has_sorted_indices and H.shape == (free.sum(), free.sum())
    assert np.abs(H.toarray() - expected).max() <= 1e-13 * np.abs(expected).max()


def test_an_earlier_factor_of_a_refactored_handle_refuses_to_solve():
    from warp_regdist.solvers.single_source.gradients import _Factor, factorization_backend

    if factorization_backend("auto") != "pardiso":
        pytest.skip("MKL not installed")
    import scipy.sparse as sp

    H = sp.diags([4.0 * np.ones(30), np.ones(29), np.ones(29)], [0, -1, 1], format="csr")
    first = _Factor(H, "pardiso")
    second = _Factor(2.0 * H, "pardiso", first)
    assert np.abs(2.0 * H @ second.solve(np.ones(30)) - 1.0).max() <= 1e-12
    with pytest.raises(RuntimeError, match="expected the latest factorization of a PARDISO handle, got one "
                                           "refactored since"):
        first.solve(np.ones(30))


def test_pardiso_falls_back_to_superlu_where_a_pivot_is_not_positive():
    """A symmetric indefinite matrix with a positive diagonal (blocks [[1, 2], [2, 1]]): PARDISO's
    Cholesky refuses it (error -4), SuperLU solves it."""
    import scipy.sparse as sp
    from warp_regdist.solvers.single_source.gradients import _Factor, factorization_backend

    if factorization_backend("auto") != "pardiso":
        pytest.skip("MKL not installed")
    A = sp.block_diag([np.array([[1.0, 2.0], [2.0, 1.0]])] * 25, format="csr")
    b = np.arange(50.0)
    factor = _Factor(A, "pardiso")
    assert factor.pardiso is None
    x = factor.solve(b)
    assert np.abs(A @ x - b).max() <= 1e-10 * np.abs(b).max()


def test_unreachable_component_moves_the_distance_only_through_the_total_area():
    """Two spheres, the source on the first: the second's distance stays inf, and moving its vertices
    changes alpha = alpha_hat A^(1/2) and mu, hence the first's distance; vjp against central
    differences of polished solves (h = 1e-6) along a displacement of the second sphere only."""
    V, F = meshes.icosphere(2)
    n = len(V)
    mesh = wrd.Mesh(np.vstack([V, V * 1.3 + [3.0, 0.0, 0.0]]), np.vstack([F, F + n]))
    res = wrd.DistanceSolver(mesh, 0.1, workers=1).solve([0])
    b = np.random.default_rng(5).random(2 * n)
    g = res.vjp(b)
    assert np.isinf(g.smoothed_distance[n:]).all() and np.isfinite(g.smoothed_distance[:n]).all()
    D = np.zeros_like(mesh.vertices)
    D[n:] = np.random.default_rng(6).standard_normal((n, 3))

    def value(h):
        moved = wrd.Mesh(mesh.vertices + h * D, mesh.elements)
        return b[:n] @ wrd.DistanceSolver(moved, 0.1, workers=1).solve([0]).polish().distance[:n]

    fd = (value(1e-6) - value(-1e-6)) / 2e-6
    assert abs((g.vertices * D).sum() - fd) <= 1e-5 * abs(fd), ((g.vertices * D).sum(), fd)


def test_a_stalled_final_level_falls_back_to_the_last_converged_one(monkeypatch):
    """Where Newton's method stalls at the final mu, vjp differentiates the problem of the last level
    that converged (mu_hat 1e-5 here), warns, and says so in ``smoothing``: the same gradients as
    asking for that mu_hat."""
    mesh = hole_mesh()
    res = wrd.DistanceSolver(mesh, 0.05, workers=1).solve([0])
    b = np.random.default_rng(7).random(mesh.n_vertices)
    center = SmoothedProblem._center

    def stalling(self, v, mu, tight):
        v, lu, count, converged = center(self, v, mu, tight)
        return v, lu, count, converged and mu > 1.5 * self.mu   # the final level never converges

    monkeypatch.setattr(SmoothedProblem, "_center", stalling)
    with pytest.warns(wrd.ConvergenceWarning, match="solved at gradient_smoothing 1e-05, not 1e-06"):
        fallback = res.vjp(b)
    monkeypatch.undo()
    direct = wrd.DistanceSolver(mesh, 0.05, workers=1).solve([0], gradient_smoothing=1e-5).vjp(b)
    assert fallback.smoothing == pytest.approx(1e-5) and direct.smoothing == pytest.approx(1e-5)
    np.testing.assert_allclose(fallback.vertices, direct.vertices, rtol=1e-6, atol=1e-8 * np.abs(direct.vertices).max())


def _refined_smoothed_value(mesh, alpha_hat, faces, bary, b, start):
    """b . u_mu on the original vertices, u_mu of the smoothed problem on ``mesh`` refined at the points
    (faces, bary) with those points as sources (Newton from ``start`` on the refined mesh)."""
    from warp_regdist.geometry.boundary_refinement import refine_boundary
    from warp_regdist.geometry.surface_points import refine

    R = (refine if mesh.element_dim == 2 else refine_boundary)(mesh, np.asarray(faces), np.asarray(bary))
    solver = wrd.DistanceSolver(R.mesh, alpha_hat, workers=1, refine_obtuse=False)
    free = np.ones(R.mesh.n_vertices, dtype=bool)
    free[R.point_vertices] = False
    u = np.zeros(R.mesh.n_vertices)
    u[free] = SmoothedProblem(solver.operators, solver.alpha, solver.options.gradient_smoothing, free,
                              wedges=solver.source_triangles.corners(R.point_vertices)).minimize(start[free])[0]
    return b @ u[:mesh.n_vertices]


@pytest.mark.parametrize("case", ["decimated spot", "tetrahedral cube"])
def test_vjp_through_point_sources_matches_central_differences(case):
    """Points inside faces and on an edge, with the feet of their perpendiculars: the gradient with
    respect to the positions (the points moving with their faces) and to one point's barycentric
    coordinates, against central differences of the smoothed problem on the re-refined mesh."""
    mesh = spot955() if case == "decimated spot" else cube_mesh()
    faces = [100, 400, 40] if case == "decimated spot" else [3, 50, 90]
    bary = np.array([[0.2, 0.5, 0.3], [0.6, 0.3, 0.1], [0.0, 0.45, 0.55]])
    rng = np.random.default_rng(7)
    b = rng.standard_normal(mesh.n_vertices)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.MeshWarning)
        # the points' refinement alone (the obtuse refinement's own gradient: test_obtuse_refinement.py)
        res = wrd.DistanceSolver(mesh, 0.05, workers=1, refine_obtuse=False).solve(points=list(zip(faces, bary)))
    g = res.vjp(b)
    assert g.points.shape == (3, 3) and g.vertices.shape == (mesh.n_vertices, 3)
    assert res.refined_mesh.n_vertices > mesh.n_vertices + 3         # the feet were inserted too
    start = g.refined_smoothed_distance
    h = 1e-7
    D = rng.standard_normal(mesh.vertices.shape)
    V, F = mesh.vertices, mesh.elements
    fd = (_refined_smoothed_value(wrd.Mesh(V + h * D, F), 0.05, faces, bary, b, start)
          - _refined_smoothed_value(wrd.Mesh(V - h * D, F), 0.05, faces, bary, b, start)) / (2 * h)
    assert (g.vertices * D).sum() == pytest.approx(fd, rel=1e-5)
    db = np.array([0.3, -0.1, -0.2])
    fd = (_refined_smoothed_value(mesh, 0.05, faces, bary + h * np.array([db, 0 * db, 0 * db]), b, start)
          - _refined_smoothed_value(mesh, 0.05, faces, bary - h * np.array([db, 0 * db, 0 * db]), b, start)) / (2 * h)
    assert g.points[0] @ db == pytest.approx(fd, rel=1e-5)
    polished = res.polish()
    np.testing.assert_allclose(polished.refined_distance, g.refined_smoothed_distance, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(polished.distance, g.smoothed_distance, rtol=1e-10, atol=1e-12)


def test_solve_many_from_points_gives_each_column_its_points_gradient():
    mesh = hole_mesh()
    res = wrd.DistanceSolver(mesh, 0.05, workers=1).solve_many(points=[[(3, (0.2, 0.3, 0.5))],
                                                                       [(40, (0.1, 0.1, 0.8)), (90, (0.5, 0.5, 0.0))]])
    g = res.vjp(np.ones((mesh.n_vertices, 2)))
    assert [p.shape for p in g.points] == [(1, 3), (2, 3)]
    assert g.vertices.shape == (mesh.n_vertices, 3) and g.smoothed_distance.shape == (mesh.n_vertices, 2)
    assert g.refined_vertices.shape == (res.refined_mesh.n_vertices, 3)
