"""AICO and R-AICO: approximate inference control with Gaussian messages.

One implementation: R-AICO is AICO with ``alpha > 0`` (thesis §3.5, Algorithm 1).

Model per iteration (shapes: ``n = n_x``, ``m = n_u``):

- dynamics linearized ``x_{t+1} ~ A_t x_t + a_t + B_t u_t`` with process noise ``Q = q I``;
- task messages ``N[x_t | r_t, R_t]`` (cost ``1/2 x^T R x - r^T x``), plus the R-AICO term
  ``alpha ||x_t - x_t^[n-1]||^2`` (``R += 2 alpha I``, ``r += 2 alpha x_t^[n-1]``) at every
  step, ``x^[n-1]`` being the trajectory the iteration started from;
- control prior ``N[u_t | h_t, H_t]`` from the control terms at the current controls, so
  with controls marginalized ``x_{t+1} | x_t ~ N(A x + a + B H^-1 h, Qbar)`` with
  ``Qbar = Q + B H^-1 B^T``.

Messages: forward (moment form ``s_t, S_t``; stored as precision ``S_t^-1`` and
``S_t^-1 s_t``), backward in canonical form ``V_t^-1, V_t^-1 v_t`` (no inverse of ``A``,
``V_T^-1 = 0``), belief ``B_t = S_t^-1 + V_t^-1 + R_t``, ``b_t = B_t^-1 (...)``; start
``S_0 = start_variance I`` around ``x0``. With ``P' = V_{t+1}^-1 + R_{t+1}`` (precision)
the backward step uses ``V* = (Q + P'^-1)^-1 = (I + q P')^-1 P'`` and
``M = B^T V* B + H``; by Woodbury ``(P'^-1 + Qbar)^-1 = V* - V* B M^-1 B^T V*``, so the
message and the controller (thesis eq. 3.6, appendix D)
``o_t = M^-1 (B^T V* (m' - a_t) + h_t)``, ``O_t = -M^-1 B^T V* A_t`` share one
factorization and never invert a possibly singular ``P'``.

Algorithm 1: the dynamics and the task messages are linearized along the whole trajectory
at once at the start of an iteration; during the forward (t = 1..T) and backward
(t = T-1..0) sweeps a time step is relinearized at its belief and repeated while
``||b_t - x_t|| > theta`` (at most ``max_repeats`` times; the point moves by
``belief_rate (b_t - x_t)``, plain AICO's learning rate). After the sweeps the controller
is rolled out on the true planning dynamics (``dynamics.step``) to give the next
trajectory and the reported cost.

Speed without changing a number (beyond rounding): the sweeps redo only what a
relinearization changes (see ``_Sweeps``), relinearizing a step evaluates only the terms
that cost it, and the task maps evaluated for the cost of a rollout are reused by the next
iteration's linearization at that trajectory (``ViaPoint``'s memo). Where a C compiler is
available the sweeps, with their relinearizations, run in compiled code (``planning/csweep.c``
via :mod:`planning.kernels`: the same steps, repeats and formulas, the numbers equal to
rounding); the dynamics and the task messages are linearized there too where the model and the
terms have compiled counterparts (``FastAnalyticDynamics``, the tree task maps), else the
kernel asks Python for them, step by step.
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from planning import kernels
from planning.constraints import AugmentedLagrangian, Constraint, ControlBox, StateBox
from planning.driver import Iterate, Status, Step, Stop, cost_change_within, drive
from planning.problem import (
    Bounds,
    Callback,
    OptionsBase,
    Problem,
    Result,
    bounds_status,
    check_range,
    is_lti,
    single_threaded_blas,
)
from plants.codegen.c_backend import check_shapes
from plants.dynamics import rollout
from plants.lazy import LazyModule

blas, lapack = LazyModule("scipy.linalg.blas"), LazyModule("scipy.linalg.lapack")  # imported at first use


SCHEDULES = ("fixed", "adaptive", "robust")


@dataclass(frozen=True)
class AICOOptions(OptionsBase):
    """Options of AICO / R-AICO (frozen; ``from_dict`` rejects unknown keys).

    Attributes:
        iterations: maximum number of iterations (>= 1).
        alpha: R-AICO regularization ``alpha^[1]`` (>= 0; 0 is plain AICO), per (state unit)^2.
        gamma: ``alpha^[n] = alpha^[n-1] gamma`` (> 0).
        theta: relinearization threshold on ``||b_t - x_t||`` (state units; ``inf``: never
            relinearize within the sweeps; then the forward sweep is skipped, as it cannot
            change the controller, and run once at the end for the beliefs).
        max_repeats: cap on the repeats of one time step within a sweep (>= 0); when it is
            reached the step keeps its last linearization.
        belief_rate: plain AICO's learning rate on the belief (state) update: a repeat moves
            the linearization point ``x_t += rate (b_t - x_t)``, in (0, 1] (Algorithm 1, line 13).
        controller_rate: the other classic learning rate (Algorithm 1, line 18): the controller of
            an iteration is ``(1 - rate)`` times the previous one plus ``rate`` times the new one,
            ``o, O`` blended, in (0, 1] (1: the new controller, AICO and R-AICO as the thesis).
        process_noise: ``q`` in ``Q = q I`` (> 0).
        start_variance: ``S_0 = start_variance I`` (tight prior around ``x0``, > 0).
        tol_rel: converged when the relative cost change of two iterations is at most this.
        divergence_factor: diverged when the cost exceeds this times the initial cost.
        schedule: ``"fixed"`` (thesis: ``alpha^[n] = alpha^[n-1] gamma`` whatever happens) or
            ``"adaptive"`` (beyond the thesis, trust-region style: after an iteration that lowers
            the cost ``alpha *= shrink`` (not below ``alpha_min``); after one that raises it the
            iterate is rejected, the previous one kept and ``alpha *= grow`` (not above
            ``alpha_max``) for the retry; ``gamma`` is not used). Each trial counts as an iteration.
            ``"robust"`` (beyond the thesis; Levenberg-Marquardt style, invariant to the cost's
            scale): the regularization is ``alpha^[n] = lambda^[n] kappa``, ``kappa`` the mean
            diagonal of the state cost's Gauss-Newton Hessian at the first trajectory (the cost's
            curvature per (state unit)^2 and step; the control Hessian's if no state term costs
            anything), ``lambda^[1] = alpha`` (relative); the process noise and the start
            variance are taken per unit of that curvature (``q / kappa``,
            ``start_variance / kappa``), so that a cost multiplied by ``c`` gives the same
            iterates. Each trial linearizes once, at the current iterate (``theta``,
            ``max_repeats`` and ``belief_rate`` are not used: the step is the minimizer of the
            regularized quadratic model the acceptance test compares it with). A trial is accepted when its actual decrease is at least ``accept`` times
            the decrease the quadratic model of the cost at the current iterate predicts along
            the step (any decrease if the model predicts none); then ``lambda /= lm_factor``
            when the ratio is at least ``decrease_above``; a rejected trial (or a numerical
            failure of the sweeps) keeps the iterate and ``lambda *= lm_factor`` (crocoddyl
            FDDP's x10 and /10), within ``[lambda_min, lambda_max]``; a trial rejected at
            ``lambda_max`` stops the run (``max-iterations``). A start that is no trajectory of
            the dynamics (x0 held) has no feasible cost to compare with: its first finite
            trial is taken (as the fixed schedule takes it), with ``lambda *= lm_factor`` if
            it costs more than the start. Details: ``lambda`` falls by Nielsen's factor
            ``max(1/lm_factor, 1 - (2 rho - 1)^3)`` and grows by 2, 4, 8, then ``lm_factor`` per
            rejection in a row (by ``lm_factor`` at once when no rollout of the trial was finite:
            no ratio to go by); before a rejection the feedforward is shortened to 1/2 and 1/4
            about the current iterate (``LINE_SEARCH``); a failed factorization also raises the
            process noise by 10 (``NOISE_MAX``); ``ASCENTS`` rejections in a row of steps the model
            rightly predicts to raise the cost stop the run (converged: no descent direction).
            Each trial counts as an iteration.
        shrink, grow, alpha_min, alpha_max: the adaptive schedule's factors and bounds.
        lm_factor, accept, decrease_above, lambda_min, lambda_max: the robust schedule's.
    """

    iterations: int = 100
    alpha: float = 0.0
    gamma: float = 1.0
    theta: float = 0.1
    max_repeats: int = 3
    belief_rate: float = 1.0
    controller_rate: float = 1.0
    process_noise: float = 1e-9
    start_variance: float = 1e-10
    tol_rel: float = 1e-9
    divergence_factor: float = 1e6
    schedule: str = "fixed"
    shrink: float = 0.3
    grow: float = 4.0
    alpha_min: float = 1e-4
    alpha_max: float = 1e8
    lm_factor: float = 10.0
    accept: float = 0.1
    decrease_above: float = 0.5
    lambda_min: float = 1e-9
    lambda_max: float = 1e9

    def validate(self) -> None:
        if self.schedule not in SCHEDULES:
            raise ValueError(f"option schedule must be one of {', '.join(SCHEDULES)}, got {self.schedule!r}")
        check_range("lm_factor", self.lm_factor, lo=1.0, lo_open=True)
        check_range("accept", self.accept, lo=0.0, hi=1.0)
        check_range("decrease_above", self.decrease_above, lo=self.accept)
        check_range("lambda_min", self.lambda_min, lo=0.0, lo_open=True)
        check_range("lambda_max", self.lambda_max, lo=self.lambda_min)
        check_range("shrink", self.shrink, lo=0.0, hi=1.0, lo_open=True)
        check_range("grow", self.grow, lo=1.0, lo_open=True)
        check_range("alpha_min", self.alpha_min, lo=0.0, lo_open=True)
        check_range("alpha_max", self.alpha_max, lo=self.alpha_min)
        if self.schedule != "fixed" and not self.alpha > 0:
            raise ValueError(f"the {self.schedule} schedule needs alpha > 0 (R-AICO)")
        check_range("iterations", self.iterations, lo=1, integer=True)
        check_range("alpha", self.alpha, lo=0.0)
        check_range("gamma", self.gamma, lo=0.0, lo_open=True)
        check_range("theta", self.theta, lo=0.0, lo_open=True)
        check_range("max_repeats", self.max_repeats, lo=0, integer=True)
        check_range("belief_rate", self.belief_rate, lo=0.0, hi=1.0, lo_open=True)
        check_range("controller_rate", self.controller_rate, lo=0.0, hi=1.0, lo_open=True)
        check_range("process_noise", self.process_noise, lo=0.0, lo_open=True)
        check_range("start_variance", self.start_variance, lo=0.0, lo_open=True)
        check_range("tol_rel", self.tol_rel, lo=0.0)
        check_range("divergence_factor", self.divergence_factor, lo=1.0, lo_open=True)
        if not math.isfinite(self.alpha) or not math.isfinite(self.gamma):
            raise ValueError("options alpha and gamma must be finite")


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
    from plants.learned import LearnedDynamics

    dt = getattr(dynamics, "dt", None)
    if isinstance(dynamics, LearnedDynamics) or not isinstance(dt, (int, float)) or not math.isfinite(dt):
        return 0.0
    return float(dt) if dt > 0 else 0.0


class _Sweeps:
    """Message state and per-step updates of one AICO run (arrays indexed by time).

    Layout (to keep the per-step work in few dense operations): a message and its
    linear term share one array, ``[P | p]`` of shape ``(n, n+1)``:
    ``SA[t] = [S_t^-1 | S_t^-1 s_t]`` (forward), ``VA[t] = [V_t^-1 | V_t^-1 v_t]``
    (backward), ``RA[t] = [R_t | r_t]`` (task); ``C[t] = [[B_t, A_t, -a_t], [0, 0, 1]]``
    ``(n+1, m+n+1)``, so that ``[V* | V* m'] C[t] = [V* B | V* A | V*(m' - a)]``;
    ``a_eff[t] = a_t + B_t H_t^-1 h_t`` is the mean drift under the control prior.

    Work that cannot change a result is skipped (same numbers as recomputing it):

    - relinearizing step ``t`` re-evaluates only what depends on ``x_t``: the dynamics unless
      the model is linear time-invariant (``planning.problem.is_lti``), the task message only if some term
      costs step ``t`` (otherwise it is ``2 alpha I``, ``2 alpha x_t^[n-1]``);
    - the belief at ``t`` is recomputed only if its inputs changed, and the backward message
      is redone only if the dynamics at ``t`` changed, reusing ``[V* | V* m']`` (it depends
      on step ``t + 1`` only);
    - the dynamics of an LTI model are filled in once.

    The per-step kernels write into preallocated buffers, fuse additions into BLAS calls
    and use a triangular inverse and matrix products where OpenBLAS's small triangular
    solves are slow (see ``forward``, ``_vstar``, ``backward``).

    Compiled sweeps (``compiled = True`` and :func:`planning.kernels.library` available): the
    same sweeps, settles and relinearizations run in C (``planning/csweep.c``), which calls
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
        self.al: AugmentedLagrangian | None = None   # hard constraints (planning.constraints), set by the caller
        self._al_model: tuple | None = None   # (R, r) the constraints add to the task messages, None: nothing
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
            if not self._C_filled:
                A, a, B = p.dynamics.linearize(X[0], U[0])
                self._C0[:n] = np.column_stack([B, A, -a])
                self._check_finite(self._C0)
                self._C_filled = True
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
        memo = self._task_memo
        if memo is not None and np.array_equal(X, memo[0]) and np.array_equal(U, memo[1]):
            lx[:], R[:] = memo[2], memo[3]                     # the last cost's rows: the same numbers
        elif ct is not None and np.isfinite(X).all():           # R = l_xx, compiled
            (lx[:], R[:]), _ = kernels.task_rows(ct, T, X, self._steps)
        else:
            p.state_derivatives(X, out=(lx, R))                # R = l_xx
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
        from plants.fast_analytic import FastAnalyticDynamics

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
        lib = kernels.library() if self.compiled else None
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


def aico(problem: Problem, options: AICOOptions | None = None, *,
         X_init: np.ndarray | None = None, U_init: np.ndarray | None = None,
         callback: Callback | None = None) -> Result:
    """Plan with AICO (``alpha = 0``) or R-AICO (``alpha > 0``).

    Args:
        problem: the planning problem (needs a positive-definite control cost).
        options: ``AICOOptions`` (defaults if ``None``).
        X_init: initial trajectory ``(T+1, n_x)`` to linearize at (default: ``x0`` at every
            step, thesis §3.4; if only ``U_init`` is given, its rollout).
        U_init: initial controls ``(T, n_u)`` (default zeros).
        callback: called after each iteration with ``(record, X, U)``.

    Returns:
        ``Result``; a run whose cost becomes non-finite or explodes, or whose messages
        fail numerically, ends with status ``"diverged"`` (no exception).
    """
    opts = options or AICOOptions()
    with single_threaded_blas():
        b = problem.bounds
        if b is None or not b.has_controls:
            res = _aico(problem, opts, X_init, U_init, callback)
        else:   # the efforts are constraints of the iterations, unclipped; the plan's rollout clips them
            inner = dataclasses.replace(problem, bounds=dataclasses.replace(b, u_lower=None, u_upper=None))
            res = _aico(inner, opts, X_init, U_init, callback, efforts=b)
            if res.status is not Status.DIVERGED:
                X, U, o, O = bounded_rollout(problem, res.o, res.O)
                if np.all(np.isfinite(X)):   # else the unclipped plan stays, its status says out-of-bounds
                    res.X, res.U, res.o, res.O = X, U, o, O
                    if res.history:
                        res.history[-1] = dataclasses.replace(res.history[-1], cost=problem.cost(X, U))
        if b is not None:
            bounds_status(problem, res)
        return res


RANGE_TOL = 1e-4   # rad, rad/s: the constraints' target on a joint range's or velocity limit's violation
AL_INNER_TOL = 1e-3   # the multipliers move where the merit fell by less than this (relative), or inside the limits
AL_MU0 = 100.0   # the augmented Lagrangian's first penalty, in units of the cost's curvature (cost_curvature)


def _aico(problem: Problem, opts: AICOOptions, X_init, U_init, callback, efforts: Bounds | None = None) -> Result:
    T, n_u = problem.T, problem.n_u
    U = np.zeros((T, n_u)) if U_init is None else np.array(U_init, dtype=float)
    if U.shape != (T, n_u):
        raise ValueError(f"U_init has shape {U.shape}, expected {(T, n_u)}")
    X0_roll = _open_loop_rollout(problem, U)
    initial_cost = problem.cost(X0_roll, U)   # the problem's own sum (the compiled one rounds otherwise)
    if X_init is None:
        X = np.tile(problem.x0, (T + 1, 1)) if U_init is None else X0_roll
    else:
        X = np.array(X_init, dtype=float)
        if X.shape != (T + 1, problem.n_x) or not np.all(np.isfinite(X)):
            raise ValueError(f"X_init must be finite with shape {(T + 1, problem.n_x)}")
    _check_control_cost(problem)
    start = Iterate(X, U, U.copy(), np.zeros((T, n_u, problem.n_x)))
    step: _RobustStep | _AICOStep
    al = hard_constraints(problem, X, U, efforts)
    if al is not None:
        callback, costs = _own_costs(problem, al, callback)
    if opts.schedule == "robust":
        kappa = cost_curvature(problem, X, U)
        # one linearization per trial, at the current iterate (theta = inf): the step is then the minimizer of
        # the regularized model the acceptance test measures it against (a relinearization at the beliefs
        # inside the sweeps makes a step of other models, which that one often sees, rightly, raise the cost)
        sw = _Sweeps(problem, dataclasses.replace(opts, theta=math.inf, process_noise=opts.process_noise / kappa,
                                                  start_variance=opts.start_variance / kappa))
        feasible = bool(np.all(np.isfinite(X0_roll))) and np.allclose(X, X0_roll, rtol=1e-12, atol=0.0)
        sw.al = al
        start_merit = initial_cost + (al.value(X0_roll, U) if al is not None and feasible else 0.0)
        step = _RobustStep(problem, sw, opts, kappa, start_merit if feasible else None)
    else:
        sw = _Sweeps(problem, opts)
        sw.al = al
        step = _AICOStep(problem, sw, float(opts.alpha), opts.gamma, opts, initial_cost)
    test = cost_change_within
    if al is not None:     # no convergence outside the constraints
        def test(previous: float, cost: float, tol: float) -> bool:
            return al.last_violation <= 1.0 and cost_change_within(previous, cost, tol)
    out = drive(step, start, opts, initial_cost=initial_cost, callback=callback, test=test)
    if al is not None:     # the history reports the problem's own cost (the merit's constraint terms left out)
        out.history = [dataclasses.replace(h, cost=costs.get(h.iteration, h.cost)) for h in out.history]
        if any(y is not None for y in al.y):
            out.message += f" (constraints: {al.updates} multiplier updates, penalty {al.mu / al.mu0:.3g} x its start)"
    last = out.last_finite
    beliefs = None
    if out.status is not Status.DIVERGED:
        try:
            with np.errstate(all="ignore"):
                beliefs = sw.beliefs()
        except (NumericalError, ArithmeticError):
            beliefs = None
    return Result(X=last.X, U=last.U, o=last.o, O=last.O, status=out.status, history=out.history,
                  iterations=len(out.history), message=out.message, initial_cost=initial_cost,
                  beliefs=beliefs, solver="raico" if opts.alpha > 0 else "aico", X_initial=X0_roll)


def hard_constraints(problem: Problem, X: np.ndarray, U: np.ndarray, efforts: Bounds | None = None
                     ) -> AugmentedLagrangian | None:
    """The hard constraints of ``problem.bounds`` (joint ranges, from a start outside one as far as the velocity
    limits let it come back, :meth:`planning.problem.Bounds.position_box`; joint velocity limits) and the effort
    limits of ``efforts`` as an augmented Lagrangian with the penalty ``AL_MU0 kappa`` (:func:`cost_curvature`
    at ``X, U``: invariant to the cost's scale; on the efforts ``AL_MU0`` times the control cost's mean
    curvature), or ``None`` (no constraint)."""
    b = problem.bounds
    has_u = efforts is not None and efforts.has_controls
    if not has_u and (b is None or not (b.has_positions or b.has_velocities)):
        return None
    T, cons = problem.T, list[Constraint]()
    kappa = cost_curvature(problem, X, U)
    if b is not None and b.has_positions:
        dt = getattr(problem.dynamics, "dt", 1.0)
        lo, hi = b.position_box(problem.x0, float(dt) if isinstance(dt, (int, float)) and dt > 0 else 1.0, T)
        cons.append(StateBox("joint_range", b.q_index, lo, hi, RANGE_TOL))
    if b is not None and b.has_velocities:
        k = len(b.v_index)
        cons.append(StateBox("joint_velocity", b.v_index, np.broadcast_to(b.v_lower, (T + 1, k)),
                             np.broadcast_to(b.v_upper, (T + 1, k)), RANGE_TOL))
    if has_u:
        idx = np.flatnonzero(np.isfinite(efforts.u_lower) | np.isfinite(efforts.u_upper))
        _, H = problem.control_derivatives(U)
        curv = float(np.trace(H, axis1=1, axis2=2).mean()) / problem.n_u   # per (control unit)^2
        scale = np.max(np.abs(np.where(np.isfinite(efforts.u_upper), efforts.u_upper, 0.0)), initial=1.0)
        cons.append(ControlBox("effort", idx, efforts.u_lower[idx], efforts.u_upper[idx],
                               np.full(len(idx), RANGE_TOL * scale), scale=curv / kappa))
    return AugmentedLagrangian(cons, T, AL_MU0 * kappa)


def _own_costs(problem: Problem, al: AugmentedLagrangian, callback: Callback | None) -> tuple[Callback, dict[int, float]]:
    """A callback that records the problem's own cost of every iterate (the solver's is the merit) and passes
    it on to ``callback``, and the record it fills (iteration -> cost)."""
    costs: dict[int, float] = {}

    def cb(rec, X, U) -> None:  # noqa: ANN001
        extra = al.value(X, U)      # 0 where no constraint is active: the merit is the solver's own cost
        costs[rec.iteration] = c = rec.cost if extra == 0.0 else problem.cost(X, U)
        if callback is not None:
            callback(dataclasses.replace(rec, cost=c), X, U)
    return cb, costs


def _rows_identical(Z: np.ndarray) -> bool:
    """Whether every row of ``Z (K, ...)`` float64 has the bits of the first (NaN rows included)."""
    Z = np.asarray(Z)
    if Z.dtype != np.float64 or Z.shape[0] == 0:
        return False
    bits = np.ascontiguousarray(Z).view(np.uint64)
    return bool((bits == bits[:1]).all())


def _open_loop_rollout(problem: Problem, U: np.ndarray) -> np.ndarray:
    """States ``(T+1, n_x)`` of the controls ``U (T, n_u)`` from ``x0``: the numbers of
    :func:`plants.dynamics.rollout`, the Python loop. On a compiled model (``FastAnalyticDynamics``) its
    controller rollout with zero feedback gives them up to the first state that is not finite (``u_t =
    U_t + 0`` exactly, the same step); the loop goes on from there (where ``0 x_t`` would be NaN), unless
    that state is all NaN: then so is every later one (semi-implicit Euler adds each coordinate's old value)."""
    from plants.fast_analytic import FastAnalyticDynamics

    with np.errstate(all="ignore"):
        if not isinstance(problem.dynamics, FastAnalyticDynamics):
            return rollout(problem.dynamics, problem.x0, U)
        X, _ = problem.controller_rollout(U, np.zeros((problem.T, problem.n_u, problem.n_x)))
        bad = ~np.isfinite(X).all(axis=1)
        if bad.any():
            k = int(np.argmax(bad))     # rows 0..k are the loop's own (each stepped from a finite state)
            if np.isnan(X[k]).all():
                X[k + 1:] = np.nan
            else:
                X[k:] = rollout(problem.dynamics, X[k], U[k:])
        return X


class _AICOStep:
    """One AICO / R-AICO iteration (a ``driver.StepFn``): linearize at the current iterate,
    sweep, roll the new controller out on the planning dynamics.

    State: the sweeps ``sw`` and ``alpha`` (the regularization of the next iteration,
    ``alpha^[n] = alpha^[1] gamma^(n-1)``).
    """

    def __init__(self, problem: Problem, sw: _Sweeps, alpha: float, gamma: float,
                 opts: AICOOptions | None = None, initial_cost: float = math.inf):
        self.problem, self.sw, self.alpha, self.gamma = problem, sw, alpha, gamma
        self.opts = opts
        self.adaptive = opts is not None and opts.schedule == "adaptive"
        self.cur_cost = initial_cost   # cost of the iterate the next step starts from (adaptive)
        self._last_merit = math.inf    # the merit of the last iterate (the constraints' multiplier updates)

    def __call__(self, it: int, cur: Iterate) -> Step:
        step = self._trial(cur)
        if not self.adaptive or step.stop is not None:
            return self._update_constraints(step)
        o = self.opts
        if step.cost <= self.cur_cost:   # accepted: take larger steps
            self.alpha = max(o.alpha_min, step.step * o.shrink)
            step = self._update_constraints(step)
            self.cur_cost = step.cost
            return step
        self.alpha = min(o.alpha_max, step.step * o.grow)   # rejected: keep the iterate, smaller step
        return Step(cur, self.cur_cost, step=step.step, repeats=step.repeats, moved=False)

    def _trial(self, cur: Iterate) -> Step:
        sw, alpha = self.sw, self.alpha
        self.alpha *= self.gamma
        sw.repeats = 0
        try:
            with np.errstate(all="ignore"):
                sw.linearize_all(cur.X, cur.U, cur.X, alpha)
                self._after_linearize(cur)
                sw.sweep()
        except (NumericalError, ArithmeticError, np.linalg.LinAlgError) as e:
            return self._failed(cur, alpha, f"{type(e).__name__}: {e}")
        o_new, O_new = sw.o_, sw.O_
        eta = self.opts.controller_rate if self.opts is not None else 1.0
        if eta < 1.0:  # Algorithm 1 line 18's learning rate: blend with the previous controller
            o_new, O_new = (1.0 - eta) * cur.o + eta * o_new, (1.0 - eta) * cur.O + eta * O_new
        try:   # a model may raise on the exploding states of a diverging rollout
            Xn, Un, o_new, O_new = bounded_rollout(self.problem, o_new, O_new)
            cost = self.sw.cost(Xn, Un)
        except (ArithmeticError, ValueError, RuntimeError) as e:
            return self._failed(cur, alpha, f"rollout failed: {type(e).__name__}: {e}")
        # o_ and O_ are new arrays every sweep (no copies needed: 3 MB per iteration on the Nao)
        return Step(Iterate(Xn, Un, o_new, O_new), cost, step=alpha,
                    repeats=sw.repeats)

    def _after_linearize(self, cur: Iterate) -> None:
        """Hook after the linearization at ``cur``, before the sweeps (the robust schedule's model)."""

    def _merit(self, X: np.ndarray, U: np.ndarray) -> float:
        """The problem's cost of ``X, U``, plus the hard constraints' augmented Lagrangian terms (``sw.al``)."""
        c = self.problem.cost(X, U)
        if self.sw.al is not None and math.isfinite(c):
            c += self.sw.al.value(X, U)
        return c

    def _update_constraints(self, step: Step) -> Step:
        """After a step that moved the iterate: the multipliers' and penalty's update at its iterate
        (:meth:`planning.constraints.AugmentedLagrangian.update`), its cost the merit under them."""
        al = self.sw.al
        if al is None or not step.moved or (step.stop is not None and step.stop.status is Status.DIVERGED) \
                or not math.isfinite(step.cost):
            return step
        prev, self._last_merit = self._last_merit, step.cost
        if abs(prev - step.cost) > AL_INNER_TOL * abs(step.cost) and al.violation(step.iterate.X, step.iterate.U) > 1.0:
            return step     # the merit still falls: its minimizer is not yet found (the multipliers wait)
        X, U = step.iterate.X, step.iterate.U
        base = step.cost - al.value(X, U)
        al.update(X, U)
        self._last_merit = base + al.value(X, U)
        return dataclasses.replace(step, cost=self._last_merit)

    def _failed(self, cur: Iterate, alpha: float, why: str) -> Step:
        """A numerical failure: cost ``inf``, status diverged."""
        return Step(cur, math.inf, step=alpha, repeats=self.sw.repeats, moved=False,
                    stop=Stop(Status.DIVERGED, why))


LINE_SEARCH = (1.0, 0.5, 0.25)   # the robust schedule's feedforward steps before a rejection
NOISE_MAX = 1e6   # the robust schedule raises the process noise by 10 per failed factorization, up to this factor
ASCENTS = 5   # the robust schedule stops after this many rejections in a row of steps the model rightly sees rise


class _RobustStep(_AICOStep):
    """R-AICO's robust schedule (``AICOOptions.schedule = "robust"``): Levenberg-Marquardt style
    ``alpha = lambda kappa`` with acceptance by the ratio of actual to predicted decrease.

    State: ``lam`` (relative regularization of the next trial), ``cur_cost`` (cost of the current
    iterate, ``None`` while it is a start that is no trajectory) and the quadratic model of the cost
    at the current iterate (``_model``: ``l_x (T+1, n)``, ``l_xx (T+1, n, n)``, ``l_u (T, m)``,
    ``l_uu (T, m, m)``, the sweeps' own task and control messages before regularization).
    """

    def __init__(self, problem: Problem, sw: _Sweeps, opts: AICOOptions, kappa: float,
                 start_cost: float | None):
        super().__init__(problem, sw, float(opts.alpha) * kappa, 1.0, opts, math.inf)
        self.kappa, self.lam = kappa, float(opts.alpha)
        self.q0 = sw.q
        self.cur_cost = start_cost
        self._model: tuple | None = None
        self._model_of: Iterate | None = None
        self._record_model = False
        self.nu = 2.0    # the next rejection's factor (Nielsen: doubles per rejection in a row)
        self.ascents = 0  # rejections in a row whose step the model rightly predicts to raise the cost

    def __call__(self, it: int, cur: Iterate) -> Step:
        o = self.opts
        self.alpha = self.lam * self.kappa
        step = self._trial(cur)
        lam = self.lam
        failed = step.stop is not None and step.stop.status is Status.DIVERGED
        if failed and "NumericalError" in step.stop.message and self.sw.q < NOISE_MAX * self.q0:
            # a factorization failed: more process noise bounds the messages' precision (V* <= I / q)
            self.sw.q *= 10.0
            self.sw.qI = self.sw.q * self.sw.I
        if self.cur_cost is None:   # the start is no trajectory: take the first finite trial
            if failed or not math.isfinite(step.cost):
                return self._reject(cur, step, lam, self._merit(cur.X, cur.U), measured=False)
            start_cost = self._merit(cur.X, cur.U)
            self.lam = min(o.lambda_max, lam * o.lm_factor) if step.cost > start_cost else lam
            out = self._update_constraints(Step(step.iterate, step.cost, step=step.step, mu=lam,
                                                repeats=step.repeats))
            self.cur_cost = out.cost
            return out
        if failed:
            return self._reject(cur, step, lam, self.cur_cost, measured=False)
        trial, pred_full, measured = step.iterate, None, False
        for eps in LINE_SEARCH:
            if eps < 1.0:       # the same controller with its feedforward shortened about cur
                trial = self._shortened(cur, step.iterate, eps)
                if trial is None:
                    continue
            cost = step.cost if eps == 1.0 else self._merit(trial.X, trial.U)
            if not math.isfinite(cost):
                continue
            measured = True
            actual = self.cur_cost - cost
            pred = self._predicted_decrease(cur, trial)
            pred_full = pred if eps == 1.0 else pred_full
            if actual > 0 and (pred <= 0 or actual >= o.accept * pred):
                break
        else:
            out = self._reject(cur, step, lam, self.cur_cost, measured)
            tol = max(o.tol_rel, 1e-14) * abs(self.cur_cost)
            act_full = self.cur_cost - step.cost
            ascent = pred_full is not None and pred_full < 0 and abs(act_full - pred_full) <= 0.1 * abs(pred_full)
            self.ascents = self.ascents + 1 if ascent else 0
            if self.ascents >= ASCENTS:
                # the model is right and its step raises the cost: more regularization shortens the step, it does
                # not turn it (controls clipped to their bounds: the projected step is no descent direction)
                out = dataclasses.replace(out, stop=Stop(Status.CONVERGED, f"{ASCENTS} trials in a row whose step "
                                                     f"the cost's model rightly predicts to raise it (last "
                                                     f"{pred_full:.3g}): no descent direction at lambda = {lam:.3g}"))
            elif pred_full is not None and lam <= 1.0 and abs(pred_full) <= tol:
                # where the regularization is at most the cost's curvature the model's own step promises nothing
                # beyond rounding: a stationary point (else lambda would climb to its cap, trial after trial)
                out = dataclasses.replace(out, stop=Stop(Status.CONVERGED, f"predicted decrease {pred_full:.3g} "
                                                     f"below tol_rel x cost ({tol:.3g}) at lambda = {lam:.3g}"))
            return self._stationary_infeasible(cur, out)
        if eps < 1.0:   # the step was too long: more regularization next time
            self.lam = min(o.lambda_max, lam * 2.0)
        else:
            rho = 1.0 if pred <= 0 else actual / pred
            self.lam = max(o.lambda_min, lam * max(1.0 / o.lm_factor, 1.0 - (2.0 * min(rho, 1.0) - 1.0) ** 3))
        self.nu, self.ascents = 2.0, 0
        out = self._update_constraints(Step(trial, cost, step=step.step * eps, mu=lam, repeats=step.repeats))
        self.cur_cost = out.cost
        return out

    def _stationary_infeasible(self, cur: Iterate, out: Step) -> Step:
        """A stationary point of the merit that breaks a hard constraint is no solution: the multipliers and
        penalty move there (the merit changes, so does its model) and the run goes on."""
        al = self.sw.al
        if al is None or out.stop is None or out.stop.status is not Status.CONVERGED \
                or al.violation(cur.X, cur.U) <= 1.0:
            return out
        al.update(cur.X, cur.U)
        al.force_growth()
        self.cur_cost = self._merit(cur.X, cur.U)
        self._model_of, self.ascents = None, 0
        return dataclasses.replace(out, cost=self.cur_cost, stop=None)

    def _shortened(self, cur: Iterate, new: Iterate, eps: float) -> Iterate | None:
        """``u_t = U_t + eps (o_t + O_t X_t - U_t) + O_t (x_t - X_t)`` about ``cur`` (DDP's line
        search on the feedforward): ``o_eps = eps o + (1 - eps)(U - O X)``, rolled out (``None``
        if the rollout fails)."""
        OX = np.einsum("tij,tj->ti", new.O, cur.X[:-1])
        o_eps = eps * new.o + (1.0 - eps) * (cur.U - OX)
        try:
            with np.errstate(all="ignore"):
                X, U, o_eps, O = bounded_rollout(self.problem, o_eps, new.O)
        except (ArithmeticError, ValueError, RuntimeError):
            return None
        return Iterate(X, U, o_eps, O)

    def _reject(self, cur: Iterate, step: Step, lam: float, cost: float, measured: bool = True) -> Step:
        """Keep ``cur``; ``lambda`` grows by Nielsen's factor (2, 4, 8, then ``lm_factor`` per rejection in a
        row), or by ``lm_factor`` at once when no trial was ``measured`` (every rollout non-finite or failed: no
        ratio of actual to predicted decrease to go by); stop when it is at its cap."""
        o = self.opts
        stop = None
        if not measured:
            self.nu = o.lm_factor
        if lam >= o.lambda_max:
            why = step.stop.message if step.stop is not None else f"trial cost {step.cost:.6g}"
            stop = Stop(Status.MAX_ITERATIONS, f"no step lowers the cost at lambda = lambda_max = "
                                               f"{o.lambda_max:g} ({why})")
        self.lam = min(o.lambda_max, lam * self.nu)
        self.nu = min(2.0 * self.nu, o.lm_factor)
        return Step(cur, cost, step=step.step, mu=lam, repeats=step.repeats, moved=False, stop=stop)

    def _trial(self, cur: Iterate) -> Step:
        if self._model_of is not cur:     # the model at a new iterate: recorded before the sweeps
            self._record_model = True
        return super()._trial(cur)

    def _after_linearize(self, cur: Iterate) -> None:
        if getattr(self, "_record_model", False):
            sw, n = self.sw, self.sw.n
            R = sw.RA[:, :, :n].copy()
            R[:, np.arange(n), np.arange(n)] -= 2.0 * sw.alpha
            lu = np.einsum("tij,tj->ti", sw.H, cur.U) - sw.h
            self._model, self._model_of, self._record_model = (sw._lx.copy(), R, lu, np.array(sw.H)), cur, False

    def _predicted_decrease(self, cur: Iterate, new: Iterate) -> float:
        """``-(g^T d + 1/2 d^T G d)`` of the cost's quadratic model at ``cur`` along ``d = new - cur``."""
        lx, R, lu, H = self._model
        dX, dU = new.X - cur.X, new.U - cur.U
        q = float(np.einsum("ti,ti->", lx, dX) + 0.5 * np.einsum("ti,tij,tj->", dX, R, dX)
                  + np.einsum("ti,ti->", lu, dU) + 0.5 * np.einsum("ti,tij,tj->", dU, H, dU))
        return -q


def bounded_rollout(problem: Problem, o: np.ndarray, O: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``problem.bounded_rollout`` with the sweeps' kernel switch (tests turn the compiled code off)."""
    return problem.bounded_rollout(o, O, kernel=_Sweeps.compiled)


def backward_sweep_at_start(problem: Problem) -> tuple[Callable[[], None], bool]:
    """One backward sweep of ``problem`` at a fixed linearization (the start held, zero controls, no
    relinearization: ``theta = inf``), as a callable to time (call it inside :func:`single_threaded_blas`),
    and whether the kernel may take the semi-implicit Euler block form: the message arithmetic on its own
    (``bench.flops``)."""
    opts = dataclasses.replace(AICOOptions(), theta=math.inf)
    T = problem.T
    X, U = np.tile(problem.x0, (T + 1, 1)), np.zeros((T, problem.n_u))
    sw = _Sweeps(problem, opts)
    sw.linearize_all(X, U, X, 1.0)
    return sw.sweep, _block_form_dt(problem.dynamics) > 0


def cost_curvature(problem: Problem, X: np.ndarray, U: np.ndarray) -> float:
    """``kappa``: the mean diagonal of the state cost's Gauss-Newton Hessian along ``X (T+1, n)``
    (cost per (state unit)^2 and step), or of the control Hessian at ``U (T, m)`` if no state term
    costs anything; scales with the cost (the robust schedule's unit of alpha)."""
    problem.set_nominal(X, U)
    _, R = problem.state_derivatives(X)
    k = float(np.trace(R, axis1=1, axis2=2).mean()) / problem.n_x
    if not (math.isfinite(k) and k > 0):
        _, H = problem.control_derivatives(U)
        k = float(np.trace(H, axis1=1, axis2=2).mean()) / problem.n_u
    if not (math.isfinite(k) and k > 0):
        raise ValueError("the robust schedule needs a cost with positive curvature")
    return k


def _check_control_cost(problem: Problem) -> None:
    """AICO marginalizes the controls: their cost Hessian must be positive definite."""
    _, luu = problem.control_derivatives(np.zeros((1, problem.n_u)))
    if np.any(np.linalg.eigvalsh(luu[0]) <= 0):
        raise ValueError("AICO needs a positive-definite control cost (add a ControlCost "
                         "with weight > 0)")
