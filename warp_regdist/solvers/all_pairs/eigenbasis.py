"""The eigenbasis engine of :class:`~warp_regdist.AllPairsSolver`: a two-block ADMM whose primal U is
symmetric with a zero diagonal by construction (docs/method.md section 5, "the eigenbasis engine").

Only the columns' gradients are split off (Z = G U; the rows' follow by symmetry), so there is no
consensus variable and the U-step is solved exactly:

    U-step  (alpha + rho/2)(W U M + M U W) = A_V A_V^T + sym(D (rho Z - Y) M) + Diag(mu),  diag(U) = 0
    Z-step  Z = Proj(a G U + (1 - a) Z_old + Y / rho),  Y += rho (a G U + (1 - a) Z_old - Z)

(M = diag(A_V), W the stiffness, D = G^T M_F, a the over-relaxation). With W' = M^(-1/2) W M^(-1/2)
= Phi Lambda Phi^T, X = M^(1/2) U M^(1/2) solves W' X + X W' = C entrywise in the eigenbasis
(8 n^3 flops of symmetric and triangular BLAS an iteration, on the host), and the diagonal's
multipliers mu solve one (n + 1) system set up once (:class:`EigenbasisUStep`). The Z-step is the
consensus engine's element kernel with X = U (kernels/all_pairs.py), so the state, its checkpoints
and the stopping rule are those of :class:`~warp_regdist.solvers.all_pairs.state.SymmetricADMM`
with X = U and H = 0.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sl
import warp as wp

from ...kernels.all_pairs import U2, X2, all_pairs_kernels
from ...kernels.element_core import G2, R2, Z2
from ...kernels.lanes import SCALARS, lane_type, row_dim, thread_span
from .state import PairsState, _Setup
from ..common.device_mesh import DeviceMesh

__all__ = ["EigenbasisUStep", "EigenbasisADMM"]


def diagonal_response(Phi, lam, nodes=80):
    """K_ik = sum over (p, q) != (0, 0) of Phi_ip Phi_kp Phi_iq Phi_kq / (lam_p + lam_q) (n, n): the
    diagonal of the U-step's response to Diag(e_k), as the integral over t of H_t(i, k)^2 - (phi0_i
    phi0_k)^2 with H_t = Phi e^(-lam t) Phi^T, by the trapezoid rule in log t (``nodes`` rank-n
    updates) over t in [1e-10 / lam_max, 60 / lam_1] (what lies outside is below 1e-10 of K; 6e-11
    measured against the sum itself on a 42-vertex mesh)."""
    s = np.linspace(np.log(1e-10 / lam[-1]), np.log(60 / lam[1]), nodes)
    K, P1, F0 = np.zeros((len(lam),) * 2), Phi[:, 1:], np.outer(Phi[:, 0], Phi[:, 0])
    syrk = sl.get_blas_funcs("syrk", dtype=Phi.dtype)
    for sk in s:
        t = np.exp(sk)
        H1 = syrk(1.0, (P1 * np.exp(-0.5 * lam[1:] * t)).T, trans=1, lower=1)  # lower triangle of H_t - F0
        K += H1 * (H1 + 2 * F0) * (t * (s[1] - s[0]))
    return np.tril(K) + np.tril(K, -1).T


class EigenbasisUStep:
    """The exact U-step: the symmetric U with zero diagonal that solves

        scale (W U M + M U W) = R + Diag(mu),   diag(U) = 0,

    for symmetric R (n, n), W the stiffness (n, n), M = diag(A_V). The multipliers mu (n,) and U's
    constant part c (which W does not see) solve one bordered system: diag(U) = 0 (n equations) and
    sum(R + Diag(mu)) = 0 (the right-hand side has no constant part). Set up once: the
    eigendecomposition M^(-1/2) W M^(-1/2) = Phi Lambda Phi^T (float64, then ``dtype``), kept as
    Psi = M^(-1/2) Phi, so that U = Psi ((Psi^T (R + Diag(mu)) Psi) * dinv) Psi^T / scale + c with
    dinv_pq = 1 / (lambda_p + lambda_q), and the LU factors of the bordered system.

    Each call is 8 n^3 flops of BLAS in ``dtype``, a third less than six general products: every
    product of the form Psi^T S Psi or Psi S Psi^T has a symmetric S = L + L^T (L its lower triangle,
    diagonal halved) and is one triangular product (n^3) and one symmetric rank-2k update (2 n^3),
    and Psi^T Diag(mu) Psi is two rank-k updates (n^3).
    """

    def __init__(self, stiffness, vertex_volumes, dtype="float64"):
        n = vertex_volumes.size
        s = 1 / np.sqrt(vertex_volumes)
        lam, Phi = np.linalg.eigh(s[:, None] * stiffness.toarray() * s[None, :])
        lam[0] = 0.0
        d = lam[:, None] + lam[None, :]
        border = np.zeros((n + 1, n + 1))
        border[:n, :n] = s[:, None] ** 2 * diagonal_response(Phi, lam)
        border[:n, n], border[n, :n] = 1.0, vertex_volumes
        self.border = sl.lu_factor(border)
        self.dtype = np.dtype(dtype)
        Phi *= s[:, None]
        self.Psi = np.asfortranarray(Phi, dtype=self.dtype)
        del Phi
        self.dinv = np.asfortranarray(np.where(d > 0, 1 / np.where(d > 0, d, 1.0), 0.0), dtype=self.dtype)
        self.areas = np.asarray(vertex_volumes, dtype=np.float64)
        self.n = n
        self._trmm, self._syr2k, self._syrk = sl.get_blas_funcs(("trmm", "syr2k", "syrk"), dtype=self.dtype)

    def _times_dinv(self, T):
        """T * dinv with its diagonal halved, in place (T (n, n) Fortran order, lower triangle of a
        symmetric matrix): the lower triangle L of (T * dinv) = L + L^T."""
        T *= self.dinv
        T[np.diag_indices(self.n)] *= 0.5
        return T

    def half_solve(self, C):
        """P = Psi L (n, n) for symmetric C (n, n, Fortran order; overwritten), where L is the lower
        triangle (diagonal halved) of Y = (Psi^T C Psi) * dinv: Psi Y Psi^T = P Psi^T + Psi P^T."""
        C[np.diag_indices(self.n)] *= 0.5  # C = L_C + L_C^T: Psi^T C Psi = syr2k(Psi, L_C Psi)
        Y = self._times_dinv(self._syr2k(1.0, self.Psi, self._trmm(1.0, C, self.Psi, lower=1), trans=1, lower=1))
        del C  # at most four (n, n) temporaries at a time (memory_estimate)
        return self._trmm(1.0, Y, self.Psi, side=1, lower=1)

    def to_vertices(self, P, scale, c, out=None):
        """U = (P Psi^T + Psi P^T) / scale + c (n, n), into ``out`` (n, n) when given: from one triangle,
        so exactly symmetric, with a zero diagonal."""
        zeros = np.zeros((self.n, self.n), dtype=self.dtype, order="F")
        upper = self._syr2k(1 / scale, P, self.Psi, c=zeros, overwrite_c=1, lower=1).T  # its upper triangle, 0 below
        U = np.add(upper, upper.T, out=out)
        U += self.dtype.type(c)
        U[np.diag_indices(self.n)] = 0
        return U

    def __call__(self, R, scale, out=None):
        """U (n, n) in ``dtype`` (into ``out`` when given) for symmetric R (overwritten when already in
        ``dtype``): exactly symmetric, zero diagonal."""
        Psi, n = self.Psi, self.n
        total = float(R.sum(dtype=np.float64))
        P = self.half_solve(R.astype(self.dtype, copy=False).T)
        diag = 2 * np.einsum("ij,ij->i", P, Psi, dtype=np.float64) / scale  # diag(Psi (L + L^T) Psi^T) / scale
        sol = sl.lu_solve(self.border, np.concatenate([-diag, [-total / scale]]))  # M^(-1) mu / scale, and c
        mu = scale * sol[:n] * self.areas  # the multipliers, for Psi^T Diag(mu) Psi: one rank-k update per sign
        S = np.zeros((n, n), dtype=self.dtype, order="F")
        for sign, rows in ((1.0, mu > 0), (-1.0, mu < 0)):
            if rows.any():
                S = self._syrk(sign, (Psi[rows] * np.sqrt(np.abs(mu[rows])).astype(self.dtype)[:, None]).T, beta=1.0,
                               c=S, overwrite_c=1, lower=1)
        P += self._trmm(1.0, self._times_dinv(S), Psi, side=1, lower=1)
        del S
        return self.to_vertices(P, scale, sol[n], out)


class EigenbasisADMM(PairsState):
    """State and one iteration of the eigenbasis engine, with the interface of
    :class:`~warp_regdist.solvers.all_pairs.state.SymmetricADMM` that
    :class:`~warp_regdist.solvers.all_pairs.run.PairsRun` drives: the arrays X (the same array as U),
    U, H (zero), DZ, DZ_acc, DY_acc and v, one process (BLAS threads run the U-step)."""

    engine = "eigenbasis"

    def __init__(self, ops, alpha_hat, device, dtype, options, u_step, constraints):
        self.setup = setup = _Setup(ops, alpha_hat, dtype, options, None, 1, constraints)
        self.n, self.m, self.A, self.L, self.alpha = setup.n, setup.m, setup.A, setup.L, setup.alpha
        self.column_area = np.zeros(setup.nb * setup.W)
        self.column_area[:self.n] = setup.vertex_volumes
        self.u_step = u_step
        sc = SCALARS[dtype]
        self.scalar = sc
        V = lane_type(sc, setup.W)
        self.arrays = {name: wp.zeros(shape[:-1], dtype=V, device=device)
                       for name, (shape, _) in setup.state_specs().items()
                       if name in ("U", "H", "DZ", "DZ_acc", "DY_acc", "v", "acc", "steep")}
        self.arrays["X"] = self.arrays["U"]
        self.arrays["U_returned"] = wp.zeros_like(self.arrays["U"])   # max(U, 0), what the steepness test measures
        self.mesh = mesh = DeviceMesh(ops, sc, device, constraints.directions)
        col0 = 0 if constraints.active else -1
        k = all_pairs_kernels(sc, setup.W)
        nb, m = setup.nb, self.m
        span = thread_span(device, nb, nb, m)
        a = self.arrays
        self.element = wp.launch(k.element_step, row_dim(m, span, nb), device=device, record_cmd=True,
                                 inputs=[mesh.elements, mesh.basis, mesh.volumes, a["U"], a["v"], sc(1.0), sc(1.0),
                                         sc(setup.relaxation), a["DZ_acc"], a["DY_acc"], a["acc"], mesh.directions, col0,
                                         *span, m])
        self.steep = wp.launch(k.steepness, row_dim(m, span, nb), device=device, record_cmd=True,
                               inputs=[mesh.elements, mesh.basis, mesh.diameters, a["U_returned"], a["steep"],
                                       mesh.directions, col0, *span, m])
        self.rho_v = 1.0
        self.penalties = None
        self._areas = setup.vertex_volumes.astype(np.float64)
        self._real = np.dtype(dtype).type
        self._areas_dt = self._areas.astype(self._real)
        self._half_areas_dt = (0.5 * self._areas).astype(self._real)
        self._weights_dt = np.outer(self._areas, self._areas).astype(self._real)
        self._gemv = sl.get_blas_funcs("gemv", dtype=self._real)
        # the U-step's right-hand side and a temporary, kept from iteration to iteration; U padded to whole
        # lanes (on the CPU the state array itself, which the U-step then writes in place)
        self._B, self._R = (np.empty((self.n, self.n), dtype=self._real) for _ in range(2))
        self._on_cpu = wp.get_device(device).is_cpu
        self._lanes = (self.view("U").reshape(self.n, -1) if self._on_cpu
                       else np.zeros((self.n, setup.nb * setup.W), dtype=self._real))

    def _matrix(self, name):
        """State array ``name`` as an (n, n) numpy array (a view on the CPU)."""
        return self.view(name).reshape(self.n, -1)[:, :self.n]

    def set_penalties(self, rho, rho2):
        self.penalties = (rho, rho2)

    def right_hand_side(self):
        """DZ <- the last element step's D Z (DZ_acc); returns per-column |D Z - DZ_old|^2 and |D Y|^2
        (nb W,); DY_acc keeps D Y for the U-step."""
        dz, dz_old, dy = (self.view(name).reshape(self.n, -1) for name in ("DZ_acc", "DZ", "DY_acc"))
        step = dz - dz_old
        s2 = np.einsum("ij,ij->j", step, step, dtype=np.float64)
        dy2 = np.einsum("ij,ij->j", dy, dy, dtype=np.float64)
        self.put("DZ", self.view("DZ_acc"))
        return s2, dy2

    def linear_and_element_steps(self, atol, rtol, max_iterations):
        """The U-step (dense, on the host) then the element step; returns 0 (no PCG iterations)."""
        rho = self.penalties[0]
        n = self.n
        B = np.multiply(self._matrix("DZ"), self._real(rho), out=self._B)
        B -= self._matrix("DY_acc")
        B *= self._half_areas_dt[None, :]
        R = np.add(B, B.T, out=self._R)   # sym(D (rho Z - Y) M) + A_V A_V^T
        R += self._weights_dt
        self.u_step(R, self.alpha + 0.5 * rho, out=self._lanes[:, :n])
        if not self._on_cpu:
            self.put("U", self._lanes.reshape(n, self.setup.nb, self.setup.W))
        for name in ("DZ_acc", "DY_acc", "acc"):
            self.arrays[name].zero_()
        self.element.set_param_by_name("rho_v", self.scalar(self.rho_v))
        self.element.set_param_by_name("rho", self.scalar(rho))
        self.element.launch()
        self.rho_v = rho
        return 0

    def coupling_step(self):
        """No coupling step (U is symmetric by construction): per-column R2, G2, Z2 sums (3, nb W) and the pair sums (5,) with X = U, H = 0."""
        acc = self.view("acc").reshape(5, -1)
        U = self._matrix("U")
        pairs = np.zeros(5)
        # a^T U^2 a with scipy's BLAS, the U-step's: numpy's wheel has its own OpenBLAS, whose threads spin
        # idle for a while after each product and would take the cores from the next U-step (up to half its speed)
        U2a = self._gemv(1.0, np.multiply(U, U, out=self._B).T, self._areas_dt)  # symmetric: .T is Fortran order
        pairs[X2] = pairs[U2] = float(self._areas @ U2a.astype(np.float64))
        return acc[[R2, G2, Z2]].astype(np.float64), pairs

    def _steepness(self):
        """The steepness of max(U, 0), the matrix a result returns: this engine's U-step does not clip U at 0,
        and clipping a slightly negative U steepens it (docs/design/all-pairs.md)."""
        self.put("U_returned", np.maximum(self.view("U"), 0))
        self.steep.launch()

