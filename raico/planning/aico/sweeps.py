"""The message state and per-step updates of one AICO run (:class:`Sweeps`).

Model per iteration (``n = n_x``, ``m = n_u``): dynamics linearized ``x_{t+1} ~ A_t x_t + a_t + B_t u_t``
with process noise ``Q = q I``; task messages ``N[x_t | r_t, R_t]`` (cost ``1/2 x^T R x - r^T x``) plus
R-AICO's ``alpha ||x_t - x_t^[n-1]||^2`` (``R += 2 alpha I``, ``r += 2 alpha x_t^[n-1]``); the control
prior ``N[u_t | h_t, H_t]`` marginalized: ``x_{t+1} | x_t ~ N(A x + a + B H^-1 h, Qbar)``,
``Qbar = Q + B H^-1 B^T``.

Messages: forward (moment form ``s_t, S_t``, stored as ``S_t^-1``, ``S_t^-1 s_t``), backward in canonical
form ``V_t^-1, V_t^-1 v_t`` (``V_T^-1 = 0``), belief ``B_t = S_t^-1 + V_t^-1 + R_t``; start
``S_0 = start_variance I``. With ``P' = V_{t+1}^-1 + R_{t+1}`` the backward step uses
``V* = (Q + P'^-1)^-1 = (I + q P')^-1 P'`` and ``M = B^T V* B + H``; by Woodbury the message and the
controller (thesis eq. 3.6, appendix D) ``o_t = M^-1 (B^T V* (m' - a_t) + h_t)``,
``O_t = -M^-1 B^T V* A_t`` share one factorization and never invert a possibly singular ``P'``.

Within the sweeps a step is relinearized at its belief and repeated while ``||b_t - x_t|| > theta``
(at most ``max_repeats`` times; the point moves by ``belief_rate (b_t - x_t)``). Where a C compiler is
available the sweeps run in compiled code (``raico/planning/csweep.c`` via :mod:`raico.planning.kernels`: the same
steps, repeats and formulas, the numbers equal to rounding).
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from raico.planning import kernels
from raico.planning.aico.boxqp import backward_boxed
from raico.planning.aico.options import AICOOptions
from raico.planning.problem import Problem, is_lti
from raico.plants.codegen.c_backend import check_shapes
from raico.plants.lazy import LazyModule

if TYPE_CHECKING:
    from raico.planning.aico.truncated import TruncatedSites
    from raico.planning.constraints import AugmentedLagrangian

blas, lapack = LazyModule("scipy.linalg.blas"), LazyModule("scipy.linalg.lapack")  # imported at first use


class NumericalError(RuntimeError):
    """A factorization failed or a message became non-finite."""


# -- small dense linear algebra with little call overhead ---------------------------------
def _chol(M: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """Lower Cholesky factor of the symmetric positive-definite ``M`` (``overwrite``: ``M``
    is scratch and, if Fortran-ordered, is factorized in place)."""
    c, info = lapack.dpotrf(M, lower=1, overwrite_a=overwrite)
    if info != 0:
        raise NumericalError(f"Cholesky failed (info={info})")
    return c


def _tri_inv(L: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """Inverse of a lower-triangular matrix (``overwrite``: ``L`` is scratch)."""
    Li, info = lapack.dtrtri(L, lower=1, overwrite_c=overwrite)
    if info != 0:
        raise NumericalError(f"triangular inverse failed (info={info})")
    return Li


def _is_constant(Z: np.ndarray) -> bool:
    """Whether the stacked array ``Z (T, ...)`` holds the same entry at every step."""
    return bool(np.array_equal(Z, np.broadcast_to(Z[0], Z.shape)))


def _block_form_dt(dynamics) -> float:
    """The time step with which the sweep kernel may take the semi-implicit Euler block form of ``C_t``
    (``A = J + e A_b``, ``B = e B_b``, checked step by step: the same matrices to rounding, fewer flops),
    or 0: the dense products. The learned (GP) models keep the dense products and their rounding: the
    thesis's learning figures flip with rounding-level changes of the planner."""
    from raico.plants.learned import LearnedDynamics

    dt = getattr(dynamics, "dt", None)
    if isinstance(dynamics, LearnedDynamics) or not isinstance(dt, (int, float)) or not math.isfinite(dt):
        return 0.0
    return float(dt) if dt > 0 else 0.0



class Sweeps:
    """Message state and per-step updates of one AICO run (arrays indexed by time).

    Layout (to keep the per-step work in few dense operations): a message and its
    linear term share one array, ``[P | p]`` of shape ``(n, n+1)``:
    ``SA[t] = [S_t^-1 | S_t^-1 s_t]`` (forward), ``VA[t] = [V_t^-1 | V_t^-1 v_t]``
    (backward), ``RA[t] = [R_t | r_t]`` (task); ``C[t] = [[B_t, A_t, -a_t], [0, 0, 1]]``
    ``(n+1, m+n+1)``, so that ``[V* | V* m'] C[t] = [V* B | V* A | V*(m' - a)]``;
    ``a_eff[t] = a_t + B_t H_t^-1 h_t`` is the mean drift under the control prior.

    Work that cannot change a result is skipped (same numbers as recomputing it):

    - relinearizing step ``t`` re-evaluates only what depends on ``x_t``: the dynamics unless
      the model is linear time-invariant (``raico.planning.problem.is_lti``), the task message only if some term
      costs step ``t`` (otherwise it is ``2 alpha I``, ``2 alpha x_t^[n-1]``);
    - the belief at ``t`` is recomputed only if its inputs changed, and the backward message
      is redone only if the dynamics at ``t`` changed, reusing ``[V* | V* m']`` (it depends
      on step ``t + 1`` only);
    - the dynamics of an LTI model are filled in once.

    The per-step kernels write into preallocated buffers, fuse additions into BLAS calls
    and use a triangular inverse and matrix products where OpenBLAS's small triangular
    solves are slow (see ``forward``, ``_vstar``, ``backward``).

    Compiled sweeps (``compiled = True`` and :func:`raico.planning.kernels.library` available): the
    same sweeps, settles and relinearizations run in C (``raico/planning/csweep.c``), which calls
    the dynamics' compiled linearization where the model has one (``c_linearizer``) and returns
    to Python only for what has none (a task term costing the step, other models' dynamics),
    see ``_sweep_compiled``. This numpy code is the fallback and the reference of the kernel.
    """

    compiled = True      # use the C kernel when it is available (tests switch it off)

    def __init__(self, problem: Problem, opts: AICOOptions):
        self.p = problem
        self.o = opts
        T, n, m = problem.T, problem.n_x, problem.n_u
        self.T, self.n, self.m = T, n, m
        self.q = opts.process_noise
        self.I = np.eye(n)
        self.qI = self.q * self.I
        # relinearization within the sweeps needs the beliefs, hence the forward messages;
        # without it (theta = inf) the forward messages cannot change the controller.
        self.relocate = math.isfinite(opts.theta) and opts.max_repeats > 0
        self.lti = is_lti(problem.dynamics)
        self.active = problem.active_state_terms()             # terms costing each step
        self.SA = np.zeros((T + 1, n, n + 1))
        self.SA[0, :, :n] = self.I / opts.start_variance
        self.SA[0, :, n] = problem.x0 / opts.start_variance
        self.VA = np.zeros((T + 1, n, n + 1))                  # V_T^-1 = 0 (end)
        # per-iteration linearization, buffers reused across iterations; an LTI model has
        # one C (and, with a constant control cost, one Qbar) shared by all steps (a
        # read-only broadcast view), filled in once
        if self.lti:
            self._C0 = np.zeros((n + 1, m + n + 1))
            self._C0[n, m + n] = 1.0
            self.C = np.broadcast_to(self._C0, (T, n + 1, m + n + 1))
        else:
            self.C = np.zeros((T, n + 1, m + n + 1))
            self.C[:, n, m + n] = 1.0
        self._C_filled = False
        self._Qbar = np.empty((T, n, n))
        self.RA = np.empty((T + 1, n, n + 1))
        self._lx = np.empty((T + 1, n))
        self.b = np.full((T + 1, n), np.nan)
        self.Z = np.zeros((T, m, n + 1))     # [-O_t | o_t] per step
        self.repeats = 0
        self.block_steps = 0     # compiled steps that took the semi-implicit Euler block form
        self._active_flags = np.array([bool(a) for a in self.active], dtype=np.uint8)
        self._kstate: tuple | None = None   # the kernel's state and the arrays it points to, on first use
        self._kwork: tuple | None = None    # the kernel's work arrays (blk, work, iwork), on first use
        self._ctask: Any = None   # compiled task messages (kernels.compile_task_set), on first use
        self._steps = np.arange(T + 1)
        self._task_memo: tuple | None = None   # (X, U, l_x, l_xx) of the last compiled cost's rows
        self.al: AugmentedLagrangian | TruncatedSites | None = None   # hard constraints (raico.planning.constraints), set by the caller
        self._al_model: tuple | None = None   # (R, r) the constraints add to the task messages, None: nothing
        self.box: tuple[np.ndarray, np.ndarray] | None = None   # (lo, hi) of the controls kept in the backward pass
        self.cross_K: np.ndarray | None = None   # the cross term's change of controls v = u + K x (cross.eliminate)
        # work buffers of the per-step kernels
        self._Pa = np.empty((n, n + 1))      # [P | p] of the forward / backward step
        self._Vs = np.empty((n, n + 1))      # [V* | V* m'] of the last backward step
        self._Ba = np.empty((n, n + 1))      # [B_t | B_t b_t] of a belief
        self._Y = np.empty((n, n))           # symmetrization

    # -- linearization -----------------------------------------------------------------
    def linearize_all(self, X: np.ndarray, U: np.ndarray, Xprev: np.ndarray,
                      alpha: float) -> None:
        """Dynamics, control and task messages along ``X (T+1, n)``, ``U (T, m)`` at once."""
        p, T, n, m = self.p, self.T, self.n, self.m
        self.X = X.copy()
        self.U = U
        self.Xprev = Xprev
        self.alpha = alpha
        p.set_nominal(X, U)
        ct = self._compiled_tasks()
        if ct is not None:
            kernels.set_task_controls(ct, U)                   # the joint terms' nominal controls
        self.H, self.h = p.quadratize_controls(U)
        al = self.al.model(X, U) if self.al is not None else None   # None where no constraint is active
        if al is not None:     # the constraints' control part: h = H u - l_u
            self.H = self.H + al[3]
            self.h = self.h + np.einsum("tij,tj->ti", al[3], U) - al[2]
        if self.lti:
            self._fill_lti(X, U)
        else:
            C = self.C
            A, a, B = self._linearize_dynamics(X[:-1], U)
            C[:, :n, :m] = B
            C[:, :n, m:m + n] = A
            np.negative(a, out=C[:, :n, m + n])
            self._check_finite(C)
        self._check_finite(self.H, self.h)
        self._control_marginals()
        RA, lx = self.RA, self._lx
        R = RA[:, :, :n]
        self._state_rows(X, U, ct, lx, R)
        self._al_model = None
        if al is not None:     # the constraints' state part, kept for the relinearizations within the sweeps
            lx += al[0]
            R += al[1]
            self._al_model = (al[1], np.einsum("tij,tj->ti", al[1], X) - al[0])
        np.matmul(R, X[:, :, None], out=RA[:, :, n:])          # r = l_xx x - l_x
        RA[:, :, n] -= lx
        if alpha:
            diag = RA.reshape(T + 1, n * (n + 1))[:, ::n + 2]  # R[:, i, i] (a view)
            diag += 2.0 * alpha
            RA[:, :, n] += 2.0 * alpha * Xprev
        self._check_finite(RA)
        self._2aI = 2.0 * alpha * self.I

    def _linearize_dynamics(self, X: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``linearize_trajectory`` along ``X (T, n)``, ``U (T, m)``: ``A (T, n, n)``, ``a (T, n)``, ``B (T, n, m)``,
        or ``(n, n)``, ``(n,)``, ``(n, m)`` for every step when all rows are the same bits (the default start:
        ``x0`` at every step, zero controls). Only on ``FastAnalyticDynamics``, whose batch linearizes each row
        alone with the same code: the one point's numbers are every step's, at ``1/T`` of the cost."""
        from raico.plants.fast_analytic import FastAnalyticDynamics

        dyn = self.p.dynamics
        if isinstance(dyn, FastAnalyticDynamics) and _rows_identical(X) and _rows_identical(U):
            A, a, B = dyn.linearize_trajectory(X[:1], U[:1])
            return A[0], a[0], B[0]
        return dyn.linearize_trajectory(X, U)

    def _compiled_tasks(self):
        """The compiled task messages (``kernels.compile_task_set``, built on first use) when the
        sweeps run compiled, else ``None``."""
        if not self.compiled or kernels.library() is None:
            return None
        if self._ctask is None:
            self._ctask = kernels.compile_task_set(self.p) or False
        return self._ctask or None

    def cost(self, X: np.ndarray, U: np.ndarray) -> float:
        """``problem.cost(X, U)`` with the state terms' values compiled where the task messages are
        (the same sums in another order: equal to rounding); with hard constraints (``al``) the merit: plus
        the augmented Lagrangian's terms (0 where none is active)."""
        c = self._cost(X, U)
        if self.al is not None and math.isfinite(c):
            c += self.al.value(X, U)
        return c

    def _cost(self, X: np.ndarray, U: np.ndarray) -> float:
        ct = self._compiled_tasks()
        if ct is None or not (np.isfinite(X).all() and np.isfinite(U).all()):
            return self.p.cost(X, U)
        kernels.set_task_controls(ct, U)     # the joint terms' costs at these controls (reset by linearize_all)
        # the rows' derivatives too (the same pass, the same numbers): the next iteration linearizes at
        # this rollout when it is accepted, and takes them from here
        derivs, per_step = kernels.task_rows(ct, self.T, X, self._steps, costs=True)
        self._task_memo = (X.copy(), np.array(U, dtype=float), *derivs)
        with np.errstate(all="ignore"):
            c = float(per_step.sum()) + sum((float(np.sum(t.value(U))) for t in self.p.control_terms), 0.0)
        return c if math.isfinite(c) else math.inf

    def _fill_lti(self, X: np.ndarray, U: np.ndarray) -> None:
        """A linear time-invariant model's one linearization ``[B, A, -a]`` into ``C0``, once per solve."""
        if not self._C_filled:
            A, a, B = self.p.dynamics.linearize(X[0], U[0])
            self._C0[:self.n] = np.column_stack([B, A, -a])
            self._check_finite(self._C0)
            self._C_filled = True

    def _state_rows(self, X: np.ndarray, U: np.ndarray, ct, lx: np.ndarray, R: np.ndarray) -> None:
        """The state terms' gradient ``lx (T+1, n)`` and Gauss-Newton Hessian ``R = l_xx (T+1, n, n)`` at
        ``X, U``, in place: the last cost's rows where ``X, U`` are its point, else the compiled task rows
        (``ct``, a finite ``X``), else the problem's own derivatives."""
        memo = self._task_memo
        if memo is not None and np.array_equal(X, memo[0]) and np.array_equal(U, memo[1]):
            lx[:], R[:] = memo[2], memo[3]                     # the last cost's rows: the same numbers
        elif ct is not None and np.isfinite(X).all():           # R = l_xx, compiled
            (lx[:], R[:]), _ = kernels.task_rows(ct, self.T, X, self._steps)
        else:
            self.p.state_derivatives(X, out=(lx, R))           # R = l_xx

    def _control_marginals(self) -> None:
        """``Qbar_t = q I + B_t H_t^-1 B_t^T`` and ``a_eff_t = a_t + B_t H_t^-1 h_t`` for all t."""
        n, m, C = self.n, self.m, self.C
        B = C[:, :n, :m]
        const_H = _is_constant(self.H)
        try:
            if const_H:
                np.linalg.cholesky(self.H[0])
                self.Hinv = np.broadcast_to(np.linalg.inv(self.H[0]), self.H.shape)
            else:
                np.linalg.cholesky(self.H)
                self.Hinv = np.linalg.inv(self.H)
        except np.linalg.LinAlgError as e:
            raise NumericalError("control Hessian H_t is not positive definite") from e
        if const_H and (self.lti or _is_constant(B)):
            BHi = B[0] @ self.Hinv[0]
            Q0 = BHi @ B[0].T + self.qI
            if self.lti:     # never relinearized: one shared matrix
                self.Qbar = np.broadcast_to(Q0, self._Qbar.shape)
            else:
                self.Qbar = self._Qbar
                self.Qbar[:] = Q0
            self.a_eff = self.h @ BHi.T - C[:, :n, m + n]
        else:
            BHi = B @ self.Hinv
            self.Qbar = self._Qbar
            np.matmul(BHi, np.swapaxes(B, -1, -2), out=self.Qbar)
            self.Qbar += self.qI
            self.a_eff = np.einsum("tij,tj->ti", BHi, self.h) - C[:, :n, m + n]

    def relinearize(self, t: int, dynamics: bool = True) -> tuple[bool, bool]:
        """Relinearize step ``t`` at ``self.X[t]``: the dynamics (if ``dynamics``, ``t < T`` and they
        depend on the state) and the task message (if a term costs step ``t``).

        Returns whether ``(dynamics, task message)`` changed.
        """
        dyn = dynamics and t < self.T and not self.lti
        if dyn:
            self._relinearize_dynamics(t)
        task = bool(self.active[t])
        if task:
            self._relinearize_task(t)
        self.repeats += 1
        return dyn, task

    def _relinearize_dynamics(self, t: int) -> None:
        """``C[t]``, ``Qbar[t]``, ``a_eff[t]`` at ``(X[t], U[t])``."""
        n, m = self.n, self.m
        A, a, B = self.p.dynamics.linearize(self.X[t], self.U[t])
        Ct = self.C[t]
        Ct[:n, :m], Ct[:n, m:m + n] = B, A
        np.negative(a, out=Ct[:n, m + n])
        self._check_finite(Ct)
        BHi = B @ self.Hinv[t]
        Qb = np.matmul(BHi, B.T, out=self.Qbar[t])
        Qb += self.qI
        self.a_eff[t] = a + BHi @ self.h[t]

    def _relinearize_task(self, t: int) -> None:
        """The task message ``RA[t]`` at ``X[t]`` (only the terms that cost step ``t``)."""
        x, n = self.X[t], self.n
        lx, lxx = self.p.point_state_derivatives(x, t, self.active[t])
        out = self.RA[t]
        np.add(lxx, self._2aI, out=out[:, :n])
        out[:, n] = lxx @ x - lx + 2.0 * self.alpha * self.Xprev[t]
        if self._al_model is not None:   # the constraints' quadratic model of this iteration's linearization
            out[:, :n] += self._al_model[0][t]
            out[:, n] += self._al_model[1][t]
        self._check_finite(out)

    @staticmethod
    def _check_finite(*arrs: np.ndarray) -> None:
        """Raise ``NumericalError`` on NaN or inf (or sums overflowing to them)."""
        for z in arrs:
            if not math.isfinite(z.sum()):
                raise NumericalError("non-finite linearization or task message")

    # -- messages -----------------------------------------------------------------------
    def forward(self, t: int) -> None:
        """Forward message ``[S_t^-1 | S_t^-1 s_t]`` at ``t >= 1`` from step ``t-1``:
        ``P = S^-1 + R``, ``s_t = A P^-1 (S^-1 s + r) + a_eff``, ``S_t = A P^-1 A^T + Qbar``.

        With ``P = L L^T``: ``W^T = A L^-T`` (one right-sided triangular solve),
        ``A P^-1 A^T = W^T W``, ``A P^-1 p = W^T (L^-1 p)``; ``S_t^-1 = L_S^-T L_S^-1`` from
        ``S_t = L_S L_S^T``.
        """
        n, m = self.n, self.m
        Pa = np.add(self.SA[t - 1], self.RA[t - 1], out=self._Pa)
        L = _chol(Pa[:, :n])
        WT = blas.dtrsm(1.0, L, self.C[t - 1, :n, m:m + n], side=1, lower=1, trans_a=1)
        y = blas.dtrsv(L, Pa[:, n], lower=1)                  # L^-1 p
        # S = W^T W + Qbar in one BLAS call, Fortran-ordered for LAPACK (Qbar^T = Qbar)
        S = blas.dgemm(1.0, WT, WT, trans_b=1, beta=1.0, c=self.Qbar[t - 1].T)
        Ci = _tri_inv(_chol(S, overwrite=True), overwrite=True)
        out = self.SA[t]
        Sinv = np.matmul(Ci.T, Ci, out=out[:, :n])
        np.matmul(Sinv, WT @ y + self.a_eff[t - 1], out=out[:, n])

    def _vstar(self, Pa: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``[V* | V* m']`` from ``Pa = [P' | p']``: ``V* = (q I + P'^-1)^-1 = (I + q P')^-1 P'``.

        With ``s = q ||[P' | p']||_F >= q lambda_max(P')``: the Neumann series
        ``sum_k (-q P')^k [P' | p']`` truncated after ``K <= 3`` terms when
        ``s^(K+1) <= 1e-16`` (relative truncation error), else a Cholesky factorization of
        the well-conditioned ``I + q P'``. ``out``: optional ``(n, n+1)`` result buffer.
        """
        q, n = self.q, self.n
        flat = Pa.reshape(-1)
        s = q * math.sqrt(float(flat @ flat))
        P = Pa[:, :n]
        if s <= 1e-4:
            K = 1 if s <= 1e-8 else (2 if s <= 10 ** (-16 / 3) else 3)
            # Horner: Y <- Pa - q P' Y, K times from Y = Pa; each step one BLAS call on the
            # transposes, which are Fortran-ordered: Y^T <- Pa^T - q Y^T P'^T
            PaT, PT = Pa.T, np.asfortranarray(P.T)
            YT = PaT
            for _ in range(K):
                YT = blas.dgemm(-q, YT, PT, beta=1.0, c=PaT)
            if out is None:
                return YT.T
            out[...] = YT.T
            return out
        Ei = _tri_inv(_chol(self.I + q * P))
        res = Ei.T @ (Ei @ Pa)
        if out is None:
            return res
        out[...] = res
        return out

    def backward(self, t: int, reuse_vstar: bool = False) -> None:
        """Backward message ``[V_t^-1 | V_t^-1 v_t]`` and the controller ``o_t, O_t``
        (``t <= T-1``), with ``P' = V_{t+1}^-1 + R_{t+1}`` and ``M = B^T V* B + H``.

        By Woodbury ``(P'^-1 + Qbar)^-1 = V* - V* B M^-1 B^T V*``, hence
        ``V_t^-1 = A^T V* A - (B^T V* A)^T M^-1 B^T V* A`` and
        ``V_t^-1 v_t = A^T V*(m' - a_eff) - ... = A^T V*(m' - a) - (B^T V* A)^T o_t`` (the
        ``h`` terms of ``a_eff`` and of ``o_t`` cancel exactly). With ``M = L L^T`` and
        ``K = L^-1 [B^T V* A | B^T V*(m' - a) + h]`` (an explicit ``L^-1``: small triangular
        solves are slow in OpenBLAS): ``[-O_t | o_t] = L^-T K`` and
        ``[V_t^-1 | V_t^-1 v_t] = [A^T V* A | A^T V*(m' - a)] - K[:, :n]^T K``.

        ``reuse_vstar``: step ``t + 1`` is unchanged since the last call (a redo after
        relinearizing step ``t``), so ``[V* | V* m']`` is reused.
        """
        n, m = self.n, self.m
        if not reuse_vstar:
            self._vstar(np.add(self.VA[t + 1], self.RA[t + 1], out=self._Pa), out=self._Vs)
        Ct = self.C[t]
        G = self._Vs @ Ct                                       # [V*B | V*A | V*(m'-a)]
        FB = Ct[:n, :m].T @ G                                   # B^T G, (m, m+n+1)
        FA = Ct[:n, m:m + n].T @ G[:, m:]                       # A^T [V*A | V*(m'-a)]
        FB[:, :m] += self.H[t]
        Li = _tri_inv(_chol(FB[:, :m]))
        rhs = FB[:, m:]                                         # [B^T V* A | B^T V*(m'-a)]
        rhs[:, n] += self.h[t]
        if self.box is not None and backward_boxed(self, t, FB[:, :m], rhs, FA):
            return
        K = Li @ rhs
        np.matmul(Li.T, K, out=self.Z[t])                       # [-O_t | o_t]
        FA -= K[:, :n].T @ K                                    # [V_t^-1 | V_t^-1 v_t]
        out = self.VA[t]
        Y = np.add(FA[:, :n], FA[:, :n].T, out=self._Y)
        np.multiply(Y, 0.5, out=out[:, :n])
        out[:, n] = FA[:, n]

    def belief(self, t: int) -> np.ndarray:
        """Belief mean ``b_t (n,)`` from ``B_t = S_t^-1 + V_t^-1 + R_t``."""
        n = self.n
        Ba = np.add(self.SA[t], self.VA[t], out=self._Ba)
        Ba += self.RA[t]
        _, b, info = lapack.dposv(Ba[:, :n], Ba[:, n], lower=1)
        if info != 0:
            raise NumericalError(f"Cholesky failed (info={info})")
        self.b[t] = b
        return b

    def settle(self, t: int, backward: bool = False) -> None:
        """Algorithm 1 at step ``t`` (message already updated): while the belief is more than
        ``theta`` from the linearization point, move the point towards it, relinearize step
        ``t`` (in the forward sweep its dynamics once, at the final point: nothing reads them
        before), redo the backward message (``backward``: in the backward sweep, where it
        depends on the dynamics at ``t``), and repeat. The belief is recomputed only when
        something it depends on changed (else it is the same)."""
        o = self.o
        x = self.X[t]
        b = self.belief(t)
        moved = False
        for _ in range(o.max_repeats):
            d = b - x
            if not math.sqrt(float(d @ d)) > o.theta:
                break
            x += o.belief_rate * d
            moved = True
            # forward sweep: nothing reads the dynamics at t before the step is left (the belief
            # does not depend on them): relinearized once below, at the final point
            dyn, task = self.relinearize(t, dynamics=backward)
            redo = backward and dyn
            if redo:
                self.backward(t, reuse_vstar=True)
            if redo or task:
                b = self.belief(t)
        if moved and not backward and t < self.T and not self.lti:
            self._relinearize_dynamics(t)

    def sweep(self) -> None:
        """One forward (t = 1..T) and one backward (t = T-1..0) sweep with relinearization;
        without relinearization (``theta = inf``) only the backward sweep."""
        lib = kernels.library() if self.compiled and self.box is None else None   # (the box: in Python)
        if lib is not None:
            self._sweep_compiled(lib)
        elif self.relocate:
            for t in range(1, self.T + 1):
                self.forward(t)
                self.settle(t)        # the forward message at t does not depend on step t
            for t in range(self.T - 1, -1, -1):
                self.backward(t)
                self.settle(t, backward=True)
        else:
            for t in range(self.T - 1, -1, -1):
                self.backward(t)
        if not np.isfinite(self.Z).all():
            raise NumericalError("non-finite controller")
        self.o_ = self.Z[:, :, self.n].copy()                 # (T, m)
        self.O_ = -self.Z[:, :, :self.n]                       # (T, m, n)

    def beliefs(self) -> np.ndarray:
        """Belief means ``(T+1, n)`` at the current linearization (``theta = inf`` mode:
        computed once, with a forward sweep and no relinearization)."""
        lib = kernels.library() if self.compiled else None
        if not self.relocate and lib is not None:
            st = self._kernel_state(lib)
            self._kernel_check(st, lib.sweep_beliefs(ctypes.byref(st)))
        elif not self.relocate:
            for t in range(1, self.T + 1):
                self.forward(t)
            for t in range(self.T + 1):
                self.belief(t)
        return self.b.copy()

    # -- the compiled sweeps -------------------------------------------------------------------
    @staticmethod
    def _addr(Z: np.ndarray, inner: int) -> tuple[int, int]:
        """Data address of ``Z (T, ...)`` and its step stride in doubles (0 for a broadcast
        view); the trailing block must be C-contiguous (``inner`` doubles)."""
        assert Z.dtype == np.float64 and Z[0].flags.c_contiguous and Z[0].size == inner
        return Z.__array_interface__["data"][0], Z.strides[0] // 8

    def _kernel_state(self, lib) -> kernels.SweepState:
        """The kernel's view of this iteration's arrays (rebuilt per sweep: ``linearize_all``
        replaces some of them)."""
        T, n, m, o = self.T, self.n, self.m, self.o
        self._check_kernel_shapes()
        st = kernels.SweepState()
        st.T, st.n, st.m = T, n, m
        st.relocate, st.max_repeats = int(self.relocate), o.max_repeats
        st.q, st.theta, st.rate = self.q, o.theta, o.belief_rate
        if self.a_eff.dtype != np.float64 or not self.a_eff.flags.c_contiguous:
            self.a_eff = np.ascontiguousarray(self.a_eff, dtype=float)
        keep = [self.H, self.h]
        for name in ("SA", "VA", "RA", "a_eff", "X", "U", "b", "Z"):
            Z = getattr(self, name)
            if not Z.flags.c_contiguous or Z.dtype != np.float64:
                if name not in ("U",):
                    raise AssertionError(f"{name} must be C-contiguous float64")
                Z = np.ascontiguousarray(Z, dtype=float)
                keep.append(Z)
            setattr(st, name, Z.__array_interface__["data"][0])
        h = np.ascontiguousarray(self.h, dtype=float)
        keep.append(h)
        st.h = h.__array_interface__["data"][0]
        st.C, st.C_s = self._addr(self.C, (n + 1) * (m + n + 1))
        st.Qbar, st.Qbar_s = self._addr(self.Qbar, n * n)
        H = self.H if self.H[0].flags.c_contiguous else np.ascontiguousarray(self.H)
        Hinv = self.Hinv if self.Hinv[0].flags.c_contiguous else np.ascontiguousarray(self.Hinv)
        keep += [H, Hinv]
        st.H, st.H_s = self._addr(H, m * m)
        st.Hinv, st.Hinv_s = self._addr(Hinv, m * m)
        st.active = self._active_flags.ctypes.data
        lin = None
        if self.lti:
            st.dyn_mode = kernels.DYN_NONE
        else:
            getter = getattr(self.p.dynamics, "c_linearizer", None)
            lin = getter() if getter is not None else None
            st.dyn_mode = kernels.DYN_PY if lin is None else kernels.DYN_C
            if lin is not None:
                st.lin_fn, st.lin_ctx = lin[0], lin[1]
            st.dt = _block_form_dt(self.p.dynamics)
        if self._ctask is None:
            self._ctask = kernels.compile_task_set(self.p) or False
        if self._ctask and self._al_model is None:
            # (the compiled task messages know no constraints: with active ones the kernel asks Python for them)
            st.task_fn, st.task_ctx = self._ctask[0], self._ctask[1]
        st.alpha = self.alpha
        Xprev = np.ascontiguousarray(self.Xprev, dtype=float)
        keep.append(Xprev)
        st.Xprev = Xprev.ctypes.data
        blk, work, iwork = self._kernel_work(lib)
        blk[:] = 0                             # the kernel's per-step note of C[t]'s block form: not known yet
        st.blk = blk.ctypes.data
        st.w, st.iw, st.sp_state = work.ctypes.data, iwork.ctypes.data, 0
        self._kstate = (st, work, iwork, keep, lin)       # keep everything the kernel points to alive
        return st

    def _kernel_work(self, lib) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The kernel's work arrays, allocated once per run and reused by every sweep (fresh pages per
        sweep cost page faults): ``blk (T,)`` uint8, ``work`` and ``iwork`` of the sizes
        ``sweep_work_size`` / ``sweep_iwork_size`` give for ``(n, m)``, checked on every reuse. The
        kernel writes every entry of them before reading it within a call (scratch; ``blk`` is zeroed
        by the caller), so nothing of an earlier sweep is read."""
        T, n, m = self.T, self.n, self.m
        sizes = (T, lib.sweep_work_size(n, m), lib.sweep_iwork_size(n, m))
        if self._kwork is None or tuple(a.size for a in self._kwork) != sizes:
            self._kwork = (np.zeros(T, dtype=np.uint8), np.empty(sizes[1]), np.empty(sizes[2], dtype=np.intc))
        return self._kwork

    def _check_kernel_shapes(self) -> None:
        """The shapes ``sweep_t`` of csweep.c accepts (its layout comment): ``ValueError`` before any
        call, never a read or write past an array (T >= 1, n >= 1, m >= 1)."""
        T, n, m = self.T, self.n, self.m
        if min(T, n, m) < 1:
            raise ValueError(f"sweep_run: T, n, m must be >= 1, got {T}, {n}, {m}")
        msg = {"SA": (T + 1, n, n + 1), "VA": (T + 1, n, n + 1), "RA": (T + 1, n, n + 1), "b": (T + 1, n),
               "X": (T + 1, n), "Xprev": (T + 1, n), "U": (T, m), "Z": (T, m, n + 1), "a_eff": (T, n),
               "C": (T, n + 1, m + n + 1), "Qbar": (T, n, n), "H": (T, m, m), "Hinv": (T, m, m), "h": (T, m),
               "_active_flags": (T + 1,)}
        check_shapes("sweep_run", **{k: (getattr(self, k), shape) for k, shape in msg.items()})

    def _kernel_check(self, st: kernels.SweepState, rc: int) -> None:
        if rc == kernels.ERR_CHOL:
            raise NumericalError(f"Cholesky failed (info={st.err_info})")
        if rc == kernels.ERR_LIN:
            raise NumericalError("non-finite linearization or task message")

    def _sweep_compiled(self, lib) -> None:
        """``sweep`` in C: the kernel returns to Python only for relinearizations it cannot do
        (bit ``NEED_DYN``: the model's dynamics; ``NEED_TASK``: the task terms of step ``t``),
        with the point of step ``t`` already moved; then it resumes where it stopped."""
        st = self._kernel_state(lib)
        st.phase, st.t = (kernels.PH_FWD, 1) if self.relocate else (kernels.PH_BWD, self.T - 1)
        st.sub = st.repeats = st.block_steps = 0
        run, ref = lib.sweep_run, ctypes.byref(st)
        while True:
            rc = run(ref)
            if rc <= 0:
                break
            t = st.t
            if rc & kernels.NEED_DYN:
                self._relinearize_dynamics(t)
            if rc & kernels.NEED_TASK:
                self._relinearize_task(t)
        self._kernel_check(st, rc)
        self.repeats += st.repeats
        self.block_steps += st.block_steps


def _rows_identical(Z: np.ndarray) -> bool:
    """Whether every row of ``Z (K, ...)`` float64 has the bits of the first (NaN rows included)."""
    Z = np.asarray(Z)
    if Z.dtype != np.float64 or Z.shape[0] == 0:
        return False
    bits = np.ascontiguousarray(Z).view(np.uint64)
    return bool((bits == bits[:1]).all())


def bounded_rollout(problem: Problem, o: np.ndarray, O: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``problem.bounded_rollout`` with the sweeps' kernel switch (tests turn the compiled code off)."""
    return problem.bounded_rollout(o, O, kernel=Sweeps.compiled)


def backward_sweep_at_start(problem: Problem) -> tuple[Callable[[], None], bool]:
    """One backward sweep of ``problem`` at a fixed linearization (the start held, zero controls, no
    relinearization: ``theta = inf``), as a callable to time (call it inside :func:`single_threaded_blas`),
    and whether the kernel may take the semi-implicit Euler block form: the message arithmetic on its own
    (``bench.flops``)."""
    opts = dataclasses.replace(AICOOptions(), theta=math.inf)
    T = problem.T
    X, U = np.tile(problem.x0, (T + 1, 1)), np.zeros((T, problem.n_u))
    sw = Sweeps(problem, opts)
    sw.linearize_all(X, U, X, 1.0)
    return sw.sweep, _block_form_dt(problem.dynamics) > 0
